//! Training a static model: random ray batches, the photometric loss, the shared optimiser
//! step, the adaptive ray count and occupancy refreshes. Budgets, logs, checkpoints and resume
//! are the shared loop's (`train_loop.rs`); the model's own state is saved by `checkpoint.rs`.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use nerf_core::metrics::psnr_from_mse;
use nerf_core::occupancy::HullRule;
use nerf_core::profile::span;
use nerf_core::render::Background;
use nerf_data::{Dataset, RayBatch};
use rand::{Rng, SeedableRng, rngs::StdRng};

use crate::checkpoint::{Sections, TrainState, has_checkpoint};
use crate::config::{Preset, TrainConfig};
use crate::error::{ModelError, Result, read_scalar};
use crate::field::{BaseField, FieldModule};
use crate::model::{FieldBuilder, StaticModel, preset_field, scene_bounds};
use crate::optimizer::Optimizer;
use crate::renderer::{Pass, tensor};

pub use crate::train_loop::{CHECKPOINT, METRICS, StepStats};

pub struct Trainer<F: Module = BaseField> {
    pub cfg: TrainConfig,
    pub dataset: Dataset,
    pub model: StaticModel<F>,
    optim: Optimizer,
    build: FieldBuilder<F>,
    pub step: usize,
    pub elapsed: f64,
    n_rays: usize,
    pub run_dir: PathBuf,
    pub device: Device,
}

/// Loads the dataset a config names (printing what the loader decided).
pub fn load_dataset(cfg: &TrainConfig) -> Result<Dataset> {
    let ds = nerf_data::load::load(&cfg.data, &cfg.load)?;
    for note in &ds.notes {
        eprintln!("note: {note}");
    }
    Ok(ds)
}

/// The device a config names, with autodiff when `train`.
pub fn device(cfg: &TrainConfig, train: bool) -> Result<Device> {
    let device = nerf_core::device::parse(&cfg.device).map_err(|msg| ModelError::Device {
        name: cfg.device.clone(),
        msg,
    })?;
    Ok(if train { device.autodiff() } else { device })
}

impl Trainer<BaseField> {
    /// A fresh run of the preset's model. The config should already be adapted to the dataset
    /// ([`TrainConfig::adapt_to`]); user overrides come after that.
    pub fn new(cfg: TrainConfig, dataset: Dataset, run_dir: &Path) -> Result<Self> {
        Trainer::with_field(cfg, dataset, run_dir, preset_field)
    }

    /// Resumes from `run_dir/checkpoint.bin`. `update` may change budgets (steps, time), or
    /// refuse the saved settings with a message (a usage error naming `run_dir`).
    pub fn resume(
        run_dir: &Path,
        update: impl FnOnce(&mut TrainConfig) -> std::result::Result<(), String>,
    ) -> Result<Self> {
        Trainer::resume_with_field(run_dir, update, preset_field)
    }
}

impl<F: FieldModule> Trainer<F> {
    /// A fresh run whose fields `build` makes (any [`Field`]).
    pub fn with_field(
        cfg: TrainConfig,
        dataset: Dataset,
        run_dir: &Path,
        build: FieldBuilder<F>,
    ) -> Result<Self> {
        let device = device(&cfg, true)?;
        std::fs::create_dir_all(run_dir).map_err(|e| nerf_data::DataError::io(run_dir, e))?;
        let mut model = StaticModel::with_field(&cfg, scene_bounds(&dataset), &device, build);
        if let Some(grid) = model.occupancy.as_mut() {
            let carved =
                nerf_core::occupancy::carve_visual_hull(grid, &dataset, &dataset.train, HullRule::AtLeast(2));
            if carved > 0.0 {
                eprintln!(
                    "occupancy grid: {:.1}% of the box carved away by the training silhouettes",
                    100.0 * carved
                );
            }
        }
        let optim = Optimizer::new(&cfg);
        let n_rays = match cfg.preset {
            Preset::Fast => 4096,
            Preset::Vanilla => cfg.vanilla.rays,
        };
        Ok(Trainer {
            cfg,
            dataset,
            model,
            optim,
            build,
            step: 0,
            elapsed: 0.0,
            n_rays,
            run_dir: run_dir.to_path_buf(),
            device,
        })
    }

    /// Resumes a run whose fields `build` makes.
    pub fn resume_with_field(
        run_dir: &Path,
        update: impl FnOnce(&mut TrainConfig) -> std::result::Result<(), String>,
        build: FieldBuilder<F>,
    ) -> Result<Self> {
        let (sections, path) = Sections::read_for_resume(run_dir)?;
        let state: TrainState = sections.json("state", &path)?;
        let mut cfg = state.config.clone();
        // Refused before the dataset is loaded.
        update(&mut cfg).map_err(|m| ModelError::usage(run_dir, m))?;
        let dataset = load_dataset(&cfg)?;
        let mut t = Trainer::with_field(cfg, dataset, run_dir, build)?;
        t.restore(&sections, &path)?;
        Ok(t)
    }

