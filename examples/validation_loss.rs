//! The validation loss of weights files on a dataset: the f32 training objective (every term, the contrastive
//! one at margin 0.5) averaged over 8 batches of 32 pairs that the trainer's sampler draws from the dataset
//! with a fixed seed, so every weights file sees the same batches (docs/experiments/bf16-training.md).
//!
//! ```sh
//! cargo run --release --example validation_loss -- data/val run-a.safetensors run-b.safetensors
//! ```

use dpr_gpu::model::Weights;
use dpr_gpu::train::data::discover_pairs;
use dpr_gpu::train::{DataSettings, LossSettings, Losses, Sampler, batch_loss};

/// Seed of the batches, batches and pairs per batch.
const SEED: u64 = 12_345;
const BATCHES: u64 = 8;
const PAIRS: usize = 32;

fn main() -> dpr_gpu::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some((data, files)) = args.split_first().filter(|(_, f)| !f.is_empty()) else {
        eprintln!("usage: validation_loss DATASET WEIGHTS...");
        std::process::exit(2);
    };
    let loss = LossSettings { contrast: true, contrast_margin: 0.5, ..LossSettings::default() };
    for path in files {
        let weights = Weights::load(path.as_ref())?;
        let pairs = discover_pairs(&[data.into()])?;
        let mut sampler = Sampler::new(pairs, DataSettings::default(), &weights.config)?;
        let mut mean = Losses::default();
        for step in 0..BATCHES {
            let batch = sampler.batch(SEED, step, PAIRS)?;
            mean.add_scaled(&batch_loss(&weights, &batch, &loss)?, 1.0 / BATCHES as f64);
        }
        let Losses { total, rec, pose, feat, contrast } = mean;
        println!("{path}: total {total:.4} rec {rec:.4} pose {pose:.4} feat {feat:.4} contrast {contrast:.4}");
    }
    Ok(())
}
