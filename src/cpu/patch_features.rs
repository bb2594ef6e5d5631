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
use rayon::prelude::*;

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
    // Patches in parallel; each patch's frame once (it depends on the keypoint's normal only).
    let n = points_per_patch.max(1);
    let mut ppf = vec![0.0; points.len() * 4];
    let mut pc = vec![0.0; points.len() * 3];
    ppf.par_chunks_mut(n * 4).zip(pc.par_chunks_mut(n * 3)).enumerate().for_each(|(patch, (ppf, pc))| {
        let (center, center_normal) = (centers[patch], center_normals[patch]);
        let rotation = match frame {
            PoseFrame::Fragment => None,
            PoseFrame::Normal => Some(normal_frame(center_normal)),
        };
        let rows = points[patch * n..].iter().zip(&normals[patch * n..]);
        for ((f_out, c_out), (p, normal)) in ppf.chunks_exact_mut(4).zip(pc.chunks_exact_mut(3)).zip(rows) {
            let (f, c) = point_features(center, center_normal, *p, *normal, radius);
            f_out.copy_from_slice(&f);
            c_out.copy_from_slice(&rotation.map_or(c, |m| apply_frame(&m, c)));
        }
    });
    (ppf, pc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Every row is its point's own features, in its patch's frame (the oracle: [`point_features`] and
    /// [`apply_frame`] of [`normal_frame`] one point at a time), for whole and partial patches.
    #[test]
    fn each_row_is_its_points_features_in_its_patchs_frame() {
        let mut rng = Rng::new(3);
        let mut v = || [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32);
        let (patches, n) = (4, 5);
        let centers: Vec<[f32; 3]> = (0..patches).map(|_| v()).collect();
        let center_normals: Vec<[f32; 3]> = (0..patches).map(|_| v()).collect();
        let rows = patches * n - 2;
        let points: Vec<[f32; 3]> = (0..rows).map(|_| v()).collect();
        let normals: Vec<[f32; 3]> = (0..rows).map(|_| v()).collect();
        for frame in [PoseFrame::Fragment, PoseFrame::Normal] {
            let (ppf, pc) = patch_features(&centers, &center_normals, &points, &normals, n, 0.7, frame);
            assert_eq!((ppf.len(), pc.len()), (rows * 4, rows * 3));
            for i in 0..rows {
                let p = i / n;
                let (f, c) = point_features(centers[p], center_normals[p], points[i], normals[i], 0.7);
                let c = if frame == PoseFrame::Normal { apply_frame(&normal_frame(center_normals[p]), c) } else { c };
                assert_eq!(ppf[i * 4..][..4], f, "row {i}, {frame:?}");
                assert_eq!(pc[i * 3..][..3], c, "row {i}, {frame:?}");
            }
        }
    }
}
