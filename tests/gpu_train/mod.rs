//! The training kernels (the backward passes) against their CPU twins, which are what the CPU trainer runs.
//! Part of the `gpu_parity` binary (its `main` runs [`TESTS`] too).

use super::{EPS, SENTINEL, SUM_ERROR_FACTOR, assert_close, normals, seed};
use dpr_gpu::cpu::adam_step::AdamStep as Step;
use dpr_gpu::cpu::dense_weight_grad::SliceShape;
use dpr_gpu::gpu;
use dpr_gpu::gpu::adam_step::AdamStep;
use dpr_gpu::gpu::backward::{
    DeviceDenseLayer, DeviceEncodeTapeBuffers, DeviceLayerBuffers, DeviceSlice, record_dense_backward,
    record_encode_backward, record_relative_backward,
};
use dpr_gpu::gpu::buffer::GpuBuffer;
use dpr_gpu::gpu::dense_input_grad::DenseInputGrad;
use dpr_gpu::gpu::dense_weight_grad::DenseWeightGrad;
use dpr_gpu::gpu::group_row_sums::GroupRowSums;
use dpr_gpu::gpu::kernel::GpuKernel;
use dpr_gpu::gpu::max_pool_backward::MaxPoolBackward;
use dpr_gpu::gpu::recorder::Recorder;
use dpr_gpu::gpu::relu_backward::ReluBackward;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::model::params::all_layers;
use dpr_gpu::model::{Model, ModelConfig, Weights};
use dpr_gpu::rng::Rng;
use dpr_gpu::train::backward::{Gradients, LayerWeights, encode_backward, relative_backward};
use dpr_gpu::train::grad::{DenseGrads, DenseLayer, Segment, dense_backward};

mod chamfer;
mod tapes;
mod trainer;

/// The training kernels' parity tests, run by `gpu_parity`'s `main`.
pub const TESTS: &[(&str, fn())] = &[
    ("relu_backward_matches_cpu_at_zero_and_signed_zeros", relu_backward_matches_cpu_at_zero_and_signed_zeros),
    ("group_row_sums_matches_cpu_ragged", group_row_sums_matches_cpu_ragged),
    (
        "max_pool_backward_matches_cpu_with_ties_and_accumulation",
        max_pool_backward_matches_cpu_with_ties_and_accumulation,
    ),
    ("dense_weight_grad_matches_cpu_ragged", dense_weight_grad_matches_cpu_ragged),
    ("dense_input_grad_matches_cpu_ragged", dense_input_grad_matches_cpu_ragged),
    ("dense_backward_on_the_device_matches_the_cpu_trainer", dense_backward_on_the_device_matches_the_cpu_trainer),
    ("encode_backward_on_the_device_matches_the_cpu_trainer", encode_backward_on_the_device_matches_the_cpu_trainer),
    (
        "relative_backward_on_the_device_matches_the_cpu_trainer",
        relative_backward_on_the_device_matches_the_cpu_trainer,
    ),
    ("adam_step_matches_cpu_within_f32_rounding", adam_step_matches_cpu_within_f32_rounding),
    (
        "encode_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass",
        tapes::encode_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass,
    ),
    (
        "decode_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass",
        tapes::decode_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass,
    ),
    (
        "relative_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass",
        tapes::relative_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass,
    ),
    ("chamfer_nearest_matches_cpu_up_to_near_ties", chamfer::chamfer_nearest_matches_cpu_up_to_near_ties),
    ("chamfer_grad_matches_cpu_on_both_branches", chamfer::chamfer_grad_matches_cpu_on_both_branches),
    ("transpose_matches_cpu_exactly", transpose_matches_cpu_exactly),
    ("device_objective_matches_the_cpu_trainer", trainer::device_objective_matches_the_cpu_trainer),
    (
        "device_step_applies_adamw_and_refreshes_the_forward_weights",
        trainer::device_step_applies_adamw_and_refreshes_the_forward_weights,
    ),
    ("device_training_resumes_bit_for_bit", trainer::device_training_resumes_bit_for_bit),
    (
        "train_cli_on_the_device_matches_the_cpu_and_resumes",
        trainer::train_cli_on_the_device_matches_the_cpu_and_resumes,
    ),
];

