//! The networks on the GPU: weights uploaded once per layer, and the forward passes of FoldNet (encode,
//! decode) and RelativeNet composed from `dense`, `max_pool` and `rotation_head` dispatches, in the
//! same order of operations as the CPU reference (`model::foldnet`, `model::relativenet`).
//!
//! Work is chunked by whole patches (or rows) so that no buffer exceeds [`GpuContext::max_buffer_bytes`];
//! each chunk is one submission, and the chunks' readbacks are collected after the last one is queued.
//! A concatenated input is never built: as on the CPU, each slice is a dense call into the same output
//! (accumulating), and the per-patch slice (global feature or codeword) becomes the group term.

use super::Gpu;
use super::device::buffer::Workspace;
use super::device::context::GpuContext;
use super::device::recorder::{Pending, Recorder};
use super::kernels::dense::{self, DenseParams};
use super::kernels::max_pool::{self, MaxPoolParams};
use super::kernels::rotation_head;
use crate::backend::RotationInputs;
use crate::cpu::dense::DenseShape;
use crate::error::{Error, Result};
use crate::model::ModelConfig;
use crate::model::linear::Linear;
use crate::model::{FoldNet, Model};

/// A linear layer's transposed weight and bias on the GPU.
pub struct GpuLinear {
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// `in_dim x out_dim`, as [`Linear::weight_t`].
    pub weight_t: wgpu::Buffer,
    /// `out_dim`.
    pub bias: wgpu::Buffer,
}

impl GpuLinear {
    fn upload(ctx: &GpuContext, layer: &Linear) -> Result<GpuLinear> {
        Ok(GpuLinear {
            in_dim: layer.in_dim,
            out_dim: layer.out_dim,
            weight_t: super::device::buffer::GpuBuffer::from_slice(ctx, "weight_t", &layer.weight_t)?.raw().clone(),
            bias: super::device::buffer::GpuBuffer::from_slice(ctx, "bias", &layer.bias)?.raw().clone(),
        })
    }
}

/// One FoldNet's layers on the GPU.
pub struct GpuFoldNet {
    /// Per-point MLP before the first max-pool.
    pub encoder: Vec<GpuLinear>,
    /// Per-point MLP after the skip concatenation.
    pub head: Vec<GpuLinear>,
    /// First folding MLP.
    pub fold1: Vec<GpuLinear>,
    /// Second folding MLP.
    pub fold2: Vec<GpuLinear>,
    /// Folding grid (`grid_points x 2`), host copy (tiled per chunk on upload).
    pub grid: Vec<f32>,
    /// Per-point input / reconstruction width.
    pub io_width: usize,
}

/// The whole model on the GPU.
pub struct GpuModel {
    /// PPF-FoldNet.
    pub ppf: GpuFoldNet,
    /// PC-FoldNet.
    pub pc: GpuFoldNet,
    /// RelativeNet.
    pub relative: Vec<GpuLinear>,
}

fn upload_all(ctx: &GpuContext, layers: &[Linear]) -> Result<Vec<GpuLinear>> {
    layers.iter().map(|l| GpuLinear::upload(ctx, l)).collect()
}

impl GpuFoldNet {
    fn upload(ctx: &GpuContext, f: &FoldNet) -> Result<GpuFoldNet> {
        if f.encoder.is_empty() || f.encoder.len() > ENCODER_NAMES.len() || f.head.is_empty() || f.fold1.is_empty() {
            return Err(Error::invalid(format!(
                "GPU FoldNet needs 1..={} encoder layers and non-empty head and folding MLPs",
                ENCODER_NAMES.len()
            )));
        }
        Ok(GpuFoldNet {
            encoder: upload_all(ctx, &f.encoder)?,
            head: upload_all(ctx, &f.head)?,
            fold1: upload_all(ctx, &f.fold1)?,
            fold2: upload_all(ctx, &f.fold2)?,
            grid: f.grid.clone(),
            io_width: f.net.io_width(),
        })
    }

    /// Codeword length.
    pub fn codeword_len(&self) -> usize {
        self.head.last().map_or(0, |l| l.out_dim)
    }
}

