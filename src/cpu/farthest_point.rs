//! CPU twin of `shaders/farthest_point.wgsl`, and the definition of the spatially uniform keypoint order on
//! every path: greedy farthest-point sampling from a start point. Each step takes the point farthest from
//! those chosen so far (squared distances `dx*dx + dy*dy + dz*dz` in f32, left to right, kept as a running
//! minimum per point); ties go to the lower index. The kernel fences its products against FMA contraction, so
//! both sides choose the same indices bit for bit.

use super::grid_knn::distance_squared;

/// `count` indices of `points` (count <= points.len()) by farthest-point sampling from `start`.
pub fn farthest_point(points: &[[f32; 3]], count: usize, start: usize) -> Vec<usize> {
    let mut nearest = vec![f32::INFINITY; points.len()];
    let mut chosen = Vec::with_capacity(count);
    let mut current = start;
    for _ in 0..count {
        chosen.push(current);
        let c = points[current];
        let mut best = (0, -1.0f32);
        for (i, p) in points.iter().enumerate() {
            let d = distance_squared(p, &c).min(nearest[i]);
            nearest[i] = d;
            if d > best.1 {
                best = (i, d);
            }
        }
        current = best.0;
    }
    chosen
}
