//! NSFF training: one frame per step, the combined, dynamic and warped renders, and the
//! scene-flow losses. Bookkeeping (checkpoints, metrics log, progress, plot) is the static
//! pipeline's.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bytes, Device, Tensor};
use nerf::checkpoint::{Sections, bytes_f32, f32_bytes};
use nerf::config::Preset;
use nerf::model::scene_bounds;
use nerf::renderer::{SceneBounds, tensor};
use nerf_core::composite::{RayLayout, composite};
use nerf_core::metrics::psnr_from_mse;
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::optim::AdamParams;
use nerf_core::profile::span;
use nerf_data::error::{DataError, Result};
use rand::{Rng, SeedableRng, rngs::StdRng};
use serde::{Deserialize, Serialize};

use crate::config::{DynamicMode, NsffConfig};
use crate::geometry;
use crate::losses::{entropy, mse, scale_shift_invariant, wmae, wmse};
use crate::model::{Field, NsffFields, occupancy_density, query_dynamic, query_static};
use crate::render::sample_rays;
use crate::video::{Video, prepare};

pub use nerf::train_loop::{CHECKPOINT, METRICS, StepStats};

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct NsffState {
    pub config: NsffConfig,
    pub step: usize,
    pub elapsed: f64,
    /// Whether the model has a dynamic field (decided once, from the video's motion).
    pub dynamic: bool,
    pub moving_fraction: f32,
    /// Rays per step (adapted to keep the sample count near the static pipeline's target).
    #[serde(default)]
    pub n_rays: usize,
}

pub struct NsffTrainer {
    pub cfg: NsffConfig,
    pub video: Video,
    pub fields: NsffFields,
    optim: ModuleOptimizer,
    pub step: usize,
    pub elapsed: f64,
    pub run_dir: PathBuf,
    pub device: Device,
    pub bounds: SceneBounds,
    /// Occupancy grid over space, occupied where the static field or the dynamic field at any
    /// time has density (object scenes with the fast preset; NDC scenes sample stratified).
    pub occupancy: Option<OccupancyGrid>,
    n_rays: usize,
}

fn optimizer(cfg: &NsffConfig) -> ModuleOptimizer {
    let b = &cfg.base;
    let mut adam = AdamConfig::new()
        .with_beta_1(b.adam_beta1 as f32)
        .with_beta_2(b.adam_beta2 as f32)
        .with_epsilon(b.adam_eps as f32);
    if b.weight_decay > 0.0 {
        adam = adam.with_weight_decay(Some(WeightDecayConfig::new(b.weight_decay as f32)));
    }
    adam.init()
}

/// Loads the video dataset a config names and prepares flows and the motion decision.
pub fn load_video(cfg: &NsffConfig, run_dir: &Path, quiet: bool) -> Result<Video> {
    let dataset = nerf_data::load::load_video(&cfg.base.data, &cfg.base.load)?;
    for note in &dataset.notes {
        if !quiet {
            eprintln!("note: {note}");
        }
    }
    prepare(
        dataset,
        &run_dir.join("flow_cache"),
        (cfg.motion_threshold_px, cfg.mask_threshold_px),
        quiet,
    )
}

impl NsffTrainer {
    /// A fresh run. `cfg` should be adapted to the video already.
    pub fn new(cfg: NsffConfig, video: Video, run_dir: &Path) -> Result<Self> {
        let device = nerf_core::device::parse(&cfg.base.device)
            .map_err(|e| DataError::invalid(run_dir, e))?
            .autodiff();
        std::fs::create_dir_all(run_dir).map_err(|e| DataError::io(run_dir, e))?;
        let with_dynamic = match cfg.dynamic {
            DynamicMode::On => true,
            DynamicMode::Off => false,
            DynamicMode::Auto => video.has_motion,
        };
        let fields = NsffFields::new(&cfg, with_dynamic, &device);
        let optim = optimizer(&cfg);
        let bounds = scene_bounds(&video.dataset);
        let f = &cfg.base.fast;
        let mut occupancy = (cfg.base.preset == Preset::Fast && f.use_occupancy && !bounds.open_far)
            .then(|| OccupancyGrid::new(f.occupancy.clone(), bounds.aabb));
        if let (Some(grid), false) = (occupancy.as_mut(), with_dynamic) {
            // A static scene is consistent with every view, so its visual hull is valid, as in
            // the static pipeline. (With independent motion a view's silhouette only bounds the
            // scene at that view's time, so dynamic scenes are not carved.)
            let carved = nerf_core::occupancy::carve_visual_hull(grid, &video.dataset, &video.frames);
            if carved > 0.0 {
                eprintln!(
                    "occupancy grid: {:.1}% of the box carved away by the training silhouettes",
                    100.0 * carved
                );
            }
        }
        let n_rays = cfg.rays;
        Ok(NsffTrainer {
            cfg,
            video,
            fields,
            optim,
            step: 0,
            elapsed: 0.0,
            run_dir: run_dir.to_path_buf(),
            device,
            bounds,
            occupancy,
            n_rays,
        })
    }

