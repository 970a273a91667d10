//! Normalised device coordinates for forward-facing scenes (NeRF's LLFF setup).
//!
//! The near plane sits at world depth `near` (z = -near); the NDC ray parameter t in [0, 1)
//! covers world depths from `near` to infinity, uniformly in disparity (t = 1 - near/|z|).

/// The projection that defines the NDC space: one shared pinhole camera, centred principal point.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ndc {
    pub fx: f64,
    pub fy: f64,
    pub width: f64,
    pub height: f64,
    pub near: f64,
}

impl Ndc {
    fn sx(&self) -> f64 {
        2.0 * self.fx / self.width
    }

    fn sy(&self) -> f64 {
        2.0 * self.fy / self.height
    }

    /// Maps a world ray to its NDC ray. The origin is first moved onto the near plane.
    pub fn ray(&self, o: [f64; 3], d: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let t_n = -(self.near + o[2]) / d[2];
        let o = [o[0] + t_n * d[0], o[1] + t_n * d[1], o[2] + t_n * d[2]];
        let o_ndc = [
            -self.sx() * o[0] / o[2],
            -self.sy() * o[1] / o[2],
            1.0 + 2.0 * self.near / o[2],
        ];
        let d_ndc = [
            -self.sx() * (d[0] / d[2] - o[0] / o[2]),
            -self.sy() * (d[1] / d[2] - o[1] / o[2]),
            -2.0 * self.near / o[2],
        ];
        (o_ndc, d_ndc)
    }

    /// Converts a batch of world rays (structure of arrays) to NDC rays in place.
    pub fn rays(&self, rays: &mut crate::rays::Rays) {
        for i in 0..rays.len() {
            let o = rays.origin(i).map(f64::from);
            let d = rays.direction(i).map(f64::from);
            let (o2, d2) = self.ray(o, d);
            for a in 0..3 {
                rays.origins[3 * i + a] = o2[a] as f32;
                rays.directions[3 * i + a] = d2[a] as f32;
            }
        }
    }

    /// World point (z < 0) to NDC.
    pub fn from_world(&self, p: [f64; 3]) -> [f64; 3] {
        [
            -self.sx() * p[0] / p[2],
            -self.sy() * p[1] / p[2],
            1.0 + 2.0 * self.near / p[2],
        ]
    }

    /// NDC point to world. `z_ndc` is clamped to [-1, 0.99] first, because the map diverges at
    /// z_ndc = 1 (NSFF's flowed points can reach it).
    pub fn to_world(&self, p: [f64; 3]) -> [f64; 3] {
        let zn = p[2].clamp(-1.0, 0.99);
        let z = 2.0 * self.near / (zn - 1.0);
        [-p[0] * z / self.sx(), -p[1] * z / self.sy(), z]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ndc_ray_passes_through_the_ndc_image_of_world_points() {
        let ndc = Ndc {
            fx: 400.0,
            fy: 420.0,
            width: 504.0,
            height: 378.0,
            near: 1.0,
        };
        let (o, d) = ([0.1, -0.2, 0.3], [0.2, 0.1, -1.0]);
        let (on, dn) = ndc.ray(o, d);
        assert!(
            (on[2] + 1.0).abs() < 1e-12,
            "origin on the near plane: z_ndc = -1"
        );
        for s in [1.5, 3.0, 10.0] {
            let p = [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]];
            let q = ndc.from_world(p);
            // t such that z matches, then x, y must match too (NDC rays are straight lines).
            let t = (q[2] - on[2]) / dn[2];
            assert!((on[0] + t * dn[0] - q[0]).abs() < 1e-9);
            assert!((on[1] + t * dn[1] - q[1]).abs() < 1e-9);
            // t = 1 - near/|z|
            assert!((t - (1.0 - 1.0 / p[2].abs())).abs() < 1e-9);
            let back = ndc.to_world(q);
            for a in 0..3 {
                assert!((back[a] - p[a]).abs() < 1e-9);
            }
        }
    }
}
