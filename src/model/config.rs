//! `ModelConfig`: every size that defines the networks. Stored in a weights file's metadata, so a weights file
//! describes itself.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// The frame PC-FoldNet sees a patch in, and so the frame RelativeNet's rotation is expressed in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PoseFrame {
    /// The paper: centred points in their fragment's frame; RelativeNet regresses the whole relative rotation.
    #[default]
    Fragment,
    /// Centred points rotated so the keypoint's normal is +z (`crate::cpu::rotation_head::normal_frame`);
    /// RelativeNet regresses the rotation between the two normal-aligned patches (mostly an angle about z) and
    /// the fragment-frame rotation is `frame_target^T R frame_source`.
    Normal,
}

/// How RelativeNet's last layer encodes a rotation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RotationOutput {
    /// The paper: 4 values, L2-normalised to a unit quaternion `[w, x, y, z]`, trained with an L2 loss.
    #[default]
    Quaternion,
    /// 6 values, the first two columns of the rotation, made orthonormal by Gram-Schmidt (Zhou et al., CVPR
    /// 2019: a continuous representation of SO(3)), trained with the chordal (Frobenius) distance.
    SixD,
    /// Coarse to fine over the cyclic group about the normal (normal-aligned patches only): `bins` logits over
    /// the angle about +z, bin k centred on `2 pi k / bins`, trained with cross-entropy against a wrapped
    /// Gaussian around the true angle (so several plausible angles can keep probability); inference takes the
    /// `candidates` best bins, refines each by a parabola through its neighbours' logits, and emits one rotation
    /// (one hypothesis) per candidate.
    AngleBins {
        /// Angle bins over the full turn.
        bins: u32,
        /// Rotations (hypotheses) per correspondence at inference.
        candidates: u32,
    },
}

/// Angle bins of `RotationOutput::AngleBins` when none are given (10 degrees each).
pub const DEFAULT_ANGLE_BINS: u32 = 36;
/// Candidates per correspondence of `RotationOutput::AngleBins` when none are given.
pub const DEFAULT_ANGLE_CANDIDATES: u32 = 3;
/// Most candidates per correspondence (the GPU kernel's fixed-size selection).
pub const MAX_ANGLE_CANDIDATES: u32 = 8;

impl std::str::FromStr for PoseFrame {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "fragment" => Ok(PoseFrame::Fragment),
            "normal" => Ok(PoseFrame::Normal),
            other => Err(Error::invalid(format!("unknown pose frame '{other}' (expected fragment or normal)"))),
        }
    }
}

impl std::str::FromStr for RotationOutput {
    type Err = Error;
    /// `quaternion`, `six-d`, or `angle-bins[:BINS[:CANDIDATES]]`.
    fn from_str(s: &str) -> Result<Self> {
        let bad = || {
            Error::invalid(format!(
                "unknown rotation output '{s}' (expected quaternion, six-d or angle-bins[:BINS[:CANDIDATES]])"
            ))
        };
        let mut parts = s.split(':');
        match parts.next() {
            Some("quaternion") if s == "quaternion" => Ok(RotationOutput::Quaternion),
            Some("six-d" | "6d") if !s.contains(':') => Ok(RotationOutput::SixD),
            Some("angle-bins") => {
                let mut num = |default: u32| -> Result<u32> {
                    parts.next().map_or(Ok(default), |v| v.parse().map_err(|_| bad()))
                };
                let bins = num(DEFAULT_ANGLE_BINS)?;
                let candidates = num(DEFAULT_ANGLE_CANDIDATES)?;
                if parts.next().is_some() {
                    return Err(bad());
                }
                Ok(RotationOutput::AngleBins { bins, candidates })
            }
            _ => Err(bad()),
        }
    }
}

impl RotationOutput {
    /// Width of RelativeNet's last layer.
    pub fn width(self) -> usize {
        match self {
            RotationOutput::Quaternion => 4,
            RotationOutput::SixD => 6,
            RotationOutput::AngleBins { bins, .. } => bins as usize,
        }
    }

