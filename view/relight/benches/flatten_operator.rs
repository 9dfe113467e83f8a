//! The flattening operator on a baked file, with `i = S e` to feed it: how large it is, how far
//! the default operator (small values dropped) lies from the exact one, and what a product
//! costs per kernel; `S e` alone and with the lagged fine bounces (the finer rows on `e + y`).
//!
//! `cargo bench -p mlt-relight --bench flatten_operator`. The file is `MLT_BENCH_FILE` (else a
//! small Cornell box baked into a temporary directory); `MLT_BENCH_ROUNDS` (default 9) rounds
//! for the medians printed first; `MLT_BENCH_DROP=d1,d2,...` adds operators with those drop
//! thresholds. Then divan times the products of the default operator and the sharpening step
//! after it.

mod common;

use std::sync::OnceLock;
use std::time::Instant;

use common::Baked;
use mlt_format::flat_basis::FlatBasis;
use mlt_format::links::LINK_DIM;
use mlt_relight::flatten_op::BLOCK_ROWS;
use mlt_relight::{
    FlattenOp, FlattenOptions, FlattenScratch, Kernel, ReceiverLinks, SharpenOp, SharpenScratch,
};

/// The file and what every benchmark reads from it.
struct Setup {
    baked: Baked,
    /// Only receivers with links are columns of the operator.
    keep: Vec<bool>,
    /// The flat basis on the points the solution needs.
    flat: FlatBasis,
    links: ReceiverLinks,
    /// Direct light at the senders, smooth in space.
    smooth: Vec<f32>,
    /// Direct light at the senders where neighbouring senders differ.
    rough: Vec<f32>,
    /// The default operator.
    op: FlattenOp,
    /// The sharpening step after it.
    sharpen: SharpenOp,
}

static SETUP: OnceLock<Setup> = OnceLock::new();

fn load() -> anyhow::Result<Setup> {
    let baked = Baked::open_or_bake("MLT_BENCH_FILE")?;
    let ib = &baked.ib;
    let mut keep = vec![false; ib.basis.len()];
    for r in baked.links.receiver_ids.iter() {
        keep[r.to_native() as usize] = true;
    }
    let links = ReceiverLinks::build(baked.links);
    let senders = baked.links.senders.to_native() as usize;
    let smooth: Vec<f32> = (0..senders * 3)
        .map(|k| {
            let p = ib.basis.positions[k / 3];
            1.0 + 0.8 * (0.4 * p[0] + (k % 3) as f32).sin() * (0.3 * p[2]).cos()
        })
        .collect();
    let rough: Vec<f32> = (0..senders * 3).map(|k| 1.0 + (k % 7) as f32).collect();
    let flat = FlatBasis::build(ib, Some(&keep))?;
    let op = FlattenOp::build(ib, &flat, Some(&keep))?;
    let t = Instant::now();
    let sharpen = SharpenOp::build(&flat)?;
    eprintln!(
        "sharpening: build {:.0} ms, {} entries ({:.1} per flat point), {:.1} MB",
        t.elapsed().as_secs_f64() * 1e3,
        sharpen.entries(),
        sharpen.entries() as f64 / flat.len().max(1) as f64,
        sharpen.bytes() as f64 / 1e6
    );
    Ok(Setup {
        baked,
        keep,
        flat,
        links,
        smooth,
        rough,
        op,
        sharpen,
    })
}

fn setup() -> &'static Setup {
    SETUP.get().expect("the set-up is loaded in main")
}

