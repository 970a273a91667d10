//! `nsff`: Neural Scene Flow Fields from one moving camera's video with known poses.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use nerf::checkpoint::has_checkpoint;
use nerf::cli::{CommonTrainArgs, MeshArgs, PointsArgs, ViewArgs};
use nerf::config::apply_overrides;
use nerf::error::{ModelError, Result};
use nerf::export::{
    PointCloud, culling_cameras, require_bounded, run_mesh_export, run_points_export, strided_pixels,
};
use nerf::render::FrameWriter;
use nerf_data::error::DataError;
use nerf_data::{Camera, Dataset, Image, LoadOptions};
use nsff::config::{DynamicMode, GateBetween, NsffConfig, TimeInterp, check_render_step_scale};
use nsff::eval::{evaluate_with_depth, render_at};
use nsff::export::SpaceTimeVolume;
use nsff::model::NsffModel;
use nsff::render::FlowMap;
use nsff::trainer::{CHECKPOINT, NsffTrainer, load_video};

#[derive(Parser)]
#[command(
    name = "nsff",
    version,
    about = "Neural Scene Flow Fields: dynamic scenes from one moving camera"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train on a video: D-NeRF-style transforms_*.json with per-frame time, or NSFF-style images/ + poses_bounds.npy.
    Train(TrainArgs),
    /// Score a run on its held-out (camera, time) views; last line "mean_psnr X".
    Eval {
        run_dir: PathBuf,
        /// Also write ground truth | render pairs to RUN_DIR/eval/.
        #[arg(long)]
        save_images: bool,
        #[command(flatten)]
        render: RenderFlags,
        /// Render with the static field alone (its full density, the dynamic field and the blend
        /// skipped everywhere) and write eval_static.json: tells whether an error comes from the
        /// static or the dynamic field.
        #[arg(long)]
        static_only: bool,
    },
    /// Render a run: the cameras of a D-NeRF transforms file, or a path (bullet time, time-lapse, space-time).
    Render(RenderArgs),
    /// Look around a trained run in the browser: a local web viewer (drag orbits, wheel zooms).
    View(ViewArgs),
    /// Take geometry out of a trained run as binary PLY (MeshLab, Blender, Open3D).
    #[command(subcommand)]
    Export(ExportWhat),
}

#[derive(Subcommand)]
enum ExportWhat {
    /// A triangle mesh of the scene at one time (the combined density's level set), coloured by the fields.
    Mesh {
        #[command(flatten)]
        mesh: MeshArgs,
        /// Normalised time in [0, 1].
        #[arg(long, default_value_t = 0.0)]
        time: f32,
    },
    /// A coloured point cloud of the surfaces each training frame sees at its own time.
    Points(PointsArgs),
}

#[derive(clap::Args)]
struct TrainArgs {
    #[command(flatten)]
    common: CommonTrainArgs,
    /// Model independent motion: auto (from the optical flow; on for a jumping camera, whose
    /// neighbouring frames carry no usable flow), on or off.
    #[arg(long, value_enum, default_value = "auto")]
    dynamic: DynamicMode,
    /// Renders between frames: direct (query the field at that time) or splat (NSFF's
    /// splatting of both neighbouring frames along the scene flow).
    #[arg(long, value_enum, default_value = "direct")]
    time_interp: TimeInterp,
}

/// Camera paths for dynamic scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum PathKind {
    /// Fixed time (--frame), the camera orbits: novel views at a training time.
    Bullet,
    /// Fixed camera (--frame's), time runs over the whole video, interpolated between frames.
    Timelapse,
    /// The camera moves along the training trajectory while time runs (space-time interpolation).
    Spacetime,
}

/// How a trained run renders; a flag left out keeps the run's own setting.
#[derive(clap::Args, Default)]
struct RenderFlags {
    /// Renders between frames: splat or direct.
    #[arg(long, value_enum)]
    time_interp: Option<TimeInterp>,
    /// March step of the renders as a fraction of the training step (`render_step_scale`;
    /// smaller is finer and slower).
    #[arg(long)]
    render_step_scale: Option<f32>,
    /// How the direct renders between frames read the time gate: held (raised towards the
    /// largest gate of the nearby frames, see --gate-reach) or field (the field's own gate at
    /// that time).
    #[arg(long, value_enum)]
    gate_between: Option<GateBetween>,
    /// Frames on each side of the render time whose gates the held gate reaches (1: frames i
    /// and i+1; 3, the default: i−2 … i+3). Each frame read costs one density query of the
    /// dynamic field per sample between frames.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=8))]
    gate_reach: Option<u32>,
}

