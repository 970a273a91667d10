//! Loss helpers (NSFF's weighted means: Σ m·err / (Σ m·C + 1e-8), the mask broadcast over the
//! C channels).

use burn::tensor::Tensor;

pub fn mse(a: Tensor<2>, b: Tensor<2>) -> Tensor<1> {
    (a - b).powi_scalar(2).mean()
}

/// Mask-weighted mean squared error; `mask` is `[N, 1]`.
pub fn wmse(a: Tensor<2>, b: Tensor<2>, mask: Tensor<2>) -> Tensor<1> {
    let c = a.dims()[1] as f32;
    let err = (a - b).powi_scalar(2) * mask.clone();
    err.sum() / (mask.sum() * c + 1e-8)
}

/// Mask-weighted mean absolute error; `mask` is `[N, 1]`.
pub fn wmae(a: Tensor<2>, b: Tensor<2>, mask: Tensor<2>) -> Tensor<1> {
    let c = a.dims()[1] as f32;
    let err = (a - b).abs() * mask.clone();
    err.sum() / (mask.sum() * c + 1e-8)
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
pub fn scale_shift_invariant(pred: Tensor<2>, target: &[f32]) -> Option<Tensor<1>> {
    let (t_med, t_spread) = median_spread(target)?;
    let pred_host = pred.clone().inner().into_data().try_into_vec_as::<f32>().ok()?;
    let (p_med, _) = median_spread(&pred_host)?;
    let dev = pred.device();
    let n = target.len();
    let t_norm: Vec<f32> = target
        .iter()
        .map(|&v| ((v as f64 - t_med) / t_spread) as f32)
        .collect();
    let t_norm = Tensor::<1>::from_data(burn::tensor::TensorData::new(t_norm, [n]), &dev).reshape([n, 1]);
    let centred = pred - p_med as f32;
    let spread = centred.clone().abs().mean().reshape([1, 1]) + 1e-8;
    Some(mse(centred / spread, t_norm))
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
        assert!(scale_shift_invariant(t2(&pred, 1, &dev), &[0.5; 7]).is_none());
        // Gradient against central differences of the f64 reference (the median element is
        // held constant in the loss, so perturb the others only).
        let autodiff = Device::flex().autodiff();
        let p = Tensor::<2>::from_data(burn::tensor::TensorData::new(pred.to_vec(), [7, 1]), &autodiff)
            .require_grad();
        let l = scale_shift_invariant(p.clone(), &target).expect("non-constant inputs");
        let grads = l.backward();
        let g: Vec<f32> = p
            .grad(&grads)
            .expect("gradient")
            .into_data()
            .try_into_vec_as::<f32>()
            .expect("f32");
        let median_index = 2; // 0.45 is the 4th of 7 sorted values
        for i in (0..7).filter(|&i| i != median_index) {
            let h = 1e-3f32;
            let (mut up, mut down) = (pred, pred);
            up[i] += h;
            down[i] -= h;
            let fd = (reference(&up, &target) - reference(&down, &target)) / (2.0 * h as f64);
            assert!(
                (g[i] as f64 - fd).abs() < 2e-3 * fd.abs().max(1.0),
                "d/dp[{i}]: {} vs {fd}",
                g[i]
            );
        }
    }
}
