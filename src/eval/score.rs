//! Scoring a result log against a scene's ground truth: registration recall and precision (spec 3.5) and
//! feature-match recall (spec 3.6), per pair and per scene.

use super::dataset::{GtEntry, SceneData};
use super::gtlog::LogRecord;
use crate::error::Result;
use crate::estimate::visibility::Consistency;
use crate::pose::{rotation_error_deg, translation_error};
use crate::settings::StageTime;
use nalgebra::Matrix4;
use serde::Serialize;
use std::collections::HashMap;

/// The patch radius the protocol's distances are defined for (metres): the default patch radius of the shipped
/// weights (their 0.30 m training radius times `RADIUS_PER_TRAINING_RADIUS`, 0.60 m).
pub const REFERENCE_RADIUS: f64 = 0.30 * crate::settings::RADIUS_PER_TRAINING_RADIUS as f64;

/// Success and inlier thresholds. At the reference radius (0.60 m) they are exactly the protocol's; for other
/// radii every distance scales with `radius / 0.60` (so object-scale data keeps proportional thresholds).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Thresholds {
    /// radius / 0.60.
    pub scale: f64,
    /// 3DMatch scenes: success when eᵀΣe / Σ₁₁ <= this (0.04 m², i.e. (0.2 m)², times scale²).
    pub max_information_error: f64,
    /// Pairs files: success when the RMSE between the source points under the estimate and under the ground
    /// truth is <= this (0.2 m times scale).
    pub max_rmse: f64,
    /// Feature-match inlier distance τ1 (0.10 m times scale): |x_i − T_ij x_j| < τ1 (strict).
    pub tau1: f64,
    /// A pair's features match when inliers / correspondences > τ2 (0.05, strict, as XuyangBai's evaluation).
    pub tau2: f64,
    /// With `--all-pairs`, a pair is reported when the share of fragment-i points within this distance of the
    /// transformed fragment j exceeds `min_overlap` (0.05 m times scale, as `register2Fragments.m`).
    pub overlap_distance: f64,
}

impl Thresholds {
    /// The thresholds for patch radius `radius` (metres or the clouds' units).
    pub fn for_radius(radius: f64) -> Thresholds {
        Thresholds::scaled(radius / REFERENCE_RADIUS)
    }

    /// The protocol's distances times `s` (1: exactly the protocol's, in metres).
    pub fn scaled(s: f64) -> Thresholds {
        Thresholds {
            scale: s,
            max_information_error: 0.04 * s * s,
            max_rmse: 0.2 * s,
            tau1: 0.10 * s,
            tau2: 0.05,
            overlap_distance: 0.05 * s,
        }
    }
}

impl Default for Thresholds {
    fn default() -> Self {
        Thresholds::for_radius(REFERENCE_RADIUS)
    }
}

/// Feature-matching outcome of one pair: correspondences and how many are ground-truth inliers.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FeatureMatch {
    /// Correspondences formed.
    pub correspondences: usize,
    /// Correspondences with |x_i − T_ij x_j| < τ1.
    pub inliers: usize,
}

impl FeatureMatch {
    /// inliers / correspondences (0 without correspondences).
    pub fn inlier_ratio(&self) -> f64 {
        if self.correspondences == 0 { 0.0 } else { self.inliers as f64 / self.correspondences as f64 }
    }
}

/// What the pipeline did for one pair (absent when scoring an existing log).
#[derive(Clone, Debug, Default, Serialize)]
pub struct PairRun {
    /// Correspondences fed to the estimator.
    pub correspondences: usize,
    /// Keypoints per scan of the progressive schedule's round that gave the pose.
    pub keypoints: usize,
    /// Pose hypotheses the estimator scored.
    pub hypotheses: usize,
    /// Correspondences within the estimator's inlier threshold under its pose.
    pub estimator_inliers: usize,
    /// Estimated overlap (share of fragment-i points near transformed fragment j), with `--all-pairs`.
    pub estimated_overlap: Option<f64>,
    /// The overlap under the ground truth, the same measure (gt.log pairs): what recall by overlap bin bins.
    pub gt_overlap: Option<f64>,
    /// Wall time of the pair's stages (correspond, estimate).
    pub timings: Vec<StageTime>,
    /// Why the estimator produced no pose, if it failed.
    pub error: Option<String>,
    /// The success verdict on the estimate (see [`crate::verdict`]), when a pose was produced.
    pub trusted: Option<bool>,
    /// Why the verdict did not trust the estimate.
    pub reason: Option<String>,
    /// Where the pose puts each scan's points in the other scan's view from its viewpoint (shares of the checked
    /// points, both ways averaged: on its first surface, and in the space it saw empty; see
    /// [`crate::estimate::visibility`]).
    pub free_space: Option<Consistency>,
}

