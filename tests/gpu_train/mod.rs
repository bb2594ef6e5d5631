//! The training kernels (the backward passes) against their CPU twins, which are what the CPU trainer runs.
//! Part of the `gpu_parity` binary (its `main` runs [`TESTS`] too).

use dpr_gpu::gpu;
use dpr_gpu::gpu::backward::{
    DeviceDenseLayer, DeviceEncodeTapeBuffers, DeviceLayerBuffers, DeviceSlice, record_dense_backward,
    record_encode_backward, record_relative_backward,
};
use dpr_gpu::gpu::buffer::GpuBuffer;
use dpr_gpu::gpu::parity::inference::{assert_close, normals, seed};
use dpr_gpu::gpu::parity::training::sum_tolerance;
use dpr_gpu::gpu::recorder::Recorder;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::model::params::all_layers;
use dpr_gpu::model::{Model, ModelConfig, Weights};
use dpr_gpu::rng::Rng;
use dpr_gpu::train::backward::{Gradients, LayerWeights, encode_backward, relative_backward};
use dpr_gpu::train::grad::{DenseGrads, DenseLayer, Segment, dense_backward};

mod tapes;
mod trainer;

/// The training kernels' parity tests, run by `gpu_parity`'s `main`.
pub const TESTS: &[(&str, fn())] = &[
    ("dense_backward_on_the_device_matches_the_cpu_trainer", dense_backward_on_the_device_matches_the_cpu_trainer),
    ("encode_backward_on_the_device_matches_the_cpu_trainer", encode_backward_on_the_device_matches_the_cpu_trainer),
    (
        "relative_backward_on_the_device_matches_the_cpu_trainer",
        relative_backward_on_the_device_matches_the_cpu_trainer,
    ),
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
