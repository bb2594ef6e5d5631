//! The training objective `L = L_rec + lambda1 L_pose + lambda2 L_feat` on a batch of corresponding patch
//! pairs, and its gradient w.r.t. every parameter.
//!
//! Per pair (source patch p, target patch q, label q* = rotation of target_from_source):
//! - `L_rec = mean over {p, q} of 1/2 (d_cham(PC, PC^) + d_cham(PPF, PPF^))`;
//! - `L_pose`: RelativeNet's output on `[f_pc(p) - f_ppf(p) | f_pc(q) - f_ppf(q)]` against the label rotation,
//!   `min(|q - q*|, |q + q*|)` for the paper's quaternion output or `|R - R*|_F / 2` for the 6-D output
//!   ([`super::loss::rotation_loss`]);
//! - `L_feat = |f_ppf(p) - f_ppf(q)|`;
//! - optionally `L_contrast`, over the whole batch: each pair's PPF codewords closer to each other than to the
//!   hardest other pair's by a margin ([`super::contrast`]), weighted by lambda3.
//!
//! The batch loss is the mean over pairs (the paper sums `L_feat` over the correspondences; with a fixed batch
//! size that is the same up to the scale of lambda2). A term can be dropped (the paper's ablation): its value
//! is still computed and reported, but it adds nothing to the loss or the gradient. The contrastive term is the
//! exception: it costs a PPF-FoldNet pass over the batch, so it is evaluated only when trained (0 otherwise).

use super::backward::{Gradients, LayerWeights, decode_backward, encode_backward, relative_backward};
use super::contrast::hardest_negative_loss;
use super::loss::{chamfer, feat_loss, rotation_loss};
use crate::cpu::gemm::Precision;
use crate::cpu::gemm_bf16::Bf16Unit;
use crate::error::{Error, Result};
use crate::model::config::RotationOutput;
use crate::model::foldnet::EncodeTape;
use crate::model::params::foldnet_layers;
use crate::model::{Model, Net, Weights, pose_feature};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One training pair: two patches (source first) and the relative rotation between them.
#[derive(Clone, Debug, PartialEq)]
pub struct PairSample {
    /// PPF-FoldNet inputs, `2 x points_per_patch x 4` (source patch, then target patch).
    pub ppf: Vec<f32>,
    /// PC-FoldNet inputs, `2 x points_per_patch x 3` (source patch, then target patch), each centred on its
    /// keypoint, divided by the radius and expressed in the model's pose frame (its fragment's augmented frame,
    /// or its keypoint's normal frame).
    pub pc: Vec<f32>,
    /// The rotation RelativeNet regresses, row-major: target_from_source between the two patches' frames (maps
    /// source-patch directions into the target patch's frame).
    pub label: [f64; 9],
}

/// Which terms are trained and their weights.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossSettings {
    /// Train on the reconstruction loss.
    pub rec: bool,
    /// Train on the pose loss.
    pub pose: bool,
    /// Train on the feature-consistency loss.
    pub feat: bool,
    /// lambda1, the weight of `L_pose`.
    pub lambda_pose: f64,
    /// lambda2, the weight of `L_feat`.
    pub lambda_feat: f64,
    /// Let `L_pose` train PPF-FoldNet too (through the PPF codeword in the pose feature). Off by default: the
    /// PPF codeword is then a constant to the pose loss, so the rotation head cannot pull the matching features
    /// away from what reconstruction and feature consistency ask of them.
    #[serde(default)]
    pub pose_trains_ppf: bool,
    /// Train on the batch contrastive loss (off in older runs' settings).
    #[serde(default)]
    pub contrast: bool,
    /// lambda3, the weight of `L_contrast`.
    #[serde(default = "default_lambda_contrast")]
    pub lambda_contrast: f64,
    /// The contrastive margin as a fraction of the batch's mean distance between non-corresponding codewords.
    #[serde(default = "default_contrast_margin")]
    pub contrast_margin: f64,
}

fn default_lambda_contrast() -> f64 {
    1.0
}

fn default_contrast_margin() -> f64 {
    0.5
}

