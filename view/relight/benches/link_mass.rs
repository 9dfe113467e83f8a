//! How the links' weight is spread within each receiver's row of `S`, per receiver level: the
//! share of a level's links that could be dropped while dropping at most a given fraction of
//! each row's weight (smallest links first). A link's weight here is its sender's scale times
//! the sum of its nine values' magnitudes, i.e. its share of the row under a uniform emission.
//! It sizes what pruning rows would save per frame (`S e` costs about the same per link).
//!
//! `MLT_BENCH_FILE=F cargo bench -p mlt-relight --bench link_mass` (else a small Cornell box
//! baked into a temporary directory).

mod common;

use common::Baked;
use half::f16;
use mlt_format::links::LINK_DIM;

/// Fractions of each row's weight that may be dropped.
const FRACTIONS: [f64; 5] = [0.001, 0.003, 0.01, 0.02, 0.05];

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> anyhow::Result<()> {
    let baked = Baked::open_or_bake("MLT_BENCH_FILE")?;
    println!("file: {}", baked.path.display());
    let links = baked.links;
    let ib = &baked.ib;
    let mut rows: Vec<Vec<f32>> = vec![Vec::new(); links.receivers.to_native() as usize];
    for slot in 0..links.sender_ids.len() {
        let scale = links.scales[slot].to_native();
        let (a, b) = (
            links.offsets[slot].to_native() as usize,
            links.offsets[slot + 1].to_native() as usize,
        );
        for k in a..b {
            let v = &links.values[k * LINK_DIM..(k + 1) * LINK_DIM];
            let sum: f32 = v
                .iter()
                .map(|x| f16::from_bits(x.to_native()).to_f32().abs())
                .sum();
            rows[links.receiver_ids[k].to_native() as usize].push(sum * scale);
        }
    }
    println!("droppable links per receiver level, at {FRACTIONS:?} of each row's weight:");
    for l in 0..ib.levels() {
        let (mut total, mut droppable) = (0usize, [0usize; FRACTIONS.len()]);
        for row in &mut rows[ib.basis.level_range(l)] {
            row.sort_by(f32::total_cmp);
            let sum: f64 = row.iter().map(|&x| f64::from(x)).sum();
            total += row.len();
            for (count, f) in droppable.iter_mut().zip(FRACTIONS) {
                let mut acc = 0.0f64;
                *count += row
                    .iter()
                    .take_while(|&&x| {
                        acc += f64::from(x);
                        acc <= f * sum
                    })
                    .count();
            }
        }
        let shares: Vec<String> = droppable
            .iter()
            .map(|&d| format!("{:.1} %", 100.0 * d as f64 / total.max(1) as f64))
            .collect();
        println!(
            "  level {l}: {total} links ({:.1} a row), droppable {}",
            total as f64 / ib.basis.level_range(l).len().max(1) as f64,
            shares.join(" / ")
        );
    }
    baked.clean_up();
    Ok(())
}