    pub fn has_dynamic(&self) -> bool {
        self.fields.dynamic.is_some()
    }

    /// Resumes from `run_dir/checkpoint.bin`; `update` may change budgets.
    pub fn resume(run_dir: &Path, update: impl FnOnce(&mut NsffConfig), quiet: bool) -> Result<Self> {
        let path = run_dir.join(CHECKPOINT);
        let s = Sections::read(&path)?;
        let state: NsffState = serde_json::from_slice(s.require("state", &path)?)
            .map_err(|e| DataError::invalid(&path, format!("bad state: {e}")))?;
        let mut cfg = state.config.clone();
        update(&mut cfg);
        let video = load_video(&cfg, run_dir, quiet)?;
        cfg.dynamic = if state.dynamic {
            DynamicMode::On
        } else {
            DynamicMode::Off
        };
        let mut t = NsffTrainer::new(cfg, video, run_dir)?;
        t.restore(&s, &path)?;
        Ok(t)
    }

    fn restore(&mut self, s: &Sections, path: &Path) -> Result<()> {
        let state: NsffState = serde_json::from_slice(s.require("state", path)?)
            .map_err(|e| DataError::invalid(path, format!("bad state: {e}")))?;
        let record =
            burn::store::ModuleRecord::from_bytes(Bytes::from_bytes_vec(s.require("fields", path)?.to_vec()))
                .map_err(|e| DataError::invalid(path, format!("cannot read model: {e:?}")))?;
        let fields = NsffFields::new(&self.cfg, state.dynamic, &self.device);
        let mut fields = fields
            .try_load_record(record)
            .map_err(|e| DataError::invalid(path, format!("model does not match its config: {e:?}")))?;
        for (k, field) in [Some(&mut fields.static_field), fields.dynamic.as_mut()]
            .into_iter()
            .flatten()
            .enumerate()
        {
            if let Field::Fast(f) = field {
                let table = bytes_f32(s.require(&format!("grid{k}"), path)?);
                if table.len() != f.grid.num_params() {
                    return Err(DataError::invalid(
                        path,
                        format!("hash table {k} has the wrong size"),
                    ));
                }
                let grid = nerf_core::encoding::HashGrid::with_table(f.grid.config.clone(), table);
                let adam = s.require(&format!("grid{k}_adam"), path)?;
                let n = grid.num_params();
                if adam.len() != 8 + 8 * n {
                    return Err(DataError::invalid(
                        path,
                        format!("hash-grid {k} optimiser state has the wrong size"),
                    ));
                }
                let step = u64::from_le_bytes(adam[..8].try_into().unwrap_or_default());
                grid.set_adam_state(
                    step,
                    bytes_f32(&adam[8..8 + 4 * n]),
                    bytes_f32(&adam[8 + 4 * n..]),
                );
                f.grid = grid;
            }
        }
        self.fields = fields;
        self.optim = optimizer(&self.cfg)
            .from_bytes(Bytes::from_bytes_vec(s.require("optim", path)?.to_vec()))
            .map_err(|e| DataError::invalid(path, format!("cannot load optimiser state: {e:?}")))?;
        if let (Some(o), Some(values)) = (self.occupancy.as_mut(), s.get("occupancy")) {
            let values = bytes_f32(values);
            if values.len() != o.num_cells() {
                return Err(DataError::invalid(path, "occupancy grid has the wrong size"));
            }
            o.set_values(values);
        }
        self.step = state.step;
        self.elapsed = state.elapsed;
        if state.n_rays > 0 {
            self.n_rays = state.n_rays;
        }
        Ok(())
    }

