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
    /// The sweep angle the source fragments were rotated by (rotation sweeps only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation_deg: Option<f64>,
    /// Per-scene scores.
    pub scenes: Vec<SceneScore>,
    /// Mean over scenes.
    pub mean: MeanScore,
}

impl EstimatorReport {
    /// A report with its mean computed.
    pub fn new(estimator: impl Into<String>, scenes: Vec<SceneScore>) -> EstimatorReport {
        let mean = MeanScore::of(&scenes);
        EstimatorReport { estimator: estimator.into(), rotation_deg: None, scenes, mean }
    }

    /// The same report, marked as the sweep angle `degrees`.
    pub fn at_rotation(self, degrees: f64) -> EstimatorReport {
        EstimatorReport { rotation_deg: Some(degrees), ..self }
    }
}

/// The rotation sweep of a report (see [`super::rotate`]).
#[derive(Clone, Debug, Serialize)]
pub struct RotationReport {
    /// The angles, in degrees, in the order given.
    pub degrees: Vec<f64>,
    /// `--rotate-seed`.
    pub seed: u64,
    /// The rules, in words.
    pub notes: Vec<String>,
    /// Axis and centre of every rotated source fragment (M = rotation by the angle about `axis` through
    /// `center`, fragment frame).
    pub fragments: Vec<super::rotate::FragmentRotation>,
}

/// The sweep rules, as printed in reports.
pub fn rotation_notes() -> Vec<String> {
    vec![
        "every source fragment j of a pair (i, j) is moved by M: rotation by the angle about a seeded random unit axis through the centroid of its points as loaded; targets are not moved".into(),
        "axis per scene and fragment: uniform on the sphere from --rotate-seed and FNV-1a(\"<scene>/<j>\"), the same for every angle".into(),
        "registration is scored in the original frames (T_est' M against T_gt with gt.info), rotation/translation errors likewise; feature matches are counted on the moved data with T_gt M^-1".into(),
        "result logs hold target_from_rotated_source (T_est'); T_est = T_est' M".into(),
    ]
}

/// How one fragment was described (pipeline runs).
#[derive(Clone, Debug, Serialize)]
pub struct FragmentReport {
    /// Scene name.
    pub scene: String,
    /// Fragment index.
    pub index: usize,
    /// The sweep angle this description's fragment was rotated by (rotation sweeps only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation_deg: Option<f64>,
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
    /// The radius chosen from each scene's clouds (none when a radius was given); the thresholds above are the
    /// first scene's, each scene's follow its radius.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub scales: Vec<SceneScale>,
    /// Registration settings (pipeline mode).
    pub settings: Option<RegistrationSettings>,
    /// The rotation sweep (`--rotate` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation: Option<RotationReport>,
    /// One entry per estimator; with a rotation sweep, one per angle and estimator (angle-major).
    pub estimators: Vec<EstimatorReport>,
    /// Per-fragment description statistics (pipeline mode).
    pub fragments: Vec<FragmentReport>,
}

