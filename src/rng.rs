//! A small seeded random number generator (SplitMix64), so every random choice is reproducible from a seed
//! on every platform and with every dependency version.

/// SplitMix64: fast, tiny, and fully specified, which is all that sampling keypoints and patches needs.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
}

impl Rng {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Rng { state: seed ^ 0x9E37_79B9_7F4A_7C15 }
    }

    /// A generator for the independent stream `stream` derived from `seed` (e.g. one per patch).
    pub fn derived(seed: u64, stream: u64) -> Self {
        let mut base = Rng::new(seed);
        let mixed = base.next_u64() ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        Rng::new(mixed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (n > 0), without modulo bias worth noting for n << 2^64.
    pub fn below(&mut self, n: usize) -> usize {
        debug_assert!(n > 0);
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    /// Uniform in [0, 1).
    pub fn unit_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit_f64()
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.unit_f64().max(1e-300);
        let u2 = self.unit_f64();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    /// `k` distinct indices from `0..n` (k <= n), in the order drawn: a partial Fisher-Yates shuffle of
    /// `0..n` whose pool is sparse (only the swapped slots are stored), so it costs O(k) time and memory
    /// whatever `n`, and draws exactly the sequence of the dense shuffle.
    pub fn sample_without_replacement(&mut self, n: usize, k: usize) -> Vec<usize> {
        debug_assert!(k <= n);
        // Slot -> value where it differs from the identity.
        let mut moved: std::collections::HashMap<usize, usize> = std::collections::HashMap::with_capacity(2 * k);
        let mut out = Vec::with_capacity(k);
        for i in 0..k {
            let j = i + self.below(n - i);
            let at_j = moved.get(&j).copied().unwrap_or(j);
            let at_i = moved.get(&i).copied().unwrap_or(i);
            moved.insert(j, at_i);
            moved.remove(&i);
            out.push(at_j);
        }
        out
    }

    /// A uniformly random unit quaternion `[w, x, y, z]` (Shoemake), i.e. a uniform rotation.
    pub fn unit_quaternion(&mut self) -> [f64; 4] {
        let (u1, u2, u3) = (self.unit_f64(), self.unit_f64(), self.unit_f64());
        let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
        let tau = 2.0 * std::f64::consts::PI;
        [b * (tau * u3).cos(), a * (tau * u2).sin(), a * (tau * u2).cos(), b * (tau * u3).sin()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_and_different_seeds_differ() {
        let a: Vec<u64> = (0..8)
            .map({
                let mut r = Rng::new(7);
                move |_| r.next_u64()
            })
            .collect();
        let b: Vec<u64> = (0..8)
            .map({
                let mut r = Rng::new(7);
                move |_| r.next_u64()
            })
            .collect();
        let c: Vec<u64> = (0..8)
            .map({
                let mut r = Rng::new(8);
                move |_| r.next_u64()
            })
            .collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn sample_without_replacement_is_distinct_and_in_range() {
        let mut r = Rng::new(1);
        let mut s = r.sample_without_replacement(100, 60);
        assert!(s.iter().all(|&i| i < 100));
        s.sort_unstable();
        s.dedup();
        assert_eq!(s.len(), 60);
    }

    /// The dense partial Fisher-Yates shuffle the sparse one replaces (the oracle of its draws).
    fn dense_sample(r: &mut Rng, n: usize, k: usize) -> Vec<usize> {
        let mut pool: Vec<usize> = (0..n).collect();
        for i in 0..k {
            let j = i + r.below(n - i);
            pool.swap(i, j);
        }
        pool.truncate(k);
        pool
    }

    #[test]
    fn sparse_sample_draws_exactly_the_dense_sequence() {
        for (seed, n, k) in [(1, 100, 60), (2, 10, 10), (3, 1, 1), (4, 5, 0), (5, 100_000, 5000), (6, 7, 6)] {
            let (mut a, mut b) = (Rng::new(seed), Rng::new(seed));
            assert_eq!(a.sample_without_replacement(n, k), dense_sample(&mut b, n, k), "n {n}, k {k}");
            assert_eq!(a.next_u64(), b.next_u64(), "same draws consumed");
        }
        // A huge population costs nothing beyond k.
        let s = Rng::new(9).sample_without_replacement(usize::MAX / 2, 3);
        assert_eq!(s.len(), 3);
    }

    #[test]
    fn below_covers_range_roughly_uniformly() {
        let mut r = Rng::new(3);
        let mut counts = [0usize; 10];
        for _ in 0..100_000 {
            counts[r.below(10)] += 1;
        }
        assert!(counts.iter().all(|&c| (9_000..11_000).contains(&c)), "{counts:?}");
    }
}
