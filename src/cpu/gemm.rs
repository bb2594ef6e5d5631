//! The fast CPU matrix kernel behind inference (`model::foldnet`) and training: one blocked multiply-accumulate with an AVX-512 and an AVX2 micro-kernel
//! picked at run time (the crate is built for baseline x86-64, and training is bound by these loops), and a
//! portable one elsewhere.
//!
//! Every output element is computed in the same order on every path: its starting value, then the products
//! added one by one in increasing `p`, each as a separate multiply and add (never a fused multiply-add), so all
//! paths give bit-identical results and [`dense`] gives exactly what `crate::cpu::dense::dense` gives.

use crate::cpu::dense::DenseShape;

/// What the kernel does with the product `A · B` for each output element.
#[derive(Clone, Copy)]
enum Epilogue<'a> {
    /// `c += A · B`.
    Accumulate,
    /// The dense layer: `c = act((accumulate ? c : 0) + group[r / rows_per_group] + A · B)`, in exactly
    /// `crate::cpu::dense::dense`'s order.
    Dense { group: &'a [f32], rows_per_group: usize, accumulate: bool, relu: bool },
}

/// Sizes and strides of `A` (`m x k`; element (i, p) at `a[i * sa + p * sp]`) and `B` (`k x n`, row stride
/// `ldb`).
#[derive(Clone, Copy)]
struct Operands<'a> {
    m: usize,
    n: usize,
    k: usize,
    a: &'a [f32],
    sa: usize,
    sp: usize,
    b: &'a [f32],
    ldb: usize,
}

/// A full-tile micro-kernel: `acc[i][j] += sum_p a[i * sa + p * sp] * b[p * ldb + j]` for an `MR x NR` tile,
/// the products added in increasing `p`. Callers guarantee `a` and `b` cover the tile.
type Micro<const MR: usize, const NR: usize> =
    unsafe fn(usize, &[f32], [usize; 2], &[f32], usize, &mut [[f32; NR]; MR]);

/// The portable tile loop (also used for partial tiles): `rn x cn` of the tile.
#[inline(always)]
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
fn tile_loop<const MR: usize, const NR: usize>(
    k: usize,
    a: &[f32],
    [sa, sp]: [usize; 2],
    b: &[f32],
    ldb: usize,
    acc: &mut [[f32; NR]; MR],
    rn: usize,
    cn: usize,
) {
    for p in 0..k {
        let w = &b[p * ldb..][..cn];
        for (i, acc_row) in acc.iter_mut().enumerate().take(rn) {
            let xv = a[i * sa + p * sp];
            for (s, &wv) in acc_row[..cn].iter_mut().zip(w) {
                *s += xv * wv;
            }
        }
    }
}

