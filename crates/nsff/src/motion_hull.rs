//! The motion hull: the space each training camera saw move at its own time. A point at time t
//! that the training camera next to t sees outside its motion mask is still (or hidden), so the
//! dynamic field has no business drawing it; off the camera path that is where its fog lands
//! over still matter (BENCHMARKS.md §6, fifty-third session).

use nerf_data::Camera;

/// Per training frame, its camera, motion mask and normalised time.
#[derive(Clone, PartialEq)]
pub struct MotionHull {
    cameras: Vec<Camera>,
    /// `[H*W]` row-major per frame, true inside the mask, at the camera's resolution.
    masks: Vec<Vec<bool>>,
    /// Increasing.
    times: Vec<f32>,
    /// Per frame `[H*W]`, the depth of the frame's rendered surface, and the margin behind it
    /// the hull reaches: matter behind a training view's surface it never saw move.
    surface: Option<(Vec<Vec<f32>>, f32)>,
}

impl std::fmt::Debug for MotionHull {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MotionHull({} frames)", self.times.len())
    }
}

/// Times this close count as the frame's own.
const SAME_TIME: f32 = 1e-6;

impl MotionHull {
    /// `cameras`, `masks` and increasing `times` per training frame; `None` when they disagree
    /// in count, or a mask in size with its camera.
    pub fn new(cameras: Vec<Camera>, masks: Vec<Vec<bool>>, times: Vec<f32>) -> Option<Self> {
        let sizes_agree = masks
            .iter()
            .zip(&cameras)
            .all(|(m, c)| m.len() == c.intrinsics.num_pixels());
        (cameras.len() == masks.len() && masks.len() == times.len() && !times.is_empty() && sizes_agree)
            .then_some(MotionHull {
                cameras,
                masks,
                times,
                surface: None,
            })
    }

    /// The hull cut `margin` behind each frame's surface depth `depths` (per frame `[H*W]`,
    /// camera depth; infinite where no surface); `None` when a map's size disagrees.
    pub fn behind_surface_cut(mut self, depths: Vec<Vec<f32>>, margin: f32) -> Option<Self> {
        let agree = depths.len() == self.masks.len()
            && depths.iter().zip(&self.masks).all(|(d, m)| d.len() == m.len());
        agree.then(|| {
            self.surface = Some((depths, margin));
            self
        })
    }

    /// The frames whose masks speak for time `t`: the frame at `t`, else the two around it
    /// (one at either end of the video).
    fn frames_at(&self, t: f32) -> impl Iterator<Item = usize> {
        let i = self.times.partition_point(|&s| s < t - SAME_TIME);
        let last = self.times.len() - 1;
        let at = i.min(last);
        let own = (self.times[at] - t).abs() <= SAME_TIME;
        let before = (!own && i > 0).then(|| i - 1);
        let after = (own || i <= last).then_some(at);
        before.into_iter().chain(after)
    }