    /// Loads model, optimiser and counters from checkpoint sections.
    fn restore(&mut self, sections: &Sections, path: &Path) -> Result<()> {
        let state: TrainState = sections.json("state", path)?;
        self.model = StaticModel::from_sections(&self.cfg, sections, path, &self.device, self.build)?;
        self.optim = Optimizer::new(&self.cfg);
        self.optim
            .load_bytes(sections.require("optim", path)?)
            .map_err(|e| ModelError::checkpoint(path, format!("cannot load optimiser state: {e}")))?;
        self.step = state.step;
        self.elapsed = state.elapsed;
        self.n_rays = state.n_rays;
        Ok(())
    }

    /// Writes the checkpoint atomically.
    pub fn save(&self) -> Result<()> {
        let path = self.run_dir.join(CHECKPOINT);
        let state = TrainState {
            config: self.cfg.clone(),
            step: self.step,
            elapsed: self.elapsed,
            n_rays: self.n_rays,
        };
        let mut s = Sections::default();
        s.push_json("state", &state, &path)?;
        self.model.write_sections(&mut s, &path)?;
        let optim = self
            .optim
            .to_bytes()
            .map_err(|e| ModelError::checkpoint(&path, format!("cannot save optimiser: {e}")))?;
        s.push("optim", optim);
        s.write_keeping_previous(&path)
    }

    fn seed_for(&self, step: usize) -> u64 {
        self.cfg
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(step as u64)
    }

    /// One optimisation step. `Ok(None)` when the loss was not finite (step skipped).
    pub fn train_step(&mut self) -> Result<Option<StepStats>> {
        let mut rng = StdRng::seed_from_u64(self.seed_for(self.step));
        let precrop = (self.step < self.cfg.precrop_steps).then_some(self.cfg.precrop_frac);
        let batch = span("sample_batch", || {
            self.dataset
                .sample_batch(&self.dataset.train, self.n_rays, precrop, &mut rng)
        });
        let (target, background) = self.targets(&batch, &mut rng);
        let rendered = self
            .model
            .render(&batch.rays, &background, Pass::Train(&mut rng), &self.device)?;
        if rendered.samples == 0 {
            // Nothing to learn from (all rays missed the occupied space); count it as a step.
            self.step += 1;
            return Ok(Some(StepStats {
                loss: f64::NAN,
                psnr: f64::NAN,
                rays: batch.rays.len(),
                samples: 0,
            }));
        }
        let mse = (rendered.out.rgb - target.clone()).powi_scalar(2).mean();
        let loss = match rendered.coarse_rgb {
            Some(c) => mse.clone() + (c - target).powi_scalar(2).mean(),
            None => mse.clone(),
        };
        let mse_value = read_scalar(mse.inner(), "loss")?;
        let loss_value = read_scalar(loss.clone().inner(), "loss")?;
        let host = self.model.host_params();
        if !loss_value.is_finite() {
            self.optim.skip(&host);
            return Ok(None);
        }
        let lr = self.cfg.lr_at(self.cfg.progress(self.step, self.elapsed));
        self.model.fields = self.optim.step(loss, lr, self.model.fields.clone(), &host);
        self.step += 1;
        if self.model.occupancy.as_ref().is_some_and(|o| o.due(self.step)) {
            span("occupancy_update", || {
                self.model.update_occupancy(self.step, &mut rng, &self.device)
            })?;
        }
        let rays = batch.rays.len();
        if self.cfg.preset == Preset::Fast {
            // Keep about `target_samples` samples per step (nerfacc's update_num_rays).
            let f = &self.cfg.fast;
            let want = self.n_rays as f64 * f.target_samples as f64 / rendered.samples.max(1) as f64;
            self.n_rays = (want as usize).clamp(f.min_rays, f.max_rays);
        }
        Ok(Some(StepStats {
            loss: loss_value,
            psnr: psnr_from_mse(mse_value),
            rays,
            samples: rendered.samples,
        }))
    }

    /// Target colours and the background used for them. With random backgrounds (RGBA data),
    /// each ray gets a random colour and its target is recomposited over it.
    fn targets(&self, batch: &RayBatch, rng: &mut StdRng) -> (Tensor<2>, Background) {
        let Some(base) = self.dataset.background else {
            return (tensor(batch.rgb.clone(), 3, &self.device), Background::None);
        };
        if !self.cfg.random_background {
            return (
                tensor(batch.rgb.clone(), 3, &self.device),
                Background::Color(base),
            );
        }
        let alpha = (0..batch.rays.len()).map(|i| {
            let view = &self.dataset.views[batch.view[i] as usize];
            view.alpha.as_ref().map_or(1.0, |a| a[batch.pixel[i] as usize])
        });
        let mut rgb = batch.rgb.clone();
        let bg = random_background(&mut rgb, alpha, base, rng);
        (
            tensor(rgb, 3, &self.device),
            Background::PerRay(tensor(bg, 3, &self.device)),
        )
    }

