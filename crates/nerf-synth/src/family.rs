//! The `family` preset: monocular videos that vary in what makes dynamic reconstruction hard.
//! A seed draws one member: the background (open floor, walls, a distant backdrop), how many
//! objects move and how (translation, spin, non-rigid squash and stretch; slow or fast), the
//! camera path (short or wide arc, forward motion, hand-held shake), the frame count and the
//! resolution. [`Variation`] records what was drawn; `scene.json` keeps it.

use serde::{Deserialize, Serialize};

use super::SynthConfig;
use super::presets::{
    CameraPath, GROUND_HALF, GROUND_Z, Kind, LAYOUT_RADIUS, Rng, STREAM_LAYOUT, STREAM_SHAKE,
    STREAM_VARIATION, add_static_objects, ground, palette, q, qv, random_shape, random_texture,
    segment_distance, texture, video_views,
};
use super::scene::{Motion, Object, Scene, Shape};
use super::texture::Pattern;
use nerf_data::math::{self, Vec3};

/// What stands behind the objects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Backdrop {
    /// The ground square alone; rays past it see the white background.
    OpenFloor,
    /// A striped back wall and a checkered side wall meeting the floor.
    Walls,
    /// A small floor in front of a large textured plane at the far edge of the box, with a
    /// depth gap between them.
    Distant,
    /// `jumping_movers`: a small plate under the movers and nothing else.
    Plate,
    /// `jumping_movers`: the movers alone on white.
    Nothing,
}

/// How one moving object moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MoverMotion {
    /// Straight travel with a vertical bob, no rotation.
    Translate,
    /// Rotation in place with a slight drift.
    Spin,
    /// Non-rigid squash and stretch along the object's axes, with a slight drift.
    Deform,
    /// Travel and rotation together (the `dynamic` preset's cube).
    TranslateSpin,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Speed {
    Slow,
    Fast,
}

/// The camera path of the video.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathKind {
    /// 30-40° of azimuth: little parallax.
    ShortArc,
    /// 90-110° of azimuth.
    WideArc,
    /// Closing in from radius 4 to 3.4 over a 10° arc.
    Forward,
    /// A 45-60° arc shaken per frame (eye ±1.2°, target ±0.12).
    HandHeld,
    /// `jumping_movers`: a random viewpoint every frame (not a video).
    Jumping,
}

/// One member of the family: what a seed drew.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Variation {
    pub backdrop: Backdrop,
    /// One entry per moving object.
    pub movers: Vec<(MoverMotion, Speed)>,
    pub path: PathKind,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
}