impl GpuModel {
    /// Uploads every weight once.
    pub fn upload(ctx: &GpuContext, model: &Model) -> Result<GpuModel> {
        if model.relative.layers.is_empty() {
            return Err(Error::invalid("RelativeNet has no layers"));
        }
        Ok(GpuModel {
            ppf: GpuFoldNet::upload(ctx, &model.ppf)?,
            pc: GpuFoldNet::upload(ctx, &model.pc)?,
            relative: upload_all(ctx, &model.relative.layers)?,
        })
    }
}

/// Workspace names of the encoder activations (kept for the skip concatenation).
const ENCODER_NAMES: [&str; 8] = ["enc0", "enc1", "enc2", "enc3", "enc4", "enc5", "enc6", "enc7"];

/// How many items of `bytes_per_item` (for the largest buffer) fit the buffer cap; an error naming the
/// limit when not even one does.
pub fn items_per_chunk(ctx: &GpuContext, bytes_per_item: u64, what: &str) -> Result<usize> {
    let cap = ctx.max_buffer_bytes();
    if bytes_per_item > cap {
        return Err(Error::Gpu(format!(
            "one {what} needs a {bytes_per_item}-byte buffer, more than the {cap}-byte limit \
             (max_storage_buffer_binding_size, max_buffer_size or {})",
            super::device::context::MAX_BUFFER_ENV
        )));
    }
    Ok((cap / bytes_per_item.max(1)).clamp(1, u64::from(u32::MAX / 2)) as usize)
}

/// A dense call of `layer` (or of rows `w_row_offset..` of it, for one slice of a concatenated input).
#[expect(clippy::too_many_arguments, reason = "a layer call is described by these values")]
fn dense_call<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    layer: &GpuLinear,
    (x, in_dim, w_row_offset): (&wgpu::Buffer, usize, usize),
    (rows, rows_per_group): (usize, usize),
    group: Option<&wgpu::Buffer>,
    (accumulate, relu): (bool, bool),
    out: &wgpu::Buffer,
) -> Result<()> {
    let shape = DenseShape { rows, in_dim, out_dim: layer.out_dim, rows_per_group, accumulate, relu };
    dense::record(rec, gpu, &DenseParams::new(&shape, w_row_offset, group.is_some())?, x, &layer.weight_t, group, out)
}

/// `layer(x)` with the bias as the only group term (`model::foldnet::apply`).
fn apply<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    layer: &GpuLinear,
    x: &wgpu::Buffer,
    rows: usize,
    relu: bool,
    out: &wgpu::Buffer,
) -> Result<()> {
    dense_call(rec, gpu, layer, (x, layer.in_dim, 0), (rows, rows.max(1)), Some(&layer.bias), (false, relu), out)
}

/// Where an MLP's layer outputs go on the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outputs {
    /// Two workspace buffers taken in turn (inference): only the last output survives the pass.
    PingPong([&'static str; 2]),
    /// One workspace buffer per layer (training's forward tape): every output is kept for the backward pass.
    Kept(&'static [&'static str]),
}

/// The output buffer of each layer of `layers` over `rows` rows, as `outputs` places them (ping-pong buffers
/// alias: layer `i` writes `names[i % 2]`).
fn layer_buffers(
    ws: &mut Workspace,
    ctx: &GpuContext,
    outputs: Outputs,
    layers: &[GpuLinear],
    rows: usize,
) -> Result<Vec<wgpu::Buffer>> {
    match outputs {
        Outputs::PingPong(names) => {
            let w = layers.iter().map(|l| l.out_dim).max().unwrap_or(1);
            let bytes = (rows * w * 4) as u64;
            let pair = [ws.buffer(ctx, names[0], bytes)?, ws.buffer(ctx, names[1], bytes)?];
            Ok((0..layers.len()).map(|i| pair[i % 2].clone()).collect())
        }
        Outputs::Kept(names) => {
            if layers.len() > names.len() {
                return Err(Error::invalid(format!(
                    "a kept forward pass holds at most {} layers per MLP, this one has {}",
                    names.len(),
                    layers.len()
                )));
            }
            layers.iter().zip(names).map(|(l, &name)| ws.buffer(ctx, name, (rows * l.out_dim * 4) as u64)).collect()
        }
    }
}

/// Layers `1..` of an MLP whose first layer's output is in `outs[0]`: layer i reads `outs[i - 1]` and writes
/// `outs[i]`, ReLU on all but the last unless `relu_last`.
fn tail<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    layers: &[GpuLinear],
    outs: &[wgpu::Buffer],
    rows: usize,
    relu_last: bool,
) -> Result<()> {
    for (i, layer) in layers.iter().enumerate().skip(1) {
        let relu = relu_last || i + 1 < layers.len();
        apply(rec, gpu, layer, &outs[i - 1], rows, relu, &outs[i])?;
    }
    Ok(())
}

