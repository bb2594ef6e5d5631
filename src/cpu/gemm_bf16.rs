//! The reduced-precision CPU dense layer: inputs and weights rounded to bfloat16 (round to nearest even),
//! products summed in f32 by the AVX-512 BF16 dot-product instruction (`vdpbf16ps`, 32 multiply-adds per
//! instruction, twice the f32 rate). Only wide layers use it, and only when asked for ([`Precision::Bf16`]):
//! the encoders at inference (see `crate::backend::cpu`), and the trainer's forward and backward multiplies
//! ([`gemm_acc_packed`], `crate::cpu::dense_grad_bf16`) when it trains in bf16. Every test oracle stays in f32.
//!
//! [`Precision::Bf16`]: crate::cpu::gemm::Precision::Bf16
//!
//! [`dense_bf16_reference`] is its readable twin: the same bf16 rounding, then an f64 sum, so the SIMD result
//! differs from it only by f32 summation error. [`bf16_dense_bound`] bounds the distance of either from the
//! exact f32-input layer ([`crate::cpu::dense::dense`]): bf16 rounding of both factors (relative `2^-8` per
//! product at most) plus the f32 sum.

use crate::cpu::dense::{DenseShape, gamma_f32};
use crate::cpu::gemm_amx;

/// Unit roundoff of bfloat16 under round to nearest: half its 2^-7 spacing (8 significant bits).
pub const BF16_UNIT_ROUNDOFF: f64 = 1.0 / 256.0;

/// Whether this CPU runs the bf16 dense layer (x86-64 with AVX-512F and AVX-512 BF16).
pub fn is_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `x` rounded to the nearest bfloat16 (ties to even), as the bf16 bits. NaN stays NaN.
pub fn to_bf16(x: f32) -> u16 {
    let bits = x.to_bits();
    if x.is_nan() {
        return ((bits >> 16) | 0x40) as u16;
    }
    let round = 0x7fff + ((bits >> 16) & 1);
    (bits.wrapping_add(round) >> 16) as u16
}

/// The f32 value of bf16 bits.
pub fn from_bf16(h: u16) -> f32 {
    f32::from_bits(u32::from(h) << 16)
}

/// `x` rounded through bfloat16.
pub fn round_bf16(x: f32) -> f32 {
    from_bf16(to_bf16(x))
}

/// Two bf16 values in one 32-bit word, the even-indexed one in the low half: the operand layout of
/// `vdpbf16ps`.
fn pair(lo: f32, hi: f32) -> u32 {
    u32::from(to_bf16(lo)) | (u32::from(to_bf16(hi)) << 16)
}

/// Rows of the concatenation of `segments` (each `rows x width`, even widths but perhaps the last) as bf16
/// pairs along k: `rows x k.div_ceil(2)` words, an odd k padded with 0.
fn pack_rows(segments: &[(&[f32], usize)], rows: usize, out: &mut Vec<u32>) {
    let k: usize = segments.iter().map(|s| s.1).sum();
    let kp = k.div_ceil(2);
    out.clear();
    out.resize(rows * kp, 0);
    for (r, dst) in out.chunks_exact_mut(kp.max(1)).enumerate().take(rows) {
        let mut at = 0;
        for &(x, width) in segments {
            let row = &x[r * width..][..width];
            let words = width.div_ceil(2);
            pack_pairs(row, &mut dst[at..at + words]);
            at += words;
        }
    }
}

