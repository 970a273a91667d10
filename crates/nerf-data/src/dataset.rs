//! The common dataset type every parser returns, and random ray batches drawn from it.

use std::path::PathBuf;

use rand::Rng;

use crate::camera::Camera;
use crate::image::Image;
use crate::ndc::Ndc;
use crate::rays::{Rays, pixel_rays};

/// Which parser produced a dataset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Format {
    /// NeRF synthetic `transforms_*.json` (also nerfstudio/instant-ngp `transforms.json`).
    Blender,
    /// Blender format with a per-frame `time` (D-NeRF).
    DNerf,
    /// `poses_bounds.npy` + `images*/`.
    Llff,
    /// A COLMAP sparse model and `images/`, no `poses_bounds.npy`.
    Colmap,
    /// The tiny NeRF `.npz`.
    TinyNpz,
    /// NSFF-style video: `images/` + `poses_bounds.npy`, time = index / (N - 1).
    NsffVideo,
}

/// How the scene is laid out, which decides ray parameterisation and render paths.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SceneKind {
    /// An object seen from all around, inside `aabb` (Blender, tiny npz).
    Object,
    /// A real capture looking one general way (LLFF, COLMAP, NSFF video): no background, a
    /// spiral render path; rays in NDC when [`Dataset::ndc`] is set, else in the frustum box.
    ForwardFacing,
}

/// One posed image.
#[derive(Clone, Debug)]
pub struct View {
    /// File stem (or index) the view came from.
    pub name: String,
    /// RGB in [0, 1], already composited over the dataset background when the source had alpha.
    pub image: Image,
    /// Source alpha, when the images had it.
    pub alpha: Option<Vec<f32>>,
    pub camera: Camera,
    /// Normalised time in [0, 1] for dynamic scenes.
    pub time: Option<f32>,
}

/// Per-frame priors for NSFF-style video inputs. All maps are at the training resolution.
#[derive(Clone, Debug, Default)]
pub struct VideoPriors {
    /// Monocular disparity per frame (relative inverse depth, unknown scale and shift), `[H*W]`.
    pub disparity: Vec<Option<Vec<f32>>>,
    /// Optical flow from frame i to i+1, `[H*W*2]` in pixels (dx, dy), and its validity mask.
    pub flow_fwd: Vec<Option<FlowField>>,
    /// Optical flow from frame i to i-1 and its mask.
    pub flow_bwd: Vec<Option<FlowField>>,
    /// Optional motion masks (1 = probably moving), `[H*W]`.
    pub motion_masks: Vec<Option<Vec<f32>>>,
}

/// A dense 2-D flow field with a validity mask.
#[derive(Clone, Debug, PartialEq)]
pub struct FlowField {
    pub width: u32,
    pub height: u32,
    /// `[H*W*2]`, (dx, dy) in pixels.
    pub flow: Vec<f32>,
    /// `[H*W]`, 1 where the flow is trusted (forward-backward consistent), else 0.
    pub mask: Vec<f32>,
}

/// Everything a model needs from a capture.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The folder or file it was loaded from.
    pub source: PathBuf,
    pub format: Format,
    pub kind: SceneKind,
    pub views: Vec<View>,
    pub train: Vec<usize>,
    pub val: Vec<usize>,
    pub test: Vec<usize>,
    /// Ray bounds in the ray parameter (depth; NDC t for forward-facing scenes).
    pub near: f32,
    pub far: f32,
    /// Depth range of the content in world units (equal to near/far except for NDC scenes, where
    /// near/far are 0 and 1). Render paths (spiral focus depth) use it.
    pub depth_bounds: [f32; 2],
    /// Colour composited behind the scene; `None` for real captures (no compositing).
    pub background: Option<[f32; 3]>,
    /// Set for forward-facing scenes: rays are warped to NDC before sampling.
    pub ndc: Option<Ndc>,
    /// Axis-aligned box holding the scene, in the space samples live in (NDC for forward-facing).
    pub aabb: [[f32; 3]; 2],
    /// What the loader decided on the user's behalf (printed by the CLI).
    pub notes: Vec<String>,
    /// NSFF priors, when the source had (or we computed) them.
    pub priors: Option<VideoPriors>,
}

/// A random batch of training rays with their target colours.
#[derive(Clone, Debug, Default)]
pub struct RayBatch {
    pub rays: Rays,
    /// `[N, 3]` target RGB.
    pub rgb: Vec<f32>,
    /// View index of each ray.
    pub view: Vec<u32>,
    /// Row-major pixel index of each ray within its view.
    pub pixel: Vec<u32>,
}

