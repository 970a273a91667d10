//! What the examples that read a trained NSFF run of a generated video share: the run, its
//! video and the generator's scene.

use std::path::Path;

use burn::module::Module;

/// A trained run (`nsff train` on a `nerf synth` video) with its training video and scene.
pub struct GeneratedRun {
    pub trained: nsff::checkpoint::TrainedNsff,
    pub dataset: nerf_data::Dataset,
    /// The dataset's views of the training frames, in time order.
    pub frames: Vec<usize>,
    pub scene: nerf_synth::Scene,
    /// The dynamic field, without autodiff.
    pub dynamic: nsff::field::DynamicField,
    /// The scene's moving objects.
    pub moving: Vec<usize>,
}

impl GeneratedRun {
    pub fn load(run: &Path) -> Result<Self, Box<dyn std::error::Error>> {
        let trained = nsff::checkpoint::load_trained(run)?;
        let cfg = &trained.state.config;
        let dataset = nerf_data::load::load_video(&cfg.base.data, &cfg.base.load)?;
        let (frames, _) = nsff::video::check_frames(&dataset)?;
        let scene = nerf::diagnosis::load_scene(&cfg.base.data)?.ok_or("not a generated scene")?;
        let dynamic = trained
            .model
            .fields
            .dynamic
            .as_ref()
            .ok_or("no dynamic field")?
            .valid();
        let moving = scene.moving_objects();
        Ok(GeneratedRun {
            trained,
            dataset,
            frames,
            scene,
            dynamic,
            moving,
        })
    }
}
