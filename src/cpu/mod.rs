//! The CPU twins of the WGSL kernels: readable, shaped like the shaders, f32. They are the oracle every
//! GPU kernel is checked against, and the fallback on machines without a GPU.

pub mod dense;
pub mod gemm;
pub mod hypotheses;
pub mod max_pool;
pub mod mutual_knn;
pub mod patch_features;
pub mod rotation_head;
pub mod score_hypotheses;