impl LossSettings {
    /// The trained per-pair terms, weighted: `L_rec + lambda1 L_pose + lambda2 L_feat` over the enabled ones
    /// (the batch's contrastive term is added by the caller).
    pub fn weighted_total(&self, rec: f64, pose: f64, feat: f64) -> f64 {
        [(self.rec, 1.0, rec), (self.pose, self.lambda_pose, pose), (self.feat, self.lambda_feat, feat)]
            .iter()
            .filter(|t| t.0)
            .map(|t| t.1 * t.2)
            .sum()
    }
}

impl Default for LossSettings {
    fn default() -> Self {
        LossSettings {
            rec: true,
            pose: true,
            feat: true,
            lambda_pose: 1.0,
            lambda_feat: 0.1,
            pose_trains_ppf: false,
            contrast: false,
            lambda_contrast: default_lambda_contrast(),
            contrast_margin: default_contrast_margin(),
        }
    }
}

/// Loss values (means over the batch). Disabled terms are still evaluated, for monitoring.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Losses {
    /// `L_rec`.
    pub rec: f64,
    /// `L_pose`.
    pub pose: f64,
    /// `L_feat`.
    pub feat: f64,
    /// `L_contrast` (a batch term; 0 with fewer than two pairs).
    pub contrast: f64,
    /// The trained total: the enabled terms, weighted.
    pub total: f64,
}

/// Index of the first PC-FoldNet layer and of the first RelativeNet layer in `all_layers` order.
pub(crate) fn bases(model: &Model) -> (usize, usize) {
    let per_net = foldnet_layers(&model.config, Net::Ppf).len();
    (per_net, 2 * per_net)
}

/// Refuses a pair whose patches do not have the model's number of points.
pub(crate) fn check_sample(model: &Model, sample: &PairSample) -> Result<()> {
    let n = model.config.points_per_patch;
    if sample.ppf.len() != 2 * n * 4 || sample.pc.len() != 2 * n * 3 {
        return Err(Error::invalid(format!(
            "training pair has {} PPF and {} PC values, expected {} and {} (2 patches of {n} points)",
            sample.ppf.len(),
            sample.pc.len(),
            2 * n * 4,
            2 * n * 3
        )));
    }
    Ok(())
}

/// What the batch terms computed for one pair, shared with its own terms: its PPF-FoldNet forward (the pair's
/// two patches) and the gradient of the batch terms w.r.t. its two PPF codewords (source then target, already
/// weighted).
pub struct BatchShare {
    /// PPF-FoldNet's forward on the pair's two patches, as [`FoldNet::encode_tape_at`] records it.
    ///
    /// [`FoldNet::encode_tape_at`]: crate::model::FoldNet::encode_tape_at
    pub ppf_tape: EncodeTape,
    /// The batch terms' gradient w.r.t. the two PPF codewords.
    pub d_ppf_codewords: Vec<f32>,
}

