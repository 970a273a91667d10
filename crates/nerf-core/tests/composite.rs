//! The fused compositing op against analytic integrals, an f64 recomputation with central finite
//! differences, and the generic burn tensor-op version.

use std::sync::Arc;

use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::composite::{RayLayout, composite, composite_reference, weights};
use rand::{Rng, SeedableRng, rngs::StdRng};

fn device() -> Device {
    Device::flex().autodiff()
}

fn t2(data: Vec<f32>, shape: [usize; 2], dev: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(data, shape), dev)
}

fn host(t: Tensor<2>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

fn layout(counts: &[usize], deltas: Vec<f32>) -> RayLayout {
    let mut offsets = vec![0u32];
    for c in counts {
        offsets.push(offsets.last().unwrap() + *c as u32);
    }
    RayLayout {
        offsets: Arc::new(offsets),
        deltas: Arc::new(deltas),
    }
}

/// Straightforward f64 compositing with K components and optional blend, written independently
/// of the kernel (running product of (1 - α)), returning `[R, C + 1]`.
fn reference_f64(
    sigma: &[f64],
    feats: &[f64],
    blend: Option<&[f64]>,
    counts: &[usize],
    deltas: &[f64],
    k_n: usize,
    c_n: usize,
) -> Vec<f64> {
    let mut out = Vec::new();
    let mut s = 0;
    for &n in counts {
        let mut row = vec![0.0; c_n + 1];
        let mut trans = 1.0;
        for _ in 0..n {
            let mut keep = 1.0;
            for k in 0..k_n {
                let b = blend.map_or(1.0, |b| b[s * k_n + k]);
                let a = b * (1.0 - (-sigma[s * k_n + k] * deltas[s]).exp());
                for c in 0..c_n {
                    row[c] += trans * a * feats[(s * k_n + k) * c_n + c];
                }
                row[c_n] += trans * a;
                keep *= 1.0 - a;
            }
            trans *= keep;
            s += 1;
        }
        out.extend(row);
    }
    out
}

#[test]
fn constant_density_matches_the_analytic_opacity() {
    let dev = Device::flex();
    let (length, sigma) = (2.5f64, 0.8f64);
    let want = 1.0 - (-sigma * length).exp();
    for n in [8usize, 64, 512, 4096] {
        let l = layout(&[n], vec![(length / n as f64) as f32; n]);
        let out = host(composite(
            t2(vec![sigma as f32; n], [n, 1], &dev),
            t2(vec![0.5; n * 3], [n, 3], &dev),
            None,
            &l,
            0.0,
        ));
        let rel = (out[3] as f64 - want).abs() / want;
        assert!(rel < 1e-5, "n = {n}: opacity {} vs {want} (rel {rel:e})", out[3]);
        assert!((out[0] as f64 - 0.5 * want).abs() / want < 1e-5);
        let w = weights(&vec![sigma as f32; n], &l, 0.0);
        let sum: f32 = w.iter().sum();
        assert!(sum <= 1.0 + 1e-6 && w.iter().all(|&v| v >= 0.0));
    }
}

#[test]
fn weights_never_sum_above_one() {
    let mut rng = StdRng::seed_from_u64(3);
    let counts: Vec<usize> = (0..200).map(|_| rng.random_range(0..40)).collect();
    let n: usize = counts.iter().sum();
    let sigma: Vec<f32> = (0..n).map(|_| 10f32.powf(rng.random_range(-3.0..4.0))).collect();
    let deltas: Vec<f32> = (0..n).map(|_| rng.random_range(0.0..0.5)).collect();
    let l = layout(&counts, deltas);
    let w = weights(&sigma, &l, 0.0);
    for r in 0..counts.len() {
        let sum: f32 = w[l.offsets[r] as usize..l.offsets[r + 1] as usize].iter().sum();
        assert!(sum <= 1.0 + 1e-5, "ray {r}: {sum}");
    }
}

#[test]
fn extreme_densities_and_steps_stay_finite_in_both_passes() {
    let dev = device();
    let sigmas = [0.0f32, 1e-30, 1e-3, 1.0, 1e3, 1e30, f32::MAX];
    let deltas = [0.0f32, 1e-12, 1.0, 1e12];
    // Every (σ, δ) pair as one sample, plus rays mixing them.
    let mut sig = Vec::new();
    let mut del = Vec::new();
    for s in sigmas {
        for d in deltas {
            sig.push(s);
            del.push(d);
        }
    }
    let n = sig.len();
    let counts = vec![1; n].into_iter().chain([n]).collect::<Vec<_>>();
    let sig2: Vec<f32> = sig.iter().chain(&sig).copied().collect();
    let del2: Vec<f32> = del.iter().chain(&del).copied().collect();
    let m = sig2.len();
    let l = layout(&counts, del2);
    for blended in [false, true] {
        let sigma = t2(sig2.clone(), [m, 1], &dev).require_grad();
        let feats = t2(vec![0.3; m * 3], [m, 3], &dev).require_grad();
        let blend = blended.then(|| t2(vec![0.7; m], [m, 1], &dev).require_grad());
        let out = composite(sigma.clone(), feats.clone(), blend.clone(), &l, 0.0);
        let vals = host(out.clone().inner());
        assert!(vals.iter().all(|v| v.is_finite()), "outputs {vals:?}");
        let grads = (out.clone() * out).sum().backward();
        for g in [sigma.grad(&grads), feats.grad(&grads)]
            .into_iter()
            .chain(blend.map(|b| b.grad(&grads)))
        {
            let g = g.unwrap().into_data().try_into_vec_as::<f32>().unwrap();
            assert!(g.iter().all(|v| v.is_finite()), "gradients {g:?}");
        }
    }
}

/// Fused gradients against central differences of the f64 reference, for K = 1 and a blended
/// K = 2 (NSFF's static + dynamic).
#[test]
fn gradients_match_f64_finite_differences() {
    let dev = device();
    let mut rng = StdRng::seed_from_u64(7);
    for (k_n, blended) in [(1usize, false), (2, true)] {
        let c_n = 3;
        let counts = [5usize, 1, 9, 3];
        let n: usize = counts.iter().sum();
        let sigma: Vec<f64> = (0..n * k_n).map(|_| rng.random_range(0.0..3.0)).collect();
        let feats: Vec<f64> = (0..n * k_n * c_n).map(|_| rng.random_range(0.0..1.0)).collect();
        let blend: Vec<f64> = (0..n * k_n).map(|_| rng.random_range(0.1..0.9)).collect();
        let deltas: Vec<f64> = (0..n).map(|_| rng.random_range(0.05..0.6)).collect();
        let upstream: Vec<f64> = (0..counts.len() * (c_n + 1))
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let f32v = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        // Round inputs to f32 first so both sides see identical values.
        let (sigma, feats, blend, deltas) = (
            f32v(&sigma).iter().map(|&v| v as f64).collect::<Vec<_>>(),
            f32v(&feats).iter().map(|&v| v as f64).collect::<Vec<_>>(),
            f32v(&blend).iter().map(|&v| v as f64).collect::<Vec<_>>(),
            f32v(&deltas).iter().map(|&v| v as f64).collect::<Vec<_>>(),
        );
        let loss = |s: &[f64], f: &[f64], b: &[f64]| -> f64 {
            let out = reference_f64(s, f, blended.then_some(b), &counts, &deltas, k_n, c_n);
            out.iter().zip(&upstream).map(|(o, u)| o * u).sum()
        };
        let l = layout(&counts, f32v(&deltas));
        let ts = t2(f32v(&sigma), [n, k_n], &dev).require_grad();
        let tf = t2(f32v(&feats), [n, k_n * c_n], &dev).require_grad();
        let tb = t2(f32v(&blend), [n, k_n], &dev).require_grad();
        let out = composite(ts.clone(), tf.clone(), blended.then(|| tb.clone()), &l, 0.0);
        // Forward agrees with the f64 reference.
        let fwd = host(out.clone().inner());
        let want = reference_f64(
            &sigma,
            &feats,
            blended.then_some(&blend[..]),
            &counts,
            &deltas,
            k_n,
            c_n,
        );
        for (a, b) in fwd.iter().zip(&want) {
            assert!((*a as f64 - b).abs() < 1e-5, "{a} vs {b}");
        }
        let up = t2(f32v(&upstream), [counts.len(), c_n + 1], &dev);
        let grads = (out * up).sum().backward();
        let check = |name: &str, got: Tensor<2>, base: &[f64], which: usize| {
            let got = host(got);
            for i in 0..base.len() {
                let h = 1e-6;
                let mut plus = [sigma.clone(), feats.clone(), blend.clone()];
                let mut minus = plus.clone();
                plus[which][i] += h;
                minus[which][i] -= h;
                let fd =
                    (loss(&plus[0], &plus[1], &plus[2]) - loss(&minus[0], &minus[1], &minus[2])) / (2.0 * h);
                let err = (got[i] as f64 - fd).abs() / fd.abs().max(1e-2);
                assert!(
                    err < 1e-3,
                    "K={k_n} d{name}[{i}]: fused {} vs finite difference {fd}",
                    got[i]
                );
            }
        };
        check("sigma", ts.grad(&grads).unwrap(), &sigma, 0);
        check("feats", tf.grad(&grads).unwrap(), &feats, 1);
        if blended {
            check("blend", tb.grad(&grads).unwrap(), &blend, 2);
        }
    }
}

#[test]
fn fused_op_matches_generic_tensor_ops() {
    let dev = device();
    let mut rng = StdRng::seed_from_u64(11);
    let (r, s, c) = (64usize, 32usize, 3usize);
    let sigma: Vec<f32> = (0..r * s).map(|_| rng.random_range(0.0..5.0)).collect();
    let feats: Vec<f32> = (0..r * s * c).map(|_| rng.random_range(0.0..1.0)).collect();
    let deltas: Vec<f32> = (0..r * s).map(|_| rng.random_range(0.0..0.2)).collect();
    let l = layout(&vec![s; r], deltas.clone());
    let ts = t2(sigma.clone(), [r * s, 1], &dev).require_grad();
    let tf = t2(feats.clone(), [r * s, c], &dev).require_grad();
    let fused = composite(ts.clone(), tf.clone(), None, &l, 0.0);
    let gs = t2(sigma, [r, s], &dev).require_grad();
    let gf = Tensor::<2>::from_data(TensorData::new(feats, [r * s, c]), &dev)
        .reshape([r, s, c])
        .require_grad();
    let generic = composite_reference(gs.clone(), gf.clone(), t2(deltas, [r, s], &dev));
    let (a, b) = (host(fused.clone().inner()), host(generic.clone().inner()));
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() < 1e-5, "{x} vs {y}");
    }
    let g1 = (fused.clone() * fused).sum().backward();
    let g2 = (generic.clone() * generic).sum().backward();
    let d1 = host(ts.grad(&g1).unwrap());
    let d2 = host(gs.grad(&g2).unwrap().reshape([r * s, 1]));
    for (x, y) in d1.iter().zip(&d2) {
        assert!((x - y).abs() < 1e-4 * (1.0 + y.abs()), "{x} vs {y}");
    }
    let f1 = host(tf.grad(&g1).unwrap());
    let f2 = host(gf.grad(&g2).unwrap().reshape([r * s, c]));
    for (x, y) in f1.iter().zip(&f2) {
        assert!((x - y).abs() < 1e-5, "{x} vs {y}");
    }
}

#[test]
fn early_termination_only_drops_negligible_light() {
    let dev = Device::flex();
    let n = 256;
    let l = layout(&[n], vec![0.05; n]);
    let sigma = vec![20.0f32; n];
    let full = host(composite(
        t2(sigma.clone(), [n, 1], &dev),
        t2(vec![1.0; n], [n, 1], &dev),
        None,
        &l,
        0.0,
    ));
    let cut = host(composite(
        t2(sigma, [n, 1], &dev),
        t2(vec![1.0; n], [n, 1], &dev),
        None,
        &l,
        1e-4,
    ));
    assert!((full[1] - cut[1]).abs() <= 1e-4, "{full:?} vs {cut:?}");
}
