//! The synthetic scene generator, checked against independent analytic references: rigid
//! motions and primitive surfaces are recomputed here from the documented formulas, cameras
//! through `rays::pixel_rays` and `Camera::project`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nerf_data::camera::{Camera, Pose};
use nerf_data::image::Image;
use nerf_data::math::{self, Mat3, Vec3};
use nerf_data::npy::read_npy;
use nerf_data::rays::pixel_rays;
use nerf_synth::{
    Backdrop, MoverMotion, Object, PathKind, Preset, Scene, Shape, Speed, Split, SynthConfig, Variation,
    ViewKind, generate,
};
use serde_json::Value;

/// A folder under the system temp dir, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let p = std::env::temp_dir().join(format!("nerf-synth-test-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        TempDir(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn small(preset: Preset) -> SynthConfig {
    match preset {
        Preset::Static => SynthConfig::new(preset).with_size(40, 32).with_views(6, 3),
        _ => SynthConfig::new(preset).with_size(48, 36).with_views(6, 4),
    }
}

/// Reference pose of an object at time τ, straight from the documented formula
/// `x_w = R_m(τ)·R_0·S(τ)·x_l + position + displacement·τ + wobble·sin(2π·cycles·τ)`, with
/// `S(τ) = diag(1 + pulse·sin(2π·pulse_cycles·τ))`: `(R, diag of S, c)`.
fn reference_pose(o: &Object, tau: f64) -> (Mat3, Vec3, Vec3) {
    let r0 = math::axis_angle(o.rotation_axis, o.rotation_deg.to_radians());
    let m = &o.motion;
    let rm = math::axis_angle(m.spin_axis, (m.spin_deg * tau).to_radians());
    let wave = (2.0 * std::f64::consts::PI * m.wobble_cycles * tau).sin();
    let c = [0, 1, 2].map(|k| o.position[k] + m.displacement[k] * tau + m.wobble[k] * wave);
    let pulse = (2.0 * std::f64::consts::PI * m.pulse_cycles * tau).sin();
    let s = m.pulse.map(|a| 1.0 + a * pulse);
    (math::mat_mul(&rm, &r0), s, c)
}

fn reference_local(o: &Object, p: Vec3, tau: f64) -> Vec3 {
    let (r, s, c) = reference_pose(o, tau);
    let rotated = math::mat_vec(&math::transpose(&r), math::sub(p, c));
    [0, 1, 2].map(|k| rotated[k] / s[k])
}

fn reference_world(o: &Object, local: Vec3, tau: f64) -> Vec3 {
    let (r, s, c) = reference_pose(o, tau);
    math::add(math::mat_vec(&r, [0, 1, 2].map(|k| local[k] * s[k])), c)
}

/// How far a local point is from lying on the primitive's surface (0 = exactly on it).
fn surface_error(shape: &Shape, p: Vec3) -> f64 {
    match *shape {
        Shape::Sphere { radius } => (math::norm(p) - radius).abs(),
        Shape::Box { half_extents: h } => {
            // On the boundary: no coordinate beyond its face and at least one on a face.
            let excess = [0, 1, 2].map(|k| p[k].abs() - h[k]);
            excess.iter().copied().fold(f64::NEG_INFINITY, f64::max).abs()
        }
        Shape::Square { half_size } => {
            let outside = (p[0].abs() - half_size).max(0.0) + (p[1].abs() - half_size).max(0.0);
            p[2].abs() + outside
        }
        Shape::Disc { radius } => p[2].abs() + ((p[0] * p[0] + p[1] * p[1]).sqrt() - radius).max(0.0),
    }
}

/// Points that bound each shape, for checking the scene stays inside the Blender box.
fn extreme_points(shape: &Shape) -> Vec<Vec3> {
    let corners = |h: Vec3| {
        (0..8)
            .map(|c| [0, 1, 2].map(|k| if (c >> k) & 1 == 1 { h[k] } else { -h[k] }))
            .collect::<Vec<_>>()
    };
    match *shape {
        Shape::Box { half_extents } => corners(half_extents),
        Shape::Square { half_size } => corners([half_size, half_size, 0.0]),
        Shape::Sphere { radius } | Shape::Disc { radius } => corners([radius; 3]),
    }
}

/// The world point seen through pixel `p` at the given depth, via the shared ray generator.
fn lift(cam: &Camera, p: usize, depth: f32) -> Vec3 {
    let rays = pixel_rays(cam, [p as u32]);
    let (o, d) = (rays.origin(0), rays.direction(0));
    [0, 1, 2].map(|k| o[k] as f64 + depth as f64 * d[k] as f64)
}

fn files_under(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.insert(
                    path.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&path).unwrap(),
                );
            }
        }
    }
    out
}

fn read_json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

