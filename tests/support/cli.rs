//! Helpers shared by the `nerf` and `nsff` command-line tests. Integration tests of one crate
//! cannot import another's, so both `crates/*/tests/cli.rs` include this file with `#[path]`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `cmd` and returns its output, failing the test with both streams if it failed.
pub fn run(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("spawn");
    assert!(
        out.status.success(),
        "{:?} failed\nstdout:\n{}\nstderr:\n{}",
        cmd,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A fresh, empty directory `<tmp>/<prefix>-<name>-<pid>`.
pub fn temp(prefix: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("{prefix}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The value after `mean_psnr` on the last line of stdout.
pub fn mean_psnr(out: &Output) -> f64 {
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or_default();
    last.strip_prefix("mean_psnr ")
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("last line: {last}"))
}

/// PSNR of rendered PNGs (`renders/0000.png`, … in file order) against the scene's test PNGs
/// composited on white, computed here independently of the program's own evaluation.
pub fn score_pngs(renders: &Path, data: &Path) -> f64 {
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("transforms_test.json")).unwrap()).unwrap();
    let frames = json["frames"].as_array().unwrap();
    let mut total = 0.0;
    for (k, f) in frames.iter().enumerate() {
        let file = f["file_path"].as_str().unwrap().trim_start_matches("./");
        let gt = image::open(data.join(format!("{file}.png")))
            .unwrap()
            .to_rgba32f();
        let ours = image::open(renders.join(format!("{k:04}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!(gt.dimensions(), ours.dimensions());
        let mut se = 0.0f64;
        for (g, o) in gt.pixels().zip(ours.pixels()) {
            let a = g[3];
            for c in 0..3 {
                let want = g[c] * a + (1.0 - a);
                se += (want as f64 - o[c] as f64 / 255.0).powi(2);
            }
        }
        let mse = se / (3 * gt.width() * gt.height()) as f64;
        total += -10.0 * mse.log10();
    }
    total / frames.len() as f64
}

/// Trains `data` with `bin train … args` twice under `dir`: once uninterrupted, once killed
/// (SIGKILL) after `kill_after` logged steps and a checkpoint, then `--resume`d. Returns the
/// evaluated PSNR of both and the resumed run's stderr.
pub fn kill_and_resume(
    bin: &str,
    data: &Path,
    dir: &Path,
    args: &[&str],
    kill_after: usize,
) -> (f64, f64, String) {
    let train = |out: &Path| {
        let mut cmd = Command::new(bin);
        cmd.arg("train").arg(data).arg("--out").arg(out);
        cmd
    };
    let eval = |out: &Path| mean_psnr(&run(Command::new(bin).arg("eval").arg(out)));
    let reference = dir.join("reference");
    run(train(&reference).args(args));
    let want = eval(&reference);

    let killed = dir.join("killed");
    let mut child = train(&killed).args(args).spawn().unwrap();
    let metrics = killed.join("metrics.jsonl");
    let start = std::time::Instant::now();
    loop {
        let steps = std::fs::read_to_string(&metrics)
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if steps >= kill_after && killed.join("checkpoint.bin").exists() {
            break;
        }
        assert!(start.elapsed().as_secs() < 300, "training did not progress");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL on Unix
    child.wait().unwrap();
    let out = run(train(&killed).arg("--resume").arg("--no-render"));
    let got = eval(&killed);
    eprintln!("uninterrupted {want:.3} dB, killed and resumed {got:.3} dB");
    (want, got, String::from_utf8_lossy(&out.stderr).into_owned())
}
