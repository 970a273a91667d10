//! Single-channel f32 rasters and the low-level operations the flow solvers share: grey
//! conversion, Gaussian blur, resampling, bilinear sampling, gradients and median filtering.
//!
//! Coordinates here are *index* coordinates: the centre of pixel (i, j) sits at (i, j). Flow is a
//! displacement, so it is the same in index and in the crate's pixel-centre coordinates.

use rayon::prelude::*;

use nerf_data::image::Image;

/// Rasters with at least this many pixels split row loops across rayon threads; smaller ones
/// (coarse pyramid levels, small videos) run serially because the per-pass scheduling overhead
/// would exceed the work. Frame pairs are parallel anyway in [`super::video_flows`].
pub(crate) const PAR_MIN_PIXELS: usize = 1 << 15;

/// A row-major single-channel raster.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Plane {
    pub w: usize,
    pub h: usize,
    pub data: Vec<f32>,
}

/// Runs `f(row_index, row)` over every row of `data` (rows of `w` values), in parallel when the
/// raster is large.
pub(crate) fn for_rows<T: Send>(data: &mut [T], w: usize, f: impl Fn(usize, &mut [T]) + Sync + Send) {
    rows_sum(data, w, |y, row| {
        f(y, row);
        0.0
    });
}

/// Like [`for_rows`], returning the sum of what `f` returns per row (e.g. a squared update size).
pub(crate) fn rows_sum<T: Send>(
    data: &mut [T],
    w: usize,
    f: impl Fn(usize, &mut [T]) -> f64 + Sync + Send,
) -> f64 {
    if data.len() >= PAR_MIN_PIXELS {
        data.par_chunks_mut(w).enumerate().map(|(y, row)| f(y, row)).sum()
    } else {
        data.chunks_mut(w).enumerate().map(|(y, row)| f(y, row)).sum()
    }
}

impl Plane {
    pub fn new(w: usize, h: usize) -> Plane {
        Plane {
            w,
            h,
            data: vec![0.0; w * h],
        }
    }

    /// A raster whose value at (x, y) is `f(x, y)`.
    pub fn from_fn(w: usize, h: usize, f: impl Fn(usize, usize) -> f32 + Sync + Send) -> Plane {
        let mut p = Plane::new(w, h);
        for_rows(&mut p.data, w, |y, row| {
            for (x, v) in row.iter_mut().enumerate() {
                *v = f(x, y);
            }
        });
        p
    }

