//! One module per registered kernel: `kernels/k.rs` is the host side of `shaders/k.wgsl` (a unit type
//! implementing [`GpuKernel`](super::device::kernel::GpuKernel): source, bindings, workgroup size, params, CPU
//! twin `cpu/k.rs`, and a `record` helper), listed once in [`registry::KERNELS`]. Beside them: the GEMM
//! variants' choice ([`gemm`]) and the parameters the three GEMM kernels share ([`dense_params`]).

pub mod adam_step;
pub mod bitonic_sort;
pub mod cell_bounds;
pub mod cell_keys;
pub mod chamfer_grad;
pub mod chamfer_nearest;
pub mod codeword_distance;
pub mod dense;
pub mod dense_coop_f16;
pub mod dense_fast;
pub mod dense_input_grad;
pub mod dense_params;
pub mod dense_weight_grad;
pub mod farthest_point;
pub mod gemm;
pub mod gemm_choice;
pub mod grid_knn;
pub mod group_row_sums;
pub mod hypotheses;
pub mod icp_normal_equations;
pub mod max_pool;
pub mod max_pool_backward;
pub mod mutual_knn;
pub mod patch_features;
pub mod patch_gather;
pub mod patch_sample;
pub mod pca_normals;
pub mod pose_feature;
pub mod prefix_scan;
pub mod registry;
pub mod relu_backward;
pub mod rotation_head;
pub mod score_hypotheses;
pub mod segments;
pub mod transpose;
pub mod unit_rows;
pub mod voxel_average;
