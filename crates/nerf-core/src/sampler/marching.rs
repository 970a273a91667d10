//! Ray marching through the scene box with a fixed or growing step, skipping cells the
//! occupancy grid marks empty.

use rand::Rng;

use super::RaySamples;
use crate::occupancy::OccupancyGrid;
use crate::rays::{Rays, intersect_aabb};

/// Marching settings. Lengths are world distances along the ray.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MarchConfig {
    /// Base step (Instant-NGP: √3/1024 of the unit cube; nerfacc lego: 5e-3 on a 3-unit box).
    pub step: f32,
    /// Cone stepping: step = clamp(distance·cone_angle, step, max_step); 0 gives a fixed step.
    pub cone_angle: f32,
    pub max_step: f32,
    /// Samples per ray at most.
    pub max_samples: usize,
}

/// Marches each ray through `aabb` ∩ [near, far] (ray parameter = depth). Without a grid every
/// step is kept. With `rng`, the start is jittered by U(0, step) (training).
pub fn march(
    rays: &Rays,
    aabb: [[f32; 3]; 2],
    near: f32,
    far: f32,
    grid: Option<&OccupancyGrid>,
    cfg: &MarchConfig,
    mut rng: Option<&mut impl Rng>,
) -> RaySamples {
    let mut out = RaySamples::with_rays(rays.len());
    for r in 0..rays.len() {
        let (o, d) = (rays.origin(r), rays.direction(r));
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let Some((t0, t1)) =
            intersect_aabb(o, d, aabb[0], aabb[1]).filter(|_| norm > 0.0 && norm.is_finite())
        else {
            out.finish_ray();
            continue;
        };
        let u = [d[0] / norm, d[1] / norm, d[2] / norm];
        // March in distance s = t·|d| so steps are world lengths.
        let (s_begin, s_end) = (t0.max(near) * norm, t1.min(far) * norm);
        let jitter = rng.as_deref_mut().map_or(0.0, |g| g.random::<f32>());
        let mut s = s_begin + jitter * cfg.step;
        let mut count = 0;
        // The tolerance keeps rounding in the running sum from adding a sliver interval at the end.
        while s < s_end - 1e-3 * cfg.step && count < cfg.max_samples {
            let ds = (s * cfg.cone_angle).clamp(cfg.step, cfg.max_step.max(cfg.step));
            let mid = s + 0.5 * ds;
            let p = [o[0] + mid * u[0], o[1] + mid * u[1], o[2] + mid * u[2]];
            match grid {
                Some(g) if !g.is_occupied(p) => {
                    // Jump to the step at or after the cell exit.
                    let exit = g.cell_exit(p, u) + (mid - s);
                    s += ds * (exit / ds).ceil().max(1.0);
                }
                _ => {
                    let end = (s + ds).min(s_end);
                    out.push(s / norm, end / norm, 0.5 * (s + end) / norm);
                    count += 1;
                    s += ds;
                }
            }
        }
        out.finish_ray();
    }
    out
}
