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

    fn query_kept(
        &self,
        query: FieldQuery<'_>,
        keep: &mut dyn FnMut(Tensor<2>) -> Vec<usize>,
    ) -> (Vec<usize>, FieldOutputs) {
        match self {
            BaseField::Fast(f) => f.query_kept(query, keep),
            BaseField::Vanilla(f) => f.query_kept(query, keep),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Preset, TrainConfig};
    use crate::model::base_field;
    use burn::tensor::{Device, TensorData};
    use nerf_core::readback::{assert_close, host};

    /// `query_kept` returns the rows its `keep` picks and, at those rows, what a full query
    /// returns: the fast field's reuse of its density pass and the default's fresh query alike,
    /// extra head included.
    #[test]
    fn query_kept_answers_as_the_full_query_at_the_kept_rows() {
        let dev = Device::flex();
        let n = 64;
        let positions: Vec<f32> = (0..3 * n)
            .map(|i| ((i * 37 % 101) as f32 / 101.0) * 2.4 - 1.2)
            .collect();
        let dirs: Vec<f32> = (0..n)
            .flat_map(|i| {
                let a = i as f32 * 0.37;
                [a.cos() * 0.6, a.sin() * 0.6, 0.8]
            })
            .collect();
        for preset in [Preset::Fast, Preset::Vanilla] {
            let mut cfg = TrainConfig::new(preset, "unused".into(), Default::default());
            cfg.vanilla.width = 32;
            cfg.vanilla.depth = 3;
            let field = base_field(&cfg, [[-1.5; 3], [1.5; 3]], 2, &dev);
            // Spread tables, so that a wrong row would show.
            field.host_params().iter().for_each(|g| g.spread());
            let x = || Tensor::<2>::from_data(TensorData::new(positions.clone(), [n, 3]), &dev);
            let full = field.query(FieldQuery::new(x(), &dirs));
            let sigma_all = host(full.sigma.clone());
            // Keep the samples denser than the median, an arbitrary subset of the rows.
            let mut sorted = sigma_all.clone();
            sorted.sort_by(f32::total_cmp);
            let median = sorted[n / 2];
            let mut seen = Vec::new();
            let (rows, kept) = field.query_kept(FieldQuery::new(x(), &dirs), &mut |sigma| {
                seen = host(sigma);
                (0..n).filter(|&i| seen[i] > median).collect()
            });
            assert_close(
                &format!("{preset:?} densities given to keep"),
                &seen,
                &sigma_all,
                1e-6,
            );
            let want: Vec<usize> = (0..n).filter(|&i| sigma_all[i] > median).collect();
            assert_eq!(rows, want, "{preset:?}: the rows keep picked");
            assert!(!rows.is_empty() && rows.len() < n, "{preset:?}: a strict subset");
            let pick = |v: Vec<f32>, c: usize| -> Vec<f32> {
                rows.iter().flat_map(|&i| v[c * i..c * i + c].to_vec()).collect()
            };
            assert_close("sigma", &host(kept.sigma), &pick(sigma_all.clone(), 1), 1e-5);
            assert_close("rgb", &host(kept.rgb), &pick(host(full.rgb), 3), 1e-5);
            assert_close(
                "extra head",
                &host(kept.extras.expect(RAW_EXTRA)),
                &pick(host(full.extras.expect(RAW_EXTRA)), 2),
                1e-5,
            );
        }
    }
}
