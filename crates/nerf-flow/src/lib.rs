//! Optical flow for NSFF videos without flow files, forward-backward consistency masks, the
//! on-disk cache in NSFF's `flow_i1/` layout, and independent-motion detection
//! (method.md §4.1-4.2).
//!
//! # Estimator
//! [`estimate_flow`] is coarse-to-fine TV-L1 (Zach et al. 2007; Wedel et al. 2009), written from
//! the papers' description:
//! 1. luma in [0, 255], Gaussian pre-smoothing (σ = 0.5 px);
//! 2. a pyramid with factor 0.5 down to a shorter side of at least 8 px (Gaussian
//!    anti-aliasing before each resampling);
//! 3. per level, 5 warps: the second image and its gradients are warped by the current flow with
//!    bicubic interpolation, the data term is linearised, and up to 100 iterations of the
//!    thresholding / dual-projection scheme solve the convex problem (see `tvl1.rs`);
//! 4. a 5×5 median filter of the flow after every warp (removes isolated outliers);
//! 5. the regulariser is Huber-TV (quadratic below a flow gradient of 0.1 px/px): plain TV
//!    staircases across textureless patches whose true flow varies (a rotating cube's faces).
//!
//! Rows run in parallel with rayon on rasters of 32k pixels or more; [`video_flows`] runs frame
//! pairs and both directions in parallel.
//!
//! ## Why TV-L1: measured end-point error
//! Mean EPE against the generator's exact flow over every GT-visible pixel of all 23 forward
//! pairs (`cargo run -p nerf-flow --release --example flow_epe -- --seed S [--size 512x288]`);
//! the three solvers share the pyramid, bicubic warping, median filter and pre-smoothing, each
//! with its best weight from a small sweep (HS α = 5, LK window σ = 2 px):
//!
//! | `dynamic` preset        | TV-L1 (Huber) | Horn–Schunck | Lucas–Kanade |
//! |-------------------------|---------------|--------------|--------------|
//! | seed 0, 128×96 (flow ≈ 2 px) | **0.147** px | 0.154 px | 0.242 px |
//! | seed 1, 128×96          | **0.142** px  | 0.154 px     | 0.223 px     |
//! | seed 2, 128×96          | **0.115** px  | 0.117 px     | 0.177 px     |
//! | seed 0, 512×288 (flow ≈ 7.5 px) | **0.244** px | 0.407 px | 0.591 px |
//! | share > 1 px, 512×288   | **5.4 %**     | 9.3 %        | 11.3 %       |
//! | on the moving cube, 512×288 | **0.87** px | 1.18 px    | 1.54 px      |
//! | time per pair, 512×288  | 0.77 s        | 0.86 s       | 0.55 s       |
//!
//! (times on a busy 2-core machine.) At NSFF's training resolution the L1 data term and edge-
//! preserving regulariser nearly halve the Horn–Schunck error, which blurs motion boundaries.
//! Other choices, measured on seed 0 at 128×96 unless stated: bicubic rather than bilinear
//! warping (0.168 → 0.165 px), Huber-TV rather than TV (0.165 → 0.145 px), λ = 0.5 rather
//! than the usual 8-bit 0.15 (512×288: 0.313 → 0.263 px), a coarsest level of 8 px rather than
//! 16 (one more level at 128×96; `--preset family --seed 4`, a tuning video with a striped wall,
//! 0.662 → 0.278 px, worst pair 3.84 → 0.94 px; the dynamic preset's seeds 0-2 and 512×288
//! unchanged to 0.001 px; `flow_epe --min-size`). Tried and dropped: a
//! structure-texture decomposition (0.168 → 0.214 px: our renders have no exposure changes to
//! remove), pyramid factor 0.7 or 10 warps (about 5% lower EPE for 1.5-2× the time).
//! A pure translation of an analytic texture by (2.3, −1.7) px is recovered to 0.005 px.
//!
//! Limits: like every coarse-to-fine method it loses small objects that move much further than
//! their own size between frames (our cube at 512×288 with 6 frames instead of 24, ~50 px per
//! frame, is not tracked). NSFF's 20-50-frame videos at 512×288 stay well within range. It also
//! loses a small object whose own motion differs from its surroundings' by a few pixels: on
//! `--preset family --seed 307` (a box about 25 px across, spinning 251° over 16 frames while
//! the camera sweeps) the flow on the box is 4.2 px off on average (7.3 px long), 85 % of its
//! pixels are more than 1 px off, and the forward-backward test keeps 86 % of the box's pixels
//! with the same share wrong among them: the wrong flow is consistent. No setting of this solver
//! mends it (BENCHMARKS.md §6, seventy-fifth session).
//!
//! # Masks
//! [`consistency_mask`] is NSFF's forward-backward test. [`video_flows`] multiplies it by
//! [`texture_mask`]: where a frame has no texture (the white sky of our renders, real skies and
//! walls) the flow is filled in by the smoothness prior, not measured. Such flow passes the
//! consistency test (both directions are smooth) but is not a measurement: on `static_video`
//! seed 0, 2.6% of the sky's consistent pixels lay more than 1 px off their epipolar lines and
//! made a static video look dynamic; with the texture mask none do. Set
//! [`FlowParams::min_texture`] to 0 for NSFF's pure consistency mask.
//!
//! # Motion
//! [`independent_motion`] applies NSFF's epipolar test to decide whether the dynamic branch is
//! needed; [`motion_masks`] gives NSFF's per-frame masks for hard-example mining. On our
//! generator (seeds 0-5, 128×96, 1 px threshold) the moving fraction is 1.7-2.5% for `dynamic`
//! and at most 0.006% for `static_video`; the decision threshold is 0.5%.
//!
//! # Cache
//! [`write_flow_cache`] / [`read_flow_cache`] store the flows as NSFF does (`{i:05}_fwd.npz`,
//! `{i:05}_bwd.npz` with `flow` and `mask`), read back by the same code as
//! [`nerf_data::video::load`]'s `flow_i1/` priors, and key them to the frames and settings they
//! came from ([`cache_key`]).

