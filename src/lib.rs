//! # dpr-gpu
//!
//! Learned pairwise registration of 3D scans: "3D Local Features for Direct Pairwise Registration"
//! (Deng, Birdal, Ilic, CVPR 2019). PPF-FoldNet codewords give correspondences, RelativeNet predicts one
//! relative rotation per correspondence, every correspondence becomes a pose hypothesis, all hypotheses are
//! scored, and the best is refined on its inliers.
//!
//! Transforms are named by their frames: `target_from_source` maps source points into the target frame,
//! p_target = T p_source. Distances are in the clouds' units (metres by default); the patch radius, voxel
//! size and thresholds scale together, so other units work by setting `radius`.
//!
//! ```
//! use dpr_gpu::{RegistrationSettings, register};
//!
//! # fn main() -> dpr_gpu::Result<()> {
//! // A scan of the shipped example pair (a synthetic room), and the same scan after a known motion, far from
//! // the identity: the built-in weights cover every relative rotation.
//! let path = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/pair/cloud_bin_0.ply");
//! let (source, _) = dpr_gpu::io::read_cloud(path.as_ref(), &Default::default())?;
//! let truth = nalgebra::Matrix4::new_translation(&nalgebra::Vector3::new(0.3, -0.2, 0.1))
//!     * nalgebra::Matrix4::from_euler_angles(2.5, -0.4, 1.0);
//! let target = source.transformed(&truth);
//!
//! let result = register(&source, &target, &RegistrationSettings::default())?;
//! assert!(result.success, "{:?}", result.reason);
//! let error = dpr_gpu::pose::rotation_error_deg(&result.estimate.target_from_source, &truth);
//! assert!(error < 0.5, "rotation error {error} deg");
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod backend;
#[cfg(feature = "cli")]
pub mod cli;
pub mod cloud;
pub mod cpu;
pub mod error;
pub mod estimate;
pub mod eval;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod io;
pub mod model;
pub mod multiway;
pub mod pipeline;
pub mod pose;
pub mod pose_graph;
pub mod preprocess;
pub mod result;
pub mod rng;
pub mod scale;
pub mod settings;
pub mod snapshot;
pub mod spatial;
pub mod synth;
pub mod train;
pub mod verdict;

pub use cloud::PointCloud;

/// Runs a future of this crate to completion on the calling thread: the blocking entry points (`Registrar`'s
/// methods, the command line, the Python package) over the async steps. A CPU backend's futures are ready when
/// polled; natively a GPU readback polls the device to completion before it is awaited. In a browser, await the
/// futures instead (a GPU readback there completes on the page's event loop).
pub fn block_on<F: std::future::Future>(future: F) -> F::Output {
    pollster::block_on(future)
}
pub use error::{Error, Result};
pub use multiway::{MultiwaySettings, Trajectory, multiway};
/// The linear-algebra crate of the public API (`target_from_source` is a [`Matrix4`]), re-exported so a
/// downstream crate needs no dependency of its own to use results.
pub use nalgebra;
pub use nalgebra::{Matrix3, Matrix4, Vector3};
pub use pipeline::{Registrar, register};
pub use settings::*;
