//! Adam with decoupled weight decay (AdamW, Loshchilov & Hutter) and an exponentially decaying learning rate.
//!
//! Per element, at step t (1-based): `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`,
//! `p -= lr_t (m / (1 - b1^t) / (sqrt(v / (1 - b2^t)) + eps) + wd p)`. The decay is *decoupled*: it shrinks the
//! parameter directly instead of being added to the gradient (L2), so it is not rescaled by Adam's
//! per-element step size. It applies to the tensors the caller marks (weight matrices, not biases).
//! The learning rate decays smoothly: `lr_t = lr * lr_decay^(t / lr_decay_every)`.

use crate::cpu::adam_step::{AdamStep, adam_step};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// Optimiser settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdamSettings {
    /// Initial learning rate.
    pub lr: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator guard.
    pub eps: f64,
    /// Decoupled weight decay (per unit learning rate).
    pub weight_decay: f64,
    /// The learning rate is multiplied by this every `lr_decay_every` steps (smoothly in between).
    pub lr_decay: f64,
    /// Steps per `lr_decay` factor; 0 keeps the learning rate constant.
    pub lr_decay_every: u64,
}

impl Default for AdamSettings {
    /// lr 1e-3, betas (0.9, 0.999), eps 1e-8, weight decay 1e-6, no learning-rate decay.
    fn default() -> Self {
        AdamSettings {
            lr: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 1e-6,
            lr_decay: 0.5,
            lr_decay_every: 0,
        }
    }
}

impl AdamSettings {
    /// Checks the values are usable.
    pub fn validate(&self) -> Result<()> {
        let ok = self.lr.is_finite()
            && self.lr > 0.0
            && (0.0..1.0).contains(&self.beta1)
            && (0.0..1.0).contains(&self.beta2)
            && self.eps.is_finite()
            && self.eps > 0.0
            && self.weight_decay.is_finite()
            && self.weight_decay >= 0.0
            && self.lr_decay.is_finite()
            && self.lr_decay > 0.0;
        if ok { Ok(()) } else { Err(Error::invalid(format!("Adam settings out of range: {self:?}"))) }
    }

    /// The learning rate used for the update after `completed` earlier updates.
    pub fn lr_at(&self, completed: u64) -> f64 {
        if self.lr_decay_every == 0 {
            self.lr
        } else {
            self.lr * self.lr_decay.powf(completed as f64 / self.lr_decay_every as f64)
        }
    }
}

/// The optimiser state: one first and one second moment per parameter tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    /// Settings.
    pub settings: AdamSettings,
    /// Updates done so far.
    pub steps: u64,
    /// First moments, one vector per tensor.
    pub m: Vec<Vec<f32>>,
    /// Second moments, one vector per tensor.
    pub v: Vec<Vec<f32>>,
}

/// One tensor to update: the parameters, their gradient, and whether weight decay applies.
pub struct Param<'a> {
    /// Parameters (updated in place).
    pub value: &'a mut [f32],
    /// Gradient of the loss.
    pub grad: &'a [f32],
    /// Apply weight decay.
    pub decay: bool,
}

impl Adam {
    /// Zero moments for tensors of the given sizes.
    pub fn new(settings: AdamSettings, sizes: &[usize]) -> Adam {
        Adam {
            settings,
            steps: 0,
            m: sizes.iter().map(|&n| vec![0.0; n]).collect(),
            v: sizes.iter().map(|&n| vec![0.0; n]).collect(),
        }
    }

    /// Counts one more step and returns its per-element constants (learning rate at the steps completed
    /// before it, bias corrections at its 1-based index): what [`Adam::step`] and the device trainer apply.
    pub fn next_step(&mut self) -> AdamStep {
        let s = self.settings;
        let lr = s.lr_at(self.steps);
        self.steps += 1;
        let t = self.steps as i32;
        AdamStep {
            lr,
            beta1: s.beta1,
            beta2: s.beta2,
            eps: s.eps,
            weight_decay: s.weight_decay,
            c1: 1.0 - s.beta1.powi(t),
            c2: 1.0 - s.beta2.powi(t),
        }
    }

    /// One update of every tensor (in the order the moments were created). Errors when the tensors do not
    /// match the moments; nothing is changed then.
    pub fn step(&mut self, params: &mut [Param<'_>]) -> Result<()> {
        let sizes_match = params.len() == self.m.len()
            && params.iter().zip(&self.m).all(|(p, m)| p.value.len() == m.len() && p.grad.len() == m.len());
        if !sizes_match {
            return Err(Error::invalid("Adam: parameter tensors do not match the optimiser state"));
        }
        let step = self.next_step();
        for ((p, m), v) in params.iter_mut().zip(&mut self.m).zip(&mut self.v) {
            adam_step(&step, p.decay, p.value, p.grad, m, v);
        }
        Ok(())
    }
}
