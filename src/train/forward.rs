//! The training forward pass: `FoldNet::encode`/`decode` and `RelativeNet::forward_raw`, step for step, keeping
//! every layer's output for the backward pass.
//!
//! The layers are `crate::model::foldnet`'s own `apply`/`apply_concat` (the fast `cpu::gemm` kernel, bit-for-bit
//! equal to the `cpu::dense` twin), so the codewords, reconstructions and quaternions equal the inference ones
//! bit for bit (checked in `tests/train.rs`).

use crate::cpu::max_pool::max_pool;
use crate::model::foldnet::{Slice, apply, apply_concat};
use crate::model::{FoldNet, RelativeNet, linear::Linear};

/// Everything the encoder computed for a batch of patches.
#[derive(Clone, Debug)]
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

/// `net.encode(input, patches, points)`, keeping the activations.
pub fn encode_tape(net: &FoldNet, input: &[f32], patches: usize, points: usize) -> EncodeTape {
    let rows = patches * points;
    let mut encoder: Vec<Vec<f32>> = Vec::with_capacity(net.encoder.len());
    for layer in &net.encoder {
        let x = encoder.last().map_or(input, |v| v.as_slice());
        encoder.push(apply(layer, x, rows, true));
    }
    let last_w = net.encoder.last().map_or(0, |l| l.out_dim);
    let global = max_pool(encoder.last().map_or(&[], Vec::as_slice), patches, points, last_w);
    let mut segments = Vec::with_capacity(encoder.len());
    let mut offset = 0;
    for (a, layer) in encoder.iter().zip(&net.encoder) {
        segments.push((a.as_slice(), layer.out_dim, offset));
        offset += layer.out_dim;
    }
    let mut head = Vec::with_capacity(net.head.len());
    head.push(apply_concat(&net.head[0], (&global, last_w, offset), &segments, rows, points, true));
    for layer in &net.head[1..] {
        let h = apply(layer, head.last().expect("one head output"), rows, true);
        head.push(h);
    }
    let codeword = max_pool(head.last().expect("head has layers"), patches, points, net.codeword_len());
    EncodeTape { patches, points, encoder, global, head, codeword }
}

/// The folding grid repeated for every patch.
pub(crate) fn tiled_grid(net: &FoldNet, patches: usize) -> Vec<f32> {
    (0..patches).flat_map(|_| net.grid.iter().copied()).collect()
}

/// One folding MLP: [codeword | x] through `layers`, ReLU on all but the last.
fn fold(
    layers: &[Linear],
    codewords: &[f32],
    cw: usize,
    x: &[f32],
    x_w: usize,
    patches: usize,
    m: usize,
) -> Vec<Vec<f32>> {
    let rows = patches * m;
    let mut outs = Vec::with_capacity(layers.len());
    outs.push(apply_concat(&layers[0], (codewords, cw, 0), &[(x, x_w, cw)], rows, m, layers.len() > 1));
    for (i, layer) in layers.iter().enumerate().skip(1) {
        let h = apply(layer, outs.last().expect("one fold output"), rows, i + 1 < layers.len());
        outs.push(h);
    }
    outs
}

/// `net.decode(codewords, patches)`, keeping the activations.
pub fn decode_tape(net: &FoldNet, codewords: &[f32], patches: usize) -> DecodeTape {
    let cw = net.codeword_len();
    let m = net.grid.len() / 2;
    let d = net.net.io_width();
    let grid = tiled_grid(net, patches);
    let fold1 = fold(&net.fold1, codewords, cw, &grid, 2, patches, m);
    let fold2 = fold(&net.fold2, codewords, cw, fold1.last().expect("fold1 has layers"), d, patches, m);
    DecodeTape { patches, fold1, fold2 }
}

/// `net.forward_raw(source, target, rows)`, keeping every layer's output (the last is the raw quaternion).
pub fn relative_tape(net: &RelativeNet, source: &[f32], target: &[f32], rows: usize) -> Vec<Vec<f32>> {
    if rows == 0 {
        return Vec::new();
    }
    let f = net.layers[0].in_dim / 2;
    let segs: [Slice<'_>; 2] = [(source, f, 0), (target, f, f)];
    let n = net.layers.len();
    let mut outs = Vec::with_capacity(n);
    outs.push(apply_concat(&net.layers[0], (&[], 0, 0), &segs, rows, rows, n > 1));
    for (i, layer) in net.layers.iter().enumerate().skip(1) {
        let h = apply(layer, outs.last().expect("one relative output"), rows, i + 1 < n);
        outs.push(h);
    }
    outs
}
