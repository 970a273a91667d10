//! Training bookkeeping shared by `nerf` and `nsff`: the JSON-lines metrics log and the
//! progress bar.

use std::io::Write;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use nerf_data::error::{DataError, Result};
use serde::{Deserialize, Serialize};

/// One line of `metrics.jsonl`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MetricsRecord {
    pub step: usize,
    /// Seconds of training (evaluation pauses excluded).
    pub time: f64,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub loss: Option<f64>,
    /// PSNR of the training batch (fine/combined output).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub train_psnr: Option<f64>,
    /// Mean PSNR over held-out views, when evaluated at this step.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub test_psnr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub lr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub rays_per_sec: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub samples_per_ray: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub note: Option<String>,
}

/// Append-only JSON-lines log.
pub struct MetricsLog {
    path: PathBuf,
}

impl MetricsLog {
    /// Opens the log, dropping lines after `resume_step` (work lost since the last checkpoint).
    pub fn open(path: &Path, resume_step: Option<usize>) -> Result<Self> {
        match resume_step {
            Some(step) if path.exists() => {
                let kept: Vec<MetricsRecord> =
                    Self::read(path)?.into_iter().filter(|r| r.step <= step).collect();
                let text: String = kept
                    .iter()
                    .map(|r| serde_json::to_string(r).unwrap_or_default() + "\n")
                    .collect();
                nerf_data::image::write_atomic(path, text.as_bytes())?;
            }
            _ => nerf_data::image::write_atomic(path, b"")?,
        }
        Ok(MetricsLog {
            path: path.to_path_buf(),
        })
    }

    pub fn append(&self, record: &MetricsRecord) -> Result<()> {
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .create(true)
            .open(&self.path)
            .map_err(|e| DataError::io(&self.path, e))?;
        let line =
            serde_json::to_string(record).map_err(|e| DataError::invalid(&self.path, e.to_string()))?;
        writeln!(f, "{line}").map_err(|e| DataError::io(&self.path, e))
    }

    pub fn read(path: &Path) -> Result<Vec<MetricsRecord>> {
        let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
        text.lines()
            .filter(|l| !l.trim().is_empty())
            .enumerate()
            .map(|(i, l)| {
                serde_json::from_str(l).map_err(|e| DataError::invalid(path, format!("line {}: {e}", i + 1)))
            })
            .collect()
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// A progress bar over steps or seconds (whichever budget binds), with a message line.
pub struct Progress {
    bar: ProgressBar,
    by_time: bool,
}

impl Progress {
    pub fn new(steps: usize, time_budget: Option<f64>, start_step: usize, start_time: f64) -> Self {
        let by_time = time_budget.is_some();
        let (len, pos) = match time_budget {
            Some(b) => (b.ceil() as u64, start_time as u64),
            None => (steps as u64, start_step as u64),
        };
        let bar = ProgressBar::new(len);
        let unit = if by_time { "s" } else { "" };
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{{bar:30.cyan/blue}} {{pos}}/{{len}}{unit} ETA {{eta}}  {{msg}}"
            ))
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_position(pos);
        Progress { bar, by_time }
    }

    pub fn update(&self, step: usize, elapsed: f64, message: String) {
        self.bar
            .set_position(if self.by_time { elapsed as u64 } else { step as u64 });
        self.bar.set_message(message);
    }

    /// Prints a line above the bar (or plainly when stderr is not a terminal).
    pub fn println(&self, line: impl AsRef<str>) {
        if self.bar.is_hidden() {
            eprintln!("{}", line.as_ref());
        } else {
            self.bar.println(line);
        }
    }

    pub fn is_hidden(&self) -> bool {
        self.bar.is_hidden()
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
