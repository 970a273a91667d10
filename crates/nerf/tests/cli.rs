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
