//! Host side of `shaders/bitonic_sort.wgsl`: sorts power-of-two arrays of [`SortKey`]s on the GPU with a
//! bitonic network, one dispatch per pass. CPU twin: [`crate::cpu::bitonic_sort`].

use crate::cpu::cell_keys::{PAD_KEY, SortKey};
use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct BitonicSortParams` in shaders/bitonic_sort.wgsl.
    pub struct BitonicSortParams {
        /// Keys (a power of two).
        pub padded: u32,
        /// Size of the bitonic sequences being merged.
        pub k: u32,
        /// Compare distance.
        pub j: u32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;

/// The `bitonic_sort` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct BitonicSort;

impl GpuKernel for BitonicSort {
    const NAME: &'static str = "bitonic_sort";
    const SOURCE: &'static str = include_str!("../../../shaders/bitonic_sort.wgsl");
    const BINDS: &'static [BindKind] = &[BindKind::Uniform, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = BitonicSortParams;
    type CpuTwin = fn(&mut [SortKey]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::bitonic_sort::bitonic_sort;
}

/// Records every pass sorting `keys` (`padded` keys, a power of two).
pub fn record(rec: &mut Recorder<'_>, keys: &wgpu::Buffer, padded: usize) -> Result<()> {
    if !padded.is_power_of_two() {
        return Err(Error::invalid(format!("bitonic_sort: {padded} keys is not a power of two")));
    }
    let p = to_u32(padded, "keys")?;
    let mut k = 2u32;
    while k <= p {
        let mut j = k / 2;
        while j > 0 {
            rec.dispatch::<BitonicSort>(
                &BitonicSortParams { padded: p, k, j, _pad: 0 },
                &[keys],
                workgroups(padded / 2, WG_SIZE),
            )?;
            j /= 2;
        }
        k = match k.checked_mul(2) {
            Some(k) => k,
            None => break,
        };
    }
    Ok(())
}

/// Sorts a slice on the GPU (padded with [`PAD_KEY`] to a power of two) and returns it sorted.
pub async fn run(gpu: &Gpu, keys: &[SortKey]) -> Result<Vec<SortKey>> {
    let padded = super::cell_keys::padded_len(keys.len())?;
    let mut data = keys.to_vec();
    data.resize(padded, PAD_KEY);
    let kb = GpuBuffer::from_slice(&gpu.context, "sort_keys", &data)?;
    let mut rec = Recorder::new(gpu, "bitonic_sort");
    record(&mut rec, kb.raw(), padded)?;
    let r = rec.read(kb.raw(), 0, (keys.len() * 16) as u64);
    let out = rec.finish().await?;
    Ok(bytemuck::pod_collect_to_vec(&out[r]))
}
