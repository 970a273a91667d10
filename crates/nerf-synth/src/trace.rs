//! Ray tracing of a [`Scene`] at one instant: images, depth, object ids and optical flow.

use rayon::prelude::*;

use super::scene::{Object, Scene};
use nerf_data::camera::Camera;
use nerf_data::image::Image;
use nerf_data::math::{self, Mat3, Vec3};

/// Rays start this far along their parameter, so a camera never hits itself.
const T_MIN: f64 = 1e-9;

/// One rendered view.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOutput {
    /// Straight (unassociated) RGBA in [0, 1]: colour = mean over the sub-pixel rays that hit,
    /// alpha = the fraction that hit. Pixels with no hit carry the scene background colour.
    pub rgba: Image,
    /// `[H*W]` camera depth (along −z) of the pixel-centre ray's hit, 0 where it hits nothing.
    pub depth: Vec<f32>,
    /// `[H*W]` index into [`Scene::objects`] hit by the pixel-centre ray, −1 for background.
    pub object_id: Vec<i32>,
}

/// The nearest surface along a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    /// Ray parameter: camera depth for camera rays (direction with camera z = −1).
    pub t: f64,
    pub object: usize,
    pub point: Vec3,
    /// The hit point in the object's local frame (moves with the object).
    pub local_point: Vec3,
    /// Outward unit normal in world space (for flat shapes: their local +z).
    pub normal: Vec3,
}

/// The objects posed at one time, so per-ray work is only local transforms and intersections.
struct Snapshot<'a> {
    objects: &'a [Object],
    /// Per object: local → world linear map, its inverse and the centre.
    poses: Vec<(Mat3, Mat3, Vec3)>,
    light_dir: Vec3,
}

impl<'a> Snapshot<'a> {
    fn new(scene: &'a Scene, time: f64) -> Self {
        let poses = scene.objects.iter().map(|o| o.transform_at(time)).collect();
        Snapshot {
            objects: &scene.objects,
            poses,
            light_dir: math::normalize(scene.light.direction),
        }
    }

    fn trace(&self, origin: Vec3, dir: Vec3) -> Option<RayHit> {
        let mut best: Option<(f64, usize, Vec3)> = None;
        // An affine map keeps the ray parameter: the local hit's t is the world hit's t.
        for (k, (obj, (_, inv, c))) in self.objects.iter().zip(&self.poses).enumerate() {
            let o = math::mat_vec(inv, math::sub(origin, *c));
            let d = math::mat_vec(inv, dir);
            if let Some((t, n)) = obj.shape.intersect(o, d, T_MIN)
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, k, n));
            }
        }
        let (t, object, n_local) = best?;
        let (_, inv, c) = &self.poses[object];
        let point = math::add(origin, math::scale(dir, t));
        Some(RayHit {
            t,
            object,
            point,
            local_point: math::mat_vec(inv, math::sub(point, *c)),
            normal: self.normal(object, inv, n_local),
        })
    }

    /// Normals map by the inverse transpose: the rotation itself for rigid objects (kept
    /// unnormalised so their shading stays bit-identical), renormalised when they deform.
    fn normal(&self, object: usize, inv: &Mat3, n_local: Vec3) -> Vec3 {
        let n = math::mat_vec(&math::transpose(inv), n_local);
        if self.objects[object].motion.is_rigid() {
            n
        } else {
            math::normalize(n)
        }
    }

    /// Lambertian colour of a hit seen along `dir`. Flat shapes are lit on the side facing the
    /// viewer; solids are never seen from inside, so flipping only affects the flat ones.
    fn shade(&self, scene: &Scene, hit: &RayHit, dir: Vec3) -> Vec3 {
        let n = if math::dot(hit.normal, dir) > 0.0 {
            math::scale(hit.normal, -1.0)
        } else {
            hit.normal
        };
        let l = &scene.light;
        let lit = l.ambient + l.diffuse * math::dot(n, self.light_dir).max(0.0);
        let albedo = self.objects[hit.object].texture.color(hit.local_point);
        albedo.map(|c| (c * lit).clamp(0.0, 1.0))
    }
}

impl Scene {
    /// Nearest hit of the ray `origin + t·direction` (t > 0) at time τ.
    pub fn intersect(&self, origin: Vec3, direction: Vec3, time: f64) -> Option<RayHit> {
        Snapshot::new(self, time).trace(origin, direction)
    }