#[test]
fn same_seed_gives_same_bytes_and_other_seeds_differ() {
    let (a, b, c) = (
        TempDir::new("det-a"),
        TempDir::new("det-b"),
        TempDir::new("det-c"),
    );
    let cfg = small(Preset::Dynamic).with_seed(7);
    let summary = generate(&cfg, &a.0).unwrap();
    generate(&cfg, &b.0).unwrap();
    generate(&cfg.clone().with_seed(8), &c.0).unwrap();
    let (fa, fb, fc) = (files_under(&a.0), files_under(&b.0), files_under(&c.0));
    assert_eq!(summary.files_written, fa.len(), "the summary counts every file");
    assert_eq!(
        (summary.train_views, summary.test_views, summary.val_views),
        (6, 4, 4)
    );
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (path, bytes) in &fa {
        assert!(
            bytes == &fb[path],
            "{} differs between identical runs",
            path.display()
        );
    }
    for name in [
        "transforms_train.json",
        "scene.json",
        "train/r_000.png",
        "train/r_003.png",
    ] {
        let p = PathBuf::from(name);
        assert!(fa.contains_key(&p), "{name} missing");
        assert_ne!(fa[&p], fc[&p], "{name} should change with the seed");
    }
}

#[test]
fn depth_lifts_onto_the_surface_of_the_reported_object() {
    for preset in Preset::ALL {
        let scene = Scene::from_config(&small(preset).with_seed(3));
        let picks = [
            scene.views_in(Split::Train).next().unwrap(),
            scene.views_in(Split::Test).last().unwrap(),
        ];
        for view in picks {
            let cam = scene.camera(view);
            let out = scene.render(&cam, view.time);
            let (w, h) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize);
            assert_eq!(
                (out.rgba.width, out.rgba.height, out.rgba.channels),
                (w as u32, h as u32, 4)
            );
            assert_eq!((out.depth.len(), out.object_id.len()), (w * h, w * h));
            let mut foreground = 0;
            for p in 0..w * h {
                let (id, depth) = (out.object_id[p], out.depth[p]);
                if id < 0 {
                    assert_eq!(depth, 0.0, "background has depth 0");
                    continue;
                }
                foreground += 1;
                assert!(
                    (scene.near..=scene.far).contains(&(depth as f64)),
                    "depth {depth} outside [near, far]"
                );
                assert!(
                    out.rgba.pixel(p)[3] > 0.0,
                    "a pixel whose centre hits has coverage"
                );
                let x = lift(&cam, p, depth);
                let (u, v, z) = cam.project(x).unwrap();
                assert!(
                    (u - ((p % w) as f64 + 0.5)).abs() < 1e-4 && (v - ((p / w) as f64 + 0.5)).abs() < 1e-4
                );
                assert!(
                    (z - depth as f64).abs() < 1e-5 * z,
                    "ray parameter is camera depth"
                );
                let obj = &scene.objects[id as usize];
                let err = surface_error(&obj.shape, reference_local(obj, x, view.time));
                assert!(
                    err < 2e-5,
                    "{preset}: pixel {p} is {err} off the surface of {}",
                    obj.name
                );
            }
            // Movers alone on white fill less of the frame than a set on a ground square.
            let least = if preset == Preset::JumpingMovers {
                w * h / 20
            } else {
                w * h / 4
            };
            assert!(
                foreground > least,
                "{preset}: only {foreground} of {} pixels show the scene",
                w * h
            );
        }
    }
}

#[test]
fn static_flow_is_the_reprojection_of_the_depth() {
    let scene = Scene::from_config(&small(Preset::Static).with_size(64, 48).with_seed(5));
    let cam_a = scene.camera(&scene.views[0]);
    // A nearby second camera: the first one turned 3° about the vertical axis.
    let eye_b = math::mat_vec(
        &math::axis_angle([0.0, 0.0, 1.0], 3f64.to_radians()),
        scene.views[0].eye,
    );
    let cam_b = Camera::new(cam_a.intrinsics, Pose::look_at(eye_b, [0.0; 3], [0.0, 0.0, 1.0]));
    let (flow, mask) = scene.optical_flow(&cam_a, 0.0, &cam_b, 0.0);
    let (ra, rb) = (scene.render(&cam_a, 0.0), scene.render(&cam_b, 0.0));
    let (w, h) = (64usize, 48usize);
    assert_eq!((flow.len(), mask.len()), (2 * w * h, w * h));
    let (mut valid, mut fg, mut same_object) = (0, 0, 0);
    for p in 0..w * h {
        if ra.object_id[p] < 0 {
            assert_eq!(
                (mask[p], flow[2 * p], flow[2 * p + 1]),
                (0.0, 0.0, 0.0),
                "background has no flow"
            );
            continue;
        }
        fg += 1;
        if mask[p] == 0.0 {
            continue;
        }
        valid += 1;
        let (u, v, _) = cam_b.project(lift(&cam_a, p, ra.depth[p])).unwrap();
        let want = [u - ((p % w) as f64 + 0.5), v - ((p / w) as f64 + 0.5)];
        for k in 0..2 {
            assert!(
                (flow[2 * p + k] as f64 - want[k]).abs() < 2e-3,
                "pixel {p}: flow {k} {} vs {}",
                flow[2 * p + k],
                want[k]
            );
        }
        // What camera b sees at the landing pixel is (almost always) the same object.
        let (bi, bj) = (u.floor() as usize, v.floor() as usize);
        same_object += (rb.object_id[bj * w + bi] == ra.object_id[p]) as usize;
    }
    assert!(
        valid * 10 >= fg * 8,
        "only {valid} of {fg} foreground pixels are visible in a 3° neighbour"
    );
    assert!(
        same_object * 100 >= valid * 97,
        "{same_object} of {valid} land on the same object"
    );

    // The same camera at the same time: zero flow, every foreground pixel visible.
    let (flow, mask) = scene.optical_flow(&cam_a, 0.0, &cam_a, 0.0);
    for p in 0..w * h {
        assert_eq!(mask[p], if ra.object_id[p] >= 0 { 1.0 } else { 0.0 });
        assert!(flow[2 * p].abs() < 1e-6 && flow[2 * p + 1].abs() < 1e-6);
    }
}

