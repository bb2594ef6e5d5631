//! The training step on the device: the objective of [`crate::train::objective`] (reconstruction, pose,
//! feature consistency, the batch contrastive term) and its gradient, then AdamW, with the weights, their
//! gradients, the optimiser's moments and every activation kept on the device across steps.
//!
//! One step is two submissions. The first runs both FoldNets' encoders and decoders keeping their activations
//! ([`super::nets::Outputs::Kept`]), the reconstruction loss and its gradient ([`super::kernels::chamfer_nearest`],
//! [`super::kernels::chamfer_grad`]), the pose features and RelativeNet; it reads back only what the small loss heads need
//! (the PPF codewords, RelativeNet's raw outputs and the per-patch reconstruction losses: a few hundred KB). The
//! host evaluates those heads with the CPU trainer's own functions (pose, feature-consistency and contrastive
//! losses: a few thousand values) and uploads their gradients; the second submission runs every backward pass
//! ([`backward`]), the optimiser ([`super::kernels::adam_step`]) and refreshes each forward weight
//! ([`super::kernels::transpose`]) without waiting: the host samples the next batch meanwhile. A step whose loss is not
//! finite changes nothing.
//!
//! A batch holds each pair's source and target patch side by side (patch `2i` and `2i + 1`), as the CPU trainer
//! encodes them, so the pose features of pair `i` are rows `2i, 2i + 1` of one buffer, which RelativeNet reads
//! as one `2 x codeword` input row and whose gradient lands directly in the PC codewords' gradient.
//!
//! The forward pass runs on an f32 GEMM (the trainer refuses a device set to f16 inputs). What is not on the
//! device yet: `pose_trains_ppf` (refused).

pub mod backward;

use super::Gpu;
use super::device::buffer::{GpuBuffer, Workspace};
use super::device::recorder::{Pending, Recorder};
use super::kernels::chamfer_grad::ChamferGradParams;
use super::kernels::chamfer_nearest::ChamferNearestParams;
use super::kernels::transpose::TransposeParams;
use super::kernels::{adam_step, pose_feature};
use super::nets::{
    EncodeOutputs, FOLD_NAMES, GpuFoldNet, GpuLinear, GpuModel, HEAD_NAMES, Outputs, RELATIVE_NAMES,
    record_decode_outputs, record_encode_outputs, record_relative_outputs,
};
use crate::error::{Error, Result};
use crate::model::{FoldNet, Model, Weights};
use crate::train::adam::Adam;
use crate::train::backward::{Gradients, LayerWeights};
use crate::train::objective::{
    LossSettings, Losses, PairHeads, PairSample, add_contrast, bases, check_sample, contrast_terms,
};
use crate::train::trainer::tensor_order;
use backward::{
    DeviceDecodeTape, DeviceEncodeTape, DeviceLayerBuffers, DeviceSlice, record_decode_backward,
    record_encode_backward, record_relative_backward,
};

/// One FoldNet's forward pass over a batch, kept for its backward pass.
struct NetPass {
    input: wgpu::Buffer,
    encode: EncodeOutputs,
    grid: wgpu::Buffer,
    decode: [Vec<wgpu::Buffer>; 2],
    /// Gradient of the batch's reconstruction loss w.r.t. the reconstruction.
    d_recon: wgpu::Buffer,
}

/// The first submission's buffers and what the host computed from its readback.
struct Forward {
    patches: usize,
    ppf: NetPass,
    pc: NetPass,
    pose: wgpu::Buffer,
    relative: Vec<wgpu::Buffer>,
    losses: Losses,
    /// The host terms' gradient w.r.t. the PPF codewords (`patches x codeword`).
    d_ppf_codewords: Vec<f32>,
    /// The pose loss's gradient w.r.t. RelativeNet's raw outputs (`pairs x width`), weighted.
    d_raw: Vec<f32>,
}