/// The transpose (a refreshed forward weight) against its twin, bit for bit, over ragged shapes past a
/// workgroup; every output element written (the sentinel never survives).
fn transpose_matches_cpu_exactly() {
    let Some(g) = gpu() else { return };
    let s = seed(154);
    let mut rng = Rng::new(s);
    for (rows, cols) in [(1, 1), (1, 70), (37, 67), (130, 9), (256, 4)] {
        let x = normals(&mut rng, rows * cols);
        let want = dpr_gpu::cpu::transpose::transpose(&x, rows, cols);
        let mut got = vec![SENTINEL; x.len()];
        dpr_gpu::block_on(gpu::transpose::run(&g, &x, rows, cols, &mut got)).unwrap();
        assert_close(&format!("transpose {rows} x {cols}"), s, &got, &want, |_| 0.0);
    }
}

/// Slices of a layer: a full layer, the skip concatenation's second part, ragged sizes past a workgroup, one
/// row (the group sums of a single patch's shared input).
const SLICES: &[SliceShape] = &[
    SliceShape { rows: 1, out_dim: 1, in_dim: 1, width: 1, offset: 0 },
    SliceShape { rows: 37, out_dim: 67, in_dim: 5, width: 5, offset: 0 },
    SliceShape { rows: 200, out_dim: 33, in_dim: 100, width: 36, offset: 64 },
    SliceShape { rows: 1, out_dim: 20, in_dim: 70, width: 64, offset: 3 },
    SliceShape { rows: 45, out_dim: 9, in_dim: 130, width: 129, offset: 1 },
];

/// Both sides add the same terms in the same order, but a GPU may contract products and sums into FMAs: allow
/// the sequential-sum bound `n * eps * (|start| + sum |terms|)` for each side, `n` the terms plus 2.
fn sum_tolerance(terms: usize, start: f32, abs_terms: f32) -> f32 {
    SUM_ERROR_FACTOR * (terms + 2) as f32 * EPS * (start.abs() + abs_terms)
}

/// Positive, negative, zero and negative-zero outputs (only strictly positive ones pass the gradient), past
/// one workgroup: one comparison and a select, so the same bits.
fn relu_backward_matches_cpu_at_zero_and_signed_zeros() {
    let Some(g) = gpu() else { return };
    let s = seed(144);
    let mut rng = Rng::new(s);
    let mut out = normals(&mut rng, 1000);
    out[..4].copy_from_slice(&[0.0, -0.0, f32::MIN_POSITIVE, -f32::MIN_POSITIVE]);
    out.iter_mut().skip(4).step_by(7).for_each(|v| *v = 0.0);
    let d_out = normals(&mut rng, out.len());
    let want = ReluBackward::CPU_TWIN(&out, &d_out);
    let mut got = vec![SENTINEL; out.len()];
    dpr_gpu::block_on(gpu::relu_backward::run(&g, &out, &d_out, &mut got)).unwrap();
    assert_close("relu_backward", s, &got, &want, |_| 0.0);
}

/// Groups of one row, of many rows, and wide rows past a workgroup. Each sum adds its rows in order from zero on
/// both sides, with no products to contract: the same bits.
fn group_row_sums_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(145);
    let mut rng = Rng::new(s);
    for (groups, rows_per_group, width) in [(1, 1, 1), (3, 1, 70), (4, 45, 9), (2, 300, 130)] {
        let x = normals(&mut rng, groups * rows_per_group * width);
        let want = GroupRowSums::CPU_TWIN(&x, rows_per_group, width);
        let mut got = vec![SENTINEL; groups * width];
        dpr_gpu::block_on(gpu::group_row_sums::run(&g, &x, rows_per_group, width, &mut got)).unwrap();
        assert_close(&format!("group_row_sums {groups}x{rows_per_group}x{width}"), s, &got, &want, |_| 0.0);
    }
}

