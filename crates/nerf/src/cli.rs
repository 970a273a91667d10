//! Command-line options shared by `nerf train` and `nsff train` (flattened into each CLI's own
//! arguments), and how they apply to a training configuration.

use std::path::PathBuf;

use crate::config::{Preset, TrainConfig};

#[derive(clap::Args, Clone, Debug)]
pub struct CommonTrainArgs {
    /// Dataset folder (or .npz file for `nerf`); the format is detected.
    pub data: PathBuf,
    /// Run folder for checkpoints, logs and renders (default: runs/<data name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Which model to train.
    #[arg(long, value_enum, default_value = "fast")]
    pub preset: Preset,
    /// Stop after this many steps (default: nerf 20000 fast, 200000 vanilla; nsff 50000;
    /// unlimited when only --time-budget is given).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Stop after this many seconds of training (evaluation pauses excluded).
    #[arg(long)]
    pub time_budget: Option<f64>,
    /// Integer image downscale factor.
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
    /// Seed of every random draw (initialisation, ray batches, sample jitter).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Continue from RUN_DIR/checkpoint.bin (budgets given here replace the saved ones).
    #[arg(long)]
    pub resume: bool,
    /// Evaluate a few held-out views every SECS seconds of training (0 = never).
    #[arg(long, default_value_t = 0.0)]
    pub eval_every: f64,
    /// Skip the evaluation and renders after training.
    #[arg(long)]
    pub no_render: bool,
    /// burn backend: flex (default CPU), ndarray, wgpu, cuda or auto.
    #[arg(long, default_value = "flex")]
    pub device: String,
    /// Override any setting, e.g. --set fast.grid.log2_table=17 (keys as in a run's checkpoint).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

impl CommonTrainArgs {
    /// The run folder: `--out`, else `runs/<prefix><data name>`.
    pub fn run_dir(&self, prefix: &str) -> PathBuf {
        self.out.clone().unwrap_or_else(|| {
            let name = self
                .data
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "run".into());
            PathBuf::from("runs").join(format!("{prefix}{name}"))
        })
    }

    /// A resumed run's saved settings `cfg` (its training settings at `base`) updated by this
    /// command line: budgets given here replace the saved ones and must be able to train, and a
    /// `--set` may only repeat a saved value ([`crate::config::overrides_agree`]).
    pub fn update_resumed<C: serde::Serialize + serde::de::DeserializeOwned + PartialEq>(
        &self,
        cfg: &mut C,
        base: fn(&mut C) -> &mut TrainConfig,
    ) -> Result<(), String> {
        let train = base(cfg);
        self.apply_budgets(train);
        train.validate()?;
        crate::config::overrides_agree(cfg, &self.overrides)
    }

    /// Budgets given on a `--resume` replace the saved ones.
    fn apply_budgets(&self, cfg: &mut TrainConfig) {
        if let Some(s) = self.steps {
            cfg.steps = s;
        }
        if self.time_budget.is_some() {
            cfg.time_budget = self.time_budget;
        }
    }

    /// Seed, budgets, evaluation cadence and device of a fresh run.
    pub fn apply_fresh(&self, cfg: &mut TrainConfig) {
        cfg.seed = self.seed;
        cfg.time_budget = self.time_budget;
        cfg.steps = match (self.steps, self.time_budget) {
            (Some(s), _) => s,
            // A time budget alone runs until the time is up.
            (None, Some(_)) => usize::MAX / 4,
            (None, None) => cfg.steps,
        };
        cfg.eval_every_secs = self.eval_every;
        cfg.device = self.device.clone();
    }
}

/// `export mesh` options shared by `nerf` and `nsff`.
#[derive(clap::Args, Clone, Debug)]
pub struct MeshArgs {
    /// Run folder written by `train`.
    pub run_dir: PathBuf,
    /// Grid cells along the longest side of the scene box.
    #[arg(long, default_value_t = 256)]
    pub resolution: usize,
    /// Density of the surface (the level set σ = THRESHOLD).
    #[arg(long, default_value_t = crate::export::DEFAULT_THRESHOLD)]
    pub threshold: f32,
    /// Output file (default: RUN_DIR/mesh.ply).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Keep surfaces that no training view sees (by default they are dropped: the field holds
    /// whatever it made up there, e.g. under a ground plane).
    #[arg(long)]
    pub no_cull: bool,
}

/// `export points` options shared by `nerf` and `nsff`.
#[derive(clap::Args, Clone, Debug)]
pub struct PointsArgs {
    /// Run folder written by `train`.
    pub run_dir: PathBuf,
    /// Render every STRIDE-th pixel of each training view in each direction.
    #[arg(long, default_value_t = 2)]
    pub stride: u32,
    /// Keep pixels whose rendered opacity reaches this.
    #[arg(long, default_value_t = 0.95)]
    pub min_opacity: f32,
    /// Output file (default: RUN_DIR/points.ply).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// `view` options shared by `nerf` and `nsff`.
#[derive(clap::Args, Clone, Debug)]
pub struct ViewArgs {
    /// Run folder written by `train`.
    pub run_dir: PathBuf,
    /// Port to listen on (0: any free port).
    #[arg(long, default_value_t = 7007)]
    pub port: u16,
    /// Address to listen on; the default serves this machine only.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
}