#[derive(clap::Args)]
struct RenderArgs {
    run_dir: PathBuf,
    /// Render exactly these (camera, time) pairs from a D-NeRF-format transforms file, one PNG per frame in file order.
    #[arg(long)]
    cameras: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "spacetime")]
    path: PathKind,
    /// Reference frame for bullet and time-lapse paths.
    #[arg(long, default_value_t = 0)]
    frame: usize,
    #[arg(long, default_value_t = 48)]
    frames: usize,
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    render: RenderFlags,
    /// Render with the static field alone (as `eval --static-only`): what the static field
    /// has learnt, e.g. at the training cameras.
    #[arg(long)]
    static_only: bool,
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
            save_images,
            render,
            static_only,
        } => {
            let mut t = open_run(&run_dir, &render)?;
            if static_only {
                t.model.settings.static_only = true;
            }
            let name = if static_only { "eval_static" } else { "eval" };
            let r = write_eval(&t, save_images, name)?;
            println!("mean_psnr {:.4}", r.mean_psnr);
            nerf_core::profile::eprint_report();
            Ok(())
        }
        Command::Render(args) => render(args).map(|()| nerf_core::profile::eprint_report()),
        Command::View(args) => {
            let t = open_run(&args.run_dir, &RenderFlags::default())?;
            let title = format!("{} (step {})", args.run_dir.display(), t.step);
            let scene = nerf::viewer::ViewerScene::of(&t.dataset, &title);
            let model = nsff::view::SpaceTimeView {
                model: &t.model,
                dataset: &t.dataset,
                device: &t.device,
            };
            nerf::viewer::run(&model, &scene, &args.host, args.port)
        }
        Command::Export(ExportWhat::Mesh { mesh, time }) => {
            let t = open_run(&mesh.run_dir, &RenderFlags::default())?;
            require_bounded(&t.dataset, &mesh.run_dir)?;
            let volume = SpaceTimeVolume {
                model: &t.model,
                time,
                device: &t.device,
            };
            let views = culling_cameras(&t.dataset, 32, 128);
            let render_depth = |cam: &nerf_data::Camera| {
                let r = render_at(&t.model, &t.dataset, cam, time, FlowMap::Skip, &t.device)?;
                Ok((r.depth, r.opacity))
            };
            run_mesh_export(
                &volume,
                &mesh,
                &t.cfg.base.data,
                time as f64,
                &views,
                &render_depth,
            )?;
            Ok(())
        }
        Command::Export(ExportWhat::Points(args)) => {
            let t = open_run(&args.run_dir, &RenderFlags::default())?;
            require_bounded(&t.dataset, &args.run_dir)?;
            let mut cloud = PointCloud::default();
            let bar = nerf::export::progress(true, t.frames.len() as u64, "frames");
            for (k, &v) in t.frames.iter().enumerate() {
                // Each frame at its own time: only the strided pixels are rendered.
                let cam = &t.dataset.views[v].camera;
                let rays = t.dataset.rays_for(cam, strided_pixels(cam, args.stride));
                let r = nsff::eval::render_rays_direct(
                    &t.model,
                    &rays,
                    t.model.times[k],
                    t.dataset.background,
                    FlowMap::Skip,
                    &t.device,
                )?;
                cloud.add_rendered(&rays, &r.rgb, &r.depth, &r.opacity, args.min_opacity);
                bar.inc(1);
            }
            bar.finish_and_clear();
            // Scored against the scene at time 0: only static surfaces are where they were then.
            run_points_export(&cloud, &args, t.model.bounds.aabb, &t.cfg.base.data, 0.0)?;
            Ok(())
        }
    }
}

