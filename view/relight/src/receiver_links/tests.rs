//! Tests of the receiver-major product: its bits against the sender-major product over the
//! rounded weights, the weights' rounding, both slot widths, the F16C and group kernels against
//! the scalar rows, the partial, split, added and filtered products, and the parallel tasks.

use half::f16;
use mlt_format::links::{ArchivedLinks, Links, SenderLinks, LINK_DIM};
use rkyv::rancor;

use super::groups::GROUP;
use super::kernels::{group_sums, row_sum};
#[cfg(target_arch = "x86_64")]
use super::kernels::{group_sums_f16c, has_f16c_lanes, row_sum_f16c};
use super::slots::Slots;
use super::tasks::{CHUNK_LINKS, RECEIVER_CHUNK};
use super::weights::{half_scale, rounded, Weights};
use super::ReceiverLinks;

/// Six senders, twelve linked receivers of 14, mixed signs.
fn sample_links() -> Links {
    let cols: Vec<Vec<(u32, [f32; 9])>> = (0..6u32)
        .map(|s| {
            (0..12u32)
                .filter(|r| (r + s) % 3 != 0)
                .map(|r| {
                    let v = std::array::from_fn(|d| {
                        ((s * 31 + r * 7 + d as u32) as f32 * 0.37).sin() * (1.0 + s as f32)
                    });
                    (r, v)
                })
                .collect()
        })
        .collect();
    let (l, _) = Links::pack(
        14,
        6,
        cols.iter().enumerate().map(|(s, c)| SenderLinks {
            sender: s as u32,
            links: c,
        }),
    );
    l
}

/// [`sample_links`] archived.
fn sample_bytes() -> rkyv::util::AlignedVec {
    rkyv::to_bytes::<rancor::Error>(&sample_links()).unwrap()
}

/// The links of `bytes`, validated.
fn validated(bytes: &[u8]) -> &ArchivedLinks {
    let a = rkyv::access::<ArchivedLinks, rancor::Error>(bytes).unwrap();
    a.validate().unwrap();
    a
}

/// RGB light for the six senders of [`sample_links`].
fn sample_emission() -> Vec<f32> {
    (0..18).map(|k| 0.3 + (k as f32 * 1.3).cos()).collect()
}

