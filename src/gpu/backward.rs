//! Backward passes composed on the device from the training kernels, step for step as the CPU trainer composes
//! their twins ([`crate::train::grad::dense_backward`]): ReLU's mask ([`super::relu_backward`]), then per input
//! slice the weight gradient ([`super::dense_weight_grad`], the bias with the first slice) and the slice's
//! gradient ([`super::dense_input_grad`]); an input shared by a group of rows goes through its group sums
//! ([`super::group_row_sums`]). The encoder's backward pass chains them with the max-pools' backward passes
//! ([`super::max_pool_backward`]) as [`crate::train::backward::encode_backward`] does. Everything stays on the
//! device: gradients are added to the buffers the caller holds.

use super::buffer::storage_buffer;
use super::dense_input_grad::DenseInputGradParams;
use super::dense_weight_grad::DenseWeightGradParams;
use super::group_row_sums::GroupRowSumsParams;
use super::max_pool_backward::MaxPoolBackwardParams;
use super::recorder::Recorder;
use super::relu_backward::ReluBackwardParams;
use crate::cpu::dense_weight_grad::SliceShape;
use crate::error::{Error, Result};
use crate::model::{FoldNet, linear::Linear};

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

/// A model's layers on the device, indexed in `model::params::all_layers` order: each weight (`out x in`,
/// PyTorch layout) and the gradient buffers its backward pass adds to.
#[derive(Clone, Debug)]
pub struct DeviceLayers<'b> {
    /// Weights.
    pub weights: Vec<&'b wgpu::Buffer>,
    /// Weight gradients.
    pub weight_grads: Vec<&'b wgpu::Buffer>,
    /// Bias gradients.
    pub bias_grads: Vec<&'b wgpu::Buffer>,
}

impl DeviceLayers<'_> {
    /// The dense-layer view of layer `index` with `linear`'s shape.
    fn layer(&self, index: usize, linear: &Linear, relu: bool) -> Result<DeviceDenseLayer<'_>> {
        let missing = || Error::invalid(format!("device layers: no layer {index}"));
        Ok(DeviceDenseLayer {
            weight: self.weights.get(index).ok_or_else(missing)?,
            in_dim: linear.in_dim,
            out_dim: linear.out_dim,
            relu,
            weight_grad: self.weight_grads.get(index).ok_or_else(missing)?,
            bias_grad: self.bias_grads.get(index).ok_or_else(missing)?,
        })
    }
}

/// A FoldNet encoder's forward activations on the device: what [`crate::model::foldnet::EncodeTape`] holds.
#[derive(Clone, Debug)]
pub struct DeviceEncodeTape<'b> {
    /// Patches encoded.
    pub patches: usize,
    /// Points per patch.
    pub points: usize,
    /// The encoder's input, `patches * points x in_dim`.
    pub input: &'b wgpu::Buffer,
    /// Output of each encoder layer (after ReLU).
    pub encoder: Vec<&'b wgpu::Buffer>,
    /// Max-pool of the last encoder output, `patches x width`.
    pub global: &'b wgpu::Buffer,
    /// Output of each head layer (after ReLU).
    pub head: Vec<&'b wgpu::Buffer>,
}

/// A zeroed device buffer of `floats` f32 (wgpu zero-initialises new buffers).
fn zeros(rec: &Recorder<'_>, label: &str, floats: usize) -> Result<wgpu::Buffer> {
    storage_buffer(&rec.gpu().context, label, (floats * 4) as u64)
}

/// Records the encoder's backward pass, as [`crate::train::backward::encode_backward`]: `d_codeword`
/// (`patches x codeword`) is the loss gradient w.r.t. the codewords; parameter gradients are added to
/// `layers` (the network's first layer at `base`).
pub fn record_encode_backward(
    rec: &mut Recorder<'_>,
    net: &FoldNet,
    layers: &DeviceLayers<'_>,
    base: usize,
    tape: &DeviceEncodeTape<'_>,
    d_codeword: &wgpu::Buffer,
) -> Result<()> {
    let (patches, points) = (tape.patches, tape.points);
    let rows = patches * points;
    let (n_enc, n_head) = (net.encoder.len(), net.head.len());
    if n_enc == 0 || n_head == 0 || tape.encoder.len() != n_enc || tape.head.len() != n_head {
        return Err(Error::invalid("device encode backward: the tape does not match the network"));
    }
    let head_base = base + n_enc;
    let width = |l: &Linear| l.out_dim;
    // The codewords are the max-pool of the last head output.
    let mut d = zeros(rec, "d head", rows * net.codeword_len())?;
    let pool = MaxPoolBackwardParams::new(patches, points, net.codeword_len())?;
    super::max_pool_backward::record(rec, &pool, tape.head[n_head - 1], d_codeword, &d)?;
    // Head layers after the first, last to first.
    for i in (1..n_head).rev() {
        let dx = zeros(rec, "d head", rows * net.head[i].in_dim)?;
        let seg = DeviceSlice { x: tape.head[i - 1], width: net.head[i].in_dim, offset: 0, dx: Some(&dx) };
        let layer = layers.layer(head_base + i, &net.head[i], true)?;
        record_dense_backward(rec, &layer, rows, rows, tape.head[i], &d, None, &[seg])?;
        d = dx;
    }
    // The first head layer reads [encoder outputs... | global feature broadcast over the patch].
    let d_enc: Vec<wgpu::Buffer> =
        net.encoder.iter().map(|l| zeros(rec, "d encoder", rows * width(l))).collect::<Result<_>>()?;
    let last_width = width(&net.encoder[n_enc - 1]);
    let d_global = zeros(rec, "d global", patches * last_width)?;
    let mut offset = 0;
    let mut segments = Vec::with_capacity(n_enc);
    for ((a, l), da) in tape.encoder.iter().zip(&net.encoder).zip(&d_enc) {
        segments.push(DeviceSlice { x: a, width: width(l), offset, dx: Some(da) });
        offset += width(l);
    }
    let global = DeviceSlice { x: tape.global, width: last_width, offset, dx: Some(&d_global) };
    let layer = layers.layer(head_base, &net.head[0], true)?;
    record_dense_backward(rec, &layer, rows, points, tape.head[0], &d, Some(global), &segments)?;
    // The global max-pool routes its gradient to the argmax rows of the last encoder output.
    let pool = MaxPoolBackwardParams::new(patches, points, last_width)?;
    super::max_pool_backward::record(rec, &pool, tape.encoder[n_enc - 1], &d_global, &d_enc[n_enc - 1])?;
    // Encoder layers, last to first; each adds into the gradient of the previous layer's output.
    for i in (0..n_enc).rev() {
        let (x, dx) = if i == 0 { (tape.input, None) } else { (tape.encoder[i - 1], Some(&d_enc[i - 1])) };
        let seg = DeviceSlice { x, width: net.encoder[i].in_dim, offset: 0, dx };
        let layer = layers.layer(base + i, &net.encoder[i], true)?;
        record_dense_backward(rec, &layer, rows, rows, tape.encoder[i], &d_enc[i], None, &[seg])?;
    }
    Ok(())
}
