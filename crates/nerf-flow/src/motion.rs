//! Independent-motion detection with NSFF's epipolar test (method.md §4.2): a static point seen
//! at p in frame a must appear on the epipolar line of p in frame b, so a flow vector that lands
//! far from that line belongs to something that moved on its own.
//!
//! Geometry. Our cameras are OpenGL-style (x right, y up, z back) with pixel centres at
//! (i + 0.5, j + 0.5) and the principal point in the same continuous coordinates. With
//! S = diag(1, −1, −1), OpenCV camera coordinates are X_cv = S·R_cᵀ·(X − t_c), and then
//! `K·X_cv / z` with the usual K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] reproduces
//! [`Camera::project`]. For the pair (a, b):
//! R = S·R_bᵀ·R_a·S, T = S·R_bᵀ·(t_a − t_b), E = [T]ₓ·R, F = K_b⁻ᵀ·E·K_a⁻¹, and the epipolar
//! line of p̃ = (i + 0.5, j + 0.5, 1) is l = F·p̃. The error is |p̃_bᵀ·l| / √(l₀² + l₁²) with
//! p_b = p + flow(p). T is normalised, so the result does not depend on the scene's scale.
//!
//! Small baselines. With no camera translation the epipolar line is undefined (F = 0), and with a
//! tiny one its direction is set by pose noise while static points barely show parallax. Then
//! the static scene is explained by the camera rotation alone: static points follow the
//! infinite homography H = K_b·R·K_a⁻¹. So when the baseline is numerically zero, or when the
//! median over valid pixels of the transfer error |p_b − H·p̃| is below
//! [`LOW_PARALLAX_PX`], [`epipolar_errors`] returns that transfer error instead. It is never
//! smaller than the epipolar distance (H·p̃ lies on the epipolar line), so the test only gets
//! stricter where it can afford to.

use nerf_data::camera::Camera;
use nerf_data::dataset::FlowField;
use nerf_data::mask::{grow, morph_cross};
use nerf_data::math::{self, Mat3, Vec3};

/// Below this median rotation-transfer error (pixels) a pair is scored with the transfer error
/// rather than the epipolar distance (see the module docs).
pub const LOW_PARALLAX_PX: f32 = 0.5;

/// Smallest share of valid pixels that must be moving (after the opening) over all frame pairs
/// for [`independent_motion`] to report motion. Measured on our generator with estimated flow
/// at a 1 px threshold (seeds 0-5, 128×96): `dynamic` 1.7-2.5%, `static_video` ≤ 0.006%. The
/// moving cube covers ~7% of the pixels, and only part of it leaves its epipolar lines, so a
/// smaller independently moving object (~1% of the image) would still register.
pub const MIN_MOVING_FRACTION: f32 = 0.005;

/// Result of [`independent_motion`].
#[derive(Clone, Debug, PartialEq)]
pub struct MotionReport {
    /// Pixels judged moving (epipolar error above the threshold, after a 3×3-cross opening) as a
    /// share of all valid (mask 1) pixels over every forward pair.
    pub moving_fraction: f32,
    /// The same share per frame, from that frame's forward flow; NaN for frames without one (the
    /// last frame) or without valid pixels.
    pub per_frame: Vec<f32>,
    /// `moving_fraction > MIN_MOVING_FRACTION`.
    pub has_independent_motion: bool,
}

const S: Mat3 = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];

fn k_matrix(cam: &Camera) -> Mat3 {
    let k = &cam.intrinsics;
    [[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]]
}

fn k_inverse(cam: &Camera) -> Mat3 {
    let k = &cam.intrinsics;
    [
        [1.0 / k.fx, 0.0, -k.cx / k.fx],
        [0.0, 1.0 / k.fy, -k.cy / k.fy],
        [0.0, 0.0, 1.0],
    ]
}

fn skew(t: Vec3) -> Mat3 {
    [[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]]
}

/// The relative motion a → b in OpenCV camera coordinates: (R, T) with X_b = R·X_a + T.
fn relative_pose(cam_a: &Camera, cam_b: &Camera) -> (Mat3, Vec3) {
    let rbt = math::transpose(&cam_b.pose.rotation);
    let r = math::mat_mul(&S, &math::mat_mul(&rbt, &math::mat_mul(&cam_a.pose.rotation, &S)));
    let t = math::mat_vec(
        &S,
        math::mat_vec(&rbt, math::sub(cam_a.pose.translation, cam_b.pose.translation)),
    );
    (r, t)
}

