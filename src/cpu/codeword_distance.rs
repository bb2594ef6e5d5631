//! CPU twin of `shaders/codeword_distance.wgsl`: squared L2 distances between two codeword sets (the input of
//! [`super::mutual_knn`]).

/// `ns x nt` squared distances, row-major (the `codeword_distance` kernel): each entry sums
/// `(source[d] - target[d])^2` over `d` in increasing order, as the kernel does.
///
/// The CPU backend runs this: rows in parallel, and within a row the sums of [`TARGET_BLOCK`] targets advance
/// together over `d` (target codewords transposed block by block), which vectorises across targets while every
/// entry keeps its own in-order sum, so the result is bit-identical to the one-entry-at-a-time loop.
pub fn codeword_distance(source: &[f32], target: &[f32], dim: usize) -> Vec<f32> {
    use rayon::prelude::*;
    if dim == 0 {
        return Vec::new();
    }
    let (ns, nt) = (source.len() / dim, target.len() / dim);
    let mut out = vec![0.0; ns * nt];
    if nt == 0 {
        return out;
    }
    // Block b holds targets b*TARGET_BLOCK.. as [d][j] (zero-padded to a full block).
    let blocks = nt.div_ceil(TARGET_BLOCK);
    let mut transposed = vec![0.0f32; blocks * dim * TARGET_BLOCK];
    for j in 0..nt {
        let (b, lane) = (j / TARGET_BLOCK, j % TARGET_BLOCK);
        for (d, &v) in target[j * dim..][..dim].iter().enumerate() {
            transposed[(b * dim + d) * TARGET_BLOCK + lane] = v;
        }
    }
    out.par_chunks_mut(nt).zip(source.par_chunks(dim)).for_each(|(row, a)| {
        for (b, block) in transposed.chunks_exact(dim * TARGET_BLOCK).enumerate() {
            let mut acc = [0.0f32; TARGET_BLOCK];
            for (&x, t) in a.iter().zip(block.chunks_exact(TARGET_BLOCK)) {
                for (s, &y) in acc.iter_mut().zip(t) {
                    let diff = x - y;
                    *s += diff * diff;
                }
            }
            let start = b * TARGET_BLOCK;
            let len = TARGET_BLOCK.min(nt - start);
            row[start..start + len].copy_from_slice(&acc[..len]);
        }
    });
    out
}

/// Targets whose distance sums [`codeword_distance`] advances together.
pub const TARGET_BLOCK: usize = 16;

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-entry-at-a-time definition the blocked loop must reproduce bit for bit.
    fn brute_force_distance(source: &[f32], target: &[f32], dim: usize) -> Vec<f32> {
        let mut out = Vec::new();
        for a in source.chunks_exact(dim) {
            for b in target.chunks_exact(dim) {
                let mut sum = 0.0f32;
                for (x, y) in a.iter().zip(b) {
                    sum += (x - y) * (x - y);
                }
                out.push(sum);
            }
        }
        out
    }

    #[test]
    fn codeword_distance_is_bit_identical_to_the_in_order_sum() {
        let mut rng = crate::rng::Rng::new(5);
        for (ns, nt, dim) in [(1, 1, 1), (3, 17, 5), (20, 33, 64), (7, 16, 3), (0, 4, 2), (4, 0, 2)] {
            let a: Vec<f32> = (0..ns * dim).map(|_| rng.unit_f64() as f32 * 4.0 - 2.0).collect();
            let b: Vec<f32> = (0..nt * dim).map(|_| rng.unit_f64() as f32 * 4.0 - 2.0).collect();
            let got = codeword_distance(&a, &b, dim);
            let want = brute_force_distance(&a, &b, dim);
            assert_eq!(got.len(), ns * nt);
            assert!(got.iter().zip(&want).all(|(g, w)| g.to_bits() == w.to_bits()), "{ns}x{nt}x{dim}");
        }
    }
}
