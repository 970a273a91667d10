//! NSFF configuration: the static pipeline's settings plus the dynamic field, sampling and the
//! loss weights (defaults from NSFF's released configs, method.md §4.6).

use nerf::config::{Preset, TrainConfig};
use nerf_core::encoding::HashGridConfig;
use nerf_data::{Dataset, LoadOptions};
use serde::{Deserialize, Serialize};

/// Loss weights (NSFF HEAD defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossWeights {
    /// Photometric loss on the dynamic-only and the two warped renders.
    pub dynamic_photo: f64,
    /// mean |p| of the disocclusion probabilities (the paper's β_w ‖1 − w‖₁).
    pub prob_reg: f64,
    /// Scene-flow cycle consistency.
    pub cycle: f64,
    /// Minimal scene flow (paper form: mean |f|).
    pub min_flow: f64,
    /// Spatial and temporal scene-flow smoothness.
    pub smooth: f64,
    /// Projected scene flow against 2-D optical flow; decays.
    pub optical_flow: f64,
    /// Scale- and shift-invariant single-view depth; decays. Used only with disparity priors.
    /// NSFF's 0.04; a video in the fast preset (not NDC) takes 0.01 ([`NsffConfig::adapt_to`]).
    pub depth: f64,
    /// One-sided entropy of the blend weight. NSFF's 1e-3; a video takes 0 ([`NsffConfig::new`]).
    pub entropy: f64,
    /// Sparsity of the blended dynamic density b·σ_dy (optical depth per march step) at random
    /// occupied points at the step's time: space that no training view sees at that time stays
    /// empty instead of holding whatever the dynamic field makes up there.
    #[serde(default = "default_sparsity")]
    pub sparsity: f64,
    /// Hidden dynamic optical depth per ray: b·σ_dy behind the combined render's visible
    /// surface on the step's own rays (what the frame's camera cannot see at its time).
    #[serde(default = "default_hidden")]
    pub hidden: f64,
    /// During the first `moving_dynamic_until` of the space-time phase (videos; BENCHMARKS.md
    /// §6, twenty-seventh to twenty-ninth sessions): the shortfall of the combined render's
    /// dynamic share below [`MOVING_SHARE_FLOOR`] on the rays inside the motion masks where the
    /// dynamic-only render fits the pixel better than the combined one, plus the dynamic share
    /// on the rays outside the masks, at the same weight. It keeps the blend from shutting when
    /// that phase starts: the static field has trained alone, the dynamic field is untrained
    /// fog, the photometric loss shuts the blend everywhere within tens of steps, and a shut
    /// sigmoid seldom reopens (the dynamic field then draws nothing). Opening it only where the
    /// dynamic field has earned it spares the static pixels the dilated masks hold, and the
    /// still rays' half teaches the blend the other side of the masks (without both it cost
    /// fam5 off the path). A jumping camera keeps its entropy term instead.
    #[serde(default)]
    pub moving_dynamic: f64,
    /// [`crate::losses::field_consistency`] between each sample of the space-time batch and
    /// the point its scene flow moves it to at the warped neighbour's time.
    #[serde(default)]
    pub field_consistency: f64,
}

impl LossWeights {
    /// Every weight is a finite number, 0 or more: a negative weight would reward the term's
    /// error, and a NaN would make every step's loss NaN. Read from the serialised weights, so
    /// a term added later is checked without touching this.
    pub fn validate(&self) -> Result<(), String> {
        let fields = match serde_json::to_value(self) {
            Ok(serde_json::Value::Object(fields)) => fields,
            other => return Err(format!("the loss weights did not serialise to a map: {other:?}")),
        };
        for (name, value) in fields {
            // serde_json writes a NaN or an infinity as null.
            match value.as_f64() {
                Some(w) if w.is_finite() && w >= 0.0 => {}
                _ => {
                    let shown = if value.is_null() {
                        "NaN or infinite".to_string()
                    } else {
                        value.to_string()
                    };
                    return Err(format!(
                        "weights.{name} must be a finite number, 0 or more, got {shown}"
                    ));
                }
            }
        }
        Ok(())
    }
}

/// The dynamic share `weights.moving_dynamic` asks for on rays inside the motion masks (which
/// are dilated: they hold static pixels too, so not all of it).
pub const MOVING_SHARE_FLOOR: f32 = 0.5;

fn default_render_step_scale() -> f32 {
    1.0
}

fn default_hidden() -> f64 {
    0.01
}

fn default_sparsity() -> f64 {
    0.01
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights {
            dynamic_photo: 1.0,
            prob_reg: 0.1,
            cycle: 1.0,
            min_flow: 0.1,
            smooth: 0.1,
            optical_flow: 0.02,
            depth: 0.04,
            entropy: 1e-3,
            sparsity: default_sparsity(),
            hidden: default_hidden(),
            moving_dynamic: 0.0,
            field_consistency: 0.0,
        }
    }
}

/// Whether to model independent motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum DynamicMode {
    /// On when the optical flow shows motion the camera does not explain.
    Auto,
    On,
    Off,
}

/// How the dynamic field encodes space and time (fast preset).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum SpaceTimeEncoding {
    /// One 4-D hash grid over (x, y, z, t) (`dynamic_grid`).
    #[default]
    Hash4d,
    /// A 3-D hash grid times (x, t), (y, t), (z, t) planes, K-Planes' hybrid
    /// (`nerf_core::encoding::planes`), with `dynamic_grid`'s levels, features and resolutions.
    Planes,
}

/// How renders at times between training frames are made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum TimeInterp {
    /// NSFF: render the two neighbouring frames' samples, move them along the scene flow and
    /// splat them into the target camera.
    Splat,
    /// Query the space-time field at the in-between time directly (the default: the hash
    /// grid's time cells end on frames, so this interpolates the two neighbours' features; on
    /// dyn0 it is 0.6–2.7 dB better in mean PSNR than splatting on the same checkpoints and
    /// 6× faster, BENCHMARKS.md §4).
    Direct,
}

