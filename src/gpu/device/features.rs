//! The device features dpr-gpu requests when it creates a device ([`device_features`], asked by
//! [`super::context`]), and what decides them: the GEMM variant the environment asks for ([`GEMM_ENV`],
//! [`GemmVariant`]) and whether the adapter can run the cooperative-matrix kernel ([`coop_f16_support`],
//! [`coop_f16`]'s requirements). It sits below the kernels: [`crate::gpu::kernels::gemm`] picks a variant on a created device
//! and names each variant's kernel.

use crate::error::{Error, Result};

/// What the cooperative-matrix GEMM (`shaders/dense_coop_f16.wgsl`, [`crate::gpu::kernels::dense_coop_f16`]) needs from a
/// device; the kernel's host side re-exports these.
pub mod coop_f16 {
    /// The subgroup width the kernel's layout assumes (each subgroup owns a block of the tile).
    pub const SUBGROUP_SIZE: u32 = 32;
    /// The cooperative matrix size M = N = K the kernel uses (`coop_mat16x16`).
    pub const MATRIX: u32 = 16;
    /// Workgroup memory the default 64 x 64 tile's shader declares: 64 x 32 and 32 x 64 f16 operand tiles and
    /// the 64 x 64 f32 product (the other tile shapes say theirs:
    /// [`crate::gpu::kernels::dense_coop_f16::CoopTile::workgroup_bytes`]).
    pub const WORKGROUP_STORAGE_BYTES: u32 = 2 * 64 * 32 * 2 + 64 * 64 * 4;
    /// The device features the kernel is compiled with.
    pub const FEATURES: wgpu::Features = wgpu::Features::SHADER_F16
        .union(wgpu::Features::SUBGROUP)
        .union(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX);
}

/// Environment variable overriding the GEMM variant: `portable`, `fast`, `coop` (or `coop_f16`), `auto`.
pub const GEMM_ENV: &str = "DPR_GPU_GEMM";

/// One GEMM kernel behind the dense layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GemmVariant {
    /// `dense`: the portable f32 reference (64 x 64 tiles).
    Portable,
    /// `dense_fast`: the portable f32 kernel with 128 x 128 register-tiled, double-buffered tiles.
    Fast,
    /// `dense_coop_f16`: cooperative matrices (tensor cores), f16 inputs, f32 accumulation.
    CoopF16,
}

impl GemmVariant {
    /// Every variant, reference first.
    pub const ALL: [GemmVariant; 3] = [GemmVariant::Portable, GemmVariant::Fast, GemmVariant::CoopF16];

    /// Short name (`portable`, `fast`, `coop_f16`), as in [`GEMM_ENV`] and the bench report.
    pub fn name(self) -> &'static str {
        match self {
            GemmVariant::Portable => "portable",
            GemmVariant::Fast => "fast",
            GemmVariant::CoopF16 => "coop_f16",
        }
    }

    /// The value of [`GEMM_ENV`]: `Some(variant)`, or `None` for `auto` / empty.
    pub fn parse(text: &str) -> Result<Option<GemmVariant>> {
        match text.trim().to_ascii_lowercase().as_str() {
            "" | "auto" => Ok(None),
            "portable" | "reference" => Ok(Some(GemmVariant::Portable)),
            "fast" => Ok(Some(GemmVariant::Fast)),
            "coop" | "coop_f16" => Ok(Some(GemmVariant::CoopF16)),
            other => Err(Error::Gpu(format!(
                "{GEMM_ENV}={other} is not a GEMM variant (expected portable, fast, coop or auto)"
            ))),
        }
    }
}

impl std::fmt::Display for GemmVariant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The variant [`GEMM_ENV`] asks for (`None`: automatic), or an error for an unknown value.
pub fn requested() -> Result<Option<GemmVariant>> {
    match std::env::var(GEMM_ENV) {
        Ok(v) => GemmVariant::parse(&v),
        Err(_) => Ok(None),
    }
}

/// Whether `adapter` can run the cooperative-matrix kernel: it has `SHADER_F16`, `SUBGROUP` and
/// `EXPERIMENTAL_COOPERATIVE_MATRIX`, reports a 16 x 16 x 16 configuration with f16 A/B and f32 C/result,
/// runs subgroups of exactly 32 invocations (each of the kernel's subgroups owns a block of the tile), and has
/// the default tile's workgroup memory. `Err` says what is missing.
pub fn coop_f16_support(adapter: &wgpu::Adapter) -> std::result::Result<(), String> {
    let missing = coop_f16::FEATURES - adapter.features();
    if !missing.is_empty() {
        return Err(format!("the adapter lacks {missing}"));
    }
    let configs = adapter.cooperative_matrix_properties();
    let suitable = configs.iter().any(|p| {
        p.m_size == coop_f16::MATRIX
            && p.n_size == coop_f16::MATRIX
            && p.k_size == coop_f16::MATRIX
            && p.ab_type == wgpu::CooperativeScalarType::F16
            && p.cr_type == wgpu::CooperativeScalarType::F32
    });
    if !suitable {
        let list: Vec<String> = configs
            .iter()
            .map(|p| format!("{}x{}x{} {:?}->{:?}", p.m_size, p.n_size, p.k_size, p.ab_type, p.cr_type))
            .collect();
        return Err(format!(
            "no 16x16x16 f16->f32 cooperative matrix configuration (the adapter reports [{}])",
            list.join(", ")
        ));
    }
    let info = adapter.get_info();
    if info.subgroup_min_size != coop_f16::SUBGROUP_SIZE || info.subgroup_max_size != coop_f16::SUBGROUP_SIZE {
        return Err(format!(
            "subgroups of {}..={} invocations; the kernel needs exactly {}",
            info.subgroup_min_size,
            info.subgroup_max_size,
            coop_f16::SUBGROUP_SIZE
        ));
    }
    let have = adapter.limits().max_compute_workgroup_storage_size;
    if have < coop_f16::WORKGROUP_STORAGE_BYTES {
        return Err(format!(
            "max_compute_workgroup_storage_size is {have} bytes; it needs {}",
            coop_f16::WORKGROUP_STORAGE_BYTES
        ));
    }
    Ok(())
}

/// Optional device features the GEMM variants want from `adapter`: the cooperative-matrix kernel's, when the
/// adapter supports it and [`GEMM_ENV`] does not exclude it (an experimental feature is requested only when it
/// will be used).
pub fn device_features(adapter: &wgpu::Adapter) -> wgpu::Features {
    let wanted = matches!(requested(), Ok(None | Some(GemmVariant::CoopF16)));
    if wanted && coop_f16_support(adapter).is_ok() { coop_f16::FEATURES } else { wgpu::Features::empty() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_accepts_the_documented_names_and_rejects_others() {
        assert_eq!(GemmVariant::parse("auto").unwrap(), None);
        assert_eq!(GemmVariant::parse(" ").unwrap(), None);
        assert_eq!(GemmVariant::parse("Portable").unwrap(), Some(GemmVariant::Portable));
        assert_eq!(GemmVariant::parse("fast").unwrap(), Some(GemmVariant::Fast));
        assert_eq!(GemmVariant::parse("coop").unwrap(), Some(GemmVariant::CoopF16));
        assert_eq!(GemmVariant::parse("coop_f16").unwrap(), Some(GemmVariant::CoopF16));
        let err = GemmVariant::parse("tensor").unwrap_err().to_string();
        assert!(err.contains(GEMM_ENV) && err.contains("tensor"), "{err}");
        for v in GemmVariant::ALL {
            assert_eq!(GemmVariant::parse(v.name()).unwrap(), Some(v));
        }
    }
}
