//! The CPU twins of the WGSL kernels: readable, shaped like the shaders, f32, one module per kernel named after
//! it (`cpu/k.rs` twins `shaders/k.wgsl`; `gpu::k::K::CPU_TWIN` points at it). They are the oracle every GPU
//! kernel is checked against, and the fallback on machines without a GPU. [`gemm`] is not a twin: it is the
//! vectorised, bit-identical form of [`dense::dense`] that the CPU backend runs; nor are [`gemm_bf16`], [`gemm_amx`] and
//! [`dense_grad_bf16`], its bf16 forms for the encoders and the trainer.

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
pub mod dense_grad_bf16;
pub mod dense_input_grad;
pub mod dense_weight_grad;
pub mod farthest_point;
pub mod gemm;
pub mod gemm_amx;
pub mod gemm_bf16;
pub mod gemm_int8;
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
pub mod relu_backward;
pub mod rotation_head;
pub mod score_hypotheses;
pub mod segments;
pub mod transpose;
pub mod unit_rows;
pub mod voxel_average;
