//! The int8 CPU dense layer: each input row quantized to 8 bits with its own scale (unsigned where the row has
//! no negative value, as every ReLU output; else offset by 128), each weight column to signed 8 bits with its
//! own scale, the products summed exactly in 32-bit integers by the AVX-512 VNNI dot product (`vpdpbusd`, 64
//! multiply-adds per instruction, twice `vdpbf16ps`'s 32), then scaled back to f32 with the layer's epilogue
//! (old output, group term, ReLU). Only the inference encoders use it, and only when asked for
//! ([`Precision::Int8`]).
//!
//! [`dense_int8_reference`] is its readable twin, bit-identical: the same quantization, the integer sums (exact
//! in any order) and the same f32 epilogue, one fused multiply-add per output.
//!
//! [`Precision::Int8`]: crate::cpu::gemm::Precision::Int8

use crate::cpu::dense::DenseShape;

/// Whether this CPU runs the int8 dense layer (x86-64 with AVX-512F, AVX-512BW and AVX-512 VNNI).
pub fn is_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Rows per register tile.
#[cfg(target_arch = "x86_64")]
const MR: usize = 8;
/// Columns per register tile (two 16-lane vectors); the weight's columns are padded to a multiple of it.
const NR: usize = 32;

/// A transposed weight (`k x n`) quantized per output column: `q = round(w / scale)` in -127..=127 with
/// `scale = max |w| / 127` of the column, four consecutive rows per 32-bit word (the lowest row in the low
/// byte), the columns padded with zeros to a whole register tile.
#[derive(Clone, Debug)]
pub struct Int8Weight {
    /// Rows (input width).
    pub k: usize,
    /// Columns (output width).
    pub n: usize,
    /// Columns padded to a multiple of the register tile.
    padded_n: usize,
    /// `k.div_ceil(4) x padded_n` words.
    words: Vec<u32>,
    /// Each column's scale (`padded_n`, 0 in the padding).
    scale: Vec<f32>,
    /// Each column's sum of quantized values (`padded_n`): what an input offset of 128 adds to every output.
    column_sum: Vec<i32>,
}

/// Quantizes rows `0..k` of the transposed weight `w_t` (`k x n`, row stride `n`).
pub fn quantize_weight(w_t: &[f32], k: usize, n: usize) -> Int8Weight {
    assert!(w_t.len() >= k * n, "quantize_weight: weight too short");
    let padded_n = n.next_multiple_of(NR);
    let kq = k.div_ceil(4);
    let mut scale = vec![0f32; padded_n];
    let mut column_sum = vec![0i32; padded_n];
    let mut words = vec![0u32; kq * padded_n];
    for o in 0..n {
        let max = (0..k).map(|p| w_t[p * n + o].abs()).fold(0f32, f32::max);
        if max == 0.0 || !max.is_finite() {
            continue;
        }
        scale[o] = max / 127.0;
        let inverse = 127.0 / max;
        for p in 0..k {
            let q = (w_t[p * n + o] * inverse).round_ties_even().clamp(-127.0, 127.0) as i32;
            column_sum[o] += q;
            words[(p / 4) * padded_n + o] |= u32::from(q as i8 as u8) << (8 * (p % 4));
        }
    }
    Int8Weight { k, n, padded_n, words, scale, column_sum }
}

/// One input row's quantization: `q = round(x * inverse) + zero`, clamped to 0..=255; `x ~ scale * (q - zero)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct RowScale {
    scale: f32,
    inverse: f32,
    zero: i32,
}

impl RowScale {
    /// Unsigned over `0..=max` when the row has no negative value, else offset by 128 over `-m..=m` with `m`
    /// its largest magnitude. A row of zeros (or a non-finite one) gets scale 0: its products vanish.
    fn of(min: f32, max: f32) -> RowScale {
        let zero = RowScale { scale: 0.0, inverse: 0.0, zero: 0 };
        if !(min.is_finite() && max.is_finite()) {
            return zero;
        }
        if min >= 0.0 {
            if max == 0.0 { zero } else { RowScale { scale: max / 255.0, inverse: 255.0 / max, zero: 0 } }
        } else {
            let m = max.max(-min);
            RowScale { scale: m / 127.0, inverse: 127.0 / m, zero: 128 }
        }
    }

