//! Image quality metrics, computed the way the NeRF papers report them.

/// PSNR in dB of two images with values in [0, 1]: −10·log10(MSE). Identical images give +∞.
pub fn psnr(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "psnr: images differ in size");
    let mse = a
        .iter()
        .zip(b)
        .map(|(x, y)| ((*x as f64) - (*y as f64)).powi(2))
        .sum::<f64>()
        / a.len().max(1) as f64;
    -10.0 * mse.log10()
}

/// PSNR from a mean squared error (as logged during training).
pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.max(1e-20).log10()
}

/// SSIM with an 11×11 Gaussian window (σ = 1.5), K1 = 0.01, K2 = 0.03, data range 1, 'valid'
/// filtering (no padding), averaged over pixels and channels — tf.image.ssim, which the NeRF
/// evaluation uses. Images are `[H, W, C]` interleaved; both must be at least 11×11.
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize, channels: usize) -> f64 {
    assert_eq!(a.len(), width * height * channels);
    assert_eq!(b.len(), a.len());
    const SIZE: usize = 11;
    if width < SIZE || height < SIZE {
        return f64::NAN;
    }
    let kernel = gaussian_kernel(SIZE, 1.5);
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let (ow, oh) = (width - SIZE + 1, height - SIZE + 1);
    let mut total = 0.0;
    for c in 0..channels {
        let channel =
            |img: &[f32]| -> Vec<f64> { img.iter().skip(c).step_by(channels).map(|v| *v as f64).collect() };
        let (x, y) = (channel(a), channel(b));
        let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
        let blur = |img: &[f64]| separable_valid(img, width, height, &kernel);
        let (mx, my, sxx, syy, sxy) = (blur(&x), blur(&y), blur(&xx), blur(&yy), blur(&xy));
        for i in 0..ow * oh {
            let (ux, uy) = (mx[i], my[i]);
            let vx = sxx[i] - ux * ux;
            let vy = syy[i] - uy * uy;
            let cov = sxy[i] - ux * uy;
            total += ((2.0 * ux * uy + c1) * (2.0 * cov + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2));
        }
    }
    total / (ow * oh * channels) as f64
}

fn gaussian_kernel(size: usize, sigma: f64) -> Vec<f64> {
    let c = (size as f64 - 1.0) / 2.0;
    let k: Vec<f64> = (0..size)
        .map(|i| (-((i as f64 - c).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// Separable 'valid' convolution of a `[H, W]` image with a 1-D kernel along both axes.
fn separable_valid(img: &[f64], w: usize, h: usize, k: &[f64]) -> Vec<f64> {
    let n = k.len();
    let ow = w - n + 1;
    let mut rows = vec![0.0; ow * h];
    for y in 0..h {
        for x in 0..ow {
            rows[y * ow + x] = (0..n).map(|i| k[i] * img[y * w + x + i]).sum();
        }
    }
    let oh = h - n + 1;
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..n).map(|i| k[i] * rows[(y + i) * ow + x]).sum();
        }
    }
    out
}