/// Checks every training pair of a video against the reference motions: scene flow carries
/// each surface point to the same material point, is zero on static objects, and the optical
/// flow is its projection wherever the mask says visible. Returns how many moving-object
/// pixels had their optical flow checked.
fn check_flow_against_scene_flow(scene: &Scene) -> usize {
    let movers = scene.moving_objects();
    let train: Vec<_> = scene.views_in(Split::Train).collect();
    let (w, h) = (scene.width as usize, scene.height as usize);
    let mut checked = 0;
    for k in 0..train.len() - 1 {
        let (va, vb) = (train[k], train[k + 1]);
        let (cam_a, cam_b) = (scene.camera(va), scene.camera(vb));
        let (flow, mask) = scene.optical_flow(&cam_a, va.time, &cam_b, vb.time);
        let ra = scene.render(&cam_a, va.time);
        for p in 0..w * h {
            let id = ra.object_id[p];
            if id < 0 {
                continue;
            }
            let x = lift(&cam_a, p, ra.depth[p]);
            let sf = scene
                .scene_flow(x, va.time, vb.time)
                .expect("a point on an object has scene flow");
            let moved = math::add(x, sf);
            let obj = &scene.objects[id as usize];
            if !movers.contains(&(id as usize)) {
                assert_eq!(sf, [0.0; 3], "static objects have zero scene flow");
                continue;
            }
            // The moved point is the same material point under the reference motion.
            let (la, lb) = (
                reference_local(obj, x, va.time),
                reference_local(obj, moved, vb.time),
            );
            assert!(
                math::norm(math::sub(la, lb)) < 1e-5,
                "scene flow of {} disagrees with the motion",
                obj.name
            );
            if mask[p] == 1.0 {
                let (u, v, _) = cam_b.project(moved).unwrap();
                let want = [u - ((p % w) as f64 + 0.5), v - ((p / w) as f64 + 0.5)];
                for c in 0..2 {
                    assert!((flow[2 * p + c] as f64 - want[c]).abs() < 2e-3);
                }
                checked += 1;
            }
        }
    }
    checked
}

