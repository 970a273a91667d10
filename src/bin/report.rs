//! Benchmark report: run time against error.
//!
//! `report speed` trains each configuration for a series of time budgets through the `nerf` and
//! `nsff` binaries next to this one (a fresh run per budget, so every point is what a user gets
//! from `--time-budget B`), scores the held-out views, and writes `speed.csv` and PSNR-against-
//! time plots. `report quadrature` measures compositing error against the analytic integral as
//! samples per ray grow, for each sampler, and writes `quadrature.csv` and a log-log plot.
//!
//! Build first: `cargo build --release --workspace`, then e.g.
//! `target/release/report speed --out docs/report` (about 30 minutes with the default budgets).

use std::path::{Path, PathBuf};
use std::process::Command;

use clap::{Parser, Subcommand};
use nerf::plot::{Chart, PALETTE, Series};
use nerf_core::composite::{self, RayLayout};
use nerf_core::occupancy::{OccupancyConfig, OccupancyGrid};
use nerf_core::rays::Rays;
use nerf_core::sampler::{self, MarchConfig, RaySamples, Spacing};
use rand::{SeedableRng, rngs::StdRng};

#[derive(Parser)]
#[command(about = "Regenerates the benchmark CSVs and plots (run time against error)")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Held-out PSNR against training time for each configuration (trains fresh runs).
    Speed {
        /// Output folder for the CSV, plots and runs.
        #[arg(long, default_value = "docs/report")]
        out: PathBuf,
        /// Tiny lego npz (static suite).
        #[arg(long, default_value = "../shared/data/lego_tiny/tiny_nerf_data.npz")]
        lego: PathBuf,
        /// Time budgets (seconds) for the static suite.
        #[arg(long, value_delimiter = ',', default_value = "15,30,60,120")]
        budgets: Vec<f64>,
        /// Time budgets (seconds) for NSFF against static NeRF on a dynamic generator scene.
        #[arg(long, value_delimiter = ',', default_value = "30,60,120")]
        dynamic_budgets: Vec<f64>,
        /// Time budgets (seconds) for NSFF against static NeRF on a static scene in the video
        /// format (NSFF's skip path).
        #[arg(long, value_delimiter = ',', default_value = "60")]
        skip_budgets: Vec<f64>,
        /// Which suites to run (`all` leaves out `dnerf`, which takes about an hour).
        #[arg(long, value_enum, default_value = "all")]
        suite: Suite,
        /// The D-NeRF benchmark folder (dnerf suite: every scene in it with a
        /// transforms_train.json, trained by `nsff --downscale 2`).
        #[arg(long, default_value = "../shared/data/dnerf")]
        dnerf: PathBuf,
        /// Time budgets (seconds) for the dnerf suite.
        #[arg(long, value_delimiter = ',', default_value = "60,120,300,600")]
        dnerf_budgets: Vec<f64>,
    },
    /// Compositing error against samples per ray for each sampler.
    Quadrature {
        #[arg(long, default_value = "docs/report")]
        out: PathBuf,
    },
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Suite {
    All,
    Static,
    Dynamic,
    Skip,
    /// NSFF on the D-NeRF benchmark's scenes at 400×400, against the published results.
    Dnerf,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Cmd::Speed {
            out,
            lego,
            budgets,
            dynamic_budgets,
            skip_budgets,
            suite,
            dnerf,
            dnerf_budgets,
        } => {
            if suite == Suite::Dnerf {
                dnerf_suite(&out, &dnerf, &dnerf_budgets)
            } else {
                speed(&out, &lego, [&budgets, &dynamic_budgets, &skip_budgets], suite)
            }
        }
        Cmd::Quadrature { out } => quadrature(&out),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

type Res<T> = Result<T, String>;

/// A sibling binary (`nerf`, `nsff`) of this executable.
fn tool(name: &str) -> Res<PathBuf> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let path = exe.with_file_name(name);
    if path.exists() {
        Ok(path)
    } else {
        Err(format!(
            "{} not found: build it with `cargo build --release --workspace`",
            path.display()
        ))
    }
}