/// A model under training on the device. See the module docs.
pub struct DeviceTrainer {
    /// The networks' shapes (the CPU copy of the weights is the starting point only; it is never updated).
    model: Model,
    loss: LossSettings,
    forward: GpuModel,
    layers: DeviceLayerBuffers,
    /// The optimiser's settings and step count; its moments live in `moments`.
    adam: Adam,
    /// `(m, v)` per tensor, in `tensor_order`.
    moments: Vec<[GpuBuffer<f32>; 2]>,
    /// Scratch per network: the two FoldNets' tapes use the same buffer names.
    ws: [Workspace; 3],
    /// The last step's backward pass and update, submitted without waiting (the host samples the next batch
    /// meanwhile); waited for when the next step starts, which collects its errors and device time.
    in_flight: Option<Pending>,
}

/// A device for training: any adapter the environment allows, its dense layers on an f32 GEMM (the `fast`
/// one where the device's default is the f16 tensor-core GEMM).
pub fn training_gpu() -> Result<Gpu> {
    let mut gpu = Gpu::with_policy(super::device::context::AdapterPolicy::Any)?;
    if !gpu.gemm_variant().is_f32() {
        gpu.set_gemm_variant(super::kernels::gemm::GemmVariant::Fast)?;
    }
    Ok(gpu)
}

/// The forward layers in `all_layers` order.
fn forward_layers(m: &GpuModel) -> Vec<&GpuLinear> {
    fn net(f: &GpuFoldNet) -> impl Iterator<Item = &GpuLinear> {
        f.encoder.iter().chain(&f.head).chain(&f.fold1).chain(&f.fold2)
    }
    net(&m.ppf).chain(net(&m.pc)).chain(&m.relative).collect()
}

impl DeviceTrainer {
    /// Uploads `weights` and the optimiser state `adam` (its moments in `tensor_order`).
    pub fn new(gpu: &Gpu, weights: &Weights, loss: LossSettings, adam: &Adam) -> Result<DeviceTrainer> {
        if loss.pose_trains_ppf {
            return Err(Error::invalid("the device trainer does not train PPF-FoldNet through the pose loss yet"));
        }
        if !gpu.gemm_variant().is_f32() {
            return Err(Error::invalid(format!(
                "the device trainer needs an f32 GEMM; this device runs {}",
                gpu.gemm_variant()
            )));
        }
        let order = tensor_order(&weights.config);
        let sizes_ok = adam.m.len() == order.len()
            && adam.v.len() == order.len()
            && order.iter().zip(adam.m.iter().zip(&adam.v)).all(|(t, (m, v))| m.len() == t.1 && v.len() == t.1);
        if !sizes_ok {
            return Err(Error::invalid("device trainer: the optimiser state does not match the model"));
        }
        let ctx = &gpu.context;
        let model = Model::from_weights(weights)?;
        let forward = GpuModel::upload(ctx, &model)?;
        let layers = DeviceLayerBuffers::upload(ctx, &LayerWeights::new(weights)?)?;
        let up = |v: &[f32]| GpuBuffer::from_slice(ctx, "adam moment", v);
        let moments = adam.m.iter().zip(&adam.v).map(|(m, v)| Ok([up(m)?, up(v)?])).collect::<Result<_>>()?;
        let adam = Adam { settings: adam.settings, steps: adam.steps, m: Vec::new(), v: Vec::new() };
        Ok(DeviceTrainer { model, loss, forward, layers, adam, moments, ws: Default::default(), in_flight: None })
    }

    /// Optimiser steps taken.
    pub fn steps(&self) -> u64 {
        self.adam.steps
    }

    /// The loss of `batch` and its gradient, without a step (read back; for checks).
    pub async fn gradients(&mut self, gpu: &Gpu, batch: &[PairSample]) -> Result<(Losses, Gradients)> {
        let fwd = self.record_forward(gpu, batch).await?;
        let mut rec = Recorder::new(gpu, "train backward");
        self.record_backward(&mut rec, &fwd)?;
        let reads: Vec<[usize; 2]> = (self.layers.weight_grads.iter().zip(&self.layers.bias_grads))
            .map(|(w, b)| [w, b].map(|t| rec.read(t.raw(), 0, (t.len() * 4) as u64)))
            .collect();
        let bytes = rec.finish().await?;
        let mut grads = Gradients::zeros(&self.model.config);
        for (layer, [w, b]) in grads.layers.iter_mut().zip(reads) {
            layer.weight = bytemuck::pod_collect_to_vec(&bytes[w]);
            layer.bias = bytemuck::pod_collect_to_vec(&bytes[b]);
        }
        Ok((fwd.losses, grads))
    }

