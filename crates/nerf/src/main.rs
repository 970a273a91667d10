//! `nerf`: train, evaluate and render static neural radiance fields.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use nerf::checkpoint::has_checkpoint;
use nerf::cli::{CommonTrainArgs, MeshArgs, PointsArgs, ViewArgs};
use nerf::config::TrainConfig;
use nerf::error::{ModelError, Result};
use nerf::export::{
    PointCloud, StaticVolume, culling_cameras, require_bounded, run_mesh_export, run_points_export,
    strided_pixels,
};
use nerf::model::StaticModel;
use nerf::render::{FrameWriter, PathKind, default_path, path_cameras};
use nerf::trainer::{CHECKPOINT, Trainer, load_dataset};
use nerf_data::error::DataError;
use nerf_data::{LoadOptions, NdcMode};

#[derive(Parser)]
#[command(
    name = "nerf",
    version,
    about = "Neural radiance fields for static scenes, on the CPU by default"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train a radiance field on a folder of posed images (Blender, LLFF, COLMAP) or a tiny-NeRF .npz.
    Train(TrainArgs),
    /// Score a trained run on its held-out views: PSNR and SSIM per view, written to RUN_DIR/eval.json.
    Eval {
        /// Run folder written by `nerf train`.
        run_dir: PathBuf,
        /// Which split to score.
        #[arg(long, default_value = "test", value_parser = ["test", "val", "train"])]
        split: String,
        /// Also write each view (ground truth | render) to RUN_DIR/eval/<view>.png.
        #[arg(long)]
        save_images: bool,
    },
    /// Render a trained run along a camera path or at the cameras of a Blender-format transforms file.
    Render(RenderArgs),
    /// Look around a trained run in the browser: a local web viewer (drag orbits, wheel zooms).
    View(ViewArgs),
    /// Take geometry out of a trained run as binary PLY (MeshLab, Blender, Open3D).
    #[command(subcommand)]
    Export(ExportWhat),
    /// Write LLFF's poses_bounds.npy from a COLMAP sparse model (the "make your own dataset" step).
    Colmap2poses {
        /// A capture folder with sparse/0 (or sparse/), or the model folder itself.
        dir: PathBuf,
        /// Output file (default: DIR/poses_bounds.npy).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Generate a synthetic scene with ground-truth depth and optical flow (Blender / D-NeRF format).
    Synth {
        /// Output folder.
        out: PathBuf,
        /// static, dynamic, static_video, family (a seed draws one of a family of videos),
        /// jumping (the dynamic scene seen D-NeRF-style, from a random viewpoint every frame) or
        /// jumping_movers (D-NeRF's kind of scene: movers alone, a random viewpoint every frame).
        #[arg(long, default_value = "static")]
        preset: nerf_synth::Preset,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Image width and height (default: the preset's).
        #[arg(long, num_args = 2, value_names = ["W", "H"])]
        size: Option<Vec<u32>>,
        /// Training views (static) or video frames (dynamic presets).
        #[arg(long)]
        frames: Option<usize>,
        /// Held-out test views.
        #[arg(long)]
        test_views: Option<usize>,
        /// Video presets: also write disp/ with a simulated monocular disparity per training
        /// frame, NSFF's depth prior: `clean` (the default when given without a value) is the
        /// true inverse depth, smoothed, noisy, under an unknown scale and shift; `rough` adds
        /// errors no scale and shift remove (blurred edges, depths spaced wrong, a smooth field
        /// across the image), as a real monocular network makes.
        #[arg(long, num_args = 0..=1, default_missing_value = "clean", value_name = "clean|rough")]
        mono_disparity: Option<nerf_synth::DisparityErrors>,
        /// Presets with a time (videos, jumping cameras): also write motion_masks/ with the moving
        /// objects' pixels per training frame (grown by 2 px), as NSFF's segmentation masks; `nsff
        /// train` then uses them on a video in place of the masks it computes from the optical flow.
        #[arg(long)]
        motion_masks: bool,
    },
}

#[derive(Subcommand)]
enum ExportWhat {
    /// A triangle mesh of the density field's level set in the scene box, coloured by the field.
    Mesh(MeshArgs),
    /// A coloured point cloud of the surfaces the training views see (rendered depth).
    Points(PointsArgs),
}

#[derive(clap::Args)]
struct TrainArgs {
    #[command(flatten)]
    common: CommonTrainArgs,
    /// Hold out every N-th view for testing (default: the format's convention).
    #[arg(long)]
    holdout: Option<usize>,
    /// Composite RGBA images over black instead of white (Blender).
    #[arg(long)]
    black_background: bool,
    /// LLFF/COLMAP captures: warp rays to NDC: `auto` does when every camera looks within 30° of
    /// the average direction (a forward-facing capture), `on` always, `off` never.
    #[arg(long, default_value = "auto", value_name = "auto|on|off")]
    ndc: NdcMode,
    /// Same as `--ndc off`.
    #[arg(long)]
    no_ndc: bool,
    /// Fast preset: march every step through the box instead of skipping empty space.
    #[arg(long)]
    no_occupancy: bool,
    /// Fast preset: keep sampling rays after they become opaque (when rendering; training
    /// never terminates early unless --set fast.train_early_termination=true).
    #[arg(long)]
    no_early_termination: bool,
    /// Checkpoint every N steps (default: 500 fast, 50 vanilla).
    #[arg(long)]
    checkpoint_every: Option<usize>,
    /// Override the learning rate.
    #[arg(long)]
    lr: Option<f64>,
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Run folder written by `nerf train`.
    run_dir: PathBuf,
    /// Render exactly the cameras of this Blender-format transforms file, one PNG per frame in file order.
    #[arg(long)]
    cameras: Option<PathBuf>,
    /// Camera path (default: orbit for objects, spiral for forward-facing captures in NDC, the
    /// capture's own trajectory for the others).
    #[arg(long, value_enum)]
    path: Option<PathKind>,
    /// Frames on the path.
    #[arg(long, default_value_t = 40)]
    frames: usize,
    /// Output folder (default: RUN_DIR/render).
    #[arg(long)]
    out: Option<PathBuf>,
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Train(args) => train(args),
        Command::Eval {
            run_dir,
            split,
            save_images,
        } => eval(&run_dir, &split, save_images).map(|()| nerf_core::profile::eprint_report()),
        Command::Render(args) => render(args).map(|()| nerf_core::profile::eprint_report()),
        Command::View(args) => {
            let t = open_run(&args.run_dir)?;
            let title = format!("{} (step {})", args.run_dir.display(), t.step);
            let scene = nerf::viewer::ViewerScene::of(&t.dataset, &title);
            let model = nerf::viewer::StaticView {
                model: &t.model,
                dataset: &t.dataset,
                device: &t.device,
            };
            nerf::viewer::run(&model, &scene, &args.host, args.port)
        }
        Command::Export(ExportWhat::Mesh(args)) => {
            let t = open_run(&args.run_dir)?;
            require_bounded(&t.dataset, &args.run_dir)?;
            let volume = StaticVolume {
                model: &t.model,
                device: &t.device,
            };
            let views = culling_cameras(&t.dataset, 32, 128);
            let render_depth = |cam: &nerf_data::Camera| {
                let rays = t.dataset.rays_for(cam, 0..cam.intrinsics.num_pixels() as u32);
                let r = t.model.render_rays(&rays, t.dataset.background, &t.device)?;
                Ok((r.depth, r.opacity))
            };
            run_mesh_export(&volume, &args, &t.cfg.data, 0.0, &views, &render_depth)?;
            Ok(())
        }
        Command::Export(ExportWhat::Points(args)) => {
            let t = open_run(&args.run_dir)?;
            require_bounded(&t.dataset, &args.run_dir)?;
            let mut cloud = PointCloud::default();
            let bar = nerf::export::progress(true, t.dataset.train.len() as u64, "views");
            for &v in &t.dataset.train {
                let cam = &t.dataset.views[v].camera;
                let rays = t.dataset.rays_for(cam, strided_pixels(cam, args.stride));
                let r = t.model.render_rays(&rays, t.dataset.background, &t.device)?;
                cloud.add_rendered(&rays, &r.rgb, &r.depth, &r.opacity, args.min_opacity);
                bar.inc(1);
            }
            bar.finish_and_clear();
            run_points_export(&cloud, &args, t.model.bounds.aabb, &t.cfg.data, 0.0)?;
            Ok(())
        }
        Command::Colmap2poses { dir, out } => {
            let model_dir = nerf_data::colmap::find_model_dir(&dir).ok_or_else(|| {
                DataError::invalid(
                    &dir,
                    "no COLMAP model found (looked for cameras.bin|txt in the folder, sparse/0/ and sparse/)",
                )
            })?;
            let model = nerf_data::colmap::read_model(&model_dir)?;
            let pb = nerf_data::colmap::poses_bounds(&model, &model_dir)?;
            let out = out.unwrap_or_else(|| dir.join("poses_bounds.npy"));
            pb.write(&out)?;
            println!(
                "wrote {} ({} images) from {}",
                out.display(),
                pb.rows.len(),
                model_dir.display()
            );
            Ok(())
        }
        Command::Synth {
            out,
            preset,
            seed,
            size,
            frames,
            test_views,
            mono_disparity,
            motion_masks,
        } => {
            let mut cfg = nerf_synth::SynthConfig::seeded(preset, seed);
            cfg.mono_disparity = mono_disparity;
            cfg.motion_masks = motion_masks;
            if let Some(s) = size {
                cfg = cfg.with_size(s[0], s[1]);
            }
            if frames.is_some() || test_views.is_some() {
                let (f, t) = (frames.unwrap_or(cfg.frames), test_views.unwrap_or(cfg.test_views));
                cfg = cfg.with_views(f, t);
            }
            cfg.validate().map_err(|m| DataError::invalid(&out, m))?;
            if motion_masks && !preset.has_time() {
                eprintln!(
                    "note: --motion-masks: the {preset} preset has no time and no movers, so no motion masks are written"
                );
            }
            let summary = nerf_synth::generate(&cfg, &out)?;
            println!(
                "wrote {} scene to {}: {} train, {} test views, {} files",
                preset,
                out.display(),
                summary.train_views,
                summary.test_views,
                summary.files_written
            );
            if let Some(v) = &summary.variation {
                println!("member: {}", v.describe());
            }
            Ok(())
        }
    }
}

