//! PPF-FoldNet / PC-FoldNet on the CPU reference path: the shared encoder (per-point MLP, max-pool, skip
//! concatenation, per-point MLP, max-pool to the codeword) and the two-fold folding decoder.

use super::config::ModelConfig;
use super::linear::Linear;
use super::params::{Net, foldnet_layers};
use super::weights::Weights;
use crate::cpu::dense::DenseShape;
use crate::cpu::gemm::dense;
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
const ROWS_PER_TASK: usize = 2048;

/// `layer(x)` over `rows` rows with only the bias as group term.
pub(crate) fn apply(layer: &Linear, x: &[f32], rows: usize, relu: bool) -> Vec<f32> {
    let mut out = vec![0.0; rows * layer.out_dim];
    let shape = DenseShape {
        rows,
        in_dim: layer.in_dim,
        out_dim: layer.out_dim,
        rows_per_group: rows.max(1),
        accumulate: false,
        relu,
    };
    dense(&shape, x, &layer.weight_t, &layer.bias, &mut out);
    out
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
    let (g_x, g_w, g_offset) = per_group;
    let groups = rows / rows_per_group;
    let mut group_term = vec![0.0; groups * layer.out_dim];
    let shape = DenseShape {
        rows: groups,
        in_dim: g_w,
        out_dim: layer.out_dim,
        rows_per_group: groups.max(1),
        accumulate: false,
        relu: false,
    };
    dense(&shape, g_x, layer.weight_t_rows(g_offset, g_w), &layer.bias, &mut group_term);
    let mut out = vec![0.0; rows * layer.out_dim];
    for (s, &(x, w, offset)) in segments.iter().enumerate() {
        let shape = DenseShape {
            rows,
            in_dim: w,
            out_dim: layer.out_dim,
            rows_per_group,
            accumulate: s > 0,
            relu: relu && s + 1 == segments.len(),
        };
        let term: &[f32] = if s == 0 { &group_term } else { &[] };
        dense(&shape, x, layer.weight_t_rows(offset, w), term, &mut out);
    }
    out
}

impl FoldNet {
    /// Builds the network from checked weights.
    pub fn from_weights(weights: &Weights, net: Net) -> Result<FoldNet> {
        let c = &weights.config;
        let specs = foldnet_layers(c, net);
        let layers: Vec<Linear> = specs.iter().map(|s| Linear::from_weights(weights, s)).collect::<Result<_>>()?;
        let (ne, nh, nf) = (c.encoder_widths.len(), c.head_widths.len(), c.fold_widths.len() + 1);
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

    /// Codewords of `patches` patches of `points` rows each (`input` is `patches x points x io_width`).
    pub fn encode(&self, input: &[f32], patches: usize, points: usize) -> Vec<f32> {
        let width = self.net.io_width();
        let per_task = (ROWS_PER_TASK / points.max(1)).max(1);
        input
            .par_chunks(per_task * points * width)
            .flat_map_iter(|chunk| self.encode_chunk(chunk, chunk.len() / (points * width), points))
            .collect::<Vec<f32>>()
            .into_iter()
            .take(patches * self.codeword_len())
            .collect()
    }

    /// Codeword length.
    pub fn codeword_len(&self) -> usize {
        self.head.last().map_or(0, |l| l.out_dim)
    }

    fn encode_chunk(&self, input: &[f32], patches: usize, points: usize) -> Vec<f32> {
        let rows = patches * points;
        let mut acts: Vec<Vec<f32>> = Vec::with_capacity(self.encoder.len());
        for layer in &self.encoder {
            let x = acts.last().map_or(input, |v| v.as_slice());
            acts.push(apply(layer, x, rows, true));
        }
        let last_w = self.encoder.last().map_or(0, |l| l.out_dim);
        let global = max_pool(acts.last().expect("encoder has layers"), patches, points, last_w);
        // Skip concatenation [enc_0 | enc_1 | ... | global]: the global slice goes in as the per-patch term,
        // so it sits last in the weight's rows; the encoder slices come first in order.
        let mut segments = Vec::with_capacity(acts.len());
        let mut offset = 0;
        for a in &acts {
            let w = a.len() / rows;
            segments.push((a.as_slice(), w, offset));
            offset += w;
        }
        let mut h = apply_concat(&self.head[0], (&global, last_w, offset), &segments, rows, points, true);
        for layer in &self.head[1..] {
            h = apply(layer, &h, rows, true);
        }
        max_pool(&h, patches, points, self.codeword_len())
    }

    /// Reconstruction (`patches x grid_points x io_width`) from codewords (`patches x codeword`).
    pub fn decode(&self, codewords: &[f32], patches: usize) -> Vec<f32> {
        let cw = self.codeword_len();
        let m = self.grid.len() / 2;
        let d = self.net.io_width();
        let grid_tiled: Vec<f32> = (0..patches).flat_map(|_| self.grid.iter().copied()).collect();
        let fold = |layers: &[Linear], x: &[f32], x_w: usize| {
            let rows = patches * m;
            let mut h = apply_concat(&layers[0], (codewords, cw, 0), &[(x, x_w, cw)], rows, m, layers.len() > 1);
            for (i, layer) in layers.iter().enumerate().skip(1) {
                h = apply(layer, &h, rows, i + 1 < layers.len());
            }
            h
        };
        let first = fold(&self.fold1, &grid_tiled, 2);
        fold(&self.fold2, &first, d)
    }
}

/// Dimensions a `FoldNet` expects, for callers that build inputs.
pub fn input_len(config: &ModelConfig, net: Net, patches: usize) -> usize {
    patches * config.points_per_patch * net.io_width()
}
