//! End-to-end checks of the `nerf` binary: the COLMAP command against the shipped poses, a tiny
//! train → eval → render cycle scored independently from the PNGs, kill-and-resume, bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "../../../tests/support/cli.rs"]
mod support;
use support::{kill_and_resume, mean_psnr, run, score_pngs};

fn nerf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nerf"))
}

fn temp(name: &str) -> PathBuf {
    support::temp("nerf-cli", name)
}

/// A small synthetic object scene (32×32, 30 views, 4 test views).
fn scene(dir: &Path) -> PathBuf {
    let data = dir.join("scene");
    run(nerf()
        .args([
            "synth",
            "--preset",
            "static",
            "--size",
            "32",
            "32",
            "--frames",
            "30",
            "--test-views",
            "4",
        ])
        .arg(&data));
    data
}

#[test]
fn colmap2poses_reproduces_the_shipped_poses_bounds() {
    let Some(shared) = nerf_data::shared_data() else {
        eprintln!("skipped: ../shared/data not found");
        return;
    };
    let dir = temp("colmap");
    let out = dir.join("poses_bounds.npy");
    run(nerf()
        .arg("colmap2poses")
        .arg(shared.join("llff/beer/sparse/0"))
        .arg("--out")
        .arg(&out));
    let ours = nerf_data::npy::read_npy(&out).unwrap();
    let theirs = nerf_data::npy::read_npy(&shared.join("llff/beer/poses_bounds.npy")).unwrap();
    assert_eq!(ours.shape, theirs.shape);
    let (mut max_deg, mut max_t, mut max_b) = (0.0f64, 0.0f64, 0.0f64);
    for (a, b) in ours.data.chunks(17).zip(theirs.data.chunks(17)) {
        // Rotation angle between the two 3×3 blocks: acos((trace(RaᵀRb) − 1)/2), via the
        // Frobenius distance for accuracy at small angles: ‖Ra − Rb‖ = 2√2·sin(θ/2).
        let mut frob = 0.0;
        for r in 0..3 {
            for c in 0..3 {
                frob += (a[r * 5 + c] - b[r * 5 + c]).powi(2);
            }
        }
        max_deg = max_deg.max((2.0 * (frob.sqrt() / (2.0 * 2f64.sqrt())).asin()).to_degrees());
        for r in 0..3 {
            max_t = max_t.max((a[r * 5 + 3] - b[r * 5 + 3]).abs() / b[r * 5 + 3].abs().max(1e-9));
        }
        for k in 15..17 {
            max_b = max_b.max((a[k] - b[k]).abs() / b[k].abs());
        }
    }
    eprintln!(
        "beer colmap2poses: max rotation {max_deg:.2e} deg, translation {max_t:.2e}, bounds {max_b:.2e} (relative)"
    );
    assert!(max_deg < 0.01 && max_t < 1e-3 && max_b < 1e-3);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn train_eval_and_render_cameras_agree() {
    let dir = temp("cycle");
    let data = scene(&dir);
    let run_dir = dir.join("run");
    let out = run(nerf().arg("train").arg(&data).arg("--out").arg(&run_dir).args([
        "--steps",
        "150",
        "--checkpoint-every",
        "50",
    ]));
    let after_train = mean_psnr(&out);
    assert!(run_dir.join("checkpoint.bin").exists() && run_dir.join("psnr.png").exists());
    assert!(run_dir.join("render/path.gif").exists());
    let eval = run(nerf().arg("eval").arg(&run_dir));
    let evaluated = mean_psnr(&eval);
    assert!(
        (evaluated - after_train).abs() < 1e-6,
        "eval {evaluated} vs end of training {after_train}"
    );
    assert!(evaluated > 15.0, "150 steps should learn something: {evaluated}");
    let renders = dir.join("cams");
    run(nerf()
        .arg("render")
        .arg(&run_dir)
        .arg("--cameras")
        .arg(data.join("transforms_test.json"))
        .arg("--out")
        .arg(&renders));
    let independent = score_pngs(&renders, &data);
    eprintln!("nerf eval {evaluated:.4} dB, independent PNG score {independent:.4} dB");
    assert!(
        (independent - evaluated).abs() < 0.05,
        "{independent} vs {evaluated}"
    );

    // Geometry out of the same run: a mesh and a point cloud, read back by a generic PLY
    // reader, and scored against the generator's true surfaces.
    let mesh = dir.join("mesh.ply");
    let out = run(nerf()
        .args(["export", "mesh"])
        .arg(&run_dir)
        .args(["--resolution", "40", "--threshold", "2", "--out"])
        .arg(&mesh));
    let text = String::from_utf8_lossy(&out.stdout);
    let (vertices, faces) = support::check_ply(&mesh, [[-5.0; 3], [5.0; 3]]);
    assert!(
        vertices > 100 && faces > 100,
        "{vertices} vertices, {faces} faces"
    );
    assert!(
        text.contains(&format!("{vertices} vertices, {faces} triangles")),
        "{text}"
    );
    assert!(
        text.contains("to the true surfaces") && text.contains("Chamfer"),
        "{text}"
    );
    let points = dir.join("points.ply");
    run(nerf()
        .args(["export", "points"])
        .arg(&run_dir)
        .args(["--stride", "4", "--out"])
        .arg(&points));
    let (n, faces) = support::check_ply(&points, [[-5.0; 3], [5.0; 3]]);
    assert!(n > 100 && faces == 0, "{n} points");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn viewer_serves_the_page_and_frames_and_refuses_bad_requests() {
    let dir = temp("view");
    let data = scene(&dir);
    let run_dir = dir.join("run");
    run(nerf()
        .arg("train")
        .arg(&data)
        .arg("--out")
        .arg(&run_dir)
        .args(["--steps", "20", "--no-render"]));
    support::check_viewer(
        env!("CARGO_BIN_EXE_nerf"),
        &run_dir,
        &["rgb", "depth", "opacity"],
        false,
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn damaged_checkpoint_is_refused_and_resume_falls_back() {
    let dir = temp("damaged");
    let data = scene(&dir);
    let run_dir = dir.join("run");
    let train = |steps: &str| {
        let mut cmd = nerf();
        cmd.arg("train").arg(&data).arg("--out").arg(&run_dir).args([
            "--steps",
            steps,
            "--checkpoint-every",
            "20",
            "--no-render",
        ]);
        cmd
    };
    run(&mut train("60"));
    let (last, prev) = (
        run_dir.join("checkpoint.bin"),
        run_dir.join("checkpoint.prev.bin"),
    );
    assert!(last.exists() && prev.exists());

    // One flipped bit in the middle of the last checkpoint: eval refuses it, naming the file.
    let mut bytes = std::fs::read(&last).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x04;
    std::fs::write(&last, &bytes).unwrap();
    let out = nerf().arg("eval").arg(&run_dir).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a damaged checkpoint was loaded");
    assert!(
        stderr.contains("checkpoint.bin") && stderr.contains("checksum mismatch"),
        "{stderr}"
    );

    // Resume falls back to the previous checkpoint (step 40), says so, and trains on.
    let out = run(train("80").arg("--resume"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("resuming from the previous checkpoint") && stderr.contains("at step 40"),
        "{stderr}"
    );
    let metrics = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap();
    assert!(metrics.contains("\"step\":80"), "training went on to step 80");
    // A `--set` the run was not started with is refused on a resume, naming it; one that
    // repeats a saved value is taken.
    let out = train("90")
        .args(["--resume", "--set", "lr=0.5"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a changed setting was resumed: {stderr}");
    assert!(
        stderr.contains("--set lr=0.5") && stderr.contains("resumed run"),
        "{stderr}"
    );
    run(train("90").args(["--resume", "--set", "fast.grid.log2_table=17"]));
    // A resumed budget must be able to train.
    let out = train("90")
        .args(["--resume", "--time-budget=-5"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a negative budget was resumed: {stderr}");
    assert!(stderr.contains("time budget"), "{stderr}");
    run(nerf().arg("eval").arg(&run_dir));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn killed_training_resumes_to_the_same_result() {
    let dir = temp("resume");
    let data = scene(&dir);
    let args = [
        "--steps",
        "240",
        "--checkpoint-every",
        "20",
        "--no-render",
        "--seed",
        "3",
    ];
    let (want, got, stderr) = kill_and_resume(env!("CARGO_BIN_EXE_nerf"), &data, &dir, &args, 100);
    assert!(stderr.contains("resuming"), "{stderr}");
    assert!((got - want).abs() < 0.5, "{got} vs {want}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn bad_inputs_fail_with_a_clear_message() {
    let dir = temp("bad");
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    for (args, needle) in [
        (
            vec!["train".to_string(), empty.display().to_string()],
            "looked for",
        ),
        (
            vec!["train".to_string(), dir.join("missing").display().to_string()],
            "not found",
        ),
        (
            vec!["eval".to_string(), empty.display().to_string()],
            "checkpoint.bin",
        ),
        (
            vec!["colmap2poses".to_string(), empty.display().to_string()],
            "no COLMAP model",
        ),
    ] {
        let out = nerf().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(err.contains("error:") && err.contains(needle), "{args:?}: {err}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `nerf synth --mono-disparity [clean|rough]`: the flag alone writes the clean disparity, `rough`
/// writes another one for the same images, and an unknown kind is refused with the choices.
#[test]
fn synth_writes_a_clean_or_a_rough_disparity() {
    let dir = temp("disparity");
    let video = |out: &Path, errors: &[&str]| {
        let mut cmd = nerf();
        cmd.arg("synth").args(errors).args([
            "--preset",
            "dynamic",
            "--size",
            "32",
            "24",
            "--frames",
            "3",
            "--test-views",
            "2",
        ]);
        cmd.arg(out);
        cmd
    };
    let (clean, rough) = (dir.join("clean"), dir.join("rough"));
    run(&mut video(&clean, &["--mono-disparity"]));
    run(&mut video(&rough, &["--mono-disparity", "rough"]));
    let read = |d: &Path, f: &str| std::fs::read(d.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
    for k in 0..3 {
        let image = format!("train/r_{k:03}.png");
        assert_eq!(read(&clean, &image), read(&rough, &image), "{image}");
        let disp = format!("disp/train/r_{k:03}.npy");
        assert_ne!(read(&clean, &disp), read(&rough, &disp), "{disp}");
    }
    let out = video(&dir.join("bad"), &["--mono-disparity", "noisy"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("rough"), "{err}");
    std::fs::remove_dir_all(dir).unwrap();
}