/// The links of `a` as built (the sample's rows too sparse to group), and with every full
/// group of rows grouped: the products must give the same bits from both.
fn presets(a: &ArchivedLinks) -> [ReceiverLinks; 2] {
    let grouped = ReceiverLinks::build_filled(a, |_, _| true, 0.0);
    assert_eq!(
        grouped.groups.rows,
        GROUP * (grouped.receiver_ids.len() / GROUP)
    );
    [ReceiverLinks::build(a), grouped]
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// `i += S e` sender-major, as [`ArchivedLinks::apply`] (each receiver's terms added in
/// ascending sender order, senders at most `threshold` in every channel skipped), over the
/// sender weights `e_s * scale_s` rounded as [`Weights`] rounds them; with `abs`, the sum
/// of the terms' magnitudes instead. Returns the number of senders used.
fn sender_major(a: &ArchivedLinks, e: &[f32], threshold: f32, abs: bool, i: &mut [f32]) -> usize {
    let slots = a.sender_ids.len();
    let mut used = 0;
    let w: Vec<[f32; 3]> = (0..slots)
        .map(|slot| {
            let s = a.sender_ids[slot].to_native() as usize;
            let es = [e[3 * s], e[3 * s + 1], e[3 * s + 2]];
            if es.iter().all(|x| x.abs() <= threshold) {
                [0.0; 3]
            } else {
                used += 1;
                es.map(|x| x * a.scales[slot].to_native())
            }
        })
        .collect();
    let scale = half_scale(w.as_flattened());
    for (slot, w) in w.iter().enumerate() {
        let w = w.map(|x| rounded(x, scale));
        for k in a.offsets[slot].to_native() as usize..a.offsets[slot + 1].to_native() as usize {
            let r = a.receiver_ids[k].to_native() as usize;
            for d in 0..LINK_DIM {
                let v = f16::from_bits(a.values[k * LINK_DIM + d].to_native()).to_f32();
                let term = w[d / 3] * v;
                i[r * LINK_DIM + d] += if abs { term.abs() } else { term };
            }
        }
    }
    used
}

/// [`sender_major`] over the rounded weights, into a zeroed vector.
fn rounded_apply(a: &ArchivedLinks, e: &[f32], threshold: f32, i: &mut [f32]) -> usize {
    sender_major(a, e, threshold, false, i)
}

#[test]
fn receiver_major_gives_the_bits_of_the_sender_major_product_over_the_rounded_weights() {
    let bytes = sample_bytes();
    let a = validated(&bytes);
    let e = sample_emission();
    let mut e_dark = e.clone();
    e_dark[6..9].copy_from_slice(&[1e-3, -1e-3, 0.0]);
    let [plain, grouped] = presets(a);
    assert_eq!((plain.groups.rows, grouped.groups.rows), (0, 8));
    assert_eq!(plain.link_count(), grouped.link_count());
    for (rl, (e, threshold, senders)) in [&plain, &grouped]
        .into_iter()
        .flat_map(|rl| [(rl, (&e, 0.0, 6)), (rl, (&e_dark, 0.01, 5))])
    {
        assert_eq!(rl.receiver_ids(), (0..12).collect::<Vec<u32>>().as_slice());
        let mut want = vec![0.0f32; 14 * 9];
        assert_eq!(rounded_apply(a, e, threshold, &mut want), senders);
        let mut got = vec![f32::NAN; 14 * 9];
        assert_eq!(rl.apply(e, threshold, &mut got), senders);
        assert_eq!(bits(&got), bits(&want));
        assert!(got[12 * 9..].iter().all(|&x| x == 0.0));
        // Within the weights' rounding of the exact product: each term moves by at most
        // 2^-11 of itself.
        let mut exact = vec![0.0f32; 14 * 9];
        assert_eq!(a.apply(e, threshold, &mut exact), senders);
        let mut magnitude = vec![0.0f32; 14 * 9];
        sender_major(a, e, threshold, true, &mut magnitude);
        for k in 0..14 * 9 {
            let bound = magnitude[k] * (2f32.powi(-11) + 1e-5) + 1e-30;
            assert!(
                (got[k] - exact[k]).abs() <= bound,
                "{k}: {} {}",
                got[k],
                exact[k]
            );
        }
        assert!(got != exact, "the weights are rounded");
    }
}

#[test]
fn weights_are_rounded_to_eleven_bits_whatever_their_scale() {
    // The largest finite weight lands in [2^14, 2^15) (infinities and NaNs aside).
    for largest in [1e-30f32, 3.0e-5, 1.0, 1.5, 2.0, 65504.0, 1e20, 3e38] {
        let s = half_scale(&[largest, -0.5 * largest, f32::INFINITY, f32::NAN]);
        assert_eq!(s.to_bits() & 0x007f_ffff, 0, "a power of two: {s}");
        let q = largest / s;
        assert!((16384.0..32768.0).contains(&q), "{largest}: {q}");
    }
    assert_eq!(half_scale(&[0.0, -0.0]), 1.0);
    assert_eq!(half_scale(&[]), 1.0);
    // Each weight moves by at most 2^-11 of itself down to 2^-24 of the largest, and the
    // same whatever the largest (the rounding does not depend on the scale).
    let w: Vec<f32> = (0..2000)
        .map(|k| (k as f32 * 0.77).sin() * 10f32.powf(-(k % 8) as f32))
        .collect();
    let (s1, s2) = (half_scale(&w), half_scale(&[w[0], 4.0]));
    for &x in w.iter().filter(|x| x.abs() >= 4.0 * 2f32.powi(-24)) {
        let r = rounded(x, s1);
        assert!((r - x).abs() <= x.abs() * 2f32.powi(-11), "{x} -> {r}");
        assert_eq!(r.to_bits(), rounded(x, s2).to_bits(), "{x}");
    }
    // `Weights` holds those, its half floats and their values agreeing, with three zeros
    // after the last sender; the vector conversion rounds as the scalar one (ties among
    // these: multiples of 2^-11 and odd multiples of 2^-12 near 1).
    let mut w3: Vec<[f32; 3]> = w.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    w3.push([
        1.0 + 2f32.powi(-11),
        1.0 + 3.0 * 2f32.powi(-11),
        -(1.0 + 2f32.powi(-11)),
    ]);
    let weights = Weights::new(&w3);
    assert_eq!(weights.scale, half_scale(w3.as_flattened()));
    assert_eq!(weights.half.len(), 3 * w3.len() + 3);
    assert!(weights.half[3 * w3.len()..].iter().all(|&h| h == 0));
    for (s, w) in w3.iter().enumerate() {
        for (c, &x) in w.iter().enumerate() {
            let h = weights.half[3 * s + c];
            assert_eq!(f16::from_bits(h).to_f32(), weights.get(s)[c]);
            assert_eq!(
                h,
                f16::from_f32(x / weights.scale).to_bits(),
                "sender {s} channel {c}"
            );
            assert_eq!(
                (weights.get(s)[c] * weights.scale).to_bits(),
                rounded(x, weights.scale).to_bits()
            );
        }
    }
}

#[test]
fn slots_take_16_bits_where_all_fit_and_the_products_keep_their_bits_either_way() {
    assert_eq!(
        Slots::new(vec![0, 7, 65535]),
        Slots::Narrow(vec![0, 7, 65535])
    );
    assert_eq!(Slots::new(vec![0, 65536]), Slots::Wide(vec![0, 65536]));
    let bytes = sample_bytes();
    let rl = ReceiverLinks::build(validated(&bytes));
    let Slots::Narrow(narrow) = &rl.slots else {
        panic!("six senders take 16-bit slots");
    };
    let wide = ReceiverLinks {
        slots: Slots::Wide(narrow.iter().map(|&s| s as u32).collect()),
        ..rl.clone()
    };
    assert_eq!(wide.bytes(), rl.bytes() + 2 * rl.link_count());
    let e = sample_emission();
    for links in [&rl, &wide] {
        let mut want = vec![0.0f32; 14 * 9];
        rounded_apply(validated(&bytes), &e, 0.0, &mut want);
        let mut got = vec![f32::NAN; 14 * 9];
        links.apply(&e, 0.0, &mut got);
        assert_eq!(bits(&got), bits(&want));
    }
}

#[test]
fn the_f16c_row_sums_give_the_bits_of_the_scalar_ones() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("f16c") {
        // Every half float but the NaNs (whose payloads the two conversions may treat
        // differently; validated links hold none), nine to a link, in each of the nine
        // places, three links to a row over seven senders' weights.
        let all: Vec<u16> = (0..=u16::MAX)
            .filter(|&h| !f16::from_bits(h).is_nan())
            .collect();
        let weights = |phase: f32| -> Weights {
            let w: Vec<[f32; 3]> = (0..7)
                .map(|s| std::array::from_fn(|k| ((s * 3 + k) as f32 * 0.37 + phase).sin() * 3.0))
                .collect();
            Weights::new(&w)
        };
        let w = weights(0.0);
        // Overflowing sums may give NaNs, whose payloads depend on operand order.
        let same = |a: [f32; LINK_DIM], b: [f32; LINK_DIM]| {
            a.iter()
                .zip(&b)
                .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
        };
        for shift in 0..LINK_DIM {
            let values: Vec<[u16; LINK_DIM]> = all[shift..]
                .chunks_exact(LINK_DIM)
                .map(|c| std::array::from_fn(|d| c[d]))
                .collect();
            let slots: Vec<u16> = (0..values.len()).map(|k| (k * 5 % 7) as u16).collect();
            for k in (0..values.len() - 3).step_by(3) {
                let (sl, vl) = (&slots[k..k + 3], &values[k..k + 3]);
                // SAFETY: this CPU has AVX2 and F16C (checked above).
                let fast = unsafe { row_sum_f16c(sl, vl, &w) };
                assert!(same(fast, row_sum::<false, _>(sl, vl, &w)), "{fast:?}");
            }
        }
    }
}

