//! Pinhole cameras and the axis conventions of the formats we read.
//!
//! Conventions used everywhere in this project:
//! - A pose is camera-to-world (c2w) with **OpenGL camera axes**: x right, y up, z back, so the
//!   camera looks along -z. Parsers convert OpenCV/COLMAP and LLFF-stored poses on load.
//! - Pixel (i, j) is column i, row j. It covers [i, i+1) x [j, j+1) in continuous image
//!   coordinates, so its **centre is (i + 0.5, j + 0.5)**. The principal point (cx, cy) is given in
//!   the same continuous coordinates, so a centred camera has cx = W/2, cy = H/2 (COLMAP's
//!   convention; nerfstudio and nerfacc sample pixel centres the same way).
//! - Ray directions have camera-space z = -1, so the ray parameter t is the camera-space **depth**
//!   and near/far bounds are depths (the nerf-pytorch convention). Step lengths are multiplied by
//!   |d| where distances are needed.

use crate::math::{self, Mat3, Vec3};

/// Pinhole intrinsics in pixels.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// A centred camera with square pixels.
    pub fn centered(focal: f64, width: u32, height: u32) -> Self {
        Intrinsics {
            fx: focal,
            fy: focal,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
            width,
            height,
        }
    }

    /// Focal length from a horizontal field of view (Blender's `camera_angle_x`).
    pub fn from_fov_x(fov_x: f64, width: u32, height: u32) -> Self {
        Self::centered(0.5 * width as f64 / (0.5 * fov_x).tan(), width, height)
    }

    /// The intrinsics of the image downscaled by `factor` (sizes rounded down, as area resizing does).
    pub fn downscaled(&self, factor: u32) -> Self {
        let f = factor as f64;
        Intrinsics {
            fx: self.fx / f,
            fy: self.fy / f,
            cx: self.cx / f,
            cy: self.cy / f,
            width: self.width / factor,
            height: self.height / factor,
        }
    }

    /// The intrinsics after resizing the image to `width` x `height` (any aspect change allowed).
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Intrinsics {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
        }
    }

    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Problems that make rays meaningless: non-finite or non-positive focal, empty image.
    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !v.is_finite() || v <= 0.0 {
                return Err(format!("focal length {name} = {v} must be finite and positive"));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(format!("principal point {name} = {v} is not finite"));
            }
        }
        if self.width == 0 || self.height == 0 {
            return Err(format!("image size {}x{} is empty", self.width, self.height));
        }
        Ok(())
    }
}

/// Camera-to-world rigid transform, OpenGL camera axes.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pose {
    /// Columns are the camera's right, up and back axes in world coordinates.
    pub rotation: Mat3,
    /// Camera centre in world coordinates.
    pub translation: Vec3,
}

/// Axis conventions of stored camera-to-world matrices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AxisConvention {
    /// x right, y up, z back (Blender, NeRF, tiny npz). Our internal convention.
    OpenGl,
    /// x right, y down, z forward (COLMAP, OpenCV).
    OpenCv,
    /// Columns [down, right, back] as stored in LLFF's `poses_bounds.npy`.
    LlffStored,
}

impl Pose {
    pub fn identity() -> Self {
        Pose {
            rotation: math::identity(),
            translation: [0.0; 3],
        }
    }

    /// A pose from a camera-to-world 3x4 (or the top of a 4x4) in the given convention.
    pub fn from_c2w(m: [[f64; 4]; 3], convention: AxisConvention) -> Self {
        let col = |c: usize| [m[0][c], m[1][c], m[2][c]];
        let (x, y, z) = match convention {
            AxisConvention::OpenGl => (col(0), col(1), col(2)),
            AxisConvention::OpenCv => (col(0), math::scale(col(1), -1.0), math::scale(col(2), -1.0)),
            AxisConvention::LlffStored => (col(1), math::scale(col(0), -1.0), col(2)),
        };
        Pose {
            rotation: math::from_columns(x, y, z),
            translation: col(3),
        }
    }

    /// The 3x4 camera-to-world matrix in the given convention (inverse of [`Pose::from_c2w`]).
    pub fn to_c2w(&self, convention: AxisConvention) -> [[f64; 4]; 3] {
        let (x, y, z) = (
            math::column(&self.rotation, 0),
            math::column(&self.rotation, 1),
            math::column(&self.rotation, 2),
        );
        let (a, b, c) = match convention {
            AxisConvention::OpenGl => (x, y, z),
            AxisConvention::OpenCv => (x, math::scale(y, -1.0), math::scale(z, -1.0)),
            AxisConvention::LlffStored => (math::scale(y, -1.0), x, z),
        };
        let t = self.translation;
        [
            [a[0], b[0], c[0], t[0]],
            [a[1], b[1], c[1], t[1]],
            [a[2], b[2], c[2], t[2]],
        ]
    }

