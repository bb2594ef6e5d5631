//! Registering one pair of described scans, and the edge information matrix of the result.
//!
//! The information matrix follows the 3DMatch toolbox and Open3D's `get_information_matrix_from_point_clouds`:
//! the points of scan j mapped by the estimate into scan i's frame that lie within a distance d of scan i form
//! the correspondence set (randomly capped in size, seeded), and Σ = Σ_q Gᵀ G with G = [I | -[q]x]. It is the same
//! computation `synth` uses for gt.info ([`crate::eval::groundtruth::pair_information`]).

use crate::eval::groundtruth::{PreparedFragment, correspondence_points};
use crate::eval::metrics::information_matrix;
use crate::pipeline::{Registrar, Round, ScanFeatures};
use crate::rng::Rng;
use nalgebra::{Matrix4, Matrix6};
use serde::{Deserialize, Serialize};

/// The registration of scan j (source) onto scan i (target), i < j, as stored in `pairs/<i>_<j>.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairResult {
    /// Target scan.
    pub i: usize,
    /// Source scan.
    pub j: usize,
    /// x_i = T x_j, rows.
    pub i_from_j: [[f64; 4]; 4],
    /// Keypoint correspondences fed to the estimator.
    pub correspondences: usize,
    /// Correspondences within the inlier threshold under the estimate.
    pub inliers: usize,
    /// inliers / correspondences.
    pub fitness: f64,
    /// RMS residual of the inliers.
    pub inlier_rmse: f64,
    /// The verdict: whether the estimate can be trusted.
    pub trusted: bool,
    /// Why not (also the error when the pair could not be registered at all).
    pub reason: Option<String>,
    /// 6x6 information matrix (translation first), rows; see the module docs.
    pub information: [[f64; 6]; 6],
    /// Seconds spent on the pair.
    pub seconds: f64,
}

impl PairResult {
    /// x_i = T x_j.
    pub fn transform(&self) -> Matrix4<f64> {
        Matrix4::from_fn(|r, c| self.i_from_j[r][c])
    }

    /// The information matrix.
    pub fn information_matrix(&self) -> Matrix6<f64> {
        Matrix6::from_fn(|r, c| self.information[r][c])
    }
}

/// How edge information matrices are computed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InformationSettings {
    /// The correspondence distance d (cloud units).
    pub distance: f64,
    /// Largest correspondence set (3DMatch: 5000).
    pub max_points: usize,
    /// Seed of the subsampling (pair (i, j) draws from its own stream).
    pub seed: u64,
}

/// A described scan's preprocessed points, indexed for the information-matrix queries up to `distance`.
pub fn prepare_for_information(features: &ScanFeatures, distance: f64) -> PreparedFragment {
    let points = features.cloud.points.iter().map(|p| p.map(f64::from)).collect();
    PreparedFragment::from_points(points, distance)
}

/// The information matrix of the edge (i, j) with estimate x_i = T x_j, from the prepared scans.
pub fn edge_information(
    prepared_i: &PreparedFragment,
    prepared_j: &PreparedFragment,
    i_from_j: &Matrix4<f64>,
    pair: (usize, usize),
    settings: &InformationSettings,
) -> Matrix6<f64> {
    let stream = (pair.0 as u64) << 32 | pair.1 as u64;
    let mut rng = Rng::derived(settings.seed, stream);
    let q = correspondence_points(prepared_i, prepared_j, i_from_j, settings.distance, settings.max_points, &mut rng);
    information_matrix(&q)
}

fn rows<const R: usize>(m: impl Fn(usize, usize) -> f64) -> [[f64; R]; R] {
    std::array::from_fn(|r| std::array::from_fn(|c| m(r, c)))
}

/// Registers described scan `j` (source) onto described scan `i` (target): correspondences, the settings'
/// estimator, the verdict and the edge information. A pair that cannot be registered (too few correspondences)
/// is returned untrusted with the identity and the error as its reason, not as an error.
#[allow(clippy::too_many_arguments)]
pub fn register_pair(
    registrar: &Registrar,
    (i, j): (usize, usize),
    target: &ScanFeatures,
    source: &ScanFeatures,
    prepared_target: &PreparedFragment,
    prepared_source: &PreparedFragment,
    information: &InformationSettings,
) -> PairResult {
    let started = std::time::Instant::now();
    let attempt = registrar.register_described_at_once(source, target, registrar.settings.estimator);
    let (t, inliers, fitness, rmse, correspondences, trusted, reason, info) = match attempt {
        Ok(Round { estimate, correspondences: c, verdict, .. }) => {
            let e = &estimate;
            let t = e.target_from_source;
            let info = edge_information(prepared_target, prepared_source, &t, (i, j), information);
            (t, e.inliers, e.fitness, e.inlier_rmse, c.len(), verdict.success, verdict.reason, info)
        }
        Err(e) => {
            let reason = Some(format!("not registered: {e}"));
            (Matrix4::identity(), 0, 0.0, 0.0, 0, false, reason, Matrix6::zeros())
        }
    };
    PairResult {
        i,
        j,
        i_from_j: rows(|r, c| t[(r, c)]),
        correspondences,
        inliers,
        fitness,
        inlier_rmse: rmse,
        trusted,
        reason,
        information: rows(|r, c| info[(r, c)]),
        seconds: started.elapsed().as_secs_f64(),
    }
}
