//! The NSFF model: the static and space-time fields, the occupancy grid over space (occupied
//! where the combined density is, at any time of its time bin), the scene bounds, the training
//! frames' times and how rays are sampled. It renders (`render.rs`), is saved and loaded with
//! the shared checkpoint parts (`checkpoint.rs`), and is trained by `trainer.rs`.

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use nerf::error::{ModelError, read_back};
use nerf::renderer::{SceneBounds, tensor};
use nerf_core::encoding::HashGrid;
use nerf_core::field::Field;
use nerf_core::sampler::MarchConfig;
use nerf_core::timed_occupancy::TimedOccupancy;

use crate::config::{GateBetween, NsffConfig, TimeInterp};
use crate::field::{BLEND, DynamicField, GATE, StaticField};

#[derive(Module, Debug)]
pub struct NsffFields {
    pub static_field: StaticField,
    /// `None` when the video has no independent motion: the model is then a static NeRF.
    pub dynamic: Option<DynamicField>,
}

impl NsffFields {
    pub fn new(cfg: &NsffConfig, aabb: [[f32; 3]; 2], with_dynamic: bool, device: &Device) -> Self {
        nerf_core::device::seeded(device, cfg.base.seed, || {
            let static_field = StaticField::new(cfg, aabb, device);
            let dynamic = with_dynamic.then(|| DynamicField::new(cfg, aabb, device));
            NsffFields {
                static_field,
                dynamic,
            }
        })
    }

    /// The hash grids (fast preset), for their sparse optimiser steps and checkpoints.
    pub fn host_params(&self) -> Vec<Arc<HashGrid>> {
        let mut out = self.static_field.host_params();
        out.extend(self.dynamic_host_params());
        out
    }

    /// The dynamic field's hash grids (none without it).
    pub fn dynamic_host_params(&self) -> Vec<Arc<HashGrid>> {
        self.dynamic.as_ref().map(|d| d.host_params()).unwrap_or_default()
    }
}

/// How the model places samples and renders between frames.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Stratified samples per ray (without an occupancy grid) and depth layers of the splat.
    pub samples: usize,
    /// Occupancy marching of training (object scenes, fast preset).
    pub march: MarchConfig,
    /// Renders march at this fraction of `march`'s step ([`NsffConfig::render_step_scale`]).
    pub render_step_scale: f32,
    /// Samples whose static blend weight b_s is below this skip the dynamic field at inference.
    pub blend_skip: f32,
    pub time_interp: TimeInterp,
    pub gate_between: GateBetween,
    /// Frames on each side whose gates the held gate reaches ([`NsffConfig::gate_reach`]).
    pub gate_reach: usize,
    /// Renders the static field alone, σ_static at full weight with the dynamic field skipped
    /// (a diagnosis: `nsff eval --static-only`); the combined model scales σ_static by 1 − b.
    pub static_only: bool,
}

impl RenderSettings {
    /// The marching of renders: training's, at `render_step_scale` of its step.
    pub fn render_march(&self) -> MarchConfig {
        MarchConfig {
            step: self.march.step * self.render_step_scale,
            ..self.march.clone()
        }
    }

    pub fn from_config(cfg: &NsffConfig) -> Self {
        RenderSettings {
            samples: cfg.samples,
            march: cfg.base.fast.march.clone(),
            render_step_scale: cfg.render_step_scale,
            blend_skip: cfg.blend_skip,
            time_interp: cfg.time_interp,
            gate_between: cfg.gate_between,
            gate_reach: cfg.gate_reach,
            static_only: false,
        }
    }
}

#[derive(Debug)]
pub struct NsffModel {
    pub fields: NsffFields,
    pub occupancy: Option<TimedOccupancy>,
    pub bounds: SceneBounds,
    /// Normalised time of each training frame, in frame order.
    pub times: Vec<f32>,
    pub settings: RenderSettings,
}

impl NsffModel {
    /// A freshly initialised model. The occupancy grid exists for object scenes with the fast
    /// preset (NDC scenes sample stratified).
    pub fn new(
        cfg: &NsffConfig,
        bounds: SceneBounds,
        times: Vec<f32>,
        with_dynamic: bool,
        device: &Device,
    ) -> Self {
        let fields = NsffFields::new(cfg, bounds.aabb, with_dynamic, device);
        let f = &cfg.base.fast;
        // Without a dynamic field nothing changes with time: one grid.
        let bins = if with_dynamic { cfg.occupancy_time_bins } else { 1 };
        let range = [
            times.first().copied().unwrap_or(0.0),
            times.last().copied().unwrap_or(1.0),
        ];
        let occupancy =
            (cfg.base.preset == nerf::config::Preset::Fast && f.use_occupancy && !bounds.open_far)
                .then(|| TimedOccupancy::new(f.occupancy.clone(), bounds.aabb, bins, range));
        NsffModel {
            fields,
            occupancy,
            bounds,
            times,
            settings: RenderSettings::from_config(cfg),
        }
    }