    /// A camera at `eye` looking at `target`, with `up` roughly up in the image.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3) -> Self {
        let back = math::normalize(math::sub(eye, target));
        let right = math::normalize(math::cross(up, back));
        let true_up = math::cross(back, right);
        Pose {
            rotation: math::from_columns(right, true_up, back),
            translation: eye,
        }
    }

    pub fn is_finite(&self) -> bool {
        self.rotation
            .iter()
            .flatten()
            .chain(self.translation.iter())
            .all(|v| v.is_finite())
    }

    /// Camera-space point to world.
    pub fn to_world(&self, p: Vec3) -> Vec3 {
        math::add(math::mat_vec(&self.rotation, p), self.translation)
    }

    /// World point to camera space (inverse rigid transform).
    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        math::mat_vec(&math::transpose(&self.rotation), math::sub(p, self.translation))
    }

    /// The pose a fraction `r` of the way from `self` to `other`: centres interpolated linearly,
    /// rotations along the shortest arc (slerp).
    pub fn lerp(&self, other: &Pose, r: f64) -> Pose {
        let q = math::slerp(
            math::mat_to_quat(&self.rotation),
            math::mat_to_quat(&other.rotation),
            r,
        );
        Pose {
            rotation: math::quat_to_mat(q),
            translation: math::add(
                math::scale(self.translation, 1.0 - r),
                math::scale(other.translation, r),
            ),
        }
    }

    /// `other` applied after `self`: the pose `a ∘ self` where `a` is given as a world transform.
    pub fn transformed(&self, rotation: &Mat3, translation: Vec3) -> Self {
        Pose {
            rotation: math::mat_mul(rotation, &self.rotation),
            translation: math::add(math::mat_vec(rotation, self.translation), translation),
        }
    }
}

/// A posed pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    pub pose: Pose,
}

impl Camera {
    pub fn new(intrinsics: Intrinsics, pose: Pose) -> Self {
        Camera { intrinsics, pose }
    }

    /// World-space direction (camera-space z = -1) through continuous image point (u, v).
    pub fn direction(&self, u: f64, v: f64) -> Vec3 {
        let k = &self.intrinsics;
        let d_cam = [(u - k.cx) / k.fx, -(v - k.cy) / k.fy, -1.0];
        math::mat_vec(&self.pose.rotation, d_cam)
    }

    /// Direction through the centre of pixel (column i, row j).
    pub fn pixel_direction(&self, i: u32, j: u32) -> Vec3 {
        self.direction(i as f64 + 0.5, j as f64 + 0.5)
    }

    /// Projects a world point to continuous image coordinates (u, v) and its camera depth.
    /// Returns `None` for points at or behind the camera plane.
    pub fn project(&self, p: Vec3) -> Option<(f64, f64, f64)> {
        let pc = self.pose.to_camera(p);
        let depth = -pc[2];
        if depth <= 0.0 {
            return None;
        }
        let k = &self.intrinsics;
        Some((k.cx + k.fx * pc[0] / depth, k.cy - k.fy * pc[1] / depth, depth))
    }

    pub fn downscaled(&self, factor: u32) -> Self {
        Camera {
            intrinsics: self.intrinsics.downscaled(factor),
            pose: self.pose,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conventions_round_trip() {
        let pose = Pose::look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        for conv in [
            AxisConvention::OpenGl,
            AxisConvention::OpenCv,
            AxisConvention::LlffStored,
        ] {
            let back = Pose::from_c2w(pose.to_c2w(conv), conv);
            for r in 0..3 {
                for c in 0..3 {
                    assert!((back.rotation[r][c] - pose.rotation[r][c]).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn principal_ray_hits_image_centre() {
        let cam = Camera::new(
            Intrinsics::centered(100.0, 64, 48),
            Pose::look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0]),
        );
        let (u, v, depth) = cam.project([0.0, 0.0, 0.0]).unwrap();
        assert!((u - 32.0).abs() < 1e-12 && (v - 24.0).abs() < 1e-12);
        assert!((depth - 4.0).abs() < 1e-12);
        // Up in the world is up in the image: smaller row index.
        let (_, v_up, _) = cam.project([0.0, 1.0, 0.0]).unwrap();
        assert!(v_up < 24.0);
    }

    #[test]
    fn lerp_interpolates_centre_linearly_and_rotation_along_the_arc() {
        let a = Pose::look_at([4.0, 0.0, 0.0], [0.0; 3], [0.0, 0.0, 1.0]);
        let b = Pose::look_at([0.0, 4.0, 2.0], [0.0, 0.0, 2.0], [0.0, 0.0, 1.0]);
        for (r, pose) in [(0.0, a), (1.0, b)] {
            let p = a.lerp(&b, r);
            for (x, y) in p.rotation.iter().flatten().zip(pose.rotation.iter().flatten()) {
                assert!((x - y).abs() < 1e-12, "endpoint r={r}");
            }
        }
        // Halfway: centre (2, 2, 1); both look horizontally, a along -x, b along -y, so the
        // halfway camera looks along -(1, 1, 0)/√2 (45° of the 90° turn about z).
        let m = a.lerp(&b, 0.5);
        assert!(math::norm(math::sub(m.translation, [2.0, 2.0, 1.0])) < 1e-12);
        let forward = math::scale(math::column(&m.rotation, 2), -1.0);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            math::norm(math::sub(forward, [-h, -h, 0.0])) < 1e-12,
            "{forward:?}"
        );
        let rtr = math::mat_mul(&math::transpose(&m.rotation), &m.rotation);
        for i in 0..3 {
            for j in 0..3 {
                assert!((rtr[i][j] - f64::from(u8::from(i == j))).abs() < 1e-12);
            }
        }
    }
}
