//! Wavefront OBJ (+ MTL + textures) loading through tobj.
//!
//! Polygons are fan-triangulated, points and lines ignored. Per-material `Kd` is the
//! albedo and `map_Kd` its texture; faces without a material, or an OBJ whose material
//! library is missing, get grey 0.5 with a warning. Emission (`Ke`) is not supported yet and
//! only warned about. Texture coordinates are stored with `v` flipped (see
//! [`crate::texture`]). Vertex normals are renormalised; zero or non-finite ones are marked
//! absent.

use std::cell::RefCell;
use std::collections::HashMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use xxhash_rust::xxh3::Xxh3;

use crate::error::SceneError;
use crate::fsutil::{join_reference, resolve_case_insensitive};
use crate::mesh::{Material, Mesh, DEFAULT_ALBEDO};
use crate::texture::Texture;

/// Records a loader warning and sends it to the log.
pub(crate) fn warn(warnings: &mut Vec<String>, message: String) {
    log::warn!("{message}");
    warnings.push(message);
}

/// What happened to one `mtllib` reference while tobj parsed the OBJ.
enum MtlOutcome {
    Loaded { bytes: Vec<u8> },
    Missing { path: PathBuf },
    Unparsable { path: PathBuf, message: String },
}

/// Loads an OBJ file, scaling positions by `scale`. Returns the mesh (zero-area triangles
/// dropped), the warnings raised, and the xxh3-64 hash of every byte read (OBJ, MTL files and
/// texture files, in that order).
pub fn load_obj(path: &Path, scale: f32) -> Result<(Mesh, Vec<String>, u64), SceneError> {
    if !scale.is_finite() || scale <= 0.0 {
        return Err(SceneError::Obj {
            path: path.to_path_buf(),
            message: format!("scale must be finite and positive, got {scale}"),
        });
    }
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    let mut hasher = Xxh3::new();
    hasher.update(&bytes);
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let mut warnings = Vec::new();

    // The struct update covers fields that only exist with some tobj features.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let mtl_outcomes: RefCell<Vec<MtlOutcome>> = RefCell::new(Vec::new());
    if let Some(message) = index_out_of_range(&bytes) {
        return Err(SceneError::Obj {
            path: path.to_path_buf(),
            message,
        });
    }
    let parsed = tobj::load_obj_buf(&mut Cursor::new(&bytes), &options, |mtl_ref| {
        let wanted = join_reference(&dir, &mtl_ref.to_string_lossy());
        let empty = || Ok((Vec::new(), Default::default()));
        let Some(found) = resolve_case_insensitive(&wanted) else {
            mtl_outcomes
                .borrow_mut()
                .push(MtlOutcome::Missing { path: wanted });
            return empty();
        };
        let mtl_bytes = match std::fs::read(&found) {
            Ok(b) => b,
            Err(e) => {
                mtl_outcomes.borrow_mut().push(MtlOutcome::Unparsable {
                    path: found,
                    message: e.to_string(),
                });
                return empty();
            }
        };
        if let Some(message) = short_colour_line(&mtl_bytes) {
            mtl_outcomes.borrow_mut().push(MtlOutcome::Unparsable {
                path: found,
                message,
            });
            return empty();
        }
        let result = tobj::load_mtl_buf(&mut Cursor::new(&mtl_bytes));
        match result {
            Ok(r) => {
                mtl_outcomes
                    .borrow_mut()
                    .push(MtlOutcome::Loaded { bytes: mtl_bytes });
                Ok(r)
            }
            Err(e) => {
                mtl_outcomes.borrow_mut().push(MtlOutcome::Unparsable {
                    path: found,
                    message: e.to_string(),
                });
                empty()
            }
        }
    });
    let (models, materials) = parsed.map_err(|e| SceneError::Obj {
        path: path.to_path_buf(),
        message: describe_tobj_error(e, &bytes),
    })?;
    for outcome in mtl_outcomes.into_inner() {
        match outcome {
            MtlOutcome::Loaded { bytes } => hasher.update(&bytes),
            MtlOutcome::Missing { path: mtl } => warn(
                &mut warnings,
                format!(
                    "{}: material library {} not found; using grey {} for its materials",
                    path.display(),
                    mtl.display(),
                    DEFAULT_ALBEDO[0]
                ),
            ),
            MtlOutcome::Unparsable { path: mtl, message } => {
                return Err(SceneError::Obj {
                    path: mtl,
                    message: format!("material library: {message}"),
                })
            }
        }
    }
    // tobj only reports an error here when every library failed, which we handled above.
    let materials = materials.unwrap_or_default();

    let mut mesh = Mesh::default();
    convert_materials(
        path,
        &dir,
        &materials,
        &mut mesh,
        &mut warnings,
        &mut hasher,
    );
    append_models(path, &bytes, &models, scale, &mut mesh, &mut warnings)?;

    mesh.finish(path, &mut warnings)?;
    Ok((mesh, warnings, hasher.digest()))
}