    pub fn has_dynamic(&self) -> bool {
        self.fields.dynamic.is_some()
    }

    pub fn host_params(&self) -> Vec<Arc<HashGrid>> {
        self.fields.host_params()
    }

    /// Refreshes the occupancy grid (one time bin of it) with the combined density at one time
    /// per point, drawn in bin k by `time_in(k)` (see [`occupancy_density`]); with
    /// `static_only`, with the static field's density alone (what the static warm-up renders:
    /// the dynamic field, untrained then, would cost half the refresh for nothing).
    pub fn update_occupancy(
        &mut self,
        step: usize,
        grid_rng: &mut rand::rngs::StdRng,
        mut time_in: impl FnMut(usize) -> f32,
        static_only: bool,
        device: &Device,
    ) -> Result<(), ModelError> {
        let Some(grid) = self.occupancy.as_mut() else {
            return Ok(());
        };
        let mut fields = self.fields.valid();
        if static_only {
            fields.dynamic = None;
        }
        let plain = device.clone().inner();
        let mut failed = None;
        let mut density = |p: &[f32], t: &[f32]| -> Vec<f32> {
            occupancy_density(&fields, p, t, &plain).unwrap_or_else(|e| {
                failed = Some(e);
                vec![0.0; t.len()]
            })
        };
        grid.update(
            step,
            self.settings.march.step,
            grid_rng,
            &mut time_in,
            &mut density,
        );
        failed.map_or(Ok(()), Err)
    }
}

/// Density at `[M, 3]` positions (host) as the combined render sees it: (1 − b)·σ_static +
/// b·σ_dynamic with b = b_s·g, the dynamic field at each point's own time in `times`.
pub fn occupancy_density(
    fields: &NsffFields,
    positions: &[f32],
    times: &[f32],
    device: &Device,
) -> Result<Vec<f32>, ModelError> {
    let mut out = Vec::with_capacity(positions.len() / 3);
    for (chunk, tc) in positions.chunks(3 * 65536).zip(times.chunks(65536)) {
        let x = tensor(chunk.to_vec(), 3, device);
        let (extras, mut sigma) = nerf_core::profile::span("occ.static", || {
            let st = fields.static_field.density(x.clone(), None);
            Ok::<_, ModelError>((st.extras, read_back(st.sigma, "static density")?))
        })?;
        if let Some(dy) = &fields.dynamic {
            let blend = read_back(extras.expect(BLEND), "blend weight")?;
            let (gate, sigma_dy) = nerf_core::profile::span("occ.dynamic", || {
                let d = dy.density(x, Some(tensor(tc.to_vec(), 1, device)));
                Ok::<_, ModelError>((
                    read_back(d.extras.expect(GATE), "time gate")?,
                    read_back(d.sigma, "dynamic density")?,
                ))
            })?;
            for (((s, dd), b), g) in sigma.iter_mut().zip(sigma_dy).zip(blend).zip(gate) {
                let (ws, wd) = blended_densities(b, g, *s, dd);
                *s = ws + wd;
            }
        }
        out.extend(sigma);
    }
    Ok(out)
}

/// The two fields' shares of the combined density at one point: ((1 − b)·σ_static, b·σ_dynamic)
/// with the blend b = b_s·g (what the renderers composite; the colour is their weighted mean).
pub fn blended_densities(b_s: f32, gate: f32, sigma_static: f32, sigma_dynamic: f32) -> (f32, f32) {
    let b = b_s * gate;
    ((1.0 - b) * sigma_static.max(0.0), b * sigma_dynamic.max(0.0))
}

/// The dynamic field's outputs at one normalised time for `[S, 3]` positions and unit
/// directions (`S·3` on the host). Differentiable in the positions (warped queries pass flowed
/// points).
pub fn query_dynamic(
    field: &DynamicField,
    positions: Tensor<2>,
    time: f32,
    dirs: &[f32],
) -> nerf_core::field::FieldOutputs {
    field.query(query_at_time(positions, time, dirs))
}

