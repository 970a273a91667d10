//! NSFF's two fields, both the static pipeline's [`BaseField`] with extra outputs.
//!
//! The static field adds one output, the blend weight b_s ∈ (0, 1) (NSFF predicts it from the
//! static network). The dynamic field takes (x, y, z, t) and adds nine: scene flow to the previous
//! and next frame, the two disocclusion probabilities, and a time gate g. The blend is
//! b = b_s(x)·g(x, t): NSFF's b is a function of position only, so along a moving object's path it
//! must be high at every time, and nothing could hide the dynamic field's guesses in space a
//! frame's camera cannot see without also hiding the object at the times it is there. The gate
//! lets b fall at one time and stay at another; b_s alone still decides which samples can skip
//! the dynamic field at render time (b ≤ b_s).
//!
//! Opt-in (`flow_levels`, fast preset), the scene flow has its own small space-time grid and MLP
//! ([`FlowNet`]) and the head's flow outputs go unused: sharing the density network's features,
//! a flow trained hard enough to follow the motion costs the views between frames 0.2-1.4 dB,
//! and its own network does not (BENCHMARKS.md §6, eighteenth to twentieth sessions).

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor};
use nerf::config::Preset;
use nerf::field::{BaseField, FastFieldConfig, RAW_EXTRA, VanillaFieldConfig, grid_coords};
use nerf::model::base_field;
use nerf_core::encoding::{GridEncoding, HashGrid, HashGridConfig};
use nerf_core::field::{Density, Extras, Field, FieldOutputs, FieldQuery};
use nerf_core::mlp::{Mlp, MlpConfig};

use crate::config::{NsffConfig, SpaceTimeEncoding};

/// Static field extra: `[S, 1]` blend weight b_s ∈ (0, 1), the dynamic share's upper bound.
pub const BLEND: &str = "blend";
/// Dynamic field extras: `[S, 3]` scene flow to the previous / next frame (scene units).
pub const FLOW_PREV: &str = "flow_prev";
pub const FLOW_NEXT: &str = "flow_next";
/// `[S, 1]` disocclusion probabilities towards the previous / next frame.
pub const PROB_PREV: &str = "prob_prev";
pub const PROB_NEXT: &str = "prob_next";
/// `[S, 1]` time gate g ∈ (0, 1): the blend weight is b_s·g.
pub const GATE: &str = "gate";

/// Raw extra outputs of the dynamic field: [flow to t−1 (3), flow to t+1 (3), p_{t→t−1},
/// p_{t→t+1}, time-gate logit].
pub const DYNAMIC_EXTRA: usize = 9;

/// Initial logit of the time gate: g ≈ 0.98, so b starts as NSFF's b_s.
const GATE_INIT_LOGIT: f32 = 4.0;

/// The static field with NSFF's blend output.
#[derive(Module, Debug)]
pub struct StaticField {
    pub inner: BaseField,
}

impl StaticField {
    pub fn new(cfg: &NsffConfig, aabb: [[f32; 3]; 2], device: &Device) -> Self {
        let mut inner = base_field(&cfg.base, aabb, 1, device);
        if let BaseField::Fast(f) = &mut inner
            && let Some(head) = f.extra.as_mut()
        {
            // Start static (b ≈ 0.05): the dynamic field sees each time from one camera only, so
            // it should take over only where the static field cannot explain the video; starting
            // at b = 0.5 leaves dynamic fog in novel views.
            head.bias = Some(burn::module::Param::from_tensor(Tensor::full(
                [1],
                cfg.blend_init_logit,
                device,
            )));
        }
        StaticField { inner }
    }

    /// Starts the blend head again: b_s = sigmoid(`logit`) at every point (the head's weights
    /// zeroed, its bias set), with new parameters, so that the optimiser's moments of the
    /// shut head do not close it again.
    pub fn reopen_blend(&mut self, logit: f32) {
        if let Some(head) = extra_head(&mut self.inner) {
            set_output(head, 0, logit, true);
        }
    }