/// Converts tobj materials into ours (textures loaded, emission warned about).
fn convert_materials(
    obj_path: &Path,
    dir: &Path,
    materials: &[tobj::Material],
    mesh: &mut Mesh,
    warnings: &mut Vec<String>,
    hasher: &mut Xxh3,
) {
    let mut texture_index: HashMap<PathBuf, Option<u32>> = HashMap::new();
    for m in materials {
        let albedo = match m.diffuse {
            Some(kd) => kd,
            None => {
                warn(
                    warnings,
                    format!(
                        "{}: material '{}' has no Kd; using grey {}",
                        obj_path.display(),
                        m.name,
                        DEFAULT_ALBEDO[0]
                    ),
                );
                DEFAULT_ALBEDO
            }
        };
        let ke = m.emissive.or_else(|| {
            m.unknown_param
                .get("Ke")
                .and_then(|s| parse_triple(s.split_whitespace()))
        });
        if let Some(ke) = ke.filter(|ke| ke.iter().any(|&c| c != 0.0)) {
            warn(
                warnings,
                format!(
                    "{}: material '{}' is emissive (Ke {} {} {}); emission ignored for now",
                    obj_path.display(),
                    m.name,
                    ke[0],
                    ke[1],
                    ke[2]
                ),
            );
        }
        let texture = m.diffuse_texture.as_deref().and_then(|reference| {
            let file = texture_file_name(reference);
            let wanted = join_reference(dir, file);
            let entry = texture_index.entry(wanted.clone()).or_insert_with(|| {
                load_texture_file(&wanted, &m.name, warnings, hasher).map(|t| {
                    mesh.textures.push(t);
                    (mesh.textures.len() - 1) as u32
                })
            });
            *entry
        });
        mesh.materials.push(Material {
            name: m.name.clone(),
            albedo,
            texture,
        });
    }
}

/// The file name in a `map_Kd` value, skipping options such as `-bm 1` or `-s 1 1 1`.
fn texture_file_name(value: &str) -> &str {
    let value = value.trim();
    if value.starts_with('-') {
        value.split_whitespace().last().unwrap_or(value)
    } else {
        value
    }
}

/// Loads one texture file (with a case-insensitive fallback); on failure warns and returns
/// `None` so the material is used untextured.
fn load_texture_file(
    wanted: &Path,
    material: &str,
    warnings: &mut Vec<String>,
    hasher: &mut Xxh3,
) -> Option<Texture> {
    let Some(found) = resolve_case_insensitive(wanted) else {
        warn(
            warnings,
            format!(
                "{}: texture of material '{material}' not found; using its Kd alone",
                wanted.display()
            ),
        );
        return None;
    };
    if found != wanted {
        log::info!(
            "{}: using {} (file name differs in case)",
            wanted.display(),
            found.display()
        );
    }
    let result = std::fs::read(&found)
        .map_err(|e| SceneError::io(&found, e))
        .and_then(|bytes| {
            hasher.update(&bytes);
            Texture::decode(&bytes, &found)
        });
    match result {
        Ok(t) => Some(t),
        Err(e) => {
            warn(
                warnings,
                format!("{e} (material '{material}' used without texture)"),
            );
            None
        }
    }
}

