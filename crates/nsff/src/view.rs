//! NSFF in the static pipeline's web viewer: any time in [0, 1], with the dynamic share and the
//! scene-flow magnitude besides colour, depth and opacity.

use burn::tensor::Device;
use nerf::error::Result;
use nerf::render::depth_image;
use nerf::viewer::ViewModel;
use nerf_data::{Camera, Dataset, Image};

use crate::eval::render_at;
use crate::model::NsffModel;
use crate::render::FlowMap;

pub struct SpaceTimeView<'a> {
    pub model: &'a NsffModel,
    pub dataset: &'a Dataset,
    pub device: &'a Device,
}

impl ViewModel for SpaceTimeView<'_> {
    fn channels(&self) -> Vec<&'static str> {
        let mut c = vec!["rgb", "depth", "opacity"];
        if self.model.has_dynamic() {
            c.extend(["dynamic", "flow"]);
        }
        c
    }

    fn times(&self) -> Vec<f32> {
        self.model.times.clone()
    }

    fn render(&self, camera: &Camera, time: f32, channel: &str) -> Result<Image> {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let flow_map = match channel {
            "flow" => FlowMap::Draw,
            _ => FlowMap::Skip,
        };
        let r = render_at(self.model, self.dataset, camera, time, flow_map, self.device)?;
        let n = (w * h) as usize;
        Ok(match channel {
            "depth" => depth_image(w, h, &r.depth, &r.opacity, None),
            "opacity" => Image::from_data(w, h, 1, r.opacity),
            "dynamic" if r.dynamic_share.len() == n => Image::from_data(w, h, 1, r.dynamic_share),
            "flow" if r.flow_magnitude.len() == n => {
                let max = r.flow_magnitude.iter().cloned().fold(1e-6f32, f32::max);
                Image::from_data(w, h, 1, r.flow_magnitude.iter().map(|m| m / max).collect())
            }
            _ => Image::from_data(w, h, 3, r.rgb),
        })
    }
}
