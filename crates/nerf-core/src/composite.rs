//! Volume compositing: samples along rays become pixel values.
//!
//! For each ray with samples s = 0..S and K density components per sample (K = 1 for a static
//! NeRF; K = 2 for NSFF's static + dynamic blend), with interval length δ_s, density σ_{s,k} and
//! optional blend factor β_{s,k} (1 when absent):
//!
//! ```text
//! α_{s,k} = β_{s,k} (1 − exp(−σ_{s,k} δ_s))
//! T_s     = exp(−Σ_{j<s} τ_j),  τ_j = −Σ_k ln(1 − α_{j,k})   (= Σ_k σ δ when β = 1)
//! out_c   = Σ_s T_s Σ_k α_{s,k} f_{s,k,c},    opacity = Σ_s T_s Σ_k α_{s,k}
//! ```
//!
//! Transmittance is the exp of a non-positive exclusive cumulative sum (never a running product
//! that can underflow to 0 and poison a division), computed in f64 inside the kernel, so no
//! σ ≥ 0 and δ ≥ 0 produce NaN or Inf. The backward pass uses the division-free back-to-front
//! recurrence Q_s = Σ_k α_{s,k} u_{s,k} + Π_k (1 − α_{s,k}) Q_{s+1}.
//! Samples after the transmittance falls below `stop_eps` are skipped (early termination).

use std::sync::Arc;

use burn::tensor::Tensor;
use rayon::prelude::*;

use crate::host_op::{HostKernel, HostTensor, host_op};

/// Ragged sample layout: ray r owns samples `offsets[r]..offsets[r + 1]`.
#[derive(Clone, Debug, PartialEq)]
pub struct RayLayout {
    pub offsets: Arc<Vec<u32>>,
    /// Interval length of each sample in distance units (depth interval times |d|).
    pub deltas: Arc<Vec<f32>>,
}

impl RayLayout {
    pub fn num_rays(&self) -> usize {
        self.offsets.len() - 1
    }

    pub fn num_samples(&self) -> usize {
        self.deltas.len()
    }

    fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.offsets[r] as usize..self.offsets[r + 1] as usize
    }
}

/// The fused compositing kernel. Inputs: σ `[S, K]`, features `[S, K·C]`, and β `[S, K]` when
/// `blended`. Output `[R, C + 1]`: the composited features and the opacity.
#[derive(Debug)]
pub struct CompositeKernel {
    pub layout: RayLayout,
    pub components: usize,
    pub channels: usize,
    pub blended: bool,
    /// Transmittance below which a ray stops; 0 disables early termination.
    pub stop_eps: f32,
}

/// α of one component and the two partial derivatives the backward pass needs, in f64.
#[inline]
fn alpha(sigma: f32, delta: f32, beta: f64) -> (f64, f64, f64) {
    let sd = sigma as f64 * delta as f64;
    let e = (-sd).exp(); // in [0, 1]; sd = +inf gives 0
    let one_minus_e = -(-sd).exp_m1();
    // dα/dσ = β δ e^{-σδ}; dα/dβ = 1 - e^{-σδ}
    (beta * one_minus_e, beta * delta as f64 * e, one_minus_e)
}

impl CompositeKernel {
    fn beta(&self, blend: Option<&[f32]>, s: usize, k: usize) -> f64 {
        blend.map_or(1.0, |b| b[s * self.components + k] as f64)
    }

    /// Optical depth −ln(1 − α) contributed by component k; exactly σδ without blending.
    fn optical_depth(&self, sigma: f32, delta: f32, a: f64) -> f64 {
        if self.blended {
            -(-a).ln_1p()
        } else {
            sigma as f64 * delta as f64
        }
    }

    /// Forward sweep of one ray; calls `visit(s, T_s, α_{s,·})` for every sample it processes.
    fn sweep(
        &self,
        r: usize,
        sigma: &[f32],
        blend: Option<&[f32]>,
        mut visit: impl FnMut(usize, f64, &[f64]),
    ) {
        let k_n = self.components;
        let mut alphas = [0.0f64; 4];
        let mut tau = 0.0f64;
        for s in self.layout.range(r) {
            let t = (-tau).exp();
            if (t as f32) < self.stop_eps {
                break;
            }
            let delta = self.layout.deltas[s];
            let mut od = 0.0;
            for k in 0..k_n {
                let sg = sigma[s * k_n + k];
                let (a, _, _) = alpha(sg, delta, self.beta(blend, s, k));
                alphas[k] = a;
                od += self.optical_depth(sg, delta, a);
            }
            visit(s, t, &alphas[..k_n]);
            tau += od;
        }
    }
}

