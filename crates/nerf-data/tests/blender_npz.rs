//! Blender, D-NeRF and tiny npz loaders on the shared data and on small generated fixtures.

use std::path::{Path, PathBuf};

use nerf_data::npy::encode_npy;
use nerf_data::npz::write_zip;
use nerf_data::{Dataset, Format, Image, LoadOptions, blender, tiny_npz};

mod common;
use common::TempDir;

fn shared(rel: &str) -> Option<PathBuf> {
    match nerf_data::shared_data() {
        Some(root) => Some(root.join(rel)),
        None => {
            eprintln!("skipped: ../shared/data not found (set NERF_SHARED_DATA)");
            None
        }
    }
}

fn opts(downscale: u32) -> LoadOptions {
    LoadOptions {
        downscale,
        ..LoadOptions::default()
    }
}

/// An RGBA test image whose alpha is 0 in the first column and 1 elsewhere.
fn write_png(dir: &TempDir, rel: &str, w: u32, h: u32) {
    let mut data = Vec::new();
    for _y in 0..h {
        for x in 0..w {
            data.extend([0.2, 0.4, 0.6, if x == 0 { 0.0 } else { 1.0 }]);
        }
    }
    let p = dir.path().join(rel);
    Image::from_data(w, h, 4, data).save_png(&p).unwrap();
}

const IDENTITY_POSE: &str = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";

