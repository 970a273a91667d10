//! Stratified sampling between near and far: N equal bins (in depth or in disparity), one sample
//! per bin, jittered uniformly within it during training and at its midpoint otherwise.

use rand::Rng;

use super::RaySamples;

/// How bins are spaced between near and far.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Spacing {
    /// Uniform in depth.
    Depth,
    /// Uniform in inverse depth (nerf-pytorch's `lindisp`), for unbounded forward scenes
    /// without NDC. Needs near > 0.
    Disparity,
}

/// `n` stratified intervals per ray over `[near[r], far[r]]`. With `rng`, each sample is
/// uniform within its bin; without, at the bin midpoint. Rays with far ≤ near get no samples.
pub fn stratified(
    near: &[f32],
    far: &[f32],
    n: usize,
    spacing: Spacing,
    mut rng: Option<&mut impl Rng>,
) -> RaySamples {
    let mut out = RaySamples::with_rays(near.len());
    out.t.reserve(near.len() * n);
    for (&a, &b) in near.iter().zip(far) {
        if b > a && n > 0 {
            let edge = |k: usize| -> f32 {
                let s = k as f32 / n as f32;
                match spacing {
                    Spacing::Depth => a + (b - a) * s,
                    Spacing::Disparity => 1.0 / (1.0 / a.max(1e-6) * (1.0 - s) + 1.0 / b * s),
                }
            };
            let mut lo = edge(0);
            for k in 0..n {
                let hi = if k + 1 == n { b } else { edge(k + 1) };
                let u = rng.as_deref_mut().map_or(0.5, |r| r.random::<f32>());
                out.push(lo, hi, lo + (hi - lo) * u);
                lo = hi;
            }
        }
        out.finish_ray();
    }
    out
}
