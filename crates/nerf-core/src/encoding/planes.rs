//! A factorised space-time encoding (K-Planes' "hybrid" form): a 3-D hash grid over space times
//! three space-time planes (x, t), (y, t), (z, t), feature by feature.
//!
//! f_l(x, y, z, t) = g_l(x, y, z) ⊙ p_l(x, t) ⊙ q_l(y, t) ⊙ r_l(z, t) at every level l.
//!
//! The planes start at 1, so the field starts as a static one and time enters only where the
//! data asks for it. The space grid starts in [0.1, 0.5] as in K-Planes (a plane's gradient is
//! the other factors' product); on the tuning set that made no difference against a hash
//! grid's ±1e-4 (BENCHMARKS.md §8, variants P and Q). Each plane is a dense 2-D grid
//! ((N_l + 1) × (time cells + 1) entries), so time is resolved per frame without the collisions
//! a 4-D hash table has at fine levels, and the product keeps the encoding a rank-limited 4-D
//! function. All four parts are [`HashGrid`]s: their fused kernels, sparse Adam steps and
//! checkpoints are the hash grid's.
//!
//! Measured against the 4-D hash grid (BENCHMARKS.md §8): about 3 dB worse on the generated
//! jumping scenes, 1.6 dB worse in mean on the three D-NeRF scenes. K-Planes also regularises
//! its planes (smoothness in time, L1 towards one); this encoding has no such terms yet.

use std::sync::Arc;

use burn::tensor::Tensor;
use rand::{Rng, SeedableRng, rngs::StdRng};

use super::hash_grid::{HashGrid, HashGridConfig, levels};

#[derive(Debug)]
pub struct SpaceTimePlanes {
    /// Over (x, y, z).
    pub space: Arc<HashGrid>,
    /// Over (x, t), (y, t), (z, t).
    pub planes: [Arc<HashGrid>; 3],
}

impl SpaceTimePlanes {
    /// From a 4-D grid's configuration: the space grid keeps its levels, features, table size and
    /// spatial resolutions; the planes keep the levels and features, with its time resolution.
    pub fn new(config: &HashGridConfig, seed: u64) -> Self {
        let (space, plane) = Self::configs(config);
        let planes = [0, 1, 2].map(|_| {
            let entries = levels(&plane).last().map_or(0, |l| l.offset + l.size);
            HashGrid::with_table(plane.clone(), vec![1.0; entries * plane.features])
        });
        let entries = levels(&space).last().map_or(0, |l| l.offset + l.size);
        let mut rng = StdRng::seed_from_u64(seed);
        let table = (0..entries * space.features)
            .map(|_| rng.random_range(0.1..0.5))
            .collect();
        SpaceTimePlanes {
            space: HashGrid::with_table(space, table),
            planes,
        }
    }

    /// The space grid's and the planes' configurations for a 4-D `config`.
    pub fn configs(config: &HashGridConfig) -> (HashGridConfig, HashGridConfig) {
        let space = HashGridConfig {
            dims: 3,
            time_resolution: None,
            time_follows_space: false,
            ..config.clone()
        };
        let plane = HashGridConfig {
            dims: 2,
            ..config.clone()
        };
        (space, plane)
    }

    pub fn output_dim(&self) -> usize {
        self.space.config.output_dim()
    }

    /// Encodes `[N, 4]` points (x, y, z, t) in [0, 1]^4 into `[N, L·F]` features. Differentiable
    /// in the points and (through each grid's host buffer) in every table.
    pub fn encode(&self, points: Tensor<2>) -> Tensor<2> {
        let n = points.dims()[0];
        let column = |a: usize| points.clone().slice([0..n, a..a + 1]);
        let mut out = self.space.encode(points.clone().slice([0..n, 0..3]));
        for (axis, plane) in self.planes.iter().enumerate() {
            out = out * plane.encode(Tensor::cat(vec![column(axis), column(3)], 1));
        }
        out
    }

    /// The four grids, space first (for optimiser steps and checkpoints, in this order).
    pub fn grids(&self) -> Vec<Arc<HashGrid>> {
        let mut out = vec![self.space.clone()];
        out.extend(self.planes.iter().cloned());
        out
    }
}