/// The fundamental matrix of the pair in pixel-centre coordinates (x_bᵀ·F·x_a = 0), or `None`
/// when the baseline is numerically zero. The translation is normalised first.
pub fn fundamental_matrix(cam_a: &Camera, cam_b: &Camera) -> Option<Mat3> {
    let (r, t) = relative_pose(cam_a, cam_b);
    let scale = math::norm(cam_a.pose.translation).max(math::norm(cam_b.pose.translation));
    let n = math::norm(t);
    if n <= 1e-9 * scale || !n.is_finite() {
        return None;
    }
    let e = math::mat_mul(&skew(math::scale(t, 1.0 / n)), &r);
    let kb_inv_t = math::transpose(&k_inverse(cam_b));
    Some(math::mat_mul(&kb_inv_t, &math::mat_mul(&e, &k_inverse(cam_a))))
}

/// Per-pixel error of `flow` (frame a → frame b) against the camera motion alone: the distance
/// in pixels from p + flow(p) to the epipolar line of p in frame b, or the rotation-transfer
/// error for pairs with (almost) no parallax (module docs). NaN where the flow mask is 0.
///
/// # Panics
/// When the flow's size differs from `cam_a`'s image or its arrays have the wrong length.
pub fn epipolar_errors(flow: &FlowField, cam_a: &Camera, cam_b: &Camera) -> Vec<f32> {
    let (w, h) = (flow.width as usize, flow.height as usize);
    assert!(
        flow.flow.len() == 2 * w * h && flow.mask.len() == w * h,
        "epipolar_errors: flow field arrays do not match its {w}x{h} size"
    );
    let k = &cam_a.intrinsics;
    assert!(
        (k.width, k.height) == (flow.width, flow.height),
        "epipolar_errors: flow is {w}x{h} but camera a is {}x{}",
        k.width,
        k.height
    );
    let target = |i: usize| {
        let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
        (
            [x, y, 1.0],
            [x + flow.flow[2 * i] as f64, y + flow.flow[2 * i + 1] as f64],
        )
    };
    let valid = |i: usize| flow.mask[i] > 0.5;

    let (r, _) = relative_pose(cam_a, cam_b);
    let h_inf = math::mat_mul(&k_matrix(cam_b), &math::mat_mul(&r, &k_inverse(cam_a)));
    let transfer: Vec<f32> = (0..w * h)
        .map(|i| {
            if !valid(i) {
                return f32::NAN;
            }
            let (p, q) = target(i);
            let m = math::mat_vec(&h_inf, p);
            if m[2] <= 0.0 {
                // Rotated behind the camera: no finite transfer; flag as inconsistent.
                return f32::INFINITY;
            }
            (q[0] - m[0] / m[2]).hypot(q[1] - m[1] / m[2]) as f32
        })
        .collect();
    let Some(f) = fundamental_matrix(cam_a, cam_b) else {
        return transfer;
    };
    let mut finite: Vec<f32> = transfer.iter().copied().filter(|v| !v.is_nan()).collect();
    if !finite.is_empty() {
        let mid = finite.len() / 2;
        let median = *finite.select_nth_unstable_by(mid, f32::total_cmp).1;
        if median < LOW_PARALLAX_PX {
            return transfer;
        }
    }
    (0..w * h)
        .map(|i| {
            if !valid(i) {
                return f32::NAN;
            }
            let (p, q) = target(i);
            let l = math::mat_vec(&f, p);
            let norm = l[0].hypot(l[1]);
            if norm > 0.0 {
                ((q[0] * l[0] + q[1] * l[1] + l[2]).abs() / norm) as f32
            } else {
                // p is the epipole itself: every line through it is possible.
                0.0
            }
        })
        .collect()
}

/// Opening (erosion then dilation) with the 3×3 cross: drops isolated pixels and one-pixel lines.
fn opening(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    morph_cross(&morph_cross(m, w, h, true), w, h, false)
}

/// Frames apart of the pairs the motion test compares: an eighth of the video (at least 1).
/// Slow or deforming motion moves less than a pixel between neighbouring frames, under the
/// test's threshold; chained over a few frames it shows (on generated videos, 5 of 10 with
/// movers went undetected between neighbours).
pub fn motion_stride(frames: usize) -> usize {
    (frames / 8).max(1)
}