    pub fn save(&self) -> Result<()> {
        let path = self.run_dir.join(CHECKPOINT);
        let state = NsffState {
            config: self.cfg.clone(),
            step: self.step,
            elapsed: self.elapsed,
            dynamic: self.has_dynamic(),
            moving_fraction: self.video.moving_fraction,
            n_rays: self.n_rays,
        };
        let mut s = Sections::default();
        s.push(
            "state",
            serde_json::to_vec_pretty(&state).map_err(|e| DataError::invalid(&path, e.to_string()))?,
        );
        let bytes = self
            .fields
            .clone()
            .into_record()
            .into_bytes()
            .map_err(|e| DataError::invalid(&path, format!("cannot save model: {e:?}")))?;
        s.push("fields", bytes.to_vec());
        for (k, grid) in self.fields.grids().iter().enumerate() {
            s.push(&format!("grid{k}"), f32_bytes(&grid.table()));
            let (step, m, v) = grid.adam_state();
            let mut adam = step.to_le_bytes().to_vec();
            adam.extend(f32_bytes(&m));
            adam.extend(f32_bytes(&v));
            s.push(&format!("grid{k}_adam"), adam);
        }
        if let Some(o) = &self.occupancy {
            s.push("occupancy", f32_bytes(o.values()));
        }
        let optim = self
            .optim
            .into_bytes()
            .map_err(|e| DataError::invalid(&path, format!("cannot save optimiser: {e:?}")))?;
        s.push("optim", optim.to_vec());
        s.write(&path)
    }

    /// One step on a random frame. `None` when the loss was not finite (step skipped).
    pub fn train_step(&mut self) -> Option<StepStats> {
        let seed = self
            .cfg
            .base
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(self.step as u64);
        let mut rng = StdRng::seed_from_u64(seed);
        let Some((loss, stats)) = span("nsff_step_loss", || self.step_loss(&mut rng)) else {
            // Every ray missed the occupied space: nothing to learn from, count the step.
            self.step += 1;
            return Some(StepStats {
                loss: f64::NAN,
                psnr: f64::NAN,
                ..StepStats::default()
            });
        };
        let value = loss.clone().inner().into_scalar::<f32>() as f64;
        if !value.is_finite() {
            for g in self.fields.grids() {
                g.zero_grad();
            }
            return None;
        }
        let grads = span("nsff_backward", || loss.backward());
        let grads = GradientsParams::from_grads(grads, &self.fields);
        let lr = self
            .cfg
            .base
            .lr_at(self.cfg.base.progress(self.step, self.elapsed));
        self.fields = span("nsff_optimizer", || {
            self.optim.step(lr, self.fields.clone(), grads)
        });
        let p = AdamParams {
            beta1: self.cfg.base.adam_beta1,
            beta2: self.cfg.base.adam_beta2,
            epsilon: self.cfg.base.adam_eps,
        };
        span("nsff_grid_adam", || {
            for g in self.fields.grids() {
                g.adam_step(&p, lr);
            }
        });
        self.step += 1;
        if self.occupancy.as_ref().is_some_and(|o| o.due(self.step)) {
            span("nsff_occupancy", || self.update_occupancy(&mut rng));
        }
        if self.occupancy.is_some() {
            // Keep about `target_samples` samples per step, as the static trainer does.
            let f = &self.cfg.base.fast;
            let want = self.n_rays as f64 * f.target_samples as f64 / stats.samples.max(1) as f64;
            self.n_rays = (want as usize).clamp(self.cfg.min_rays, self.cfg.rays.max(self.cfg.min_rays));
        }
        Some(StepStats { loss: value, ..stats })
    }

    /// Refreshes the occupancy grid: each refreshed point takes the density the combined render
    /// sees, with the dynamic field at a random training time (its own per point). One time draw per
    /// refresh is enough: a cell the moving object crosses stays above the threshold for many
    /// refreshes once seen (values decay by 5 % per refresh), and the refresh was a fifth of an
    /// NSFF step's time with four draws.
    fn update_occupancy(&mut self, rng: &mut StdRng) {
        let Some(grid) = self.occupancy.as_mut() else {
            return;
        };
        let fields = self.fields.valid();
        let plain = self.device.clone().inner();
        let (aabb, times) = (self.bounds.aabb, &self.video.times);
        let step_size = self.cfg.base.fast.march.step;
        let mut density = |p: &[f32]| -> Vec<f32> {
            let n = p.len() / 3;
            let t: Vec<f32> = (0..n).map(|_| times[rng.random_range(0..times.len())]).collect();
            occupancy_density(&fields, p, &t, aabb, &plain).unwrap_or_default()
        };
        let mut grid_rng = StdRng::seed_from_u64(self.step as u64);
        grid.update(self.step, step_size, &mut grid_rng, &mut density);
    }

    /// Weight multiplier of the decaying terms (optical flow, depth) now.
    fn decay(&self) -> f64 {
        let progress = self.cfg.base.progress(self.step, self.elapsed);
        self.cfg.decay(self.step, progress)
    }