fn train(args: TrainArgs) -> Result<()> {
    let common = &args.common;
    let run_dir = common.run_dir("");
    let mut trainer = if common.resume {
        if !has_checkpoint(&run_dir) {
            return Err(ModelError::usage(
                &run_dir,
                "--resume: no checkpoint.bin in the run folder",
            ));
        }
        let t = Trainer::resume(&run_dir, |cfg| common.update_resumed(cfg, |c| c))?;
        eprintln!(
            "resuming {} at step {} ({:.0} s trained)",
            run_dir.display(),
            t.step,
            t.elapsed
        );
        t
    } else {
        let load = LoadOptions {
            downscale: common.downscale.max(1),
            background: args.black_background.then_some([0.0; 3]),
            holdout: args.holdout,
            ndc: if args.no_ndc { NdcMode::Off } else { args.ndc },
            spherify: false,
        };
        let mut cfg = TrainConfig::new(common.preset, common.data.clone(), load);
        common.apply_fresh(&mut cfg);
        cfg.fast.use_occupancy = !args.no_occupancy;
        cfg.fast.early_termination = !args.no_early_termination;
        cfg.fast.train_early_termination &= !args.no_early_termination;
        if let Some(c) = args.checkpoint_every {
            cfg.checkpoint_every = c;
        }
        if let Some(lr) = args.lr {
            cfg.lr_final *= lr / cfg.lr;
            cfg.lr = lr;
        }
        let dataset = load_dataset(&cfg)?;
        cfg.adapt_to(&dataset);
        let cfg = nerf::config::apply_overrides(&cfg, &common.overrides)
            .and_then(|c| c.validate().map(|()| c))
            .map_err(|m| ModelError::usage(&common.data, m))?;
        Trainer::new(cfg, dataset, &run_dir)?
    };
    trainer.train(true)?;
    eprintln!(
        "trained {} steps in {:.1} s; checkpoint {}",
        trainer.step,
        trainer.elapsed,
        run_dir.join(CHECKPOINT).display()
    );
    if !common.no_render {
        let run = Run {
            cfg: trainer.cfg,
            step: trainer.step,
            elapsed: trainer.elapsed,
            model: trainer.model,
            dataset: trainer.dataset,
            run_dir: trainer.run_dir,
            device: trainer.device,
        };
        let result = write_eval(&run, "test", false)?;
        println!("mean_psnr {:.4}", result.mean_psnr);
        let kind = default_path(&run.dataset);
        let out = run_dir.join("render");
        render_path(&run, kind, 40, &out)?;
        eprintln!(
            "rendered {} and psnr.png into {}",
            out.join("path.gif").display(),
            run_dir.display()
        );
    }
    Ok(())
}