/// How renders read the time gate at times between training frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum GateBetween {
    /// The dynamic field's own gate at that time (its time cells interpolate the two
    /// neighbouring frames').
    Field,
    /// Raised towards the largest of the nearby frames' gates at the same point (`gate_reach`
    /// frames on each side), fully half-way and not at all on a frame: what a nearby frame draws
    /// with the dynamic field stays drawn between frames (the default; BENCHMARKS.md §6,
    /// fifty-fifth and fifty-sixth sessions).
    #[default]
    Held,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NsffConfig {
    /// Shared with the static pipeline: data, preset, budgets, learning rate, static field.
    pub base: TrainConfig,
    /// Rays per step, all from one frame (as NSFF samples); with an occupancy grid the most rays,
    /// the count adapting to keep the static pipeline's `target_samples` per step.
    pub rays: usize,
    /// The fewest rays per step with an occupancy grid.
    #[serde(default = "default_min_rays")]
    pub min_rays: usize,
    /// Stratified samples per ray.
    pub samples: usize,
    /// The dynamic field's space-time hash grid (fast preset).
    pub dynamic_grid: HashGridConfig,
    /// Whether `dynamic_grid` is one 4-D grid or a space grid times space-time planes.
    #[serde(default)]
    pub dynamic_encoding: SpaceTimeEncoding,
    /// Hidden width of the dynamic field's density and colour MLPs (fast preset). Half the
    /// static field's: the moving part of a scene is small, and it keeps the dynamic field's
    /// cost per sample at about the static field's.
    #[serde(default = "default_dynamic_width")]
    pub dynamic_width: usize,
    /// Spherical-harmonics degree of the dynamic field's view directions (the static field
    /// keeps the full degree 4; 2 was chosen for cost). Degree 1 (colour independent of the
    /// view) is level with 2 on the seven tuning videos without masks: mean −0.04 dB, off the
    /// path −0.02 (BENCHMARKS.md §6, seventy-sixth session).
    #[serde(default = "default_dynamic_sh_degree")]
    pub dynamic_sh_degree: usize,
    /// Scene flow is tanh(raw) × flow_scale (scene units per frame; NDC for forward-facing).
    pub flow_scale: f32,
    pub weights: LossWeights,
    /// The optical-flow and depth weights divide by 10 every `decay_steps` steps (NSFF's
    /// schedule) or every `decay_fraction` of the run's progress, whichever comes first.
    pub decay_steps: usize,
    /// Without it a `--time-budget` run (a few thousand steps) never leaves the first phase:
    /// on dyn0 the optical-flow term at full weight holds the train PSNR near 30 dB, and the
    /// renders between frames lose 3 dB (BENCHMARKS.md §4, E8 against E9).
    #[serde(default = "default_decay_fraction")]
    pub decay_fraction: f64,
    pub dynamic: DynamicMode,
    /// Independent-motion threshold (pixels of epipolar error), for `DynamicMode::Auto`.
    pub motion_threshold_px: f32,
    /// Epipolar-error threshold of the per-frame motion masks (hard mining, static batch). Lower
    /// than the decision's: motion along an epipolar line shows only part of its flow there, and
    /// the built-in flow's error is about 0.15 px. A mover pixel the masks miss costs more than
    /// a static pixel they hold.
    #[serde(default = "default_mask_threshold_px")]
    pub mask_threshold_px: f32,
    /// Mask a pixel only when the flows to both neighbouring frames disagree with the camera
    /// (an occlusion edge breaks one of them, a mover both), instead of either. Off: it loses a
    /// third to two thirds of the movers (BENCHMARKS.md §6, seventeenth session).
    #[serde(default)]
    pub mask_both_neighbours: bool,
    /// Keep the pixels an RGBA video marks as background (alpha 0) out of the motion masks, so
    /// that the static batch learns those rays are empty: no mover is there, and the flow test
    /// fires on them along every silhouette against the background (a third of fam3's masks).
    /// Hard mining still draws from them. Off: level on the tuning set (off the path ahead by
    /// one scene), and it cost the views between frames on the report set (BENCHMARKS.md §6,
    /// twenty-second session).
    #[serde(default)]
    pub unmask_background: bool,
    /// Initial logit of the blend weight b (the dynamic share): −3 gives b ≈ 0.05.
    #[serde(default = "default_blend_init_logit")]
    pub blend_init_logit: f32,
    /// At render time, samples whose blend weight is below this skip the dynamic field.
    pub blend_skip: f32,
    pub time_interp: TimeInterp,
    /// NSFF's hard mining: for the first `decay_steps` steps (NSFF's first decay period; not
    /// shortened by `decay_fraction`), each step adds this fraction of its rays again, drawn
    /// from the frame's motion mask (NSFF: 512 on 1024).
    #[serde(default = "default_hard_fraction")]
    pub hard_fraction: f32,
    /// Each step also renders the static field alone on as many rays again, drawn from all
    /// frames outside their motion masks: the static pipeline's cheap step, so the background
    /// learns as fast as in `nerf` while the costly dynamic terms see one frame per step.
    #[serde(default = "default_static_batch")]
    pub static_batch: bool,
    /// Samples of the static batch per step, as a share of the static pipeline's
    /// `target_samples` (its ray count adapts to keep it, as `nerf train`'s does): at 1 the static
    /// batch is a `nerf train` step. Videos take 0.5, a jumping camera 1.
    #[serde(default = "default_static_batch_scale")]
    pub static_batch_scale: f32,
    /// Samples of the space-time batch (one frame, four field queries per sample) per step, as a
    /// share of the static pipeline's `target_samples`; its ray count adapts to keep it.
    /// Videos take 0.5, a jumping camera 1.
    #[serde(default = "default_space_time_share")]
    pub space_time_share: f32,
    /// Share of the budget (time or steps, as `progress`) during which steps train the static
    /// field alone on pixels outside the motion masks, at the static pipeline's cost per step,
    /// before the space-time terms start; the decaying weights' schedule starts after it. 0.3:
    /// better off the camera path on each of six tuning scenes (BENCHMARKS.md §6). Checkpoints
    /// from before it read 0 (their runs go on as they started).
    #[serde(default)]
    pub static_warm_up: f64,
    /// Share of the masked pixels (inside the motion masks) that the static batch draws all run
    /// long, each weighted by the robust weight 1 / (1 + e / τ) of its squared error e (held
    /// fixed), τ = `masked_static_scale` × the mean error of the batch's unmasked rays. A
    /// static object the masks hold (a thin plate whose flow fails) is seen the same from
    /// every frame, so the static field comes to fit it and its weight rises; a mover differs
    /// from frame to frame, stays far off and weighs little (RobustNeRF's reading of
    /// distractors). At 1 every masked pixel is as likely as an unmasked one. 0 (the default,
    /// and what checkpoints from before it read): the static batch draws outside the masks
    /// only. Opt-in: over the seven tuning videos at 600 s it gains 0.48 dB off the path and
    /// 0.10 on the mean, but on the report set it loses off the path on fam21, where the masked
    /// rays against the white sky teach the static field white fog (BENCHMARKS.md §6,
    /// thirty-eighth session).
    #[serde(default)]
    pub masked_static: f32,
    /// `masked_static` during the static warm-up only: the static field learns the still matter
    /// the masks hold (a plate whose flow fails), and the space-time phase draws outside the
    /// masks again. False (the default, and what checkpoints from before it read): all run
    /// long. Opt-in: with `masked_static` 1, on the seven tuning videos at 600 s, it gained 0.52
    /// and 0.43 dB off the path in two screens and lost 0.46 and 0.29 between frames, the mean
    /// +0.03 and +0.07 (BENCHMARKS.md §6, fifty-first and fifty-second sessions). Beside the
    /// depth prior (a rough disparity) it lost 0.12 dB on the mean and 0.13 off the path
    /// (sixty-third session).
    #[serde(default)]
    pub masked_static_warm_up_only: bool,
    /// The static batch (warm-up included) composites each RGBA pixel's target over a random
    /// colour, as `nerf train` does, instead of the dataset's background: a pixel that sees the
    /// background says its ray is empty at that time, so empty of static matter at every time,
    /// and over white the static field could leave white fog there that shows in front of
    /// surfaces from other viewpoints. False: what checkpoints from before it read. Opt-in: with
    /// given motion masks it was level on the seven tuning videos' mean and lost 0.32-0.48 dB
    /// on two of them (BENCHMARKS.md §6, seventy-eighth session).
    #[serde(default)]
    pub static_random_background: bool,
    /// `masked_static` after the static warm-up only: the warm-up's static field knows nothing
    /// of the movers, so the blend opens on them when the space-time phase starts as it does
    /// without `masked_static` (with the masked pixels from the start, the static field draws
    /// ghosts of the movers and the blend can shut for good: fam3, sixty-fifth session), and
    /// the masked pixels then clear the fog along the movers' paths. False: the default, and
    /// what checkpoints from before it read. Opt-in: with `masked_static` 1 and
    /// `static_random_background` it gained 0.50 dB off the path on the seven tuning videos but
    /// lost 0.31 dB on the mean on four fresh ones (BENCHMARKS.md §6, sixty-sixth session).
    #[serde(default)]
    pub masked_static_after_warm_up: bool,
    /// τ of `masked_static`'s weight, in units of the unmasked rays' mean squared error.
    #[serde(default = "default_masked_static_scale")]
    pub masked_static_scale: f32,
    /// Empties the occupancy-grid cells that no training frame sees (nor sees anything but
    /// background through) before training, for videos with a background (RGBA or a known
    /// colour): nothing was observed there, and whatever the fields put there shows as floaters
    /// from other viewpoints ([`nerf_core::occupancy::HullRule::NoForeground`]). On for videos
    /// with given motion masks ([`NsffConfig::adapt_to_given_masks`]); false otherwise and in
    /// checkpoints from before it.
    #[serde(default)]
    pub carve_unseen: bool,
    /// Whether the learning rate's decay, like the decaying weights', counts from the end of the
    /// static warm-up (the rate stays at `lr` during it). Without it the dynamic field starts at
    /// the rate of 30 % into the run. Checkpoints from before it read false.
    #[serde(default)]
    pub lr_decay_after_warm_up: bool,
    /// Ends the static warm-up early once the occupancy grid fills up again to this many times
    /// its lowest occupied fraction (and by at least 10 % of the grid): the sign that the views
    /// disagree and the static field paints fog where things move. 0: off (videos, whose
    /// warm-up was chosen on the family); a jumping camera sets it ([`NsffConfig::
    /// adapt_to_jumping_camera`]).
    #[serde(default)]
    pub warm_up_exit_rise: f32,
    /// During the static warm-up, refresh the occupancy grid with the static field's density
    /// alone (what the warm-up renders) instead of the combined density: the untrained dynamic
    /// field costs half of each refresh for nothing. On for videos (BENCHMARKS.md §6,
    /// twenty-sixth session); off for a jumping camera, whose warm-up exit
    /// (`warm_up_exit_rise`) was chosen with the combined grid; checkpoints from before it read off.
    #[serde(default)]
    pub warm_up_static_occupancy: bool,
    /// Share of the space-time phase during which `weights.moving_dynamic` applies (1: all of
    /// it). The collapse it prevents happens in the first tens of steps; held all run, it keeps
    /// the blend open on static rays too (fog off the path: BENCHMARKS.md §6, twenty-seventh
    /// session). After it the photometric loss shuts the blend where the static field is
    /// better and keeps it open on the movers.
    #[serde(default = "default_moving_dynamic_until")]
    pub moving_dynamic_until: f64,
    /// Reopens a blend that shut on the moving rays during `weights.moving_dynamic`'s span:
    /// when the blend readout on the moving rays averages below this over the span's last
    /// quarter, the blend heads start again (b ≈ 0.05, see [`crate::field::StaticField::
    /// reopen_blend`]) and the span starts again. A shut blend's sigmoids pass almost no
    /// gradient, so it stays shut for most of the run and the static field draws ghosts of the
    /// movers between frames. 0: off (checkpoints from before it); videos 0.1: over 49 runs
    /// (sessions 69-71) the two that shut read 0.000 and 0.001 there, the other 47 at least
    /// 0.60 (BENCHMARKS.md §6, seventy-second session).
    #[serde(default)]
    pub reopen_blend_below: f32,
    /// The share of the space-time phase at which the blend was reopened
    /// (`reopen_blend_below`); saved, so that a resumed run neither reopens it twice nor
    /// loses the span that restarted there.
    #[serde(default)]
    pub blend_reopened_at: Option<f64>,
    /// Random points per step for the dynamic sparsity term (`weights.sparsity`): 1024 for a
    /// video, 512 for a jumping camera.
    #[serde(default = "default_sparsity_points")]
    pub sparsity_points: usize,
    /// Share of a space-time step's rays drawn where the frame's recent renders were worst
    /// (Instant-NGP's error map over 8-pixel tiles, `nerf_core::error_map`); the rest are
    /// uniform. Every ray counts in the photometric loss. Jumping cameras only (a video's
    /// extra rays are NSFF's hard mining); `adapt_to_jumping_camera` sets 0.5.
    #[serde(default)]
    pub error_rays: f32,
    /// Half-width, in frames, of a uniform random offset added to each space-time ray's time
    /// while training (0: the frame's own time). With one viewpoint per frame, a frame's own
    /// time cells at the finest levels would otherwise be fitted to that one view.
    #[serde(default)]
    pub time_jitter: f32,
    /// The march step of renders (evaluation, `nsff render`, the viewer) as a fraction of the
    /// training step. Training marches coarsely because a sample there costs four field queries
    /// and a backward pass; a render's sample costs two queries (1: the training step, which
    /// checkpoints from before it read; 0.5 for new runs, BENCHMARKS.md §6 and §8).
    #[serde(default = "default_render_step_scale")]
    pub render_step_scale: f32,
    /// Occupancy grids over time: the training times' range split into this many bins, each
    /// with its own grid, so rays at one time skip the space movers occupy only at other times
    /// (1: one grid for all times, as videos keep; a jumping camera sets 8; checkpoints from
    /// before it read 1).
    #[serde(default = "default_occupancy_time_bins")]
    pub occupancy_time_bins: usize,
    /// Frames the space-time batch draws its rays from, `rays / frames_per_batch` each. 1 for a
    /// video, whose flow, warp and disparity terms compare one frame with its neighbours; a
    /// jumping camera has none of those and draws from several times at once (checkpoints from
    /// before it read 1).
    #[serde(default = "default_frames_per_batch")]
    pub frames_per_batch: usize,
    /// Neighbouring frames a video's space-time step warps to (the warped render, cycle and
    /// optical-flow terms): 2 is NSFF's both neighbours; 1 (the default) draws one of them at
    /// random and doubles its terms' weight (the same loss in expectation), saving a
    /// dynamic-field query of every sample and its backward pass.
    #[serde(default = "default_warp_neighbours")]
    pub warp_neighbours: usize,
    /// Scene flow from its own small space-time grid (this many levels; fast preset) and MLP
    /// instead of the dynamic field's shared head, so the flow terms do not pull the features
    /// that density and colour are made of. 0: the shared head (the vanilla preset's, a jumping
    /// camera's and an NDC video's); any other video in the fast preset takes 4
    /// ([`NsffConfig::adapt_to`]).
    #[serde(default)]
    pub flow_levels: usize,
    /// log2 of the flow grid's entries per level.
    #[serde(default = "default_flow_log2_table")]
    pub flow_log2_table: u32,
    /// Finest spatial resolution of the flow grid (scene flow is smooth).
    #[serde(default = "default_flow_finest")]
    pub flow_finest: u32,
    /// Hidden width of the flow MLP.
    #[serde(default = "default_flow_hidden")]
    pub flow_hidden: usize,
    /// The projected-flow term reads the dynamic render's weights detached, so it trains the
    /// scene flow only, not where the dynamic field puts its density.
    #[serde(default)]
    pub flow_detach_weights: bool,
    /// With `flow_detach_weights`, the share of the projected-flow term that still reads the
    /// render weights (the rest reads them detached): through the weights the term also places
    /// the movers' geometry. 0: all detached (checkpoints from before it read 0).
    #[serde(default)]
    pub flow_weights_share: f32,
    /// The blend b = b_s(x)·g(x, t) with the dynamic field's time gate g; off, b = b_s(x) as in
    /// NSFF (the gate's output is held at 1). Off, the seven tuning videos at 600 s gain 0.46 dB
    /// between frames and lose 0.14 off the path (BENCHMARKS.md §6, fifty-fourth session).
    #[serde(default = "default_time_gate")]
    pub time_gate: bool,
    /// How renders between frames read the time gate (render-time only; checkpoints from before
    /// it render with the default).
    #[serde(default)]
    pub gate_between: GateBetween,
    /// Frames on each side of a render time whose gates the held gate reaches (`held` only):
    /// 1 reads frames i and i+1, 3 (the default) reads i−2 … i+3 (render-time only). On two
    /// independent sets of the seven tuning videos' checkpoints, 3 gains 0.03 dB on the mean
    /// over 2 on 7/7 videos each time, and 0.28-0.31 dB between frames over the field's gate
    /// (BENCHMARKS.md §6, fifty-sixth and fifty-seventh sessions, with its render cost).
    #[serde(default = "default_gate_reach")]
    pub gate_reach: usize,
}