    fn of_range((min, max): (f32, f32)) -> RowScale {
        RowScale::of(min, max)
    }

    fn quantize(self, x: f32) -> u8 {
        ((x * self.inverse).round_ties_even() as i32 + self.zero).clamp(0, 255) as u8
    }
}

/// The smallest and largest value of a row made of `segments` (row `r` of each), and 0: min and max are
/// exact, so any order gives the same.
fn row_range(segments: &[(&[f32], usize)], r: usize) -> (f32, f32) {
    segments.iter().map(|&(x, w)| range(&x[r * w..][..w])).fold((0f32, 0f32), |(lo, hi), (l, h)| (lo.min(l), hi.max(h)))
}

/// The smallest and largest value of `x`, and 0.
fn range(x: &[f32]) -> (f32, f32) {
    x.iter().fold((0f32, 0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)))
}

/// The output `r, o` from the integer sum `acc`: `start + (row scale x column scale) x (acc - zero x column
/// sum)`, one fused multiply-add, then ReLU.
fn finish(start: f32, row: RowScale, weight: &Int8Weight, o: usize, acc: i32, relu: bool) -> f32 {
    let centred = acc.wrapping_sub(row.zero.wrapping_mul(weight.column_sum[o])) as f32;
    let v = (row.scale * weight.scale[o]).mul_add(centred, start);
    // As `vmaxps v, 0`: v where v > 0, else +0 (so -0 and NaN become +0 on both paths).
    if relu && v.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) { 0.0 } else { v }
}

/// The value an output starts from: its old value when accumulating, plus the group term.
fn start_value(shape: &DenseShape, group_term: &[f32], out: &[f32], r: usize, o: usize) -> f32 {
    let start = if shape.accumulate { out[r * shape.out_dim + o] } else { 0.0 };
    if group_term.is_empty() {
        start
    } else {
        start + group_term[(r / shape.rows_per_group.max(1)) * shape.out_dim + o]
    }
}