/// Ties (equal values in a channel, where the lowest row must win), a group of one row, negative inputs, and
/// a gradient added to a nonzero `dx`.
fn max_pool_backward_matches_cpu_with_ties_and_accumulation() {
    let Some(g) = gpu() else { return };
    let s = seed(141);
    let mut rng = Rng::new(s);
    for (groups, rows, channels) in [(1, 1, 1), (5, 37, 67), (3, 1, 130), (2, 300, 5)] {
        let mut x = normals(&mut rng, groups * rows * channels);
        x[..rows * channels].iter_mut().for_each(|v| *v = -v.abs() - 1.0);
        // Round to quarters so channels hold many exact ties.
        x.iter_mut().skip(rows * channels).step_by(2).for_each(|v| *v = (*v * 4.0).round() / 4.0);
        let d_out = normals(&mut rng, groups * channels);
        let start = normals(&mut rng, x.len());
        let mut want = start.clone();
        MaxPoolBackward::CPU_TWIN(&x, groups, rows, channels, &d_out, &mut want);
        let mut got = start.clone();
        dpr_gpu::block_on(gpu::max_pool_backward::run(&g, &x, groups, rows, channels, &d_out, &mut got)).unwrap();
        // One addition per element at most, in the same order: the same bits.
        assert_close(&format!("max_pool_backward {groups}x{rows}x{channels}"), s, &got, &want, |_| 0.0);
    }
}

/// With and without the bias gradient, added to nonzero gradients; columns outside the slice stay as they were.
fn dense_weight_grad_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(142);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let x = normals(&mut rng, shape.rows * shape.width);
        let (w_start, b_start) = (normals(&mut rng, shape.out_dim * shape.in_dim), normals(&mut rng, shape.out_dim));
        for bias in [true, false] {
            let (mut want_w, mut want_b) = (w_start.clone(), b_start.clone());
            DenseWeightGrad::CPU_TWIN(shape, &dz, &x, &mut want_w, bias.then_some(&mut want_b[..]));
            let mut got_w = w_start.clone();
            let mut got_b = if bias { b_start.clone() } else { vec![SENTINEL; shape.out_dim] };
            dpr_gpu::block_on(gpu::dense_weight_grad::run(
                &g,
                shape,
                &dz,
                &x,
                &mut got_w,
                bias.then_some(&mut got_b[..]),
            ))
            .unwrap();
            let tol_w = |i: usize| {
                let (o, col) = (i / shape.in_dim, i % shape.in_dim);
                let Some(c) = col.checked_sub(shape.offset).filter(|&c| c < shape.width) else { return 0.0 };
                let terms: f32 =
                    (0..shape.rows).map(|r| (dz[r * shape.out_dim + o] * x[r * shape.width + c]).abs()).sum();
                sum_tolerance(shape.rows, w_start[i], terms)
            };
            // tol_w is 0 outside the slice: those columns must keep their starting bits.
            assert_close(&format!("dense_weight_grad weights {shape:?}"), s, &got_w, &want_w, tol_w);
            if bias {
                let tol_b = |o: usize| {
                    let terms: f32 = (0..shape.rows).map(|r| dz[r * shape.out_dim + o].abs()).sum();
                    sum_tolerance(shape.rows, b_start[o], terms)
                };
                assert_close(&format!("dense_weight_grad bias {shape:?}"), s, &got_b, &want_b, tol_b);
            }
        }
    }
}

