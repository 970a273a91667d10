//! NSFF's loss terms (method.md §4.6), each a function of tensors with its formula and shapes.
//! The training step (`trainer.rs`) renders and calls them; their weights are `LossWeights`.
//! Weighted means follow NSFF: Σ m·err / (Σ m·C + 1e-8), the mask broadcast over the C channels.

use burn::tensor::{Int, Tensor, TensorData};
use nerf::error::{ModelError, read_back};
use nerf::renderer::tensor;
use nerf_core::composite::RayLayout;
use nerf_core::sampler::RaySamples;
use nerf_data::{Camera, Ndc};

use crate::geometry;

pub fn mse(a: Tensor<2>, b: Tensor<2>) -> Tensor<1> {
    (a - b).powi_scalar(2).mean()
}

/// Mask-weighted mean squared error; `mask` is `[N, 1]`.
pub fn wmse(a: Tensor<2>, b: Tensor<2>, mask: Tensor<2>) -> Tensor<1> {
    let c = a.dims()[1] as f32;
    let err = (a - b).powi_scalar(2) * mask.clone();
    err.sum() / (mask.sum() * c + 1e-8)
}

/// Per-ray weights of a static batch that holds masked rays (`masked`, the rays inside the
/// motion masks), from each ray's squared colour error (`errors`, held fixed): 1 outside the
/// masks, 1 / (1 + e / τ) inside, τ = `scale` × the mean error of the unmasked rays (of all
/// rays when none is unmasked). A masked ray the static field explains as well as the still
/// ones counts almost fully; one it cannot explain (a mover, different in every frame) counts
/// little. Non-finite errors weigh 0.
pub fn robust_ray_weights(errors: &[f32], masked: &[bool], scale: f32) -> Vec<f32> {
    let mean = |keep: &dyn Fn(usize) -> bool| {
        let (sum, n) = (0..errors.len())
            .filter(|&i| keep(i) && errors[i].is_finite())
            .fold((0.0f64, 0usize), |(s, n), i| (s + errors[i] as f64, n + 1));
        (n > 0).then(|| sum / n as f64)
    };
    let reference = mean(&|i| !masked[i]).or_else(|| mean(&|_| true)).unwrap_or(0.0);
    let tau = (scale as f64 * reference).max(1e-12);
    errors
        .iter()
        .zip(masked)
        .map(|(&e, &m)| match (m, e.is_finite()) {
            (false, _) => 1.0,
            (true, true) => (1.0 / (1.0 + e.max(0.0) as f64 / tau)) as f32,
            (true, false) => 0.0,
        })
        .collect()
}

/// Mask-weighted mean absolute error; `mask` is `[N, 1]`.
pub fn wmae(a: Tensor<2>, b: Tensor<2>, mask: Tensor<2>) -> Tensor<1> {
    let c = a.dims()[1] as f32;
    let err = (a - b).abs() * mask.clone();
    err.sum() / (mask.sum() * c + 1e-8)
}

/// Mean dynamic share Σ_i w_dy,i over the rays that see no motion: `share` `[R, 1]` from the
/// combined render, `still` R host values (1 = outside the frame's motion mask). 0 when no ray
/// is still.
pub fn still_dynamic_share(share: Tensor<2>, still: Vec<f32>) -> Tensor<1> {
    let n = still.iter().sum::<f32>().max(1.0);
    let mask = tensor(still, 1, &share.device());
    (share * mask).sum() / n
}

/// Mean shortfall max(0, floor − share) of the dynamic share below `floor` over the rays inside
/// the motion masks: `share` `[R, 1]` from the combined render, `moving` R host values (1 =
/// inside the frame's motion mask). 0 when no ray moves.
pub fn moving_dynamic_share(share: Tensor<2>, moving: Vec<f32>, floor: f32) -> Tensor<1> {
    still_dynamic_share((share.neg() + floor).clamp_min(0.0), moving)
}