impl Dataset {
    /// A scene in the Blender convention with no views yet: an object inside [−1.5, 1.5]³ seen
    /// from cameras at radius about 4 (near 2, far 6), composited over `background`.
    pub fn blender_object(source: PathBuf, format: Format, background: [f32; 3], notes: Vec<String>) -> Self {
        Dataset {
            source,
            format,
            kind: SceneKind::Object,
            views: Vec::new(),
            train: Vec::new(),
            val: Vec::new(),
            test: Vec::new(),
            near: 2.0,
            far: 6.0,
            depth_bounds: [2.0, 6.0],
            background: Some(background),
            ndc: None,
            aabb: [[-1.5; 3], [1.5; 3]],
            notes,
            priors: None,
        }
    }

    /// Rays of a whole view, row-major, in the space the model samples (NDC where set).
    pub fn view_rays(&self, view: usize) -> Rays {
        let cam = &self.views[view].camera;
        self.rays_for(cam, 0..cam.intrinsics.num_pixels() as u32)
    }

    /// Rays through the given pixels of an arbitrary camera, in model space.
    pub fn rays_for(&self, cam: &Camera, pixels: impl IntoIterator<Item = u32>) -> Rays {
        let mut rays = pixel_rays(cam, pixels);
        if let Some(ndc) = &self.ndc {
            ndc.rays(&mut rays);
        }
        rays
    }

    /// `n` rays drawn uniformly over all pixels of the given views. With `precrop` in (0, 1),
    /// pixels come only from the central `precrop` fraction of each image (NeRF's precrop).
    pub fn sample_batch(
        &self,
        views: &[usize],
        n: usize,
        precrop: Option<f32>,
        rng: &mut impl Rng,
    ) -> RayBatch {
        let mut batch = RayBatch {
            rays: Rays::with_capacity(n),
            rgb: Vec::with_capacity(3 * n),
            view: Vec::with_capacity(n),
            pixel: Vec::with_capacity(n),
        };
        for _ in 0..n {
            let v = views[rng.random_range(0..views.len())];
            let view = &self.views[v];
            let (w, h) = (view.image.width, view.image.height);
            let (x, y) = match precrop {
                Some(f) if f > 0.0 && f < 1.0 => {
                    let (cw, ch) = (((w as f32 * f) as u32).max(1), ((h as f32 * f) as u32).max(1));
                    let (x0, y0) = ((w - cw) / 2, (h - ch) / 2);
                    (x0 + rng.random_range(0..cw), y0 + rng.random_range(0..ch))
                }
                _ => (rng.random_range(0..w), rng.random_range(0..h)),
            };
            let p = y * w + x;
            batch.view.push(v as u32);
            batch.pixel.push(p);
            batch.rgb.extend_from_slice(&view.image.pixel(p as usize)[..3]);
        }
        // Rays are generated per view so the NDC warp and camera lookups stay simple.
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&i| batch.view[i]);
        let mut rays_sorted = vec![([0f32; 3], [0f32; 3]); n];
        let mut k = 0;
        while k < n {
            let v = batch.view[order[k]] as usize;
            let mut e = k;
            while e < n && batch.view[order[e]] as usize == v {
                e += 1;
            }
            let rays = self.rays_for(&self.views[v].camera, order[k..e].iter().map(|&i| batch.pixel[i]));
            for (j, &i) in order[k..e].iter().enumerate() {
                rays_sorted[i] = (rays.origin(j), rays.direction(j));
            }
            k = e;
        }
        for (o, d) in rays_sorted {
            batch.rays.origins.extend(o);
            batch.rays.directions.extend(d);
        }
        batch
    }

    /// Checks that images and cameras agree: sizes match the intrinsics, poses are finite.
    pub fn validate(&self) -> crate::error::Result<()> {
        use crate::error::DataError;
        for (i, v) in self.views.iter().enumerate() {
            let k = &v.camera.intrinsics;
            k.validate()
                .map_err(|m| DataError::invalid(&self.source, format!("view {i} ({}): {m}", v.name)))?;
            if (v.image.width, v.image.height) != (k.width, k.height) {
                return Err(DataError::invalid(
                    &self.source,
                    format!(
                        "view {i} ({}): image is {}x{} but its camera says {}x{}",
                        v.name, v.image.width, v.image.height, k.width, k.height
                    ),
                ));
            }
            if !v.camera.pose.is_finite() {
                return Err(DataError::invalid(
                    &self.source,
                    format!("view {i} ({}): pose has NaN/Inf", v.name),
                ));
            }
            if let Some(t) = v.time
                && !(0.0..=1.0).contains(&t)
            {
                return Err(DataError::invalid(
                    &self.source,
                    format!("view {i} ({}): time {t} is outside [0, 1]", v.name),
                ));
            }
        }
        Ok(())
    }

    /// Training views' images and the mean image size, for messages.
    pub fn describe(&self) -> String {
        let v = &self.views[0];
        format!(
            "{:?} scene from {}: {} views ({} train, {} test) at {}x{}, near {:.3} far {:.3}{}",
            self.format,
            self.source.display(),
            self.views.len(),
            self.train.len(),
            self.test.len(),
            v.image.width,
            v.image.height,
            self.near,
            self.far,
            if self.ndc.is_some() { ", NDC" } else { "" }
        )
    }
}
