//! Optical flow, consistency masks, the flow cache and independent-motion detection, scored
//! against analytic shifts and the synthetic generator's exact ground truth.
//!
//! The bounds quote the values measured when they were set (release build); each is loose
//! enough for float noise but fails if the estimator or a convention broke.

use std::time::Instant;

use nerf_data::{Camera, FlowField, Image, Pose};
use nerf_flow::{
    FlowParams, MIN_MOVING_FRACTION, MaskRule, cache_key, chained_flow, consistency_mask, epipolar_errors,
    estimate_flow, fundamental_matrix, independent_motion, motion_masks, motion_stride, read_flow_cache,
    video_flows, write_flow_cache,
};
use nerf_synth::{Preset, Scene, Split, SynthConfig, SynthView};

#[path = "../../nerf-data/tests/common/mod.rs"]
mod common;
use common::TempDir;

/// A video preset rendered in memory: frames composited over the background, their cameras,
/// the views (for times) and the object id of every pixel.
struct Video {
    scene: Scene,
    views: Vec<SynthView>,
    frames: Vec<Image>,
    cameras: Vec<Camera>,
    ids: Vec<Vec<i32>>,
}

impl Video {
    fn render(preset: Preset, seed: u64) -> Video {
        let scene = Scene::from_config(&SynthConfig::new(preset).with_seed(seed));
        let views: Vec<SynthView> = scene.views_in(Split::Train).cloned().collect();
        let bg = scene.background.map(|v| v as f32);
        let (mut frames, mut cameras, mut ids) = (Vec::new(), Vec::new(), Vec::new());
        for v in &views {
            let cam = scene.camera(v);
            let out = scene.render(&cam, v.time);
            frames.push(out.rgba.composite_alpha(bg).0);
            cameras.push(cam);
            ids.push(out.object_id);
        }
        Video {
            scene,
            views,
            frames,
            cameras,
            ids,
        }
    }

    /// Ground-truth flow and visibility mask from frame a to frame b.
    fn gt(&self, a: usize, b: usize) -> (Vec<f32>, Vec<f32>) {
        self.scene.optical_flow(
            &self.cameras[a],
            self.views[a].time,
            &self.cameras[b],
            self.views[b].time,
        )
    }

    fn size(&self) -> (u32, u32) {
        (self.frames[0].width, self.frames[0].height)
    }
}

/// Mean end-point error over pixels where `keep` holds.
fn mean_epe(flow: &[f32], gt: &[f32], keep: impl Fn(usize) -> bool) -> (f64, usize) {
    let (mut sum, mut n) = (0f64, 0usize);
    for p in 0..gt.len() / 2 {
        if keep(p) {
            sum += ((flow[2 * p] - gt[2 * p]) as f64).hypot((flow[2 * p + 1] - gt[2 * p + 1]) as f64);
            n += 1;
        }
    }
    (sum / n.max(1) as f64, n)
}

/// A band-limited analytic texture: random-phase sinusoids with 5-24 px wavelengths.
fn texture(x: f64, y: f64) -> f32 {
    let waves = [
        (0.31, 0.12, 0.4),
        (-0.17, 0.27, 1.3),
        (0.07, -0.41, 2.1),
        (0.52, 0.33, 0.7),
        (-0.44, 0.21, 2.9),
        (0.26, -0.05, 1.7),
    ];
    let v: f64 = waves.iter().map(|&(a, b, ph)| (a * x + b * y + ph).sin()).sum();
    (0.5 + v / 12.0) as f32
}