/// One-sided entropy −b·log(b + 1e-8), averaged: pushes blend weights towards 0 or 1.
pub fn entropy(b: Tensor<2>) -> Tensor<1> {
    (b.clone() * (b + 1e-8).log()).neg().mean()
}

/// NSFF's scale- and shift-invariant depth loss: MSE between n(pred) and n(target), with
/// n(x) = (x − median x) / mean|x − median x| over the batch (method.md §4.6). `pred` is
/// `[N, 1]`, `target` N host values (monocular disparity). The median of `pred` is held
/// constant (it is one sample's value: a shift, whose gradient the mean-centred spread carries
/// anyway); the spread keeps its gradient, so shrinking the prediction does not lower the loss.
/// `None` when either side is constant (nothing to match).
pub fn scale_shift_invariant(pred: Tensor<2>, target: &[f32]) -> Result<Option<Tensor<1>>, ModelError> {
    let Some((t_med, t_spread)) = median_spread(target) else {
        return Ok(None);
    };
    let pred_host = read_back(pred.clone().inner(), "rendered disparity")?;
    let Some((p_med, _)) = median_spread(&pred_host) else {
        return Ok(None);
    };
    let dev = pred.device();
    let n = target.len();
    let t_norm: Vec<f32> = target
        .iter()
        .map(|&v| ((v as f64 - t_med) / t_spread) as f32)
        .collect();
    let t_norm = Tensor::<1>::from_data(burn::tensor::TensorData::new(t_norm, [n]), &dev).reshape([n, 1]);
    let centred = pred - p_med as f32;
    let spread = centred.clone().abs().mean().reshape([1, 1]) + 1e-8;
    Ok(Some(mse(centred / spread, t_norm)))
}

/// Cycle consistency of the scene flow: the flow back from the warped point, `back` `[S, 3]`,
/// should undo the flow that got there, `flow` `[S, 3]`, where the point is not disoccluded:
/// Σ (1 − p)·|flow + back| / (Σ (1 − p)·3), `prob` `[S, 1]`.
pub fn cycle(flow: Tensor<2>, back: Tensor<2>, prob: Tensor<2>) -> Tensor<1> {
    wmae(flow, back.neg(), prob.neg() + 1.0)
}

/// The projected scene flow against 2-D optical flow (NSFF's L_geo): the flowed surface point of
/// each ray, Σ w·(x + f) over the ray's opacity (`flowed_sum` `[R, 3]`, `opacity` `[R, 1]`),
/// converted from NDC when `ndc`, projected into the neighbouring frame's `camera`, against
/// `target_uv` (`R·2`: pixel centre + optical flow), weighted by `mask` (`R`: the flow's
/// consistency mask) times the ray's opacity. Unnormalised, a ray that is partly transparent
/// (white background, early training) would project its point towards the world origin, and the
/// flow would learn to undo that instead of the motion; such rays count as much as they are opaque.
pub fn optical_flow(
    flowed_sum: Tensor<2>,
    opacity: Tensor<2>,
    ndc: Option<&Ndc>,
    camera: &Camera,
    target_uv: Vec<f32>,
    mut mask: Vec<f32>,
) -> Result<Tensor<1>, ModelError> {
    let dev = flowed_sum.device();
    for (m, a) in mask
        .iter_mut()
        .zip(read_back(opacity.clone().inner(), "opacity")?)
    {
        *m *= a.clamp(0.0, 1.0);
    }
    let point = flowed_sum / opacity.clamp_min(1e-3);
    let world = match ndc {
        Some(ndc) => geometry::ndc_to_world(point, ndc),
        None => point,
    };
    let uv = geometry::project(world, camera, &dev);
    Ok(wmae(uv, tensor(target_uv, 2, &dev), tensor(mask, 1, &dev)))
}

/// NSFF's small-flow prior: ½(mean|f_next| + mean|f_prev|), flows `[S, 3]`.
pub fn min_flow(flow_next: Tensor<2>, flow_prev: Tensor<2>) -> Tensor<1> {
    (flow_next.abs().mean() + flow_prev.abs().mean()) * 0.5
}