impl HostKernel for CompositeKernel {
    fn forward(&self, inputs: &[HostTensor]) -> HostTensor {
        let (k_n, c_n) = (self.components, self.channels);
        assert!(k_n <= 4, "at most 4 density components");
        let sigma = &inputs[0].data;
        let feats = &inputs[1].data;
        let blend = self.blended.then(|| inputs[2].data.as_slice());
        let width = c_n + 1;
        let mut out = vec![0.0f32; self.layout.num_rays() * width];
        out.par_chunks_mut(width)
            .enumerate()
            .with_min_len(64)
            .for_each(|(r, row)| {
                let mut acc = vec![0.0f64; width];
                self.sweep(r, sigma, blend, |s, t, alphas| {
                    for (k, &a) in alphas.iter().enumerate() {
                        let w = t * a;
                        let f = &feats[(s * k_n + k) * c_n..(s * k_n + k + 1) * c_n];
                        for c in 0..c_n {
                            acc[c] += w * f[c] as f64;
                        }
                        acc[c_n] += w;
                    }
                });
                for (o, a) in row.iter_mut().zip(&acc) {
                    *o = *a as f32;
                }
            });
        HostTensor::new(vec![self.layout.num_rays(), width], out)
    }

    fn backward(
        &self,
        inputs: &[HostTensor],
        _: &HostTensor,
        grad: &HostTensor,
        wanted: &[bool],
    ) -> Vec<Option<HostTensor>> {
        let (k_n, c_n) = (self.components, self.channels);
        let sigma = &inputs[0].data;
        let feats = &inputs[1].data;
        let blend = self.blended.then(|| inputs[2].data.as_slice());
        let n = self.layout.num_samples();
        let mut d_sigma = vec![0.0f32; n * k_n];
        let mut d_feats = vec![0.0f32; n * k_n * c_n];
        let mut d_blend = vec![0.0f32; if self.blended { n * k_n } else { 0 }];
        // Each ray writes only its own sample range, so split the outputs by ray.
        let ranges: Vec<(usize, usize)> = (0..self.layout.num_rays())
            .map(|r| {
                (
                    self.layout.offsets[r] as usize,
                    self.layout.offsets[r + 1] as usize,
                )
            })
            .collect();
        let ds = split_by_ranges(&mut d_sigma, &ranges, k_n);
        let df = split_by_ranges(&mut d_feats, &ranges, k_n * c_n);
        let db: Vec<Option<&mut [f32]>> = if self.blended {
            split_by_ranges(&mut d_blend, &ranges, k_n)
                .into_iter()
                .map(Some)
                .collect()
        } else {
            ranges.iter().map(|_| None).collect()
        };
        ds.into_par_iter()
            .zip(df)
            .zip(db)
            .enumerate()
            .with_min_len(64)
            .for_each(|(r, ((ds, df), mut db))| {
                let g = &grad.data[r * (c_n + 1)..(r + 1) * (c_n + 1)];
                let start = ranges[r].0;
                // Forward sweep, remembering T_s and α for the processed samples.
                let mut ts = Vec::new();
                let mut alphas = Vec::new();
                self.sweep(r, sigma, blend, |_, t, a| {
                    ts.push(t);
                    alphas.extend_from_slice(a);
                });
                let mut q = 0.0f64;
                for i in (0..ts.len()).rev() {
                    let s = start + i;
                    let t = ts[i];
                    let a = &alphas[i * k_n..(i + 1) * k_n];
                    let delta = self.layout.deltas[s];
                    let mut v = 0.0;
                    let mut p_all = 1.0;
                    for k in 0..k_n {
                        p_all *= 1.0 - a[k];
                    }
                    for k in 0..k_n {
                        let f = &feats[(s * k_n + k) * c_n..(s * k_n + k + 1) * c_n];
                        let u: f64 =
                            f.iter().zip(g).map(|(f, g)| *f as f64 * *g as f64).sum::<f64>() + g[c_n] as f64;
                        let others: f64 = (0..k_n).filter(|&j| j != k).map(|j| 1.0 - a[j]).product();
                        let d_alpha = t * (u - others * q);
                        let (_, da_dsigma, da_dbeta) =
                            alpha(sigma[s * k_n + k], delta, self.beta(blend, s, k));
                        ds[i * k_n + k] = (d_alpha * da_dsigma) as f32;
                        if let Some(db) = db.as_deref_mut() {
                            db[i * k_n + k] = (d_alpha * da_dbeta) as f32;
                        }
                        let w = t * a[k];
                        for c in 0..c_n {
                            df[(i * k_n + k) * c_n + c] = (w * g[c] as f64) as f32;
                        }
                        v += a[k] * u;
                    }
                    q = v + p_all * q;
                }
            });
        let mut out = vec![
            wanted[0].then(|| HostTensor::new(vec![n, k_n], d_sigma)),
            wanted[1].then(|| HostTensor::new(vec![n, k_n * c_n], d_feats)),
        ];
        if self.blended {
            out.push(wanted[2].then(|| HostTensor::new(vec![n, k_n], d_blend)));
        }
        out
    }
}

