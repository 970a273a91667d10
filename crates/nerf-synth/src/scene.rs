//! The scene description: primitives, rigid motions, lights and the views to render. It is
//! what `scene.json` holds, so ground truth can be recomputed after the fact.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::family::Variation;
use super::texture::Texture;
use super::{Preset, SynthConfig};
use nerf_data::camera::{Camera, Intrinsics, Pose};
use nerf_data::error::{DataError, Result};
use nerf_data::math::{self, Mat3, Vec3};

/// Name of the scene description inside a generated folder.
pub const SCENE_FILE: &str = "scene.json";
const FORMAT: &str = "nerf-rs-synth";
const VERSION: u32 = 1;
/// World up axis (Blender's z), used for every camera's `look_at`.
const UP: Vec3 = [0.0, 0.0, 1.0];

/// An analytic primitive in its local frame (centred at the local origin).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Shape {
    /// Sphere of `radius`.
    Sphere { radius: f64 },
    /// Solid box `[-h, h]` on each local axis, `h = half_extents`.
    Box { half_extents: Vec3 },
    /// Square `[-h, h]²` in the local z = 0 plane, visible from both sides.
    Square { half_size: f64 },
    /// Disc of `radius` in the local z = 0 plane, visible from both sides.
    Disc { radius: f64 },
}

impl Shape {
    /// First hit with `t > t_min` of the local ray `o + t·d`: `(t, outward unit normal)`.
    /// For the flat shapes the normal is local +z whichever side is hit.
    pub fn intersect(&self, o: Vec3, d: Vec3, t_min: f64) -> Option<(f64, Vec3)> {
        if d == [0.0; 3] {
            return None;
        }
        match *self {
            Shape::Sphere { radius } => {
                let a = math::dot(d, d);
                let b = math::dot(o, d);
                let c = math::dot(o, o) - radius * radius;
                let disc = b * b - a * c;
                if disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                let t = [(-b - s) / a, (-b + s) / a].into_iter().find(|&t| t > t_min)?;
                let p = math::add(o, math::scale(d, t));
                Some((t, math::scale(p, 1.0 / radius)))
            }
            Shape::Box { half_extents: h } => {
                let (mut t_near, mut near_axis) = (f64::NEG_INFINITY, 0);
                let (mut t_far, mut far_axis) = (f64::INFINITY, 0);
                for a in 0..3 {
                    if d[a] == 0.0 {
                        // Parallel to this slab: inside it for all t, or never.
                        if o[a].abs() > h[a] {
                            return None;
                        }
                        continue;
                    }
                    let (t0, t1) = ((-h[a] - o[a]) / d[a], (h[a] - o[a]) / d[a]);
                    let (lo, hi) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
                    if lo > t_near {
                        (t_near, near_axis) = (lo, a);
                    }
                    if hi < t_far {
                        (t_far, far_axis) = (hi, a);
                    }
                }
                if t_near > t_far {
                    return None;
                }
                let (t, axis, sign) = if t_near > t_min {
                    (t_near, near_axis, -d[near_axis].signum())
                } else if t_far > t_min {
                    (t_far, far_axis, d[far_axis].signum())
                } else {
                    return None;
                };
                let mut n = [0.0; 3];
                n[axis] = sign;
                Some((t, n))
            }
            Shape::Square { half_size } => {
                plane_hit(o, d, t_min, |x, y| x.abs() <= half_size && y.abs() <= half_size)
            }
            Shape::Disc { radius } => plane_hit(o, d, t_min, |x, y| x * x + y * y <= radius * radius),
        }
    }

    /// Signed distance from the local point `p` to the surface (negative inside solids; the
    /// flat shapes have no inside).
    pub fn signed_distance(&self, p: Vec3) -> f64 {
        match *self {
            Shape::Sphere { radius } => math::norm(p) - radius,
            Shape::Box { half_extents: h } => {
                let q = [0, 1, 2].map(|k| p[k].abs() - h[k]);
                let outside = math::norm(q.map(|v| v.max(0.0)));
                let inside = q[0].max(q[1]).max(q[2]).min(0.0);
                outside + inside
            }
            Shape::Square { half_size } => {
                let (dx, dy) = (
                    (p[0].abs() - half_size).max(0.0),
                    (p[1].abs() - half_size).max(0.0),
                );
                (dx * dx + dy * dy + p[2] * p[2]).sqrt()
            }
            Shape::Disc { radius } => {
                let dr = ((p[0] * p[0] + p[1] * p[1]).sqrt() - radius).max(0.0);
                (dr * dr + p[2] * p[2]).sqrt()
            }
        }
    }