/// Temporal smoothness: ½ mean ‖f_next + f_prev‖² (constant velocity), Euclidean flows `[S, 3]`.
pub fn temporal_smoothness(flow_next: Tensor<2>, flow_prev: Tensor<2>) -> Tensor<1> {
    (flow_next + flow_prev).powi_scalar(2).sum_dim(1).mean() * 0.5
}

/// Spatial smoothness: mean|f_a − f_b| over pairs (a, b) of neighbouring samples on a ray, for
/// both flows (`[S, 3]`, Euclidean); `None` without pairs.
pub fn spatial_smoothness(
    flow_next: Tensor<2>,
    flow_prev: Tensor<2>,
    pairs: &(Vec<i32>, Vec<i32>),
) -> Option<Tensor<1>> {
    let n = pairs.0.len();
    if n == 0 {
        return None;
    }
    let dev = flow_next.device();
    let ia = Tensor::<1, Int>::from_data(TensorData::new(pairs.0.clone(), [n]), &dev);
    let ib = Tensor::<1, Int>::from_data(TensorData::new(pairs.1.clone(), [n]), &dev);
    let diff = |f: Tensor<2>| {
        (f.clone().select(0, ia.clone()) - f.select(0, ib.clone()))
            .abs()
            .mean()
    };
    Some(diff(flow_next) + diff(flow_prev))
}

/// Index pairs (s, s + 1) of neighbouring samples on the same ray, over the first `frac` of each
/// ray's samples (NSFF skips the far end, where NDC warps stretch).
pub fn adjacent_pairs(samples: &RaySamples, frac: f32) -> (Vec<i32>, Vec<i32>) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for r in 0..samples.num_rays() {
        let range = samples.range(r);
        let keep = ((range.len() as f32 * frac) as usize).max(1);
        for s in range.start..(range.start + keep).min(range.end).saturating_sub(1) {
            a.push(s as i32);
            b.push(s as i32 + 1);
        }
    }
    (a, b)
}

/// Transmittance below which a sample counts as hidden. The visible surface itself spans a
/// few samples over which T falls from 1 to 0; weighting by (1 − T) penalised its back half.
pub const HIDDEN_BELOW_T: f32 = 0.05;

/// Host copies of a space-time batch's per-sample static density, dynamic density, static
/// blend weight b_s and blend b = b_s·g: read back once per step for the terms that walk the
/// combined render's transmittance ([`hidden_dynamic_depth`]).
pub struct BlendedSamples {
    pub sigma_st: Vec<f32>,
    pub sigma_dy: Vec<f32>,
    pub b_s: Vec<f32>,
    pub blend: Vec<f32>,
}

impl BlendedSamples {
    /// Reads the four `[S, 1]` tensors back (no gradient).
    pub fn read(
        sigma_st: &Tensor<2>,
        sigma_dy: &Tensor<2>,
        b_s: &Tensor<2>,
        gate: &Tensor<2>,
    ) -> Result<Self, ModelError> {
        let host = |t: &Tensor<2>, what| read_back(t.clone().inner(), what);
        let b_s = host(b_s, "blend weight")?;
        let blend = b_s
            .iter()
            .zip(host(gate, "time gate")?)
            .map(|(b, g)| b * g)
            .collect();
        Ok(BlendedSamples {
            sigma_st: host(sigma_st, "static density")?,
            sigma_dy: host(sigma_dy, "dynamic density")?,
            b_s,
            blend,
        })
    }
}

/// The combined render's density at one sample: (1 − b)·σ_st + b·σ_dy, never negative.
fn blended_density(sigma_st: f32, sigma_dy: f32, blend: f32) -> f32 {
    ((1.0 - blend) * sigma_st + blend * sigma_dy).max(0.0)
}

