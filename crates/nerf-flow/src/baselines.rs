//! The two classical alternatives we measured TV-L1 against (see the crate docs for
//! the numbers): Horn–Schunck with warping and median filtering, and dense
//! Lucas–Kanade with a Gaussian window. Both run inside the same pyramid as TV-L1.

use super::plane::{Flow, Linearised, Plane, for_rows};

/// Horn–Schunck at one level: quadratic data and smoothness terms, Jacobi iterations on the
/// linearised Euler–Lagrange equations, `warps` relinearisations with a median filter after each.
/// `alpha` weighs smoothness against the data term (intensities in [0, 255]).
pub(crate) fn horn_schunck(
    i0: &Plane,
    i1: &Plane,
    mut flow: Flow,
    alpha: f32,
    warps: usize,
    iterations: usize,
    median_radius: usize,
) -> Flow {
    let (w, h) = (i0.w, i0.h);
    let (i1x, i1y) = i1.gradients();
    let a2 = alpha * alpha;
    for _ in 0..warps {
        let lin = Linearised::new(i1, &i1x, &i1y, &flow);
        let rho_c = lin.residual_constant(i0, &flow);
        let (gx, gy) = (&lin.gx, &lin.gy);
        let mut uv = flow.pairs();
        let mut next = uv.clone();
        for _ in 0..iterations {
            {
                let uv = &uv;
                let (gx, gy, rho_c) = (&gx.data, &gy.data, &rho_c);
                for_rows(&mut next, w, |y, row| {
                    for (x, out) in row.iter_mut().enumerate() {
                        let i = y * w + x;
                        let mut avg = [0f32; 2];
                        let mut n = 0.0;
                        for (ok, j) in [
                            (x > 0, i.wrapping_sub(1)),
                            (x + 1 < w, i + 1),
                            (y > 0, i.wrapping_sub(w)),
                            (y + 1 < h, i + w),
                        ] {
                            if ok {
                                avg[0] += uv[j][0];
                                avg[1] += uv[j][1];
                                n += 1.0;
                            }
                        }
                        let avg = [avg[0] / n, avg[1] / n];
                        let (ix, iy) = (gx[i], gy[i]);
                        let r = (rho_c[i] + ix * avg[0] + iy * avg[1]) / (a2 + ix * ix + iy * iy);
                        *out = [avg[0] - ix * r, avg[1] - iy * r];
                    }
                });
            }
            std::mem::swap(&mut uv, &mut next);
        }
        flow.set_pairs(&uv);
        flow = flow.median(median_radius);
    }
    flow
}

/// Dense Lucas–Kanade at one level: per pixel, the least-squares update over a Gaussian window
/// of standard deviation `sigma`, iterated `warps` times with a median filter after each.
pub(crate) fn lucas_kanade(
    i0: &Plane,
    i1: &Plane,
    mut flow: Flow,
    sigma: f32,
    warps: usize,
    median_radius: usize,
) -> Flow {
    let (w, h) = (i0.w, i0.h);
    let (i1x, i1y) = i1.gradients();
    for _ in 0..warps {
        let Linearised { i1: i1w, gx, gy } = Linearised::new(i1, &i1x, &i1y, &flow);
        let it: Vec<f32> = (0..w * h).map(|i| i1w.data[i] - i0.data[i]).collect();
        let prod =
            |f: &(dyn Fn(usize) -> f32 + Sync + Send)| Plane::from_fn(w, h, |x, y| f(y * w + x)).blur(sigma);
        let (xx, xy, yy) = (
            prod(&|i| gx.data[i] * gx.data[i]),
            prod(&|i| gx.data[i] * gy.data[i]),
            prod(&|i| gy.data[i] * gy.data[i]),
        );
        let (xt, yt) = (prod(&|i| gx.data[i] * it[i]), prod(&|i| gy.data[i] * it[i]));
        // A small ridge keeps flat windows (no texture) from producing huge updates.
        let ridge = 1.0;
        let mut uv = flow.pairs();
        for_rows(&mut uv, w, |y, row| {
            for (x, u) in row.iter_mut().enumerate() {
                let i = y * w + x;
                let (a, b, c) = (xx.data[i] + ridge, xy.data[i], yy.data[i] + ridge);
                let det = a * c - b * b;
                let (bx, by) = (xt.data[i], yt.data[i]);
                u[0] -= (c * bx - b * by) / det;
                u[1] -= (a * by - b * bx) / det;
            }
        });
        flow.set_pairs(&uv);
        flow = flow.median(median_radius);
    }
    flow
}
