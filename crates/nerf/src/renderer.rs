//! The static model's two ways to place samples, each ending in the shared render function:
//! occupancy-grid marching with early termination (fast preset) and NeRF's hierarchical
//! sampling with a proposal field (vanilla preset). Both work with any [`Field`].

use burn::tensor::{Device, Tensor};
use nerf_core::composite;
use nerf_core::field::{Field, FieldOutputs, FieldQuery};
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::profile::span;
use nerf_core::rays::Rays;
use nerf_core::render::{Background, Component, RenderOptions, RenderOutput, render};
use nerf_core::sampler::{self, MarchConfig, RaySamples, Spacing};
use rand::Rng;
use rand::rngs::StdRng;
use serde::{Deserialize, Serialize};

use crate::config::{Preset, TrainConfig};
use crate::error::{ModelError, read_back};
use crate::field::FieldModule;

pub use nerf_core::render::host_tensor as tensor;

/// Scene geometry the renderer needs from the dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneBounds {
    pub near: f32,
    pub far: f32,
    pub aabb: [[f32; 3]; 2],
    /// The last interval of each ray absorbs all remaining light (real scenes without background).
    pub open_far: bool,
}

impl SceneBounds {
    /// An object scene: rays from `near` to `far` through the box `aabb`, nothing beyond.
    pub fn object(near: f32, far: f32, aabb: [[f32; 3]; 2]) -> Self {
        SceneBounds {
            near,
            far,
            aabb,
            open_far: false,
        }
    }

    /// The box's longest side: a length of the scene.
    pub fn extent(&self) -> f32 {
        let [lo, hi] = self.aabb;
        (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f32::max)
    }
}

/// Training renders jitter their samples (and may add density noise); inference renders do not.
pub enum Pass<'a> {
    Train(&'a mut StdRng),
    Infer,
}

impl Pass<'_> {
    pub fn is_train(&self) -> bool {
        matches!(self, Pass::Train(_))
    }

    pub fn rng(&mut self) -> Option<&mut StdRng> {
        match self {
            Pass::Train(rng) => Some(&mut **rng),
            Pass::Infer => None,
        }
    }
}

/// Where samples go along a ray.
#[derive(Clone, Debug, PartialEq)]
pub enum Sampling {
    /// March through the occupancy grid (or the whole box without one), in fixed steps.
    March {
        march: MarchConfig,
        /// Early ray termination when rendering / while training.
        early_termination: bool,
        train_early_termination: bool,
        stop_eps: f32,
    },
    /// Stratified samples for the proposal field, then inverse-CDF samples from its weights for
    /// the main field (NeRF's coarse and fine networks).
    Hierarchical {
        coarse: usize,
        fine: usize,
        spacing: Spacing,
        /// Density noise while training (real scenes).
        raw_noise_std: f32,
    },
}

impl Sampling {
    pub fn from_config(cfg: &TrainConfig) -> Self {
        match cfg.preset {
            Preset::Fast => Sampling::March {
                march: cfg.fast.march.clone(),
                early_termination: cfg.fast.early_termination,
                train_early_termination: cfg.fast.train_early_termination,
                stop_eps: cfg.fast.stop_eps,
            },
            Preset::Vanilla => Sampling::Hierarchical {
                coarse: cfg.vanilla.coarse_samples,
                fine: cfg.vanilla.fine_samples,
                spacing: cfg.vanilla.spacing,
                raw_noise_std: cfg.vanilla.raw_noise_std,
            },
        }
    }
}

/// What to render: rays through a scene, the background behind it, the device to render on.
#[derive(Clone, Copy)]
pub struct Target<'a> {
    pub rays: &'a Rays,
    pub bounds: &'a SceneBounds,
    pub background: &'a Background,
    pub device: &'a Device,
}

/// A render of `R` rays.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// The main field's pixels (rgb with background, depth, opacity).
    pub out: RenderOutput,
    /// The proposal field's colour (hierarchical sampling), for its loss term.
    pub coarse_rgb: Option<Tensor<2>>,
    /// Field evaluations that produced this result.
    pub samples: usize,
}

/// Densities of `[S, 3]` positions without building a graph.
pub fn density_host<F: FieldModule>(
    field: &F,
    positions: &[f32],
    device: &Device,
) -> Result<Vec<f32>, ModelError> {
    if positions.is_empty() {
        return Ok(Vec::new());
    }
    let plain = device.clone().inner();
    let sigma = field
        .valid()
        .density(tensor(positions.to_vec(), 3, &plain), None)
        .sigma;
    read_back(sigma, "density")
}

/// Occupancy marching: samples in the occupied cells, optionally cut where rays become opaque
/// (densities from a no-grad pass), then one differentiable pass over the surviving samples.
pub fn render_march<F: FieldModule>(
    field: &F,
    occupancy: Option<&OccupancyGrid>,
    (march, early_termination, stop_eps): (&MarchConfig, bool, f32),
    target: Target<'_>,
    mut pass: Pass<'_>,
) -> Result<Rendered, ModelError> {
    let (rays, bounds, background, device) = (target.rays, target.bounds, target.background, target.device);
    let mut samples = span("march", || {
        sampler::march(
            rays,
            bounds.aabb,
            bounds.near,
            bounds.far,
            occupancy,
            march,
            pass.rng(),
        )
    });
    let stop_eps = if early_termination { stop_eps } else { 0.0 };
    // Marching skips empty cells, so a ray's last sample need not lie at the far bound: it must
    // not absorb the remaining light.
    let options = RenderOptions {
        open_far: false,
        stop_eps,
    };
    let terminate = early_termination && samples.num_samples() > 0;
    let out = if terminate && !pass.is_train() {
        let (reached, fields) = query_reached(field, rays, &samples, options.open_far, stop_eps, device)?;
        samples = reached;
        render_one(rays, &samples, fields, background, options, device)
    } else {
        if terminate {
            // Training: a no-grad density pass, then the differentiable query of the survivors.
            let sigma = span("early_stop_density", || {
                density_host(field, &samples.positions(rays), device)
            })?;
            let alive = composite::alive(&sigma, &samples.layout(rays, options.open_far), stop_eps);
            samples = samples.filter(&alive);
        }
        query_and_render(field, rays, &samples, None, background, options, device)
    };
    Ok(Rendered {
        samples: out.samples,
        out,
        coarse_rgb: None,
    })
}