#[test]
fn a_group_gives_each_row_the_bits_of_its_own_links_summed_alone() {
    // Every finite half float (the infinite ones times a missing link's zero would give
    // NaNs; validated links hold none) spread over groups of 40 senders, about a third of
    // each row's links missing (zeros in the group), ±0 values among the present ones.
    let all: Vec<u16> = (0..=u16::MAX)
        .filter(|&h| f16::from_bits(h).is_finite())
        .collect();
    let w: Vec<[f32; 3]> = (0..40)
        .map(|s| std::array::from_fn(|k| ((s * 3 + k) as f32 * 0.61).cos() * 2.5))
        .collect();
    let w = Weights::new(&w);
    let present = |u: usize, j: usize| (u * 7 + j * 3) % 10 < 7;
    let slots: Vec<u16> = (0..40u16).collect();
    for chunk in all.chunks_exact(40 * GROUP * LINK_DIM) {
        let values: Vec<[u16; GROUP * LINK_DIM]> = chunk
            .chunks_exact(GROUP * LINK_DIM)
            .enumerate()
            .map(|(u, c)| std::array::from_fn(|k| if present(u, k % GROUP) { c[k] } else { 0 }))
            .collect();
        let slow = group_sums::<false, u16>(&slots, &values, &w);
        #[cfg(target_arch = "x86_64")]
        if has_f16c_lanes() {
            // SAFETY: this CPU has AVX2 and F16C (checked).
            let fast = unsafe { group_sums_f16c(&slots, &values, &w) };
            assert_eq!(
                fast.map(|r| r.map(f32::to_bits)),
                slow.map(|r| r.map(f32::to_bits))
            );
        }
        for (j, got) in slow.iter().enumerate() {
            let (row_slots, row_values): (Vec<u16>, Vec<[u16; LINK_DIM]>) = (0..40)
                .filter(|&u| present(u, j))
                .map(|u| (u as u16, std::array::from_fn(|d| values[u][d * GROUP + j])))
                .unzip();
            let want = row_sum::<false, u16>(&row_slots, &row_values, &w);
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "row {j}");
        }
    }
}