/// The patch radius chosen from one scene's clouds.
#[derive(Clone, Debug, Serialize)]
pub struct SceneScale {
    /// Scene name.
    pub scene: String,
    /// Patch radius (cloud units).
    pub radius: f32,
    /// How it was chosen ([`crate::scale::ScaleChoice::rule`]).
    pub rule: String,
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

/// One row of the table: the label columns, then the counts and the scores.
fn row(labels: &[String], counts: [String; 3], scores: [String; 4]) -> String {
    let mut out = String::new();
    for (k, l) in labels.iter().enumerate() {
        // The first label is the estimator (12 wide, left); the scene (28 wide, left) is last; a rotation
        // angle (6 wide, right) sits between them.
        let w = if k == 0 {
            format!("{l:<12}")
        } else if k + 1 == labels.len() {
            format!("{l:<28}")
        } else {
            format!("{l:>6}")
        };
        if k > 0 {
            out.push(' ');
        }
        out.push_str(&w);
    }
    for c in counts {
        out.push_str(&format!(" {c:>6}"));
    }
    for v in scores {
        out.push_str(&format!(" {v:>8}"));
    }
    out.push('\n');
    out
}

/// The summary table: one row per estimator and scene, then the mean. With a rotation sweep a `rot` column
/// gives each row's angle, and a summary of the means per angle and estimator follows.
pub fn format_table(report: &Report) -> String {
    let sweep = report.rotation.is_some();
    let labels = |estimator: &str, rotation: Option<f64>, scene: String| -> Vec<String> {
        match (sweep, rotation) {
            (true, Some(d)) => vec![estimator.to_string(), super::rotate::angle_label(d), scene],
            (true, None) => vec![estimator.to_string(), String::new(), scene],
            (false, _) => vec![estimator.to_string(), scene],
        }
    };
    let header: Vec<String> = if sweep {
        vec!["estimator".into(), "rot".into(), "scene".into()]
    } else {
        vec!["estimator".into(), "scene".into()]
    };
    let mut out = row(
        &header,
        ["pairs".into(), "RRset".into(), "good".into()],
        ["FMR".into(), "IR".into(), "RR".into(), "prec".into()],
    );
    for e in &report.estimators {
        for s in &e.scenes {
            out.push_str(&row(
                &labels(&e.estimator, e.rotation_deg, s.scene.clone()),
                [s.gt_pairs.to_string(), s.recall_pairs.to_string(), s.good.to_string()],
                [s.feature_match_recall, s.mean_inlier_ratio, s.registration_recall, s.precision].map(cell),
            ));
        }
        out.push_str(&row(
            &labels(&e.estimator, e.rotation_deg, format!("mean ({} scenes)", e.mean.scenes)),
            [String::new(), String::new(), String::new()],
            [e.mean.feature_match_recall, e.mean.mean_inlier_ratio, e.mean.registration_recall, e.mean.precision]
                .map(cell),
        ));
    }
    if sweep {
        out.push_str("rotation sweep, means over scenes:\n");
        out.push_str(&format!(
            "{:>8} {:<12} {:>8} {:>8} {:>8} {:>8}\n",
            "rot(deg)", "estimator", "FMR", "IR", "RR", "prec"
        ));
        for e in &report.estimators {
            out.push_str(&format!(
                "{:>8} {:<12} {:>8} {:>8} {:>8} {:>8}\n",
                e.rotation_deg.map(super::rotate::angle_label).unwrap_or_default(),
                e.estimator,
                cell(e.mean.feature_match_recall),
                cell(e.mean.mean_inlier_ratio),
                cell(e.mean.registration_recall),
                cell(e.mean.precision)
            ));
        }
    }
    out
}

/// The per-pair table: for every estimator (and sweep angle) and scene, each pair that is in gt.log or was
/// reported, with its rotation and translation errors, the criterion value and the outcome.
pub fn format_pairs(report: &Report) -> String {
    let mut out = format!(
        "{:<12} {:>6} {:<20} {:>9} {:>9} {:>9} {:>10} {:>6} {:>7} {}\n",
        "estimator", "rot", "scene", "pair j>i", "rot(deg)", "trans", "criterion", "IR", "counts", "outcome"
    );
    let opt = |v: Option<f64>, digits: usize| v.map_or_else(|| "-".to_string(), |x| format!("{x:.digits$}"));
    for e in &report.estimators {
        let angle = e.rotation_deg.map(super::rotate::angle_label).unwrap_or_default();
        for s in &e.scenes {
            for p in &s.pairs {
                let outcome = match (p.success, p.reported) {
                    (Some(true), _) => "ok",
                    (Some(false), true) => "FAIL",
                    (Some(false), false) => "missing",
                    (None, _) => "not in gt.log",
                };
                out.push_str(&format!(
                    "{:<12} {:>6} {:<20} {:>9} {:>9} {:>9} {:>10} {:>6} {:>7} {outcome}\n",
                    e.estimator,
                    angle,
                    s.scene,
                    format!("{}>{}", p.j, p.i),
                    opt(p.rotation_error_deg, 2),
                    opt(p.translation_error, 3),
                    opt(p.error, 4),
                    opt(p.feature_match.as_ref().map(|f| f.inlier_ratio()), 3),
                    if p.counts_for_recall { "yes" } else { "no" },
                ));
            }
        }
    }
    out
}

/// What the table's abbreviations mean, printed under it.
pub fn legend(t: &Thresholds) -> String {
    [
        "legend:".to_string(),
        "  pairs  gt.log pairs of the scene; RRset: those that count for registration recall (3DMatch: j - i > 1)"
            .to_string(),
        "  good   RRset pairs registered correctly".to_string(),
        format!(
            "  FMR    feature-match recall: share of gt.log pairs whose correspondences have an inlier ratio > {} (inlier: within {:.4} under the ground truth)",
            t.tau2, t.tau1
        ),
        "  IR     mean inlier ratio of the correspondences over gt.log pairs".to_string(),
        "  RR     registration recall: good / RRset; '-' when the scene has no pair that counts (e.g. only consecutive fragments)"
            .to_string(),
        "  prec   precision: good / results reported for pairs that count".to_string(),
        "  criterion  e^T Sigma e / Sigma_11 (m^2, 3DMatch scenes) or source-point RMSE (pairs files); counts: the pair counts for RR"
            .to_string(),
    ]
    .join("\n")
        + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(scene: &str, rr: Option<f64>) -> SceneScore {
        SceneScore {
            scene: scene.into(),
            gt_pairs: 7,
            recall_pairs: 4,
            reported: 4,
            good: 3,
            registration_recall: rr,
            precision: Some(0.75),
            feature_match_recall: Some(0.5),
            mean_inlier_ratio: None,
            pairs: Vec::new(),
        }
    }

    fn report(estimators: Vec<EstimatorReport>, rotation: Option<RotationReport>) -> Report {
        Report {
            dataset: "d".into(),
            mode: "log".into(),
            log: None,
            thresholds: Thresholds::default(),
            protocol: Vec::new(),
            scales: Vec::new(),
            settings: None,
            rotation,
            estimators,
            fragments: Vec::new(),
        }
    }

    #[test]
    fn table_without_a_sweep_keeps_the_fixed_column_layout() {
        let r = report(vec![EstimatorReport::new("ransac", vec![score("kitchen", Some(0.75))])], None);
        // The layout as a single format string (the table's original definition).
        let line = |a: &str, b: &str, c: [&str; 3], d: [&str; 4]| {
            format!(
                "{:<12} {:<28} {:>6} {:>6} {:>6} {:>8} {:>8} {:>8} {:>8}\n",
                a, b, c[0], c[1], c[2], d[0], d[1], d[2], d[3]
            )
        };
        let expected = line("estimator", "scene", ["pairs", "RRset", "good"], ["FMR", "IR", "RR", "prec"])
            + &line("ransac", "kitchen", ["7", "4", "3"], ["0.5000", "-", "0.7500", "0.7500"])
            + &line("ransac", "mean (1 scenes)", ["", "", ""], ["0.5000", "-", "0.7500", "0.7500"]);
        assert_eq!(format_table(&r), expected);
        let json = serde_json::to_value(&r).unwrap();
        assert!(json.get("rotation").is_none() && json["estimators"][0].get("rotation_deg").is_none());
    }

    #[test]
    fn table_with_a_sweep_labels_every_row_with_its_angle() {
        let sweep = RotationReport { degrees: vec![0.0, 90.0], seed: 0, notes: Vec::new(), fragments: Vec::new() };
        let r = report(
            vec![
                EstimatorReport::new("ransac", vec![score("kitchen", Some(1.0))]).at_rotation(0.0),
                EstimatorReport::new("ransac", vec![score("kitchen", Some(0.25))]).at_rotation(90.0),
            ],
            Some(sweep),
        );
        let table = format_table(&r);
        assert!(table.lines().next().unwrap().contains(" rot "), "{table}");
        let rows: Vec<&str> = table.lines().filter(|l| l.contains("kitchen")).collect();
        assert_eq!(rows.len(), 2);
        assert!(rows[0].contains("     0 kitchen") && rows[0].contains("1.0000"), "{table}");
        assert!(rows[1].contains("    90 kitchen") && rows[1].contains("0.2500"), "{table}");
        let summary: Vec<&str> = table.lines().skip_while(|l| !l.starts_with("rotation sweep")).collect();
        assert_eq!(summary.len(), 4, "{table}");
        assert!(summary[3].trim_start().starts_with("90 ransac"), "{table}");
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(json["estimators"][1]["rotation_deg"], 90.0);
        assert_eq!(json["rotation"]["degrees"][1], 90.0);
    }

    #[test]
    fn pair_table_lists_every_pair_with_its_errors_and_outcome() {
        use super::super::score::{FeatureMatch, PairReport};
        let pair = |j: usize, success: Option<bool>, reported: bool| PairReport {
            i: 0,
            j,
            in_gt: success.is_some(),
            counts_for_recall: j > 1,
            reported,
            error: reported.then_some(0.01),
            success,
            rotation_error_deg: reported.then_some(1.5),
            translation_error: reported.then_some(0.02),
            feature_match: Some(FeatureMatch { correspondences: 10, inliers: 4 }),
            run: None,
        };
        let mut kitchen = score("kitchen", Some(0.5));
        kitchen.pairs = vec![pair(2, Some(true), true), pair(3, Some(false), true), pair(4, Some(false), false)];
        let r = report(vec![EstimatorReport::new("ransac", vec![kitchen])], None);
        let table = format_pairs(&r);
        let rows: Vec<&str> = table.lines().skip(1).collect();
        assert_eq!(rows.len(), 3, "{table}");
        assert!(rows[0].contains("2>0") && rows[0].contains("1.50") && rows[0].ends_with("ok"), "{table}");
        assert!(rows[0].contains("0.400"), "inlier ratio 4/10: {table}");
        assert!(rows[1].ends_with("FAIL") && rows[2].ends_with("missing"), "{table}");
        let legend = legend(&Thresholds::default());
        for abbreviation in ["RRset", "FMR", "IR", "RR ", "prec", "'-'"] {
            assert!(legend.contains(abbreviation), "{abbreviation} not explained: {legend}");
        }
    }
}
