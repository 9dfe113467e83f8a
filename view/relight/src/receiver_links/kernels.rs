//! The products' kernels: one row's sum over its links ([`row_sum`]) and one group's eight
//! rows' sums ([`group_sums`]), each scalar or with AVX2 and F16C (the same bits), the vector
//! loads and unpacking they share, and the check for those CPU features.

use half::f16;
use mlt_format::links::LINK_DIM;

use super::groups::GROUP;
use super::slots::Slot;
use super::weights::Weights;

/// One row's sum `sum_k w[slot_k] * value_k`, element by element in link order, each term a
/// product then a sum in `f32` (no fused multiply-add). With `F16C` (set only in code compiled
/// for and run on CPUs with AVX2 and F16C) by [`row_sum_f16c`], else by the scalar loop: the
/// same bits (the half floats' conversion is exact, and a vector lane's product and sum are
/// the scalar's).
#[inline(always)]
pub(super) fn row_sum<const F16C: bool, S: Slot>(
    slots: &[S],
    values: &[[u16; LINK_DIM]],
    w: &Weights,
) -> [f32; LINK_DIM] {
    #[cfg(target_arch = "x86_64")]
    if F16C {
        // SAFETY: `F16C` is set only by `chunk_f16c`, which runs only on CPUs with AVX2 and
        // F16C (checked by its callers).
        return unsafe { row_sum_f16c(slots, values, w) };
    }
    let mut acc = [0.0f32; LINK_DIM];
    for (&slot, v) in slots.iter().zip(values) {
        let (ws, v) = (w.get(slot.index()), decode(v));
        for d in 0..LINK_DIM {
            acc[d] += ws[d / 3] * v[d];
        }
    }
    acc
}

/// The sums of a group's eight rows ([`Groups`](super::groups::Groups)) over the weights `w`: per group sender (its
/// slot and its rows' values, element `d` of row `j` at `d * GROUP + j`), each row's element
/// gets one product then one sum in `f32`, in ascending sender order, as in [`row_sum`]. With
/// `F16C` (as in `row_sum`) by [`group_sums_f16c`]: the same bits.
#[inline(always)]
pub(super) fn group_sums<const F16C: bool, S: Slot>(
    slots: &[S],
    values: &[[u16; GROUP * LINK_DIM]],
    w: &Weights,
) -> [[f32; LINK_DIM]; GROUP] {
    #[cfg(target_arch = "x86_64")]
    if F16C {
        // SAFETY: as in `row_sum`.
        return unsafe { group_sums_f16c(slots, values, w) };
    }
    let mut acc = [[0.0f32; LINK_DIM]; GROUP];
    for (&slot, v) in slots.iter().zip(values) {
        let ws = w.get(slot.index());
        for d in 0..LINK_DIM {
            for j in 0..GROUP {
                acc[j][d] += ws[d / 3] * f16::from_bits(v[d * GROUP + j]).to_f32();
            }
        }
    }
    acc
}

/// [`group_sums`] with AVX2 and F16C: element `d` of the eight rows converted, multiplied by
/// the sender's weight `d` and added at once (separate products and sums, as the scalar loop).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
#[inline]
pub(super) fn group_sums_f16c<S: Slot>(
    slots: &[S],
    values: &[[u16; GROUP * LINK_DIM]],
    w: &Weights,
) -> [[f32; LINK_DIM]; GROUP] {
    use std::arch::x86_64::*;
    let mut acc = [_mm256_setzero_ps(); LINK_DIM];
    for (&slot, v) in slots.iter().zip(values) {
        let ws = w.get(slot.index());
        for (d, acc) in acc.iter_mut().enumerate() {
            // SAFETY: `v` holds 72 `u16`: the 16 bytes from element `8 d` (d < 9) are in
            // bounds (an unaligned load).
            let vd = unsafe { _mm_loadu_si128(v.as_ptr().add(d * GROUP).cast::<__m128i>()) };
            let prod = _mm256_mul_ps(_mm256_set1_ps(ws[d / 3]), _mm256_cvtph_ps(vd));
            *acc = _mm256_add_ps(*acc, prod);
        }
    }
    let mut by_element = [[0.0f32; GROUP]; LINK_DIM];
    for d in 0..LINK_DIM {
        // SAFETY: `by_element[d]` holds 8 `f32`, the 32 bytes stored (an unaligned store).
        unsafe { _mm256_storeu_ps(by_element[d].as_mut_ptr(), acc[d]) };
    }
    std::array::from_fn(|j| std::array::from_fn(|d| by_element[d][j]))
}