/// One pair's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct PairReport {
    /// Target fragment.
    pub i: usize,
    /// Source fragment.
    pub j: usize,
    /// The pair is in gt.log.
    pub in_gt: bool,
    /// The pair counts for registration recall / precision (3DMatch: j - i > 1).
    pub counts_for_recall: bool,
    /// The method reported a pose for it (it is in the result log).
    pub reported: bool,
    /// The criterion value: eᵀΣe/Σ₁₁ (m²) for 3DMatch scenes, source-point RMSE (m) for pairs files.
    pub error: Option<f64>,
    /// Registered correctly (false when missing; absent when not in gt.log).
    pub success: Option<bool>,
    /// Rotation error against the ground truth (degrees).
    pub rotation_error_deg: Option<f64>,
    /// Translation error against the ground truth (cloud units).
    pub translation_error: Option<f64>,
    /// Feature-matching outcome (pipeline runs only).
    pub feature_match: Option<FeatureMatch>,
    /// Pipeline details (pipeline runs only).
    pub run: Option<PairRun>,
}

/// One scene's scores for one estimator (or one result log).
#[derive(Clone, Debug, Serialize)]
pub struct SceneScore {
    /// Scene name.
    pub scene: String,
    /// gt.log pairs (the feature-match recall denominator).
    pub gt_pairs: usize,
    /// gt.log pairs that count for recall (3DMatch: j - i > 1).
    pub recall_pairs: usize,
    /// Reported results that count for precision.
    pub reported: usize,
    /// Correctly registered recall pairs.
    pub good: usize,
    /// good / recall_pairs.
    pub registration_recall: Option<f64>,
    /// good / reported.
    pub precision: Option<f64>,
    /// Share of gt.log pairs whose inlier ratio exceeds τ2 (pipeline runs only).
    pub feature_match_recall: Option<f64>,
    /// Mean inlier ratio over gt.log pairs (pipeline runs only).
    pub mean_inlier_ratio: Option<f64>,
    /// Every gt.log pair and every reported pair, sorted by (i, j).
    pub pairs: Vec<PairReport>,
}

/// Scores `results` against `scene` (spec 3.5): for each result that counts for recall, not in gt.log is a false
/// positive; otherwise it succeeds when `error_of(gt, estimate) <= max_error`. gt pairs without a result count
/// as failures. Results that do not count for recall (consecutive pairs) are listed but not scored.
pub fn score_registration(
    scene: &SceneData,
    results: &[LogRecord],
    error_of: &dyn Fn(&GtEntry, &Matrix4<f64>) -> Result<f64>,
    max_error: f64,
) -> Result<SceneScore> {
    let mut pairs = Vec::new();
    let mut reported = 0;
    let mut good = 0;
    let mut seen = std::collections::HashSet::new();
    for r in results {
        seen.insert((r.i, r.j));
        let counts = scene.counts_for_recall(r.i, r.j);
        let gt = scene.lookup(r.i, r.j);
        if counts {
            reported += 1;
        }
        let (error, success, rot, trans) = match gt {
            Some(g) => {
                let e = error_of(g, &r.i_from_j)?;
                let ok = e <= max_error;
                if counts && ok {
                    good += 1;
                }
                (
                    Some(e),
                    Some(ok),
                    Some(rotation_error_deg(&g.i_from_j, &r.i_from_j)),
                    Some(translation_error(&g.i_from_j, &r.i_from_j)),
                )
            }
            None => (None, None, None, None),
        };
        pairs.push(PairReport {
            i: r.i,
            j: r.j,
            in_gt: gt.is_some(),
            counts_for_recall: counts,
            reported: true,
            error,
            success,
            rotation_error_deg: rot,
            translation_error: trans,
            feature_match: None,
            run: None,
        });
    }
    for g in &scene.gt {
        if !seen.contains(&(g.i, g.j)) {
            pairs.push(PairReport {
                i: g.i,
                j: g.j,
                in_gt: true,
                counts_for_recall: scene.counts_for_recall(g.i, g.j),
                reported: false,
                error: None,
                success: Some(false),
                rotation_error_deg: None,
                translation_error: None,
                feature_match: None,
                run: None,
            });
        }
    }
    pairs.sort_by_key(|p| (p.i, p.j));
    let recall_pairs = scene.gt.iter().filter(|g| scene.counts_for_recall(g.i, g.j)).count();
    Ok(SceneScore {
        scene: scene.name.clone(),
        gt_pairs: scene.gt.len(),
        recall_pairs,
        reported,
        good,
        registration_recall: (recall_pairs > 0).then(|| good as f64 / recall_pairs as f64),
        precision: (reported > 0).then(|| good as f64 / reported as f64),
        feature_match_recall: None,
        mean_inlier_ratio: None,
        pairs,
    })
}

