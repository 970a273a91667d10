//! NSFF training: one frame per step; the combined, dynamic-only, warped and static-batch
//! renders (all through the shared render function) and the loss terms of `losses.rs`.
//! Bookkeeping (budgets, checkpoints, metrics log, progress, plot) is the static pipeline's loop.

use std::cell::{Cell, RefCell};
use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor};
use nerf::checkpoint::{Sections, has_checkpoint};
use nerf::error::{ModelError, Result, read_scalar};
use nerf::model::scene_bounds;
use nerf::optimizer::Optimizer;
use nerf::renderer::tensor;
use nerf_core::error_map::ErrorMap;
use nerf_core::field::{Field, FieldOutputs, FieldQuery};
use nerf_core::metrics::psnr_from_mse;
use nerf_core::occupancy::{HullRule, carve_visual_hull};
use nerf_core::profile::span;
use nerf_core::rays::Rays;
use nerf_core::render::{Background, Component, RenderOutput, render};
use nerf_core::sampler::RaySamples;
use rand::{Rng, SeedableRng, rngs::StdRng, seq::SliceRandom};

use crate::checkpoint::{read_model, write_model};
use crate::config::{DynamicMode, NsffConfig};
use crate::field::{BLEND, DynamicField, FLOW_NEXT, FLOW_PREV, GATE, PROB_NEXT, PROB_PREV};
use crate::geometry;
use crate::losses;
use crate::model::{NsffModel, query_dynamic};
use crate::render::{DYNAMIC_SHARE, query_space_time, render_combined, render_options, sample_rays};
use crate::video::{Video, prepare};

pub use crate::checkpoint::NsffState;
pub use nerf::train_loop::{CHECKPOINT, METRICS, StepStats};

pub struct NsffTrainer {
    pub cfg: NsffConfig,
    pub video: Video,
    pub model: NsffModel,
    optim: Optimizer,
    pub step: usize,
    pub elapsed: f64,
    pub run_dir: PathBuf,
    pub device: Device,
    n_rays: usize,
    /// Rays of the static batch.
    n_static_rays: usize,
    /// The lowest occupied fraction of the grid seen during the static warm-up.
    occupancy_floor: f32,
    /// A message for the training log, taken by the loop.
    note: Option<String>,
    /// Per-frame tile errors for `error_rays` (filled in by the steps, which borrow `self`).
    error_map: Option<RefCell<ErrorMap>>,
    /// Whether the last step was a static warm-up step (for the profile's phase split).
    profiling_warm_up: bool,
    /// The blend on the last sampled space-time batch's rays (the status line's readout).
    blend_readout: Cell<Option<BlendReadout>>,
    /// While `weights.moving_dynamic` applies: the share of the last read batch's masked rays
    /// the dynamic-only render fits better than the combined one: the rays it opens the blend
    /// on (the status line's readout).
    earned_readout: Cell<Option<f32>>,
    /// Sum and count of the moving rays' blend readouts over the last quarter of the moving
    /// term's span (`reopen_blend_below`).
    shut_watch: Cell<(f64, usize)>,
}

/// How far the blend b = b_s·g opens on a batch's rays inside and outside the motion masks:
/// the mean over rays of each ray's largest b. A blend that stays shut on the moving rays
/// means the static field draws the movers and the dynamic field is unused.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BlendReadout {
    moving: f32,
    still: f32,
}

/// Space-time steps between two blend readouts (each reads the batch's blend back).
const BLEND_READOUT_EVERY: usize = 50;

/// Loads the video dataset a config names and prepares flows and the motion decision.
pub fn load_video(cfg: &NsffConfig, run_dir: &Path, quiet: bool) -> Result<Video> {
    let dataset = nerf_data::load::load_video(&cfg.base.data, &cfg.base.load)?;
    for note in &dataset.notes {
        if !quiet {
            eprintln!("note: {note}");
        }
    }
    Ok(prepare(
        dataset,
        &run_dir.join("flow_cache"),
        cfg.motion_threshold_px,
        nerf_flow::MaskRule {
            threshold_px: cfg.mask_threshold_px,
            both_neighbours: cfg.mask_both_neighbours,
        },
        cfg.unmask_background,
        quiet,
    )?)
}

/// One step's rays, in groups of rays from one frame each (one group for a video: its terms
/// compare that frame with its neighbours). Within a group, uniformly drawn pixels, then those
/// drawn from the error map, then NSFF's hard-mined ones.
struct FrameBatch {
    /// Each group's frame and its rays' range in `pixels`, `rays` and `target`.
    groups: Vec<(usize, std::ops::Range<usize>)>,
    pixels: Vec<u32>,
    /// Rays the combined render's loss scores: all but the hard-mined ones (which would bias the
    /// blend); the error-map rays count.
    n_uniform: usize,
    rays: Rays,
    /// `[R, 3]` target colours.
    target: Tensor<2>,
}

impl FrameBatch {
    /// The first group's frame: the frame of a one-frame batch.
    fn frame(&self) -> usize {
        self.groups[0].0
    }

    /// `f(frame, pixel)` for every ray, in ray order.
    fn per_ray<T>(&self, mut f: impl FnMut(usize, u32) -> T) -> Vec<T> {
        let mut out = Vec::with_capacity(self.pixels.len());
        for (k, range) in &self.groups {
            out.extend(self.pixels[range.clone()].iter().map(|&p| f(*k, p)));
        }
        out
    }

    /// Per ray, 1 where its frame's motion mask is `inside` at its pixel, else 0.
    fn mask_weights(&self, masks: &[Vec<bool>], inside: bool) -> Vec<f32> {
        self.per_ray(|k, p| f32::from(u8::from(masks[k][p as usize] == inside)))
    }
}

impl NsffTrainer {
    /// A fresh run. `cfg` should be adapted to the video already.
    pub fn new(cfg: NsffConfig, video: Video, run_dir: &Path) -> Result<Self> {
        let device = nerf::trainer::device(&cfg.base, true)?;
        std::fs::create_dir_all(run_dir).map_err(|e| nerf_data::DataError::io(run_dir, e))?;
        let with_dynamic = match cfg.dynamic {
            DynamicMode::On => true,
            DynamicMode::Off => false,
            DynamicMode::Auto => video.has_motion,
        };
        if cfg.frames_per_batch > 1 && !video.camera_path.is_jumping() {
            return Err(ModelError::usage(
                &cfg.base.data,
                "frames_per_batch > 1 needs a jumping camera: a video's flow, warp and disparity terms compare one frame with its neighbours",
            ));
        }
        let bounds = scene_bounds(&video.dataset);
        let mut model = NsffModel::new(&cfg, bounds, video.times.clone(), with_dynamic, &device);
        // A still scene is consistent with every view, so its visual hull is valid, as in the
        // static pipeline. With independent motion a view's silhouette bounds the scene at that
        // view's time only, so a dynamic scene's grid loses only the cells that look empty (or
        // are unseen) at every time, and only with `carve_unseen`.
        let rules = [
            (!with_dynamic).then_some(HullRule::AtLeast(2)),
            cfg.carve_unseen
                .then_some(HullRule::NoForeground { min_background: 0 }),
        ];
        if let Some(grid) = model.occupancy.as_mut() {
            for rule in rules.into_iter().flatten() {
                let carved = grid.with_bins_mut(|bins| {
                    bins.iter_mut()
                        .map(|g| carve_visual_hull(g, &video.dataset, &video.frames, rule))
                        .fold(0.0f32, f32::max)
                });
                if carved > 0.0 {
                    eprintln!(
                        "occupancy grid: {:.1}% of the box carved away by the training frames ({rule:?})",
                        100.0 * carved
                    );
                }
            }
        }
        let optim = Optimizer::new(&cfg.base);
        let n_rays = cfg.rays;
        let n_static_rays = cfg.rays;
        let error_map = (cfg.error_rays > 0.0 && video.camera_path.is_jumping()).then(|| {
            let images = video.frames.iter().map(|&i| &video.dataset.views[i].image);
            let sizes: Vec<(u32, u32)> = images.map(|im| (im.width, im.height)).collect();
            // Tiles start above any squared error (at most 3), so unseen tiles come first.
            RefCell::new(ErrorMap::new(&sizes, 8, 3.0))
        });
        Ok(NsffTrainer {
            cfg,
            video,
            model,
            optim,
            step: 0,
            elapsed: 0.0,
            run_dir: run_dir.to_path_buf(),
            device,
            n_rays,
            n_static_rays,
            occupancy_floor: 1.0,
            note: None,
            error_map,
            profiling_warm_up: false,
            blend_readout: Cell::new(None),
            earned_readout: Cell::new(None),
            shut_watch: Cell::new((0.0, 0)),
        })
    }

    pub fn has_dynamic(&self) -> bool {
        self.model.has_dynamic()
    }

    /// Resumes from `run_dir/checkpoint.bin`; `update` may change budgets, or refuse the saved
    /// settings with a message (a usage error naming `run_dir`, before the video is loaded).
    pub fn resume(
        run_dir: &Path,
        update: impl FnOnce(&mut NsffConfig) -> std::result::Result<(), String>,
        quiet: bool,
    ) -> Result<Self> {
        let (s, path) = Sections::read_for_resume(run_dir)?;
        let state: NsffState = s.json("state", &path)?;
        let mut cfg = state.config.clone();
        // Refused before the video is loaded and its optical flow read or computed.
        update(&mut cfg).map_err(|m| ModelError::usage(run_dir, m))?;
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
        let state: NsffState = s.json("state", path)?;
        self.model = read_model(&self.cfg, state.dynamic, s, path, &self.device)?;
        self.optim = Optimizer::new(&self.cfg.base);
        self.optim
            .load_bytes(s.require("optim", path)?)
            .map_err(|e| ModelError::checkpoint(path, format!("cannot load optimiser state: {e}")))?;
        self.step = state.step;
        self.elapsed = state.elapsed;
        // A rollback to before a reopening gets the shut heads back, so it may reopen again.
        self.cfg.blend_reopened_at = state.config.blend_reopened_at;
        self.shut_watch.set((0.0, 0));
        if state.n_rays > 0 {
            self.n_rays = state.n_rays;
        }
        if state.n_static_rays > 0 {
            self.n_static_rays = state.n_static_rays;
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
            n_static_rays: self.n_static_rays,
        };
        let mut s = Sections::default();
        s.push_json("state", &state, &path)?;
        write_model(&self.model, &mut s, &path)?;
        let optim = self
            .optim
            .to_bytes()
            .map_err(|e| ModelError::checkpoint(&path, format!("cannot save optimiser: {e}")))?;
        s.push("optim", optim);
        s.write_keeping_previous(&path)
    }