/// One link's values and sender `s`'s weights as vectors: elements 0-7 and elements 5-8 of
/// each (one instruction per load or conversion; [`unpack`] takes elements 5-8 from the
/// second). The weights are the sender's three channel weights spread to the elements they
/// multiply (`d / 3`) by one permute each.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
#[inline]
fn lanes(
    v: &[u16; LINK_DIM],
    w: &Weights,
    s: usize,
) -> (
    std::arch::x86_64::__m256,
    std::arch::x86_64::__m128,
    std::arch::x86_64::__m256,
    std::arch::x86_64::__m128,
) {
    use std::arch::x86_64::*;
    let q = w.four(s);
    // SAFETY: `v` holds 9 `u16`: the 16 bytes from `v[0]` and the 8 from `v[5]` are in
    // bounds (unaligned loads).
    let (v8, v9) = unsafe {
        let p = v.as_ptr();
        (
            _mm256_cvtph_ps(_mm_loadu_si128(p.cast::<__m128i>())),
            _mm_cvtph_ps(_mm_loadl_epi64(p.add(5).cast::<__m128i>())),
        )
    };
    (
        v8,
        v9,
        _mm256_permutevar8x32_ps(
            _mm256_castps128_ps256(q),
            _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2),
        ),
        _mm_permutevar_ps(q, _mm_setr_epi32(1, 2, 2, 2)),
    )
}

/// Two accumulators of nine floats held as elements 0-7 and 5-8 (a row's, or a point's) as the
/// nine floats: elements 0-4 from the first, 5-8 from the second. (Elements 5-7 are in both;
/// taking them from the second keeps every lane of it in use, which keeps the compiler from
/// narrowing it to the ninth element alone, inserted into the low lane of a register it picks:
/// when that register holds an accumulator, each link's conversion waits for the previous
/// link's sum, and the product takes twice as long.)
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn unpack(
    acc8: std::arch::x86_64::__m256,
    acc4: std::arch::x86_64::__m128,
) -> [f32; LINK_DIM] {
    use std::arch::x86_64::*;
    let mut out = [0.0f32; LINK_DIM];
    // SAFETY: `out` holds 9 `f32`: the 32 bytes stored from its start and the 16 from its
    // sixth element are in bounds; the second store follows the first.
    unsafe {
        _mm256_storeu_ps(out.as_mut_ptr(), acc8);
        _mm_storeu_ps(out.as_mut_ptr().add(5), acc4);
    }
    out
}

/// [`row_sum`] with AVX2 and F16C: a link's values converted, multiplied and added eight (and
/// four) at a time ([`lanes`]; separate products and sums, so each element's bits are the
/// scalar loop's).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
#[inline]
pub(super) fn row_sum_f16c<S: Slot>(
    slots: &[S],
    values: &[[u16; LINK_DIM]],
    w: &Weights,
) -> [f32; LINK_DIM] {
    use std::arch::x86_64::*;
    let (mut acc8, mut acc9) = (_mm256_setzero_ps(), _mm_setzero_ps());
    for (&slot, v) in slots.iter().zip(values) {
        let (v8, v9, w8, w9) = lanes(v, w, slot.index());
        acc8 = _mm256_add_ps(acc8, _mm256_mul_ps(w8, v8));
        acc9 = _mm_add_ps(acc9, _mm_mul_ps(w9, v9));
    }
    unpack(acc8, acc9)
}

/// Whether this CPU has AVX2 and F16C, which the products' `_f16c` kernels are compiled for.
#[cfg(target_arch = "x86_64")]
pub(super) fn has_f16c_lanes() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("f16c")
}

/// A link's half-float values as `f32` (exact).
#[inline(always)]
fn decode(v: &[u16; LINK_DIM]) -> [f32; LINK_DIM] {
    std::array::from_fn(|d| f16::from_bits(v[d]).to_f32())
}