/// Added to a nonzero `dx`.
fn dense_input_grad_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(143);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let weight = normals(&mut rng, shape.out_dim * shape.in_dim);
        let start = normals(&mut rng, shape.rows * shape.width);
        let mut want = start.clone();
        DenseInputGrad::CPU_TWIN(shape, &dz, &weight, &mut want);
        let mut got = start.clone();
        dpr_gpu::block_on(gpu::dense_input_grad::run(&g, shape, &dz, &weight, &mut got)).unwrap();
        let tol = |i: usize| {
            let (r, c) = (i / shape.width, i % shape.width);
            let terms: f32 = (0..shape.out_dim)
                .map(|o| (dz[r * shape.out_dim + o] * weight[o * shape.in_dim + shape.offset + c]).abs())
                .sum();
            sum_tolerance(shape.out_dim, start[i], terms)
        };
        assert_close(&format!("dense_input_grad {shape:?}"), s, &got, &want, tol);
    }
}

/// An input slice, host side: `(x, width, offset, gradient start or None when not wanted)`.
type Slice = (Vec<f32>, usize, usize, Option<Vec<f32>>);

/// A dense layer's gradients: (weight, bias, shared input, per-row inputs).
type LayerGrads = (Vec<f32>, Vec<f32>, Option<Vec<f32>>, Vec<Option<Vec<f32>>>);

/// A dense layer's inputs and gradients, host side: what [`dense_backward`] and the device composition take.
struct LayerCase {
    rows: usize,
    rows_per_group: usize,
    in_dim: usize,
    out_dim: usize,
    relu: bool,
    weight: Vec<f32>,
    out: Vec<f32>,
    d_out: Vec<f32>,
    /// The input shared by each group of rows.
    group: Slice,
    /// The per-row inputs.
    segments: Vec<Slice>,
    weight_grad: Vec<f32>,
    bias_grad: Vec<f32>,
}

impl LayerCase {
    /// Random data: per-row slices of `widths` (gradient wanted where `want`), then the group input of
    /// `group_width` at `group_offset`; gradients start nonzero.
    #[expect(clippy::too_many_arguments, reason = "a layer's shape")]
    fn new(
        rng: &mut Rng,
        rows: usize,
        rows_per_group: usize,
        out_dim: usize,
        relu: bool,
        widths: &[(usize, usize, bool)],
        group_width: usize,
        group_offset: usize,
    ) -> LayerCase {
        let in_dim = widths.iter().map(|w| w.0).sum::<usize>() + group_width;
        let segments = widths
            .iter()
            .map(|&(w, offset, want)| (normals(rng, rows * w), w, offset, want.then(|| normals(rng, rows * w))))
            .collect();
        let groups = rows / rows_per_group;
        LayerCase {
            rows,
            rows_per_group,
            in_dim,
            out_dim,
            relu,
            weight: normals(rng, out_dim * in_dim),
            out: normals(rng, rows * out_dim),
            d_out: normals(rng, rows * out_dim),
            group: (
                normals(rng, groups * group_width),
                group_width,
                group_offset,
                Some(normals(rng, groups * group_width)),
            ),
            segments,
            weight_grad: normals(rng, out_dim * in_dim),
            bias_grad: normals(rng, out_dim),
        }
    }

    /// Every value replaced by its magnitude (`out` kept: it only masks): run through the same sums, it gives
    /// `|start| + sum |terms|` of every gradient element, the scale of its rounding error.
    fn magnitudes(&self) -> LayerCase {
        let abs = |v: &Vec<f32>| v.iter().map(|x| x.abs()).collect::<Vec<f32>>();
        let slice = |s: &Slice| (abs(&s.0), s.1, s.2, s.3.as_ref().map(abs));
        LayerCase {
            weight: abs(&self.weight),
            out: self.out.clone(),
            d_out: abs(&self.d_out),
            group: slice(&self.group),
            segments: self.segments.iter().map(slice).collect(),
            weight_grad: abs(&self.weight_grad),
            bias_grad: abs(&self.bias_grad),
            ..*self
        }
    }

