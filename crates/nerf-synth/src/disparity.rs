//! A stand-in for a monocular depth network (NSFF uses MiDaS): one frame's disparity made from
//! its true depth, with the errors such a network has, at two strengths.

use rand::Rng;

/// Which errors the simulated disparity carries. Both have an unknown scale in [0.5, 2]
/// (log-uniform) and shift in [−0.1, 0.1] per frame and Gaussian noise of 5 % of the frame's
/// mean disparity: the depth prior may rely only on what a real network gives, the ordering and
/// relative spacing of depths within a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DisparityErrors {
    /// The true inverse depth smoothed by a 3×3 box filter: affine in the truth up to the
    /// noise, an upper bound on what a real network gives.
    Clean,
    /// Errors a real network makes that no scale and shift remove: edges blurred over a 5×5
    /// box, a per-frame power γ ∈ [0.71, 1.41] (log-uniform) on the normalised inverse depth
    /// (depths ordered right, spaced wrong), and a smooth field across the image that scales the
    /// disparity by up to ±15 % (two plane waves of 0.3-1.2 cycles per image).
    Rough,
}

impl std::str::FromStr for DisparityErrors {
    type Err = String;

    /// `clean` or `rough`, case ignored (`nerf synth --mono-disparity`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "clean" => Ok(DisparityErrors::Clean),
            "rough" => Ok(DisparityErrors::Rough),
            _ => Err(format!(
                "unknown disparity errors '{s}' (expected clean or rough)"
            )),
        }
    }
}

/// One frame's simulated disparity, row-major `[h·w]`, from its true camera depths `depth`
/// (`[h·w]`, 0 where no surface is hit, which stays at the shift) with `errors`, drawn from
/// `rng`.
pub fn simulate(
    depth: &[f32],
    (w, h): (usize, usize),
    errors: DisparityErrors,
    rng: &mut impl Rng,
) -> Vec<f32> {
    let inv: Vec<f64> = depth
        .iter()
        .map(|&z| if z > 0.0 { 1.0 / f64::from(z) } else { 0.0 })
        .collect();
    let scale = 2f64.powf(rng.random_range(-1.0..=1.0));
    let shift = rng.random_range(-0.1..=0.1);
    let mean = inv.iter().sum::<f64>() / inv.len().max(1) as f64;
    let (radius, distort) = match errors {
        DisparityErrors::Clean => (1, None),
        DisparityErrors::Rough => (2, Some(Distortion::draw(rng))),
    };
    let blurred = box_blur(&inv, (w, h), radius);
    let peak = blurred.iter().copied().fold(0.0, f64::max).max(1e-12);
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let mut d = blurred[y * w + x];
            if let Some(distort) = &distort {
                d = distort.apply(d, peak, (x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            }
            // Box-Muller: one standard normal from two uniforms.
            let (u1, u2): (f64, f64) = (rng.random_range(f64::EPSILON..1.0), rng.random());
            let noise = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
            out.push((scale * (d + 0.05 * mean * noise) + shift) as f32);
        }
    }
    out
}

/// Mean over the (2r+1)² window, clipped at the image borders.
fn box_blur(v: &[f64], (w, h): (usize, usize), r: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut n) = (0.0, 0.0);
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    sum += v[yy * w + xx];
                    n += 1.0;
                }
            }
            out.push(sum / n);
        }
    }
    out
}

/// The rough model's per-frame distortion: a power on the normalised disparity and a smooth
/// multiplicative field.
struct Distortion {
    gamma: f64,
    /// Two plane waves: (cycles per image across, cycles per image down, phase).
    waves: [(f64, f64, f64); 2],
}

impl Distortion {
    const FIELD: f64 = 0.15;

