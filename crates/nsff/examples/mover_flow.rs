//! Why a trained NSFF run's scene flow does or does not follow the movers of a generated video:
//! `cargo run --release -p nsff --example mover_flow -- RUN [RUN ...]`.
//!
//! At every pixel of each training frame k whose centre ray first meets a moving object at the
//! frame's time, forward to frame k + 1, it prints:
//! - the rendered depth (Σ w·t over the opacity of the full render; training's projected-flow
//!   term reads the dynamic field's own render, which on the movers is nearly the same) against
//!   the true one;
//! - the dynamic field's scene flow at the true surface and at the rendered one, against the
//!   generator's motion (mean length and cosine);
//! - the run's optical-flow prior (its `flow_cache`) on those pixels: the share it trusts, its
//!   error against the exact flow, and its *motion part*, the prior less the image motion a still
//!   point would have. The projected-flow term places that still point at the rendered depth: where
//!   the depth is off, so is the still point's parallax, and the scene flow is asked to make up the
//!   difference. Printed: how far the depth error moves the still point, and the motion part's
//!   cosine to the true one when the still point sits at the true surface and at the rendered one.

mod common;

use std::path::Path;

use common::GeneratedRun;
use nerf_data::camera::Camera;
use nerf_data::math::{dot, norm};
use nsff::eval::{SurfaceHits, surface_hits};
use nsff::render::FlowMap;

/// Pixel coordinates of world point `p` in `camera`; the image centre for a point behind it
/// (which a surface both frames see is not).
fn project(p: [f64; 3], camera: &Camera) -> [f64; 2] {
    camera
        .project(p)
        .map_or([camera.intrinsics.cx, camera.intrinsics.cy], |(u, v, _)| [u, v])
}

fn length2(v: [f64; 2]) -> f64 {
    v[0].hypot(v[1])
}

fn cosine2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] * b[0] + a[1] * b[1]) / (length2(a).max(1e-9) * length2(b).max(1e-9))
}

fn cosine3(a: [f64; 3], b: [f64; 3]) -> f64 {
    dot(a, b) / (norm(a).max(1e-12) * norm(b).max(1e-12))
}

