//! Host side of `shaders/dense_coop_f16.wgsl`: the dense layer on cooperative matrices (tensor cores), f16
//! inputs and f32 accumulation (the [`super::gemm::GemmVariant::CoopF16`] GEMM). Same parameters and bindings
//! as [`super::dense`], which records it ([`super::dense::record_with`]). Compiled only on devices created with
//! [`DenseCoopF16::FEATURES`], which [`crate::gpu::device::features::device_features`] requests only when the adapter reports a
//! suitable configuration ([`crate::gpu::device::features::coop_f16_support`]). CPU twin: [`crate::cpu::dense_coop_f16`].
//!
//! [`CoopTile`] lists the tile shapes `dpr-gpu bench --gemm-sweep` times. The default, [`CoopTile::DEFAULT`]
//! (64 x 64, four subgroups of 2 x 2 accumulators, single-buffered), is `shaders/dense_coop_f16.wgsl` (the
//! registry's pipeline, the kernel whose parity was checked on an H200). The others are generated from
//! `shaders/tiles/dense_coop_f16.wgsl` (four constants: `SG_M` x `SG_N` subgroups of 32 invocations, each
//! holding `FM` x `FN` accumulators of 16 x 16; k-tiles double-buffered) by [`CoopTile::source`], run only once
//! a sweep on the device has checked them against the twin and recorded one, and are compiled on first use
//! ([`super::registry::Kernels::coop_tile`]), after a check that the device's
//! `max_compute_workgroup_storage_size` holds the shape's workgroup memory ([`CoopTile::unavailable_reason`]).
//! Every shape sums each output's products in the same order (16-deep cooperative multiply-adds in increasing
//! k from a zero accumulator, then start value, group term and product sum in the twin's order); how a tensor
//! core adds within one 16-deep step is the hardware's, so the shapes are expected, not guaranteed, to give the
//! same bits. All are within the twin's bound ([`crate::cpu::dense_coop_f16::parity_tolerance`]).

use super::dense_params::DenseParams;
use crate::cpu::dense::DenseShape;
use crate::error::Result;
pub use crate::gpu::device::features::coop_f16::{MATRIX, SUBGROUP_SIZE, WORKGROUP_STORAGE_BYTES};
use crate::gpu::device::kernel::{BindKind, GpuKernel};

/// Invocations per workgroup (`WG_SIZE` in the shader) of the default tile: four subgroups of [`SUBGROUP_SIZE`].
pub const WG_SIZE: u32 = 128;
/// Output rows per workgroup tile (the default tile).
pub const TILE_M: usize = 64;
/// Output columns per workgroup tile (the default tile).
pub const TILE_N: usize = 64;
/// Depth of one k-tile (`TILE_K` in the shader): two 16-deep cooperative multiply-adds per k step.
pub const TILE_K: u32 = 32;

/// One tile shape of the cooperative-matrix kernel: `sg_m` x `sg_n` subgroups, each holding `fm` x `fn_`
/// accumulators of 16 x 16, so a workgroup computes a `16 sg_m fm` x `16 sg_n fn_` output tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CoopTile {
    /// Subgroups along the rows (`SG_M`).
    pub sg_m: u32,
    /// Subgroups along the columns (`SG_N`).
    pub sg_n: u32,
    /// 16-row accumulators per subgroup (`FM`).
    pub fm: u32,
    /// 16-column accumulators per subgroup (`FN`).
    pub fn_: u32,
}

impl CoopTile {
    /// The shape the shader is written with: 64 x 64 tiles, 2 x 2 subgroups of 2 x 2 accumulators.
    pub const DEFAULT: CoopTile = CoopTile { sg_m: 2, sg_n: 2, fm: 2, fn_: 2 };
    /// Every shape the sweep times, the default first: 128 x 64 and 64 x 128 (four subgroups of 4 x 2 or 2 x 4
    /// accumulators), 128 x 128 with four subgroups of 4 x 4 and with eight of 2 x 4.
    pub const ALL: [CoopTile; 5] = [
        CoopTile::DEFAULT,
        CoopTile { sg_m: 2, sg_n: 2, fm: 4, fn_: 2 },
        CoopTile { sg_m: 2, sg_n: 2, fm: 2, fn_: 4 },
        CoopTile { sg_m: 2, sg_n: 2, fm: 4, fn_: 4 },
        CoopTile { sg_m: 4, sg_n: 2, fm: 2, fn_: 4 },
    ];

    /// Output rows and columns of one workgroup's tile.
    pub fn tile(self) -> (usize, usize) {
        let m = MATRIX as usize;
        ((self.sg_m * self.fm) as usize * m, (self.sg_n * self.fn_) as usize * m)
    }

    /// Subgroups per workgroup.
    pub fn subgroups(self) -> u32 {
        self.sg_m * self.sg_n
    }

    /// Invocations per workgroup (`WG_SIZE` in the shader).
    pub fn workgroup_size(self) -> u32 {
        self.subgroups() * SUBGROUP_SIZE
    }

    /// Workgroup memory the shader declares: the default's [`WORKGROUP_STORAGE_BYTES`]; a generated shape's
    /// two f16 buffers of the `TILE_M x 32` and `32 x TILE_N` operand tiles and one 16 x 16 f32 accumulator
    /// per subgroup.
    pub fn workgroup_bytes(self) -> u32 {
        if self == CoopTile::DEFAULT {
            return WORKGROUP_STORAGE_BYTES;
        }
        let (m, n) = self.tile();
        2 * TILE_K * (m + n) as u32 * 2 + self.subgroups() * MATRIX * MATRIX * 4
    }