/// Waits for every chunk and concatenates read `index` of each.
async fn collect(gpu: &Gpu, pending: Vec<Pending>, index: usize) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    for p in pending {
        out.extend_from_slice(&p.wait(gpu).await?[index]);
    }
    Ok(out)
}

/// Patches per submission of the encoder: the most whose widest activation fits the buffer cap.
pub fn encoder_chunk(ctx: &GpuContext, f: &GpuFoldNet, points: usize) -> Result<usize> {
    let width = f.io_width;
    let widest = f.encoder.iter().chain(&f.head).map(|l| l.out_dim).chain([width]).max().unwrap_or(width);
    items_per_chunk(ctx, (points * widest * 4) as u64, "patch of the encoder")
}

/// Every buffer an encoder pass wrote (workspace buffers, valid until the workspace hands them out again).
#[derive(Clone, Debug)]
pub struct EncodeOutputs {
    /// Output of each encoder layer (after ReLU), `patches * points x width`; always kept (the skip
    /// concatenation reads them all).
    pub encoder: Vec<wgpu::Buffer>,
    /// Max-pool of the last encoder output, `patches x width`.
    pub global: wgpu::Buffer,
    /// Output buffer of each head layer; with [`Outputs::PingPong`] they alias and only the last is valid.
    pub head: Vec<wgpu::Buffer>,
    /// Codewords, `patches x codeword` (workspace `enc_codewords`).
    pub codewords: wgpu::Buffer,
}

/// Workspace names of the head outputs when a pass keeps them.
pub const HEAD_NAMES: [&str; 8] = ["head0", "head1", "head2", "head3", "head4", "head5", "head6", "head7"];

/// Records the encoder on `patches` patches of `points` rows already on the device (`x_in`, `io_width` values
/// per row), the head's outputs placed as `head` says (training keeps them: [`Outputs::Kept`] with
/// [`HEAD_NAMES`]); returns every buffer it wrote. The one device definition of the encoder: inference reads
/// only the codewords, the trainer's backward pass reads the rest.
pub fn record_encode_outputs<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    ws: &mut Workspace,
    f: &GpuFoldNet,
    x_in: &wgpu::Buffer,
    (cp, points): (usize, usize),
    head: Outputs,
) -> Result<EncodeOutputs> {
    let ctx = &gpu.context;
    let rows = cp * points;
    let cw = f.codeword_len();
    let last = f.encoder.last().expect("checked on upload");
    let head0 = &f.head[0];
    let concat_offset: usize = f.encoder.iter().map(|l| l.out_dim).sum();
    let mut encoder: Vec<wgpu::Buffer> = Vec::with_capacity(f.encoder.len());
    for (i, layer) in f.encoder.iter().enumerate() {
        let out = ws.buffer(ctx, ENCODER_NAMES[i], (rows * layer.out_dim * 4) as u64)?;
        let x = encoder.last().unwrap_or(x_in);
        apply(rec, gpu, layer, x, rows, true, &out)?;
        encoder.push(out);
    }
    let global = ws.buffer(ctx, "enc_global", (cp * last.out_dim * 4) as u64)?;
    max_pool::record(rec, &MaxPoolParams::new(cp, points, last.out_dim)?, &encoder[encoder.len() - 1], &global)?;
    // The global slice sits after the encoder slices in head.0's input; it is the per-patch term.
    let group = ws.buffer(ctx, "enc_group", (cp * head0.out_dim * 4) as u64)?;
    dense_call(
        rec,
        gpu,
        head0,
        (&global, last.out_dim, concat_offset),
        (cp, cp),
        Some(&head0.bias),
        (false, false),
        &group,
    )?;
    let outs = layer_buffers(ws, ctx, head, &f.head, rows)?;
    let mut offset = 0;
    for (s, (a, layer)) in encoder.iter().zip(&f.encoder).enumerate() {
        let first = s == 0;
        let last_seg = s + 1 == encoder.len();
        let g = first.then_some(&group);
        dense_call(rec, gpu, head0, (a, layer.out_dim, offset), (rows, points), g, (!first, last_seg), &outs[0])?;
        offset += layer.out_dim;
    }
    tail(rec, gpu, &f.head, &outs, rows, true)?;
    let codewords = ws.buffer(ctx, "enc_codewords", (cp * cw * 4) as u64)?;
    max_pool::record(rec, &MaxPoolParams::new(cp, points, cw)?, &outs[outs.len() - 1], &codewords)?;
    Ok(EncodeOutputs { encoder, global, head: outs, codewords })
}

