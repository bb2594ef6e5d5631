//! # dpr-gpu
//!
//! Learned pairwise registration of 3D scans: "3D Local Features for Direct Pairwise Registration"
//! (Deng, Birdal, Ilic, CVPR 2019). PPF-FoldNet codewords give correspondences, RelativeNet predicts one
//! relative rotation per correspondence, every correspondence becomes a pose hypothesis, and the best
//! hypothesis is refined on its inliers.
#![warn(missing_docs)]

pub mod backend;
pub mod cli;
pub mod cloud;
pub mod cpu;
pub mod error;
pub mod estimate;
pub mod io;
pub mod model;
pub mod pipeline;
pub mod pose;
pub mod preprocess;
pub mod rng;
pub mod settings;
pub mod spatial;

pub use cloud::PointCloud;
pub use error::{Error, Result};
pub use settings::*;
