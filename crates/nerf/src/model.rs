//! The static model: a field (and a proposal field for hierarchical sampling), the occupancy
//! grid, the scene bounds and how samples are placed. It renders (training and inference) and
//! refreshes its occupancy grid; it is saved and loaded by `checkpoint.rs`, trained by
//! `trainer.rs`. Generic over the field: any [`Field`] that is a burn module works.

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::Device;
use nerf_core::encoding::HashGrid;
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::rays::Rays;
use nerf_core::render::Background;
use nerf_data::{Dataset, SceneKind};
use rand::rngs::StdRng;

use crate::config::{Preset, TrainConfig};
use crate::error::{ModelError, read_back};
use crate::field::{BaseField, FastFieldConfig, FieldModule, VanillaFieldConfig};
use crate::renderer::{self, Pass, Rendered, Sampling, SceneBounds, Target, tensor};

/// The burn modules of a model (what the optimiser updates and checkpoints store).
#[derive(Module, Debug)]
pub struct StaticFields<F: Module> {
    pub field: F,
    /// The coarse network of hierarchical sampling.
    pub proposal: Option<F>,
}

/// Fields plus the non-learned state rendering needs.
#[derive(Debug)]
pub struct StaticModel<F: Module = BaseField> {
    pub fields: StaticFields<F>,
    pub occupancy: Option<OccupancyGrid>,
    pub bounds: SceneBounds,
    pub sampling: Sampling,
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

/// The preset's field for `cfg`, over `aabb`, with `extra_outputs` raw extra outputs (NSFF's
/// blend weight). MLP initialisation draws from the device's RNG: seed it first.
pub fn base_field(
    cfg: &TrainConfig,
    aabb: [[f32; 3]; 2],
    extra_outputs: usize,
    device: &Device,
) -> BaseField {
    match cfg.preset {
        Preset::Fast => BaseField::Fast(fast_config(cfg, aabb, extra_outputs).init(device, cfg.seed)),
        Preset::Vanilla => BaseField::Vanilla(
            VanillaFieldConfig::new()
                .with_width(cfg.vanilla.width)
                .with_depth(cfg.vanilla.depth)
                .with_extra_outputs(extra_outputs)
                .init(device),
        ),
    }
}

/// The fast field's configuration from the training config.
pub fn fast_config(cfg: &TrainConfig, aabb: [[f32; 3]; 2], extra_outputs: usize) -> FastFieldConfig {
    let f = &cfg.fast;
    FastFieldConfig::new(f.grid.clone(), aabb)
        .with_hidden(f.hidden)
        .with_geo_features(f.geo_features)
        .with_color_hidden(f.color_hidden)
        .with_color_layers(f.color_layers)
        .with_extra_outputs(extra_outputs)
}

impl StaticModel<BaseField> {
    /// A freshly initialised model of `cfg`'s preset.
    pub fn new(cfg: &TrainConfig, bounds: SceneBounds, device: &Device) -> Self {
        StaticModel::with_field(cfg, bounds, device, preset_field)
    }
}

/// The preset's field over the scene box: the [`FieldBuilder`] of the `nerf` binary's model.
pub fn preset_field(cfg: &TrainConfig, bounds: &SceneBounds, device: &Device) -> BaseField {
    base_field(cfg, bounds.aabb, 0, device)
}

/// Builds a model's field from the config (called once per field: the vanilla preset's
/// proposal field is a second call).
pub type FieldBuilder<F> = fn(&TrainConfig, &SceneBounds, &Device) -> F;

impl<F: FieldModule> StaticModel<F> {
    /// A freshly initialised model with fields made by `build`.
    pub fn with_field(
        cfg: &TrainConfig,
        bounds: SceneBounds,
        device: &Device,
        build: FieldBuilder<F>,
    ) -> Self {
        let sampling = Sampling::from_config(cfg);
        let fields = nerf_core::device::seeded(device, cfg.seed, || {
            // The proposal (coarse) field is built, and so drawn, first.
            let proposal =
                matches!(sampling, Sampling::Hierarchical { .. }).then(|| build(cfg, &bounds, device));
            let field = build(cfg, &bounds, device);
            StaticFields { field, proposal }
        });
        let occupancy = (matches!(sampling, Sampling::March { .. }) && cfg.fast.use_occupancy)
            .then(|| OccupancyGrid::new(cfg.fast.occupancy.clone(), bounds.aabb));
        StaticModel {
            fields,
            occupancy,
            bounds,
            sampling,
        }
    }

