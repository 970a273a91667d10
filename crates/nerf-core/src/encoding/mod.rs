//! Input encodings for the fields.

pub mod hash_grid;
pub mod positional;
pub mod spherical_harmonics;

pub use hash_grid::{HashGrid, HashGridConfig};
pub use positional::{PositionalEncoding, PositionalEncodingConfig};
pub use spherical_harmonics::{SphericalHarmonics, SphericalHarmonicsConfig};
