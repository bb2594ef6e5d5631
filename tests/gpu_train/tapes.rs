//! The networks' forward passes on the device keeping every activation (the trainer's forward tape), each
//! against the CPU forward tape, and the backward pass run from the device's own tape against the CPU trainer's
//! backward pass over that same tape read back. Reading the tape back makes the backward oracle exact in what
//! it routes (a max-pool's argmax is decided by the device's own activations on both sides), so the test checks
//! that the kept buffers are the tape the backward pass expects, not how two summation orders break ties.

use super::{RelativeCase, assert_gradients, read_gradients, relative_case, small_model};
use crate::{NETWORK_RTOL, assert_close, f32_gemm_gpu, normals, seed};
use dpr_gpu::gpu::backward::{
    DeviceDecodeTape, DeviceEncodeTape, DeviceLayerBuffers, DeviceSlice, record_decode_backward,
    record_encode_backward, record_relative_backward,
};
use dpr_gpu::gpu::buffer::{GpuBuffer, Workspace};
use dpr_gpu::gpu::nets::{
    FOLD_NAMES, GpuModel, HEAD_NAMES, Outputs, RELATIVE_NAMES, record_decode_outputs, record_encode_outputs,
    record_relative_outputs,
};
use dpr_gpu::gpu::recorder::Recorder;
use dpr_gpu::model::foldnet::{DecodeTape, EncodeTape};
use dpr_gpu::model::params::all_layers;
use dpr_gpu::rng::Rng;
use dpr_gpu::train::backward::{Gradients, LayerWeights, decode_backward, encode_backward, relative_backward};

/// Read `index` of a readback as floats.
fn floats(bytes: &[Vec<u8>], index: usize) -> Vec<f32> {
    bytemuck::cast_slice::<u8, f32>(&bytes[index]).to_vec()
}

/// Queues the read-back of the first `len` floats of each buffer.
fn read_all(rec: &mut Recorder<'_>, buffers: &[wgpu::Buffer], lens: impl Iterator<Item = usize>) -> Vec<usize> {
    buffers.iter().zip(lens).map(|(b, n)| rec.read(b, 0, (n * 4) as u64)).collect()
}

/// Each kept activation against the CPU forward's, within [`NETWORK_RTOL`] of the tensor's largest element.
fn assert_activations(what: &str, s: u64, got: &[Vec<f32>], want: &[Vec<f32>]) {
    assert_eq!(got.len(), want.len(), "{what}: layer count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let largest = w.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(largest > 0.0, "{what}, layer {i}: an all-zero activation tests nothing");
        assert_close(&format!("{what}, layer {i}"), s, g, w, |_| NETWORK_RTOL * largest);
    }
}

/// PPF-FoldNet's encoder on the device with its head kept: every layer's output, the global feature and the
/// codewords match the CPU tape, and the encoder's backward pass from the device tape matches the CPU trainer's.
pub fn encode_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass() {
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(150);
    let mut rng = Rng::new(s);
    let (weights, model) = small_model(s);
    let net = &model.ppf;
    let (patches, points) = (5, 16);
    let input = normals(&mut rng, patches * points * net.encoder[0].in_dim);
    let want = net.encode_tape(&input, patches, points);
    let d_codeword = normals(&mut rng, patches * net.codeword_len());

    let ctx = &g.context;
    let gpu_model = GpuModel::upload(ctx, &model).unwrap();
    let w = LayerWeights::new(&weights).unwrap();
    let layers = DeviceLayerBuffers::upload(ctx, &w).unwrap();
    let (x, d_cw) =
        (GpuBuffer::from_slice(ctx, "x", &input).unwrap(), GpuBuffer::from_slice(ctx, "d", &d_codeword).unwrap());
    let mut ws = Workspace::default();
    let mut rec = Recorder::new(&g, "encode tape test");
    let kept = Outputs::Kept(&HEAD_NAMES);
    let outs = record_encode_outputs(&mut rec, &g, &mut ws, &gpu_model.ppf, x.raw(), (patches, points), kept).unwrap();
    let tape = DeviceEncodeTape::from_outputs(&outs, x.raw(), (patches, points));
    record_encode_backward(&mut rec, net, &layers.view(), 0, &tape, d_cw.raw()).unwrap();
    let r_enc = read_all(&mut rec, &outs.encoder, want.encoder.iter().map(Vec::len));
    let r_head = read_all(&mut rec, &outs.head, want.head.iter().map(Vec::len));
    let r_global = rec.read(&outs.global, 0, (want.global.len() * 4) as u64);
    let r_cw = rec.read(&outs.codewords, 0, (want.codeword.len() * 4) as u64);
    let reads = read_gradients(&mut rec, &layers);
    let bytes = dpr_gpu::block_on(rec.finish()).unwrap();

    let got = EncodeTape {
        patches,
        points,
        encoder: r_enc.iter().map(|&r| floats(&bytes, r)).collect(),
        global: floats(&bytes, r_global),
        head: r_head.iter().map(|&r| floats(&bytes, r)).collect(),
        codeword: floats(&bytes, r_cw),
    };
    assert_activations("encode tape, encoder", s, &got.encoder, &want.encoder);
    assert_activations("encode tape, head", s, &got.head, &want.head);
    assert_activations("encode tape, global", s, std::slice::from_ref(&got.global), &[want.global]);
    assert_activations("encode tape, codewords", s, std::slice::from_ref(&got.codeword), &[want.codeword]);
    let mut want_grads = Gradients::zeros(&weights.config);
    encode_backward(net, &w, 0, &input, &got, &d_codeword, &mut want_grads);
    let touched = 0..net.encoder.len() + net.head.len();
    assert_gradients("encode backward from the device tape", s, &bytes, &reads, &want_grads, touched);
}