    /// Luma (Rec. 601 weights) of an image scaled to [0, 255], so the solvers' weights match the
    /// usual 8-bit literature values. One-channel images are used as they are, two-channel ones
    /// (grey + alpha) by their first channel; alpha is ignored.
    pub fn luma(img: &Image) -> Plane {
        let c = img.channels as usize;
        let (w, h) = (img.width as usize, img.height as usize);
        let data = img
            .data
            .chunks_exact(c.max(1))
            .map(|px| {
                if c >= 3 {
                    255.0 * (0.299 * px[0] + 0.587 * px[1] + 0.114 * px[2])
                } else {
                    255.0 * px[0]
                }
            })
            .collect();
        Plane { w, h, data }
    }

    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.w + x]
    }

    /// Bilinear sample at index coordinates, clamped to the border (edge pixels repeat).
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let xm = (self.w - 1) as f32;
        let ym = (self.h - 1) as f32;
        let x = if x.is_finite() { x.clamp(0.0, xm) } else { 0.0 };
        let y = if y.is_finite() { y.clamp(0.0, ym) } else { 0.0 };
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let r0 = self.data[y0 * self.w + x0] * (1.0 - fx) + self.data[y0 * self.w + x1] * fx;
        let r1 = self.data[y1 * self.w + x0] * (1.0 - fx) + self.data[y1 * self.w + x1] * fx;
        r0 * (1.0 - fy) + r1 * fy
    }

    /// Bicubic (Keys, a = −0.5) sample at index coordinates, border clamped. Sharper than
    /// bilinear: bilinear warping blurs by an amount that depends on the sub-pixel offset, which
    /// biases the data term towards integer displacements.
    #[inline]
    pub fn sample_cubic(&self, x: f32, y: f32) -> f32 {
        let xm = (self.w - 1) as f32;
        let ym = (self.h - 1) as f32;
        let x = if x.is_finite() { x.clamp(0.0, xm) } else { 0.0 };
        let y = if y.is_finite() { y.clamp(0.0, ym) } else { 0.0 };
        let (xf, yf) = (x.floor(), y.floor());
        let (tx, ty) = (x - xf, y - yf);
        let weights = |t: f32| {
            let t2 = t * t;
            let t3 = t2 * t;
            [
                -0.5 * t3 + t2 - 0.5 * t,
                1.5 * t3 - 2.5 * t2 + 1.0,
                -1.5 * t3 + 2.0 * t2 + 0.5 * t,
                0.5 * t3 - 0.5 * t2,
            ]
        };
        let (wx, wy) = (weights(tx), weights(ty));
        let (x0, y0) = (xf as isize - 1, yf as isize - 1);
        let (wmax, hmax) = (self.w as isize - 1, self.h as isize - 1);
        let mut acc = 0.0;
        for (j, wyj) in wy.iter().enumerate() {
            let row = (y0 + j as isize).clamp(0, hmax) as usize * self.w;
            let mut r = 0.0;
            for (i, wxi) in wx.iter().enumerate() {
                r += wxi * self.data[row + (x0 + i as isize).clamp(0, wmax) as usize];
            }
            acc += wyj * r;
        }
        acc
    }

    /// Separable Gaussian blur with standard deviation `sigma` pixels (edges repeat). A sigma
    /// below 0.1 returns a copy.
    pub fn blur(&self, sigma: f32) -> Plane {
        if sigma < 0.1 {
            return self.clone();
        }
        let r = (3.0 * sigma).ceil() as isize;
        let mut k: Vec<f32> = (-r..=r)
            .map(|i| (-((i * i) as f32) / (2.0 * sigma * sigma)).exp())
            .collect();
        let sum: f32 = k.iter().sum();
        k.iter_mut().for_each(|v| *v /= sum);
        let (w, h) = (self.w as isize, self.h as isize);
        let mut tmp = Plane::new(self.w, self.h);
        for_rows(&mut tmp.data, self.w, |y, row| {
            let src = &self.data[y * self.w..(y + 1) * self.w];
            for (x, out) in row.iter_mut().enumerate() {
                *out = k
                    .iter()
                    .enumerate()
                    .map(|(t, kv)| kv * src[(x as isize + t as isize - r).clamp(0, w - 1) as usize])
                    .sum();
            }
        });
        let mut out = Plane::new(self.w, self.h);
        for_rows(&mut out.data, self.w, |y, row| {
            for (t, kv) in k.iter().enumerate() {
                let sy = (y as isize + t as isize - r).clamp(0, h - 1) as usize;
                let src = &tmp.data[sy * self.w..(sy + 1) * self.w];
                for (o, s) in row.iter_mut().zip(src) {
                    *o += kv * s;
                }
            }
        });
        out
    }

    /// Resamples to `w` x `h` by bilinear sampling at the mapped pixel centres, after a Gaussian
    /// blur matched to the scale factor (anti-aliasing for downsampling; none for upsampling).
    pub fn resized(&self, w: usize, h: usize) -> Plane {
        let (sx, sy) = (self.w as f32 / w as f32, self.h as f32 / h as f32);
        let s = sx.max(sy);
        // σ = 0.6·sqrt(s² − 1): ~0.8 px for a factor 2 (OpenCV's TV-L1 pyramid uses 0.8).
        let src = if s > 1.0 {
            self.blur(0.6 * (s * s - 1.0).sqrt())
        } else {
            self.clone()
        };
        Plane::from_fn(w, h, |x, y| {
            src.sample((x as f32 + 0.5) * sx - 0.5, (y as f32 + 0.5) * sy - 0.5)
        })
    }

    /// Central-difference gradients (one-sided at the border).
    pub fn gradients(&self) -> (Plane, Plane) {
        let (w, h) = (self.w, self.h);
        let gx = Plane::from_fn(w, h, |x, y| {
            let (a, b) = (x.saturating_sub(1), (x + 1).min(w - 1));
            if a == b {
                0.0
            } else {
                (self.at(b, y) - self.at(a, y)) / (b - a) as f32
            }
        });
        let gy = Plane::from_fn(w, h, |x, y| {
            let (a, b) = (y.saturating_sub(1), (y + 1).min(h - 1));
            if a == b {
                0.0
            } else {
                (self.at(x, b) - self.at(x, a)) / (b - a) as f32
            }
        });
        (gx, gy)
    }

    /// Smaller eigenvalue of the structure tensor (gradient outer products averaged with a
    /// Gaussian window of `sigma` pixels): how well a window pins down motion in its *weakest*
    /// direction. Near zero on flat regions and along straight edges (the aperture problem).
    pub fn min_eigen_structure(&self, sigma: f32) -> Plane {
        let (gx, gy) = self.gradients();
        let prod =
            |a: &Plane, b: &Plane| Plane::from_fn(self.w, self.h, |x, y| a.at(x, y) * b.at(x, y)).blur(sigma);
        let (xx, xy, yy) = (prod(&gx, &gx), prod(&gx, &gy), prod(&gy, &gy));
        Plane::from_fn(self.w, self.h, |x, y| {
            let (a, b, c) = (xx.at(x, y), xy.at(x, y), yy.at(x, y));
            let half_diff = 0.5 * (a - c);
            (0.5 * (a + c) - half_diff.hypot(b)).max(0.0)
        })
    }

    /// Median over a (2r+1)² window (clipped at the border). Removes isolated flow outliers while
    /// keeping motion edges, which is why coarse-to-fine solvers apply it after every warp.
    pub fn median(&self, r: usize) -> Plane {
        if r == 0 {
            return self.clone();
        }
        Plane::from_fn(self.w, self.h, |x, y| {
            let mut win = [0f32; 121];
            let r = r.min(5);
            let mut n = 0;
            for yy in y.saturating_sub(r)..=(y + r).min(self.h - 1) {
                for xx in x.saturating_sub(r)..=(x + r).min(self.w - 1) {
                    win[n] = self.at(xx, yy);
                    n += 1;
                }
            }
            let win = &mut win[..n];
            let mid = n / 2;
            *win.select_nth_unstable_by(mid, f32::total_cmp).1
        })
    }
}