fn default_gate_reach() -> usize {
    3
}

fn default_time_gate() -> bool {
    true
}

fn default_flow_log2_table() -> u32 {
    14
}

fn default_flow_finest() -> u32 {
    64
}

fn default_flow_hidden() -> usize {
    32
}

/// A render step scale must be a positive number (a zero step would put every render sample at
/// one point); `name` is what the user wrote it as, a setting or a flag.
pub fn check_render_step_scale(name: &str, scale: f32) -> Result<(), String> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(format!("{name} must be a positive number, got {scale}"))
    }
}

/// Frames per time cell of the space-time grid's finest level for a jumping camera.
const JUMPING_FRAMES_PER_TIME_CELL: u32 = 2;

fn default_frames_per_batch() -> usize {
    1
}

fn default_occupancy_time_bins() -> usize {
    1
}

// A video's step: half the static batch, half the space-time batch, half the sparsity points
// and one warp neighbour (was 1, 1, 2048 and 2, which the `default_*` functions below keep for
// checkpoints from before each setting). Paired screen on the six tuning videos at 120 s
// (BENCHMARKS.md §6, twelfth session): mean PSNR +0.45 dB (better on five of six), NSFF's
// seconds per step 1.6-2.0× NeRF's instead of 2.6-3.3×.
const VIDEO_STATIC_BATCH_SCALE: f32 = 0.5;
const VIDEO_SPACE_TIME_SHARE: f32 = 0.5;
const VIDEO_SPARSITY_POINTS: usize = 1024;
const VIDEO_WARP_NEIGHBOURS: usize = 1;