/// Appends tobj's models (one per group/material run) to `mesh`.
fn append_models(
    path: &Path,
    text: &[u8],
    models: &[tobj::Model],
    scale: f32,
    mesh: &mut Mesh,
    warnings: &mut Vec<String>,
) -> Result<(), SceneError> {
    let any_normals = models.iter().any(|m| !m.mesh.normals.is_empty());
    let any_uvs = models.iter().any(|m| !m.mesh.texcoords.is_empty());
    let mut default_material: Option<u32> = None;
    let mut partial_normals = 0usize;
    let mut partial_uvs = 0usize;
    for model in models {
        let m = &model.mesh;
        let base = mesh.positions.len() as u32;
        let count = m.positions.len() / 3;
        for (k, p) in m.positions.chunks_exact(3).enumerate() {
            let v = Vec3::new(p[0], p[1], p[2]);
            if !v.is_finite() {
                return Err(non_finite_vertex(path, text, mesh.positions.len() + k));
            }
            let scaled = v * scale;
            if !scaled.is_finite() {
                return Err(SceneError::NonFinite {
                    path: path.to_path_buf(),
                    what: format!(
                        "vertex {} position (after scaling by {scale})",
                        base as usize + k
                    ),
                });
            }
            mesh.positions.push(scaled);
        }
        if any_normals {
            if m.normals.len() == 3 * count {
                for n in m.normals.chunks_exact(3) {
                    let n = Vec3::new(n[0], n[1], n[2]);
                    if !n.is_finite() {
                        // NaN or infinite: an error in the file (a zero normal is only
                        // absent, and warned about).
                        return Err(non_finite_statement(path, text, "vn", "normal"));
                    }
                    mesh.normals.push(n);
                }
            } else {
                partial_normals += count;
                mesh.normals.extend(std::iter::repeat_n(Vec3::ZERO, count));
            }
        }
        if any_uvs {
            if m.texcoords.len() == 2 * count {
                for (k, t) in m.texcoords.chunks_exact(2).enumerate() {
                    let uv = Vec2::new(t[0], 1.0 - t[1]);
                    if !uv.is_finite() {
                        return Err(SceneError::NonFinite {
                            path: path.to_path_buf(),
                            what: format!("vertex {} texture coordinate", base as usize + k),
                        });
                    }
                    mesh.uvs.push(uv);
                }
            } else {
                partial_uvs += count;
                mesh.uvs.extend(std::iter::repeat_n(Vec2::ZERO, count));
            }
        }
        let material = match m.material_id {
            Some(id) if id < mesh.materials.len() => id as u32,
            _ => *default_material.get_or_insert_with(|| {
                warn(
                    warnings,
                    format!(
                        "{}: faces without a (known) material, e.g. in group '{}'; using grey {}",
                        path.display(),
                        model.name,
                        DEFAULT_ALBEDO[0]
                    ),
                );
                mesh.materials
                    .push(Material::plain("(default grey)", DEFAULT_ALBEDO));
                (mesh.materials.len() - 1) as u32
            }),
        };
        for tri in m.indices.chunks_exact(3) {
            if let Some(&index) = tri.iter().find(|&&i| i as usize >= count) {
                return Err(SceneError::IndexOutOfRange {
                    path: path.to_path_buf(),
                    triangle: mesh.triangles.len(),
                    index: base + index,
                    vertex_count: mesh.positions.len(),
                });
            }
            mesh.triangles
                .push([base + tri[0], base + tri[1], base + tri[2]]);
            mesh.triangle_material.push(material);
        }
    }
    if partial_normals > 0 {
        warn(
            warnings,
            format!(
                "{}: {partial_normals} vertices belong to faces without normals; they use the face normal",
                path.display()
            ),
        );
    }
    if partial_uvs > 0 {
        warn(
            warnings,
            format!(
                "{}: {partial_uvs} vertices have no texture coordinates (set to 0, 0)",
                path.display()
            ),
        );
    }
    Ok(())
}