#[test]
fn recovers_a_subpixel_translation() {
    let (w, h) = (128u32, 96u32);
    let d = (2.3f32, -1.7f32);
    let render = |shift: (f32, f32)| {
        let data = (0..w * h)
            .map(|p| {
                texture(
                    (p % w) as f64 + 0.5 - shift.0 as f64,
                    (p / w) as f64 + 0.5 - shift.1 as f64,
                )
            })
            .collect();
        Image::from_data(w, h, 1, data)
    };
    let a = render((0.0, 0.0));
    // b(q) = a(q − d): pixel p of a is found at p + d in b. Once analytically, once by bilinear
    // resampling of a (which also blurs b a little, as real resampling does).
    let exact = render(d);
    let bilinear = Image::from_data(
        w,
        h,
        1,
        (0..w * h)
            .map(|p| {
                let (x, y) = ((p % w) as f32 - d.0, (p / w) as f32 - d.1);
                let (x0, y0) = (x.floor(), y.floor());
                let (fx, fy) = (x - x0, y - y0);
                let at = |i: f32, j: f32| {
                    let (i, j) = (i.clamp(0.0, (w - 1) as f32), j.clamp(0.0, (h - 1) as f32));
                    a.data[(j as u32 * w + i as u32) as usize]
                };
                (1.0 - fy) * ((1.0 - fx) * at(x0, y0) + fx * at(x0 + 1.0, y0))
                    + fy * ((1.0 - fx) * at(x0, y0 + 1.0) + fx * at(x0 + 1.0, y0 + 1.0))
            })
            .collect(),
    );
    let gt: Vec<f32> = (0..w * h).flat_map(|_| [d.0, d.1]).collect();
    let margin = 8;
    let interior = |p: usize| {
        let (x, y) = (p as u32 % w, p as u32 / w);
        (margin..w - margin).contains(&x) && (margin..h - margin).contains(&y)
    };
    for (name, b, bound) in [("analytic", &exact, 0.1), ("bilinear", &bilinear, 0.2)] {
        let flow = estimate_flow(&a, b, &FlowParams::default());
        let (epe, n) = mean_epe(&flow, &gt, interior);
        println!("{name} shift: mean EPE {epe:.4} px over {n} interior pixels");
        // Measured: analytic 0.0053 px, bilinear 0.028 px.
        assert!(epe < bound, "{name} shift: mean EPE {epe} px");
    }
}

#[test]
fn dynamic_preset_flow_matches_ground_truth() {
    let video = Video::render(Preset::Dynamic, 0);
    let params = FlowParams::default();
    let (mut sum, mut count, mut secs) = (0f64, 0usize, 0f64);
    for k in [0, 7, 15, 22] {
        let t = Instant::now();
        let flow = estimate_flow(&video.frames[k], &video.frames[k + 1], &params);
        secs += t.elapsed().as_secs_f64();
        let (gt, mask) = video.gt(k, k + 1);
        let (epe, n) = mean_epe(&flow, &gt, |p| mask[p] > 0.5);
        println!("pair {k}->{}: mean EPE {epe:.3} px over {n} pixels", k + 1);
        sum += epe * n as f64;
        count += n;
    }
    let epe = sum / count as f64;
    println!(
        "dynamic seed 0, 4 pairs: mean EPE {epe:.3} px ({:.0} ms per pair)",
        secs * 250.0
    );
    // Measured 0.149 px (flow about 2 px; 0.169, 0.147, 0.137, 0.143 per pair); bound = 1.4x.
    assert!(epe < 0.21, "mean EPE {epe} px");
}

#[test]
fn consistency_mask_on_analytic_flows() {
    let (w, h) = (20u32, 10u32);
    let n = (w * h) as usize;
    let fwd: Vec<f32> = (0..n).flat_map(|_| [2.0, 1.0]).collect();
    let bwd: Vec<f32> = (0..n).flat_map(|_| [-2.0, -1.0]).collect();
    let mask = consistency_mask(&fwd, &bwd, w, h);
    for p in 0..n {
        let (x, y) = (p as u32 % w, p as u32 / w);
        // Pixel centre x + 0.5 + 2 must stay below W; y + 0.5 + 1 below H.
        let inside = x + 2 < w && y + 1 < h;
        assert_eq!(mask[p], if inside { 1.0 } else { 0.0 }, "pixel ({x}, {y})");
    }
    // A backward flow that does not return: inconsistent wherever |f| is large enough.
    let zero = vec![0.0; 2 * n];
    assert!(consistency_mask(&fwd, &zero, w, h).iter().all(|&m| m == 0.0));
    // Tiny flows pass through the +0.5 px slack.
    let small: Vec<f32> = (0..n).flat_map(|_| [0.2, 0.1]).collect();
    let m = consistency_mask(&small, &zero, w, h);
    assert_eq!(m[0], 1.0);
}

/// Share of GT-occluded pixels the estimated flows' consistency mask rejects, and share of
/// GT-valid pixels it keeps. `occluded(p)`: p is visible in a, hidden in b but inside the image.
fn occlusion_rates(
    a: &Image,
    b: &Image,
    occluded: impl Fn(usize) -> bool,
    valid: impl Fn(usize) -> bool,
) -> (f64, f64, usize) {
    let params = FlowParams::default();
    let (fwd, bwd) = rayon_join(|| estimate_flow(a, b, &params), || estimate_flow(b, a, &params));
    let mask = consistency_mask(&fwd, &bwd, a.width, a.height);
    let (mut occ, mut occ_out, mut val, mut val_kept) = (0usize, 0usize, 0usize, 0usize);
    for p in 0..mask.len() {
        if occluded(p) {
            occ += 1;
            occ_out += (mask[p] < 0.5) as usize;
        } else if valid(p) {
            val += 1;
            val_kept += (mask[p] > 0.5) as usize;
        }
    }
    (occ_out as f64 / occ as f64, val_kept as f64 / val as f64, occ)
}