    /// Renders rays (differentiably on an autodiff device).
    pub fn render(
        &self,
        rays: &Rays,
        background: &Background,
        pass: Pass<'_>,
        device: &Device,
    ) -> Result<Rendered, ModelError> {
        let target = Target {
            rays,
            bounds: &self.bounds,
            background,
            device,
        };
        match (&self.sampling, &self.fields.proposal) {
            (
                Sampling::Hierarchical {
                    coarse,
                    fine,
                    spacing,
                    raw_noise_std,
                },
                Some(proposal),
            ) => renderer::render_hierarchical(
                proposal,
                &self.fields.field,
                (*coarse, *fine, *spacing, *raw_noise_std),
                target,
                pass,
            ),
            (
                Sampling::March {
                    march,
                    early_termination,
                    train_early_termination,
                    stop_eps,
                },
                _,
            ) => {
                let early = if pass.is_train() {
                    *train_early_termination
                } else {
                    *early_termination
                };
                renderer::render_march(
                    &self.fields.field,
                    self.occupancy.as_ref(),
                    (march, early, *stop_eps),
                    target,
                    pass,
                )
            }
            (Sampling::Hierarchical { .. }, None) => {
                unreachable!("hierarchical sampling always builds a proposal field")
            }
        }
    }

    /// Renders many rays without gradients, in chunks, on the inference device.
    pub fn render_rays(
        &self,
        rays: &Rays,
        background: Option<[f32; 3]>,
        device: &Device,
    ) -> Result<ImageRender, ModelError> {
        let plain = device.clone().inner();
        let valid = StaticModel {
            fields: self.fields.valid(),
            occupancy: self.occupancy.clone(),
            bounds: self.bounds.clone(),
            sampling: self.sampling.clone(),
        };
        let chunk = match self.sampling {
            Sampling::March { .. } => 8192,
            Sampling::Hierarchical { .. } => 1024,
        };
        let mut out = ImageRender {
            rgb: Vec::new(),
            depth: Vec::new(),
            opacity: Vec::new(),
            samples_per_ray: 0.0,
        };
        let mut samples = 0usize;
        let bg = Background::from_option(background);
        for start in (0..rays.len()).step_by(chunk) {
            let part = rays.slice(start..(start + chunk).min(rays.len()));
            let r = valid.render(&part, &bg, Pass::Infer, &plain)?;
            samples += r.samples;
            out.rgb.extend(read_back(r.out.rgb, "rendered colour")?);
            out.depth.extend(read_back(r.out.depth, "rendered depth")?);
            out.opacity.extend(read_back(r.out.opacity, "rendered opacity")?);
        }
        out.samples_per_ray = samples as f64 / rays.len().max(1) as f64;
        Ok(out)
    }

    /// Refreshes the occupancy grid from the current densities (marching only).
    pub fn update_occupancy(
        &mut self,
        step: usize,
        rng: &mut StdRng,
        device: &Device,
    ) -> Result<(), ModelError> {
        let (Sampling::March { march, .. }, Some(grid)) = (&self.sampling, self.occupancy.as_mut()) else {
            return Ok(());
        };
        let field = self.fields.field.valid();
        let plain = device.clone().inner();
        let mut failed = None;
        let mut density = |p: &[f32]| -> Vec<f32> {
            let mut out = Vec::with_capacity(p.len() / 3);
            for chunk in p.chunks(3 * 65536) {
                let sigma = field.density(tensor(chunk.to_vec(), 3, &plain), None).sigma;
                match read_back(sigma, "occupancy density") {
                    Ok(v) => out.extend(v),
                    Err(e) => {
                        failed = Some(e);
                        out.resize(out.len() + chunk.len() / 3, 0.0);
                    }
                }
            }
            out
        };
        grid.update(step, march.step, rng, &mut density);
        failed.map_or(Ok(()), Err)
    }