    /// Renders `camera` at time τ. Colour is anti-aliased with the scene's n×n stratified
    /// sub-pixel rays; depth and object id come from the single pixel-centre ray, so they are
    /// exact for that ray (what `rays::pixel_rays` generates).
    pub fn render(&self, camera: &Camera, time: f64) -> RenderOutput {
        let snap = Snapshot::new(self, time);
        let (w, h) = (
            camera.intrinsics.width as usize,
            camera.intrinsics.height as usize,
        );
        let n = self.samples_per_axis.max(1) as usize;
        let origin = camera.pose.translation;
        let rows: Vec<(Vec<f32>, Vec<f32>, Vec<i32>)> = (0..h)
            .into_par_iter()
            .map(|j| {
                let mut rgba = Vec::with_capacity(4 * w);
                let mut depth = Vec::with_capacity(w);
                let mut ids = Vec::with_capacity(w);
                for i in 0..w {
                    let centre = snap.trace(origin, camera.pixel_direction(i as u32, j as u32));
                    depth.push(centre.map_or(0.0, |hit| hit.t as f32));
                    ids.push(centre.map_or(-1, |hit| hit.object as i32));
                    let mut sum = [0.0f64; 3];
                    let mut hits = 0usize;
                    for sy in 0..n {
                        for sx in 0..n {
                            let u = i as f64 + (sx as f64 + 0.5) / n as f64;
                            let v = j as f64 + (sy as f64 + 0.5) / n as f64;
                            let dir = camera.direction(u, v);
                            if let Some(hit) = snap.trace(origin, dir) {
                                let c = snap.shade(self, &hit, dir);
                                sum = math::add(sum, c);
                                hits += 1;
                            }
                        }
                    }
                    let rgb = if hits > 0 {
                        math::scale(sum, 1.0 / hits as f64)
                    } else {
                        self.background
                    };
                    rgba.extend(rgb.map(|c| c as f32));
                    rgba.push(hits as f32 / (n * n) as f32);
                }
                (rgba, depth, ids)
            })
            .collect();
        let mut out = RenderOutput {
            rgba: Image::new(w as u32, h as u32, 4),
            depth: Vec::with_capacity(w * h),
            object_id: Vec::with_capacity(w * h),
        };
        out.rgba.data.clear();
        for (rgba, depth, ids) in rows {
            out.rgba.data.extend(rgba);
            out.depth.extend(depth);
            out.object_id.extend(ids);
        }
        out
    }

    /// Ground-truth optical flow from `cam_a` at time `t_a` to `cam_b` at `t_b`, at the pixel
    /// centres of `cam_a`: `([H*W*2] (dx, dy) in pixels, [H*W] mask)`.
    ///
    /// The surface point seen through each pixel is carried with its object to `t_b` and
    /// projected into `cam_b`. The mask is 1 only where that point lands inside `cam_b`'s image
    /// and is what `cam_b` sees there (a ray traced back hits the same object at the same
    /// place), so occluded, out-of-frame and background pixels get 0. Flow is still filled in
    /// for occluded and out-of-frame points in front of `cam_b`; elsewhere it is 0.
    pub fn optical_flow(&self, cam_a: &Camera, t_a: f64, cam_b: &Camera, t_b: f64) -> (Vec<f32>, Vec<f32>) {
        let (snap_a, snap_b) = (Snapshot::new(self, t_a), Snapshot::new(self, t_b));
        let (w, h) = (cam_a.intrinsics.width as usize, cam_a.intrinsics.height as usize);
        let (wb, hb) = (cam_b.intrinsics.width as f64, cam_b.intrinsics.height as f64);
        let rows: Vec<(Vec<f32>, Vec<f32>)> = (0..h)
            .into_par_iter()
            .map(|j| {
                let mut flow = Vec::with_capacity(2 * w);
                let mut mask = Vec::with_capacity(w);
                for i in 0..w {
                    let (f, m) = (|| {
                        let hit = snap_a
                            .trace(cam_a.pose.translation, cam_a.pixel_direction(i as u32, j as u32))?;
                        let (r, _, c) = &snap_b.poses[hit.object];
                        let moved = math::add(math::mat_vec(r, hit.local_point), *c);
                        let (u, v, depth) = cam_b.project(moved)?;
                        let f = [u - (i as f64 + 0.5), v - (j as f64 + 0.5)];
                        let in_frame = (0.0..wb).contains(&u) && (0.0..hb).contains(&v);
                        let visible = in_frame
                            && snap_b
                                .trace(cam_b.pose.translation, cam_b.direction(u, v))
                                .is_some_and(|back| {
                                    back.object == hit.object
                                        && math::norm(math::sub(back.point, moved)) <= 1e-6 * (1.0 + depth)
                                });
                        Some((f, if visible { 1.0 } else { 0.0 }))
                    })()
                    .unwrap_or(([0.0; 2], 0.0));
                    flow.extend(f.map(|v| v as f32));
                    mask.push(m);
                }
                (flow, mask)
            })
            .collect();
        let mut flow = Vec::with_capacity(2 * w * h);
        let mut mask = Vec::with_capacity(w * h);
        for (f, m) in rows {
            flow.extend(f);
            mask.extend(m);
        }
        (flow, mask)
    }
}
