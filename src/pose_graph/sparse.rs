//! Block-sparse symmetric positive definite systems H x = b solved with faer's sparse Cholesky (LLᵀ, AMD
//! ordering, supernodal: the 6 x 6 blocks make dense supernodes, which faer's automatic choice, simplicial on
//! these graphs, left to scalar updates). H is given by blocks: one B x B block per variable block
//! on the diagonal and one per coupled pair (a, b), a < b (duplicates are summed), so its storage and the
//! factorisation's follow the graph's edges. The symbolic analysis is done once per pattern and reused for every
//! numeric factorisation (each Levenberg-Marquardt trial).

use crate::error::{Error, Result};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::sparse::{Argsort, Pair, SparseColMat, SymbolicSparseColMat};
use faer::{Conj, Par, Side};

/// The sparsity pattern of a block system and its symbolic factorisation.
pub struct BlockPattern {
    /// Block size B.
    block: usize,
    /// Number of variable blocks.
    blocks: usize,
    /// Coupled block pairs (a, b) with a < b, in the order their values are given.
    pairs: Vec<(usize, usize)>,
    /// The upper triangle's structure (CSC) and the order that sorts the entries into it.
    symbolic: SymbolicSparseColMat<usize>,
    argsort: Argsort<usize>,
    /// Elimination ordering and supernodes, shared by every numeric factorisation.
    llt: SymbolicCholesky<usize>,
}

/// A numeric factorisation of one matrix of a [`BlockPattern`].
pub struct Factor<'a> {
    symbolic: &'a SymbolicCholesky<usize>,
    values: Vec<f64>,
}

impl BlockPattern {
    /// The pattern of `blocks` diagonal blocks of size `block` and the off-diagonal blocks of `pairs` (each
    /// (a, b) with a != b; stored as (min, max)).
    pub fn new(block: usize, blocks: usize, pairs: &[(usize, usize)]) -> Result<BlockPattern> {
        let pairs: Vec<(usize, usize)> = pairs.iter().map(|&(a, b)| (a.min(b), a.max(b))).collect();
        if block == 0 || pairs.iter().any(|&(a, b)| a == b || b >= blocks) {
            return Err(Error::invalid("sparse system: a block pair joins a block to itself or to no block"));
        }
        let mut entries = Vec::with_capacity(blocks * block * (block + 1) / 2 + pairs.len() * block * block);
        for a in 0..blocks {
            for c in 0..block {
                for r in 0..=c {
                    entries.push(Pair { row: a * block + r, col: a * block + c });
                }
            }
        }
        for &(a, b) in &pairs {
            for c in 0..block {
                for r in 0..block {
                    entries.push(Pair { row: a * block + r, col: b * block + c });
                }
            }
        }
        let n = blocks * block;
        let (symbolic, argsort) = SymbolicSparseColMat::try_new_from_indices(n, n, &entries)
            .map_err(|e| Error::invalid(format!("sparse system: cannot build the pattern: {e:?}")))?;
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..CholeskySymbolicParams::default()
        };
        let llt = factorize_symbolic_cholesky(symbolic.as_ref(), Side::Upper, SymmetricOrdering::Amd, params)
            .map_err(|e| Error::invalid(format!("sparse system: symbolic factorisation failed: {e:?}")))?;
        Ok(BlockPattern { block, blocks, pairs, symbolic, argsort, llt })
    }

    /// Number of scalar unknowns.
    pub fn dim(&self) -> usize {
        self.block * self.blocks
    }

    /// Factors the matrix with diagonal blocks `diagonal[a]` plus `damping[a * B + r]` on their diagonals, and
    /// off-diagonal blocks `off[p]` (rows of block `pairs[p].0`, columns of `pairs[p].1`); blocks are row-major
    /// B x B slices. `None` when the matrix is not positive definite.
    pub fn factor(&self, diagonal: &[f64], damping: &[f64], off: &[f64]) -> Result<Option<Factor<'_>>> {
        let b = self.block;
        debug_assert_eq!(diagonal.len(), self.blocks * b * b);
        debug_assert_eq!(off.len(), self.pairs.len() * b * b);
        let mut values = Vec::with_capacity(self.blocks * b * (b + 1) / 2 + off.len());
        for a in 0..self.blocks {
            for c in 0..b {
                for r in 0..=c {
                    let v = diagonal[a * b * b + r * b + c];
                    values.push(if r == c { v + damping[a * b + r] } else { v });
                }
            }
        }
        for p in 0..self.pairs.len() {
            for c in 0..b {
                for r in 0..b {
                    values.push(off[p * b * b + r * b + c]);
                }
            }
        }
        let matrix = SparseColMat::new_from_argsort(self.symbolic.clone(), &self.argsort, &values)
            .map_err(|e| Error::invalid(format!("sparse system: {e:?}")))?;
        let mut values = vec![0.0; self.llt.len_val()];
        let scratch = self.llt.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default());
        let mut memory = MemBuffer::try_new(scratch).map_err(|_| Error::invalid("sparse system: out of memory"))?;
        // The only failure left once the scratch memory is allocated is a non-positive pivot.
        let positive_definite = self
            .llt
            .factorize_numeric_llt(
                &mut values,
                matrix.as_ref(),
                Side::Upper,
                Default::default(),
                Par::Seq,
                MemStack::new(&mut memory),
                Default::default(),
            )
            .is_ok();
        Ok(positive_definite.then_some(Factor { symbolic: &self.llt, values }))
    }

    /// The coupled pairs, in value order.
    pub fn pairs(&self) -> &[(usize, usize)] {
        &self.pairs
    }
}