#[inline(always)]
fn body<const MR: usize, const NR: usize>(
    op: &Operands<'_>,
    c: &mut [f32],
    ldc: usize,
    epi: Epilogue<'_>,
    (micro, half): (Option<Micro<MR, NR>>, Option<Micro<MR, NR>>),
) {
    let Operands { m, n, k, a, sa, sp, b, ldb } = *op;
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
            // (With k = 0 the operands may be empty: nothing is read from them then.)
            let (a_t, b_t) = (a.get(r0 * sa..).unwrap_or(&[]), b.get(c0..).unwrap_or(&[]));
            match micro {
                // SAFETY: a full tile; `run` checked that A and B cover every tile, and the micro-kernel was
                // chosen for a CPU feature that is present.
                Some(f) if rn == MR && cn == NR && k > 0 => unsafe { f(k, a_t, [sa, sp], b_t, ldb, &mut acc) },
                // A strip of half the tile's width (a 48-wide layer's last 16 columns).
                _ if rn == MR && cn == NR / 2 && k > 0 && half.is_some() => {
                    let f = half.expect("checked");
                    unsafe { f(k, a_t, [sa, sp], b_t, ldb, &mut acc) }
                }
                _ => tile_loop(k, a_t, [sa, sp], b_t, ldb, &mut acc, rn, cn),
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
mod x86 {
    use std::arch::x86_64::*;

    /// 8 x 32 tile in 16 AVX-512 registers (`H` = 2), or its first 16 columns in 8 (`H` = 1, the rest of
    /// `acc` untouched). Separate multiply and add, as the portable loop.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn micro_avx512<const H: usize>(
        k: usize,
        a: &[f32],
        [sa, sp]: [usize; 2],
        b: &[f32],
        ldb: usize,
        acc: &mut [[f32; 32]; 8],
    ) {
        debug_assert!(a.len() > 7 * sa + (k - 1) * sp && b.len() >= (k - 1) * ldb + 16 * H);
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        // SAFETY (all pointer reads): the caller guarantees rows 0..8 of A hold k values and rows 0..k of B
        // hold 16 H values at these strides.
        unsafe {
            let mut c = [[_mm512_setzero_ps(); H]; 8];
            for (ci, row) in c.iter_mut().zip(acc.iter()) {
                for (h, v) in ci.iter_mut().enumerate() {
                    *v = _mm512_loadu_ps(row.as_ptr().add(16 * h));
                }
            }
            for p in 0..k {
                let w: [__m512; H] = std::array::from_fn(|h| _mm512_loadu_ps(pb.add(p * ldb + 16 * h)));
                for (i, ci) in c.iter_mut().enumerate() {
                    let x = _mm512_set1_ps(*pa.add(i * sa + p * sp));
                    for (v, &wh) in ci.iter_mut().zip(&w) {
                        *v = _mm512_add_ps(*v, _mm512_mul_ps(x, wh));
                    }
                }
            }
            for (ci, row) in c.iter().zip(acc.iter_mut()) {
                for (h, v) in ci.iter().enumerate() {
                    _mm512_storeu_ps(row.as_mut_ptr().add(16 * h), *v);
                }
            }
        }
    }

    /// 6 x 16 tile in 12 AVX registers. Separate multiply and add, as the portable loop.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn micro_avx2(
        k: usize,
        a: &[f32],
        [sa, sp]: [usize; 2],
        b: &[f32],
        ldb: usize,
        acc: &mut [[f32; 16]; 6],
    ) {
        debug_assert!(a.len() > 5 * sa + (k - 1) * sp && b.len() >= (k - 1) * ldb + 16);
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        // SAFETY (all pointer reads): the caller guarantees rows 0..6 of A hold k values and rows 0..k of B
        // hold 16 values at these strides.
        unsafe {
            let mut c = [[_mm256_setzero_ps(); 2]; 6];
            for i in 0..6 {
                c[i][0] = _mm256_loadu_ps(acc[i].as_ptr());
                c[i][1] = _mm256_loadu_ps(acc[i].as_ptr().add(8));
            }
            for p in 0..k {
                let b0 = _mm256_loadu_ps(pb.add(p * ldb));
                let b1 = _mm256_loadu_ps(pb.add(p * ldb + 8));
                for (i, ci) in c.iter_mut().enumerate() {
                    let x = _mm256_set1_ps(*pa.add(i * sa + p * sp));
                    ci[0] = _mm256_add_ps(ci[0], _mm256_mul_ps(x, b0));
                    ci[1] = _mm256_add_ps(ci[1], _mm256_mul_ps(x, b1));
                }
            }
            for i in 0..6 {
                _mm256_storeu_ps(acc[i].as_mut_ptr(), c[i][0]);
                _mm256_storeu_ps(acc[i].as_mut_ptr().add(8), c[i][1]);
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    pub(super) fn body_avx512(op: &super::Operands<'_>, c: &mut [f32], ldc: usize, epi: super::Epilogue<'_>) {
        super::body::<8, 32>(op, c, ldc, epi, (Some(micro_avx512::<2>), Some(micro_avx512::<1>)))
    }

    #[target_feature(enable = "avx2")]
    pub(super) fn body_avx2(op: &super::Operands<'_>, c: &mut [f32], ldc: usize, epi: super::Epilogue<'_>) {
        super::body::<6, 16>(op, c, ldc, epi, (Some(micro_avx2), None))
    }
}

/// The micro-kernels the multiply can run on; [`GemmPath::selected`] is the one every public function uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GemmPath {
    /// 8 x 32 tiles in AVX-512 registers (x86-64 with AVX-512F).
    Avx512,
    /// 6 x 16 tiles in AVX2 registers (x86-64 with AVX2).
    Avx2,
    /// The portable 4 x 64 tile loop.
    Portable,
}

impl GemmPath {
    /// Short name (`avx512`, `avx2`, `portable`).
    pub fn name(self) -> &'static str {
        match self {
            GemmPath::Avx512 => "avx512",
            GemmPath::Avx2 => "avx2",
            GemmPath::Portable => "portable",
        }
    }

    /// Whether this CPU can run the path.
    pub fn is_available(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            GemmPath::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(target_arch = "x86_64")]
            GemmPath::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            GemmPath::Portable => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The paths this CPU can run, fastest first.
    pub fn available() -> Vec<GemmPath> {
        [GemmPath::Avx512, GemmPath::Avx2, GemmPath::Portable].into_iter().filter(|p| p.is_available()).collect()
    }

    /// The path the crate uses on this CPU (the fastest available).
    pub fn selected() -> GemmPath {
        [GemmPath::Avx512, GemmPath::Avx2].into_iter().find(|p| p.is_available()).unwrap_or(GemmPath::Portable)
    }
}

fn run(op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    run_on(GemmPath::selected(), op, c, ldc, epi)
}

/// The multiply on `path`, which the caller checked is available.
fn run_on(path: GemmPath, op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    if op.m == 0 || op.n == 0 {
        return;
    }
    assert!(op.k == 0 || op.a.len() > (op.m - 1) * op.sa + (op.k - 1) * op.sp, "gemm: A too short");
    assert!(op.k == 0 || op.b.len() >= (op.k - 1) * op.ldb + op.n, "gemm: B too short");
    assert!(c.len() >= (op.m - 1) * ldc + op.n, "gemm: C too short");
    assert!(path.is_available(), "gemm: path {} is not available on this CPU", path.name());
    if matches!(epi, Epilogue::Accumulate) && op.k > KC {
        // Each block adds to C where the previous one left off: the same additions in the same order.
        for k0 in (0..op.k).step_by(KC) {
            let block = Operands { k: KC.min(op.k - k0), a: &op.a[k0 * op.sp..], b: &op.b[k0 * op.ldb..], ..*op };
            body_on(path, &block, c, ldc, epi);
        }
    } else {
        body_on(path, op, c, ldc, epi);
    }
}

/// Depth of a k-block of an accumulating multiply. A long reduction (a weight gradient sums over every row of
/// a batch) is cut into blocks so that the column strip of B the row blocks stream past stays in cache; without
/// them the weight gradient ran at a quarter of the input gradient's rate. Every output element is loaded from C
/// at the start of a block and stored at its end, so blocking changes no bit.
const KC: usize = 512;

/// The multiply's tiles on `path`, over the whole `k` of `op`.
fn body_on(path: GemmPath, op: &Operands<'_>, c: &mut [f32], ldc: usize, epi: Epilogue<'_>) {
    match path {
        // SAFETY: the CPU supports AVX-512F (checked just above).
        #[cfg(target_arch = "x86_64")]
        GemmPath::Avx512 => unsafe { x86::body_avx512(op, c, ldc, epi) },
        // SAFETY: the CPU supports AVX2 (checked just above).
        #[cfg(target_arch = "x86_64")]
        GemmPath::Avx2 => unsafe { x86::body_avx2(op, c, ldc, epi) },
        _ => body::<4, 64>(op, c, ldc, epi, (None, None)),
    }
}

/// `c[i * ldc + j] += sum_p a[i * lda + p] * b[p * ldb + j]` for `i < m`, `j < n`, `p < k`.
///
/// Panics when a slice is too short for the sizes and strides (an internal invariant of the callers).
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
pub fn gemm_acc(m: usize, n: usize, k: usize, a: &[f32], lda: usize, b: &[f32], ldb: usize, c: &mut [f32], ldc: usize) {
    run(&Operands { m, n, k, a, sa: lda, sp: 1, b, ldb }, c, ldc, Epilogue::Accumulate);
}

/// [`gemm_acc`] with `A` stored transposed: `c[i * ldc + j] += sum_p a[p * lda + i] * b[p * ldb + j]`.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
pub fn gemm_acc_at(
    m: usize,
    n: usize,
    k: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    ldb: usize,
    c: &mut [f32],
    ldc: usize,
) {
    run(&Operands { m, n, k, a, sa: 1, sp: lda, b, ldb }, c, ldc, Epilogue::Accumulate);
}

/// Exactly `crate::cpu::dense::dense` (same arguments, bit-identical results), vectorised for the CPU at hand.
pub fn dense(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    dense_on(GemmPath::selected(), shape, x, w_t, group_term, out)
}

/// [`dense`] on a given micro-kernel (benchmarks time each path); panics when `path` is not available on
/// this CPU ([`GemmPath::is_available`]).
pub fn dense_on(path: GemmPath, shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    let DenseShape { rows, in_dim, out_dim, rows_per_group, accumulate, relu } = *shape;
    let op = Operands { m: rows, n: out_dim, k: in_dim, a: x, sa: in_dim, sp: 1, b: w_t, ldb: out_dim };
    let epi = Epilogue::Dense { group: group_term, rows_per_group: rows_per_group.max(1), accumulate, relu };
    run_on(path, &op, out, out_dim, epi);
}

/// The arithmetic of the CPU dense layers, at inference and in training: f32 (bit-identical to the twin) or
/// bf16 inputs with f32 sums ([`crate::cpu::gemm_bf16`]), for layers at least [`BF16_MIN_IN_DIM`] wide.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// f32 throughout: [`dense`].
    #[default]
    F32,
    /// bf16 inputs and weights, f32 sums: [`crate::cpu::gemm_bf16::dense_bf16`].
    Bf16,
    /// Inference only: int8 inputs (a scale per row) and weights (a scale per column), exact integer sums
    /// ([`crate::cpu::gemm_int8::dense_int8`]); a layer the int8 layer does not take runs in bf16 where the CPU
    /// has it, else in f32.
    Int8,
}

