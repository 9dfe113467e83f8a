//! The weights of a product's senders, `e_s * scale_s` per colour channel, rounded to
//! half-float precision and held as half floats over a power-of-two scale ([`Weights`]), and
//! the conversion to half floats (eight at a time with F16C).

use half::f16;

#[cfg(target_arch = "x86_64")]
use super::kernels::has_f16c_lanes;

/// The sender weights of a product: those of most rows, those of the rows of receivers
/// `0..m`, `m`, and the receivers below which rows are skipped (neither computed nor written).
pub(super) type SenderWeights<'a> = (&'a Weights, &'a Weights, usize, usize);

/// The weights of a product's senders, by stored sender slot: per colour channel `e_s *
/// scale_s` (element `d` of a link is multiplied by channel `d / 3`), each rounded to
/// half-float precision (11 significant bits: a relative change of at most 2^-11, the
/// precision of the half-float links they multiply) and held as half floats: six bytes a
/// sender, so that the weights of a scene's senders stay in the first-level cache (textured
/// Sponza's 4,889 take 29 KB, against 176 KB as nine floats a sender), where each link's gather
/// of them finds them. Products and sums are `f32`, as before; each row's sum over the weights
/// divided by [`Weights::scale`] (a power of two that brings the largest into the half floats'
/// range) is multiplied by it at the end, which is exact, so a row's bits are those of its
/// sum over the rounded weights themselves, whatever the scale.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Weights {
    /// The weights over `scale`, as `f32` (exactly the half floats): the portable sums' and
    /// the groups'.
    unscaled: Vec<[f32; 3]>,
    /// The same as half-float bits, three a sender, then three zeros that no slot names, so
    /// that the eight bytes from any sender's three are readable (the vector kernels load them
    /// as one four-float vector and leave its fourth float unused).
    pub(super) half: Vec<u16>,
    /// The power of two each sum over `unscaled` is multiplied by.
    pub(super) scale: f32,
}

impl Weights {
    /// The weights `w`, rounded (see [`Weights`]).
    pub(super) fn new(w: &[[f32; 3]]) -> Weights {
        let scale = half_scale(w.as_flattened());
        let n = 3 * w.len();
        let mut half = vec![0u16; n + 3];
        let mut unscaled = vec![[0.0f32; 3]; w.len()];
        to_half(
            w.as_flattened(),
            1.0 / scale,
            &mut half[..n],
            unscaled.as_flattened_mut(),
        );
        Weights {
            unscaled,
            half,
            scale,
        }
    }

    /// Sender slot `s`'s weights (over the scale). Panics unless `s` names a sender.
    #[inline(always)]
    pub(super) fn get(&self, s: usize) -> &[f32; 3] {
        &self.unscaled[s]
    }

    /// Sender slot `s`'s weights (over the scale) as four floats (the fourth is the next
    /// slot's, not to be used), with F16C. Panics unless `s` names a sender.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx,f16c")]
    #[inline]
    pub(super) fn four(&self, s: usize) -> std::arch::x86_64::__m128 {
        use std::arch::x86_64::*;
        assert!(s < self.unscaled.len());
        // SAFETY: `s` names a sender (checked) and three zeros follow the senders' half
        // floats, so the 8 bytes from sender `s`'s first (6 of its own, 2 of the next) lie
        // within `self.half`; the pointer is derived from the whole slice's (an unaligned
        // load).
        unsafe { _mm_cvtph_ps(_mm_loadl_epi64(self.half.as_ptr().add(3 * s).cast())) }
    }
}

/// The power of two by which weights `w` are divided to be held as half floats: the largest
/// finite one in magnitude then lies in `[2^14, 2^15)`, below the half floats' largest
/// (65,504), so that each keeps its 11 significant bits down to `2^-24` of it (smaller ones
/// lose bits, as subnormal half floats, and below `2^-39` of it round to 0; `S e` skips
/// senders below `1e-4` of the brightest). 1 where none is finite and nonzero; never below the
/// smallest normal `f32`.
pub(super) fn half_scale(w: &[f32]) -> f32 {
    let largest = w
        .iter()
        .filter(|x| x.is_finite())
        .fold(0.0f32, |m, x| m.max(x.abs()));
    if largest == 0.0 {
        return 1.0;
    }
    // `largest` lies in [2^k, 2^(k + 1)) (a subnormal counts as below 2^-126).
    let k = ((largest.to_bits() >> 23) as i32 - 127).max(-126);
    f32::from_bits((((k - 14).max(-126) + 127) as u32) << 23)
}

/// `half[k]` = `src[k] * inv` rounded to a half float (to nearest, ties to even), and
/// `widened[k]` its value as `f32` (exact). `inv` is a power of two, so `src[k] * inv` is the
/// exact quotient by its inverse. With F16C eight at a time (the same rounding).
fn to_half(src: &[f32], inv: f32, half: &mut [u16], widened: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if has_f16c_lanes() {
        // SAFETY: this CPU has AVX2 and F16C (checked), all `to_half_f16c` needs.
        unsafe { to_half_f16c(src, inv, half, widened) };
        return;
    }
    for ((&x, h), y) in src.iter().zip(half).zip(widened) {
        let v = f16::from_f32(x * inv);
        *h = v.to_bits();
        *y = v.to_f32();
    }
}

/// [`to_half`] with F16C.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
fn to_half_f16c(src: &[f32], inv: f32, half: &mut [u16], widened: &mut [f32]) {
    use std::arch::x86_64::*;
    let (s8, s_rest) = src.as_chunks::<8>();
    let (h8, h_rest) = half.as_chunks_mut::<8>();
    let (w8, w_rest) = widened.as_chunks_mut::<8>();
    for ((s, h), w) in s8.iter().zip(h8).zip(w8) {
        // SAFETY: `s` and `w` hold 8 `f32` (32 bytes), `h` 8 `u16` (16 bytes): unaligned
        // loads and stores within them.
        unsafe {
            let x = _mm256_mul_ps(_mm256_loadu_ps(s.as_ptr()), _mm256_set1_ps(inv));
            let bits = _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(x);
            _mm_storeu_si128(h.as_mut_ptr().cast(), bits);
            _mm256_storeu_ps(w.as_mut_ptr(), _mm256_cvtph_ps(bits));
        }
    }
    for ((&x, h), y) in s_rest.iter().zip(h_rest).zip(w_rest) {
        let v = f16::from_f32(x * inv);
        *h = v.to_bits();
        *y = v.to_f32();
    }
}

/// `x` rounded as [`Weights`] rounds a weight of a product whose scale is `scale`.
#[cfg(test)]
pub(super) fn rounded(x: f32, scale: f32) -> f32 {
    f16::from_f32(x / scale).to_f32() * scale
}