    fn draw(rng: &mut impl Rng) -> Self {
        let gamma = 2f64.powf(rng.random_range(-0.5..=0.5));
        let mut wave = || {
            let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
            (
                rng.random_range(0.3..=1.2),
                sign * rng.random_range(0.3..=1.2),
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        };
        Distortion {
            gamma,
            waves: [wave(), wave()],
        }
    }

    /// Disparity `d` (the frame's largest is `peak`) at image position (`u`, `v`) ∈ [0, 1]².
    fn apply(&self, d: f64, peak: f64, u: f64, v: f64) -> f64 {
        let field: f64 = self
            .waves
            .iter()
            .map(|&(a, b, phase)| (std::f64::consts::TAU * (a * u + b * v) + phase).cos())
            .sum::<f64>()
            / 2.0;
        peak * (d / peak).powf(self.gamma) * (1.0 + Self::FIELD * field)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};

    const W: usize = 64;
    const H: usize = 48;

    /// A floor receding from 2 to 6 units down the image, a box at 2.5 units in front of it
    /// and an empty strip (no surface) along the top.
    fn depth() -> Vec<f32> {
        let mut d = vec![0.0; W * H];
        for y in 4..H {
            for x in 0..W {
                d[y * W + x] = 6.0 - 4.0 * y as f32 / H as f32;
                if (20..40).contains(&x) && (10..30).contains(&y) {
                    d[y * W + x] = 2.5;
                }
            }
        }
        d
    }

    /// Pearson's correlation of `xs` and `ys`, and the residual RMS of the least-squares affine
    /// fit of `ys` on `xs` over the spread of `ys`.
    fn fit(xs: &[f64], ys: &[f64]) -> (f64, f64) {
        let n = xs.len() as f64;
        let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
        let sxy: f64 = xs.iter().zip(ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
        let syy: f64 = ys.iter().map(|y| (y - my).powi(2)).sum();
        let slope = sxy / sxx;
        let rss: f64 = xs
            .iter()
            .zip(ys)
            .map(|(x, y)| (y - my - slope * (x - mx)).powi(2))
            .sum();
        (sxy / (sxx * syy).sqrt(), (rss / syy).sqrt())
    }

    /// Spearman's rank correlation (no ties in noisy data).
    fn rank_correlation(xs: &[f64], ys: &[f64]) -> f64 {
        let ranks = |v: &[f64]| {
            let mut idx: Vec<usize> = (0..v.len()).collect();
            idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
            let mut r = vec![0.0; v.len()];
            for (rank, &i) in idx.iter().enumerate() {
                r[i] = rank as f64;
            }
            r
        };
        fit(&ranks(xs), &ranks(ys)).0
    }

    /// Both models keep the order of the depths; the clean one is affine in the smoothed inverse
    /// depth up to its noise, the rough one is not: its affine fit leaves several times the
    /// residual. Compared on the means of 4×4 blocks (which average the per-pixel noise away and
    /// keep the structured errors), against the truth recomputed here in f64, on blocks away from
    /// the edges that the two blurs treat differently.
    #[test]
    fn rough_disparity_keeps_the_order_of_depths_but_no_scale_and_shift_fits_it() {
        let depth = depth();
        let interior = |x: usize, y: usize| {
            let near_box = (17..43).contains(&x) && (7..33).contains(&y);
            let on_box = (22..38).contains(&x) && (12..28).contains(&y);
            (7..H - 2).contains(&y) && (2..W - 2).contains(&x) && (on_box || !near_box)
        };
        let blocks: Vec<Vec<usize>> = (0..H / 4)
            .flat_map(|by| (0..W / 4).map(move |bx| (bx, by)))
            .map(|(bx, by)| {
                (0..16)
                    .map(|i| (4 * bx + i % 4, 4 * by + i / 4))
                    .filter(|&(x, y)| interior(x, y))
                    .map(|(x, y)| y * W + x)
                    .collect::<Vec<_>>()
            })
            .filter(|b| b.len() == 16)
            .collect();
        let mean =
            |v: &dyn Fn(usize) -> f64, b: &[usize]| b.iter().map(|&p| v(p)).sum::<f64>() / b.len() as f64;
        let truth: Vec<f64> = blocks
            .iter()
            .map(|b| mean(&|p| 1.0 / f64::from(depth[p]), b))
            .collect();
        assert!(blocks.len() > 60, "{} blocks", blocks.len());
        for seed in 0..8 {
            let score = |errors| {
                let disp = simulate(&depth, (W, H), errors, &mut StdRng::seed_from_u64(seed));
                assert!(disp.iter().all(|y| y.is_finite()), "{errors:?}: not finite");
                let ys: Vec<f64> = blocks.iter().map(|b| mean(&|p| f64::from(disp[p]), b)).collect();
                (fit(&truth, &ys).1, rank_correlation(&truth, &ys))
            };
            let (clean, clean_rank) = score(DisparityErrors::Clean);
            let (rough, rough_rank) = score(DisparityErrors::Rough);
            assert!(
                clean < 0.1 && clean_rank > 0.95,
                "seed {seed}: clean {clean}, rank {clean_rank}"
            );
            assert!(
                rough > 2.0 * clean,
                "seed {seed}: rough {rough} against clean {clean}"
            );
            assert!(
                rough_rank > 0.7,
                "seed {seed}: rough rank correlation {rough_rank}"
            );
        }
    }

    /// The same seed gives the same frame; the empty strip holds only shift and noise.
    #[test]
    fn the_simulated_disparity_is_reproducible_and_flat_where_nothing_is_hit() {
        let depth = depth();
        for errors in [DisparityErrors::Clean, DisparityErrors::Rough] {
            let a = simulate(&depth, (W, H), errors, &mut StdRng::seed_from_u64(3));
            let b = simulate(&depth, (W, H), errors, &mut StdRng::seed_from_u64(3));
            assert_eq!(a, b);
            let top: Vec<f32> = a[..2 * W].to_vec();
            let spread =
                top.iter().fold(f32::MIN, |m, &v| m.max(v)) - top.iter().fold(f32::MAX, |m, &v| m.min(v));
            let full = a.iter().fold(f32::MIN, |m, &v| m.max(v)) - a.iter().fold(f32::MAX, |m, &v| m.min(v));
            assert!(
                spread < 0.5 * full,
                "{errors:?}: empty strip spread {spread} of {full}"
            );
        }
    }
}