fn run(cmd: &mut Command) -> Res<String> {
    let out = cmd.output().map_err(|e| format!("{cmd:?}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{cmd:?} failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// One configuration of the speed report.
struct Config {
    suite: &'static str,
    name: &'static str,
    binary: &'static str,
    args: Vec<&'static str>,
}

/// One measured point.
struct Point {
    psnr: f64,
    ssim: f64,
    steps: u64,
    eval_samples_per_ray: f64,
    train_rays_per_sec: f64,
    train_samples_per_ray: f64,
    render_s_per_view: f64,
}

/// The CSV columns after the budget: steps, test PSNR and SSIM, eval samples per ray, train
/// rays per second and samples per ray, render seconds per view.
const POINT_COLUMNS: &str =
    "steps,test_psnr,test_ssim,eval_samples_per_ray,train_rays_per_s,train_samples_per_ray,render_s_per_view";

impl Point {
    fn csv(&self) -> String {
        format!(
            "{},{:.3},{:.4},{:.2},{:.0},{:.2},{:.3}",
            self.steps,
            self.psnr,
            self.ssim,
            self.eval_samples_per_ray,
            self.train_rays_per_sec,
            self.train_samples_per_ray,
            self.render_s_per_view
        )
    }
}

/// Writes a line chart with a logarithmic x axis to `path`.
fn save_chart(title: &str, (x_label, y_label): (&str, &str), series: Vec<Series>, path: &Path) -> Res<()> {
    Chart {
        title: title.into(),
        x_label: x_label.into(),
        y_label: y_label.into(),
        series,
        log_x: true,
    }
    .save(path)
    .map_err(|e| e.to_string())
}

fn train_and_score(cfg: &Config, data: &Path, budget: f64, run_dir: &Path) -> Res<Point> {
    let bin = tool(cfg.binary)?;
    let _ = std::fs::remove_dir_all(run_dir);
    run(Command::new(&bin)
        .arg("train")
        .arg(data)
        .arg("--out")
        .arg(run_dir)
        .arg("--time-budget")
        .arg(budget.to_string())
        .arg("--no-render")
        .args(&cfg.args))?;
    run(Command::new(&bin).arg("eval").arg(run_dir))?;
    let eval: serde_json::Value = serde_json::from_slice(
        &std::fs::read(run_dir.join("eval.json")).map_err(|e| format!("{}: {e}", run_dir.display()))?,
    )
    .map_err(|e| e.to_string())?;
    let num = |v: &serde_json::Value, k: &str| v.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN);
    // Training throughput from the metrics log: rays and samples over the logged step times.
    let log = std::fs::read_to_string(run_dir.join("metrics.jsonl")).map_err(|e| e.to_string())?;
    let (mut rays, mut samples, mut n) = (0.0, 0.0, 0.0);
    for line in log.lines() {
        let Ok(rec) = serde_json::from_str::<serde_json::Value>(line) else {
            continue;
        };
        let (r, s) = (num(&rec, "rays_per_sec"), num(&rec, "samples_per_ray"));
        if r.is_finite() && s.is_finite() {
            rays += r;
            samples += s;
            n += 1.0;
        }
    }
    Ok(Point {
        psnr: num(&eval, "mean_psnr"),
        ssim: num(&eval, "mean_ssim"),
        steps: eval.get("step").and_then(|x| x.as_u64()).unwrap_or(0),
        eval_samples_per_ray: num(&eval, "samples_per_ray"),
        train_rays_per_sec: rays / n,
        train_samples_per_ray: samples / n,
        render_s_per_view: num(&eval, "render_seconds")
            / eval
                .get("views")
                .and_then(|v| v.as_array())
                .map_or(f64::NAN, |v| v.len() as f64),
    })
}

fn speed(
    out: &Path,
    lego: &Path,
    [budgets, dyn_budgets, skip_budgets]: [&[f64]; 3],
    suite: Suite,
) -> Res<()> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut configs = Vec::new();
    if matches!(suite, Suite::All | Suite::Static) {
        if !lego.exists() {
            return Err(format!("{} not found (pass --lego)", lego.display()));
        }
        for (name, args) in [
            ("vanilla", vec!["--preset", "vanilla"]),
            ("fast", vec![]),
            (
                "fast, no occupancy grid",
                vec!["--set", "fast.use_occupancy=false"],
            ),
            (
                "fast, no early termination",
                vec!["--set", "fast.early_termination=false"],
            ),
        ] {
            configs.push((
                Config {
                    suite: "tiny_lego",
                    name,
                    binary: "nerf",
                    args,
                },
                lego.to_path_buf(),
                budgets.to_vec(),
            ));
        }
    }
    for (which, suite_name, preset, budgets) in [
        (Suite::Dynamic, "dynamic", "dynamic", dyn_budgets),
        (Suite::Skip, "static_video", "static_video", skip_budgets),
    ] {
        if !(suite == Suite::All || suite == which) {
            continue;
        }
        let scene = out.join("runs").join(format!("{suite_name}_scene"));
        if !scene.join("transforms_train.json").exists() {
            run(Command::new(tool("nerf")?)
                .args(["synth", "--preset", preset, "--seed", "0"])
                .arg(&scene))?;
        }
        for (name, binary) in [("static NeRF (fast)", "nerf"), ("NSFF (fast)", "nsff")] {
            configs.push((
                Config {
                    suite: suite_name,
                    name,
                    binary,
                    args: vec![],
                },
                scene.clone(),
                budgets.to_vec(),
            ));
        }
    }
    let csv_path = out.join("speed.csv");
    let mut csv = format!("suite,config,budget_s,{POINT_COLUMNS}\n");
    let mut curves: Vec<(&str, Series)> = Vec::new();
    for (k, (cfg, data, budgets)) in configs.iter().enumerate() {
        let mut series = Series {
            name: cfg.name.to_string(),
            points: Vec::new(),
            color: PALETTE[k % PALETTE.len()],
        };
        for &b in budgets {
            let slug: String = cfg
                .name
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect();
            let dir = out.join("runs").join(format!("{}_{slug}_{b}", cfg.suite));
            eprintln!("{} / {} / {b} s ...", cfg.suite, cfg.name);
            let p = train_and_score(cfg, data, b, &dir)?;
            eprintln!(
                "  test PSNR {:.2} dB, {} steps, {:.1} samples/ray at eval, {:.0} train rays/s",
                p.psnr, p.steps, p.eval_samples_per_ray, p.train_rays_per_sec
            );
            csv.push_str(&format!(
                "{},{},{b},{}\n",
                cfg.suite,
                cfg.name.replace(',', ";"),
                p.csv()
            ));
            series.points.push((b, p.psnr));
            // Written after every point, so an interrupted report keeps what it measured.
            nerf_data::image::write_atomic(&csv_path, csv.as_bytes()).map_err(|e| e.to_string())?;
        }
        curves.push((cfg.suite, series));
    }
    for (suite, title) in [
        ("tiny_lego", "Tiny lego: held-out PSNR against training time"),
        (
            "dynamic",
            "Dynamic generator scene: held-out PSNR against training time",
        ),
        (
            "static_video",
            "Static scene in the video format: held-out PSNR against training time",
        ),
    ] {
        let series: Vec<Series> = curves
            .iter()
            .filter(|(s, _)| *s == suite)
            .map(|(_, c)| c.clone())
            .collect();
        if series.is_empty() {
            continue;
        }
        save_chart(
            title,
            ("training time budget (s)", "test PSNR (dB)"),
            series,
            &out.join(format!("speed_{suite}.png")),
        )?;
    }
    println!("{csv}");
    println!("wrote {}", csv_path.display());
    Ok(())
}

/// Published test PSNR on the three shared D-NeRF scenes (bouncingballs, jumpingjacks,
/// standup), averaged over them; method.md §8.
const DNERF_PUBLISHED: [(&str, [f64; 3]); 4] = [
    ("D-NeRF paper (about 20 h, GPU)", [32.80, 32.80, 32.79]),
    ("K-Planes (nerfacc re-run, 70 min, GPU)", [39.10, 31.11, 32.51]),
    ("TiNeuVox (official, 14 min, GPU)", [39.37, 32.92, 33.59]),
    ("T-NeRF + nerfacc (1 h, GPU)", [39.49, 32.73, 35.90]),
];

/// The dnerf suite: `nsff` on every scene of `root` for each budget, `dnerf.csv` and a plot of
/// test PSNR against training time with the published results as horizontal lines.
fn dnerf_suite(out: &Path, root: &Path, budgets: &[f64]) -> Res<()> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(root)
        .map_err(|e| format!("{}: {e}", root.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("transforms_train.json").exists())
        .collect();
    scenes.sort();
    if scenes.is_empty() {
        return Err(format!(
            "{}: no scene folders with transforms_train.json",
            root.display()
        ));
    }
    let csv_path = out.join("dnerf.csv");
    let mut csv = format!("scene,budget_s,{POINT_COLUMNS}\n");
    let mut series = Vec::new();
    let mut by_budget = vec![Vec::new(); budgets.len()];
    for (k, scene) in scenes.iter().enumerate() {
        let name = scene
            .file_name()
            .map_or("scene".into(), |n| n.to_string_lossy().into_owned());
        let cfg = Config {
            suite: "dnerf",
            name: "nsff",
            binary: "nsff",
            args: vec!["--downscale", "2"],
        };
        let mut points = Vec::new();
        for (i, &b) in budgets.iter().enumerate() {
            eprintln!("dnerf / {name} / {b} s ...");
            let p = train_and_score(
                &cfg,
                scene,
                b,
                &out.join("runs").join(format!("dnerf_{name}_{b}")),
            )?;
            eprintln!(
                "  test PSNR {:.2} dB, SSIM {:.4}, {} steps",
                p.psnr, p.ssim, p.steps
            );
            csv.push_str(&format!("{name},{b},{}\n", p.csv()));
            nerf_data::image::write_atomic(&csv_path, csv.as_bytes()).map_err(|e| e.to_string())?;
            points.push((b, p.psnr));
            by_budget[i].push(p.psnr);
        }
        series.push(Series {
            name: format!("nsff, {name}"),
            points,
            color: PALETTE[k % PALETTE.len()],
        });
    }
    series.push(Series {
        name: "nsff, mean".into(),
        points: budgets
            .iter()
            .zip(&by_budget)
            .map(|(&b, v)| (b, v.iter().sum::<f64>() / v.len() as f64))
            .collect(),
        color: [0, 0, 0],
    });
    let (lo, hi) = budgets
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &b| (lo.min(b), hi.max(b)));
    for (k, (label, psnr)) in DNERF_PUBLISHED.iter().enumerate() {
        let mean = psnr.iter().sum::<f64>() / 3.0;
        series.push(Series {
            name: format!("{label}: {mean:.2}"),
            points: vec![(lo, mean), (hi, mean)],
            color: PALETTE[(scenes.len() + k) % PALETTE.len()],
        });
    }
    save_chart(
        "D-NeRF scenes at 400x400: test PSNR against training time (2 CPU cores)",
        (
            "training time budget (s)",
            "test PSNR (dB); published: mean over the same three scenes",
        ),
        series,
        &out.join("dnerf.png"),
    )?;
    println!("{csv}");
    println!(
        "wrote {} and {}",
        csv_path.display(),
        out.join("dnerf.png").display()
    );
    Ok(())
}

