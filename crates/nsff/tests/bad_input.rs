//! `nsff train` on malformed videos fails with a message naming the file and the problem.

use std::path::{Path, PathBuf};
use std::process::Command;

use nerf_data::Image;

fn temp(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nsff-bad-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("train")).unwrap();
    dir
}

/// A D-NeRF-style video of `times.len()` 8×6 frames; `None` leaves a frame's time out.
fn video(tag: &str, times: &[Option<f64>]) -> PathBuf {
    let dir = temp(tag);
    let frames: Vec<serde_json::Value> = times
        .iter()
        .enumerate()
        .map(|(k, t)| {
            let mut img = Image::new(8, 6, 3);
            img.data
                .iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v = ((i + k) % 7) as f32 / 7.0);
            img.save_png(&dir.join(format!("train/r_{k:03}.png"))).unwrap();
            let x = 0.1 * k as f64;
            let mut f = serde_json::json!({
                "file_path": format!("./train/r_{k:03}"),
                "transform_matrix": [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]],
            });
            if let Some(t) = t {
                f["time"] = serde_json::json!(t);
            }
            f
        })
        .collect();
    let json = serde_json::json!({ "camera_angle_x": 0.7, "frames": frames });
    for split in ["train", "test"] {
        std::fs::write(
            dir.join(format!("transforms_{split}.json")),
            serde_json::to_string_pretty(&json).unwrap(),
        )
        .unwrap();
    }
    dir
}

fn train_error(data: &Path) -> String {
    train_error_with(data, &[])
}

fn train_error_with(data: &Path, extra: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_nsff"))
        .arg("train")
        .arg(data)
        .arg("--out")
        .arg(data.join("run"))
        .args(["--steps", "1", "--no-render"])
        .args(extra)
        .output()
        .unwrap();
    assert!(!out.status.success(), "training on bad input succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn malformed_videos_name_the_file_and_the_problem() {
    let cases: [(&str, Vec<Option<f64>>, &str); 5] = [
        (
            "sometime",
            vec![Some(0.0), None, Some(1.0)],
            r#"frame 1 (./train/r_001) has no "time""#,
        ),
        ("notime", vec![None, None, None], "frames without time"),
        (
            "decreasing",
            vec![Some(0.0), Some(0.6), Some(0.3), Some(1.0)],
            "time decreases",
        ),
        (
            "duplicate",
            vec![Some(0.0), Some(0.5), Some(0.5), Some(1.0)],
            "the same time",
        ),
        ("two", vec![Some(0.0), Some(1.0)], "at least 3"),
    ];
    for (tag, times, problem) in cases {
        let data = video(tag, &times);
        let err = train_error(&data);
        assert!(
            err.contains("transforms_train.json") && err.contains(problem),
            "{tag}: {err}"
        );
        std::fs::remove_dir_all(data).unwrap();
    }
}

/// A bad `--set` is refused before the video is loaded and its optical flow computed.
#[test]
fn bad_settings_are_refused_before_the_video_is_prepared() {
    let data = video("set", &[Some(0.0), Some(0.5), Some(1.0)]);
    for (set, want) in [
        ("warp_neighbours=0", "warp_neighbours"),
        ("no_such_setting=1", "no setting 'no_such_setting'"),
        ("time_jitter=-1", "time_jitter"),
    ] {
        let err = train_error_with(&data, &["--set", set]);
        assert!(err.contains(want), "{set}: {err}");
        assert!(err.contains(&data.display().to_string()), "{set}: {err}");
        assert!(
            !err.contains("optical flow"),
            "{set}: prepared the video first: {err}"
        );
        assert!(!err.contains("loaded and prepared"), "{set}: {err}");
    }
    std::fs::remove_dir_all(data).unwrap();
}