/// `cfg` with the `--set` overrides applied and validated; an error names the data folder.
fn with_overrides(cfg: &NsffConfig, common: &CommonTrainArgs) -> Result<NsffConfig> {
    apply_overrides(cfg, &common.overrides)
        .and_then(|c| c.validate().map(|()| c))
        .map_err(|m| ModelError::usage(&common.data, m))
}

fn train(args: TrainArgs) -> Result<()> {
    let common = &args.common;
    let run_dir = common.run_dir("nsff-");
    let mut t = if common.resume {
        if !has_checkpoint(&run_dir) {
            return Err(ModelError::usage(
                &run_dir,
                "--resume: no checkpoint.bin in the run folder",
            ));
        }
        let update = |cfg: &mut NsffConfig| common.update_resumed(cfg, |c| &mut c.base);
        let t = NsffTrainer::resume(&run_dir, update, false)?;
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
            ..LoadOptions::default()
        };
        let mut cfg = NsffConfig::new(common.preset, common.data.clone(), load);
        common.apply_fresh(&mut cfg.base);
        cfg.dynamic = args.dynamic;
        cfg.time_interp = args.time_interp;
        // A mistyped or invalid `--set` fails here, before the load and the optical flow
        // (seconds to minutes); the preparation (motion test, masks) takes its thresholds from
        // the overridden settings, and the overrides are applied for good after `adapt_to` below.
        let overridden = with_overrides(&cfg, common)?;
        let start = std::time::Instant::now();
        let video = load_video(&overridden, &run_dir, false)?;
        eprintln!(
            "loaded and prepared {} frames in {:.1} s",
            video.frames.len(),
            start.elapsed().as_secs_f64()
        );
        cfg.adapt_to(&video.dataset, video.frames.len());
        if video.camera_path.is_jumping() && cfg.adapt_to_jumping_camera() {
            eprintln!(
                "note: a jumping camera trains no scene flow; rendering between frames uses --time-interp direct"
            );
        }
        if video.masks_given {
            cfg.adapt_to_given_masks();
        }
        if video.masks_ignored {
            eprintln!(
                "note: the motion masks in {} are not used: a jumping camera trains without motion masks",
                video.dataset.source.join("motion_masks").display()
            );
        }
        let cfg = with_overrides(&cfg, common)?;
        NsffTrainer::new(cfg, video, &run_dir)?
    };
    t.train(true)?;
    eprintln!(
        "trained {} steps in {:.1} s; checkpoint {}",
        t.step,
        t.elapsed,
        run_dir.join(CHECKPOINT).display()
    );
    if !common.no_render {
        let t = Run {
            cfg: t.cfg,
            step: t.step,
            elapsed: t.elapsed,
            model: t.model,
            dataset: t.video.dataset,
            frames: t.video.frames,
            run_dir: t.run_dir,
            device: t.device,
        };
        let r = write_eval(&t, false, "eval")?;
        println!("mean_psnr {:.4}", r.mean_psnr);
        render_path(&t, PathKind::Spacetime, 0, 48, &run_dir.join("render"))?;
        eprintln!(
            "rendered {} into {}",
            run_dir.join("render/path.gif").display(),
            run_dir.display()
        );
    }
    Ok(())
}

/// A trained model with the dataset it is scored and rendered on (no flows, no optimiser).
struct Run {
    cfg: NsffConfig,
    step: usize,
    elapsed: f64,
    model: NsffModel,
    dataset: Dataset,
    /// Training views in time order.
    frames: Vec<usize>,
    run_dir: PathBuf,
    device: burn::tensor::Device,
}

