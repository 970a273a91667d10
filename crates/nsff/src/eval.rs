//! Held-out (camera, time) evaluation for NSFF.

use std::path::Path;

use burn::module::Module;
use burn::tensor::Device;
use nerf::error::{Result, read_back};
use nerf::eval::{EvalResult, score_views};
use nerf_data::math::{dot, norm, normalize, sub};
use nerf_data::{Dataset, Rays};

use crate::config::TimeInterp;
use crate::field::FLOW_NEXT;
use crate::model::NsffModel;
use crate::render::{FlowMap, HostRender, render_direct, render_splat};

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
/// between frames use the model's time interpolation.
pub fn render_at(
    model: &NsffModel,
    dataset: &Dataset,
    camera: &nerf_data::Camera,
    time: f32,
    flow_map: FlowMap,
    device: &Device,
) -> Result<HostRender> {
    let times = &model.times;
    let tau = frame_position(times, time);
    let on_frame = (tau - tau.round()).abs() < 1e-4;
    if !(on_frame || model.settings.time_interp == TimeInterp::Direct || !model.has_dynamic()) {
        return render_splat(model, dataset, camera, tau, device);
    }
    let rays = dataset.rays_for(camera, 0..camera.intrinsics.num_pixels() as u32);
    let time = if on_frame {
        times[tau.round() as usize]
    } else {
        time
    };
    render_rays_direct(model, &rays, time, dataset.background, flow_map, device)
}

/// Renders `rays` (any subset of a camera's pixels) at normalised `time`, querying the
/// space-time field at that time, in chunks of 4096 rays.
pub fn render_rays_direct(
    model: &NsffModel,
    rays: &Rays,
    time: f32,
    background: Option<[f32; 3]>,
    flow_map: FlowMap,
    device: &Device,
) -> Result<HostRender> {
    let mut out = HostRender::default();
    for start in (0..rays.len()).step_by(4096) {
        let part = rays.slice(start..(start + 4096).min(rays.len()));
        let r = render_direct(model, &part, time, background, flow_map, device)?;
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
    Ok(out)
}

/// Scores held-out views (each with its own camera and time), optionally saving ground truth |
/// render pairs into `save`, and returns each view's rendered depth (`[H*W]`, Σw·t over the
/// opacity, camera depth for Euclidean scenes). With `scene`, the generator's description of
/// the dataset, it also splits the error by view kind on and off the moving objects
/// ([`nerf::diagnosis`], in [`EvalResult::groups`]). `step` and `train_seconds` are left for
/// the caller.
pub fn evaluate_with_depth(
    model: &NsffModel,
    dataset: &Dataset,
    views: &[usize],
    with_ssim: bool,
    save: Option<&Path>,
    scene: Option<&nerf_synth::Scene>,
    device: &Device,
) -> Result<(EvalResult, Vec<Vec<f32>>)> {
    let mut depths = Vec::with_capacity(views.len());
    let result = score_views(dataset, views, with_ssim, save, scene, |v| {
        let view = &dataset.views[v];
        let time = view.time.unwrap_or(0.0);
        let r = render_at(model, dataset, &view.camera, time, FlowMap::Skip, device)?;
        depths.push(
            r.depth
                .iter()
                .zip(&r.opacity)
                .map(|(d, a)| d / a.max(1e-3))
                .collect(),
        );
        Ok((r.rgb, r.samples_per_ray))
    })?;
    Ok((result, depths))
}

/// Rendered depth against the generator's ground truth on surface pixels of held-out views.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DepthError {
    /// Mean |rendered − true| camera depth (scene units).
    pub mean_abs: f64,
    /// Median of |rendered − true| / true.
    pub median_relative: f64,
    pub pixels: usize,
}

/// Compares `depths` (one per view in `views`, from [`evaluate_with_depth`]) with
/// `gt/<view name>_depth.npy` under the dataset folder (written by `nerf synth`; 0 where the
/// pixel sees background, skipped). `None` when no view has a ground-truth file or for NDC
/// scenes, whose ray parameter is not a camera depth.
pub fn depth_error(
    data: &Path,
    ds: &Dataset,
    views: &[usize],
    depths: &[Vec<f32>],
) -> Result<Option<DepthError>> {
    if ds.ndc.is_some() {
        return Ok(None);
    }
    let (mut abs, mut rel) = (0.0f64, Vec::new());
    for (&v, depth) in views.iter().zip(depths) {
        let path = data.join("gt").join(format!("{}_depth.npy", ds.views[v].name));
        if !path.is_file() {
            continue;
        }
        let truth = nerf_data::npy::read_npy(&path)?.to_f32();
        for (&d, &g) in depth.iter().zip(&truth).filter(|(_, g)| **g > 0.0) {
            let e = (d as f64 - g as f64).abs();
            abs += e;
            rel.push(e / g as f64);
        }
    }
    if rel.is_empty() {
        return Ok(None);
    }
    rel.sort_by(f64::total_cmp);
    Ok(Some(DepthError {
        mean_abs: abs / rel.len() as f64,
        median_relative: rel[rel.len() / 2],
        pixels: rel.len(),
    }))
}

