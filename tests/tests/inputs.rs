//! NaN or infinity anywhere in the inputs is refused with a message that names the input and
//! the field: built-in parameters and bake options here; OBJ, glTF and manifests in the
//! scenes crate's tests (obj.rs, gltf_scene.rs, tests/manifests.rs), the command line in
//! bake/tests/cli.rs.

use mlt_bake::{bake_scene, BakeOptions, Silent};

#[test]
fn non_finite_builtin_parameters_name_the_scene_and_the_key() {
    for (spec, key) in [
        ("sphere?radius=inf", "radius"),
        ("sphere?albedo=nan", "albedo"),
        ("sphere?albedo=0.5,NaN,0.5", "albedo"),
        ("sphere-mesh?radius=-inf", "radius"),
        ("box?size=NaN", "size"),
        ("box?albedo=inf", "albedo"),
        ("quad?size=infinity", "size"),
        ("triangle?albedo=nan", "albedo"),
        ("cornell?scale=inf", "scale"),
        ("cornell?scale=1e39", "scale"),
    ] {
        let e = mlt_scenes::load_scene(&format!("builtin:{spec}"))
            .err()
            .unwrap_or_else(|| panic!("{spec} accepted"));
        let msg = e.to_string();
        let name = spec.split('?').next().unwrap();
        assert!(
            msg.contains(&format!("builtin:{name}")) && msg.contains(key),
            "{spec}: {msg}"
        );
        assert!(msg.contains("finite"), "{spec}: {msg}");
    }
}

#[test]
fn non_finite_bake_options_are_refused_naming_the_option() {
    let scene = mlt_scenes::load_scene("builtin:sphere").unwrap();
    let small = || BakeOptions {
        receiver_levels: Some(2),
        coarse_count: Some(12),
        sender_levels: Some(1),
        gather_rays: Some(16),
        ..Default::default()
    };
    let cases: Vec<(BakeOptions, &str)> = vec![
        (
            BakeOptions {
                epsilon: Some(f32::NAN),
                ..small()
            },
            "epsilon",
        ),
        (
            BakeOptions {
                epsilon: Some(f32::INFINITY),
                ..small()
            },
            "epsilon",
        ),
        (
            BakeOptions {
                bounce_epsilon: Some(f32::NAN),
                ..small()
            },
            "bounce epsilon",
        ),
        (
            BakeOptions {
                coarse_radius: Some(f32::INFINITY),
                coarse_count: None,
                ..small()
            },
            "coarse radius",
        ),
        (
            BakeOptions {
                coarse_radius: Some(f32::NAN),
                coarse_count: None,
                ..small()
            },
            "coarse radius",
        ),
        (
            BakeOptions {
                bounce_tolerance: Some(f64::NAN),
                ..small()
            },
            "bounce tolerance",
        ),
    ];
    for (opts, field) in cases {
        let e = bake_scene(&scene, &opts, &Silent)
            .err()
            .unwrap_or_else(|| panic!("{field}: accepted"));
        let msg = e.to_string();
        assert!(msg.contains(field), "{field}: {msg}");
        assert!(
            msg.contains("finite") || msg.contains("fraction"),
            "{field}: {msg}"
        );
    }
}

/// A manifest's non-finite `[bake]` numbers are refused at load time, naming the manifest,
/// before the bake would refuse them without a file name.
#[test]
fn a_manifest_bake_table_with_nan_names_the_manifest() {
    let dir = mlt_tests::TempDir::new("inputs");
    let path = dir.join("nan_bake.toml");
    std::fs::write(
        &path,
        "[scene]\nsource = \"builtin:sphere\"\n[bake]\nepsilon = nan\n",
    )
    .unwrap();
    let e = mlt_scenes::load_scene(path.to_str().unwrap()).expect_err("accepted");
    let msg = e.to_string();
    assert!(
        msg.contains("nan_bake.toml") && msg.contains("[bake] epsilon"),
        "{msg}"
    );
}