/// `row` as bf16 pairs into `dst` (`row.len().div_ceil(2)` words), 32 values per instruction where the CPU
/// has it. The instruction flushes subnormal inputs to zero where [`to_bf16`] keeps them; both are within
/// [`bf16_dense_bound`].
fn pack_pairs(row: &[f32], dst: &mut [u32]) {
    assert!(dst.len() >= row.len().div_ceil(2));
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (checked first).
    let done = if is_available() { unsafe { x86::pack_pairs(row, dst) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for (q, w) in dst.iter_mut().enumerate().skip(done / 2) {
        *w = pair(row[2 * q], row.get(2 * q + 1).copied().unwrap_or(0.0));
    }
}

/// The transposed weight (`k x n`) as bf16 pairs of consecutive rows: `k.div_ceil(2) x n` words, an odd k's
/// last pair padded with 0. Rows `2q..` of a packed weight are the packing of rows `2q..` of the weight, so
/// one packing serves every even row offset (the slices of a concatenated input).
pub fn pack_weight(w_t: &[f32], k: usize, n: usize) -> Vec<u32> {
    pack_row_pairs(w_t, k, n, n)
}

/// Rows `0..k` of a `k x n` matrix stored with row stride `ld` (columns `0..n` of each) as bf16 pairs of
/// consecutive rows: `k.div_ceil(2) x n` words, an odd k's last pair padded with 0. The B operand of
/// [`gemm_acc_packed`]; [`pack_weight`] is the case `ld = n`.
pub fn pack_row_pairs(x: &[f32], k: usize, n: usize, ld: usize) -> Vec<u32> {
    let kp = k.div_ceil(2);
    assert!(k == 0 || x.len() >= (k - 1) * ld + n, "pack_row_pairs: matrix too short");
    let mut out = vec![0u32; kp * n];
    let zeros = vec![0.0; n];
    for (p, dst) in out.chunks_exact_mut(n.max(1)).enumerate().take(kp) {
        let lo = &x[2 * p * ld..][..n];
        let hi = if 2 * p + 1 < k { &x[(2 * p + 1) * ld..][..n] } else { &zeros[..] };
        interleave_pairs(lo, hi, dst);
    }
    out
}

/// `dst[j] = (lo[j], hi[j])` as one bf16 pair each (`lo` in the low half), 16 words per instruction where
/// the CPU has it (which flushes subnormal inputs to zero, as [`pack_pairs`]).
fn interleave_pairs(lo: &[f32], hi: &[f32], dst: &mut [u32]) {
    assert!(lo.len() >= dst.len() && hi.len() >= dst.len());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (checked first).
    let done = if is_available() { unsafe { x86::interleave_pairs(lo, hi, dst) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for (j, w) in dst.iter_mut().enumerate().skip(done) {
        *w = pair(lo[j], hi[j]);
    }
}

/// The columns of a `k x n` matrix stored with row stride `ld`, each as one row of bf16 pairs along k:
/// `n x k.div_ceil(2)` words, an odd k padded with 0. The A operand of [`gemm_acc_packed`] for a transposed
/// factor (`A = X^T`).
pub fn pack_column_pairs(x: &[f32], k: usize, n: usize, ld: usize) -> Vec<u32> {
    let kp = k.div_ceil(2);
    let by_rows = pack_row_pairs(x, k, n, ld);
    let mut out = vec![0u32; n * kp];
    // Blocks of 16 x 16 words, so that both the reads and the writes stay within a few cache lines.
    const BLOCK: usize = 16;
    for p0 in (0..kp).step_by(BLOCK) {
        for j0 in (0..n).step_by(BLOCK) {
            for p in p0..(p0 + BLOCK).min(kp) {
                for j in j0..(j0 + BLOCK).min(n) {
                    out[j * kp + p] = by_rows[p * n + j];
                }
            }
        }
    }
    out
}

/// The rows of a `rows x k` matrix (row stride `k`) as bf16 pairs along k: `rows x k.div_ceil(2)` words, an
/// odd k padded with 0. The A operand of [`gemm_acc_packed`].
pub fn pack_rows_of(x: &[f32], rows: usize, k: usize) -> Vec<u32> {
    assert!(x.len() >= rows * k, "pack_rows_of: matrix too short");
    let mut out = Vec::new();
    pack_rows(&[(x, k)], rows, &mut out);
    out
}

/// Which unit multiplies the bf16 pairs. Both sum the products in f32, in different orders, so their results
/// differ by f32 rounding only (each is within [`bf16_dense_bound`] of the f32 layer).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Bf16Unit {
    /// The AVX-512 BF16 dot product (`vdpbf16ps`) on every CPU with AVX-512 BF16.
    Vector,
    /// AMX tiles ([`crate::cpu::gemm_amx`]) where the CPU and OS have them, else the vector unit: what the
    /// encoders and the trainer run.
    #[default]
    Tiles,
}

impl Bf16Unit {
    /// The unit that runs: [`Bf16Unit::Tiles`] falls back to [`Bf16Unit::Vector`] where AMX is not available.
    pub fn effective(self) -> Bf16Unit {
        if self == Bf16Unit::Tiles && gemm_amx::is_available() { Bf16Unit::Tiles } else { Bf16Unit::Vector }
    }

    /// Which unit runs, in words: "on AMX tiles" or "on the vector unit (no AMX)".
    pub fn describe(self) -> &'static str {
        match (self, self.effective()) {
            (_, Bf16Unit::Tiles) => "multiplies on AMX tiles",
            (Bf16Unit::Tiles, Bf16Unit::Vector) => {
                "multiplies on the AVX-512 BF16 vector unit (this CPU or OS has no AMX)"
            }
            (Bf16Unit::Vector, Bf16Unit::Vector) => "multiplies on the AVX-512 BF16 vector unit",
        }
    }
}

/// `c[i * ldc + j] += sum_p A[i, p] B[p, j]` for `i < m`, `j < n`, with both factors rounded to bf16 and
/// packed in pairs along p (`a`: `m x kp` words, [`pack_rows_of`] or [`pack_column_pairs`]; `b`: `kp x n`
/// words, [`pack_row_pairs`]), the products summed in f32 on `unit` onto the old value of `c`. Within
/// [`bf16_dense_bound`] (with `in_dim = 2 kp`) of the f32 product. Panics when the CPU lacks AVX-512 BF16
/// ([`is_available`]) or a slice is too short.
pub fn gemm_acc_packed(
    unit: Bf16Unit,
    (m, n, kp): (usize, usize, usize),
    a: &[u32],
    b: &[u32],
    c: &mut [f32],
    ldc: usize,
) {
    assert!(is_available(), "gemm_acc_packed: this CPU has no AVX-512 BF16");
    if m == 0 || n == 0 {
        return;
    }
    assert!(a.len() >= m * kp && b.len() >= kp * n && c.len() >= (m - 1) * ldc + n, "gemm_acc_packed: sizes");
    if unit.effective() == Bf16Unit::Tiles {
        gemm_acc_tiles_padded((m, n, kp), a, b, c, ldc);
    } else {
        #[cfg(target_arch = "x86_64")]
        {
            let shape =
                DenseShape { rows: m, in_dim: 2 * kp, out_dim: n, rows_per_group: 1, accumulate: true, relu: false };
            // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (asserted above); the operands have the packed sizes.
            unsafe { x86::body(&shape, a, b, &[], c, ldc) }
        }
    }
}

/// [`gemm_acc_packed`] on the AMX tiles, any sizes: operands whose sizes are not whole tiles are copied
/// zero-padded (the padding adds exact zeros), and so is `c`, whose block is copied back.
fn gemm_acc_tiles_padded((m, n, kp): (usize, usize, usize), a: &[u32], b: &[u32], c: &mut [f32], ldc: usize) {
    use gemm_amx::{BLOCK, K_WORDS, gemm_acc_tiles};
    let (mp, np, kq) = (m.next_multiple_of(BLOCK), n.next_multiple_of(BLOCK), kp.next_multiple_of(K_WORDS));
    let a_pad;
    let a = if (mp, kq) == (m, kp) {
        a
    } else {
        a_pad = padded(a, (m, kp, kp), (mp, kq));
        &a_pad[..]
    };
    let b_pad;
    let (b, ldb) = if (kq, np) == (kp, n) {
        (b, n)
    } else {
        b_pad = padded(b, (kp, n, n), (kq, np));
        (&b_pad[..], np)
    };
    if (mp, np) == (m, n) {
        gemm_acc_tiles((m, n, kq), a, kq, b, ldb, c, ldc);
        return;
    }
    let mut c_pad = padded(c, (m, n, ldc), (mp, np));
    gemm_acc_tiles((mp, np, kq), a, kq, b, ldb, &mut c_pad, np);
    for (dst, src) in c.chunks_mut(ldc).zip(c_pad.chunks_exact(np)).take(m) {
        dst[..n].copy_from_slice(&src[..n]);
    }
}

/// The `rows x cols` matrix `x` (row stride `ld`) in a zero `rows_to x cols_to` one (row stride `cols_to`).
fn padded<T: Copy + Default>(
    x: &[T],
    (rows, cols, ld): (usize, usize, usize),
    (rows_to, cols_to): (usize, usize),
) -> Vec<T> {
    let mut out = vec![T::default(); rows_to * cols_to];
    for (r, dst) in out.chunks_exact_mut(cols_to).enumerate().take(rows) {
        dst[..cols].copy_from_slice(&x[r * ld..][..cols]);
    }
    out
}

/// Rows per register tile and columns per register tile (two 16-lane vectors) of the SIMD kernel.
#[cfg(target_arch = "x86_64")]
const MR: usize = 8;
#[cfg(target_arch = "x86_64")]
const NR: usize = 32;

thread_local! {
    /// Each thread's packed-input buffer, reused across calls (a layer's input is packed once per call).
    static PACKED_ROWS: std::cell::RefCell<Vec<u32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The dense layer of `crate::cpu::dense::dense` (same arguments and epilogue: accumulate, group term, ReLU,
/// all in f32) with `x` and `w_t` rounded to bf16 and the products summed by `vdpbf16ps`. Panics when the
/// CPU lacks it ([`is_available`]); callers check first.
pub fn dense_bf16(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    assert!(w_t.len() >= shape.in_dim * shape.out_dim, "dense_bf16: weight too short");
    let packed = pack_weight(w_t, shape.in_dim, shape.out_dim);
    dense_bf16_packed(shape, &[(x, shape.in_dim)], &packed, group_term, out)
}

/// [`dense_bf16`] with the weight already packed ([`pack_weight`]; `shape.in_dim.div_ceil(2) x out_dim` words
/// or more) on the concatenation of `segments` (`rows x width` each; `shape.in_dim` is the sum of the widths,
/// all even but the last), which is never built: one multiply over the whole width, on the vector unit.
pub fn dense_bf16_packed(
    shape: &DenseShape,
    segments: &[(&[f32], usize)],
    w_packed: &[u32],
    group_term: &[f32],
    out: &mut [f32],
) {
    dense_bf16_packed_on(Bf16Unit::Vector, shape, segments, w_packed, group_term, out)
}

/// [`dense_bf16_packed`] on `unit`. On AMX tiles the output starts as the old output (when accumulating) plus
/// the group term, the product is added, then ReLU: the same epilogue, in f32.
pub fn dense_bf16_packed_on(
    unit: Bf16Unit,
    shape: &DenseShape,
    segments: &[(&[f32], usize)],
    w_packed: &[u32],
    group_term: &[f32],
    out: &mut [f32],
) {
    assert!(is_available(), "dense_bf16: this CPU has no AVX-512 BF16");
    let DenseShape { rows, in_dim, out_dim, rows_per_group, .. } = *shape;
    let total: usize = segments.iter().map(|s| s.1).sum();
    assert!(total == in_dim && segments.iter().rev().skip(1).all(|s| s.1 % 2 == 0), "dense_bf16: widths");
    assert!(segments.iter().all(|s| s.0.len() >= rows * s.1), "dense_bf16: input too short");
    assert!(w_packed.len() >= in_dim.div_ceil(2) * out_dim && out.len() >= rows * out_dim, "dense_bf16: sizes");
    assert!(group_term.is_empty() || group_term.len() >= rows.div_ceil(rows_per_group.max(1)) * out_dim);
    if rows == 0 || out_dim == 0 {
        return;
    }
    PACKED_ROWS.with_borrow_mut(|a| {
        pack_rows(segments, rows, a);
        if unit.effective() == Bf16Unit::Tiles {
            dense_on_tiles(shape, a, w_packed, group_term, out);
        } else {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (asserted above); `a` and `w_packed` have the packed
            // sizes.
            unsafe {
                x86::body(shape, a, w_packed, group_term, out, out_dim)
            }
        }
    })
}

/// The dense layer on the AMX tiles, from the packed rows `a` and weight `w_packed`: the output starts as the
/// old output (when accumulating) plus the group term, the product is added, then ReLU.
fn dense_on_tiles(shape: &DenseShape, a: &[u32], w_packed: &[u32], group_term: &[f32], out: &mut [f32]) {
    let DenseShape { rows, in_dim, out_dim, rows_per_group, accumulate, relu } = *shape;
    let out = &mut out[..rows * out_dim];
    for (r, row) in out.chunks_exact_mut(out_dim).enumerate() {
        match (accumulate, group_term.is_empty()) {
            (true, true) => {}
            (false, true) => row.fill(0.0),
            (acc, false) => {
                let g = &group_term[(r / rows_per_group.max(1)) * out_dim..][..out_dim];
                if acc {
                    row.iter_mut().zip(g).for_each(|(v, gv)| *v += gv);
                } else {
                    row.copy_from_slice(g);
                }
            }
        }
    }
    gemm_acc_tiles_padded((rows, out_dim, in_dim.div_ceil(2)), a, w_packed, out, out_dim);
    if relu {
        out.iter_mut().for_each(|v| *v = v.max(0.0));
    }
}

/// The tile's starting values: the old output (row stride `ldc`) when accumulating, plus the group term.
#[cfg(target_arch = "x86_64")]
fn start_tile(
    shape: &DenseShape,
    group_term: &[f32],
    (out, ldc): (&[f32], usize),
    (r0, rn): (usize, usize),
    (c0, cn): (usize, usize),
) -> [[f32; NR]; MR] {
    let mut acc = [[0f32; NR]; MR];
    let n = shape.out_dim;
    for (i, acc_row) in acc.iter_mut().enumerate().take(rn) {
        let r = r0 + i;
        if shape.accumulate {
            acc_row[..cn].copy_from_slice(&out[r * ldc + c0..][..cn]);
        }
        if !group_term.is_empty() {
            let g = &group_term[(r / shape.rows_per_group.max(1)) * n + c0..][..cn];
            for (v, gv) in acc_row[..cn].iter_mut().zip(g) {
                *v += gv;
            }
        }
    }
    acc
}

/// Writes the tile (row stride `ldc`), with ReLU when the layer has it.
#[cfg(target_arch = "x86_64")]
fn store_tile(
    shape: &DenseShape,
    acc: &[[f32; NR]; MR],
    (out, ldc): (&mut [f32], usize),
    (r0, rn): (usize, usize),
    (c0, cn): (usize, usize),
) {
    for (i, acc_row) in acc.iter().enumerate().take(rn) {
        let dst = &mut out[(r0 + i) * ldc + c0..][..cn];
        for (d, &s) in dst.iter_mut().zip(&acc_row[..cn]) {
            *d = if shape.relu { s.max(0.0) } else { s };
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{MR, NR, start_tile, store_tile};
    use crate::cpu::dense::DenseShape;
    use std::arch::x86_64::*;

    /// Packs the leading multiple of 16 of `dst`: word j is the bf16 pair (`lo[j]`, `hi[j]`), `lo[j]` in the
    /// low half; returns how many words it wrote.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) fn interleave_pairs(lo: &[f32], hi: &[f32], dst: &mut [u32]) -> usize {
        let full = dst.len().min(lo.len()).min(hi.len()) / 16 * 16;
        for j in (0..full).step_by(16) {
            // SAFETY: `lo`, `hi` and `dst` hold at least `full` values.
            unsafe {
                let a: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(_mm512_loadu_ps(lo.as_ptr().add(j))));
                let b: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(_mm512_loadu_ps(hi.as_ptr().add(j))));
                let high = _mm512_slli_epi32::<16>(_mm512_cvtepu16_epi32(b));
                let words = _mm512_or_si512(_mm512_cvtepu16_epi32(a), high);
                _mm512_storeu_si512(dst.as_mut_ptr().add(j).cast(), words);
            }
        }
        full
    }

    /// Packs the leading multiple of 32 of `row` into `dst` as bf16 pairs; returns how many values it packed.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) fn pack_pairs(row: &[f32], dst: &mut [u32]) -> usize {
        let full = row.len() / 32 * 32;
        for (c, chunk) in row[..full].chunks_exact(32).enumerate() {
            // SAFETY: `chunk` holds 32 values and `dst` 16 words at `c * 16` (row.len() / 2 words in all).
            unsafe {
                let lo = _mm512_loadu_ps(chunk.as_ptr());
                let hi = _mm512_loadu_ps(chunk.as_ptr().add(16));
                // Lower half from `lo`: value 2q lands in the low 16 bits of word q.
                let packed: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo));
                _mm512_storeu_si512(dst.as_mut_ptr().add(c * 16).cast(), packed);
            }
        }
        if row.len() - full >= 16 {
            // 16 more values: 16 bf16 in order are 8 pairs, value 2q in the low half of word q.
            // SAFETY: `row` holds 16 values at `full` and `dst` 8 words at `full / 2`.
            unsafe {
                let packed: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(_mm512_loadu_ps(row.as_ptr().add(full))));
                _mm256_storeu_si256(dst.as_mut_ptr().add(full / 2).cast(), packed);
            }
            return full + 16;
        }
        full
    }

    /// Column strips of `NR` outermost (the strip of packed weights stays in cache), row blocks of `MR`
    /// inside. Full tiles start from and write to `out` (row stride `ldc`) in registers; partial tiles go
    /// through an array and zero-padded copies of their operands.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) fn body(shape: &DenseShape, a: &[u32], b: &[u32], group_term: &[f32], out: &mut [f32], ldc: usize) {
        let (m, n, kp) = (shape.rows, shape.out_dim, shape.in_dim.div_ceil(2));
        let rpg = shape.rows_per_group.max(1);
        // Zero-padded copies for partial tiles, allocated only when a layer has one.
        let (mut b_pad, mut a_pad) = (Vec::new(), Vec::new());
        for c0 in (0..n).step_by(NR) {
            let cn = NR.min(n - c0);
            let (b_strip, b_stride) = if cn == NR {
                (&b[c0..], n)
            } else {
                b_pad.resize(kp * NR, 0u32);
                for p in 0..kp {
                    b_pad[p * NR..][..cn].copy_from_slice(&b[p * n + c0..][..cn]);
                }
                (&b_pad[..], NR)
            };
            for r0 in (0..m).step_by(MR) {
                let rn = MR.min(m - r0);
                if rn == MR && cn == NR {
                    // SAFETY: rows r0..r0 + MR of `a` (kp words each) and of `out` (ldc apart, NR from c0),
                    // and the group rows of those rows, exist; `b_strip` holds kp rows of NR at b_stride.
                    unsafe {
                        let mut c = [[_mm512_setzero_ps(); 2]; MR];
                        for (i, ci) in c.iter_mut().enumerate() {
                            let r = r0 + i;
                            if shape.accumulate {
                                let o = out.as_ptr().add(r * ldc + c0);
                                *ci = [_mm512_loadu_ps(o), _mm512_loadu_ps(o.add(16))];
                            }
                            if !group_term.is_empty() {
                                let g = group_term.as_ptr().add((r / rpg) * n + c0);
                                ci[0] = _mm512_add_ps(ci[0], _mm512_loadu_ps(g));
                                ci[1] = _mm512_add_ps(ci[1], _mm512_loadu_ps(g.add(16)));
                            }
                        }
                        micro(kp, &a[r0 * kp..], b_strip, b_stride, &mut c);
                        let zero = _mm512_setzero_ps();
                        for (i, ci) in c.iter().enumerate() {
                            let o = out.as_mut_ptr().add((r0 + i) * ldc + c0);
                            let (v0, v1) = if shape.relu {
                                (_mm512_max_ps(ci[0], zero), _mm512_max_ps(ci[1], zero))
                            } else {
                                (ci[0], ci[1])
                            };
                            _mm512_storeu_ps(o, v0);
                            _mm512_storeu_ps(o.add(16), v1);
                        }
                    }
                    continue;
                }
                if rn == MR && cn == NR / 2 {
                    // A strip of 16 columns (a 144- or 240-wide layer's last).
                    // SAFETY: as for the full tile, with 16 columns from c0; `b` holds kp rows of n >= c0 + 16.
                    unsafe { half_tile(shape, (&a[r0 * kp..], &b[c0..]), group_term, (out, ldc), (r0, c0)) };
                    continue;
                }
                let a_tile = if rn == MR {
                    &a[r0 * kp..]
                } else {
                    a_pad.clear();
                    a_pad.resize(MR * kp, 0u32);
                    a_pad[..rn * kp].copy_from_slice(&a[r0 * kp..][..rn * kp]);
                    &a_pad[..]
                };
                let acc = start_tile(shape, group_term, (out, ldc), (r0, rn), (c0, cn));
                // SAFETY: the tile array is plain memory of MR x NR values.
                let mut c = unsafe {
                    let mut c = [[_mm512_setzero_ps(); 2]; MR];
                    for i in 0..MR {
                        c[i] = [_mm512_loadu_ps(acc[i].as_ptr()), _mm512_loadu_ps(acc[i].as_ptr().add(16))];
                    }
                    c
                };
                // SAFETY: `a_tile` holds MR rows of kp words and `b_strip` kp rows of NR words at `b_stride`.
                unsafe { micro(kp, a_tile, b_strip, b_stride, &mut c) };
                let mut acc = [[0f32; NR]; MR];
                for i in 0..MR {
                    // SAFETY: as above.
                    unsafe {
                        _mm512_storeu_ps(acc[i].as_mut_ptr(), c[i][0]);
                        _mm512_storeu_ps(acc[i].as_mut_ptr().add(16), c[i][1]);
                    }
                }
                store_tile(shape, &acc, (out, ldc), (r0, rn), (c0, cn));
            }
        }
    }

    /// An 8-row tile of the 16 columns from `c0`: the full tile's arithmetic on one register per row (start,
    /// [`micro_half`], ReLU), `a` from row r0 and `b` from column c0 (row stride `shape.out_dim`).
    #[target_feature(enable = "avx512f,avx512bf16")]
    unsafe fn half_tile(
        shape: &DenseShape,
        (a, b): (&[u32], &[u32]),
        group_term: &[f32],
        (out, ldc): (&mut [f32], usize),
        (r0, c0): (usize, usize),
    ) {
        let (n, kp, rpg) = (shape.out_dim, shape.in_dim.div_ceil(2), shape.rows_per_group.max(1));
        // SAFETY: the caller's bounds: rows r0..r0 + MR of `out` (ldc apart) and their group rows hold the 16
        // columns from c0.
        unsafe {
            let mut c = [_mm512_setzero_ps(); MR];
            for (i, ci) in c.iter_mut().enumerate() {
                let r = r0 + i;
                if shape.accumulate {
                    *ci = _mm512_loadu_ps(out.as_ptr().add(r * ldc + c0));
                }
                if !group_term.is_empty() {
                    *ci = _mm512_add_ps(*ci, _mm512_loadu_ps(group_term.as_ptr().add((r / rpg) * n + c0)));
                }
            }
            micro_half(kp, a, b, n, &mut c);
            let zero = _mm512_setzero_ps();
            for (i, ci) in c.iter().enumerate() {
                let v = if shape.relu { _mm512_max_ps(*ci, zero) } else { *ci };
                _mm512_storeu_ps(out.as_mut_ptr().add((r0 + i) * ldc + c0), v);
            }
        }
    }

    /// [`micro`] on 16 columns: `c[i] += sum_p dot(a[i * kp + p], b[p * ldb ..])`, an 8 x 16 tile in 8
    /// registers, each column's products added in the same order.
    #[target_feature(enable = "avx512f,avx512bf16")]
    unsafe fn micro_half(kp: usize, a: &[u32], b: &[u32], ldb: usize, c: &mut [__m512; MR]) {
        debug_assert!(a.len() >= MR * kp && (kp == 0 || b.len() >= (kp - 1) * ldb + NR / 2));
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        // SAFETY (pointer reads): bounds as asserted above.
        unsafe {
            for p in 0..kp {
                let b0: __m512bh = std::mem::transmute(_mm512_loadu_si512(pb.add(p * ldb).cast()));
                for (i, ci) in c.iter_mut().enumerate() {
                    let x: __m512bh = std::mem::transmute(_mm512_set1_epi32(*pa.add(i * kp + p) as i32));
                    *ci = _mm512_dpbf16_ps(*ci, x, b0);
                }
            }
        }
    }

    /// `c[i][h] += sum_p dot(a[i * kp + p], b[p * ldb + 16 h ..])` over bf16 pairs: an 8 x 32 tile in 16
    /// registers.
    #[target_feature(enable = "avx512f,avx512bf16")]
    unsafe fn micro(kp: usize, a: &[u32], b: &[u32], ldb: usize, c: &mut [[__m512; 2]; MR]) {
        debug_assert!(a.len() >= MR * kp && (kp == 0 || b.len() >= (kp - 1) * ldb + NR));
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        // SAFETY (pointer reads): bounds as asserted above.
        unsafe {
            for p in 0..kp {
                let b0: __m512bh = std::mem::transmute(_mm512_loadu_si512(pb.add(p * ldb).cast()));
                let b1: __m512bh = std::mem::transmute(_mm512_loadu_si512(pb.add(p * ldb + 16).cast()));
                for (i, ci) in c.iter_mut().enumerate() {
                    let x: __m512bh = std::mem::transmute(_mm512_set1_epi32(*pa.add(i * kp + p) as i32));
                    ci[0] = _mm512_dpbf16_ps(ci[0], x, b0);
                    ci[1] = _mm512_dpbf16_ps(ci[1], x, b1);
                }
            }
        }
    }
}

