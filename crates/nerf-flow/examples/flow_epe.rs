//! End-point error of `nerf_flow::estimate_flow` against the synthetic generator's exact
//! optical flow, over every forward pair of a video preset, with the time per pair.
//!
//! ```text
//! cargo run -p nerf-flow --release --example flow_epe -- [--preset dynamic] [--seed 0]
//!     [--method tvl1|hs|lk|all] [--size 128x96] [--frames 24] [--min-size 8]
//! ```
//! The crate docs of `nerf_flow` quote its output (`--method all`). With `--preset family` a seed
//! draws its own frame count and size, as in `nerf synth` (`--size` and `--frames` override them).

use std::time::Instant;

use nerf_data::Image;
use nerf_flow::{FlowMethod, FlowParams, TvL1Params, estimate_flow};
use nerf_synth::{Preset, Scene, Split, SynthConfig};

fn arg<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map(String::as_str)
}

/// The methods to compare, with the shared settings overridden from the command line.
fn methods(args: &[String]) -> Result<Vec<(&'static str, FlowParams)>, String> {
    let num = |name: &str, default: f32| -> Result<f32, String> {
        arg(args, name).map_or(Ok(default), |v| v.parse().map_err(|e| format!("{name} {v}: {e}")))
    };
    let d = FlowParams::default();
    let tv = TvL1Params::default();
    let base = FlowParams {
        scale_step: num("--step", d.scale_step)?,
        min_size: num("--min-size", d.min_size as f32)? as u32,
        warps: num("--warps", d.warps as f32)? as u32,
        iterations: num("--iters", d.iterations as f32)? as u32,
        median_radius: num("--median", d.median_radius as f32)? as u32,
        presmooth_sigma: num("--presmooth", d.presmooth_sigma)?,
        ..d
    };
    let tvl1 = TvL1Params {
        lambda: num("--lambda", tv.lambda)?,
        theta: num("--theta", tv.theta)?,
        huber: num("--huber", tv.huber)?,
        ..tv
    };
    let all = [
        (
            "tvl1",
            FlowParams {
                method: FlowMethod::TvL1(tvl1),
                ..base
            },
        ),
        (
            "hs",
            FlowParams {
                method: FlowMethod::HornSchunck {
                    alpha: num("--alpha", 5.0)?,
                },
                ..base
            },
        ),
        (
            "lk",
            FlowParams {
                method: FlowMethod::LucasKanade {
                    sigma: num("--sigma", 2.0)?,
                },
                ..base
            },
        ),
    ];
    let which = arg(args, "--method").unwrap_or("all");
    let picked: Vec<_> = all
        .into_iter()
        .filter(|(n, _)| which == "all" || *n == which)
        .collect();
    if picked.is_empty() {
        return Err(format!("unknown method '{which}' (tvl1, hs, lk or all)"));
    }
    Ok(picked)
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let preset: Preset = arg(&args, "--preset").unwrap_or("dynamic").parse()?;
    let seed: u64 = arg(&args, "--seed")
        .unwrap_or("0")
        .parse()
        .map_err(|e| format!("--seed: {e}"))?;
    let mut cfg = SynthConfig::seeded(preset, seed);
    if let Some(size) = arg(&args, "--size") {
        let (w, h) = size
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .ok_or_else(|| format!("--size {size}: expected WxH"))?;
        cfg = cfg.with_size(w, h);
    }
    if let Some(n) = arg(&args, "--frames") {
        cfg.frames = n.parse().map_err(|e| format!("--frames: {e}"))?;
    }
    cfg.validate()?;
    if !preset.is_video() {
        return Err("flow needs a video preset (dynamic or static_video)".into());
    }
    let scene = Scene::from_config(&cfg);
    let views: Vec<_> = scene.views_in(Split::Train).cloned().collect();
    let t0 = Instant::now();
    let frames: Vec<Image> = views
        .iter()
        .map(|v| {
            let out = scene.render(&scene.camera(v), v.time);
            out.rgba
                .composite_alpha([
                    scene.background[0] as f32,
                    scene.background[1] as f32,
                    scene.background[2] as f32,
                ])
                .0
        })
        .collect();
    let gt: Vec<(Vec<f32>, Vec<f32>)> = views
        .windows(2)
        .map(|p| scene.optical_flow(&scene.camera(&p[0]), p[0].time, &scene.camera(&p[1]), p[1].time))
        .collect();
    let (mut mag, mut n) = (0f64, 0usize);
    for (f, m) in &gt {
        for p in 0..m.len() {
            if m[p] > 0.5 {
                mag += (f[2 * p] as f64).hypot(f[2 * p + 1] as f64);
                n += 1;
            }
        }
    }
    println!(
        "{preset} seed {seed}: {} frames {}x{}, rendered with ground truth in {:.1} s; mean |flow| {:.2} px",
        frames.len(),
        cfg.width,
        cfg.height,
        t0.elapsed().as_secs_f64(),
        mag / n.max(1) as f64
    );
    for (name, params) in methods(&args)? {
        let (mut sum, mut count, mut secs, mut worst) = (0f64, 0usize, 0f64, 0f64);
        let mut moving = (0f64, 0usize);
        let mut all_errors = Vec::new();
        let mover = scene.moving_objects();
        for (k, (gflow, gmask)) in gt.iter().enumerate() {
            let t = Instant::now();
            let flow = estimate_flow(&frames[k], &frames[k + 1], &params);
            secs += t.elapsed().as_secs_f64();
            let ids = scene.render(&scene.camera(&views[k]), views[k].time).object_id;
            let (mut s, mut c) = (0f64, 0usize);
            for p in 0..gmask.len() {
                if gmask[p] > 0.5 {
                    let e = ((flow[2 * p] - gflow[2 * p]) as f64)
                        .hypot((flow[2 * p + 1] - gflow[2 * p + 1]) as f64);
                    s += e;
                    all_errors.push(e);
                    c += 1;
                    if mover.contains(&(ids[p].max(0) as usize)) && ids[p] >= 0 {
                        moving.0 += e;
                        moving.1 += 1;
                    }
                }
            }
            if let (0, Some(dir)) = (k, arg(&args, "--dump")) {
                dump(std::path::Path::new(dir), name, &frames[0], &flow, gflow, gmask)?;
            }
            worst = worst.max(s / c.max(1) as f64);
            sum += s;
            count += c;
        }
        all_errors.sort_by(f64::total_cmp);
        let median = all_errors.get(all_errors.len() / 2).copied().unwrap_or(f64::NAN);
        let over1 = all_errors.iter().filter(|&&e| e > 1.0).count() as f64 / all_errors.len().max(1) as f64;
        println!(
            "{name:5} mean EPE {:.3} px, median {median:.3}, {:.2}% > 1 px, over {} GT-valid pixels (worst pair {:.3}, on the moving object {:.3}), {:.1} ms per pair",
            sum / count.max(1) as f64,
            100.0 * over1,
            count,
            worst,
            moving.0 / moving.1.max(1) as f64,
            1e3 * secs / gt.len() as f64
        );
    }
    Ok(())
}

/// Writes the first frame and the first pair's end-point error (white = 1 px or more, red =
/// no ground truth) as PNGs, to see where a method fails.
fn dump(
    dir: &std::path::Path,
    name: &str,
    frame: &Image,
    flow: &[f32],
    gt: &[f32],
    mask: &[f32],
) -> Result<(), String> {
    let err = |e: nerf_data::DataError| e.to_string();
    frame.save_png(&dir.join("frame0.png")).map_err(err)?;
    let data = (0..mask.len())
        .flat_map(|p| {
            if mask[p] > 0.5 {
                let e = (flow[2 * p] - gt[2 * p])
                    .hypot(flow[2 * p + 1] - gt[2 * p + 1])
                    .min(1.0);
                [e, e, e]
            } else {
                [0.5, 0.0, 0.0]
            }
        })
        .collect();
    Image::from_data(frame.width, frame.height, 3, data)
        .save_png(&dir.join(format!("epe_{name}.png")))
        .map_err(err)
}
