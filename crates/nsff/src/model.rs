//! NSFF's two fields. The static field is the static pipeline's field with one extra output,
//! the blend weight b (NSFF predicts it from the static network); the dynamic field is the same
//! field type over (x, y, z, t) with eight extra outputs: scene flow to the previous and next
//! frame and the two disocclusion probabilities.

use burn::module::Module;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor};
use nerf::config::Preset;
use nerf::field::{FastField, FastFieldConfig, VanillaField, VanillaFieldConfig, normalize, normalize_host};
use nerf::model::fast_config;
use nerf::renderer::tensor;

use crate::config::NsffConfig;

/// Extra outputs of the dynamic field: [flow to t−1 (3), flow to t+1 (3), p_{t→t−1}, p_{t→t+1}].
pub const DYNAMIC_EXTRA: usize = 8;

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
    let prob = sigmoid(extra.slice([0..n, 6..8]));
    DynamicOut {
        sigma: density(field, out.sigma),
        rgb: out.rgb,
        flow_prev: flow.clone().slice([0..n, 0..3]),
        flow_next: flow.slice([0..n, 3..6]),
        prob_prev: prob.clone().slice([0..n, 0..1]),
        prob_next: prob.slice([0..n, 1..2]),
    }
}

/// Density for the occupancy grid at `[M, 3]` world positions (host), as the combined render
/// sees it: (1 − b)·σ_static + b·σ_dynamic, with the dynamic field at each point's own time in
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
            for ((s, d), b) in sigma.iter_mut().zip(host(dy.density(xt))).zip(blend) {
                *s = (1.0 - b) * *s + b * d;
            }
        }
        out.extend(sigma);
    }
    Some(out)
}