/// Loads a run's model from its checkpoint, and its dataset for cameras and images; `Some`
/// overrides the run's own render settings.
fn open_run(run_dir: &Path, flags: &RenderFlags) -> Result<Run> {
    let mut t = nsff::checkpoint::load_trained(run_dir)?;
    let settings = &mut t.model.settings;
    if let Some(ti) = flags.time_interp {
        settings.time_interp = ti;
    }
    if let Some(gb) = flags.gate_between {
        settings.gate_between = gb;
    }
    if let Some(reach) = flags.gate_reach {
        settings.gate_reach = reach as usize;
    }
    if let Some(scale) = flags.render_step_scale {
        check_render_step_scale("--render-step-scale", scale).map_err(|m| ModelError::usage(run_dir, m))?;
        settings.render_step_scale = scale;
    }
    let cfg = t.state.config;
    let dataset = nerf_data::load::load_video(&cfg.base.data, &cfg.base.load)?;
    let (frames, _) = nsff::video::check_frames(&dataset)?;
    Ok(Run {
        cfg,
        step: t.state.step,
        elapsed: t.state.elapsed,
        model: t.model,
        dataset,
        frames,
        run_dir: run_dir.to_path_buf(),
        device: t.device,
    })
}

/// Scores the held-out views into RUN_DIR/`name`.json (and images into RUN_DIR/`name`/).
fn write_eval(t: &Run, save_images: bool, name: &str) -> Result<nerf::eval::EvalResult> {
    let views = t.dataset.test.clone();
    if views.is_empty() {
        return Err(ModelError::usage(
            &t.cfg.base.data,
            "the video has no held-out views",
        ));
    }
    let dir = t.run_dir.join(name);
    if save_images {
        std::fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
    }
    let save = save_images.then_some(dir.as_path());
    let scene = nerf::diagnosis::load_scene(&t.cfg.base.data)?;
    let (mut result, depths) = evaluate_with_depth(
        &t.model,
        &t.dataset,
        &views,
        true,
        save,
        scene.as_ref(),
        &t.device,
    )?;
    result.step = t.step;
    result.train_seconds = t.elapsed;
    let path = t.run_dir.join(format!("{name}.json"));
    let json = serde_json::to_vec_pretty(&result).map_err(|e| DataError::invalid(&path, e.to_string()))?;
    nerf_data::image::write_atomic(&path, &json)?;
    for v in &result.views {
        let time = t.dataset.views[v.view].time.unwrap_or(f32::NAN);
        println!(
            "{:>4} {:<20} t {:.3}  psnr {:7.3}  ssim {:.4}",
            v.view,
            v.name,
            time,
            v.psnr,
            v.ssim.unwrap_or(f64::NAN)
        );
    }
    println!(
        "{} views, rendered in {:.1} s; mean_ssim {:.4}",
        result.views.len(),
        result.render_seconds,
        result.mean_ssim.unwrap_or(f64::NAN)
    );
    if t.dataset.format == nerf_data::Format::DNerf {
        println!("LPIPS: not computed (it needs pretrained network weights, which nsff does not download)");
    }
    if let Some(groups) = &result.groups {
        print!("{}", nerf::diagnosis::table(groups));
    }
    // Scenes from our generator carry their exact motion: score the scene flow too.
    if let Some(scene) = &scene
        && let Some(e) = nsff::eval::scene_flow_error(&t.model, &t.dataset, &t.frames, scene, 4, &t.device)?
    {
        println!(
            "scene flow on moving objects: EPE {:.4} (no-motion baseline {:.4}; predicted length {:.4}, cosine {:.2}) over {} surface points; in the next frame {:.2} px (no motion {:.2} px)",
            e.epe,
            e.zero_motion_epe,
            e.predicted_length,
            e.cosine,
            e.points,
            e.pixel_epe,
            e.pixel_zero_motion_epe
        );
        let path = t.run_dir.join("scene_flow.json");
        let json = serde_json::to_vec_pretty(&e).map_err(|err| DataError::invalid(&path, err.to_string()))?;
        nerf_data::image::write_atomic(&path, &json)?;
    }
    if let Some(e) = nsff::eval::depth_error(&t.cfg.base.data, &t.dataset, &views, &depths)? {
        println!(
            "depth on surfaces of the held-out views: mean abs error {:.4}, median relative error {:.4} over {} pixels",
            e.mean_abs, e.median_relative, e.pixels
        );
    }
    Ok(result)
}

