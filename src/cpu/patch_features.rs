//! CPU twin of `shaders/patch_features.wgsl`: per patch point, the 4-D point pair feature and the centred,
//! scaled PC coordinate.
//!
//! For reference point p_r (the keypoint, normal n_r) and neighbour p_i (normal n_i), with d = p_r - p_i:
//! `ppf = (angle(n_r, d) / pi, angle(n_i, d) / pi, angle(n_r, n_i) / pi, |d| / r)` and `pc = (p_i - p_r) / r`,
//! where `angle(a, b) = atan2(|a x b|, a . b)` is in [0, pi] and is 0 when a or b is zero (coincident points,
//! zero normals), so degenerate geometry gives finite features. With [`PoseFrame::Normal`] the PC coordinate is
//! rotated into the keypoint's normal frame, `pc = F(n_r) (p_i - p_r) / r` (`rotation_head::normal_frame`), so
//! every patch's normal is +z.

use super::rotation_head::normal_frame;
use crate::model::config::PoseFrame;

/// Angle between two vectors in [0, pi]; 0 when either is zero.
pub fn angle(a: [f32; 3], b: [f32; 3]) -> f32 {
    let cross = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let s = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
    let c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if s == 0.0 && c == 0.0 { 0.0 } else { s.atan2(c) }
}

/// Features of one neighbour: (ppf, pc).
pub fn point_features(p_r: [f32; 3], n_r: [f32; 3], p_i: [f32; 3], n_i: [f32; 3], radius: f32) -> ([f32; 4], [f32; 3]) {
    let d = [p_r[0] - p_i[0], p_r[1] - p_i[1], p_r[2] - p_i[2]];
    let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let inv_pi = std::f32::consts::FRAC_1_PI;
    let ppf = [angle(n_r, d) * inv_pi, angle(n_i, d) * inv_pi, angle(n_r, n_i) * inv_pi, dist / radius];
    let pc = [-d[0] / radius, -d[1] / radius, -d[2] / radius];
    (ppf, pc)
}

/// `frame * v` for a row-major 3x3 frame.
pub fn apply_frame(frame: &[f32; 9], v: [f32; 3]) -> [f32; 3] {
    [
        frame[0] * v[0] + frame[1] * v[1] + frame[2] * v[2],
        frame[3] * v[0] + frame[4] * v[1] + frame[5] * v[2],
        frame[6] * v[0] + frame[7] * v[1] + frame[8] * v[2],
    ]
}

/// Features of every patch. `centers`/`center_normals` have one entry per patch; `points`/`normals` have
/// `patches x points_per_patch` entries (gathered neighbours). Returns (`ppf`: P x N x 4, `pc`: P x N x 3), the
/// PC coordinates in `frame`.
pub fn patch_features(
    centers: &[[f32; 3]],
    center_normals: &[[f32; 3]],
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    points_per_patch: usize,
    radius: f32,
    frame: PoseFrame,
) -> (Vec<f32>, Vec<f32>) {
    let mut ppf = Vec::with_capacity(points.len() * 4);
    let mut pc = Vec::with_capacity(points.len() * 3);
    for (i, (p, n)) in points.iter().zip(normals).enumerate() {
        let patch = i / points_per_patch;
        let (f, c) = point_features(centers[patch], center_normals[patch], *p, *n, radius);
        ppf.extend_from_slice(&f);
        match frame {
            PoseFrame::Fragment => pc.extend_from_slice(&c),
            PoseFrame::Normal => pc.extend_from_slice(&apply_frame(&normal_frame(center_normals[patch]), c)),
        }
    }
    (ppf, pc)
}
