//! The evaluation report: per-scene and mean scores for each estimator, as JSON and as a printed table.

use super::score::{SceneScore, Thresholds};
use crate::settings::{RegistrationSettings, StageTime};
use serde::Serialize;

/// Unweighted means over scenes (as the paper's "Average" row); scenes without a value are skipped.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MeanScore {
    /// Number of scenes.
    pub scenes: usize,
    /// Mean registration recall.
    pub registration_recall: Option<f64>,
    /// Mean precision.
    pub precision: Option<f64>,
    /// Mean feature-match recall.
    pub feature_match_recall: Option<f64>,
    /// Mean of the scenes' mean inlier ratios.
    pub mean_inlier_ratio: Option<f64>,
}

fn mean(values: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = values.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

impl MeanScore {
    /// The unweighted mean of the scene scores.
    pub fn of(scenes: &[SceneScore]) -> MeanScore {
        MeanScore {
            scenes: scenes.len(),
            registration_recall: mean(scenes.iter().map(|s| s.registration_recall)),
            precision: mean(scenes.iter().map(|s| s.precision)),
            feature_match_recall: mean(scenes.iter().map(|s| s.feature_match_recall)),
            mean_inlier_ratio: mean(scenes.iter().map(|s| s.mean_inlier_ratio)),
        }
    }
}

/// All scenes for one estimator (or one scored log).
#[derive(Clone, Debug, Serialize)]
pub struct EstimatorReport {
    /// "relativenet", "ransac" or "log".
    pub estimator: String,
    /// Per-scene scores.
    pub scenes: Vec<SceneScore>,
    /// Mean over scenes.
    pub mean: MeanScore,
}

impl EstimatorReport {
    /// A report with its mean computed.
    pub fn new(estimator: impl Into<String>, scenes: Vec<SceneScore>) -> EstimatorReport {
        let mean = MeanScore::of(&scenes);
        EstimatorReport { estimator: estimator.into(), scenes, mean }
    }
}

/// How one fragment was described (pipeline runs).
#[derive(Clone, Debug, Serialize)]
pub struct FragmentReport {
    /// Scene name.
    pub scene: String,
    /// Fragment index.
    pub index: usize,
    /// Points after preprocessing.
    pub points: usize,
    /// Keypoints described.
    pub keypoints: usize,
    /// Stage times of the description.
    pub timings: Vec<StageTime>,
}

/// The whole evaluation.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The dataset path.
    pub dataset: String,
    /// "pipeline" (registration run here) or "log" (an existing result log scored).
    pub mode: String,
    /// The scored log (log mode).
    pub log: Option<String>,
    /// Thresholds used.
    pub thresholds: Thresholds,
    /// Rules, in words.
    pub protocol: Vec<String>,
    /// Registration settings (pipeline mode).
    pub settings: Option<RegistrationSettings>,
    /// One entry per estimator.
    pub estimators: Vec<EstimatorReport>,
    /// Per-fragment description statistics (pipeline mode).
    pub fragments: Vec<FragmentReport>,
}

/// The protocol rules, as printed in reports.
pub fn protocol_notes(t: &Thresholds) -> Vec<String> {
    vec![
        format!(
            "3DMatch scenes: registration recall over gt.log pairs with j - i > 1; success if e^T Sigma e / Sigma_11 <= {:.4} (e = [t; quaternion vector part, w >= 0] of T_gt^-1 T_est)",
            t.max_information_error
        ),
        format!(
            "pairs files: every pair counts; success if the RMSE of the source points under T_est vs T_gt <= {:.4}",
            t.max_rmse
        ),
        "precision = good / reported results that count for recall (results not in gt.log count against it)".into(),
        format!(
            "feature-match recall over all gt.log pairs (consecutive included): inlier if |x_i - T_ij x_j| < tau1 = {:.4}; matched if inlier ratio > tau2 = {} (strict)",
            t.tau1, t.tau2
        ),
        "scene averages are unweighted means over scenes".into(),
    ]
}

fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), |x| format!("{x:.4}"))
}

/// The summary table: one row per estimator and scene, then the mean.
pub fn format_table(report: &Report) -> String {
    let mut out = format!(
        "{:<12} {:<28} {:>6} {:>6} {:>6} {:>8} {:>8} {:>8} {:>8}\n",
        "estimator", "scene", "pairs", "RRset", "good", "FMR", "IR", "RR", "prec"
    );
    for e in &report.estimators {
        for s in &e.scenes {
            out.push_str(&format!(
                "{:<12} {:<28} {:>6} {:>6} {:>6} {:>8} {:>8} {:>8} {:>8}\n",
                e.estimator,
                s.scene,
                s.gt_pairs,
                s.recall_pairs,
                s.good,
                cell(s.feature_match_recall),
                cell(s.mean_inlier_ratio),
                cell(s.registration_recall),
                cell(s.precision)
            ));
        }
        out.push_str(&format!(
            "{:<12} {:<28} {:>6} {:>6} {:>6} {:>8} {:>8} {:>8} {:>8}\n",
            e.estimator,
            format!("mean ({} scenes)", e.mean.scenes),
            "",
            "",
            "",
            cell(e.mean.feature_match_recall),
            cell(e.mean.mean_inlier_ratio),
            cell(e.mean.registration_recall),
            cell(e.mean.precision)
        ));
    }
    out
}