fn rayon_join<A: Send, B: Send>(a: impl FnOnce() -> A + Send, b: impl FnOnce() -> B + Send) -> (A, B) {
    std::thread::scope(|s| {
        let hb = s.spawn(b);
        (a(), hb.join().unwrap())
    })
}

#[test]
fn consistency_mask_flags_occlusions_by_a_moving_object() {
    // A textured square moves by d over a static textured background (analytic ground truth).
    let (w, h) = (128u32, 96u32);
    let (x0, y0, side, d) = (40.0f64, 30.0f64, 32.0f64, (5.0f64, 3.0f64));
    let inside =
        |x: f64, y: f64, ox: f64, oy: f64| (ox..ox + side).contains(&x) && (oy..oy + side).contains(&y);
    let render = |ox: f64, oy: f64| {
        let data = (0..w * h)
            .map(|p| {
                let (x, y) = ((p % w) as f64 + 0.5, (p / w) as f64 + 0.5);
                if inside(x, y, ox, oy) {
                    // The square's own texture moves with it.
                    1.0 - texture(2.0 * (x - ox) + 7.0, 1.5 * (y - oy) - 3.0)
                } else {
                    texture(x, y)
                }
            })
            .collect();
        Image::from_data(w, h, 1, data)
    };
    let (a, b) = (render(x0, y0), render(x0 + d.0, y0 + d.1));
    let centre = |p: usize| ((p as u32 % w) as f64 + 0.5, (p as u32 / w) as f64 + 0.5);
    let occluded = |p: usize| {
        let (x, y) = centre(p);
        !inside(x, y, x0, y0) && inside(x, y, x0 + d.0, y0 + d.1)
    };
    let valid = |p: usize| {
        let (x, y) = centre(p);
        let (tx, ty) = if inside(x, y, x0, y0) {
            (x + d.0, y + d.1)
        } else {
            (x, y)
        };
        tx < w as f64 && ty < h as f64
    };
    let (rejected, kept, n) = occlusion_rates(&a, &b, occluded, valid);
    println!(
        "moving square: {rejected:.3} of {n} occluded pixels masked out, {kept:.4} of valid pixels kept"
    );
    // Measured: 0.30 of the 241 occluded pixels rejected, 0.993 of the valid pixels kept (0.41
    // and 0.970 for d = (8, 5)). The flow fills the occluded band with a ramp between the
    // square's and the background's motion, and NSFF's lenient relative test accepts the part
    // of the ramp that nearly agrees with the backward flow: it rejects the band's outer part.
    assert!(rejected > 0.2 && kept > 0.98, "{rejected} {kept}");
}

#[test]
fn consistency_mask_on_the_dynamic_preset() {
    // With a moving camera NSFF's relative test (|f + b̃| < 0.5·(|f| + |b̃|) + 0.5) only rejects
    // occluded pixels whose motion differs from the occluder's by more than about half the flow,
    // so here it rejects a minority of them; it must still keep nearly all valid pixels.
    let video = Video::render(Preset::Dynamic, 0);
    let (w, h) = video.size();
    let (mut rej, mut kept, mut count) = (0f64, 0f64, 0usize);
    for k in [3, 11, 19] {
        let (gt, gt_mask) = video.gt(k, k + 1);
        let occluded = |p: usize| {
            let (x, y) = ((p as u32 % w) as f32 + 0.5, (p as u32 / w) as f32 + 0.5);
            let (tx, ty) = (x + gt[2 * p], y + gt[2 * p + 1]);
            let lands_inside = tx >= 0.0 && tx < w as f32 && ty >= 0.0 && ty < h as f32;
            gt_mask[p] < 0.5 && video.ids[k][p] >= 0 && lands_inside
        };
        let (r, kp, n) = occlusion_rates(&video.frames[k], &video.frames[k + 1], occluded, |p| {
            gt_mask[p] > 0.5
        });
        rej += r * n as f64;
        kept += kp;
        count += n;
    }
    let (rejected, kept) = (rej / count as f64, kept / 3.0);
    println!(
        "dynamic preset: {rejected:.3} of {count} occluded pixels masked out, {kept:.4} of valid pixels kept"
    );
    // Measured: 0.27 of 362 occluded pixels rejected, 0.998 of valid pixels kept.
    assert!(rejected > 0.15 && kept > 0.98, "{rejected} {kept}");
}

