//! Sampling designs (paper, Step 1): which grid points to measure.
//!
//! A design and its seed fully determine the targets, so any run can be reproduced.
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How targets are drawn from the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DesignKind {
    /// Every grid point (the full scan the paper compares against).
    Full,
    /// m grid points from a seeded random permutation (the paper's design).
    Random,
    /// One random grid point in each of m equal strata: random, but no long gaps.
    Jittered,
}

/// A reproducible sampling design.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Design {
    pub kind: DesignKind,
    pub m: usize,
    pub seed: u64,
}

impl Design {
    pub fn new(kind: DesignKind, m: usize, seed: u64) -> Self {
        Self { kind, m, seed }
    }

    /// Grid indices to measure, ascending. `m` is clamped to `n` for the full scan only.
    pub fn indices(&self, n: usize) -> Result<Vec<usize>, String> {
        if self.kind != DesignKind::Full && (self.m < 2 || self.m > n) {
            return Err(format!(
                "sampling needs 2 <= m <= n = {n}, got m = {}",
                self.m
            ));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let mut idx = match self.kind {
            DesignKind::Full => (0..n).collect(),
            DesignKind::Random => {
                let mut perm: Vec<usize> = (0..n).collect();
                perm.shuffle(&mut rng);
                perm.truncate(self.m);
                perm
            }
            DesignKind::Jittered => (0..self.m)
                .map(|k| {
                    // Stratum k covers [k n / m, (k+1) n / m) of the grid.
                    let lo = k * n / self.m;
                    let hi = ((k + 1) * n / self.m).max(lo + 1);
                    rng.random_range(lo..hi)
                })
                .collect(),
        };
        idx.sort_unstable();
        Ok(idx)
    }

    /// Targets in visiting order: ascending for forward runs, descending for backward runs.
    pub fn ordered(&self, n: usize, forward: bool) -> Result<Vec<usize>, String> {
        let mut idx = self.indices(n)?;
        if !forward {
            idx.reverse();
        }
        Ok(idx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_design_is_seeded_sorted_and_distinct() {
        let d = Design::new(DesignKind::Random, 600, 42);
        let a = d.indices(1901).unwrap();
        assert_eq!(a, d.indices(1901).unwrap());
        assert_ne!(
            a,
            Design::new(DesignKind::Random, 600, 43)
                .indices(1901)
                .unwrap()
        );
        assert_eq!(a.len(), 600);
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        assert!(*a.last().unwrap() < 1901);
        let back = d.ordered(1901, false).unwrap();
        assert!(back.windows(2).all(|w| w[0] > w[1]));
    }

    #[test]
    fn jittered_design_has_one_point_per_stratum() {
        let n = 1901;
        let m = 100;
        let a = Design::new(DesignKind::Jittered, m, 7).indices(n).unwrap();
        assert_eq!(a.len(), m);
        for (k, &i) in a.iter().enumerate() {
            assert!(i >= k * n / m && i < (k + 1) * n / m, "stratum {k}: {i}");
        }
        // No gap longer than two strata.
        let max_gap = a.windows(2).map(|w| w[1] - w[0]).max().unwrap();
        assert!(max_gap < 2 * n / m + 2, "gap {max_gap}");
    }

    #[test]
    fn bad_m_is_refused() {
        assert!(Design::new(DesignKind::Random, 1, 0).indices(10).is_err());
        assert!(Design::new(DesignKind::Random, 11, 0).indices(10).is_err());
        assert_eq!(
            Design::new(DesignKind::Full, 0, 0)
                .indices(10)
                .unwrap()
                .len(),
            10
        );
    }
}
