//! PSNR and SSIM against straightforward float64 recomputations (direct 2-D window sums).

use nerf_core::metrics::{psnr, ssim};
use rand::{Rng, SeedableRng, rngs::StdRng};

fn ssim_reference(a: &[f32], b: &[f32], w: usize, h: usize, ch: usize) -> f64 {
    let (size, sigma) = (11usize, 1.5f64);
    let mut win = vec![0.0f64; size * size];
    for y in 0..size {
        for x in 0..size {
            let (dx, dy) = (x as f64 - 5.0, y as f64 - 5.0);
            win[y * size + x] = (-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp();
        }
    }
    let s: f64 = win.iter().sum();
    win.iter_mut().for_each(|v| *v /= s);
    let (c1, c2) = (1e-4, 9e-4);
    let mut total = 0.0;
    let mut count = 0;
    for c in 0..ch {
        for y0 in 0..=h - size {
            for x0 in 0..=w - size {
                let (mut mx, mut my, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for y in 0..size {
                    for x in 0..size {
                        let i = ((y0 + y) * w + x0 + x) * ch + c;
                        let (p, q, k) = (a[i] as f64, b[i] as f64, win[y * size + x]);
                        mx += k * p;
                        my += k * q;
                        sxx += k * p * p;
                        syy += k * q * q;
                        sxy += k * p * q;
                    }
                }
                let (vx, vy, cov) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
                total +=
                    (2.0 * mx * my + c1) * (2.0 * cov + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2));
                count += 1;
            }
        }
    }
    total / count as f64
}

#[test]
fn psnr_and_ssim_match_f64_references() {
    let mut rng = StdRng::seed_from_u64(0);
    for (w, h) in [(11usize, 11usize), (32, 20), (40, 40)] {
        for noise in [0.01f32, 0.1, 0.5] {
            let a: Vec<f32> = (0..w * h * 3).map(|_| rng.random_range(0.0..1.0)).collect();
            let b: Vec<f32> = a
                .iter()
                .map(|v| (v + rng.random_range(-noise..noise)).clamp(0.0, 1.0))
                .collect();
            let mse: f64 = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
                .sum::<f64>()
                / a.len() as f64;
            assert!((psnr(&a, &b) - (-10.0 * mse.log10())).abs() < 1e-4);
            let (got, want) = (ssim(&a, &b, w, h, 3), ssim_reference(&a, &b, w, h, 3));
            assert!(
                (got - want).abs() < 1e-4,
                "{w}x{h} noise {noise}: {got} vs {want}"
            );
        }
    }
    let a: Vec<f32> = (0..16 * 16).map(|i| (i % 7) as f32 / 7.0).collect();
    assert!((ssim(&a, &a, 16, 16, 1) - 1.0).abs() < 1e-12);
    assert!(psnr(&a, &a).is_infinite());
}