#[test]
fn the_first_rows_alone_give_the_bits_of_the_full_product() {
    let bytes = sample_bytes();
    let a = validated(&bytes);
    let e = sample_emission();
    let mut full = vec![0.0f32; 14 * 9];
    ReceiverLinks::build(a).apply(&e, 0.0, &mut full);
    for (rl, m) in presets(a)
        .iter()
        .flat_map(|rl| [0, 1, 5, 12, 14].map(|m| (rl, m)))
    {
        let mut first = vec![f32::NAN; m * 9];
        assert_eq!(rl.apply_first(&e, 0.0, m, &mut first), 6);
        assert_eq!(bits(&first), bits(&full[..m * 9]), "first {m}");
    }
}

#[test]
fn the_rows_from_m_on_are_added_with_the_bits_of_the_added_product_and_the_rest_untouched() {
    let bytes = sample_bytes();
    let a = validated(&bytes);
    let e = sample_emission();
    let start: Vec<f32> = (0..14 * 9).map(|k| (k as f32 * 0.37).cos()).collect();
    let mut all = start.clone();
    ReceiverLinks::build(a).apply_add(&e, 0.0, &mut all);
    for (rl, m) in presets(a)
        .iter()
        .flat_map(|rl| [0, 1, 5, 12, 14].map(|m| (rl, m)))
    {
        let mut got = start.clone();
        rl.apply_add_from(&e, 0.0, m, &mut got);
        assert_eq!(bits(&got[..m * 9]), bits(&start[..m * 9]), "below {m}");
        assert_eq!(bits(&got[m * 9..]), bits(&all[m * 9..]), "from {m}");
    }
}

#[test]
fn tasks_split_the_heavy_rows_and_leave_every_row_its_bits() {
    // 3,000 senders reach the first 24 of 5,000 receivers (3,000 links each, as level 0's
    // rows do) and a few of the rest each (light rows); 76 receivers have no link.
    let (n, senders) = (5_000u32, 3_000u32);
    let cols: Vec<Vec<(u32, [f32; 9])>> = (0..senders)
        .map(|s| {
            (0..n)
                .filter(|&r| r < 24 || (r >= 100 && (r * 7 + s) % 97 == 0))
                .map(|r| {
                    let v =
                        std::array::from_fn(|d| ((s * 13 + r * 5 + d as u32) as f32 * 0.11).sin());
                    (r, v)
                })
                .collect()
        })
        .collect();
    let (links, _) = Links::pack(
        n,
        senders,
        cols.iter().enumerate().map(|(s, c)| SenderLinks {
            sender: s as u32,
            links: c,
        }),
    );
    let bytes = rkyv::to_bytes::<rancor::Error>(&links).unwrap();
    let a = validated(&bytes);
    let e: Vec<f32> = (0..senders as usize * 3)
        .map(|k| 0.5 + (k as f32 * 0.37).cos())
        .collect();
    let mut want = vec![0.0f32; n as usize * 9];
    rounded_apply(a, &e, 0.0, &mut want);
    // Row by row, and with the dense heavy rows grouped (as built): three groups.
    let plain = ReceiverLinks::build_filled(a, |_, _| true, f64::INFINITY);
    for (rl, grouped, heavy_tasks) in [(plain, 0, 3), (ReceiverLinks::build(a), 24, 2)] {
        assert_eq!(rl.groups.rows, grouped);
        let rows = rl.receiver_ids.len();
        assert!(rows > 2 * RECEIVER_CHUNK, "{rows}");
        // The tasks cover the rows in order; each holds at most RECEIVER_CHUNK rows, and
        // fewer than CHUNK_LINKS links before its last row (its last group's first row
        // among the grouped rows, where tasks start only at a group's first row).
        let starts = &rl.task_starts;
        assert_eq!((starts[0], *starts.last().unwrap()), (0, rows as u32));
        assert!(starts.windows(2).all(|w| w[0] < w[1]));
        for w in starts.windows(2) {
            let (q0, q1) = (w[0] as usize, w[1] as usize);
            assert!(q0 >= grouped || q0 % GROUP == 0, "{q0}");
            let last = if q1 <= grouped { q1 - GROUP } else { q1 - 1 };
            assert!(q1 - q0 <= RECEIVER_CHUNK);
            assert!(((rl.offsets[last] - rl.offsets[q0]) as usize) < CHUNK_LINKS);
        }
        // The heavy rows (72,000 links) are spread over three tasks (eleven rows each),
        // or two when grouped (16 and 8 rows)...
        assert_eq!(rl.tasks(24), heavy_tasks);
        assert_eq!(rl.tasks(0), 0);
        assert_eq!(rl.tasks(rows), starts.len() - 1);
        // ...and every product gives the sender-major product's bits, for any thread count.
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let got = pool.install(|| {
                let mut got = vec![f32::NAN; n as usize * 9];
                rl.apply(&e, 0.0, &mut got);
                got
            });
            assert_eq!(bits(&got), bits(&want), "{threads} threads");
        }
        // A split product over the same tasks: the rows below `m` (20: inside the last
        // group) on `e`, the others on `2 e`, which doubles their sums exactly.
        let e2: Vec<f32> = e.iter().map(|v| 2.0 * v).collect();
        for m in [20, 50] {
            let mut got = vec![f32::NAN; want.len()];
            rl.apply_split(&e2, &e, m, 0.0, &mut got);
            let mut expect = want.clone();
            expect[m * 9..].iter_mut().for_each(|v| *v *= 2.0);
            assert_eq!(bits(&got), bits(&expect), "m {m}");
        }
    }
}