/// A trained model and the dataset it is scored and rendered on (no optimiser state).
struct Run {
    cfg: TrainConfig,
    step: usize,
    elapsed: f64,
    model: StaticModel,
    dataset: nerf_data::Dataset,
    run_dir: PathBuf,
    device: burn::tensor::Device,
}

/// Loads a run's model from its checkpoint and its dataset for cameras and images.
fn open_run(run_dir: &Path) -> Result<Run> {
    let t = nerf::checkpoint::load_trained(run_dir)?;
    let dataset = load_dataset(&t.state.config)?;
    Ok(Run {
        cfg: t.state.config,
        step: t.state.step,
        elapsed: t.state.elapsed,
        model: t.model,
        dataset,
        run_dir: run_dir.to_path_buf(),
        device: t.device,
    })
}

fn split_views(t: &Run, split: &str) -> Vec<usize> {
    match split {
        "train" => t.dataset.train.clone(),
        "val" if !t.dataset.val.is_empty() => t.dataset.val.clone(),
        _ => t.dataset.test.clone(),
    }
}

fn write_eval(t: &Run, split: &str, save_images: bool) -> Result<nerf::eval::EvalResult> {
    let views = split_views(t, split);
    if views.is_empty() {
        return Err(ModelError::usage(
            &t.cfg.data,
            format!("the dataset has no {split} views"),
        ));
    }
    let dir = t.run_dir.join("eval");
    if save_images {
        std::fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
    }
    let save = save_images.then_some(dir.as_path());
    let scene = nerf::diagnosis::load_scene(&t.cfg.data)?;
    let mut result = nerf::eval::evaluate(
        &t.model,
        &t.dataset,
        &views,
        true,
        save,
        scene.as_ref(),
        &t.device,
    )?;
    result.split = split.into();
    result.step = t.step;
    result.train_seconds = t.elapsed;
    let path = t.run_dir.join("eval.json");
    let json = serde_json::to_vec_pretty(&result).map_err(|e| DataError::invalid(&path, e.to_string()))?;
    nerf_data::image::write_atomic(&path, &json)?;
    for v in &result.views {
        println!(
            "{:>4} {:<24} psnr {:7.3}  ssim {:.4}",
            v.view,
            v.name,
            v.psnr,
            v.ssim.unwrap_or(f64::NAN)
        );
    }
    println!(
        "{} views, {:.1} samples/ray, rendered in {:.1} s; mean_ssim {:.4}",
        result.views.len(),
        result.samples_per_ray,
        result.render_seconds,
        result.mean_ssim.unwrap_or(f64::NAN)
    );
    if let Some(groups) = &result.groups {
        print!("{}", nerf::diagnosis::table(groups));
    }
    Ok(result)
}

