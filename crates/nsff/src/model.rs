//! NSFF's two fields. The static field is the static pipeline's field with one extra output,
//! the blend weight b_s (NSFF predicts it from the static network); the dynamic field is the
//! same field type over (x, y, z, t) with nine extra outputs: scene flow to the previous and
//! next frame, the two disocclusion probabilities, and a time gate g.
//!
//! The blend is b = b_s(x)·g(x, t). NSFF's b is a function of position only, so along a moving
//! object's path it must be high at every time, and nothing can hide the dynamic field's guesses
//! in space a frame's camera cannot see without also hiding the object at the times it is there.
//! The gate lets b fall at one time and stay at another; b_s alone still decides which samples
//! can skip the dynamic field at render time (b ≤ b_s).

use burn::module::Module;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor};
use nerf::config::Preset;
use nerf::field::{FastField, FastFieldConfig, VanillaField, VanillaFieldConfig, normalize, normalize_host};
use nerf::model::fast_config;
use nerf::renderer::tensor;

use crate::config::NsffConfig;

/// Extra outputs of the dynamic field: [flow to t−1 (3), flow to t+1 (3), p_{t→t−1}, p_{t→t+1},
/// time-gate logit].
pub const DYNAMIC_EXTRA: usize = 9;

/// Initial logit of the time gate: g ≈ 0.98, so b starts as NSFF's b_s.
const GATE_INIT_LOGIT: f32 = 4.0;

#[allow(clippy::large_enum_variant)] // two values per run; boxing would not pay for itself
#[derive(Module, Debug)]
pub enum Field {
    Fast(FastField),
    Vanilla(VanillaField),
}

#[derive(Module, Debug)]
pub struct NsffFields {
    pub static_field: Field,
    /// `None` when the video has no independent motion: the model is then a static NeRF.
    pub dynamic: Option<Field>,
}

/// Static field outputs for S samples.
#[derive(Clone, Debug)]
pub struct StaticOut {
    pub sigma: Tensor<2>,
    pub rgb: Tensor<2>,
    /// Blend weight b ∈ (0, 1): the dynamic share of each sample.
    pub blend: Tensor<2>,
}

/// Dynamic field outputs for S samples at one time.
#[derive(Clone, Debug)]
pub struct DynamicOut {
    pub sigma: Tensor<2>,
    pub rgb: Tensor<2>,
    /// `[S, 3]` scene flow to the previous frame and to the next frame.
    pub flow_prev: Tensor<2>,
    pub flow_next: Tensor<2>,
    /// `[S, 1]` disocclusion probabilities towards the previous and next frame.
    pub prob_prev: Tensor<2>,
    pub prob_next: Tensor<2>,
    /// `[S, 1]` time gate g ∈ (0, 1): the blend weight is b_s·g.
    pub gate: Tensor<2>,
}

impl NsffFields {
    pub fn new(cfg: &NsffConfig, with_dynamic: bool, device: &Device) -> Self {
        let seed = cfg.base.seed;
        device.seed(seed);
        let (static_field, dynamic) = match cfg.base.preset {
            Preset::Fast => {
                let mut st = fast_config(&cfg.base, 1).init(device, seed);
                if let Some(head) = st.extra.as_mut() {
                    // Start static (b ≈ 0.05): the dynamic field sees each time from one camera
                    // only, so it should take over only where the static field cannot explain
                    // the video; starting at b = 0.5 leaves dynamic fog in novel views.
                    head.bias = Some(burn::module::Param::from_tensor(Tensor::full(
                        [1],
                        cfg.blend_init_logit,
                        device,
                    )));
                }
                let dy = with_dynamic.then(|| {
                    let f = &cfg.base.fast;
                    FastFieldConfig::new(cfg.dynamic_grid.clone())
                        .with_hidden(cfg.dynamic_width)
                        .with_geo_features(f.geo_features)
                        .with_color_hidden(cfg.dynamic_width)
                        .with_sh_degree(cfg.dynamic_sh_degree)
                        .with_color_layers(f.color_layers)
                        .with_extra_outputs(DYNAMIC_EXTRA)
                        .init(device, seed.wrapping_add(1))
                });
                let dy = dy.map(|mut f| {
                    if let Some(head) = f.extra.as_mut() {
                        open_gate(head, device);
                    }
                    f
                });
                (Field::Fast(st), dy.map(Field::Fast))
            }
            Preset::Vanilla => {
                let v = &cfg.base.vanilla;
                let st = VanillaFieldConfig::new()
                    .with_width(v.width)
                    .with_depth(v.depth)
                    .with_extra_outputs(1)
                    .init(device);
                let dy = with_dynamic.then(|| {
                    VanillaFieldConfig::new()
                        .with_width(v.width)
                        .with_depth(v.depth)
                        .with_input_dims(4)
                        .with_extra_outputs(DYNAMIC_EXTRA)
                        .init(device)
                });
                let dy = dy.map(|mut f| {
                    if let Some(head) = f.extra.as_mut() {
                        open_gate(head, device);
                    }
                    f
                });
                (Field::Vanilla(st), dy.map(Field::Vanilla))
            }
        };
        NsffFields {
            static_field,
            dynamic,
        }
    }