const RENDER_STEP_SCALE: f32 = 0.5;

// A video's scene flow ([`NsffConfig::use_flow_grid`]).
const VIDEO_FLOW_LEVELS: usize = 4;
const VIDEO_FLOW_WEIGHTS_SHARE: f32 = 0.1;
const VIDEO_OPTICAL_FLOW: f64 = 0.2;

// No entropy term on a video's blend: with NSFF's 1e-3 the blend closes during the space-time
// phase on half the tuning videos and the dynamic field draws nothing there. Without it the
// dynamic field takes part on all six; mean PSNR +0.23 dB at 300 s, better on four of six
// (BENCHMARKS.md §6, thirteenth session).
const VIDEO_ENTROPY: f64 = 0.0;

// Holds a video's blend open on the movers for the space-time phase's first fifth (it shuts
// on the tuning videos, fam4's for good, and the dynamic field then draws nothing): +0.43 dB
// over the six tuning videos at 600 s, fam4 +1.70 (BENCHMARKS.md §6, twenty-eighth and
// twenty-ninth sessions).
const VIDEO_MOVING_DYNAMIC: f64 = 0.01;

// A blend shut on the moving rays reads 0.000-0.001 at the end of the moving term's span, an
// open one 0.60 or more (49 runs, BENCHMARKS.md §6, seventy-second session).
const VIDEO_REOPEN_BLEND_BELOW: f32 = 0.1;