fn eval(run_dir: &Path, split: &str, save_images: bool) -> Result<()> {
    let t = open_run(run_dir)?;
    let result = write_eval(&t, split, save_images)?;
    println!("mean_psnr {:.4}", result.mean_psnr);
    Ok(())
}

fn render_cameras(t: &Run, cameras: &[nerf_data::Camera], out: &Path, gif: &str) -> Result<()> {
    let mut writer = FrameWriter::new(out, None)?;
    let bar = indicatif::ProgressBar::new(cameras.len() as u64);
    for (k, cam) in cameras.iter().enumerate() {
        let rays = t.dataset.rays_for(cam, 0..cam.intrinsics.num_pixels() as u32);
        let r = t.model.render_rays(&rays, t.dataset.background, &t.device)?;
        writer.push(
            k,
            cam.intrinsics.width,
            cam.intrinsics.height,
            r.rgb,
            &r.depth,
            &r.opacity,
        )?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    eprintln!("{}", writer.finish(gif)?);
    Ok(())
}

fn render_path(t: &Run, kind: PathKind, frames: usize, out: &Path) -> Result<()> {
    render_cameras(t, &path_cameras(&t.dataset, kind, frames), out, "path.gif")
}

fn render(args: RenderArgs) -> Result<()> {
    let t = open_run(&args.run_dir)?;
    let out = args.out.unwrap_or_else(|| args.run_dir.join("render"));
    match args.cameras {
        Some(json) => {
            let first = &t.dataset.views[t.dataset.train.first().copied().unwrap_or(0)]
                .camera
                .intrinsics;
            let cams = nerf_data::blender::read_cameras(&json, (first.width, first.height))?;
            let cameras: Vec<_> = cams.iter().map(|c| c.camera).collect();
            render_cameras(&t, &cameras, &out, "cameras.gif")?;
            let names: Vec<&str> = cams.iter().map(|c| c.file_path.as_str()).collect();
            let path = out.join("frames.json");
            let json_out =
                serde_json::to_vec_pretty(&names).map_err(|e| DataError::invalid(&path, e.to_string()))?;
            nerf_data::image::write_atomic(&path, &json_out)?;
            println!(
                "rendered {} cameras from {} into {}",
                cameras.len(),
                json.display(),
                out.display()
            );
        }
        None => {
            let kind = args.path.unwrap_or_else(|| default_path(&t.dataset));
            render_path(&t, kind, args.frames, &out)?;
            println!(
                "rendered {} frames ({:?} path) into {}",
                args.frames,
                kind,
                out.display()
            );
        }
    }
    Ok(())
}