/// Running sums, one per printed figure (divided by the pixel counts when printed).
#[derive(Default)]
struct Tally {
    pixels: usize,
    depth_error: Vec<f64>,
    true_scene_flow: f64,
    flow_true: (f64, f64),
    flow_rendered: (f64, f64),
    trusted: usize,
    prior_error: f64,
    still_shift: f64,
    true_motion_part: f64,
    cosine_true: f64,
    cosine_rendered: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let runs: Vec<String> = std::env::args().skip(1).collect();
    if runs.is_empty() {
        return Err("usage: mover_flow RUN [RUN ...]".into());
    }
    for run in &runs {
        let g = GeneratedRun::load(Path::new(run))?;
        let (t, ds, scene, dynamic, moving) = (&g.trained, &g.dataset, &g.scene, &g.dynamic, &g.moving);
        let plain = t.device.clone().inner();
        let mut tally = Tally::default();
        for k in 0..g.frames.len().saturating_sub(1) {
            let (t0, t1) = (t.model.times[k], t.model.times[k + 1]);
            let (camera, next) = (&ds.views[g.frames[k]].camera, &ds.views[g.frames[k + 1]].camera);
            let (w, h) = (
                camera.intrinsics.width as usize,
                camera.intrinsics.height as usize,
            );
            let cache = Path::new(run).join(format!("flow_cache/{k:05}_fwd.npz"));
            let prior = nerf_data::video::read_flow(&cache, w, h)?;
            let (exact, _) = scene.optical_flow(camera, f64::from(t0), next, f64::from(t1));
            let SurfaceHits {
                hits,
                pixels,
                points: true_points,
                dirs,
            } = surface_hits(scene, camera, t0, 1, |hit| moving.contains(&hit.object));
            let rays = nerf_data::rays::pixel_rays(camera, pixels.iter().copied());
            let out =
                nsff::eval::render_rays_direct(&t.model, &rays, t0, ds.background, FlowMap::Skip, &t.device)?;
            let mut rendered_points = Vec::with_capacity(3 * hits.len());
            for (i, hit) in hits.iter().enumerate() {
                let depth = out.depth[i] / out.opacity[i].max(1e-3);
                let (o, d) = (rays.origin(i), rays.direction(i));
                tally.depth_error.push(((f64::from(depth) - hit.t) / hit.t).abs());
                rendered_points.extend((0..3).map(|c| o[c] + depth * d[c]));
            }
            let forward = |points: Vec<f32>| -> Result<Vec<f32>, Box<dyn std::error::Error>> {
                let time = nsff::field::time_column(t0, hits.len(), &plain);
                let (_, next) = dynamic.scene_flow(nerf::renderer::tensor(points, 3, &plain), time, &dirs);
                Ok(nerf_core::readback::read_back(next, "flow")?)
            };
            let (at_true, at_rendered) = (forward(true_points)?, forward(rendered_points.clone())?);
            for (i, hit) in hits.iter().enumerate() {
                let motion = scene.object_scene_flow(hit.object, hit.point, f64::from(t0), f64::from(t1));
                let a: [f64; 3] = std::array::from_fn(|c| f64::from(at_true[3 * i + c]));
                let b: [f64; 3] = std::array::from_fn(|c| f64::from(at_rendered[3 * i + c]));
                tally.pixels += 1;
                tally.true_scene_flow += norm(motion);
                tally.flow_true.0 += norm(a);
                tally.flow_true.1 += cosine3(a, motion);
                tally.flow_rendered.0 += norm(b);
                tally.flow_rendered.1 += cosine3(b, motion);
                let p = pixels[i] as usize;
                if prior.mask[p] < 0.5 {
                    continue;
                }
                tally.trusted += 1;
                let centre = [(p % w) as f64 + 0.5, (p / w) as f64 + 0.5];
                let of = [f64::from(prior.flow[2 * p]), f64::from(prior.flow[2 * p + 1])];
                let gt = [f64::from(exact[2 * p]), f64::from(exact[2 * p + 1])];
                tally.prior_error += length2([of[0] - gt[0], of[1] - gt[1]]);
                let rendered: [f64; 3] = std::array::from_fn(|c| f64::from(rendered_points[3 * i + c]));
                let (still_true, still_rendered) = (project(hit.point, next), project(rendered, next));
                let part = |still: [f64; 2], flow: [f64; 2]| {
                    [centre[0] + flow[0] - still[0], centre[1] + flow[1] - still[1]]
                };
                let true_part = part(still_true, gt);
                tally.still_shift += length2([
                    still_true[0] - still_rendered[0],
                    still_true[1] - still_rendered[1],
                ]);
                tally.true_motion_part += length2(true_part);
                tally.cosine_true += cosine2(part(still_true, of), true_part);
                tally.cosine_rendered += cosine2(part(still_rendered, of), true_part);
            }
        }
        if tally.pixels == 0 {
            println!("{run}: no mover pixels");
            continue;
        }
        tally.depth_error.sort_by(f64::total_cmp);
        let median = tally.depth_error[tally.depth_error.len() / 2];
        let (n, m) = (tally.pixels as f64, tally.trusted.max(1) as f64);
        println!("{run}: {} mover pixels", tally.pixels);
        println!("  rendered depth, median relative error {median:.3}");
        println!(
            "  scene flow to the next frame: true length {:.4}; at the true surface {:.4}, cosine {:.2}; at the rendered surface {:.4}, cosine {:.2}",
            tally.true_scene_flow / n,
            tally.flow_true.0 / n,
            tally.flow_true.1 / n,
            tally.flow_rendered.0 / n,
            tally.flow_rendered.1 / n
        );
        println!(
            "  optical-flow prior: trusted on {:.0} %, error {:.2} px; true motion part {:.2} px; a still point moved {:.2} px by the depth error; the prior's motion part, cosine to the truth: {:.2} with the still point at the true surface, {:.2} at the rendered one",
            100.0 * m / n,
            tally.prior_error / m,
            tally.true_motion_part / m,
            tally.still_shift / m,
            tally.cosine_true / m,
            tally.cosine_rendered / m
        );
    }
    Ok(())
}
