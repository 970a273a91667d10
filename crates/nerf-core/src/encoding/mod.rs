//! Input encodings for the fields.

pub mod hash_grid;
pub mod planes;
pub mod positional;
pub mod spherical_harmonics;

use std::sync::Arc;

use burn::tensor::Tensor;

pub use hash_grid::{HashGrid, HashGridConfig};
pub use planes::SpaceTimePlanes;
pub use positional::{PositionalEncoding, PositionalEncodingConfig};
pub use spherical_harmonics::{SphericalHarmonics, SphericalHarmonicsConfig};

/// How a grid field encodes its input: one hash grid over all of it, or (space-time only) a
/// space grid times space-time planes.
#[derive(Clone, Debug)]
pub enum GridEncoding {
    Hash(Arc<HashGrid>),
    Planes(Arc<SpaceTimePlanes>),
}

impl GridEncoding {
    /// `[N, D]` coordinates in [0, 1]^D → `[N, L·F]` features.
    pub fn encode(&self, coords: Tensor<2>) -> Tensor<2> {
        match self {
            GridEncoding::Hash(g) => g.encode(coords),
            GridEncoding::Planes(p) => p.encode(coords),
        }
    }

    /// Features per point, `L·F`.
    pub fn output_dim(&self) -> usize {
        match self {
            GridEncoding::Hash(g) => g.config.output_dim(),
            GridEncoding::Planes(p) => p.output_dim(),
        }
    }

    /// The host tables, in a fixed order (sparse optimiser steps, checkpoints).
    pub fn grids(&self) -> Vec<Arc<HashGrid>> {
        match self {
            GridEncoding::Hash(g) => vec![g.clone()],
            GridEncoding::Planes(p) => p.grids(),
        }
    }
}
