//! NSFF checkpoints: the run state, and the model's sections through the shared model parts
//! (`nerf::checkpoint`), so static and dynamic models save and load their fields, hash grids and
//! occupancy grid the same way.

use std::path::Path;

use burn::tensor::Device;
use nerf::checkpoint::{Sections, read_model_parts, write_model_parts};
use nerf::error::Result;
use serde::{Deserialize, Serialize};

use crate::config::NsffConfig;
use crate::model::{NsffFields, NsffModel};

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct NsffState {
    pub config: NsffConfig,
    pub step: usize,
    pub elapsed: f64,
    /// Whether the model has a dynamic field (decided once, from the video's motion).
    pub dynamic: bool,
    /// Share of flow pixels with independent motion; `None` for a jumping camera (no flow).
    pub moving_fraction: Option<f32>,
    /// Rays per step (adapted to keep the sample count near the static pipeline's target).
    #[serde(default)]
    pub n_rays: usize,
    /// Rays of the static batch per step (adapted the same way); 0 in older checkpoints.
    #[serde(default)]
    pub n_static_rays: usize,
}

/// Writes an NSFF model's sections ("bounds", "times" and the "model" parts).
pub fn write_model(model: &NsffModel, s: &mut Sections, path: &Path) -> Result<()> {
    s.push_json("bounds", &model.bounds, path)?;
    s.push_json("times", &model.times, path)?;
    let host = model.host_params();
    write_model_parts(s, &model.fields, &host, model.occupancy.as_ref(), path)
}

/// Rebuilds the model `cfg` describes (with or without a dynamic field) from checkpoint sections.
pub fn read_model(
    cfg: &NsffConfig,
    dynamic: bool,
    s: &Sections,
    path: &Path,
    device: &Device,
) -> Result<NsffModel> {
    let mut model = NsffModel::new(
        cfg,
        s.json("bounds", path)?,
        s.json("times", path)?,
        dynamic,
        device,
    );
    let host = NsffFields::host_params;
    model.fields = read_model_parts(s, model.fields, host, model.occupancy.as_mut(), path)?;
    Ok(model)
}

/// A trained NSFF model for inference on a plain (no autodiff) device: no video preprocessing,
/// no optimiser.
pub struct TrainedNsff {
    pub state: NsffState,
    pub model: NsffModel,
    pub device: Device,
}

/// Loads `run_dir/checkpoint.bin` written by `nsff train`.
pub fn load_trained(run_dir: &Path) -> Result<TrainedNsff> {
    let path = run_dir.join(nerf::train_loop::CHECKPOINT);
    let s = Sections::read(&path)?;
    let state: NsffState = s.json("state", &path)?;
    let device = nerf::trainer::device(&state.config.base, false)?;
    let model = read_model(&state.config, state.dynamic, &s, &path, &device)?;
    Ok(TrainedNsff { state, model, device })
}
