//! Procedural textures, evaluated in an object's local coordinates so the pattern moves with it.
//!
//! Flat colours make optical flow and NeRF fitting ill-posed (a uniform patch matches anywhere),
//! so every texture has sharp pattern edges or smooth gradients plus fine multiplicative noise.

use serde::{Deserialize, Serialize};

use nerf_data::math::{self, Vec3};

/// The large-scale pattern of a [`Texture`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Pattern {
    /// 3-D checkerboard of cubes with side `1 / cells_per_unit`, alternating the two colours.
    Checker { cells_per_unit: f64 },
    /// Parallel slabs across `direction` (about unit length), alternating the two colours.
    Stripes { direction: Vec3, stripes_per_unit: f64 },
    /// Smooth value noise blending the two colours.
    Noise { scale: f64 },
    /// Cycling hues along `frequency` (cycles per unit), warped by noise so no direction is flat;
    /// tinted a little towards the first colour.
    Rainbow { frequency: Vec3 },
}

/// A procedural albedo in [0, 1]³.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Texture {
    pub pattern: Pattern,
    pub colors: [Vec3; 2],
    /// Strength of the multiplicative detail noise in [0, 1): the albedo is scaled by a factor
    /// in [1 - detail, 1 + detail].
    pub detail: f64,
    /// Lattice cells per unit of the detail noise.
    pub detail_scale: f64,
    /// Added to the local point before evaluating, so pattern edges do not line up with faces.
    pub offset: Vec3,
    /// Decorrelates the noise of different objects.
    pub seed: u64,
}

impl Texture {
    /// A plain colour (no pattern, no noise).
    pub fn solid(color: Vec3) -> Self {
        Texture {
            pattern: Pattern::Checker { cells_per_unit: 0.0 },
            colors: [color, color],
            detail: 0.0,
            detail_scale: 1.0,
            offset: [0.0; 3],
            seed: 0,
        }
    }

    /// Albedo at the local point `p`.
    pub fn color(&self, p: Vec3) -> Vec3 {
        let p = math::add(p, self.offset);
        let [c0, c1] = self.colors;
        let base = match &self.pattern {
            Pattern::Checker { cells_per_unit } => {
                let parity: i64 = p.iter().map(|v| (v * cells_per_unit).floor() as i64).sum();
                if parity.rem_euclid(2) == 0 { c0 } else { c1 }
            }
            Pattern::Stripes {
                direction,
                stripes_per_unit,
            } => {
                let x = math::dot(*direction, p) * stripes_per_unit;
                if x - x.floor() < 0.5 { c0 } else { c1 }
            }
            Pattern::Noise { scale } => {
                let n = fbm(math::scale(p, *scale), self.seed ^ 0xA5A5_5A5A);
                lerp(c0, c1, smoothstep(0.3, 0.7, n))
            }
            Pattern::Rainbow { frequency } => {
                let warp = fbm(math::scale(p, 3.0), self.seed ^ 0x5EED);
                let phase = math::dot(*frequency, p) + 0.6 * warp;
                let hue = [0.0, 1.0 / 3.0, 2.0 / 3.0]
                    .map(|o| 0.5 + 0.45 * (std::f64::consts::TAU * (phase + o)).cos());
                lerp(hue, c0, 0.25)
            }
        };
        if self.detail == 0.0 {
            return base;
        }
        let n = fbm(math::scale(p, self.detail_scale), self.seed);
        let factor = 1.0 - self.detail + 2.0 * self.detail * n;
        base.map(|c| (c * factor).clamp(0.0, 1.0))
    }
}

fn lerp(a: Vec3, b: Vec3, w: f64) -> Vec3 {
    [0, 1, 2].map(|k| a[k] + (b[k] - a[k]) * w)
}

fn smoothstep(lo: f64, hi: f64, x: f64) -> f64 {
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// SplitMix64's finaliser: a cheap bijective mix with good avalanche, used for all hashing.
pub(super) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform value in [0, 1) attached to an integer lattice point.
fn lattice(ix: i64, iy: i64, iz: i64, seed: u64) -> f64 {
    let h = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (ix as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (iy as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ (iz as u64).wrapping_mul(0x27D4_EB2F_1656_67C5);
    (mix64(h) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Value noise: lattice values blended with smoothstep weights (C¹, values in [0, 1]).
fn value_noise(p: Vec3, seed: u64) -> f64 {
    let cell = p.map(f64::floor);
    let w = [0, 1, 2].map(|k| {
        let f = p[k] - cell[k];
        f * f * (3.0 - 2.0 * f)
    });
    let [x0, y0, z0] = cell.map(|v| v as i64);
    let mut acc = 0.0;
    for corner in 0..8i64 {
        let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
        let pick = |d: i64, wk: f64| if d == 1 { wk } else { 1.0 - wk };
        acc += pick(dx, w[0]) * pick(dy, w[1]) * pick(dz, w[2]) * lattice(x0 + dx, y0 + dy, z0 + dz, seed);
    }
    acc
}

/// Two octaves of value noise, in [0, 1].
fn fbm(p: Vec3, seed: u64) -> f64 {
    let fine = math::add(math::scale(p, 2.03), [17.1, 5.3, 11.7]);
    (value_noise(p, seed) + 0.5 * value_noise(fine, seed.wrapping_add(1))) / 1.5
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_bounded_and_continuous() {
        for k in 0..200 {
            let p = [k as f64 * 0.173 - 10.0, k as f64 * 0.071, -(k as f64) * 0.031];
            let n = fbm(p, 7);
            assert!((0.0..=1.0).contains(&n));
            let q = math::add(p, [1e-7, 0.0, 0.0]);
            assert!((fbm(q, 7) - n).abs() < 1e-5, "noise must be continuous");
        }
    }

    #[test]
    fn checker_alternates_between_neighbouring_cells() {
        let t = Texture {
            pattern: Pattern::Checker { cells_per_unit: 2.0 },
            colors: [[1.0; 3], [0.0; 3]],
            detail: 0.0,
            detail_scale: 1.0,
            offset: [0.0; 3],
            seed: 0,
        };
        assert_eq!(t.color([0.1, 0.1, 0.1]), [1.0; 3]);
        assert_eq!(t.color([0.6, 0.1, 0.1]), [0.0; 3]);
        assert_eq!(t.color([-0.1, 0.1, 0.1]), [0.0; 3]);
    }
}