/// A flow field as two component rasters (dx, dy) in index units of its own resolution.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Flow {
    pub u: Plane,
    pub v: Plane,
}

impl Flow {
    pub fn zeros(w: usize, h: usize) -> Flow {
        Flow {
            u: Plane::new(w, h),
            v: Plane::new(w, h),
        }
    }

    /// The flow resampled to `w` x `h`, with the vectors rescaled to the new pixel size.
    pub fn resized(&self, w: usize, h: usize) -> Flow {
        let (sx, sy) = (w as f32 / self.u.w as f32, h as f32 / self.u.h as f32);
        let map = |p: &Plane, s: f32| {
            Plane::from_fn(w, h, |x, y| {
                s * p.sample((x as f32 + 0.5) / sx - 0.5, (y as f32 + 0.5) / sy - 0.5)
            })
        };
        Flow {
            u: map(&self.u, sx),
            v: map(&self.v, sy),
        }
    }

    pub fn median(&self, r: usize) -> Flow {
        Flow {
            u: self.u.median(r),
            v: self.v.median(r),
        }
    }

    /// The vectors as (dx, dy) pairs, the layout the per-level solvers iterate on.
    pub fn pairs(&self) -> Vec<[f32; 2]> {
        self.u
            .data
            .iter()
            .zip(&self.v.data)
            .map(|(&a, &b)| [a, b])
            .collect()
    }