/// Renders (camera, time) pairs: colour, depth, opacity, dynamic share and scene-flow maps, GIF.
fn render_pairs(t: &Run, pairs: &[(Camera, f32)], out: &Path, gif: &str) -> Result<()> {
    let mut writer = FrameWriter::new(out, None)?;
    for d in ["dynamic", "flow"] {
        std::fs::create_dir_all(out.join(d)).map_err(|e| DataError::io(out.join(d), e))?;
    }
    let bar = indicatif::ProgressBar::new(pairs.len() as u64);
    for (k, (cam, time)) in pairs.iter().enumerate() {
        let r = render_at(&t.model, &t.dataset, cam, *time, FlowMap::Draw, &t.device)?;
        let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
        let name = format!("{k:04}.png");
        if r.dynamic_share.len() == (w * h) as usize {
            Image::from_data(w, h, 1, r.dynamic_share.clone()).save_png(&out.join("dynamic").join(&name))?;
            let max = r.flow_magnitude.iter().cloned().fold(1e-6f32, f32::max);
            Image::from_data(w, h, 1, r.flow_magnitude.iter().map(|m| m / max).collect())
                .save_png(&out.join("flow").join(&name))?;
        }
        writer.push(k, w, h, r.rgb, &r.depth, &r.opacity)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    eprintln!("{}", writer.finish(gif)?);
    Ok(())
}

fn render_path(t: &Run, kind: PathKind, frame: usize, n: usize, out: &Path) -> Result<()> {
    let (ds, frames, times) = (&t.dataset, &t.frames, &t.model.times);
    let frame = frame.min(frames.len() - 1);
    let cam_of = |k: usize| ds.views[frames[k]].camera;
    let last = frames.len() - 1;
    let pairs: Vec<(Camera, f32)> = match kind {
        PathKind::Bullet => {
            let kind = nerf::render::default_path(ds);
            nerf::render::path_cameras(ds, kind, n)
                .into_iter()
                .map(|c| (Camera::new(cam_of(frame).intrinsics, c.pose), times[frame]))
                .collect()
        }
        PathKind::Timelapse => (0..n)
            .map(|i| (cam_of(frame), i as f32 / (n - 1).max(1) as f32))
            .collect(),
        PathKind::Spacetime => (0..n)
            .map(|i| {
                let tau = last as f32 * i as f32 / (n - 1).max(1) as f32;
                let a = (tau.floor() as usize).min(last.saturating_sub(1));
                let r = (tau - a as f32) as f64;
                let pose = cam_of(a).pose.lerp(&cam_of((a + 1).min(last)).pose, r);
                let time = times[a] + (times[(a + 1).min(last)] - times[a]) * r as f32;
                (Camera::new(cam_of(a).intrinsics, pose), time)
            })
            .collect(),
    };
    render_pairs(t, &pairs, out, "path.gif")
}

fn render(args: RenderArgs) -> Result<()> {
    let mut t = open_run(&args.run_dir, &args.render)?;
    t.model.settings.static_only = args.static_only;
    let out = args.out.unwrap_or_else(|| args.run_dir.join("render"));
    match args.cameras {
        Some(json) => {
            let first = t.dataset.views[t.frames[0]].camera.intrinsics;
            let cams = nerf_data::blender::read_cameras(&json, (first.width, first.height))?;
            let pairs: Vec<(Camera, f32)> = cams
                .iter()
                .map(|c| {
                    c.time.map(|time| (c.camera, time as f32)).ok_or_else(|| {
                        DataError::invalid(&json, format!("frame {} has no time", c.file_path))
                    })
                })
                .collect::<Result<_, DataError>>()?;
            render_pairs(&t, &pairs, &out, "cameras.gif")?;
            let names: Vec<&str> = cams.iter().map(|c| c.file_path.as_str()).collect();
            let path = out.join("frames.json");
            nerf_data::image::write_atomic(
                &path,
                &serde_json::to_vec_pretty(&names).map_err(|e| DataError::invalid(&path, e.to_string()))?,
            )?;
            println!(
                "rendered {} (camera, time) pairs from {} into {}",
                pairs.len(),
                json.display(),
                out.display()
            );
        }
        None => {
            render_path(&t, args.path, args.frame, args.frames, &out)?;
            println!(
                "rendered {} frames ({:?} path) into {}",
                args.frames,
                args.path,
                out.display()
            );
        }
    }
    Ok(())
}
