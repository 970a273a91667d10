//! How well NSFF's motion masks (epipolar error of the built-in optical flow) cover the moving
//! objects of generated videos, against the generator's exact object ids:
//! `cargo run --release -p nsff --example mask_recall -- DIR [DIR ...]`.
//!
//! Recall: share of true mover pixels inside the mask; precision: share of mask pixels on a
//! mover; both pooled over all frames, for the raw mask and dilated by 2 and 4 pixels. "still in
//! mask": static pixels inside the raw mask, as a share of all pixels (the static batch never
//! trains them). `MASK_THRESHOLDS=0.5,1,2` scores several mask thresholds (pixels of epipolar
//! error; default 0.35, NSFF's `mask_threshold_px`) on one flow computation, and
//! `MASK_RULES=either,both` each with the larger and the smaller of the two neighbours' errors
//! (`mask_both_neighbours`; default `either`); `MASK_UNMASK_BACKGROUND=1` keeps the background
//! pixels (alpha 0) out of the masks (`unmask_background`); `MASK_PNG_DIR=D`
//! also writes each scene's frame-0 mask over its image to `D/<scene>_<threshold>.png` (masked
//! pixels red where the generator says static, green on a mover; mover pixels the mask misses
//! blue); with `MASK_PNG_ALL=1` every
//! frame, as `D/<scene>_<threshold>_<frame>.png`.

use std::path::Path;

use nerf_data::LoadOptions;

fn dilate(mask: &[bool], w: usize, h: usize, r: i64) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            if !mask[(y * w as i64 + x) as usize] {
                continue;
            }
            for dy in -r..=r {
                for dx in -r..=r {
                    let (xx, yy) = (x + dx, y + dy);
                    if (0..w as i64).contains(&xx) && (0..h as i64).contains(&yy) {
                        out[(yy * w as i64 + xx) as usize] = true;
                    }
                }
            }
        }
    }
    out
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Without MASK_THRESHOLDS, the threshold `nsff train` uses.
    let train = nsff::config::NsffConfig::new(nerf::config::Preset::Fast, "".into(), LoadOptions::default());
    let default = train.mask_threshold_px.to_string();
    let unmask_background = train.unmask_background || std::env::var_os("MASK_UNMASK_BACKGROUND").is_some();
    let thresholds: Vec<f32> = std::env::var("MASK_THRESHOLDS")
        .unwrap_or(default)
        .split(',')
        .map(|t| t.trim().parse())
        .collect::<Result<_, _>>()?;
    let rules = std::env::var("MASK_RULES").unwrap_or_else(|_| "either".into());
    let rules: Vec<bool> = rules
        .split(',')
        .map(|r| match r.trim() {
            "either" => Ok(false),
            "both" => Ok(true),
            other => Err(format!("MASK_RULES: `{other}` is neither `either` nor `both`")),
        })
        .collect::<Result<_, _>>()?;
    let png = match std::env::var_os("MASK_PNG_DIR") {
        Some(d) => {
            let dir = std::path::PathBuf::from(d);
            std::fs::create_dir_all(&dir)?;
            Some(Pngs {
                dir,
                all_frames: std::env::var_os("MASK_PNG_ALL").is_some(),
            })
        }
        None => None,
    };
    println!(
        "scene | mask threshold | motion found (moving share) | true mover share | mask share | still in mask | recall r0 / r2 / r4 | precision r0 / r2 / r4"
    );
    for dir in std::env::args().skip(1) {
        let dir = Path::new(&dir);
        let cache = std::env::temp_dir().join(format!("mask-recall-{}", std::process::id()));
        for &threshold_px in &thresholds {
            for &both_neighbours in &rules {
                let rule = nerf_flow::MaskRule {
                    threshold_px,
                    both_neighbours,
                };
                score(dir, &cache, rule, unmask_background, png.as_ref())?;
            }
        }
        let _ = std::fs::remove_dir_all(&cache);
    }
    Ok(())
}

/// Where mask overlays go (`MASK_PNG_DIR`), and whether every frame's or frame 0's only.
struct Pngs {
    dir: std::path::PathBuf,
    all_frames: bool,
}