/// [`record_encode_outputs`] for inference: the head in ping-pong buffers; returns the codewords' buffer.
pub fn record_encode<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    ws: &mut Workspace,
    f: &GpuFoldNet,
    x_in: &wgpu::Buffer,
    patches_points: (usize, usize),
) -> Result<wgpu::Buffer> {
    let head = Outputs::PingPong(["head_a", "head_b"]);
    Ok(record_encode_outputs(rec, gpu, ws, f, x_in, patches_points, head)?.codewords)
}

/// Codewords (`patches x codeword`) of `input` (`patches x points x io_width`), as `FoldNet::encode`.
pub async fn encode(
    gpu: &Gpu,
    ws: &mut Workspace,
    f: &GpuFoldNet,
    input: &[f32],
    patches: usize,
    points: usize,
) -> Result<Vec<f32>> {
    let width = f.io_width;
    if input.len() != patches * points * width {
        return Err(Error::invalid(format!(
            "encode: input has {} values, expected {patches} patches x {points} points x {width}",
            input.len()
        )));
    }
    if patches == 0 || points == 0 {
        return Ok(vec![0.0; 0]);
    }
    let ctx = &gpu.context;
    let chunk = encoder_chunk(ctx, f, points)?;
    let cw = f.codeword_len();
    let mut pending = Vec::new();
    for c0 in (0..patches).step_by(chunk) {
        let cp = chunk.min(patches - c0);
        let x_in = ws.upload(ctx, "enc_input", &input[c0 * points * width..(c0 + cp) * points * width])?;
        let mut rec = Recorder::new(gpu, "encode");
        let codewords = record_encode(&mut rec, gpu, ws, f, &x_in, (cp, points))?;
        rec.read(&codewords, 0, (cp * cw * 4) as u64);
        pending.push(rec.submit()?);
    }
    Ok(bytemuck::pod_collect_to_vec(&collect(gpu, pending, 0).await?))
}

/// One folding MLP over `rows = patches x m` rows: `[codeword | x]` in, as `FoldNet::decode`'s `fold`;
/// returns each layer's output buffer (placed as `outputs` says).
#[expect(clippy::too_many_arguments, reason = "a folding stage is described by these values")]
fn fold<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    ws: &mut Workspace,
    layers: &[GpuLinear],
    (codewords, cw): (&wgpu::Buffer, usize),
    (x, x_width): (&wgpu::Buffer, usize),
    (patches, m): (usize, usize),
    outputs: Outputs,
) -> Result<Vec<wgpu::Buffer>> {
    let ctx = &gpu.context;
    let l0 = &layers[0];
    let rows = patches * m;
    let group = ws.buffer(ctx, "fold_group", (patches * l0.out_dim * 4) as u64)?;
    dense_call(rec, gpu, l0, (codewords, cw, 0), (patches, patches), Some(&l0.bias), (false, false), &group)?;
    let outs = layer_buffers(ws, ctx, outputs, layers, rows)?;
    dense_call(rec, gpu, l0, (x, x_width, cw), (rows, m), Some(&group), (false, layers.len() > 1), &outs[0])?;
    tail(rec, gpu, layers, &outs, rows, false)?;
    Ok(outs)
}

/// Workspace names of the folds' outputs when a pass keeps them.
pub const FOLD_NAMES: [[&str; 8]; 2] = [
    ["fold1_0", "fold1_1", "fold1_2", "fold1_3", "fold1_4", "fold1_5", "fold1_6", "fold1_7"],
    ["fold2_0", "fold2_1", "fold2_2", "fold2_3", "fold2_4", "fold2_5", "fold2_6", "fold2_7"],
];