    /// The CPU trainer's backward pass: (weight, bias, group, segments) gradients.
    fn cpu(&self) -> LayerGrads {
        let (mut w, mut b) = (self.weight_grad.clone(), self.bias_grad.clone());
        let mut dg = self.group.3.clone();
        let mut ds: Vec<Option<Vec<f32>>> = self.segments.iter().map(|s| s.3.clone()).collect();
        let layer = DenseLayer { weight: &self.weight, in_dim: self.in_dim, out_dim: self.out_dim, relu: self.relu };
        let segments: Vec<Segment<'_>> =
            self.segments.iter().map(|s| Segment { x: &s.0, width: s.1, offset: s.2 }).collect();
        let group = Segment { x: &self.group.0, width: self.group.1, offset: self.group.2 };
        let mut grads = DenseGrads {
            weight: &mut w,
            bias: &mut b,
            group: dg.as_deref_mut(),
            segments: ds.iter_mut().map(|d| d.as_deref_mut()).collect(),
        };
        dense_backward(
            &layer,
            self.rows,
            self.rows_per_group,
            &self.out,
            &self.d_out,
            Some(group),
            &segments,
            &mut grads,
        );
        (w, b, dg, ds)
    }

    /// The same on the device, in one submission; only the gradients come back.
    fn device(&self, g: &gpu::Gpu) -> LayerGrads {
        let up = |v: &[f32]| GpuBuffer::from_slice(&g.context, "case", v).unwrap();
        let (weight, out, d_out) = (up(&self.weight), up(&self.out), up(&self.d_out));
        let (wg, bg) = (up(&self.weight_grad), up(&self.bias_grad));
        let slice_buffers = |s: &Slice| (up(&s.0), s.3.as_deref().map(up));
        let group_buffers = slice_buffers(&self.group);
        let segment_buffers: Vec<_> = self.segments.iter().map(slice_buffers).collect();
        fn device_slice<'b>(s: &Slice, b: &'b (GpuBuffer<f32>, Option<GpuBuffer<f32>>)) -> DeviceSlice<'b> {
            DeviceSlice { x: b.0.raw(), width: s.1, offset: s.2, dx: b.1.as_ref().map(|d| d.raw()) }
        }
        let layer = DeviceDenseLayer {
            weight: weight.raw(),
            in_dim: self.in_dim,
            out_dim: self.out_dim,
            relu: self.relu,
            weight_grad: wg.raw(),
            bias_grad: bg.raw(),
        };
        let group = device_slice(&self.group, &group_buffers);
        let segments: Vec<DeviceSlice<'_>> =
            self.segments.iter().zip(&segment_buffers).map(|(s, b)| device_slice(s, b)).collect();
        let mut rec = Recorder::new(g, "dense backward test");
        record_dense_backward(
            &mut rec,
            &layer,
            self.rows,
            self.rows_per_group,
            out.raw(),
            d_out.raw(),
            Some(group),
            &segments,
        )
        .unwrap();
        let read = |rec: &mut Recorder<'_>, b: &GpuBuffer<f32>| rec.read(b.raw(), 0, (b.len() * 4) as u64);
        let (rw, rb) = (read(&mut rec, &wg), read(&mut rec, &bg));
        let rg = group_buffers.1.as_ref().map(|d| read(&mut rec, d));
        let rs: Vec<Option<usize>> = segment_buffers.iter().map(|b| b.1.as_ref().map(|d| read(&mut rec, d))).collect();
        let bytes = dpr_gpu::block_on(rec.finish()).unwrap();
        let floats = |i: usize| bytemuck::cast_slice::<u8, f32>(&bytes[i]).to_vec();
        (floats(rw), floats(rb), rg.map(floats), rs.into_iter().map(|r| r.map(floats)).collect())
    }
}