    /// One training step on `batch`: the loss, its gradient and an AdamW update, all on the device. Returns
    /// the losses (the batch means); an error, with nothing changed, when the loss is not finite.
    pub async fn step(&mut self, gpu: &Gpu, batch: &[PairSample]) -> Result<Losses> {
        let fwd = self.record_forward(gpu, batch).await?;
        if !fwd.losses.total.is_finite() {
            return Err(Error::invalid(format!(
                "the loss is not finite at step {} ({:?})",
                self.adam.steps, fwd.losses
            )));
        }
        let mut rec = Recorder::new(gpu, "train step");
        self.record_backward(&mut rec, &fwd)?;
        self.record_update(&mut rec)?;
        self.in_flight = Some(rec.submit()?);
        Ok(fwd.losses)
    }

    /// The weights as they are now (read back).
    pub async fn weights(&self, gpu: &Gpu) -> Result<Weights> {
        let mut rec = Recorder::new(gpu, "train weights");
        let biases = forward_layers(&self.forward);
        let reads: Vec<[usize; 2]> = (self.layers.weights.iter().zip(&biases))
            .map(|(w, l)| [rec.read(w.raw(), 0, (w.len() * 4) as u64), rec.read(&l.bias, 0, (l.out_dim * 4) as u64)])
            .collect();
        let bytes = rec.finish().await?;
        let config = self.model.config.clone();
        let mut tensors = std::collections::BTreeMap::new();
        for (spec, [w, b]) in crate::model::params::all_layers(&config).iter().zip(reads) {
            tensors.insert(format!("{}.weight", spec.name), bytemuck::pod_collect_to_vec(&bytes[w]));
            tensors.insert(format!("{}.bias", spec.name), bytemuck::pod_collect_to_vec(&bytes[b]));
        }
        Ok(Weights { config, tensors, notes: Default::default() })
    }

    /// The optimiser state as it is now (read back), for a checkpoint.
    pub async fn adam(&self, gpu: &Gpu) -> Result<Adam> {
        let mut rec = Recorder::new(gpu, "train adam");
        let reads: Vec<[usize; 2]> =
            self.moments.iter().map(|mv| mv.each_ref().map(|t| rec.read(t.raw(), 0, (t.len() * 4) as u64))).collect();
        let bytes = rec.finish().await?;
        let mut adam = self.adam.clone();
        for [m, v] in reads {
            adam.m.push(bytemuck::pod_collect_to_vec(&bytes[m]));
            adam.v.push(bytemuck::pod_collect_to_vec(&bytes[v]));
        }
        Ok(adam)
    }

