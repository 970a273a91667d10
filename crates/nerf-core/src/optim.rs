//! Sparse Adam for host-side parameter tables (the hash grid).

/// Adam hyper-parameters (the learning rate is passed per step).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdamParams {
    pub beta1: f64,
    pub beta2: f64,
    pub epsilon: f64,
}

impl Default for AdamParams {
    /// Instant-NGP's settings.
    fn default() -> Self {
        AdamParams {
            beta1: 0.9,
            beta2: 0.99,
            epsilon: 1e-15,
        }
    }
}

/// Adam whose update visits only the rows that received a gradient this step ("lazy" Adam, as
/// Instant-NGP does for hash entries). Bias correction uses the global step count.
#[derive(Clone, Debug, Default)]
pub struct SparseAdam {
    step: u64,
    m: Vec<f32>,
    v: Vec<f32>,
}

impl SparseAdam {
    pub fn new(len: usize) -> Self {
        SparseAdam {
            step: 0,
            m: vec![0.0; len],
            v: vec![0.0; len],
        }
    }

    /// Updates the rows (each `width` values) whose gradient is not all zero, then zeroes the
    /// gradient. Only blocks of `block_rows` rows flagged in `dirty` are visited (and their flags
    /// cleared), so the cost follows the rows a step touched, not the table size. Returns how
    /// many rows were updated.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        p: &AdamParams,
        lr: f64,
        params: &mut [f32],
        grad: &mut [f32],
        width: usize,
        dirty: &mut [bool],
        block_rows: usize,
    ) -> usize {
        use rayon::prelude::*;
        self.step += 1;
        let t = self.step.min(i32::MAX as u64) as i32;
        let (bc1, bc2) = (1.0 - p.beta1.powi(t), 1.0 - p.beta2.powi(t));
        let (b1, b2) = (p.beta1 as f32, p.beta2 as f32);
        let step_size = (lr / bc1) as f32;
        let (inv_bc2_sqrt, eps) = ((1.0 / bc2.sqrt()) as f32, p.epsilon as f32);
        const BLOCKS: usize = 1024;
        let chunk = width * block_rows * BLOCKS;
        params
            .par_chunks_mut(chunk)
            .zip(grad.par_chunks_mut(chunk))
            .zip(self.m.par_chunks_mut(chunk))
            .zip(self.v.par_chunks_mut(chunk))
            .zip(dirty.par_chunks_mut(BLOCKS))
            .map(|((((x, g), m), v), dirty)| {
                let mut rows = 0;
                for (b, flag) in dirty.iter_mut().enumerate() {
                    if !std::mem::take(flag) {
                        continue;
                    }
                    let start = b * block_rows * width;
                    let end = (start + block_rows * width).min(x.len());
                    for r in (start..end).step_by(width) {
                        if g[r..r + width].iter().all(|v| *v == 0.0) {
                            continue;
                        }
                        rows += 1;
                        for i in r..r + width {
                            let gi = g[i];
                            m[i] = b1 * m[i] + (1.0 - b1) * gi;
                            v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                            x[i] -= step_size * m[i] / (v[i].sqrt() * inv_bc2_sqrt + eps);
                            g[i] = 0.0;
                        }
                    }
                }
                rows
            })
            .sum()
    }

    pub fn state(&self) -> (u64, Vec<f32>, Vec<f32>) {
        (self.step, self.m.clone(), self.v.clone())
    }

    pub fn set_state(&mut self, step: u64, m: Vec<f32>, v: Vec<f32>) {
        assert_eq!(m.len(), self.m.len());
        assert_eq!(v.len(), self.v.len());
        (self.step, self.m, self.v) = (step, m, v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On touched rows the update equals textbook dense Adam; untouched rows stay put.
    #[test]
    fn matches_dense_adam_on_touched_rows() {
        let p = AdamParams {
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
        };
        let mut adam = SparseAdam::new(4);
        let mut x = vec![1.0f32, 2.0, 3.0, 4.0];
        let (mut m, mut v) = (0.0f64, 0.0f64);
        let mut x0 = 1.0f64;
        for t in 1..=5 {
            let g = 0.5 * t as f32;
            let rows = adam.step(&p, 0.1, &mut x, &mut [g, g, 0.0, 0.0], 2, &mut [true, true], 1);
            assert_eq!(rows, 1);
            m = 0.9 * m + 0.1 * g as f64;
            v = 0.999 * v + 0.001 * (g as f64).powi(2);
            let mh = m / (1.0 - 0.9f64.powi(t));
            let vh = v / (1.0 - 0.999f64.powi(t));
            x0 -= 0.1 * mh / (vh.sqrt() + 1e-8);
            assert!((x[0] as f64 - x0).abs() < 1e-5, "{} vs {x0}", x[0]);
        }
        assert_eq!(&x[2..], &[3.0, 4.0]);
    }
}
