//! Samplers decide where to look along each ray. All run on the host: sample positions carry no
//! gradient, and host loops beat generic tensor gathers for this bookkeeping.
//!
//! Every sampler returns [`RaySamples`]: a ragged batch of intervals [t_start, t_end] along each
//! ray, with the point `t` inside the interval where the field is evaluated. Compositing uses
//! the interval lengths, so a partition of [near, far] integrates a constant density exactly.

pub mod marching;
pub mod pdf;
pub mod stratified;

use std::sync::Arc;

use crate::composite::RayLayout;
use crate::rays::Rays;

pub use marching::{MarchConfig, march};
pub use pdf::sample_pdf;
pub use stratified::{Spacing, stratified};

/// Intervals along a batch of rays: ray r owns samples `offsets[r]..offsets[r + 1]`, sorted by t.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RaySamples {
    pub offsets: Vec<u32>,
    pub t_start: Vec<f32>,
    pub t_end: Vec<f32>,
    /// Evaluation point of each interval, within [t_start, t_end].
    pub t: Vec<f32>,
}

impl RaySamples {
    pub fn with_rays(num_rays: usize) -> Self {
        let mut offsets = Vec::with_capacity(num_rays + 1);
        offsets.push(0);
        RaySamples {
            offsets,
            ..Default::default()
        }
    }

    pub fn num_rays(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub fn num_samples(&self) -> usize {
        self.t.len()
    }

    pub fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.offsets[r] as usize..self.offsets[r + 1] as usize
    }

    /// Appends one interval to the ray being built.
    pub fn push(&mut self, t_start: f32, t_end: f32, t: f32) {
        self.t_start.push(t_start);
        self.t_end.push(t_end);
        self.t.push(t);
    }

    /// Closes the ray being built.
    pub fn finish_ray(&mut self) {
        self.offsets.push(self.t.len() as u32);
    }

    /// Ray index of every sample.
    pub fn ray_indices(&self) -> Vec<u32> {
        let mut out = Vec::with_capacity(self.num_samples());
        for r in 0..self.num_rays() {
            out.extend(std::iter::repeat_n(r as u32, self.range(r).len()));
        }
        out
    }

    /// Sample positions `o + t·d`, `[S, 3]`.
    pub fn positions(&self, rays: &Rays) -> Vec<f32> {
        let mut out = Vec::with_capacity(3 * self.num_samples());
        for r in 0..self.num_rays() {
            let (o, d) = (rays.origin(r), rays.direction(r));
            for s in self.range(r) {
                let t = self.t[s];
                out.extend([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
            }
        }
        out
    }

    /// The rays of `other` after this batch's (samples drawn group by group, e.g. each group of
    /// rays marched through its own occupancy grid).
    pub fn append(&mut self, other: &RaySamples) {
        let base = self.num_samples() as u32;
        self.offsets
            .extend(other.offsets.iter().skip(1).map(|o| base + o));
        self.t_start.extend_from_slice(&other.t_start);
        self.t_end.extend_from_slice(&other.t_end);
        self.t.extend_from_slice(&other.t);
    }

    /// Per-sample copies of a per-ray scalar (e.g. each ray's time), `[S]`.
    pub fn per_sample(&self, per_ray: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.num_samples());
        for (r, &v) in per_ray.iter().enumerate().take(self.num_rays()) {
            out.extend(std::iter::repeat_n(v, self.range(r).len()));
        }
        out
    }

    /// Per-sample copies of a per-ray `[R, 3]` quantity (e.g. view directions), `[S, 3]`.
    pub fn per_sample3(&self, per_ray: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(3 * self.num_samples());
        for r in 0..self.num_rays() {
            for _ in self.range(r) {
                out.extend_from_slice(&per_ray[3 * r..3 * r + 3]);
            }
        }
        out
    }

    /// The compositing layout: interval lengths turned into distances (× |d|). With
    /// `open_far`, each ray's last interval extends to infinity in effect (length 1e10·|d|),
    /// so whatever light is left is absorbed there (nerf-pytorch's convention for real scenes).
    pub fn layout(&self, rays: &Rays, open_far: bool) -> RayLayout {
        let mut deltas = Vec::with_capacity(self.num_samples());
        for r in 0..self.num_rays() {
            let d = rays.direction(r);
            let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let range = self.range(r);
            let last = range.end.wrapping_sub(1);
            for s in range {
                let len = if open_far && s == last {
                    1e10
                } else {
                    (self.t_end[s] - self.t_start[s]).max(0.0)
                };
                deltas.push(len * norm);
            }
        }
        RayLayout {
            offsets: Arc::new(self.offsets.clone()),
            deltas: Arc::new(deltas),
        }
    }

    /// Keeps the samples whose flag is set (e.g. after early termination or alpha culling).
    pub fn filter(&self, keep: &[bool]) -> RaySamples {
        let mut out = RaySamples::with_rays(self.num_rays());
        for r in 0..self.num_rays() {
            for s in self.range(r) {
                if keep[s] {
                    out.push(self.t_start[s], self.t_end[s], self.t[s]);
                }
            }
            out.finish_ray();
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn no_jitter() -> Option<&'static mut rand::rngs::StdRng> {
        None
    }

    /// Sampling two groups of rays apart and appending equals sampling them together.
    #[test]
    fn appended_groups_equal_one_batch() {
        let (near, far) = ([0.5f32, 1.0, 2.0, 0.0, 3.0], [4.0f32, 1.0, 6.0, 2.5, 3.5]);
        let whole = stratified(&near, &far, 7, Spacing::Depth, no_jitter());
        let mut parts = stratified(&near[..2], &far[..2], 7, Spacing::Depth, no_jitter());
        parts.append(&stratified(&near[2..], &far[2..], 7, Spacing::Depth, no_jitter()));
        assert_eq!(parts, whole);
        // One value per ray spread over its samples: ray r's samples carry r.
        let per_ray: Vec<f32> = (0..5).map(|r| r as f32).collect();
        let spread = parts.per_sample(&per_ray);
        let expected: Vec<f32> = parts.ray_indices().iter().map(|&r| r as f32).collect();
        assert_eq!(spread, expected);
    }
}
