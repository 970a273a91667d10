//! Fields: what the scene is. A field answers density at points, and density, colour and named
//! extra outputs at points seen from directions, optionally at a time (nerfstudio's `Field`,
//! nerfacc's `sigma_fn` / `rgb_sigma_fn`).
//!
//! One contract for every field:
//! - positions are the renderer's sample points, `[S, 3]`, in the scene's coordinates (world
//!   coordinates, or NDC for forward-facing captures); a field that needs another frame (a grid
//!   over its box) converts them itself;
//! - time, when given, is `[S, 1]`, normalised to [0, 1] over the video;
//! - σ is activated (≥ 0), colour is in [0, 1];
//! - extras are named, activated `[S, C]` channels (scene flow, a blend weight, ...).

use std::sync::Arc;

use burn::tensor::{Int, Tensor, TensorData};

use crate::encoding::HashGrid;

/// Named `[S, C]` channels beside density and colour.
#[derive(Clone, Debug, Default)]
pub struct Extras(pub Vec<(&'static str, Tensor<2>)>);

impl Extras {
    pub fn push(&mut self, name: &'static str, value: Tensor<2>) {
        self.0.push((name, value));
    }

    pub fn get(&self, name: &str) -> Option<&Tensor<2>> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, t)| t)
    }

    /// The channel `name`; a field that promises it and lacks it is a programming error.
    pub fn expect(&self, name: &str) -> Tensor<2> {
        self.get(name)
            .cloned()
            .unwrap_or_else(|| panic!("field output has no '{name}' channel"))
    }
}

/// A query for `S` samples.
#[derive(Clone, Debug)]
pub struct FieldQuery<'a> {
    /// `[S, 3]` sample positions (world, or NDC).
    pub positions: Tensor<2>,
    /// `S·3` unit view directions on the host (they never need gradients).
    pub dirs: &'a [f32],
    /// `[S, 1]` normalised time for space-time fields.
    pub time: Option<Tensor<2>>,
    /// `[S, 1]` noise added to the density before its activation (NeRF's training regulariser
    /// on real scenes); fields without a raw density ignore it.
    pub density_noise: Option<Tensor<2>>,
}

impl<'a> FieldQuery<'a> {
    pub fn new(positions: Tensor<2>, dirs: &'a [f32]) -> Self {
        FieldQuery {
            positions,
            dirs,
            time: None,
            density_noise: None,
        }
    }

    pub fn at_time(mut self, time: Option<Tensor<2>>) -> Self {
        self.time = time;
        self
    }

    /// Positions `[K, 3]`, times `[K, 1]` and directions `K·3` of the samples `rows` (no density
    /// noise: this serves inference).
    pub fn rows(&self, rows: &[usize]) -> (Tensor<2>, Option<Tensor<2>>, Vec<f32>) {
        let pick = |t: &Tensor<2>| select_rows(t.clone(), rows);
        (
            pick(&self.positions),
            self.time.as_ref().map(pick),
            rows3(self.dirs, rows),
        )
    }
}

/// Density and the view-independent extras that come with it, for `S` points.
#[derive(Clone, Debug)]
pub struct Density {
    /// `[S, 1]`, ≥ 0.
    pub sigma: Tensor<2>,
    pub extras: Extras,
}

impl Density {
    /// The same density with its extras replaced by `f(extras)` (a field wrapping another one
    /// names and activates the inner field's raw outputs this way).
    pub fn map_extras(self, f: impl FnOnce(Extras) -> Extras) -> Self {
        Density {
            sigma: self.sigma,
            extras: f(self.extras),
        }
    }
}

/// A full query's answer for `S` samples.
#[derive(Clone, Debug)]
pub struct FieldOutputs {
    /// `[S, 1]`, ≥ 0.
    pub sigma: Tensor<2>,
    /// `[S, 3]` in [0, 1].
    pub rgb: Tensor<2>,
    pub extras: Extras,
}

impl FieldOutputs {
    /// The same outputs with their extras replaced by `f(extras)`.
    pub fn map_extras(self, f: impl FnOnce(Extras) -> Extras) -> Self {
        FieldOutputs {
            extras: f(self.extras),
            ..self
        }
    }
}

/// The 3-vectors `rows` of a flat host array `S·3` (directions, positions), in that order:
/// `rows.len()·3`.
pub fn rows3(v: &[f32], rows: &[usize]) -> Vec<f32> {
    rows.iter().flat_map(|&i| v[3 * i..3 * i + 3].to_vec()).collect()
}

/// Rows `rows` of `[S, C]`: `[K, C]`.
pub fn select_rows(t: Tensor<2>, rows: &[usize]) -> Tensor<2> {
    let ids: Vec<i64> = rows.iter().map(|&i| i as i64).collect();
    let ids = Tensor::<1, Int>::from_data(TensorData::new(ids, [rows.len()]), &t.device());
    t.select(0, ids)
}

/// What the scene is: see the module documentation for the contract.
pub trait Field {
    /// Density (and view-independent extras) at `[S, 3]` positions, at `[S, 1]` times for
    /// space-time fields. No colour network runs.
    fn density(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Density;

    /// Density, colour and extras.
    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs;

    /// Inference's early ray termination: densities at every sample of `query`, then the full
    /// query at the samples `keep` picks from them (`[S, 1]` densities in, ascending sample
    /// indices out). Returns those indices and their outputs, which are `query`'s at those rows.
    /// This default queries the picked samples afresh; a field whose colour is computed from its
    /// density pass's features (the fast field) overrides it to run only its colour network again.
    fn query_kept(
        &self,
        query: FieldQuery<'_>,
        keep: &mut dyn FnMut(Tensor<2>) -> Vec<usize>,
    ) -> (Vec<usize>, FieldOutputs) {
        let rows = keep(self.density(query.positions.clone(), query.time.clone()).sigma);
        let (positions, time, dirs) = query.rows(&rows);
        let outputs = self.query(FieldQuery::new(positions, &dirs).at_time(time));
        (rows, outputs)
    }

    /// Parameters kept on the host outside burn's autodiff (hash tables with their own sparse
    /// optimiser); the model's checkpoint and optimiser step visit them through this.
    fn host_params(&self) -> Vec<Arc<HashGrid>> {
        Vec::new()
    }
}
