//! The training loop: sample a batch, compute the loss and its gradient, take one Adam step.
//!
//! Everything random in step `s` comes from the stream `Rng::derived(seed, s)`, so the whole state of a run is
//! the weights, the Adam moments and the step count: that is what a checkpoint holds, and resuming from it
//! continues bit-identically.

use super::adam::{Adam, AdamSettings, Param};
use super::backward::Gradients;
use super::data::{DataSettings, FragmentPair, Sampler, discover_pairs};
use super::objective::{LossSettings, Losses, PairSample, batch_objective_at};
use crate::cpu::gemm::Precision;
use crate::error::{Error, Result};
use crate::model::params::tensor_specs;
use crate::model::{Model, ModelConfig, Weights};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::PathBuf;

/// Everything that defines a training run besides the model sizes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainSettings {
    /// Dataset folders, scene folders, gt.log or pairs files.
    pub data: Vec<PathBuf>,
    /// Pairs per step.
    pub batch: usize,
    /// Seed of the initial weights and of every sample.
    pub seed: u64,
    /// Loss terms and weights.
    pub loss: LossSettings,
    /// Optimiser.
    pub adam: AdamSettings,
    /// Pair sampling.
    pub sampling: DataSettings,
    /// The arithmetic of the CPU step's multiplies: f32 (the default, and what runs saved before this setting
    /// existed resume with), or bf16 products with f32 sums in the wide layers where the CPU has AVX-512 BF16
    /// (`dpr-gpu train` picks it there); weights and optimiser state stay f32 either way.
    #[serde(default)]
    pub precision: Precision,
    /// Distillation: the teacher's weights file. When set, each step trains only the encoders to reproduce the
    /// teacher's codewords ([`super::distill`]) and the loss terms above are not used.
    #[serde(default)]
    pub distill_from: Option<PathBuf>,
}

impl Default for TrainSettings {
    fn default() -> Self {
        TrainSettings {
            data: Vec::new(),
            batch: 32,
            seed: 0,
            loss: LossSettings::default(),
            adam: AdamSettings::default(),
            sampling: DataSettings::default(),
            precision: Precision::F32,
            distill_from: None,
        }
    }
}

impl TrainSettings {
    /// Checks the values are usable.
    pub fn validate(&self) -> Result<()> {
        if self.batch == 0 {
            return Err(Error::invalid("batch must be at least 1"));
        }
        let l = &self.loss;
        let usable = |v: f64| v.is_finite() && v >= 0.0;
        if ![l.lambda_pose, l.lambda_feat, l.lambda_contrast, l.contrast_margin].into_iter().all(usable) {
            return Err(Error::invalid(format!("loss weights must be finite and non-negative: {l:?}")));
        }
        if !(l.rec || l.pose || l.feat || l.contrast || self.distill_from.is_some()) {
            return Err(Error::invalid("every loss term is disabled: nothing to train"));
        }
        if !self.precision.is_available() {
            return Err(Error::invalid(format!(
                "training precision {} needs AVX-512 BF16, which this CPU lacks (train in f32)",
                self.precision.name()
            )));
        }
        self.adam.validate()
    }
}

/// Named tensors a distillation student keeps as the teacher's.
type KeptTensors = Vec<(String, Vec<f32>)>;

/// A training run in progress.
pub struct Trainer {
    settings: TrainSettings,
    weights: Weights,
    adam: Adam,
    step: u64,
    sampler: Sampler,
    /// The teacher of a distillation run (`settings.distill_from`), loaded once, and its tensors the student
    /// keeps as they are (RelativeNet, the decoders).
    teacher: Option<(Model, KeptTensors)>,
}

/// Parameter tensor names in `tensor_specs` order, with whether weight decay applies (weights, not biases).
pub(crate) fn tensor_order(config: &ModelConfig) -> Vec<(String, usize, bool)> {
    tensor_specs(config)
        .into_iter()
        .map(|(name, shape)| {
            let decay = name.ends_with(".weight");
            (name, shape.iter().product(), decay)
        })
        .collect()
}

/// One AdamW step of `adam` on every tensor of `weights` from `grads` (layer `i`'s weight and bias gradients
/// are tensors `2i` and `2i + 1` of [`tensor_order`]); weight matrices decay, biases do not.
pub fn apply_gradients(weights: &mut Weights, adam: &mut Adam, grads: &Gradients) -> Result<()> {
    let order = tensor_order(&weights.config);
    let index: HashMap<&str, usize> = order.iter().enumerate().map(|(i, t)| (t.0.as_str(), i)).collect();
    let mut slots: Vec<Option<Param<'_>>> = (0..order.len()).map(|_| None).collect();
    for (name, value) in weights.tensors.iter_mut() {
        let Some(&i) = index.get(name.as_str()) else {
            return Err(Error::invalid(format!("weights have an unexpected tensor '{name}'")));
        };
        let layer = grads.layers.get(i / 2).ok_or_else(|| Error::invalid("gradients are missing a layer"))?;
        let grad = if i % 2 == 0 { &layer.weight } else { &layer.bias };
        slots[i] = Some(Param { value, grad, decay: order[i].2 });
    }
    let mut params: Vec<Param<'_>> = slots
        .into_iter()
        .collect::<Option<_>>()
        .ok_or_else(|| Error::invalid("weights are missing a tensor of the model configuration"))?;
    adam.step(&mut params)
}

impl Trainer {
    /// A fresh run: weights initialised from `settings.seed`, pairs discovered under `settings.data`.
    pub fn new(config: ModelConfig, settings: TrainSettings) -> Result<Trainer> {
        let pairs = discover_pairs(&settings.data)?;
        Trainer::with_pairs(Weights::init(&config, settings.seed)?, settings, pairs)
    }