/// The device composition of a dense layer's backward pass against the CPU trainer's, on the two shapes the
/// networks use: the head's first layer (the encoder outputs side by side with the global feature shared by
/// the patch, ReLU) and a fold's first layer (the codeword shared by the grid, then per-point coordinates whose
/// gradient is not wanted, no ReLU). Tolerance: the sequential-sum bound at each element's own magnitudes.
fn dense_backward_on_the_device_matches_the_cpu_trainer() {
    let Some(g) = gpu() else { return };
    let s = seed(146);
    let mut rng = Rng::new(s);
    let cases = [
        LayerCase::new(&mut rng, 3 * 20, 20, 24, true, &[(8, 0, true), (12, 8, true)], 12, 20),
        LayerCase::new(&mut rng, 2 * 25, 25, 10, false, &[(2, 16, false)], 16, 0),
    ];
    for (k, case) in cases.iter().enumerate() {
        let (want, got, scale) = (case.cpu(), case.device(&g), case.magnitudes().cpu());
        let terms = case.rows + case.out_dim;
        let tol = |scale: &[f32]| {
            let scale = scale.to_vec();
            move |i: usize| sum_tolerance(terms, 0.0, scale[i])
        };
        let what = |part: &str| format!("dense backward on the device, case {k}: {part}");
        assert_close(&what("weight"), s, &got.0, &want.0, tol(&scale.0));
        assert_close(&what("bias"), s, &got.1, &want.1, tol(&scale.1));
        let (gg, wg, sg) = (got.2.unwrap(), want.2.unwrap(), scale.2.unwrap());
        assert_close(&what("shared input"), s, &gg, &wg, tol(&sg));
        for (i, ((a, e), m)) in got.3.iter().zip(&want.3).zip(&scale.3).enumerate() {
            assert_eq!(a.is_some(), e.is_some());
            if let (Some(a), Some(e), Some(m)) = (a, e, m) {
                assert_close(&what(&format!("slice {i}")), s, a, e, tol(m));
            }
        }
    }
}

/// Queues the read-back of every gradient of `layers`: `(weight, bias)` read indices per layer.
fn read_gradients(rec: &mut Recorder<'_>, layers: &DeviceLayerBuffers) -> Vec<(usize, usize)> {
    let mut read = |b: &GpuBuffer<f32>| rec.read(b.raw(), 0, (b.len() * 4) as u64);
    layers.weight_grads.iter().zip(&layers.bias_grads).map(|(w, b)| (read(w), read(b))).collect()
}

/// The layers `touched` (indices into `all_layers`) must match the CPU trainer's gradients within 1e-3 of each
/// tensor's largest element (the same sums in the same order on both sides, up to FMA contraction through the
/// chain) and be nonzero there; every other layer must stay zero on both sides.
fn assert_gradients(
    what: &str,
    seed: u64,
    bytes: &[Vec<u8>],
    reads: &[(usize, usize)],
    want: &Gradients,
    touched: std::ops::Range<usize>,
) {
    let floats = |i: usize| bytemuck::cast_slice::<u8, f32>(&bytes[i]).to_vec();
    for (i, ((rw, rb), layer)) in reads.iter().zip(&want.layers).enumerate() {
        for (part, got, expected) in [("weight", floats(*rw), &layer.weight), ("bias", floats(*rb), &layer.bias)] {
            let largest = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            if touched.contains(&i) {
                assert!(largest > 0.0, "{what}, layer {i} {part}: a zero gradient tests nothing");
            } else {
                assert!(largest == 0.0, "{what}: the CPU trainer touched layer {i}");
            }
            assert_close(&format!("{what}, layer {i} {part}"), seed, &got, expected, |_| 1e-3 * largest);
        }
    }
}

/// A small model and its layers for the network tests.
fn small_model(seed: u64) -> (Weights, Model) {
    let weights = Weights::init(&ModelConfig { points_per_patch: 16, ..ModelConfig::default() }, seed).unwrap();
    let model = Model::from_weights(&weights).unwrap();
    (weights, model)
}