    /// Radius of a sphere about the local origin that holds the whole shape.
    /// The same shape with every size (radius, half extent) replaced by `f(size)`.
    pub fn map_sizes(self, f: impl Fn(f64) -> f64) -> Shape {
        match self {
            Shape::Sphere { radius } => Shape::Sphere { radius: f(radius) },
            Shape::Disc { radius } => Shape::Disc { radius: f(radius) },
            Shape::Box { half_extents } => Shape::Box {
                half_extents: half_extents.map(f),
            },
            Shape::Square { half_size } => Shape::Square {
                half_size: f(half_size),
            },
        }
    }

    pub fn bounding_radius(&self) -> f64 {
        match *self {
            Shape::Sphere { radius } | Shape::Disc { radius } => radius,
            Shape::Box { half_extents } => math::norm(half_extents),
            Shape::Square { half_size } => half_size * std::f64::consts::SQRT_2,
        }
    }

    fn validate(&self) -> std::result::Result<(), String> {
        let sizes: Vec<f64> = match *self {
            Shape::Sphere { radius } | Shape::Disc { radius } => vec![radius],
            Shape::Box { half_extents } => half_extents.to_vec(),
            Shape::Square { half_size } => vec![half_size],
        };
        if sizes.iter().all(|v| v.is_finite() && *v > 0.0) {
            Ok(())
        } else {
            Err(format!("shape {self:?} needs finite, positive sizes"))
        }
    }
}

/// Hit of the local z = 0 plane, kept when `inside(x, y)` says the point is on the shape.
fn plane_hit(o: Vec3, d: Vec3, t_min: f64, inside: impl Fn(f64, f64) -> bool) -> Option<(f64, Vec3)> {
    if d[2] == 0.0 {
        return None;
    }
    let t = -o[2] / d[2];
    (t > t_min && inside(o[0] + t * d[0], o[1] + t * d[1])).then_some((t, [0.0, 0.0, 1.0]))
}

/// A motion over normalised time τ, the identity at τ = 0:
/// rotation `R_m(τ)` = `spin_deg·τ` degrees about `spin_axis` (world frame, about the object's
/// centre), centre offset `displacement·τ + wobble·sin(2π·wobble_cycles·τ)` and, for non-rigid
/// motion, a squash-and-stretch `S(τ) = diag(1 + pulse·sin(2π·pulse_cycles·τ))` along the
/// object's own axes. τ outside [0, 1] extrapolates the same formulas.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Motion {
    /// Straight-line displacement of the centre reached at τ = 1.
    pub displacement: Vec3,
    /// Amplitude of the sinusoidal part of the path.
    pub wobble: Vec3,
    pub wobble_cycles: f64,
    pub spin_axis: Vec3,
    pub spin_deg: f64,
    /// Relative scale amplitude along each local axis (zero: rigid).
    #[serde(default)]
    pub pulse: Vec3,
    #[serde(default)]
    pub pulse_cycles: f64,
}

impl Motion {
    /// No motion at all (static objects).
    pub fn identity() -> Self {
        Motion {
            spin_axis: UP,
            ..Motion::default()
        }
    }

    pub fn is_identity(&self) -> bool {
        let wobbles = self.wobble != [0.0; 3] && self.wobble_cycles != 0.0;
        self.displacement == [0.0; 3] && !wobbles && self.spin_deg == 0.0 && self.is_rigid()
    }

    /// No change of shape over time.
    pub fn is_rigid(&self) -> bool {
        self.pulse == [0.0; 3] || self.pulse_cycles == 0.0
    }