/// A transforms json with `camera_angle_x` and the given frame objects (as JSON text).
fn transforms(frames: &[String]) -> String {
    format!(r#"{{"camera_angle_x": 0.69, "frames": [{}]}}"#, frames.join(","))
}

fn frame(path: &str, extra: &str) -> String {
    format!(r#"{{"file_path": "{path}", "transform_matrix": {IDENTITY_POSE}{extra}}}"#)
}

fn load_err(dir: &Path) -> String {
    match blender::load(dir, &LoadOptions::default()) {
        Ok(_) => panic!("{} loaded but should have failed", dir.display()),
        Err(e) => e.to_string(),
    }
}

fn npz_err(path: &Path) -> String {
    match tiny_npz::load(path, &LoadOptions::default()) {
        Ok(_) => panic!("{} loaded but should have failed", path.display()),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "error should mention {p:?}: {msg}");
    }
}

#[test]
fn tiny_lego_npz() {
    let Some(path) = shared("lego_tiny/tiny_nerf_data.npz") else {
        return;
    };
    let ds = tiny_npz::load(&path, &LoadOptions::default()).unwrap();
    assert_eq!(ds.format, Format::TinyNpz);
    assert_eq!(ds.views.len(), 106);
    assert_eq!(ds.train, (0..100).collect::<Vec<_>>());
    assert_eq!(ds.test, (100..106).collect::<Vec<_>>());
    assert_eq!(ds.background, Some([0.0; 3]));
    assert_eq!((ds.near, ds.far), (2.0, 6.0));
    let k = ds.views[0].camera.intrinsics;
    assert_eq!((k.width, k.height), (100, 100));
    assert!((k.fx - 138.888_878_899_221).abs() < 1e-9, "focal {}", k.fx);
    assert_eq!((k.cx, k.cy), (50.0, 50.0));
    let (mut black, mut total) = (0usize, 0usize);
    for v in &ds.views {
        assert!(v.alpha.is_none());
        for px in v.image.data.chunks_exact(3) {
            black += usize::from(px.iter().all(|&c| c == 0.0));
            total += 1;
        }
    }
    let frac = black as f64 / total as f64;
    assert!((0.62..0.72).contains(&frac), "black fraction {frac}");
    for v in &ds.views {
        let r = nerf_data::math::norm(v.camera.pose.translation);
        assert!((r - 4.031).abs() < 0.01, "{}: camera radius {r}", v.name);
    }
}

#[test]
fn tiny_lego_npz_downscaled() {
    let Some(path) = shared("lego_tiny/tiny_nerf_data.npz") else {
        return;
    };
    let ds = tiny_npz::load(&path, &opts(2)).unwrap();
    let k = ds.views[101].camera.intrinsics;
    assert_eq!((k.width, k.height, ds.views[101].image.width), (50, 50, 50));
    assert!((k.fx - 138.888_878_899_221 / 2.0).abs() < 1e-9);
}

#[test]
fn blender_lego_quarter_resolution() {
    let Some(dir) = shared("nerf_synthetic/lego") else {
        return;
    };
    let start = std::time::Instant::now();
    let ds: Dataset = blender::load(&dir, &opts(4)).unwrap();
    eprintln!("lego /4 loaded in {:.2?}", start.elapsed());
    assert_eq!(ds.format, Format::Blender);
    assert_eq!(ds.views.len(), 90);
    assert_eq!(ds.test, (0..90).step_by(10).collect::<Vec<_>>());
    assert_eq!(ds.train.len(), 81);
    assert!(ds.val.is_empty());
    assert_eq!(ds.background, Some([1.0; 3]));
    assert_eq!(ds.views[0].name, "train/r_1");
    let focal = 0.5 * 800.0 / (0.5 * 0.691_111_207_008_361_8f64).tan() / 4.0;
    assert!((focal - 1111.11 / 4.0).abs() < 1e-3);
    let mut transparent = 0;
    for v in &ds.views {
        let k = v.camera.intrinsics;
        assert_eq!(
            (k.width, k.height, v.image.width, v.image.height),
            (200, 200, 200, 200)
        );
        assert!((k.fx - focal).abs() < 1e-9 && (k.fy - focal).abs() < 1e-9);
        assert_eq!((k.cx, k.cy), (100.0, 100.0));
        let alpha = v.alpha.as_ref().unwrap();
        assert_eq!(alpha.len(), 200 * 200);
        for (a, px) in alpha.iter().zip(v.image.data.chunks_exact(3)) {
            if *a == 0.0 {
                transparent += 1;
                assert_eq!(
                    px,
                    [1.0, 1.0, 1.0],
                    "{}: a transparent pixel must be white",
                    v.name
                );
            }
        }
    }
    assert!(
        transparent > 90 * 1000,
        "only {transparent} fully transparent pixels"
    );
    // A point along a pixel-centre ray projects back to that pixel centre.
    let cam = ds.views[3].camera;
    for (i, j) in [(0, 0), (57, 143), (199, 199)] {
        let d = cam.pixel_direction(i, j);
        let p = nerf_data::math::add(cam.pose.translation, nerf_data::math::scale(d, 3.7));
        let (u, v, depth) = cam.project(p).unwrap();
        assert!(
            (u - (i as f64 + 0.5)).abs() < 1e-4 && (v - (j as f64 + 0.5)).abs() < 1e-4,
            "({u}, {v})"
        );
        assert!((depth - 3.7).abs() < 1e-5, "depth {depth}");
    }
}

#[test]
fn per_frame_intrinsics_are_honoured() {
    let dir = TempDir::new("per-frame");
    for name in ["r_0", "r_1", "r_2"] {
        write_png(&dir, &format!("train/{name}.png"), 8, 6);
    }
    let json = transforms(&[
        frame(
            "./train/r_0",
            r#", "fl_x": 10.0, "fl_y": 11.0, "cx": 3.0, "cy": 2.5, "w": 8, "h": 6"#,
        ),
        frame("./train/r_1.png", r#", "fl_x": 20.0, "cx": 4.5"#),
        frame("train/r_2", ""),
    ]);
    dir.write("transforms_train.json", json.as_bytes());
    dir.write(
        "transforms_test.json",
        transforms(&[frame("./train/r_2", "")]).as_bytes(),
    );
    let ds = blender::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!((ds.train.clone(), ds.test.clone()), (vec![0, 1, 2], vec![3]));
    let k: Vec<_> = ds.views.iter().map(|v| v.camera.intrinsics).collect();
    assert_eq!((k[0].fx, k[0].fy, k[0].cx, k[0].cy), (10.0, 11.0, 3.0, 2.5));
    assert_eq!((k[1].fx, k[1].fy, k[1].cx, k[1].cy), (20.0, 20.0, 4.5, 3.0));
    let fov_focal = 0.5 * 8.0 / (0.5f64 * 0.69).tan();
    assert!((k[2].fx - fov_focal).abs() < 1e-12 && (k[2].cx, k[2].cy) == (4.0, 3.0));
    // White compositing keeps the straight alpha.
    let v = &ds.views[0];
    assert_eq!(v.alpha.as_ref().unwrap()[0], 0.0);
    assert_eq!(&v.image.data[..3], &[1.0, 1.0, 1.0]);

    // The json's w/h describe full-size images; halving the images halves the intrinsics.
    let ds = blender::load(dir.path(), &opts(2)).unwrap();
    let k = ds.views[0].camera.intrinsics;
    assert_eq!((k.fx, k.cx, k.cy, k.width, k.height), (5.0, 1.5, 1.25, 4, 3));
    assert_eq!(ds.views[0].alpha.as_ref().unwrap()[0], 0.5);
}

/// `n` 4×4 frames `images/f{i}.png` at times i / (n − 1), listed in one `transforms.json`.
fn write_dnerf_video(dir: &TempDir, n: usize) {
    let frames: Vec<String> = (0..n)
        .map(|i| {
            write_png(dir, &format!("images/f{i}.png"), 4, 4);
            frame(
                &format!("images/f{i}.png"),
                &format!(r#", "time": {}"#, i as f64 / (n - 1) as f64),
            )
        })
        .collect();
    dir.write("transforms.json", transforms(&frames).as_bytes());
}

#[test]
fn single_transforms_json_and_dnerf_times() {
    let dir = TempDir::new("dnerf");
    write_dnerf_video(&dir, 4);
    let ds = blender::load(
        dir.path(),
        &LoadOptions {
            holdout: Some(2),
            ..LoadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(ds.format, Format::DNerf);
    assert_eq!((ds.train.clone(), ds.test.clone()), (vec![1, 3], vec![0, 2]));
    assert_eq!(ds.views[3].time, Some(1.0));
    assert!((ds.views[1].time.unwrap() - 1.0 / 3.0).abs() < 1e-7);
}

/// A D-NeRF video's motion masks, `motion_masks/<view name>.png`, are read per view (first
/// channel, 255 = 1); one of the wrong size is refused, naming the file.
#[test]
fn dnerf_motion_masks_are_read_per_view() {
    let dir = TempDir::new("dnerf-masks");
    write_dnerf_video(&dir, 3);
    let mut mask = Image::new(4, 4, 1);
    mask.data[5] = 1.0;
    mask.save_png(&dir.path().join("motion_masks/images/f1.png"))
        .unwrap();
    let ds = blender::load(dir.path(), &LoadOptions::default()).unwrap();
    let masks = &ds.priors.as_ref().expect("priors with the masks").motion_masks;
    assert!(masks[0].is_none() && masks[2].is_none());
    let m = masks[1].as_ref().expect("frame 1's mask");
    assert_eq!(m.iter().filter(|&&v| v > 0.5).count(), 1);
    assert_eq!(m[5], 1.0);

    Image::new(3, 4, 1)
        .save_png(&dir.path().join("motion_masks/images/f2.png"))
        .unwrap();
    assert_mentions(
        &load_err(dir.path()),
        &[
            "motion_masks/images/f2.png",
            "motion mask is 4x3 but frames are 4x4",
        ],
    );
}

#[test]
fn bad_blender_inputs_name_the_file_and_the_problem() {
    let missing = std::env::temp_dir().join("nerf-data-no-such-scene-folder");
    assert_mentions(
        &load_err(&missing),
        &["nerf-data-no-such-scene-folder", "not found"],
    );

    let dir = TempDir::new("no-json");
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "transforms.json", "looked for"],
    );

    let dir = TempDir::new("malformed");
    write_png(&dir, "train/r_0.png", 4, 4);
    dir.write(
        "transforms_train.json",
        br#"{"camera_angle_x": 0.69, "frames": [ {"file_path": "#,
    );
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "malformed JSON", "EOF"],
    );

    let dir = TempDir::new("missing-image");
    write_png(&dir, "train/r_0.png", 4, 4);
    dir.write(
        "transforms_train.json",
        transforms(&[frame("./train/r_0", ""), frame("./train/r_7", "")]).as_bytes(),
    );
    assert_mentions(&load_err(dir.path()), &["r_7.png", "not found", "frame 1"]);

    let dir = TempDir::new("truncated-png");
    write_png(&dir, "train/r_0.png", 16, 16);
    let png = std::fs::read(dir.path().join("train/r_0.png")).unwrap();
    dir.write("train/r_1.png", &png[..png.len() / 2]);
    dir.write(
        "transforms_train.json",
        transforms(&[frame("./train/r_0", ""), frame("./train/r_1", "")]).as_bytes(),
    );
    assert_mentions(&load_err(dir.path()), &["r_1.png", "cannot decode image"]);

    let dir = TempDir::new("nan-pose");
    write_png(&dir, "train/r_0.png", 4, 4);
    let bad_pose =
        r#"{"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,NaN,0,0],[0,0,1,4],[0,0,0,1]]}"#;
    dir.write(
        "transforms_train.json",
        transforms(&[frame("./train/r_0", ""), bad_pose.into()]).as_bytes(),
    );
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "frame 1", "./train/r_0", "NaN"],
    );

    let dir = TempDir::new("not-4x4");
    write_png(&dir, "train/r_0.png", 4, 4);
    let short = r#"{"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4]]}"#;
    dir.write("transforms_train.json", transforms(&[short.into()]).as_bytes());
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "frame 0", "4x4"],
    );

    let dir = TempDir::new("zero-angle");
    write_png(&dir, "train/r_0.png", 4, 4);
    let json = format!(
        r#"{{"camera_angle_x": 0, "frames": [{}]}}"#,
        frame("./train/r_0", "")
    );
    dir.write("transforms_train.json", json.as_bytes());
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "camera_angle_x = 0"],
    );

    let dir = TempDir::new("negative-focal");
    write_png(&dir, "train/r_0.png", 4, 4);
    dir.write(
        "transforms_train.json",
        transforms(&[frame("./train/r_0", r#", "fl_x": -5"#)]).as_bytes(),
    );
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "fl_x = -5", "positive"],
    );

    let dir = TempDir::new("sizes");
    write_png(&dir, "train/r_0.png", 8, 8);
    write_png(&dir, "train/r_3.png", 4, 4);
    dir.write(
        "transforms_train.json",
        transforms(&[frame("./train/r_0", ""), frame("./train/r_3", "")]).as_bytes(),
    );
    assert_mentions(&load_err(dir.path()), &["r_3.png is 4x4 but r_0.png is 8x8"]);

    let dir = TempDir::new("no-time");
    write_png(&dir, "train/r_0.png", 4, 4);
    let frames = [frame("./train/r_0", r#", "time": 0.5"#), frame("./train/r_0", "")];
    dir.write("transforms_train.json", transforms(&frames).as_bytes());
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "frames without time", "frame 1"],
    );

    let dir = TempDir::new("late-time");
    write_png(&dir, "train/r_0.png", 4, 4);
    dir.write(
        "transforms_train.json",
        transforms(&[frame("./train/r_0", r#", "time": 1.5"#)]).as_bytes(),
    );
    assert_mentions(
        &load_err(dir.path()),
        &["transforms_train.json", "time 1.5", "outside [0, 1]"],
    );
}

#[test]
fn truncated_npz_names_the_file() {
    let Some(path) = shared("lego_tiny/tiny_nerf_data.npz") else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap();
    let dir = TempDir::new("npz-truncated");
    let cut = dir.write("half.npz", &bytes[..bytes.len() / 2]);
    assert_mentions(&npz_err(&cut), &["half.npz", "truncated"]);
}

/// A small npz with `n` black 4x4 views, camera at z = 4; `edit` may change the arrays first.
fn small_npz(
    dir: &TempDir,
    name: &str,
    n: usize,
    edit: impl FnOnce(&mut Vec<f64>, &mut Vec<f64>),
) -> PathBuf {
    let images = vec![0.0; n * 4 * 4 * 3];
    let mut poses = Vec::new();
    for _ in 0..n {
        poses.extend([1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 4., 0., 0., 0., 1.]);
    }
    let mut focal = vec![5.0];
    edit(&mut poses, &mut focal);
    let images = encode_npy(&[n, 4, 4, 3], &images, true);
    let poses = encode_npy(&[n, 4, 4], &poses, true);
    let focal = encode_npy(&[], &focal, false);
    let zip = write_zip(
        &[
            ("images.npy", &images),
            ("poses.npy", &poses),
            ("focal.npy", &focal),
        ],
        true,
    );
    dir.write(name, &zip)
}

#[test]
fn bad_npz_inputs_name_the_file_and_the_problem() {
    let dir = TempDir::new("npz-bad");
    let good = small_npz(&dir, "good.npz", 3, |_, _| {});
    let ds = tiny_npz::load(&good, &LoadOptions::default()).unwrap();
    assert_eq!((ds.views.len(), ds.views[0].camera.intrinsics.fx), (3, 5.0));

    let images = encode_npy(&[1, 4, 4, 3], &[0.0; 48], true);
    let poses = encode_npy(&[1, 4, 4], &[0.0; 16], true);
    let no_focal = dir.write(
        "no_focal.npz",
        write_zip(&[("images.npy", &images), ("poses.npy", &poses)], false),
    );
    assert_mentions(
        &npz_err(&no_focal),
        &["no_focal.npz", "missing key 'focal'", "images, poses"],
    );

    let nan = small_npz(&dir, "nan_pose.npz", 3, |p, _| p[16 + 5] = f64::NAN);
    assert_mentions(&npz_err(&nan), &["nan_pose.npz", "view 1", "NaN"]);

    let neg = small_npz(&dir, "neg_focal.npz", 3, |_, f| f[0] = -1.0);
    assert_mentions(&npz_err(&neg), &["neg_focal.npz", "'focal' = -1"]);

    let wrong = dir.write(
        "wrong_shape.npz",
        write_zip(
            &[
                ("images.npy", &encode_npy(&[2, 4, 4], &[0.0; 32], true)),
                ("poses.npy", &poses),
                ("focal.npy", &encode_npy(&[], &[5.0], false)),
            ],
            false,
        ),
    );
    assert_mentions(
        &npz_err(&wrong),
        &["wrong_shape.npz", "(N, H, W, 3)", "[2, 4, 4]"],
    );

    let missing = dir.path().join("absent.npz");
    assert_mentions(&npz_err(&missing), &["absent.npz", "not found"]);
}
