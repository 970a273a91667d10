//! The training loop for static scenes: random ray batches, Adam with a decaying learning rate,
//! periodic atomic checkpoints, exact resume, non-finite-loss handling, a progress bar, the
//! metrics log and the PSNR-vs-time plot.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bytes, Device, Tensor};
use nerf_core::metrics::psnr_from_mse;
use nerf_core::optim::AdamParams;
use nerf_core::profile::span;
use nerf_data::error::{DataError, Result};
use nerf_data::{Dataset, RayBatch};
use rand::{Rng, SeedableRng, rngs::StdRng};
use serde::{Deserialize, Serialize};

use crate::checkpoint::{Sections, bytes_f32, f32_bytes};
use crate::config::{Preset, TrainConfig};
use crate::model::{Fields, StaticModel, scene_bounds};
use crate::renderer::tensor;

pub use crate::train_loop::{CHECKPOINT, METRICS, StepStats};

/// What a checkpoint records besides the tensors.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainState {
    pub config: TrainConfig,
    pub step: usize,
    /// Seconds of training so far (evaluation pauses excluded).
    pub elapsed: f64,
    /// Current ray count of the adaptive batch (fast preset).
    pub n_rays: usize,
}

pub struct Trainer {
    pub cfg: TrainConfig,
    pub dataset: Dataset,
    pub model: StaticModel,
    optim: ModuleOptimizer,
    pub step: usize,
    pub elapsed: f64,
    n_rays: usize,
    pub run_dir: PathBuf,
    pub device: Device,
}

/// Builds the MLP optimiser for a config.
fn optimizer(cfg: &TrainConfig) -> ModuleOptimizer {
    let mut adam = AdamConfig::new()
        .with_beta_1(cfg.adam_beta1 as f32)
        .with_beta_2(cfg.adam_beta2 as f32)
        .with_epsilon(cfg.adam_eps as f32);
    if cfg.weight_decay > 0.0 {
        adam = adam.with_weight_decay(Some(WeightDecayConfig::new(cfg.weight_decay as f32)));
    }
    adam.init()
}

/// Loads the dataset a config names (printing what the loader decided).
pub fn load_dataset(cfg: &TrainConfig) -> Result<Dataset> {
    let ds = nerf_data::load::load(&cfg.data, &cfg.load)?;
    for note in &ds.notes {
        eprintln!("note: {note}");
    }
    Ok(ds)
}

impl Trainer {
    /// A fresh run in `run_dir`. The config should already be adapted to the dataset
    /// ([`TrainConfig::adapt_to`]); user overrides come after that.
    pub fn new(cfg: TrainConfig, dataset: Dataset, run_dir: &Path) -> Result<Self> {
        let device = nerf_core::device::parse(&cfg.device)
            .map_err(|e| DataError::invalid(run_dir, e))?
            .autodiff();
        std::fs::create_dir_all(run_dir).map_err(|e| DataError::io(run_dir, e))?;
        let mut model = StaticModel::new(&cfg, scene_bounds(&dataset), &device);
        if let Some(grid) = model.occupancy.as_mut() {
            let carved = nerf_core::occupancy::carve_visual_hull(grid, &dataset, &dataset.train);
            if carved > 0.0 {
                eprintln!(
                    "occupancy grid: {:.1}% of the box carved away by the training silhouettes",
                    100.0 * carved
                );
            }
        }
        let optim = optimizer(&cfg);
        let n_rays = match cfg.preset {
            Preset::Fast => 4096,
            Preset::Vanilla => cfg.vanilla.rays,
        };
        Ok(Trainer {
            cfg,
            dataset,
            model,
            optim,
            step: 0,
            elapsed: 0.0,
            n_rays,
            run_dir: run_dir.to_path_buf(),
            device,
        })
    }

    /// Resumes from `run_dir/checkpoint.bin`. `update` may change budgets (steps, time).
    pub fn resume(run_dir: &Path, update: impl FnOnce(&mut TrainConfig)) -> Result<Self> {
        let path = run_dir.join(CHECKPOINT);
        let sections = Sections::read(&path)?;
        let state: TrainState = serde_json::from_slice(sections.require("state", &path)?)
            .map_err(|e| DataError::invalid(&path, format!("bad state: {e}")))?;
        let mut cfg = state.config.clone();
        update(&mut cfg);
        let dataset = load_dataset(&cfg)?;
        let mut t = Trainer::new(cfg, dataset, run_dir)?;
        t.restore(&sections, &path)?;
        Ok(t)
    }

