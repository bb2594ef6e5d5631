//! Kernel parity cases: every registered WGSL kernel ([`crate::gpu::registry::KERNELS`]) run on a device against
//! its CPU twin (`src/cpu/k.rs`) on seeded, adversarial inputs (sizes that miss the workgroup and tile sizes,
//! dispatches past 65,535 workgroups in one dimension, degenerate geometry, heavy ties; outputs pre-filled with a
//! NaN / 0xDEADBEEF sentinel so an element a kernel never writes fails), within named tolerances.
//!
//! The same cases run natively, in `tests/gpu_parity.rs` ([`crate::gpu::testing::run_tests`] runs each with
//! [`crate::block_on`]), and in a browser on WebGPU (`web/parity.html`), where Chromium's compiler (Tint) and
//! its WebGPU implementation run the kernels. A case is async because its readbacks are. A mismatch panics with
//! the kernel, the seed (`DPR_SEED` overrides the defaults natively) and the first element off.

pub mod icp;
pub mod inference;
pub mod preprocess;
pub mod training;

use super::Gpu;
use std::future::Future;
use std::pin::Pin;

/// How a case ended (a mismatch panics instead).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Every comparison held.
    Passed,
    /// The device lacks what the case needs (a feature such as cooperative matrices): not run, with the reason.
    Skipped(String),
}

/// A running case.
pub type CaseFuture<'a> = Pin<Box<dyn Future<Output = Outcome> + 'a>>;

/// One case: its name (`<kernel>_matches_cpu...`) and its body on a device.
#[derive(Clone, Copy)]
pub struct Case {
    /// The case's name; it starts with the kernel's.
    pub name: &'static str,
    /// Runs the case on a device.
    pub run: for<'a> fn(&'a Gpu) -> CaseFuture<'a>,
}

/// A [`Case`] per async case function, named after it.
macro_rules! cases {
    ($($module:ident :: $case:ident),* $(,)?) => {
        &[$(Case { name: stringify!($case), run: |g| Box::pin($module::$case(g)) }),*]
    };
}

/// Every case, in the order of [`crate::gpu::registry::KERNELS`].
pub const CASES: &[Case] = cases![
    preprocess::cell_bounds_matches_cpu,
    preprocess::cell_keys_matches_cpu,
    preprocess::bitonic_sort_matches_cpu,
    preprocess::prefix_scan_matches_cpu,
    preprocess::segments_matches_cpu,
    preprocess::voxel_average_matches_cpu,
    preprocess::voxel_downsample_matches_cpu,
    preprocess::grid_knn_matches_cpu,
    preprocess::pca_normals_matches_cpu,
    preprocess::normals_and_downsampling_match_cpu,
    preprocess::farthest_point_matches_cpu,
    preprocess::patch_sample_matches_cpu,
    preprocess::patch_gather_matches_cpu,
    preprocess::sample_patches_matches_cpu_and_brute_force,
    preprocess::device_cloud_normals_match_cpu,
    inference::patch_features_matches_cpu_ragged,
    inference::patch_features_matches_cpu_degenerate,
    inference::dense_matches_cpu_ragged,
    inference::dense_fast_matches_cpu_ragged,
    inference::dense_fast_tiles_match_cpu_ragged,
    inference::dense_coop_f16_matches_cpu_within_the_f16_bound,
    inference::dense_coop_f16_tiles_match_cpu_within_the_f16_bound,
    inference::max_pool_matches_cpu_ragged,
    inference::max_pool_matches_cpu_past_65535_workgroups,
    inference::unit_rows_matches_cpu_ragged,
    inference::codeword_distance_matches_cpu_ragged,
    inference::mutual_knn_matches_cpu_random,
    inference::mutual_knn_matches_cpu_with_ties,
    inference::pose_feature_matches_cpu_scattered,
    inference::rotation_head_matches_cpu,
    inference::hypotheses_matches_cpu,
    inference::score_hypotheses_matches_cpu,
    inference::score_hypotheses_matches_cpu_past_65535_workgroups,
    icp::icp_normal_equations_matches_cpu,
    training::relu_backward_matches_cpu_at_zero_and_signed_zeros,
    training::group_row_sums_matches_cpu_ragged,
    training::max_pool_backward_matches_cpu_with_ties_and_accumulation,
    training::dense_weight_grad_matches_cpu_ragged,
    training::dense_input_grad_matches_cpu_ragged,
    training::adam_step_matches_cpu_within_f32_rounding,
    training::chamfer_nearest_matches_cpu_up_to_near_ties,
    training::chamfer_grad_matches_cpu_on_both_branches,
    training::transpose_matches_cpu_exactly,
];
