//! Backward passes composed on the device from the training kernels, step for step as the CPU trainer composes
//! their twins ([`crate::train::grad::dense_backward`]): ReLU's mask ([`crate::gpu::kernels::relu_backward`]), then per input
//! slice the weight gradient ([`crate::gpu::kernels::dense_weight_grad`], the bias with the first slice) and the slice's
//! gradient ([`crate::gpu::kernels::dense_input_grad`]); an input shared by a group of rows goes through its group sums
//! ([`crate::gpu::kernels::group_row_sums`]). The encoder's backward pass chains them with the max-pools' backward passes
//! ([`crate::gpu::kernels::max_pool_backward`]) as [`crate::train::backward::encode_backward`] does; the decoder's and
//! RelativeNet's follow `decode_backward` and `relative_backward` the same way. Everything stays on the device:
//! gradients are added to the buffers the caller holds.

use crate::cpu::dense_weight_grad::SliceShape;
use crate::error::{Error, Result};
use crate::gpu::device::buffer::{GpuBuffer, storage_buffer};
use crate::gpu::device::context::GpuContext;
use crate::gpu::device::recorder::Recorder;
use crate::gpu::kernels::dense_input_grad::DenseInputGradParams;
use crate::gpu::kernels::dense_weight_grad::DenseWeightGradParams;
use crate::gpu::kernels::group_row_sums::GroupRowSumsParams;
use crate::gpu::kernels::max_pool_backward::MaxPoolBackwardParams;
use crate::gpu::kernels::relu_backward::ReluBackwardParams;
use crate::model::foldnet::EncodeTape;
use crate::model::{FoldNet, RelativeNet, linear::Linear};
use crate::train::backward::LayerWeights;

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
        crate::gpu::kernels::relu_backward::record(
            rec,
            &ReluBackwardParams::new(rows * n_out)?,
            out,
            d_out,
            &dz_buffer,
        )?;
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
        crate::gpu::kernels::dense_weight_grad::record(rec, &params, dz, seg.x, layer.weight_grad, layer.bias_grad)?;
        if let Some(dx) = seg.dx {
            crate::gpu::kernels::dense_input_grad::record(
                rec,
                &DenseInputGradParams::new(&slice)?,
                dz,
                layer.weight,
                dx,
            )?;
        }
    }
    if let Some(g) = group {
        let rpg = rows_per_group.max(1);
        let groups = rows / rpg;
        let sums = storage_buffer(ctx, "dense backward group sums", (groups * n_out * 4) as u64)?;
        crate::gpu::kernels::group_row_sums::record(rec, &GroupRowSumsParams::new(groups, rpg, n_out)?, dz, &sums)?;
        let slice = shape(groups, &g);
        let params = DenseWeightGradParams::new(&slice, false)?;
        crate::gpu::kernels::dense_weight_grad::record(rec, &params, &sums, g.x, layer.weight_grad, layer.bias_grad)?;
        if let Some(dx) = g.dx {
            crate::gpu::kernels::dense_input_grad::record(
                rec,
                &DenseInputGradParams::new(&slice)?,
                &sums,
                layer.weight,
                dx,
            )?;
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
    let d = zeros(rec, "d head", rows * net.codeword_len())?;
    let pool = MaxPoolBackwardParams::new(patches, points, net.codeword_len())?;
    crate::gpu::kernels::max_pool_backward::record(rec, &pool, tape.head[n_head - 1], d_codeword, &d)?;
    // Head layers after the first, last to first.
    let d = record_chain_backward(rec, layers, head_base, &net.head, &tape.head, rows, |_| true, d)?;
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
    crate::gpu::kernels::max_pool_backward::record(rec, &pool, tape.encoder[n_enc - 1], &d_global, &d_enc[n_enc - 1])?;
    // Encoder layers, last to first; each adds into the gradient of the previous layer's output.
    for i in (0..n_enc).rev() {
        let (x, dx) = if i == 0 { (tape.input, None) } else { (tape.encoder[i - 1], Some(&d_enc[i - 1])) };
        let seg = DeviceSlice { x, width: net.encoder[i].in_dim, offset: 0, dx };
        let layer = layers.layer(base + i, &net.encoder[i], true)?;
        record_dense_backward(rec, &layer, rows, rows, tape.encoder[i], &d_enc[i], None, &[seg])?;
    }
    Ok(())
}

/// A chain of plain layers `first..first + outs.len()` (outputs `outs`, ReLU where `relu(i)`), as the CPU
/// trainer's `chain_backward`: back-propagates `d_last` (w.r.t. the last output) down to the gradient w.r.t. the
/// first layer's output, which it returns; the first layer itself is left to the caller.
#[expect(clippy::too_many_arguments, reason = "layer-shaped signature, as the CPU trainer's chain_backward")]
fn record_chain_backward(
    rec: &mut Recorder<'_>,
    layers: &DeviceLayers<'_>,
    first: usize,
    linears: &[Linear],
    outs: &[&wgpu::Buffer],
    rows: usize,
    relu: impl Fn(usize) -> bool,
    d_last: wgpu::Buffer,
) -> Result<wgpu::Buffer> {
    let mut d = d_last;
    for i in (1..linears.len()).rev() {
        let dx = zeros(rec, "d chain", rows * linears[i].in_dim)?;
        let seg = DeviceSlice { x: outs[i - 1], width: linears[i].in_dim, offset: 0, dx: Some(&dx) };
        let layer = layers.layer(first + i, &linears[i], relu(i))?;
        record_dense_backward(rec, &layer, rows, rows, outs[i], &d, None, &[seg])?;
        d = dx;
    }
    Ok(d)
}

/// A FoldNet decoder's forward activations on the device: what [`crate::model::foldnet::DecodeTape`] holds,
/// with the decoder's inputs.
#[derive(Clone, Debug)]
pub struct DeviceDecodeTape<'b> {
    /// Patches decoded.
    pub patches: usize,
    /// The codewords decoded, `patches x codeword`.
    pub codewords: &'b wgpu::Buffer,
    /// The folding grid repeated for every patch (`FoldNet::tiled_grid`), `patches * grid_points x 2`.
    pub grid: &'b wgpu::Buffer,
    /// Output of each first-fold layer.
    pub fold1: Vec<&'b wgpu::Buffer>,
    /// Output of each second-fold layer; the last is the reconstruction.
    pub fold2: Vec<&'b wgpu::Buffer>,
}