/// PPF-FoldNet's encoder backward pass on the device, from its forward tape uploaded, against the CPU trainer's
/// `encode_backward`: the gradient of every encoder and head layer (max-pool routing, the skip concatenation, the
/// broadcast global feature), and no other layer touched.
fn encode_backward_on_the_device_matches_the_cpu_trainer() {
    let Some(g) = gpu() else { return };
    let s = seed(147);
    let mut rng = Rng::new(s);
    let (weights, model) = small_model(s);
    let net = &model.ppf;
    let (patches, points) = (5, 16);
    let input = normals(&mut rng, patches * points * net.encoder[0].in_dim);
    let tape = net.encode_tape(&input, patches, points);
    let d_codeword = normals(&mut rng, patches * net.codeword_len());
    let w = LayerWeights::new(&weights).unwrap();
    let mut want = Gradients::zeros(&weights.config);
    encode_backward(net, &w, 0, &input, &tape, &d_codeword, &mut want);

    let layers = DeviceLayerBuffers::upload(&g.context, &w).unwrap();
    let tape_buffers = DeviceEncodeTapeBuffers::upload(&g.context, &input, &tape).unwrap();
    let d_cw = GpuBuffer::from_slice(&g.context, "d codeword", &d_codeword).unwrap();
    let mut rec = Recorder::new(&g, "encode backward test");
    record_encode_backward(&mut rec, net, &layers.view(), 0, &tape_buffers.view(), d_cw.raw()).unwrap();
    let reads = read_gradients(&mut rec, &layers);
    let bytes = dpr_gpu::block_on(rec.finish()).unwrap();
    assert_gradients("encode backward", s, &bytes, &reads, &want, 0..net.encoder.len() + net.head.len());
}

/// A small model and 7 rows of random source and target features with a random gradient of RelativeNet's raw
/// outputs, for the RelativeNet tests.
struct RelativeCase {
    weights: Weights,
    model: Model,
    /// RelativeNet's first layer in `all_layers` order.
    base: usize,
    rows: usize,
    /// Features per side.
    f: usize,
    source: Vec<f32>,
    target: Vec<f32>,
    d_raw: Vec<f32>,
}

fn relative_case(s: u64) -> RelativeCase {
    let mut rng = Rng::new(s);
    let (weights, model) = small_model(s);
    let net = &model.relative;
    let base = all_layers(&weights.config).iter().position(|l| l.name.starts_with("relative")).unwrap();
    let (rows, f) = (7, net.layers[0].in_dim / 2);
    let (source, target) = (normals(&mut rng, rows * f), normals(&mut rng, rows * f));
    let d_raw = normals(&mut rng, rows * net.layers.last().unwrap().out_dim);
    RelativeCase { weights, model, base, rows, f, source, target, d_raw }
}

/// RelativeNet's backward pass on the device against the CPU trainer's `relative_backward`: every layer's
/// gradient and the gradients w.r.t. the source and target features.
fn relative_backward_on_the_device_matches_the_cpu_trainer() {
    let Some(g) = gpu() else { return };
    let s = seed(149);
    let RelativeCase { weights, model, base, rows, f, source, target, d_raw } = relative_case(s);
    let net = &model.relative;
    let outs = net.forward_tape(&source, &target, rows);
    let w = LayerWeights::new(&weights).unwrap();
    let mut want = Gradients::zeros(&weights.config);
    let (want_ds, want_dt) = relative_backward(net, &w, base, &source, &target, rows, &outs, d_raw.clone(), &mut want);

    let up = |v: &[f32]| GpuBuffer::from_slice(&g.context, "relative backward", v).unwrap();
    let layers = DeviceLayerBuffers::upload(&g.context, &w).unwrap();
    let (source_b, target_b, d_raw_b) = (up(&source), up(&target), up(&d_raw));
    let outs_b: Vec<_> = outs.iter().map(|a| up(a)).collect();
    let outs_raw: Vec<&wgpu::Buffer> = outs_b.iter().map(|b| b.raw()).collect();
    let (ds_b, dt_b) = (up(&vec![0.0; rows * f]), up(&vec![0.0; rows * f]));
    let (ds, dt) = (ds_b.raw(), dt_b.raw());
    let inputs = [
        DeviceSlice { x: source_b.raw(), width: f, offset: 0, dx: Some(ds) },
        DeviceSlice { x: target_b.raw(), width: f, offset: f, dx: Some(dt) },
    ];
    let mut rec = Recorder::new(&g, "relative backward test");
    record_relative_backward(&mut rec, net, &layers.view(), base, &inputs, rows, &outs_raw, d_raw_b.raw().clone())
        .unwrap();
    let reads = read_gradients(&mut rec, &layers);
    let (r_ds, r_dt) = (rec.read(ds, 0, (rows * f * 4) as u64), rec.read(dt, 0, (rows * f * 4) as u64));
    let bytes = dpr_gpu::block_on(rec.finish()).unwrap();
    assert_gradients("relative backward", s, &bytes, &reads, &want, base..base + net.layers.len());
    for (part, r, expected) in [("source", r_ds, &want_ds), ("target", r_dt, &want_dt)] {
        let got = bytemuck::cast_slice::<u8, f32>(&bytes[r]).to_vec();
        let largest = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(largest > 0.0, "relative backward, {part}: a zero gradient tests nothing");
        assert_close(&format!("relative backward, {part} features"), s, &got, expected, |_| 1e-3 * largest);
    }
}

