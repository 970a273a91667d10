//! Renderers: rays → samples (sampler) → field queries → composited pixels.

use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::composite::{self, RayLayout};
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::profile::span;
use nerf_core::rays::Rays;
use nerf_core::sampler::{self, RaySamples};
use rand::Rng;
use rand::rngs::StdRng;

use crate::config::TrainConfig;
use crate::field::{FastField, VanillaField, normalize_host};

/// Scene geometry the renderer needs from the dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneBounds {
    pub near: f32,
    pub far: f32,
    pub aabb: [[f32; 3]; 2],
    /// The last interval of each ray absorbs all remaining light (real scenes without background).
    pub open_far: bool,
}

/// Composited output for `R` rays.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// `[R, 3]`, background included.
    pub rgb: Tensor<2>,
    /// `[R, 1]` expected ray parameter (depth, or NDC t) of the visible surface.
    pub depth: Tensor<2>,
    /// `[R, 1]` accumulated opacity.
    pub opacity: Tensor<2>,
    /// The coarse network's colour (vanilla preset), for its loss term.
    pub coarse_rgb: Option<Tensor<2>>,
    /// Field evaluations that produced this result.
    pub samples: usize,
}

/// Host data → `[n, w]` tensor.
pub fn tensor(data: Vec<f32>, w: usize, device: &Device) -> Tensor<2> {
    let n = data.len() / w.max(1);
    Tensor::from_data(TensorData::new(data, [n, w]), device)
}

/// Splits a composite output `[R, C + 1]` (colour, depth, opacity) and adds the background.
fn finish(out: Tensor<2>, background: Option<&Tensor<2>>) -> (Tensor<2>, Tensor<2>, Tensor<2>) {
    let r = out.dims()[0];
    let rgb = out.clone().slice([0..r, 0..3]);
    let depth = out.clone().slice([0..r, 3..4]);
    let opacity = out.slice([0..r, 4..5]);
    let rgb = match background {
        Some(bg) => rgb + (opacity.clone().neg() + 1.0) * bg.clone(),
        None => rgb,
    };
    (rgb, depth, opacity)
}

fn empty(rays: usize, device: &Device, background: Option<&Tensor<2>>) -> Rendered {
    let zeros = |w| Tensor::<2>::zeros([rays, w], device);
    Rendered {
        rgb: background.cloned().unwrap_or_else(|| zeros(3)),
        depth: zeros(1),
        opacity: zeros(1),
        coarse_rgb: None,
        samples: 0,
    }
}

/// Per-sample `[S, 4]` features: colour and the sample's t (its composite is the depth).
fn colour_and_t(rgb: Tensor<2>, samples: &RaySamples, device: &Device) -> Tensor<2> {
    Tensor::cat(vec![rgb, tensor(samples.t.clone(), 1, device)], 1)
}

/// Fast preset: occupancy-grid marching, optional early termination (densities from a no-grad
/// pass), then one differentiable pass over the surviving samples.
#[allow(clippy::too_many_arguments)]
pub fn render_fast(
    field: &FastField,
    occupancy: Option<&OccupancyGrid>,
    rays: &Rays,
    bounds: &SceneBounds,
    cfg: &TrainConfig,
    background: Option<&Tensor<2>>,
    rng: Option<&mut StdRng>,
    device: &Device,
) -> Rendered {
    let s = &cfg.fast;
    let early_termination = if rng.is_some() {
        s.train_early_termination
    } else {
        s.early_termination
    };
    let mut samples = span("march", || {
        sampler::march(
            rays,
            bounds.aabb,
            bounds.near,
            bounds.far,
            occupancy,
            &s.march,
            rng,
        )
    });
    let stop_eps = if early_termination { s.stop_eps } else { 0.0 };
    // Marching skips empty cells, so a ray's last sample need not lie at the far bound: it must
    // not absorb the remaining light (`open_far` is for stratified sampling only).
    let open_far = false;
    if early_termination && samples.num_samples() > 0 {
        let sigma = span("early_stop_density", || {
            density_host(field, &samples.positions(rays), bounds.aabb, device)
        });
        let alive = composite::alive(&sigma, &samples.layout(rays, open_far), stop_eps);
        samples = samples.filter(&alive);
    }
    if samples.num_samples() == 0 {
        return empty(rays.len(), device, background);
    }
    let positions = normalize_host(&samples.positions(rays), bounds.aabb);
    let dirs = samples.per_sample3(&rays.viewdirs());
    let out = span("field_forward", || {
        field.forward(tensor(positions, 3, device), &dirs)
    });
    let layout = samples.layout(rays, open_far);
    let comp = span("composite", || {
        composite::composite(
            out.sigma,
            colour_and_t(out.rgb, &samples, device),
            None,
            &layout,
            stop_eps,
        )
    });
    let (rgb, depth, opacity) = finish(comp, background);
    Rendered {
        rgb,
        depth,
        opacity,
        coarse_rgb: None,
        samples: samples.num_samples(),
    }
}