    /// Whether world point `x` at normalised time `t` falls inside the motion mask of a frame
    /// next to `t` (projected through that frame's camera; behind it or outside its image: no).
    pub fn contains(&self, x: [f32; 3], t: f32) -> bool {
        let p = [f64::from(x[0]), f64::from(x[1]), f64::from(x[2])];
        self.frames_at(t).any(|k| {
            let (cam, mask) = (&self.cameras[k], &self.masks[k]);
            let Some((u, v, depth)) = cam.project(p) else {
                return false;
            };
            let (w, h) = (cam.intrinsics.width as f64, cam.intrinsics.height as f64);
            if !(0.0..w).contains(&u) || !(0.0..h).contains(&v) {
                return false;
            }
            let pixel = v as usize * w as usize + u as usize;
            let in_front = self
                .surface
                .as_ref()
                .is_none_or(|(d, margin)| depth as f32 <= d[k][pixel] + margin);
            mask[pixel] && in_front
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_data::camera::{Intrinsics, Pose};

    /// A 4×4 camera with focal 4 at (`eye_x`, 0, 4), looking down −z.
    fn camera(eye_x: f64) -> Camera {
        let pose = Pose::look_at([eye_x, 0.0, 4.0], [eye_x, 0.0, 0.0], [0.0, 1.0, 0.0]);
        Camera::new(Intrinsics::centered(4.0, 4, 4), pose)
    }

    /// Mask of a 4×4 image with the one pixel (col, row) set.
    fn one_pixel(col: usize, row: usize) -> Vec<bool> {
        let mut m = vec![false; 16];
        m[row * 4 + col] = true;
        m
    }

    #[test]
    fn a_point_is_inside_where_its_frame_saw_motion() {
        let cams = vec![camera(0.0), camera(0.0), camera(0.0)];
        // Frame 0 marks pixel (2, 2), frame 1 pixel (0, 0), frame 2 nothing.
        let masks = vec![one_pixel(2, 2), one_pixel(0, 0), vec![false; 16]];
        let hull = MotionHull::new(cams, masks, vec![0.0, 0.5, 1.0]).unwrap();
        // Projections by hand: focal 4 on a 4-pixel image centred at (2, 2); the origin (depth 4)
        // lands at (2, 2); (−1.5, 1.5, 0) at (2 − 1.5, 2 − 1.5) = (0.5, 0.5).
        let (centre, corner) = ([0.1, -0.1, 0.0], [-1.5, 1.5, 0.0]);
        let c = camera(0.0);
        let (u, v, d) = c.project([0.1, -0.1, 0.0]).unwrap();
        assert!((u - 2.1).abs() < 1e-9 && (v - 2.1).abs() < 1e-9 && (d - 4.0).abs() < 1e-9);
        assert!(hull.contains(centre, 0.0) && !hull.contains(corner, 0.0));
        assert!(!hull.contains(centre, 0.5) && hull.contains(corner, 0.5));
        assert!(!hull.contains(centre, 1.0) && !hull.contains(corner, 1.0));
        // Between frames 0 and 1 both masks speak; between 1 and 2, frame 1's only.
        assert!(hull.contains(centre, 0.25) && hull.contains(corner, 0.25));
        assert!(!hull.contains(centre, 0.75) && hull.contains(corner, 0.75));
        // Behind the camera, or outside its image: not inside.
        assert!(!hull.contains([0.1, -0.1, 5.0], 0.0));
        assert!(!hull.contains([-9.0, 0.0, 0.0], 0.5));
    }

    #[test]
    fn a_surface_cut_leaves_out_what_lies_behind_the_frame_s_surface() {
        let masks = vec![one_pixel(2, 2)];
        let hull = MotionHull::new(vec![camera(0.0)], masks, vec![0.0]).unwrap();
        // The surface at pixel (2, 2) is 3.5 from the camera (which is at z = 4).
        let mut depth = vec![f32::INFINITY; 16];
        depth[2 * 4 + 2] = 3.5;
        let cut = hull
            .clone()
            .behind_surface_cut(vec![depth.clone()], 0.25)
            .unwrap();
        // Camera depths 3.6 (in the margin), 4.0 (behind it) and 3.0 (in front).
        for (z, inside) in [(0.4, true), (0.0, false), (1.0, true)] {
            assert!(hull.contains([0.1, -0.1, z], 0.0));
            assert_eq!(cut.contains([0.1, -0.1, z], 0.0), inside, "z {z}");
        }
        assert!(
            hull.behind_surface_cut(vec![depth[..15].to_vec()], 0.25)
                .is_none()
        );
    }

    #[test]
    fn the_frames_at_a_time_are_its_own_or_its_two_neighbours() {
        let hull = MotionHull::new(
            vec![camera(0.0); 3],
            vec![vec![false; 16]; 3],
            vec![0.0, 0.5, 1.0],
        )
        .unwrap();
        let at = |t| hull.frames_at(t).collect::<Vec<_>>();
        assert_eq!(at(0.0), vec![0]);
        assert_eq!(at(0.5), vec![1]);
        assert_eq!(at(1.0), vec![2]);
        assert_eq!(at(0.3), vec![0, 1]);
        assert_eq!(at(0.9), vec![1, 2]);
        // Outside the video's times: the end frame.
        assert_eq!(at(-0.2), vec![0]);
        assert_eq!(at(1.2), vec![2]);
    }

    #[test]
    fn frames_that_disagree_make_no_hull() {
        let cams = vec![camera(0.0); 2];
        assert!(MotionHull::new(cams.clone(), vec![vec![false; 16]], vec![0.0, 1.0]).is_none());
        assert!(MotionHull::new(cams.clone(), vec![vec![false; 15]; 2], vec![0.0, 1.0]).is_none());
        assert!(MotionHull::new(vec![], vec![], vec![]).is_none());
    }
}
