//! NSFF at one time as the static pipeline's export [`Volume`]: the combined density
//! (1 − b)·σ_static + b·σ_dynamic that the renderers composite, and the matching blend of the
//! two fields' colours.

use burn::tensor::Device;
use nerf::error::Result;
use nerf::export::{Volume, mask_unoccupied};
use nerf::renderer::tensor;
use nerf_core::field::{Field, FieldQuery};
use nerf_core::readback::read_back;

use crate::field::{BLEND, GATE};
use crate::model::{NsffModel, blended_densities, occupancy_density, query_dynamic};

/// The scene at normalised time `time`.
pub struct SpaceTimeVolume<'a> {
    pub model: &'a NsffModel,
    pub time: f32,
    pub device: &'a Device,
}

impl Volume for SpaceTimeVolume<'_> {
    fn aabb(&self) -> [[f32; 3]; 2] {
        self.model.bounds.aabb
    }

    fn density(&self, positions: &[f32]) -> Result<Vec<f32>> {
        let times = vec![self.time; positions.len() / 3];
        let mut sigma = occupancy_density(&self.model.fields, positions, &times, self.device)?;
        let grid = self.model.occupancy.as_ref().map(|o| o.at(self.time));
        mask_unoccupied(grid, positions, &mut sigma);
        Ok(sigma)
    }

    fn color(&self, positions: &[f32], dirs: &[f32]) -> Result<Vec<f32>> {
        let fields = &self.model.fields;
        let x = tensor(positions.to_vec(), 3, self.device);
        let st = fields.static_field.query(FieldQuery::new(x.clone(), dirs));
        let mut rgb = read_back(st.rgb, "static colour")?;
        let Some(dynamic) = &fields.dynamic else {
            return Ok(rgb);
        };
        let sigma_s = read_back(st.sigma, "static density")?;
        let blend = read_back(st.extras.expect(BLEND), "blend weight")?;
        let dy = query_dynamic(dynamic, x, self.time, dirs);
        let (sigma_d, rgb_d) = (
            read_back(dy.sigma, "dynamic density")?,
            read_back(dy.rgb, "dynamic colour")?,
        );
        let gate = read_back(dy.extras.expect(GATE), "time gate")?;
        for i in 0..sigma_s.len() {
            let (ws, wd) = blended_densities(blend[i], gate[i], sigma_s[i], sigma_d[i]);
            let total = ws + wd;
            if total > 1e-6 {
                for c in 0..3 {
                    rgb[3 * i + c] = (ws * rgb[3 * i + c] + wd * rgb_d[3 * i + c]) / total;
                }
            }
        }
        Ok(rgb)
    }
}