/// Hidden dynamic optical depth: Σ_rays Σ_s h_s·b_s·g_s·σ_dy,s / R, with h_s the host weights of
/// [`hidden_weights`] (no gradient) through the blended density. Dynamic density that this
/// frame's camera cannot see at this time (behind what the combined render shows) is constrained
/// by nothing but this term: without it the dynamic field fills the space behind a moving object
/// with whatever its MLP makes up, and novel views look into it. The penalty reaches the density
/// and the time gate, not b_s: b_s is time-independent, and points hidden at this time are the
/// object's visible surface at others. `host` holds the same samples' values; the tensors are
/// `[S, 1]`.
pub fn hidden_dynamic_depth(
    host: &BlendedSamples,
    sigma_dy: Tensor<2>,
    gate: Tensor<2>,
    layout: &RayLayout,
) -> Tensor<1> {
    let hidden = hidden_weights(&host.sigma_st, &host.sigma_dy, &host.blend, layout);
    let fixed: Vec<f32> = host.b_s.iter().zip(hidden).map(|(b, h)| b * h).collect();
    let dev = sigma_dy.device();
    (gate * sigma_dy * tensor(fixed, 1, &dev)).sum() / layout.num_rays() as f32
}

/// Per sample, δ·max(0, 1 − T/T_h): its interval where it lies behind the combined render's
/// visible surface (T = transmittance before the sample through the blended density
/// (1 − b)·σ_st + b·σ_dy, T_h = [`HIDDEN_BELOW_T`]), so that Σ weight·b·σ_dy is the ray's hidden
/// dynamic optical depth. Host values: `sigma_st`, `sigma_dy`, `blend` per sample.
pub fn hidden_weights(sigma_st: &[f32], sigma_dy: &[f32], blend: &[f32], layout: &RayLayout) -> Vec<f32> {
    let mut out = vec![0.0f32; sigma_st.len()];
    for r in 0..layout.num_rays() {
        let mut optical = 0.0f32;
        for i in layout.offsets[r] as usize..layout.offsets[r + 1] as usize {
            let (b, delta) = (blend[i], layout.deltas[i]);
            out[i] = (1.0 - (-optical).exp() / HIDDEN_BELOW_T).max(0.0) * delta;
            optical += blended_density(sigma_st[i], sigma_dy[i], b) * delta;
        }
    }
    out
}

/// Dynamic sparsity: the mean blended dynamic optical depth per march step, mean(b_s·g·σ_dy)·step,
/// at random points (all `[P, 1]`).
pub fn sparsity(blend_s: Tensor<2>, gate: Tensor<2>, sigma_dy: Tensor<2>, step: f32) -> Tensor<1> {
    (blend_s * gate * sigma_dy).mean() * step
}

/// The dynamic field's consistency along its scene flow: a point x at time t and the point it
/// flows to, x + f(x, t), at the neighbouring frame's time hold the same matter. With each
/// sample's dynamic opacity α = 1 − exp(−g·σ_dy·δ) (gate g, `deltas` δ `[S, 1]`), the squared
/// difference of α plus the squared colour difference weighted by the mean of the two α (held
/// fixed), averaged over the `[S, 1]` samples (colour over its 3 channels too). The warped
/// render asks only that the integral along one ray match; this asks it of every sample, so a
/// static object inside the motion masks keeps one shape across frames instead of one per frame
/// (each frame's camera sees it from one side only).
pub fn field_consistency(
    a: (Tensor<2>, Tensor<2>),
    b: (Tensor<2>, Tensor<2>),
    deltas: Tensor<2>,
) -> Tensor<1> {
    let alpha = |density: Tensor<2>| (density * deltas.clone()).neg().exp().neg() + 1.0;
    let (alpha_a, alpha_b) = (alpha(a.0), alpha(b.0));
    let weight = ((alpha_a.clone() + alpha_b.clone()) * 0.5).detach();
    let opacity = (alpha_a - alpha_b).powi_scalar(2);
    let colour = ((a.1 - b.1).powi_scalar(2) * weight).mean();
    opacity.mean() + colour
}

