//! Host side of `shaders/dense_fast.wgsl`: the dense layer with 128 x 128 register-tiled, double-buffered
//! tiles (the [`super::gemm::GemmVariant::Fast`] GEMM). Same parameters and bindings as [`super::dense`], which
//! records it ([`super::dense::record_with`]). CPU twin: [`crate::cpu::dense_fast`].
//!
//! The tile shape is two constants of the shader (`BM`, `BN`: blocks of 4 x 4 outputs per invocation in each
//! direction); [`FastTile`] lists the shapes `dpr-gpu bench --gemm-sweep` times. The default,
//! [`FastTile::DEFAULT`], is the shader as written (the registry's pipeline); the others are generated from it by
//! [`FastTile::source`] and compiled on first use ([`super::registry::Kernels::fast_tile`]). Every shape adds
//! the same terms in the same order for each output, so all give the same bits; they differ only in speed.

use super::dense_params::DenseParams;
use crate::cpu::dense::DenseShape;
use crate::error::Result;
use crate::gpu::device::kernel::{BindKind, GpuKernel};

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Output rows per workgroup tile (the default tile).
pub const TILE_M: usize = 128;
/// Output columns per workgroup tile (the default tile).
pub const TILE_N: usize = 128;
/// Workgroup memory the shader declares at its largest (the default) tile: two buffers of 8 x 128 floats for
/// each operand.
pub const WORKGROUP_STORAGE_BYTES: u32 = 2 * 2 * 8 * 128 * 4;

/// One tile shape of the fast kernel: `bm` x `bn` blocks of 4 x 4 outputs per invocation, so a workgroup of
/// 16 x 16 invocations computes a `64 bm` x `64 bn` output tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FastTile {
    /// Blocks of 4 rows per invocation (1 or 2).
    pub bm: u32,
    /// Blocks of 4 columns per invocation (1 or 2).
    pub bn: u32,
}

impl FastTile {
    /// The shape the shader is written with: 128 x 128 tiles, 8 x 8 outputs per invocation.
    pub const DEFAULT: FastTile = FastTile { bm: 2, bn: 2 };
    /// Every shape the sweep times, the default first.
    pub const ALL: [FastTile; 4] =
        [FastTile::DEFAULT, FastTile { bm: 1, bn: 1 }, FastTile { bm: 1, bn: 2 }, FastTile { bm: 2, bn: 1 }];

    /// Output rows and columns of one workgroup's tile.
    pub fn tile(self) -> (usize, usize) {
        (64 * self.bm as usize, 64 * self.bn as usize)
    }

    /// Outputs one invocation computes (rows, columns).
    pub fn per_invocation(self) -> (u32, u32) {
        (4 * self.bm, 4 * self.bn)
    }

    /// The tile as `ROWSxCOLS` (`128x128`), the name the sweep and the choice file use.
    pub fn name(self) -> String {
        let (m, n) = self.tile();
        format!("{m}x{n}")
    }

    /// The shape named `text` (`128x128`), if it is one of [`FastTile::ALL`].
    pub fn parse(text: &str) -> Option<FastTile> {
        FastTile::ALL.into_iter().find(|t| t.name() == text.trim())
    }

    /// Position in [`FastTile::ALL`].
    pub fn index(self) -> Option<usize> {
        FastTile::ALL.iter().position(|&t| t == self)
    }

    /// The shader for this shape: `shaders/dense_fast.wgsl` with its `BM` and `BN` lines replaced.
    pub fn source(self) -> Result<String> {
        let constants = [("BM", 2, self.bm), ("BN", 2, self.bn)];
        crate::gpu::device::wgsl::with_constants("shaders/dense_fast.wgsl", DenseFast::SOURCE, &constants)
    }
}

impl std::fmt::Display for FastTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

/// The `dense_fast` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseFast;

impl GpuKernel for DenseFast {
    const NAME: &'static str = "dense_fast";
    const SOURCE: &'static str = include_str!("../../../shaders/dense_fast.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_fast::dense_fast;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_have_distinct_names_that_parse_back_and_default_source_is_the_shader() {
        let names: std::collections::BTreeSet<String> = FastTile::ALL.iter().map(|t| t.name()).collect();
        assert_eq!(names.len(), FastTile::ALL.len());
        for t in FastTile::ALL {
            assert_eq!(FastTile::parse(&t.name()), Some(t));
            let src = t.source().unwrap();
            assert!(src.contains(&format!("const BM: u32 = {}u;", t.bm)), "{t}");
            assert!(src.contains(&format!("const BN: u32 = {}u;", t.bn)), "{t}");
        }
        assert_eq!(FastTile::DEFAULT.source().unwrap(), DenseFast::SOURCE);
        assert_eq!(FastTile::DEFAULT.tile(), (TILE_M, TILE_N));
        assert_eq!(FastTile::parse("256x256"), None);
    }
}