/// Loss of one pair, and (when `grads` is given) `scale` times its gradient added into `grads`, with the
/// multiplies at `w.precision`. `share` is what the batch terms computed for this pair: its PPF forward is
/// reused, and their codeword gradient back-propagated with the pair's own terms.
pub fn sample_objective(
    model: &Model,
    w: &LayerWeights<'_>,
    sample: &PairSample,
    settings: &LossSettings,
    scale: f64,
    share: Option<BatchShare>,
    grads: Option<&mut Gradients>,
) -> Result<Losses> {
    let n = model.config.points_per_patch;
    check_sample(model, sample)?;
    let (pc_base, rel_base) = bases(model);
    let precision = w.precision;
    let (ppf_e, batch_ppf_cw) = match share {
        Some(s) => (s.ppf_tape, Some(s.d_ppf_codewords)),
        None => (model.ppf.encode_tape_at(precision, &sample.ppf, 2, n), None),
    };
    let pc_e = model.pc.encode_tape_at(precision, &sample.pc, 2, n);
    let ppf_d = model.ppf.decode_tape_at(precision, &ppf_e.codeword, 2);
    let pc_d = model.pc.decode_tape_at(precision, &pc_e.codeword, 2);
    let m = model.config.grid_points();

    // Reconstruction: both patches, both networks.
    let mut rec = 0.0;
    let mut d_ppf_rec = vec![0.0f32; 2 * m * 4];
    let mut d_pc_rec = vec![0.0f32; 2 * m * 3];
    for p in 0..2 {
        let (c_pc, g_pc) = chamfer(&sample.pc[p * n * 3..][..n * 3], &pc_d.output()[p * m * 3..][..m * 3], 3);
        let (c_ppf, g_ppf) = chamfer(&sample.ppf[p * n * 4..][..n * 4], &ppf_d.output()[p * m * 4..][..m * 4], 4);
        rec += 0.25 * (c_pc + c_ppf);
        let k = (0.25 * scale) as f32;
        d_pc_rec[p * m * 3..][..m * 3].iter_mut().zip(&g_pc).for_each(|(d, g)| *d = k * g);
        d_ppf_rec[p * m * 4..][..m * 4].iter_mut().zip(&g_ppf).for_each(|(d, g)| *d = k * g);
    }

    // Pose: RelativeNet on the pose features (PC codeword minus PPF codeword) of source and target; feature
    // consistency on the PPF codewords.
    let cw = model.config.codeword();
    let feature = |p: usize| pose_feature(&pc_e.codeword[p * cw..][..cw], &ppf_e.codeword[p * cw..][..cw]);
    let (f_s, f_t) = (feature(0), feature(1));
    let rel = model.relative.forward_tape(&f_s, &f_t, 1);
    let raw = rel.last().expect("relative has layers");
    let mut heads = PairHeads::new(raw, model.config.rotation_output, &sample.label, &ppf_e.codeword, settings, scale);

    let (pose, feat) = (heads.pose, heads.feat);
    let total = settings.weighted_total(rec, pose, feat);
    let losses = Losses { rec, pose, feat, contrast: 0.0, total };
    let Some(grads) = grads else { return Ok(losses) };

    let mut d_ppf_cw = vec![0.0f32; 2 * cw];
    let mut d_pc_cw = vec![0.0f32; 2 * cw];
    if settings.rec {
        decode_backward(&model.ppf, w, 0, &ppf_e.codeword, &ppf_d, d_ppf_rec, &mut d_ppf_cw, grads);
        decode_backward(&model.pc, w, pc_base, &pc_e.codeword, &pc_d, d_pc_rec, &mut d_pc_cw, grads);
    }
    if settings.pose {
        let (d_fs, d_ft) = relative_backward(
            &model.relative,
            w,
            rel_base,
            &f_s,
            &f_t,
            1,
            &rel,
            std::mem::take(&mut heads.d_raw),
            grads,
        );
        for (p, d_f) in [d_fs, d_ft].iter().enumerate() {
            for (i, &g) in d_f.iter().enumerate() {
                d_pc_cw[p * cw + i] += g;
                if settings.pose_trains_ppf {
                    d_ppf_cw[p * cw + i] -= g;
                }
            }
        }
    }
    heads.add_feat_gradient(&mut d_ppf_cw, settings, scale);
    if let Some(extra) = batch_ppf_cw {
        d_ppf_cw.iter_mut().zip(&extra).for_each(|(d, g)| *d += g);
    }
    // An all-zero codeword gradient back-propagates to exactly zero: skip the work.
    if d_ppf_cw.iter().any(|&v| v != 0.0) {
        encode_backward(&model.ppf, w, 0, &sample.ppf, &ppf_e, &d_ppf_cw, grads);
    }
    if d_pc_cw.iter().any(|&v| v != 0.0) {
        encode_backward(&model.pc, w, pc_base, &sample.pc, &pc_e, &d_pc_cw, grads);
    }
    Ok(losses)
}

/// Samples of a batch are split into at most this many contiguous groups; each group accumulates its samples'
/// gradients, in order, into one buffer on one thread. The grouping depends only on the batch size, never on
/// the number of threads.
pub const MAX_GROUPS: usize = 8;

/// Mean loss over `samples` and its gradient, in f32: [`batch_objective_at`] with [`Precision::F32`].
pub fn batch_objective(
    weights: &Weights,
    samples: &[PairSample],
    settings: &LossSettings,
) -> Result<(Losses, Gradients)> {
    batch_objective_at(Precision::F32, weights, samples, settings)
}

