//! With epsilon -> 0, the adaptive S equals a dense brute-force computation of the same
//! discrete operator (every link, no refinement), written here independently, to within the
//! Monte Carlo noise that two dense computations with different random numbers show.

use glam::Vec3;
use mlt_bake::BakeOptions;
use mlt_format::links::LINK_DIM;
use mlt_format::pull_push::{project, pull_push};
use mlt_format::shepard::MIN_WEIGHT_SUM;
use mlt_format::{BakedFile, IndexedBasis, WriteOptions};
use mlt_scenes::RayCaster;
use mlt_tests::{bake_with, surface_samples};

type Link = [f32; LINK_DIM];

/// SplitMix64, independent of the bake's generator.
struct Rand(u64);
impl Rand {
    fn f(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e3779b97f4a7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Dense T' by plain Monte Carlo: uniform random hemisphere directions, Eq. 16 with 1/pi.
fn dense_t_prime(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    senders: usize,
    sender_levels: usize,
    rays: u32,
    seed: u64,
) -> Vec<Vec<Link>> {
    let b = &ib.basis;
    let eps = caster.ray_epsilon();
    (0..b.len())
        .map(|i| {
            let mut row = vec![[0.0f32; LINK_DIM]; senders];
            let x = Vec3::from(b.positions[i]);
            let n = Vec3::from(b.normals[i]);
            let mut rng = Rand(seed ^ (i as u64).wrapping_mul(0x2545F4914F6CDD1D));
            for _ in 0..rays {
                // Uniform direction on the sphere, flipped into the hemisphere.
                let z = 1.0 - 2.0 * rng.f();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = std::f32::consts::TAU * rng.f();
                let mut d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                if d.dot(n) < 0.0 {
                    d = -d;
                }
                let Some(h) = caster.intersect(x + n * eps, d, 0.0, f32::INFINITY) else {
                    continue;
                };
                let (y, ny) = (h.position.to_array(), h.shading_normal.to_array());
                for m in 0..sender_levels {
                    let mut ws = Vec::new();
                    let sum = ib.for_each_weight(m, y, ny, |j, w| ws.push((j, w)));
                    if sum <= MIN_WEIGHT_SUM {
                        continue;
                    }
                    for (j, w) in ws {
                        // pdf 1 / (2 pi), times 1/pi: 2 / rays.
                        let k = 2.0 / rays as f32 * w / sum;
                        for c in 0..3 {
                            for a in 0..3 {
                                row[j][3 * c + a] += k * h.albedo[c] * d[a];
                            }
                        }
                    }
                }
            }
            row
        })
        .collect()
}

/// Dense S with bounces on all receivers: T by Eq. 7 per sender column, then the series.
fn dense_s(ib: &IndexedBasis, tp: &[Vec<Link>], senders: usize, bounces: u32) -> Vec<Vec<Link>> {
    let b = &ib.basis;
    let n = b.len();
    // Eq. 17 is Eq. 7 applied to each sender's column of T'.
    let mut t = vec![vec![[0.0f32; LINK_DIM]; senders]; n];
    for s in 0..senders {
        let column: Vec<f32> = (0..n).flat_map(|i| tp[i][s]).collect();
        let (alpha, _) = project(ib, &column, LINK_DIM);
        for i in 0..n {
            t[i][s].copy_from_slice(&alpha[i * LINK_DIM..(i + 1) * LINK_DIM]);
        }
    }
    let n0 = b.level_range(0).len();
    let mut s_total = t.clone();
    let mut prev = t.clone();
    for _ in 2..=bounces {
        let mut next = vec![vec![[0.0f32; LINK_DIM]; senders]; n];
        for r in 0..n {
            for j in 0..n0 {
                let k = t[r][j];
                let nj = b.normals[j];
                for s in 0..senders {
                    let v = prev[j][s];
                    for c in 0..3 {
                        let y = nj[0] * v[3 * c] + nj[1] * v[3 * c + 1] + nj[2] * v[3 * c + 2];
                        for a in 0..3 {
                            next[r][s][3 * c + a] += k[3 * c + a] * y;
                        }
                    }
                }
            }
        }
        for r in 0..n {
            for s in 0..senders {
                for d in 0..LINK_DIM {
                    s_total[r][s][d] += next[r][s][d];
                }
            }
        }
        prev = next;
    }
    s_total
}

/// Indirect irradiance (n . vector irradiance, RGB) at `points` for receiver coefficients `i`.
fn irradiance(ib: &IndexedBasis, i: &[f32], points: &[(Vec3, Vec3)]) -> Vec<f32> {
    let mut out = Vec::new();
    for (x, n) in points {
        let mut v = [0.0f32; 9];
        ib.reconstruct(i, 9, 0..ib.levels(), x.to_array(), n.to_array(), &mut v);
        for c in 0..3 {
            out.push(n.x * v[3 * c] + n.y * v[3 * c + 1] + n.z * v[3 * c + 2]);
        }
    }
    out
}

fn rms(a: &[f32], b: &[f32]) -> f64 {
    (a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.len() as f64)
        .sqrt()
}

#[test]
fn adaptive_s_matches_a_dense_brute_force_operator() {
    let spec = "builtin:box?albedo=0.6";
    let (levels, sender_levels, bounces) = (3u32, 2u32, 3u32);
    let out = bake_with(
        spec,
        BakeOptions {
            receiver_levels: Some(levels),
            coarse_count: Some(10),
            sender_levels: Some(sender_levels),
            epsilon: Some(1e-7),
            bounces: Some(bounces),
            gather_rays: Some(1024),
            bounces_on_all_receivers: true,
            ..Default::default()
        },
        2,
    );
    let bytes = mlt_format::file::encode(&out.contents, WriteOptions::default()).unwrap();
    let file = BakedFile::from_bytes(std::path::Path::new("box.mlt"), &bytes).unwrap();
    let ib = file.basis().unwrap();
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let senders = ib.basis.level_offsets[sender_levels as usize] as usize;
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let caster = scene.build_caster();

    // A point light off-centre in the box, with visibility: non-uniform direct light.
    let light = Vec3::new(0.2, 0.3, -0.1);
    let direct: Vec<f32> = (0..ib.basis.len())
        .flat_map(|j| {
            let x = Vec3::from(ib.basis.positions[j]);
            let n = Vec3::from(ib.basis.normals[j]);
            let d = light - x;
            let e = if caster.occluded(x, light) {
                0.0
            } else {
                (n.dot(d.normalize())).max(0.0) / d.length_squared()
            };
            [e, 0.5 * e, 0.25 * e]
        })
        .collect();
    let (e, _) = pull_push(&ib, &direct, 3);

    let apply_dense = |s: &Vec<Vec<Link>>| {
        let mut i = vec![0.0f32; ib.basis.len() * 9];
        for (r, row) in s.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                for c in 0..3 {
                    for a in 0..3 {
                        i[r * 9 + 3 * c + a] += v[3 * c + a] * e[3 * j + c];
                    }
                }
            }
        }
        i
    };
    let points = surface_samples(caster.as_ref(), Vec3::ZERO, 300);