/// Records one fold's backward pass, as the CPU trainer's `fold_backward`: `x` is the per-point input of its
/// first layer (after the codeword); the codeword gradient is added to `d_codeword`; returns the gradient
/// w.r.t. `x` when `want_x`.
#[expect(clippy::too_many_arguments, reason = "layer-shaped signature, as the CPU trainer's fold_backward")]
fn record_fold_backward(
    rec: &mut Recorder<'_>,
    layers: &DeviceLayers<'_>,
    first: usize,
    linears: &[Linear],
    outs: &[&wgpu::Buffer],
    tape: &DeviceDecodeTape<'_>,
    net: &FoldNet,
    x: &wgpu::Buffer,
    d_out: wgpu::Buffer,
    d_codeword: &wgpu::Buffer,
    want_x: bool,
) -> Result<Option<wgpu::Buffer>> {
    let n = linears.len();
    let (codeword, grid_points) = (net.codeword_len(), net.grid.len() / 2);
    let rows = tape.patches * grid_points;
    let d0 = record_chain_backward(rec, layers, first, linears, outs, rows, |i| i + 1 < n, d_out)?;
    let x_width = linears[0].in_dim - codeword;
    let dx = if want_x { Some(zeros(rec, "d fold input", rows * x_width)?) } else { None };
    let group = DeviceSlice { x: tape.codewords, width: codeword, offset: 0, dx: Some(d_codeword) };
    let seg = DeviceSlice { x, width: x_width, offset: codeword, dx: dx.as_ref() };
    let layer = layers.layer(first, &linears[0], n > 1)?;
    record_dense_backward(rec, &layer, rows, grid_points, outs[0], &d0, Some(group), &[seg])?;
    Ok(dx)
}