    /// Rotations (hypotheses) per correspondence.
    pub fn candidates(self) -> usize {
        match self {
            RotationOutput::AngleBins { bins, candidates } => candidates.min(bins) as usize,
            _ => 1,
        }
    }
}

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
    /// RelativeNet hidden widths (512-256-128); input is 2 x codeword, output `rotation_output.width()`.
    pub relative_widths: Vec<usize>,
    /// The frame of PC-FoldNet's input (weights files without it use the paper's fragment frame).
    #[serde(default)]
    pub pose_frame: PoseFrame,
    /// RelativeNet's rotation encoding (weights files without it use the paper's quaternion).
    #[serde(default)]
    pub rotation_output: RotationOutput,
    /// PC-FoldNet's own per-point widths where they differ from PPF-FoldNet's (`encoder_widths` and
    /// `head_widths` are then PPF-FoldNet's), as in a pruned model (`dpr-gpu prune`): the same layer counts and
    /// codeword. Weights files without it use one set of widths for both networks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pc_widths: Option<NetWidths>,
}

/// One FoldNet's per-point widths: before the first max-pool, and after the skip concatenation.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct NetWidths {
    /// Per-point MLP widths before the first max-pool.
    pub encoder: Vec<usize>,
    /// Per-point MLP widths after the skip concatenation; the last is the codeword size.
    pub head: Vec<usize>,
}

impl Default for ModelConfig {
    /// The compact configuration: the paper's widths, fewer points per patch (256, grid 16 x 16) so that
    /// training and CPU inference fit a 2-core machine, and the pose head that covers all of SO(3):
    /// normal-aligned patches with 36 angle bins, 3 candidates per correspondence (see `weights/README.md`).
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
            pose_frame: PoseFrame::Normal,
            rotation_output: RotationOutput::AngleBins {
                bins: DEFAULT_ANGLE_BINS,
                candidates: DEFAULT_ANGLE_CANDIDATES,
            },
            pc_widths: None,
        }
    }
}

impl ModelConfig {
    /// The paper's configuration: 2048 points per patch, FoldingNet's 45 x 45 grid over [-0.3, 0.3]^2, and the
    /// paper's pose head (fragment-frame patches, quaternion output).
    pub fn paper() -> Self {
        ModelConfig {
            points_per_patch: 2048,
            grid: [45, 45],
            pose_frame: PoseFrame::Fragment,
            rotation_output: RotationOutput::Quaternion,
            ..ModelConfig::default()
        }
    }

    /// The compact sizes with the paper's pose head (fragment-frame patches, quaternion output): the
    /// formulation the ablation compares against.
    pub fn compact_paper_head() -> Self {
        ModelConfig {
            pose_frame: PoseFrame::Fragment,
            rotation_output: RotationOutput::Quaternion,
            ..ModelConfig::default()
        }
    }

    /// Codeword length (the last head width).
    pub fn codeword(&self) -> usize {
        *self.head_widths.last().unwrap_or(&0)
    }

    /// Points the folding decoder reconstructs.
    pub fn grid_points(&self) -> usize {
        self.grid[0] * self.grid[1]
    }

    /// Width of PPF-FoldNet's skip concatenation [encoder outputs | global max-pool]
    /// (`crate::model::params::concat_width` for either network).
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
            ("pc_widths.encoder", self.pc_widths.as_ref().map_or(&self.encoder_widths, |w| &w.encoder)),
            ("pc_widths.head", self.pc_widths.as_ref().map_or(&self.head_widths, |w| &w.head)),
        ] {
            if widths.is_empty() || widths.contains(&0) {
                problems.push(format!("{name} must be non-empty and positive, got {widths:?}"));
            } else if widths.len() > MAX_LAYERS || widths.iter().any(|&w| w > MAX_WIDTH) {
                problems.push(format!("{name} must have at most {MAX_LAYERS} layers of width <= {MAX_WIDTH}"));
            }
        }
        if let Some(pc) = &self.pc_widths
            && (pc.encoder.len() != self.encoder_widths.len()
                || pc.head.len() != self.head_widths.len()
                || pc.head.last() != self.head_widths.last())
        {
            problems.push(format!(
                "pc_widths must have as many layers as encoder_widths and head_widths and the same codeword, got {:?} \
                 and {:?} against {:?} and {:?}",
                pc.encoder, pc.head, self.encoder_widths, self.head_widths
            ));
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
        if let RotationOutput::AngleBins { bins, candidates } = self.rotation_output {
            if !(4..=360).contains(&bins) || !(1..=MAX_ANGLE_CANDIDATES).contains(&candidates) {
                problems.push(format!(
                    "angle-bins needs 4..=360 bins and 1..={MAX_ANGLE_CANDIDATES} candidates, got {bins} and {candidates}"
                ));
            }
            if self.pose_frame != PoseFrame::Normal {
                problems.push("angle-bins regresses the angle about the normal: it needs pose_frame normal".into());
            }
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