/// Mean loss over `samples` and its gradient, the multiplies at `precision` (f32, or bf16 products with f32
/// sums for the wide layers: `grad::bf16_backward`). The batch is cut into at most [`MAX_GROUPS`] contiguous
/// groups (a function of the batch size only); groups run in parallel (rayon), in waves of one group per
/// thread, each accumulating its samples' gradients in sample order, and the group gradients are summed in
/// group order. The result is therefore bit-identical whatever the number of threads.
pub fn batch_objective_at(
    precision: Precision,
    weights: &Weights,
    samples: &[PairSample],
    settings: &LossSettings,
) -> Result<(Losses, Gradients)> {
    if samples.is_empty() {
        return Err(Error::invalid("empty training batch"));
    }
    let model = Model::from_weights(weights)?.with_bf16_unit(Bf16Unit::Tiles);
    let w = LayerWeights::with_precision(weights, precision)?;
    let (contrast, shares) = batch_terms(&model, precision, samples, settings)?;
    let scale = 1.0 / samples.len() as f64;
    let per_group = samples.len().div_ceil(MAX_GROUPS);
    let mut shares = shares.into_iter();
    let mut groups = samples
        .chunks(per_group)
        .map(|g| (g, (0..g.len()).map(|_| shares.next()).collect::<Vec<Option<BatchShare>>>()))
        .collect::<Vec<_>>()
        .into_iter();
    let mut total = Gradients::zeros(&weights.config);
    let mut losses = Losses::default();
    let wave_len = rayon::current_num_threads().max(1);
    loop {
        let wave: Vec<_> = groups.by_ref().take(wave_len).collect();
        if wave.is_empty() {
            break;
        }
        let results: Vec<Result<(Vec<Losses>, Gradients)>> = wave
            .into_par_iter()
            .map(|(group, group_shares)| {
                let mut g = Gradients::zeros(&weights.config);
                let l = group
                    .iter()
                    .zip(group_shares)
                    .map(|(s, share)| sample_objective(&model, &w, s, settings, scale, share, Some(&mut g)))
                    .collect::<Result<Vec<_>>>()?;
                Ok((l, g))
            })
            .collect();
        for r in results {
            let (ls, g) = r?;
            for l in ls {
                losses.add_scaled(&l, scale);
            }
            total.add_assign(&g);
        }
    }
    add_contrast(&mut losses, contrast, settings);
    Ok((losses, total))
}

/// Mean loss over `samples` without gradients (f32; parallel, deterministic).
pub fn batch_loss(weights: &Weights, samples: &[PairSample], settings: &LossSettings) -> Result<Losses> {
    let model = Model::from_weights(weights)?;
    let w = LayerWeights::new(weights)?;
    let scale = 1.0 / samples.len().max(1) as f64;
    let (contrast, shares) = batch_terms(&model, Precision::F32, samples, settings)?;
    let mut shares = shares.into_iter();
    let jobs: Vec<(&PairSample, Option<BatchShare>)> = samples.iter().map(|s| (s, shares.next())).collect();
    let all: Vec<Losses> = jobs
        .into_par_iter()
        .map(|(s, share)| sample_objective(&model, &w, s, settings, scale, share, None))
        .collect::<Result<_>>()?;
    let mut losses = Losses::default();
    all.iter().for_each(|l| losses.add_scaled(l, scale));
    add_contrast(&mut losses, contrast, settings);
    Ok(losses)
}

/// The batch terms (today the contrastive loss, evaluated only when enabled: it needs a PPF-FoldNet pass over
/// the batch first, at `precision`): their value and, per sample, what [`sample_objective`] reuses (the
/// forward and the weighted gradient w.r.t. its two PPF codewords; empty when disabled). The codewords are
/// those of the forward the sample's backward pass runs on, so the gradient is exact.
fn batch_terms(
    model: &Model,
    precision: Precision,
    samples: &[PairSample],
    settings: &LossSettings,
) -> Result<(f64, Vec<BatchShare>)> {
    if !settings.contrast || samples.len() < 2 {
        return Ok((0.0, Vec::new()));
    }
    let n = model.config.points_per_patch;
    let cw = model.config.codeword();
    let tapes: Vec<EncodeTape> = samples
        .par_iter()
        .map(|s| {
            check_sample(model, s)?;
            Ok(model.ppf.encode_tape_at(precision, &s.ppf, 2, n))
        })
        .collect::<Result<_>>()?;
    let source: Vec<f32> = tapes.iter().flat_map(|t| t.codeword[..cw].iter().copied()).collect();
    let target: Vec<f32> = tapes.iter().flat_map(|t| t.codeword[cw..].iter().copied()).collect();
    let (value, grads) = contrast_terms(&source, &target, cw, settings);
    let shares = tapes
        .into_iter()
        .zip(grads)
        .map(|(ppf_tape, d_ppf_codewords)| BatchShare { ppf_tape, d_ppf_codewords })
        .collect();
    Ok((value, shares))
}