fn main() {
    eprintln!("machine: {}", common::machine());
    let s = match load() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    };
    eprintln!("file: {}", s.baked.path.display());
    let rounds: usize = std::env::var("MLT_BENCH_ROUNDS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(9);
    let mut variants = vec![
        ("exact", FlattenOptions::EXACT),
        ("default", FlattenOptions::default()),
    ];
    if let Ok(list) = std::env::var("MLT_BENCH_DROP") {
        for d in list.split(',').filter_map(|d| d.parse::<f64>().ok()) {
            variants.push(("drop", FlattenOptions { drop_below: d }));
        }
    }
    let mut exact_flat = Vec::new();
    for (name, options) in variants {
        if let Err(e) = figures(&s, name, options, rounds, &mut exact_flat) {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
    let s = SETUP.get_or_init(|| s);
    divan::main();
    s.baked.clean_up();
}

/// Prints the build figures of one operator, its distance from the exact one (the first
/// variant, whose results go to `exact_flat`) and the medians of `rounds` timed products.
fn figures(
    s: &Setup,
    name: &str,
    options: FlattenOptions,
    rounds: usize,
    exact_flat: &mut Vec<Vec<f32>>,
) -> anyhow::Result<()> {
    let ib = &s.baked.ib;
    let n = ib.basis.len();
    eprintln!("{name}: {options:?}");
    let t = Instant::now();
    let op = FlattenOp::build_with(ib, &s.flat, Some(&s.keep), options)?;
    let rows = s.flat.len();
    let parts = op.parts();
    let blocks = parts.block_offsets.len() - 1;
    eprintln!(
        "{name}: build {:.0} ms, {} columns ({:.0} per block of {BLOCK_ROWS} rows), {} entries \
         ({:.1} per point), {:.1} MB, stored in point order: {}",
        t.elapsed().as_secs_f64() * 1e3,
        op.columns(),
        parts.block_cols.len() as f64 / blocks as f64,
        op.entries(),
        op.entries() as f64 / rows as f64,
        op.bytes() as f64 / 1e6,
        op.in_point_order()
    );
    let mut i = vec![0.0f32; n * LINK_DIM];
    let mut flat = vec![0.0f32; rows * LINK_DIM];
    let mut scratch = FlattenScratch::default();
    for (pattern, e) in [("smooth", &s.smooth), ("rough", &s.rough)] {
        s.links.apply(e, 0.0, &mut i);
        op.apply(&i, LINK_DIM, &mut flat, &mut scratch);
        if name == "exact" {
            exact_flat.push(flat.clone());
            continue;
        }
        let reference = &exact_flat[if pattern == "smooth" { 0 } else { 1 }];
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (x, y) in flat.iter().zip(reference) {
            num += f64::from(x - y).powi(2);
            den += f64::from(*y).powi(2);
        }
        eprintln!(
            "  {pattern} direct light: relative rms difference from exact {:.2e}",
            (num / den).sqrt()
        );
    }
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    let mut times = Vec::new();
    for round in 0..rounds {
        let t = Instant::now();
        let e = if round % 2 == 0 { &s.smooth } else { &s.rough };
        s.links.apply(e, 0.0, &mut i);
        let t1 = Instant::now();
        op.apply(&i, LINK_DIM, &mut flat, &mut scratch);
        let t2 = Instant::now();
        op.apply_with(Kernel::Portable, &i, LINK_DIM, &mut flat, &mut scratch);
        let t3 = Instant::now();
        #[cfg(target_arch = "x86_64")]
        if Kernel::Avx2Fma.supported() {
            op.apply_with(Kernel::Avx2Fma, &i, LINK_DIM, &mut flat, &mut scratch);
        }
        let t4 = Instant::now();
        times.push((ms(t, t1), ms(t1, t2), ms(t2, t3), ms(t3, t4)));
    }
    let t = Instant::now();
    let mut table = Vec::new();
    let mut sum = 0.0f32;
    for b in 0..blocks {
        op.gather_table(&i, LINK_DIM, b, &mut table);
        sum += table.first().copied().unwrap_or(0.0);
    }
    eprintln!(
        "  gathering the tables alone, one thread: {:.2} ms ({sum})",
        t.elapsed().as_secs_f64() * 1e3
    );
    if rounds == 0 {
        return Ok(());
    }
    let median = |f: fn(&(f64, f64, f64, f64)) -> f64| {
        let mut v: Vec<f64> = times.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    eprintln!(
        "  medians of {rounds}: S e {:.2} ms, flatten {:.2} ms ({:?}); portable kernel {:.2} ms, \
         AVX2 kernel {:.2} ms",
        median(|t| t.0),
        median(|t| t.1),
        Kernel::detect(),
        median(|t| t.2),
        median(|t| t.3)
    );
    Ok(())
}

/// `i = S e`, receiver-major (the input of the flattening).
#[divan::bench]
fn receiver_links(bencher: divan::Bencher) {
    let s = setup();
    let mut i = vec![0.0f32; s.baked.ib.basis.len() * LINK_DIM];
    bencher.bench_local(|| s.links.apply(divan::black_box(&s.smooth), 0.0, &mut i));
}

/// The level-0 rows of `S e` alone (the nearly dense coarsest receivers, summed eight rows at
/// a time): what they cost of the whole product.
#[divan::bench]
fn receiver_links_level0(bencher: divan::Bencher) {
    let s = setup();
    let m = s.baked.ib.basis.level_range(0).len();
    let mut i = vec![0.0f32; m * LINK_DIM];
    bencher.bench_local(|| {
        s.links
            .apply_first(divan::black_box(&s.smooth), 0.0, m, &mut i)
    });
}

/// `S e` with the finer rows on `e + y` in the same pass (the window's lagged fine bounces
/// on a file with traced level-0 rows: `y` reaches the receivers past level 0).
#[divan::bench]
fn receiver_links_lagged(bencher: divan::Bencher) {
    let s = setup();
    let n = s.baked.ib.basis.len() * LINK_DIM;
    let m = s.baked.ib.basis.level_range(0).len();
    let sum: Vec<f32> = s.smooth.iter().zip(&s.rough).map(|(a, b)| a + b).collect();
    let mut i = vec![0.0f32; n];
    bencher.bench_local(|| {
        s.links
            .apply_split(divan::black_box(&sum), &s.smooth, m, 0.0, &mut i)
    });
}

/// One product of the default operator with `kernel`.
fn flatten_with(bencher: divan::Bencher, kernel: Kernel) {
    let s = setup();
    let mut i = vec![0.0f32; s.baked.ib.basis.len() * LINK_DIM];
    s.links.apply(&s.smooth, 0.0, &mut i);
    let mut flat = vec![0.0f32; s.flat.len() * LINK_DIM];
    let mut scratch = FlattenScratch::default();
    bencher.bench_local(|| {
        s.op.apply_with(
            kernel,
            divan::black_box(&i),
            LINK_DIM,
            &mut flat,
            &mut scratch,
        )
    });
}

/// The flattening with the portable kernel.
#[divan::bench]
fn flatten_portable(bencher: divan::Bencher) {
    flatten_with(bencher, Kernel::Portable);
}

/// The flattening with the AVX2 and FMA kernel, where the CPU has it.
#[cfg(target_arch = "x86_64")]
#[divan::bench]
fn flatten_avx2_fma(bencher: divan::Bencher) {
    if Kernel::Avx2Fma.supported() {
        flatten_with(bencher, Kernel::Avx2Fma);
    }
}

/// The default sharpening steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` on the default operator's
/// flat coefficients.
#[divan::bench]
fn sharpen(bencher: divan::Bencher) {
    let s = setup();
    let mut i = vec![0.0f32; s.baked.ib.basis.len() * LINK_DIM];
    s.links.apply(&s.smooth, 0.0, &mut i);
    let mut flat = vec![0.0f32; s.flat.len() * LINK_DIM];
    s.op.apply(&i, LINK_DIM, &mut flat, &mut FlattenScratch::default());
    let flat = flat;
    let mut scratch = SharpenScratch::default();
    // Each run from the same coefficients (repeated steps would grow without bound).
    bencher
        .with_inputs(|| flat.clone())
        .bench_local_refs(|c| s.sharpen.apply(c, LINK_DIM, &mut scratch));
}