    /// A fresh run from given initial weights and fragment pairs (the configuration is the weights').
    pub fn with_pairs(weights: Weights, settings: TrainSettings, pairs: Vec<FragmentPair>) -> Result<Trainer> {
        settings.validate()?;
        weights.config.validate()?;
        let sizes: Vec<usize> = tensor_order(&weights.config).iter().map(|t| t.1).collect();
        let adam = Adam::new(settings.adam, &sizes);
        let sampler = Sampler::new(pairs, settings.sampling.clone(), &weights.config)?;
        let teacher = match &settings.distill_from {
            Some(path) => {
                let teacher = Weights::load(path)?;
                super::distill::check_teacher(&teacher.config, &weights.config)?;
                let kept = super::distill::kept_tensors(&teacher);
                Some((Model::from_weights(&teacher)?, kept))
            }
            None => None,
        };
        Ok(Trainer { settings, weights, adam, step: 0, sampler, teacher })
    }

    /// Rebuilds a run from its saved state (see `checkpoint::read_checkpoint`): weights, settings, the fragment
    /// pairs, the optimiser state and the steps completed.
    pub fn from_checkpoint_parts(
        weights: Weights,
        settings: TrainSettings,
        pairs: Vec<FragmentPair>,
        adam: Adam,
        step: u64,
    ) -> Result<Trainer> {
        let mut t = Trainer::with_pairs(weights, settings, pairs)?;
        let sizes_ok = adam.m.len() == t.adam.m.len() && adam.m.iter().zip(&t.adam.m).all(|(a, b)| a.len() == b.len());
        if !sizes_ok || adam.v.len() != adam.m.len() {
            return Err(Error::invalid("checkpoint: optimiser state does not match the model"));
        }
        t.adam = adam;
        t.step = step;
        Ok(t)
    }

    /// The settings of this run.
    pub fn settings(&self) -> &TrainSettings {
        &self.settings
    }

    /// The current weights.
    pub fn weights(&self) -> &Weights {
        &self.weights
    }

    /// The optimiser state.
    pub fn adam(&self) -> &Adam {
        &self.adam
    }

    /// Steps completed.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// The pair sampler (e.g. to preload the data).
    pub fn sampler_mut(&mut self) -> &mut Sampler {
        &mut self.sampler
    }

    /// The learning rate the next step will use.
    pub fn learning_rate(&self) -> f64 {
        self.adam.settings.lr_at(self.adam.steps)
    }

    /// The batch the next step will train on.
    pub fn next_batch(&mut self) -> Result<Vec<PairSample>> {
        self.sampler.batch(self.settings.seed, self.step, self.settings.batch)
    }

    /// One training step; returns the batch's losses (before the update).
    pub fn step(&mut self) -> Result<Losses> {
        let batch = self.next_batch()?;
        let precision = self.settings.precision;
        let (losses, grads) = match &self.teacher {
            Some((teacher, _)) => super::distill::batch_distill_at(precision, &self.weights, teacher, &batch)?,
            None => batch_objective_at(precision, &self.weights, &batch, &self.settings.loss)?,
        };
        if !losses.total.is_finite() {
            return Err(Error::invalid(format!("the loss is not finite at step {} ({losses:?})", self.step)));
        }
        apply_gradients(&mut self.weights, &mut self.adam, &grads)?;
        if let Some((_, kept)) = &self.teacher {
            // Weight decay would move them a little; a student keeps the teacher's exactly.
            for (name, value) in kept {
                if let Some(t) = self.weights.tensors.get_mut(name) {
                    t.clone_from(value);
                }
            }
        }
        self.step += 1;
        Ok(losses)
    }

    /// One step whose objective and update run elsewhere (the device trainer, `gpu::train::DeviceTrainer`):
    /// samples the batch exactly as [`Trainer::step`] does, hands it to `run`, and counts the step (in the
    /// optimiser too, so the learning rate follows). The weights and moments held here are the run's starting
    /// point until [`Trainer::set_state`] brings them up to date.
    pub fn step_with(&mut self, run: impl FnOnce(&[PairSample]) -> Result<Losses>) -> Result<Losses> {
        let batch = self.next_batch()?;
        let losses = run(&batch)?;
        self.step += 1;
        self.adam.steps += 1;
        Ok(losses)
    }

    /// Replaces the weights and the optimiser state (read back from where the steps ran); the weights' notes
    /// are kept. An error, with nothing changed, when they do not fit the model or the step count.
    pub fn set_state(&mut self, mut weights: Weights, adam: Adam) -> Result<()> {
        let shapes_ok = adam.m.len() == self.adam.m.len()
            && adam.v.len() == self.adam.v.len()
            && adam.m.iter().zip(&self.adam.m).all(|(a, b)| a.len() == b.len());
        if weights.config != self.weights.config || !shapes_ok || adam.steps != self.adam.steps {
            return Err(Error::invalid("trainer state: the weights or optimiser state do not match this run"));
        }
        weights.notes = std::mem::take(&mut self.weights.notes);
        self.weights = weights;
        self.adam = adam;
        Ok(())
    }

    /// Replaces the fragment pairs (e.g. when resuming with the data at another path). The pairs must be the
    /// same for the run to continue identically.
    pub fn set_pairs(&mut self, pairs: Vec<FragmentPair>) -> Result<()> {
        self.sampler = Sampler::new(pairs, self.settings.sampling.clone(), &self.weights.config)?;
        Ok(())
    }
}
