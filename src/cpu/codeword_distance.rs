//! CPU twin of `shaders/codeword_distance.wgsl`: squared L2 distances between two codeword sets (the input of
//! [`super::mutual_knn`]).

/// `ns x nt` squared distances, row-major (each a sum of squared differences in increasing index order).
pub fn codeword_distance(source: &[f32], target: &[f32], dim: usize) -> Vec<f32> {
    let (ns, nt) = (source.len() / dim, target.len() / dim);
    let mut out = vec![0.0; ns * nt];
    for i in 0..ns {
        let a = &source[i * dim..][..dim];
        for j in 0..nt {
            let b = &target[j * dim..][..dim];
            out[i * nt + j] = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
        }
    }
    out
}