    /// The diagonal of `S(τ)`.
    pub fn scale_at(&self, tau: f64) -> Vec3 {
        if self.is_rigid() {
            return [1.0; 3];
        }
        let wave = (std::f64::consts::TAU * self.pulse_cycles * tau).sin();
        self.pulse.map(|p| 1.0 + p * wave)
    }

    /// `(R_m(τ), centre offset(τ))`.
    pub fn at(&self, tau: f64) -> (Mat3, Vec3) {
        let rot = if self.spin_deg == 0.0 {
            math::identity()
        } else {
            math::axis_angle(self.spin_axis, (self.spin_deg * tau).to_radians())
        };
        let wave = (std::f64::consts::TAU * self.wobble_cycles * tau).sin();
        let offset = math::add(
            math::scale(self.displacement, tau),
            math::scale(self.wobble, wave),
        );
        (rot, offset)
    }
}

/// One textured primitive with its pose at τ = 0 and its motion.
/// Local to world at time τ: `x_w = R_m(τ)·R_0·S(τ)·x_l + position + offset(τ)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Object {
    pub name: String,
    pub shape: Shape,
    pub texture: Texture,
    /// World position of the local origin at τ = 0.
    pub position: Vec3,
    /// Orientation `R_0` at τ = 0 as an axis and an angle in degrees.
    pub rotation_axis: Vec3,
    pub rotation_deg: f64,
    pub motion: Motion,
}

impl Object {
    /// `(A, A⁻¹, c)` with `x_w = A·x_l + c` at time τ (`A = R·S`, a rotation for rigid objects).
    pub fn transform_at(&self, tau: f64) -> (Mat3, Mat3, Vec3) {
        let r0 = if self.rotation_deg == 0.0 {
            math::identity()
        } else {
            math::axis_angle(self.rotation_axis, self.rotation_deg.to_radians())
        };
        let (rm, offset) = self.motion.at(tau);
        let r = math::mat_mul(&rm, &r0);
        let s = self.motion.scale_at(tau);
        // R·S scales columns, (R·S)⁻¹ = S⁻¹·Rᵀ scales rows.
        let a = r.map(|row| [0, 1, 2].map(|k| row[k] * s[k]));
        let mut inv = math::transpose(&r);
        for (row, sk) in inv.iter_mut().zip(s) {
            *row = row.map(|v| v / sk);
        }
        (a, inv, math::add(self.position, offset))
    }

    pub fn to_world(&self, local: Vec3, tau: f64) -> Vec3 {
        let (a, _, c) = self.transform_at(tau);
        math::add(math::mat_vec(&a, local), c)
    }

    pub fn to_local(&self, world: Vec3, tau: f64) -> Vec3 {
        let (_, inv, c) = self.transform_at(tau);
        math::mat_vec(&inv, math::sub(world, c))
    }

    pub fn is_moving(&self) -> bool {
        !self.motion.is_identity()
    }

    fn validate(&self) -> std::result::Result<(), String> {
        let ctx = |m: String| format!("object '{}': {m}", self.name);
        self.shape.validate().map_err(ctx)?;
        let m = &self.motion;
        let t = &self.texture;
        let values = [
            self.position,
            self.rotation_axis,
            m.displacement,
            m.wobble,
            m.spin_axis,
            m.pulse,
        ]
        .into_iter()
        .flatten()
        .chain([
            self.rotation_deg,
            m.wobble_cycles,
            m.spin_deg,
            m.pulse_cycles,
            t.detail,
            t.detail_scale,
        ])
        .chain(t.colors.into_iter().flatten())
        .chain(t.offset);
        if values.into_iter().any(|v| !v.is_finite()) {
            return Err(ctx("has a non-finite parameter".into()));
        }
        if self.rotation_deg != 0.0 && math::norm(self.rotation_axis) == 0.0 {
            return Err(ctx("rotation_deg is set but rotation_axis is zero".into()));
        }
        if m.pulse.iter().any(|p| p.abs() >= 0.9) {
            return Err(ctx(
                "pulse amplitudes must be below 0.9 (the object would invert)".into(),
            ));
        }
        if m.spin_deg != 0.0 && math::norm(m.spin_axis) == 0.0 {
            return Err(ctx("spin_deg is set but spin_axis is zero".into()));
        }
        Ok(())
    }
}

