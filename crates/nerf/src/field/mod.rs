//! The static pipeline's fields (the [`Field`] contract is `nerf_core::field`'s): the NeRF
//! paper's MLP ([`VanillaField`]) and the Instant-NGP recipe ([`FastField`]). [`BaseField`] is
//! either, chosen by the preset; NSFF builds its static and space-time fields from it too.

pub mod fast;
pub mod vanilla;

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::Tensor;
use nerf_core::encoding::HashGrid;
use nerf_core::field::{Density, Field, FieldOutputs, FieldQuery};

pub use fast::{FastField, FastFieldConfig};
pub use vanilla::{VanillaField, VanillaFieldConfig};

/// Name of the raw (not activated) outputs of a field's extra head, `[S, E]`; models that build a
/// field with extra outputs (NSFF's blend weight, scene flow) name and activate them.
pub const RAW_EXTRA: &str = "raw";

/// A field that is also a burn module (what models, checkpoints and the optimiser need); every
/// `#[derive(Module)]` type that implements [`Field`] is one.
pub trait FieldModule: Field + Module + burn::module::ModuleDisplay {}

impl<T: Field + Module + burn::module::ModuleDisplay> FieldModule for T {}

/// The field a preset trains.
#[allow(clippy::large_enum_variant)] // one or two values per run; boxing would not pay for itself
#[derive(Module, Debug)]
pub enum BaseField {
    Fast(FastField),
    Vanilla(VanillaField),
}

impl Field for BaseField {
    fn density(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Density {
        match self {
            BaseField::Fast(f) => f.density(positions, time),
            BaseField::Vanilla(f) => f.density(positions, time),
        }
    }

    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs {
        match self {
            BaseField::Fast(f) => f.query(query),
            BaseField::Vanilla(f) => f.query(query),
        }
    }

    fn host_params(&self) -> Vec<Arc<HashGrid>> {
        match self {
            BaseField::Fast(f) => f.host_params(),
            BaseField::Vanilla(f) => f.host_params(),
        }
    }
}

/// The raw outputs of an optional extra head on features `[S, W]`, named [`RAW_EXTRA`].
pub fn raw_extras(head: Option<&burn::nn::Linear>, features: Tensor<2>) -> nerf_core::field::Extras {
    let mut extras = nerf_core::field::Extras::default();
    if let Some(head) = head {
        extras.push(RAW_EXTRA, head.forward(features));
    }
    extras
}

/// Grid coordinates `[S, D]` of a grid encoding over `aabb`: positions `[S, 3]` normalised over
/// the box, then the time `[S, 1]`, if any, as a fourth axis.
pub fn grid_coords(positions: Tensor<2>, time: Option<Tensor<2>>, aabb: [[f32; 3]; 2]) -> Tensor<2> {
    let x = normalize(positions, aabb);
    match time {
        Some(t) => Tensor::cat(vec![x, t], 1),
        None => x,
    }
}

/// Maps world positions inside `aabb` to [0, 1]^3 (differentiable; used by grid encodings).
pub fn normalize(positions: Tensor<2>, aabb: [[f32; 3]; 2]) -> Tensor<2> {
    let device = positions.device();
    let lo = Tensor::<1>::from_floats(aabb[0], &device).unsqueeze_dim::<2>(0);
    let inv = Tensor::<1>::from_floats([0, 1, 2].map(|a| 1.0 / (aabb[1][a] - aabb[0][a])), &device)
        .unsqueeze_dim::<2>(0);
    (positions - lo) * inv
}
