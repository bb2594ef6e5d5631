//! Backward passes of the whole networks: FoldNet encoder (per-point MLP, max-pool, skip concatenation with the
//! broadcast global feature, per-point MLP, max-pool), folding decoder (codeword broadcast to every grid point,
//! two folds) and RelativeNet, built from the layer backward passes in [`super::grad`].

use super::grad::{
    DenseGrads, DenseLayer, LayerInputs, Segment, dense_backward_at, max_pool_backward, max_pool_backward_acc,
};
use crate::cpu::gemm::Precision;
use crate::error::Result;
use crate::model::foldnet::{DecodeTape, EncodeTape};
use crate::model::params::{LayerSpec, all_layers};
use crate::model::{FoldNet, ModelConfig, RelativeNet, Weights, linear::Linear};

/// The gradient of one linear layer, in the `Weights` layout.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerGrad {
    /// `out x in`, row-major.
    pub weight: Vec<f32>,
    /// `out`.
    pub bias: Vec<f32>,
}

/// Gradients of every layer, in `params::all_layers` order (PPF-FoldNet, PC-FoldNet, RelativeNet).
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients {
    /// One entry per layer.
    pub layers: Vec<LayerGrad>,
}

impl Gradients {
    /// All-zero gradients for `config`.
    pub fn zeros(config: &ModelConfig) -> Gradients {
        let layers = all_layers(config)
            .iter()
            .map(|l| LayerGrad { weight: vec![0.0; l.in_dim * l.out_dim], bias: vec![0.0; l.out_dim] })
            .collect();
        Gradients { layers }
    }

    /// `self += other`, element by element (same config).
    pub fn add_assign(&mut self, other: &Gradients) {
        for (a, b) in self.layers.iter_mut().zip(&other.layers) {
            a.weight.iter_mut().zip(&b.weight).for_each(|(x, y)| *x += y);
            a.bias.iter_mut().zip(&b.bias).for_each(|(x, y)| *x += y);
        }
    }

    /// The gradient of the tensor `name` (e.g. "pc.head.0.weight"), if it exists.
    pub fn get(&self, config: &ModelConfig, name: &str) -> Option<&[f32]> {
        let (layer, kind) = name.rsplit_once('.')?;
        let index = all_layers(config).iter().position(|l| l.name == layer)?;
        let g = self.layers.get(index)?;
        match kind {
            "weight" => Some(&g.weight),
            "bias" => Some(&g.bias),
            _ => None,
        }
    }

    /// Euclidean norm over every element (f64 accumulation).
    pub fn norm(&self) -> f64 {
        let sq = |v: &[f32]| v.iter().map(|&x| (x as f64) * (x as f64)).sum::<f64>();
        self.layers.iter().map(|l| sq(&l.weight) + sq(&l.bias)).sum::<f64>().sqrt()
    }
}

/// The weights in `Weights` layout (`[out, in]`), per layer in `all_layers` order: what the backward passes
/// multiply by, and at which precision.
pub struct LayerWeights<'a> {
    /// The layer specs.
    pub specs: Vec<LayerSpec>,
    /// Each layer's weight.
    pub weights: Vec<&'a [f32]>,
    /// The arithmetic of the training multiplies: f32, or bf16 for the wide layers (`grad::bf16_backward`,
    /// and the forward's `FoldNet::encode_tape_at`).
    pub precision: Precision,
}