#[test]
fn dynamic_flow_follows_the_scene_flow_of_the_moving_cube() {
    let scene = Scene::from_config(&small(Preset::Dynamic).with_size(64, 48).with_seed(11));
    assert!(scene.has_motion());
    let movers = scene.moving_objects();
    assert_eq!(movers.len(), 1, "exactly one object moves");
    let m = movers[0];
    let mover = &scene.objects[m];
    assert!(
        matches!(mover.shape, Shape::Box { .. }),
        "the moving object is a cube"
    );

    // Its documented motion: 0.5-1 unit of travel and a quarter turn over the sequence.
    let (r0, _, c0) = reference_pose(mover, 0.0);
    let (r1, _, c1) = reference_pose(mover, 1.0);
    let travel = math::norm(math::sub(c1, c0));
    assert!((0.5..=1.0).contains(&travel), "travel {travel}");
    let rel = math::mat_mul(&r1, &math::transpose(&r0));
    let angle = ((rel[0][0] + rel[1][1] + rel[2][2] - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    assert!((angle - 90.0).abs() < 1e-6, "rotation {angle}°");

    let checked = check_flow_against_scene_flow(&scene);
    assert!(checked > 50, "only {checked} visible cube pixels were checked");

    // Scene flow of a point in empty space is undefined; over no time it is zero.
    assert_eq!(scene.scene_flow([0.0, 0.0, 1.45], 0.0, 1.0), None);
    let on_cube = reference_world(mover, [0.25, 0.0, 0.0], 0.3);
    assert_eq!(scene.scene_flow(on_cube, 0.3, 0.3), Some([0.0; 3]));
    let want = math::sub(reference_world(mover, [0.25, 0.0, 0.0], 0.8), on_cube);
    let got = scene.scene_flow(on_cube, 0.3, 0.8).unwrap();
    assert!(math::norm(math::sub(got, want)) < 1e-9);
}

#[test]
fn static_video_is_the_dynamic_layout_without_motion() {
    let dynamic = Scene::from_config(&small(Preset::Dynamic).with_seed(4));
    let still = Scene::from_config(&small(Preset::StaticVideo).with_seed(4));
    assert!(!still.has_motion() && still.moving_objects().is_empty());
    assert_eq!(dynamic.objects.len(), still.objects.len());
    for (d, s) in dynamic.objects.iter().zip(&still.objects) {
        assert_eq!(
            (&d.shape, d.position, &d.texture),
            (&s.shape, s.position, &s.texture)
        );
        assert!(!s.is_moving());
    }
    assert_eq!(dynamic.views, still.views, "same cameras and times");
    let v = &still.views[2];
    let cam = still.camera(v);
    let out = still.render(&cam, v.time);
    for p in (0..out.depth.len()).filter(|&p| out.object_id[p] >= 0) {
        let sf = still
            .scene_flow(lift(&cam, p, out.depth[p]), v.time, 1.0)
            .unwrap();
        assert!(math::norm(sf) < 1e-12);
    }
}

#[test]
fn transforms_json_reads_as_blender_and_dnerf() {
    let dir = TempDir::new("json");
    let cfg = small(Preset::Dynamic).with_seed(2);
    generate(&cfg, &dir.0).unwrap();
    let (w, h, n) = (cfg.width as usize, cfg.height as usize, cfg.frames);

    let check_frames = |split: &str, json: &Value| -> Vec<f64> {
        let angle = json["camera_angle_x"].as_f64().unwrap();
        let fx = 0.5 * w as f64 / (0.5 * angle).tan();
        let mut times = Vec::new();
        for f in json["frames"].as_array().unwrap() {
            let file = f["file_path"].as_str().unwrap();
            assert!(file.starts_with(&format!("./{split}/r_")), "{file}");
            let img = Image::load(&dir.0.join(format!("{}.png", &file[2..]))).unwrap();
            assert_eq!((img.width, img.height, img.channels), (w as u32, h as u32, 4));
            assert!((f["fl_x"].as_f64().unwrap() - fx).abs() < 1e-9 && f["fl_y"] == f["fl_x"]);
            assert_eq!(
                (f["cx"].as_f64().unwrap(), f["cy"].as_f64().unwrap()),
                (w as f64 / 2.0, h as f64 / 2.0)
            );
            assert_eq!(
                (f["w"].as_u64().unwrap(), f["h"].as_u64().unwrap()),
                (w as u64, h as u64)
            );
            let m: Vec<Vec<f64>> = serde_json::from_value(f["transform_matrix"].clone()).unwrap();
            assert_eq!(m.len(), 4);
            assert_eq!(m[3], vec![0.0, 0.0, 0.0, 1.0]);
            for a in 0..3 {
                for b in 0..3 {
                    let dot: f64 = (0..3).map(|r| m[r][a] * m[r][b]).sum();
                    assert!(
                        (dot - if a == b { 1.0 } else { 0.0 }).abs() < 1e-9,
                        "rotation is orthonormal"
                    );
                }
            }
            let radius = (m[0][3].powi(2) + m[1][3].powi(2) + m[2][3].powi(2)).sqrt();
            assert!(
                (radius - 4.0).abs() < 1e-6 && m[2][3] > 0.0,
                "camera on the upper sphere of radius 4"
            );
            // The camera looks at the origin: its −z axis points from the centre to the origin.
            let look = [0, 1, 2].map(|r| -m[r][2]);
            let to_origin = [0, 1, 2].map(|r| -m[r][3] / radius);
            assert!(math::dot(look, to_origin) > 1.0 - 1e-9);
            let t = f["time"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&t));
            times.push(t);
        }
        times
    };

    let train = read_json(&dir.0.join("transforms_train.json"));
    let times = check_frames("train", &train);
    assert_eq!(times.len(), n);
    for (i, t) in times.iter().enumerate() {
        assert!(
            (t - i as f64 / (n - 1) as f64).abs() < 1e-8,
            "video time is i/(N-1)"
        );
    }
    assert!(times.windows(2).all(|p| p[0] <= p[1]));
    let test = read_json(&dir.0.join("transforms_test.json"));
    let test_times = check_frames("test", &test);
    assert_eq!(test_times.len(), cfg.test_views);
    let scene = Scene::load(&dir.0).unwrap();
    for (v, t) in scene.views_in(Split::Test).zip(&test_times) {
        let frame = t * (n - 1) as f64;
        match v.kind {
            ViewKind::OffPath => assert!(
                (frame - frame.round()).abs() < 1e-7,
                "off-path views use training times"
            ),
            ViewKind::MidFrame => assert!((frame - frame.floor() - 0.5).abs() < 1e-7, "mid-frame times"),
            k => panic!("unexpected test view kind {k:?}"),
        }
    }
    assert_eq!(read_json(&dir.0.join("transforms_val.json")), test);

    // Ground truth arrays: shapes, depth equal to a fresh render, no flow past the ends.
    let gt = dir.0.join("gt/train");
    let depth = read_npy(&gt.join("r_002_depth.npy")).unwrap();
    assert_eq!(
        (depth.shape.as_slice(), depth.dtype.as_str()),
        ([h, w].as_slice(), "<f4")
    );
    let v = scene.views_in(Split::Train).nth(2).unwrap();
    assert_eq!(depth.to_f32(), scene.render(&scene.camera(v), v.time).depth);
    let flow = read_npy(&gt.join("r_002_flow_fwd.npy")).unwrap();
    assert_eq!(flow.shape, vec![h, w, 2]);
    assert!(flow.data.iter().any(|&f| f != 0.0));
    let first_bwd = read_npy(&gt.join("r_000_flow_bwd_mask.npy")).unwrap();
    let last_fwd = read_npy(&gt.join(format!("r_{:03}_flow_fwd_mask.npy", n - 1))).unwrap();
    assert_eq!(first_bwd.shape, vec![h, w]);
    assert!(first_bwd.data.iter().chain(&last_fwd.data).all(|&m| m == 0.0));
    let mid_mask = read_npy(&gt.join("r_003_flow_bwd_mask.npy")).unwrap();
    assert!(mid_mask.data.iter().filter(|&&m| m == 1.0).count() > w * h / 4);
    assert!(dir.0.join("gt/test/r_000_depth.npy").is_file());

    // The static preset is plain Blender: no time.
    let dir_s = TempDir::new("json-static");
    generate(&small(Preset::Static), &dir_s.0).unwrap();
    let stat = read_json(&dir_s.0.join("transforms_train.json"));
    assert!(stat["camera_angle_x"].is_f64());
    let frames = stat["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 6);
    assert!(
        frames
            .iter()
            .all(|f| f.get("time").is_none() && f["file_path"].is_string())
    );
}

#[test]
fn reloaded_scene_is_identical_and_renders_identically() {
    let dir = TempDir::new("reload");
    let cfg = small(Preset::Dynamic).with_seed(9);
    generate(&cfg, &dir.0).unwrap();
    let original = Scene::from_config(&cfg);
    let loaded = Scene::load(&dir.0).unwrap();
    assert_eq!(loaded, original, "scene.json round-trips exactly");
    assert_eq!(Scene::load(&dir.0.join("scene.json")).unwrap(), original);
    let view = loaded.views_in(Split::Test).last().unwrap();
    let cam = loaded.camera(view);
    assert_eq!(loaded.render(&cam, view.time), original.render(&cam, view.time));
    let saved = Image::load(&dir.0.join(format!("test/{}.png", view.name))).unwrap();
    let fresh = loaded.render(&cam, view.time).rgba;
    assert_eq!(saved.to_u8(), fresh.to_u8(), "the PNG is the render");

    // Broken descriptions fail with an error naming the file.
    let bad = dir.0.join("broken");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("scene.json"), b"{ \"format\": 3").unwrap();
    let err = Scene::load(&bad).unwrap_err().to_string();
    assert!(err.contains("scene.json") && err.contains("broken"), "{err}");
    let mut wrong = original.clone();
    wrong.objects[1].shape = Shape::Sphere { radius: -1.0 };
    std::fs::write(bad.join("scene.json"), wrong.to_json()).unwrap();
    let err = Scene::load(&bad).unwrap_err().to_string();
    assert!(err.contains("scene.json") && err.contains("positive"), "{err}");
    let err = Scene::load(&dir.0.join("missing")).unwrap_err().to_string();
    assert!(err.contains("missing"), "{err}");
}

#[test]
fn scenes_fit_the_blender_bounds() {
    for preset in Preset::ALL {
        for seed in 0..6 {
            let scene = Scene::from_config(&SynthConfig::new(preset).with_seed(seed));
            let reparsed: Scene = serde_json::from_str(&scene.to_json()).unwrap();
            assert!(
                reparsed == scene,
                "{preset} seed {seed}: scene.json does not round-trip exactly"
            );
            let extra = scene.objects.iter().filter(|o| o.name != "ground").count();
            match preset {
                Preset::Static => assert!((3..=5).contains(&extra), "{extra} objects"),
                Preset::Family | Preset::Jumping => assert!(scene.has_motion()),
                Preset::JumpingMovers => {
                    // Movers alone (and at most a plate): nothing static but the ground.
                    assert!((1..=3).contains(&extra), "{extra} movers");
                    let still = scene.objects.iter().filter(|o| !o.is_moving());
                    assert!(still.map(|o| o.name.as_str()).all(|n| n == "ground"));
                }
                _ => assert!((2..=3).contains(&extra), "{extra} objects besides the ground"),
            }
            for o in &scene.objects {
                for step in 0..=10 {
                    let tau = step as f64 / 10.0;
                    if let Shape::Sphere { radius } = o.shape {
                        // A (squashed) sphere lies inside the sphere of its largest axis.
                        let (_, s, c) = reference_pose(o, tau);
                        let r = radius * s.iter().fold(0.0f64, |a, b| a.max(b.abs()));
                        assert!(
                            c.iter().all(|v| v.abs() + r <= 1.5),
                            "{preset} seed {seed}: {} leaves the box",
                            o.name
                        );
                        continue;
                    }
                    for p in extreme_points(&o.shape) {
                        let x = reference_world(o, p, tau);
                        assert!(
                            x.iter().all(|v| v.abs() <= 1.5),
                            "{preset} seed {seed}: {} leaves the box",
                            o.name
                        );
                    }
                }
            }
            // The family's forward paths close in from 4 to 3.4.
            let radius = if preset == Preset::Family {
                3.4..=4.0
            } else {
                4.0..=4.0
            };
            for v in &scene.views {
                let r = math::norm(v.eye);
                assert!(r > radius.start() - 1e-6 && r < radius.end() + 1e-6 && v.eye[2] > 0.0);
                assert!((0.0..=1.0).contains(&v.time));
            }
        }
    }
}

#[test]
fn presets_and_configs() {
    for p in Preset::ALL {
        assert_eq!(p.to_string().parse::<Preset>().unwrap(), p);
    }
    for k in [
        ViewKind::Orbit,
        ViewKind::Video,
        ViewKind::OffPath,
        ViewKind::MidFrame,
    ] {
        assert_eq!(
            serde_json::to_value(k).unwrap(),
            k.as_str(),
            "as_str is scene.json's name"
        );
    }
    assert_eq!("static-video".parse::<Preset>().unwrap(), Preset::StaticVideo);
    assert!("bouncing".parse::<Preset>().unwrap_err().contains("bouncing"));
    let d = SynthConfig::new(Preset::Dynamic);
    assert!(d.frames >= 24 && (d.width, d.height) == (128, 96));
    let s = SynthConfig::new(Preset::Static);
    assert!(s.frames >= 100 && s.test_views > 0);

    // The layout does not depend on how many views are asked for.
    let few = Scene::from_config(&small(Preset::Static));
    let many = Scene::from_config(&small(Preset::Static).with_views(20, 9));
    assert_eq!(few.objects, many.objects);
    assert_eq!(few.views[..6], many.views[..6]);

    let dir = TempDir::new("bad-config");
    let err = generate(&small(Preset::Dynamic).with_views(1, 0), &dir.0)
        .unwrap_err()
        .to_string();
    assert!(err.contains("frames") && err.contains("bad-config"), "{err}");
    assert!(!dir.0.exists(), "nothing is written for an invalid config");
}

/// Generation time of the default presets (release build):
/// `cargo test -p nerf-synth --release --test synth -- --ignored --nocapture`.
#[test]
#[ignore]
fn generation_time_of_default_presets() {
    for preset in Preset::ALL {
        let dir = TempDir::new(&format!("timing-{preset}"));
        let cfg = SynthConfig::new(preset);
        let start = std::time::Instant::now();
        let summary = generate(&cfg, &dir.0).unwrap();
        let total = start.elapsed();
        let scene = Scene::from_config(&cfg);
        let v = &scene.views[0];
        let cam = scene.camera(v);
        let start = std::time::Instant::now();
        for _ in 0..10 {
            std::hint::black_box(scene.render(&cam, v.time));
        }
        println!(
            "{preset}: {}x{}, {} train + {} test views, {} files in {:.2} s; one render {:.1} ms",
            cfg.width,
            cfg.height,
            summary.train_views,
            summary.test_views,
            summary.files_written,
            total.as_secs_f64(),
            start.elapsed().as_secs_f64() * 100.0
        );
    }
}

#[test]
fn the_blender_loader_reads_the_generated_folder() {
    let dir = TempDir::new("blender-load");
    let cfg = small(Preset::Dynamic).with_seed(1);
    generate(&cfg, &dir.0).unwrap();
    let scene = Scene::from_config(&cfg);
    let data = nerf_data::blender::load(&dir.0, &nerf_data::LoadOptions::default()).unwrap();
    assert_eq!(data.format, nerf_data::Format::DNerf);
    assert_eq!((data.train.len(), data.test.len()), (cfg.frames, cfg.test_views));
    let ours: Vec<_> = scene.views_in(Split::Train).collect();
    for (&i, v) in data.train.iter().zip(&ours) {
        let (loaded, want) = (&data.views[i], scene.camera(v));
        assert_eq!(loaded.camera.intrinsics, want.intrinsics);
        assert_eq!(loaded.time, Some(v.time as f32));
        for r in 0..3 {
            for c in 0..3 {
                assert!((loaded.camera.pose.rotation[r][c] - want.pose.rotation[r][c]).abs() < 1e-12);
            }
            assert!((loaded.camera.pose.translation[r] - want.pose.translation[r]).abs() < 1e-12);
        }
    }
}

/// `--mono-disparity`: every training frame gets `disp/train/<name>.npy`, the D-NeRF loader
/// reads it as the video's disparity prior, and each frame's disparity is an affine function
/// of the true inverse depth after the documented smoothing, up to the noise (a least-squares
/// fit per frame against the ground-truth depth: positive scale, high correlation).
/// A disparity file of the wrong size is an error naming the file.
#[test]
fn mono_disparity_is_affine_in_true_inverse_depth_and_loads_as_a_prior() {
    let dir = TempDir::new("disp");
    let mut cfg = small(Preset::Dynamic).with_seed(4);
    cfg.mono_disparity = Some(nerf_synth::DisparityErrors::Clean);
    generate(&cfg, &dir.0).unwrap();
    let opts = nerf_data::LoadOptions::default();
    let ds = nerf_data::load::load_video(&dir.0, &opts).unwrap();
    let priors = ds.priors.as_ref().expect("disp/ is read as a prior");
    assert_eq!(priors.disparity.len(), ds.views.len());
    let mut slopes = Vec::new();
    for (i, view) in ds.views.iter().enumerate() {
        let disp = &priors.disparity[i];
        if !ds.train.contains(&i) {
            assert!(disp.is_none(), "{}: test views have no prior", view.name);
            continue;
        }
        let disp = disp
            .as_ref()
            .unwrap_or_else(|| panic!("{}: no disparity", view.name));
        let depth = read_npy(&dir.0.join("gt").join(format!("{}_depth.npy", view.name)))
            .unwrap()
            .to_f32();
        // The documented smoothing, recomputed here: 3x3 box mean of 1/z (0 on background),
        // clipped at the borders; the disparity must be affine in it up to the noise.
        let (w, h) = (cfg.width as usize, cfg.height as usize);
        let inv: Vec<f64> = depth
            .iter()
            .map(|&z| if z > 0.0 { 1.0 / z as f64 } else { 0.0 })
            .collect();
        let (mut xs, mut ys) = (Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let (mut sum, mut count) = (0.0, 0.0);
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        sum += inv[yy * w + xx];
                        count += 1.0;
                    }
                }
                xs.push(sum / count);
                ys.push(disp[y * w + x] as f64);
            }
        }
        assert!(
            xs.len() > 100,
            "{}: too few flat pixels ({})",
            view.name,
            xs.len()
        );
        let n = xs.len() as f64;
        let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
        let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
        let syy: f64 = ys.iter().map(|y| (y - my).powi(2)).sum();
        let slope = sxy / sxx;
        let corr = sxy / (sxx * syy).sqrt();
        // Noise of 5 % of the mean disparity against a signal spread of about 0.1.
        assert!(
            slope > 0.0 && corr > 0.9,
            "{}: slope {slope}, correlation {corr}",
            view.name
        );
        slopes.push(slope);
    }
    // The scale differs from frame to frame (what makes the prior scale-invariant per frame).
    let (lo, hi) = slopes
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &s| (a.min(s), b.max(s)));
    assert!(hi / lo > 1.2, "per-frame scales {slopes:?}");

    // A disparity of the wrong size names its file.
    let bad = dir.0.join("disp/train/r_001.npy");
    nerf_data::npy::write_npy(&bad, &[3, 4], &[0.5; 12]).unwrap();
    let err = nerf_data::load::load_video(&dir.0, &opts)
        .unwrap_err()
        .to_string();
    assert!(err.contains("r_001.npy") && err.contains("disparity"), "{err}");
}