/// PC-FoldNet's decoder on the device with both folds kept: every layer's output matches the CPU tape, and the
/// decoder's backward pass from the device tape (both folds: the codeword shared by the grid, the first fold's
/// output feeding the second) matches the CPU trainer's: every fold layer's gradient, and the codeword gradient
/// added to a nonzero start.
pub fn decode_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass() {
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(151);
    let mut rng = Rng::new(s);
    let (weights, model) = small_model(s);
    let net = &model.pc;
    let base = all_layers(&weights.config).iter().position(|l| l.name.starts_with("pc")).unwrap();
    let patches = 3;
    let codewords = normals(&mut rng, patches * net.codeword_len());
    let want = net.decode_tape(&codewords, patches);
    let d_recon = normals(&mut rng, want.output().len());

    let ctx = &g.context;
    let up = |v: &[f32]| GpuBuffer::from_slice(ctx, "decode tape test", v).unwrap();
    let gpu_model = GpuModel::upload(ctx, &model).unwrap();
    let w = LayerWeights::new(&weights).unwrap();
    let layers = DeviceLayerBuffers::upload(ctx, &w).unwrap();
    let (code, grid, d_recon_b) = (up(&codewords), up(&net.tiled_grid(patches)), up(&d_recon));
    // The codeword gradient is added to what the buffer holds: a nonzero start.
    let d_code_start = normals(&mut rng, codewords.len());
    let d_code = up(&d_code_start);
    let mut ws = Workspace::default();
    let mut rec = Recorder::new(&g, "decode tape test");
    let kept = [Outputs::Kept(&FOLD_NAMES[0]), Outputs::Kept(&FOLD_NAMES[1])];
    let outs =
        record_decode_outputs(&mut rec, &g, &mut ws, &gpu_model.pc, [code.raw(), grid.raw()], patches, kept).unwrap();
    let tape = DeviceDecodeTape::from_outputs(&outs, [code.raw(), grid.raw()], patches);
    record_decode_backward(&mut rec, net, &layers.view(), base, &tape, d_recon_b.raw().clone(), d_code.raw()).unwrap();
    let r_fold1 = read_all(&mut rec, &outs[0], want.fold1.iter().map(Vec::len));
    let r_fold2 = read_all(&mut rec, &outs[1], want.fold2.iter().map(Vec::len));
    let r_d_code = rec.read(d_code.raw(), 0, (codewords.len() * 4) as u64);
    let reads = read_gradients(&mut rec, &layers);
    let bytes = dpr_gpu::block_on(rec.finish()).unwrap();

    let got = DecodeTape {
        patches,
        fold1: r_fold1.iter().map(|&r| floats(&bytes, r)).collect(),
        fold2: r_fold2.iter().map(|&r| floats(&bytes, r)).collect(),
    };
    assert_activations("decode tape, first fold", s, &got.fold1, &want.fold1);
    assert_activations("decode tape, second fold", s, &got.fold2, &want.fold2);
    let mut want_grads = Gradients::zeros(&weights.config);
    let mut want_d_code = d_code_start.clone();
    decode_backward(net, &w, base, &codewords, &got, d_recon, &mut want_d_code, &mut want_grads);
    let folds = base + net.encoder.len() + net.head.len();
    let touched = folds..folds + net.fold1.len() + net.fold2.len();
    assert_gradients("decode backward from the device tape", s, &bytes, &reads, &want_grads, touched);
    let largest = want_d_code.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(largest > 0.0, "decode backward: a zero codeword gradient tests nothing");
    assert_close("decode backward, codeword gradient", s, &floats(&bytes, r_d_code), &want_d_code, |_| 1e-3 * largest);
}