/// Adds feature-match recall (spec 3.6) to a scene score: over all gt.log pairs (consecutive ones included), a
/// pair matches when its inlier ratio is > τ2; missing pairs count as unmatched with ratio 0.
pub fn add_feature_matches(score: &mut SceneScore, matches: &HashMap<(usize, usize), FeatureMatch>, tau2: f64) {
    let mut matched = 0;
    let mut ratio_sum = 0.0;
    for p in score.pairs.iter_mut() {
        p.feature_match = matches.get(&(p.i, p.j)).copied();
        if p.in_gt {
            let ratio = p.feature_match.map_or(0.0, |f| f.inlier_ratio());
            ratio_sum += ratio;
            if ratio > tau2 {
                matched += 1;
            }
        }
    }
    if score.gt_pairs > 0 {
        score.feature_match_recall = Some(matched as f64 / score.gt_pairs as f64);
        score.mean_inlier_ratio = Some(ratio_sum / score.gt_pairs as f64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::dataset::Protocol;
    use std::path::PathBuf;

    fn scene(pairs: &[(usize, usize)]) -> SceneData {
        let gt =
            pairs.iter().map(|&(i, j)| GtEntry { i, j, i_from_j: Matrix4::identity(), information: None }).collect();
        SceneData::new("s".into(), PathBuf::new(), vec![PathBuf::new(); 6], gt, Protocol::ThreeDMatch)
    }

    fn rec(i: usize, j: usize, ok: bool) -> LogRecord {
        let mut m = Matrix4::identity();
        if !ok {
            m[(0, 3)] = 1.0;
        }
        LogRecord { i, j, n: 6, i_from_j: m }
    }

    fn translation_error_of(g: &GtEntry, est: &Matrix4<f64>) -> Result<f64> {
        Ok(translation_error(&g.i_from_j, est))
    }

    #[test]
    fn consecutive_pairs_excluded_missing_count_against_recall_extras_against_precision() {
        let s = scene(&[(0, 1), (0, 2), (1, 3), (2, 5)]);
        // (0,1) consecutive and wrong: ignored for recall. (0,2) good, (1,3) wrong, (2,5) missing,
        // (0,4) not in gt: false positive. (3,4) consecutive and not in gt: not counted at all.
        let results = [rec(0, 1, false), rec(0, 2, true), rec(1, 3, false), rec(0, 4, true), rec(3, 4, true)];
        let sc = score_registration(&s, &results, &translation_error_of, 0.2).unwrap();
        assert_eq!((sc.gt_pairs, sc.recall_pairs, sc.reported, sc.good), (4, 3, 3, 1));
        assert_eq!(sc.registration_recall, Some(1.0 / 3.0));
        assert_eq!(sc.precision, Some(1.0 / 3.0));
        let missing = sc.pairs.iter().find(|p| (p.i, p.j) == (2, 5)).unwrap();
        assert!(!missing.reported && missing.success == Some(false));
        let extra = sc.pairs.iter().find(|p| (p.i, p.j) == (0, 4)).unwrap();
        assert!(!extra.in_gt && extra.success.is_none());
    }

    #[test]
    fn feature_match_recall_uses_all_gt_pairs_and_a_strict_tau2() {
        let s = scene(&[(0, 1), (0, 2), (1, 3)]);
        let mut sc = score_registration(&s, &[], &translation_error_of, 0.2).unwrap();
        assert_eq!(sc.registration_recall, Some(0.0));
        let mut m = HashMap::new();
        m.insert((0, 1), FeatureMatch { correspondences: 100, inliers: 6 }); // consecutive, 6% > 5%: matched
        m.insert((0, 2), FeatureMatch { correspondences: 100, inliers: 5 }); // exactly 5%: not matched
        add_feature_matches(&mut sc, &m, 0.05);
        assert_eq!(sc.feature_match_recall, Some(1.0 / 3.0));
        assert!((sc.mean_inlier_ratio.unwrap() - 0.11 / 3.0).abs() < 1e-12);
    }
}
