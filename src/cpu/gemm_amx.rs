//! The bf16 multiply on Intel AMX tiles (Advanced Matrix Extensions, Sapphire Rapids and later): one
//! `tdpbf16ps` adds a 16 x 32 bf16 tile times a 32 x 16 bf16 tile into a 16 x 16 f32 tile, about eight
//! times the AVX-512 BF16 rate per core. The operands are the bf16 pairs of [`crate::cpu::gemm_bf16`] as they
//! are packed for the vector kernel: a row of an A tile is 16 words (32 values along k), a row of a B tile 16
//! words of pairs along k, so both kernels read the same packing.
//!
//! Stable Rust has no AMX intrinsics: the five instructions are written as inline assembly. Linux hands the
//! tile state to a process only when it asks (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`);
//! [`is_available`] asks once and says no on any other system or when refused.

/// Whether this CPU and OS run the tile kernel: CPUID reports AMX-TILE and AMX-BF16, and Linux granted the
/// tile state to this process (asked once, on the first call).
pub fn is_available() -> bool {
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    {
        static GRANTED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *GRANTED.get_or_init(|| x86::cpu_has_amx_bf16() && x86::request_tile_state())
    }
    #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
    {
        false
    }
}

/// Rows and columns of the block one pass of the kernel computes (2 x 2 tiles of 16 x 16).
pub const BLOCK: usize = 32;
/// Words (bf16 pairs) along k per tile: 32 values.
pub const K_WORDS: usize = 16;

/// `c[i * ldc + j] += sum_q dot(a[i * lda + q], b[q * ldb + j])` over bf16 pairs, for `i < m`, `j < n`,
/// `q < kp`, where `m` and `n` are multiples of [`BLOCK`] and `kp` of [`K_WORDS`]. Panics when AMX is not
/// available ([`is_available`]), a size is not such a multiple, or a slice is too short.
pub fn gemm_acc_tiles(
    (m, n, kp): (usize, usize, usize),
    a: &[u32],
    lda: usize,
    b: &[u32],
    ldb: usize,
    c: &mut [f32],
    ldc: usize,
) {
    assert!(is_available(), "gemm_acc_tiles: this CPU or OS does not run AMX");
    assert!(m % BLOCK == 0 && n % BLOCK == 0 && kp % K_WORDS == 0, "gemm_acc_tiles: {m} x {n} x {kp}");
    if m == 0 || n == 0 {
        return;
    }
    assert!(lda >= kp && ldb >= n && ldc >= n, "gemm_acc_tiles: strides");
    assert!(a.len() >= (m - 1) * lda + kp && c.len() >= (m - 1) * ldc + n, "gemm_acc_tiles: A or C too short");
    assert!(kp == 0 || b.len() >= (kp - 1) * ldb + n, "gemm_acc_tiles: B too short");
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    // SAFETY: AMX is available and granted (asserted); every tile read or written lies inside the slices
    // (asserted sizes: whole blocks of rows and columns, at the given strides).
    unsafe {
        x86::gemm(m, n, kp, a.as_ptr(), lda, b.as_ptr(), ldb, c.as_mut_ptr(), ldc)
    }
}

#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
mod x86 {
    use super::{BLOCK, K_WORDS};
    use std::arch::asm;

    /// CPUID leaf 7: EDX bit 22 (AMX-BF16) and bit 24 (AMX-TILE).
    pub(super) fn cpu_has_amx_bf16() -> bool {
        let max_leaf = std::arch::x86_64::__cpuid(0).eax;
        if max_leaf < 7 {
            return false;
        }
        let edx = std::arch::x86_64::__cpuid_count(7, 0).edx;
        edx & (1 << 22) != 0 && edx & (1 << 24) != 0
    }

    /// Asks Linux for the tile data state: `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`.
    pub(super) fn request_tile_state() -> bool {
        const SYS_ARCH_PRCTL: i64 = 158;
        const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
        const XFEATURE_XTILEDATA: i64 = 18;
        let ret: i64;
        // SAFETY: a plain system call; it changes only this process's permission to use the tile state.
        unsafe {
            asm!(
                "syscall",
                inlateout("rax") SYS_ARCH_PRCTL => ret,
                in("rdi") ARCH_REQ_XCOMP_PERM,
                in("rsi") XFEATURE_XTILEDATA,
                lateout("rcx") _,
                lateout("r11") _,
                options(nostack),
            );
        }
        ret == 0
    }

