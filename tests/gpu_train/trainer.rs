//! The device trainer ([`dpr_gpu::gpu::train::DeviceTrainer`]) against the CPU trainer: the whole objective's
//! value and gradient on a batch (every term on, the contrastive one included), and one AdamW step.

use crate::{EPS, assert_close, f32_gemm_gpu, normals, seed};
use dpr_gpu::gpu::train::DeviceTrainer;
use dpr_gpu::model::params::tensor_specs;
use dpr_gpu::model::{ModelConfig, Weights};
use dpr_gpu::rng::Rng;
use dpr_gpu::train::trainer::apply_gradients;
use dpr_gpu::train::{Adam, AdamSettings, Gradients, LossSettings, Losses, PairSample, batch_loss, batch_objective};

/// A small model (16 points per patch, the default widths and head) and a batch of `pairs` random pairs whose
/// labels turn about z (so the angle-bin loss is defined for every pair).
fn setup(s: u64, pairs: usize) -> (Weights, Vec<PairSample>, LossSettings) {
    let mut rng = Rng::new(s);
    let config = ModelConfig { points_per_patch: 16, ..ModelConfig::default() };
    let weights = Weights::init(&config, s).unwrap();
    let n = config.points_per_patch;
    let batch = (0..pairs)
        .map(|_| {
            let a = rng.uniform(-3.0, 3.0);
            let (c, sn) = (a.cos(), a.sin());
            PairSample {
                ppf: normals(&mut rng, 2 * n * 4),
                pc: normals(&mut rng, 2 * n * 3),
                label: [c, -sn, 0.0, sn, c, 0.0, 0.0, 0.0, 1.0],
            }
        })
        .collect();
    let loss = LossSettings { contrast: true, ..LossSettings::default() };
    (weights, batch, loss)
}

/// Fresh optimiser state for `weights`.
fn fresh_adam(weights: &Weights) -> Adam {
    let sizes: Vec<usize> = tensor_specs(&weights.config).iter().map(|(_, s)| s.iter().product()).collect();
    Adam::new(AdamSettings { lr: 1e-3, ..AdamSettings::default() }, &sizes)
}

/// Each loss term within `rtol` of the CPU's (relative, with an absolute floor of `rtol` for terms near 0).
fn assert_losses(what: &str, s: u64, got: &Losses, want: &Losses, rtol: f64) {
    for (term, g, w) in [
        ("rec", got.rec, want.rec),
        ("pose", got.pose, want.pose),
        ("feat", got.feat, want.feat),
        ("contrast", got.contrast, want.contrast),
        ("total", got.total, want.total),
    ] {
        assert!((g - w).abs() <= rtol * w.abs().max(1.0), "{what}, {term}: device {g} vs cpu {w} (seed {s})");
    }
}

/// The device objective on a batch of 4 pairs (reconstruction, angle-bin pose, feature consistency, contrastive)
/// against the CPU trainer's `batch_objective`: every loss term within f32 rounding, and every layer's weight and
/// bias gradient within 1e-3 of the tensor's largest element (both sides sum in f32, in different orders; the
/// max-pools' and the Chamfer search's choices may differ only on near-ties, which random data does not have).
pub fn device_objective_matches_the_cpu_trainer() {
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(155);
    let (weights, batch, loss) = setup(s, 4);
    let (want_losses, want) = batch_objective(&weights, &batch, &loss).unwrap();
    let mut trainer = DeviceTrainer::new(&g, &weights, loss, &fresh_adam(&weights)).unwrap();
    let (losses, grads) = dpr_gpu::block_on(trainer.gradients(&g, &batch)).unwrap();
    assert_losses("device objective", s, &losses, &want_losses, 1e-4);
    assert!(want_losses.contrast > 0.0 && want_losses.pose > 0.0, "a zero loss term tests nothing");
    assert_grads("device objective", s, &grads, &want);
}

/// Every layer's gradients within 1e-3 of each tensor's largest element, and none all zero.
fn assert_grads(what: &str, s: u64, got: &Gradients, want: &Gradients) {
    for (i, (g, w)) in got.layers.iter().zip(&want.layers).enumerate() {
        for (part, gv, wv) in [("weight", &g.weight, &w.weight), ("bias", &g.bias, &w.bias)] {
            let largest = wv.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(largest > 0.0, "{what}, layer {i} {part}: a zero gradient tests nothing");
            assert_close(&format!("{what}, layer {i} {part}"), s, gv, wv, |_| 1e-3 * largest);
        }
    }
}