impl Factor<'_> {
    /// Solves H X = B for the columns of `rhs` (`columns` of them, each of length dim, stored one after another).
    pub fn solve(&self, rhs: &[f64], columns: usize) -> Vec<f64> {
        let n = rhs.len() / columns.max(1);
        let mut x = faer::Mat::from_fn(n, columns, |r, c| rhs[c * n + r]);
        let mut memory = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(columns, Par::Seq));
        LltRef::new(self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            x.as_mut(),
            Par::Seq,
            MemStack::new(&mut memory),
        );
        (0..columns).flat_map(|c| (0..n).map(move |r| (r, c))).map(|(r, c)| x[(r, c)]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use nalgebra::DMatrix;

    #[test]
    fn block_solve_matches_a_dense_solve() {
        // A chain of 5 blocks of size 2 with a loop (0, 4) and a duplicated pair (1, 2): the oracle is the dense
        // matrix assembled from the same blocks.
        let mut rng = Rng::new(3);
        let (b, blocks) = (2, 5);
        let pairs = [(0, 1), (2, 1), (2, 3), (3, 4), (0, 4), (1, 2)];
        let pattern = BlockPattern::new(b, blocks, &pairs).unwrap();
        let off: Vec<f64> = (0..pairs.len() * b * b).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let mut dense = DMatrix::<f64>::zeros(b * blocks, b * blocks);
        for (p, &(a, c)) in pattern.pairs().iter().enumerate() {
            for r in 0..b {
                for s in 0..b {
                    let v = off[p * b * b + r * b + s];
                    dense[(a * b + r, c * b + s)] += v;
                    dense[(c * b + s, a * b + r)] += v;
                }
            }
        }
        // Diagonal blocks: symmetric, dominant enough to make the whole matrix positive definite.
        let mut diagonal = vec![0.0; blocks * b * b];
        for a in 0..blocks {
            let m = rng.uniform(-0.5, 0.5);
            for (r, s, v) in [(0, 0, 8.0), (1, 1, 9.0), (0, 1, m), (1, 0, m)] {
                diagonal[a * b * b + r * b + s] = v;
                dense[(a * b + r, a * b + s)] += v;
            }
        }
        let damping: Vec<f64> = (0..blocks * b).map(|k| 0.1 * k as f64).collect();
        for (k, d) in damping.iter().enumerate() {
            dense[(k, k)] += d;
        }
        let rhs: Vec<f64> = (0..2 * b * blocks).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let x = pattern.factor(&diagonal, &damping, &off).unwrap().unwrap().solve(&rhs, 2);
        let n = b * blocks;
        for c in 0..2 {
            let xc = nalgebra::DVector::from_column_slice(&x[c * n..(c + 1) * n]);
            let residual = &dense * xc - nalgebra::DVector::from_column_slice(&rhs[c * n..(c + 1) * n]);
            assert!(residual.norm() < 1e-10, "column {c}: {residual}");
        }
        // An indefinite matrix is reported, not factored.
        let negative = vec![-1.0; blocks * b * b];
        assert!(pattern.factor(&negative, &damping, &off).unwrap().is_none());
    }
}