    /// Loads model, optimiser and counters from checkpoint sections.
    fn restore(&mut self, sections: &Sections, path: &Path) -> Result<()> {
        let state: TrainState = serde_json::from_slice(sections.require("state", path)?)
            .map_err(|e| DataError::invalid(path, format!("bad state: {e}")))?;
        self.model = load_model(
            &self.cfg,
            sections,
            path,
            scene_bounds(&self.dataset),
            &self.device,
        )?;
        let optim_bytes = Bytes::from_bytes_vec(sections.require("optim", path)?.to_vec());
        self.optim = optimizer(&self.cfg)
            .from_bytes(optim_bytes)
            .map_err(|e| DataError::invalid(path, format!("cannot load optimiser state: {e:?}")))?;
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
        s.push(
            "state",
            serde_json::to_vec_pretty(&state).map_err(|e| DataError::invalid(&path, e.to_string()))?,
        );
        save_model(&self.model, &mut s, &path)?;
        let optim = self
            .optim
            .into_bytes()
            .map_err(|e| DataError::invalid(&path, format!("cannot save optimiser: {e:?}")))?;
        s.push("optim", optim.to_vec());
        s.write(&path)
    }

    fn seed_for(&self, step: usize) -> u64 {
        self.cfg
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(step as u64)
    }

    /// One optimisation step. Returns `None` when the loss was not finite (step skipped).
    pub fn train_step(&mut self) -> Option<StepStats> {
        let mut rng = StdRng::seed_from_u64(self.seed_for(self.step));
        let precrop = (self.step < self.cfg.precrop_steps).then_some(self.cfg.precrop_frac);
        let batch = span("sample_batch", || {
            self.dataset
                .sample_batch(&self.dataset.train, self.n_rays, precrop, &mut rng)
        });
        let (target, background) = self.targets(&batch, &mut rng);
        let rendered = self.model.render(
            &batch.rays,
            &self.cfg,
            background.as_ref(),
            Some(&mut rng),
            &self.device,
        );
        if rendered.samples == 0 {
            // Nothing to learn from (all rays missed the occupied space); count it as a step.
            self.step += 1;
            return Some(StepStats {
                loss: f64::NAN,
                psnr: f64::NAN,
                rays: batch.rays.len(),
                samples: 0,
            });
        }
        let mse = (rendered.rgb - target.clone()).powi_scalar(2).mean();
        let loss = match rendered.coarse_rgb {
            Some(c) => mse.clone() + (c - target).powi_scalar(2).mean(),
            None => mse.clone(),
        };
        let mse_value = mse.clone().inner().into_scalar::<f32>() as f64;
        let loss_value = loss.clone().inner().into_scalar::<f32>() as f64;
        if !loss_value.is_finite() {
            if let Some(g) = self.model.grid() {
                g.zero_grad();
            }
            return None;
        }
        let grads = span("backward", || loss.backward());
        let grads = GradientsParams::from_grads(grads, &self.model.fields);
        let lr = self.cfg.lr_at(self.cfg.progress(self.step, self.elapsed));
        self.model.fields = span("adam_mlp", || {
            self.optim.step(lr, self.model.fields.clone(), grads)
        });
        if let Some(g) = self.model.grid() {
            let p = AdamParams {
                beta1: self.cfg.adam_beta1,
                beta2: self.cfg.adam_beta2,
                epsilon: self.cfg.adam_eps,
            };
            span("adam_grid", || g.adam_step(&p, lr));
        }
        self.step += 1;
        if self.model.occupancy.as_ref().is_some_and(|o| o.due(self.step)) {
            span("occupancy_update", || {
                self.model
                    .update_occupancy(self.step, &self.cfg, &mut rng, &self.device)
            });
        }
        let rays = batch.rays.len();
        if self.cfg.preset == Preset::Fast {
            // Keep about `target_samples` samples per step (nerfacc's update_num_rays).
            let f = &self.cfg.fast;
            let want = self.n_rays as f64 * f.target_samples as f64 / rendered.samples.max(1) as f64;
            self.n_rays = (want as usize).clamp(f.min_rays, f.max_rays);
        }
        Some(StepStats {
            loss: loss_value,
            psnr: psnr_from_mse(mse_value),
            rays,
            samples: rendered.samples,
        })
    }

    /// Target colours and the background used for them. With random backgrounds (RGBA data),
    /// each ray gets a random colour and its target is recomposited over it.
    fn targets(&self, batch: &RayBatch, rng: &mut StdRng) -> (Tensor<2>, Option<Tensor<2>>) {
        let n = batch.rays.len();
        let dataset_bg = self.dataset.background;
        let Some(base) = dataset_bg else {
            return (tensor(batch.rgb.clone(), 3, &self.device), None);
        };
        if !self.cfg.random_background {
            let bg = tensor(base.repeat(n).to_vec(), 3, &self.device);
            return (tensor(batch.rgb.clone(), 3, &self.device), Some(bg));
        }
        let mut rgb = batch.rgb.clone();
        let mut bg = Vec::with_capacity(3 * n);
        for i in 0..n {
            let view = &self.dataset.views[batch.view[i] as usize];
            let a = view.alpha.as_ref().map_or(1.0, |a| a[batch.pixel[i] as usize]);
            let c: [f32; 3] = [rng.random(), rng.random(), rng.random()];
            for k in 0..3 {
                rgb[3 * i + k] += (1.0 - a) * (c[k] - base[k]);
            }
            bg.extend(c);
        }
        (tensor(rgb, 3, &self.device), Some(tensor(bg, 3, &self.device)))
    }