/// Records the decoder's backward pass, as [`crate::train::backward::decode_backward`]: `d_recon` is the loss
/// gradient w.r.t. the reconstruction; the codeword gradient is added to `d_codeword` (`patches x codeword`)
/// and parameter gradients to `layers` (the network's first layer at `base`).
pub fn record_decode_backward(
    rec: &mut Recorder<'_>,
    net: &FoldNet,
    layers: &DeviceLayers<'_>,
    base: usize,
    tape: &DeviceDecodeTape<'_>,
    d_recon: wgpu::Buffer,
    d_codeword: &wgpu::Buffer,
) -> Result<()> {
    let (fold1, fold2) = (&net.fold1, &net.fold2);
    if fold1.is_empty() || fold2.is_empty() || tape.fold1.len() != fold1.len() || tape.fold2.len() != fold2.len() {
        return Err(Error::invalid("device decode backward: the tape does not match the network"));
    }
    let fold1_base = base + net.encoder.len() + net.head.len();
    let fold2_base = fold1_base + fold1.len();
    let first_out = tape.fold1[fold1.len() - 1];
    let d_first = record_fold_backward(
        rec,
        layers,
        fold2_base,
        fold2,
        &tape.fold2,
        tape,
        net,
        first_out,
        d_recon,
        d_codeword,
        true,
    )?
    .ok_or_else(|| Error::Gpu("device decode backward: the second fold returned no input gradient".into()))?;
    record_fold_backward(
        rec,
        layers,
        fold1_base,
        fold1,
        &tape.fold1,
        tape,
        net,
        tape.grid,
        d_first,
        d_codeword,
        false,
    )?;
    Ok(())
}

/// Records RelativeNet's backward pass, as [`crate::train::backward::relative_backward`]: `outs` are its layers'
/// outputs over `rows` rows whose input is made of `inputs` (the slices [`crate::gpu::nets::record_relative_outputs`]
/// read, `[source | target]`) and `d_raw` the loss gradient w.r.t. the raw rotation outputs; parameter
/// gradients are added to `layers` (RelativeNet's first layer at `base`), each input's gradient to its `dx`.
#[expect(clippy::too_many_arguments, reason = "layer-shaped signature, as the CPU trainer's relative_backward")]
pub fn record_relative_backward(
    rec: &mut Recorder<'_>,
    net: &RelativeNet,
    layers: &DeviceLayers<'_>,
    base: usize,
    inputs: &[DeviceSlice<'_>],
    rows: usize,
    outs: &[&wgpu::Buffer],
    d_raw: wgpu::Buffer,
) -> Result<()> {
    let n = net.layers.len();
    if n == 0 || outs.len() != n {
        return Err(Error::invalid("device relative backward: the outputs do not match the network"));
    }
    if inputs.iter().map(|s| s.width).sum::<usize>() != net.layers[0].in_dim {
        return Err(Error::invalid("device relative backward: the input slices do not make the first layer's input"));
    }
    let d0 = record_chain_backward(rec, layers, base, &net.layers, outs, rows, |i| i + 1 < n, d_raw)?;
    let layer = layers.layer(base, &net.layers[0], n > 1)?;
    record_dense_backward(rec, &layer, rows, rows, outs[0], &d0, None, inputs)
}

/// Every layer of a model uploaded, with zeroed gradient buffers: owns what [`DeviceLayers`] borrows.
pub struct DeviceLayerBuffers {
    /// Weights (`out x in`), in `all_layers` order.
    pub weights: Vec<GpuBuffer<f32>>,
    /// Weight gradients.
    pub weight_grads: Vec<GpuBuffer<f32>>,
    /// Bias gradients.
    pub bias_grads: Vec<GpuBuffer<f32>>,
}

impl DeviceLayerBuffers {
    /// Uploads every weight of `w`, with zero gradients.
    pub fn upload(ctx: &GpuContext, w: &LayerWeights<'_>) -> Result<DeviceLayerBuffers> {
        let up = |v: &[f32]| GpuBuffer::from_slice(ctx, "layer", v);
        let zeros = |n: usize| up(&vec![0.0; n]);
        Ok(DeviceLayerBuffers {
            weights: w.weights.iter().map(|x| up(x)).collect::<Result<_>>()?,
            weight_grads: w.specs.iter().map(|s| zeros(s.in_dim * s.out_dim)).collect::<Result<_>>()?,
            bias_grads: w.specs.iter().map(|s| zeros(s.out_dim)).collect::<Result<_>>()?,
        })
    }

    /// The borrowed view the backward passes take.
    pub fn view(&self) -> DeviceLayers<'_> {
        fn raw(v: &[GpuBuffer<f32>]) -> Vec<&wgpu::Buffer> {
            v.iter().map(GpuBuffer::raw).collect()
        }
        DeviceLayers {
            weights: raw(&self.weights),
            weight_grads: raw(&self.weight_grads),
            bias_grads: raw(&self.bias_grads),
        }
    }
}

