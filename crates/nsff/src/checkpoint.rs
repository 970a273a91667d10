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
    let grids = model.occupancy.as_ref().map_or(&[][..], |o| o.bins());
    write_model_parts(s, &model.fields, &host, grids, path)
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
    let fields = model.fields;
    model.fields = match model.occupancy.as_mut() {
        Some(o) => o.with_bins_mut(|grids| read_model_parts(s, fields, host, grids, path))?,
        None => read_model_parts(s, fields, host, &mut [], path)?,
    };
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::SpaceTimeEncoding;
    use crate::model::query_dynamic;
    use nerf::renderer::{SceneBounds, tensor};
    use nerf_core::field::Field;

    /// A dynamic model for `cfg` with every hash table filled with distinct values, and the
    /// model a checkpoint of it loads back.
    fn round_trip(cfg: &NsffConfig, device: &Device) -> (NsffModel, NsffModel) {
        let bounds = SceneBounds::object(2.0, 6.0, [[-1.0; 3], [1.0; 3]]);
        let times: Vec<f32> = (0..10).map(|i| i as f32 / 9.0).collect();
        let model = NsffModel::new(cfg, bounds, times, true, device);
        for (k, grid) in model.host_params().iter().enumerate() {
            let table: Vec<f32> = (0..grid.num_params())
                .map(|i| ((i * 7919 + k * 31) % 1000) as f32 / 500.0 - 1.0)
                .collect();
            grid.set_table(table).unwrap();
        }
        let path = Path::new("run/checkpoint.bin");
        let mut s = Sections::default();
        write_model(&model, &mut s, path).unwrap();
        let loaded = read_model(cfg, true, &s, path, device).unwrap();
        (model, loaded)
    }

    /// 50 probe positions in the box and their (constant) view directions.
    fn probe() -> (Vec<f32>, Vec<f32>) {
        let n = 50;
        let pos = (0..3 * n).map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0).collect();
        (pos, [0.0f32, 0.0, 1.0].repeat(n))
    }

    /// A model with a space-time planes encoding saves its four dynamic grids and loads them back
    /// in place: the loaded dynamic field answers exactly as the saved one.
    #[test]
    fn planes_encoding_round_trips_through_a_checkpoint() {
        let device = Device::flex();
        let mut cfg = NsffConfig::new(nerf::config::Preset::Fast, "unused".into(), Default::default());
        cfg.dynamic_encoding = SpaceTimeEncoding::Planes;
        cfg.dynamic_grid.time_resolution = Some(9);
        let (model, loaded) = round_trip(&cfg, &device);
        // Static grid, then the dynamic field's space grid and three planes.
        assert_eq!(model.host_params().len(), 1 + 4);
        let (pos, dirs) = probe();
        let answer = |m: &NsffModel| {
            let d = m.fields.dynamic.as_ref().unwrap();
            let out = query_dynamic(d, tensor(pos.clone(), 3, &device), 0.37, &dirs);
            out.sigma.into_data().try_into_vec_as::<f32>().unwrap()
        };
        let (want, got) = (answer(&model), answer(&loaded));
        assert_eq!(want, got);
        // The planes matter: the same field with planes reset to one answers differently.
        for grid in &loaded.fields.dynamic.as_ref().unwrap().host_params()[1..] {
            grid.set_table(vec![1.0; grid.num_params()]).unwrap();
        }
        assert_ne!(answer(&loaded), want);
    }

    /// With its own network (`flow_levels`), the scene flow comes from the flow grid and MLP,
    /// which a checkpoint saves and loads back: the loaded field answers the same flow, and
    /// changing the flow grid changes the flow but not the density.
    #[test]
    fn own_flow_network_round_trips_and_owns_the_flow() {
        let device = Device::flex();
        let mut cfg = NsffConfig::new(nerf::config::Preset::Fast, "unused".into(), Default::default());
        cfg.dynamic_grid.time_resolution = Some(9);
        cfg.flow_levels = 3;
        let (model, loaded) = round_trip(&cfg, &device);
        // Static grid, the dynamic field's grid, the flow grid.
        assert_eq!(model.host_params().len(), 3);
        let flow_grid = model.host_params()[2].clone();
        assert_eq!(flow_grid.config.levels, 3);
        let (pos, dirs) = probe();
        let answer = |m: &NsffModel| {
            let d = m.fields.dynamic.as_ref().unwrap();
            let out = query_dynamic(d, tensor(pos.clone(), 3, &device), 0.37, &dirs);
            let host = |t: burn::tensor::Tensor<2>| t.into_data().try_into_vec_as::<f32>().unwrap();
            (host(out.sigma), host(out.extras.expect(crate::field::FLOW_NEXT)))
        };
        let (want, got) = (answer(&model), answer(&loaded));
        assert_eq!(want, got);
        loaded.host_params()[2]
            .set_table(vec![0.0; flow_grid.num_params()])
            .unwrap();
        let (sigma, flow) = answer(&loaded);
        assert_eq!(sigma, want.0, "the flow grid does not touch the density");
        assert_ne!(flow, want.1, "the flow comes from the flow grid");
    }

    /// Time-binned occupancy grids save one grid per bin and load back bin for bin (and the
    /// union is rebuilt from them); a model without a dynamic field has one grid.
    #[test]
    fn time_binned_occupancy_round_trips_through_a_checkpoint() {
        let device = Device::flex();
        let mut cfg = NsffConfig::new(nerf::config::Preset::Fast, "unused".into(), Default::default());
        cfg.occupancy_time_bins = 3;
        let bounds = SceneBounds::object(2.0, 6.0, [[-1.0; 3], [1.0; 3]]);
        let times: Vec<f32> = (0..10).map(|i| i as f32 / 9.0).collect();
        let mut model = NsffModel::new(&cfg, bounds.clone(), times.clone(), true, &device);
        let occupancy = model.occupancy.as_mut().unwrap();
        assert_eq!(occupancy.num_bins(), 3);
        occupancy.with_bins_mut(|bins| {
            for (k, g) in bins.iter_mut().enumerate() {
                // Bin k: the first (k + 1) tenths of the cells.
                let n = g.num_cells();
                g.set_values(
                    (0..n)
                        .map(|i| if i * 10 < (k + 1) * n { 1.0 } else { 0.0 })
                        .collect(),
                );
            }
        });
        let path = Path::new("run/checkpoint.bin");
        let mut s = Sections::default();
        write_model(&model, &mut s, path).unwrap();
        let loaded = read_model(&cfg, true, &s, path, &device).unwrap();
        let (want, got) = (model.occupancy.unwrap(), loaded.occupancy.unwrap());
        assert_eq!(got, want);
        for (k, g) in got.bins().iter().enumerate() {
            assert!((g.occupied_fraction() - 0.1 * (k + 1) as f32).abs() < 1e-3);
        }
        assert!((got.occupied_fraction() - 0.3).abs() < 1e-3, "the union");
        let still = NsffModel::new(&cfg, bounds, times, false, &device);
        assert_eq!(still.occupancy.unwrap().num_bins(), 1);
    }

    /// A checkpoint written before an opt-in experiment was taken out of the code still loads:
    /// its state names settings and loss weights the config no longer has (here from the
    /// sixty-second session's removals), and they are ignored, the rest read as written.
    #[test]
    fn a_state_naming_removed_settings_still_loads() {
        let cfg = NsffConfig::new(
            nerf::config::Preset::Fast,
            "data".into(),
            nerf_data::LoadOptions::default(),
        );
        let state = NsffState {
            config: cfg,
            step: 7,
            elapsed: 1.5,
            dynamic: true,
            moving_fraction: Some(0.1),
            n_rays: 512,
            n_static_rays: 256,
        };
        let mut json = serde_json::to_value(&state).unwrap();
        json["masks_refined"] = true.into();
        let config = &mut json["config"];
        config["warp_hops"] = 3.into();
        config["mask_refine_quantile"] = 0.9.into();
        config["static_lr_final"] = serde_json::Value::Null;
        config["weights"]["blend_hole"] = 0.3.into();
        config["weights"]["still_persistence"] = 1.0.into();
        let back: NsffState = serde_json::from_value(json).unwrap();
        assert_eq!(back.config, state.config);
        assert_eq!((back.step, back.n_rays, back.n_static_rays), (7, 512, 256));
    }
}
