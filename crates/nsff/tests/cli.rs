//! End-to-end checks of the `nsff` binary on small videos from our generator: train → eval →
//! render cycle scored independently from the PNGs, the static-video skip path, kill-and-resume.

use std::path::{Path, PathBuf};
use std::process::Command;

use nerf_synth::{Preset, SynthConfig};

#[path = "../../../tests/support/cli.rs"]
mod support;
use support::{kill_and_resume, mean_psnr, run, score_pngs};

fn nsff() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nsff"))
}

fn temp(name: &str) -> PathBuf {
    support::temp("nsff-cli", name)
}

/// A video from our generator (`preset`: dynamic or static_video), `w`×`h`, `frames` frames,
/// 4 held-out (camera, time) pairs, with a simulated monocular disparity (`disp/`), so training
/// runs the depth prior too.
fn video(dir: &Path, preset: Preset, size: (u32, u32), frames: usize) -> PathBuf {
    generate(dir, &video_config(preset, size, frames))
}

/// [`video`]'s settings, for a test that changes one before generating.
fn video_config(preset: Preset, (w, h): (u32, u32), frames: usize) -> SynthConfig {
    let mut cfg = SynthConfig::new(preset).with_size(w, h).with_views(frames, 4);
    cfg.mono_disparity = Some(nerf_synth::DisparityErrors::Clean);
    cfg
}

/// The video `cfg` describes, in `dir/<preset>`.
fn generate(dir: &Path, cfg: &SynthConfig) -> PathBuf {
    let data = dir.join(cfg.preset.as_str());
    nerf_synth::generate(cfg, &data).unwrap();
    data
}

/// `nsff train DATA --out RUN_DIR --steps STEPS --no-render`; its stderr.
fn train_briefly(data: &Path, run_dir: &Path, steps: usize) -> String {
    train_briefly_with(data, run_dir, steps, &[])
}

/// [`train_briefly`] with `extra` arguments after its own (`--set` overrides).
fn train_briefly_with(data: &Path, run_dir: &Path, steps: usize, extra: &[&str]) -> String {
    let out = run(nsff()
        .arg("train")
        .arg(data)
        .arg("--out")
        .arg(run_dir)
        .args(["--steps", &steps.to_string(), "--no-render"])
        .args(extra));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn train_eval_and_render_cameras_agree() {
    let dir = temp("cycle");
    let data = video(&dir, Preset::Dynamic, (32, 24), 6);
    let run_dir = dir.join("run");
    let out = run(nsff().arg("train").arg(&data).arg("--out").arg(&run_dir).args([
        "--steps",
        "60",
        "--set",
        "base.checkpoint_every=30",
    ]));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("dynamic field on"), "{stderr}");
    // Six frames over the generator's 80° arc: 16° steps, still a video (flow computed).
    assert!(stderr.contains("camera path: smooth video"), "{stderr}");
    // `--set` reaches the preparation too: masks at an unreachable threshold are empty.
    assert!(!stderr.contains("motion masks: 0.0%"), "{stderr}");
    let no_masks = train_briefly_with(
        &data,
        &dir.join("no_masks"),
        1,
        &["--set", "mask_threshold_px=1000"],
    );
    assert!(no_masks.contains("motion masks: 0.0%"), "{no_masks}");
    let after_train = mean_psnr(&out);
    for f in [
        "checkpoint.bin",
        "psnr.png",
        "render/path.gif",
        "eval.json",
        "scene_flow.json",
    ] {
        assert!(run_dir.join(f).exists(), "{f} missing");
    }
    let eval = run(nsff().arg("eval").arg(&run_dir));
    let evaluated = mean_psnr(&eval);
    assert!(
        (evaluated - after_train).abs() < 1e-6,
        "eval {evaluated} vs end of training {after_train}"
    );
    // The generator's scenes carry their motion: the scene-flow error is reported.
    let text = String::from_utf8_lossy(&eval.stdout);
    assert!(text.contains("scene flow on moving objects: EPE"), "{text}");
    assert!(text.contains("depth on surfaces of the held-out views"), "{text}");
    assert!(evaluated > 12.0, "60 steps should learn something: {evaluated}");

    let renders = dir.join("cams");
    let test_json = data.join("transforms_test.json");
    run(nsff()
        .arg("render")
        .arg(&run_dir)
        .arg("--cameras")
        .arg(&test_json)
        .arg("--out")
        .arg(&renders));
    let independent = score_pngs(&renders, &data);
    eprintln!("nsff eval {evaluated:.4} dB, independent PNG score {independent:.4} dB");
    assert!(
        (independent - evaluated).abs() < 0.05,
        "{independent} vs {evaluated}"
    );
    // One PNG per (camera, time) pair in file order, with its visualisations.
    let names: Vec<String> =
        serde_json::from_slice(&std::fs::read(renders.join("frames.json")).unwrap()).unwrap();
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&test_json).unwrap()).unwrap();
    let want: Vec<&str> = json["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file_path"].as_str().unwrap())
        .collect();
    assert_eq!(names, want);
    for sub in ["", "depth", "dynamic", "flow"] {
        for k in 0..want.len() {
            assert!(
                renders.join(sub).join(format!("{k:04}.png")).exists(),
                "{sub}/{k:04}.png"
            );
        }
    }
    assert!(renders.join("cameras.gif").exists());

    // The static field alone: `render --static-only`, scored independently, agrees with
    // `eval --static-only`, and differs from the full model's renders.
    let static_eval = mean_psnr(&run(nsff().arg("eval").arg(&run_dir).arg("--static-only")));
    let static_renders = dir.join("cams_static");
    run(nsff()
        .arg("render")
        .arg(&run_dir)
        .arg("--cameras")
        .arg(&test_json)
        .arg("--static-only")
        .arg("--out")
        .arg(&static_renders));
    let static_independent = score_pngs(&static_renders, &data);
    assert!(
        (static_independent - static_eval).abs() < 0.05,
        "{static_independent} vs {static_eval}"
    );
    assert!(
        (static_independent - independent).abs() > 1e-3,
        "--static-only rendered the full model: {static_independent} vs {independent}"
    );

    // Geometry at one time and the frames' surface points, read back by a generic PLY reader.
    let mesh = dir.join("mesh.ply");
    let out = run(nsff()
        .args(["export", "mesh"])
        .arg(&run_dir)
        .args([
            "--time",
            "0.5",
            "--resolution",
            "24",
            "--threshold",
            "0.5",
            "--out",
        ])
        .arg(&mesh));
    let (vertices, faces) = support::check_ply(&mesh, [[-5.0; 3], [5.0; 3]]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        faces > 0 && text.contains(&format!("{vertices} vertices, {faces} triangles")),
        "{text}"
    );
    let points = dir.join("points.ply");
    run(nsff()
        .args(["export", "points"])
        .arg(&run_dir)
        .args(["--stride", "2", "--min-opacity", "0.5", "--out"])
        .arg(&points));
    let (n, _) = support::check_ply(&points, [[-5.0; 3], [5.0; 3]]);
    assert!(n > 0);
    // The web viewer at any time, with the dynamic share and the scene flow.
    let channels = ["rgb", "depth", "opacity", "dynamic", "flow"];
    support::check_viewer(env!("CARGO_BIN_EXE_nsff"), &run_dir, &channels, true);
    std::fs::remove_dir_all(dir).unwrap();
}