/// Records the decoder on `patches` codewords on the device, with the folding grid tiled per patch (`grid`,
/// `patches * grid_points x 2`); each fold's outputs placed as `outputs[fold]` says. Returns every layer's
/// output buffer of the first and the second fold (the last of the second is the reconstruction). The one
/// device definition of the decoder.
pub fn record_decode_outputs<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    ws: &mut Workspace,
    f: &GpuFoldNet,
    [codewords, grid]: [&wgpu::Buffer; 2],
    patches: usize,
    outputs: [Outputs; 2],
) -> Result<[Vec<wgpu::Buffer>; 2]> {
    let (cw, m, d) = (f.codeword_len(), f.grid.len() / 2, f.io_width);
    let first = fold(rec, gpu, ws, &f.fold1, (codewords, cw), (grid, 2), (patches, m), outputs[0])?;
    let x = &first[first.len() - 1];
    let second = fold(rec, gpu, ws, &f.fold2, (codewords, cw), (x, d), (patches, m), outputs[1])?;
    Ok([first, second])
}

/// Reconstructions (`patches x grid_points x io_width`) of codewords (`patches x codeword`), as
/// `FoldNet::decode`.
pub async fn decode(
    gpu: &Gpu,
    ws: &mut Workspace,
    f: &GpuFoldNet,
    codewords: &[f32],
    patches: usize,
) -> Result<Vec<f32>> {
    let cw = f.codeword_len();
    if codewords.len() != patches * cw {
        return Err(Error::invalid(format!("decode: {} values are not {patches} codewords of {cw}", codewords.len())));
    }
    let m = f.grid.len() / 2;
    if patches == 0 || m == 0 {
        return Ok(Vec::new());
    }
    let ctx = &gpu.context;
    let d = f.io_width;
    let widest = f.fold1.iter().chain(&f.fold2).map(|l| l.out_dim).chain([2, d]).max().unwrap_or(d);
    let chunk = items_per_chunk(ctx, (m * widest * 4) as u64, "patch of the decoder")?;
    let mut pending = Vec::new();
    for c0 in (0..patches).step_by(chunk) {
        let cp = chunk.min(patches - c0);
        let code = ws.upload(ctx, "dec_codewords", &codewords[c0 * cw..(c0 + cp) * cw])?;
        let tiled: Vec<f32> = (0..cp).flat_map(|_| f.grid.iter().copied()).collect();
        let grid = ws.upload(ctx, "dec_grid", &tiled)?;
        let mut rec = Recorder::new(gpu, "decode");
        let outputs = [Outputs::PingPong(["fold1_a", "fold1_b"]), Outputs::PingPong(["fold2_a", "fold2_b"])];
        let [_, second] = record_decode_outputs(&mut rec, gpu, ws, f, [&code, &grid], cp, outputs)?;
        let out = &second[second.len() - 1];
        rec.read(out, 0, (cp * m * d * 4) as u64);
        pending.push(rec.submit()?);
    }
    Ok(bytemuck::pod_collect_to_vec(&collect(gpu, pending, 0).await?))
}

/// Checks RelativeNet's output width against the configured rotation head; returns the pose feature width.
pub fn relative_width(layers: &[GpuLinear], config: &ModelConfig) -> Result<usize> {
    let out_w = layers.last().map_or(0, |l| l.out_dim);
    if out_w != config.rotation_output.width() {
        return Err(Error::invalid(format!(
            "RelativeNet's last layer has width {out_w}, expected {} for {:?}",
            config.rotation_output.width(),
            config.rotation_output
        )));
    }
    Ok(layers[0].in_dim / 2)
}

/// Bytes per row of RelativeNet's largest buffer (for [`items_per_chunk`]).
pub fn relative_row_bytes(layers: &[GpuLinear], config: &ModelConfig) -> u64 {
    let f = layers[0].in_dim / 2;
    let m = config.rotation_output.candidates();
    (layers.iter().map(|l| l.out_dim).chain([f, 9 * m]).max().unwrap_or(f) * 4) as u64
}

/// Records RelativeNet and its rotation head on `n` rows already on the device (`[source, target]` pose
/// features, `[source, target]` normals); returns the buffer of rotations (`n x candidates x 9`, workspace
/// `rel_rotations`).
pub fn record_relative<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    ws: &mut Workspace,
    (layers, config): (&[GpuLinear], &ModelConfig),
    [s, t, ns, nt]: [&wgpu::Buffer; 4],
    n: usize,
) -> Result<wgpu::Buffer> {
    let m = config.rotation_output.candidates();
    let f = layers[0].in_dim / 2;
    let inputs = [(s, f, 0), (t, f, f)];
    let outs = record_relative_outputs(rec, gpu, ws, layers, &inputs, n, Outputs::PingPong(["rel_a", "rel_b"]))?;
    let raw = &outs[outs.len() - 1];
    let rotations = ws.buffer(&gpu.context, "rel_rotations", (n * m * 36) as u64)?;
    let params = rotation_head::RotationHeadParams::new(n, config.rotation_output, config.pose_frame)?;
    rotation_head::record(rec, &params, [raw, ns, nt], &rotations)?;
    Ok(rotations)
}

