//! The three presets. Each is a pure function of the config: a private SplitMix64 generator
//! (stable across crate versions, unlike `rand`'s StdRng) draws from separate streams for the
//! layout and for each camera split, so changing the number of views keeps the layout.

use super::scene::{Motion, Object, Scene, Shape, Split, SynthView, ViewKind};
use super::texture::{Pattern, Texture, mix64};
use super::{Preset, SynthConfig};
use nerf_data::math::{self, Vec3};

/// Height of the ground square and its half side; everything fits in [-1.5, 1.5]³.
pub(super) const GROUND_Z: f64 = -0.5;
pub(super) const GROUND_HALF: f64 = 1.3;
/// Objects stand within this distance of the vertical axis (so most views see all of them).
pub(super) const LAYOUT_RADIUS: f64 = 1.2;
pub(super) const CAMERA_RADIUS: f64 = 4.0;
/// Azimuth swept by the video camera over the whole sequence, degrees.
const ARC_DEG: f64 = 80.0;
/// Half side of the moving cube and the height of its centre above the ground.
const MOVER_HALF: f64 = 0.25;
const MOVER_LIFT: f64 = 0.6;

pub(super) const STREAM_LAYOUT: u64 = 1;
const STREAM_TRAIN: u64 = 2;
const STREAM_TEST: u64 = 3;
pub(super) const STREAM_SHAKE: u64 = 4;
pub(super) const STREAM_VARIATION: u64 = 5;

/// Rounds to 1e-9: stored values then have short decimal forms that JSON parsers read back
/// exactly, so a reloaded `scene.json` is bit-identical.
pub(super) fn q(v: f64) -> f64 {
    (v * 1e9).round() / 1e9
}

pub(super) fn qv(v: Vec3) -> Vec3 {
    v.map(q)
}

/// SplitMix64.
pub(super) struct Rng(u64);

impl Rng {
    pub(super) fn new(seed: u64, stream: u64) -> Self {
        Rng(mix64(
            seed ^ mix64(
                stream
                    .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    .wrapping_add(0x632B_E59B),
            ),
        ))
    }

    pub(super) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.0)
    }

    /// Uniform in [0, 1).
    pub(super) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    pub(super) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    pub(super) fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }

    pub(super) fn coin(&mut self) -> bool {
        self.next_u64() >> 63 == 1
    }

    /// Uniform direction (rejection sampling in the unit ball).
    pub(super) fn unit_vector(&mut self) -> Vec3 {
        loop {
            let v = [
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            ];
            let n = math::norm(v);
            if n > 0.1 && n <= 1.0 {
                return math::scale(v, 1.0 / n);
            }
        }
    }

    pub(super) fn shuffle<T>(&mut self, items: &mut [T]) {
        for i in (1..items.len()).rev() {
            let j = self.below(i + 1);
            items.swap(i, j);
        }
    }
}

pub(super) fn build(cfg: &SynthConfig) -> Scene {
    let mut scene = Scene::empty(cfg.preset, cfg.seed, cfg.width, cfg.height);
    match cfg.preset {
        Preset::Static => {
            scene.objects = static_objects(cfg.seed);
            let mut train = Rng::new(cfg.seed, STREAM_TRAIN);
            let mut test = Rng::new(cfg.seed, STREAM_TEST);
            let (dn, dt) = (digits(cfg.frames), digits(cfg.test_views));
            scene
                .views
                .extend((0..cfg.frames).map(|k| orbit_view(&mut train, Split::Train, name(k, dn))));
            scene
                .views
                .extend((0..cfg.test_views).map(|k| orbit_view(&mut test, Split::Test, name(k, dt))));
        }
        Preset::Dynamic | Preset::StaticVideo => {
            let (objects, path) = video_layout(cfg.seed, cfg.preset == Preset::Dynamic);
            scene.objects = objects;
            let mut shake = Rng::new(cfg.seed, STREAM_SHAKE);
            scene.views = video_views(&path, cfg.frames, cfg.test_views, &mut shake);
        }
        Preset::Family => super::family::build(cfg, &mut scene),
        Preset::Jumping => {
            scene.objects = video_layout(cfg.seed, true).0;
            scene.views = jumping_views(cfg);
        }
        Preset::JumpingMovers => {
            super::family::build_movers(cfg, &mut scene);
            scene.views = jumping_views(cfg);
        }
    }
    scene
}