/// Flow from frame `i` to frame `i + stride` (`step = 1`, through `flows = fwd`) or to
/// `i − stride` (`step = −1`, `flows = bwd`), chaining one-frame flows with bilinear lookups
/// at the moved positions. Trusted only where every link is trusted and stays in the image.
/// `None` when a link is missing.
pub fn chained_flow(flows: &[Option<FlowField>], i: usize, stride: usize, step: isize) -> Option<FlowField> {
    let first = flows.get(i)?.as_ref()?;
    let (w, h) = (first.width as usize, first.height as usize);
    let links: Vec<&FlowField> = (0..stride)
        .map(|s| {
            let j = i.checked_add_signed(step * s as isize)?;
            flows.get(j)?.as_ref()
        })
        .collect::<Option<_>>()?;
    let mut flow = vec![0f32; 2 * w * h];
    let mut mask = vec![0f32; w * h];
    for p in 0..w * h {
        let start = ((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
        let mut pos = start;
        let mut trusted = true;
        for link in &links {
            match sample_flow(link, pos) {
                Some((dx, dy, ok)) => {
                    pos = (pos.0 + dx, pos.1 + dy);
                    trusted &= ok;
                }
                None => {
                    trusted = false;
                    break;
                }
            }
        }
        flow[2 * p] = pos.0 - start.0;
        flow[2 * p + 1] = pos.1 - start.1;
        mask[p] = if trusted { 1.0 } else { 0.0 };
    }
    Some(FlowField {
        width: first.width,
        height: first.height,
        flow,
        mask,
    })
}

/// Bilinear flow at a continuous pixel position (pixel centres at +0.5) and whether all four
/// neighbours are trusted; `None` outside the image.
fn sample_flow(f: &FlowField, (x, y): (f32, f32)) -> Option<(f32, f32, bool)> {
    let (w, h) = (f.width as usize, f.height as usize);
    let (u, v) = (x - 0.5, y - 0.5);
    if !(u > -0.5 && v > -0.5 && u < w as f32 - 0.5 && v < h as f32 - 0.5) {
        return None;
    }
    let (u, v) = (u.clamp(0.0, (w - 1) as f32), v.clamp(0.0, (h - 1) as f32));
    let (x0, y0) = (u.floor() as usize, v.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (u - x0 as f32, v - y0 as f32);
    let mut out = (0.0, 0.0, true);
    for (xx, yy, wt) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ] {
        let i = yy * w + xx;
        out.0 += wt * f.flow[2 * i];
        out.1 += wt * f.flow[2 * i + 1];
        out.2 &= f.mask[i] > 0.5;
    }
    Some(out)
}

/// Whether the video shows motion the camera does not explain (NSFF's epipolar test).
///
/// For each pair (i, i + stride), with the forward flows chained over `stride` frames
/// ([`chained_flow`], [`motion_stride`]): pixels with mask 1 are valid; those with
/// [`epipolar_errors`] > `threshold_px` (NSFF uses 1 px at training resolution) are moving;
/// a 3×3-cross opening removes isolated ones (flow noise, thin occlusion edges). The decision is
/// `moving_fraction > MIN_MOVING_FRACTION` (0.5% of valid pixels over all pairs). `frames[i]`
/// is frame i's camera; `fwd[i]` its flow to frame i+1 (as from [`super::video_flows`]).
///
/// # Panics
/// When `fwd` and `frames` differ in length, or a flow does not match its camera's size.
pub fn independent_motion(
    frames: &[Camera],
    fwd: &[Option<FlowField>],
    threshold_px: f32,
    stride: usize,
) -> MotionReport {
    assert_eq!(
        frames.len(),
        fwd.len(),
        "independent_motion: one camera per frame and one forward flow slot per frame"
    );
    let stride = stride.max(1);
    let counts: Vec<Option<(usize, usize)>> = {
        use rayon::prelude::*;
        (0..frames.len())
            .into_par_iter()
            .map(|i| {
                let cam_b = frames.get(i + stride)?;
                let chained = chained_flow(fwd, i, stride, 1)?;
                let flow = &chained;
                let (w, h) = (flow.width as usize, flow.height as usize);
                let err = epipolar_errors(flow, &frames[i], cam_b);
                let valid = err.iter().filter(|e| !e.is_nan()).count();
                let moving: Vec<bool> = err.iter().map(|&e| e > threshold_px).collect();
                let moving = opening(&moving, w, h).into_iter().filter(|&m| m).count();
                Some((moving, valid))
            })
            .collect()
    };
    let per_frame = counts
        .iter()
        .map(|c| match c {
            Some((m, v)) if *v > 0 => *m as f32 / *v as f32,
            _ => f32::NAN,
        })
        .collect();
    let (moving, valid) = counts
        .iter()
        .flatten()
        .fold((0usize, 0usize), |(m, v), (a, b)| (m + a, v + b));
    let moving_fraction = if valid > 0 {
        moving as f32 / valid as f32
    } else {
        0.0
    };
    MotionReport {
        moving_fraction,
        per_frame,
        has_independent_motion: moving_fraction > MIN_MOVING_FRACTION,
    }
}

/// How [`motion_masks`] marks a pixel as moving.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaskRule {
    /// Epipolar error (pixels) above which a pixel counts as moving.
    pub threshold_px: f32,
    /// Count a pixel as moving only when both neighbours' errors exceed the threshold (the
    /// smaller error, not the larger): an occlusion edge breaks the flow towards one neighbour
    /// only, a mover shows in both. Frames with one neighbour use that one.
    pub both_neighbours: bool,
}

impl MaskRule {
    /// NSFF's rule: the larger of the two neighbours' errors above `threshold_px`.
    pub fn either(threshold_px: f32) -> Self {
        Self {
            threshold_px,
            both_neighbours: false,
        }
    }
}

/// NSFF-style per-frame motion masks (`[H*W]`, 1 = probably moving) for hard-example mining:
/// e = max(e_bwd·mask_bwd, e_fwd·mask_fwd) (or the min, [`MaskRule::both_neighbours`]) from
/// [`epipolar_errors`] of the neighbours
/// `stride` frames away (flows chained, [`chained_flow`]; the nearest available when the video
/// ends sooner), opened with the 3×3 cross at the rule's threshold, then dilated twice by it (≈ NSFF's
/// `disk(2)` dilation, without its semantic-segmentation part). Frames with no flow get all zeros.
///
/// # Panics
/// When the slices differ in length or a flow does not match its camera's size.
pub fn motion_masks(
    frames: &[Camera],
    fwd: &[Option<FlowField>],
    bwd: &[Option<FlowField>],
    rule: MaskRule,
    stride: usize,
) -> Vec<Vec<f32>> {
    use rayon::prelude::*;
    assert!(
        frames.len() == fwd.len() && frames.len() == bwd.len(),
        "motion_masks: one camera and one forward and backward flow slot per frame"
    );
    let n = frames.len();
    (0..n)
        .into_par_iter()
        .map(|i| {
            let k = &frames[i].intrinsics;
            let (w, h) = (k.width as usize, k.height as usize);
            // Per pixel, the neighbours' errors combined by the rule (NaN until one is seen;
            // `f32::max` and `f32::min` return the other operand when one is NaN).
            let mut e = vec![f32::NAN; w * h];
            let ahead = stride.max(1).min(n - 1 - i);
            let behind = stride.max(1).min(i);
            let neighbours = [
                (ahead > 0)
                    .then(|| chained_flow(fwd, i, ahead, 1))
                    .flatten()
                    .map(|f| (f, i + ahead)),
                (behind > 0)
                    .then(|| chained_flow(bwd, i, behind, -1))
                    .flatten()
                    .map(|f| (f, i - behind)),
            ];
            for (flow, j) in neighbours.into_iter().flatten() {
                if let Some(cam_b) = frames.get(j) {
                    let flow = &flow;
                    for (acc, v) in e.iter_mut().zip(epipolar_errors(flow, &frames[i], cam_b)) {
                        *acc = if rule.both_neighbours {
                            acc.min(v)
                        } else {
                            acc.max(v)
                        };
                    }
                }
            }
            let moving: Vec<bool> = e.iter().map(|&v| v > rule.threshold_px).collect();
            grow(&opening(&moving, w, h), w, h, 2)
                .into_iter()
                .map(|b| if b { 1.0 } else { 0.0 })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_drops_isolated_pixels_and_keeps_blobs() {
        let (w, h) = (8, 6);
        let mut m = vec![false; w * h];
        m[w + 1] = true; // isolated
        for y in 2..5 {
            for x in 4..7 {
                m[y * w + x] = true;
            }
        }
        let o = opening(&m, w, h);
        assert!(!o[w + 1]);
        assert!(o[3 * w + 5]);
    }
}
