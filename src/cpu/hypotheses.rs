//! CPU twin of `shaders/hypotheses.wgsl`: one rigid pose hypothesis per correspondence from RelativeNet's
//! rotation (target_from_source, from `rotation_head`): R, t = p_target - R p_source.

/// A rigid pose, p_target = rotation * p_source + translation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hypothesis {
    /// Row-major 3x3 rotation.
    pub rotation: [f32; 9],
    /// Translation.
    pub translation: [f32; 3],
}

/// `r * p` for a row-major rotation.
pub fn rotate(r: &[f32; 9], p: [f32; 3]) -> [f32; 3] {
    [
        r[0] * p[0] + r[1] * p[1] + r[2] * p[2],
        r[3] * p[0] + r[4] * p[1] + r[5] * p[2],
        r[6] * p[0] + r[7] * p[1] + r[8] * p[2],
    ]
}

/// One hypothesis per (row-major rotation, source point, target point).
pub fn hypotheses(rotations: &[[f32; 9]], source_points: &[[f32; 3]], target_points: &[[f32; 3]]) -> Vec<Hypothesis> {
    rotations
        .iter()
        .zip(source_points.iter().zip(target_points))
        .map(|(&rotation, (&ps, &pt))| {
            let rp = rotate(&rotation, ps);
            Hypothesis { rotation, translation: [pt[0] - rp[0], pt[1] - rp[1], pt[2] - rp[2]] }
        })
        .collect()
}