/// The readable twin of [`dense_bf16`]: the same epilogue, `x` and `w_t` rounded to bf16, each output's
/// products summed exactly in f64 and rounded once.
pub fn dense_bf16_reference(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    let DenseShape { rows, in_dim, out_dim, rows_per_group, accumulate, relu } = *shape;
    for r in 0..rows {
        for o in 0..out_dim {
            let mut s = if accumulate { f64::from(out[r * out_dim + o]) } else { 0.0 };
            if !group_term.is_empty() {
                s += f64::from(group_term[(r / rows_per_group.max(1)) * out_dim + o]);
            }
            for p in 0..in_dim {
                s += f64::from(round_bf16(x[r * in_dim + p])) * f64::from(round_bf16(w_t[p * out_dim + o]));
            }
            let v = s as f32;
            out[r * out_dim + o] = if relu { v.max(0.0) } else { v };
        }
    }
}

/// Largest distance of one output of [`dense_bf16`] from the f32-input layer, given `magnitude` = the sum of
/// `|x_p w_p|` over its products plus `|start|` (old output and group term): bf16 rounding of both factors
/// (`(1 + u)^2 - 1` per product, u = 2^-8), the f32 sum of `in_dim + 2` terms, and inputs below the smallest
/// normal f32 that the instruction flushes to zero (at most `2^-126 * |other factor|` each, bounded by
/// `in_dim * 2^-126 * 4` for factors of magnitude <= 2; callers with larger factors add their own).
pub fn bf16_dense_bound(in_dim: usize, magnitude: f64) -> f64 {
    let u = BF16_UNIT_ROUNDOFF;
    let rounding = (1.0 + u) * (1.0 + u) - 1.0;
    let flush = in_dim as f64 * 4.0 * f64::from(f32::MIN_POSITIVE);
    (rounding + 2.0 * gamma_f32(in_dim + 2) * (1.0 + rounding)) * magnitude + flush
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn bf16_rounding_is_to_nearest_even() {
        assert_eq!(round_bf16(1.0), 1.0);
        // 1 + 2^-8 is half-way between 1 and 1 + 2^-7: ties go to the even significand (1.0).
        assert_eq!(round_bf16(1.0 + 1.0 / 256.0), 1.0);
        // 1 + 3 * 2^-8 is half-way between 1 + 2^-7 and 1 + 2^-6: even is 1 + 2^-6.
        assert_eq!(round_bf16(1.0 + 3.0 / 256.0), 1.0 + 1.0 / 64.0);
        assert_eq!(round_bf16(-2.5), -2.5);
        assert!(round_bf16(f32::NAN).is_nan());
        assert_eq!(round_bf16(f32::INFINITY), f32::INFINITY);
        let mut rng = Rng::new(4);
        for _ in 0..10_000 {
            let x = (rng.normal() * 10.0) as f32;
            let r = round_bf16(x);
            assert!(((r - x) / x).abs() as f64 <= BF16_UNIT_ROUNDOFF, "{x} -> {r}");
        }
    }

    /// The vector packing of a row (32 values per instruction, then 16) is the scalar rounding of every pair,
    /// at every width: the 16-value step, the 32-value steps and the scalar leftovers.
    #[test]
    fn packed_pairs_are_the_scalar_rounding_at_every_width() {
        let mut rng = Rng::new(8);
        for width in 0..=100usize {
            let row: Vec<f32> = (0..width).map(|_| (rng.normal() * 3.0) as f32).collect();
            let mut packed = vec![0u32; width.div_ceil(2)];
            pack_pairs(&row, &mut packed);
            let scalar: Vec<u32> =
                (0..width.div_ceil(2)).map(|q| pair(row[2 * q], row.get(2 * q + 1).copied().unwrap_or(0.0))).collect();
            assert_eq!(packed, scalar, "width {width}");
        }
    }

    #[test]
    fn a_concatenated_input_gives_the_layer_on_the_built_concatenation_bit_for_bit() {
        if !is_available() {
            eprintln!("SKIPPED: this CPU has no AVX-512 BF16 (the bf16 layer is never selected here)");
            return;
        }
        let mut rng = Rng::new(5);
        let (rows, widths, out_dim) = (37, [64usize, 34, 7], 45);
        let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
        let segs: Vec<Vec<f32>> = widths.iter().map(|&w| v(rows * w)).collect();
        let k: usize = widths.iter().sum();
        let (w, g) = (v(k * out_dim), v(4 * out_dim));
        let mut joined = Vec::with_capacity(rows * k);
        for r in 0..rows {
            for (seg, &wd) in segs.iter().zip(&widths) {
                joined.extend_from_slice(&seg[r * wd..][..wd]);
            }
        }
        let s = DenseShape { rows, in_dim: k, out_dim, rows_per_group: 10, accumulate: false, relu: true };
        let mut want = vec![0.0; rows * out_dim];
        dense_bf16(&s, &joined, &w, &g, &mut want);
        let parts: Vec<(&[f32], usize)> = segs.iter().map(Vec::as_slice).zip(widths).collect();
        let mut got = vec![0.0; rows * out_dim];
        dense_bf16_packed(&s, &parts, &pack_weight(&w, k, out_dim), &g, &mut got);
        assert_eq!(got, want);
        assert!(want.iter().any(|&x| x > 0.0));
    }

    /// A layer whose last strip is 16 columns wide (48, 144) gives, bit for bit, the first columns of the same
    /// layer widened with zero weight columns to whole 32-column strips, which runs full tiles only: with and
    /// without the old output and the group term, and with rows that leave a partial block.
    #[test]
    fn a_half_strip_is_the_full_strip_arithmetic() {
        if !is_available() {
            eprintln!("SKIPPED: this CPU has no AVX-512 BF16 (the bf16 layer is never selected here)");
            return;
        }
        let mut rng = Rng::new(10);
        for &(rows, in_dim, out_dim, rpg, accumulate, relu) in &[
            (19usize, 48usize, 48usize, 8usize, false, true),
            (64, 272, 144, 16, true, true),
            (13, 30, 16, 13, true, false),
        ] {
            let wide = out_dim.next_multiple_of(32);
            let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
            let (x, w, g, init) =
                (v(rows * in_dim), v(in_dim * out_dim), v(rows.div_ceil(rpg) * out_dim), v(rows * out_dim));
            let widen = |m: &[f32], r: usize| -> Vec<f32> {
                let mut out = vec![0.0; r * wide];
                for (dst, src) in out.chunks_exact_mut(wide).zip(m.chunks_exact(out_dim)) {
                    dst[..out_dim].copy_from_slice(src);
                }
                out
            };
            let parts = [(&x[..], in_dim)];
            let s = DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu };
            let mut got = init.clone();
            dense_bf16_packed_on(Bf16Unit::Vector, &s, &parts, &pack_weight(&w, in_dim, out_dim), &g, &mut got);
            let s_wide = DenseShape { out_dim: wide, ..s };
            let (w_wide, g_wide) = (widen(&w, in_dim), widen(&g, rows.div_ceil(rpg)));
            let mut want = widen(&init, rows);
            let packed = pack_weight(&w_wide, in_dim, wide);
            dense_bf16_packed_on(Bf16Unit::Vector, &s_wide, &parts, &packed, &g_wide, &mut want);
            for (r, row) in want.chunks_exact(wide).enumerate() {
                assert_eq!(&got[r * out_dim..][..out_dim], &row[..out_dim], "{rows}x{in_dim}x{out_dim} row {r}");
            }
        }
    }

    #[test]
    fn simd_layer_matches_the_twin_and_stays_within_the_bound_of_the_f32_layer() {
        if !is_available() {
            eprintln!("SKIPPED: this CPU has no AVX-512 BF16 (the bf16 layer is never selected here)");
            return;
        }
        let mut rng = Rng::new(9);
        for &(rows, in_dim, out_dim, rpg, accumulate, relu) in &[
            (8, 2, 32, 8, false, false),
            (7, 3, 5, 7, false, true),
            (130, 70, 130, 16, true, false),
            (257, 64, 512, 256, false, true),
            (33, 511, 40, 11, true, true),
            (1, 1, 1, 1, true, true),
            // Whole AMX blocks, with and without the old output.
            (256, 64, 512, 256, false, true),
            (64, 96, 64, 16, true, true),
        ] {
            let s = DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu };
            let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
            let (x, w, g, init) =
                (v(rows * in_dim), v(in_dim * out_dim), v(rows.div_ceil(rpg) * out_dim), v(rows * out_dim));
            let mut got = init.clone();
            dense_bf16(&s, &x, &w, &g, &mut got);
            // The AMX tiles (where the CPU has them) within f32 summation of the vector unit's layer.
            let parts = [(&x[..], in_dim)];
            let mut tiles = init.clone();
            dense_bf16_packed_on(Bf16Unit::Tiles, &s, &parts, &pack_weight(&w, in_dim, out_dim), &g, &mut tiles);
            let mut twin = init.clone();
            dense_bf16_reference(&s, &x, &w, &g, &mut twin);
            let mut f32_layer = init.clone();
            crate::cpu::dense::dense(&s, &x, &w, &g, &mut f32_layer);
            let mut worst_use = 0.0f64;
            for r in 0..rows {
                for o in 0..out_dim {
                    let start =
                        if accumulate { init[r * out_dim + o].abs() } else { 0.0 } + g[(r / rpg) * out_dim + o].abs();
                    let mag = f64::from(start)
                        + (0..in_dim).map(|p| f64::from((x[r * in_dim + p] * w[p * out_dim + o]).abs())).sum::<f64>();
                    let i = r * out_dim + o;
                    // Twin and SIMD differ by f32 summation only (same rounded factors; ReLU is 1-Lipschitz).
                    let sum_only = 2.0 * gamma_f32(in_dim + 2) * mag * 1.01 + 1e-30;
                    assert!(f64::from((got[i] - twin[i]).abs()) <= sum_only, "{s:?} at {i}: {} vs {}", got[i], twin[i]);
                    let tiles_off = f64::from((tiles[i] - twin[i]).abs());
                    assert!(tiles_off <= sum_only, "{s:?} at {i}: tiles {} vs {}", tiles[i], twin[i]);
                    let bound = bf16_dense_bound(in_dim, mag);
                    let d = f64::from((got[i] - f32_layer[i]).abs());
                    assert!(d <= bound, "{s:?} at {i}: {} vs f32 {} (bound {bound})", got[i], f32_layer[i]);
                    worst_use = worst_use.max(d / bound);
                }
            }
            // The bound is not vacuous: bf16 rounding shows up at a visible fraction of it.
            if in_dim >= 64 {
                assert!(worst_use > 0.01, "{s:?}: worst error only {worst_use} of the bound");
            }
        }
    }
}