fn name_of<T: Serialize>(v: &T) -> String {
    serde_json::to_value(v)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

impl Variation {
    /// The member `seed` draws (its own random stream: the layout does not shift it).
    pub fn draw(seed: u64) -> Self {
        let mut rng = Rng::new(seed, STREAM_VARIATION);
        let backdrop = [Backdrop::OpenFloor, Backdrop::Walls, Backdrop::Distant][rng.below(3)];
        let count = [1, 1, 2, 2, 3][rng.below(5)];
        let movers = draw_motions(&mut rng, count);
        let path = [
            PathKind::ShortArc,
            PathKind::WideArc,
            PathKind::Forward,
            PathKind::HandHeld,
        ][rng.below(4)];
        let frames = [16, 24, 32][rng.below(3)];
        let (width, height) = [(96, 72), (128, 96), (160, 120)][rng.below(3)];
        Variation {
            backdrop,
            movers,
            path,
            frames,
            width,
            height,
        }
    }

    /// One line, e.g. `walls; movers: deform fast, translate slow; hand_held path; 24 frames at 128x96`.
    pub fn describe(&self) -> String {
        let movers: Vec<String> = self
            .movers
            .iter()
            .map(|(m, s)| format!("{} {}", name_of(m), name_of(s)))
            .collect();
        format!(
            "{}; movers: {}; {} path; {} frames at {}x{}",
            name_of(&self.backdrop),
            movers.join(", "),
            name_of(&self.path),
            self.frames,
            self.width,
            self.height
        )
    }
}

/// `count` movers' motions and speeds, each drawn uniformly.
fn draw_motions(rng: &mut Rng, count: usize) -> Vec<(MoverMotion, Speed)> {
    let motions = [
        MoverMotion::Translate,
        MoverMotion::Spin,
        MoverMotion::Deform,
        MoverMotion::TranslateSpin,
    ];
    (0..count)
        .map(|_| {
            let motion = motions[rng.below(4)];
            (motion, if rng.coin() { Speed::Fast } else { Speed::Slow })
        })
        .collect()
}

/// Wall thickness (walls are thin boxes, so they are solid from both sides).
const WALL_HALF_THICKNESS: f64 = 0.025;
/// Walls stand this far from the centre and reach this far along their edge: inside the
/// [-1.5, 1.5]³ box, and near enough that their far corners stay within camera depth 6.
const WALL_AT: f64 = 1.3;

/// Fills `scene` with the family member of `cfg.seed` (frames and size come from `cfg`).
pub(super) fn build(cfg: &SynthConfig, scene: &mut Scene) {
    let mut variation = Variation::draw(cfg.seed);
    (variation.frames, variation.width, variation.height) = (cfg.frames, cfg.width, cfg.height);
    let mut rng = Rng::new(cfg.seed, STREAM_LAYOUT);
    let mut objects = vec![ground(&mut rng)];

    // The back wall stands on one side of the box's axes; the camera looks at it.
    let axis = rng.below(4);
    let back = axis_direction(axis);
    let az_mid = match variation.backdrop {
        Backdrop::OpenFloor => rng.range(0.0, 360.0),
        _ => (-back[1]).atan2(-back[0]).to_degrees() + rng.range(-20.0, 20.0),
    };
    let path = camera_path(&mut rng, variation.path, az_mid);
    let mut shake = Rng::new(cfg.seed, STREAM_SHAKE);
    let views = video_views(&path, cfg.frames, cfg.test_views, &mut shake);

    match variation.backdrop {
        // The family never draws the movers preset's plate or nothing.
        Backdrop::OpenFloor | Backdrop::Plate | Backdrop::Nothing => {}
        Backdrop::Walls => {
            objects[0].shape = Shape::Square { half_size: WALL_AT };
            let stripes = Pattern::Stripes {
                direction: qv(math::normalize([rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 1.0])),
                stripes_per_unit: q(rng.range(3.0, 5.0)),
            };
            let colors = palette(&mut rng);
            let t = texture(&mut rng, stripes, colors);
            objects.push(wall("back_wall", axis, t, WALL_AT, 0.975, 0.475));
            // The side wall covers the back half of the side no camera comes near (a camera
            // beyond it would see the scene through the wall's back).
            let reach = |side: usize| {
                let d = axis_direction(side);
                views.iter().map(|v| math::dot(v.eye, d)).fold(f64::MIN, f64::max)
            };
            let side = [(axis + 1) % 4, (axis + 3) % 4]
                .into_iter()
                .min_by(|a, b| reach(*a).total_cmp(&reach(*b)))
                .unwrap_or(axis);
            let cells = Pattern::Checker {
                cells_per_unit: q(rng.range(2.0, 3.5)),
            };
            let colors = palette(&mut rng);
            let t = texture(&mut rng, cells, colors);
            if reach(side) < 0.5 {
                let mut w = wall("side_wall", side, t, 0.5 * WALL_AT, 0.975, 0.475);
                w.position = qv(math::add(w.position, math::scale(back, 0.5 * WALL_AT)));
                objects.push(w);
            }
        }
        Backdrop::Distant => {
            objects[0].shape = Shape::Square { half_size: 1.0 };
            let noise = Pattern::Noise {
                scale: q(rng.range(2.0, 3.5)),
            };
            let colors = palette(&mut rng);
            let t = texture(&mut rng, noise, colors);
            // Reaches below the floor (the depth gap) but not so low that it passes far = 6.
            objects.push(wall("backdrop", axis, t, WALL_AT, 1.075, 0.375));
        }
    }
    let floor_half = match objects[0].shape {
        Shape::Square { half_size } => half_size,
        _ => GROUND_HALF,
    };

    let mut movers: Vec<(Object, f64)> = Vec::new();
    for (k, &(motion, speed)) in variation.movers.iter().enumerate() {
        // A few hundred tries always find room for three small movers; one that does not fit
        // is left out deterministically.
        if let Some(m) =
            (0..300).find_map(|_| draw_mover(&mut rng, k, motion, speed, 1.0, floor_half, &movers))
        {
            movers.push(m);
        }
    }

    // Static objects keep clear of every mover's whole swept path.
    let paths: Vec<([f64; 2], [f64; 2], f64)> = movers
        .iter()
        .map(|(o, reach)| {
            let end = o.to_world([0.0; 3], 1.0);
            ([o.position[0], o.position[1]], [end[0], end[1]], *reach)
        })
        .collect();
    let mut kinds = [Kind::Sphere, Kind::Block, Kind::Pillar, Kind::Cube, Kind::Plate];
    rng.shuffle(&mut kinds);
    let count = 1 + rng.below(3);
    add_static_objects(&mut rng, &mut objects, &kinds, count, |xy, r| {
        paths
            .iter()
            .all(|(a, b, reach)| segment_distance(xy, *a, *b) >= r + reach + 0.1)
    });
    objects.extend(movers.into_iter().map(|(o, _)| o));

    scene.objects = objects;
    scene.views = views;
    scene.variation = Some(variation);
}

/// The camera path of `kind` around azimuth `az_mid` (degrees). Radii keep every surface
/// within camera depth [2, 6] (the Blender loader's near and far).
fn camera_path(rng: &mut Rng, kind: PathKind, az_mid: f64) -> CameraPath {
    let el = rng.range(22.0, 32.0);
    match kind {
        PathKind::ShortArc => CameraPath {
            arc_deg: q(rng.range(30.0, 40.0)),
            bob_deg: 3.0,
            ..CameraPath::arc(az_mid, el)
        },
        // The family never draws the movers preset's jumping camera.
        PathKind::WideArc | PathKind::Jumping => CameraPath {
            arc_deg: q(rng.range(90.0, 110.0)),
            ..CameraPath::arc(az_mid, el)
        },
        PathKind::Forward => CameraPath {
            arc_deg: 10.0,
            bob_deg: 2.0,
            radius: [4.0, 3.4],
            ..CameraPath::arc(az_mid, el)
        },
        PathKind::HandHeld => CameraPath {
            arc_deg: q(rng.range(45.0, 60.0)),
            bob_deg: 4.0,
            shake_deg: 1.2,
            ..CameraPath::arc(az_mid, el)
        },
    }
}

/// How much larger than the family's the `jumping_movers` movers are, for one, two and three
/// movers (so that several still fit side by side).
const MOVERS_SCALE: [f64; 3] = [1.8, 1.4, 1.15];
/// A `jumping_movers` mover keeps its bounding sphere this far inside the [-1.5, 1.5]³ box.
const MOVERS_BOX: f64 = 1.45;

/// Fills `scene` with the `jumping_movers` member of `cfg.seed`: one to three movers of the
/// family's motions, up to [`MOVERS_SCALE`] times the family's size, over a small plate for one seed
/// in three. The cameras are the caller's.
pub(super) fn build_movers(cfg: &SynthConfig, scene: &mut Scene) {
    let mut rng = Rng::new(cfg.seed, STREAM_VARIATION);
    let backdrop = if rng.below(3) == 0 {
        Backdrop::Plate
    } else {
        Backdrop::Nothing
    };
    let count = [1, 2, 2, 3][rng.below(4)];
    let drawn = draw_motions(&mut rng, count);

    let mut rng = Rng::new(cfg.seed, STREAM_LAYOUT);
    let mut objects = Vec::new();
    if backdrop == Backdrop::Plate {
        let mut plate = ground(&mut rng);
        plate.shape = Shape::Square { half_size: 0.9 };
        objects.push(plate);
    }
    let inside = |o: &Object, reach: f64| {
        (0..=20).all(|i| {
            let c = o.to_world([0.0; 3], i as f64 / 20.0);
            c.iter().all(|v| v.abs() + reach <= MOVERS_BOX)
        })
    };
    let mut movers: Vec<(Object, f64)> = Vec::new();
    let mut kept = Vec::new();
    for (k, &(motion, speed)) in drawn.iter().enumerate() {
        let fits = (0..300).find_map(|_| {
            draw_mover(
                &mut rng,
                k,
                motion,
                speed,
                MOVERS_SCALE[count - 1],
                GROUND_HALF,
                &movers,
            )
            .filter(|(o, reach)| inside(o, *reach))
        });
        if let Some(m) = fits {
            movers.push(m);
            kept.push((motion, speed));
        }
    }
    objects.extend(movers.into_iter().map(|(o, _)| o));
    scene.objects = objects;
    scene.variation = Some(Variation {
        backdrop,
        movers: kept,
        path: PathKind::Jumping,
        frames: cfg.frames,
        width: cfg.width,
        height: cfg.height,
    });
}

/// +x, +y, −x, −y for 0..4.
fn axis_direction(axis: usize) -> Vec3 {
    [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ][axis % 4]
}

/// A thin wall at distance [`WALL_AT`] in `axis`'s direction, centred on that axis, `half_length`
/// along the edge and `half_height` about `centre_z`.
fn wall(
    name: &str,
    axis: usize,
    texture: super::texture::Texture,
    half_length: f64,
    half_height: f64,
    centre_z: f64,
) -> Object {
    let d = axis_direction(axis);
    let half_extents = if d[0] != 0.0 {
        [WALL_HALF_THICKNESS, half_length, half_height]
    } else {
        [half_length, WALL_HALF_THICKNESS, half_height]
    };
    let offset = WALL_AT - WALL_HALF_THICKNESS;
    Object {
        name: name.into(),
        shape: Shape::Box { half_extents },
        texture,
        position: qv([d[0] * offset, d[1] * offset, centre_z]),
        rotation_axis: [0.0, 0.0, 1.0],
        rotation_deg: 0.0,
        motion: Motion::identity(),
    }
}

/// One try at a moving object (`scale` times the usual size) that stays over the floor, inside
/// the layout circle and clear of the movers already placed at every time: `(object, reach)`
/// with `reach` the radius of a sphere about its centre that holds it at all times.
fn draw_mover(
    rng: &mut Rng,
    k: usize,
    motion: MoverMotion,
    speed: Speed,
    scale: f64,
    floor_half: f64,
    placed: &[(Object, f64)],
) -> Option<(Object, f64)> {
    let fast = speed == Speed::Fast;
    let kind = [Kind::Cube, Kind::Sphere, Kind::Block][rng.below(3)];
    let mut shape = random_shape(rng, kind).shape;
    if scale != 1.0 {
        // Rounded like every stored parameter, so `scene.json` re-parses bit-identically.
        shape = shape.map_sizes(|v| q(v * scale));
    }
    let size = shape.bounding_radius();
    let pulse_amp = if motion == MoverMotion::Deform {
        q(rng.range(0.25, 0.35))
    } else {
        0.0
    };
    let reach = size * (1.0 + pulse_amp);
    let lift = rng.range(reach + 0.05, reach + 0.45);
    let travel = match (motion, fast) {
        (MoverMotion::Translate | MoverMotion::TranslateSpin, false) => rng.range(0.3, 0.5),
        (MoverMotion::Translate | MoverMotion::TranslateSpin, true) => rng.range(0.8, 1.1),
        _ => rng.range(0.05, 0.15),
    };
    let spin = match (motion, fast) {
        (MoverMotion::Spin, false) => rng.range(90.0, 150.0),
        (MoverMotion::Spin, true) => rng.range(240.0, 330.0),
        (MoverMotion::TranslateSpin, false) => rng.range(60.0, 90.0),
        (MoverMotion::TranslateSpin, true) => rng.range(150.0, 200.0),
        _ => 0.0,
    };
    let spin_deg = q(if rng.coin() { spin } else { -spin });
    let phi = rng.range(0.0, std::f64::consts::TAU);
    let limit = LAYOUT_RADIUS.min(floor_half) - reach;
    let start = [rng.range(-limit, limit), rng.range(-limit, limit)];
    let displacement = qv([phi.cos() * travel, phi.sin() * travel, 0.0]);
    let end = [start[0] + displacement[0], start[1] + displacement[1]];
    if start[0].hypot(start[1]) > limit || end[0].hypot(end[1]) > limit {
        return None;
    }
    let bob = if matches!(motion, MoverMotion::Translate | MoverMotion::TranslateSpin) {
        q(rng.range(0.03, 0.08).min(lift - reach - 0.01))
    } else {
        0.0
    };
    let cycles = if fast { 2.0 } else { 1.0 };
    let mut pulse = [0.0; 3];
    if pulse_amp > 0.0 {
        pulse = [-0.5 * pulse_amp; 3];
        pulse[rng.below(3)] = pulse_amp;
    }
    let texture = random_texture(rng);
    let object = Object {
        name: format!("mover_{k}"),
        shape,
        texture,
        position: qv([start[0], start[1], GROUND_Z + lift]),
        rotation_axis: qv(rng.unit_vector()),
        rotation_deg: q(rng.range(0.0, 360.0)),
        motion: Motion {
            displacement,
            wobble: [0.0, 0.0, bob],
            wobble_cycles: cycles,
            spin_axis: qv(math::normalize([
                rng.range(-0.35, 0.35),
                rng.range(-0.35, 0.35),
                1.0,
            ])),
            spin_deg,
            pulse: qv(pulse),
            pulse_cycles: if pulse_amp > 0.0 { cycles } else { 0.0 },
        },
    };
    let clear = (0..=20).all(|i| {
        let tau = i as f64 / 20.0;
        let c = object.to_world([0.0; 3], tau);
        placed
            .iter()
            .all(|(o, r)| math::norm(math::sub(c, o.to_world([0.0; 3], tau))) >= reach + r + 0.05)
    });
    clear.then_some((object, reach))
}