// Each sample of the space-time batch holds the same matter as the point its scene flow moves
// it to at the warped neighbour's time (`LossWeights::field_consistency`): over the six tuning
// videos at 600 s, paired runs, mean PSNR +0.18 dB, off the path +0.13, between frames +0.23,
// better off the path on four of six (BENCHMARKS.md §6, thirty-fourth session); no extra
// field query, so no extra cost.
const VIDEO_FIELD_CONSISTENCY: f64 = 0.1;

// A video's learning rate ends at 0.3 × its start (the fast preset's 1e-2 to 3e-3, against
// NeRF's 1e-3): on the six tuning videos in two screens, +0.18 and +0.21 dB on the mean, +0.40
// and +0.33 between frames, −0.04 and +0.09 off the path; 6e-3 gained less (BENCHMARKS.md §6,
// forty-ninth and fiftieth sessions).
const VIDEO_LR_FINAL_RATIO: f64 = 0.3;

// A video's monocular depth prior, when it has one, at a quarter of NSFF's 0.04: over the seven
// tuning videos with a rough simulated disparity, three arms side by side at 600 s, mean PSNR
// +0.19 dB over no prior against 0.04's +0.09, between frames +0.01 against −0.51, off the path
// +0.37 against +0.68 (BENCHMARKS.md §6, sixty-first session).
const VIDEO_DEPTH: f64 = 0.01;

fn default_sparsity_points() -> usize {
    2048
}

// Mover pixels the masks miss train the static field and cost far more than static pixels they
// hold (BENCHMARKS.md §6, seventeenth session: 0.35 over 0.5 on the six tuning scenes).
fn default_mask_threshold_px() -> f32 {
    0.35
}

fn default_hard_fraction() -> f32 {
    0.5
}

fn default_static_batch() -> bool {
    true
}

fn default_static_batch_scale() -> f32 {
    1.0
}

fn default_space_time_share() -> f32 {
    1.0
}

fn default_warp_neighbours() -> usize {
    2
}

fn default_masked_static_scale() -> f32 {
    2.0
}

fn default_moving_dynamic_until() -> f64 {
    0.2
}

fn default_min_rays() -> usize {
    64
}

/// Half the run: NSFF's 25k-step period on our 50k default steps.
fn default_decay_fraction() -> f64 {
    0.5
}

/// The blend weight's default initial logit, −3 (b ≈ 0.05).
pub fn default_blend_init_logit() -> f32 {
    -3.0
}

fn default_dynamic_width() -> usize {
    32
}

fn default_dynamic_sh_degree() -> usize {
    2
}

impl NsffConfig {
    pub fn new(preset: Preset, data: std::path::PathBuf, load: LoadOptions) -> Self {
        let mut base = TrainConfig::new(preset, data, load);
        base.random_background = false;
        base.checkpoint_every = 200;
        base.steps = 50_000;
        NsffConfig {
            base,
            rays: 1024,
            min_rays: default_min_rays(),
            samples: 64,
            dynamic_grid: HashGridConfig {
                dims: 4,
                levels: 12,
                features: 2,
                log2_table: 17,
                base_resolution: 16,
                finest_resolution: 256,
                time_resolution: None,
                // Coarse levels share their features across frames, only the finest resolve
                // single frames: better on every generated jumping scene (BENCHMARKS.md §8) and
                // on five of six tuning videos, equal on the sixth (§6, fifteenth session).
                time_follows_space: true,
            },
            dynamic_encoding: SpaceTimeEncoding::default(),
            dynamic_width: default_dynamic_width(),
            dynamic_sh_degree: default_dynamic_sh_degree(),
            flow_scale: 0.25,
            weights: LossWeights {
                entropy: VIDEO_ENTROPY,
                moving_dynamic: VIDEO_MOVING_DYNAMIC,
                field_consistency: VIDEO_FIELD_CONSISTENCY,
                ..LossWeights::default()
            },
            decay_steps: 25_000,
            decay_fraction: default_decay_fraction(),
            dynamic: DynamicMode::Auto,
            motion_threshold_px: 1.0,
            mask_threshold_px: default_mask_threshold_px(),
            mask_both_neighbours: false,
            unmask_background: false,
            blend_init_logit: default_blend_init_logit(),
            blend_skip: 1e-2,
            time_interp: TimeInterp::Direct,
            hard_fraction: default_hard_fraction(),
            static_batch: default_static_batch(),
            static_batch_scale: VIDEO_STATIC_BATCH_SCALE,
            space_time_share: VIDEO_SPACE_TIME_SHARE,
            static_warm_up: 0.3,
            masked_static: 0.0,
            masked_static_warm_up_only: false,
            masked_static_scale: default_masked_static_scale(),
            static_random_background: false,
            masked_static_after_warm_up: false,
            lr_decay_after_warm_up: true,
            carve_unseen: false,
            sparsity_points: VIDEO_SPARSITY_POINTS,
            error_rays: 0.0,
            time_jitter: 0.0,
            // Half the training step: better on every generated jumping scene (BENCHMARKS.md §8)
            // and on every video of the tuning set (§6, fifteenth session).
            render_step_scale: RENDER_STEP_SCALE,
            warm_up_exit_rise: 0.0,
            warm_up_static_occupancy: true,
            moving_dynamic_until: default_moving_dynamic_until(),
            reopen_blend_below: VIDEO_REOPEN_BLEND_BELOW,
            blend_reopened_at: None,
            occupancy_time_bins: default_occupancy_time_bins(),
            frames_per_batch: default_frames_per_batch(),
            warp_neighbours: VIDEO_WARP_NEIGHBOURS,
            flow_levels: 0,
            flow_log2_table: default_flow_log2_table(),
            flow_finest: default_flow_finest(),
            flow_hidden: default_flow_hidden(),
            flow_detach_weights: false,
            flow_weights_share: 0.0,
            time_gate: default_time_gate(),
            gate_between: GateBetween::default(),
            gate_reach: default_gate_reach(),
        }
    }