    /// One step on a random frame. `Ok(None)` when the loss was not finite (step skipped).
    pub fn train_step(&mut self) -> Result<Option<StepStats>> {
        let seed = self
            .cfg
            .base
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(self.step as u64);
        let mut rng = StdRng::seed_from_u64(seed);
        let warm_up = self.in_static_warm_up();
        if !warm_up && self.profiling_warm_up && nerf_core::profile::enabled() {
            // The loop prints the rest at the end: the two phases' steps cost differently.
            eprint!(
                "profile of the static warm-up (steps 0-{}):\n{}",
                self.step,
                nerf_core::profile::take_report()
            );
        }
        self.profiling_warm_up = warm_up;
        let Some((loss, stats, static_samples)) =
            span("nsff_step_loss", || self.step_loss(warm_up, &mut rng))?
        else {
            // Every ray missed the occupied space: nothing to learn from, count the step.
            self.step += 1;
            return Ok(Some(StepStats {
                loss: f64::NAN,
                psnr: f64::NAN,
                ..StepStats::default()
            }));
        };
        let value = read_scalar(loss.clone().inner(), "loss")?;
        let host = self.model.host_params();
        if !value.is_finite() {
            self.optim.skip(&host);
            return Ok(None);
        }
        self.model.fields = self.optim.step(loss, self.lr(), self.model.fields.clone(), &host);
        self.step += 1;
        self.reopen_blend_if_shut();
        if self.model.occupancy.as_ref().is_some_and(|o| o.due(self.step)) {
            // One random training time of the bin per refreshed point: a cell the moving object
            // crosses stays above the threshold for many refreshes once seen (values decay by
            // 5 % per refresh).
            let in_bin = self.training_times_per_bin();
            let mut grid_rng = StdRng::seed_from_u64(self.step as u64);
            span("nsff_occupancy", || {
                self.model.update_occupancy(
                    self.step,
                    &mut grid_rng,
                    |k| in_bin[k][rng.random_range(0..in_bin[k].len())],
                    warm_up && self.cfg.warm_up_static_occupancy,
                    &self.device,
                )
            })?;
            if warm_up && self.cfg.warm_up_exit_rise > 0.0 {
                self.end_warm_up_if_refilling();
            }
        }
        if self.model.occupancy.is_some() {
            // Keep each batch near its share of `target_samples`, as the static trainer does.
            let f = &self.cfg.base.fast;
            let share = if self.has_dynamic() {
                self.cfg.space_time_share
            } else {
                1.0
            };
            let adapt = |rays: usize, samples: usize, share: f32| {
                rays as f64 * f.target_samples as f64 * share as f64 / samples.max(1) as f64
            };
            if !warm_up {
                let want = adapt(self.n_rays, stats.samples, share);
                self.n_rays = (want as usize).clamp(self.cfg.min_rays, self.cfg.rays.max(self.cfg.min_rays));
            }
            if static_samples > 0 {
                let want = adapt(self.n_static_rays, static_samples, self.cfg.static_batch_scale);
                self.n_static_rays = (want as usize).clamp(f.min_rays, f.max_rays);
            }
        }
        Ok(Some(StepStats { loss: value, ..stats }))
    }

    /// Weight multiplier of the decaying terms (optical flow, depth) now; the budget's progress
    /// counts from the end of the static warm-up.
    fn decay(&self) -> f64 {
        self.cfg.decay(self.step, self.after_warm_up())
    }

    /// The learning rate now.
    fn lr(&self) -> f64 {
        self.cfg.base.lr_at(self.lr_progress())
    }

    /// How far the learning rates have decayed, in [0, 1].
    fn lr_progress(&self) -> f64 {
        if self.cfg.lr_decay_after_warm_up {
            self.after_warm_up()
        } else {
            self.cfg.base.progress(self.step, self.elapsed)
        }
    }

    /// The budget's progress counted from the end of the static warm-up, in [0, 1] (0 during it).
    fn after_warm_up(&self) -> f64 {
        let progress = self.cfg.base.progress(self.step, self.elapsed);
        let w = self.cfg.static_warm_up.clamp(0.0, 0.99);
        ((progress - w) / (1.0 - w)).max(0.0)
    }

    /// Whether `weights.moving_dynamic` applies now: its span at the start of the space-time
    /// phase, and again from where the blend was reopened.
    fn in_moving_span(&self) -> bool {
        let (after, until) = (self.after_warm_up(), self.cfg.moving_dynamic_until);
        after < until || self.cfg.blend_reopened_at.is_some_and(|r| after < r + until)
    }

    /// Once the moving term's span is over: reopens the blend if its readouts on the moving
    /// rays over the span's last quarter averaged below `reopen_blend_below` (the blend and
    /// gate heads start again, and so does the span; `reopen_blend_below`). Once per run.
    fn reopen_blend_if_shut(&mut self) {
        let below = self.cfg.reopen_blend_below;
        if below <= 0.0
            || self.cfg.weights.moving_dynamic <= 0.0
            || self.cfg.blend_reopened_at.is_some()
            || self.after_warm_up() < self.cfg.moving_dynamic_until
        {
            return;
        }
        let (sum, n) = self.shut_watch.replace((0.0, 0));
        if n == 0 || sum / n as f64 >= f64::from(below) {
            return;
        }
        // Where a new run's blend starts by default (b ≈ 0.05), whatever this run started at.
        let logit = crate::config::default_blend_init_logit();
        self.model.fields.static_field.reopen_blend(logit);
        if let Some(dynamic) = self.model.fields.dynamic.as_mut() {
            dynamic.reopen_gate();
        }
        let after = self.after_warm_up();
        self.cfg.blend_reopened_at = Some(after);
        self.note = Some(format!(
            "the blend had shut on the moving rays (readout {:.3} over the last quarter of the moving term's span, below {below}): reopened at step {} ({:.0} % of the space-time phase), and the span starts again",
            sum / n as f64,
            self.step,
            100.0 * after,
        ));
    }

    /// Ends the static warm-up now when the occupancy grid, after carving down to its floor,
    /// fills up again by `warm_up_exit_rise` times and at least [`WARM_UP_EXIT_MIN_RISE`]: the
    /// views disagree (things move), so the static field is painting fog over the space the
    /// movers sweep, which would keep costing samples and sharpness for the rest of the run.
    /// A static set only carves. The schedules then count from here (`static_warm_up` is set to
    /// the progress now, and saved with the config).
    fn end_warm_up_if_refilling(&mut self) {
        let Some(now) = self.model.occupancy.as_ref().map(|g| g.occupied_fraction()) else {
            return;
        };
        let floor = self.occupancy_floor.min(now);
        self.occupancy_floor = floor;
        if now > self.cfg.warm_up_exit_rise * floor && now - floor > WARM_UP_EXIT_MIN_RISE {
            let progress = self.cfg.base.progress(self.step, self.elapsed);
            self.cfg.static_warm_up = progress;
            self.note = Some(format!(
                "static warm-up ended at step {} ({:.0} % of the budget): the occupancy grid filled up again from {:.1} % to {:.1} % (the views disagree: things move)",
                self.step,
                100.0 * progress,
                100.0 * floor,
                100.0 * now,
            ));
        }
    }

    /// The training times in each of the occupancy grid's time bins; a bin without a frame gets
    /// its middle time.
    fn training_times_per_bin(&self) -> Vec<Vec<f32>> {
        let Some(grid) = &self.model.occupancy else {
            return Vec::new();
        };
        let mut in_bin = vec![Vec::new(); grid.num_bins()];
        for &t in &self.video.times {
            in_bin[grid.bin_of(t)].push(t);
        }
        for (k, times) in in_bin.iter_mut().enumerate().filter(|(_, t)| t.is_empty()) {
            let [lo, hi] = grid.bin_range(k);
            times.push(0.5 * (lo + hi));
        }
        in_bin
    }

    /// Whether this step trains the static field alone (`static_warm_up`).
    fn in_static_warm_up(&self) -> bool {
        self.has_dynamic() && self.cfg.base.progress(self.step, self.elapsed) < self.cfg.static_warm_up
    }

    /// Rays of `frames_per_batch` random frames: uniform pixels, plus (NSFF's hard mining, early
    /// on, one frame only) pixels the flow says are moving.
    fn frame_batch(&self, rng: &mut StdRng) -> FrameBatch {
        let v = &self.video;
        let n_frames = self.cfg.frames_per_batch.clamp(1, self.n_rays.max(1));
        let (mut groups, mut pixels, mut colours) = (Vec::new(), Vec::new(), Vec::new());
        let mut rays = Rays::with_capacity(self.n_rays);
        for g in 0..n_frames {
            let frame = rng.random_range(0..v.frames.len());
            let view = &v.dataset.views[v.frames[frame]];
            let (w, h) = (view.image.width, view.image.height);
            // Split n_rays as evenly as the division allows.
            let n = (g + 1) * self.n_rays / n_frames - g * self.n_rays / n_frames;
            let n_error = match &self.error_map {
                Some(_) => (n as f32 * self.cfg.error_rays.clamp(0.0, 1.0)).round() as usize,
                None => 0,
            };
            let mut own: Vec<u32> = (0..n - n_error).map(|_| rng.random_range(0..w * h)).collect();
            if let Some(map) = &self.error_map {
                own.extend(map.borrow().sample(frame, n_error, rng));
            }
            let moving = &v.moving_pixels[frame];
            if n_frames == 1 && self.has_dynamic() && self.step < self.cfg.decay_steps && !moving.is_empty() {
                let extra = (n as f32 * self.cfg.hard_fraction).round() as usize;
                own.extend((0..extra).map(|_| moving[rng.random_range(0..moving.len())]));
            }
            groups.push((frame, pixels.len()..pixels.len() + own.len()));
            rays.extend(&v.dataset.rays_for(&view.camera, own.iter().copied()));
            colours.extend(pixel_colours(view, &own));
            pixels.extend(own);
        }
        FrameBatch {
            groups,
            rays,
            target: tensor(colours, 3, &self.device),
            pixels,
            n_uniform: self.n_rays,
        }
    }

    /// Renders components along `rays` at `samples` on the training device.
    fn render(&self, rays: &Rays, samples: &RaySamples, components: &[Component]) -> RenderOutput {
        let background = Background::from_option(self.video.dataset.background);
        self.render_over(rays, samples, components, &background)
    }

    /// [`Self::render`] over `background` instead of the dataset's.
    fn render_over(
        &self,
        rays: &Rays,
        samples: &RaySamples,
        components: &[Component],
        background: &Background,
    ) -> RenderOutput {
        render(
            rays,
            samples,
            components,
            background,
            render_options(&self.model),
            &self.device,
        )
    }

    /// Jittered samples along `rays` (occupancy marching where there is a grid: the grid of
    /// `time`'s bin, or of all bins for rays of mixed times).
    fn samples(&self, rays: &Rays, time: Option<f32>, rng: &mut StdRng) -> RaySamples {
        let march = self.model.occupancy.as_ref().map(|g| {
            let grid = time.map_or_else(|| g.union(), |t| g.at(t));
            (grid, &self.model.settings.march)
        });
        let bounds = &self.model.bounds;
        sample_rays(rays, bounds, self.cfg.samples, !bounds.open_far, march, Some(rng))
    }

    /// [`Self::samples`] of a batch, each group at its frame's time, and each sample's time.
    fn batch_samples(&self, batch: &FrameBatch, rng: &mut StdRng) -> (RaySamples, Vec<f32>) {
        let times = &self.video.times;
        let mut samples = RaySamples::with_rays(batch.rays.len());
        for (k, range) in &batch.groups {
            samples.append(&self.samples(&batch.rays.slice(range.clone()), Some(times[*k]), rng));
        }
        let jitter = self.cfg.time_jitter / (times.len().max(2) - 1) as f32;
        let ray_times = batch.per_ray(|k, _| {
            if jitter > 0.0 {
                (times[k] + rng.random_range(-jitter..=jitter)).clamp(0.0, 1.0)
            } else {
                times[k]
            }
        });
        let sample_times = samples.per_sample(&ray_times);
        (samples, sample_times)
    }