/// Splits `data` (row width `width`) into disjoint mutable chunks, one per sample range.
fn split_by_ranges<'a>(
    mut data: &'a mut [f32],
    ranges: &[(usize, usize)],
    width: usize,
) -> Vec<&'a mut [f32]> {
    let mut out = Vec::with_capacity(ranges.len());
    let mut consumed = 0;
    for &(a, b) in ranges {
        let (_, rest) = std::mem::take(&mut data).split_at_mut((a - consumed) * width);
        let (chunk, rest) = rest.split_at_mut((b - a) * width);
        out.push(chunk);
        data = rest;
        consumed = b;
    }
    out
}

/// Composites per-sample features along rays (differentiable in σ, features and β).
///
/// - `sigma`: `[S, K]` densities (≥ 0), `feats`: `[S, K·C]`, `blend`: optional `[S, K]`.
/// - Returns `[R, C + 1]`: composited features, then opacity.
pub fn composite(
    sigma: Tensor<2>,
    feats: Tensor<2>,
    blend: Option<Tensor<2>>,
    layout: &RayLayout,
    stop_eps: f32,
) -> Tensor<2> {
    let components = sigma.dims()[1];
    let channels = feats.dims()[1] / components;
    let kernel = CompositeKernel {
        layout: layout.clone(),
        components,
        channels,
        blended: blend.is_some(),
        stop_eps,
    };
    let mut inputs = vec![sigma, feats];
    inputs.extend(blend);
    host_op(inputs, Arc::new(kernel))
}

/// Per-sample weights w_s = T_s α_s for a single density component, on the host (no gradient):
/// what hierarchical sampling and early termination need.
pub fn weights(sigma: &[f32], layout: &RayLayout, stop_eps: f32) -> Vec<f32> {
    let kernel = CompositeKernel {
        layout: layout.clone(),
        components: 1,
        channels: 0,
        blended: false,
        stop_eps,
    };
    let mut w = vec![0.0f32; sigma.len()];
    let ranges: Vec<(usize, usize)> = (0..layout.num_rays())
        .map(|r| (layout.offsets[r] as usize, layout.offsets[r + 1] as usize))
        .collect();
    split_by_ranges(&mut w, &ranges, 1)
        .into_par_iter()
        .enumerate()
        .with_min_len(64)
        .for_each(|(r, out)| {
            let start = ranges[r].0;
            kernel.sweep(r, sigma, None, |s, t, a| out[s - start] = (t * a[0]) as f32);
        });
    w
}

/// Which samples a ray still reaches before its transmittance falls below `stop_eps` (single
/// density component, host): the samples early termination keeps.
pub fn alive(sigma: &[f32], layout: &RayLayout, stop_eps: f32) -> Vec<bool> {
    let mut keep = vec![false; sigma.len()];
    let kernel = CompositeKernel {
        layout: layout.clone(),
        components: 1,
        channels: 0,
        blended: false,
        stop_eps,
    };
    for r in 0..layout.num_rays() {
        kernel.sweep(r, sigma, None, |s, _, _| keep[s] = true);
    }
    keep
}

/// The same compositing written with generic burn tensor ops, for rays with a fixed number of
/// samples and one component: the cross-check for the fused kernel and the baseline it beats.
///
/// `sigma`: `[R, S]`, `feats`: `[R, S, C]`, `deltas`: `[R, S]`; returns `[R, C + 1]`.
pub fn composite_reference(sigma: Tensor<2>, feats: Tensor<3>, deltas: Tensor<2>) -> Tensor<2> {
    let [r, s] = sigma.dims();
    let sd = sigma * deltas;
    let inclusive = sd.clone().cumsum(1);
    let exclusive = Tensor::cat(
        vec![
            inclusive.clone().slice([0..r, 0..1]).zeros_like(),
            inclusive.slice([0..r, 0..s - 1]),
        ],
        1,
    );
    let trans = exclusive.neg().exp();
    let alpha = sd.neg().exp().neg().add_scalar(1.0);
    let w = (trans * alpha).unsqueeze_dim::<3>(2);
    let rgb = (w.clone() * feats).sum_dim(1).squeeze_dim::<2>(1);
    let acc = w.sum_dim(1).squeeze_dim::<2>(1);
    Tensor::cat(vec![rgb, acc], 1)
}