    /// Scene-dependent settings once the video is known.
    pub fn adapt_to(&mut self, dataset: &Dataset, frames: usize) {
        self.base.adapt_to(dataset);
        self.base.random_background = false;
        // Time cells end on frames, so each frame has its own features and in-between times
        // interpolate between the two neighbours.
        self.dynamic_grid.time_resolution = Some((frames.max(2) - 1) as u32);
        // NSFF's D: min(max(25, frames), 250); weights decay by 10 every 1000·D steps.
        self.decay_steps = 1000 * frames.clamp(25, 250);
        if dataset.ndc.is_some() {
            self.samples = 128;
            self.flow_scale = 1.0;
        } else {
            let extent = nerf::model::scene_bounds(dataset).extent();
            self.flow_scale = 0.1 * extent;
            // Four field queries per sample make NSFF's samples dear, and the grid prunes only
            // once training has emptied the air: march at a quarter of the static pipeline's
            // resolution (128 steps across the box diagonal, about NSFF's sample count).
            self.base.fast.march.step = extent * 3f32.sqrt() / 128.0;
            if self.base.preset == Preset::Fast {
                self.use_flow_grid();
                self.base.lr_final = VIDEO_LR_FINAL_RATIO * self.base.lr;
                self.weights.depth = VIDEO_DEPTH;
            }
        }
    }

    /// The scene flow on its own 4-level grid, trained by the projected-flow term at ten times
    /// NSFF's weight with nine tenths of it reading the render weights detached (the tenth that
    /// reads them still places the movers' geometry). The default for a generated-style video
    /// (not NDC, which was never screened): on the six tuning videos the scene flow beats no
    /// motion on all six at level PSNR (BENCHMARKS.md §6, twentieth and twenty-first sessions);
    /// on two forward-path videos outside both sets its error is 22 % and 53 % below no motion
    /// against the shared head's 4 % and 41 %, with PSNR +0.15 and +0.36 dB (twenty-fourth).
    fn use_flow_grid(&mut self) {
        self.flow_levels = VIDEO_FLOW_LEVELS;
        self.flow_detach_weights = true;
        self.flow_weights_share = VIDEO_FLOW_WEIGHTS_SHARE;
        self.weights.optical_flow = VIDEO_OPTICAL_FLOW;
    }

    /// Settings for a jumping camera ([`crate::capture`]), after [`NsffConfig::adapt_to`]. Each
    /// time is seen from one viewpoint only, so even the space-time grid's finest time cells
    /// span two frames (its coarse levels share theirs across many frames, as a video's do); a
    /// ray's time is jittered by up to half a frame so that a fine time cell learns from more
    /// than one view. Renders between frames query the field directly: splatting follows a scene
    /// flow that nothing trains here. The
    /// static warm-up ends early when the occupancy grid fills up again (`warm_up_exit_rise`;
    /// BENCHMARKS.md §8: where most of the scene moves, the warm-up's fog cost 1-2 dB). The
    /// occupancy grid has 8 time bins (BENCHMARKS.md §8: level quality on the tuning set, fewer
    /// samples per ray where things move), and steps take half the static pipeline's samples.
    /// Returns whether it had to switch `time_interp`.
    pub fn adapt_to_jumping_camera(&mut self) -> bool {
        // Time cells two frames long at the finest level (so every level's are twice as long):
        // each frame is seen from one viewpoint, and a cell then learns from two. Better on all
        // seven generated jumping scenes at 120 s (BENCHMARKS.md §8).
        if let Some(cells) = self.dynamic_grid.time_resolution {
            self.dynamic_grid.time_resolution = Some((cells / JUMPING_FRAMES_PER_TIME_CELL).max(1));
        }
        self.warm_up_exit_rise = 2.0;
        // The exit rule reads the grid's refill, measured on D-NeRF with the combined density.
        self.warm_up_static_occupancy = false;
        self.occupancy_time_bins = 8;
        // Full batches: the settings below were chosen with them (a video's half batches were
        // screened on videos only).
        self.static_batch_scale = 1.0;
        self.space_time_share = 1.0;
        self.weights.entropy = LossWeights::default().entropy;
        // The blend term was screened on videos only; a jumping camera keeps the entropy term.
        self.weights.moving_dynamic = LossWeights::default().moving_dynamic;
        // The consistency term was screened on videos only.
        self.weights.field_consistency = LossWeights::default().field_consistency;
        // The learning rate's end and the depth prior's weight were screened on videos only.
        self.base.lr_final = self.base.preset.learning_rates().1;
        self.weights.depth = LossWeights::default().depth;
        // No optical flow, so no flow term trains a flow grid: the shared head, as screened.
        self.flow_levels = 0;
        self.flow_detach_weights = false;
        self.flow_weights_share = 0.0;
        self.weights.optical_flow = LossWeights::default().optical_flow;
        // Half the samples per step, about 1.5× the steps: better on six of seven generated
        // jumping scenes at 120 s (BENCHMARKS.md §8).
        self.base.fast.target_samples = 4096;
        // A quarter of the sparsity term's points: a cheaper step, better on six of seven
        // generated jumping scenes at 120 s (BENCHMARKS.md §8).
        self.sparsity_points = 512;
        // Half the rays where the frame rendered worst: better on six of seven (BENCHMARKS.md §8).
        self.error_rays = 0.5;
        // Each ray's time within half a frame of its frame's: better on six of seven
        // (BENCHMARKS.md §8).
        self.time_jitter = 0.5;
        let splat = self.time_interp == TimeInterp::Splat;
        self.time_interp = TimeInterp::Direct;
        splat
    }

