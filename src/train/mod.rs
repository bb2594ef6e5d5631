//! Training of PPF-FoldNet, PC-FoldNet and RelativeNet together on the CPU (RelativeNet paper, section 3.3):
//! `L = L_rec + lambda1 L_pose + lambda2 L_feat` on pairs of corresponding patches.
//!
//! - the forward pass is the inference one (`FoldNet::encode_tape`/`decode_tape`, `RelativeNet::forward_tape`),
//!   which keeps every layer's output;
//! - the multiplies run in f32 (bit-identical on every CPU, what the gradient checks use) or, with
//!   [`TrainSettings::precision`] bf16, in bf16 with f32 sums for the wide layers (AMX tiles where the CPU has
//!   them, else AVX-512 BF16), weights and Adam staying f32;
//! - [`grad`], [`backward`]: backward passes of every layer and of the whole networks;
//! - [`loss`]: Chamfer distance, the pose losses (quaternion and 6-D) and the feature-consistency loss;
//! - [`contrast`]: the optional batch contrastive loss on PPF codewords (in-batch hardest negatives);
//! - [`objective`]: the per-pair loss and the batch gradient (parallel, deterministic);
//! - [`adam`]: AdamW with an exponentially decaying learning rate;
//! - [`data`]: training pairs from 3DMatch-layout datasets or pairs files;
//! - [`trainer`], [`checkpoint`]: the loop, and exact save/resume.
//!
//! ```no_run
//! use dpr_gpu::model::ModelConfig;
//! use dpr_gpu::train::{TrainSettings, Trainer};
//! # fn main() -> dpr_gpu::Result<()> {
//! let settings = TrainSettings { data: vec!["data/synth".into()], ..TrainSettings::default() };
//! let mut trainer = Trainer::new(ModelConfig::default(), settings)?;
//! for _ in 0..100 {
//!     let losses = trainer.step()?;
//!     println!("{} {:.4}", trainer.step_count(), losses.total);
//! }
//! trainer.save_checkpoint("run.ckpt.safetensors".as_ref())?;
//! trainer.weights().save("weights.safetensors".as_ref())?;
//! # Ok(())
//! # }
//! ```

pub mod adam;
pub mod backward;
pub mod checkpoint;
pub mod contrast;
pub mod data;
pub mod distill;
pub mod grad;
pub mod loss;
pub mod objective;
pub mod occlusion;
pub mod trainer;

pub use adam::{Adam, AdamSettings};
pub use backward::Gradients;
pub use checkpoint::{load_checkpoint, save_checkpoint};
pub use data::{DataSettings, FragmentPair, Sampler};
pub use objective::{LossSettings, Losses, PairSample, batch_loss, batch_objective, batch_objective_at};
pub use trainer::{TrainSettings, Trainer};
