//! What a kernel is, independent of any particular kernel: the [`GpuKernel`] trait each kernel implements once
//! (shader source, bindings, workgroup size, uniform parameter type, CPU twin), its type-erased [`KernelSpec`],
//! and [`Kernel`], a pipeline compiled from a spec. This module names no kernel; the list of kernels is
//! [`crate::gpu::kernels::registry`], which depends on the kernel modules, while they depend only on this one.
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

        impl $crate::gpu::device::kernel::GpuParams for $name {
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

/// Everything the host knows about one kernel, type-erased ([`GpuKernel::SPEC`]); `shaders/{name}.wgsl` is
/// its source.
#[derive(Clone, Copy, Debug)]
pub struct KernelSpec {
    /// File stem, shared by `shaders/{name}.wgsl`, `gpu/kernels/{name}.rs` and the CPU twin `cpu/{name}.rs`.
    pub name: &'static str,
    /// WGSL source as written (its `// #include` lines not yet composed: see [`KernelSpec::composed_source`]).
    pub source: &'static str,
    /// Bindings 0.. of group 0, in order.
    pub binds: &'static [BindKind],
    /// `@workgroup_size` (1-D).
    pub workgroup_size: u32,
    /// The uniform struct at binding 0.
    pub params: ParamsLayout,
    /// Device features the shader needs (`enable f16;` and the like); empty for the portable kernels. A kernel
    /// is compiled only on devices that have them ([`crate::gpu::kernels::registry::Kernels`]).
    pub features: wgpu::Features,
}

impl KernelSpec {
    /// The source the device compiles: [`KernelSpec::source`] with its shared modules composed in
    /// ([`super::wgsl::compose`]).
    pub fn composed_source(&self) -> Result<std::borrow::Cow<'static, str>> {
        super::wgsl::compose(self.source)
    }
}

/// One WGSL kernel, declared once: a unit type in `gpu/{NAME}.rs` implements this, and one line in
/// [`crate::gpu::kernels::registry::KERNELS`] registers it (compiled per device, validated by `tests/shaders.rs`, checked
/// against its twin by `tests/gpu_parity.rs`).
pub trait GpuKernel: 'static {
    /// File stem of the shader, the host module and the CPU twin's module.
    const NAME: &'static str;
    /// WGSL source (`include_str!` of `shaders/{NAME}.wgsl`).
    const SOURCE: &'static str;
    /// Bindings 0.. of group 0: the uniform, read-only inputs, then outputs.
    const BINDS: &'static [BindKind];
    /// `@workgroup_size` (1-D).
    const WORKGROUP_SIZE: u32;
    /// The uniform parameter struct at binding 0; [`super::recorder::Recorder::dispatch`] takes only this type.
    type Params: GpuParams;
    /// The CPU twin's signature (a function pointer type).
    type CpuTwin: Copy;
    /// The CPU twin, in `crate::cpu::{NAME}`: the oracle the kernel is tested against.
    const CPU_TWIN: Self::CpuTwin;
    /// Device features the shader needs (none for a portable kernel).
    const FEATURES: wgpu::Features = wgpu::Features::empty();
    /// The type-erased registry entry.
    const SPEC: KernelSpec = KernelSpec {
        name: Self::NAME,
        source: Self::SOURCE,
        binds: Self::BINDS,
        workgroup_size: Self::WORKGROUP_SIZE,
        params: ParamsLayout::of::<Self::Params>(),
        features: Self::FEATURES,
    };
}

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
    /// Compiles `spec` on the context's device (through its pipeline cache, where it has one: see
    /// [`super::pipeline_cache`]); shader or layout errors become [`Error::Gpu`] naming the kernel.
    pub fn new(ctx: &GpuContext, spec: &'static KernelSpec) -> Result<Kernel> {
        Kernel::with_source(ctx, spec, &spec.composed_source()?, spec.name)
    }

    /// [`Kernel::new`] from a variant of `spec`'s source (`source`, composed here; the same bindings and
    /// parameters), labelled `label` (a generated tile shape: see [`crate::gpu::kernels::dense_fast::FastTile`]).
    pub fn with_source(ctx: &GpuContext, spec: &'static KernelSpec, source: &str, label: &str) -> Result<Kernel> {
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
        let source = super::wgsl::compose(source)?;
        ctx.scoped(&format!("compiling kernel '{label}'"), || {
            let layout = device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries: &entries });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into_owned().into()),
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: ctx.pipeline_cache().map(super::pipeline_cache::PipelineCache::wgpu),
            });
            Kernel { spec, pipeline, layout }
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