/// D-NeRF's cameras: every training frame and held-out view from a random viewpoint on the
/// upper hemisphere; frames at evenly spaced times, held-out views at random times.
fn jumping_views(cfg: &SynthConfig) -> Vec<SynthView> {
    let mut train = Rng::new(cfg.seed, STREAM_TRAIN);
    let mut test = Rng::new(cfg.seed, STREAM_TEST);
    let (dn, dt) = (digits(cfg.frames), digits(cfg.test_views));
    let last = cfg.frames.saturating_sub(1).max(1) as f64;
    let mut views: Vec<SynthView> = (0..cfg.frames)
        .map(|k| SynthView {
            time: q(k as f64 / last),
            ..orbit_view(&mut train, Split::Train, name(k, dn))
        })
        .collect();
    views.extend((0..cfg.test_views).map(|k| {
        let view = orbit_view(&mut test, Split::Test, name(k, dt));
        SynthView {
            time: q(test.unit()),
            ..view
        }
    }));
    views
}

/// Zero-padded width of view numbers: 3 like `r_007`, more for long sequences.
fn digits(count: usize) -> usize {
    count.saturating_sub(1).to_string().len().max(3)
}

fn name(k: usize, digits: usize) -> String {
    format!("r_{k:0digits$}")
}

/// A point at `radius` from the origin, azimuth from +x towards +y, elevation above the xy-plane.
pub(super) fn spherical(radius: f64, az_deg: f64, el_deg: f64) -> Vec3 {
    let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
    qv([
        radius * el.cos() * az.cos(),
        radius * el.cos() * az.sin(),
        radius * el.sin(),
    ])
}

/// A camera uniformly distributed over the spherical cap between 12° and 75° elevation.
fn orbit_view(rng: &mut Rng, split: Split, name: String) -> SynthView {
    let az = rng.range(0.0, 360.0);
    let z = rng.range(12f64.to_radians().sin(), 75f64.to_radians().sin());
    SynthView {
        name,
        split,
        kind: ViewKind::Orbit,
        eye: spherical(CAMERA_RADIUS, az, z.asin().to_degrees()),
        target: [0.0; 3],
        time: 0.0,
    }
}