    fn blend(raw: Extras) -> Extras {
        let mut extras = Extras::default();
        extras.push(BLEND, sigmoid(raw.expect(RAW_EXTRA)));
        extras
    }
}

impl Field for StaticField {
    fn density(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Density {
        self.inner.density(positions, time).map_extras(Self::blend)
    }

    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs {
        self.inner.query(query).map_extras(Self::blend)
    }

    fn host_params(&self) -> Vec<Arc<HashGrid>> {
        self.inner.host_params()
    }
}

/// The space-time field with scene flow, disocclusion and the time gate. Queries need a time.
#[derive(Module, Debug)]
pub struct DynamicField {
    pub inner: BaseField,
    /// Scene flow is `flow_scale · tanh(raw)`.
    pub flow_scale: f32,
    /// The scene flow's own network; without it the flow is the shared head's first six outputs.
    pub flow: Option<FlowNet>,
    /// Whether the time gate is learnt; without it g ≡ 1 (NSFF's blend b = b_s).
    #[module(skip)]
    pub time_gate: bool,
}

/// Scene flow from its own space-time hash grid and MLP: `[S, 6]` raw flow to the previous and
/// next frame at positions `[S, 3]` and times `[S, 1]`.
#[derive(Module, Debug)]
pub struct FlowNet {
    pub mlp: Mlp,
    #[module(skip)]
    pub encoding: GridEncoding,
    #[module(skip)]
    pub aabb: [[f32; 3]; 2],
}

impl FlowNet {
    pub fn new(grid: HashGridConfig, hidden: usize, aabb: [[f32; 3]; 2], device: &Device, seed: u64) -> Self {
        let encoding = GridEncoding::Hash(HashGrid::new(grid, seed));
        FlowNet {
            mlp: MlpConfig::new(encoding.output_dim(), hidden, 1, 6).init(device),
            encoding,
            aabb,
        }
    }

    pub fn forward(&self, positions: Tensor<2>, time: Tensor<2>) -> Tensor<2> {
        let x = grid_coords(positions, Some(time), self.aabb);
        let enc = nerf_core::profile::span("fwd.flow_encode", || self.encoding.encode(x));
        nerf_core::profile::span("fwd.flow_mlp", || self.mlp.forward(enc))
    }
}

impl DynamicField {
    pub fn new(cfg: &NsffConfig, aabb: [[f32; 3]; 2], device: &Device) -> Self {
        let seed = cfg.base.seed;
        let mut inner = match cfg.base.preset {
            Preset::Fast => {
                let f = &cfg.base.fast;
                BaseField::Fast(
                    FastFieldConfig::new(cfg.dynamic_grid.clone(), aabb)
                        .with_hidden(cfg.dynamic_width)
                        .with_geo_features(f.geo_features)
                        .with_color_hidden(cfg.dynamic_width)
                        .with_sh_degree(cfg.dynamic_sh_degree)
                        .with_color_layers(f.color_layers)
                        .with_extra_outputs(DYNAMIC_EXTRA)
                        .with_time_planes(cfg.dynamic_encoding == SpaceTimeEncoding::Planes)
                        .init(device, seed.wrapping_add(1)),
                )
            }
            Preset::Vanilla => {
                let v = &cfg.base.vanilla;
                BaseField::Vanilla(
                    VanillaFieldConfig::new()
                        .with_width(v.width)
                        .with_depth(v.depth)
                        .with_input_dims(4)
                        .with_extra_outputs(DYNAMIC_EXTRA)
                        .init(device),
                )
            }
        };
        if let Some(head) = extra_head(&mut inner) {
            set_output(head, DYNAMIC_EXTRA - 1, GATE_INIT_LOGIT, false);
        }
        let flow = cfg
            .flow_grid()
            .map(|grid| FlowNet::new(grid, cfg.flow_hidden, aabb, device, seed.wrapping_add(2)));
        DynamicField {
            inner,
            flow_scale: cfg.flow_scale,
            flow,
            time_gate: cfg.time_gate,
        }
    }

