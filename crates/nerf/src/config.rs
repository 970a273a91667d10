//! Training configuration: presets, sampling, optimisation and bookkeeping. Saved in every
//! checkpoint so `--resume`, `eval` and `render` rebuild exactly the trained model.

use nerf_core::encoding::HashGridConfig;
use nerf_core::occupancy::OccupancyConfig;
use nerf_core::sampler::{MarchConfig, Spacing};
use nerf_data::{Dataset, LoadOptions, SceneKind};
use serde::{Deserialize, Serialize};

/// Which model to train.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// Hash grid + tiny MLPs, occupancy-grid marching, early ray termination (Instant-NGP).
    Fast,
    /// The NeRF paper's model: positional encoding, 8×256 MLPs, 64 coarse + 128 fine samples.
    Vanilla,
}

impl Preset {
    /// The learning rate's start and end (exponential decay between them).
    pub fn learning_rates(self) -> (f64, f64) {
        match self {
            Preset::Fast => (1e-2, 1e-3),
            Preset::Vanilla => (5e-4, 5e-5),
        }
    }
}

/// Fast-preset settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FastSettings {
    pub grid: HashGridConfig,
    pub hidden: usize,
    pub geo_features: usize,
    pub color_hidden: usize,
    pub color_layers: usize,
    pub occupancy: OccupancyConfig,
    /// Skip empty space with the occupancy grid (off: march every step through the box).
    pub use_occupancy: bool,
    /// Stop rays once their transmittance falls below `stop_eps` when rendering (evaluation,
    /// renders): the samples behind are never evaluated.
    pub early_termination: bool,
    /// The same during training. It costs an extra density pass over all marched samples to find
    /// where rays stop, which on the CPU outweighs the saved backward work (measured in
    /// BENCHMARKS.md), so it is off by default.
    pub train_early_termination: bool,
    pub stop_eps: f32,
    pub march: MarchConfig,
    /// Samples per training step; the ray count adapts to keep it (nerfacc's scheme).
    pub target_samples: usize,
    /// Ray count bounds.
    pub min_rays: usize,
    pub max_rays: usize,
}

/// Vanilla-preset settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VanillaSettings {
    pub coarse_samples: usize,
    pub fine_samples: usize,
    pub width: usize,
    pub depth: usize,
    pub rays: usize,
    /// Standard deviation of the noise added to raw density while training (real scenes).
    pub raw_noise_std: f32,
    pub spacing: Spacing,
}

/// Everything that defines a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub preset: Preset,
    pub data: std::path::PathBuf,
    pub load: LoadOptions,
    pub seed: u64,
    /// Stop after this many steps ...
    pub steps: usize,
    /// ... or this many seconds of training, whichever comes first.
    pub time_budget: Option<f64>,
    pub lr: f64,
    /// Learning rate at the last step (exponential decay from `lr`).
    pub lr_final: f64,
    pub adam_beta1: f64,
    pub adam_beta2: f64,
    pub adam_eps: f64,
    /// L2 weight decay on MLP weights (fast preset).
    pub weight_decay: f64,
    /// NeRF's precrop: sample only the central `precrop_frac` of each image for the first steps.
    pub precrop_steps: usize,
    pub precrop_frac: f32,
    /// Random background colour per ray for images with alpha (reduces halos); evaluation uses
    /// the dataset background.
    pub random_background: bool,
    pub checkpoint_every: usize,
    /// Evaluate on a few held-out views every this many seconds of training (0 = never).
    pub eval_every_secs: f64,
    pub fast: FastSettings,
    pub vanilla: VanillaSettings,
    /// burn backend (`flex`, `ndarray`, `wgpu`, `cuda`, `auto`).
    pub device: String,
}