/// The contrastive batch term of both trainers from the pairs' PPF codewords (`source` and `target`, pair by
/// pair, `cw` wide; enabled and two pairs or more): its value and, per pair, its gradient w.r.t. the pair's two
/// codewords (source then target), weighted by lambda3. (0, none) when disabled or under two pairs.
pub(crate) fn contrast_terms(
    source: &[f32],
    target: &[f32],
    cw: usize,
    settings: &LossSettings,
) -> (f64, Vec<Vec<f32>>) {
    let pairs = source.len() / cw.max(1);
    if !settings.contrast || pairs < 2 {
        return (0.0, Vec::new());
    }
    let (value, d_source, d_target) = hardest_negative_loss(source, target, cw, settings.contrast_margin);
    let k = settings.lambda_contrast as f32;
    let grads = (0..pairs)
        .map(|i| d_source[i * cw..][..cw].iter().chain(&d_target[i * cw..][..cw]).map(|g| k * g).collect())
        .collect();
    (value, grads)
}

/// The per-pair loss heads of both trainers (the CPU's [`sample_objective`] and the GPU trainer): the pose
/// loss of the raw RelativeNet output against the label, and the feature-consistency loss of the pair's two
/// PPF codewords, with their gradients.
pub(crate) struct PairHeads {
    /// `L_pose`.
    pub pose: f64,
    /// Gradient w.r.t. the raw output, weighted by lambda1 and the batch scale.
    pub d_raw: Vec<f32>,
    /// `L_feat`.
    pub feat: f64,
    /// Gradient of `L_feat` w.r.t. the source codeword (unweighted; the target's is its negation).
    d_feat: Vec<f32>,
}

impl PairHeads {
    /// The heads of one pair: `raw` RelativeNet output, `label` rotation, `ppf_codewords` source then target.
    pub fn new(
        raw: &[f32],
        output: RotationOutput,
        label: &[f64; 9],
        ppf_codewords: &[f32],
        settings: &LossSettings,
        scale: f64,
    ) -> PairHeads {
        let cw = ppf_codewords.len() / 2;
        let (pose, d) = rotation_loss(raw, output, label);
        let k_pose = (settings.lambda_pose * scale) as f32;
        let (feat, d_feat) = feat_loss(&ppf_codewords[..cw], &ppf_codewords[cw..]);
        PairHeads { pose, d_raw: d.iter().map(|g| g * k_pose).collect(), feat, d_feat }
    }

    /// Adds the weighted `L_feat` gradient into `d_ppf_codewords` (the pair's two codewords, source then
    /// target) when `L_feat` is trained.
    pub fn add_feat_gradient(&self, d_ppf_codewords: &mut [f32], settings: &LossSettings, scale: f64) {
        if !settings.feat {
            return;
        }
        let cw = self.d_feat.len();
        let k = (settings.lambda_feat * scale) as f32;
        for (i, &g) in self.d_feat.iter().enumerate() {
            d_ppf_codewords[i] += k * g;
            d_ppf_codewords[cw + i] -= k * g;
        }
    }
}

impl Losses {
    /// Adds `other`, weighted by `scale`, term by term (batch means, running means).
    pub fn add_scaled(&mut self, other: &Losses, scale: f64) {
        self.rec += other.rec * scale;
        self.pose += other.pose * scale;
        self.feat += other.feat * scale;
        self.contrast += other.contrast * scale;
        self.total += other.total * scale;
    }
}

/// Records the batch's contrastive loss, and adds it to the total when it is trained.
pub(crate) fn add_contrast(losses: &mut Losses, contrast: f64, settings: &LossSettings) {
    losses.contrast = contrast;
    if settings.contrast {
        losses.total += settings.lambda_contrast * contrast;
    }
}
