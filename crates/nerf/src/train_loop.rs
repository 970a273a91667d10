//! The training loop the static and NSFF trainers share: step and time budgets, progress bar,
//! metrics log, skipping non-finite steps and rolling back after repeated ones, periodic
//! held-out evaluation, checkpoints, and the PSNR-against-time plot at the end.

use std::path::Path;
use std::time::Instant;

use crate::error::Result;

use crate::config::TrainConfig;
use crate::logging::{MetricsLog, MetricsRecord, Progress};

pub const CHECKPOINT: &str = "checkpoint.bin";
pub const METRICS: &str = "metrics.jsonl";
/// Non-finite losses in a row before rolling back to the last checkpoint.
pub const MAX_BAD_STEPS: usize = 5;

/// Per-step result.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepStats {
    pub loss: f64,
    pub psnr: f64,
    pub rays: usize,
    pub samples: usize,
}

/// The steps since the last printed status line, which reads their means: one step's loss, PSNR
/// and rate swing with the pixels it drew and with the occupancy refreshes and other periodic
/// work, so the last step alone misleads.
#[derive(Default)]
struct Window {
    steps: usize,
    loss: f64,
    /// Sum of the steps' mean squared errors, 10^(−PSNR/10).
    mse: f64,
    rays: usize,
    samples: usize,
    secs: f64,
}

impl Window {
    fn add(&mut self, stats: &StepStats, secs: f64) {
        self.steps += 1;
        self.loss += stats.loss;
        self.mse += 10f64.powf(-stats.psnr / 10.0);
        self.rays += stats.rays;
        self.samples += stats.samples;
        self.secs += secs;
    }

    /// "loss L train psnr P R rays/s, S samples/ray", the PSNR that of the mean squared error.
    fn line(&self) -> String {
        let n = self.steps.max(1) as f64;
        format!(
            "loss {:.4} train psnr {:.2} {:.0} rays/s, {:.0} samples/ray",
            self.loss / n,
            -10.0 * (self.mse / n).log10(),
            self.rays as f64 / self.secs.max(1e-9),
            self.samples as f64 / self.rays.max(1) as f64
        )
    }
}

/// What the loop needs from a trainer.
pub trait Trainable {
    /// Budgets, schedule, checkpoint and evaluation intervals.
    fn config(&self) -> &TrainConfig;
    fn run_dir(&self) -> &Path;
    fn step(&self) -> usize;
    /// Seconds of training so far (evaluation pauses excluded).
    fn elapsed(&self) -> f64;
    fn add_elapsed(&mut self, secs: f64);
    /// One optimisation step; `Ok(None)` when the loss was not finite (step skipped).
    fn train_step(&mut self) -> Result<Option<StepStats>>;
    /// Writes the checkpoint atomically.
    fn save(&self) -> Result<()>;
    /// Restores the last checkpoint (or the initial state when there is none).
    fn rollback(&mut self) -> Result<()>;
    /// Mean PSNR over a few held-out views.
    fn quick_eval(&mut self) -> Result<f64>;
    /// A message the last step left for the training log (printed and kept in the metrics).
    fn take_note(&mut self) -> Option<String> {
        None
    }
    /// The learning rate of the step just taken (logged).
    fn lr(&self) -> f64 {
        let cfg = self.config();
        cfg.lr_at(cfg.progress(self.step(), self.elapsed()))
    }
    /// Extra state for the periodic log line (e.g. how much of the occupancy grid is occupied).
    fn status(&self) -> String {
        String::new()
    }
}

