//! Backward passes composed on the device from the training kernels, step for step as the CPU trainer composes
//! their twins ([`crate::train::grad::dense_backward`]): ReLU's mask ([`super::relu_backward`]), then per input
//! slice the weight gradient ([`super::dense_weight_grad`], the bias with the first slice) and the slice's
//! gradient ([`super::dense_input_grad`]); an input shared by a group of rows goes through its group sums
//! ([`super::group_row_sums`]). Everything stays on the device: gradients are added to the buffers the caller
//! holds.

use super::buffer::storage_buffer;
use super::dense_input_grad::DenseInputGradParams;
use super::dense_weight_grad::DenseWeightGradParams;
use super::group_row_sums::GroupRowSumsParams;
use super::recorder::Recorder;
use super::relu_backward::ReluBackwardParams;
use crate::cpu::dense_weight_grad::SliceShape;
use crate::error::{Error, Result};

/// One input slice of a dense layer on the device.
#[derive(Clone, Copy, Debug)]
pub struct DeviceSlice<'b> {
    /// The slice's rows (`rows x width`; `groups x width` for an input shared by a group of rows).
    pub x: &'b wgpu::Buffer,
    /// Its width.
    pub width: usize,
    /// First weight column it multiplies.
    pub offset: usize,
    /// Where its gradient is added (the shape of `x`); `None` skips it.
    pub dx: Option<&'b wgpu::Buffer>,
}

/// A dense layer on the device, as its backward pass sees it.
#[derive(Clone, Copy, Debug)]
pub struct DeviceDenseLayer<'b> {
    /// Weight, `out_dim x in_dim` (PyTorch layout).
    pub weight: &'b wgpu::Buffer,
    /// Full input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Whether the layer applies ReLU to its output.
    pub relu: bool,
    /// Weight gradient (`out_dim x in_dim`), added to.
    pub weight_grad: &'b wgpu::Buffer,
    /// Bias gradient (`out_dim`), added to.
    pub bias_grad: &'b wgpu::Buffer,
}

/// Records the backward pass of one dense layer over `rows` rows, as [`crate::train::grad::dense_backward`]:
/// `out` is the layer's output (after the activation) and `d_out` the loss gradient w.r.t. it (`rows x
/// out_dim` each); `group` is an input shared by each `rows_per_group` consecutive rows. The layer needs at
/// least one per-row slice (every layer of the networks has one); the bias gradient comes with the first.
#[expect(clippy::too_many_arguments, reason = "layer-shaped signature, as train::grad::dense_backward")]
pub fn record_dense_backward(
    rec: &mut Recorder<'_>,
    layer: &DeviceDenseLayer<'_>,
    rows: usize,
    rows_per_group: usize,
    out: &wgpu::Buffer,
    d_out: &wgpu::Buffer,
    group: Option<DeviceSlice<'_>>,
    segments: &[DeviceSlice<'_>],
) -> Result<()> {
    if segments.is_empty() {
        return Err(Error::invalid("dense backward on the device: the layer has no per-row input slice"));
    }
    let ctx = &rec.gpu().context;
    let n_out = layer.out_dim;
    let dz_buffer;
    let dz = if layer.relu {
        dz_buffer = storage_buffer(ctx, "dense backward dz", (rows * n_out * 4) as u64)?;
        super::relu_backward::record(rec, &ReluBackwardParams::new(rows * n_out)?, out, d_out, &dz_buffer)?;
        &dz_buffer
    } else {
        d_out
    };
    let shape = |rows: usize, slice: &DeviceSlice<'_>| SliceShape {
        rows,
        out_dim: n_out,
        in_dim: layer.in_dim,
        width: slice.width,
        offset: slice.offset,
    };
    for (i, seg) in segments.iter().enumerate() {
        let slice = shape(rows, seg);
        let params = DenseWeightGradParams::new(&slice, i == 0)?;
        super::dense_weight_grad::record(rec, &params, dz, seg.x, layer.weight_grad, layer.bias_grad)?;
        if let Some(dx) = seg.dx {
            super::dense_input_grad::record(rec, &DenseInputGradParams::new(&slice)?, dz, layer.weight, dx)?;
        }
    }
    if let Some(g) = group {
        let rpg = rows_per_group.max(1);
        let groups = rows / rpg;
        let sums = storage_buffer(ctx, "dense backward group sums", (groups * n_out * 4) as u64)?;
        super::group_row_sums::record(rec, &GroupRowSumsParams::new(groups, rpg, n_out)?, dz, &sums)?;
        let slice = shape(groups, &g);
        let params = DenseWeightGradParams::new(&slice, false)?;
        super::dense_weight_grad::record(rec, &params, &sums, g.x, layer.weight_grad, layer.bias_grad)?;
        if let Some(dx) = g.dx {
            super::dense_input_grad::record(rec, &DenseInputGradParams::new(&slice)?, &sums, layer.weight, dx)?;
        }
    }
    Ok(())
}
