//! The matrix kernels of training: one register-blocked multiply-accumulate, compiled three times (baseline,
//! AVX2, AVX-512) and picked at run time, because the crate is built for baseline x86-64 and training is
//! bound by these loops.
//!
//! Every output element is computed in the same order on every path: the starting value, then the products
//! added one by one in increasing `p`, each as a separate multiply and add (Rust never contracts to FMA), so the
//! three paths give bit-identical results and [`dense`] gives exactly what `crate::cpu::dense::dense` gives.

use crate::cpu::dense::DenseShape;

/// Rows of the output computed together.
const MR: usize = 4;
/// Output columns computed together (two AVX-512 or four AVX2 registers per row).
const NR: usize = 32;

/// What the kernel does with the product `A · B` for each output element.
#[derive(Clone, Copy)]
enum Epilogue<'a> {
    /// `c += A · B`.
    Accumulate,
    /// The dense layer: `c = act((accumulate ? c : 0) + group[r / rows_per_group] + A · B)`, in exactly
    /// `crate::cpu::dense::dense`'s order.
    Dense { group: &'a [f32], rows_per_group: usize, accumulate: bool, relu: bool },
}

/// Sizes and strides of `A` (`m x k`, row stride `lda`) and `B` (`k x n`, row stride `ldb`).
#[derive(Clone, Copy)]
struct Operands<'a> {
    m: usize,
    n: usize,
    k: usize,
    a: &'a [f32],
    lda: usize,
    b: &'a [f32],
    ldb: usize,
}

#[inline(always)]
fn body(op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    let Operands { m, n, k, a, lda, b, ldb } = *op;
    // Column strips outermost so a strip of B (k x NR) stays in cache while every row block streams past it.
    for c0 in (0..n).step_by(NR) {
        let cn = NR.min(n - c0);
        for r0 in (0..m).step_by(MR) {
            let rn = MR.min(m - r0);
            let mut acc = [[0f32; NR]; MR];
            for (i, acc_row) in acc.iter_mut().enumerate().take(rn) {
                let r = r0 + i;
                match epi {
                    Epilogue::Accumulate => acc_row[..cn].copy_from_slice(&c[r * ldc + c0..][..cn]),
                    Epilogue::Dense { group, rows_per_group, accumulate, .. } => {
                        if accumulate {
                            acc_row[..cn].copy_from_slice(&c[r * ldc + c0..][..cn]);
                        }
                        if !group.is_empty() {
                            let g = &group[(r / rows_per_group) * n + c0..][..cn];
                            for (x, y) in acc_row[..cn].iter_mut().zip(g) {
                                *x += y;
                            }
                        }
                    }
                }
            }
            if cn == NR && rn == MR {
                // The hot path: fixed trip counts, so the accumulators stay in registers.
                for p in 0..k {
                    let w: &[f32; NR] = b[p * ldb + c0..][..NR].try_into().expect("NR columns");
                    for (i, acc_row) in acc.iter_mut().enumerate() {
                        let xv = a[(r0 + i) * lda + p];
                        for (s, &wv) in acc_row.iter_mut().zip(w) {
                            *s += xv * wv;
                        }
                    }
                }
            } else {
                for p in 0..k {
                    let w = &b[p * ldb + c0..][..cn];
                    for (i, acc_row) in acc.iter_mut().enumerate().take(rn) {
                        let xv = a[(r0 + i) * lda + p];
                        for (s, &wv) in acc_row[..cn].iter_mut().zip(w) {
                            *s += xv * wv;
                        }
                    }
                }
            }
            let relu = matches!(epi, Epilogue::Dense { relu: true, .. });
            for (i, acc_row) in acc.iter().enumerate().take(rn) {
                let dst = &mut c[(r0 + i) * ldc + c0..][..cn];
                for (d, &s) in dst.iter_mut().zip(&acc_row[..cn]) {
                    *d = if relu { s.max(0.0) } else { s };
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn body_avx512(op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    body(op, c, ldc, epi)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn body_avx2(op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    body(op, c, ldc, epi)
}

fn run(op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    if op.m == 0 || op.n == 0 {
        return;
    }
    assert!(op.a.len() >= (op.m - 1) * op.lda + op.k, "gemm: A too short");
    assert!(op.k == 0 || op.b.len() >= (op.k - 1) * op.ldb + op.n, "gemm: B too short");
    assert!(c.len() >= (op.m - 1) * ldc + op.n, "gemm: C too short");
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above).
            return unsafe { body_avx512(op, c, ldc, epi) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { body_avx2(op, c, ldc, epi) };
        }
    }
    body(op, c, ldc, epi)
}

/// `c[i * ldc + j] += sum_p a[i * lda + p] * b[p * ldb + j]` for `i < m`, `j < n`, `p < k`.
///
/// Panics when a slice is too short for the sizes and strides (an internal invariant of the callers).
#[allow(clippy::too_many_arguments)]
pub fn gemm_acc(m: usize, n: usize, k: usize, a: &[f32], lda: usize, b: &[f32], ldb: usize, c: &mut [f32], ldc: usize) {
    run(&Operands { m, n, k, a, lda, b, ldb }, c, ldc, Epilogue::Accumulate);
}

/// Exactly `crate::cpu::dense::dense` (same arguments, bit-identical results), vectorised for the CPU at hand.
pub fn dense(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    let DenseShape { rows, in_dim, out_dim, rows_per_group, accumulate, relu } = *shape;
    let op = Operands { m: rows, n: out_dim, k: in_dim, a: x, lda: in_dim, b: w_t, ldb: out_dim };
    let epi = Epilogue::Dense { group: group_term, rows_per_group: rows_per_group.max(1), accumulate, relu };
    run(&op, out, out_dim, epi);
}