/// What a CPU offers the encoders' reduced-precision layers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CpuUnits {
    /// AVX-512 BF16 ([`Precision::Bf16`]).
    pub bf16: bool,
    /// AVX-512 VNNI ([`Precision::Int8`]).
    pub int8: bool,
    /// AMX tiles for bf16 ([`crate::cpu::gemm_amx`]).
    pub amx: bool,
}

impl CpuUnits {
    /// This CPU's.
    pub fn of_this_cpu() -> CpuUnits {
        CpuUnits {
            bf16: Precision::Bf16.is_available(),
            int8: Precision::Int8.is_available(),
            amx: Precision::Bf16.is_available() && crate::cpu::gemm_amx::is_available(),
        }
    }
}

/// Environment variable that picks the CPU backend's encoder precision: `f32`, `bf16`, `int8` or `auto`.
pub const CPU_PRECISION_ENV: &str = "DPR_GPU_CPU_PRECISION";

/// Narrowest input the bf16 layer takes: the first layers (3-4 wide PPF / PC inputs) cost nothing and keep
/// their inputs exact.
pub const BF16_MIN_IN_DIM: usize = 32;

impl Precision {
    /// `f32`, `bf16` or `int8`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
            Precision::Int8 => "int8",
        }
    }

    /// The precision the trainer takes for this one: int8 is for inference, so training runs bf16 there (where
    /// the CPU has it, else f32).
    pub fn for_training(self) -> Precision {
        match self {
            Precision::Int8 if Precision::Bf16.is_available() => Precision::Bf16,
            Precision::Int8 => Precision::F32,
            p => p,
        }
    }

    /// Whether this CPU computes at this precision.
    pub fn is_available(self) -> bool {
        match self {
            Precision::F32 => true,
            Precision::Bf16 => crate::cpu::gemm_bf16::is_available(),
            Precision::Int8 => crate::cpu::gemm_int8::is_available(),
        }
    }
}