#[test]
fn ground_truth_flow_of_a_static_video_lies_on_the_epipolar_lines() {
    // Independent check of F's conventions: exact flow of a static scene from the ray tracer.
    let video = Video::render(Preset::StaticVideo, 0);
    let (w, h) = video.size();
    let mut worst = 0f32;
    for k in [0, 10, 22] {
        for (a, b) in [(k, k + 1), (k + 1, k)] {
            let (flow, mask) = video.gt(a, b);
            let field = FlowField {
                width: w,
                height: h,
                flow,
                mask,
            };
            let err = epipolar_errors(&field, &video.cameras[a], &video.cameras[b]);
            let valid: Vec<f32> = err.iter().copied().filter(|e| !e.is_nan()).collect();
            assert_eq!(valid.len(), field.mask.iter().filter(|&&m| m > 0.5).count());
            worst = valid.iter().fold(worst, |m, &e| m.max(e));
        }
    }
    println!("static video, ground-truth flow: worst epipolar error {worst:.2e} px");
    // Measured: 2e-4 px (f32 flow storage).
    assert!(worst < 0.05, "worst epipolar error {worst} px");

    // The moving cube's exact flow leaves its epipolar lines; the static objects' does not.
    let dynamic = Video::render(Preset::Dynamic, 0);
    let mover = dynamic.scene.moving_objects()[0] as i32;
    let (mut cube, mut cube_off, mut rest, mut rest_off) = (0usize, 0usize, 0usize, 0usize);
    for k in 0..dynamic.frames.len() - 1 {
        let (flow, mask) = dynamic.gt(k, k + 1);
        let field = FlowField {
            width: w,
            height: h,
            flow,
            mask,
        };
        let err = epipolar_errors(&field, &dynamic.cameras[k], &dynamic.cameras[k + 1]);
        for (p, e) in err.iter().enumerate().filter(|(_, e)| !e.is_nan()) {
            if dynamic.ids[k][p] == mover {
                cube += 1;
                cube_off += (*e > 0.5) as usize;
            } else {
                rest += 1;
                rest_off += (*e > 0.5) as usize;
            }
        }
    }
    let (cube_rate, rest_rate) = (cube_off as f64 / cube as f64, rest_off as f64 / rest as f64);
    println!("dynamic, ground-truth flow, error > 0.5 px: cube {cube_rate:.3}, static {rest_rate:.5}");
    // Measured: cube 0.648 (it moves mostly along the epipolar lines), static 0.
    assert!(cube_rate > 0.4 && rest_rate < 1e-3, "{cube_rate} {rest_rate}");
}

#[test]
fn a_rotating_camera_is_scored_by_the_rotation_transfer() {
    // No baseline: the epipolar geometry is undefined, static points follow the homography.
    let scene = Scene::from_config(&SynthConfig::new(Preset::StaticVideo));
    let v = &scene.views_in(Split::Train).next().unwrap().clone();
    let cam_a = scene.camera(v);
    let cam_b = Camera::new(
        cam_a.intrinsics,
        Pose::look_at(v.eye, [0.2, -0.1, 0.1], [0.0, 0.0, 1.0]),
    );
    let (flow, mask) = scene.optical_flow(&cam_a, v.time, &cam_b, v.time);
    let (w, h) = (cam_a.intrinsics.width, cam_a.intrinsics.height);
    let magnitude = (0..mask.len())
        .filter(|&p| mask[p] > 0.5)
        .map(|p| flow[2 * p].hypot(flow[2 * p + 1]))
        .fold(0f32, f32::max);
    let field = FlowField {
        width: w,
        height: h,
        flow: flow.clone(),
        mask: mask.clone(),
    };
    let err = epipolar_errors(&field, &cam_a, &cam_b);
    let worst = err.iter().filter(|e| !e.is_nan()).fold(0f32, |m, &e| m.max(e));
    println!("pure rotation: flow up to {magnitude:.1} px, worst transfer error {worst:.2e} px");
    assert!(magnitude > 3.0 && worst < 0.05, "{magnitude} {worst}");
    // A flow that ignores the rotation is caught everywhere.
    let wrong = FlowField {
        flow: vec![0.0; flow.len()],
        ..field
    };
    let err = epipolar_errors(&wrong, &cam_a, &cam_b);
    let caught = err.iter().filter(|e| !e.is_nan() && **e > 1.0).count();
    assert!(caught > mask.iter().filter(|&&m| m > 0.5).count() / 2);
}