impl TrainConfig {
    /// Defaults for a preset, adapted to the dataset (scene box, NDC, background).
    pub fn new(preset: Preset, data: std::path::PathBuf, load: LoadOptions) -> Self {
        let (lr, lr_final) = preset.learning_rates();
        TrainConfig {
            preset,
            data,
            load,
            seed: 0,
            steps: match preset {
                Preset::Fast => 20_000,
                Preset::Vanilla => 200_000,
            },
            time_budget: None,
            lr,
            lr_final,
            adam_beta1: 0.9,
            adam_beta2: match preset {
                Preset::Fast => 0.99,
                Preset::Vanilla => 0.999,
            },
            adam_eps: match preset {
                Preset::Fast => 1e-15,
                Preset::Vanilla => 1e-7,
            },
            weight_decay: match preset {
                Preset::Fast => 1e-6,
                Preset::Vanilla => 0.0,
            },
            precrop_steps: match preset {
                Preset::Fast => 0,
                Preset::Vanilla => 500,
            },
            precrop_frac: 0.5,
            random_background: preset == Preset::Fast,
            checkpoint_every: match preset {
                Preset::Fast => 500,
                Preset::Vanilla => 50,
            },
            eval_every_secs: 0.0,
            fast: FastSettings {
                grid: HashGridConfig {
                    dims: 3,
                    levels: 16,
                    features: 2,
                    // 2^17 entries per level and one colour hidden layer beat the GPU defaults
                    // (2^19, two layers) at equal CPU time on tiny lego (BENCHMARKS.md).
                    log2_table: 17,
                    base_resolution: 16,
                    finest_resolution: 1024,
                    time_resolution: None,
                    time_follows_space: false,
                },
                hidden: 64,
                geo_features: 16,
                color_hidden: 64,
                color_layers: 1,
                occupancy: OccupancyConfig::default(),
                use_occupancy: true,
                early_termination: true,
                train_early_termination: false,
                stop_eps: 1e-4,
                march: MarchConfig {
                    step: 3.0f32 * 3f32.sqrt() / 512.0,
                    cone_angle: 0.0,
                    max_step: 1e10,
                    max_samples: 1024,
                },
                // Many small steps learn faster per CPU second than few large ones.
                target_samples: 1 << 13,
                min_rays: 64,
                max_rays: 1 << 14,
            },
            vanilla: VanillaSettings {
                coarse_samples: 64,
                fine_samples: 128,
                width: 256,
                depth: 8,
                rays: 1024,
                raw_noise_std: 0.0,
                spacing: Spacing::Depth,
            },
            device: "flex".into(),
        }
    }

    /// Scene-dependent settings, once the dataset is known.
    pub fn adapt_to(&mut self, dataset: &Dataset) {
        let extent = crate::model::scene_bounds(dataset).extent();
        // About 512 steps across the box's diagonal.
        self.fast.march.step = extent * 3f32.sqrt() / 512.0;
        if dataset.ndc.is_some() {
            // NDC depth is uniform in disparity over z ∈ [-1, 1]: 128 steps, as NSFF samples.
            self.fast.march.step = 2.0 / 128.0;
        }
        if dataset.kind == SceneKind::ForwardFacing {
            self.vanilla.raw_noise_std = 1.0;
            self.random_background = false;
        }
        // Recompositing over a random colour needs the alpha the colour was composited with.
        if dataset.background.is_none() || dataset.views.iter().any(|v| v.alpha.is_none()) {
            self.random_background = false;
        }
    }

    /// The optimiser's and the budgets' numbers make sense (after `--lr` and `--set`): a
    /// learning rate of 0 or below, a beta outside [0, 1) or a NaN would train to nothing
    /// without saying so.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("lr", self.lr),
            ("lr_final", self.lr_final),
            ("adam_eps", self.adam_eps),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be a positive number, got {v}"));
            }
        }
        for (name, v) in [("adam_beta1", self.adam_beta1), ("adam_beta2", self.adam_beta2)] {
            if !(0.0..1.0).contains(&v) {
                return Err(format!("{name} must be in [0, 1), got {v}"));
            }
        }
        let not_negative = [
            ("weight_decay", self.weight_decay),
            ("eval_every_secs", self.eval_every_secs),
        ];
        for (name, v) in not_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be 0 or more, got {v}"));
            }
        }
        if let Some(b) = self.time_budget.filter(|b| !(b.is_finite() && *b > 0.0)) {
            return Err(format!(
                "the time budget must be a positive number of seconds, got {b}"
            ));
        }
        if !(self.precrop_frac > 0.0 && self.precrop_frac <= 1.0) {
            return Err(format!(
                "precrop_frac must be in (0, 1], got {}",
                self.precrop_frac
            ));
        }
        Ok(())
    }

    /// Training progress in [0, 1]: the larger of the step and time fractions, so a run cut by
    /// `--time-budget` still ends at `lr_final`.
    pub fn progress(&self, step: usize, elapsed: f64) -> f64 {
        let by_steps = step as f64 / self.steps.max(1) as f64;
        let by_time = self.time_budget.map_or(0.0, |b| elapsed / b.max(1e-9));
        by_steps.max(by_time).min(1.0)
    }

    /// Learning rate at a given progress (exponential decay from `lr` to `lr_final`).
    pub fn lr_at(&self, progress: f64) -> f64 {
        exponential_lr(self.lr, self.lr_final, progress)
    }
}