/// The arithmetic of each encoder on the CPU backend: PPF-FoldNet's codewords are matched, PC-FoldNet's feed
/// RelativeNet's pose. A precision per network, because they respond differently to int8: int8 on PPF-FoldNet
/// moves which correspondences match, on PC-FoldNet it changed no verdict measured (docs/experiments/cpu-int8.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderPrecision {
    /// PPF-FoldNet's wide layers.
    pub ppf: Precision,
    /// PC-FoldNet's wide layers.
    pub pc: Precision,
}

impl From<Precision> for EncoderPrecision {
    fn from(p: Precision) -> EncoderPrecision {
        EncoderPrecision { ppf: p, pc: p }
    }
}

impl EncoderPrecision {
    /// The value [`CPU_PRECISION_ENV`] takes for this choice: one name (`bf16`) when both encoders share it,
    /// else `PPF,PC` (`bf16,int8`).
    pub fn name(self) -> String {
        if self.ppf == self.pc { self.ppf.name().into() } else { format!("{},{}", self.ppf.name(), self.pc.name()) }
    }

    /// Whether either encoder runs at `p`.
    pub fn uses(self, p: Precision) -> bool {
        self.ppf == p || self.pc == p
    }

    /// Whether this CPU computes both encoders' precisions.
    pub fn is_available(self) -> bool {
        self.ppf.is_available() && self.pc.is_available()
    }