#[test]
fn a_tiny_baseline_is_scored_by_the_rotation_transfer() {
    // 1e-4 units of translation: F exists, but its lines come from noise-level parallax
    // (~0.004 px here). Motion along those lines must still be caught.
    let scene = Scene::from_config(&SynthConfig::new(Preset::StaticVideo));
    let v = scene.views_in(Split::Train).next().unwrap().clone();
    let cam_a = scene.camera(&v);
    let eye_b = [v.eye[0] + 1e-4, v.eye[1], v.eye[2]];
    let cam_b = Camera::new(
        cam_a.intrinsics,
        Pose::look_at(eye_b, [0.15, 0.1, 0.0], [0.0, 0.0, 1.0]),
    );
    let f = fundamental_matrix(&cam_a, &cam_b).expect("a non-zero baseline has a fundamental matrix");
    let (mut flow, mask) = scene.optical_flow(&cam_a, v.time, &cam_b, v.time);
    let (w, h) = (cam_a.intrinsics.width, cam_a.intrinsics.height);
    // Every 10th valid pixel slides 2 px along its epipolar line: zero epipolar distance.
    let mut slid = Vec::new();
    for p in (0..mask.len()).filter(|&p| mask[p] > 0.5).step_by(10) {
        let (x, y) = ((p as u32 % w) as f64 + 0.5, (p as u32 / w) as f64 + 0.5);
        let l: Vec<f64> = (0..3).map(|r| f[r][0] * x + f[r][1] * y + f[r][2]).collect();
        let n = l[0].hypot(l[1]);
        flow[2 * p] += (-2.0 * l[1] / n) as f32;
        flow[2 * p + 1] += (2.0 * l[0] / n) as f32;
        slid.push(p);
    }
    let field = FlowField {
        width: w,
        height: h,
        flow,
        mask,
    };
    let err = epipolar_errors(&field, &cam_a, &cam_b);
    let caught = slid.iter().filter(|&&p| err[p] > 1.9).count();
    let static_worst = (0..err.len())
        .filter(|p| !err[*p].is_nan() && !slid.contains(p))
        .map(|p| err[p])
        .fold(0f32, f32::max);
    println!(
        "tiny baseline: {caught} of {} slid pixels caught, static worst {static_worst:.3} px",
        slid.len()
    );
    assert_eq!(caught, slid.len());
    assert!(static_worst < 0.05, "{static_worst}");
}

/// Flows of a whole video with [`video_flows`], the motion report and motion masks.
/// Returns (moving fraction, has motion, share of the cube's pixels in the motion masks, share
/// of the other pixels in them).
fn motion_of(preset: Preset) -> (f32, bool, f64, f64) {
    let video = Video::render(preset, 0);
    let t = Instant::now();
    let refs: Vec<&Image> = video.frames.iter().collect();
    let (fwd, bwd) = video_flows(&refs, &FlowParams::default());
    let secs = t.elapsed().as_secs_f64();
    let n = video.frames.len();
    assert!(fwd[n - 1].is_none() && bwd[0].is_none());
    assert!(fwd[..n - 1].iter().all(Option::is_some) && bwd[1..].iter().all(Option::is_some));
    let stride = motion_stride(n);
    let report = independent_motion(&video.cameras, &fwd, 1.0, stride);
    println!(
        "{preset}: moving fraction {:.5}, worst frame {:.4} ({} flows in {secs:.2} s)",
        report.moving_fraction,
        report
            .per_frame
            .iter()
            .copied()
            .filter(|v| !v.is_nan())
            .fold(0f32, f32::max),
        2 * (n - 1)
    );
    assert_eq!(report.per_frame.len(), n);
    // Frames with no partner `stride` ahead have no score.
    assert!(
        report.per_frame[n - stride..].iter().all(|v| v.is_nan())
            && report.per_frame[..n - stride].iter().all(|v| !v.is_nan())
    );

    let masks = motion_masks(&video.cameras, &fwd, &bwd, MaskRule::either(1.0), stride);
    let mover = video
        .scene
        .objects
        .iter()
        .position(|o| o.name == "mover")
        .unwrap() as i32;
    let (mut on, mut cube, mut off, mut rest) = (0usize, 0usize, 0usize, 0usize);
    for (m, ids) in masks.iter().zip(&video.ids) {
        for (mv, id) in m.iter().zip(ids) {
            if *id == mover {
                cube += 1;
                on += (*mv > 0.5) as usize;
            } else {
                rest += 1;
                off += (*mv > 0.5) as usize;
            }
        }
    }
    let (cube_rate, rest_rate) = (on as f64 / cube as f64, off as f64 / rest as f64);
    println!("{preset}: motion masks cover {cube_rate:.3} of the cube, {rest_rate:.4} of the rest");
    (
        report.moving_fraction,
        report.has_independent_motion,
        cube_rate,
        rest_rate,
    )
}