/// Median (the lower middle value, as torch.median) and mean absolute deviation from it, in
/// f64; `None` for an empty or constant input.
fn median_spread(v: &[f32]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let mut sorted: Vec<f32> = v.to_vec();
    sorted.sort_by(f32::total_cmp);
    let med = sorted[(sorted.len() - 1) / 2] as f64;
    let spread = v.iter().map(|&x| (x as f64 - med).abs()).sum::<f64>() / v.len() as f64;
    (spread > 1e-12).then_some((med, spread))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Device;

    fn t2(v: &[f32], c: usize, dev: &Device) -> Tensor<2> {
        nerf::renderer::tensor(v.to_vec(), c, dev)
    }

    /// Unmasked rays weigh 1; masked ones 1 / (1 + e / τ) with τ from the unmasked rays' mean
    /// error, so a masked ray as good as the still ones keeps most of its weight and one far
    /// off little; with no unmasked ray τ comes from all rays; NaN weighs 0.
    #[test]
    fn robust_ray_weights_spare_the_masked_rays_the_static_field_cannot_explain() {
        let errors = [0.01f32, 0.03, 0.02, 0.5, f32::NAN];
        let masked = [false, false, true, true, true];
        let w = robust_ray_weights(&errors, &masked, 2.0);
        let tau = 2.0 * (0.01f64 + 0.03) / 2.0;
        let want = [1.0, 1.0, 1.0 / (1.0 + 0.02 / tau), 1.0 / (1.0 + 0.5 / tau), 0.0];
        for (g, w) in w.iter().zip(want) {
            assert!((*g as f64 - w).abs() < 1e-6, "{g} against {w}");
        }
        assert!(w[2] > 0.6 && w[3] < 0.1, "{w:?}");
        let all = robust_ray_weights(&[0.1, 0.3], &[true, true], 1.0);
        assert!(
            (all[0] as f64 - 1.0 / 1.5).abs() < 1e-6 && (all[1] as f64 - 0.4).abs() < 1e-6,
            "{all:?}"
        );
    }

    /// Central difference of `f` in its `i`-th input at `x`, step `h`.
    fn central_difference<const N: usize>(
        f: impl Fn(&[f32; N]) -> f64,
        x: [f32; N],
        i: usize,
        h: f32,
    ) -> f64 {
        let (mut up, mut down) = (x, x);
        up[i] += h;
        down[i] -= h;
        (f(&up) - f(&down)) / (2.0 * h as f64)
    }

    /// Against a float64 recomputation of α = 1 − exp(−σδ), (α_a − α_b)² and the colour
    /// difference weighted by (α_a + α_b)/2, with densities from empty to saturated; zero for
    /// identical samples; gradients against finite differences.
    #[test]
    fn field_consistency_matches_a_float64_recomputation() {
        let dev = Device::flex();
        let sig_a = [0.0f32, 2.0, 50.0, 1e6];
        let sig_b = [0.5f32, 2.0, 5.0, 0.0];
        let rgb_a = [0.1f32, 0.2, 0.3, 0.5, 0.5, 0.5, 0.9, 0.0, 0.4, 1.0, 1.0, 1.0];
        let rgb_b = [0.2f32, 0.2, 0.1, 0.5, 0.5, 0.5, 0.1, 0.3, 0.4, 0.0, 0.0, 0.0];
        let deltas = [0.1f32, 0.02, 0.05, 0.01];
        let alpha = |s: f32, d: f32| 1.0 - (-(s as f64) * d as f64).exp();
        // The colour weight (α_a + α_b)/2 at the given densities, held fixed as in the loss.
        let weights: Vec<f64> = (0..4)
            .map(|i| 0.5 * (alpha(sig_a[i], deltas[i]) + alpha(sig_b[i], deltas[i])))
            .collect();
        let reference = |sa: &[f32], ca: &[f32]| -> f64 {
            let (mut da, mut dc) = (0.0f64, 0.0f64);
            for i in 0..4 {
                da += (alpha(sa[i], deltas[i]) - alpha(sig_b[i], deltas[i])).powi(2);
                for c in 0..3 {
                    dc += weights[i] * (ca[3 * i + c] as f64 - rgb_b[3 * i + c] as f64).powi(2);
                }
            }
            da / 4.0 + dc / 12.0
        };
        let loss = |sa: Tensor<2>, ca: Tensor<2>, d: &Device| {
            field_consistency((sa, ca), (t2(&sig_b, 1, d), t2(&rgb_b, 3, d)), t2(&deltas, 1, d))
        };
        let got = f64::from(loss(t2(&sig_a, 1, &dev), t2(&rgb_a, 3, &dev), &dev).into_scalar::<f32>());
        let want = reference(&sig_a, &rgb_a);
        assert!(want > 0.05, "the test inputs must disagree: {want}");
        assert!((got - want).abs() < 1e-6, "got {got}, want {want}");
        let same = field_consistency(
            (t2(&sig_a, 1, &dev), t2(&rgb_a, 3, &dev)),
            (t2(&sig_a, 1, &dev), t2(&rgb_a, 3, &dev)),
            t2(&deltas, 1, &dev),
        );
        assert_eq!(same.into_scalar::<f32>(), 0.0);
        // Gradients against central differences of the reference (weights held fixed), at the
        // unsaturated samples (a saturated one's α has no slope left).
        let autodiff = Device::flex().autodiff();
        let sa = t2(&sig_a, 1, &autodiff).require_grad();
        let ca = t2(&rgb_a, 3, &autodiff).require_grad();
        let grads = loss(sa.clone(), ca.clone(), &autodiff).backward();
        let read = |t: Tensor<2>| -> Vec<f32> {
            t.grad(&grads)
                .expect("gradient")
                .into_data()
                .try_into_vec_as::<f32>()
                .expect("f32")
        };
        let (g_sig, g_rgb) = (read(sa), read(ca));
        for i in 0..3 {
            let fd = central_difference(|s| reference(s, &rgb_a), sig_a, i, 1e-2 * sig_a[i].max(1.0));
            assert!(
                (g_sig[i] as f64 - fd).abs() < 1e-4 + 1e-2 * fd.abs(),
                "d/dσ[{i}]: {} vs {fd}",
                g_sig[i]
            );
        }
        for i in 0..12 {
            let fd = central_difference(|c| reference(&sig_a, c), rgb_a, i, 1e-3);
            assert!(
                (g_rgb[i] as f64 - fd).abs() < 1e-4,
                "d/drgb[{i}]: {} vs {fd}",
                g_rgb[i]
            );
        }
    }

    #[test]
    fn moving_dynamic_share_averages_the_shortfall_over_moving_rays() {
        let dev = Device::flex();
        let share = t2(&[0.5, 0.9, 0.1, 0.0], 1, &dev);
        let l = moving_dynamic_share(share, vec![1.0, 1.0, 0.0, 1.0], 0.6);
        // Moving rays: shortfalls 0.1, 0 and 0.6.
        assert!((l.into_scalar::<f32>() - 0.7 / 3.0).abs() < 1e-6);
        let none = moving_dynamic_share(t2(&[0.0], 1, &dev), vec![0.0], 0.6);
        assert_eq!(none.into_scalar::<f32>(), 0.0);
    }

    #[test]
    fn still_dynamic_share_averages_over_still_rays_only() {
        let dev = Device::flex();
        let share = t2(&[0.5, 0.9, 0.1, 0.0], 1, &dev);
        let scalar = |t: Tensor<1>| t.into_scalar::<f32>() as f64;
        // Rays 0 and 2 are still: (0.5 + 0.1) / 2.
        let got = scalar(still_dynamic_share(share.clone(), vec![1.0, 0.0, 1.0, 0.0]));
        assert!((got - 0.3).abs() < 1e-6, "{got}");
        // No still ray: nothing to penalise.
        assert_eq!(scalar(still_dynamic_share(share, vec![0.0; 4])), 0.0);
    }

    /// Each loss against its definition recomputed in f64 on the host.
    #[test]
    fn losses_match_their_f64_definitions() {
        let dev = Device::flex();
        let a = [0.1f32, 0.9, -0.4, 0.25, 0.0, 1.5];
        let b = [0.3f32, 0.7, -0.1, 0.05, 0.5, 1.0];
        let m = [0.2f32, 0.9];
        let (a64, b64): (Vec<f64>, Vec<f64>) = (
            a.iter().map(|&x| x as f64).collect(),
            b.iter().map(|&x| x as f64).collect(),
        );
        let want_mse = a64.iter().zip(&b64).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / 6.0;
        let (mut se, mut ae) = (0.0f64, 0.0f64);
        for r in 0..2 {
            for c in 0..3 {
                let d = a64[3 * r + c] - b64[3 * r + c];
                se += m[r] as f64 * d * d;
                ae += m[r] as f64 * d.abs();
            }
        }
        let msum = (m[0] + m[1]) as f64 * 3.0;
        let scalar = |t: Tensor<1>| t.into_scalar::<f32>() as f64;
        let got_mse = scalar(mse(t2(&a, 3, &dev), t2(&b, 3, &dev)));
        let got_wmse = scalar(wmse(t2(&a, 3, &dev), t2(&b, 3, &dev), t2(&m, 1, &dev)));
        let got_wmae = scalar(wmae(t2(&a, 3, &dev), t2(&b, 3, &dev), t2(&m, 1, &dev)));
        assert!((got_mse - want_mse).abs() < 1e-6, "{got_mse} vs {want_mse}");
        assert!((got_wmse - se / msum).abs() < 1e-6, "{got_wmse}");
        assert!((got_wmae - ae / msum).abs() < 1e-6, "{got_wmae}");
        // Entropy: zero at b = 0 and b = 1, largest at 1/e.
        let bs = [0.0f32, 1.0, 0.5, std::f32::consts::E.recip()];
        let want: f64 = bs
            .iter()
            .map(|&x| -(x as f64) * (x as f64 + 1e-8).ln())
            .sum::<f64>()
            / 4.0;
        let got = scalar(entropy(t2(&bs, 1, &dev)));
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }

    /// The depth loss against its definition in f64, its invariance to a positive scale and a
    /// shift of the target, and a finite-difference check of its gradient.
    #[test]
    fn depth_loss_is_scale_shift_invariant_and_matches_f64() {
        let dev = Device::flex();
        let pred = [0.3f32, 0.9, 0.45, 0.1, 0.7, 0.52, 0.2];
        let target = [1.0f32, 2.6, 1.9, 0.2, 2.0, 1.5, 0.9];
        let norm = |v: &[f64]| -> Vec<f64> {
            let mut s = v.to_vec();
            s.sort_by(f64::total_cmp);
            let med = s[(s.len() - 1) / 2];
            let spread = v.iter().map(|x| (x - med).abs()).sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - med) / spread).collect()
        };
        let reference = |p: &[f32], t: &[f32]| -> f64 {
            let (p64, t64): (Vec<f64>, Vec<f64>) = (
                p.iter().map(|&x| x as f64).collect(),
                t.iter().map(|&x| x as f64).collect(),
            );
            let (np, nt) = (norm(&p64), norm(&t64));
            np.iter().zip(&nt).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / p.len() as f64
        };
        let loss = |p: &[f32], t: &[f32]| -> f64 {
            scale_shift_invariant(t2(p, 1, &dev), t)
                .unwrap()
                .expect("non-constant inputs")
                .into_scalar::<f32>() as f64
        };
        let want = reference(&pred, &target);
        assert!(want > 0.1, "the test inputs must disagree: {want}");
        assert!(
            (loss(&pred, &target) - want).abs() < 1e-5,
            "{} vs {want}",
            loss(&pred, &target)
        );
        // A monocular disparity has an unknown scale and shift: neither may change the loss.
        let moved: Vec<f32> = target.iter().map(|&v| 3.5 * v - 0.8).collect();
        assert!((loss(&pred, &moved) - want).abs() < 1e-5);
        // Matching the target up to scale and shift gives zero.
        let fit: Vec<f32> = target.iter().map(|&v| 0.2 * v + 0.05).collect();
        assert!(loss(&fit, &target) < 1e-10);
        // Constant sides have nothing to match.
        assert!(
            scale_shift_invariant(t2(&pred, 1, &dev), &[0.5; 7])
                .unwrap()
                .is_none()
        );
        // Gradient against central differences of the f64 reference (the median element is
        // held constant in the loss, so perturb the others only).
        let autodiff = Device::flex().autodiff();
        let p = Tensor::<2>::from_data(burn::tensor::TensorData::new(pred.to_vec(), [7, 1]), &autodiff)
            .require_grad();
        let l = scale_shift_invariant(p.clone(), &target)
            .unwrap()
            .expect("non-constant inputs");
        let grads = l.backward();
        let g: Vec<f32> = p
            .grad(&grads)
            .expect("gradient")
            .into_data()
            .try_into_vec_as::<f32>()
            .expect("f32");
        let median_index = 2; // 0.45 is the 4th of 7 sorted values
        for i in (0..7).filter(|&i| i != median_index) {
            let fd = central_difference(|p| reference(p, &target), pred, i, 1e-3);
            assert!(
                (g[i] as f64 - fd).abs() < 2e-3 * fd.abs().max(1.0),
                "d/dp[{i}]: {} vs {fd}",
                g[i]
            );
        }
    }

    /// The hidden weights against transmittance recomputed in f64 from its definition,
    /// T_i = exp(−Σ_{j<i} σ_j δ_j) with σ = (1 − b)·σ_st + b·σ_dy.
    #[test]
    fn hidden_weights_follow_the_blended_transmittance() {
        // Two rays: 3 samples, the last partly hidden (T ≈ 0.03), then 4 with an opaque static
        // wall at the second sample.
        let sigma_st = [0.0f32, 2.0, 0.5, 0.0, 1e4, 0.0, 0.0];
        let sigma_dy = [1.0f32, 60.0, 0.0, 5.0, 0.0, 2.0, 7.0];
        let blend = [1.0f32, 0.25, 0.5, 0.9, 0.0, 1.0, 0.5];
        let layout = nerf_core::composite::RayLayout {
            offsets: std::sync::Arc::new(vec![0, 3, 7]),
            deltas: std::sync::Arc::new(vec![0.1, 0.2, 0.3, 0.05, 0.05, 0.1, 0.1]),
        };
        let got = hidden_weights(&sigma_st, &sigma_dy, &blend, &layout);
        for r in 0..2 {
            let mut sum = 0.0f64;
            for i in layout.offsets[r] as usize..layout.offsets[r + 1] as usize {
                let (b, d) = (blend[i] as f64, layout.deltas[i] as f64);
                let want = (1.0 - (-sum).exp() / HIDDEN_BELOW_T as f64).max(0.0) * d;
                assert!(
                    (got[i] as f64 - want).abs() < 1e-6,
                    "sample {i}: {} vs {want}",
                    got[i]
                );
                sum += ((1.0 - b) * sigma_st[i] as f64 + b * sigma_dy[i] as f64) * d;
            }
        }
        // The first sample of a ray is never hidden; behind the wall everything is.
        assert_eq!(got[0], 0.0);
        assert_eq!(got[3], 0.0);
        assert!(got[1] == 0.0 && got[2] > 0.0 && got[2] < 0.3, "{got:?}");
        assert!((got[5] - 0.1).abs() < 1e-6 && (got[6] - 0.1).abs() < 1e-6);
    }
}