    /// The hash grids (fast preset), for their sparse optimiser steps.
    pub fn grids(&self) -> Vec<std::sync::Arc<nerf_core::encoding::HashGrid>> {
        [Some(&self.static_field), self.dynamic.as_ref()]
            .into_iter()
            .flatten()
            .filter_map(|f| match f {
                Field::Fast(f) => Some(f.grid.clone()),
                Field::Vanilla(_) => None,
            })
            .collect()
    }
}

/// Sets the time-gate output's bias to [`GATE_INIT_LOGIT`], keeping the others.
fn open_gate(head: &mut burn::nn::Linear, device: &Device) {
    let mut bias = head
        .bias
        .as_ref()
        .map(|b| b.val().into_data().try_into_vec_as::<f32>().unwrap_or_default())
        .unwrap_or_default();
    bias.resize(DYNAMIC_EXTRA, 0.0);
    bias[DYNAMIC_EXTRA - 1] = GATE_INIT_LOGIT;
    head.bias = Some(burn::module::Param::from_tensor(Tensor::from_data(
        burn::tensor::TensorData::new(bias, [DYNAMIC_EXTRA]),
        device,
    )));
}

/// Density activation: the fast field returns σ already; the vanilla one a raw value.
fn density(field: &Field, raw: Tensor<2>) -> Tensor<2> {
    match field {
        Field::Fast(_) => raw,
        Field::Vanilla(_) => relu(raw),
    }
}

/// Queries the static field at `[S, 3]` positions (world, or NDC) with unit view directions.
pub fn query_static(field: &Field, positions: Tensor<2>, dirs: &[f32], aabb: [[f32; 3]; 2]) -> StaticOut {
    let out = match field {
        Field::Fast(f) => f.forward(normalize(positions, aabb), dirs),
        Field::Vanilla(f) => f.forward(positions, dirs),
    };
    let extra = out
        .extra
        .unwrap_or_else(|| unreachable!("the static field is built with a blend output"));
    StaticOut {
        sigma: density(field, out.sigma),
        rgb: out.rgb,
        blend: sigmoid(extra),
    }
}

/// Queries the dynamic field at `[S, 3]` positions and one normalised time `t` ∈ [0, 1].
/// Differentiable in the positions (warped queries pass flowed points).
pub fn query_dynamic(
    field: &Field,
    positions: Tensor<2>,
    t: f32,
    dirs: &[f32],
    aabb: [[f32; 3]; 2],
    flow_scale: f32,
) -> DynamicOut {
    let n = positions.dims()[0];
    let device = positions.device();
    let time = tensor(vec![t; n], 1, &device);
    let out = match field {
        Field::Fast(f) => f.forward(Tensor::cat(vec![normalize(positions, aabb), time], 1), dirs),
        // NSFF encodes t in [−1, 1] jointly with x.
        Field::Vanilla(f) => f.forward(Tensor::cat(vec![positions, time * 2.0 - 1.0], 1), dirs),
    };
    let extra = out
        .extra
        .unwrap_or_else(|| unreachable!("the dynamic field is built with flow outputs"));
    let flow = extra.clone().slice([0..n, 0..6]).tanh() * flow_scale;
    let prob = sigmoid(extra.clone().slice([0..n, 6..8]));
    DynamicOut {
        sigma: density(field, out.sigma),
        rgb: out.rgb,
        flow_prev: flow.clone().slice([0..n, 0..3]),
        flow_next: flow.slice([0..n, 3..6]),
        prob_prev: prob.clone().slice([0..n, 0..1]),
        prob_next: prob.slice([0..n, 1..2]),
        gate: sigmoid(extra.slice([0..n, 8..9])),
    }
}