#[test]
fn the_both_neighbours_rule_keeps_an_error_towards_one_neighbour_out_of_the_mask() {
    // Three frames of the dynamic video with exact flows, except that the middle frame's
    // backward flow is 3 px off the epipolar lines on the static pixels of its left third (as
    // where an occlusion edge breaks the flow towards one neighbour only).
    let video = Video::render(Preset::Dynamic, 0);
    let (w, h) = video.size();
    let field = |(flow, mask): (Vec<f32>, Vec<f32>)| FlowField {
        width: w,
        height: h,
        flow,
        mask,
    };
    let (a, k, b) = (10, 11, 12);
    let mover = video.scene.moving_objects()[0] as i32;
    let mut broken = field(video.gt(k, a));
    let corrupted: Vec<usize> = (0..(w * h) as usize)
        .filter(|&p| p % w as usize <= w as usize / 3 && broken.mask[p] > 0.5 && video.ids[k][p] != mover)
        .collect();
    for &p in &corrupted {
        broken.flow[2 * p + 1] += 3.0;
    }
    let cameras = [video.cameras[a], video.cameras[k], video.cameras[b]];
    let fwd = [Some(field(video.gt(a, k))), Some(field(video.gt(k, b))), None];
    let bwd = [None, Some(broken), Some(field(video.gt(b, k)))];
    let masks = |both_neighbours| {
        let rule = MaskRule {
            threshold_px: 0.5,
            both_neighbours,
        };
        motion_masks(&cameras, &fwd, &bwd, rule, 1).swap_remove(1)
    };
    let (either, both) = (masks(false), masks(true));
    let share = |m: &[f32], pixels: &mut dyn Iterator<Item = usize>| {
        let (mut on, mut n) = (0usize, 0usize);
        for p in pixels {
            n += 1;
            on += usize::from(m[p] > 0.5);
        }
        on as f64 / n.max(1) as f64
    };
    let cube = || (0..(w * h) as usize).filter(|&p| video.ids[k][p] == mover);
    let (broken_either, broken_both) = (
        share(&either, &mut corrupted.iter().copied()),
        share(&both, &mut corrupted.iter().copied()),
    );
    let (cube_either, cube_both) = (share(&either, &mut cube()), share(&both, &mut cube()));
    println!(
        "one broken neighbour: masked {broken_either:.3} (either) / {broken_both:.3} (both); \
         cube {cube_either:.3} / {cube_both:.3}"
    );
    // Measured: broken pixels masked 1.000 / 0.000, the cube 0.932 / 0.928 (it moves off its
    // epipolar lines towards both neighbours). The smaller error never exceeds the larger, and
    // the mask's morphology is monotone, so `both` lies inside `either`.
    assert!(either.iter().zip(&both).all(|(e, b)| e >= b));
    assert!(broken_either > 0.95, "{broken_either}");
    assert!(broken_both < 0.05, "{broken_both}");
    assert!(cube_both > 0.8, "{cube_both}");
}

#[test]
fn detects_the_moving_cube_of_the_dynamic_video() {
    let (fraction, moving, cube, rest) = motion_of(Preset::Dynamic);
    // Measured with flows chained over 3 frames: moving fraction 0.104 (0.0215 between
    // neighbours). Motion masks cover 0.988 of the cube (0.34 between neighbours: it moves
    // mostly along the epipolar lines, and less than a pixel per frame) and 0.047 of the rest
    // (the swept area, occlusion edges and the dilation).
    assert!(moving && fraction > 0.05, "moving fraction {fraction}");
    assert!(cube > 0.9 && rest < 0.08, "{cube} {rest}");
}

#[test]
fn finds_no_independent_motion_in_the_static_video() {
    let (fraction, moving, cube, rest) = motion_of(Preset::StaticVideo);
    // Measured with flows chained over 3 frames: moving fraction 0.0043 (0.00003 between
    // neighbours; other seeds up to 0.026, which then train a dynamic field for nothing: the
    // chained test is biased towards finding motion, BENCHMARKS.md §6).
    assert!(
        !moving && fraction < MIN_MOVING_FRACTION,
        "moving fraction {fraction}"
    );
    assert!(cube + rest < 0.03, "{cube} {rest}");
}