/// AdamW on the device (f32) against its twin (f64 per element): at the first step (large bias corrections)
/// and a late one, with and without weight decay, over gradients with zeros and tiny values. Each result within
/// a few f32 roundings of its terms: 4 eps of the moments' terms, and of `x` plus 1e-5 of the step.
fn adam_step_matches_cpu_within_f32_rounding() {
    let Some(g) = gpu() else { return };
    let s = seed(150);
    let mut rng = Rng::new(s);
    let n = 1000;
    for (t, decay) in [(1, true), (1000, false), (37, true)] {
        let (beta1, beta2): (f64, f64) = (0.9, 0.999);
        let step = Step {
            lr: 3e-4,
            beta1,
            beta2,
            eps: 1e-8,
            weight_decay: 1e-2,
            c1: 1.0 - beta1.powi(t),
            c2: 1.0 - beta2.powi(t),
        };
        let value = normals(&mut rng, n);
        let mut grad = normals(&mut rng, n);
        grad[..10].fill(0.0);
        grad[10..20].iter_mut().for_each(|v| *v *= 1e-6);
        let m: Vec<f32> = normals(&mut rng, n).iter().map(|v| v * 0.1).collect();
        let v: Vec<f32> = normals(&mut rng, n).iter().map(|v| v.abs() * 0.01).collect();
        let (mut want_x, mut want_m, mut want_v) = (value.clone(), m.clone(), v.clone());
        AdamStep::CPU_TWIN(&step, decay, &mut want_x, &grad, &mut want_m, &mut want_v);
        let (mut got_x, mut got_m, mut got_v) = (value.clone(), m.clone(), v.clone());
        dpr_gpu::block_on(gpu::adam_step::run(&g, &step, decay, &mut got_x, &grad, &mut got_m, &mut got_v)).unwrap();
        let what = |part: &str| format!("adam_step t={t} decay={decay}: {part}");
        let b = |x: f64| x as f32;
        let tol_m = |i: usize| 4.0 * EPS * (b(beta1) * m[i].abs() + b(1.0 - beta1) * grad[i].abs());
        let tol_v = |i: usize| 4.0 * EPS * (b(beta2) * v[i] + b(1.0 - beta2) * grad[i] * grad[i]);
        let wd = if decay { step.weight_decay } else { 0.0 };
        let tol_x = |i: usize| {
            let adam = (want_m[i] as f64 / step.c1) / ((want_v[i] as f64 / step.c2).sqrt() + step.eps);
            let size = step.lr * (adam.abs() + (wd * value[i] as f64).abs());
            4.0 * EPS * value[i].abs() + 1e-5 * size as f32
        };
        assert_close(&what("first moment"), s, &got_m, &want_m, tol_m);
        assert_close(&what("second moment"), s, &got_v, &want_v, tol_v);
        assert_close(&what("value"), s, &got_x, &want_x, tol_x);
        assert!(got_x.iter().zip(&value).filter(|(a, b)| a != b).count() > n / 2, "{}", what("the step moved nothing"));
    }
}
