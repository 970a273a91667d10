//! What kind of capture a time-stamped dataset is, decided from its poses alone.
//!
//! A *video* has neighbouring frames seen from nearby cameras, so optical flow between them,
//! the motion masks drawn from it and NSFF's flow and warp losses describe real motion. A
//! *jumping* camera (the D-NeRF benchmark: every frame from an unrelated viewpoint) makes all of
//! these noise; the time-conditioned field then has to carry the motion by itself.
//!
//! The measure is the view change between neighbouring frames in time order: the larger of the
//! rotation angle between the two cameras and the angle their centres' step subtends at the
//! scene's middle depth. Its median is robust to a few cuts in a video. Measured on the data we
//! have: generated videos (arcs, forward motion, hand-held) 0.5°–4.7°; the D-NeRF scenes and our
//! orbit captures 85°–101°. The threshold sits at the geometric middle, 4× from both.

use nerf_data::Camera;
use nerf_data::math;

/// Neighbouring frames whose median view change exceeds this are a jumping camera (degrees).
pub const JUMP_THRESHOLD_DEG: f64 = 20.0;

/// The kind of camera motion between neighbouring frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraMotion {
    /// A video: neighbouring frames from nearby viewpoints.
    Smooth,
    /// A new, unrelated viewpoint every frame (multi-view capture of a dynamic scene).
    Jumping,
}

/// The decision and the number it was made from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraPath {
    pub motion: CameraMotion,
    /// Median view change between neighbouring frames, degrees.
    pub median_step_deg: f64,
}

impl CameraPath {
    pub fn is_jumping(&self) -> bool {
        self.motion == CameraMotion::Jumping
    }

    /// One line for the training header.
    pub fn describe(&self) -> String {
        match self.motion {
            CameraMotion::Smooth => format!(
                "camera path: smooth video (median {:.1}° between neighbouring frames)",
                self.median_step_deg
            ),
            CameraMotion::Jumping => format!(
                "camera path: jumping (median {:.1}° between neighbouring frames): no optical flow, \
                 motion masks, flow or warp losses, or hard mining; the time-conditioned field \
                 carries the motion",
                self.median_step_deg
            ),
        }
    }
}

/// Classifies `cameras` (in time order); `scene_depth` is the content's typical distance from
/// the cameras (world units), which turns a centre step into an angle. Fewer than two cameras
/// count as a video.
pub fn classify(cameras: &[Camera], scene_depth: f64) -> CameraPath {
    let depth = scene_depth.max(1e-9);
    let mut steps: Vec<f64> = cameras
        .windows(2)
        .map(|pair| {
            let (a, b) = (&pair[0].pose, &pair[1].pose);
            let rotation = rotation_angle_deg(&math::mat_mul(&math::transpose(&a.rotation), &b.rotation));
            let shift = math::norm(math::sub(b.translation, a.translation)) / depth;
            rotation.max(shift.to_degrees())
        })
        .collect();
    let median = if steps.is_empty() {
        0.0
    } else {
        steps.sort_by(f64::total_cmp);
        let n = steps.len();
        if n % 2 == 1 {
            steps[n / 2]
        } else {
            0.5 * (steps[n / 2 - 1] + steps[n / 2])
        }
    };
    CameraPath {
        motion: if median > JUMP_THRESHOLD_DEG {
            CameraMotion::Jumping
        } else {
            CameraMotion::Smooth
        },
        median_step_deg: median,
    }
}

/// Angle of a rotation matrix, degrees (trace = 1 + 2 cos θ, clamped against rounding).
fn rotation_angle_deg(r: &math::Mat3) -> f64 {
    let trace = r[0][0] + r[1][1] + r[2][2];
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_data::camera::{Intrinsics, Pose};

    /// A camera at azimuth `az_deg` on a circle of radius 4 around the origin, looking at it.
    fn orbit(az_deg: f64) -> Camera {
        let a = az_deg.to_radians();
        let eye = [4.0 * a.cos(), 4.0 * a.sin(), 1.0];
        Camera::new(
            Intrinsics::centered(50.0, 64, 48),
            Pose::look_at(eye, [0.0; 3], [0.0, 0.0, 1.0]),
        )
    }

    #[test]
    fn rotation_angle_matches_a_known_turn() {
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let r = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        assert!((rotation_angle_deg(&r) - 30.0).abs() < 1e-9);
        assert_eq!(
            rotation_angle_deg(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            0.0
        );
    }

    #[test]
    fn a_slow_arc_is_a_video_and_random_viewpoints_jump() {
        let arc: Vec<Camera> = (0..24).map(|k| orbit(3.0 * k as f64)).collect();
        let path = classify(&arc, 4.0);
        assert_eq!(path.motion, CameraMotion::Smooth);
        // Turning 3° about the look-at point turns the camera by about 3° and moves its centre
        // along a chord of 4·√(1 + 1/16)·3° ≈ 0.216 units (3.1° at depth 4).
        assert!(
            (path.median_step_deg - 3.09).abs() < 0.1,
            "{}",
            path.median_step_deg
        );

        // Golden-angle azimuths: every neighbour is ~137.5° away.
        let jumping: Vec<Camera> = (0..24).map(|k| orbit(137.5 * k as f64)).collect();
        let path = classify(&jumping, 4.0);
        assert_eq!(path.motion, CameraMotion::Jumping);
        assert!(path.median_step_deg > 90.0, "{}", path.median_step_deg);
    }

    #[test]
    fn a_fixed_camera_and_a_single_frame_are_videos() {
        let still: Vec<Camera> = (0..5).map(|_| orbit(10.0)).collect();
        assert_eq!(classify(&still, 4.0).motion, CameraMotion::Smooth);
        assert_eq!(classify(&still[..1], 4.0).median_step_deg, 0.0);
    }
}