fn some_fields(w: u32, h: u32, n: usize) -> (Vec<Option<FlowField>>, Vec<Option<FlowField>>) {
    let field = |i: usize, sign: f32| FlowField {
        width: w,
        height: h,
        flow: (0..2 * w * h)
            .map(|k| sign * (k as f32 * 0.37 + i as f32).sin() * 3.0)
            .collect(),
        mask: (0..w * h)
            .map(|k| f32::from(u8::from(!(k as usize + i).is_multiple_of(3))))
            .collect(),
    };
    (
        (0..n).map(|i| (i + 1 < n).then(|| field(i, 1.0))).collect(),
        (0..n).map(|i| (i > 0).then(|| field(i, -1.0))).collect(),
    )
}

#[test]
fn flow_cache_round_trips_and_reports_bad_files() {
    let tmp = TempDir::new("cache");
    let dir = tmp.0.join("flow_i1");
    let (w, h, n) = (12u32, 8u32, 5usize);
    let key = "video A\n";
    assert!(
        read_flow_cache(&dir, key, n, w, h).unwrap().is_none(),
        "no folder yet"
    );
    let (fwd, bwd) = some_fields(w, h, n);
    write_flow_cache(&dir, key, &fwd, &bwd).unwrap();
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names.len(), 2 * (n - 1) + 1, "{names:?}");
    assert_eq!(names[0], "00000_fwd.npz");
    assert!(names.contains(&"00004_bwd.npz".to_string()) && !names.contains(&"00004_fwd.npz".to_string()));
    assert_eq!(std::fs::read_to_string(dir.join("key.txt")).unwrap(), key);

    let (rf, rb) = read_flow_cache(&dir, key, n, w, h)
        .unwrap()
        .expect("complete cache");
    assert_eq!((rf, rb), (fwd.clone(), bwd.clone()));

    // The NSFF video loader reads the same files (it is the reader the cache uses).
    let arrays = nerf_data::npz::read_npz(&dir.join("00002_bwd.npz")).unwrap();
    assert_eq!(arrays["flow"].shape, vec![h as usize, w as usize, 2]);
    assert_eq!(arrays["mask"].shape, vec![h as usize, w as usize]);

    // Another video (or other settings): not read, so recomputed.
    assert!(read_flow_cache(&dir, "video B\n", n, w, h).unwrap().is_none());
    // More frames than cached: incomplete, so None (recompute).
    assert!(read_flow_cache(&dir, key, n + 1, w, h).unwrap().is_none());

    // A file of the wrong resolution under a matching key is an error naming the file and both
    // shapes: the folder was damaged, not left by another video.
    let (small_fwd, small_bwd) = some_fields(6, 4, n);
    let other = tmp.0.join("other");
    write_flow_cache(&other, key, &small_fwd, &small_bwd).unwrap();
    std::fs::copy(other.join("00003_fwd.npz"), dir.join("00003_fwd.npz")).unwrap();
    let err = read_flow_cache(&dir, key, n, w, h).unwrap_err().to_string();
    assert!(
        err.contains("00003_fwd.npz") && err.contains("flow is 4x6x2 but frames are 8x12"),
        "{err}"
    );

    // A missing file makes the cache incomplete rather than an error.
    std::fs::remove_file(dir.join("00003_fwd.npz")).unwrap();
    assert!(read_flow_cache(&dir, key, n, w, h).unwrap().is_none());

    // Rewriting under a new key replaces the key; a cache without one (an older run's) is not read.
    write_flow_cache(&dir, "video B\n", &fwd, &bwd).unwrap();
    assert!(read_flow_cache(&dir, key, n, w, h).unwrap().is_none());
    assert!(read_flow_cache(&dir, "video B\n", n, w, h).unwrap().is_some());
    std::fs::remove_file(dir.join("key.txt")).unwrap();
    assert!(read_flow_cache(&dir, "video B\n", n, w, h).unwrap().is_none());
}

#[test]
fn the_cache_key_follows_the_pixels_and_the_settings() {
    let a = Video::render(Preset::Dynamic, 0);
    let b = Video::render(Preset::Dynamic, 1);
    let (fa, fb) = (a.frames.clone(), b.frames.clone());
    fn refs(f: &[Image]) -> Vec<&Image> {
        f.iter().collect()
    }
    let params = FlowParams::default();
    let key_a = cache_key(&refs(&fa), &params);
    assert_eq!(key_a, cache_key(&refs(&fa), &params), "deterministic");
    assert!(
        key_a.starts_with(&format!(
            "frames {} size {}x{} ",
            fa.len(),
            fa[0].width,
            fa[0].height
        )),
        "{key_a}"
    );
    // Same size and frame count, other pixels.
    assert_eq!((fa.len(), fa[0].width), (fb.len(), fb[0].width));
    assert_ne!(key_a, cache_key(&refs(&fb), &params));
    // One pixel of one frame changed by one step of 8 bits.
    let mut touched = fa.clone();
    touched[3].data[17] += 1.0 / 255.0;
    assert_ne!(key_a, cache_key(&refs(&touched), &params));
    let other = FlowParams {
        warps: params.warps + 1,
        ..params
    };
    assert_ne!(key_a, cache_key(&refs(&fa), &other));
}