/// Density for the occupancy grid at `[M, 3]` world positions (host), as the combined render
/// sees it: (1 − b)·σ_static + b·σ_dynamic with b = b_s·g, with the dynamic field at each point's own time in
/// `times` (one per point). `None` for the vanilla preset, which samples without a grid.
pub fn occupancy_density(
    fields: &NsffFields,
    positions: &[f32],
    times: &[f32],
    aabb: [[f32; 3]; 2],
    device: &Device,
) -> Option<Vec<f32>> {
    let Field::Fast(st) = &fields.static_field else {
        return None;
    };
    let host = |t: Tensor<2>| t.into_data().try_into_vec_as::<f32>().unwrap_or_default();
    let mut out = Vec::with_capacity(positions.len() / 3);
    for (chunk, tc) in positions.chunks(3 * 65536).zip(times.chunks(65536)) {
        let x = tensor(normalize_host(chunk, aabb), 3, device);
        let (sigma, extra) = st.density_extra(x.clone());
        let mut sigma = host(sigma);
        if let (Some(Field::Fast(dy)), Some(extra)) = (&fields.dynamic, extra) {
            let blend = host(sigmoid(extra));
            let xt = Tensor::cat(vec![x, tensor(tc.to_vec(), 1, device)], 1);
            let (sigma_dy, extra_dy) = dy.density_extra(xt);
            let m = blend.len();
            let gate = extra_dy
                .map(|e| host(sigmoid(e.slice([0..m, DYNAMIC_EXTRA - 1..DYNAMIC_EXTRA]))))
                .unwrap_or_else(|| vec![1.0; m]);
            for (((s, d), b), g) in sigma.iter_mut().zip(host(sigma_dy)).zip(blend).zip(gate) {
                let b = b * g;
                *s = (1.0 - b) * *s + b * d;
            }
        }
        out.extend(sigma);
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The occupancy density uses the same blend as the renderers, b = b_s·g, recomputed here in
    /// f64 from the query functions' outputs; the gate starts open.
    #[test]
    fn occupancy_density_blends_with_the_time_gate() {
        let device = Device::flex();
        let cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        let fields = NsffFields::new(&cfg, true, &device);
        let aabb = [[-1.0f32, -1.0, -1.0], [1.0, 1.0, 1.0]];
        let n = 64;
        let pos: Vec<f32> = (0..3 * n).map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0).collect();
        let times: Vec<f32> = (0..n).map(|i| i as f32 / (n - 1) as f32).collect();
        let got = occupancy_density(&fields, &pos, &times, aabb, &device).unwrap();
        let host = |t: Tensor<2>| t.into_data().try_into_vec_as::<f32>().unwrap();
        let dirs = [0.0f32, 0.0, 1.0].repeat(n);
        let st = query_static(&fields.static_field, tensor(pos.clone(), 3, &device), &dirs, aabb);
        let (sigma_st, blend) = (host(st.sigma), host(st.blend));
        let dynamic = fields.dynamic.as_ref().unwrap();
        for i in 0..n {
            let x = tensor(pos[3 * i..3 * i + 3].to_vec(), 3, &device);
            let dy = query_dynamic(dynamic, x, times[i], &dirs[..3], aabb, cfg.flow_scale);
            let (sigma_dy, gate) = (host(dy.sigma)[0] as f64, host(dy.gate)[0] as f64);
            assert!(gate > 0.9, "the gate starts open: {gate}");
            let b = blend[i] as f64 * gate;
            let want = (1.0 - b) * sigma_st[i] as f64 + b * sigma_dy;
            assert!(
                (got[i] as f64 - want).abs() <= 1e-4 * want.abs().max(1.0),
                "point {i}: {} vs {want}",
                got[i]
            );
        }
    }
}