    /// The loss of one step (NSFF HEAD's terms, method.md §4.6); `None` when no ray has samples.
    fn step_loss(&self, rng: &mut StdRng) -> Option<(Tensor<1>, StepStats)> {
        let dev = &self.device;
        let v = &self.video;
        let ds = &v.dataset;
        let n_frames = v.frames.len();
        let k = rng.random_range(0..n_frames);
        let view = &ds.views[v.frames[k]];
        let cam = view.camera;
        let (w, h) = (view.image.width, view.image.height);
        let n_uniform = self.n_rays;
        let mut pixels: Vec<u32> = (0..n_uniform).map(|_| rng.random_range(0..w * h)).collect();
        let Some(dynamic) = &self.fields.dynamic else {
            // No independent motion: the static pipeline's photometric loss only.
            let rays = ds.rays_for(&cam, pixels.iter().copied());
            let target = pixel_colours(view, &pixels);
            let (loss, m, s_n) = self.static_photometric(&rays, target, rng)?;
            return Some((loss, stats(m, rays.len(), s_n)));
        };
        if self.step < self.cfg.decay_steps {
            // Hard mining (NSFF): extra rays where the flow says something moves.
            let moving = &v.moving_pixels[k];
            if !moving.is_empty() {
                let extra = (n_uniform as f32 * self.cfg.hard_fraction).round() as usize;
                pixels.extend((0..extra).map(|_| moving[rng.random_range(0..moving.len())]));
            }
        }
        let rays = ds.rays_for(&cam, pixels.iter().copied());
        let target = tensor(pixel_colours(view, &pixels), 3, dev);
        let march = self.occupancy.as_ref().map(|g| (g, &self.cfg.base.fast.march));
        let clip = !self.bounds.open_far;
        let samples = sample_rays(&rays, &self.bounds, self.cfg.samples, clip, march, Some(rng));
        let s_n = samples.num_samples();
        if s_n == 0 {
            return None;
        }
        let layout = samples.layout(&rays, self.bounds.open_far && march.is_none());
        let x = tensor(samples.positions(&rays), 3, dev);
        let dirs = samples.per_sample3(&rays.viewdirs());
        let t_col = tensor(samples.t.clone(), 1, dev);
        let bg = ds
            .background
            .map(|c| tensor(c.repeat(rays.len()).to_vec(), 3, dev));
        let with_bg = |rgb: Tensor<2>, acc: Tensor<2>| match &bg {
            Some(b) => rgb + (acc.neg() + 1.0) * b.clone(),
            None => rgb,
        };
        let r_n = rays.len();
        let wts = &self.cfg.weights;
        let decay = self.decay();
        let st = query_static(&self.fields.static_field, x.clone(), &dirs, self.bounds.aabb);
        let flow_scale = self.cfg.flow_scale;
        let dy = query_dynamic(
            dynamic,
            x.clone(),
            v.times[k],
            &dirs,
            self.bounds.aabb,
            flow_scale,
        );

        // Combined render: the static and dynamic components blended per sample by b = b_s·g.
        let blend = st.blend.clone() * dy.gate.clone();
        let sigma2 = Tensor::cat(vec![st.sigma.clone(), dy.sigma.clone()], 1);
        let feats2 = Tensor::cat(
            vec![st.rgb.clone(), t_col.clone(), dy.rgb.clone(), t_col.clone()],
            1,
        );
        let blend2 = Tensor::cat(vec![blend.clone().neg() + 1.0, blend.clone()], 1);
        let cb = composite(sigma2, feats2, Some(blend2), &layout, 0.0);
        let rgb_cb = with_bg(cb.clone().slice([0..r_n, 0..3]), cb.slice([0..r_n, 4..5]));
        // Over the uniformly drawn rays only, as NSFF: the mined ones would bias the blend.
        let mse_cb = mse(
            rgb_cb.slice([0..n_uniform, 0..3]),
            target.clone().slice([0..n_uniform, 0..3]),
        );
        let mut loss = mse_cb.clone();
        if wts.hidden > 0.0 {
            // Dynamic density that this frame's camera cannot see at this time (behind what the
            // combined render shows) is constrained by nothing but this term: without it the
            // dynamic field fills the space behind a moving object with whatever its MLP makes
            // up, and novel views look into it. The penalty reaches the density and the time
            // gate, not b_s: b_s is time-independent, and points hidden at this time are the
            // object's visible surface at others.
            let hidden = hidden_weights(
                &host_values(&st.sigma),
                &host_values(&dy.sigma),
                &host_values(&blend),
                &layout,
            );
            let fixed = host_values(&st.blend)
                .iter()
                .zip(hidden)
                .map(|(b, h)| b * h)
                .collect();
            let depth = (dy.gate.clone() * dy.sigma.clone() * tensor(fixed, 1, dev)).sum() / r_n as f32;
            loss = loss + depth * wts.hidden;
        }

        // Dynamic-only render, also integrating the flowed points (for the optical-flow term)
        // and a disparity-like value per sample (for the depth prior).
        let x_next = x.clone() + dy.flow_next.clone();
        let x_prev = x.clone() + dy.flow_prev.clone();
        let disp_col = tensor(sample_disparity(&samples.t, ds.ndc.is_some()), 1, dev);
        let feats_d = Tensor::cat(
            vec![
                dy.rgb.clone(),
                t_col.clone(),
                x_next.clone(),
                x_prev.clone(),
                disp_col,
            ],
            1,
        );
        let d = composite(dy.sigma.clone(), feats_d, None, &layout, 0.0);
        let acc_d = d.clone().slice([0..r_n, 11..12]);
        let rgb_d = with_bg(d.clone().slice([0..r_n, 0..3]), acc_d.clone());
        loss = loss + mse(rgb_d, target.clone()) * wts.dynamic_photo;
        if let (Some(disp), true) = (&v.disparity[k], wts.depth > 0.0) {
            // Monocular disparity, up to an unknown scale and shift per frame.
            let prior: Vec<f32> = pixels.iter().map(|&p| disp[p as usize]).collect();
            let rendered = d.clone().slice([0..r_n, 10..11]);
            if let Some(l) = scale_shift_invariant(rendered, &prior) {
                loss = loss + l * (wts.depth * decay);
            }
        }

        // Neighbouring frames: warped renders, disocclusion weights, cycle and flow terms.
        let neighbours = [
            (k + 1 < n_frames).then(|| (k + 1, true)),
            (k > 0).then(|| (k - 1, false)),
        ];
        for (j, forward) in neighbours.into_iter().flatten() {
            let (flow, prob, x_j) = if forward {
                (dy.flow_next.clone(), dy.prob_next.clone(), x_next.clone())
            } else {
                (dy.flow_prev.clone(), dy.prob_prev.clone(), x_prev.clone())
            };
            let dj = query_dynamic(dynamic, x_j, v.times[j], &dirs, self.bounds.aabb, flow_scale);
            let warped = composite(dj.sigma.clone(), dj.rgb.clone(), None, &layout, 0.0);
            let rgb_w = with_bg(warped.clone().slice([0..r_n, 0..3]), warped.slice([0..r_n, 3..4]));
            // Ŵ = Σ sg(w_j)·(1 − p): gradients reach p only.
            let vis = composite(
                dj.sigma.clone().detach(),
                prob.clone().neg() + 1.0,
                None,
                &layout,
                0.0,
            )
            .slice([0..r_n, 0..1]);
            loss = loss + wmse(rgb_w, target.clone(), vis) * wts.dynamic_photo;
            // The flow back from the warped point should undo the flow that got there.
            let back = if forward { dj.flow_prev } else { dj.flow_next };
            loss = loss + wmae(flow.clone(), back.neg(), prob.clone().neg() + 1.0) * wts.cycle;
            loss = loss + prob.abs().mean() * wts.prob_reg;
            // Projected scene flow against the 2-D optical flow of this pixel.
            let prior = if forward { &v.flow_fwd[k] } else { &v.flow_bwd[k] };
            if let (Some(of), true) = (prior, wts.optical_flow > 0.0) {
                let mut tgt = Vec::with_capacity(2 * r_n);
                let mut mask = Vec::with_capacity(r_n);
                for &p in &pixels {
                    let (i, jj) = ((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
                    let q = p as usize;
                    tgt.extend([i + of.flow[2 * q], jj + of.flow[2 * q + 1]]);
                    mask.push(of.mask[q]);
                }
                // The flowed surface point: Σ w·(x + f) over the ray's opacity. Unnormalised, a
                // ray that is partly transparent (white background, early training) would
                // project its point towards the world origin, and the flow would learn to undo
                // that instead of the motion; such rays count as much as they are opaque.
                let opacity = host_values(&acc_d);
                for (m, a) in mask.iter_mut().zip(&opacity) {
                    *m *= a.clamp(0.0, 1.0);
                }
                let expected = d
                    .clone()
                    .slice(if forward { [0..r_n, 4..7] } else { [0..r_n, 7..10] })
                    / acc_d.clone().clamp_min(1e-3);
                let world = match &ds.ndc {
                    Some(ndc) => geometry::ndc_to_world(expected, ndc),
                    None => expected,
                };
                let uv = geometry::project(world, &ds.views[v.frames[j]].camera, dev);
                loss =
                    loss + wmae(uv, tensor(tgt, 2, dev), tensor(mask, 1, dev)) * (wts.optical_flow * decay);
            }
        }
        // Scene-flow priors: small, temporally smooth (f_next + f_prev ≈ 0), spatially smooth.
        // Smoothness is measured in Euclidean space (NDC flows are converted first).
        let (fn_e, fp_e) = match &ds.ndc {
            Some(ndc) => {
                let xe = geometry::ndc_to_world(x.clone(), ndc);
                (
                    geometry::ndc_to_world(x_next.clone(), ndc) - xe.clone(),
                    geometry::ndc_to_world(x_prev.clone(), ndc) - xe,
                )
            }
            None => (dy.flow_next.clone(), dy.flow_prev.clone()),
        };
        loss = loss
            + (dy.flow_next.clone().abs().mean() + dy.flow_prev.clone().abs().mean()) * (0.5 * wts.min_flow);
        loss = loss + (fn_e.clone() + fp_e.clone()).powi_scalar(2).sum_dim(1).mean() * (0.5 * wts.smooth);
        let (a, b) = adjacent_pairs(&samples, 0.95);
        if !a.is_empty() {
            let n_pairs = a.len();
            let ia =
                Tensor::<1, burn::tensor::Int>::from_data(burn::tensor::TensorData::new(a, [n_pairs]), dev);
            let ib =
                Tensor::<1, burn::tensor::Int>::from_data(burn::tensor::TensorData::new(b, [n_pairs]), dev);
            let spatial = (fn_e.clone().select(0, ia.clone()) - fn_e.select(0, ib.clone()))
                .abs()
                .mean()
                + (fp_e.clone().select(0, ia) - fp_e.select(0, ib)).abs().mean();
            loss = loss + spatial * wts.smooth;
        }
        loss = loss + entropy(blend) * wts.entropy;
        if wts.sparsity > 0.0 {
            let sparse = span("nsff_sparsity", || self.sparsity_loss(dynamic, v.times[k], rng));
            loss = loss + sparse * wts.sparsity;
        }
        if self.cfg.static_batch {
            let (rays_s, target_s) = self.still_pixels(n_uniform, rng);
            let still = span("nsff_static_batch", || {
                self.static_photometric(&rays_s, target_s, rng)
            });
            if let Some((loss_s, _, _)) = still {
                loss = loss + loss_s;
            }
        }
        // Ray and sample counts of the space-time batch (what the ray count adapts to).
        let m = mse_cb.inner().into_scalar::<f32>() as f64;
        Some((loss, stats(m, r_n, s_n)))
    }

    /// Mean blended dynamic optical depth per march step, b·σ_dy·δ, at `sparsity_points` random
    /// points at time `time`: drawn from occupied cells when there is a grid (the rest of the box
    /// is skipped by rendering anyway), else uniformly in the box.
    fn sparsity_loss(&self, dynamic: &Field, time: f32, rng: &mut StdRng) -> Tensor<1> {
        let [lo, hi] = self.bounds.aabb;
        let mut pos = Vec::with_capacity(3 * self.cfg.sparsity_points);
        for _ in 0..self.cfg.sparsity_points {
            let mut p = [0.0f32; 3];
            for _ in 0..8 {
                p = std::array::from_fn(|a| lo[a] + (hi[a] - lo[a]) * rng.random::<f32>());
                if self.occupancy.as_ref().is_none_or(|g| g.is_occupied(p)) {
                    break;
                }
            }
            pos.extend(p);
        }
        let n = pos.len() / 3;
        let x = tensor(pos, 3, &self.device);
        let dirs: Vec<f32> = [0.0, 0.0, 1.0].repeat(n);
        let b = query_static(&self.fields.static_field, x.clone(), &dirs, self.bounds.aabb).blend;
        let dy = query_dynamic(dynamic, x, time, &dirs, self.bounds.aabb, self.cfg.flow_scale);
        let step = match &self.occupancy {
            Some(_) => self.cfg.base.fast.march.step,
            // Stratified samples: their mean spacing.
            None => (self.bounds.far - self.bounds.near) / self.cfg.samples as f32,
        };
        (b * dy.gate * dy.sigma).mean() * step
    }

    /// `n` rays from random frames at pixels outside their motion masks, and their colours
    /// (`[n * 3]`).
    fn still_pixels(&self, n: usize, rng: &mut StdRng) -> (nerf_data::Rays, Vec<f32>) {
        let v = &self.video;
        let mut per_frame: Vec<Vec<u32>> = vec![Vec::new(); v.frames.len()];
        for _ in 0..n {
            // A few tries per ray: masks cover a small share of each frame.
            for _ in 0..8 {
                let k = rng.random_range(0..v.frames.len());
                let img = &v.dataset.views[v.frames[k]].image;
                let p = rng.random_range(0..img.width * img.height);
                if !v.motion_masks[k][p as usize] {
                    per_frame[k].push(p);
                    break;
                }
            }
        }
        let mut rays = nerf_data::Rays::with_capacity(n);
        let mut target = Vec::with_capacity(3 * n);
        for (k, pixels) in per_frame.iter().enumerate().filter(|(_, p)| !p.is_empty()) {
            let view = &v.dataset.views[v.frames[k]];
            rays.extend(&v.dataset.rays_for(&view.camera, pixels.iter().copied()));
            target.extend(pixel_colours(view, pixels));
        }
        (rays, target)
    }

    /// The static field alone on `rays` against `target` (`[R * 3]`): the static pipeline's
    /// photometric loss, its value, and the sample count. `None` when no ray has samples.
    fn static_photometric(
        &self,
        rays: &nerf_data::Rays,
        target: Vec<f32>,
        rng: &mut StdRng,
    ) -> Option<(Tensor<1>, f64, usize)> {
        let dev = &self.device;
        let march = self.occupancy.as_ref().map(|g| (g, &self.cfg.base.fast.march));
        let clip = !self.bounds.open_far;
        let samples = sample_rays(rays, &self.bounds, self.cfg.samples, clip, march, Some(rng));
        let s_n = samples.num_samples();
        if s_n == 0 {
            return None;
        }
        let r_n = rays.len();
        let layout = samples.layout(rays, self.bounds.open_far && march.is_none());
        let x = tensor(samples.positions(rays), 3, dev);
        let dirs = samples.per_sample3(&rays.viewdirs());
        let t_col = tensor(samples.t.clone(), 1, dev);
        let st = query_static(&self.fields.static_field, x, &dirs, self.bounds.aabb);
        let out = composite(st.sigma, Tensor::cat(vec![st.rgb, t_col], 1), None, &layout, 0.0);
        let mut rgb = out.clone().slice([0..r_n, 0..3]);
        if let Some(c) = self.video.dataset.background {
            let bg = tensor(c.repeat(r_n).to_vec(), 3, dev);
            rgb = rgb + (out.slice([0..r_n, 4..5]).neg() + 1.0) * bg;
        }
        let loss = mse(rgb, tensor(target, 3, dev));
        let m = loss.clone().inner().into_scalar::<f32>() as f64;
        Some((loss, m, s_n))
    }

    /// Trains until a budget is reached (the static pipeline's loop).
    pub fn train(&mut self, show_progress: bool) -> Result<()> {
        let header = format!(
            "{}; {} frames; independent motion in {:.2}% of flow pixels (motion masks: {:.1}%): dynamic field {}",
            self.video.dataset.describe(),
            self.video.frames.len(),
            100.0 * self.video.moving_fraction,
            100.0 * self.video.mask_fraction(),
            if self.has_dynamic() {
                "on"
            } else {
                "off (static scene)"
            }
        );
        nerf::train_loop::train(self, &header, show_progress)
    }

    fn rollback(&mut self) -> Result<()> {
        let path = self.run_dir.join(CHECKPOINT);
        if path.exists() {
            let s = Sections::read(&path)?;
            self.restore(&s, &path)
        } else {
            let dynamic = self.has_dynamic();
            self.fields = NsffFields::new(&self.cfg, dynamic, &self.device);
            self.optim = optimizer(&self.cfg);
            self.step = 0;
            Ok(())
        }
    }
}

/// Transmittance below which a sample counts as hidden. The visible surface itself spans a
/// few samples over which T falls from 1 to 0; weighting by (1 − T) penalised its back half.
const HIDDEN_BELOW_T: f32 = 0.05;

/// Per sample, δ·max(0, 1 − T/T_h): its interval where it lies behind the combined render's
/// visible surface (T = transmittance before the sample through the blended density
/// (1 − b)·σ_st + b·σ_dy, T_h = [`HIDDEN_BELOW_T`]), so that Σ weight·b·σ_dy is the ray's hidden
/// dynamic optical depth. Host values (no gradient): `sigma_st`, `sigma_dy`, `blend` per sample.
fn hidden_weights(sigma_st: &[f32], sigma_dy: &[f32], blend: &[f32], layout: &RayLayout) -> Vec<f32> {
    let mut out = vec![0.0f32; sigma_st.len()];
    for r in 0..layout.num_rays() {
        let mut optical = 0.0f32;
        for i in layout.offsets[r] as usize..layout.offsets[r + 1] as usize {
            let (b, delta) = (blend[i], layout.deltas[i]);
            out[i] = (1.0 - (-optical).exp() / HIDDEN_BELOW_T).max(0.0) * delta;
            optical += ((1.0 - b) * sigma_st[i] + b * sigma_dy[i]).max(0.0) * delta;
        }
    }
    out
}

/// Per-sample value whose render the depth prior compares with monocular disparity: 1/t for a
/// Euclidean ray (t is the camera depth), 1 − t in NDC (t = 1 − near/|z|, so 1 − t is
/// proportional to the disparity). Either way the rendered value is affine in disparity where
/// the ray is opaque, which is all the scale- and shift-invariant loss needs.
fn sample_disparity(t: &[f32], ndc: bool) -> Vec<f32> {
    t.iter()
        .map(|&t| if ndc { 1.0 - t } else { 1.0 / t.max(1e-3) })
        .collect()
}

/// A `[N, 1]` tensor's values on the host, without gradient.
fn host_values(t: &Tensor<2>) -> Vec<f32> {
    t.clone()
        .inner()
        .into_data()
        .try_into_vec_as::<f32>()
        .unwrap_or_default()
}

/// Colours (`[P * 3]`) of a view's pixels.
fn pixel_colours(view: &nerf_data::View, pixels: &[u32]) -> Vec<f32> {
    pixels
        .iter()
        .flat_map(|&p| view.image.pixel(p as usize)[..3].to_vec())
        .collect()
}

fn stats(mse: f64, rays: usize, samples: usize) -> StepStats {
    StepStats {
        loss: mse,
        psnr: psnr_from_mse(mse),
        rays,
        samples,
    }
}

/// Index pairs (s, s + 1) of neighbouring samples on the same ray, over the first `frac` of each
/// ray's samples (NSFF skips the far end, where NDC warps stretch).
fn adjacent_pairs(samples: &nerf_core::sampler::RaySamples, frac: f32) -> (Vec<i32>, Vec<i32>) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for r in 0..samples.num_rays() {
        let range = samples.range(r);
        let keep = ((range.len() as f32 * frac) as usize).max(1);
        for s in range.start..(range.start + keep).min(range.end).saturating_sub(1) {
            a.push(s as i32);
            b.push(s as i32 + 1);
        }
    }
    (a, b)
}

impl nerf::train_loop::Trainable for NsffTrainer {
    fn config(&self) -> &nerf::config::TrainConfig {
        &self.cfg.base
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
        NsffTrainer::train_step(self)
    }
    fn save(&self) -> Result<()> {
        NsffTrainer::save(self)
    }
    fn rollback(&mut self) -> Result<()> {
        NsffTrainer::rollback(self)
    }
    fn quick_eval(&mut self) -> Result<f64> {
        let views = crate::eval::quick_views(&self.video.dataset);
        Ok(crate::eval::evaluate(self, &views, false, None)?.mean_psnr)
    }
    fn status(&self) -> String {
        self.occupancy.as_ref().map_or(String::new(), |o| {
            format!(", {:.1}% occupied", 100.0 * o.occupied_fraction())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// The hidden weights against transmittance recomputed in f64 from its definition,
    /// T_i = exp(−Σ_{j<i} σ_j δ_j) with σ = (1 − b)·σ_st + b·σ_dy.
    #[test]
    fn hidden_weights_follow_the_blended_transmittance() {
        // Two rays: 3 samples, the last partly hidden (T ≈ 0.03), then 4 with an opaque static
        // wall at the second sample.
        let sigma_st = [0.0f32, 2.0, 0.5, 0.0, 1e4, 0.0, 0.0];
        let sigma_dy = [1.0f32, 60.0, 0.0, 5.0, 0.0, 2.0, 7.0];
        let blend = [1.0f32, 0.25, 0.5, 0.9, 0.0, 1.0, 0.5];
        let layout = RayLayout {
            offsets: Arc::new(vec![0, 3, 7]),
            deltas: Arc::new(vec![0.1, 0.2, 0.3, 0.05, 0.05, 0.1, 0.1]),
        };
        let got = hidden_weights(&sigma_st, &sigma_dy, &blend, &layout);
        for r in 0..2 {
            let mut sum = 0.0f64;
            for i in layout.offsets[r] as usize..layout.offsets[r + 1] as usize {
                let (b, d) = (blend[i] as f64, layout.deltas[i] as f64);
                let want = (1.0 - (-sum).exp() / HIDDEN_BELOW_T as f64).max(0.0) * d;
                assert!(
                    (got[i] as f64 - want).abs() < 1e-6,
                    "sample {i}: {} vs {want}",
                    got[i]
                );
                sum += ((1.0 - b) * sigma_st[i] as f64 + b * sigma_dy[i] as f64) * d;
            }
        }
        // The first sample of a ray is never hidden; behind the wall everything is.
        assert_eq!(got[0], 0.0);
        assert_eq!(got[3], 0.0);
        assert!(got[1] == 0.0 && got[2] > 0.0 && got[2] < 0.3, "{got:?}");
        assert!((got[5] - 0.1).abs() < 1e-6 && (got[6] - 0.1).abs() < 1e-6);
    }
}
