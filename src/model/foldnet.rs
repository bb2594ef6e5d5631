//! PPF-FoldNet / PC-FoldNet on the CPU reference path: the shared encoder (per-point MLP, max-pool, skip
//! concatenation, per-point MLP, max-pool to the codeword) and the two-fold folding decoder.

use super::config::ModelConfig;
use super::linear::Linear;
use super::params::{Net, foldnet_layers};
use super::weights::WeightsView;
use crate::cpu::dense::DenseShape;
use crate::cpu::gemm::{BF16_MIN_IN_DIM, Precision, dense};
use crate::cpu::gemm_bf16::dense_bf16_packed_on;
use crate::cpu::gemm_int8::Int8Weight;
use crate::cpu::max_pool::max_pool;
use crate::error::Result;
use rayon::prelude::*;

/// One auto-encoder's layers.
#[derive(Clone, Debug)]
pub struct FoldNet {
    /// Which network (input width 4 or 3).
    pub net: Net,
    /// Per-point MLP before the first max-pool.
    pub encoder: Vec<Linear>,
    /// Per-point MLP after the skip concatenation.
    pub head: Vec<Linear>,
    /// First folding MLP (input [codeword | grid]).
    pub fold1: Vec<Linear>,
    /// Second folding MLP (input [codeword | fold-1 output]).
    pub fold2: Vec<Linear>,
    /// Folding grid, `grid_points x 2`.
    pub grid: Vec<f32>,
}

/// Rows processed per parallel task: enough to amortise, few enough to balance across cores.
const ROWS_PER_TASK: usize = 512;

/// `layer(x)` over `rows` rows with only the bias as group term.
pub(crate) fn apply(layer: &Linear, x: &[f32], rows: usize, relu: bool) -> Vec<f32> {
    apply_at(Precision::F32, layer, x, rows, relu)
}

/// [`apply`] at `precision`.
pub(crate) fn apply_at(precision: Precision, layer: &Linear, x: &[f32], rows: usize, relu: bool) -> Vec<f32> {
    dense_layer(precision, layer, &[(x, layer.in_dim, 0)], (rows, rows.max(1)), &layer.bias, relu)
}

/// One slice of a concatenated input: data (`rows x width`), its width, and the first row of the layer's
/// transposed weight that multiplies it.
pub(crate) type Slice<'a> = (&'a [f32], usize, usize);