    let mut i_adaptive = vec![0.0f32; ib.basis.len() * 9];
    links.apply(&e, 0.0, &mut i_adaptive);
    let adaptive = irradiance(&ib, &i_adaptive, &points);
    let dense = |seed| {
        let tp = dense_t_prime(
            &ib,
            caster.as_ref(),
            senders,
            sender_levels as usize,
            1024,
            seed,
        );
        irradiance(
            &ib,
            &apply_dense(&dense_s(&ib, &tp, senders, bounces)),
            &points,
        )
    };
    let (dense_a, dense_b) = (dense(11), dense(23));

    let scale =
        (dense_a.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / dense_a.len() as f64).sqrt();
    let noise = rms(&dense_a, &dense_b);
    let diff = 0.5 * (rms(&adaptive, &dense_a) + rms(&adaptive, &dense_b));
    eprintln!("RMS indirect irradiance {scale:.5}; dense vs dense {noise:.5}; adaptive vs dense {diff:.5}");
    assert!(
        scale > 0.0 && noise < 0.1 * scale,
        "the reference itself is too noisy"
    );
    // The adaptive result (Hammersley gathers, less noisy) should be no further from either
    // dense result than the two dense results are from each other, with margin.
    assert!(
        diff < 1.5 * noise + 1e-3 * scale,
        "adaptive S differs from the dense operator: {diff} vs noise {noise}"
    );
}