    /// Settings for a video whose motion masks are given (`motion_masks/`), after
    /// [`NsffConfig::adapt_to`]: the cells no training frame sees are carved (`carve_unseen`).
    /// With given masks the static field explains more of the frame, and over seeds it left
    /// white fog in that space on some runs (fam14 at two seeds of six, 4.75 dB behind NeRF off
    /// the path at one). On the seven tuning videos with masks the carve gained 0.44 dB off the
    /// path (fam17 2.66, none below −0.24; BENCHMARKS.md §6, seventy-first session). Videos
    /// without masks keep the default: there it was level, and it bets on white where the unseen
    /// space holds a surface.
    pub fn adapt_to_given_masks(&mut self) {
        self.carve_unseen = true;
    }

    /// Settings that cannot work together, as a message (after `--set` overrides).
    pub fn validate(&self) -> Result<(), String> {
        if self.dynamic_encoding == SpaceTimeEncoding::Planes && self.base.preset != Preset::Fast {
            return Err(format!(
                "dynamic_encoding=planes needs --preset fast (the {:?} preset's dynamic field has no grid to factorise)",
                self.base.preset
            ));
        }
        if self.flow_levels > 0 && self.base.preset != Preset::Fast {
            return Err(format!(
                "flow_levels={} needs --preset fast (the {:?} preset's scene flow comes from its shared head)",
                self.flow_levels, self.base.preset
            ));
        }
        if !(0.0..=1.0).contains(&self.masked_static) {
            return Err(format!(
                "masked_static must be in [0, 1], got {}",
                self.masked_static
            ));
        }
        if self.masked_static_warm_up_only && self.masked_static_after_warm_up {
            return Err(
                "masked_static_warm_up_only and masked_static_after_warm_up together would leave no phase for masked_static"
                    .into(),
            );
        }
        if !(self.masked_static_scale.is_finite() && self.masked_static_scale > 0.0) {
            return Err(format!(
                "masked_static_scale must be a positive number, got {}",
                self.masked_static_scale
            ));
        }
        if !(0.0..=1.0).contains(&self.flow_weights_share) {
            return Err(format!(
                "flow_weights_share must be in [0, 1], got {}",
                self.flow_weights_share
            ));
        }
        if self.flow_levels > 0 && self.flow_finest < self.dynamic_grid.base_resolution {
            return Err(format!(
                "flow_finest={} is below the dynamic grid's base resolution ({}), the flow grid's coarsest level",
                self.flow_finest, self.dynamic_grid.base_resolution
            ));
        }
        if !(self.time_jitter.is_finite() && self.time_jitter >= 0.0) {
            return Err(format!(
                "time_jitter must be 0 or more frames, got {}",
                self.time_jitter
            ));
        }
        if self.warp_neighbours == 0 {
            return Err(
                "warp_neighbours must be at least 1 (0 would drop the scene flow's warp terms)".into(),
            );
        }
        if self.gate_reach == 0 {
            return Err("gate_reach must be at least 1 (the two neighbouring frames)".into());
        }
        self.base.validate()?;
        self.weights.validate()?;
        check_render_step_scale("render_step_scale", self.render_step_scale)
    }

    /// The scene-flow grid (`flow_levels` > 0): the dynamic grid's time cells, coarser in space.
    pub fn flow_grid(&self) -> Option<HashGridConfig> {
        (self.flow_levels > 0).then(|| HashGridConfig {
            levels: self.flow_levels,
            log2_table: self.flow_log2_table,
            finest_resolution: self.flow_finest,
            ..self.dynamic_grid.clone()
        })
    }