mod baselines;
mod cache;
mod motion;
mod plane;
mod tvl1;

use rayon::prelude::*;

pub use cache::{cache_key, read_flow_cache, write_flow_cache};
pub use motion::{
    LOW_PARALLAX_PX, MIN_MOVING_FRACTION, MaskRule, MotionReport, chained_flow, epipolar_errors,
    fundamental_matrix, independent_motion, motion_masks, motion_stride,
};
pub use tvl1::TvL1Params;

use nerf_data::dataset::FlowField;
use nerf_data::image::Image;
use plane::{Flow, Plane};

/// The per-level solver run inside the coarse-to-fine pyramid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FlowMethod {
    /// TV-L1 (the default; see the crate docs for why).
    TvL1(TvL1Params),
    /// Horn–Schunck with warping and median filtering; `alpha` is the smoothness weight for
    /// intensities in [0, 255].
    HornSchunck { alpha: f32 },
    /// Dense Lucas–Kanade with a Gaussian window of standard deviation `sigma` pixels.
    LucasKanade { sigma: f32 },
}

impl Default for FlowMethod {
    fn default() -> Self {
        FlowMethod::TvL1(TvL1Params::default())
    }
}

/// Settings of [`estimate_flow`]. The defaults are what the measurements in the crate docs used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowParams {
    pub method: FlowMethod,
    /// Size ratio between successive pyramid levels, in (0, 1).
    pub scale_step: f32,
    /// The coarsest level keeps its shorter side at least this many pixels (8: striped walls
    /// that move a stripe's width or more between frames are tracked, see the crate docs).
    pub min_size: u32,
    /// At most this many levels (the full-resolution level included).
    pub max_levels: u32,
    /// Relinearisations (image warps) per level.
    pub warps: u32,
    /// Inner iterations per warp (TV-L1 may stop earlier; ignored by Lucas–Kanade).
    pub iterations: u32,
    /// Median filter of the flow after every warp: (2r+1)² window, 0 = off, at most 5.
    pub median_radius: u32,
    /// Gaussian pre-smoothing of both images (pixels), against noise and aliasing.
    pub presmooth_sigma: f32,
    /// [`video_flows`] also zeroes the mask where [`texture_mask`] says the frame is too flat
    /// for flow to be measured; 0 keeps NSFF's pure consistency mask. In (intensity levels per
    /// pixel)²: the default 1.0 keeps every pixel of our textured objects and drops the sky
    /// except within a few pixels of object outlines.
    pub min_texture: f32,
}