    /// The scene flow alone at `[N, 3]` positions and their times `[N, 1]`: (to the previous
    /// frame, to the next), each `[N, 3]`, as a full query's [`FLOW_PREV`] and [`FLOW_NEXT`].
    /// From the flow grid when there is one (a fraction of a full query's cost), else from a
    /// full query's shared head (`dirs`: `N·3` unit directions for it).
    pub fn scene_flow(&self, positions: Tensor<2>, time: Tensor<2>, dirs: &[f32]) -> (Tensor<2>, Tensor<2>) {
        match &self.flow {
            Some(f) => self.split_flow(f.forward(positions, time)),
            None => {
                let out = self.query(FieldQuery::new(positions, dirs).at_time(Some(time)));
                (out.extras.expect(FLOW_PREV), out.extras.expect(FLOW_NEXT))
            }
        }
    }

    /// Opens the time gate again as it starts (g ≈ 0.98 at every point and time: its weights
    /// zeroed, its bias set), with new head parameters ([`StaticField::reopen_blend`]).
    pub fn reopen_gate(&mut self) {
        if let Some(head) = extra_head(&mut self.inner) {
            set_output(head, DYNAMIC_EXTRA - 1, GATE_INIT_LOGIT, true);
        }
    }

    /// Raw flow outputs `[N, 6]` to (previous, next) flows, bounded by `flow_scale`.
    fn split_flow(&self, raw: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        let n = raw.dims()[0];
        let flow = raw.tanh() * self.flow_scale;
        (flow.clone().slice([0..n, 0..3]), flow.slice([0..n, 3..6]))
    }

    /// A full query without the scene flow: every extra but [`FLOW_PREV`] and [`FLOW_NEXT`],
    /// and a flow network of its own is not run (renders that draw no flow map).
    pub fn query_without_flow(&self, query: FieldQuery<'_>) -> FieldOutputs {
        self.query_with(query, false)
    }

    fn query_with(&self, query: FieldQuery<'_>, with_flow: bool) -> FieldOutputs {
        debug_assert!(query.time.is_some(), "the dynamic field needs a time");
        let own_flow = match (&self.flow, &query.time) {
            (Some(f), Some(t)) if with_flow => Some(f.forward(query.positions.clone(), t.clone())),
            _ => None,
        };
        self.inner
            .query(query)
            .map_extras(|e| self.extras(e, with_flow, own_flow))
    }