    /// Host-side parameters of every field (hash tables), in a fixed order.
    pub fn host_params(&self) -> Vec<Arc<HashGrid>> {
        self.fields.host_params()
    }
}

impl<F: FieldModule> StaticFields<F> {
    pub fn host_params(&self) -> Vec<Arc<HashGrid>> {
        let mut out = self.field.host_params();
        if let Some(p) = &self.proposal {
            out.extend(p.host_params());
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::readback::{assert_close, host};
    use nerf_data::{Camera, Intrinsics, Pose};

    /// The differentiable render the trainer calls (autodiff device, whole batch) and the
    /// inference render (`valid()` module, plain device, chunks) give the same pixels for the
    /// same parameters and unjittered samples, for both presets.
    #[test]
    fn training_and_inference_renders_agree() {
        let pose = Pose::look_at([0.4, -3.5, 1.0], [0.0; 3], [0.0, 0.0, 1.0]);
        let camera = Camera::new(Intrinsics::centered(14.0, 12, 10), pose);
        let rays = nerf_data::rays::camera_rays(&camera);
        let bg = [0.2f32, 0.4, 0.6];
        for preset in [Preset::Fast, Preset::Vanilla] {
            let mut cfg = TrainConfig::new(preset, "unused".into(), Default::default());
            cfg.vanilla.width = 32;
            cfg.vanilla.depth = 3;
            cfg.vanilla.coarse_samples = 16;
            cfg.vanilla.fine_samples = 16;
            let bounds = SceneBounds::object(2.0, 6.0, [[-1.5; 3], [1.5; 3]]);
            let dev = Device::flex().autodiff();
            let model = StaticModel::new(&cfg, bounds, &dev);
            let train = model
                .render(&rays, &Background::Color(bg), Pass::Infer, &dev)
                .unwrap();
            let infer = model.render_rays(&rays, Some(bg), &dev).unwrap();
            let opacity = host(train.out.opacity.clone());
            let mean = opacity.iter().sum::<f32>() / opacity.len() as f32;
            assert!(
                mean > 0.05,
                "{preset:?}: the untrained field must absorb light ({mean})"
            );
            for (name, a, b) in [
                ("rgb", host(train.out.rgb), infer.rgb),
                ("depth", host(train.out.depth), infer.depth),
                ("opacity", opacity, infer.opacity),
            ] {
                assert_close(&format!("{preset:?} {name}"), &a, &b, 1e-5);
            }
        }
    }

    /// Inference's early ray termination queries the field once ([`Field::query_kept`]) and
    /// renders as the two-pass definition does: densities at every marched sample, the samples
    /// reached before the transmittance falls below `stop_eps`, and a fresh query of those.
    #[test]
    fn early_termination_in_one_pass_renders_as_two_passes() {
        use nerf_core::composite;
        use nerf_core::field::{Field, FieldQuery};
        use nerf_core::render::{Component, RenderOptions};
        let pose = Pose::look_at([0.4, -3.5, 1.0], [0.0; 3], [0.0, 0.0, 1.0]);
        let camera = Camera::new(Intrinsics::centered(14.0, 12, 10), pose);
        let rays = nerf_data::rays::camera_rays(&camera);
        let bg = Background::Color([0.2f32, 0.4, 0.6]);
        let mut cfg = TrainConfig::new(Preset::Fast, "unused".into(), Default::default());
        // An untrained field is faint: a loose threshold so that rays do stop.
        cfg.fast.stop_eps = 0.7;
        let dev = Device::flex();
        let bounds = SceneBounds::object(2.0, 6.0, [[-1.5; 3], [1.5; 3]]);
        let model = StaticModel::new(&cfg, bounds.clone(), &dev);
        // Spread tables, so that a wrong row would show.
        model.fields.field.host_params().iter().for_each(|g| g.spread());
        let got = model.render(&rays, &bg, Pass::Infer, &dev).unwrap();

        let field = &model.fields.field;
        let march = &cfg.fast.march;
        let samples = nerf_core::sampler::march(
            &rays,
            bounds.aabb,
            bounds.near,
            bounds.far,
            model.occupancy.as_ref(),
            march,
            None::<&mut StdRng>,
        );
        let sigma = crate::renderer::density_host(field, &samples.positions(&rays), &dev).unwrap();
        let options = RenderOptions {
            open_far: false,
            stop_eps: cfg.fast.stop_eps,
        };
        let alive = composite::alive(&sigma, &samples.layout(&rays, false), options.stop_eps);
        let reached = samples.filter(&alive);
        assert!(
            reached.num_samples() < samples.num_samples() && reached.num_samples() > 0,
            "rays must stop early for the check to mean anything ({} of {})",
            reached.num_samples(),
            samples.num_samples()
        );
        let dirs = reached.per_sample3(&rays.viewdirs());
        let q = field.query(FieldQuery::new(
            crate::renderer::tensor(reached.positions(&rays), 3, &dev),
            &dirs,
        ));
        let want = nerf_core::render::render(
            &rays,
            &reached,
            &[Component::new(q.sigma, q.rgb)],
            &bg,
            options,
            &dev,
        );
        assert_eq!(got.samples, reached.num_samples(), "samples evaluated");
        for (name, a, b) in [
            ("rgb", host(got.out.rgb), host(want.rgb)),
            ("depth", host(got.out.depth), host(want.depth)),
            ("opacity", host(got.out.opacity), host(want.opacity)),
        ] {
            assert_close(name, &a, &b, 1e-5);
        }
    }
}