    /// Weight multiplier of the decaying terms at `step` and training `progress` in [0, 1].
    pub fn decay(&self, step: usize, progress: f64) -> f64 {
        let by_steps = step / self.decay_steps.max(1);
        let by_progress = (progress / self.decay_fraction.max(1e-9)).floor() as usize;
        0.1f64.powi(by_steps.max(by_progress).min(1000) as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_need_the_fast_preset() {
        let mut cfg = NsffConfig::new(Preset::Vanilla, "unused".into(), LoadOptions::default());
        assert!(cfg.validate().is_ok());
        cfg.dynamic_encoding = SpaceTimeEncoding::Planes;
        let err = cfg.validate().unwrap_err();
        assert!(err.contains("planes") && err.contains("fast"), "{err}");
        cfg.base.preset = Preset::Fast;
        assert!(cfg.validate().is_ok());
    }

    /// A negative or NaN jitter, a render step scale that is not positive, a gate reach of 0, or
    /// a still-ray weight outside [0, 1] is refused with the setting's name (a zero step would
    /// put every render sample at one point).
    #[test]
    fn jitter_and_render_step_must_make_sense() {
        let fresh = || NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        for jitter in [-0.5, f32::NAN] {
            let mut cfg = fresh();
            cfg.time_jitter = jitter;
            assert!(cfg.validate().unwrap_err().contains("time_jitter"));
        }
        for scale in [0.0, -1.0, f32::INFINITY] {
            let mut cfg = fresh();
            cfg.render_step_scale = scale;
            assert!(cfg.validate().unwrap_err().contains("render_step_scale"));
        }
        // The held gate reads at least the two neighbouring frames.
        let mut cfg = fresh();
        cfg.gate_reach = 0;
        assert!(cfg.validate().unwrap_err().contains("gate_reach"));
        let mut cfg = fresh();
        cfg.adapt_to_jumping_camera();
        assert!(cfg.validate().is_ok());
    }

    /// A loss weight that is negative, NaN or infinite is refused with its name; 0 and
    /// positive weights pass, on the first field and on the last.
    #[test]
    fn loss_weights_must_be_finite_and_not_negative() {
        let fresh = || NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        for (w, ok) in [
            (0.0, true),
            (0.5, true),
            (-0.01, false),
            (f64::NAN, false),
            (f64::INFINITY, false),
        ] {
            let first: fn(&mut LossWeights) -> &mut f64 = |l| &mut l.dynamic_photo;
            let last: fn(&mut LossWeights) -> &mut f64 = |l| &mut l.field_consistency;
            for (name, field) in [("dynamic_photo", first), ("field_consistency", last)] {
                let mut cfg = fresh();
                *field(&mut cfg.weights) = w;
                let got = cfg.validate();
                assert_eq!(got.is_ok(), ok, "{name} {w}: {got:?}");
                if let Err(e) = got {
                    assert!(e.contains(&format!("weights.{name}")), "{e}");
                }
            }
        }
    }

    /// A video's step takes half batches and one warp neighbour, and its blend no entropy term;
    /// a jumping camera, whose settings were chosen with full batches and the term, keeps them.
    /// Both share time on the space-time grid's coarse levels and render at half the step. A
    /// video's warm-up refreshes the occupancy grid from the static field alone; a jumping
    /// camera's, whose exit rule reads the grid, from the combined density as measured, and
    /// its learning rate ends where the preset's does and its depth prior keeps NSFF's weight
    /// (a video's higher end and lighter prior were screened on videos only).
    #[test]
    fn videos_halve_the_batches_and_jumping_cameras_keep_them() {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        assert_eq!((cfg.static_batch_scale, cfg.space_time_share), (0.5, 0.5));
        assert_eq!((cfg.sparsity_points, cfg.warp_neighbours), (1024, 1));
        assert_eq!((cfg.weights.entropy, cfg.render_step_scale), (0.0, 0.5));
        assert!(cfg.dynamic_grid.time_follows_space);
        assert!(cfg.warm_up_static_occupancy);
        assert_eq!(
            (cfg.weights.moving_dynamic, cfg.moving_dynamic_until),
            (0.01, 0.2)
        );
        (cfg.base.lr_final, cfg.weights.depth) = (3e-3, 0.01); // as a video's adapt_to leaves them
        cfg.adapt_to_jumping_camera();
        assert_eq!(
            (cfg.base.lr, cfg.base.lr_final),
            (1e-2, 1e-3),
            "the preset's rates"
        );
        assert_eq!(cfg.weights.depth, 0.04, "NSFF's depth weight");
        assert_eq!((cfg.static_batch_scale, cfg.space_time_share), (1.0, 1.0));
        assert_eq!(cfg.sparsity_points, 512);
        assert_eq!((cfg.weights.entropy, cfg.weights.moving_dynamic), (1e-3, 0.0));
        assert!(!cfg.warm_up_static_occupancy);
    }

    /// The flow grid is opt-in (`flow_levels`), with the dynamic grid's time cells and its own
    /// levels, resolution and table; the vanilla preset, which has no grid, refuses it.
    #[test]
    fn the_flow_grid_is_opt_in_and_needs_the_fast_preset() {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        cfg.dynamic_grid.time_resolution = Some(23);
        assert!(cfg.flow_grid().is_none());
        assert!(!cfg.flow_detach_weights);
        cfg.flow_levels = 4;
        let grid = cfg.flow_grid().unwrap();
        assert_eq!(
            (grid.levels, grid.finest_resolution, grid.log2_table),
            (4, 64, 14)
        );
        assert_eq!((grid.dims, grid.time_resolution), (4, Some(23)));
        assert!(cfg.validate().is_ok());
        // A finest resolution below the coarsest level is refused, not raised.
        cfg.flow_finest = 8;
        let err = cfg.validate().unwrap_err();
        assert!(err.contains("flow_finest=8") && err.contains("16"), "{err}");
        cfg.flow_finest = 64;
        // The share of the term through the weights is a fraction.
        for (share, ok) in [(0.0, true), (0.1, true), (1.0, true), (-0.1, false), (1.5, false)] {
            cfg.flow_weights_share = share;
            assert_eq!(cfg.validate().is_ok(), ok, "share {share}");
        }
        cfg.flow_weights_share = 0.0;
        cfg.base.preset = Preset::Vanilla;
        let err = cfg.validate().unwrap_err();
        assert!(err.contains("flow_levels") && err.contains("fast"), "{err}");
    }

    /// No warp neighbour at all would silently drop the scene flow's warp terms: refused.
    #[test]
    fn warp_neighbours_must_be_at_least_one() {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        cfg.warp_neighbours = 0;
        assert!(cfg.validate().unwrap_err().contains("warp_neighbours"));
        cfg.warp_neighbours = 1;
        assert!(cfg.validate().is_ok());
    }

    /// A jumping camera's finest time cells span two frames: 150 frames (149 gaps, as
    /// `adapt_to` sets) give 74 cells, and the grid's finest level has them; never fewer than 1.
    #[test]
    fn a_jumping_camera_has_two_frames_per_time_cell() {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        cfg.dynamic_grid.time_resolution = Some(149);
        cfg.adapt_to_jumping_camera();
        assert_eq!(cfg.dynamic_grid.time_resolution, Some(74));
        let finest = nerf_core::encoding::hash_grid::levels(&cfg.dynamic_grid);
        assert_eq!(finest.last().unwrap().resolutions[3], 74);
        cfg.dynamic_grid.time_resolution = Some(1);
        cfg.adapt_to_jumping_camera();
        assert_eq!(cfg.dynamic_grid.time_resolution, Some(1));
    }

    #[test]
    fn decay_follows_steps_or_budget_whichever_is_first() {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), LoadOptions::default());
        cfg.decay_steps = 1000;
        cfg.decay_fraction = 0.5;
        // Step schedule alone (a long run): 10x per 1000 steps.
        assert_eq!(cfg.decay(999, 0.01), 1.0);
        assert!((cfg.decay(1000, 0.02) - 0.1).abs() < 1e-12);
        assert!((cfg.decay(2500, 0.05) - 0.01).abs() < 1e-12);
        // A short, budgeted run: 10x at half of it.
        assert_eq!(cfg.decay(10, 0.49), 1.0);
        assert!((cfg.decay(10, 0.5) - 0.1).abs() < 1e-12);
        assert!((cfg.decay(10, 1.0) - 0.01).abs() < 1e-12);
    }
}
