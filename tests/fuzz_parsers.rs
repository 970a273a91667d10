//! Fuzzed parsers: every reader of user files is fed random bytes (with and without the valid
//! file's first bytes, so the header checks let them through), every truncation of a small valid
//! file and random bit flips. None may panic, and every error must name the file it read.
//!
//! A plain binary (`harness = false`) so that the table of how many inputs each parser was tried
//! with shows in CI's log. The inputs come from proptest with a fixed seed: a failure shrinks to a
//! small input and reproduces on the next run.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use nerf::checkpoint::Sections;
use nerf_data::colmap::{self, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use nerf_data::npy::encode_npy;
use nerf_data::npz::write_zip;
use nerf_data::{Image, blender, llff, npy, npz, video};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};

/// Random inputs per kind (random bytes, random bytes after the valid header, bit flips).
const CASES: u32 = 500;

type Parse = Box<dyn Fn(&Path) -> Result<(), String>>;

/// One parser under test: it reads `dir`, in which `file` holds the bytes being tried and
/// `extra` the other (valid) files it needs.
struct Target {
    name: &'static str,
    file: &'static str,
    valid: Vec<u8>,
    extra: Vec<(&'static str, Vec<u8>)>,
    parse: Parse,
}

fn target(
    name: &'static str,
    file: &'static str,
    valid: Vec<u8>,
    parse: impl Fn(&Path) -> Result<(), String> + 'static,
) -> Target {
    Target {
        name,
        file,
        valid,
        extra: Vec::new(),
        parse: Box::new(parse),
    }
}

fn text<T, E: std::fmt::Display>(r: Result<T, E>) -> Result<(), String> {
    r.map(|_| ()).map_err(|e| e.to_string())
}

fn f64s(n: usize) -> Vec<f64> {
    (0..n).map(|i| (i as f64 * 0.37).sin()).collect()
}

fn png_bytes(w: u32, h: u32) -> Vec<u8> {
    let dir = std::env::temp_dir().join(format!("fuzz-png-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("a.png");
    let data = (0..w * h * 3).map(|i| (i % 7) as f32 / 6.0).collect();
    Image::from_data(w, h, 3, data).save_png(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    bytes
}

fn jpeg_bytes() -> Vec<u8> {
    let img = image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([(x * 30) as u8, (y * 30) as u8, 90]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
    out.into_inner()
}

/// A small valid COLMAP model: two cameras, two images, two points.
fn colmap_model() -> ColmapModel {
    let camera = |id, model_id, params: Vec<f64>| ColmapCamera {
        id,
        model_id,
        width: 8,
        height: 6,
        params,
    };
    let image = |id, name: &str, t: f64| ColmapImage {
        id,
        qvec: [1.0, 0.0, 0.0, 0.0],
        tvec: [t, 0.0, 4.0],
        camera_id: id,
        name: name.into(),
        points2d: vec![([1.5, 2.5], 1), ([3.0, 4.0], -1)],
    };
    let point = |id, x| ColmapPoint {
        id,
        xyz: [x, 0.5, 1.0],
        rgb: [10, 20, 30],
        error: 0.5,
        track: vec![(1, 0), (2, 0)],
    };
    ColmapModel {
        cameras: vec![
            camera(1, 1, vec![7.0, 7.0, 4.0, 3.0]),
            camera(2, 2, vec![7.0, 4.0, 3.0, 0.01]),
        ],
        images: vec![image(1, "a.png", 0.0), image(2, "b.png", 0.5)],
        points: vec![point(1, 0.0), point(2, 1.0)],
    }
}

fn colmap_files(binary: bool) -> Vec<(String, Vec<u8>)> {
    let dir = std::env::temp_dir().join(format!("fuzz-colmap-{binary}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let model = colmap_model();
    if binary {
        colmap::write_binary(&model, &dir).unwrap();
    } else {
        colmap::write_text(&model, &dir).unwrap();
    }
    let ext = if binary { "bin" } else { "txt" };
    let files = ["cameras", "images", "points3D"]
        .iter()
        .map(|f| {
            let name = format!("{f}.{ext}");
            let bytes = std::fs::read(dir.join(&name)).unwrap();
            (name, bytes)
        })
        .collect();
    std::fs::remove_dir_all(&dir).unwrap();
    files
}

/// The COLMAP model with `file` under test and the other two files valid.
fn colmap_target(name: &'static str, file: &'static str, binary: bool) -> Target {
    let files = colmap_files(binary);
    let valid = files.iter().find(|(n, _)| n == file).unwrap().1.clone();
    let extra = files
        .into_iter()
        .filter(|(n, _)| n != file)
        .map(|(n, b)| (&*Box::leak(n.into_boxed_str()), b))
        .collect();
    Target {
        extra,
        ..target(name, file, valid, |dir| text(colmap::read_model(dir)))
    }
}

fn transforms_json() -> Vec<u8> {
    let frame = |i: usize, x: f64| {
        serde_json::json!({
            "file_path": format!("./train/r_{i}"),
            "time": i as f64 / 2.0,
            "transform_matrix": [[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]],
        })
    };
    let json = serde_json::json!({
        "camera_angle_x": 0.69,
        "frames": [frame(0, 0.0), frame(1, 0.3), frame(2, 0.6)],
    });
    serde_json::to_vec_pretty(&json).unwrap()
}

fn checkpoint_bytes() -> Vec<u8> {
    let mut s = Sections::default();
    s.push("state", br#"{"step": 120, "elapsed": 3.5}"#.to_vec());
    s.push("model", (0u8..96).collect());
    s.push("optim", vec![7; 24]);
    s.to_bytes()
}

fn targets() -> Vec<Target> {
    let (h, w) = (6usize, 8usize);
    let flow = encode_npy(&[h, w, 2], &f64s(2 * h * w), true);
    let mask = encode_npy(&[h, w], &vec![1.0; h * w], true);
    let flow_npz = write_zip(&[("flow.npy", &flow), ("mask.npy", &mask)], true);
    let stored_npz = write_zip(
        &[
            ("a.npy", &encode_npy(&[3, 4], &f64s(12), false)),
            ("b.npy", &mask),
        ],
        false,
    );
    // Three LLFF rows: [R | t | (h, w, f)] row by row, then near and far; identity rotations.
    let poses: Vec<f64> = (0..3)
        .flat_map(|k| {
            let mut row = Vec::with_capacity(17);
            for r in 0..3 {
                let rot = [0, 1, 2].map(|c| f64::from(u8::from(r == c)));
                row.extend(rot);
                row.extend([
                    if r == 2 { 4.0 + k as f64 } else { 0.1 * k as f64 },
                    [6.0, 8.0, 7.0][r],
                ]);
            }
            row.extend([1.0, 10.0]);
            row
        })
        .collect();
    let poses = encode_npy(&[3, 17], &poses, false);
    let mut t = vec![
        target("npy", "a.npy", encode_npy(&[4, 3], &f64s(12), true), |d| {
            text(npy::read_npy(&d.join("a.npy")))
        }),
        target("npz (stored)", "a.npz", stored_npz, |d| {
            text(npz::read_npz(&d.join("a.npz")))
        }),
        target("npz (deflated)", "a.npz", flow_npz.clone(), |d| {
            text(npz::read_npz(&d.join("a.npz")))
        }),
        target("flow (npz)", "00000_fwd.npz", flow_npz, move |d| {
            text(video::read_flow(&d.join("00000_fwd.npz"), w, h))
        }),
        target(
            "disparity (npy)",
            "00000.npy",
            encode_npy(&[h, w], &f64s(h * w), true),
            move |d| text(video::read_disparity(&d.join("00000.npy"), w, h)),
        ),
        target(
            "motion mask (png)",
            "00000.png",
            png_bytes(w as u32, h as u32),
            move |d| text(video::read_mask(&d.join("00000.png"), w, h)),
        ),
        target("image (png)", "a.png", png_bytes(5, 4), |d| {
            text(Image::load(&d.join("a.png")))
        }),
        target("image (jpeg)", "a.jpg", jpeg_bytes(), |d| {
            text(Image::load(&d.join("a.jpg")))
        }),
        target("transforms json", "transforms.json", transforms_json(), |d| {
            text(blender::read_cameras(&d.join("transforms.json"), (8, 6)))
        }),
        target("poses_bounds.npy", "poses_bounds.npy", poses, |d| {
            text(llff::read_poses_bounds(&d.join("poses_bounds.npy")))
        }),
        target("checkpoint", "checkpoint.bin", checkpoint_bytes(), |d| {
            let path = d.join("checkpoint.bin");
            let s = Sections::read(&path).map_err(|e| e.to_string())?;
            text(s.json::<serde_json::Value>("state", &path))
        }),
    ];
    for (name, file, binary) in [
        ("COLMAP cameras.bin", "cameras.bin", true),
        ("COLMAP images.bin", "images.bin", true),
        ("COLMAP points3D.bin", "points3D.bin", true),
        ("COLMAP cameras.txt", "cameras.txt", false),
        ("COLMAP images.txt", "images.txt", false),
        ("COLMAP points3D.txt", "points3D.txt", false),
    ] {
        t.push(colmap_target(name, file, binary));
    }
    t
}

#[derive(Default)]
struct Counts {
    random: usize,
    truncated: usize,
    flipped: usize,
    errors: usize,
}

/// Tries `bytes` on the target: a panic or an error that does not name the file fails.
fn try_input(t: &Target, dir: &Path, bytes: &[u8], counts: &mut Counts) -> Result<(), String> {
    let path = dir.join(t.file);
    std::fs::write(&path, bytes).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    match catch_unwind(AssertUnwindSafe(|| (t.parse)(dir))) {
        Err(_) => Err(format!("{}: panicked on {} bytes", t.name, bytes.len())),
        Ok(Ok(())) => Ok(()),
        Ok(Err(msg)) => {
            counts.errors += 1;
            if msg.contains(t.file) {
                Ok(())
            } else {
                Err(format!("{}: the error does not name {}: {msg}", t.name, t.file))
            }
        }
    }
}

fn fuzz(t: &Target, root: &Path) -> Result<Counts, String> {
    let dir = root.join(t.name.replace([' ', '(', ')'], "_"));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    for (name, bytes) in &t.extra {
        std::fs::write(dir.join(name), bytes).map_err(|e| e.to_string())?;
    }
    let mut counts = Counts::default();
    // The valid file must read, or the harness tests nothing.
    std::fs::write(dir.join(t.file), &t.valid).map_err(|e| e.to_string())?;
    (t.parse)(&dir).map_err(|e| format!("{}: the valid file does not read: {e}", t.name))?;

    // Every truncation.
    for cut in 0..t.valid.len() {
        try_input(t, &dir, &t.valid[..cut], &mut counts)?;
        counts.truncated += 1;
    }

    let counts = std::cell::RefCell::new(counts);
    let runner = |seed: u8| {
        let config = Config {
            cases: CASES,
            failure_persistence: None,
            ..Config::default()
        };
        TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &[seed; 32]))
    };
    let check = |bytes: &[u8], flipped: bool| {
        let mut c = counts.borrow_mut();
        try_input(t, &dir, bytes, &mut c).map_err(TestCaseError::fail)?;
        if flipped {
            c.flipped += 1;
        } else {
            c.random += 1;
        }
        Ok(())
    };

    // Random bytes, as they come and after the valid file's first bytes.
    let n = t.valid.len();
    let bytes = prop::collection::vec(any::<u8>(), 0..2 * n + 16);
    report(t, runner(1).run(&bytes, |b| check(&b, false)))?;
    let head = t.valid[..n.min(16)].to_vec();
    report(
        t,
        runner(2).run(&bytes, |b| {
            let mut with_head = head.clone();
            with_head.extend(b);
            check(&with_head, false)
        }),
    )?;
    // One to four flipped bits.
    report(
        t,
        runner(3).run(&prop::collection::vec((0..n, 0u8..8), 1..5), |flips| {
            let mut bytes = t.valid.clone();
            for (i, bit) in flips {
                bytes[i] ^= 1 << bit;
            }
            check(&bytes, true)
        }),
    )?;
    Ok(counts.into_inner())
}

fn report<V: std::fmt::Debug>(
    t: &Target,
    r: Result<(), proptest::test_runner::TestError<V>>,
) -> Result<(), String> {
    r.map_err(|e| format!("{}: {e}", t.name))
}

fn main() {
    // Panics are caught and reported as failures; keep their messages out of the log.
    std::panic::set_hook(Box::new(|_| {}));
    let root: PathBuf = std::env::temp_dir().join(format!("nerf-fuzz-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let mut failures = Vec::new();
    println!("fuzzed parsers ({CASES} proptest cases per random kind, fixed seeds)");
    println!(
        "{:<22} {:>7} {:>10} {:>8} {:>7} {:>7}",
        "parser", "random", "truncated", "flipped", "total", "errors"
    );
    // The harness must catch what it looks for: a parser that panics on some inputs and one
    // whose errors do not name the file.
    let panics = target("self-check (panic)", "x.bin", vec![1, 2, 3, 4], |d| {
        let b = std::fs::read(d.join("x.bin")).map_err(|e| e.to_string())?;
        assert!(b.len() != 2, "deliberate panic");
        Ok(())
    });
    let unnamed = target("self-check (no name)", "x.bin", vec![1, 2, 3, 4], |d| {
        let b = std::fs::read(d.join("x.bin")).map_err(|e| e.to_string())?;
        if b.len() == 4 {
            Ok(())
        } else {
            Err("too short".into())
        }
    });
    for t in [panics, unnamed] {
        if fuzz(&t, &root).is_ok() {
            eprintln!("{}: the harness missed a deliberate failure", t.name);
            std::process::exit(1);
        }
    }
    let (mut all, start) = (0, std::time::Instant::now());
    for t in targets() {
        match fuzz(&t, &root) {
            Ok(c) => {
                let total = c.random + c.truncated + c.flipped;
                all += total;
                println!(
                    "{:<22} {:>7} {:>10} {:>8} {:>7} {:>7}",
                    t.name, c.random, c.truncated, c.flipped, total, c.errors
                );
            }
            Err(e) => {
                println!("{:<22} FAILED", t.name);
                failures.push(e);
            }
        }
    }
    let _ = std::fs::remove_dir_all(&root);
    if !failures.is_empty() {
        for f in &failures {
            eprintln!("{f}");
        }
        std::process::exit(1);
    }
    println!(
        "{all} inputs in {:.1} s; none panicked, every error named its file",
        start.elapsed().as_secs_f64()
    );
}