/// An encoder's forward activations uploaded from the host: owns what [`DeviceEncodeTape`] borrows.
pub struct DeviceEncodeTapeBuffers {
    patches: usize,
    points: usize,
    input: GpuBuffer<f32>,
    encoder: Vec<GpuBuffer<f32>>,
    global: GpuBuffer<f32>,
    head: Vec<GpuBuffer<f32>>,
}

impl DeviceEncodeTapeBuffers {
    /// Uploads `tape` and the `input` it was computed from.
    pub fn upload(ctx: &GpuContext, input: &[f32], tape: &EncodeTape) -> Result<DeviceEncodeTapeBuffers> {
        let up = |v: &[f32]| GpuBuffer::from_slice(ctx, "encode tape", v);
        Ok(DeviceEncodeTapeBuffers {
            patches: tape.patches,
            points: tape.points,
            input: up(input)?,
            encoder: tape.encoder.iter().map(|a| up(a)).collect::<Result<_>>()?,
            global: up(&tape.global)?,
            head: tape.head.iter().map(|a| up(a)).collect::<Result<_>>()?,
        })
    }

    /// The borrowed view [`record_encode_backward`] takes.
    pub fn view(&self) -> DeviceEncodeTape<'_> {
        DeviceEncodeTape {
            patches: self.patches,
            points: self.points,
            input: self.input.raw(),
            encoder: self.encoder.iter().map(GpuBuffer::raw).collect(),
            global: self.global.raw(),
            head: self.head.iter().map(GpuBuffer::raw).collect(),
        }
    }
}

impl<'b> DeviceEncodeTape<'b> {
    /// The tape of an encoder pass that kept its head ([`crate::gpu::nets::Outputs::Kept`]) over `input`.
    pub fn from_outputs(
        outputs: &'b crate::gpu::nets::EncodeOutputs,
        input: &'b wgpu::Buffer,
        (patches, points): (usize, usize),
    ) -> DeviceEncodeTape<'b> {
        DeviceEncodeTape {
            patches,
            points,
            input,
            encoder: outputs.encoder.iter().collect(),
            global: &outputs.global,
            head: outputs.head.iter().collect(),
        }
    }
}

impl<'b> DeviceDecodeTape<'b> {
    /// The tape of a decoder pass that kept both folds' outputs ([`crate::gpu::nets::record_decode_outputs`]) over
    /// `codewords` and the tiled `grid`.
    pub fn from_outputs(
        [fold1, fold2]: &'b [Vec<wgpu::Buffer>; 2],
        [codewords, grid]: [&'b wgpu::Buffer; 2],
        patches: usize,
    ) -> DeviceDecodeTape<'b> {
        DeviceDecodeTape { patches, codewords, grid, fold1: fold1.iter().collect(), fold2: fold2.iter().collect() }
    }
}