#[test]
fn family_members_cover_every_axis_of_variation() {
    let members: Vec<Variation> = (0..48).map(Variation::draw).collect();
    for (seed, v) in members.iter().enumerate().take(16) {
        println!("seed {seed:>2}: {}", v.describe());
    }
    let any = |f: &dyn Fn(&Variation) -> bool| members.iter().any(f);
    for b in [Backdrop::OpenFloor, Backdrop::Walls, Backdrop::Distant] {
        assert!(any(&|v| v.backdrop == b), "{b:?} never drawn");
    }
    for p in [
        PathKind::ShortArc,
        PathKind::WideArc,
        PathKind::Forward,
        PathKind::HandHeld,
    ] {
        assert!(any(&|v| v.path == p), "{p:?} never drawn");
    }
    for m in [
        MoverMotion::Translate,
        MoverMotion::Spin,
        MoverMotion::Deform,
        MoverMotion::TranslateSpin,
    ] {
        for s in [Speed::Slow, Speed::Fast] {
            assert!(any(&|v| v.movers.contains(&(m, s))), "{m:?} {s:?} never drawn");
        }
    }
    for n in 1..=3 {
        assert!(any(&|v| v.movers.len() == n), "{n} movers never drawn");
    }
    for f in [16, 24, 32] {
        assert!(any(&|v| v.frames == f));
    }
    for w in [96, 128, 160] {
        assert!(any(&|v| v.width == w && v.height * 4 == w * 3));
    }
    // The seeded config takes the member's frame count and size; the scene records it.
    let cfg = SynthConfig::seeded(Preset::Family, 5);
    assert_eq!(
        (cfg.frames, cfg.width, cfg.height),
        (members[5].frames, members[5].width, members[5].height)
    );
    let scene = Scene::from_config(&cfg);
    assert_eq!(scene.variation.as_ref(), Some(&members[5]));
    assert_eq!(scene.moving_objects().len(), members[5].movers.len());
}