impl Default for FlowParams {
    fn default() -> Self {
        FlowParams {
            method: FlowMethod::default(),
            scale_step: 0.5,
            min_size: 8,
            max_levels: 6,
            warps: 5,
            iterations: 100,
            median_radius: 2,
            presmooth_sigma: 0.5,
            min_texture: 1.0,
        }
    }
}

impl FlowParams {
    /// Pyramid sizes from full resolution down to the coarsest level.
    fn level_sizes(&self, w: usize, h: usize) -> Vec<(usize, usize)> {
        let step = if self.scale_step > 0.0 && self.scale_step < 1.0 {
            self.scale_step
        } else {
            0.5
        };
        let min = (self.min_size as usize).max(2);
        let mut sizes = vec![(w, h)];
        while sizes.len() < self.max_levels.max(1) as usize {
            let (pw, ph) = sizes[sizes.len() - 1];
            let (nw, nh) = (
                (pw as f32 * step).round() as usize,
                (ph as f32 * step).round() as usize,
            );
            if nw.min(nh) < min || (nw, nh) == (pw, ph) {
                break;
            }
            sizes.push((nw, nh));
        }
        sizes
    }
}

/// Dense optical flow from `a` to `b`: `[H*W*2]` (dx, dy) in pixels, so pixel p of `a` shows
/// what pixel p + flow(p) of `b` shows. Colour images are reduced to luma.
///
/// # Panics
/// When the two images differ in size or are empty.
pub fn estimate_flow(a: &Image, b: &Image, params: &FlowParams) -> Vec<f32> {
    assert!(
        (a.width, a.height) == (b.width, b.height),
        "estimate_flow: images are {}x{} and {}x{}; flow needs equal sizes",
        a.width,
        a.height,
        b.width,
        b.height
    );
    assert!(
        a.width > 0 && a.height > 0 && a.channels > 0 && b.channels > 0,
        "estimate_flow: empty image"
    );
    let (w, h) = (a.width as usize, a.height as usize);
    let sizes = params.level_sizes(w, h);
    let pyramid = |img: &Image| {
        let mut levels = vec![Plane::luma(img).blur(params.presmooth_sigma)];
        for &(lw, lh) in &sizes[1..] {
            let next = levels[levels.len() - 1].resized(lw, lh);
            levels.push(next);
        }
        levels
    };
    let (p0, p1) = rayon::join(|| pyramid(a), || pyramid(b));
    let (cw, ch) = sizes[sizes.len() - 1];
    let mut flow = Flow::zeros(cw, ch);
    let (warps, iters, med) = (
        params.warps.max(1) as usize,
        params.iterations as usize,
        params.median_radius as usize,
    );
    for level in (0..sizes.len()).rev() {
        let (lw, lh) = sizes[level];
        if (flow.u.w, flow.u.h) != (lw, lh) {
            flow = flow.resized(lw, lh);
        }
        let (i0, i1) = (&p0[level], &p1[level]);
        flow = match params.method {
            FlowMethod::TvL1(p) => tvl1::refine(i0, i1, flow, &p, warps, iters, med),
            FlowMethod::HornSchunck { alpha } => {
                baselines::horn_schunck(i0, i1, flow, alpha, warps, iters, med)
            }
            FlowMethod::LucasKanade { sigma } => baselines::lucas_kanade(i0, i1, flow, sigma, warps, med),
        };
    }
    flow.interleaved()
}

/// Where `img` has enough texture for flow to be *measured* rather than filled in by the
/// smoothness prior: `[H*W]`, 1 where the smaller structure-tensor eigenvalue (Gaussian window
/// σ = 1.5 px, intensities in [0, 255]) reaches `params.min_texture`, else 0. All ones when
/// `min_texture` is 0.
pub fn texture_mask(img: &Image, params: &FlowParams) -> Vec<f32> {
    if params.min_texture <= 0.0 {
        return vec![1.0; img.num_pixels()];
    }
    Plane::luma(img)
        .blur(params.presmooth_sigma)
        .min_eigen_structure(TEXTURE_WINDOW_SIGMA)
        .data
        .iter()
        .map(|&e| if e >= params.min_texture { 1.0 } else { 0.0 })
        .collect()
}

