//! Distillation (issue 39, item 1): a student whose FoldNet encoders are cheaper (narrower head layers after
//! the skip concatenation, where most of a patch's FLOPs are) learns to reproduce a trained teacher's codewords,
//! PPF-FoldNet's and PC-FoldNet's, on the training pairs' patches. RelativeNet and the folding decoders are the
//! teacher's, copied and left as they are: RelativeNet reads the codewords the student learns to reproduce, and
//! the decoders are not used at inference.
//!
//! The loss is the mean squared difference between the student's and the teacher's codewords, per codeword
//! element, summed over the two nets; its gradient flows through [`encode_backward`], the same backward pass the
//! trainer's other losses use, so only the encoders' tensors get gradients.

use super::backward::{Gradients, LayerWeights, encode_backward};
use super::objective::{Losses, PairSample, bases, check_sample};
use crate::cpu::gemm::Precision;
use crate::cpu::gemm_bf16::Bf16Unit;
use crate::error::{Error, Result};
use crate::model::{Model, ModelConfig, Weights};
use rayon::prelude::*;

/// Refuses a teacher the student cannot learn from: the same codeword length, points per patch, patch radius
/// and pose frame (the inputs and outputs the student must share), and the same RelativeNet and decoders.
pub fn check_teacher(teacher: &ModelConfig, student: &ModelConfig) -> Result<()> {
    let same_io = teacher.codeword() == student.codeword()
        && teacher.points_per_patch == student.points_per_patch
        && teacher.radius == student.radius
        && teacher.pose_frame == student.pose_frame
        && teacher.rotation_output == student.rotation_output
        && teacher.relative_widths == student.relative_widths
        && teacher.fold_widths == student.fold_widths
        && teacher.grid == student.grid;
    if same_io {
        Ok(())
    } else {
        Err(Error::invalid(format!(
            "the distillation teacher's model ({teacher:?}) differs from the student's ({student:?}) in more than \
             the encoder and head widths"
        )))
    }
}

/// A student of `config` (the teacher's but for its encoder and head widths): fresh weights (`seed`) where the
/// shapes differ, the teacher's tensors wherever a tensor of the same name and size exists (RelativeNet, the
/// decoders and any encoder layer of unchanged width).
pub fn student_weights(teacher: &Weights, config: &ModelConfig, seed: u64) -> Result<Weights> {
    check_teacher(&teacher.config, config)?;
    let mut student = Weights::init(config, seed)?;
    for (name, value) in student.tensors.iter_mut() {
        if let Some(t) = teacher.tensors.get(name)
            && t.len() == value.len()
        {
            value.clone_from(t);
        }
    }
    Ok(student)
}

/// The teacher's tensors a student keeps unchanged: all but the encoders' (`*.encoder.*`, `*.head.*`).
pub fn kept_tensors(teacher: &Weights) -> Vec<(String, Vec<f32>)> {
    let trained = |name: &str| name.contains(".encoder.") || name.contains(".head.");
    teacher.tensors.iter().filter(|(n, _)| !trained(n)).map(|(n, t)| (n.clone(), t.clone())).collect()
}

/// The distillation loss over `samples` and its gradient with respect to the student's `weights`, the student's
/// multiplies at `precision` (the teacher's codewords in f32). Parallel over samples, summed in sample order, so
/// the result does not depend on the thread count.
pub fn batch_distill_at(
    precision: Precision,
    weights: &Weights,
    teacher: &Model,
    samples: &[PairSample],
) -> Result<(Losses, Gradients)> {
    if samples.is_empty() {
        return Err(Error::invalid("empty training batch"));
    }
    check_teacher(&teacher.config, &weights.config)?;
    let student = Model::from_weights(weights)?.with_bf16_unit(Bf16Unit::Tiles);
    let w = LayerWeights::with_precision(weights, precision)?;
    let scale = 1.0 / samples.len() as f64;
    let per_task = samples.len().div_ceil(rayon::current_num_threads().max(1));
    let parts: Vec<Result<(f64, Gradients)>> = samples
        .par_chunks(per_task)
        .map(|chunk| {
            let mut g = Gradients::zeros(&weights.config);
            let mut loss = 0.0;
            for s in chunk {
                loss += sample_distill(&student, &w, teacher, precision, s, scale, &mut g)?;
            }
            Ok((loss, g))
        })
        .collect();
    let mut total = Gradients::zeros(&weights.config);
    let mut loss = 0.0;
    for part in parts {
        let (l, g) = part?;
        loss += l;
        total.add_assign(&g);
    }
    Ok((Losses { total: loss, ..Losses::default() }, total))
}