    /// Sets the vectors from (dx, dy) pairs.
    pub fn set_pairs(&mut self, uv: &[[f32; 2]]) {
        for (i, u) in uv.iter().enumerate() {
            self.u.data[i] = u[0];
            self.v.data[i] = u[1];
        }
    }

    /// Interleaved `[H*W*2]` (dx, dy), the layout of [`nerf_data::FlowField`].
    pub fn interleaved(&self) -> Vec<f32> {
        self.u
            .data
            .iter()
            .zip(&self.v.data)
            .flat_map(|(&a, &b)| [a, b])
            .collect()
    }
}

/// `img` sampled at p + flow(p) for every pixel p (bilinear, border clamped).
pub(crate) fn warp(img: &Plane, flow: &Flow) -> Plane {
    Plane::from_fn(img.w, img.h, |x, y| {
        let i = y * img.w + x;
        img.sample_cubic(x as f32 + flow.u.data[i], y as f32 + flow.v.data[i])
    })
}

/// Frame 1 and its gradients warped by the current flow: one relinearisation of brightness
/// constancy I1(p + u) = I0(p) around the flow, shared by the per-level solvers.
pub(crate) struct Linearised {
    /// I1 warped by the flow.
    pub i1: Plane,
    /// ∂I1/∂x and ∂I1/∂y warped by the flow.
    pub gx: Plane,
    pub gy: Plane,
}

impl Linearised {
    /// `i1x`, `i1y`: the gradients of `i1` (computed once per level, not per warp).
    pub fn new(i1: &Plane, i1x: &Plane, i1y: &Plane, flow: &Flow) -> Linearised {
        Linearised {
            i1: warp(i1, flow),
            gx: warp(i1x, flow),
            gy: warp(i1y, flow),
        }
    }

    /// ρ_c = I1w − ∇I1w·u0 − I0 per pixel, so the linearised residual is ρ(u) = ρ_c + ∇I1w·u.
    pub fn residual_constant(&self, i0: &Plane, flow: &Flow) -> Vec<f32> {
        (0..i0.data.len())
            .map(|i| {
                self.i1.data[i]
                    - self.gx.data[i] * flow.u.data[i]
                    - self.gy.data[i] * flow.v.data[i]
                    - i0.data[i]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_sampling_is_exact_on_linear_ramps() {
        let p = Plane::from_fn(8, 6, |x, y| 2.0 * x as f32 - 3.0 * y as f32);
        assert!((p.sample(2.25, 3.5) - (4.5 - 10.5)).abs() < 1e-5);
        // Clamped outside.
        assert_eq!(p.sample(-4.0, 0.0), p.at(0, 0));
    }

    #[test]
    fn blur_keeps_constants_and_median_drops_spikes() {
        let c = Plane::from_fn(9, 7, |_, _| 3.0);
        assert!(c.blur(1.3).data.iter().all(|v| (v - 3.0).abs() < 1e-5));
        let mut s = c.clone();
        s.data[3 * 9 + 4] = 100.0;
        assert_eq!(s.median(1).at(4, 3), 3.0);
    }

    #[test]
    fn resized_flow_scales_vectors() {
        let mut f = Flow::zeros(8, 4);
        f.u.data.fill(1.5);
        f.v.data.fill(-0.5);
        let g = f.resized(16, 8);
        assert!(g.u.data.iter().all(|v| (v - 3.0).abs() < 1e-6));
        assert!(g.v.data.iter().all(|v| (v + 1.0).abs() < 1e-6));
    }
}
