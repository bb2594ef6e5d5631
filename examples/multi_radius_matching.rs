//! Feature-match recall when each keypoint is matched on its PPF-FoldNet codewords at several patch radii side
//! by side (each codeword unit-normalised and weighted, then concatenated), against the ground truth of a
//! dataset `dpr-gpu eval` reads. A measurement tool for docs/experiments/context-radii.md ("Matching on codewords at several
//! radii"), not part of the pipeline.
//!
//! cargo run --release --example multi_radius_matching -- DATASET RADII WEIGHTS [KEYPOINTS] [VOXEL] [SCALE] [MODEL]
//!   RADII: comma-separated patch radii (cloud units), e.g. 0.6,0.3,1.2; the first one's keypoints are used
//!   WEIGHTS: weight sets separated by `;`, one weight per radius, e.g. "1,0,0;1,0,1;1,0.7,0.7"
//!   KEYPOINTS: keypoints per scan (default 1000); VOXEL: one voxel size for every radius (default 0: keep every
//!   point, right for files with normals); SCALE: the protocol's distances in the clouds' units, as `eval
//!   --protocol-scale` (default 1: tau1 = 0.10 m); MODEL: a weights file or a training checkpoint (default: the
//!   shipped weights)
//!
//! Beside each weight set's recall it gives the recall of the pairs grouped by their view angle: the median, over
//! the source keypoints with a target keypoint within tau1 of their true position, of the angle at that point
//! between the directions to the two fragments' sensors (each fragment's origin), the viewpoint change a
//! descriptor must bear (docs/experiments/viewpoint-change.md).
use dpr_gpu::eval::dataset::load_dataset;
use dpr_gpu::eval::metrics::count_feature_inliers;
use dpr_gpu::eval::score::Thresholds;
use dpr_gpu::io::{LoadOptions, read_cloud};
use dpr_gpu::nalgebra::{Matrix4, Vector3};
use dpr_gpu::{MatchMode, Registrar, RegistrationSettings};
use std::path::{Path, PathBuf};

/// Upper ends of the view-angle groups, degrees.
const VIEW_GROUPS: [f64; 4] = [30.0, 60.0, 90.0, 180.0];

/// One scan described at one radius: kept keypoints (ranks in the keypoint order), positions, codewords.
struct Described {
    ranks: Vec<u32>,
    points: Vec<[f32; 3]>,
    codewords: Vec<f32>,
}

impl Described {
    fn codeword(&self, rank: u32) -> &[f32] {
        let dim = self.codewords.len() / self.ranks.len();
        let row = self.ranks.binary_search(&rank).expect("rank kept at every radius");
        &self.codewords[row * dim..(row + 1) * dim]
    }
}

/// Ranks kept at every radius.
fn common_ranks(scan: &[Described]) -> Vec<u32> {
    let mut ranks = scan[0].ranks.clone();
    for other in &scan[1..] {
        ranks.retain(|r| other.ranks.binary_search(r).is_ok());
    }
    ranks
}

/// Rows of unit codewords times their radius weight, concatenated over the radii with a non-zero weight.
fn matching_rows(scan: &[Described], ranks: &[u32], weights: &[f32]) -> (Vec<f32>, usize) {
    let mut rows = Vec::new();
    let mut dim = 0;
    for &rank in ranks {
        let start = rows.len();
        for (described, &w) in scan.iter().zip(weights).filter(|(_, w)| **w != 0.0) {
            let c = described.codeword(rank);
            let norm = c.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
            rows.extend(c.iter().map(|x| x / norm * w));
        }
        dim = rows.len() - start;
    }
    (rows, dim)
}

/// The median view angle (degrees) of a pair: over the source keypoints with a target keypoint within `tau1` of
/// their true position, the angle there between the directions to the target's sensor (the origin) and the
/// source's (the source origin mapped); `None` without any such keypoint.
fn median_view_angle(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    target_from_source: &Matrix4<f64>,
    tau1: f64,
) -> Option<f64> {
    let v = |p: [f32; 3]| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let rotation = target_from_source.fixed_view::<3, 3>(0, 0);
    let source_sensor = target_from_source.fixed_view::<3, 1>(0, 3).into_owned();
    let mut angles: Vec<f64> = source
        .iter()
        .map(|&p| rotation * v(p) + source_sensor)
        .filter(|q| target.iter().any(|&t| (v(t) - q).norm() < tau1))
        .map(|q| (-q).angle(&(source_sensor - q)).to_degrees())
        .collect();
    angles.sort_by(f64::total_cmp);
    angles.get(angles.len() / 2).copied()
}

