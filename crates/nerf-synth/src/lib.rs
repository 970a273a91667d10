//! Deterministic synthetic scenes with exact ground truth, written in Blender / D-NeRF format.
//!
//! Captured datasets give images but no true depth, optical flow or 3-D scene flow, so neither
//! the geometry code nor NSFF's motion estimates can be scored exactly on them. This crate
//! ray-traces small analytic scenes (spheres, boxes, flat squares and discs with procedural
//! textures, Lambertian shading) and writes them together with that ground truth.
//!
//! Conventions are those of [`nerf_data::camera`]: OpenGL camera axes, pixel centres at (i + 0.5,
//! j + 0.5), ray parameter = camera depth. The world is z-up like Blender's, the content fits in
//! the box [-1.5, 1.5]³ and cameras sit at radius 4 looking at the origin (near 2, far 6).
//!
//! Every scene is a pure function of its [`SynthConfig`] (no global random state, no
//! time-dependent input), so the same seed always gives the same bytes. All stored parameters
//! are rounded to 1e-9 so `scene.json` re-parses to bit-identical values and a reloaded scene
//! renders identically.
//!
//! Output folder written by [`generate`]:
//! - `transforms_{train,val,test}.json`: `camera_angle_x`, the shared intrinsics
//!   (`fl_x, fl_y, cx, cy, w, h`) and per frame `file_path` (`./train/r_000`, no extension),
//!   `transform_matrix` (4×4 c2w, OpenGL), the same intrinsics, and `time` ∈ [0, 1] for the
//!   video presets. `val` lists the test images.
//! - `train/*.png`, `test/*.png`: RGBA, straight alpha = sub-pixel coverage.
//! - `gt/{split}/r_000_depth.npy`: float32 H×W camera depth, 0 on background.
//! - video presets, training frames only: `gt/train/r_000_flow_{fwd,bwd}.npy` (float32 H×W×2,
//!   (dx, dy) in pixels, to the next / previous frame) and `..._flow_{fwd,bwd}_mask.npy` (float32
//!   H×W, 1 where the point is visible in that frame, else 0; all zero where there is no
//!   neighbour).
//! - `scene.json`: the full [`Scene`], reloadable with [`Scene::load`].
//! - with [`SynthConfig::mono_disparity`], video presets: `disp/train/r_000.npy`, a simulated
//!   monocular disparity (float32 H×W, unknown scale and shift per frame, smoothed and noisy;
//!   [`DisparityErrors::Rough`] adds errors no scale and shift remove).
//! - with [`SynthConfig::motion_masks`], presets with a time: `motion_masks/train/r_000.png`, the moving
//!   objects' pixels grown by 2 (8-bit grey, 255 = moving), as NSFF's segmentation masks.

pub mod disparity;
mod family;
mod presets;
mod scene;
mod texture;
mod trace;
mod writer;

use std::fmt;
use std::str::FromStr;

pub use disparity::DisparityErrors;
pub use family::{Backdrop, MoverMotion, PathKind, Speed, Variation};
pub use scene::{Light, Motion, Object, SCENE_FILE, Scene, Shape, Split, SynthView, ViewKind};
pub use texture::{Pattern, Texture};
pub use trace::{RayHit, RenderOutput};
pub use writer::{GenerateSummary, generate};

/// Which kind of scene to build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// Textured objects on a ground square, seen from an upper hemisphere (like Blender lego).
    Static,
    /// A monocular video of a static set plus one moving, rotating cube (D-NeRF / NSFF style).
    Dynamic,
    /// [`Preset::Dynamic`] with every motion removed: a video without independent motion.
    StaticVideo,
    /// A family of monocular videos: the seed draws the background, one to three movers
    /// (translation, spin, non-rigid deformation; slow or fast), the camera path (short or
    /// wide arc, forward motion, hand-held), the frame count and the resolution
    /// ([`Variation`]).
    Family,
    /// [`Preset::Dynamic`]'s scene seen the D-NeRF benchmark's way: every frame from a random
    /// viewpoint on the upper hemisphere (a jumping camera), held-out views likewise at random
    /// times. No optical flow is written (neighbouring frames are unrelated views).
    Jumping,
    /// The D-NeRF benchmark's kind of scene with [`Preset::Jumping`]'s cameras: movers alone
    /// (one to three, larger than the family's; deforming, spinning, travelling), over a small
    /// plate for one seed in three, on white. Almost every pixel that is not background moves.
    JumpingMovers,
}

impl Preset {
    pub const ALL: [Preset; 6] = [
        Preset::Static,
        Preset::Dynamic,
        Preset::StaticVideo,
        Preset::Family,
        Preset::Jumping,
        Preset::JumpingMovers,
    ];

