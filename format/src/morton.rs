//! Morton (Z-order) codes: the spatially coherent order in which the bake stores each level's
//! points, so that neighbouring indices are neighbouring points. Products that walk points in
//! index order then find the coefficients they read already in cache (the viewer's flattening
//! operator relies on it).

/// 63-bit Morton code of `p` quantised over the box `lo..hi` (21 bits per axis); points
/// outside the box are clamped to it.
pub fn morton_code(p: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> u64 {
    let mut code = 0u64;
    for a in 0..3 {
        let extent = hi[a] - lo[a];
        let t = if extent > 0.0 {
            ((p[a] - lo[a]) / extent).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = (t * ((1u32 << 21) - 1) as f32) as u64;
        for bit in 0..21 {
            code |= ((q >> bit) & 1) << (3 * bit + a);
        }
    }
    code
}

/// The permutation that sorts `positions` by Morton code over their own bounding box, ties
/// by index: `order[i]` is the index of the `i`-th point in Morton order. A slice already in
/// that order gives the identity.
pub fn morton_order(positions: &[[f32; 3]]) -> Vec<u32> {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let mut keyed: Vec<(u64, u32)> = positions
        .iter()
        .enumerate()
        .map(|(j, &p)| (morton_code(p, lo, hi), j as u32))
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, j)| j).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_interleave_the_axes() {
        let (lo, hi) = ([0.0; 3], [1.0; 3]);
        assert_eq!(morton_code([0.0; 3], lo, hi), 0);
        // The top bit of each axis lands at bits 60, 61, 62.
        assert_eq!(morton_code([1.0, 0.0, 0.0], lo, hi), 0x1249_2492_4924_9249);
        assert_eq!(
            morton_code([0.0, 1.0, 0.0], lo, hi),
            0x1249_2492_4924_9249 << 1
        );
        assert_eq!(
            morton_code([0.0, 0.0, 1.0], lo, hi),
            0x1249_2492_4924_9249 << 2
        );
        // Outside the box clamps; a flat box does not divide by zero.
        assert_eq!(morton_code([-5.0, 0.0, 0.0], lo, hi), 0);
        assert_eq!(morton_code([3.0, 3.0, 3.0], [3.0; 3], [3.0; 3]), 0);
    }

    #[test]
    fn order_is_a_permutation_and_idempotent() {
        let mut s = 7u64;
        let positions: Vec<[f32; 3]> = (0..500)
            .map(|_| {
                let mut r = || {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                    (s >> 40) as f32 / (1u64 << 24) as f32
                };
                [r(), r(), 0.25 * r()]
            })
            .collect();
        let order = morton_order(&positions);
        let mut seen = vec![false; positions.len()];
        for &j in &order {
            assert!(!seen[j as usize]);
            seen[j as usize] = true;
        }
        let sorted: Vec<[f32; 3]> = order.iter().map(|&j| positions[j as usize]).collect();
        let again = morton_order(&sorted);
        assert!(again.iter().enumerate().all(|(i, &j)| i == j as usize));
        // Coherent: consecutive points are much closer than random pairs.
        let step = |p: &[[f32; 3]]| {
            p.windows(2)
                .map(|w| ((w[0][0] - w[1][0]).powi(2) + (w[0][1] - w[1][1]).powi(2)).sqrt())
                .sum::<f32>()
                / (p.len() - 1) as f32
        };
        assert!(
            step(&sorted) < 0.3 * step(&positions),
            "{} {}",
            step(&sorted),
            step(&positions)
        );
    }
}