/// Densities of `[S, 3]` world positions without building a graph.
pub fn density_host(field: &FastField, positions: &[f32], aabb: [[f32; 3]; 2], device: &Device) -> Vec<f32> {
    if positions.is_empty() {
        return Vec::new();
    }
    let plain = device.clone().inner();
    let field = field.valid();
    let x = tensor(normalize_host(positions, aabb), 3, &plain);
    field
        .density(x)
        .into_data()
        .try_into_vec_as::<f32>()
        .unwrap_or_default()
}

/// ReLU(raw + noise): nerf-pytorch's density activation, noise only while training.
fn activate(raw: Tensor<2>, noise_std: f32, rng: Option<&mut StdRng>) -> Tensor<2> {
    let raw = match rng {
        Some(rng) if noise_std > 0.0 => {
            let n = raw.dims()[0];
            let noise: Vec<f32> = (0..n)
                .map(|_| {
                    // Box–Muller from two uniforms.
                    let (u1, u2): (f32, f32) = (rng.random::<f32>().max(1e-12), rng.random());
                    noise_std * (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
                })
                .collect();
            raw.clone() + tensor(noise, 1, &raw.device())
        }
        _ => raw,
    };
    burn::tensor::activation::relu(raw)
}

fn query_vanilla(
    field: &VanillaField,
    rays: &Rays,
    samples: &RaySamples,
    layout: &RayLayout,
    noise_std: f32,
    rng: Option<&mut StdRng>,
    device: &Device,
) -> (Tensor<2>, Tensor<2>) {
    let dirs = samples.per_sample3(&rays.viewdirs());
    let out = field.forward(tensor(samples.positions(rays), 3, device), &dirs);
    let sigma = activate(out.sigma, noise_std, rng);
    let comp = composite::composite(
        sigma.clone(),
        colour_and_t(out.rgb, samples, device),
        None,
        layout,
        0.0,
    );
    (comp, sigma)
}

/// Vanilla preset: stratified coarse samples, inverse-CDF fine samples from the coarse weights,
/// the fine network on the union.
#[allow(clippy::too_many_arguments)]
pub fn render_vanilla(
    coarse: &VanillaField,
    fine: &VanillaField,
    rays: &Rays,
    bounds: &SceneBounds,
    cfg: &TrainConfig,
    background: Option<&Tensor<2>>,
    mut rng: Option<&mut StdRng>,
    device: &Device,
) -> Rendered {
    let v = &cfg.vanilla;
    let n = rays.len();
    let (near, far) = (vec![bounds.near; n], vec![bounds.far; n]);
    let coarse_samples = sampler::stratified(&near, &far, v.coarse_samples, v.spacing, rng.as_deref_mut());
    let layout_c = coarse_samples.layout(rays, bounds.open_far);
    let (comp_c, sigma_c) = query_vanilla(
        coarse,
        rays,
        &coarse_samples,
        &layout_c,
        v.raw_noise_std,
        rng.as_deref_mut(),
        device,
    );
    let sigma_host = sigma_c
        .inner()
        .into_data()
        .try_into_vec_as::<f32>()
        .unwrap_or_default();
    let weights = composite::weights(&sigma_host, &layout_c, 0.0);
    let fine_samples = sampler::sample_pdf(&coarse_samples, &weights, v.fine_samples, rng.as_deref_mut());
    let layout_f = fine_samples.layout(rays, bounds.open_far);
    let (comp_f, _) = query_vanilla(fine, rays, &fine_samples, &layout_f, v.raw_noise_std, rng, device);
    let (coarse_rgb, _, _) = finish(comp_c, background);
    let (rgb, depth, opacity) = finish(comp_f, background);
    Rendered {
        rgb,
        depth,
        opacity,
        coarse_rgb: Some(coarse_rgb),
        samples: coarse_samples.num_samples() + fine_samples.num_samples(),
    }
}
