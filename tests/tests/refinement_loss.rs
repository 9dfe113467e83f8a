//! The light that refinement drops from T at epsilon (Fig. 5), and the bake's estimates of it:
//! in the Cornell box, T computed with a large epsilon delivers a different single-bounce light
//! than T with epsilon near zero (same basis, same gather rays, so the only difference is what
//! the keep rules dropped). The uniform-emission estimate (`RefineStats::dropped_share`) has the
//! sign of the change under uniform emission and is within a factor of two of it. The estimate
//! stored in the file (`drop_estimate`, the `TDRP` section, under the file's light) vanishes
//! when nothing is dropped; it sees only the links dropped at receivers that refinement
//! processed, not the detail of the receivers it never reached, and the numbers are printed.

use glam::Vec3;
use mlt_bake::drop_estimate::{estimate, representative_emission};
use mlt_bake::refine::{ReceiverLinks, RefinePolicy};
use mlt_bake::transport::refine_t;
use mlt_bake::{BakeOptions, Silent};
use mlt_format::light::{LightDesc, LightKind};
use mlt_format::meta::TransportParams;
use mlt_format::pull_push::pull_push_levels;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use mlt_tests::{bake_with, surface_samples};

const SPEC: &str = "builtin:cornell";
const SENDER_LEVELS: usize = 2;

fn params(epsilon: f32, levels: u32) -> TransportParams {
    TransportParams {
        epsilon,
        bounce_epsilon: epsilon,
        sender_levels: SENDER_LEVELS as u32,
        receiver_levels: levels,
        bounces: 1,
        gather_rays: 128,
        bounces_on_all_receivers: false,
        seed: 7,
    }
}

/// A unit point light near the left wall, the representative emission of the estimate.
fn light() -> LightDesc {
    LightDesc {
        kind: LightKind::Point,
        position: [0.2, 0.45, 0.3],
        intensity: [1.0; 3],
        direction: None,
        cone_deg: None,
        falloff: Default::default(),
    }
}

/// Mean single-bounce indirect irradiance `n . (T e)` over surface points seen from the
/// box's centre.
fn mean_irradiance(ib: &IndexedBasis, caster: &dyn RayCaster, t: &ReceiverLinks, e: &[f32]) -> f64 {
    let mut i = vec![0.0f32; ib.basis.len() * 9];
    for &r in &t.rows {
        let (senders, values) = t.row(r as usize);
        for (&s, v) in senders.iter().zip(values) {
            for c in 0..3 {
                for k in 0..3 {
                    i[9 * r as usize + 3 * c + k] += v[3 * c + k] * e[3 * s as usize + c];
                }
            }
        }
    }
    let samples = surface_samples(caster, Vec3::new(0.278, 0.274, 0.28), 400);
    let mut sum = 0.0f64;
    for (x, n) in &samples {
        let mut v = [0.0f32; 9];
        ib.reconstruct(&i, 9, 0..ib.levels(), x.to_array(), n.to_array(), &mut v);
        sum += (n.x * v[0] + n.y * v[1] + n.z * v[2]) as f64;
    }
    sum / samples.len() as f64
}

/// Four and five levels, so that levels 2 and 3 keep the coarsest-sender budget away from
/// contacts as in a default file (`RefinePolicy::keeps_budget`), at two epsilons each. The
/// uniform estimate counts only the dropped links of receivers whose children were not
/// refined: a refined receiver's dropped links reappear in its children's differences (Eq. 17).
/// Counted at every level instead, it was 2.3-4.1 times the loss at four and five levels. At
/// three levels, where the finest level 2 keeps the budget at contacts only, the leaves'
/// sum is 0.48 times the loss at epsilon 0.1 and 0.74 times at 0.2: a known limit, stated in
/// `docs/design.md`, "Accuracy". `MLT_LOSS_EPS` replaces the two epsilons by one.
#[test]
fn the_estimate_of_the_light_refinement_drops_is_within_a_factor_of_two() {
    let epsilons: Vec<f32> = match std::env::var("MLT_LOSS_EPS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        Some(e) => vec![e],
        // 0.15 rather than 0.1 since the supports are clipped at occluders: at five levels
        // epsilon 0.1 then drops only 1.2 % of the uniform light, too little to measure.
        None => vec![0.15, 0.2],
    };
    for levels in [4u32, 5] {
        for &eps in &epsilons {
            check(levels, eps);
        }
    }
}

fn check(levels: u32, eps: f32) {
    let opts = BakeOptions {
        receiver_levels: Some(levels),
        coarse_count: Some(36),
        sender_levels: Some(SENDER_LEVELS as u32),
        basis_only: true,
        ..Default::default()
    };
    let ib = bake_with(SPEC, opts, 2).contents.basis;
    let scene = mlt_scenes::load_scene(SPEC).unwrap();
    let caster = scene.build_caster();
    let senders = ib.basis.level_offsets[SENDER_LEVELS] as usize;
    // Uniform unit emission (what the estimate assumes) and a point light near a wall.
    let uniform = pull_push_levels(&ib, &vec![1.0; senders * 3], 3, SENDER_LEVELS).0;
    let model = mlt_format::light_model::Light::from_desc(&light()).unwrap();
    let point = representative_emission(&ib, caster.as_ref(), &model, SENDER_LEVELS);
    let refined = |epsilon| {
        refine_t(
            &ib,
            caster.as_ref(),
            &params(epsilon, levels),
            &RefinePolicy::default(),
            &light(),
            None,
            &Silent,
        )
        .unwrap()
    };
    let ((t_exact, s_exact, _), (t_cut, s_cut, _)) = (refined(1e-6), refined(eps));
    // Nothing is dropped at epsilon near zero.
    assert!(s_exact.dropped_share().abs() < 1e-3);
    assert!(estimate(&ib, &t_exact).share.abs() < 1e-3);
    let estimates = [s_cut.dropped_share(), estimate(&ib, &t_cut).share];
    let mut losses = Vec::new();
    for ((name, e), estimate) in [("uniform", &uniform), ("point light", &point)]
        .into_iter()
        .zip(estimates)
    {
        let exact = mean_irradiance(&ib, caster.as_ref(), &t_exact, e);
        let cut = mean_irradiance(&ib, caster.as_ref(), &t_cut, e);
        let loss = 1.0 - cut / exact;
        eprintln!(
            "{name}, {levels} levels: epsilon {eps} keeps {} of {} links; measured loss {loss:.4}, estimate {estimate:.4}",
            t_cut.link_count(),
            t_exact.link_count(),
        );
        assert!(
            loss.abs() > 0.015,
            "{name}, {levels} levels: epsilon {eps} should change the light: {loss}"
        );
        losses.push(loss);
    }
    // The uniform-emission estimate against uniform emission: the sign, and the size within a
    // factor of two.
    let (estimate, loss) = (estimates[0], losses[0]);
    let ratio = estimate.abs() / loss.abs();
    assert!(
        (0.5..2.0).contains(&ratio),
        "{levels} levels, epsilon {eps}: estimate {estimate} against the measured loss {loss}"
    );
    assert_eq!(estimate.signum(), loss.signum(), "{estimate} {loss}");
}
