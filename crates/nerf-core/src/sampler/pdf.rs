//! Hierarchical (inverse-CDF) sampling: more samples where the coarse pass found weight.

use rand::Rng;

use super::RaySamples;

/// Draws `n` points per ray from the piecewise-constant density given by `weights` over the
/// (contiguous) intervals of `coarse`, then returns the intervals between the sorted union of
/// the coarse edges and the new points, evaluated at their midpoints.
///
/// Robust for any weights: 1e-5 is added to every bin before normalising (nerf-pytorch's guard),
/// so all-zero or NaN-free degenerate weights give uniform sampling; negative or non-finite
/// weights count as zero. With `rng`, the n quantiles are stratified-jittered; without, they
/// are the bin centres (k + 0.5)/n.
pub fn sample_pdf(
    coarse: &RaySamples,
    weights: &[f32],
    n: usize,
    mut rng: Option<&mut impl Rng>,
) -> RaySamples {
    let mut out = RaySamples::with_rays(coarse.num_rays());
    let mut edges: Vec<f32> = Vec::new();
    let mut cdf: Vec<f64> = Vec::new();
    for r in 0..coarse.num_rays() {
        let range = coarse.range(r);
        if range.is_empty() {
            out.finish_ray();
            continue;
        }
        // Bin edges and the CDF over the bins.
        edges.clear();
        edges.push(coarse.t_start[range.start]);
        edges.extend(range.clone().map(|s| coarse.t_end[s]));
        cdf.clear();
        cdf.push(0.0);
        let mut total = 0.0f64;
        for s in range.clone() {
            let w = weights[s];
            total += if w.is_finite() && w > 0.0 { w as f64 } else { 0.0 } + 1e-5;
            cdf.push(total);
        }
        for c in cdf.iter_mut() {
            *c /= total;
        }
        let (lo, hi) = (edges[0], *edges.last().unwrap_or(&edges[0]));
        let mut points: Vec<f32> = Vec::with_capacity(n + edges.len());
        let mut bin = 0;
        for k in 0..n {
            let jitter = rng.as_deref_mut().map_or(0.5, |g| g.random::<f64>());
            let u = (k as f64 + jitter) / n as f64;
            // The quantiles increase, so the bin search resumes where it stopped.
            while bin + 1 < cdf.len() - 1 && cdf[bin + 1] <= u {
                bin += 1;
            }
            let (c0, c1) = (cdf[bin], cdf[bin + 1]);
            let frac = if c1 - c0 > 1e-12 {
                ((u - c0) / (c1 - c0)).clamp(0.0, 1.0)
            } else {
                0.5
            };
            let t = edges[bin] + (edges[bin + 1] - edges[bin]) * frac as f32;
            points.push(t.clamp(lo, hi));
        }
        points.extend_from_slice(&edges);
        points.sort_by(f32::total_cmp);
        for pair in points.windows(2) {
            out.push(pair[0], pair[1], 0.5 * (pair[0] + pair[1]));
        }
        out.finish_ray();
    }
    out
}