/// The first face, line or point index out of range in a way tobj does not check: a positive
/// one beyond the file's line count (every vertex takes a line, so no valid index is), or a
/// negative (relative) one reaching before the first vertex, normal or texture coordinate.
/// tobj multiplies such indices unchecked, which overflows.
fn index_out_of_range(text: &[u8]) -> Option<String> {
    let lines = text.split(|&b| b == b'\n').count() as u64;
    // Statements seen so far: v, vt, vn (the slots of a face vertex `v/vt/vn`).
    let mut seen = [0u64; 3];
    for (i, line) in text.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => seen[0] += 1,
            Some("vt") => seen[1] += 1,
            Some("vn") => seen[2] += 1,
            Some("f" | "l" | "p") => {
                for w in words {
                    for (slot, k) in w.split('/').enumerate().take(3) {
                        let Ok(k) = k.parse::<i64>() else {
                            continue;
                        };
                        let out = match k < 0 {
                            true => k.unsigned_abs() > seen[slot],
                            false => k as u64 > lines,
                        };
                        if out {
                            return Some(format!("line {}: index {k} is out of range", i + 1));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    None
}

/// The first colour statement (`Ka`, `Kd`, `Ks`, `Ke`) with fewer than three values, which
/// tobj's MTL parser would panic on; such a file is refused instead, naming the line.
fn short_colour_line(mtl: &[u8]) -> Option<String> {
    mtl.split(|&b| b == b'\n')
        .enumerate()
        .find_map(|(i, line)| {
            let line = String::from_utf8_lossy(line);
            let mut words = line.split_whitespace();
            let key = words.next()?;
            (["Ka", "Kd", "Ks", "Ke"].contains(&key) && words.count() < 3)
                .then(|| format!("line {}: {key} needs three numbers", i + 1))
        })
}

fn parse_triple<'a>(mut words: impl Iterator<Item = &'a str>) -> Option<[f32; 3]> {
    let mut out = [0.0; 3];
    for o in &mut out {
        *o = words.next()?.parse().ok()?;
    }
    Some(out)
}

/// Error for a non-finite `keyword` statement (`vn`, `vt`): names the first one with a
/// non-finite number and its line.
fn non_finite_statement(path: &Path, text: &[u8], keyword: &str, what: &str) -> SceneError {
    let text = String::from_utf8_lossy(text);
    let mut number = 0usize;
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some(keyword) {
            continue;
        }
        number += 1;
        if words.any(|w| w.parse::<f32>().map_or(true, |x| !x.is_finite())) {
            return SceneError::NonFinite {
                path: path.to_path_buf(),
                what: format!("{what} {number} ('{keyword}' on line {})", line_no + 1),
            };
        }
    }
    SceneError::NonFinite {
        path: path.to_path_buf(),
        what: format!("a vertex {what}"),
    }
}

/// Error for a non-finite position: names the `v` statement and its line in the file when it
/// can be found, else the loader's vertex number.
fn non_finite_vertex(path: &Path, text: &[u8], mesh_index: usize) -> SceneError {
    let text = String::from_utf8_lossy(text);
    let mut v_number = 0usize;
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        v_number += 1;
        let bad = words
            .take(3)
            .any(|w| w.parse::<f32>().map_or(true, |x| !x.is_finite()));
        if bad {
            return SceneError::NonFinite {
                path: path.to_path_buf(),
                what: format!("vertex {v_number} (line {})", line_no + 1),
            };
        }
    }
    SceneError::NonFinite {
        path: path.to_path_buf(),
        what: format!("vertex {mesh_index}"),
    }
}

/// Turns a tobj error into a message; for face errors, finds the first offending line.
fn describe_tobj_error(e: tobj::LoadError, text: &[u8]) -> String {
    use tobj::LoadError as E;
    let face_error = matches!(
        e,
        E::FaceParseError
            | E::FaceVertexOutOfBounds
            | E::FaceTexCoordOutOfBounds
            | E::FaceNormalOutOfBounds
    );
    if face_error {
        if let Some(detail) = find_bad_face(text) {
            return format!("{e}: {detail}");
        }
    }
    e.to_string()
}

/// Scans an OBJ for the first face with an index that is zero, unparsable or out of range
/// (relative indices resolved against the counts so far, absolute ones against the totals).
fn find_bad_face(text: &[u8]) -> Option<String> {
    let text = String::from_utf8_lossy(text);
    let mut totals = [0i64; 3];
    for line in text.lines() {
        match line.split_whitespace().next() {
            Some("v") => totals[0] += 1,
            Some("vt") => totals[1] += 1,
            Some("vn") => totals[2] += 1,
            _ => {}
        }
    }
    let names = ["vertex", "texture coordinate", "normal"];
    let mut so_far = [0i64; 3];
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => so_far[0] += 1,
            Some("vt") => so_far[1] += 1,
            Some("vn") => so_far[2] += 1,
            Some("f") => {
                for corner in words {
                    for (k, part) in corner.split('/').enumerate().take(3) {
                        if part.is_empty() {
                            continue;
                        }
                        let bad = match part.parse::<i64>() {
                            Ok(i) if i > 0 => i > totals[k],
                            Ok(i) if i < 0 => -i > so_far[k],
                            _ => true,
                        };
                        if bad {
                            return Some(format!(
                                "line {}: face refers to {} '{part}', but {} are defined",
                                line_no + 1,
                                names[k],
                                totals[k]
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    use mlt_test_support::TempDir;

    fn temp_dir(name: &str) -> TempDir {
        TempDir::new(&format!("obj-{name}"))
    }

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("write temp file");
        p
    }

    #[test]
    fn quad_with_material_texture_and_flipped_v() {
        let dir = temp_dir("quad");
        let mut png = Vec::new();
        image::RgbImage::from_raw(1, 2, vec![255, 0, 0, 0, 255, 0])
            .expect("size")
            .write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("png");
        std::fs::write(dir.join("Tex.PNG"), &png).expect("write png");
        write(
            &dir,
            "m.mtl",
            "newmtl a\nKd 0.5 1 1\nmap_Kd tex.png\nnewmtl glow\nKd 1 1 1\nKe 1 2 3\n",
        );
        let obj = write(
            &dir,
            "q.obj",
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0.25\nvt 1 0.25\nvt 1 0.75\nvt 0 0.75\n\
             usemtl a\nf 1/1 2/2 3/3 4/4\nusemtl glow\nf 1/1 3/3 4/4\n",
        );
        let (mesh, warnings, hash) = load_obj(&obj, 2.0).expect("loads");
        assert_eq!(mesh.triangles.len(), 3);
        assert_eq!(mesh.positions.iter().map(|p| p.x).fold(0.0, f32::max), 2.0);
        assert_eq!(mesh.textures.len(), 1, "case-insensitive texture lookup");
        // OBJ v = 0 (bottom) is the last image row (green); v = 1 the first (red). Texel
        // centres of the 1x2 image are at v = 0.25 and 0.75.
        let bottom = mesh.albedo_at(0, (0.0, 0.0)); // corner 1: vt 0 0.25
        assert!(bottom[1] > 0.9 && bottom[0] < 0.1, "{bottom:?}");
        let top = mesh.albedo_at(0, (0.0, 1.0)); // corner 3: vt 1 0.75
        assert!((top[0] - 0.5).abs() < 1e-5 && top[1] < 0.1, "{top:?}");
        assert!(warnings
            .iter()
            .any(|w| w.contains("glow") && w.contains("emission ignored")));
        assert_ne!(hash, 0);
    }

    #[test]
    fn missing_mtl_and_unmaterialled_faces_are_grey() {
        let dir = temp_dir("nomtl");
        let obj = write(
            &dir,
            "t.obj",
            "mtllib nowhere.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nusemtl x\nf 1//1 2//1 3//1\n",
        );
        let (mesh, warnings, _) = load_obj(&obj, 1.0).expect("loads");
        assert_eq!(mesh.albedo_at(0, (0.3, 0.3)), DEFAULT_ALBEDO);
        assert!(warnings.iter().any(|w| w.contains("nowhere.mtl")));
        // The zero normal is absent: shading normal falls back.
        assert_eq!(mesh.shading_normal(0, (0.3, 0.3)), None);
    }

    #[test]
    fn a_colour_with_too_few_values_is_an_error_naming_the_mtl_and_line() {
        let dir = temp_dir("shortkd");
        write(&dir, "m.mtl", "newmtl a\nKd 0.5\n");
        let obj = write(
            &dir,
            "t.obj",
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n",
        );
        let e = load_obj(&obj, 1.0).unwrap_err().to_string();
        assert!(e.contains("m.mtl") && e.contains("line 2: Kd"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_huge_face_index_is_an_error_naming_the_line() {
        let dir = temp_dir("hugeidx");
        let obj = write(
            &dir,
            "t.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/4611686018427387904 2 3\n",
        );
        let e = load_obj(&obj, 1.0).unwrap_err().to_string();
        assert!(e.contains("t.obj") && e.contains("line 5: index"), "{e}");
        let obj = write(
            &dir,
            "n.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//-1 2//-1 3//-2\n",
        );
        let e = load_obj(&obj, 1.0).unwrap_err().to_string();
        assert!(e.contains("line 5: index -2 is out of range"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn bad_objs_give_errors_naming_the_file() {
        let dir = temp_dir("bad");
        let cases = [
            (
                "nan.obj",
                "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
                "vertex 2",
            ),
            (
                "inf.obj",
                "v 0 0 0\nv 1 0 0\nv 0 inf 0\nf 1 2 3\n",
                "vertex 3",
            ),
            (
                "range.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
                "line 4",
            ),
            (
                "nan_normal.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 NaN 1\nf 1//1 2//2 3//1\n",
                "normal 2 ('vn' on line 5)",
            ),
            (
                "inf_normal.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn -inf 0 1\nf 1//1 2//1 3//1\n",
                "normal 1 ('vn' on line 4)",
            ),
            (
                "nan_kd.obj",
                "mtllib nan.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n",
                "material 'm' albedo",
            ),
            ("relative.obj", "v 0 0 0\nv 1 0 0\nf -1 -2 -3\n", "line 3"),
            ("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4"),
            ("empty.obj", "v 0 0 0\nv 1 0 0\nl 1 2\n", "no triangles"),
            (
                "flat.obj",
                "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n",
                "no triangles",
            ),
        ];
        write(&dir, "nan.mtl", "newmtl m\nKd 0.5 nan 0.5\n");
        for (name, text, needle) in cases {
            let p = write(&dir, name, text);
            let e = load_obj(&p, 1.0).expect_err(name).to_string();
            assert!(e.contains(name), "{e}");
            assert!(e.contains(needle), "{name}: {e}");
        }
        let missing = dir.join("does-not-exist.obj");
        let e = load_obj(&missing, 1.0).unwrap_err();
        assert!(matches!(e, SceneError::Io { .. }));
        assert!(e.to_string().contains("does-not-exist.obj"), "{e}");
    }

    #[test]
    fn texture_option_flags_are_skipped() {
        assert_eq!(texture_file_name("-bm 0.5 bump.jpg"), "bump.jpg");
        assert_eq!(texture_file_name(" my tex.jpg "), "my tex.jpg");
    }
}
