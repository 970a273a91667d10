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
}