    /// The loss of one step (NSFF HEAD's terms, method.md §4.6), the space-time batch's stats and
    /// the static batch's sample count (0 without one); `None` when no ray has samples. During the
    /// static warm-up (`warm_up`) the static batch alone.
    fn step_loss(&self, warm_up: bool, rng: &mut StdRng) -> Result<Option<(Tensor<1>, StepStats, usize)>> {
        if warm_up {
            let still = self.static_batch(true, rng)?;
            return Ok(still.map(|(loss, m, rays, n)| (loss, stats(m, rays, n), n)));
        }
        let batch = self.frame_batch(rng);
        let Some(dynamic) = &self.model.fields.dynamic else {
            // No independent motion: the static pipeline's photometric loss only.
            let background = Background::from_option(self.video.dataset.background);
            let Some((loss, m, s_n)) =
                self.static_photometric(&batch.rays, batch.target, &background, None, rng)?
            else {
                return Ok(None);
            };
            return Ok(Some((loss, stats(m, batch.rays.len(), s_n), 0)));
        };
        let (v, ds, dev) = (&self.video, &self.video.dataset, &self.device);
        let (k, rays, target, r_n) = (batch.frame(), &batch.rays, &batch.target, batch.rays.len());
        let (samples, sample_times) = self.batch_samples(&batch, rng);
        let s_n = samples.num_samples();
        if s_n == 0 {
            return Ok(None);
        }
        let (wts, decay) = (&self.cfg.weights, self.decay());
        let t = tensor(sample_times, 1, dev);
        let q = query_space_time(&self.model, dynamic, rays, &samples, t, dev);
        let (x, dirs, st, dy) = (&q.x, &q.dirs, &q.st, &q.dy);
        let (b_s, gate) = (st.extras.expect(BLEND), dy.extras.expect(GATE));
        if self.step.is_multiple_of(BLEND_READOUT_EVERY) {
            let blend =
                nerf_core::readback::read_back((b_s.clone() * gate.clone()).detach().inner(), "blend")?;
            let moving = batch.per_ray(|k, p| v.motion_masks[k][p as usize]);
            let readout = blend_readout(&blend, &samples.offsets, &moving);
            self.blend_readout.set(Some(readout));
            let (after, until) = (self.after_warm_up(), self.cfg.moving_dynamic_until);
            if (0.75 * until..until).contains(&after) && moving.contains(&true) {
                let (sum, n) = self.shut_watch.get();
                self.shut_watch.set((sum + f64::from(readout.moving), n + 1));
            }
        }

        // Combined render, scored over the uniform and error-map rays, not NSFF's hard-mined
        // ones (they would bias the blend).
        let moving_share = wts.moving_dynamic > 0.0 && self.in_moving_span();
        if !moving_share {
            self.earned_readout.set(None);
        }
        let combined = render_combined(&self.model, rays, &samples, &q, ds.background, moving_share, dev);
        let n_u = batch.n_uniform;
        let mse_cb = losses::mse(
            combined.rgb.clone().slice([0..n_u, 0..3]),
            target.clone().slice([0..n_u, 0..3]),
        );
        // Per-ray errors of the combined render, read back once for the error map and the
        // blend term.
        let combined_err = if self.error_map.is_some() || moving_share {
            ray_errors(&combined.rgb, target)?
        } else {
            Vec::new()
        };
        if let Some(map) = &self.error_map {
            let mut map = map.borrow_mut();
            for (frame, range) in &batch.groups {
                map.record(*frame, &batch.pixels[range.clone()], &combined_err[range.clone()]);
            }
        }
        let mut loss = mse_cb.clone();
        if wts.hidden > 0.0 {
            let host = losses::BlendedSamples::read(&st.sigma, &dy.sigma, &b_s, &gate)?;
            let hidden =
                losses::hidden_dynamic_depth(&host, dy.sigma.clone(), gate.clone(), &combined.layout);
            loss = loss + hidden * wts.hidden;
        }

        // Dynamic-only render, also integrating the flowed points (for the part of the
        // optical-flow term that reads the render weights) and a disparity-like value per
        // sample (for the depth prior).
        let (flow_next, flow_prev) = (dy.extras.expect(FLOW_NEXT), dy.extras.expect(FLOW_PREV));
        let x_next = x.clone() + flow_next.clone();
        let x_prev = x.clone() + flow_prev.clone();
        let disparity = tensor(sample_disparity(&samples.t, ds.ndc.is_some()), 1, dev);
        let mut dyn_component = Component::new(dy.sigma.clone(), dy.rgb.clone()).with(DISPARITY, disparity);
        // Share of the projected-flow term that reads the render weights (the rest reads them
        // detached, below).
        let through = match (wts.optical_flow > 0.0, self.cfg.flow_detach_weights) {
            (false, _) => 0.0,
            (true, true) => f64::from(self.cfg.flow_weights_share),
            (true, false) => 1.0,
        };
        if through > 0.0 {
            dyn_component = dyn_component
                .with(X_NEXT, x_next.clone())
                .with(X_PREV, x_prev.clone());
        }
        let dyn_only = self.render(rays, &samples, &[dyn_component]);
        loss = loss + losses::mse(dyn_only.rgb.clone(), target.clone()) * wts.dynamic_photo;
        if moving_share {
            // Open the blend where the dynamic field already fits the mover better, shut it on
            // the still rays.
            let dyn_err = ray_errors(&dyn_only.rgb, target)?;
            let masked = &batch.mask_weights(&v.motion_masks, true)[..n_u];
            let moving: Vec<f32> = masked
                .iter()
                .zip(dyn_err.iter().zip(&combined_err))
                .map(|(&m, (d, c))| if d < c { m } else { 0.0 })
                .collect();
            if self.step.is_multiple_of(BLEND_READOUT_EVERY) {
                self.earned_readout.set(earned_share(&moving, masked));
            }
            let mut still = batch.mask_weights(&v.motion_masks, false);
            still.truncate(n_u);
            let share = combined.expect(DYNAMIC_SHARE).slice([0..n_u, 0..1]);
            let short =
                losses::moving_dynamic_share(share.clone(), moving, crate::config::MOVING_SHARE_FLOOR);
            let held = short + losses::still_dynamic_share(share, still);
            loss = loss + held * (wts.moving_dynamic * decay);
        }
        // Monocular disparity, up to an unknown scale and shift per frame: one frame's rays only.
        if let (Some(disp), true, 1) = (&v.disparity[k], wts.depth > 0.0, batch.groups.len()) {
            let prior: Vec<f32> = batch.pixels.iter().map(|&p| disp[p as usize]).collect();
            if let Some(l) = losses::scale_shift_invariant(dyn_only.expect(DISPARITY), &prior)? {
                loss = loss + l * (wts.depth * decay);
            }
        }

        // The flowed points integrated with the render weights held fixed, for the part of the
        // projected-flow term that trains the scene flow alone (`flow_detach_weights`).
        let flow_render = (wts.optical_flow > 0.0 && through < 1.0).then(|| {
            let flowed = Component::channels_only(dy.sigma.clone().detach())
                .with(X_NEXT, x_next.clone())
                .with(X_PREV, x_prev.clone());
            self.render(rays, &samples, &[flowed])
        });
        // The projected-flow term reads these renders, weighted: the flowed points integrated
        // with the render weights (`through`) and with them detached (the rest).
        let projected: Vec<(&RenderOutput, f64)> =
            [(Some(&dyn_only), through), (flow_render.as_ref(), 1.0 - through)]
                .into_iter()
                .filter_map(|(r, w)| r.filter(|_| w > 0.0).map(|r| (r, w)))
                .collect();

        // The dynamic field's effective density (gate included), colour and each sample's march
        // interval in the ray parameter t, for the consistency term against the neighbour's
        // time. The render's interval is a distance, δ·|d|: directions have z = −1, so it is
        // 1 to 1.10 times this at a 40° field of view.
        let consistency_from = (wts.field_consistency > 0.0).then(|| {
            let deltas = samples
                .t_end
                .iter()
                .zip(&samples.t_start)
                .map(|(e, s)| e - s)
                .collect();
            (
                gate.clone() * dy.sigma.clone(),
                dy.rgb.clone(),
                tensor(deltas, 1, dev),
            )
        });
        // Neighbouring frames: warped renders, disocclusion weights, cycle, flow and consistency
        // terms.
        let (warp_to, warp_weight) = pick_neighbours(
            neighbours(k, v.frames.len(), v.camera_path.is_jumping()),
            self.cfg.warp_neighbours,
            rng,
        );
        for (j, forward) in warp_to {
            let (flow, prob, x_j, flowed) = if forward {
                (
                    flow_next.clone(),
                    dy.extras.expect(PROB_NEXT),
                    x_next.clone(),
                    X_NEXT,
                )
            } else {
                (
                    flow_prev.clone(),
                    dy.extras.expect(PROB_PREV),
                    x_prev.clone(),
                    X_PREV,
                )
            };
            loss = loss
                + self.warp_terms(
                    dynamic,
                    &batch,
                    &samples,
                    dirs,
                    (j, forward),
                    (flow, prob, x_j),
                    consistency_from.as_ref(),
                )? * warp_weight;
            // Projected scene flow against the 2-D optical flow of this pixel.
            let prior = if forward { &v.flow_fwd[k] } else { &v.flow_bwd[k] };
            if let (Some(of), true) = (prior, wts.optical_flow > 0.0) {
                let w = ds.views[v.frames[k]].image.width;
                let mut tgt = Vec::with_capacity(2 * r_n);
                let mut mask = Vec::with_capacity(r_n);
                for &p in &batch.pixels {
                    let (i, jj) = ((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
                    let q = p as usize;
                    tgt.extend([i + of.flow[2 * q], jj + of.flow[2 * q + 1]]);
                    mask.push(of.mask[q]);
                }
                let camera = &ds.views[v.frames[j]].camera;
                for &(render, w) in &projected {
                    let l = losses::optical_flow(
                        render.expect(flowed),
                        render.opacity.clone(),
                        ds.ndc.as_ref(),
                        camera,
                        tgt.clone(),
                        mask.clone(),
                    )?;
                    loss = loss + l * (w * wts.optical_flow * decay * warp_weight as f64);
                }
            }
        }
        if !v.camera_path.is_jumping() {
            loss = loss + self.scene_flow_priors(dy, x, &x_next, &x_prev, &samples);
        }
        if wts.entropy > 0.0 {
            loss = loss + losses::entropy(b_s * gate) * wts.entropy;
        }
        if wts.sparsity > 0.0 {
            let sparse = span("nsff_sparsity", || self.sparsity(dynamic, v.times[k], rng))?;
            loss = loss + sparse * wts.sparsity;
        }
        let mut static_samples = 0;
        // The static batch draws from outside the motion masks; a jumping camera has none.
        if self.cfg.static_batch
            && !v.camera_path.is_jumping()
            && let Some((loss_s, _, _, n)) = self.static_batch(false, rng)?
        {
            loss = loss + loss_s;
            static_samples = n;
        }
        // Ray and sample counts of the space-time batch (what its ray count adapts to).
        let m = read_scalar(mse_cb.inner(), "loss")?;
        Ok(Some((loss, stats(m, r_n, s_n), static_samples)))
    }

    /// The terms towards neighbouring frame `j` (the next frame when `forward`): the photometric
    /// loss of the warped render (the dynamic field at `j`'s time, at the points flowed there),
    /// weighted by visibility Ŵ = Σ sg(w)·(1 − p) with p towards `j` (gradients reach p only),
    /// the cycle term at `j` and the disocclusion regulariser; with `consistency` (this frame's
    /// effective dynamic density `[S, 1]`, colour `[S, 3]` and march intervals `[S, 1]`) also
    /// [`losses::field_consistency`] against `j`'s at the flowed points. `x_j`: the samples
    /// flowed to `j`.
    #[allow(clippy::too_many_arguments)]
    fn warp_terms(
        &self,
        dynamic: &DynamicField,
        batch: &FrameBatch,
        samples: &RaySamples,
        dirs: &[f32],
        (j, forward): (usize, bool),
        (flow, prob, x_j): (Tensor<2>, Tensor<2>, Tensor<2>),
        consistency: Option<&(Tensor<2>, Tensor<2>, Tensor<2>)>,
    ) -> Result<Tensor<1>> {
        let wts = &self.cfg.weights;
        let dj = query_dynamic(dynamic, x_j, self.video.times[j], dirs);
        let warped = self.render(
            &batch.rays,
            samples,
            &[Component::new(dj.sigma.clone(), dj.rgb.clone())],
        );
        let vis = self
            .render(
                &batch.rays,
                samples,
                &[Component::channels_only(dj.sigma.clone().detach())
                    .with(VISIBLE, prob.clone().neg() + 1.0)],
            )
            .expect(VISIBLE);
        let mut loss = losses::wmse(warped.rgb, batch.target.clone(), vis) * wts.dynamic_photo;
        let back = dj.extras.expect(if forward { FLOW_PREV } else { FLOW_NEXT });
        loss = loss + losses::cycle(flow, back, prob.clone()) * wts.cycle + prob.abs().mean() * wts.prob_reg;
        if let Some((density, rgb, deltas)) = consistency {
            let there = (dj.extras.expect(GATE) * dj.sigma.clone(), dj.rgb.clone());
            loss = loss
                + losses::field_consistency((density.clone(), rgb.clone()), there, deltas.clone())
                    * wts.field_consistency;
        }
        Ok(loss)
    }

    /// Scene-flow priors: small, temporally smooth (f_next + f_prev ≈ 0) and spatially smooth
    /// along rays, measured in Euclidean space (NDC flows are converted first).
    fn scene_flow_priors(
        &self,
        dy: &FieldOutputs,
        x: &Tensor<2>,
        x_next: &Tensor<2>,
        x_prev: &Tensor<2>,
        samples: &RaySamples,
    ) -> Tensor<1> {
        let wts = &self.cfg.weights;
        let (flow_next, flow_prev) = (dy.extras.expect(FLOW_NEXT), dy.extras.expect(FLOW_PREV));
        let (fn_e, fp_e) = match &self.video.dataset.ndc {
            Some(ndc) => {
                let xe = geometry::ndc_to_world(x.clone(), ndc);
                (
                    geometry::ndc_to_world(x_next.clone(), ndc) - xe.clone(),
                    geometry::ndc_to_world(x_prev.clone(), ndc) - xe,
                )
            }
            None => (flow_next.clone(), flow_prev.clone()),
        };
        let mut loss = losses::min_flow(flow_next, flow_prev) * wts.min_flow
            + losses::temporal_smoothness(fn_e.clone(), fp_e.clone()) * wts.smooth;
        if let Some(spatial) = losses::spatial_smoothness(fn_e, fp_e, &losses::adjacent_pairs(samples, 0.95))
        {
            loss = loss + spatial * wts.smooth;
        }
        loss
    }

    /// [`losses::sparsity`] (unweighted) at `sparsity_points` random points at time `time`:
    /// drawn from occupied cells when there is a grid (the rest of the box is skipped by
    /// rendering anyway), else uniformly in the box.
    fn sparsity(&self, dynamic: &DynamicField, time: f32, rng: &mut StdRng) -> Result<Tensor<1>> {
        let [lo, hi] = self.model.bounds.aabb;
        let mut pos = Vec::with_capacity(3 * self.cfg.sparsity_points);
        for _ in 0..self.cfg.sparsity_points {
            let mut p = [0.0f32; 3];
            for _ in 0..8 {
                p = std::array::from_fn(|a| lo[a] + (hi[a] - lo[a]) * rng.random::<f32>());
                if self
                    .model
                    .occupancy
                    .as_ref()
                    .is_none_or(|g| g.at(time).is_occupied(p))
                {
                    break;
                }
            }
            pos.extend(p);
        }
        let n = pos.len() / 3;
        let x = tensor(pos, 3, &self.device);
        let st = self.model.fields.static_field.density(x.clone(), None);
        let dy = dynamic.density(x, Some(crate::field::time_column(time, n, &self.device)));
        let step = match &self.model.occupancy {
            Some(_) => self.model.settings.march.step,
            // Stratified samples: their mean spacing.
            None => (self.model.bounds.far - self.model.bounds.near) / self.cfg.samples as f32,
        };
        let (b_s, gate) = (st.extras.expect(BLEND), dy.extras.expect(GATE));
        Ok(losses::sparsity(b_s, gate, dy.sigma, step))
    }

    /// The static batch: the static pipeline's step on `n_static_rays` pixels outside the motion
    /// masks (and, with `masked_static`, inside them). Its loss, loss value, ray and sample
    /// counts; `None` when no ray has samples.
    fn static_batch(
        &self,
        warm_up: bool,
        rng: &mut StdRng,
    ) -> Result<Option<(Tensor<1>, f64, usize, usize)>> {
        let masked_static = self.static_batch_masked(warm_up);
        let pixels = self.still_pixels(self.n_static_rays.max(1), masked_static, rng);
        let (rays, target) = self.pixel_rays(&pixels);
        // The masked rays in `pixel_rays`' order, for `masked_static`'s robust weights.
        let masks = &self.video.motion_masks;
        let masked: Option<Vec<bool>> = (masked_static > 0.0).then(|| {
            (pixels.iter().enumerate())
                .flat_map(|(k, ps)| ps.iter().map(move |&p| masks[k][p as usize]))
                .collect()
        });
        let (target, background) = self.static_targets(&pixels, target, rng);
        let still = span("nsff_static_batch", || {
            self.static_photometric(&rays, target, &background, masked.as_deref(), rng)
        })?;
        Ok(still.map(|(loss, m, n)| (loss, m, rays.len(), n)))
    }

    /// The static batch's targets (`[R, 3]` from `rgb`, `[R * 3]` in `pixels`' order) and the
    /// background to render them over: with `static_random_background` on RGBA frames, each
    /// ray's target is recomposited over a random colour (the static pipeline's
    /// [`nerf::trainer::random_background`]), so the static field cannot hide density of the
    /// background's colour where a frame sees the background through it.
    fn static_targets(
        &self,
        pixels: &[Vec<u32>],
        mut rgb: Vec<f32>,
        rng: &mut StdRng,
    ) -> (Tensor<2>, Background) {
        let (v, dev) = (&self.video, &self.device);
        let base = v.dataset.background;
        let (Some(base), true) = (base, self.cfg.static_random_background) else {
            return (tensor(rgb, 3, dev), Background::from_option(base));
        };
        let alpha = (pixels.iter().enumerate()).flat_map(|(k, ps)| {
            let alpha = v.dataset.views[v.frames[k]].alpha.as_deref();
            ps.iter().map(move |&p| alpha.map_or(1.0, |a| a[p as usize]))
        });
        let bg = nerf::trainer::random_background(&mut rgb, alpha, base, rng);
        (tensor(rgb, 3, dev), Background::PerRay(tensor(bg, 3, dev)))
    }

    /// The static batch's `masked_static` now: 0 after the warm-up with
    /// `masked_static_warm_up_only`, 0 during it with `masked_static_after_warm_up`.
    fn static_batch_masked(&self, warm_up: bool) -> f32 {
        let c = &self.cfg;
        if (!warm_up && c.masked_static_warm_up_only) || (warm_up && c.masked_static_after_warm_up) {
            0.0
        } else {
            c.masked_static
        }
    }

    /// Per frame, `n` pixels in all drawn at random outside the frame's motion mask; a masked
    /// pixel is taken too with probability `masked_share`.
    fn still_pixels(&self, n: usize, masked_share: f32, rng: &mut StdRng) -> Vec<Vec<u32>> {
        let v = &self.video;
        let mut per_frame: Vec<Vec<u32>> = vec![Vec::new(); v.frames.len()];
        for _ in 0..n {
            // A few tries per ray: masks cover a small share of each frame.
            for _ in 0..8 {
                let k = rng.random_range(0..v.frames.len());
                let img = &v.dataset.views[v.frames[k]].image;
                let p = rng.random_range(0..img.width * img.height);
                if !v.motion_masks[k][p as usize]
                    || (masked_share > 0.0 && rng.random::<f32>() < masked_share)
                {
                    per_frame[k].push(p);
                    break;
                }
            }
        }
        per_frame
    }

    /// The rays of `pixels` (per frame) and their colours (`[n * 3]`).
    fn pixel_rays(&self, pixels: &[Vec<u32>]) -> (Rays, Vec<f32>) {
        let v = &self.video;
        let n = pixels.iter().map(Vec::len).sum();
        let mut rays = Rays::with_capacity(n);
        let mut target = Vec::with_capacity(3 * n);
        for (k, pixels) in pixels.iter().enumerate().filter(|(_, p)| !p.is_empty()) {
            let view = &v.dataset.views[v.frames[k]];
            rays.extend(&v.dataset.rays_for(&view.camera, pixels.iter().copied()));
            target.extend(pixel_colours(view, pixels));
        }
        (rays, target)
    }

    /// The static field alone on `rays` against `target` (`[R, 3]`): the static pipeline's
    /// photometric loss, its value, and the sample count. With `masked` (per ray, inside the
    /// motion masks) the masked rays weigh [`losses::robust_ray_weights`] (`masked_static`).
    /// `None` when no ray has samples.
    fn static_photometric(
        &self,
        rays: &Rays,
        target: Tensor<2>,
        background: &Background,
        masked: Option<&[bool]>,
        rng: &mut StdRng,
    ) -> Result<Option<(Tensor<1>, f64, usize)>> {
        // Rays of mixed times (the static batch), or a model without time bins: the union.
        let samples = self.samples(rays, None, rng);
        let s_n = samples.num_samples();
        if s_n == 0 {
            return Ok(None);
        }
        let x = tensor(samples.positions(rays), 3, &self.device);
        let dirs = samples.per_sample3(&rays.viewdirs());
        let st = self.model.fields.static_field.query(FieldQuery::new(x, &dirs));
        let out = self.render_over(rays, &samples, &[Component::new(st.sigma, st.rgb)], background);
        let photo = match masked {
            Some(m) if m.iter().any(|&m| m) => robust_mse(out.rgb, target, m, self.cfg.masked_static_scale)?,
            _ => losses::mse(out.rgb, target),
        };
        let m = read_scalar(photo.clone().inner(), "loss")?;
        Ok(Some((photo, m, s_n)))
    }

    /// Trains until a budget is reached (the static pipeline's loop).
    pub fn train(&mut self, show_progress: bool) -> Result<()> {
        let v = &self.video;
        let motion = match v.moving_fraction {
            None => String::new(),
            Some(f) => format!(
                "; independent motion in {:.2}% of flow pixels (motion masks{}: {:.1}%)",
                100.0 * f,
                if v.masks_given {
                    ", given with the video"
                } else {
                    ""
                },
                100.0 * v.mask_fraction()
            ),
        };
        let header = format!(
            "{}; {} frames; {}{motion}: dynamic field {}",
            v.dataset.describe(),
            v.frames.len(),
            v.camera_path.describe(),
            if self.has_dynamic() {
                "on"
            } else {
                "off (static scene)"
            }
        );
        nerf::train_loop::train(self, &header, show_progress)
    }

    fn rollback(&mut self) -> Result<()> {
        if has_checkpoint(&self.run_dir) {
            let (s, path) = Sections::read_for_resume(&self.run_dir)?;
            self.restore(&s, &path)
        } else {
            let dynamic = self.has_dynamic();
            let bounds = self.model.bounds.clone();
            self.model = NsffModel::new(&self.cfg, bounds, self.video.times.clone(), dynamic, &self.device);
            self.optim = Optimizer::new(&self.cfg.base);
            self.step = 0;
            Ok(())
        }
    }
}

/// The least rise of the occupied fraction (of the whole grid) that ends a warm-up early, so
/// that small grids' noise does not.
const WARM_UP_EXIT_MIN_RISE: f32 = 0.1;

/// Channels of the training renders beyond colour: the flowed points Σw(x + f) towards the next
/// and previous frame, the disparity-like value of the depth prior, and the warped render's
/// visibility weight.
const X_NEXT: &str = "x_next";
const X_PREV: &str = "x_prev";
const DISPARITY: &str = "disparity";
const VISIBLE: &str = "visible";

/// The neighbours of frame `k` (of `frames`) that a step's warp terms compare it with, each
/// with whether it is the next frame: none for a jumping camera, whose neighbours are unrelated
/// views.
fn neighbours(k: usize, frames: usize, jumping: bool) -> Vec<(usize, bool)> {
    if jumping {
        return Vec::new();
    }
    let next = (k + 1 < frames).then_some((k + 1, true));
    let prev = (k > 0).then(|| (k - 1, false));
    next.into_iter().chain(prev).collect()
}

/// At most `keep` of `all` neighbours, drawn at random when there are more, and the weight that
/// keeps their terms' sum the same in expectation (all / kept). Draws nothing from `rng` when all
/// are kept (NSFF's `keep` 2, or a jumping camera's none), so those runs' random streams are as
/// before the option. `keep` 0, which `validate` refuses, keeps all rather than dividing by zero.
fn pick_neighbours(mut all: Vec<(usize, bool)>, keep: usize, rng: &mut StdRng) -> (Vec<(usize, bool)>, f32) {
    let n = all.len();
    if keep >= n || keep == 0 {
        return (all, 1.0);
    }
    all.shuffle(rng);
    all.truncate(keep);
    (all, n as f32 / keep as f32)
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

/// Colours (`[P * 3]`) of a view's pixels.
fn pixel_colours(view: &nerf_data::View, pixels: &[u32]) -> Vec<f32> {
    pixels
        .iter()
        .flat_map(|&p| view.image.pixel(p as usize)[..3].to_vec())
        .collect()
}

/// [`BlendReadout`] of per-sample blends `blend` on rays split by `offsets`, `moving` telling
/// which rays are inside the motion masks (a side without rays reads 0).
fn blend_readout(blend: &[f32], offsets: &[u32], moving: &[bool]) -> BlendReadout {
    let (mut sum, mut count) = ([0.0f64; 2], [0usize; 2]);
    for (r, w) in offsets.windows(2).enumerate() {
        let top = blend[w[0] as usize..w[1] as usize]
            .iter()
            .fold(0.0f32, |a, &b| a.max(b));
        let side = usize::from(moving[r]);
        sum[side] += f64::from(top);
        count[side] += 1;
    }
    let mean = |i: usize| (sum[i] / count[i].max(1) as f64) as f32;
    BlendReadout {
        moving: mean(1),
        still: mean(0),
    }
}

/// Share of the masked rays (`masked`, 1 inside) that `earned` keeps (1 where the dynamic-only
/// render fits better); `None` without masked rays.
fn earned_share(earned: &[f32], masked: &[f32]) -> Option<f32> {
    let n = masked.iter().sum::<f32>();
    (n > 0.0).then(|| earned.iter().sum::<f32>() / n)
}

/// Squared colour error per ray of `rgb` `[R, 3]` against `target` `[R, 3]`, detached and
/// read back (R values).
fn ray_errors(rgb: &Tensor<2>, target: &Tensor<2>) -> Result<Vec<f32>> {
    let err = (rgb.clone().detach() - target.clone())
        .powf_scalar(2.0)
        .sum_dim(1);
    Ok(nerf_core::readback::read_back(err.inner(), "ray errors")?)
}

/// The mean squared error of `rgb` against `target` (`[R, 3]`), each ray weighted by
/// [`losses::robust_ray_weights`] of its error (held fixed) given which rays are `masked`.
fn robust_mse(rgb: Tensor<2>, target: Tensor<2>, masked: &[bool], scale: f32) -> Result<Tensor<1>> {
    let errors = ray_errors(&rgb, &target)?;
    let w = losses::robust_ray_weights(&errors, masked, scale);
    let dev = rgb.device();
    Ok(losses::wmse(rgb, target, tensor(w, 1, &dev)))
}

fn stats(mse: f64, rays: usize, samples: usize) -> StepStats {
    StepStats {
        loss: mse,
        psnr: psnr_from_mse(mse),
        rays,
        samples,
    }
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
    fn train_step(&mut self) -> Result<Option<StepStats>> {
        NsffTrainer::train_step(self)
    }
    fn save(&self) -> Result<()> {
        NsffTrainer::save(self)
    }
    fn lr(&self) -> f64 {
        NsffTrainer::lr(self)
    }
    fn rollback(&mut self) -> Result<()> {
        NsffTrainer::rollback(self)
    }
    fn quick_eval(&mut self) -> Result<f64> {
        let views = crate::eval::quick_views(&self.video.dataset);
        let ds = &self.video.dataset;
        let (result, _) =
            crate::eval::evaluate_with_depth(&self.model, ds, &views, false, None, None, &self.device)?;
        Ok(result.mean_psnr)
    }
    fn take_note(&mut self) -> Option<String> {
        self.note.take()
    }
    fn status(&self) -> String {
        let blend = self.blend_readout.get().map_or(String::new(), |b| {
            let earned = self.earned_readout.get().map_or(String::new(), |e| {
                format!(" (earned on {:.0}% of the moving)", 100.0 * e)
            });
            format!(", blend {:.3} moving / {:.3} still{earned}", b.moving, b.still)
        });
        let grid = self
            .model
            .occupancy
            .as_ref()
            .map_or(String::new(), |o| match o.num_bins() {
                1 => format!(", {:.1}% occupied", 100.0 * o.occupied_fraction()),
                _ => format!(
                    ", {:.1}% occupied ({:.1}% per time bin)",
                    100.0 * o.occupied_fraction(),
                    100.0 * o.mean_bin_fraction()
                ),
            });
        grid + &blend
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf::config::Preset;
    use nerf_core::readback::host;
    use nerf_data::LoadOptions;

    fn tables(grids: Vec<std::sync::Arc<nerf_core::encoding::HashGrid>>) -> Vec<Vec<f32>> {
        grids.iter().map(|g| g.table()).collect()
    }

    #[test]
    fn the_blend_readout_averages_each_ray_s_largest_blend_per_side() {
        // Rays: [0.1, 0.7] moving, [0.2] still, [] moving (no samples: reads 0), [0.5, 0.3] still.
        let blend = [0.1, 0.7, 0.2, 0.5, 0.3];
        let offsets = [0, 2, 3, 3, 5];
        let b = blend_readout(&blend, &offsets, &[true, false, true, false]);
        assert!((b.moving - (0.7 + 0.0) / 2.0).abs() < 1e-6, "{b:?}");
        assert!((b.still - (0.2 + 0.5) / 2.0).abs() < 1e-6, "{b:?}");
        let none = blend_readout(&blend[..2], &offsets[..2], &[true]);
        assert_eq!(none.still, 0.0);
    }

    #[test]
    fn the_earned_share_counts_the_kept_rays_among_the_masked() {
        assert_eq!(
            earned_share(&[1.0, 0.0, 0.0, 1.0], &[1.0, 1.0, 0.0, 1.0]),
            Some(2.0 / 3.0)
        );
        assert_eq!(earned_share(&[0.0; 3], &[1.0, 0.0, 1.0]), Some(0.0));
        assert_eq!(earned_share(&[0.0; 2], &[0.0; 2]), None);
    }

    #[test]
    fn ray_errors_sum_the_squared_colour_differences() {
        let dev = Device::default();
        let t = |v: &[f32]| tensor(v.to_vec(), 3, &dev);
        let target = t(&[0.5, 0.5, 0.5, 0.0, 0.0, 0.0]);
        let combined = ray_errors(&t(&[0.9, 0.5, 0.5, 0.1, 0.0, 0.0]), &target).unwrap();
        let dynamic = ray_errors(&t(&[0.6, 0.6, 0.5, 0.0, 0.3, 0.0]), &target).unwrap();
        for (got, want) in combined.iter().chain(&dynamic).zip([0.16, 0.01, 0.02, 0.09]) {
            assert!((got - want).abs() < 1e-6, "{combined:?} {dynamic:?}");
        }
        // Ray 0: the dynamic render nearer; ray 1: the combined one.
        let better: Vec<bool> = dynamic.iter().zip(&combined).map(|(d, c)| d < c).collect();
        assert_eq!(better, vec![true, false]);
    }

    /// The masked rays of a static batch weigh 1 / (1 + e / τ), τ = scale × the unmasked rays'
    /// mean error, in a mean over the weights; against a float64 recomputation.
    #[test]
    fn robust_mse_matches_a_float64_recomputation() {
        let dev = Device::default();
        let rgb = [0.2f32, 0.4, 0.6, 0.5, 0.5, 0.5, 0.9, 0.1, 0.3, 0.0, 0.7, 0.2];
        let target = [0.25f32, 0.4, 0.5, 0.5, 0.6, 0.45, 0.1, 0.1, 0.9, 0.05, 0.65, 0.2];
        let masked = [false, false, true, true];
        let got = robust_mse(
            tensor(rgb.to_vec(), 3, &dev),
            tensor(target.to_vec(), 3, &dev),
            &masked,
            2.0,
        )
        .unwrap();
        let got = nerf_core::readback::read_back(got.inner(), "loss").unwrap()[0] as f64;
        let e: Vec<f64> = (0..4)
            .map(|r| {
                (0..3)
                    .map(|c| (rgb[3 * r + c] as f64 - target[3 * r + c] as f64).powi(2))
                    .sum()
            })
            .collect();
        let tau = 2.0 * (e[0] + e[1]) / 2.0;
        let w: Vec<f64> = (0..4)
            .map(|r| if masked[r] { 1.0 / (1.0 + e[r] / tau) } else { 1.0 })
            .collect();
        let want = (0..4).map(|r| w[r] * e[r]).sum::<f64>() / (3.0 * w.iter().sum::<f64>());
        assert!((got - want).abs() < 1e-6 * want.max(1e-3), "{got} against {want}");
        // Ray 2 is far off (e = 1.0), so the loss is below the unweighted mean.
        let plain = e.iter().sum::<f64>() / 12.0;
        assert!(got < 0.5 * plain, "{got} against the unweighted {plain}");
    }

    /// One neighbour of two: drawn at random (both directions come up), weighted 2 so the sum
    /// of the terms keeps its expectation; where only one exists, or both are kept, weight 1.
    #[test]
    fn one_warp_neighbour_is_drawn_and_reweighted() {
        let mut rng = StdRng::seed_from_u64(3);
        let both = neighbours(5, 10, false);
        assert_eq!(pick_neighbours(both.clone(), 2, &mut rng), (both.clone(), 1.0));
        let mut seen = Vec::new();
        for _ in 0..32 {
            let (kept, w) = pick_neighbours(both.clone(), 1, &mut rng);
            assert_eq!((kept.len(), w), (1, 2.0));
            assert!(both.contains(&kept[0]));
            seen.push(kept[0].1);
        }
        assert!(seen.contains(&true) && seen.contains(&false), "{seen:?}");
        let first = neighbours(0, 10, false);
        assert_eq!(pick_neighbours(first.clone(), 1, &mut rng), (first, 1.0));
    }

    /// With the render weights detached, the projected-flow term reaches the scene flow's own
    /// grid and not the dynamic field's: that grid gets the gradient it gets without the term.
    /// With a share of the term through the weights, the term reaches it too.
    #[test]
    fn the_detached_flow_term_reaches_the_flow_grid_only() {
        let (dir, mut t) = space_time_trainer("nsff-flow-share", |cfg| {
            cfg.flow_levels = 3;
            cfg.flow_detach_weights = true;
        });
        assert!(t.video.flow_fwd.iter().any(Option::is_some), "no optical flow");
        let grids = t.model.fields.dynamic.as_ref().unwrap().host_params();
        assert_eq!(grids.len(), 2, "the dynamic grid and the flow grid");
        // (dynamic grid, flow grid) gradients of one space-time step's loss, same draws.
        let mut grads = |optical_flow: f64, share: f32| {
            t.cfg.weights.optical_flow = optical_flow;
            t.cfg.flow_weights_share = share;
            let mut g = step_grads(&t, &grids, 11);
            let flow = g.pop().unwrap();
            (g.pop().unwrap(), flow)
        };
        let (dyn_without, flow_without) = grads(0.0, 0.0);
        let (dyn_detached, flow_detached) = grads(0.5, 0.0);
        let (dyn_through, _) = grads(0.5, 0.5);
        let diff = max_abs_diff;
        let scale = max_abs(&dyn_without);
        assert!(scale > 0.0, "no gradient reached the dynamic grid");
        assert!(
            diff(&dyn_detached, &dyn_without) <= 1e-6 * scale,
            "the detached term moved the dynamic grid"
        );
        assert!(
            diff(&flow_detached, &flow_without) > 0.0,
            "the term did not reach the flow grid"
        );
        assert!(
            diff(&dyn_through, &dyn_without) > 1e-4 * scale,
            "the share through the weights did not reach the dynamic grid"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The consistency term compares the dynamic field with itself along the scene flow: it
    /// reaches the dynamic grid and not the static field.
    #[test]
    fn the_consistency_term_reaches_the_dynamic_field_only() {
        reaches_the_dynamic_field_only("nsff-consistency", [0.0, 1.0], |cfg, w| {
            cfg.weights.field_consistency = w
        });
    }

    /// One step's static and dynamic grid gradients with a term at `weights[0]` and at
    /// `weights[1]` (`set` applies one): the same static gradient, a different dynamic one.
    fn reaches_the_dynamic_field_only(name: &str, weights: [f64; 2], set: impl Fn(&mut NsffConfig, f64)) {
        let (dir, mut t) = space_time_trainer(name, |_| {});
        // A new field is nearly the same everywhere and at every time, so the term and its
        // gradient start near zero: train it a little first.
        for _ in 0..40 {
            t.train_step().unwrap();
        }
        let mut grads = |weight: f64| {
            set(&mut t.cfg, weight);
            static_and_dynamic_grads(&t, 7)
        };
        let (static_without, dynamic_without) = grads(weights[0]);
        let (static_with, dynamic_with) = grads(weights[1]);
        assert!(
            max_abs(&static_without) > 0.0,
            "no gradient reached the static grid"
        );
        unmoved(&static_with, &static_without, "the term moved the static grid");
        moved(
            &dynamic_with,
            &dynamic_without,
            "the term did not reach the dynamic grid",
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Once the moving term's span is over, a blend whose readouts on the moving rays averaged
    /// below `reopen_blend_below` over the span's last quarter is reopened, once: the blend reads
    /// b ≈ 0.05 everywhere, the span starts again, a note says so, and training goes on. One
    /// that read above it is left as it is; a rollback to before the reopening undoes it.
    #[test]
    fn a_shut_blend_is_reopened_once_after_the_moving_span() {
        let (dir, mut t) = space_time_trainer("nsff-reopen", |cfg| {
            cfg.blend_init_logit = -20.0;
            cfg.base.steps = 10;
            cfg.base.time_budget = None;
            cfg.moving_dynamic_until = 0.5;
        });
        assert!(t.cfg.weights.moving_dynamic > 0.0 && t.cfg.reopen_blend_below > 0.0);
        let blend = |t: &NsffTrainer| {
            let x = tensor(vec![0.1, -0.2, 0.3, -0.4, 0.2, 0.0], 3, &t.device);
            let q = t.model.fields.static_field.density(x, None);
            nerf_core::readback::read_back(q.extras.expect(BLEND), "blend").unwrap()
        };
        assert!(blend(&t).iter().all(|&b| b < 1e-6), "the blend starts shut");
        t.save().unwrap();
        // An open blend's readouts: left as it is.
        t.step = 5;
        t.shut_watch.set((0.9 + 0.7, 2));
        t.reopen_blend_if_shut();
        assert_eq!(t.cfg.blend_reopened_at, None);
        assert!(t.note.is_none() && blend(&t).iter().all(|&b| b < 1e-6));
        // A shut one, before the span is over: not yet.
        t.step = 4;
        t.shut_watch.set((0.001, 1));
        t.reopen_blend_if_shut();
        assert_eq!(t.cfg.blend_reopened_at, None);
        assert_eq!(t.shut_watch.get(), (0.001, 1), "the readouts were dropped");
        // Over: reopened.
        t.step = 5;
        t.reopen_blend_if_shut();
        assert_eq!(t.cfg.blend_reopened_at, Some(0.5));
        assert!(t.note.take().is_some_and(|n| n.contains("reopened at step 5")));
        let want = 1.0 / (1.0 + 3.0f32.exp());
        assert!(
            blend(&t).iter().all(|&b| (b - want).abs() < 1e-6),
            "{:?}",
            blend(&t)
        );
        assert!(t.in_moving_span(), "the span did not start again");
        t.train_step()
            .unwrap()
            .expect("a finite step after the reopening");
        // Once per run.
        t.shut_watch.set((0.001, 1));
        t.step = 10;
        t.reopen_blend_if_shut();
        assert_eq!(t.cfg.blend_reopened_at, Some(0.5));
        assert!(!t.in_moving_span(), "the span went on past its length");
        // A rollback to the checkpoint from before the reopening: shut, and not yet reopened.
        t.rollback().unwrap();
        assert_eq!(t.cfg.blend_reopened_at, None);
        assert!(blend(&t).iter().all(|&b| b < 1e-6));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Gradients `with` a term equal those `without` it, to 1e-6 of their largest.
    fn unmoved(with: &[f32], without: &[f32], what: &str) {
        assert!(max_abs_diff(with, without) <= 1e-6 * max_abs(without), "{what}");
    }

    /// Gradients `with` a term differ from those `without` it by over 1e-4 of their largest.
    fn moved(with: &[f32], without: &[f32], what: &str) {
        assert!(max_abs_diff(with, without) > 1e-4 * max_abs(without), "{what}");
    }

    /// A video in the fast preset takes its scene flow from its own grid, trained by the
    /// projected-flow term mostly through detached render weights, its learning rate ends at
    /// 0.3 × its start and its depth prior weighs 0.01; the vanilla preset and a jumping camera
    /// (no optical flow to train it) keep the shared head and NSFF's weights.
    #[test]
    fn a_video_s_scene_flow_has_its_own_grid() {
        let (dir, mut cfg, video) = temp_video("nsff-flow-grid");
        assert_eq!(cfg.flow_levels, 0, "before the video is known");
        let mut vanilla = cfg.clone();
        cfg.dynamic = DynamicMode::On;
        cfg.adapt_to(&video.dataset, video.frames.len());
        assert_eq!(cfg.flow_levels, 4);
        assert!(cfg.flow_detach_weights);
        assert_eq!((cfg.flow_weights_share, cfg.weights.optical_flow), (0.1, 0.2));
        assert_eq!(
            (cfg.base.lr, cfg.base.lr_final),
            (1e-2, 0.3 * 1e-2),
            "a video's rate ends higher"
        );
        assert_eq!(
            cfg.weights.depth, 0.01,
            "a video's depth prior at a quarter of NSFF's"
        );
        assert!(cfg.validate().is_ok());
        vanilla.base.preset = Preset::Vanilla;
        (vanilla.base.lr, vanilla.base.lr_final) = Preset::Vanilla.learning_rates();
        vanilla.adapt_to(&video.dataset, video.frames.len());
        assert_eq!(vanilla.flow_levels, 0);
        assert_eq!(
            (vanilla.base.lr, vanilla.base.lr_final),
            (5e-4, 5e-5),
            "not screened"
        );
        assert_eq!(vanilla.weights.depth, 0.04, "NSFF's weight");
        assert!(
            vanilla.validate().is_ok(),
            "the vanilla preset refuses a flow grid"
        );
        let t = NsffTrainer::new(cfg, video, &dir.join("run")).unwrap();
        let grids = t.model.fields.dynamic.as_ref().unwrap().host_params();
        assert_eq!(grids.len(), 2, "the dynamic grid and the flow grid");
        let _ = std::fs::remove_dir_all(&dir);
        let (dir, cfg, _) = jumping_scene("nsff-flow-grid-jumping");
        assert_eq!(cfg.flow_levels, 0);
        assert!(!cfg.flow_detach_weights);
        assert_eq!(
            cfg.weights.optical_flow,
            crate::config::LossWeights::default().optical_flow
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A video's step warps towards both neighbours (one at either end); a jumping camera's
    /// towards none.
    #[test]
    fn warp_neighbours_are_a_video_s_only() {
        assert_eq!(neighbours(0, 5, false), vec![(1, true)]);
        assert_eq!(neighbours(2, 5, false), vec![(3, true), (1, false)]);
        assert_eq!(neighbours(4, 5, false), vec![(3, false)]);
        assert_eq!(neighbours(0, 1, false), vec![]);
        for k in 0..5 {
            assert_eq!(neighbours(k, 5, true), vec![], "frame {k}");
        }
    }

    /// A small generated jumping-camera scene in a fresh temporary folder named after `name`:
    /// the folder, the config adapted to it and the loaded video (run folder `dir/run`).
    fn jumping_scene(name: &str) -> (PathBuf, NsffConfig, Video) {
        let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let data = dir.join("jumping");
        let synth = nerf_synth::SynthConfig::new(nerf_synth::Preset::JumpingMovers)
            .with_size(24, 24)
            .with_views(6, 2);
        nerf_synth::generate(&synth, &data).unwrap();
        let mut cfg = NsffConfig::new(Preset::Fast, data, LoadOptions::default());
        let video = load_video(&cfg, &dir.join("run"), true).unwrap();
        assert!(video.camera_path.is_jumping());
        cfg.adapt_to(&video.dataset, video.frames.len());
        cfg.adapt_to_jumping_camera();
        (dir, cfg, video)
    }

    /// With `error_rays`, a jumping camera's batch draws that share of its rays from the frame's
    /// error map (every ray still scored), and a step records each ray's squared error in its
    /// frame's tile: rays then follow the tiles that rendered worst. A video keeps no map.
    #[test]
    fn error_rays_follow_the_frames_worst_tiles() {
        let (dir, mut cfg, video) = jumping_scene("nsff-error-rays");
        let run_dir = dir.join("run");
        cfg.error_rays = 0.5;
        cfg.static_warm_up = 0.0;
        let mut t = NsffTrainer::new(cfg, video, &run_dir).unwrap();
        t.n_rays = 64;
        let mut rng = StdRng::seed_from_u64(9);
        let batch = t.frame_batch(&mut rng);
        assert_eq!((batch.rays.len(), batch.n_uniform), (64, 64));
        // One step on a fresh model (the same draws): each recorded tile moves from its start
        // (3, above any squared error) towards its rays' errors.
        let frame = batch.frame();
        let mut rng = StdRng::seed_from_u64(9);
        t.step_loss(false, &mut rng).unwrap().expect("a step");
        let map = t.error_map.as_ref().unwrap().borrow();
        let mut rng = StdRng::seed_from_u64(9);
        let again = t.frame_batch(&mut rng);
        // The uniform half is drawn first, so it repeats the step's rays.
        assert_eq!(again.frame(), frame);
        assert_eq!(again.pixels[..32], batch.pixels[..32]);
        let touched = again
            .pixels
            .iter()
            .filter(|&&p| map.tile_error(frame, p) < 3.0)
            .count();
        assert!(touched > 0, "the step recorded no error");
        for &p in &again.pixels {
            let e = map.tile_error(frame, p);
            assert!(e.is_finite() && (0.0..=3.0).contains(&e), "{e}");
        }
        // Draws follow the errors: after recording zero error everywhere but one tile, the
        // error half of a batch lands in that tile.
        drop(map);
        let w = t.video.dataset.views[t.video.frames[frame]].image.width;
        {
            let mut map = t.error_map.as_ref().unwrap().borrow_mut();
            let all: Vec<u32> = (0..w * w).collect();
            for _ in 0..100 {
                map.record(frame, &all, &vec![0.0; all.len()]);
                map.record(frame, &[0], &[1.0]);
            }
        }
        let map = t.error_map.as_ref().unwrap().borrow();
        let drawn = map.sample(frame, 200, &mut rng);
        assert!(
            drawn.iter().all(|&p| p % w < 8 && p / w < 8),
            "outside the hot tile"
        );
        drop(map);

        let (mut cfg, video) = video_scene(&dir);
        cfg.error_rays = 0.5;
        let t = NsffTrainer::new(cfg, video, &run_dir).unwrap();
        assert!(t.error_map.is_none());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A fresh temporary folder `name`-pid and the generated video in it ([`video_scene`]).
    fn temp_video(name: &str) -> (PathBuf, NsffConfig, Video) {
        let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (cfg, video) = video_scene(&dir);
        (dir, cfg, video)
    }

    /// [`temp_video`] with the dynamic field on and the settings adapted to the video.
    fn dynamic_video(name: &str) -> (PathBuf, NsffConfig, Video) {
        let (dir, mut cfg, video) = temp_video(name);
        cfg.dynamic = DynamicMode::On;
        cfg.adapt_to(&video.dataset, video.frames.len());
        (dir, cfg, video)
    }

    /// A trainer on a small video that starts in the space-time phase (no static warm-up), the
    /// dynamic field on, `tweak` applied to its settings; with the temporary folder to remove.
    fn space_time_trainer(name: &str, tweak: impl FnOnce(&mut NsffConfig)) -> (PathBuf, NsffTrainer) {
        let (dir, mut cfg, video) = dynamic_video(name);
        cfg.static_warm_up = 0.0;
        tweak(&mut cfg);
        // One model per test, its settings changed between the steps compared (the device's
        // initialisation draws are shared with tests running beside it).
        let t = NsffTrainer::new(cfg, video, &dir.join("run")).unwrap();
        (dir, t)
    }

    /// The gradients of `grids` from one space-time step's loss, its draws seeded by `seed` (the
    /// same rays and samples on every call), the grids' earlier gradients cleared first.
    fn step_grads(
        t: &NsffTrainer,
        grids: &[std::sync::Arc<nerf_core::encoding::HashGrid>],
        seed: u64,
    ) -> Vec<Vec<f32>> {
        grids.iter().for_each(|g| g.zero_grad());
        let (loss, _, _) = t
            .step_loss(false, &mut StdRng::seed_from_u64(seed))
            .unwrap()
            .unwrap();
        let _ = loss.backward();
        grids.iter().map(|g| g.grad()).collect()
    }

    /// The (static grid, dynamic grid) gradients of one space-time step's loss, its draws
    /// seeded by `seed` ([`step_grads`] over both fields' grids).
    fn static_and_dynamic_grads(t: &NsffTrainer, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let statics = t.model.fields.static_field.host_params();
        let dynamics = t.model.fields.dynamic.as_ref().unwrap().host_params();
        let grids: Vec<_> = statics.iter().chain(&dynamics).cloned().collect();
        let mut g = step_grads(t, &grids, seed);
        (std::mem::take(&mut g[0]), std::mem::take(&mut g[statics.len()]))
    }

    fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
    }

    fn max_abs(g: &[f32]) -> f32 {
        g.iter().fold(0.0, |m, x| m.max(x.abs()))
    }

    /// A small generated video (smooth camera path) under `dir/video`, loaded.
    fn video_scene(dir: &Path) -> (NsffConfig, Video) {
        let data = dir.join("video");
        let synth = nerf_synth::SynthConfig::new(nerf_synth::Preset::Dynamic)
            .with_size(32, 24)
            .with_views(6, 2);
        nerf_synth::generate(&synth, &data).unwrap();
        let cfg = NsffConfig::new(Preset::Fast, data, LoadOptions::default());
        let video = load_video(&cfg, &dir.join("run"), true).unwrap();
        assert!(!video.camera_path.is_jumping());
        (cfg, video)
    }

    /// `carve_unseen` empties part of a dynamic video's grid, and never a cell holding a
    /// surface some training frame saw at its time (the generator's depth maps, independent of
    /// the carve's projection: a flipped image axis fails here); off, nothing is carved. A mover
    /// seen against open background is `nerf_core::occupancy`'s test.
    #[test]
    fn carve_unseen_spares_every_surface_a_frame_saw() {
        let (dir, cfg, video) = dynamic_video("nsff-carve-off");
        let off = NsffTrainer::new(cfg, video, &dir.join("run")).unwrap();
        let grid = off.model.occupancy.as_ref().unwrap().union();
        assert!(grid.carved().iter().all(|&c| !c), "opt-in");
        let _ = std::fs::remove_dir_all(&dir);
        let (dir, mut cfg, video) = dynamic_video("nsff-carve-unseen");
        cfg.carve_unseen = true;
        let scene = nerf_synth::Scene::load(&cfg.base.data).unwrap();
        let t = NsffTrainer::new(cfg, video, &dir.join("run")).unwrap();
        let grid = t.model.occupancy.as_ref().unwrap().union();
        let carved = grid.carved().iter().filter(|&&c| c).count();
        assert!(
            carved > grid.num_cells() / 20,
            "{carved} of {} cells carved",
            grid.num_cells()
        );
        let mut surfaces = 0;
        for &f in &t.video.frames {
            let view = &t.video.dataset.views[f];
            let traced = scene.render(&view.camera, f64::from(view.time.unwrap()));
            let w = view.image.width;
            for (p, &depth) in traced.depth.iter().enumerate() {
                if depth <= 0.0 {
                    continue;
                }
                let d = view.camera.pixel_direction(p as u32 % w, p as u32 / w);
                let eye = view.camera.pose.translation;
                let x: [f32; 3] = std::array::from_fn(|a| (eye[a] + d[a] * f64::from(depth)) as f32);
                if grid.cell_coords(x).is_some() {
                    surfaces += 1;
                    assert!(grid.is_occupied(x), "frame {f} pixel {p}: a seen surface carved");
                }
            }
        }
        assert!(surfaces > 1000, "{surfaces} surface points checked");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The static batch draws masked pixels at `masked_static`, all run long, in the warm-up
    /// only or after it only; at a share s a masked pixel is kept with probability s on each try, so masked
    /// pixels make f·s / (1 − f + f·s) of the draw for a mask fraction f (f at s = 1: uniform).
    #[test]
    fn the_static_batch_draws_masked_pixels_at_its_share() {
        let (dir, cfg, video) = temp_video("nsff-warm-masked");
        assert_eq!(cfg.masked_static, 0.0, "opt-in");
        let mut t = NsffTrainer::new(cfg, video, &dir.join("run")).unwrap();
        assert_eq!(t.static_batch_masked(true), 0.0);
        t.cfg.masked_static = 0.5;
        assert_eq!(t.static_batch_masked(false), 0.5);
        assert_eq!(t.static_batch_masked(true), 0.5);
        t.cfg.masked_static_warm_up_only = true;
        assert_eq!(t.static_batch_masked(false), 0.0);
        assert_eq!(t.static_batch_masked(true), 0.5);
        t.cfg.masked_static_warm_up_only = false;
        t.cfg.masked_static_after_warm_up = true;
        assert_eq!(t.static_batch_masked(false), 0.5);
        assert_eq!(t.static_batch_masked(true), 0.0);
        t.cfg.masked_static_warm_up_only = true;
        assert!(t.cfg.validate().unwrap_err().contains("no phase"));
        (
            t.cfg.masked_static_warm_up_only,
            t.cfg.masked_static_after_warm_up,
        ) = (true, false);
        let f = t.video.mask_fraction() as f64;
        assert!(
            f > 0.02 && f < 0.98,
            "the masks hold too few or too many pixels to tell: {f}"
        );
        let mut rng = StdRng::seed_from_u64(9);
        let n = 20_000;
        let mut masked_share = |s: f32| {
            let pixels = t.still_pixels(n, s, &mut rng);
            let drawn: usize = pixels.iter().map(Vec::len).sum();
            // Eight tries per ray, each kept with probability 1 − f + f·s.
            let kept = 1.0 - (f * (1.0 - s as f64)).powi(8);
            assert!(
                (drawn as f64 / n as f64 - kept).abs() < 0.02,
                "{drawn} of {n} drawn, want {kept:.4}"
            );
            let masked = pixels
                .iter()
                .enumerate()
                .map(|(k, p)| p.iter().filter(|&&p| t.video.motion_masks[k][p as usize]).count())
                .sum::<usize>();
            masked as f64 / drawn as f64
        };
        assert_eq!(masked_share(0.0), 0.0, "the default draws outside the masks only");
        for s in [1.0f64, 0.5] {
            let want = f * s / (1.0 - f + f * s);
            let got = masked_share(s as f32);
            // About 8 standard deviations of a share of 20 000 draws.
            assert!(
                (got - want).abs() < 0.03,
                "share {s}: masked {got:.4}, want {want:.4}"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// With `static_random_background` the static batch's targets are its pixels recomposited
    /// over the colours it renders over: a pixel of alpha a becomes a·fg + (1 − a)·c, so a
    /// background pixel's target is its ray's colour c (checked in f64 against the dataset's
    /// white composite); without it the targets are the frames' colours over the dataset's
    /// background.
    #[test]
    fn the_static_batch_recomposites_over_random_colours() {
        let (dir, cfg, video) = temp_video("nsff-static-bg");
        assert!(!cfg.static_random_background, "opt-in");
        let mut t = NsffTrainer::new(cfg, video, &dir.join("run")).unwrap();
        let base = t
            .video
            .dataset
            .background
            .expect("the synthetic video has a background");
        // Every pixel of the first two frames: both background and surface pixels.
        let n = t.video.dataset.views[t.video.frames[0]]
            .alpha
            .as_ref()
            .unwrap()
            .len() as u32;
        let mut pixels = vec![Vec::new(); t.video.frames.len()];
        pixels[0] = (0..n).collect();
        pixels[1] = (0..n).step_by(3).collect();
        let alpha: Vec<f64> = (0..2)
            .flat_map(|k| {
                let a = t.video.dataset.views[t.video.frames[k]].alpha.clone().unwrap();
                pixels[k]
                    .iter()
                    .map(move |&p| a[p as usize] as f64)
                    .collect::<Vec<_>>()
            })
            .collect();
        assert!(
            alpha.contains(&0.0) && alpha.contains(&1.0),
            "no background or no surface pixels"
        );
        let (_, rgb) = t.pixel_rays(&pixels);
        let mut rng = StdRng::seed_from_u64(4);

        let (target, background) = t.static_targets(&pixels, rgb.clone(), &mut rng);
        assert!(matches!(background, Background::Color(c) if c == base));
        assert_eq!(host(target), rgb);

        t.cfg.static_random_background = true;
        let (target, background) = t.static_targets(&pixels, rgb.clone(), &mut rng);
        let Background::PerRay(colours) = background else {
            panic!("one background colour per ray expected");
        };
        let (target, colours) = (host(target), host(colours));
        assert_eq!((target.len(), colours.len()), (rgb.len(), rgb.len()));
        for (i, &a) in alpha.iter().enumerate() {
            for c in 0..3 {
                let j = 3 * i + c;
                let want = rgb[j] as f64 + (1.0 - a) * (colours[j] as f64 - base[c] as f64);
                assert!((target[j] as f64 - want).abs() < 1e-5, "ray {i} channel {c}");
                if a == 0.0 {
                    assert!(
                        (target[j] - colours[j]).abs() < 1e-5,
                        "a background pixel's target is its colour"
                    );
                }
            }
        }
        // The colours are drawn, not the base.
        assert!(
            colours
                .chunks(3)
                .any(|c| c.iter().zip(&base).any(|(a, b)| (a - b).abs() > 0.1))
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// On a generated RGBA video the flow test masks background pixels along the silhouettes;
    /// with `unmask_background` the motion masks are the same less exactly those,
    /// and hard mining still draws from all of them.
    #[test]
    fn background_pixels_are_kept_out_of_the_motion_masks() {
        let (dir, mut cfg, kept) = temp_video("nsff-unmask-bg");
        assert!(!cfg.unmask_background, "opt-in");
        cfg.unmask_background = true;
        let unmasked = load_video(&cfg, &dir.join("run"), true).unwrap();
        let (mut background, mut masked) = (0, 0);
        for (k, &f) in kept.frames.iter().enumerate() {
            let alpha = kept.dataset.views[f]
                .alpha
                .as_ref()
                .expect("the synthetic video has alpha");
            for (p, &a) in alpha.iter().enumerate() {
                let (before, after) = (kept.motion_masks[k][p], unmasked.motion_masks[k][p]);
                assert_eq!(after, before && a > 0.0, "frame {k} pixel {p} (alpha {a})");
                background += usize::from(before && a == 0.0);
                masked += usize::from(after);
            }
            assert_eq!(
                unmasked.moving_pixels[k], kept.moving_pixels[k],
                "frame {k}: hard mining draws from the flow test's masks, background included"
            );
        }
        assert!(
            background > 0,
            "no background pixel was masked: the test cannot tell"
        );
        assert!(masked > 0, "the masks hold no pixel");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A jumping camera's warm-up ends when the grid fills up again after carving (twice its
    /// floor and by at least a tenth of the grid); a grid that only carves, or rises by less,
    /// keeps it. The schedules then count from the progress at that moment.
    #[test]
    fn warm_up_ends_when_the_grid_fills_up_again() {
        let (dir, mut cfg, video) = jumping_scene("nsff-warm-up-exit");
        let run_dir = dir.join("run");
        assert_eq!(cfg.warm_up_exit_rise, 2.0);
        cfg.base.steps = 100;
        cfg.base.time_budget = None;
        cfg.static_warm_up = 0.9;
        let mut t = NsffTrainer::new(cfg, video, &run_dir).unwrap();
        let occupy = |t: &mut NsffTrainer, fraction: f64| {
            t.model.occupancy.as_mut().unwrap().with_bins_mut(|bins| {
                for grid in bins {
                    let n = grid.num_cells();
                    let k = (fraction * n as f64).round() as usize;
                    grid.set_values((0..n).map(|i| if i < k { 100.0 } else { 0.0 }).collect());
                }
            });
            t.end_warm_up_if_refilling();
        };
        t.step = 10;
        for f in [1.0, 0.4, 0.1, 0.08, 0.15, 0.17] {
            // Carving, then a rise by less than a tenth of the grid.
            occupy(&mut t, f);
            assert!(t.in_static_warm_up(), "ended at {f}");
            assert!(t.note.is_none());
        }
        assert!((t.occupancy_floor - 0.08).abs() < 1e-3);
        t.step = 30;
        occupy(&mut t, 0.2);
        assert!(
            !t.in_static_warm_up(),
            "a grid refilled from 8 % to 20 % ends the warm-up"
        );
        assert!((t.cfg.static_warm_up - 0.3).abs() < 1e-9);
        let note = t.note.take().unwrap();
        assert!(note.contains("8.0 % to 20.0 %"), "{note}");
        assert_eq!(t.after_warm_up(), 0.0);
        t.step = 65;
        assert!(
            (t.after_warm_up() - 0.5).abs() < 1e-9,
            "the schedules count from the exit"
        );

        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A jumping camera's batch draws from several frames: the rays of each group come from its
    /// frame's camera through the drawn pixels (checked by projecting them back), and every
    /// sample carries its frame's time (or, with a time jitter, its ray's time near the frame's).
    /// A video refuses more than one frame per batch.
    #[test]
    fn a_batch_draws_from_several_frames_of_a_jumping_camera() {
        let (dir, mut cfg, video) = jumping_scene("nsff-frames-per-batch");
        let run_dir = dir.join("run");
        cfg.frames_per_batch = 3;
        let mut t = NsffTrainer::new(cfg, video, &run_dir).unwrap();
        t.n_rays = 10;
        let mut rng = StdRng::seed_from_u64(7);
        let batch = t.frame_batch(&mut rng);
        let sizes: Vec<usize> = batch.groups.iter().map(|(_, r)| r.len()).collect();
        assert_eq!(sizes, vec![3, 3, 4]);
        assert_eq!((batch.rays.len(), batch.target.dims()), (10, [10, 3]));
        for (k, range) in &batch.groups {
            let camera = &t.video.dataset.views[t.video.frames[*k]].camera;
            let centre = camera.pose.to_world([0.0; 3]);
            for r in range.clone() {
                let (o, d) = (batch.rays.origin(r), batch.rays.direction(r));
                let p: [f64; 3] = std::array::from_fn(|a| f64::from(o[a] + 2.0 * d[a]));
                let (u, v, _) = camera.project(p).expect("in front of its camera");
                let w = camera.intrinsics.width;
                let px = batch.pixels[r];
                assert!((u - (f64::from(px % w) + 0.5)).abs() < 1e-3, "ray {r}: u {u}");
                assert!((v - (f64::from(px / w) + 0.5)).abs() < 1e-3, "ray {r}: v {v}");
                assert!((0..3).all(|a| (f64::from(o[a]) - centre[a]).abs() < 1e-4));
            }
        }
        let frame_time = |times: &[f32], ray: u32| {
            let (k, _) = batch
                .groups
                .iter()
                .find(|(_, r)| r.contains(&(ray as usize)))
                .unwrap();
            times[*k]
        };
        t.cfg.time_jitter = 0.0;
        let (samples, times) = t.batch_samples(&batch, &mut rng);
        assert!(samples.num_samples() > 0);
        for (s, &ray) in samples.ray_indices().iter().enumerate() {
            assert_eq!(times[s], frame_time(&t.video.times, ray));
        }

        // With a time jitter every ray's samples share one time, within the jitter (one
        // frame's spacing here) of the frame's time and inside [0, 1].
        t.cfg.time_jitter = 1.0;
        let spacing = 1.0 / (t.video.times.len() - 1) as f32;
        let (samples, times) = t.batch_samples(&batch, &mut rng);
        let mut ray_time = std::collections::HashMap::new();
        let mut moved = 0;
        for (s, &ray) in samples.ray_indices().iter().enumerate() {
            let offset = (times[s] - frame_time(&t.video.times, ray)).abs();
            assert!(
                offset <= spacing * 1.0001 && (0.0..=1.0).contains(&times[s]),
                "sample {s}: {offset}"
            );
            assert_eq!(
                *ray_time.entry(ray).or_insert(times[s]),
                times[s],
                "ray {ray}'s samples disagree"
            );
            moved += usize::from(offset > 0.0);
        }
        assert!(moved > 0, "no sample's time moved");

        let (mut cfg, video) = video_scene(&dir);
        cfg.frames_per_batch = 2;
        let err = NsffTrainer::new(cfg, video, &run_dir)
            .err()
            .expect("a video refuses it");
        assert!(err.to_string().contains("frames_per_batch"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// During the static warm-up a step leaves the dynamic field untouched and trains the static
    /// one; after it the space-time terms reach the dynamic field.
    #[test]
    fn static_warm_up_trains_the_static_field_alone() {
        let dir = std::env::temp_dir().join(format!("nsff-warm-up-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let data = dir.join("video");
        let synth = nerf_synth::SynthConfig::new(nerf_synth::Preset::Dynamic)
            .with_size(32, 24)
            .with_views(6, 2);
        nerf_synth::generate(&synth, &data).unwrap();
        let mut cfg = NsffConfig::new(Preset::Fast, data, LoadOptions::default());
        cfg.dynamic = DynamicMode::On;
        let run_dir = dir.join("run");
        let video = load_video(&cfg, &run_dir, true).unwrap();
        cfg.adapt_to(&video.dataset, video.frames.len());
        cfg.base.steps = 4;
        cfg.base.time_budget = None;
        cfg.static_warm_up = 0.5;
        let mut t = NsffTrainer::new(cfg, video, &run_dir).unwrap();
        let dynamic = |t: &NsffTrainer| tables(t.model.fields.dynamic.as_ref().unwrap().host_params());
        let still = |t: &NsffTrainer| tables(t.model.fields.static_field.host_params());
        let (dyn0, st0) = (dynamic(&t), still(&t));
        let (lr0, lr1) = (t.cfg.base.lr, t.cfg.base.lr_final);
        for _ in 0..2 {
            assert!(t.in_static_warm_up());
            assert_eq!(t.lr(), lr0, "the rate decayed during the warm-up");
            t.train_step().unwrap().expect("a finite warm-up step");
        }
        assert_eq!(dynamic(&t), dyn0, "the warm-up changed the dynamic field");
        assert_ne!(still(&t), st0, "the warm-up did not train the static field");
        assert!(!t.in_static_warm_up());
        assert_eq!(t.lr(), lr0, "the space-time phase starts at the full rate");
        t.train_step().unwrap().expect("a finite space-time step");
        assert_ne!(
            dynamic(&t),
            dyn0,
            "the space-time step did not reach the dynamic field"
        );
        // One of the two space-time steps done: half-way through the decay.
        let want = lr0 * (lr1 / lr0).powf(0.5);
        assert!((t.lr() - want).abs() < 1e-9 * lr0, "lr {} vs {want}", t.lr());
        // The schedule of checkpoints from before: one decay over the whole budget (3 of 4 steps).
        t.cfg.lr_decay_after_warm_up = false;
        let old = lr0 * (lr1 / lr0).powf(0.75);
        assert!((t.lr() - old).abs() < 1e-9 * lr0, "lr {} vs {old}", t.lr());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