thread_local! {
    /// Each thread's quantized input rows and their scales, reused across calls.
    static QUANTIZED_ROWS: std::cell::RefCell<(Vec<u8>, Vec<RowScale>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// The dense layer of `crate::cpu::dense::dense` (same epilogue: accumulate, group term, ReLU, in f32) on the
/// concatenation of `segments` (`rows x width` each; `shape.in_dim` is the sum of the widths, never built),
/// with the inputs and `weight` (rows `0..shape.in_dim` of the layer, [`quantize_weight`]) in int8 and the
/// products summed exactly. Panics when the CPU lacks AVX-512 VNNI ([`is_available`]); callers check first.
pub fn dense_int8(
    shape: &DenseShape,
    segments: &[(&[f32], usize)],
    weight: &Int8Weight,
    group_term: &[f32],
    out: &mut [f32],
) {
    assert!(is_available(), "dense_int8: this CPU has no AVX-512 VNNI");
    let DenseShape { rows, in_dim, out_dim, rows_per_group, .. } = *shape;
    assert!(segments.iter().map(|s| s.1).sum::<usize>() == in_dim, "dense_int8: widths");
    assert!(segments.iter().all(|s| s.0.len() >= rows * s.1), "dense_int8: input too short");
    assert!(weight.k == in_dim && weight.n == out_dim && out.len() >= rows * out_dim, "dense_int8: sizes");
    assert!(group_term.is_empty() || group_term.len() >= rows.div_ceil(rows_per_group.max(1)) * out_dim);
    if rows == 0 || out_dim == 0 {
        return;
    }
    QUANTIZED_ROWS.with_borrow_mut(|(a, scales)| {
        quantize_rows(segments, rows, a, scales);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has AVX-512F, BW and VNNI (asserted above); `a` holds `rows` rows of the packed width.
        unsafe {
            x86::body(shape, a, scales, weight, group_term, out)
        }
    })
}

/// Rows of the concatenated `segments` quantized into `a` (`rows x 4 k.div_ceil(4)` bytes, zero-padded) with
/// their scales, 16 values per instruction where the CPU has it.
fn quantize_rows(segments: &[(&[f32], usize)], rows: usize, a: &mut Vec<u8>, scales: &mut Vec<RowScale>) {
    let k: usize = segments.iter().map(|s| s.1).sum();
    let stride = 4 * k.div_ceil(4);
    a.clear();
    a.resize(rows * stride, 0);
    scales.clear();
    #[cfg(target_arch = "x86_64")]
    if is_available() {
        // SAFETY: the CPU has AVX-512F and BW (checked first); `a` holds `rows` rows of `stride >= k` bytes.
        unsafe { x86::quantize_rows(segments, rows, stride, a, scales) };
        return;
    }
    for (r, dst) in a.chunks_exact_mut(stride.max(1)).enumerate().take(rows) {
        let row = RowScale::of_range(row_range(segments, r));
        scales.push(row);
        let mut at = 0;
        for &(x, w) in segments {
            dst[at..at + w].iter_mut().zip(&x[r * w..][..w]).for_each(|(d, &v)| *d = row.quantize(v));
            at += w;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Int8Weight, MR, NR, RowScale, finish, start_value};
    use crate::cpu::dense::DenseShape;
    use std::arch::x86_64::*;

    /// [`super::quantize_rows`]: each row's range, then its values quantized, 16 at a time, the leftovers as
    /// [`RowScale::quantize`] (the same arithmetic: an f32 product, rounded to nearest even, offset, clamped).
    #[target_feature(enable = "avx512f,avx512bw")]
    pub(super) fn quantize_rows(
        segments: &[(&[f32], usize)],
        rows: usize,
        stride: usize,
        a: &mut [u8],
        scales: &mut Vec<RowScale>,
    ) {
        for r in 0..rows {
            let (mut lo, mut hi) = (_mm512_setzero_ps(), _mm512_setzero_ps());
            let (mut lo_tail, mut hi_tail) = (0f32, 0f32);
            for &(x, w) in segments {
                let x = &x[r * w..][..w];
                let full = w / 16 * 16;
                for j in (0..full).step_by(16) {
                    // SAFETY: `x` holds `w >= full` values.
                    let v = unsafe { _mm512_loadu_ps(x.as_ptr().add(j)) };
                    (lo, hi) = (_mm512_min_ps(lo, v), _mm512_max_ps(hi, v));
                }
                (lo_tail, hi_tail) = x[full..].iter().fold((lo_tail, hi_tail), |(l, h), &v| (l.min(v), h.max(v)));
            }
            let row = RowScale::of(_mm512_reduce_min_ps(lo).min(lo_tail), _mm512_reduce_max_ps(hi).max(hi_tail));
            scales.push(row);
            let (inverse, zero) = (_mm512_set1_ps(row.inverse), _mm512_set1_epi32(row.zero));
            let (floor, ceiling) = (_mm512_setzero_si512(), _mm512_set1_epi32(255));
            let dst = &mut a[r * stride..][..stride];
            let mut at = 0;
            for &(x, w) in segments {
                let x = &x[r * w..][..w];
                let full = w / 16 * 16;
                for j in (0..full).step_by(16) {
                    // SAFETY: `x` holds `w >= full` values and `dst` `at + w` bytes.
                    unsafe {
                        let v = _mm512_mul_ps(_mm512_loadu_ps(x.as_ptr().add(j)), inverse);
                        let q = _mm512_add_epi32(_mm512_cvtps_epi32(v), zero);
                        let q = _mm512_min_epi32(_mm512_max_epi32(q, floor), ceiling);
                        _mm_storeu_si128(dst.as_mut_ptr().add(at + j).cast(), _mm512_cvtepi32_epi8(q));
                    }
                }
                dst[at + full..at + w].iter_mut().zip(&x[full..]).for_each(|(d, &v)| *d = row.quantize(v));
                at += w;
            }
        }
    }

    /// Column strips of `NR` outermost (the strip of the weight stays in cache), row blocks of `MR` inside.
    /// Whole tiles finish in registers; a last partial row block through [`finish`], value by value.
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    pub(super) fn body(
        shape: &DenseShape,
        a: &[u8],
        scales: &[RowScale],
        weight: &Int8Weight,
        group_term: &[f32],
        out: &mut [f32],
    ) {
        let (m, n, np) = (shape.rows, shape.out_dim, weight.padded_n);
        let kq = weight.k.div_ceil(4);
        let rpg = shape.rows_per_group.max(1);
        let mut a_pad = Vec::new();
        for c0 in (0..n).step_by(NR) {
            let cn = NR.min(n - c0);
            for r0 in (0..m).step_by(MR) {
                let rn = MR.min(m - r0);
                let a_tile = if rn == MR {
                    &a[r0 * 4 * kq..]
                } else {
                    a_pad.clear();
                    a_pad.resize(MR * 4 * kq, 0u8);
                    a_pad[..rn * 4 * kq].copy_from_slice(&a[r0 * 4 * kq..][..rn * 4 * kq]);
                    &a_pad[..]
                };
                if rn == MR && cn == NR / 2 {
                    // A strip of 16 columns (a 240- or 272-wide layer's last): the same sums and epilogue on one
                    // register per row.
                    let mut acc = [[_mm512_setzero_si512(); 1]; MR];
                    // SAFETY: as for the whole tile below, with 16 columns from c0.
                    unsafe {
                        micro(kq, a_tile, &weight.words[c0..], np, &mut acc);
                        finish_tile(shape, (r0, c0), &scales[r0..r0 + MR], weight, group_term, rpg, &acc, out);
                    }
                    continue;
                }
                let mut acc = [[_mm512_setzero_si512(); 2]; MR];
                // SAFETY: `a_tile` holds MR rows of kq words, the weight kq rows of np >= c0 + NR words.
                unsafe { micro(kq, a_tile, &weight.words[c0..], np, &mut acc) };
                if rn == MR && cn == NR {
                    // SAFETY: rows r0..r0 + MR of `out` and columns c0..c0 + NR exist, and so do their group
                    // rows; the weight's scales and sums are padded to np >= c0 + NR.
                    unsafe { finish_tile(shape, (r0, c0), &scales[r0..r0 + MR], weight, group_term, rpg, &acc, out) };
                    continue;
                }
                let mut sums = [[0i32; NR]; MR];
                for (i, row) in sums.iter_mut().enumerate() {
                    // SAFETY: each row of `sums` holds NR = 2 x 16 values.
                    unsafe {
                        _mm512_storeu_si512(row.as_mut_ptr().cast(), acc[i][0]);
                        _mm512_storeu_si512(row.as_mut_ptr().add(16).cast(), acc[i][1]);
                    }
                }
                for (i, row) in sums.iter().enumerate().take(rn) {
                    let r = r0 + i;
                    for (j, &s) in row.iter().enumerate().take(cn) {
                        let o = c0 + j;
                        let start = start_value(shape, group_term, out, r, o);
                        out[r * n + o] = finish(start, scales[r], weight, o, s, shape.relu);
                    }
                }
            }
        }
    }

    /// The epilogue of a whole tile (`H` = 2) or half a tile (`H` = 1, 16 columns) in registers: [`finish`]
    /// on 16 columns at a time.
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn finish_tile<const H: usize>(
        shape: &DenseShape,
        (r0, c0): (usize, usize),
        scales: &[RowScale],
        weight: &Int8Weight,
        group_term: &[f32],
        rpg: usize,
        acc: &[[__m512i; H]; MR],
        out: &mut [f32],
    ) {
        let n = shape.out_dim;
        // SAFETY: bounds as the caller promises.
        unsafe {
            let w_scale: [__m512; H] = std::array::from_fn(|h| _mm512_loadu_ps(weight.scale.as_ptr().add(c0 + 16 * h)));
            let sums: [__m512i; H] =
                std::array::from_fn(|h| _mm512_loadu_si512(weight.column_sum.as_ptr().add(c0 + 16 * h).cast()));
            let zero = _mm512_setzero_ps();
            for (i, row) in scales.iter().enumerate() {
                let r = r0 + i;
                let o = out.as_mut_ptr().add(r * n + c0);
                let offset = _mm512_set1_epi32(row.zero);
                let row_scale = _mm512_set1_ps(row.scale);
                for h in 0..H {
                    let mut start = if shape.accumulate { _mm512_loadu_ps(o.add(16 * h)) } else { zero };
                    if !group_term.is_empty() {
                        let g = group_term.as_ptr().add((r / rpg) * n + c0 + 16 * h);
                        start = _mm512_add_ps(start, _mm512_loadu_ps(g));
                    }
                    let centred = _mm512_cvtepi32_ps(_mm512_sub_epi32(acc[i][h], _mm512_mullo_epi32(offset, sums[h])));
                    let mut v = _mm512_fmadd_ps(_mm512_mul_ps(row_scale, w_scale[h]), centred, start);
                    if shape.relu {
                        v = _mm512_max_ps(v, zero);
                    }
                    _mm512_storeu_ps(o.add(16 * h), v);
                }
            }
        }
    }

    /// `acc[i][h] += sum_p dot4(a[i][p], b[p][16 h..])`: unsigned bytes of `a` (MR rows of `kq` words) by
    /// signed bytes of `b` (`kq` rows of `ldb` words), an 8 x 16 `H` tile in `8 H` registers.
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    unsafe fn micro<const H: usize>(kq: usize, a: &[u8], b: &[u32], ldb: usize, acc: &mut [[__m512i; H]; MR]) {
        debug_assert!(a.len() >= MR * 4 * kq && (kq == 0 || b.len() >= (kq - 1) * ldb + 16 * H));
        let (pa, pb) = (a.as_ptr().cast::<i32>(), b.as_ptr());
        // SAFETY (pointer reads): bounds as asserted above; `a` is read unaligned, a word at a time.
        unsafe {
            for p in 0..kq {
                let w: [__m512i; H] = std::array::from_fn(|h| _mm512_loadu_si512(pb.add(p * ldb + 16 * h).cast()));
                for (i, ci) in acc.iter_mut().enumerate() {
                    let x = _mm512_set1_epi32(pa.add(i * kq + p).read_unaligned());
                    for (c, &wh) in ci.iter_mut().zip(&w) {
                        *c = _mm512_dpbusd_epi32(*c, x, wh);
                    }
                }
            }
        }
    }
}

/// The readable twin of [`dense_int8`], bit-identical to it: the same quantization of rows and weight, each
/// output's integer sum in i64 (exact, so any order gives the same), the same f32 epilogue.
pub fn dense_int8_reference(
    shape: &DenseShape,
    segments: &[(&[f32], usize)],
    weight: &Int8Weight,
    group_term: &[f32],
    out: &mut [f32],
) {
    let DenseShape { rows, in_dim, out_dim, .. } = *shape;
    assert!(weight.k == in_dim && weight.n == out_dim, "dense_int8_reference: sizes");
    let byte = |p: usize, o: usize| (weight.words[(p / 4) * weight.padded_n + o] >> (8 * (p % 4))) as u8 as i8;
    for r in 0..rows {
        let row = RowScale::of_range(row_range(segments, r));
        let q: Vec<u8> = segments.iter().flat_map(|&(x, w)| &x[r * w..][..w]).map(|&v| row.quantize(v)).collect();
        for o in 0..out_dim {
            let acc: i64 = q.iter().enumerate().map(|(p, &u)| i64::from(u) * i64::from(byte(p, o))).sum();
            let start = start_value(shape, group_term, out, r, o);
            out[r * out_dim + o] = finish(start, row, weight, o, acc as i32, shape.relu);
        }
    }
}

/// Bound on `|dense_int8 - dense|` (the exact f32-input layer) for one output: half a quantization step of
/// every input (`x_scale / 2`) times the column's largest weight magnitude, plus half a weight step
/// (`w_scale / 2`) times the row's largest input magnitude, over `in_dim` products, plus f32 rounding.
pub fn int8_dense_bound(in_dim: usize, x_max: f64, w_max: f64, x_scale: f64, w_scale: f64) -> f64 {
    let k = in_dim as f64;
    k * (0.5 * x_scale * w_max + 0.5 * w_scale * x_max + 0.25 * x_scale * w_scale) + 1e-5 * k * x_max * w_max
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::dense::dense;
    use crate::rng::Rng;

    fn shape(rows: usize, in_dim: usize, out_dim: usize, rpg: usize, accumulate: bool, relu: bool) -> DenseShape {
        DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu }
    }

    #[test]
    fn the_kernel_equals_its_twin_bit_for_bit() {
        if !is_available() {
            eprintln!("skipped: this CPU has no AVX-512 VNNI (the twin is tested below)");
            return;
        }
        let mut rng = Rng::new(3);
        // Whole and partial tiles, widths not multiples of 4, signed and unsigned rows, two segments.
        for &(m, k1, k2, n, accumulate, relu, signed) in &[
            (16, 64, 0, 32, false, true, false),
            (13, 37, 30, 70, true, false, true),
            (24, 512, 192, 512, false, true, false),
            (9, 3, 1, 33, false, false, true),
            // A last strip of 16 columns (48 = 32 + 16, 272 = 8 x 32 + 16).
            (16, 100, 0, 48, true, true, false),
            (17, 64, 32, 272, false, true, true),
        ] {
            let mut v = |len: usize| -> Vec<f32> {
                (0..len).map(|_| if signed { rng.normal() as f32 } else { rng.normal().abs() as f32 }).collect()
            };
            let (x1, x2) = (v(m * k1), v(m * k2));
            let w_t = v((k1 + k2) * n);
            let group = v(m.div_ceil(4) * n);
            let weight = quantize_weight(&w_t, k1 + k2, n);
            let s = shape(m, k1 + k2, n, 4, accumulate, relu);
            let old = v(m * n);
            let segments: Vec<(&[f32], usize)> =
                [(&x1[..], k1), (&x2[..], k2)].into_iter().filter(|s| s.1 > 0).collect();
            let (mut got, mut want) = (old.clone(), old.clone());
            dense_int8(&s, &segments, &weight, &group, &mut got);
            dense_int8_reference(&s, &segments, &weight, &group, &mut want);
            assert_eq!(
                got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "{m}x{k1}+{k2}x{n}"
            );
        }
    }

    #[test]
    fn the_twin_is_within_the_quantization_bound_of_the_f32_layer() {
        let mut rng = Rng::new(5);
        for &(m, k, n, signed) in &[(8, 96, 40, false), (5, 130, 17, true)] {
            let x: Vec<f32> =
                (0..m * k).map(|_| if signed { rng.normal() as f32 } else { rng.normal().abs() as f32 }).collect();
            let w_t: Vec<f32> = (0..k * n).map(|_| rng.normal() as f32 * 0.1).collect();
            let group: Vec<f32> = (0..m * n).map(|_| rng.normal() as f32).collect();
            let s = shape(m, k, n, 1, false, false);
            let weight = quantize_weight(&w_t, k, n);
            let mut got = vec![0.0; m * n];
            dense_int8_reference(&s, &[(&x, k)], &weight, &group, &mut got);
            let mut exact = vec![0.0; m * n];
            dense(&s, &x, &w_t, &group, &mut exact);
            let mut worst = 0f64;
            for r in 0..m {
                let row = &x[r * k..][..k];
                let x_max = row.iter().fold(0f32, |a, v| a.max(v.abs())) as f64;
                let x_scale = if signed { x_max / 127.0 } else { x_max / 255.0 };
                for o in 0..n {
                    let w_max = (0..k).map(|p| w_t[p * n + o].abs()).fold(0f32, f32::max) as f64;
                    let bound = int8_dense_bound(k, x_max, w_max, x_scale, w_max / 127.0);
                    let err = (got[r * n + o] as f64 - exact[r * n + o] as f64).abs();
                    assert!(err <= bound, "{r},{o}: {err} > {bound}");
                    worst = worst.max(err / bound);
                }
            }
            // The bound is not vacuous: quantization moves the outputs by a visible share of it.
            assert!(worst > 1e-3, "error {worst} of the bound: was the layer quantized at all?");
        }
    }

    #[test]
    fn rows_of_zeros_and_a_zero_weight_column_give_the_start_value() {
        let (m, k, n) = (2, 8, 3);
        let mut x = vec![0.0; m * k];
        x[k..].iter_mut().enumerate().for_each(|(i, v)| *v = i as f32);
        let mut w_t = vec![0.5; k * n];
        (0..k).for_each(|p| w_t[p * n + 1] = 0.0);
        let weight = quantize_weight(&w_t, k, n);
        let group = vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let mut out = vec![9.0; m * n];
        dense_int8_reference(&shape(m, k, n, 1, false, false), &[(&x, k)], &weight, &group, &mut out);
        assert_eq!(&out[..3], &[1.0, 2.0, 3.0], "a zero row adds nothing");
        assert_eq!(out[4], 5.0, "a zero column adds nothing");
        // 0.5 x (0 + 1 + ... + 7) = 14, exactly representable after quantization (7 -> 255, 0.5 -> 127).
        assert!((out[3] - 18.0).abs() < 0.05, "{}", out[3]);
    }
}