/// 3-D scene-flow error of the dynamic field on the moving objects of a scene from our
/// generator, against the generator's exact rigid motion.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneFlowError {
    /// Mean end-point error of the forward flow (scene units per frame).
    pub epe: f64,
    /// Mean true displacement: the error of predicting no motion.
    pub zero_motion_epe: f64,
    /// Mean length of the predicted flow (a field that learned no motion reads near 0).
    pub predicted_length: f64,
    /// Mean cosine between predicted and true flow (1: right directions, 0: unrelated).
    pub cosine: f64,
    /// The same flow seen by the next frame's camera: mean pixel distance between where the
    /// predicted and the true displacement take the point (the part 2-D optical flow constrains).
    pub pixel_epe: f64,
    /// Pixel distance of the true displacement in the next frame (the no-motion error).
    pub pixel_zero_motion_epe: f64,
    pub points: usize,
}

/// The true first surfaces that the centre rays of every `stride`-th pixel of `camera` hit at
/// `time` in a generated scene, keeping those `keep` accepts.
pub struct SurfaceHits {
    pub hits: Vec<nerf_synth::RayHit>,
    /// The pixel (row-major index) of each hit.
    pub pixels: Vec<u32>,
    /// `[hits.len() * 3]`: the hit points, f32 for the field.
    pub points: Vec<f32>,
    /// `[hits.len() * 3]`: unit ray directions.
    pub dirs: Vec<f32>,
}

/// Traces the pixel-centre rays of `camera` against `scene` at `time` (see [`SurfaceHits`]).
pub fn surface_hits(
    scene: &nerf_synth::Scene,
    camera: &nerf_data::Camera,
    time: f32,
    stride: usize,
    keep: impl Fn(&nerf_synth::RayHit) -> bool,
) -> SurfaceHits {
    let pixels: Vec<u32> = (0..camera.intrinsics.num_pixels() as u32)
        .step_by(stride.max(1))
        .collect();
    let rays = nerf_data::rays::pixel_rays(camera, pixels.iter().copied());
    let mut out = SurfaceHits {
        hits: Vec::new(),
        pixels: Vec::new(),
        points: Vec::new(),
        dirs: Vec::new(),
    };
    for r in 0..rays.len() {
        let (o, d) = (rays.origin(r).map(f64::from), rays.direction(r).map(f64::from));
        let Some(hit) = scene.intersect(o, d, time as f64).filter(&keep) else {
            continue;
        };
        out.points.extend(hit.point.map(|c| c as f32));
        out.dirs.extend(normalize(d).map(|c| c as f32));
        out.pixels.push(pixels[r]);
        out.hits.push(hit);
    }
    out
}