/// A fixed directional light plus ambient: albedo · (ambient + diffuse · max(0, n·l)).
/// Shading does not depend on the viewer, so colours are view-independent.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Light {
    /// Direction towards the light (normalised when used).
    pub direction: Vec3,
    pub ambient: f64,
    pub diffuse: f64,
}

/// Which output split a view belongs to (`val` repeats `test`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Train,
    Test,
}

impl Split {
    pub fn as_str(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
        }
    }
}

/// How a view's camera was chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewKind {
    /// Random point of the upper hemisphere (static preset).
    Orbit,
    /// A frame of the video path.
    Video,
    /// Held out: off the video path, at a training frame's time.
    OffPath,
    /// Held out: on the video path halfway between two frames, at the halfway time.
    MidFrame,
}

impl ViewKind {
    /// The name `scene.json` uses.
    pub fn as_str(self) -> &'static str {
        match self {
            ViewKind::Orbit => "orbit",
            ViewKind::Video => "video",
            ViewKind::OffPath => "off_path",
            ViewKind::MidFrame => "mid_frame",
        }
    }
}

/// A camera to render: position, target (world up is +z) and time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SynthView {
    /// File stem, e.g. `r_007`.
    pub name: String,
    pub split: Split,
    pub kind: ViewKind,
    pub eye: Vec3,
    pub target: Vec3,
    /// Normalised time τ ∈ [0, 1] (0 for static scenes).
    pub time: f64,
}

/// A complete synthetic scene: what `scene.json` stores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// Always `nerf-rs-synth`; guards against loading some other JSON.
    pub format: String,
    pub version: u32,
    pub preset: Preset,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// Horizontal field of view in radians (square pixels, centred principal point).
    pub camera_angle_x: f64,
    /// Depth bounds that hold all content from every view.
    pub near: f64,
    pub far: f64,
    /// Anti-aliasing: colour averages a stratified n×n grid of sub-pixel rays.
    pub samples_per_axis: u32,
    /// Colour of pixels no ray hits (alpha 0 there anyway).
    pub background: Vec3,
    pub light: Light,
    pub objects: Vec<Object>,
    pub views: Vec<SynthView>,
    /// The `family` preset: what its seed drew.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variation: Option<Variation>,
}

impl Scene {
    /// The scene a config describes (a pure function of it).
    pub fn from_config(cfg: &SynthConfig) -> Scene {
        super::presets::build(cfg)
    }

    pub(super) fn empty(preset: Preset, seed: u64, width: u32, height: u32) -> Scene {
        Scene {
            format: FORMAT.into(),
            version: VERSION,
            preset,
            seed,
            width,
            height,
            camera_angle_x: 0.6911112,
            near: 2.0,
            far: 6.0,
            samples_per_axis: 3,
            background: [1.0; 3],
            light: Light {
                direction: [0.35, 0.45, 0.82],
                ambient: 0.35,
                diffuse: 0.65,
            },
            objects: Vec::new(),
            views: Vec::new(),
            variation: None,
        }
    }

    /// Reads `scene.json` from a generated folder (or from the file itself when `path` is one).
    pub fn load(path: &Path) -> Result<Scene> {
        let file = if path.is_file() {
            path.to_path_buf()
        } else {
            path.join(SCENE_FILE)
        };
        let bytes = nerf_data::error::read_file(&file)?;
        let scene: Scene = serde_json::from_slice(&bytes)
            .map_err(|e| DataError::invalid(&file, format!("not a synthetic scene description: {e}")))?;
        if scene.format != FORMAT || scene.version != VERSION {
            return Err(DataError::invalid(
                &file,
                format!(
                    "format '{}' version {} is not {FORMAT} version {VERSION}",
                    scene.format, scene.version
                ),
            ));
        }
        scene.validate().map_err(|m| DataError::invalid(&file, m))?;
        Ok(scene)
    }