/// `layer(concat(...))` where `per_group` (`groups x w`) is constant over each group of `rows_per_group`
/// rows and each segment is a per-row input; the concatenation is never built.
pub(crate) fn apply_concat(
    layer: &Linear,
    per_group: Slice<'_>,
    segments: &[Slice<'_>],
    rows: usize,
    rows_per_group: usize,
    relu: bool,
) -> Vec<f32> {
    apply_concat_at(Precision::F32, layer, per_group, segments, rows, rows_per_group, relu)
}

/// [`apply_concat`] at `precision` (the per-group term is always f32: it is one row per patch).
pub(crate) fn apply_concat_at(
    precision: Precision,
    layer: &Linear,
    per_group: Slice<'_>,
    segments: &[Slice<'_>],
    rows: usize,
    rows_per_group: usize,
    relu: bool,
) -> Vec<f32> {
    let (g_x, g_w, g_offset) = per_group;
    let groups = rows / rows_per_group;
    let group_term =
        dense_layer(Precision::F32, layer, &[(g_x, g_w, g_offset)], (groups, groups.max(1)), &layer.bias, false);
    dense_layer(precision, layer, segments, (rows, rows_per_group), &group_term, relu)
}

/// The rows of `layer` fed by `segments` over `rows` rows, plus `group_term` (one row per `rows_per_group`
/// rows), in a new output. f32: one call per segment, accumulating, exactly the twin's order. bf16 (where
/// [`bf16_segments`] allows): one multiply over the whole width with the layer's packed weight.
fn dense_layer(
    precision: Precision,
    layer: &Linear,
    segments: &[Slice<'_>],
    (rows, rows_per_group): (usize, usize),
    group_term: &[f32],
    relu: bool,
) -> Vec<f32> {
    let mut out = Vec::new();
    dense_layer_into(precision, layer, segments, (rows, rows_per_group), group_term, relu, &mut out);
    out
}

/// [`dense_layer`] into `out`, reusing its allocation (the encoder's tasks keep their buffers across
/// chunks).
fn dense_layer_into(
    precision: Precision,
    layer: &Linear,
    segments: &[Slice<'_>],
    (rows, rows_per_group): (usize, usize),
    group_term: &[f32],
    relu: bool,
    out: &mut Vec<f32>,
) {
    let n = layer.out_dim;
    // Every path below overwrites the whole output (the first multiply does not accumulate), so a buffer kept
    // from the previous chunk at the same size is not cleared first.
    if out.len() != rows * n {
        out.clear();
        out.resize(rows * n, 0.0);
    }
    if let Some(weight) = int8_weight(precision, layer, segments) {
        let parts: Vec<(&[f32], usize)> = segments.iter().map(|&(x, w, _)| (x, w)).collect();
        let shape = DenseShape { rows, in_dim: weight.k, out_dim: n, rows_per_group, accumulate: false, relu };
        crate::cpu::gemm_int8::dense_int8(&shape, &parts, weight, group_term, out);
        return;
    }
    if bf16_segments(precision, segments) {
        let parts: Vec<(&[f32], usize)> = segments.iter().map(|&(x, w, _)| (x, w)).collect();
        let in_dim = parts.iter().map(|p| p.1).sum();
        let shape = DenseShape { rows, in_dim, out_dim: n, rows_per_group, accumulate: false, relu };
        let packed = &layer.packed_bf16()[segments[0].2 / 2 * n..];
        dense_bf16_packed_on(layer.bf16_unit(), &shape, &parts, packed, group_term, out);
        return;
    }
    for (s, &(x, w, offset)) in segments.iter().enumerate() {
        let shape = DenseShape {
            rows,
            in_dim: w,
            out_dim: n,
            rows_per_group,
            accumulate: s > 0,
            relu: relu && s + 1 == segments.len(),
        };
        let term: &[f32] = if s == 0 { group_term } else { &[] };
        dense(&shape, x, layer.weight_t_rows(offset, w), term, out);
    }
}

/// `layers` one after another over `rows` rows from `input`, each with its bias and ReLU, into `outs[i]`
/// (their allocations reused).
fn chain_into(precision: Precision, layers: &[Linear], input: &[f32], rows: usize, outs: &mut [Vec<f32>]) {
    for (i, layer) in layers.iter().enumerate() {
        let (done, rest) = outs.split_at_mut(i);
        let x = done.last().map_or(input, |v| v.as_slice());
        let segment = [(x, layer.in_dim, 0)];
        dense_layer_into(precision, layer, &segment, (rows, rows.max(1)), &layer.bias, true, &mut rest[0]);
    }
}

/// Whether `segments` go through the bf16 layer as one input: bf16 asked for and available, at least
/// [`BF16_MIN_IN_DIM`] wide, the first weight row even and the segments' rows consecutive with even widths
/// (but the last), so they are rows of the layer's packed weight.
fn bf16_segments(precision: Precision, segments: &[Slice<'_>]) -> bool {
    let width: usize = segments.iter().map(|s| s.1).sum();
    matches!(precision, Precision::Bf16 | Precision::Int8)
        && Precision::Bf16.is_available()
        && width >= BF16_MIN_IN_DIM
        && segments.first().is_some_and(|s| s.2 % 2 == 0)
        && segments.iter().rev().skip(1).all(|s| s.1 % 2 == 0)
        && segments.windows(2).all(|w| w[0].2 + w[0].1 == w[1].2)
}

/// The layer's int8 weight when `segments` go through the int8 layer: int8 asked for and available, at least
/// [`BF16_MIN_IN_DIM`] wide, and the segments the layer's weight rows from its first one on, consecutive.
fn int8_weight<'l>(precision: Precision, layer: &'l Linear, segments: &[Slice<'_>]) -> Option<&'l Int8Weight> {
    let width: usize = segments.iter().map(|s| s.1).sum();
    let usable = precision == Precision::Int8
        && Precision::Int8.is_available()
        && width >= BF16_MIN_IN_DIM
        && segments.first().is_some_and(|s| s.2 == 0)
        && segments.windows(2).all(|w| w[0].2 + w[0].1 == w[1].2);
    if usable { layer.quantized_int8(width) } else { None }
}

/// Everything the encoder computed for a batch of patches: the codewords, and every layer's output (what the
/// trainer's backward pass needs).
#[derive(Clone, Debug, Default)]
pub struct EncodeTape {
    /// Patches encoded.
    pub patches: usize,
    /// Points per patch.
    pub points: usize,
    /// Output of each encoder layer (after ReLU), `patches * points x width`.
    pub encoder: Vec<Vec<f32>>,
    /// Max-pool of the last encoder output, `patches x width`.
    pub global: Vec<f32>,
    /// Output of each head layer (after ReLU), `patches * points x width`.
    pub head: Vec<Vec<f32>>,
    /// Codewords, `patches x codeword`.
    pub codeword: Vec<f32>,
}

/// Everything the folding decoder computed.
#[derive(Clone, Debug)]
pub struct DecodeTape {
    /// Patches decoded.
    pub patches: usize,
    /// Output of each first-fold layer, `patches * grid_points x width`.
    pub fold1: Vec<Vec<f32>>,
    /// Output of each second-fold layer; the last is the reconstruction.
    pub fold2: Vec<Vec<f32>>,
}

impl DecodeTape {
    /// The reconstruction, `patches * grid_points x io_width`.
    pub fn output(&self) -> &[f32] {
        self.fold2.last().map_or(&[], Vec::as_slice)
    }
}

/// One folding MLP at `precision`: [codeword | x] through `layers`, ReLU on all but the last; every layer's
/// output.
fn fold(
    precision: Precision,
    layers: &[Linear],
    (codewords, cw): (&[f32], usize),
    x: (&[f32], usize),
    patches: usize,
    m: usize,
) -> Vec<Vec<f32>> {
    let rows = patches * m;
    let mut outs: Vec<Vec<f32>> = Vec::with_capacity(layers.len());
    let relu0 = layers.len() > 1;
    outs.push(apply_concat_at(precision, &layers[0], (codewords, cw, 0), &[(x.0, x.1, cw)], rows, m, relu0));
    for (i, layer) in layers.iter().enumerate().skip(1) {
        let h = apply_at(precision, layer, outs.last().expect("one fold output"), rows, i + 1 < layers.len());
        outs.push(h);
    }
    outs
}

impl FoldNet {
    /// Builds the network from checked weights.
    pub fn from_weights(weights: &WeightsView<'_>, net: Net) -> Result<FoldNet> {
        let c = &weights.config;
        let specs = foldnet_layers(c, net);
        // Transposed in parallel, checked in order (the first bad layer is the one reported).
        let layers: Vec<Result<Linear>> = specs.par_iter().map(|s| Linear::from_weights(weights, s)).collect();
        let layers: Vec<Linear> = layers.into_iter().collect::<Result<_>>()?;
        let (ne, nh) = (super::params::encoder_widths(c, net).len(), super::params::head_widths(c, net).len());
        let nf = c.fold_widths.len() + 1;
        let mut it = layers.into_iter();
        let mut take = |n: usize| (&mut it).take(n).collect::<Vec<_>>();
        Ok(FoldNet {
            net,
            encoder: take(ne),
            head: take(nh),
            fold1: take(nf),
            fold2: take(nf),
            grid: c.grid_coordinates(),
        })
    }

    /// Codewords of `patches` patches of `points` rows each (`input` is `patches x points x io_width`), in
    /// parallel chunks of patches.
    pub fn encode(&self, input: &[f32], patches: usize, points: usize) -> Vec<f32> {
        self.encode_at(Precision::F32, input, patches, points)
    }

    /// [`FoldNet::encode`] with the wide layers at `precision`.
    pub fn encode_at(&self, precision: Precision, input: &[f32], patches: usize, points: usize) -> Vec<f32> {
        let width = self.net.io_width();
        let per_task = (ROWS_PER_TASK / points.max(1)).max(1);
        input
            .par_chunks(per_task * points * width)
            .map_init(EncodeTape::default, |tape, chunk| {
                self.encode_into(precision, chunk, chunk.len() / (points * width), points, tape);
                tape.codeword.clone()
            })
            .flatten_iter()
            .collect::<Vec<f32>>()
            .into_iter()
            .take(patches * self.codeword_len())
            .collect()
    }

    /// Codeword length.
    pub fn codeword_len(&self) -> usize {
        self.head.last().map_or(0, |l| l.out_dim)
    }

    /// The encoder, the one definition inference and training share: per-point MLP, max-pool, skip
    /// concatenation `[enc_0 | enc_1 | ... | global]` (the global slice enters as the per-patch term, so it sits
    /// last in the weight's rows), per-point MLP, max-pool to the codeword. Keeps every layer's output.
    pub fn encode_tape(&self, input: &[f32], patches: usize, points: usize) -> EncodeTape {
        self.encode_tape_at(Precision::F32, input, patches, points)
    }

    /// [`FoldNet::encode_tape`] with the wide layers at `precision` (the trainer in f32 or bf16).
    pub fn encode_tape_at(&self, precision: Precision, input: &[f32], patches: usize, points: usize) -> EncodeTape {
        let mut tape = EncodeTape::default();
        self.encode_into(precision, input, patches, points, &mut tape);
        tape
    }

    /// [`FoldNet::encode_tape_at`] into `tape`, reusing its buffers.
    fn encode_into(&self, precision: Precision, input: &[f32], patches: usize, points: usize, tape: &mut EncodeTape) {
        let rows = patches * points;
        (tape.patches, tape.points) = (patches, points);
        tape.encoder.resize_with(self.encoder.len(), Vec::new);
        chain_into(precision, &self.encoder, input, rows, &mut tape.encoder);
        let last_w = self.encoder.last().map_or(0, |l| l.out_dim);
        tape.global = max_pool(tape.encoder.last().map_or(&[], Vec::as_slice), patches, points, last_w);
        let mut segments = Vec::with_capacity(tape.encoder.len());
        let mut offset = 0;
        for (a, layer) in tape.encoder.iter().zip(&self.encoder) {
            segments.push((a.as_slice(), layer.out_dim, offset));
            offset += layer.out_dim;
        }
        tape.head.resize_with(self.head.len(), Vec::new);
        let head0 = &self.head[0];
        let groups = rows / points.max(1);
        let group_term = dense_layer(
            Precision::F32,
            head0,
            &[(&tape.global, last_w, offset)],
            (groups, groups.max(1)),
            &head0.bias,
            false,
        );
        dense_layer_into(precision, head0, &segments, (rows, points), &group_term, true, &mut tape.head[0]);
        let (first, rest) = tape.head.split_at_mut(1);
        chain_into(precision, &self.head[1..], &first[0], rows, rest);
        tape.codeword = max_pool(tape.head.last().expect("head has layers"), patches, points, self.codeword_len());
    }

    /// The folding grid repeated for every patch.
    pub fn tiled_grid(&self, patches: usize) -> Vec<f32> {
        (0..patches).flat_map(|_| self.grid.iter().copied()).collect()
    }

    /// The decoder, shared by inference and training: two folds, each `[codeword | x]` through its MLP (x the
    /// grid, then the first fold's output). Keeps every layer's output.
    pub fn decode_tape(&self, codewords: &[f32], patches: usize) -> DecodeTape {
        self.decode_tape_at(Precision::F32, codewords, patches)
    }

    /// [`FoldNet::decode_tape`] with the wide layers at `precision` (the trainer in bf16).
    pub fn decode_tape_at(&self, precision: Precision, codewords: &[f32], patches: usize) -> DecodeTape {
        let cw = (codewords, self.codeword_len());
        let m = self.grid.len() / 2;
        let d = self.net.io_width();
        let grid = self.tiled_grid(patches);
        let fold1 = fold(precision, &self.fold1, cw, (&grid, 2), patches, m);
        let fold2 = fold(precision, &self.fold2, cw, (fold1.last().expect("fold1 has layers"), d), patches, m);
        DecodeTape { patches, fold1, fold2 }
    }

    /// Reconstruction (`patches x grid_points x io_width`) from codewords (`patches x codeword`).
    pub fn decode(&self, codewords: &[f32], patches: usize) -> Vec<f32> {
        self.decode_tape(codewords, patches).fold2.pop().unwrap_or_default()
    }
}

/// Dimensions a `FoldNet` expects, for callers that build inputs.
pub fn input_len(config: &ModelConfig, net: Net, patches: usize) -> usize {
    patches * config.points_per_patch * net.io_width()
}