/// Exponential decay from `first` to `last` at `progress` ∈ [0, 1] (clamped).
pub fn exponential_lr(first: f64, last: f64, progress: f64) -> f64 {
    first * (last / first).powf(progress.clamp(0.0, 1.0))
}

/// Applies `key.path=value` overrides (values parsed as JSON, else taken as strings), e.g.
/// `fast.color_layers=1` or `fast.grid.log2_table=17`. Unknown keys are errors. Works on any
/// serialisable config (the NSFF config nests this one under `base`).
pub fn apply_overrides<C: Serialize + serde::de::DeserializeOwned>(
    cfg: &C,
    overrides: &[String],
) -> Result<C, String> {
    let mut value = serde_json::to_value(cfg).map_err(|e| e.to_string())?;
    for item in overrides {
        let (key, raw) = item
            .split_once('=')
            .ok_or_else(|| format!("--set {item}: expected key=value"))?;
        let mut node = &mut value;
        for part in key.split('.') {
            node = node.get_mut(part).ok_or_else(|| {
                format!("--set {item}: no setting '{key}' (see the config in a run's checkpoint)")
            })?;
        }
        *node = serde_json::from_str(raw).unwrap_or_else(|_| serde_json::Value::String(raw.to_string()));
    }
    serde_json::from_value(value).map_err(|e| format!("--set: {e}"))
}

/// Whether `overrides` leave a resumed run's saved `cfg` as it is: re-running the command that
/// started a run with `--resume` appended is fine, but a `--set` that would change a setting is
/// refused (naming it), since a resumed run keeps the settings it was started with.
pub fn overrides_agree<C: Serialize + serde::de::DeserializeOwned + PartialEq>(
    cfg: &C,
    overrides: &[String],
) -> Result<(), String> {
    for item in overrides {
        if apply_overrides(cfg, std::slice::from_ref(item))? != *cfg {
            return Err(format!(
                "--set {item}: a resumed run keeps the settings it was started with; drop this \
                 --set, or start a new run (another --out) with it"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--set` on a resume: the saved value passes, a new value or an unknown key is refused.
    #[test]
    fn a_resume_takes_only_the_overrides_it_already_has() {
        let mut cfg = TrainConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        cfg.fast.grid.log2_table = 15;
        let same = ["fast.grid.log2_table=15".to_string(), "seed=0".to_string()];
        assert_eq!(overrides_agree(&cfg, &same), Ok(()));
        let err = overrides_agree(&cfg, &["fast.grid.log2_table=17".to_string()]).unwrap_err();
        assert!(err.contains("--set fast.grid.log2_table=17"), "{err}");
        let err = overrides_agree(&cfg, &["no_such_key=1".to_string()]).unwrap_err();
        assert!(err.contains("no_such_key"), "{err}");
    }

    /// The defaults of both presets pass; each nonsensical optimiser or budget number is refused
    /// with its name.
    #[test]
    fn optimiser_and_budget_numbers_must_make_sense() {
        for preset in [Preset::Fast, Preset::Vanilla] {
            let cfg = TrainConfig::new(preset, "unused".into(), LoadOptions::default());
            assert_eq!(cfg.validate(), Ok(()), "{preset:?}");
        }
        type Spoil = fn(&mut TrainConfig);
        let fresh = || TrainConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        let cases: [(&str, Spoil); 9] = [
            ("lr", |c| c.lr = 0.0),
            ("lr_final", |c| c.lr_final = f64::NAN),
            ("adam_eps", |c| c.adam_eps = -1e-8),
            ("adam_beta1", |c| c.adam_beta1 = 1.0),
            ("adam_beta2", |c| c.adam_beta2 = -0.1),
            ("weight_decay", |c| c.weight_decay = -1e-6),
            ("eval_every_secs", |c| c.eval_every_secs = f64::INFINITY),
            ("time budget", |c| c.time_budget = Some(0.0)),
            ("precrop_frac", |c| c.precrop_frac = 0.0),
        ];
        for (name, spoil) in cases {
            let mut cfg = fresh();
            spoil(&mut cfg);
            let err = cfg.validate().expect_err(name);
            assert!(err.contains(name), "{name}: {err}");
        }
        let mut cfg = fresh();
        (cfg.time_budget, cfg.adam_beta1, cfg.weight_decay) = (Some(600.0), 0.0, 0.0);
        assert_eq!(cfg.validate(), Ok(()));
    }
}