/// RelativeNet on the device with every layer kept, in the trainer's layout (one input slice of each row's
/// source and target features side by side): each output matches the CPU tape (two slices), and the backward
/// pass from the device tape matches the CPU trainer's (layer gradients, source and target feature gradients).
pub fn relative_tape_on_the_device_matches_the_cpu_and_feeds_the_backward_pass() {
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(152);
    let RelativeCase { weights, model, base, rows, f, source, target, d_raw } = relative_case(s);
    let net = &model.relative;
    let want = net.forward_tape(&source, &target, rows);

    let ctx = &g.context;
    let up = |v: &[f32]| GpuBuffer::from_slice(ctx, "relative tape test", v).unwrap();
    let gpu_model = GpuModel::upload(ctx, &model).unwrap();
    let w = LayerWeights::new(&weights).unwrap();
    let layers = DeviceLayerBuffers::upload(ctx, &w).unwrap();
    // The trainer's layout: each row's source and target features side by side, one slice of `2f`.
    let pairs: Vec<f32> =
        (0..rows).flat_map(|r| source[r * f..][..f].iter().chain(&target[r * f..][..f])).copied().collect();
    let (pairs_b, d_raw_b, d_pairs_b) = (up(&pairs), up(&d_raw), up(&vec![0.0; pairs.len()]));
    let mut ws = Workspace::default();
    let mut rec = Recorder::new(&g, "relative tape test");
    let kept = Outputs::Kept(&RELATIVE_NAMES);
    let input = [(pairs_b.raw(), 2 * f, 0)];
    let outs = record_relative_outputs(&mut rec, &g, &mut ws, &gpu_model.relative, &input, rows, kept).unwrap();
    let outs_ref: Vec<&wgpu::Buffer> = outs.iter().collect();
    let slice = [DeviceSlice { x: pairs_b.raw(), width: 2 * f, offset: 0, dx: Some(d_pairs_b.raw()) }];
    let d_raw_raw = d_raw_b.raw().clone();
    record_relative_backward(&mut rec, net, &layers.view(), base, &slice, rows, &outs_ref, d_raw_raw).unwrap();
    let r_outs = read_all(&mut rec, &outs, want.iter().map(Vec::len));
    let r_d_pairs = rec.read(d_pairs_b.raw(), 0, (pairs.len() * 4) as u64);
    let reads = read_gradients(&mut rec, &layers);
    let bytes = dpr_gpu::block_on(rec.finish()).unwrap();

    let got: Vec<Vec<f32>> = r_outs.iter().map(|&r| floats(&bytes, r)).collect();
    assert_activations("relative tape", s, &got, &want);
    let mut want_grads = Gradients::zeros(&weights.config);
    let (want_ds, want_dt) = relative_backward(net, &w, base, &source, &target, rows, &got, d_raw, &mut want_grads);
    let touched = base..base + net.layers.len();
    assert_gradients("relative backward from the device tape", s, &bytes, &reads, &want_grads, touched);
    let d_pairs = floats(&bytes, r_d_pairs);
    for (part, side, expected) in [("source", 0, &want_ds), ("target", 1, &want_dt)] {
        let got: Vec<f32> = (0..rows).flat_map(|r| d_pairs[(2 * r + side) * f..][..f].iter().copied()).collect();
        let largest = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(largest > 0.0, "relative backward, {part}: a zero gradient tests nothing");
        assert_close(&format!("relative backward, {part} features"), s, &got, expected, |_| 1e-3 * largest);
    }
}
