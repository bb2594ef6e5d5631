//! The kernel registry: every WGSL kernel with its source, binding list, workgroup size and uniform
//! parameter struct ([`KERNELS`]), and the compiled pipelines ([`Kernels`]), created once per device with
//! explicit bind group layouts and reused for every dispatch.
//!
//! Binding convention (all kernels): group 0 only, binding 0 is the uniform parameter struct, then the
//! read-only storage inputs, then the read-write outputs. Entry point `main`. Every kernel linearises its
//! workgroup id as `wid.x + wid.y * num_workgroups.x`, so a dispatch past the per-dimension limit folds into
//! a 2-D grid ([`grid`]).

use super::context::GpuContext;
use crate::error::{Error, Result};

/// How a binding is declared in WGSL.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindKind {
    /// `var<uniform>`: the parameter struct.
    Uniform,
    /// `var<storage, read>`.
    ReadOnly,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// A `#[repr(C)]` uniform struct mirrored field by field from a WGSL struct of the same name.
pub trait GpuParams: bytemuck::Pod {
    /// The WGSL struct's name.
    const WGSL_NAME: &'static str;
    /// `(field name, byte offset, byte size)` in declaration order.
    fn fields() -> Vec<(&'static str, usize, usize)>;
}

/// Declares a uniform parameter struct that mirrors the WGSL struct of the same name (checked by
/// `tests/shaders.rs` against naga's layout of the shader).
macro_rules! gpu_params {
    ($(#[$meta:meta])* pub struct $name:ident { $($(#[$fmeta:meta])* pub $field:ident: $ty:ty),* $(,)? }) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
        pub struct $name {
            $($(#[$fmeta])* pub $field: $ty),*
        }

        impl $crate::gpu::kernel::GpuParams for $name {
            const WGSL_NAME: &'static str = stringify!($name);
            fn fields() -> Vec<(&'static str, usize, usize)> {
                vec![$((stringify!($field), std::mem::offset_of!($name, $field), std::mem::size_of::<$ty>())),*]
            }
        }
    };
}
pub(crate) use gpu_params;

/// The reflected layout of a parameter struct: WGSL name, size and fields.
#[derive(Clone, Copy, Debug)]
pub struct ParamsLayout {
    /// The WGSL struct's name.
    pub wgsl_name: &'static str,
    /// `size_of` the Rust struct.
    pub size: usize,
    /// `(name, offset, size)` of each field.
    pub fields: fn() -> Vec<(&'static str, usize, usize)>,
}

impl ParamsLayout {
    /// The layout of `P`.
    pub const fn of<P: GpuParams>() -> ParamsLayout {
        ParamsLayout { wgsl_name: P::WGSL_NAME, size: std::mem::size_of::<P>(), fields: P::fields }
    }
}

/// Everything the host knows about one kernel; `shaders/{name}.wgsl` is its source.
#[derive(Clone, Copy, Debug)]
pub struct KernelSpec {
    /// File stem, shared with the host module and the CPU twin.
    pub name: &'static str,
    /// WGSL source.
    pub source: &'static str,
    /// Bindings 0.. of group 0, in order.
    pub binds: &'static [BindKind],
    /// `@workgroup_size` (1-D).
    pub workgroup_size: u32,
    /// The uniform struct at binding 0.
    pub params: ParamsLayout,
}

/// Every kernel, in pipeline order.
pub const KERNELS: &[&KernelSpec] = &[
    &super::patch_features::SPEC,
    &super::dense::SPEC,
    &super::max_pool::SPEC,
    &super::codeword_distance::SPEC,
    &super::mutual_knn::SPEC,
    &super::rotation_head::SPEC,
    &super::hypotheses::SPEC,
    &super::score_hypotheses::SPEC,
];

/// A compiled kernel: its pipeline and bind group layout.
#[derive(Debug)]
pub struct Kernel {
    /// What it was built from.
    pub spec: &'static KernelSpec,
    /// The compute pipeline (entry point `main`).
    pub pipeline: wgpu::ComputePipeline,
    /// Group 0's layout, from `spec.binds`.
    pub layout: wgpu::BindGroupLayout,
}

impl Kernel {
    /// Compiles `spec` on the context's device; shader or layout errors become [`Error::Gpu`] naming the kernel.
    pub fn new(ctx: &GpuContext, spec: &'static KernelSpec) -> Result<Kernel> {
        let device = &ctx.device;
        let entries: Vec<wgpu::BindGroupLayoutEntry> = spec
            .binds
            .iter()
            .enumerate()
            .map(|(i, kind)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: match kind {
                        BindKind::Uniform => wgpu::BufferBindingType::Uniform,
                        BindKind::ReadOnly => wgpu::BufferBindingType::Storage { read_only: true },
                        BindKind::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                    },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        ctx.scoped(&format!("compiling kernel '{}'", spec.name), || {
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(spec.name),
                entries: &entries,
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(spec.name),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(spec.name),
                source: wgpu::ShaderSource::Wgsl(spec.source.into()),
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(spec.name),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: None,
            });
            Kernel { spec, pipeline, layout }
        })
    }
}

/// All pipelines, compiled once per device.
#[derive(Debug)]
pub struct Kernels {
    /// `shaders/patch_features.wgsl`.
    pub patch_features: Kernel,
    /// `shaders/dense.wgsl`.
    pub dense: Kernel,
    /// `shaders/max_pool.wgsl`.
    pub max_pool: Kernel,
    /// `shaders/codeword_distance.wgsl`.
    pub codeword_distance: Kernel,
    /// `shaders/mutual_knn.wgsl`.
    pub mutual_knn: Kernel,
    /// `shaders/rotation_head.wgsl`.
    pub rotation_head: Kernel,
    /// `shaders/hypotheses.wgsl`.
    pub hypotheses: Kernel,
    /// `shaders/score_hypotheses.wgsl`.
    pub score_hypotheses: Kernel,
}

impl Kernels {
    /// Compiles every kernel of [`KERNELS`].
    pub fn new(ctx: &GpuContext) -> Result<Kernels> {
        Ok(Kernels {
            patch_features: Kernel::new(ctx, &super::patch_features::SPEC)?,
            dense: Kernel::new(ctx, &super::dense::SPEC)?,
            max_pool: Kernel::new(ctx, &super::max_pool::SPEC)?,
            codeword_distance: Kernel::new(ctx, &super::codeword_distance::SPEC)?,
            mutual_knn: Kernel::new(ctx, &super::mutual_knn::SPEC)?,
            rotation_head: Kernel::new(ctx, &super::rotation_head::SPEC)?,
            hypotheses: Kernel::new(ctx, &super::hypotheses::SPEC)?,
            score_hypotheses: Kernel::new(ctx, &super::score_hypotheses::SPEC)?,
        })
    }
}

/// Splits `workgroups` into an `[x, y]` grid with `x <= max_per_dim` (kernels linearise the id back).
pub fn grid(workgroups: u64, max_per_dim: u32) -> Result<[u32; 2]> {
    let max = u64::from(max_per_dim.max(1));
    let x = workgroups.min(max);
    let y = if x == 0 { 0 } else { workgroups.div_ceil(x) };
    if y > max {
        return Err(Error::Gpu(format!(
            "dispatch of {workgroups} workgroups exceeds max_compute_workgroups_per_dimension^2 ({max}^2)"
        )));
    }
    Ok([x as u32, y as u32])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_folds_past_the_dimension_limit() {
        assert_eq!(grid(0, 65535).unwrap(), [0, 0]);
        assert_eq!(grid(10, 65535).unwrap(), [10, 1]);
        assert_eq!(grid(65536, 65535).unwrap(), [65535, 2]);
        assert!(grid(65535 * 65535 + 1, 65535).is_err());
    }
}