/// Window of the structure tensor in [`texture_mask`].
const TEXTURE_WINDOW_SIGMA: f32 = 1.5;

/// NSFF's forward-backward consistency mask (α₁ = α₂ = 0.5) of `fwd` (a→b) given `bwd` (b→a):
/// b̃(p) = bwd sampled bilinearly at p + fwd(p), and mask(p) = 1 when
/// |fwd(p) + b̃(p)| < 0.5·(|fwd(p)| + |b̃(p)|) + 0.5, else 0. Pixels whose target p + fwd(p)
/// (pixel-centre coordinates) leaves the image [0, W) × [0, H) get 0: they have no partner.
///
/// # Panics
/// When either flow is not `[H*W*2]`.
pub fn consistency_mask(fwd: &[f32], bwd: &[f32], width: u32, height: u32) -> Vec<f32> {
    let (w, h) = (width as usize, height as usize);
    assert!(
        fwd.len() == 2 * w * h && bwd.len() == 2 * w * h,
        "consistency_mask: flows have {} and {} values, {width}x{height} needs {}",
        fwd.len(),
        bwd.len(),
        2 * w * h
    );
    let bu = Plane::from_fn(w, h, |x, y| bwd[2 * (y * w + x)]);
    let bv = Plane::from_fn(w, h, |x, y| bwd[2 * (y * w + x) + 1]);
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let (fu, fv) = (fwd[2 * i], fwd[2 * i + 1]);
            // Target in pixel-centre coordinates (x + 0.5 + fu) must stay inside [0, W).
            let (tx, ty) = (x + fu, y + fv);
            let inside = tx + 0.5 >= 0.0 && tx + 0.5 < w as f32 && ty + 0.5 >= 0.0 && ty + 0.5 < h as f32;
            if !inside {
                return 0.0;
            }
            let (wu, wv) = (bu.sample(tx, ty), bv.sample(tx, ty));
            let err = (fu + wu).hypot(fv + wv);
            let bound = 0.5 * (fu.hypot(fv) + wu.hypot(wv)) + 0.5;
            if err < bound { 1.0 } else { 0.0 }
        })
        .collect()
}

/// Forward (i → i+1; `None` for the last frame) and backward (i → i−1; `None` for the first)
/// flows of a video with their masks, the layout of [`nerf_data::VideoPriors::flow_fwd`] /
/// `flow_bwd`. Each mask is [`consistency_mask`] times [`texture_mask`] of the source frame
/// (see the crate docs for why). Frame pairs and both directions run in parallel.
///
/// # Panics
/// When the frames differ in size.
pub fn video_flows(
    frames: &[&Image],
    params: &FlowParams,
) -> (Vec<Option<FlowField>>, Vec<Option<FlowField>>) {
    let n = frames.len();
    // Both directions of each neighbouring pair: (i → i+1, i+1 → i).
    let pairs: Vec<(Vec<f32>, Vec<f32>)> = (0..n.saturating_sub(1))
        .into_par_iter()
        .map(|i| {
            rayon::join(
                || estimate_flow(frames[i], frames[i + 1], params),
                || estimate_flow(frames[i + 1], frames[i], params),
            )
        })
        .collect();
    let textured: Vec<Vec<f32>> = frames.par_iter().map(|f| texture_mask(f, params)).collect();
    let field = |i: usize, flow: &[f32], other: &[f32]| {
        let (w, h) = (frames[i].width, frames[i].height);
        let mut mask = consistency_mask(flow, other, w, h);
        mask.iter_mut().zip(&textured[i]).for_each(|(m, t)| *m *= t);
        FlowField {
            width: w,
            height: h,
            flow: flow.to_vec(),
            mask,
        }
    };
    let fwd = (0..n)
        .map(|i| (i + 1 < n).then(|| field(i, &pairs[i].0, &pairs[i].1)))
        .collect();
    let bwd = (0..n)
        .map(|i| (i > 0).then(|| field(i, &pairs[i - 1].1, &pairs[i - 1].0)))
        .collect();
    (fwd, bwd)
}