/// The query of `[S, 3]` positions and `S·3` unit directions, all at one normalised time.
pub fn query_at_time(positions: Tensor<2>, time: f32, dirs: &[f32]) -> nerf_core::field::FieldQuery<'_> {
    let n = positions.dims()[0];
    let t = crate::field::time_column(time, n, &positions.device());
    nerf_core::field::FieldQuery::new(positions, dirs).at_time(Some(t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::time_column;
    use nerf::config::Preset;
    use nerf_core::field::FieldQuery;

    /// During the static warm-up the occupancy grid follows the static field alone (what the
    /// warm-up renders): the refresh equals, value for value, a plain grid refreshed with the
    /// static field's own density query, and differs from the combined density's.
    #[test]
    fn a_static_only_refresh_ignores_the_dynamic_field() {
        use nerf_core::occupancy::OccupancyGrid;
        use rand::SeedableRng;
        let device = Device::flex();
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        cfg.base.fast.occupancy.resolution = 16;
        let bounds = SceneBounds::object(2.0, 6.0, [[-1.0; 3], [1.0; 3]]);
        let times: Vec<f32> = (0..10).map(|i| i as f32 / 9.0).collect();
        let mut model = NsffModel::new(&cfg, bounds.clone(), times, true, &device);
        let blank = model.occupancy.clone();
        let mut refreshed = |static_only: bool| {
            model.occupancy = blank.clone();
            let mut rng = rand::rngs::StdRng::seed_from_u64(3);
            model
                .update_occupancy(0, &mut rng, |_| 0.5, static_only, &device)
                .unwrap();
            model.occupancy.as_ref().unwrap().union().values().to_vec()
        };
        let got = refreshed(true);
        let combined = refreshed(false);
        let mut want = OccupancyGrid::new(cfg.base.fast.occupancy.clone(), bounds.aabb);
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        want.update(0, model.settings.march.step, &mut rng, &mut |p| {
            let x = tensor(p.to_vec(), 3, &device);
            let sigma = model.fields.static_field.density(x, None).sigma;
            sigma.into_data().try_into_vec_as::<f32>().unwrap()
        });
        let want = want.values().to_vec();
        assert!(want.iter().any(|v| *v > 0.0));
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() <= 1e-6 * w.abs().max(1e-3), "{g} vs {w}");
        }
        assert_ne!(combined, want, "the combined density differs");
    }

    /// The occupancy density uses the same blend as the renderers, b = b_s·g, recomputed here in
    /// f64 from full field queries; the gate starts open.
    #[test]
    fn occupancy_density_blends_with_the_time_gate() {
        let device = Device::flex();
        let cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        let aabb = [[-1.0f32, -1.0, -1.0], [1.0, 1.0, 1.0]];
        let fields = NsffFields::new(&cfg, aabb, true, &device);
        let n = 64;
        let pos: Vec<f32> = (0..3 * n).map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0).collect();
        let times: Vec<f32> = (0..n).map(|i| i as f32 / (n - 1) as f32).collect();
        let got = occupancy_density(&fields, &pos, &times, &device).unwrap();
        let host = |t: Tensor<2>| t.into_data().try_into_vec_as::<f32>().unwrap();
        let dirs = [0.0f32, 0.0, 1.0].repeat(n);
        let st = fields
            .static_field
            .query(FieldQuery::new(tensor(pos.clone(), 3, &device), &dirs));
        let (sigma_st, blend) = (host(st.sigma), host(st.extras.expect(BLEND)));
        let dynamic = fields.dynamic.as_ref().unwrap();
        for i in 0..n {
            let x = tensor(pos[3 * i..3 * i + 3].to_vec(), 3, &device);
            let q = FieldQuery::new(x, &dirs[..3]).at_time(Some(time_column(times[i], 1, &device)));
            let dy = dynamic.query(q);
            let (sigma_dy, gate) = (host(dy.sigma)[0] as f64, host(dy.extras.expect(GATE))[0] as f64);
            assert!(gate > 0.9, "the gate starts open: {gate}");
            let b = blend[i] as f64 * gate;
            let want = (1.0 - b) * sigma_st[i] as f64 + b * sigma_dy;
            assert!(
                (got[i] as f64 - want).abs() <= 1e-4 * want.abs().max(1.0),
                "point {i}: {} vs {want}",
                got[i]
            );
        }
    }
}
