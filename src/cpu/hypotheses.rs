//! CPU twin of `shaders/hypotheses.wgsl`: one rigid pose hypothesis per correspondence from RelativeNet's
//! quaternion: R = R(q) (target_from_source), t = p_target - R p_source.

/// A rigid pose, p_target = rotation * p_source + translation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hypothesis {
    /// Row-major 3x3 rotation.
    pub rotation: [f32; 9],
    /// Translation.
    pub translation: [f32; 3],
}

/// Rotation matrix (row-major) of a unit quaternion `[w, x, y, z]`.
pub fn quaternion_to_matrix(q: [f32; 4]) -> [f32; 9] {
    let [w, x, y, z] = q;
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ]
}

/// `r * p` for a row-major rotation.
pub fn rotate(r: &[f32; 9], p: [f32; 3]) -> [f32; 3] {
    [
        r[0] * p[0] + r[1] * p[1] + r[2] * p[2],
        r[3] * p[0] + r[4] * p[1] + r[5] * p[2],
        r[6] * p[0] + r[7] * p[1] + r[8] * p[2],
    ]
}

/// One hypothesis per (quaternion, source point, target point).
pub fn hypotheses(quaternions: &[[f32; 4]], source_points: &[[f32; 3]], target_points: &[[f32; 3]]) -> Vec<Hypothesis> {
    quaternions
        .iter()
        .zip(source_points.iter().zip(target_points))
        .map(|(&q, (&ps, &pt))| {
            let rotation = quaternion_to_matrix(q);
            let rp = rotate(&rotation, ps);
            Hypothesis { rotation, translation: [pt[0] - rp[0], pt[1] - rp[1], pt[2] - rp[2]] }
        })
        .collect()
}
