//! Training checkpoints: one safetensors file with the weights (`weights/<name>`), the Adam moments
//! (`adam_m/<name>`, `adam_v/<name>`), and in the metadata the model configuration, the training settings,
//! the step count and the optimiser's step count. The sampler needs no state of its own: step `s` always draws
//! from `Rng::derived(seed, s)`. Written atomically (temp file + rename), so a crash never leaves a torn
//! checkpoint.

use super::adam::Adam;
use super::data::discover_pairs;
use super::trainer::{TrainSettings, Trainer, tensor_order};
use crate::error::{Error, Result};
use crate::model::{ModelConfig, Weights};
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// Metadata key of the checkpoint description (JSON).
pub const CHECKPOINT_KEY: &str = "dpr_gpu.checkpoint";
/// Checkpoint format version.
pub const CHECKPOINT_VERSION: u32 = 1;

/// What a checkpoint's metadata records.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMeta {
    /// Format version.
    pub version: u32,
    /// Model sizes.
    pub config: ModelConfig,
    /// The run's settings.
    pub settings: TrainSettings,
    /// Training steps completed.
    pub step: u64,
    /// Adam updates completed (equal to `step`).
    pub adam_steps: u64,
}

fn view(name: String, shape: Vec<usize>, data: &[f32]) -> Result<(String, TensorView<'_>)> {
    let v = TensorView::new(Dtype::F32, shape, bytemuck::cast_slice(data))
        .map_err(|e| Error::invalid(format!("checkpoint tensor '{name}': {e}")))?;
    Ok((name, v))
}

/// Serialises the trainer's state.
pub fn checkpoint_bytes(trainer: &Trainer) -> Result<Vec<u8>> {
    let weights = trainer.weights();
    let adam = trainer.adam();
    let meta = CheckpointMeta {
        version: CHECKPOINT_VERSION,
        config: weights.config.clone(),
        settings: trainer.settings().clone(),
        step: trainer.step_count(),
        adam_steps: adam.steps,
    };
    let json = serde_json::to_string(&meta).map_err(|e| Error::invalid(format!("checkpoint metadata: {e}")))?;
    let mut metadata = HashMap::new();
    metadata.insert(CHECKPOINT_KEY.to_string(), json);
    let specs: BTreeMap<String, Vec<usize>> = crate::model::params::tensor_specs(&weights.config).into_iter().collect();
    let mut views = Vec::new();
    for (i, (name, _, _)) in tensor_order(&weights.config).iter().enumerate() {
        let shape = specs.get(name).cloned().unwrap_or_default();
        views.push(view(format!("weights/{name}"), shape.clone(), weights.get(name)?)?);
        views.push(view(format!("adam_m/{name}"), shape.clone(), &adam.m[i])?);
        views.push(view(format!("adam_v/{name}"), shape, &adam.v[i])?);
    }
    safetensors::serialize(views, Some(metadata)).map_err(|e| Error::invalid(format!("serialising checkpoint: {e}")))
}

/// Writes the trainer's state to `path` atomically.
pub fn save_checkpoint(trainer: &Trainer, path: &Path) -> Result<()> {
    crate::io::write_atomic(path, &checkpoint_bytes(trainer)?)
}

/// Reads a checkpoint's metadata and tensors.
pub fn read_checkpoint(path: &Path) -> Result<(CheckpointMeta, Weights, Adam)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let fail = |m: String| Error::invalid(format!("checkpoint {}: {m}", path.display()));
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| fail(format!("not a safetensors file: {e}")))?;
    let json = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(CHECKPOINT_KEY))
        .ok_or_else(|| fail(format!("no '{CHECKPOINT_KEY}' metadata (not a dpr-gpu training checkpoint)")))?;
    let meta: CheckpointMeta = serde_json::from_str(json).map_err(|e| fail(format!("bad metadata: {e}")))?;
    if meta.version != CHECKPOINT_VERSION {
        return Err(fail(format!("format version {} (this build reads {CHECKPOINT_VERSION})", meta.version)));
    }
    meta.config.validate()?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| fail(format!("corrupt: {e}")))?;
    let order = tensor_order(&meta.config);
    let read = |name: &str, len: usize| -> Result<Vec<f32>> {
        let t = st.tensor(name).map_err(|_| fail(format!("missing tensor '{name}'")))?;
        if t.dtype() != Dtype::F32 || t.data().len() != len * 4 {
            return Err(fail(format!("tensor '{name}' has the wrong dtype or size")));
        }
        Ok(t.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
    };
    let mut tensors = BTreeMap::new();
    let mut adam = Adam::new(meta.settings.adam, &order.iter().map(|t| t.1).collect::<Vec<_>>());
    for (i, (name, len, _)) in order.iter().enumerate() {
        let w = read(&format!("weights/{name}"), *len)?;
        if w.iter().any(|v| !v.is_finite()) {
            return Err(fail(format!("tensor 'weights/{name}' is not finite")));
        }
        tensors.insert(name.clone(), w);
        adam.m[i] = read(&format!("adam_m/{name}"), *len)?;
        adam.v[i] = read(&format!("adam_v/{name}"), *len)?;
    }
    adam.steps = meta.adam_steps;
    let weights = Weights { config: meta.config.clone(), tensors, notes: BTreeMap::new() };
    Ok((meta, weights, adam))
}

/// Resumes a run from a checkpoint. `data`, when given, replaces the recorded data paths (the data must be
/// the same for the run to continue identically).
pub fn load_checkpoint(path: &Path, data: Option<Vec<PathBuf>>) -> Result<Trainer> {
    let (meta, weights, adam) = read_checkpoint(path)?;
    let mut settings = meta.settings;
    if let Some(d) = data {
        settings.data = d;
    }
    let pairs = discover_pairs(&settings.data)?;
    Trainer::from_checkpoint_parts(weights, settings, pairs, adam, meta.step)
}

impl Trainer {
    /// Writes this run's state to `path` (atomically).
    pub fn save_checkpoint(&self, path: &Path) -> Result<()> {
        save_checkpoint(self, path)
    }

    /// Resumes the run saved at `path` (data paths as recorded).
    pub fn load_checkpoint(path: &Path) -> Result<Trainer> {
        load_checkpoint(path, None)
    }
}