/// The first family seed whose draw satisfies `want`.
fn family_seed(want: impl Fn(&Variation) -> bool) -> u64 {
    (0..200)
        .find(|&s| want(&Variation::draw(s)))
        .expect("some seed draws it")
}

#[test]
fn family_flow_follows_the_scene_flow_of_deforming_and_several_movers() {
    let deform = family_seed(|v| v.movers.iter().any(|m| m.0 == MoverMotion::Deform));
    let several = family_seed(|v| v.movers.len() >= 2 && v.path == PathKind::HandHeld);
    for seed in [deform, several] {
        let cfg = SynthConfig::seeded(Preset::Family, seed)
            .with_size(64, 48)
            .with_views(5, 2);
        let scene = Scene::from_config(&cfg);
        let checked = check_flow_against_scene_flow(&scene);
        assert!(checked > 20, "seed {seed}: only {checked} mover pixels checked");
        // Movers never overlap, at any time.
        let movers = scene.moving_objects();
        for step in 0..=20 {
            let tau = step as f64 / 20.0;
            for (i, &a) in movers.iter().enumerate() {
                for &b in &movers[i + 1..] {
                    let (oa, ob) = (&scene.objects[a], &scene.objects[b]);
                    let d = math::norm(math::sub(
                        reference_world(oa, [0.0; 3], tau),
                        reference_world(ob, [0.0; 3], tau),
                    ));
                    let reach = |o: &Object| {
                        o.shape.bounding_radius()
                            * (1.0 + o.motion.pulse.iter().fold(0.0f64, |m, p| m.max(p.abs())))
                    };
                    assert!(
                        d >= reach(oa) + reach(ob),
                        "seed {seed}: movers meet at τ = {tau}"
                    );
                }
            }
        }
    }
    // A deforming mover really changes shape: its local axes stretch over time.
    let scene = Scene::from_config(&SynthConfig::seeded(Preset::Family, deform));
    let o = scene
        .objects
        .iter()
        .find(|o| !o.motion.is_rigid())
        .expect("a deforming mover");
    let (_, s, _) = reference_pose(o, 0.25 / o.motion.pulse_cycles);
    assert!(s.iter().any(|&v| v > 1.2) && s.iter().any(|&v| v < 0.95), "{s:?}");
}

