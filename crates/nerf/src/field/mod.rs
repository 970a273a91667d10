//! Fields: what the scene is. A field maps sample positions (and view directions) to density,
//! colour and optional extra raw outputs (NSFF's blend weight, scene flow, ...).

pub mod fast;
pub mod vanilla;

use burn::tensor::Tensor;

pub use fast::{FastField, FastFieldConfig};
pub use vanilla::{VanillaField, VanillaFieldConfig};

/// What a field returns for `S` samples.
#[derive(Debug, Clone)]
pub struct FieldOutput {
    /// `[S, 1]` density ≥ 0.
    pub sigma: Tensor<2>,
    /// `[S, 3]` colour in [0, 1].
    pub rgb: Tensor<2>,
    /// `[S, E]` raw extra outputs (no activation), when the field was built with any.
    pub extra: Option<Tensor<2>>,
}

/// Maps world positions inside `aabb` to [0, 1]^3 (differentiable; used by grid encodings).
pub fn normalize(positions: Tensor<2>, aabb: [[f32; 3]; 2]) -> Tensor<2> {
    let device = positions.device();
    let lo = Tensor::<1>::from_floats(aabb[0], &device).unsqueeze_dim::<2>(0);
    let inv = Tensor::<1>::from_floats([0, 1, 2].map(|a| 1.0 / (aabb[1][a] - aabb[0][a])), &device)
        .unsqueeze_dim::<2>(0);
    (positions - lo) * inv
}

/// Host version of [`normalize`] for `[S, 3]` positions.
pub fn normalize_host(positions: &[f32], aabb: [[f32; 3]; 2]) -> Vec<f32> {
    let inv = [0, 1, 2].map(|a| 1.0 / (aabb[1][a] - aabb[0][a]));
    positions
        .chunks_exact(3)
        .flat_map(|p| [0, 1, 2].map(|a| (p[a] - aabb[0][a]) * inv[a]))
        .collect()
}