    /// One FoldNet over the batch: encoder and decoder keeping their activations, the reconstruction loss per
    /// patch (read index returned) and its gradient, scaled by `0.25 / pairs` as the CPU objective.
    fn record_net<'a>(
        rec: &mut Recorder<'a>,
        gpu: &'a Gpu,
        ws: &mut Workspace,
        (net, f): (&FoldNet, &GpuFoldNet),
        input: &[f32],
        (patches, points): (usize, usize),
        scale: f32,
    ) -> Result<(NetPass, usize)> {
        let ctx = &gpu.context;
        let (d, m) = (net.net.io_width(), net.grid.len() / 2);
        let x = ws.upload(ctx, "train_input", input)?;
        let encode = record_encode_outputs(rec, gpu, ws, f, &x, (patches, points), Outputs::Kept(&HEAD_NAMES))?;
        let grid = ws.upload(ctx, "train_grid", &net.tiled_grid(patches))?;
        let kept = [Outputs::Kept(&FOLD_NAMES[0]), Outputs::Kept(&FOLD_NAMES[1])];
        let decode = record_decode_outputs(rec, gpu, ws, f, [&encode.codewords, &grid], patches, kept)?;
        let recon = &decode[1][decode[1].len() - 1];
        let rows = patches * (points + m);
        let nearest = ws.buffer(ctx, "train_nearest", (rows * 4) as u64)?;
        let distance = ws.buffer(ctx, "train_distance", (rows * 4) as u64)?;
        let params = ChamferNearestParams::new(patches, (points, m), d)?;
        super::kernels::chamfer_nearest::record(rec, &params, [&x, recon], [&nearest, &distance])?;
        let d_recon = ws.buffer(ctx, "train_d_recon", (patches * m * d * 4) as u64)?;
        let loss = ws.buffer(ctx, "train_rec_loss", (patches * 4) as u64)?;
        let params = ChamferGradParams::new(patches, (points, m), d, scale)?;
        super::kernels::chamfer_grad::record(rec, &params, [&x, recon, &nearest, &distance], [&d_recon, &loss])?;
        let read = rec.read(&loss, 0, (patches * 4) as u64);
        Ok((NetPass { input: x, encode, grid, decode, d_recon }, read))
    }

    /// The first submission (see the module docs) and the host's loss heads.
    async fn record_forward(&mut self, gpu: &Gpu, batch: &[PairSample]) -> Result<Forward> {
        if let Some(last) = self.in_flight.take() {
            last.wait(gpu).await?;
        }
        let config = &self.model.config;
        let n = config.points_per_patch;
        if batch.is_empty() {
            return Err(Error::invalid("empty training batch"));
        }
        for sample in batch {
            check_sample(&self.model, sample)?;
        }
        let (pairs, patches) = (batch.len(), 2 * batch.len());
        let scale = 1.0 / pairs as f64;
        let cw = config.codeword();
        let k = config.rotation_output.width();
        let ppf_in: Vec<f32> = batch.iter().flat_map(|s| s.ppf.iter().copied()).collect();
        let pc_in: Vec<f32> = batch.iter().flat_map(|s| s.pc.iter().copied()).collect();
        let rec_scale = (0.25 * scale) as f32;
        let [ws_ppf, ws_pc, ws_rel] = &mut self.ws;
        let mut rec = Recorder::new(gpu, "train forward");
        let fp = (&self.model.ppf, &self.forward.ppf);
        let (ppf, r_ppf) = Self::record_net(&mut rec, gpu, ws_ppf, fp, &ppf_in, (patches, n), rec_scale)?;
        let fc = (&self.model.pc, &self.forward.pc);
        let (pc, r_pc) = Self::record_net(&mut rec, gpu, ws_pc, fc, &pc_in, (patches, n), rec_scale)?;
        let ctx = &gpu.context;
        let identity: Vec<u32> = (0..patches as u32).collect();
        let rows = ws_rel.upload(ctx, "train_rows", &identity)?;
        let pose = ws_rel.buffer(ctx, "train_pose", (patches * cw * 4) as u64)?;
        let codewords = [&pc.encode.codewords, &ppf.encode.codewords, &rows];
        pose_feature::record(&mut rec, (patches, cw), codewords, &pose)?;
        let input = [(&pose, 2 * cw, 0)];
        let relative = record_relative_outputs(
            &mut rec,
            gpu,
            ws_rel,
            &self.forward.relative,
            &input,
            pairs,
            Outputs::Kept(&RELATIVE_NAMES),
        )?;
        let r_cw = rec.read(&ppf.encode.codewords, 0, (patches * cw * 4) as u64);
        let r_raw = rec.read(&relative[relative.len() - 1], 0, (pairs * k * 4) as u64);
        let bytes = rec.finish().await?;
        let floats = |i: usize| -> Vec<f32> { bytemuck::pod_collect_to_vec(&bytes[i]) };
        let (loss_ppf, loss_pc, ppf_cw, raw) = (floats(r_ppf), floats(r_pc), floats(r_cw), floats(r_raw));

        let s = self.loss;
        let mut losses = Losses::default();
        let rec_sum: f64 = loss_ppf.iter().zip(&loss_pc).map(|(a, b)| 0.25 * (f64::from(*a) + f64::from(*b))).sum();
        losses.rec = rec_sum * scale;
        let mut d_raw = vec![0.0f32; pairs * k];
        let mut d_ppf_codewords = vec![0.0f32; patches * cw];
        for (i, sample) in batch.iter().enumerate() {
            let pair_cw = &ppf_cw[2 * i * cw..][..2 * cw];
            let heads = PairHeads::new(&raw[i * k..][..k], config.rotation_output, &sample.label, pair_cw, &s, scale);
            losses.pose += heads.pose * scale;
            d_raw[i * k..][..k].copy_from_slice(&heads.d_raw);
            losses.feat += heads.feat * scale;
            heads.add_feat_gradient(&mut d_ppf_codewords[2 * i * cw..][..2 * cw], &s, scale);
        }
        let side = |p: usize| -> Vec<f32> {
            (0..pairs).flat_map(|i| ppf_cw[(2 * i + p) * cw..][..cw].iter().copied()).collect()
        };
        let (contrast, d_contrast) = contrast_terms(&side(0), &side(1), cw, &s);
        for (i, d) in d_contrast.iter().enumerate() {
            d_ppf_codewords[2 * i * cw..][..2 * cw].iter_mut().zip(d).for_each(|(o, g)| *o += g);
        }
        losses.total = s.weighted_total(losses.rec, losses.pose, losses.feat);
        add_contrast(&mut losses, contrast, &s);
        Ok(Forward { patches, ppf, pc, pose, relative, losses, d_ppf_codewords, d_raw })
    }

    /// Every backward pass of the batch into freshly zeroed gradient buffers.
    fn record_backward(&mut self, rec: &mut Recorder<'_>, fwd: &Forward) -> Result<()> {
        let gpu = rec.gpu();
        let ctx = &gpu.context;
        for g in self.layers.weight_grads.iter().chain(&self.layers.bias_grads) {
            rec.clear(g.raw());
        }
        let layers = self.layers.view();
        let (pc_base, rel_base) = bases(&self.model);
        let (patches, n) = (fwd.patches, self.model.config.points_per_patch);
        let s = self.loss;
        let [ws_ppf, ws_pc, ws_rel] = &mut self.ws;
        let d_ppf = ws_ppf.upload(ctx, "train_d_codewords", &fwd.d_ppf_codewords)?;
        let d_pc = ws_pc.buffer(ctx, "train_d_codewords", (fwd.d_ppf_codewords.len() * 4) as u64)?;
        rec.clear(&d_pc);
        let nets = [(&self.model.ppf, 0, &fwd.ppf, &d_ppf), (&self.model.pc, pc_base, &fwd.pc, &d_pc)];
        if s.rec {
            for &(net, base, pass, d_cw) in &nets {
                let tape = DeviceDecodeTape::from_outputs(&pass.decode, [&pass.encode.codewords, &pass.grid], patches);
                record_decode_backward(rec, net, &layers, base, &tape, pass.d_recon.clone(), d_cw)?;
            }
        }
        if s.pose {
            let d_raw = ws_rel.upload(ctx, "train_d_raw", &fwd.d_raw)?;
            let cw = self.model.config.codeword();
            let input = [DeviceSlice { x: &fwd.pose, width: 2 * cw, offset: 0, dx: Some(&d_pc) }];
            let outs: Vec<&wgpu::Buffer> = fwd.relative.iter().collect();
            record_relative_backward(rec, &self.model.relative, &layers, rel_base, &input, patches / 2, &outs, d_raw)?;
        }
        for &(net, base, pass, d_cw) in &nets {
            let tape = DeviceEncodeTape::from_outputs(&pass.encode, &pass.input, (patches, n));
            record_encode_backward(rec, net, &layers, base, &tape, d_cw)?;
        }
        Ok(())
    }

    /// AdamW on every tensor, then each forward weight refreshed from the updated one.
    fn record_update(&mut self, rec: &mut Recorder<'_>) -> Result<()> {
        let step = self.adam.next_step();
        let order = tensor_order(&self.model.config);
        let forward = forward_layers(&self.forward);
        for (i, (t, [m, v])) in order.iter().zip(&self.moments).enumerate() {
            let layer = i / 2;
            let (value, grad) = if i % 2 == 0 {
                (self.layers.weights[layer].raw(), self.layers.weight_grads[layer].raw())
            } else {
                (&forward[layer].bias, self.layers.bias_grads[layer].raw())
            };
            let params = adam_step::AdamStepParams::new(&step, t.2, t.1)?;
            adam_step::record(rec, &params, grad, value, m.raw(), v.raw())?;
        }
        for (w, l) in self.layers.weights.iter().zip(&forward) {
            super::kernels::transpose::record(rec, &TransposeParams::new(l.out_dim, l.in_dim)?, w.raw(), &l.weight_t)?;
        }
        Ok(())
    }
}