    /// The trainer's precision for this choice: PPF-FoldNet's, int8 read as bf16 ([`Precision::for_training`]).
    pub fn for_training(self) -> Precision {
        self.ppf.for_training()
    }

    /// The precisions [`CPU_PRECISION_ENV`] asks for on this CPU, and why: see [`EncoderPrecision::choose`].
    pub fn from_env() -> crate::error::Result<(EncoderPrecision, String)> {
        let value = std::env::var(CPU_PRECISION_ENV).ok();
        let (precision, why) = EncoderPrecision::choose(value.as_deref(), CpuUnits::of_this_cpu())?;
        Ok(if precision.uses(Precision::Bf16) {
            (precision, format!("{why}; {}", crate::cpu::gemm_bf16::Bf16Unit::Tiles.describe()))
        } else {
            (precision, why)
        })
    }

    /// The precisions a value of [`CPU_PRECISION_ENV`] asks for on a CPU with `units`, and why.
    /// Unset, empty or `auto`: the fastest the CPU has, where each registers the same pairs as bf16 on the
    /// shipped weights (docs/speed.md): bf16 on AMX tiles where the CPU has them; else, where it has both AVX-512
    /// BF16 and VNNI, PPF-FoldNet in bf16 and PC-FoldNet in int8 (int8 on PPF-FoldNet too is 1.7x bf16's speed
    /// but opt-in: it trusts a wrong pose on the tuning set rm961 that bf16 does not,
    /// docs/experiments/cpu-int8.md); else bf16; else int8; else f32.
    /// `f32`, `bf16` or `int8`: that for both encoders (an error where the CPU lacks it); `PPF,PC` (`bf16,int8`):
    /// one for each; f32 alone is bit-identical on every CPU.
    pub fn choose(value: Option<&str>, units: CpuUnits) -> crate::error::Result<(EncoderPrecision, String)> {
        let one = |name: &str| -> crate::error::Result<Precision> {
            let refused = |what: &str| {
                Err(crate::error::Error::invalid(format!(
                    "{CPU_PRECISION_ENV}={}: {name}, but this CPU has no {what}",
                    value.unwrap_or_default().trim()
                )))
            };
            match name.trim() {
                "f32" => Ok(Precision::F32),
                "bf16" if units.bf16 => Ok(Precision::Bf16),
                "bf16" => refused("AVX-512 BF16"),
                "int8" if units.int8 => Ok(Precision::Int8),
                "int8" => refused("AVX-512 VNNI"),
                other => Err(crate::error::Error::invalid(format!(
                    "{CPU_PRECISION_ENV}='{other}': expected f32, bf16, int8, auto or PPF,PC (e.g. bf16,int8)"
                ))),
            }
        };
        let off = format!("({CPU_PRECISION_ENV}=f32 for f32)");
        match value.map(str::trim) {
            None | Some("" | "auto") => Ok(if units.bf16 && units.amx {
                (Precision::Bf16.into(), format!("bf16 encoders: this CPU has AMX tiles {off}"))
            } else if units.bf16 && units.int8 {
                (
                    EncoderPrecision { ppf: Precision::Bf16, pc: Precision::Int8 },
                    format!(
                        "bf16,int8 encoders (PPF-FoldNet bf16, PC-FoldNet int8): this CPU has AVX-512 BF16 and VNNI \
                         ({CPU_PRECISION_ENV}=bf16 for bf16 alone, f32 for f32)"
                    ),
                )
            } else if units.bf16 {
                (Precision::Bf16.into(), format!("bf16 encoders: this CPU has AVX-512 BF16 {off}"))
            } else if units.int8 {
                (Precision::Int8.into(), format!("int8 encoders: this CPU has AVX-512 VNNI, no BF16 {off}"))
            } else {
                (Precision::F32.into(), "f32 encoders: this CPU has no AVX-512 BF16".into())
            }),
            Some(v) => {
                let precision = match v.split_once(',') {
                    Some((ppf, pc)) => EncoderPrecision { ppf: one(ppf)?, pc: one(pc)? },
                    None => one(v)?.into(),
                };
                Ok((precision, format!("{} encoders: {CPU_PRECISION_ENV}={v}", precision.name())))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn auto_takes_the_fastest_unit_and_an_explicit_choice_is_kept_or_refused() {
        let units = |bf16, int8, amx| CpuUnits { bf16, int8, amx };
        let choose = |v, u| EncoderPrecision::choose(v, u).map(|c| c.0);
        let auto = |u| choose(None, u).unwrap();
        let both = EncoderPrecision::from;
        let mixed = EncoderPrecision { ppf: Precision::Bf16, pc: Precision::Int8 };
        assert_eq!(auto(units(true, true, true)), both(Precision::Bf16), "AMX tiles");
        assert_eq!(auto(units(true, true, false)), mixed, "int8 only on PC-FoldNet where bf16 runs");
        assert_eq!(auto(units(false, true, false)), both(Precision::Int8), "VNNI without BF16");
        assert_eq!(auto(units(true, false, false)), both(Precision::Bf16));
        assert_eq!(auto(units(false, false, false)), both(Precision::F32));
        assert_eq!(choose(Some(" auto "), units(false, true, false)).unwrap(), both(Precision::Int8));
        for u in [units(true, true, true), units(false, false, false)] {
            assert_eq!(choose(Some("f32"), u).unwrap(), both(Precision::F32));
        }
        assert_eq!(choose(Some("int8"), units(true, true, true)).unwrap(), both(Precision::Int8));
        assert_eq!(choose(Some("bf16"), units(true, true, false)).unwrap(), both(Precision::Bf16));
        assert_eq!(choose(Some("bf16, int8"), units(true, true, true)).unwrap(), mixed);
        assert_eq!(choose(Some("f32,bf16"), units(true, false, false)).unwrap().pc, Precision::Bf16);
        assert_eq!((mixed.name(), both(Precision::Int8).name()), ("bf16,int8".into(), "int8".into()));
        let refused = choose(Some("int8"), units(true, false, true)).unwrap_err().to_string();
        assert!(refused.contains("VNNI"), "{refused}");
        let refused = choose(Some("bf16,int8"), units(true, false, false)).unwrap_err().to_string();
        assert!(refused.contains("VNNI") && refused.contains("bf16,int8"), "{refused}");
        assert!(choose(Some("bf16"), units(false, false, false)).is_err());
        assert!(choose(Some("fp8"), units(true, true, true)).unwrap_err().to_string().contains("fp8"));
        assert!(choose(Some("bf16,int8,f32"), units(true, true, true)).is_err());
        // The trainer: PPF-FoldNet's precision, int8 read as bf16 where the CPU has it.
        assert_eq!(mixed.for_training(), Precision::Bf16);
    }

    #[test]
    fn every_path_matches_the_portable_loop_bit_for_bit() {
        let mut rng = Rng::new(1);
        // The last case is cut into k-blocks (an unblocked body is the reference).
        for &(m, n, k) in &[
            (1, 1, 1),
            (8, 32, 5),
            (13, 70, 33),
            (17, 47, 64),
            (6, 16, 0),
            (40, 100, 9),
            (19, 48, 4),
            (9, 40, 2 * KC + 77),
        ] {
            let mut v = |len: usize| (0..len).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
            let (lda, ldb, ldc) = (k + 3, n + 5, n + 2);
            let a = v(m * lda);
            let b = v(k.max(1) * ldb);
            let c0 = v(m * ldc);
            let op = Operands { m, n, k, a: &a, sa: lda, sp: 1, b: &b, ldb };
            let mut want = c0.clone();
            body::<4, 64>(&op, &mut want, ldc, Epilogue::Accumulate, (None, None));
            let mut got = c0.clone();
            run(&op, &mut got, ldc, Epilogue::Accumulate);
            assert_eq!(got, want, "{m}x{n}x{k}");
            // The same product with A stored transposed.
            let mut a_t = vec![0.0; k.max(1) * m];
            for i in 0..m {
                for p in 0..k {
                    a_t[p * m + i] = a[i * lda + p];
                }
            }
            let mut got_t = c0.clone();
            gemm_acc_at(m, n, k, &a_t, m, &b, ldb, &mut got_t, ldc);
            assert_eq!(got_t, want, "transposed {m}x{n}x{k}");
            // Against a plain f64 product too.
            for i in 0..m {
                for j in 0..n {
                    let exact: f64 = c0[i * ldc + j] as f64
                        + (0..k).map(|p| a[i * lda + p] as f64 * b[p * ldb + j] as f64).sum::<f64>();
                    assert!((got[i * ldc + j] as f64 - exact).abs() < 1e-4 * (1.0 + exact.abs()));
                }
            }
        }
    }

    /// Each SIMD kernel on its own, whatever `run` would pick: on a machine with AVX-512 `run` never reaches
    /// the AVX2 kernel, so it is called directly here (when the CPU has AVX2) and compared bit for bit with the
    /// portable loop, for both epilogues and for shapes that leave partial tiles.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn each_simd_kernel_matches_the_portable_loop_directly() {
        let mut rng = Rng::new(3);
        type Kernel = fn(&Operands<'_>, &mut [f32], usize, Epilogue<'_>);
        let kernels: [(&str, bool, Kernel); 2] = [
            ("avx2", std::arch::is_x86_feature_detected!("avx2"), |op, c, ldc, epi| {
                // SAFETY: only called when the CPU has AVX2 (checked by the caller).
                unsafe { x86::body_avx2(op, c, ldc, epi) }
            }),
            ("avx512", std::arch::is_x86_feature_detected!("avx512f"), |op, c, ldc, epi| {
                // SAFETY: only called when the CPU has AVX-512F (checked by the caller).
                unsafe { x86::body_avx512(op, c, ldc, epi) }
            }),
        ];
        let mut ran = 0;
        for (name, available, kernel) in kernels {
            if !available {
                eprintln!("SKIPPED: the CPU has no {name}");
                continue;
            }
            ran += 1;
            for &(m, n, k) in &[(1, 1, 1), (6, 16, 7), (7, 17, 33), (19, 70, 64), (40, 100, 9), (17, 48, 4), (5, 3, 0)]
            {
                let mut v = |len: usize| (0..len).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
                let (lda, ldb, ldc) = (k + 1, n + 3, n + 2);
                let (a, b, c0, g) = (v(m * lda), v(k.max(1) * ldb), v(m * ldc), v(m * n));
                let op = Operands { m, n, k, a: &a, sa: lda, sp: 1, b: &b, ldb };
                let dense_epi = Epilogue::Dense { group: &g, rows_per_group: 1, accumulate: true, relu: true };
                for epi in [Epilogue::Accumulate, dense_epi] {
                    let mut want = c0.clone();
                    body::<4, 64>(&op, &mut want, ldc, epi, (None, None));
                    let mut got = c0.clone();
                    kernel(&op, &mut got, ldc, epi);
                    assert_eq!(got, want, "{name} {m}x{n}x{k}");
                }
            }
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            assert!(ran >= 1);
        }
    }

    #[test]
    fn dense_equals_the_cpu_twin_bit_for_bit() {
        let mut rng = Rng::new(2);
        for &(rows, in_dim, out_dim, rpg, accumulate, relu) in &[
            (7, 3, 5, 7, false, true),
            (130, 70, 130, 16, true, false),
            (257, 64, 512, 256, false, true),
            (1, 1, 1, 1, true, true),
        ] {
            let s = DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu };
            let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
            let (x, w, g, init) =
                (v(rows * in_dim), v(in_dim * out_dim), v(rows.div_ceil(rpg) * out_dim), v(rows * out_dim));
            let mut fast = init.clone();
            dense(&s, &x, &w, &g, &mut fast);
            let mut want = init.clone();
            crate::cpu::dense::dense(&s, &x, &w, &g, &mut want);
            assert_eq!(fast, want, "{s:?}");
            // Every path the benchmarks time gives the same bits.
            for path in GemmPath::available() {
                let mut on_path = init.clone();
                dense_on(path, &s, &x, &w, &g, &mut on_path);
                assert_eq!(on_path, want, "{} {s:?}", path.name());
            }
            assert_eq!(GemmPath::available()[0], GemmPath::selected());
        }
    }
}