/// One pair's share of the loss (`scale` times its mean squared codeword difference, summed over both nets),
/// its gradient added to `grads`.
fn sample_distill(
    student: &Model,
    w: &LayerWeights<'_>,
    teacher: &Model,
    precision: Precision,
    sample: &PairSample,
    scale: f64,
    grads: &mut Gradients,
) -> Result<f64> {
    check_sample(student, sample)?;
    let n = student.config.points_per_patch;
    let (pc_base, _) = bases(student);
    let mut loss = 0.0;
    for (net, teacher_net, input, base) in
        [(&student.ppf, &teacher.ppf, &sample.ppf, 0), (&student.pc, &teacher.pc, &sample.pc, pc_base)]
    {
        let tape = net.encode_tape_at(precision, input, 2, n);
        let target = teacher_net.encode(input, 2, n);
        let count = target.len().max(1) as f64;
        let mut d_codeword = vec![0.0f32; target.len()];
        for ((d, &s), &t) in d_codeword.iter_mut().zip(&tape.codeword).zip(&target) {
            let diff = f64::from(s) - f64::from(t);
            loss += scale * diff * diff / count;
            *d = (2.0 * scale * diff / count) as f32;
        }
        encode_backward(net, w, base, input, &tape, &d_codeword, grads);
    }
    Ok(loss)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn small_config() -> ModelConfig {
        ModelConfig {
            points_per_patch: 16,
            encoder_widths: vec![8, 16],
            head_widths: vec![32, 24],
            fold_widths: vec![8],
            grid: [3, 3],
            relative_widths: vec![16],
            ..ModelConfig::default()
        }
    }

    fn samples(config: &ModelConfig, count: usize, seed: u64) -> Vec<PairSample> {
        let mut rng = Rng::new(seed);
        let n = config.points_per_patch;
        (0..count)
            .map(|_| PairSample {
                ppf: (0..2 * n * 4).map(|_| rng.normal() as f32 * 0.5).collect(),
                pc: (0..2 * n * 3).map(|_| rng.normal() as f32 * 0.5).collect(),
                label: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            })
            .collect()
    }

    #[test]
    fn a_student_equal_to_its_teacher_has_no_loss_and_no_gradient() {
        let config = small_config();
        let teacher = Weights::init(&config, 3).unwrap();
        let student = student_weights(&teacher, &config, 9).unwrap();
        assert_eq!(student.tensors, teacher.tensors, "same widths: every tensor is the teacher's");
        let model = Model::from_weights(&teacher).unwrap();
        let (losses, grads) = batch_distill_at(Precision::F32, &student, &model, &samples(&config, 4, 1)).unwrap();
        assert_eq!(losses.total, 0.0);
        assert!(grads.layers.iter().all(|g| g.weight.iter().chain(&g.bias).all(|&v| v == 0.0)));
    }

    #[test]
    fn the_gradient_matches_finite_differences_and_only_the_encoders_get_one() {
        let config = small_config();
        let teacher_weights = Weights::init(&config, 3).unwrap();
        let narrow = ModelConfig { head_widths: vec![12, 24], ..config.clone() };
        let student = student_weights(&teacher_weights, &narrow, 9).unwrap();
        assert_eq!(student.get("relative.0.weight").unwrap(), teacher_weights.get("relative.0.weight").unwrap());
        let teacher = Model::from_weights(&teacher_weights).unwrap();
        let batch = samples(&config, 3, 2);
        let (losses, grads) = batch_distill_at(Precision::F32, &student, &teacher, &batch).unwrap();
        assert!(losses.total > 0.0);
        let layers = crate::model::params::all_layers(&narrow);
        for (spec, g) in layers.iter().zip(&grads.layers) {
            let trained = spec.name.contains(".encoder.") || spec.name.contains(".head.");
            assert_eq!(g.weight.iter().any(|&v| v != 0.0), trained, "{}", spec.name);
        }
        // Central differences on a few entries of an encoder and a head layer of each net.
        for (layer, tensor) in [("ppf.head.0", "weight"), ("pc.head.1", "weight"), ("pc.encoder.0", "bias")] {
            let at = layers.iter().position(|l| l.name == layer).unwrap();
            let name = format!("{layer}.{tensor}");
            for i in [0usize, 5, 7] {
                let h = 1e-3f32;
                let loss_at = |delta: f32| {
                    let mut w = student.clone();
                    w.tensors.get_mut(&name).unwrap()[i] += delta;
                    batch_distill_at(Precision::F32, &w, &teacher, &batch).unwrap().0.total
                };
                let numeric = (loss_at(h) - loss_at(-h)) / (2.0 * f64::from(h));
                let g = &grads.layers[at];
                let analytic = f64::from(if tensor == "weight" { g.weight[i] } else { g.bias[i] });
                let tol = 2e-2 * numeric.abs().max(analytic.abs()) + 1e-6;
                assert!((numeric - analytic).abs() <= tol, "{name}[{i}]: numeric {numeric} vs analytic {analytic}");
            }
        }
    }

    #[test]
    fn a_teacher_of_another_codeword_or_patch_size_is_refused() {
        let config = small_config();
        let other = ModelConfig { points_per_patch: 32, ..config.clone() };
        assert!(check_teacher(&other, &config).is_err());
        let wider = ModelConfig { head_widths: vec![32, 48], ..config.clone() };
        assert!(check_teacher(&wider, &config).is_err());
        assert!(check_teacher(&ModelConfig { head_widths: vec![8, 24], ..config.clone() }, &config).is_ok());
    }
}
