//! How long a trained NSFF run's scene flow is on still and on moving matter of a generated
//! video, against the generator's exact object ids: `cargo run --release -p nsff --example
//! still_flow -- RUN [RUN ...]`.
//!
//! At every 4th pixel of every training frame, the centre ray's first surface at the frame's
//! time (moving object or not), the longer of the dynamic field's forward and backward flows
//! there, as a share of the scene box's largest side (the unit of `still_flow_scale`). Prints
//! quantiles for the still and the moving surfaces, and the share of each that the
//! still-matter gate exp(−(m/ε)²) keeps above one half at several ε: a gate that separates them
//! keeps most still points and few moving ones.

mod common;

use std::path::Path;

use common::GeneratedRun;
use nsff::field::{FLOW_NEXT, FLOW_PREV};

fn quantile(sorted: &[f32], q: f64) -> f32 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let runs: Vec<String> = std::env::args().skip(1).collect();
    if runs.is_empty() {
        return Err("usage: still_flow RUN [RUN ...]".into());
    }
    let scales = [2.5e-4f32, 5e-4, 1e-3, 2e-3, 4e-3];
    for run in &runs {
        let g = GeneratedRun::load(Path::new(run))?;
        let (t, ds, scene, dynamic, moving) = (&g.trained, &g.dataset, &g.scene, &g.dynamic, &g.moving);
        let extent = t.model.bounds.extent();
        let plain = t.device.clone().inner();
        let (mut still, mut movers) = (Vec::new(), Vec::new());
        for (k, &view) in g.frames.iter().enumerate() {
            let time = t.model.times[k];
            let camera = &ds.views[view].camera;
            let surfaces = nsff::eval::surface_hits(scene, camera, time, 4, |_| true);
            if surfaces.hits.is_empty() {
                continue;
            }
            let is_moving: Vec<bool> = surfaces.hits.iter().map(|h| moving.contains(&h.object)).collect();
            let (points, dirs) = (surfaces.points, surfaces.dirs);
            let x = nerf::renderer::tensor(points, 3, &plain);
            let out = nsff::model::query_dynamic(dynamic, x, time, &dirs);
            let read = |name| nerf_core::readback::read_back(out.extras.expect(name), "scene flow");
            let (next, prev) = (read(FLOW_NEXT)?, read(FLOW_PREV)?);
            for (i, &m) in is_moving.iter().enumerate() {
                let len = |f: &[f32]| f[3 * i..3 * i + 3].iter().map(|c| c * c).sum::<f32>().sqrt();
                let l = len(&next).max(len(&prev)) / extent;
                if m { movers.push(l) } else { still.push(l) }
            }
        }
        println!("{run} (box side {extent:.3}; flow length as a share of it)");
        for (name, v) in [("still", &mut still), ("moving", &mut movers)] {
            if v.is_empty() {
                println!("  {name:<7} no points");
                continue;
            }
            v.sort_by(f32::total_cmp);
            let kept: Vec<String> = scales
                .iter()
                .map(|&e| {
                    let share =
                        v.iter().filter(|&&l| (-(l / e).powi(2)).exp() > 0.5).count() as f64 / v.len() as f64;
                    format!("ε {e:.1e}: {:.0} %", 100.0 * share)
                })
                .collect();
            println!(
                "  {name:<7} {:>6} points; quantiles 10/25/50/75/90 %: {:.2e} {:.2e} {:.2e} {:.2e} {:.2e}; gate > ½ at {}",
                v.len(),
                quantile(v, 0.1),
                quantile(v, 0.25),
                quantile(v, 0.5),
                quantile(v, 0.75),
                quantile(v, 0.9),
                kept.join(", ")
            );
        }
    }
    Ok(())
}