/// One device step against AdamW applied on the host to the device's own gradient (so the oracle is exact in
/// what it updates): every weight and moment within f32 rounding of the f64 update. Then the next forward pass
/// runs on the updated weights: the device's loss after the step matches the CPU loss at the read-back weights.
pub fn device_step_applies_adamw_and_refreshes_the_forward_weights() {
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(156);
    let (weights, batch, loss) = setup(s, 3);
    let adam = fresh_adam(&weights);
    let (_, grads) =
        dpr_gpu::block_on(DeviceTrainer::new(&g, &weights, loss, &adam).unwrap().gradients(&g, &batch)).unwrap();
    let mut trainer = DeviceTrainer::new(&g, &weights, loss, &adam).unwrap();
    dpr_gpu::block_on(trainer.step(&g, &batch)).unwrap();
    assert_eq!(trainer.steps(), 1);

    let (mut want, mut want_adam) = (weights.clone(), adam.clone());
    apply_gradients(&mut want, &mut want_adam, &grads).unwrap();
    let got = dpr_gpu::block_on(trainer.weights(&g)).unwrap();
    let lr = adam.settings.lr as f32;
    for (name, w) in &want.tensors {
        let before = &weights.tensors[name];
        // A step moves an element by at most about lr; f32 rounding of x and of the step, and the f32 moments.
        assert_close(&format!("weights after a step, {name}"), s, &got.tensors[name], w, |i| {
            4.0 * EPS * before[i].abs() + 1e-4 * lr
        });
    }
    let got_adam = dpr_gpu::block_on(trainer.adam(&g)).unwrap();
    assert_eq!(got_adam.steps, 1);
    for (k, (m, v)) in got_adam.m.iter().zip(&got_adam.v).enumerate() {
        assert_close(&format!("first moment {k}"), s, m, &want_adam.m[k], |i| 4.0 * EPS * want_adam.m[k][i].abs());
        assert_close(&format!("second moment {k}"), s, v, &want_adam.v[k], |i| 4.0 * EPS * want_adam.v[k][i].abs());
    }
    let moved = want.tensors.iter().any(|(name, w)| w != &weights.tensors[name]);
    assert!(moved, "the step changed nothing");
    let (after, _) = dpr_gpu::block_on(trainer.gradients(&g, &batch)).unwrap();
    let want_after = batch_loss(&got, &batch, &loss).unwrap();
    let (before, _) = batch_objective(&weights, &batch, &loss).unwrap();
    assert!((want_after.total - before.total).abs() > 1e-6, "the step did not change the loss");
    assert_losses("loss after a step", s, &after, &want_after, 1e-4);
}

/// A device run stopped after two steps and restarted from its read-back weights and optimiser state (what a
/// checkpoint holds) takes the third step to the same bits as the uninterrupted run: the state on the device is
/// exactly what is read back.
pub fn device_training_resumes_bit_for_bit() {
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(157);
    let (weights, batch, loss) = setup(s, 4);
    let batches = [&batch[..2], &batch[2..], &batch[1..3]];
    let adam = fresh_adam(&weights);
    let mut straight = DeviceTrainer::new(&g, &weights, loss, &adam).unwrap();
    let want: Vec<Losses> = batches.iter().map(|b| dpr_gpu::block_on(straight.step(&g, b)).unwrap()).collect();
    let mut first = DeviceTrainer::new(&g, &weights, loss, &adam).unwrap();
    let mut got: Vec<Losses> = batches[..2].iter().map(|b| dpr_gpu::block_on(first.step(&g, b)).unwrap()).collect();
    let (w2, a2) = (dpr_gpu::block_on(first.weights(&g)).unwrap(), dpr_gpu::block_on(first.adam(&g)).unwrap());
    assert_eq!(a2.steps, 2);
    let mut resumed = DeviceTrainer::new(&g, &w2, loss, &a2).unwrap();
    got.push(dpr_gpu::block_on(resumed.step(&g, batches[2])).unwrap());
    assert_eq!(got, want, "losses differ after resuming (seed {s})");
    assert_eq!(
        dpr_gpu::block_on(resumed.weights(&g)).unwrap().tensors,
        dpr_gpu::block_on(straight.weights(&g)).unwrap().tensors,
        "weights differ"
    );
    assert_eq!(
        dpr_gpu::block_on(resumed.adam(&g)).unwrap(),
        dpr_gpu::block_on(straight.adam(&g)).unwrap(),
        "optimiser state differs"
    );
}

