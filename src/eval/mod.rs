//! Evaluation on the 3DMatch geometric registration benchmark (spec section 3) and on pairs files.
//!
//! - [`gtlog`]: gt.log / gt.info / result-log readers and writers.
//! - [`metrics`]: the protocol's error (eᵀΣe/Σ₁₁ with the quaternion of T_gt⁻¹ T_est, w >= 0), information
//!   matrices, rotation / translation errors, feature-match inliers.
//! - [`groundtruth`]: making gt.log / gt.info from fragments with known poses (spec 3.3).
//! - [`dataset`]: finding scenes (scene folders, a single scene, or a pairs file).
//! - [`score`]: registration recall and precision (spec 3.5) and feature-match recall (spec 3.6).
//! - [`run`]: scoring an existing log, or running the pipeline on every pair.
//! - [`report`]: JSON report and printed table.
//! - [`rotate`]: the rotation sweep (`eval --rotate`): moving source fragments and mapping poses between frames.
//!
//! Conventions: gt.log record `i j` maps fragment j into fragment i (x_i = T x_j), so registration uses
//! source = fragment j and target = fragment i. Registration recall counts only pairs with j - i > 1;
//! feature-match recall counts every gt.log pair, with a strict τ2 (inlier ratio > 0.05). Scene averages are
//! unweighted means over scenes.

pub mod dataset;
pub mod groundtruth;
pub mod gtlog;
pub mod metrics;
pub mod report;
pub mod rotate;
pub mod run;
pub mod score;

pub use dataset::{GtEntry, Protocol, SceneData, load_dataset};
pub use report::{EstimatorReport, MeanScore, Report};
pub use rotate::RotationSweep;
pub use run::{EvalOptions, run_scene, run_scene_sweep, score_log, score_log_sweep};
pub use score::{SceneScore, Thresholds};