/// The weights file to describe with: `model` itself, or a training checkpoint's weights written next to it.
fn model_file(model: &str) -> Result<PathBuf, Box<dyn std::error::Error>> {
    if !model.ends_with(".ckpt.safetensors") {
        return Ok(model.into());
    }
    let (_, weights, _) = dpr_gpu::train::checkpoint::read_checkpoint(Path::new(model))?;
    let path = PathBuf::from(format!("{}.weights.safetensors", model.trim_end_matches(".ckpt.safetensors")));
    weights.save(&path)?;
    Ok(path)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: multi_radius_matching DATASET RADII WEIGHTS [KEYPOINTS] [VOXEL] [SCALE]".into());
    }
    let radii: Vec<f32> = args[1].split(',').map(str::parse).collect::<Result<_, _>>()?;
    let weight_sets: Vec<Vec<f32>> =
        args[2].split(';').map(|s| s.split(',').map(str::parse).collect::<Result<_, _>>()).collect::<Result<_, _>>()?;
    if weight_sets.iter().any(|w| w.len() != radii.len() || w.iter().all(|&x| x == 0.0)) {
        return Err("every weight set needs one weight per radius, not all zero".into());
    }
    let keypoints: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(1000);
    let voxel: f32 = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(0.0);
    let protocol = Thresholds::scaled(args.get(5).map(|s| s.parse()).transpose()?.unwrap_or(1.0));
    let model = args.get(6).map(|m| model_file(m)).transpose()?;
    let registrars = radii
        .iter()
        .map(|&r| {
            let settings = RegistrationSettings {
                radius: Some(r),
                voxel: Some(voxel),
                keypoints,
                first_keypoints: None,
                weights: model.clone(),
                ..RegistrationSettings::default()
            };
            Registrar::new(&settings)
        })
        .collect::<Result<Vec<_>, _>>()?;
    // Per weight set: matched pairs, pairs, sum of inlier ratios; per scene for the protocol's scene mean.
    let mut scene_recalls = vec![Vec::new(); weight_sets.len()];
    let (mut matched, mut ratio_sum, mut pairs) = (vec![0usize; weight_sets.len()], vec![0f64; weight_sets.len()], 0);
    // Per view-angle group: pairs, and matched pairs per weight set.
    let mut group_pairs = [0usize; VIEW_GROUPS.len()];
    let mut group_matched = vec![[0usize; VIEW_GROUPS.len()]; weight_sets.len()];
    for scene in load_dataset(Path::new(&args[0]))? {
        let mut scans = Vec::new();
        for file in &scene.files {
            let (cloud, _) = read_cloud(file, &LoadOptions::default())?;
            let mut at_radii = Vec::new();
            for registrar in &registrars {
                let f = registrar.describe(&cloud, 0)?;
                at_radii.push(Described {
                    ranks: f.keypoint_ranks.clone(),
                    points: f.keypoints.clone(),
                    codewords: f.read_codewords()?,
                });
            }
            scans.push(at_radii);
        }
        let mut scene_matched = vec![0usize; weight_sets.len()];
        for gt in &scene.gt {
            // x_i = T x_j: fragment j is the source.
            let (source, target) = (&scans[gt.j], &scans[gt.i]);
            let (source_ranks, target_ranks) = (common_ranks(source), common_ranks(target));
            let position = |scan: &[Described], rank: u32| scan[0].points[scan[0].ranks.binary_search(&rank).unwrap()];
            let angle = median_view_angle(&source[0].points, &target[0].points, &gt.i_from_j, protocol.tau1);
            let group = angle.map(|a| VIEW_GROUPS.iter().position(|&end| a < end).unwrap_or(VIEW_GROUPS.len() - 1));
            if let Some(g) = group {
                group_pairs[g] += 1;
            }
            for (k, weights) in weight_sets.iter().enumerate() {
                let (s, dim) = matching_rows(source, &source_ranks, weights);
                let (t, _) = matching_rows(target, &target_ranks, weights);
                let matches =
                    dpr_gpu::block_on(registrars[0].backend().match_codewords(&s, &t, dim, MatchMode::Mutual(1)))?;
                let inliers = count_feature_inliers(
                    matches.iter().map(|m| {
                        (
                            position(target, target_ranks[m.target as usize]),
                            position(source, source_ranks[m.source as usize]),
                        )
                    }),
                    &gt.i_from_j,
                    protocol.tau1,
                );
                let ratio = inliers as f64 / matches.len().max(1) as f64;
                ratio_sum[k] += ratio;
                if ratio > protocol.tau2 {
                    matched[k] += 1;
                    scene_matched[k] += 1;
                    if let Some(g) = group {
                        group_matched[k][g] += 1;
                    }
                }
            }
            pairs += 1;
        }
        for k in 0..weight_sets.len() {
            scene_recalls[k].push(scene_matched[k] as f64 / scene.gt.len().max(1) as f64);
        }
        eprintln!("{} done", scene.name);
    }
    for (k, weights) in weight_sets.iter().enumerate() {
        let scene_mean = scene_recalls[k].iter().sum::<f64>() / scene_recalls[k].len().max(1) as f64;
        println!(
            "radii {radii:?} weights {weights:?}: FMR {scene_mean:.3} (scene mean; {}/{pairs} pairs) inlier ratio {:.3}",
            matched[k],
            ratio_sum[k] / pairs.max(1) as f64
        );
        let mut start = 0.0;
        for (g, end) in VIEW_GROUPS.iter().enumerate() {
            println!("  view angle {start}-{end} deg: {} / {} pairs matched", group_matched[k][g], group_pairs[g]);
            start = *end;
        }
    }
    Ok(())
}