/// At every `stride`-th pixel of every training frame but the last, whose centre ray hits a
/// moving object at that frame's time, compares the field's forward scene flow at the true
/// surface point with the object's displacement to the next frame's time. `None` without a
/// dynamic field, for NDC scenes, or when no ray hits a moving object.
pub fn scene_flow_error(
    model: &NsffModel,
    ds: &Dataset,
    frames: &[usize],
    scene: &nerf_synth::Scene,
    stride: usize,
    device: &Device,
) -> Result<Option<SceneFlowError>> {
    let Some(dynamic) = model.fields.dynamic.as_ref().map(|d| d.valid()) else {
        return Ok(None);
    };
    if ds.ndc.is_some() {
        return Ok(None);
    }
    let plain = device.clone().inner();
    let times = &model.times;
    let moving = scene.moving_objects();
    let (mut sum, mut zero, mut n) = (0.0f64, 0.0f64, 0usize);
    let (mut length, mut cosine) = (0.0f64, 0.0f64);
    let (mut pix, mut pix_zero, mut n_pix) = (0.0f64, 0.0f64, 0usize);
    for k in 0..frames.len().saturating_sub(1) {
        let (t0, t1) = (times[k], times[k + 1]);
        let camera = &ds.views[frames[k]].camera;
        let next_camera = &ds.views[frames[k + 1]].camera;
        let SurfaceHits {
            hits, points, dirs, ..
        } = surface_hits(scene, camera, t0, stride, |h| moving.contains(&h.object));
        if hits.is_empty() {
            continue;
        }
        let truth: Vec<[f64; 3]> = hits
            .iter()
            .map(|h| scene.object_scene_flow(h.object, h.point, t0 as f64, t1 as f64))
            .collect();
        let out = crate::model::query_dynamic(&dynamic, nerf::renderer::tensor(points, 3, &plain), t0, &dirs);
        let pred = read_back(out.extras.expect(FLOW_NEXT), "scene flow")?;
        for (i, g) in truth.iter().enumerate() {
            let p: [f64; 3] = std::array::from_fn(|a| pred[3 * i + a] as f64);
            let (lp, lg) = (norm(p), norm(*g));
            sum += norm(sub(p, *g));
            zero += lg;
            length += lp;
            if lp > 0.0 && lg > 0.0 {
                cosine += dot(p, *g) / (lp * lg);
            }
            let h = hits[i].point;
            let moved = |d: [f64; 3]| next_camera.project(std::array::from_fn(|a| h[a] + d[a]));
            if let (Some(a), Some(b), Some(c)) = (moved(p), moved(*g), moved([0.0; 3])) {
                pix += (a.0 - b.0).hypot(a.1 - b.1);
                pix_zero += (c.0 - b.0).hypot(c.1 - b.1);
                n_pix += 1;
            }
            n += 1;
        }
    }
    Ok((n > 0).then(|| SceneFlowError {
        epe: sum / n as f64,
        zero_motion_epe: zero / n as f64,
        predicted_length: length / n as f64,
        cosine: cosine / n as f64,
        pixel_epe: pix / n_pix.max(1) as f64,
        pixel_zero_motion_epe: pix_zero / n_pix.max(1) as f64,
        points: n,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_synth::{Preset, Scene, SynthConfig};

    /// Checked against the generator's own renderer and the camera's projection, neither of
    /// which `surface_hits` calls: every hit projects back to its pixel's centre at the depth
    /// the renderer reports for that pixel, on the object it reports, and the pixels with a hit
    /// are exactly those the renderer gives an object.
    #[test]
    fn surface_hits_lie_on_their_pixel_centre_rays() {
        let mut cfg = SynthConfig::new(Preset::Family);
        (cfg.seed, cfg.width, cfg.height, cfg.frames, cfg.test_views) = (14, 32, 24, 4, 2);
        let scene = Scene::from_config(&cfg);
        let view = &scene.views[1];
        let camera = scene.camera(view);
        let time = view.time as f32;
        let truth = scene.render(&camera, time as f64);
        let (w, stride) = (cfg.width as usize, 3);
        let pixels: Vec<usize> = (0..truth.depth.len())
            .step_by(stride)
            .filter(|&p| truth.object_id[p] >= 0)
            .collect();
        let all = surface_hits(&scene, &camera, time, stride, |_| true);
        assert_eq!(all.hits.len(), pixels.len());
        assert!(pixels.len() > 50, "the test view should see the scene");
        assert_eq!(
            (all.points.len(), all.dirs.len()),
            (3 * pixels.len(), 3 * pixels.len())
        );
        // `pixel_rays` stores rays in f32, the renderer traces in f64: agree to ~1e-6 px.
        for (i, (hit, &p)) in all.hits.iter().zip(&pixels).enumerate() {
            let (u, v, depth) = camera
                .project(hit.point)
                .expect("hits lie in front of the camera");
            assert!((u - ((p % w) as f64 + 0.5)).abs() < 1e-4, "pixel {p}: u {u}");
            assert!((v - ((p / w) as f64 + 0.5)).abs() < 1e-4, "pixel {p}: v {v}");
            assert!(
                (depth - truth.depth[p] as f64).abs() <= 1e-5 * depth,
                "pixel {p}: depth {depth}"
            );
            assert_eq!(hit.object as i32, truth.object_id[p]);
            let point: [f32; 3] = std::array::from_fn(|a| hit.point[a] as f32);
            assert_eq!(all.points[3 * i..3 * i + 3], point);
            let d = &all.dirs[3 * i..3 * i + 3];
            let to_hit = normalize(sub(hit.point, camera.pose.translation));
            assert!(
                (0..3).all(|a| (d[a] as f64 - to_hit[a]).abs() < 1e-6),
                "pixel {p}: direction"
            );
        }
        // `keep` filters by the hit: only the first object's surface points stay.
        let first = all.hits[0].object;
        let kept = surface_hits(&scene, &camera, time, stride, |h| h.object == first);
        let expected = all.hits.iter().filter(|h| h.object == first).count();
        assert_eq!(kept.hits.len(), expected);
        assert!(
            expected < all.hits.len(),
            "the test view should see more than one object"
        );
    }
}