/// One line of the table: the masks by `rule`, the flow cached in `cache`.
fn score(
    dir: &Path,
    cache: &Path,
    rule: nerf_flow::MaskRule,
    unmask_background: bool,
    png: Option<&Pngs>,
) -> Result<(), Box<dyn std::error::Error>> {
    let scene = nerf_synth::Scene::load(dir)?;
    let ds = nerf_data::load::load_video(dir, &LoadOptions::default())?;
    let video = nsff::video::prepare(ds, cache, 1.0, rule, unmask_background, true)?;
    let threshold = format!(
        "{}{}",
        rule.threshold_px,
        if rule.both_neighbours { " both" } else { "" }
    );
    let movers = scene.moving_objects();
    let (mut truth, mut total) = (0usize, 0usize);
    let mut hit = [0usize; 3];
    let mut masked = [0usize; 3];
    let mut objects = vec![ObjectTally::default(); scene.objects.len()];
    for (k, &v) in video.frames.iter().enumerate() {
        let view = &video.dataset.views[v];
        let (w, h) = (view.image.width as usize, view.image.height as usize);
        let time = view.time.unwrap_or(0.0) as f64;
        let traced = scene.render(&view.camera, time);
        // The generator's exact flow to the next frame (every hit in front of its camera).
        let exact = video.frames.get(k + 1).map(|&n| {
            let next = &video.dataset.views[n];
            scene
                .optical_flow(&view.camera, time, &next.camera, next.time.unwrap_or(0.0) as f64)
                .0
        });
        for (p, &id) in traced.object_id.iter().enumerate() {
            let Some(tally) = usize::try_from(id).ok().and_then(|i| objects.get_mut(i)) else {
                continue;
            };
            tally.pixels += 1;
            tally.masked += usize::from(video.motion_masks[k][p]);
            if let (Some(exact), Some(flow)) = (&exact, video.flow_fwd[k].as_ref()) {
                tally.epe += f64::from(flow.flow[2 * p] - exact[2 * p])
                    .hypot(f64::from(flow.flow[2 * p + 1] - exact[2 * p + 1]));
                tally.flow_pixels += 1;
            }
        }
        let ids = traced.object_id;
        let gt: Vec<bool> = ids
            .iter()
            .map(|&i| i >= 0 && movers.contains(&(i as usize)))
            .collect();
        if let Some(png) = png.filter(|p| k == 0 || p.all_frames) {
            let name = dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let mut img = image::RgbImage::new(w as u32, h as u32);
            for (p, px) in img.pixels_mut().enumerate() {
                let c = view.image.pixel(p);
                let grey = (255.0 * (c[0] + c[1] + c[2]) / 3.0).clamp(0.0, 255.0) as u8;
                *px = match (video.motion_masks[k][p], gt[p]) {
                    (true, true) => image::Rgb([0, 200, 0]),
                    (true, false) => image::Rgb([230, 0, 0]),
                    (false, true) => image::Rgb([0, 90, 255]),
                    _ => image::Rgb([grey, grey, grey]),
                };
            }
            let frame = if png.all_frames {
                format!("_{k:03}")
            } else {
                String::new()
            };
            img.save(
                png.dir
                    .join(format!("{name}_{}{frame}.png", threshold.replace(' ', "_"))),
            )?;
        }
        truth += gt.iter().filter(|&&g| g).count();
        total += gt.len();
        for (j, r) in [0, 2, 4].into_iter().enumerate() {
            let m = dilate(&video.motion_masks[k], w, h, r);
            masked[j] += m.iter().filter(|&&x| x).count();
            hit[j] += m.iter().zip(&gt).filter(|(a, b)| **a && **b).count();
        }
    }
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    println!(
        "{} | {threshold} | {} ({:.2} %) | {:.1} % | {:.1} % | {:.1} % | {:.0} / {:.0} / {:.0} % | {:.0} / {:.0} / {:.0} %",
        dir.display(),
        video.has_motion,
        100.0 * video.moving_fraction.unwrap_or(f32::NAN),
        pct(truth, total),
        pct(masked[0], total),
        pct(masked[0] - hit[0], total),
        pct(hit[0], truth),
        pct(hit[1], truth),
        pct(hit[2], truth),
        pct(hit[0], masked[0]),
        pct(hit[1], masked[1]),
        pct(hit[2], masked[2]),
    );
    for (object, t) in scene.objects.iter().zip(&objects) {
        println!(
            "    {:<12} {:<6} | {:.1} % of the pixels | {:.1} % in mask | flow EPE {:.2} px",
            object.name,
            if object.is_moving() { "mover" } else { "static" },
            pct(t.pixels, total),
            pct(t.masked, t.pixels),
            t.epe / t.flow_pixels.max(1) as f64,
        );
    }
    Ok(())
}

/// One object's pixels over all frames: how many, how many inside the mask, and the sum of the
/// one-step flow's end-point error over those with a next frame to project into.
#[derive(Clone, Default)]
struct ObjectTally {
    pixels: usize,
    masked: usize,
    epe: f64,
    flow_pixels: usize,
}