    /// The description as pretty JSON (what [`Scene::load`] reads).
    pub fn to_json(&self) -> String {
        // Serialising plain data with string keys cannot fail.
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// Problems that would make rendering meaningless.
    pub fn validate(&self) -> std::result::Result<(), String> {
        self.intrinsics().validate()?;
        if !(self.camera_angle_x > 0.0 && self.camera_angle_x < std::f64::consts::PI) {
            return Err(format!(
                "camera_angle_x = {} must be in (0, π)",
                self.camera_angle_x
            ));
        }
        if !(1..=16).contains(&self.samples_per_axis) {
            return Err(format!(
                "samples_per_axis = {} must be in 1..=16",
                self.samples_per_axis
            ));
        }
        let l = &self.light;
        if !l
            .direction
            .iter()
            .chain([&l.ambient, &l.diffuse])
            .all(|v| v.is_finite())
        {
            return Err("light has a non-finite parameter".into());
        }
        for o in &self.objects {
            o.validate()?;
        }
        for v in &self.views {
            let ok = v
                .eye
                .iter()
                .chain(&v.target)
                .chain([&v.time])
                .all(|x| x.is_finite());
            let back = math::sub(v.eye, v.target);
            if !ok || math::norm(math::cross(UP, back)) < 1e-9 * math::norm(back).max(1e-300) {
                return Err(format!(
                    "view '{}': eye and target must be finite, distinct and not vertically aligned",
                    v.name
                ));
            }
        }
        Ok(())
    }

    /// The shared intrinsics of all views.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics::from_fov_x(self.camera_angle_x, self.width, self.height)
    }

    pub fn camera(&self, view: &SynthView) -> Camera {
        Camera::new(self.intrinsics(), Pose::look_at(view.eye, view.target, UP))
    }

    pub fn views_in(&self, split: Split) -> impl Iterator<Item = &SynthView> {
        self.views.iter().filter(move |v| v.split == split)
    }

    /// Whether anything moves (false for the static and static_video presets).
    pub fn has_motion(&self) -> bool {
        self.objects.iter().any(Object::is_moving)
    }

    /// Indices of the objects that move.
    pub fn moving_objects(&self) -> Vec<usize> {
        (0..self.objects.len())
            .filter(|&k| self.objects[k].is_moving())
            .collect()
    }

    /// The object whose surface or inside holds the world point `p` at time τ: the one with
    /// the smallest signed distance among those within `tolerance`.
    pub fn object_at(&self, p: Vec3, time: f64, tolerance: f64) -> Option<usize> {
        self.objects
            .iter()
            .enumerate()
            .map(|(k, o)| (k, o.shape.signed_distance(o.to_local(p, time))))
            .filter(|&(_, sd)| sd <= tolerance)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(k, _)| k)
    }

    /// Distance from the world point `p` to the nearest object surface at time τ (exact for
    /// rigid objects; for scaled ones, the distance in the object's own frame).
    pub fn surface_distance(&self, p: Vec3, time: f64) -> f64 {
        self.objects
            .iter()
            .map(|o| o.shape.signed_distance(o.to_local(p, time)).abs())
            .fold(f64::INFINITY, f64::min)
    }

    /// 3-D displacement from time `t0` to `t1` of the point that sits at world `p` at `t0` and
    /// moves with object `object` (the same local point). Exactly zero for static objects and for `t0 == t1`.
    pub fn object_scene_flow(&self, object: usize, p: Vec3, t0: f64, t1: f64) -> Vec3 {
        let o = &self.objects[object];
        if t0 == t1 || !o.is_moving() {
            return [0.0; 3];
        }
        math::sub(o.to_world(o.to_local(p, t0), t1), p)
    }

    /// Ground-truth scene flow of the world point `p` (on or inside an object at time `t0`,
    /// within 1e-3 world units) from `t0` to `t1`: zero for static objects, `None` for points in
    /// empty space. Use [`Scene::object_at`] / [`Scene::object_scene_flow`] for another tolerance.
    pub fn scene_flow(&self, p: Vec3, t0: f64, t1: f64) -> Option<Vec3> {
        let k = self.object_at(p, t0, 1e-3)?;
        Some(self.object_scene_flow(k, p, t0, t1))
    }
}