/// Motion masks given with a video turn on the carve of the space no training frame sees
/// (`carve_unseen`, as the checkpoint records it); `--set carve_unseen=false` still wins, and
/// the same video without masks trains without the carve.
#[test]
fn given_masks_carve_the_unseen_space() {
    let dir = temp("masks");
    let mut cfg = video_config(Preset::Dynamic, (32, 24), 6);
    cfg.motion_masks = true;
    let data = generate(&dir, &cfg);
    let carve_of = |run_dir: &Path| -> bool {
        let state = std::fs::read(run_dir.join("checkpoint.bin")).unwrap();
        let text = String::from_utf8_lossy(&state);
        let on = text.contains("\"carve_unseen\": true");
        assert!(
            on || text.contains("\"carve_unseen\": false"),
            "no carve_unseen recorded"
        );
        on
    };
    let masked = dir.join("masked");
    let stderr = train_briefly(&data, &masked, 1);
    assert!(stderr.contains("given with the video"), "{stderr}");
    assert!(stderr.contains("NoForeground"), "{stderr}");
    assert!(carve_of(&masked));

    let kept = dir.join("kept");
    let stderr = train_briefly_with(&data, &kept, 1, &["--set", "carve_unseen=false"]);
    assert!(!stderr.contains("NoForeground"), "{stderr}");
    assert!(!carve_of(&kept));

    std::fs::remove_dir_all(data.join("motion_masks")).unwrap();
    let unmasked = dir.join("unmasked");
    let stderr = train_briefly(&data, &unmasked, 1);
    assert!(!stderr.contains("given with the video"), "{stderr}");
    assert!(!carve_of(&unmasked));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn static_video_switches_the_dynamic_field_off() {
    let dir = temp("static");
    // The motion decision needs the built-in flow at the generator's own video settings: at
    // 32×24, or with 6 frames on the same camera arc (large steps), the flow's errors read as
    // a few percent of moving pixels.
    let data = video(&dir, Preset::StaticVideo, (128, 96), 24);
    let run_dir = dir.join("run");
    let stderr = train_briefly(&data, &run_dir, 20);
    assert!(stderr.contains("dynamic field off (static scene)"), "{stderr}");
    let state = std::fs::read(run_dir.join("checkpoint.bin")).unwrap();
    let text = String::from_utf8_lossy(&state);
    assert!(
        text.contains("\"dynamic\": false"),
        "checkpoint state should record no dynamic field"
    );
    // Forcing it on is honoured.
    let forced = dir.join("forced");
    let out = run(nsff().arg("train").arg(&data).arg("--out").arg(&forced).args([
        "--steps",
        "2",
        "--no-render",
        "--dynamic",
        "on",
    ]));
    assert!(String::from_utf8_lossy(&out.stderr).contains("dynamic field on"));
    std::fs::remove_dir_all(dir).unwrap();
}

/// The D-NeRF benchmark's kind of capture, from our generator: a random viewpoint every frame.
/// Neighbouring frames are unrelated, so no flow is computed (no cache folder), the header says
/// why, and the time-conditioned field still trains and is scored.
#[test]
fn a_jumping_camera_skips_the_flow() {
    let dir = temp("jumping");
    let cfg = SynthConfig::new(Preset::Jumping)
        .with_size(32, 32)
        .with_views(12, 4);
    let data = generate(&dir, &cfg);
    let run_dir = dir.join("run");
    // 100 steps: after 30 no occupancy cell is occupied, and the render check below needs samples.
    let stderr = train_briefly(&data, &run_dir, 100);
    assert!(stderr.contains("camera path: jumping"), "{stderr}");
    assert!(stderr.contains("no optical flow"), "{stderr}");
    assert!(stderr.contains("dynamic field on"), "{stderr}");
    assert!(!stderr.contains("computing optical flow"), "{stderr}");
    assert!(
        !run_dir.join("flow_cache").exists(),
        "no flow is computed or cached"
    );
    let state = std::fs::read(run_dir.join("checkpoint.bin")).unwrap();
    let text = String::from_utf8_lossy(&state);
    // The jumping camera's settings, as the checkpoint records them, and why each is there.
    let settings = [
        (
            "\"time_interp\": \"direct\"",
            "it renders between frames by querying the field",
        ),
        (
            "\"warm_up_exit_rise\": 2.0",
            "its static warm-up ends when the grid fills up again",
        ),
        ("\"occupancy_time_bins\": 8", "its occupancy grid has time bins"),
        (
            "\"target_samples\": 4096",
            "it takes smaller, more frequent steps",
        ),
        (
            "\"sparsity_points\": 512",
            "its sparsity term looks at fewer points",
        ),
        ("\"error_rays\": 0.5", "half its rays follow its error map"),
        ("\"time_jitter\": 0.5", "it jitters its rays' times"),
        (
            "\"render_step_scale\": 0.5",
            "it renders at half the training step",
        ),
        (
            "\"time_resolution\": 5",
            "its time cells span two frames (12 frames: 11 gaps, 5 cells)",
        ),
    ];
    for (setting, why) in settings {
        assert!(text.contains(setting), "a jumping camera: {why} (no {setting})");
    }
    let eval = run(nsff().arg("eval").arg(&run_dir));
    assert!(mean_psnr(&eval).is_finite());
    // A finer render step, asked for at evaluation, marches more samples per ray (twice as
    // many from the run's own 0.5 to 0.25).
    let samples_per_ray = || -> f64 {
        let text = std::fs::read_to_string(run_dir.join("eval.json")).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v["samples_per_ray"].as_f64().unwrap()
    };
    let own = samples_per_ray();
    let fine = run(nsff()
        .arg("eval")
        .arg(&run_dir)
        .args(["--render-step-scale", "0.25"]));
    assert!(mean_psnr(&fine).is_finite());
    let finer = samples_per_ray();
    assert!(finer > 1.5 * own, "{finer} against {own}");
    let bad = nsff()
        .arg("eval")
        .arg(&run_dir)
        .args(["--render-step-scale", "0"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && stderr.contains("--render-step-scale"),
        "{stderr}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn killed_training_resumes_to_the_same_result() {
    let dir = temp("resume");
    let data = video(&dir, Preset::Dynamic, (32, 24), 6);
    let args = [
        "--steps",
        "100",
        "--set",
        "base.checkpoint_every=10",
        "--no-render",
        "--seed",
        "3",
    ];
    let (want, got, stderr) = kill_and_resume(env!("CARGO_BIN_EXE_nsff"), &data, &dir, &args, 40);
    assert!(stderr.contains("resuming"), "{stderr}");
    assert!(stderr.contains("trained 100 steps"), "{stderr}");
    assert!((got - want).abs() < 0.5, "{got} vs {want}");
    std::fs::remove_dir_all(dir).unwrap();
}