    /// The tile configuration (palette 1): 8 tiles of 16 rows of 64 bytes.
    #[repr(C, align(64))]
    struct TileConfig {
        palette: u8,
        start_row: u8,
        reserved: [u8; 14],
        bytes_per_row: [u16; 16],
        rows: [u8; 16],
    }

    /// The kernel: C blocks of 2 x 2 tiles (tmm0-3) held across k, A tiles in tmm4-5, B tiles in tmm6-7.
    ///
    /// # Safety
    /// AMX is available and granted; `m`, `n` are multiples of [`BLOCK`] and `kp` of [`K_WORDS`]; `a`, `b` and
    /// `c` point at `m x kp`, `kp x n` and `m x n` matrices with row strides `lda`, `ldb`, `ldc` elements.
    #[expect(clippy::too_many_arguments, reason = "BLAS-style signature")]
    pub(super) unsafe fn gemm(
        m: usize,
        n: usize,
        kp: usize,
        a: *const u32,
        lda: usize,
        b: *const u32,
        ldb: usize,
        c: *mut f32,
        ldc: usize,
    ) {
        let mut config =
            TileConfig { palette: 1, start_row: 0, reserved: [0; 14], bytes_per_row: [0; 16], rows: [0; 16] };
        for t in 0..8 {
            config.bytes_per_row[t] = 64;
            config.rows[t] = 16;
        }
        let (sa, sb, sc) = (lda * 4, ldb * 4, ldc * 4);
        // SAFETY (every block below): the caller's guarantees; each tile is 16 rows of 16 elements inside the
        // matrices.
        unsafe {
            asm!("ldtilecfg [{}]", in(reg) &config, options(nostack));
            // Row strip by row strip: a strip of A stays in L1 while B streams from L2.
            for i0 in (0..m).step_by(BLOCK) {
                for j0 in (0..n).step_by(BLOCK) {
                    let c0 = c.add(i0 * ldc + j0);
                    let (c1, c2) = (c0.add(16), c0.add(16 * ldc));
                    let c3 = c2.add(16);
                    asm!(
                        "tileloadd tmm0, [{c0} + {sc} * 1]",
                        "tileloadd tmm1, [{c1} + {sc} * 1]",
                        "tileloadd tmm2, [{c2} + {sc} * 1]",
                        "tileloadd tmm3, [{c3} + {sc} * 1]",
                        c0 = in(reg) c0, c1 = in(reg) c1, c2 = in(reg) c2, c3 = in(reg) c3, sc = in(reg) sc,
                        options(nostack, readonly),
                    );
                    for q0 in (0..kp).step_by(K_WORDS) {
                        let a0 = a.add(i0 * lda + q0);
                        let a1 = a0.add(16 * lda);
                        let b0 = b.add(q0 * ldb + j0);
                        let b1 = b0.add(16);
                        asm!(
                            "tileloadd tmm4, [{a0} + {sa} * 1]",
                            "tileloadd tmm5, [{a1} + {sa} * 1]",
                            "tileloadd tmm6, [{b0} + {sb} * 1]",
                            "tileloadd tmm7, [{b1} + {sb} * 1]",
                            "tdpbf16ps tmm0, tmm4, tmm6",
                            "tdpbf16ps tmm1, tmm4, tmm7",
                            "tdpbf16ps tmm2, tmm5, tmm6",
                            "tdpbf16ps tmm3, tmm5, tmm7",
                            a0 = in(reg) a0, a1 = in(reg) a1, b0 = in(reg) b0, b1 = in(reg) b1,
                            sa = in(reg) sa, sb = in(reg) sb,
                            options(nostack, readonly),
                        );
                    }
                    asm!(
                        "tilestored [{c0} + {sc} * 1], tmm0",
                        "tilestored [{c1} + {sc} * 1], tmm1",
                        "tilestored [{c2} + {sc} * 1], tmm2",
                        "tilestored [{c3} + {sc} * 1], tmm3",
                        c0 = in(reg) c0, c1 = in(reg) c1, c2 = in(reg) c2, c3 = in(reg) c3, sc = in(reg) sc,
                        options(nostack),
                    );
                }
            }
            asm!("tilerelease", options(nostack, nomem));
        }
    }
}
