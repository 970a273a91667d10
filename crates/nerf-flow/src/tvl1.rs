//! TV-L1 optical flow at one pyramid level (Zach, Pock and Bischof 2007, in the form of Wedel et
//! al. 2009 and Sánchez Pérez, Meinhardt-Llopis and Facciolo, IPOL 2013).
//!
//! Energy: ∫ λ·|I1(x + u) − I0(x)| + |∇u1| + |∇u2|. The data term is linearised around the
//! current flow u0 at each warp, ρ(u) = I1(x + u0) + ∇I1·(u − u0) − I0, and the problem is split
//! with an auxiliary field v coupled by (1/2θ)|u − v|²:
//! - v step (pointwise): soft-thresholding of ρ, the closed-form minimiser of λ|ρ(v)| + |u − v|²/2θ;
//! - u step: a TV denoising of v, solved by Chambolle's dual projection with dual fields p.
//!
//! The L1 data term tolerates occlusions and the brightness changes of shaded rotating surfaces
//! much better than a quadratic one, and TV keeps motion boundaries sharp. With `huber` > 0
//! the regulariser is Huber-TV (Werlberger et al. 2009): quadratic for small flow gradients, so
//! flow varies smoothly across textureless patches instead of forming staircases.

use super::plane::{Flow, Linearised, Plane, for_rows, rows_sum};

/// TV-L1 weights. λ is for intensities in [0, 255] (the solver's internal scale).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TvL1Params {
    /// Data-term weight λ: larger follows the images more closely, smaller smooths more.
    pub lambda: f32,
    /// Coupling θ between u and the auxiliary v (small = tight coupling).
    pub theta: f32,
    /// Dual step τ; τ ≤ 1/4 guarantees convergence of Chambolle's projection on a 2-D grid.
    pub tau: f32,
    /// Stop a warp's inner loop when the mean squared update of u falls below ε².
    pub epsilon: f32,
    /// Huber threshold of the regulariser (flow gradient, pixels per pixel): gradients below it
    /// are penalised quadratically, so flow varies smoothly across textureless regions instead
    /// of staircasing; 0 gives plain TV.
    pub huber: f32,
}

impl Default for TvL1Params {
    fn default() -> Self {
        TvL1Params {
            lambda: 0.5,
            theta: 0.3,
            tau: 0.25,
            epsilon: 0.01,
            huber: 0.1,
        }
    }
}

/// Squared gradients below this are treated as flat: the v step leaves u unchanged there.
const GRAD_MIN: f32 = 1e-9;

/// Refines `flow` from `i0` to `i1` (same size) with `warps` linearisations of up to
/// `iterations` inner steps each, and a (2r+1)² median filter after each warp when r > 0.
pub(crate) fn refine(
    i0: &Plane,
    i1: &Plane,
    mut flow: Flow,
    p: &TvL1Params,
    warps: usize,
    iterations: usize,
    median_radius: usize,
) -> Flow {
    let (w, h) = (i0.w, i0.h);
    let (i1x, i1y) = i1.gradients();
    // Dual fields of u1 and u2: [p11, p12, p21, p22] per pixel. Kept across warps.
    let mut dual = vec![[0f32; 4]; w * h];
    let lt = p.lambda * p.theta;
    let step = p.tau / p.theta;
    for _ in 0..warps {
        let lin = Linearised::new(i1, &i1x, &i1y, &flow);
        let rho_c = lin.residual_constant(i0, &flow);
        let (gx, gy) = (&lin.gx, &lin.gy);
        let mut uv = flow.pairs();
        for _ in 0..iterations {
            // v step and u step together: u only needs the current dual fields.
            let change = {
                let dual = &dual;
                let (gx, gy, rho_c) = (&gx.data, &gy.data, &rho_c);
                rows_sum(&mut uv, w, |y, row| {
                    let mut err = 0.0f64;
                    for (x, u) in row.iter_mut().enumerate() {
                        let i = y * w + x;
                        let (ix, iy) = (gx[i], gy[i]);
                        let g2 = ix * ix + iy * iy;
                        let rho = rho_c[i] + ix * u[0] + iy * u[1];
                        let (d1, d2) = if rho < -lt * g2 {
                            (lt * ix, lt * iy)
                        } else if rho > lt * g2 {
                            (-lt * ix, -lt * iy)
                        } else if g2 > GRAD_MIN {
                            (-rho * ix / g2, -rho * iy / g2)
                        } else {
                            (0.0, 0.0)
                        };
                        let v = [u[0] + d1, u[1] + d2];
                        // div p with backward differences; p is zero past the last column/row.
                        let q = dual[i];
                        let left = if x > 0 { dual[i - 1] } else { [0.0; 4] };
                        let up = if y > 0 { dual[i - w] } else { [0.0; 4] };
                        let div1 = q[0] - left[0] + q[1] - up[1];
                        let div2 = q[2] - left[2] + q[3] - up[3];
                        let new = [v[0] + p.theta * div1, v[1] + p.theta * div2];
                        err += ((new[0] - u[0]).powi(2) + (new[1] - u[1]).powi(2)) as f64;
                        *u = new;
                    }
                    err
                })
            };
            // Dual ascent with reprojection onto the unit ball (Chambolle's semi-implicit form).
            {
                let uv = &uv;
                for_rows(&mut dual, w, |y, row| {
                    for (x, q) in row.iter_mut().enumerate() {
                        let i = y * w + x;
                        let u = uv[i];
                        let (ux, vx) = if x + 1 < w {
                            (uv[i + 1][0] - u[0], uv[i + 1][1] - u[1])
                        } else {
                            (0.0, 0.0)
                        };
                        let (uy, vy) = if y + 1 < h {
                            (uv[i + w][0] - u[0], uv[i + w][1] - u[1])
                        } else {
                            (0.0, 0.0)
                        };
                        if p.huber > 0.0 {
                            // Huber-TV: damped ascent, then projection onto the unit ball.
                            let d = 1.0 + step * p.huber;
                            let a = [(q[0] + step * ux) / d, (q[1] + step * uy) / d];
                            let b = [(q[2] + step * vx) / d, (q[3] + step * vy) / d];
                            let na = a[0].hypot(a[1]).max(1.0);
                            let nb = b[0].hypot(b[1]).max(1.0);
                            *q = [a[0] / na, a[1] / na, b[0] / nb, b[1] / nb];
                        } else {
                            let n1 = 1.0 + step * (ux * ux + uy * uy).sqrt();
                            let n2 = 1.0 + step * (vx * vx + vy * vy).sqrt();
                            *q = [
                                (q[0] + step * ux) / n1,
                                (q[1] + step * uy) / n1,
                                (q[2] + step * vx) / n2,
                                (q[3] + step * vy) / n2,
                            ];
                        }
                    }
                });
            }
            if change / ((w * h) as f64) < (p.epsilon * p.epsilon) as f64 {
                break;
            }
        }
        flow.set_pairs(&uv);
        flow = flow.median(median_radius);
    }
    flow
}