/// Trains until the step or time budget is reached. `header` is printed first.
pub fn train(t: &mut impl Trainable, header: &str, show_progress: bool) -> Result<()> {
    let run_dir = t.run_dir().to_path_buf();
    let log = MetricsLog::open(&run_dir.join(METRICS), (t.step() > 0).then_some(t.step()))?;
    let cfg = t.config().clone();
    let progress = Progress::new(cfg.steps, cfg.time_budget, t.step(), t.elapsed());
    if !show_progress {
        progress.finish();
    }
    progress.println(header);
    let mut bad = 0usize;
    let mut next_eval = if cfg.eval_every_secs > 0.0 {
        cfg.eval_every_secs * ((t.elapsed() / cfg.eval_every_secs).floor() + 1.0)
    } else {
        f64::INFINITY
    };
    let mut last_print = Instant::now();
    let mut window = Window::default();
    let mut saved_at = None;
    while t.step() < cfg.steps && cfg.time_budget.is_none_or(|b| t.elapsed() < b) {
        let t0 = Instant::now();
        let stats = t.train_step()?;
        let dt = t0.elapsed().as_secs_f64();
        t.add_elapsed(dt);
        let Some(stats) = stats else {
            bad += 1;
            progress.println(format!(
                "step {}: non-finite loss, step skipped ({bad} in a row)",
                t.step()
            ));
            if bad >= MAX_BAD_STEPS {
                let msg = format!(
                    "{MAX_BAD_STEPS} non-finite losses in a row at step {}; rolling back to the last checkpoint",
                    t.step()
                );
                progress.println(&msg);
                log.append(&MetricsRecord {
                    step: t.step(),
                    time: t.elapsed(),
                    note: Some(msg),
                    ..Default::default()
                })?;
                t.rollback()?;
                bad = 0;
            }
            continue;
        };
        bad = 0;
        let (step, elapsed) = (t.step(), t.elapsed());
        let note = t.take_note();
        if let Some(note) = &note {
            progress.println(format!("step {step}: {note}"));
        }
        let rays_per_sec = stats.rays as f64 / dt.max(1e-9);
        let spr = stats.samples as f64 / stats.rays.max(1) as f64;
        window.add(&stats, dt);
        let lr = t.lr();
        progress.update(
            step,
            elapsed,
            format!(
                "step {step} loss {:.4} psnr {:.2} {rays_per_sec:.0} rays/s {spr:.1} samples/ray",
                stats.loss, stats.psnr
            ),
        );
        if progress.is_hidden() && last_print.elapsed().as_secs_f64() > 10.0 {
            eprintln!("step {step} ({elapsed:.0} s) {}{}", window.line(), t.status());
            last_print = Instant::now();
            window = Window::default();
        }
        let mut record = MetricsRecord {
            step,
            time: elapsed,
            loss: Some(stats.loss),
            train_psnr: Some(stats.psnr),
            lr: Some(lr),
            rays_per_sec: Some(rays_per_sec),
            samples_per_ray: Some(spr),
            note,
            ..Default::default()
        };
        if elapsed >= next_eval {
            let psnr = t.quick_eval()?;
            progress.println(format!("step {step} ({elapsed:.0} s): test psnr {psnr:.2}"));
            record.test_psnr = Some(psnr);
            next_eval += cfg.eval_every_secs;
        }
        log.append(&record)?;
        if step.is_multiple_of(cfg.checkpoint_every.max(1)) {
            t.save()?;
            saved_at = Some(step);
        }
    }
    progress.finish();
    nerf_core::profile::eprint_report();
    if let Some(peak) = nerf_core::profile::peak_memory_bytes() {
        eprintln!(
            "peak memory {:.2} GiB (resident)",
            peak as f64 / (1u64 << 30) as f64
        );
    }
    if saved_at != Some(t.step()) {
        // (Saving the same state again would make it the previous checkpoint as well.)
        t.save()?;
    }
    Ok(crate::plot::training_curve(
        &run_dir.join(METRICS),
        &run_dir.join("psnr.png"),
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The status line reads the window's means: loss (0.1 + 0.3) / 2, the PSNR of the mean
    /// squared error (0.01 + 0.001) / 2 = 0.0055, i.e. 22.596 dB (not the mean PSNR, 25), rays
    /// over seconds 400 / 0.4 and samples over rays 10000 / 400.
    #[test]
    fn the_status_line_reads_the_window_s_means() {
        let mut window = Window::default();
        let step = |loss, psnr, rays, samples| StepStats {
            loss,
            psnr,
            rays,
            samples,
        };
        window.add(&step(0.1, 20.0, 100, 1000), 0.1);
        window.add(&step(0.3, 30.0, 300, 9000), 0.3);
        assert_eq!(
            window.line(),
            "loss 0.2000 train psnr 22.60 1000 rays/s, 25 samples/ray"
        );
    }
}