#[test]
fn flow_of_a_training_size_pair_is_fast_enough() {
    let video = Video::render(Preset::Dynamic, 0);
    let t = Instant::now();
    let _ = estimate_flow(&video.frames[0], &video.frames[1], &FlowParams::default());
    let secs = t.elapsed().as_secs_f64();
    println!("128x96 pair: {:.0} ms", 1e3 * secs);
    // Measured 50-190 ms in release on a busy 2-core machine; debug builds are ~20x slower.
    let bound = if cfg!(debug_assertions) { 20.0 } else { 1.0 };
    assert!(secs < bound, "{secs} s");
}

/// Full-sequence report: `cargo test -p nerf-flow --release --test flow -- --ignored --nocapture`.
#[test]
#[ignore = "report: mean EPE over every forward pair of the dynamic preset, and a 512x288 timing"]
fn report_full_dynamic_sequence() {
    let video = Video::render(Preset::Dynamic, 0);
    let (mut sum, mut count, mut secs) = (0f64, 0usize, 0f64);
    for k in 0..video.frames.len() - 1 {
        let t = Instant::now();
        let flow = estimate_flow(&video.frames[k], &video.frames[k + 1], &FlowParams::default());
        secs += t.elapsed().as_secs_f64();
        let (gt, mask) = video.gt(k, k + 1);
        let (epe, n) = mean_epe(&flow, &gt, |p| mask[p] > 0.5);
        sum += epe * n as f64;
        count += n;
    }
    let pairs = video.frames.len() - 1;
    println!(
        "dynamic seed 0, 128x96, {pairs} forward pairs: mean EPE {:.3} px, {:.1} ms per pair",
        sum / count as f64,
        1e3 * secs / pairs as f64
    );
    let scene = Scene::from_config(&SynthConfig::new(Preset::Dynamic).with_size(512, 288));
    let views: Vec<SynthView> = scene.views_in(Split::Train).take(2).cloned().collect();
    let frames: Vec<Image> = views
        .iter()
        .map(|v| {
            scene
                .render(&scene.camera(v), v.time)
                .rgba
                .composite_alpha([1.0; 3])
                .0
        })
        .collect();
    let t = Instant::now();
    let flow = estimate_flow(&frames[0], &frames[1], &FlowParams::default());
    let secs = t.elapsed().as_secs_f64();
    let (gt, mask) = scene.optical_flow(
        &scene.camera(&views[0]),
        views[0].time,
        &scene.camera(&views[1]),
        views[1].time,
    );
    let (epe, _) = mean_epe(&flow, &gt, |p| mask[p] > 0.5);
    println!("512x288 pair 0->1: mean EPE {epe:.3} px in {secs:.2} s");
}

#[test]
fn chained_flows_match_the_direct_flow_over_several_frames() {
    let video = Video::render(Preset::Dynamic, 2);
    let (w, h) = video.size();
    let n = video.frames.len();
    let field = |(flow, mask): (Vec<f32>, Vec<f32>)| FlowField {
        width: w,
        height: h,
        flow,
        mask,
    };
    let fwd: Vec<Option<FlowField>> = (0..n)
        .map(|i| (i + 1 < n).then(|| field(video.gt(i, i + 1))))
        .collect();
    let bwd: Vec<Option<FlowField>> = (0..n)
        .map(|i| (i > 0).then(|| field(video.gt(i, i - 1))))
        .collect();
    for (i, stride, step) in [(2usize, 3usize, 1isize), (10, 3, -1), (5, 1, 1)] {
        let chained = chained_flow(if step > 0 { &fwd } else { &bwd }, i, stride, step).unwrap();
        let j = i.checked_add_signed(step * stride as isize).unwrap();
        let (direct, visible) = video.gt(i, j);
        // Where every link and the direct flow are trusted, chaining lands where the direct
        // flow does (up to bilinear lookups across object edges).
        let (epe, count) = mean_epe(&chained.flow, &direct, |p| {
            chained.mask[p] > 0.5 && visible[p] > 0.5
        });
        println!("frames {i} -> {j}: chained vs direct EPE {epe:.4} px over {count} pixels");
        assert!(count as u32 > w * h / 3, "{count}");
        assert!(epe < 0.05, "{epe}");
    }
    // A missing link gives no chained flow.
    assert!(chained_flow(&fwd, n - 2, 3, 1).is_none());
}