/// HSV (all in [0, 1]) to RGB.
pub(super) fn hsv(h: f64, s: f64, v: f64) -> Vec3 {
    let h6 = (h - h.floor()) * 6.0;
    let f = h6 - h6.floor();
    let (p, qq, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    let rgb = match h6 as u32 {
        0 => [v, t, p],
        1 => [qq, v, p],
        2 => [p, v, t],
        3 => [p, qq, v],
        4 => [t, p, v],
        _ => [v, p, qq],
    };
    qv(rgb)
}

pub(super) fn texture(rng: &mut Rng, pattern: Pattern, colors: [Vec3; 2]) -> Texture {
    Texture {
        pattern,
        colors,
        detail: q(rng.range(0.2, 0.35)),
        detail_scale: q(rng.range(9.0, 14.0)),
        offset: qv([rng.unit(), rng.unit(), rng.unit()]),
        seed: rng.next_u64() >> 11,
    }
}

/// A bright colour and a darker, contrasting one.
pub(super) fn palette(rng: &mut Rng) -> [Vec3; 2] {
    let hue = rng.unit();
    [
        hsv(hue, rng.range(0.55, 0.9), rng.range(0.8, 1.0)),
        hsv(
            hue + rng.range(0.3, 0.6),
            rng.range(0.5, 0.9),
            rng.range(0.3, 0.55),
        ),
    ]
}

pub(super) fn random_texture(rng: &mut Rng) -> Texture {
    let colors = palette(rng);
    let pattern = match rng.below(4) {
        0 => Pattern::Checker {
            cells_per_unit: q(rng.range(5.0, 9.0)),
        },
        1 => Pattern::Stripes {
            direction: qv(rng.unit_vector()),
            stripes_per_unit: q(rng.range(5.0, 9.0)),
        },
        2 => Pattern::Noise {
            scale: q(rng.range(4.0, 7.0)),
        },
        _ => Pattern::Rainbow {
            frequency: qv(math::scale(rng.unit_vector(), rng.range(1.5, 3.0))),
        },
    };
    texture(rng, pattern, colors)
}

/// The textured ground square every preset stands on.
pub(super) fn ground(rng: &mut Rng) -> Object {
    let hue = rng.unit();
    let colors = [hsv(hue, 0.15, 0.92), hsv(hue + 0.5, 0.45, 0.5)];
    Object {
        name: "ground".into(),
        shape: Shape::Square {
            half_size: GROUND_HALF,
        },
        texture: texture(rng, Pattern::Checker { cells_per_unit: 2.5 }, colors),
        position: [0.0, 0.0, GROUND_Z],
        rotation_axis: [0.0, 0.0, 1.0],
        rotation_deg: 0.0,
        motion: Motion::identity(),
    }
}

#[derive(Clone, Copy)]
pub(super) enum Kind {
    Sphere,
    Cube,
    Block,
    Pillar,
    Plate,
}

/// A shape of `kind` resting on (or, for the plate, floating tilted just above) the ground.
pub(super) struct Placed {
    pub shape: Shape,
    /// Height of the centre above the ground.
    pub lift: f64,
    /// Radius of the object's footprint around its centre, for non-overlapping placement.
    pub footprint: f64,
    pub rotation_axis: Vec3,
    pub rotation_deg: f64,
    pub label: &'static str,
}

pub(super) fn random_shape(rng: &mut Rng, kind: Kind) -> Placed {
    let about_z = |rng: &mut Rng| ([0.0, 0.0, 1.0], q(rng.range(0.0, 90.0)));
    match kind {
        Kind::Sphere => {
            let r = q(rng.range(0.22, 0.38));
            let (axis, deg) = (qv(rng.unit_vector()), q(rng.range(0.0, 360.0)));
            Placed {
                shape: Shape::Sphere { radius: r },
                lift: r,
                footprint: r,
                rotation_axis: axis,
                rotation_deg: deg,
                label: "sphere",
            }
        }
        Kind::Cube => {
            let h = q(rng.range(0.18, 0.28));
            let (axis, deg) = about_z(rng);
            let shape = Shape::Box { half_extents: [h; 3] };
            Placed {
                shape,
                lift: h,
                footprint: h * 2f64.sqrt(),
                rotation_axis: axis,
                rotation_deg: deg,
                label: "cube",
            }
        }
        Kind::Block => {
            let e = [
                q(rng.range(0.15, 0.32)),
                q(rng.range(0.15, 0.32)),
                q(rng.range(0.12, 0.25)),
            ];
            let (axis, deg) = about_z(rng);
            let footprint = e[0].hypot(e[1]);
            Placed {
                shape: Shape::Box { half_extents: e },
                lift: e[2],
                footprint,
                rotation_axis: axis,
                rotation_deg: deg,
                label: "block",
            }
        }
        Kind::Pillar => {
            let (a, c) = (q(rng.range(0.1, 0.16)), q(rng.range(0.35, 0.5)));
            let (axis, deg) = about_z(rng);
            let shape = Shape::Box {
                half_extents: [a, a, c],
            };
            Placed {
                shape,
                lift: c,
                footprint: a * 2f64.sqrt(),
                rotation_axis: axis,
                rotation_deg: deg,
                label: "pillar",
            }
        }
        Kind::Plate => {
            let r = q(rng.range(0.25, 0.35));
            let azimuth = rng.range(0.0, 360.0).to_radians();
            let tilt = q(rng.range(55.0, 80.0));
            let axis = qv([azimuth.cos(), azimuth.sin(), 0.0]);
            let lift = r * tilt.to_radians().sin() + 0.12;
            Placed {
                shape: Shape::Disc { radius: r },
                lift,
                footprint: r,
                rotation_axis: axis,
                rotation_deg: tilt,
                label: "plate",
            }
        }
    }
}

/// A ground position for a footprint of `radius` that clears `placed` and satisfies `clear`;
/// `None` when no free spot turns up (the object is then left out, deterministically).
pub(super) fn place(
    rng: &mut Rng,
    radius: f64,
    placed: &[([f64; 2], f64)],
    clear: impl Fn([f64; 2]) -> bool,
) -> Option<[f64; 2]> {
    let lim = GROUND_HALF - radius - 0.05;
    for _ in 0..500 {
        let xy = [q(rng.range(-lim, lim)), q(rng.range(-lim, lim))];
        let free = placed
            .iter()
            .all(|(c, r)| (xy[0] - c[0]).hypot(xy[1] - c[1]) >= r + radius + 0.08);
        if xy[0].hypot(xy[1]) + radius <= LAYOUT_RADIUS && free && clear(xy) {
            return Some(xy);
        }
    }
    None
}

/// Adds up to `count` static objects of the given kinds, standing on the ground.
pub(super) fn add_static_objects(
    rng: &mut Rng,
    objects: &mut Vec<Object>,
    kinds: &[Kind],
    count: usize,
    clear: impl Fn([f64; 2], f64) -> bool,
) {
    let mut placed: Vec<([f64; 2], f64)> = Vec::new();
    for &kind in kinds.iter().take(count) {
        let p = random_shape(rng, kind);
        let texture = random_texture(rng);
        if let Some(xy) = place(rng, p.footprint, &placed, |xy| clear(xy, p.footprint)) {
            placed.push((xy, p.footprint));
            objects.push(Object {
                name: format!("{}_{}", p.label, objects.len()),
                shape: p.shape,
                texture,
                position: qv([xy[0], xy[1], GROUND_Z + p.lift]),
                rotation_axis: p.rotation_axis,
                rotation_deg: p.rotation_deg,
                motion: Motion::identity(),
            });
        }
    }
}

/// Static preset: ground square plus 3 to 5 objects of different kinds.
fn static_objects(seed: u64) -> Vec<Object> {
    let mut rng = Rng::new(seed, STREAM_LAYOUT);
    let mut objects = vec![ground(&mut rng)];
    let mut kinds = [Kind::Sphere, Kind::Cube, Kind::Block, Kind::Pillar, Kind::Plate];
    rng.shuffle(&mut kinds);
    let count = 3 + rng.below(3);
    add_static_objects(&mut rng, &mut objects, &kinds, count, |_, _| true);
    objects
}

/// The video camera path: an arc around the origin, looking at it, possibly closing in
/// (forward motion) and shaken per frame (hand-held).
pub(super) struct CameraPath {
    pub az_mid_deg: f64,
    pub el_deg: f64,
    /// Azimuth swept over the whole sequence.
    pub arc_deg: f64,
    /// Elevation rises by this much mid-sequence (half a sine).
    pub bob_deg: f64,
    /// Distance from the origin at the first and the last frame.
    pub radius: [f64; 2],
    /// Hand-held shake of the training frames: per-frame azimuth/elevation offsets up to this
    /// many degrees, and look-at offsets up to a tenth of it in scene units; 0 = none.
    pub shake_deg: f64,
}

impl CameraPath {
    /// The `dynamic` preset's path: an 80° arc at radius 4.
    pub(super) fn arc(az_mid_deg: f64, el_deg: f64) -> Self {
        CameraPath {
            az_mid_deg,
            el_deg,
            arc_deg: ARC_DEG,
            bob_deg: 6.0,
            radius: [CAMERA_RADIUS; 2],
            shake_deg: 0.0,
        }
    }

    /// Camera position at path parameter s ∈ [0, 1] (s = time for the training frames).
    fn eye(&self, s: f64, extra_az_deg: f64, extra_el_deg: f64) -> Vec3 {
        let az = self.az_mid_deg + self.arc_deg * (s - 0.5) + extra_az_deg;
        let el = self.el_deg + self.bob_deg * (std::f64::consts::PI * s).sin() + extra_el_deg;
        let radius = self.radius[0] + (self.radius[1] - self.radius[0]) * s;
        spherical(radius, az, el)
    }
}

/// Video presets: ground, one or two static objects and a floating cube that (when `moving`)
/// travels 0.75-0.95 units across the ground with a small vertical bob and turns 90° about a
/// near-vertical axis. The layout is drawn identically whether or not it moves.
fn video_layout(seed: u64, moving: bool) -> (Vec<Object>, CameraPath) {
    let mut rng = Rng::new(seed, STREAM_LAYOUT);
    let mut objects = vec![ground(&mut rng)];

    let phi = rng.range(0.0, 360.0).to_radians();
    let (dir, perp) = ([phi.cos(), phi.sin(), 0.0], [-phi.sin(), phi.cos(), 0.0]);
    let travel = rng.range(0.75, 0.95);
    let start = math::add(
        math::add(
            math::scale(dir, -0.5 * travel),
            math::scale(perp, rng.range(-0.2, 0.2)),
        ),
        [0.0, 0.0, GROUND_Z + MOVER_LIFT],
    );
    let start = qv(start);
    let displacement = qv(math::scale(dir, travel));
    let spin_axis = qv(math::normalize([
        rng.range(-0.35, 0.35),
        rng.range(-0.35, 0.35),
        1.0,
    ]));
    let spin_deg = if rng.coin() { 90.0 } else { -90.0 };
    let hue = rng.unit();
    let cells = q(rng.range(6.0, 8.0));
    let mover_texture = texture(
        &mut rng,
        Pattern::Checker {
            cells_per_unit: cells,
        },
        [hsv(hue, 0.85, 1.0), hsv(hue + 0.5, 0.8, 0.45)],
    );
    let mut mover = Object {
        name: "mover".into(),
        shape: Shape::Box {
            half_extents: [MOVER_HALF; 3],
        },
        texture: mover_texture,
        position: start,
        rotation_axis: qv(rng.unit_vector()),
        rotation_deg: q(rng.range(0.0, 360.0)),
        motion: Motion {
            displacement,
            wobble: [0.0, 0.0, 0.1],
            wobble_cycles: 1.0,
            spin_axis,
            spin_deg,
            ..Motion::identity()
        },
    };
    if !moving {
        mover.motion = Motion::identity();
    }

    // Static objects keep clear of the cube's whole swept path (its half diagonal is the reach).
    let (a, b) = (
        [start[0], start[1]],
        [start[0] + displacement[0], start[1] + displacement[1]],
    );
    let reach = MOVER_HALF * 3f64.sqrt();
    let mut kinds = [Kind::Sphere, Kind::Block, Kind::Pillar];
    rng.shuffle(&mut kinds);
    let count = 1 + rng.below(2);
    add_static_objects(&mut rng, &mut objects, &kinds, count, |xy, r| {
        segment_distance(xy, a, b) >= r + reach + 0.1
    });
    objects.push(mover);

    // The camera looks across the motion, from either side.
    let side = if rng.coin() { 90.0 } else { -90.0 };
    let path = CameraPath::arc(
        phi.to_degrees() + side + rng.range(-20.0, 20.0),
        rng.range(25.0, 33.0),
    );
    (objects, path)
}

pub(super) fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ab, ap) = ([b[0] - a[0], b[1] - a[1]], [p[0] - a[0], p[1] - a[1]]);
    let len2 = ab[0] * ab[0] + ab[1] * ab[1];
    let s = if len2 > 0.0 {
        ((ap[0] * ab[0] + ap[1] * ab[1]) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (ap[0] - s * ab[0]).hypot(ap[1] - s * ab[1])
}

/// Index `m` of `count` spread evenly over 0..=max (rounded).
fn spread(m: usize, count: usize, max: usize) -> usize {
    if count <= 1 {
        max / 2
    } else {
        (m * max + (count - 1) / 2) / (count - 1)
    }
}

/// Training frames along the arc with time i/(N−1); test views: off-path cameras (±25° azimuth,
/// +12° elevation) at training times, then on-path cameras at mid-frame times.
/// With a shaken path, each training frame's eye and target move by its own draw from
/// `shake` (the held-out cameras stay on the smooth path).
pub(super) fn video_views(
    path: &CameraPath,
    frames: usize,
    test_views: usize,
    shake: &mut Rng,
) -> Vec<SynthView> {
    let last = frames.saturating_sub(1).max(1);
    let view = |name: String, split, kind, eye, time: f64| SynthView {
        name,
        split,
        kind,
        eye,
        target: [0.0; 3],
        time: q(time),
    };
    let mut views = Vec::with_capacity(frames + test_views);
    let dn = digits(frames);
    for k in 0..frames {
        let s = k as f64 / last as f64;
        let mut v = view(
            name(k, dn),
            Split::Train,
            ViewKind::Video,
            path.eye(s, 0.0, 0.0),
            s,
        );
        if path.shake_deg > 0.0 {
            let a = path.shake_deg;
            v.eye = path.eye(s, shake.range(-a, a), shake.range(-a, a));
            v.target = qv([0; 3].map(|_| shake.range(-0.1 * a, 0.1 * a)));
        }
        views.push(v);
    }
    let n_off = test_views.div_ceil(2);
    let dt = digits(test_views);
    for m in 0..n_off {
        let s = spread(m, n_off, frames.saturating_sub(1)) as f64 / last as f64;
        let az = if m % 2 == 0 { 25.0 } else { -25.0 };
        views.push(view(
            name(m, dt),
            Split::Test,
            ViewKind::OffPath,
            path.eye(s, az, 12.0),
            s,
        ));
    }
    for m in 0..test_views - n_off {
        let i = spread(m, test_views - n_off, frames.saturating_sub(2));
        let s = (i as f64 + 0.5) / last as f64;
        views.push(view(
            name(n_off + m, dt),
            Split::Test,
            ViewKind::MidFrame,
            path.eye(s, 0.0, 0.0),
            s,
        ));
    }
    views
}