    /// Why a device with `limits` cannot run the shape (its workgroup memory is more than the device's
    /// `max_compute_workgroup_storage_size`), or `None` when it can.
    pub fn unavailable_reason(self, limits: &wgpu::Limits) -> Option<String> {
        let have = limits.max_compute_workgroup_storage_size;
        let need = self.workgroup_bytes();
        (have < need).then(|| {
            format!("dense_coop_f16 {self}: max_compute_workgroup_storage_size is {have} bytes; the tile needs {need}")
        })
    }

    /// The tile and its subgroups as `ROWSxCOLS/Nsg` (`128x128/8sg`), the name the sweep and the choice file
    /// use.
    pub fn name(self) -> String {
        let (m, n) = self.tile();
        format!("{m}x{n}/{}sg", self.subgroups())
    }

    /// The shape named `text` (`64x64/4sg`), if it is one of [`CoopTile::ALL`].
    pub fn parse(text: &str) -> Option<CoopTile> {
        CoopTile::ALL.into_iter().find(|t| t.name() == text.trim())
    }

    /// Position in [`CoopTile::ALL`].
    pub fn index(self) -> Option<usize> {
        CoopTile::ALL.iter().position(|&t| t == self)
    }

    /// The shader for this shape: `shaders/dense_coop_f16.wgsl` for the default, else
    /// `shaders/tiles/dense_coop_f16.wgsl` with its `SG_M`, `SG_N`, `FM` and `FN` lines replaced.
    pub fn source(self) -> Result<String> {
        if self == CoopTile::DEFAULT {
            return Ok(DenseCoopF16::SOURCE.to_string());
        }
        let w = TILES_WRITTEN;
        let constants =
            [("SG_M", w.sg_m, self.sg_m), ("SG_N", w.sg_n, self.sg_n), ("FM", w.fm, self.fm), ("FN", w.fn_, self.fn_)];
        crate::gpu::device::wgsl::with_constants("shaders/tiles/dense_coop_f16.wgsl", TILES_SOURCE, &constants)
    }
}

/// The source the generated shapes come from.
const TILES_SOURCE: &str = include_str!("../../../shaders/tiles/dense_coop_f16.wgsl");
/// The shape `shaders/tiles/dense_coop_f16.wgsl` is written with.
const TILES_WRITTEN: CoopTile = CoopTile { sg_m: 2, sg_n: 2, fm: 2, fn_: 2 };

impl std::fmt::Display for CoopTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

/// The `dense_coop_f16` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseCoopF16;

impl GpuKernel for DenseCoopF16 {
    const NAME: &'static str = "dense_coop_f16";
    const SOURCE: &'static str = include_str!("../../../shaders/dense_coop_f16.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_coop_f16::dense_coop_f16;
    const FEATURES: wgpu::Features = crate::gpu::device::features::coop_f16::FEATURES;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_have_distinct_names_that_parse_back_and_default_source_is_the_shader() {
        let names: std::collections::BTreeSet<String> = CoopTile::ALL.iter().map(|t| t.name()).collect();
        assert_eq!(names.len(), CoopTile::ALL.len());
        for t in CoopTile::ALL {
            assert_eq!(CoopTile::parse(&t.name()), Some(t));
            if t == CoopTile::DEFAULT {
                continue;
            }
            let src = t.source().unwrap();
            for (name, v) in [("SG_M", t.sg_m), ("SG_N", t.sg_n), ("FM", t.fm), ("FN", t.fn_)] {
                assert!(src.contains(&format!("const {name}: u32 = {v}u;")), "{t}: {name}");
            }
            // Each invocation loads whole groups of four of both operand tiles (the shader's const_assert).
            let (m, n) = t.tile();
            let per_step = 4 * t.workgroup_size() as usize;
            assert_eq!((m * TILE_K as usize % per_step, n * TILE_K as usize % per_step), (0, 0), "{t}");
            // Within what a typical tensor-core GPU gives a workgroup without opting in (48 KiB).
            assert!(t.workgroup_bytes() <= 48 * 1024, "{t}: {} bytes", t.workgroup_bytes());
        }
        assert_eq!(CoopTile::DEFAULT.source().unwrap(), DenseCoopF16::SOURCE);
        assert_eq!(CoopTile::DEFAULT.tile(), (TILE_M, TILE_N));
        assert_eq!(CoopTile::DEFAULT.workgroup_size(), WG_SIZE);
        assert_eq!(CoopTile::DEFAULT.workgroup_bytes(), WORKGROUP_STORAGE_BYTES);
        assert_eq!(CoopTile::parse("64x64"), None);
        assert_eq!(CoopTile::parse(" 128x128/8sg "), Some(CoopTile::ALL[4]));
    }

    #[test]
    fn a_tile_the_workgroup_memory_cannot_hold_is_refused_by_name() {
        let big = CoopTile::ALL[4];
        let limits =
            wgpu::Limits { max_compute_workgroup_storage_size: big.workgroup_bytes() - 1, ..wgpu::Limits::default() };
        let why = big.unavailable_reason(&limits).unwrap();
        assert!(why.contains("128x128/8sg") && why.contains("max_compute_workgroup_storage_size"), "{why}");
        let limits = wgpu::Limits { max_compute_workgroup_storage_size: big.workgroup_bytes(), ..limits };
        assert_eq!(big.unavailable_reason(&limits), None);
    }
}