/// The `dpr-gpu` binary: Cargo's build of it, or (where the test binary was carried to another machine, as
/// `benches/device/pack.sh` does) the one beside the test binary.
fn binary() -> std::path::PathBuf {
    let built = std::path::PathBuf::from(env!("CARGO_BIN_EXE_dpr-gpu"));
    if built.exists() {
        return built;
    }
    let exe = std::env::current_exe().expect("the test binary's path");
    exe.parent().expect("the test binary's folder").join("dpr-gpu")
}

/// `dpr-gpu` with `args` (the test process's environment: the test adapter); asserts it succeeded.
fn dpr(what: &str, args: &[&str]) {
    let o = std::process::Command::new(binary()).args(args).output().expect("binary runs");
    assert!(o.status.success(), "{what}: {}", String::from_utf8_lossy(&o.stderr));
}

/// The CLI's `train --backend gpu` on a generated dataset (the glue: sampling through the CPU trainer, the device
/// steps, the state read back for checkpoints and the output): its per-step losses match `--backend cpu`'s
/// within f32 rounding, and a device run checkpointed at step 2 and resumed to 4 writes the same weight bytes as
/// a straight 4-step device run.
pub fn train_cli_on_the_device_matches_the_cpu_and_resumes() {
    let Some(_g) = f32_gemm_gpu() else { return };
    let dir = crate::common::temp_dir("gpu-train-cli");
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let data = path("data");
    dpr("synth", &["synth", &data, "--fragments", "3", "--frames", "4", "--width", "64", "--seed", "4"]);
    let train = |what: &str, extra: &[&str]| {
        let small = ["--points", "16", "--grid", "3", "--batch", "2", "--voxel", "0.03", "--seed", "3"];
        let weights = ["--lambda-contrast", "1", "--lr-decay-every", "2"];
        dpr(what, &[&["train", "--data", &data][..], &small, &weights, extra].concat());
    };
    let (cpu_out, cpu_log) = (path("cpu.safetensors"), path("cpu.csv"));
    // f32 on the CPU too: the device's GEMM here is f32 (`auto` would take bf16 on a CPU that has it).
    train("cpu run", &["--precision", "f32", "--out", &cpu_out, "--log", &cpu_log, "--steps", "4"]);
    let (gpu_out, gpu_log) = (path("gpu.safetensors"), path("gpu.csv"));
    train("gpu run", &["--backend", "gpu", "--out", &gpu_out, "--log", &gpu_log, "--steps", "4"]);
    let rows = |f: &str| -> Vec<Vec<f64>> {
        let text = std::fs::read_to_string(f).unwrap();
        text.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect()
    };
    let (cpu, gpu) = (rows(&cpu_log), rows(&gpu_log));
    assert!(cpu.len() == 4 && gpu.len() == 4, "one row per step: {} and {}", cpu.len(), gpu.len());
    for (c, g) in cpu.iter().zip(&gpu) {
        // step, total, rec, pose, feat, lr, seconds, contrast: all but the time.
        for k in [0, 1, 2, 3, 4, 5, 7] {
            let close = (c[k] - g[k]).abs() <= 1e-4 * c[k].abs().max(1.0);
            assert!(close, "step {}, column {k}: cpu {} vs gpu {}", c[0], c[k], g[k]);
        }
    }
    let (half_out, half_ckpt, resumed) =
        (path("half.safetensors"), path("half.ckpt.safetensors"), path("resumed.safetensors"));
    train("gpu run to step 2", &["--backend", "gpu", "--out", &half_out, "--checkpoint", &half_ckpt, "--steps", "2"]);
    let resume = ["train", "--resume", &half_ckpt, "--out", &resumed, "--steps", "4", "--backend", "gpu"];
    dpr("resumed gpu run", &resume);
    let tensors = |f: &str| Weights::load(std::path::Path::new(f)).unwrap().tensors;
    assert_eq!(tensors(&resumed), tensors(&gpu_out), "resuming on the device changed the run");
    // The device run's output is its trained weights: as far from the CPU run's as f32 rounding takes them, a
    // small fraction of how far both moved from the start.
    let init = path("init.safetensors");
    train("initial weights", &["--out", &init, "--steps", "0"]);
    let distance = |a: &str, b: &str| -> f64 {
        let (a, b) = (tensors(a), tensors(b));
        a.iter().map(|(name, x)| x.iter().zip(&b[name]).map(|(u, v)| f64::from((u - v).abs())).sum::<f64>()).sum()
    };
    let (moved, apart) = (distance(&cpu_out, &init), distance(&gpu_out, &cpu_out));
    assert!(moved > 0.0 && apart < 0.05 * moved, "device and CPU runs {apart} apart, moved {moved}");
}
