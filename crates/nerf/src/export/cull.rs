//! Culling what no training camera sees: the field holds whatever it made up in space that no
//! view constrains (under a ground plane, corners of the box outside every image), and a level
//! set there is not the scene. A vertex counts as seen by a view when it projects into the image
//! and lies no further than a slack behind the view's rendered surface.

use super::ColoredMesh;

/// A training camera's rendered depth, for culling surfaces no training view sees.
pub struct DepthView {
    pub camera: nerf_data::Camera,
    /// Camera depth per pixel (row-major); infinite where the render is transparent.
    pub depth: Vec<f32>,
}

impl DepthView {
    /// From a render's opacity-weighted depth and opacity (pixel rays with camera z = −1, so the
    /// ray parameter is the camera depth).
    pub fn new(camera: nerf_data::Camera, depth: &[f32], opacity: &[f32]) -> Self {
        let depth = depth
            .iter()
            .zip(opacity)
            .map(|(d, a)| if *a > 0.5 { d / a } else { f32::INFINITY })
            .collect();
        DepthView { camera, depth }
    }

    /// Whether `p` is in this view's image and not behind its rendered surface by more than `slack`.
    fn sees(&self, p: [f32; 3], slack: f32) -> bool {
        let Some((u, v, d)) = self.camera.project(p.map(f64::from)) else {
            return false;
        };
        let k = &self.camera.intrinsics;
        if u < 0.0 || v < 0.0 || u >= k.width as f64 || v >= k.height as f64 {
            return false;
        }
        let pixel = v as usize * k.width as usize + u as usize;
        d as f32 <= self.depth[pixel] + slack
    }
}

/// Up to `max_views` training cameras, evenly spaced, scaled down to at most `max_width` pixels
/// wide: what culling renders.
pub fn culling_cameras(
    dataset: &nerf_data::Dataset,
    max_views: usize,
    max_width: u32,
) -> Vec<nerf_data::Camera> {
    let train = &dataset.train;
    let n = train.len().min(max_views.max(1));
    (0..n)
        .map(|k| {
            let cam = dataset.views[train[k * train.len() / n]].camera;
            cam.downscaled(cam.intrinsics.width.div_ceil(max_width.max(1)).max(1))
        })
        .collect()
}

/// Drops the faces with a vertex that no view sees (outside every image, or behind every
/// rendered surface by more than `slack`), then the vertices no face uses. What no training
/// camera sees (the space under a ground plane, corners of the box outside every view) holds
/// whatever the field made up there. Returns how many faces were dropped.
pub fn cull_unseen(m: &mut ColoredMesh, views: &[DepthView], slack: f32) -> usize {
    let seen: Vec<bool> = m
        .mesh
        .vertices
        .iter()
        .map(|&p| views.iter().any(|v| v.sees(p, slack)))
        .collect();
    let before = m.mesh.faces.len();
    m.mesh.faces.retain(|f| f.iter().all(|&i| seen[i as usize]));
    let mut used = vec![false; m.mesh.vertices.len()];
    m.mesh
        .faces
        .iter()
        .flatten()
        .for_each(|&i| used[i as usize] = true);
    let mut new_index = vec![u32::MAX; used.len()];
    let mut next = 0u32;
    for (i, u) in used.iter().enumerate() {
        if *u {
            new_index[i] = next;
            next += 1;
        }
    }
    keep_used(&mut m.mesh.vertices, &used);
    keep_used(&mut m.mesh.normals, &used);
    keep_used(&mut m.colors, &used);
    for f in &mut m.mesh.faces {
        *f = f.map(|i| new_index[i as usize]);
    }
    before - m.mesh.faces.len()
}

/// Keeps the items whose flag in `used` is set.
fn keep_used<T>(items: &mut Vec<T>, used: &[bool]) {
    let mut k = 0;
    items.retain(|_| {
        k += 1;
        used[k - 1]
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::marching;
    use nerf_data::{Camera, Intrinsics, Pose};

    /// A sphere mesh seen by one camera on +z with the sphere's true depth map: culling keeps
    /// the near hemisphere and drops the far one; no view drops everything.
    #[test]
    fn culling_keeps_what_a_view_sees() {
        let (n, r) = (25usize, 0.5f32);
        let spacing = 2.0 / (n - 1) as f32;
        let values: Vec<f32> = (0..n * n * n)
            .map(|p| {
                let c = [p % n, (p / n) % n, p / (n * n)].map(|c| -1.0 + c as f32 * spacing);
                r - (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
            })
            .collect();
        let grid = marching::Grid {
            values: &values,
            dims: [n; 3],
            origin: [-1.0; 3],
            spacing,
        };
        let mesh = marching::level_set(&grid, 0.0);
        let colors = vec![[0u8; 3]; mesh.vertices.len()];
        let whole = ColoredMesh {
            mesh,
            colors,
            dims: [n; 3],
            spacing,
        };
        let camera = Camera::new(
            Intrinsics::centered(60.0, 64, 64),
            Pose::look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0]),
        );
        // True camera depth of the sphere (ray from the eye, direction with camera z = −1).
        let depth: Vec<f32> = (0..64 * 64)
            .map(|p| {
                let d = camera.pixel_direction(p % 64, p / 64);
                let o = camera.pose.translation;
                let (b, c) = (
                    (0..3).map(|a| o[a] * d[a]).sum::<f64>(),
                    (0..3).map(|a| o[a] * o[a]).sum::<f64>() - (r * r) as f64,
                );
                let a = (0..3).map(|k| d[k] * d[k]).sum::<f64>();
                let disc = b * b - a * c;
                if disc < 0.0 {
                    0.0
                } else {
                    ((-b - disc.sqrt()) / a) as f32
                }
            })
            .collect();
        let opacity: Vec<f32> = depth.iter().map(|&d| f32::from(u8::from(d > 0.0))).collect();
        let depth: Vec<f32> = depth.iter().zip(&opacity).map(|(d, a)| d * a).collect();
        let view = DepthView::new(camera, &depth, &opacity);

        let mut m = ColoredMesh {
            mesh: whole.mesh.clone(),
            colors: whole.colors.clone(),
            ..whole
        };
        let total = m.mesh.faces.len();
        let dropped = cull_unseen(&mut m, &[view], 0.5 * spacing);
        assert!(
            dropped > total / 3 && dropped < 2 * total / 3,
            "{dropped} of {total}"
        );
        assert_eq!(m.mesh.vertices.len(), m.colors.len());
        assert!(
            m.mesh
                .faces
                .iter()
                .flatten()
                .all(|&i| (i as usize) < m.mesh.vertices.len())
        );
        // What is left faces the camera: z ≥ 0 up to the slack.
        assert!(
            m.mesh.vertices.iter().all(|v| v[2] > -0.1),
            "a far-side vertex survived"
        );

        let mut none = ColoredMesh {
            mesh: m.mesh.clone(),
            colors: m.colors.clone(),
            dims: m.dims,
            spacing,
        };
        cull_unseen(&mut none, &[], 1.0);
        assert!(none.mesh.faces.is_empty() && none.mesh.vertices.is_empty());
    }
}