/// Test medium along the ray: a slab of density SIGMA on depths [A, A + L] (shifted per ray),
/// colour equal to depth. Opacity and colour have closed forms.
const SIGMA: f64 = 20.0;
const A: f64 = 0.3;
const L: f64 = 0.237;
const RAYS: usize = 256;

fn slab_start(ray: usize) -> f64 {
    A + 0.1 * ray as f64 / RAYS as f64
}

/// Analytic opacity and colour (∫ T σ c dt with c = t) of ray `ray`.
fn analytic(ray: usize) -> (f64, f64) {
    let a = slab_start(ray);
    let e = (-SIGMA * L).exp();
    (1.0 - e, a * (1.0 - e) + (1.0 - e) / SIGMA - L * e)
}

fn density(ray: usize, t: f64) -> f64 {
    let a = slab_start(ray);
    if t >= a && t < a + L { SIGMA } else { 0.0 }
}

/// RMS errors (opacity, colour) of compositing `samples` through our compositing kernel.
fn errors(samples: &RaySamples, rays: &Rays) -> (f64, f64) {
    let layout: RayLayout = samples.layout(rays, false);
    let sigma: Vec<f32> = (0..samples.num_rays())
        .flat_map(|r| samples.range(r).map(move |i| (r, i)))
        .map(|(r, i)| density(r, samples.t[i] as f64) as f32)
        .collect();
    let w = composite::weights(&sigma, &layout, 0.0);
    let (mut e_a, mut e_c) = (0.0, 0.0);
    for r in 0..samples.num_rays() {
        let (mut acc, mut col) = (0.0f64, 0.0f64);
        for i in samples.range(r) {
            acc += w[i] as f64;
            col += w[i] as f64 * samples.t[i] as f64;
        }
        let (a, c) = analytic(r);
        e_a += (acc - a).powi(2);
        e_c += (col - c).powi(2);
    }
    let n = samples.num_rays() as f64;
    ((e_a / n).sqrt(), (e_c / n).sqrt())
}

