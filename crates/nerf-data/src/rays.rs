//! Ray generation (host side: no gradients flow through rays).
//!
//! Layout: structure of arrays, `origins` and `directions` hold `3 * len` f32 each, so a batch
//! turns into an `[N, 3]` tensor without reshuffling. Directions follow the camera convention of
//! [`crate::camera`]: camera-space z = -1, so t along a ray is depth.

use crate::camera::Camera;
use crate::math::Vec3;

/// A batch of rays, structure of arrays, `[N, 3]` each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rays {
    pub origins: Vec<f32>,
    pub directions: Vec<f32>,
}

impl Rays {
    pub fn with_capacity(n: usize) -> Self {
        Rays {
            origins: Vec::with_capacity(3 * n),
            directions: Vec::with_capacity(3 * n),
        }
    }

    pub fn len(&self) -> usize {
        self.origins.len() / 3
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    pub fn push(&mut self, origin: Vec3, direction: Vec3) {
        self.origins.extend(origin.map(|v| v as f32));
        self.directions.extend(direction.map(|v| v as f32));
    }

    pub fn origin(&self, i: usize) -> [f32; 3] {
        [
            self.origins[3 * i],
            self.origins[3 * i + 1],
            self.origins[3 * i + 2],
        ]
    }

    pub fn direction(&self, i: usize) -> [f32; 3] {
        [
            self.directions[3 * i],
            self.directions[3 * i + 1],
            self.directions[3 * i + 2],
        ]
    }

    /// Unit-length viewing directions, `[N, 3]` (what direction encodings consume).
    pub fn viewdirs(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.directions.len());
        for d in self.directions.chunks_exact(3) {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-20);
            out.extend([d[0] / n, d[1] / n, d[2] / n]);
        }
        out
    }

    /// Rays `range` as a new batch (used to render images chunk by chunk).
    pub fn slice(&self, range: std::ops::Range<usize>) -> Rays {
        Rays {
            origins: self.origins[3 * range.start..3 * range.end].to_vec(),
            directions: self.directions[3 * range.start..3 * range.end].to_vec(),
        }
    }

    pub fn extend(&mut self, other: &Rays) {
        self.origins.extend_from_slice(&other.origins);
        self.directions.extend_from_slice(&other.directions);
    }
}

/// One ray per pixel, row-major (pixel k is column k % W, row k / W), through pixel centres.
pub fn camera_rays(camera: &Camera) -> Rays {
    let k = &camera.intrinsics;
    pixel_rays(camera, 0..k.num_pixels() as u32)
}

/// Rays through the centres of the given row-major pixel indices.
pub fn pixel_rays(camera: &Camera, pixels: impl IntoIterator<Item = u32>) -> Rays {
    let w = camera.intrinsics.width;
    let pixels = pixels.into_iter();
    let mut rays = Rays::with_capacity(pixels.size_hint().0);
    for p in pixels {
        rays.push(camera.pose.translation, camera.pixel_direction(p % w, p / w));
    }
    rays
}

/// Intersection of rays with an axis-aligned box: per ray `(t_enter, t_exit)` in the ray's own
/// parameter (depth), or `None` when it misses. `t_enter` is clamped to 0 for origins inside.
pub fn intersect_aabb(
    origin: [f32; 3],
    direction: [f32; 3],
    lo: [f32; 3],
    hi: [f32; 3],
) -> Option<(f32, f32)> {
    let mut t0 = 0.0f32;
    let mut t1 = f32::INFINITY;
    for a in 0..3 {
        let inv = 1.0 / direction[a];
        // inv is ±inf for a zero component; then the slab test degenerates to an inside check.
        let (mut ta, mut tb) = ((lo[a] - origin[a]) * inv, (hi[a] - origin[a]) * inv);
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        if ta.is_nan() || tb.is_nan() {
            // 0 * inf: the ray runs inside the slab plane; inside iff the origin is within it.
            if origin[a] < lo[a] || origin[a] > hi[a] {
                return None;
            }
            continue;
        }
        t0 = t0.max(ta);
        t1 = t1.min(tb);
    }
    (t0 < t1).then_some((t0, t1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, Pose};

    #[test]
    fn ray_points_project_back_to_their_pixel() {
        let cam = Camera::new(
            Intrinsics {
                fx: 120.0,
                fy: 110.0,
                cx: 33.0,
                cy: 20.5,
                width: 64,
                height: 40,
            },
            Pose::look_at([0.5, -3.0, 2.0], [0.0; 3], [0.0, 0.0, 1.0]),
        );
        let rays = camera_rays(&cam);
        for k in [0usize, 17, 1000, 64 * 40 - 1] {
            let (o, d) = (rays.origin(k), rays.direction(k));
            let p = [0, 1, 2].map(|a| o[a] as f64 + 2.5 * d[a] as f64);
            let (u, v, depth) = cam.project(p).unwrap();
            assert!((u - ((k % 64) as f64 + 0.5)).abs() < 1e-4);
            assert!((v - ((k / 64) as f64 + 0.5)).abs() < 1e-4);
            assert!((depth - 2.5).abs() < 1e-5, "t is camera depth");
        }
    }

    #[test]
    fn aabb_hits_and_misses() {
        let (lo, hi) = ([-1.0; 3], [1.0; 3]);
        let (t0, t1) = intersect_aabb([0.0, 0.0, 5.0], [0.0, 0.0, -1.0], lo, hi).unwrap();
        assert_eq!((t0, t1), (4.0, 6.0));
        assert!(intersect_aabb([0.0, 3.0, 5.0], [0.0, 0.0, -1.0], lo, hi).is_none());
        // Grazing along a face plane counts as inside.
        assert!(intersect_aabb([0.0, 1.0, 5.0], [0.0, 0.0, -1.0], lo, hi).is_some());
    }
}