    /// Video presets have one camera per time step, `time` in the JSON and optical flow.
    pub fn is_video(self) -> bool {
        matches!(self, Preset::Dynamic | Preset::StaticVideo | Preset::Family)
    }

    /// Presets whose frames carry a `time` (the videos and the jumping camera).
    pub fn has_time(self) -> bool {
        self.is_video() || matches!(self, Preset::Jumping | Preset::JumpingMovers)
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Preset::Static => "static",
            Preset::Dynamic => "dynamic",
            Preset::StaticVideo => "static_video",
            Preset::Family => "family",
            Preset::Jumping => "jumping",
            Preset::JumpingMovers => "jumping_movers",
        }
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Preset {
    type Err = String;

    /// Accepts the [`fmt::Display`] names; `-` may stand for `_`, case is ignored.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let norm = s.trim().to_ascii_lowercase().replace('-', "_");
        Preset::ALL
            .into_iter()
            .find(|p| p.as_str() == norm)
            .ok_or_else(|| {
                format!("unknown synthetic preset '{s}' (expected static, dynamic, static_video, family, jumping or jumping_movers)")
            })
    }
}

/// What to generate. Build with [`SynthConfig::new`] and override fields as needed.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    pub preset: Preset,
    /// Seeds the layout, textures and cameras; the same config always gives the same bytes.
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// Training views (static) or video frames (video presets, at least 2).
    pub frames: usize,
    /// Held-out views. Video presets split them into off-path cameras at training times (the
    /// first half, rounded up) and on-path cameras at mid-frame times (the rest).
    pub test_views: usize,
    /// Video presets: also write a simulated monocular disparity per training frame with these
    /// errors (`disp/train/r_000.npy`, see [`disparity::simulate`]).
    pub mono_disparity: Option<DisparityErrors>,
    /// Presets with a time: also write the moving objects' masks per training frame
    /// (`motion_masks/train/r_000.png`, see [`Scene::write_motion_masks`]).
    pub motion_masks: bool,
}

impl SynthConfig {
    /// Defaults per preset: static 100×100 with 100 train and 20 test views; video presets
    /// 128×96 with 24 frames and 8 test views; the jumping presets 100×100 with 60 frames and 10
    /// test views.
    /// Seed 0.
    pub fn new(preset: Preset) -> Self {
        let (width, height, frames, test_views) = match preset {
            Preset::Static => (100, 100, 100, 20),
            Preset::Dynamic | Preset::StaticVideo | Preset::Family => (128, 96, 24, 8),
            Preset::Jumping | Preset::JumpingMovers => (100, 100, 60, 10),
        };
        SynthConfig {
            preset,
            seed: 0,
            width,
            height,
            frames,
            test_views,
            mono_disparity: None,
            motion_masks: false,
        }
    }

    /// [`SynthConfig::new`] at `seed`; for the family the frame count and the resolution are
    /// the seed's draw too.
    pub fn seeded(preset: Preset, seed: u64) -> Self {
        let cfg = SynthConfig::new(preset).with_seed(seed);
        if preset != Preset::Family {
            return cfg;
        }
        let v = Variation::draw(seed);
        let tests = cfg.test_views;
        cfg.with_size(v.width, v.height).with_views(v.frames, tests)
    }

    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    pub fn with_size(mut self, width: u32, height: u32) -> Self {
        self.width = width;
        self.height = height;
        self
    }

    pub fn with_views(mut self, frames: usize, test_views: usize) -> Self {
        self.frames = frames;
        self.test_views = test_views;
        self
    }

    /// Rejects sizes and counts that cannot make a usable scene.
    pub fn validate(&self) -> Result<(), String> {
        const MAX_SIDE: u32 = 16384;
        const MAX_VIEWS: usize = 100_000;
        if self.width == 0 || self.height == 0 || self.width > MAX_SIDE || self.height > MAX_SIDE {
            return Err(format!(
                "image size {}x{} must be between 1 and {MAX_SIDE} pixels per side",
                self.width, self.height
            ));
        }
        let min_frames = if self.preset.has_time() { 2 } else { 1 };
        if self.frames < min_frames || self.frames > MAX_VIEWS {
            return Err(format!(
                "{} frames requested; the {} preset needs between {min_frames} and {MAX_VIEWS}",
                self.frames, self.preset
            ));
        }
        if self.test_views > MAX_VIEWS {
            return Err(format!(
                "{} test views requested; at most {MAX_VIEWS}",
                self.test_views
            ));
        }
        Ok(())
    }
}