    /// The named extras from the raw head `[S, 9]` and, with its own network, the raw flow
    /// `[S, 6]`; the flows only `with_flow`.
    fn extras(&self, raw: Extras, with_flow: bool, own_flow: Option<Tensor<2>>) -> Extras {
        let raw = raw.expect(RAW_EXTRA);
        let n = raw.dims()[0];
        let mut extras = Extras::default();
        if with_flow {
            let (prev, next) = self.split_flow(own_flow.unwrap_or_else(|| raw.clone().slice([0..n, 0..6])));
            extras.push(FLOW_PREV, prev);
            extras.push(FLOW_NEXT, next);
        }
        let prob = sigmoid(raw.clone().slice([0..n, 6..8]));
        extras.push(PROB_PREV, prob.clone().slice([0..n, 0..1]));
        extras.push(PROB_NEXT, prob.slice([0..n, 1..2]));
        extras.push(GATE, gate(raw, self.time_gate));
        extras
    }
}

impl Field for DynamicField {
    /// Density with the time gate only (what occupancy and sparsity need; scene flow and
    /// disocclusion come with full queries).
    fn density(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Density {
        let learnt = self.time_gate;
        self.inner
            .density(positions, time)
            .map_extras(|e| gate_only(e, learnt))
    }

    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs {
        self.query_with(query, true)
    }

    fn host_params(&self) -> Vec<Arc<HashGrid>> {
        let mut out = self.inner.host_params();
        if let Some(f) = &self.flow {
            out.extend(f.encoding.grids());
        }
        out
    }
}

/// The time gate `[S, 1]` from the raw head `[S, 9]`: g = sigmoid(raw logit), or 1 when it is
/// not learnt.
fn gate(raw: Tensor<2>, learnt: bool) -> Tensor<2> {
    let n = raw.dims()[0];
    if learnt {
        sigmoid(raw.slice([0..n, DYNAMIC_EXTRA - 1..DYNAMIC_EXTRA]))
    } else {
        Tensor::ones([n, 1], &raw.device())
    }
}

/// The time gate alone from the raw head's extras.
fn gate_only(raw: Extras, learnt: bool) -> Extras {
    let mut extras = Extras::default();
    extras.push(GATE, gate(raw.expect(RAW_EXTRA), learnt));
    extras
}

/// A field's head of extra outputs, where it has one.
fn extra_head(field: &mut BaseField) -> Option<&mut burn::nn::Linear> {
    match field {
        BaseField::Fast(f) => f.extra.as_mut(),
        BaseField::Vanilla(f) => f.extra.as_mut(),
    }
}

/// Sets output `col` of `head` to start at `logit`: its bias, and with `zero_weights` its
/// weights to 0 (so that it reads `logit` at every input). The other outputs keep theirs. New
/// leaves: the parameters must not hang off the graph of the old ones. A weight not yet drawn
/// stays lazy unless it is zeroed: drawing it here would move every later draw of the run's
/// random stream, so that a seed would no longer give the run it gave before.
fn set_output(head: &mut burn::nn::Linear, col: usize, logit: f32, zero_weights: bool) {
    let (device, n) = (head.weight.lazy_device(), head.weight.lazy_shape()[1]);
    let bias = match &head.bias {
        Some(b) => b.val(),
        None => Tensor::zeros([n], &device),
    };
    let (mut keep, mut set) = (vec![1.0f32; n], vec![0.0f32; n]);
    (keep[col], set[col]) = (0.0, logit);
    let keep = Tensor::<1>::from_floats(keep.as_slice(), &device);
    let bias = bias * keep.clone() + Tensor::<1>::from_floats(set.as_slice(), &device);
    head.bias = Some(burn::module::Param::from_tensor(bias.detach()));
    if zero_weights {
        let weight = head.weight.val() * keep.unsqueeze_dim::<2>(0);
        head.weight = burn::module::Param::from_tensor(weight.detach());
    }
}

/// A `[S, 1]` column holding one time for every sample.
pub fn time_column(t: f32, n: usize, device: &Device) -> Tensor<2> {
    Tensor::full([n, 1], t, device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf::config::Preset;
    use nerf_core::readback::read_back;

    const AABB: [[f32; 3]; 2] = [[-1.0; 3], [1.0; 3]];

    /// `n` points spread over [−1, 1]³ `[n, 3]`, their times in [0, 1] `[n, 1]`, and one unit
    /// direction for all (`n·3`).
    fn probe(n: usize, device: &Device) -> (Tensor<2>, Tensor<2>, Vec<f32>) {
        let pos: Vec<f32> = (0..3 * n).map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0).collect();
        let t: Vec<f32> = (0..n).map(|i| (i % 7) as f32 / 6.0).collect();
        let x = Tensor::<2>::from_data(burn::tensor::TensorData::new(pos, [n, 3]), device);
        let tt = Tensor::<2>::from_data(burn::tensor::TensorData::new(t, [n, 1]), device);
        (x, tt, (0..n).flat_map(|_| [0.0, 0.6, -0.8]).collect())
    }

    /// A fast dynamic field with `flow_levels` levels of its own flow grid (none: the shared
    /// head's flow) and six time cells.
    fn field_with_flow(flow_levels: usize, device: &Device) -> DynamicField {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        cfg.dynamic_grid.time_resolution = Some(6);
        cfg.flow_levels = flow_levels;
        DynamicField::new(&cfg, AABB, device)
    }

    /// The flow-only query ([`DynamicField::scene_flow`]) gives what a full query's flow
    /// outputs give at the same points and times, with the flow grid and with the shared head.
    #[test]
    fn the_flow_only_query_matches_the_full_query() {
        let device = Device::flex();
        let n = 64;
        let (x, tt, dirs) = probe(n, &device);
        for flow_levels in [4, 0] {
            let field = field_with_flow(flow_levels, &device);
            assert_eq!(field.flow.is_some(), flow_levels > 0);
            let (x, tt) = (x.clone(), tt.clone());
            let full = field.query(FieldQuery::new(x.clone(), &dirs).at_time(Some(tt.clone())));
            let (prev, next) = field.scene_flow(x, tt, &dirs);
            for (alone, name) in [(prev, FLOW_PREV), (next, FLOW_NEXT)] {
                let a = read_back(alone, name).unwrap();
                let b = read_back(full.extras.expect(name), name).unwrap();
                assert_eq!(a.len(), 3 * n);
                assert!(
                    b.iter().any(|v| v.abs() > 1e-6),
                    "{name}: an all-zero flow tests nothing"
                );
                for (u, w) in a.iter().zip(&b) {
                    assert!(
                        (u - w).abs() <= 1e-6,
                        "{name}, flow_levels {flow_levels}: {u} vs {w}"
                    );
                }
            }
        }
    }

    /// A query without the flow answers as a full query in every other output, with the flow
    /// network and with the shared head, and has no flow.
    #[test]
    fn the_query_without_flow_is_the_full_query_less_the_flow() {
        let device = Device::flex();
        let n = 48;
        let (x, tt, dirs) = probe(n, &device);
        for flow_levels in [4, 0] {
            let field = field_with_flow(flow_levels, &device);
            field.host_params().iter().for_each(|g| g.spread());
            let (x, tt) = (x.clone(), tt.clone());
            let full = field.query(FieldQuery::new(x.clone(), &dirs).at_time(Some(tt.clone())));
            let less = field.query_without_flow(FieldQuery::new(x, &dirs).at_time(Some(tt)));
            assert!(less.extras.get(FLOW_PREV).is_none() && less.extras.get(FLOW_NEXT).is_none());
            assert!(full.extras.get(FLOW_NEXT).is_some());
            let pairs = [
                ("sigma", full.sigma, less.sigma),
                ("rgb", full.rgb, less.rgb),
                (
                    PROB_PREV,
                    full.extras.expect(PROB_PREV),
                    less.extras.expect(PROB_PREV),
                ),
                (
                    PROB_NEXT,
                    full.extras.expect(PROB_NEXT),
                    less.extras.expect(PROB_NEXT),
                ),
                (GATE, full.extras.expect(GATE), less.extras.expect(GATE)),
            ];
            for (name, a, b) in pairs {
                let (a, b) = (read_back(a, name).unwrap(), read_back(b, name).unwrap());
                assert_eq!(a, b, "{name}, flow_levels {flow_levels}");
            }
        }
    }

    /// Opening the time gate as the dynamic field is built sets the head's bias only: the head's
    /// weights stay undrawn until first used, as before the gate was set through `set_output`.
    /// Drawing them early moved every later draw, so each seed gave another run than before
    /// (seventy-seventh session, BENCHMARKS.md §6). The gate still starts at its logit.
    #[test]
    fn building_the_dynamic_field_leaves_its_head_weights_undrawn() {
        let device = Device::flex();
        for preset in [Preset::Fast, Preset::Vanilla] {
            let cfg = NsffConfig::new(preset, "unused".into(), Default::default());
            let mut dy = DynamicField::new(&cfg, AABB, &device);
            let head = extra_head(&mut dy.inner).expect("the dynamic field has a head of extras");
            assert!(
                !head.weight.is_initialized(),
                "{preset:?}: the weights were drawn"
            );
            let bias = read_back(head.bias.as_ref().expect("a bias").val(), "bias").unwrap();
            assert_eq!(bias.len(), DYNAMIC_EXTRA);
            assert_eq!(bias[DYNAMIC_EXTRA - 1], GATE_INIT_LOGIT, "{preset:?}");
        }
    }

    /// A reopened blend head reads its logit at every point, and a reopened gate its starting
    /// logit at every point and time; the dynamic field's other outputs stay as they were.
    #[test]
    fn reopened_heads_read_their_starting_logits_everywhere() {
        let device = Device::flex();
        let (x, tt, dirs) = probe(64, &device);
        let cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        let mut st = StaticField::new(&cfg, AABB, &device);
        let mut dy = field_with_flow(0, &device);
        // Spread features, so that the heads read a different value at each point.
        st.host_params()
            .iter()
            .chain(&dy.host_params())
            .for_each(|g| g.spread());
        let blend = |st: &StaticField| {
            let q = st.query(FieldQuery::new(x.clone(), &dirs));
            read_back(q.extras.expect(BLEND), "blend").unwrap()
        };
        let query = |dy: &DynamicField| dy.query(FieldQuery::new(x.clone(), &dirs).at_time(Some(tt.clone())));
        let spread =
            |v: &[f32]| v.iter().fold(f32::MIN, |a, &b| a.max(b)) - v.iter().fold(f32::MAX, |a, &b| a.min(b));
        let before = blend(&st);
        assert!(spread(&before) > 1e-4, "the blend reads one value before");
        st.reopen_blend(-3.0);
        let want = 1.0 / (1.0 + 3.0f32.exp());
        assert!(blend(&st).iter().all(|b| (b - want).abs() < 1e-6));
        let before = query(&dy);
        assert!(spread(&read_back(before.extras.expect(GATE), "gate").unwrap()) > 1e-4);
        dy.reopen_gate();
        let after = query(&dy);
        let want = 1.0 / (1.0 + (-GATE_INIT_LOGIT).exp());
        let gate = read_back(after.extras.expect(GATE), "gate").unwrap();
        assert!(gate.iter().all(|g| (g - want).abs() < 1e-6), "gate {gate:?}");
        for name in [FLOW_PREV, FLOW_NEXT, PROB_PREV, PROB_NEXT] {
            let (a, b) = (before.extras.expect(name), after.extras.expect(name));
            assert_eq!(read_back(a, name).unwrap(), read_back(b, name).unwrap(), "{name}");
        }
        let (a, b) = (before.sigma, after.sigma);
        assert_eq!(read_back(a, "sigma").unwrap(), read_back(b, "sigma").unwrap());
    }

    /// With `time_gate` off the blend is NSFF's b = b_s: the gate reads exactly 1 from full and
    /// density-only queries, at every time, while a learnt gate starts near sigmoid(4) (below 1).
    #[test]
    fn without_the_time_gate_the_gate_reads_one() {
        let device = Device::flex();
        let n = 32;
        let (x, tt, dirs) = probe(n, &device);
        for learnt in [true, false] {
            let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
            cfg.time_gate = learnt;
            let field = DynamicField::new(&cfg, AABB, &device);
            let (x, tt) = (x.clone(), tt.clone());
            let full = field.query(FieldQuery::new(x.clone(), &dirs).at_time(Some(tt.clone())));
            let dens = field.density(x, Some(tt));
            for g in [full.extras.expect(GATE), dens.extras.expect(GATE)] {
                let g = read_back(g, "gate").unwrap();
                assert_eq!(g.len(), n);
                for v in g {
                    if learnt {
                        // sigmoid(4) = 0.982; the head's random weights move it a little.
                        assert!(v > 0.9 && v < 1.0, "learnt gate {v}");
                    } else {
                        assert_eq!(v, 1.0);
                    }
                }
            }
        }
    }
}
