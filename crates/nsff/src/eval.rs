//! Held-out (camera, time) evaluation for NSFF.

use std::path::Path;
use std::time::Instant;

use nerf::eval::{EvalResult, ViewScore};
use nerf_core::metrics::{psnr, ssim};
use nerf_data::Dataset;
use nerf_data::error::Result;

use crate::config::TimeInterp;
use crate::render::{HostRender, render_direct, render_splat};
use crate::trainer::NsffTrainer;

pub use nerf::eval::quick_views;

/// Continuous frame position of a normalised time (frame i sits at times[i]).
pub fn frame_position(times: &[f32], t: f32) -> f32 {
    let last = times.len() - 1;
    if t <= times[0] {
        return 0.0;
    }
    for i in 0..last {
        if t <= times[i + 1] {
            let span = (times[i + 1] - times[i]).max(1e-9);
            return i as f32 + (t - times[i]) / span;
        }
    }
    last as f32
}

/// Renders a camera at a normalised time. Times on a training frame render directly; times
/// between frames use the configured interpolation (NSFF's splatting by default).
pub fn render_at(t: &NsffTrainer, camera: &nerf_data::Camera, time: f32) -> HostRender {
    let times = &t.video.times;
    let tau = frame_position(times, time);
    let on_frame = (tau - tau.round()).abs() < 1e-4;
    let ds = &t.video.dataset;
    if on_frame || t.cfg.time_interp == TimeInterp::Direct || !t.has_dynamic() {
        let rays = ds.rays_for(camera, 0..camera.intrinsics.num_pixels() as u32);
        let time = if on_frame {
            times[tau.round() as usize]
        } else {
            time
        };
        let mut out = HostRender::default();
        for start in (0..rays.len()).step_by(4096) {
            let part = rays.slice(start..(start + 4096).min(rays.len()));
            let r = render_direct(
                &t.fields,
                &part,
                time,
                &t.cfg,
                &t.bounds,
                ds.background,
                &t.device,
            );
            out.rgb.extend(r.rgb);
            out.depth.extend(r.depth);
            out.opacity.extend(r.opacity);
            out.dynamic_share.extend(r.dynamic_share);
            out.flow_magnitude.extend(r.flow_magnitude);
            out.samples_per_ray += r.samples_per_ray * part.len() as f64;
            out.dynamic_per_ray += r.dynamic_per_ray * part.len() as f64;
        }
        out.samples_per_ray /= rays.len().max(1) as f64;
        out.dynamic_per_ray /= rays.len().max(1) as f64;
        out
    } else {
        render_splat(&t.fields, ds, camera, tau, times, &t.cfg, &t.bounds, &t.device)
    }
}

/// Scores held-out views (each with its own camera and time), optionally saving
/// ground truth | render pairs into `save`.
pub fn evaluate(
    t: &NsffTrainer,
    views: &[usize],
    with_ssim: bool,
    save: Option<&Path>,
) -> Result<EvalResult> {
    let start = Instant::now();
    let ds: &Dataset = &t.video.dataset;
    let mut scores = Vec::new();
    let mut spr = 0.0;
    for &v in views {
        let view = &ds.views[v];
        let time = view.time.unwrap_or(0.0);
        let r = render_at(t, &view.camera, time);
        spr += r.samples_per_ray;
        let (w, h) = (view.image.width as usize, view.image.height as usize);
        if let Some(dir) = save {
            let mut pair = Vec::with_capacity(2 * w * h * 3);
            for y in 0..h {
                pair.extend_from_slice(&view.image.data[y * w * 3..(y + 1) * w * 3]);
                pair.extend_from_slice(&r.rgb[y * w * 3..(y + 1) * w * 3]);
            }
            nerf_data::Image::from_data(2 * w as u32, h as u32, 3, pair)
                .save_png(&dir.join(format!("{v:04}.png")))?;
        }
        scores.push(ViewScore {
            view: v,
            name: view.name.clone(),
            psnr: psnr(&r.rgb, &view.image.data),
            ssim: with_ssim.then(|| ssim(&r.rgb, &view.image.data, w, h, 3)),
        });
    }
    let n = scores.len().max(1) as f64;
    Ok(EvalResult {
        split: "test".into(),
        step: t.step,
        train_seconds: t.elapsed,
        mean_psnr: scores.iter().map(|s| s.psnr).sum::<f64>() / n,
        mean_ssim: with_ssim.then(|| scores.iter().filter_map(|s| s.ssim).sum::<f64>() / n),
        views: scores,
        samples_per_ray: spr / n,
        render_seconds: start.elapsed().as_secs_f64(),
    })
}