#[test]
fn family_depths_stay_within_the_blender_near_and_far() {
    for seed in 0..24 {
        let cfg = SynthConfig::seeded(Preset::Family, seed).with_size(32, 24);
        let scene = Scene::from_config(&cfg);
        for v in &scene.views {
            let out = scene.render(&scene.camera(v), v.time);
            for &d in out.depth.iter().filter(|d| **d > 0.0) {
                assert!(
                    (scene.near..=scene.far).contains(&(d as f64)),
                    "seed {seed}, view {}: depth {d} outside [near, far]",
                    v.name
                );
            }
        }
    }
}

/// `jumping_movers` is the D-NeRF kind of scene: most of what the cameras see moves, unlike
/// `jumping` (the dynamic preset's set, where one small cube moves).
#[test]
fn jumping_movers_show_mostly_moving_pixels() {
    let moving_share = |preset: Preset, seed: u64| {
        let scene = Scene::from_config(&SynthConfig::new(preset).with_seed(seed).with_size(48, 48));
        let movers = scene.moving_objects();
        let (mut hit, mut moving) = (0usize, 0usize);
        for v in scene.views_in(Split::Train).step_by(6) {
            for id in scene.render(&scene.camera(v), v.time).object_id {
                hit += usize::from(id >= 0);
                moving += usize::from(id >= 0 && movers.contains(&(id as usize)));
            }
        }
        moving as f64 / hit.max(1) as f64
    };
    for seed in 0..4 {
        let (movers, jumping) = (
            moving_share(Preset::JumpingMovers, seed),
            moving_share(Preset::Jumping, seed),
        );
        assert!(movers > 0.3, "seed {seed}: {movers:.2} of the seen pixels move");
        assert!(jumping < 0.2, "seed {seed}: jumping preset {jumping:.2}");
    }
}