#[test]
fn a_split_product_gives_each_row_the_bits_of_the_product_of_its_vector() {
    let bytes = sample_bytes();
    let a = validated(&bytes);
    let rl = ReceiverLinks::build(a);
    let e = sample_emission();
    let mut e_first: Vec<f32> = (0..18).map(|k| -0.2 + (k as f32 * 0.7).sin()).collect();
    // A sender dark in `e_first` only: skipped there, used for the other rows.
    e_first[3..6].copy_from_slice(&[1e-3, 0.0, -1e-3]);
    let (mut plain, mut other) = (vec![0.0f32; 14 * 9], vec![0.0f32; 14 * 9]);
    rl.apply(&e, 0.01, &mut plain);
    rl.apply(&e_first, 0.01, &mut other);
    for (links, m) in presets(a)
        .iter()
        .flat_map(|rl| [0, 1, 5, 8, 12, 14].map(|m| (rl, m)))
    {
        let mut got = vec![f32::NAN; 14 * 9];
        assert_eq!(links.apply_split(&e, &e_first, m, 0.01, &mut got), 6);
        assert_eq!(bits(&got[..m * 9]), bits(&other[..m * 9]), "first {m}");
        assert_eq!(bits(&got[m * 9..]), bits(&plain[m * 9..]), "rest {m}");
    }
}

#[test]
fn a_filtered_product_added_gives_the_bits_of_the_full_product_of_the_kept_links() {
    // Keep senders 0-2 and receivers from 4 on: the added product must equal the full
    // product of the same links (senders 3-5 dark, receivers below 4 not written) formed
    // on its own and then added, bit for bit.
    let bytes = sample_bytes();
    let a = validated(&bytes);
    let keep = |s: u32, r: u32| s < 3 && r >= 4;
    for rl in [
        ReceiverLinks::build_where(a, keep),
        ReceiverLinks::build_filled(a, keep, 0.0),
    ] {
        assert!(rl.receiver_ids().iter().all(|&r| r >= 4));
        assert_eq!(
            rl.link_count(),
            (0..3u32)
                .map(|s| (4..12u32).filter(|r| (r + s) % 3 != 0).count())
                .sum::<usize>()
        );
        let e = sample_emission();
        let mut dark = e.clone();
        dark[9..].fill(0.0);
        let mut product = vec![0.0f32; 14 * 9];
        rounded_apply(a, &dark, 0.0, &mut product);
        let start: Vec<f32> = (0..14 * 9).map(|k| (k as f32 * 0.71).sin()).collect();
        let mut want = start.clone();
        for (k, w) in want.iter_mut().enumerate().skip(4 * 9) {
            *w += product[k];
        }
        let mut got = start.clone();
        // Only the kept senders' entries are read.
        assert_eq!(rl.apply_add(&e[..9], 0.0, &mut got), 3);
        assert_eq!(bits(&got), bits(&want));
    }
}