    /// Trains until the step or time budget is reached. Checkpoints every `checkpoint_every`
    /// steps and at the end; evaluates held-out views every `eval_every_secs` of training.
    pub fn train(&mut self, show_progress: bool) -> Result<()> {
        let header = self.dataset.describe();
        crate::train_loop::train(self, &header, show_progress)
    }

    /// Restores the last checkpoint (or the initial state when there is none).
    pub fn rollback(&mut self) -> Result<()> {
        let path = self.run_dir.join(CHECKPOINT);
        if path.exists() {
            let sections = Sections::read(&path)?;
            self.restore(&sections, &path)
        } else {
            self.model = StaticModel::new(&self.cfg, scene_bounds(&self.dataset), &self.device);
            self.optim = optimizer(&self.cfg);
            self.step = 0;
            Ok(())
        }
    }
}

/// Adds the model's sections (fields, hash grid and its optimiser, occupancy) to a checkpoint.
pub fn save_model(model: &StaticModel, s: &mut Sections, path: &Path) -> Result<()> {
    let bytes = model
        .fields
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| DataError::invalid(path, format!("cannot save model: {e:?}")))?;
    s.push("fields", bytes.to_vec());
    if let Some(grid) = model.grid() {
        s.push("grid", f32_bytes(&grid.table()));
        let (step, m, v) = grid.adam_state();
        let mut adam = step.to_le_bytes().to_vec();
        adam.extend(f32_bytes(&m));
        adam.extend(f32_bytes(&v));
        s.push("grid_adam", adam);
    }
    if let Some(o) = &model.occupancy {
        s.push("occupancy", f32_bytes(o.values()));
        s.push("carved", o.carved().iter().map(|&c| u8::from(c)).collect());
    }
    Ok(())
}

/// Rebuilds a model from checkpoint sections.
pub fn load_model(
    cfg: &TrainConfig,
    s: &Sections,
    path: &Path,
    bounds: crate::renderer::SceneBounds,
    device: &Device,
) -> Result<StaticModel> {
    let mut model = StaticModel::new(cfg, bounds, device);
    let record =
        burn::store::ModuleRecord::from_bytes(Bytes::from_bytes_vec(s.require("fields", path)?.to_vec()))
            .map_err(|e| DataError::invalid(path, format!("cannot read model: {e:?}")))?;
    model.fields = model
        .fields
        .clone()
        .try_load_record(record)
        .map_err(|e| DataError::invalid(path, format!("model does not match its config: {e:?}")))?;
    if let Fields::Fast(f) = &mut model.fields {
        let table = bytes_f32(s.require("grid", path)?);
        if table.len() != f.grid.num_params() {
            return Err(DataError::invalid(
                path,
                format!(
                    "hash table has {} values, config needs {}",
                    table.len(),
                    f.grid.num_params()
                ),
            ));
        }
        let grid = nerf_core::encoding::HashGrid::with_table(f.grid.config.clone(), table);
        let adam = s.require("grid_adam", path)?;
        if adam.len() != 8 + 8 * grid.num_params() {
            return Err(DataError::invalid(
                path,
                "hash-grid optimiser state has the wrong size",
            ));
        }
        let n = grid.num_params();
        let step = u64::from_le_bytes(adam[..8].try_into().unwrap_or_default());
        grid.set_adam_state(
            step,
            bytes_f32(&adam[8..8 + 4 * n]),
            bytes_f32(&adam[8 + 4 * n..]),
        );
        f.grid = grid;
    }
    if let (Some(o), Some(values)) = (model.occupancy.as_mut(), s.get("occupancy")) {
        let values = bytes_f32(values);
        if values.len() != o.num_cells() {
            return Err(DataError::invalid(path, "occupancy grid has the wrong size"));
        }
        o.set_values(values);
        if let Some(carved) = s.get("carved") {
            if carved.len() != o.num_cells() {
                return Err(DataError::invalid(
                    path,
                    "occupancy carve mask has the wrong size",
                ));
            }
            o.set_carved(carved.iter().map(|&c| c != 0).collect());
        }
    }
    Ok(model)
}

impl crate::train_loop::Trainable for Trainer {
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
    fn train_step(&mut self) -> Option<StepStats> {
        Trainer::train_step(self)
    }
    fn save(&self) -> Result<()> {
        Trainer::save(self)
    }
    fn rollback(&mut self) -> Result<()> {
        Trainer::rollback(self)
    }
    fn quick_eval(&mut self) -> Result<f64> {
        Ok(crate::eval::evaluate(self, &crate::eval::quick_views(&self.dataset), false).mean_psnr)
    }
    fn status(&self) -> String {
        self.model.occupancy.as_ref().map_or(String::new(), |o| {
            format!(", {:.1}% occupied", 100.0 * o.occupied_fraction())
        })
    }
}