fn quadrature(out: &Path) -> Res<()> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    // Rays along +z from the origin through the unit box; depth t is the z coordinate.
    let mut rays = Rays::with_capacity(RAYS);
    for _ in 0..RAYS {
        rays.push([0.5, 0.5, 0.0], [0.0, 0.0, 1.0]);
    }
    let (near, far) = (vec![0.0f32; RAYS], vec![1.0f32; RAYS]);
    // Occupancy grid marking the cells any ray's slab touches (what a trained grid holds).
    let occ_cfg = OccupancyConfig {
        resolution: 64,
        ..OccupancyConfig::default()
    };
    let mut grid = OccupancyGrid::new(occ_cfg, [[0.0; 3], [1.0; 3]]);
    let values = (0..grid.num_cells())
        .map(|i| {
            let z = grid.cell_center(i)[2] as f64;
            let half = 0.5 / 64.0;
            if z + half > A && z - half < A + 0.1 + L {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    grid.set_values(values);
    let mut rng = StdRng::seed_from_u64(0);
    let mut csv = String::from("method,samples_per_ray,opacity_rmse,color_rmse\n");
    let names = ["uniform", "stratified", "hierarchical", "occupancy-marched"];
    let mut series: Vec<Series> = names
        .iter()
        .enumerate()
        .map(|(k, n)| Series {
            name: n.to_string(),
            points: Vec::new(),
            color: PALETTE[k],
        })
        .collect();
    for n in [4usize, 8, 16, 32, 64, 128, 256, 512] {
        let uniform = sampler::stratified(&near, &far, n, Spacing::Depth, None::<&mut StdRng>);
        let strat = sampler::stratified(&near, &far, n, Spacing::Depth, Some(&mut rng));
        // NeRF's hierarchy: n/2 coarse, n/2 drawn from the coarse weights, composited together.
        let coarse = sampler::stratified(&near, &far, (n / 2).max(1), Spacing::Depth, Some(&mut rng));
        let layout_c = coarse.layout(&rays, false);
        let sigma_c: Vec<f32> = (0..RAYS)
            .flat_map(|r| coarse.range(r).map(move |i| (r, i)))
            .map(|(r, i)| density(r, coarse.t[i] as f64) as f32)
            .collect();
        let w = composite::weights(&sigma_c, &layout_c, 0.0);
        let fine = sampler::sample_pdf(&coarse, &w, (n / 2).max(1), Some(&mut rng));
        // sample_pdf returns the intervals of the sorted union of coarse and fine samples.
        let hier = fine;
        // Marching: choose the step so the slab region holds about n samples per ray.
        let march_cfg = MarchConfig {
            step: (L + 0.1 + 2.0 / 64.0) as f32 / n as f32,
            cone_angle: 0.0,
            max_step: 1.0,
            max_samples: 100_000,
        };
        let marched = sampler::march(
            &rays,
            grid.aabb,
            0.0,
            1.0,
            Some(&grid),
            &march_cfg,
            Some(&mut rng),
        );
        for (k, s) in [uniform, strat, hier, marched].iter().enumerate() {
            let (ea, ec) = errors(s, &rays);
            let spr = s.num_samples() as f64 / RAYS as f64;
            csv.push_str(&format!("{},{spr:.2},{ea:.3e},{ec:.3e}\n", names[k]));
            series[k].points.push((spr, ec.max(1e-12).log10()));
        }
    }
    let path = out.join("quadrature.csv");
    nerf_data::image::write_atomic(&path, csv.as_bytes()).map_err(|e| e.to_string())?;
    save_chart(
        "Compositing error against samples per ray (slab, analytic reference)",
        ("samples per ray", "log10 RMS colour error"),
        series,
        &out.join("quadrature.png"),
    )?;
    println!("{csv}");
    println!("wrote {}", path.display());
    Ok(())
}