/// Workspace names of RelativeNet's outputs when a pass keeps them.
pub const RELATIVE_NAMES: [&str; 8] = ["rel0", "rel1", "rel2", "rel3", "rel4", "rel5", "rel6", "rel7"];

/// Records RelativeNet's layers on `n` rows of pose features on the device, its input given as slices `(buffer,
/// width, first weight column)` that together make `[source | target]` (inference: the two sides' buffers;
/// training: one buffer of interleaved source and target rows read as `n x 2f`), placed as `outputs` says;
/// returns each layer's output buffer (the last holds the raw rotation outputs). The one device definition of
/// RelativeNet's MLP, before the rotation head.
pub fn record_relative_outputs<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    ws: &mut Workspace,
    layers: &[GpuLinear],
    inputs: &[(&wgpu::Buffer, usize, usize)],
    n: usize,
    outputs: Outputs,
) -> Result<Vec<wgpu::Buffer>> {
    let l0 = &layers[0];
    if inputs.is_empty() || inputs.iter().map(|i| i.1).sum::<usize>() != l0.in_dim {
        return Err(Error::invalid(format!("RelativeNet's input slices do not make its {} inputs", l0.in_dim)));
    }
    let outs = layer_buffers(ws, &gpu.context, outputs, layers, n)?;
    let relu0 = layers.len() > 1;
    for (k, &slice) in inputs.iter().enumerate() {
        let (first, last) = (k == 0, k + 1 == inputs.len());
        let bias = first.then_some(&l0.bias);
        dense_call(rec, gpu, l0, slice, (n, n), bias, (!first, last && relu0), &outs[0])?;
    }
    tail(rec, gpu, layers, &outs, n, false)?;
    Ok(outs)
}

/// RelativeNet's rotations (row-major, fragment frames; `candidates` per row) for the rows of `pose`, as
/// `RelativeNet::predict`.
pub async fn relative(
    gpu: &Gpu,
    ws: &mut Workspace,
    layers: &[GpuLinear],
    config: &ModelConfig,
    pose: RotationInputs<'_>,
) -> Result<Vec<[f32; 9]>> {
    let RotationInputs { source, target, source_normals, target_normals, rows } = pose;
    let f = relative_width(layers, config)?;
    if source.len() != rows * f || target.len() != rows * f {
        return Err(Error::invalid(format!("predict_rotations: inputs must be {rows} rows of {f} values")));
    }
    if source_normals.len() != rows || target_normals.len() != rows {
        return Err(Error::invalid(format!("predict_rotations: expected {rows} normals per side")));
    }
    if rows == 0 {
        return Ok(Vec::new());
    }
    let ctx = &gpu.context;
    let m = config.rotation_output.candidates();
    let chunk = items_per_chunk(ctx, relative_row_bytes(layers, config), "RelativeNet row")?;
    let mut pending = Vec::new();
    for r0 in (0..rows).step_by(chunk) {
        let n = chunk.min(rows - r0);
        let s = ws.upload(ctx, "rel_source", &source[r0 * f..(r0 + n) * f])?;
        let t = ws.upload(ctx, "rel_target", &target[r0 * f..(r0 + n) * f])?;
        let ns = ws.upload(ctx, "rel_source_normals", &source_normals[r0..r0 + n])?;
        let nt = ws.upload(ctx, "rel_target_normals", &target_normals[r0..r0 + n])?;
        let mut rec = Recorder::new(gpu, "predict_rotations");
        let rotations = record_relative(&mut rec, gpu, ws, (layers, config), [&s, &t, &ns, &nt], n)?;
        rec.read(&rotations, 0, (n * m * 36) as u64);
        pending.push(rec.submit()?);
    }
    Ok(bytemuck::pod_collect_to_vec(&collect(gpu, pending, 0).await?))
}
