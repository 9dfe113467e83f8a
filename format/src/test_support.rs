//! Small bases for tests, here and in the crates that build on this one (enabled for them by
//! the `test-support` feature).

use crate::basis::Basis;
use crate::kernel::support_factor;
use crate::shepard::IndexedBasis;

/// Points on a jittered grid on the unit square (z = 0, normal +z) on `levels` levels,
/// each level twice as dense, radii `C R` as the paper.
pub fn plane_basis(levels: usize, coarse_n: usize) -> IndexedBasis {
    let mut b = Basis::default();
    b.level_offsets.push(0);
    let mut s = 12345u64;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 40) as f32) / (1u64 << 24) as f32 - 0.5
    };
    for l in 0..levels {
        let n = coarse_n << l;
        let spacing = 1.0 / n as f32;
        let c = support_factor(l, levels, 1.5, 2.5);
        for iy in 0..=n {
            for ix in 0..=n {
                let x = (ix as f32 + 0.3 * rnd()) * spacing;
                let y = (iy as f32 + 0.3 * rnd()) * spacing;
                b.positions.push([x, y, 0.0]);
                b.normals.push([0.0, 0.0, 1.0]);
                b.radii.push(c * spacing);
            }
        }
        b.level_offsets.push(b.positions.len() as u32);
        b.disk_radii.push(spacing);
    }
    IndexedBasis::build(b).unwrap()
}
