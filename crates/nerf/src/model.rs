//! The trainable static model: its fields, the occupancy grid, and whole-image rendering.

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::rays::Rays;
use nerf_data::{Dataset, SceneKind};
use rand::rngs::StdRng;

use crate::config::{Preset, TrainConfig};
use crate::field::{FastField, FastFieldConfig, VanillaField, VanillaFieldConfig, normalize_host};
use crate::renderer::{self, Rendered, SceneBounds, tensor};

/// NeRF's coarse and fine networks.
#[derive(Module, Debug)]
pub struct VanillaPair {
    pub coarse: VanillaField,
    pub fine: VanillaField,
}

/// The burn modules of a preset (what the optimiser updates and checkpoints store).
#[allow(clippy::large_enum_variant)] // one value per run; boxing would not pay for itself
#[derive(Module, Debug)]
pub enum Fields {
    Fast(FastField),
    Vanilla(VanillaPair),
}

/// Fields plus the non-learned state rendering needs.
#[derive(Debug)]
pub struct StaticModel {
    pub fields: Fields,
    pub occupancy: Option<OccupancyGrid>,
    pub bounds: SceneBounds,
}

/// A rendered image on the host: `[H·W, 3]` colour, `[H·W]` depth and opacity.
#[derive(Clone, Debug)]
pub struct ImageRender {
    pub rgb: Vec<f32>,
    pub depth: Vec<f32>,
    pub opacity: Vec<f32>,
    /// Mean field evaluations per ray.
    pub samples_per_ray: f64,
}

/// Scene bounds from a dataset.
pub fn scene_bounds(dataset: &Dataset) -> SceneBounds {
    SceneBounds {
        near: dataset.near,
        far: dataset.far,
        aabb: dataset.aabb,
        open_far: dataset.background.is_none() && dataset.kind == SceneKind::ForwardFacing,
    }
}

impl StaticModel {
    /// A freshly initialised model for `cfg` on `device`.
    pub fn new(cfg: &TrainConfig, bounds: SceneBounds, device: &Device) -> Self {
        // MLP initialisation draws from the device's RNG; seeding it makes runs reproducible.
        device.seed(cfg.seed);
        let fields = match cfg.preset {
            Preset::Fast => Fields::Fast(fast_config(cfg, 0).init(device, cfg.seed)),
            Preset::Vanilla => {
                let vc = VanillaFieldConfig::new()
                    .with_width(cfg.vanilla.width)
                    .with_depth(cfg.vanilla.depth);
                Fields::Vanilla(VanillaPair {
                    coarse: vc.init(device),
                    fine: vc.init(device),
                })
            }
        };
        let occupancy = (cfg.preset == Preset::Fast && cfg.fast.use_occupancy)
            .then(|| OccupancyGrid::new(cfg.fast.occupancy.clone(), bounds.aabb));
        StaticModel {
            fields,
            occupancy,
            bounds,
        }
    }

    /// Renders rays; with `rng` the samplers jitter (training).
    pub fn render(
        &self,
        rays: &Rays,
        cfg: &TrainConfig,
        background: Option<&Tensor<2>>,
        rng: Option<&mut StdRng>,
        device: &Device,
    ) -> Rendered {
        match &self.fields {
            Fields::Fast(f) => renderer::render_fast(
                f,
                self.occupancy.as_ref(),
                rays,
                &self.bounds,
                cfg,
                background,
                rng,
                device,
            ),
            Fields::Vanilla(p) => renderer::render_vanilla(
                &p.coarse,
                &p.fine,
                rays,
                &self.bounds,
                cfg,
                background,
                rng,
                device,
            ),
        }
    }

    /// Renders many rays without gradients, in chunks, on the inference device.
    pub fn render_rays(
        &self,
        rays: &Rays,
        cfg: &TrainConfig,
        background: Option<[f32; 3]>,
        device: &Device,
    ) -> ImageRender {
        let plain = device.clone().inner();
        let valid = StaticModel {
            fields: self.fields.valid(),
            occupancy: self.occupancy.clone(),
            bounds: self.bounds.clone(),
        };
        let chunk = match cfg.preset {
            Preset::Fast => 8192,
            Preset::Vanilla => 1024,
        };
        let mut out = ImageRender {
            rgb: Vec::new(),
            depth: Vec::new(),
            opacity: Vec::new(),
            samples_per_ray: 0.0,
        };
        let mut samples = 0usize;
        for start in (0..rays.len()).step_by(chunk) {
            let part = rays.slice(start..(start + chunk).min(rays.len()));
            let bg = background.map(|c| tensor(c.repeat(part.len()).to_vec(), 3, &plain));
            let r = valid.render(&part, cfg, bg.as_ref(), None, &plain);
            samples += r.samples;
            let host = |t: Tensor<2>| t.into_data().try_into_vec_as::<f32>().unwrap_or_default();
            out.rgb.extend(host(r.rgb));
            out.depth.extend(host(r.depth));
            out.opacity.extend(host(r.opacity));
        }
        out.samples_per_ray = samples as f64 / rays.len().max(1) as f64;
        out
    }

    /// Refreshes the occupancy grid (fast preset) from the current densities.
    pub fn update_occupancy(&mut self, step: usize, cfg: &TrainConfig, rng: &mut StdRng, device: &Device) {
        let (Fields::Fast(field), Some(grid)) = (&self.fields, self.occupancy.as_mut()) else {
            return;
        };
        let field = field.valid();
        let plain = device.clone().inner();
        let aabb = self.bounds.aabb;
        let mut density = |p: &[f32]| -> Vec<f32> {
            let mut out = Vec::with_capacity(p.len() / 3);
            for chunk in p.chunks(3 * 65536) {
                let x = tensor(normalize_host(chunk, aabb), 3, &plain);
                out.extend(
                    field
                        .density(x)
                        .into_data()
                        .try_into_vec_as::<f32>()
                        .unwrap_or_default(),
                );
            }
            out
        };
        grid.update(step, cfg.fast.march.step, rng, &mut density);
    }

    /// The hash grid of the fast preset.
    pub fn grid(&self) -> Option<&std::sync::Arc<nerf_core::encoding::HashGrid>> {
        match &self.fields {
            Fields::Fast(f) => Some(&f.grid),
            Fields::Vanilla(_) => None,
        }
    }
}

/// The fast field's configuration from the training config (`extra_outputs` for NSFF reuse).
pub fn fast_config(cfg: &TrainConfig, extra_outputs: usize) -> FastFieldConfig {
    let f = &cfg.fast;
    FastFieldConfig::new(f.grid.clone())
        .with_hidden(f.hidden)
        .with_geo_features(f.geo_features)
        .with_color_hidden(f.color_hidden)
        .with_color_layers(f.color_layers)
        .with_extra_outputs(extra_outputs)
}