impl<'a> LayerWeights<'a> {
    /// Borrows every weight tensor of `weights`, for f32 training.
    pub fn new(weights: &'a Weights) -> Result<LayerWeights<'a>> {
        LayerWeights::with_precision(weights, Precision::F32)
    }

    /// Borrows every weight tensor of `weights`, for training at `precision`.
    pub fn with_precision(weights: &'a Weights, precision: Precision) -> Result<LayerWeights<'a>> {
        let specs = all_layers(&weights.config);
        let weights = specs.iter().map(|s| weights.get(&format!("{}.weight", s.name))).collect::<Result<_>>()?;
        Ok(LayerWeights { specs, weights, precision })
    }

    /// The dense-layer view of layer `index`.
    fn layer(&self, index: usize, relu: bool) -> DenseLayer<'a> {
        let s = &self.specs[index];
        DenseLayer { weight: self.weights[index], in_dim: s.in_dim, out_dim: s.out_dim, relu }
    }
}

/// Index of a FoldNet's first layer of each kind in `all_layers` order, given the network's first layer.
struct FoldIndex {
    encoder: usize,
    head: usize,
    fold1: usize,
    fold2: usize,
}

impl FoldIndex {
    fn new(net: &FoldNet, base: usize) -> FoldIndex {
        let head = base + net.encoder.len();
        let fold1 = head + net.head.len();
        FoldIndex { encoder: base, head, fold1, fold2: fold1 + net.fold1.len() }
    }
}

/// Runs `dense_backward` for layer `index` with the given inputs, accumulating into `grads.layers[index]`.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
fn layer_backward(
    w: &LayerWeights<'_>,
    grads: &mut Gradients,
    index: usize,
    relu: bool,
    rows: usize,
    rows_per_group: usize,
    out: &[f32],
    d_out: &[f32],
    group: Option<(Segment<'_>, Option<&mut [f32]>)>,
    segments: &[Segment<'_>],
    d_segments: Vec<Option<&mut [f32]>>,
) {
    let layer = w.layer(index, relu);
    let g = &mut grads.layers[index];
    let (group_in, d_group) = match group {
        Some((s, d)) => (Some(s), d),
        None => (None, None),
    };
    let mut dg = DenseGrads { weight: &mut g.weight, bias: &mut g.bias, group: d_group, segments: d_segments };
    let inputs = LayerInputs { rows, rows_per_group, group: group_in, segments };
    dense_backward_at(w.precision, &layer, &inputs, out, d_out, &mut dg);
}

/// A chain of plain layers `first..first + outs.len()` (outputs `outs`), ReLU
/// on those for which `relu(i)`: back-propagates `d_last` (w.r.t. the last output) down to the gradient w.r.t.
/// the first layer's output, which it returns; the first layer itself is left to the caller.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
fn chain_backward(
    w: &LayerWeights<'_>,
    grads: &mut Gradients,
    first: usize,
    layers: &[Linear],
    outs: &[Vec<f32>],
    rows: usize,
    relu: impl Fn(usize) -> bool,
    d_last: Vec<f32>,
) -> Vec<f32> {
    let mut d = d_last;
    for i in (1..layers.len()).rev() {
        let x = &outs[i - 1];
        let mut dx = vec![0.0; x.len()];
        let seg = [Segment { x, width: layers[i].in_dim, offset: 0 }];
        layer_backward(w, grads, first + i, relu(i), rows, rows, &outs[i], &d, None, &seg, vec![Some(&mut dx)]);
        d = dx;
    }
    d
}

/// Back-propagates through the encoder: `d_codeword` (`patches x codeword`) is the loss gradient w.r.t. the
/// codewords; parameter gradients accumulate into `grads`. `base` is the network's first layer index.
pub fn encode_backward(
    net: &FoldNet,
    w: &LayerWeights<'_>,
    base: usize,
    input: &[f32],
    tape: &EncodeTape,
    d_codeword: &[f32],
    grads: &mut Gradients,
) {
    let ix = FoldIndex::new(net, base);
    let (patches, points) = (tape.patches, tape.points);
    let rows = patches * points;
    let head_last = tape.head.last().expect("head has layers");
    let d_head_last = max_pool_backward(head_last, patches, points, net.codeword_len(), d_codeword);
    // Head layers after the first.
    let d_head0 = chain_backward(w, grads, ix.head, &net.head, &tape.head, rows, |_| true, d_head_last);
    // First head layer: [encoder outputs... | global] with the global feature broadcast over the patch.
    let mut d_enc: Vec<Vec<f32>> = tape.encoder.iter().map(|a| vec![0.0; a.len()]).collect();
    let last_w = net.encoder.last().map_or(0, |l| l.out_dim);
    let mut d_global = vec![0.0; tape.global.len()];
    {
        let mut segments = Vec::new();
        let mut offset = 0;
        for (a, layer) in tape.encoder.iter().zip(&net.encoder) {
            segments.push(Segment { x: a, width: layer.out_dim, offset });
            offset += layer.out_dim;
        }
        let group = Segment { x: &tape.global, width: last_w, offset };
        let d_segs = d_enc.iter_mut().map(|d| Some(d.as_mut_slice())).collect();
        let out = &tape.head[0];
        layer_backward(
            w,
            grads,
            ix.head,
            true,
            rows,
            points,
            out,
            &d_head0,
            Some((group, Some(&mut d_global))),
            &segments,
            d_segs,
        );
    }
    // The global max-pool routes its gradient to the argmax rows of the last encoder output.
    let enc_last = tape.encoder.last().expect("encoder has layers");
    let n_enc = d_enc.len();
    max_pool_backward_acc(enc_last, patches, points, last_w, &d_global, &mut d_enc[n_enc - 1]);
    // Encoder layers, last to first; each adds into the gradient of the previous layer's output.
    for i in (0..net.encoder.len()).rev() {
        let d = std::mem::take(&mut d_enc[i]);
        let (x, width) = if i == 0 {
            (input, net.encoder[0].in_dim)
        } else {
            (tape.encoder[i - 1].as_slice(), net.encoder[i].in_dim)
        };
        let seg = [Segment { x, width, offset: 0 }];
        let d_segs = if i == 0 { vec![None] } else { vec![Some(d_enc[i - 1].as_mut_slice())] };
        layer_backward(w, grads, ix.encoder + i, true, rows, rows, &tape.encoder[i], &d, None, &seg, d_segs);
    }
}

/// Back-propagates through one fold; `x` is the per-point input of its first layer; returns the gradient
/// w.r.t. `x` when `want_x`, and adds the codeword gradient into `d_codeword`.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
fn fold_backward(
    w: &LayerWeights<'_>,
    grads: &mut Gradients,
    first: usize,
    layers: &[Linear],
    outs: &[Vec<f32>],
    codewords: &[f32],
    x: &[f32],
    m: usize,
    d_out: Vec<f32>,
    d_codeword: &mut [f32],
    want_x: bool,
) -> Vec<f32> {
    let n = layers.len();
    let rows = outs[0].len() / layers[0].out_dim;
    let d0 = chain_backward(w, grads, first, layers, outs, rows, |i| i + 1 < n, d_out);
    let cw = codewords.len() / (rows / m).max(1);
    let x_w = layers[0].in_dim - cw;
    let mut dx = if want_x { vec![0.0; x.len()] } else { Vec::new() };
    let group = Segment { x: codewords, width: cw, offset: 0 };
    let seg = [Segment { x, width: x_w, offset: cw }];
    let d_segs = vec![if want_x { Some(dx.as_mut_slice()) } else { None }];
    layer_backward(w, grads, first, n > 1, rows, m, &outs[0], &d0, Some((group, Some(d_codeword))), &seg, d_segs);
    dx
}

/// Back-propagates through the decoder: `d_recon` is the loss gradient w.r.t. the reconstruction; the codeword
/// gradient is added into `d_codeword`. `base` is the network's first layer index.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
pub fn decode_backward(
    net: &FoldNet,
    w: &LayerWeights<'_>,
    base: usize,
    codewords: &[f32],
    tape: &DecodeTape,
    d_recon: Vec<f32>,
    d_codeword: &mut [f32],
    grads: &mut Gradients,
) {
    let ix = FoldIndex::new(net, base);
    let m = net.grid.len() / 2;
    let first = tape.fold1.last().expect("fold1 has layers");
    let d_first =
        fold_backward(w, grads, ix.fold2, &net.fold2, &tape.fold2, codewords, first, m, d_recon, d_codeword, true);
    let grid = net.tiled_grid(tape.patches);
    fold_backward(w, grads, ix.fold1, &net.fold1, &tape.fold1, codewords, &grid, m, d_first, d_codeword, false);
}

/// Back-propagates through RelativeNet from `d_raw` (gradient w.r.t. the raw 4-vectors); returns the
/// gradients w.r.t. the source and target features. `base` is RelativeNet's first layer index.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
pub fn relative_backward(
    net: &RelativeNet,
    w: &LayerWeights<'_>,
    base: usize,
    source: &[f32],
    target: &[f32],
    rows: usize,
    outs: &[Vec<f32>],
    d_raw: Vec<f32>,
    grads: &mut Gradients,
) -> (Vec<f32>, Vec<f32>) {
    let n = net.layers.len();
    let d0 = chain_backward(w, grads, base, &net.layers, outs, rows, |i| i + 1 < n, d_raw);
    let f = net.layers[0].in_dim / 2;
    let mut d_src = vec![0.0; source.len()];
    let mut d_tgt = vec![0.0; target.len()];
    let segs = [Segment { x: source, width: f, offset: 0 }, Segment { x: target, width: f, offset: f }];
    layer_backward(
        w,
        grads,
        base,
        n > 1,
        rows,
        rows,
        &outs[0],
        &d0,
        None,
        &segs,
        vec![Some(&mut d_src), Some(&mut d_tgt)],
    );
    (d_src, d_tgt)
}