/// Inference's early ray termination in one pass over the field ([`Field::query_kept`]): the
/// samples each ray reaches before its transmittance falls below `stop_eps`, and the field's
/// outputs there.
fn query_reached<F: Field>(
    field: &F,
    rays: &Rays,
    samples: &RaySamples,
    open_far: bool,
    stop_eps: f32,
    device: &Device,
) -> Result<(RaySamples, FieldOutputs), ModelError> {
    let dirs = samples.per_sample3(&rays.viewdirs());
    let query = FieldQuery::new(tensor(samples.positions(rays), 3, device), &dirs);
    let layout = samples.layout(rays, open_far);
    let mut alive = Vec::new();
    let mut failed = None;
    let (_, outputs) = span("field_forward", || {
        field.query_kept(query, &mut |sigma| match read_back(sigma, "density") {
            Ok(sigma) => {
                alive = composite::alive(&sigma, &layout, stop_eps);
                (0..alive.len()).filter(|&i| alive[i]).collect()
            }
            Err(e) => {
                failed = Some(e);
                Vec::new()
            }
        })
    });
    match failed {
        Some(e) => Err(e),
        None => Ok((samples.filter(&alive), outputs)),
    }
}

/// Composites one field's outputs at `samples`.
fn render_one(
    rays: &Rays,
    samples: &RaySamples,
    outputs: FieldOutputs,
    background: &Background,
    options: RenderOptions,
    device: &Device,
) -> RenderOutput {
    span("composite", || {
        render(
            rays,
            samples,
            &[Component::new(outputs.sigma, outputs.rgb)],
            background,
            options,
            device,
        )
    })
}

/// Queries `field` at `samples` and renders them as one component. `noise`: pre-activation
/// density noise per sample.
fn query_and_render<F: Field>(
    field: &F,
    rays: &Rays,
    samples: &RaySamples,
    noise: Option<Vec<f32>>,
    background: &Background,
    options: RenderOptions,
    device: &Device,
) -> RenderOutput {
    if samples.num_samples() == 0 {
        return render(rays, samples, &[], background, options, device);
    }
    let dirs = samples.per_sample3(&rays.viewdirs());
    let mut query = FieldQuery::new(tensor(samples.positions(rays), 3, device), &dirs);
    query.density_noise = noise.map(|n| tensor(n, 1, device));
    let out = span("field_forward", || field.query(query));
    render_one(rays, samples, out, background, options, device)
}

/// Gaussian noise for `n` samples (Box–Muller from two uniforms), or `None` when not training.
fn density_noise(n: usize, std: f32, pass: &mut Pass<'_>) -> Option<Vec<f32>> {
    let rng = pass.rng().filter(|_| std > 0.0)?;
    Some(
        (0..n)
            .map(|_| {
                let (u1, u2): (f32, f32) = (rng.random::<f32>().max(1e-12), rng.random());
                std * (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
            })
            .collect(),
    )
}

/// Hierarchical sampling: the proposal field on stratified samples, the main field on the union
/// of those and inverse-CDF samples drawn from the proposal's weights.
pub fn render_hierarchical<F: Field>(
    proposal: &F,
    field: &F,
    (coarse, fine, spacing, noise_std): (usize, usize, Spacing, f32),
    target: Target<'_>,
    mut pass: Pass<'_>,
) -> Result<Rendered, ModelError> {
    let (rays, bounds, background, device) = (target.rays, target.bounds, target.background, target.device);
    let n = rays.len();
    let options = RenderOptions {
        open_far: bounds.open_far,
        stop_eps: 0.0,
    };
    let (near, far) = (vec![bounds.near; n], vec![bounds.far; n]);
    let coarse_samples = sampler::stratified(&near, &far, coarse, spacing, pass.rng());
    let noise = density_noise(coarse_samples.num_samples(), noise_std, &mut pass);
    let dirs = coarse_samples.per_sample3(&rays.viewdirs());
    let mut query = FieldQuery::new(tensor(coarse_samples.positions(rays), 3, device), &dirs);
    query.density_noise = noise.map(|v| tensor(v, 1, device));
    let out_c = proposal.query(query);
    let sigma_host = read_back(out_c.sigma.clone(), "proposal density")?;
    let comp_c = render(
        rays,
        &coarse_samples,
        &[Component::new(out_c.sigma, out_c.rgb)],
        background,
        options,
        device,
    );
    let weights = composite::weights(&sigma_host, &comp_c.layout, 0.0);
    let fine_samples = sampler::sample_pdf(&coarse_samples, &weights, fine, pass.rng());
    let noise = density_noise(fine_samples.num_samples(), noise_std, &mut pass);
    let out = query_and_render(field, rays, &fine_samples, noise, background, options, device);
    Ok(Rendered {
        out,
        coarse_rgb: Some(comp_c.rgb),
        samples: coarse_samples.num_samples() + fine_samples.num_samples(),
    })
}