    /// Trains until the step or time budget is reached. Checkpoints every `checkpoint_every`
    /// steps and at the end; evaluates held-out views every `eval_every_secs` of training.
    pub fn train(&mut self, show_progress: bool) -> Result<()> {
        let header = self.dataset.describe();
        crate::train_loop::train(self, &header, show_progress)
    }

    /// Restores the last checkpoint (or the initial state when there is none).
    pub fn rollback(&mut self) -> Result<()> {
        if has_checkpoint(&self.run_dir) {
            let (sections, path) = Sections::read_for_resume(&self.run_dir)?;
            self.restore(&sections, &path)
        } else {
            self.model =
                StaticModel::with_field(&self.cfg, scene_bounds(&self.dataset), &self.device, self.build);
            self.optim = Optimizer::new(&self.cfg);
            self.step = 0;
            Ok(())
        }
    }
}

impl<F: FieldModule> crate::train_loop::Trainable for Trainer<F> {
    fn config(&self) -> &TrainConfig {
        &self.cfg
    }
    fn run_dir(&self) -> &Path {
        &self.run_dir
    }
    fn step(&self) -> usize {
        self.step
    }
    fn elapsed(&self) -> f64 {
        self.elapsed
    }
    fn add_elapsed(&mut self, secs: f64) {
        self.elapsed += secs;
    }
    fn train_step(&mut self) -> Result<Option<StepStats>> {
        Trainer::train_step(self)
    }
    fn save(&self) -> Result<()> {
        Trainer::save(self)
    }
    fn rollback(&mut self) -> Result<()> {
        Trainer::rollback(self)
    }
    fn quick_eval(&mut self) -> Result<f64> {
        let views = crate::eval::quick_views(&self.dataset);
        Ok(crate::eval::evaluate(
            &self.model,
            &self.dataset,
            &views,
            false,
            None,
            None,
            &self.device,
        )?
        .mean_psnr)
    }
    fn status(&self) -> String {
        self.model.occupancy.as_ref().map_or(String::new(), |o| {
            format!(", {:.1}% occupied", 100.0 * o.occupied_fraction())
        })
    }
}

/// Recomposites target colours `rgb` (`[n * 3]`, composited over `base`) over a random colour per
/// ray, given each pixel's `alpha`, and returns those colours (`[n * 3]`, the per-ray
/// background to render with): a model trained so cannot paint the background into the scene.
pub fn random_background(
    rgb: &mut [f32],
    alpha: impl Iterator<Item = f32>,
    base: [f32; 3],
    rng: &mut impl Rng,
) -> Vec<f32> {
    let mut bg = Vec::with_capacity(rgb.len());
    for (px, a) in rgb.chunks_exact_mut(3).zip(alpha) {
        let c: [f32; 3] = [rng.random(), rng.random(), rng.random()];
        for k in 0..3 {
            px[k] += (1.0 - a) * (c[k] - base[k]);
        }
        bg.extend(c);
    }
    bg
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_background_recomposites_over_the_returned_colours() {
        // Foregrounds composited over a grey base with alphas 0, 0.25, 1: after recompositing
        // each target is a·fg + (1 − a)·c for the colour c returned for its ray (in f64).
        let base = [0.5f32, 0.5, 0.5];
        let fg = [[0.9f64, 0.1, 0.3], [0.2, 0.7, 0.4], [0.6, 0.6, 0.0]];
        let alpha = [0.0f32, 0.25, 1.0];
        let mut rgb: Vec<f32> = (0..3)
            .flat_map(|i| {
                (0..3).map(move |k| {
                    (alpha[i] as f64 * fg[i][k] + (1.0 - alpha[i] as f64) * base[k] as f64) as f32
                })
            })
            .collect();
        let bg = random_background(
            &mut rgb,
            alpha.iter().copied(),
            base,
            &mut StdRng::seed_from_u64(3),
        );
        assert_eq!(bg.len(), 9);
        for i in 0..3 {
            for k in 0..3 {
                let a = alpha[i] as f64;
                let want = a * fg[i][k] + (1.0 - a) * bg[3 * i + k] as f64;
                assert!((rgb[3 * i + k] as f64 - want).abs() < 1e-6, "ray {i} channel {k}");
            }
        }
        // The colours are drawn, not the base.
        assert!(bg.iter().any(|&c| (c - 0.5).abs() > 1e-3));
    }
}
