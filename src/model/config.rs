//! `ModelConfig`: every size that defines the networks. Stored in a weights file's metadata, so a weights file
//! describes itself.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// Most points per patch a weights file may declare.
pub const MAX_POINTS_PER_PATCH: usize = 1 << 16;
/// Largest folding grid side.
pub const MAX_GRID_SIDE: usize = 1 << 10;
/// Most folding grid points (columns x rows).
pub const MAX_GRID_POINTS: usize = 1 << 16;
/// Widest layer.
pub const MAX_WIDTH: usize = 1 << 13;
/// Most layers per width list.
pub const MAX_LAYERS: usize = 32;

/// Sizes of PPF-FoldNet, PC-FoldNet (same architecture, input/output width 4 vs 3) and RelativeNet.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelConfig {
    /// Patch radius r the model was trained with (cloud units; 0.30 m in the paper).
    pub radius: f32,
    /// Points N sampled per patch (2048 in the paper).
    pub points_per_patch: usize,
    /// Per-point MLP widths before the first max-pool (64-128-256).
    pub encoder_widths: Vec<usize>,
    /// Per-point MLP widths after the skip concatenation (512-512); the last is the codeword size.
    pub head_widths: Vec<usize>,
    /// Hidden widths of each folding MLP (256-128-64-32); the output width is 4 (PPF) or 3 (PC).
    pub fold_widths: Vec<usize>,
    /// Folding grid size (columns, rows); the decoder reconstructs columns x rows points.
    pub grid: [usize; 2],
    /// The grid spans [-grid_extent, grid_extent]^2.
    pub grid_extent: f32,
    /// RelativeNet hidden widths (512-256-128); input is 2 x codeword, output a quaternion (4).
    pub relative_widths: Vec<usize>,
}

impl Default for ModelConfig {
    /// The compact configuration the shipped weights use: the paper's widths, fewer points per patch
    /// (256, grid 16 x 16) so that training and CPU inference fit a 2-core machine.
    fn default() -> Self {
        ModelConfig {
            radius: 0.30,
            points_per_patch: 256,
            encoder_widths: vec![64, 128, 256],
            head_widths: vec![512, 512],
            fold_widths: vec![256, 128, 64, 32],
            grid: [16, 16],
            grid_extent: 0.3,
            relative_widths: vec![512, 256, 128],
        }
    }
}

impl ModelConfig {
    /// The paper's configuration: 2048 points per patch and FoldingNet's 45 x 45 grid over [-0.3, 0.3]^2.
    pub fn paper() -> Self {
        ModelConfig { points_per_patch: 2048, grid: [45, 45], ..ModelConfig::default() }
    }

    /// Codeword length (the last head width).
    pub fn codeword(&self) -> usize {
        *self.head_widths.last().unwrap_or(&0)
    }

    /// Points the folding decoder reconstructs.
    pub fn grid_points(&self) -> usize {
        self.grid[0] * self.grid[1]
    }

    /// Width of the skip concatenation [encoder outputs | global max-pool].
    pub fn concat_width(&self) -> usize {
        self.encoder_widths.iter().sum::<usize>() + self.encoder_widths.last().copied().unwrap_or(0)
    }

    /// Checks that every size is usable.
    pub fn validate(&self) -> Result<()> {
        let mut problems = Vec::new();
        if !(self.radius.is_finite() && self.radius > 0.0) {
            problems.push(format!("radius must be positive, got {}", self.radius));
        }
        if !(1..=MAX_POINTS_PER_PATCH).contains(&self.points_per_patch) {
            problems
                .push(format!("points_per_patch must be 1..={MAX_POINTS_PER_PATCH}, got {}", self.points_per_patch));
        }
        for (name, widths) in [
            ("encoder_widths", &self.encoder_widths),
            ("head_widths", &self.head_widths),
            ("fold_widths", &self.fold_widths),
            ("relative_widths", &self.relative_widths),
        ] {
            if widths.is_empty() || widths.contains(&0) {
                problems.push(format!("{name} must be non-empty and positive, got {widths:?}"));
            } else if widths.len() > MAX_LAYERS || widths.iter().any(|&w| w > MAX_WIDTH) {
                problems.push(format!("{name} must have at most {MAX_LAYERS} layers of width <= {MAX_WIDTH}"));
            }
        }
        if self.grid.contains(&0) {
            problems.push(format!("grid must be positive, got {:?}", self.grid));
        } else if self.grid.iter().any(|&g| g > MAX_GRID_SIDE)
            || self.grid[0].saturating_mul(self.grid[1]) > MAX_GRID_POINTS
        {
            problems.push(format!(
                "grid must be at most {MAX_GRID_SIDE} per side and {MAX_GRID_POINTS} points, got {:?}",
                self.grid
            ));
        }
        if !(self.grid_extent.is_finite() && self.grid_extent > 0.0) {
            problems.push(format!("grid_extent must be positive, got {}", self.grid_extent));
        }
        if problems.is_empty() { Ok(()) } else { Err(Error::invalid(format!("model config: {}", problems.join("; ")))) }
    }

    /// The folding grid, `grid_points() x 2`, x outer and y inner, evenly spaced over [-extent, extent].
    pub fn grid_coordinates(&self) -> Vec<f32> {
        let axis = |n: usize, i: usize| {
            if n == 1 { 0.0 } else { -self.grid_extent + 2.0 * self.grid_extent * i as f32 / (n - 1) as f32 }
        };
        let mut out = Vec::with_capacity(self.grid_points() * 2);
        for i in 0..self.grid[0] {
            for j in 0..self.grid[1] {
                out.push(axis(self.grid[0], i));
                out.push(axis(self.grid[1], j));
            }
        }
        out
    }
}
