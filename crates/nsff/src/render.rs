//! Space-time rendering: samples along rays, the combined static + dynamic render (through the
//! shared render function), and NSFF's time interpolation by splatting scene-flow-displaced
//! samples layer by layer (a mixture of two times per layer, which the per-sample compositor
//! cannot express; its background goes through the shared helper).

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use nerf::error::{ModelError, read_back};
use nerf::renderer::{SceneBounds, tensor};
use nerf_core::field::{Field, FieldOutputs, FieldQuery, rows3};
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::profile::span;
use nerf_core::rays::{Rays, intersect_aabb};
use nerf_core::render::{Background, Component, RenderOptions, RenderOutput, add_background_host, render};
use nerf_core::sampler::{self, MarchConfig, RaySamples, Spacing, stratified};
use nerf_data::{Camera, Dataset};
use rand::rngs::StdRng;

use crate::config::GateBetween;
use crate::eval::frame_position;
use crate::field::{BLEND, DynamicField, FLOW_NEXT, FLOW_PREV, GATE, time_column};
use crate::geometry;
use crate::model::{NsffModel, query_at_time, query_dynamic};

/// Samples along rays. With an occupancy grid (object scenes, fast preset) the rays march through
/// it and skip empty space; otherwise `n` stratified samples per ray in [near, far], clipped to
/// the scene box when `clip_to_box`. Jittered when `rng` is given.
pub fn sample_rays(
    rays: &Rays,
    bounds: &SceneBounds,
    n: usize,
    clip_to_box: bool,
    march: Option<(&OccupancyGrid, &MarchConfig)>,
    rng: Option<&mut StdRng>,
) -> RaySamples {
    if let Some((grid, cfg)) = march {
        return sampler::march(rays, bounds.aabb, bounds.near, bounds.far, Some(grid), cfg, rng);
    }
    let mut near = Vec::with_capacity(rays.len());
    let mut far = Vec::with_capacity(rays.len());
    for r in 0..rays.len() {
        let (mut a, mut b) = (bounds.near, bounds.far);
        if clip_to_box {
            match intersect_aabb(rays.origin(r), rays.direction(r), bounds.aabb[0], bounds.aabb[1]) {
                Some((t0, t1)) => {
                    a = a.max(t0);
                    b = b.min(t1);
                }
                None => b = a, // misses the box: no samples
            }
        }
        near.push(a);
        far.push(b);
    }
    stratified(&near, &far, n, Spacing::Depth, rng)
}

/// Colour, depth and opacity of rays on the host.
#[derive(Clone, Debug, Default)]
pub struct HostRender {
    pub rgb: Vec<f32>,
    pub depth: Vec<f32>,
    pub opacity: Vec<f32>,
    /// Share of each pixel rendered by the dynamic field (NSFF's M_dd).
    pub dynamic_share: Vec<f32>,
    /// Expected scene-flow magnitude to the next frame along each ray (scene units); empty when
    /// the render skipped it ([`FlowMap::Skip`]).
    pub flow_magnitude: Vec<f32>,
    /// Dynamic-field evaluations per ray (what the blend-weight skip saves).
    pub dynamic_per_ray: f64,
    pub samples_per_ray: f64,
}

/// Both fields queried at a batch's samples at one time (the training step's queries).
pub struct SpaceTimeQuery {
    /// `[S, 3]` sample positions and `S·3` unit view directions.
    pub x: Tensor<2>,
    pub dirs: Vec<f32>,
    pub st: FieldOutputs,
    pub dy: FieldOutputs,
}

/// Queries both fields at `samples` along `rays` at `[S, 1]` normalised times `time` (see
/// [`crate::field::time_column`] for one time).
pub fn query_space_time(
    model: &NsffModel,
    dynamic: &DynamicField,
    rays: &Rays,
    samples: &RaySamples,
    time: Tensor<2>,
    device: &Device,
) -> SpaceTimeQuery {
    let x = tensor(samples.positions(rays), 3, device);
    let dirs = samples.per_sample3(&rays.viewdirs());
    let st = model.fields.static_field.query(FieldQuery::new(x.clone(), &dirs));
    let dy = dynamic.query(FieldQuery::new(x.clone(), &dirs).at_time(Some(time)));
    SpaceTimeQuery { x, dirs, st, dy }
}

/// Compositing options of the model's samples: marched rays end wherever the grid does, so they
/// must not absorb the remaining light.
pub fn render_options(model: &NsffModel) -> RenderOptions {
    RenderOptions {
        open_far: model.bounds.open_far && model.occupancy.is_none(),
        stop_eps: 0.0,
    }
}

/// The combined render of training (differentiable on an autodiff device): the static and
/// dynamic components blended per sample by b = b_s·g; with `dynamic_share`, also the
/// [`DYNAMIC_SHARE`] channel (an extra channel on the hot path, so only when a loss reads it).
pub fn render_combined(
    model: &NsffModel,
    rays: &Rays,
    samples: &RaySamples,
    q: &SpaceTimeQuery,
    background: Option<[f32; 3]>,
    dynamic_share: bool,
    device: &Device,
) -> RenderOutput {
    let blend = q.st.extras.expect(BLEND) * q.dy.extras.expect(GATE);
    let mut dynamic = Component::new(q.dy.sigma.clone(), q.dy.rgb.clone()).blended(blend.clone());
    if dynamic_share {
        let ones = Tensor::ones([q.dy.sigma.dims()[0], 1], &q.dy.sigma.device());
        dynamic = dynamic.with(DYNAMIC_SHARE, ones);
    }
    render(
        rays,
        samples,
        &[
            Component::new(q.st.sigma.clone(), q.st.rgb.clone()).blended(blend.neg() + 1.0),
            dynamic,
        ],
        &Background::from_option(background),
        render_options(model),
        device,
    )
}

/// Whether a render draws the scene-flow magnitude map ([`HostRender::flow_magnitude`]; the
/// render command's and the viewer's `flow` channel). Skipping it spares a dynamic field with
/// its own flow network that network: about 7 % of an eval (BENCHMARKS.md §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlowMap {
    Skip,
    Draw,
}

/// Renders rays at normalised time `time` with the combined model, no gradients. Samples whose
/// static blend weight is below `blend_skip` skip the dynamic field. With an occupancy grid the
/// rays march through it.
pub fn render_direct(
    model: &NsffModel,
    rays: &Rays,
    time: f32,
    background: Option<[f32; 3]>,
    flow_map: FlowMap,
    device: &Device,
) -> Result<HostRender, ModelError> {
    let plain = device.clone().inner();
    let fields = model.fields.valid();
    let (bounds, settings) = (&model.bounds, &model.settings);
    let render_march = settings.render_march();
    let march = model.occupancy.as_ref().map(|g| (g.at(time), &render_march));
    let samples = span("render_march", || {
        sample_rays(rays, bounds, settings.samples, !bounds.open_far, march, None)
    });
    let s_n = samples.num_samples();
    if s_n == 0 {
        let out = render(
            rays,
            &samples,
            &[],
            &Background::from_option(background),
            RenderOptions::default(),
            &plain,
        );
        let zeros = vec![0.0; rays.len()];
        return Ok(HostRender {
            rgb: read_back(out.rgb, "background")?,
            depth: zeros.clone(),
            opacity: zeros.clone(),
            dynamic_share: zeros.clone(),
            flow_magnitude: match flow_map {
                FlowMap::Draw => zeros,
                FlowMap::Skip => Vec::new(),
            },
            ..HostRender::default()
        });
    }
    let pos = samples.positions(rays);
    let dirs = samples.per_sample3(&rays.viewdirs());
    // Spans end with a read-back, so they time the work, not the building of a lazy graph.
    let (st, mut blend) = span("render_static", || {
        let st = fields
            .static_field
            .query(FieldQuery::new(tensor(pos.clone(), 3, &plain), &dirs));
        read_back(st.extras.expect(BLEND), "blend weight").map(|b| (st, b))
    })?;
    // Without the dynamic field the static field renders at full density, as it trains (the
    // static pipeline's loss) and as the occupancy grid sees it.
    let dynamic = fields.dynamic.as_ref().filter(|_| !settings.static_only);
    if dynamic.is_none() {
        blend.fill(0.0);
    }
    let mut sigma_dy = vec![0.0f32; s_n];
    let mut rgb_dy = vec![0.0f32; 3 * s_n];
    let mut flow_mag = vec![0.0f32; s_n];
    let mut evaluated = 0usize;
    if let Some(dynamic) = dynamic {
        // b = b_s·g ≤ b_s: where b_s says static, the dynamic field cannot contribute.
        let keep: Vec<usize> = (0..s_n).filter(|&i| blend[i] >= settings.blend_skip).collect();
        evaluated = keep.len();
        if !keep.is_empty() {
            let kept_pos = rows3(&pos, &keep);
            let (s, c, f, mut g) = span("render_dynamic", || {
                let kept_dirs = rows3(&dirs, &keep);
                let query = query_at_time(tensor(kept_pos.clone(), 3, &plain), time, &kept_dirs);
                let dy = match flow_map {
                    FlowMap::Draw => dynamic.query(query),
                    FlowMap::Skip => dynamic.query_without_flow(query),
                };
                let flow = match dy.extras.get(FLOW_NEXT) {
                    Some(next) => read_back(next.clone(), "scene flow")?,
                    None => Vec::new(),
                };
                Ok::<_, ModelError>((
                    read_back(dy.sigma, "dynamic density")?,
                    read_back(dy.rgb, "dynamic colour")?,
                    flow,
                    read_back(dy.extras.expect(GATE), "time gate")?,
                ))
            })?;
            if settings.gate_between == GateBetween::Held {
                let reach = settings.gate_reach;
                span("render_held_gate", || {
                    hold_gate(
                        dynamic,
                        &model.times,
                        time,
                        reach,
                        HELD_GATE_SKIP,
                        &kept_pos,
                        &mut g,
                        &plain,
                    )
                })?;
            }
            for (k, &i) in keep.iter().enumerate() {
                blend[i] *= g[k];
                sigma_dy[i] = s[k];
                rgb_dy[3 * i..3 * i + 3].copy_from_slice(&c[3 * k..3 * k + 3]);
                if let Some(f) = f.get(3 * k..3 * k + 3) {
                    flow_mag[i] = (f[0].powi(2) + f[1].powi(2) + f[2].powi(2)).sqrt();
                }
            }
        }
    }
    let b = tensor(blend, 1, &plain);
    let mut dynamic_component = Component::new(tensor(sigma_dy, 1, &plain), tensor(rgb_dy, 3, &plain))
        .blended(b.clone())
        .with(DYNAMIC_SHARE, Tensor::ones([s_n, 1], &plain));
    if flow_map == FlowMap::Draw {
        dynamic_component = dynamic_component.with(FLOW_MAGNITUDE, tensor(flow_mag, 1, &plain));
    }
    let components = [
        Component::new(st.sigma, st.rgb).blended(b.neg() + 1.0),
        dynamic_component,
    ];
    let r = rays.len().max(1) as f64;
    span("render_composite", || {
        let out = render(
            rays,
            &samples,
            &components,
            &Background::from_option(background),
            render_options(model),
            &plain,
        );
        let share = out.expect(DYNAMIC_SHARE);
        let flow_magnitude = match out.extra(FLOW_MAGNITUDE) {
            Some(flow) => read_back(flow.clone(), "flow magnitude")?,
            None => Vec::new(),
        };
        Ok(HostRender {
            rgb: read_back(out.rgb, "rendered colour")?,
            depth: read_back(out.depth, "rendered depth")?,
            opacity: read_back(out.opacity, "rendered opacity")?,
            dynamic_share: read_back(share, "dynamic share")?,
            flow_magnitude,
            samples_per_ray: s_n as f64 / r,
            dynamic_per_ray: evaluated as f64 / r,
        })
    })
}

/// Samples whose own gate is at least this are left as they are by the held gate: it could
/// raise them by at most 1 − this, and on the tuning videos 14-43 % of the samples between
/// frames are there (BENCHMARKS.md §6, fifty-seventh session).
const HELD_GATE_SKIP: f32 = 0.99;

/// Between training frames i and i + 1, a fraction r of the way, raises each sample's time gate
/// towards the largest gate at the same point of frames i+1−reach … i+reach (clipped to the
/// video), by w = 1 − |2r − 1| (full half-way, none on a frame, so renders stay continuous in
/// time): a point that a nearby frame draws with the dynamic field stays drawn between frames.
/// Gates at or above `skip_above` are not read further. `positions` is `S·3`, `gate` `S`.
#[allow(clippy::too_many_arguments)]
fn hold_gate(
    dynamic: &DynamicField,
    times: &[f32],
    time: f32,
    reach: usize,
    skip_above: f32,
    positions: &[f32],
    gate: &mut [f32],
    device: &Device,
) -> Result<(), ModelError> {
    if times.len() < 2 || gate.is_empty() {
        return Ok(());
    }
    let tau = frame_position(times, time);
    let i = (tau.floor() as usize).min(times.len() - 2);
    let w = 1.0 - (2.0 * (tau - i as f32) - 1.0).abs();
    if w <= 0.0 {
        return Ok(());
    }
    let open: Vec<usize> = (0..gate.len()).filter(|&k| gate[k] < skip_above).collect();
    if open.is_empty() {
        return Ok(());
    }
    let at = tensor(rows3(positions, &open), 3, device);
    // Frames i+1−reach … i+reach, clipped to the video.
    let frames = (i + 1).saturating_sub(reach)..=(i + reach).min(times.len() - 1);
    let n = open.len();
    let mut held = vec![0.0f32; n];
    for t in frames.map(|f| times[f]) {
        let d = dynamic.density(at.clone(), Some(time_column(t, n, device)));
        let at_frame = read_back(d.extras.expect(GATE), "time gate at a frame")?;
        for (h, v) in held.iter_mut().zip(at_frame) {
            *h = h.max(v);
        }
    }
    for (&k, h) in open.iter().zip(held) {
        gate[k] += w * (h - gate[k]).max(0.0);
    }
    Ok(())
}

/// Render channels beside colour, depth and opacity: the share of each pixel rendered by the
/// dynamic component, and its expected scene-flow magnitude.
/// Extra channel: the dynamic component's share of a pixel (Σ of its blended weights).
pub const DYNAMIC_SHARE: &str = "dynamic_share";
const FLOW_MAGNITUDE: &str = "flow_magnitude";

/// Renders a whole camera at a continuous frame position `tau` (frame index units). Between
/// frames i and i+1 (r = tau − i), NSFF's splatting: the samples of both neighbouring times are
/// moved along their scene flow by r and 1 − r, projected into the camera, and splatted layer by
/// layer (samples share depths across rays, so layer k is a fronto-parallel slice), then
/// composited front to back. `times[i]` is frame i's normalised time.
pub fn render_splat(
    model: &NsffModel,
    dataset: &Dataset,
    camera: &Camera,
    tau: f32,
    device: &Device,
) -> Result<HostRender, ModelError> {
    let plain = device.clone().inner();
    let (times, bounds) = (&model.times, &model.bounds);
    let rays = dataset.rays_for(camera, 0..camera.intrinsics.num_pixels() as u32);
    let last = times.len() - 1;
    let i = (tau.floor().max(0.0) as usize).min(last.saturating_sub(1));
    let r = (tau - i as f32).clamp(0.0, 1.0);
    let dynamic = model
        .fields
        .dynamic
        .as_ref()
        .filter(|_| !model.settings.static_only);
    let Some(dynamic) = dynamic.map(|d| d.valid()) else {
        return render_direct(model, &rays, times[i], dataset.background, FlowMap::Draw, device);
    };
    let st_field = model.fields.static_field.valid();
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let n_rays = rays.len();
    // Same depths for every ray: layers are slices of constant camera depth (or NDC t).
    let s = model.settings.samples;
    // Not clipped to the box: every ray needs all `s` layers.
    let samples = sample_rays(&rays, bounds, s, false, None, None);
    let pos = samples.positions(&rays);
    let dirs = samples.per_sample3(&rays.viewdirs());
    let layout = samples.layout(&rays, bounds.open_far);
    let x = tensor(pos.clone(), 3, &plain);
    let st = st_field.query(FieldQuery::new(x.clone(), &dirs));
    let blend = read_back(st.extras.expect(BLEND), "blend weight")?;
    let (mut sigma_st, rgb_st) = (
        read_back(st.sigma, "static density")?,
        read_back(st.rgb, "static colour")?,
    );
    // Layers span [near, far], which can leave the scene box; the fields are undefined there.
    let inside: Vec<bool> = pos
        .chunks_exact(3)
        .map(|p| (0..3).all(|a| p[a] >= bounds.aabb[0][a] && p[a] <= bounds.aabb[1][a]))
        .collect();
    for (sg, &ok) in sigma_st.iter_mut().zip(&inside) {
        if !ok {
            *sg = 0.0;
        }
    }
    // Per time: α^dy, colour, and splat target pixel of each sample.
    let mut per_time = Vec::new();
    for (m, frame) in [i, i + 1].into_iter().enumerate() {
        let dy = query_dynamic(&dynamic, x.clone(), times[frame], &dirs);
        // Move towards the target time: from frame i forward by r, from i+1 backward by 1 − r.
        let (flow, amount) = if m == 0 {
            (dy.extras.expect(FLOW_NEXT), r)
        } else {
            (dy.extras.expect(FLOW_PREV), 1.0 - r)
        };
        let moved = x.clone() + flow * amount;
        let world = match &dataset.ndc {
            Some(ndc) => geometry::ndc_to_world(moved, ndc),
            None => moved,
        };
        let uv = read_back(geometry::project(world, camera, &plain), "projected samples")?;
        let mut sigma_dy = read_back(dy.sigma, "dynamic density")?;
        for (sg, &ok) in sigma_dy.iter_mut().zip(&inside) {
            if !ok {
                *sg = 0.0;
            }
        }
        // This time's blend, b_s·g.
        let gate = read_back(dy.extras.expect(GATE), "time gate")?;
        let b: Vec<f32> = blend.iter().zip(gate).map(|(b, g)| b * g).collect();
        per_time.push((sigma_dy, read_back(dy.rgb, "dynamic colour")?, uv, b));
    }
    let mut rgb = vec![0.0f32; 3 * n_rays];
    let mut trans = vec![1.0f32; n_rays];
    let mut acc = vec![0.0f32; n_rays];
    let mut depth = vec![0.0f32; n_rays];
    // Splat buffers for one layer and one time: Σw·(α c, α), Σw.
    let mut splat = vec![[0.0f32; 5]; n_rays];
    let mut layers = [vec![[0.0f32; 4]; n_rays], vec![[0.0f32; 4]; n_rays]];
    for k in 0..s {
        for (m, (sigma_dy, rgb_dy, uv, blend)) in per_time.iter().enumerate() {
            splat.iter_mut().for_each(|v| *v = [0.0; 5]);
            for ray in 0..n_rays {
                let sidx = layout.offsets[ray] as usize + k;
                let a = (1.0 - (-sigma_dy[sidx] * layout.deltas[sidx]).exp()) * blend[sidx];
                let (u, v) = (uv[2 * sidx] - 0.5, uv[2 * sidx + 1] - 0.5);
                if !(u.is_finite() && v.is_finite()) || u < -1.0 || v < -1.0 || u > w as f32 || v > h as f32 {
                    continue;
                }
                let (x0, y0) = (u.floor(), v.floor());
                let (fx, fy) = (u - x0, v - y0);
                for (dx, dy, wgt) in [
                    (0, 0, (1.0 - fx) * (1.0 - fy)),
                    (1, 0, fx * (1.0 - fy)),
                    (0, 1, (1.0 - fx) * fy),
                    (1, 1, fx * fy),
                ] {
                    let (px, py) = (x0 as i64 + dx, y0 as i64 + dy);
                    if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 || wgt <= 0.0 {
                        continue;
                    }
                    let t = &mut splat[py as usize * w + px as usize];
                    for c in 0..3 {
                        t[c] += wgt * a * rgb_dy[3 * sidx + c];
                    }
                    t[3] += wgt * a;
                    t[4] += wgt;
                }
            }
            for (dst, src) in layers[m].iter_mut().zip(&splat) {
                let norm = 1.0 / (src[4] + 1e-7);
                *dst = [src[0] * norm, src[1] * norm, src[2] * norm, src[3] * norm];
            }
        }
        for ray in 0..n_rays {
            let sidx = layout.offsets[ray] as usize + k;
            // The static share at each neighbouring time: 1 − b_s·g of that time.
            let alpha_st = 1.0 - (-sigma_st[sidx] * layout.deltas[sidx]).exp();
            let a1 = alpha_st * (1.0 - per_time[0].3[sidx]);
            let a2 = alpha_st * (1.0 - per_time[1].3[sidx]);
            let (l1, l2) = (layers[0][ray], layers[1][ray]);
            let tr = trans[ray];
            for c in 0..3 {
                let st_c = rgb_st[3 * sidx + c];
                rgb[3 * ray + c] += tr * ((1.0 - r) * (l1[c] + a1 * st_c) + r * (l2[c] + a2 * st_c));
            }
            // As the training composite (NSFF): light passes both components, (1 − α_dy)(1 − α_st),
            // and the opacity counts each component's weight, T·(α_dy + α_st).
            let weight = (1.0 - r) * (l1[3] + a1) + r * (l2[3] + a2);
            let pass = (1.0 - r) * (1.0 - l1[3]) * (1.0 - a1) + r * (1.0 - l2[3]) * (1.0 - a2);
            acc[ray] += tr * weight;
            depth[ray] += tr * weight * samples.t[sidx];
            trans[ray] = tr * pass.max(0.0);
        }
    }
    add_background_host(&mut rgb, &acc, dataset.background);
    Ok(HostRender {
        rgb,
        depth,
        opacity: acc,
        dynamic_share: vec![0.0; n_rays],
        flow_magnitude: vec![0.0; n_rays],
        dynamic_per_ray: 2.0 * s as f64,
        samples_per_ray: s as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::NsffConfig;
    use nerf::config::Preset;
    use nerf_core::readback::{assert_close, host};
    use nerf_data::{Format, Intrinsics, Pose};

    /// An untrained model with both fields at three times, no occupancy grid, no blend skip and
    /// b_s = 0.5 (so both components show), and the rays of a 12×10 camera looking at it.
    fn untrained_scene(dev: &Device) -> (NsffConfig, SceneBounds, NsffModel, Rays) {
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        cfg.samples = 24;
        cfg.blend_skip = 0.0;
        cfg.blend_init_logit = 0.0;
        let bounds = SceneBounds::object(2.0, 6.0, [[-1.5; 3], [1.5; 3]]);
        let mut model = NsffModel::new(&cfg, bounds.clone(), vec![0.0, 0.5, 1.0], true, dev);
        model.occupancy = None;
        let pose = Pose::look_at([0.3, 0.2, 3.5], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let camera = Camera::new(Intrinsics::centered(14.0, 12, 10), pose);
        (cfg, bounds, model, nerf_data::rays::camera_rays(&camera))
    }

    /// The training step's combined render (autodiff device, both fields queried everywhere) and
    /// the inference render (plain device, blend skip off) agree for the same parameters and
    /// unjittered samples, at a frame time and between frames.
    #[test]
    fn training_and_inference_renders_agree_on_and_between_frames() {
        let dev = Device::flex().autodiff();
        let (cfg, bounds, model, rays) = untrained_scene(&dev);
        let bg = Some([0.9f32, 0.5, 0.1]);
        // Training renders with the field's own gate; the held gate is a render-time rule.
        let mut model = model;
        model.settings.gate_between = GateBetween::Field;
        let dynamic = model.fields.dynamic.as_ref().unwrap();
        for time in [0.5f32, 0.3] {
            let samples = sample_rays(&rays, &bounds, cfg.samples, true, None, None);
            let t = crate::field::time_column(time, samples.num_samples(), &dev);
            let q = query_space_time(&model, dynamic, &rays, &samples, t, &dev);
            let train = render_combined(&model, &rays, &samples, &q, bg, true, &dev);
            let infer = render_direct(&model, &rays, time, bg, FlowMap::Skip, &dev).unwrap();
            let opacity = host(train.opacity.clone());
            assert!(opacity.iter().sum::<f32>() / opacity.len() as f32 > 0.05);
            for (name, a, b) in [
                ("rgb", host(train.rgb.clone()), infer.rgb),
                ("depth", host(train.depth.clone()), infer.depth),
                ("opacity", opacity, infer.opacity),
                (
                    "dynamic share",
                    host(train.expect(DYNAMIC_SHARE)),
                    infer.dynamic_share,
                ),
            ] {
                assert_close(&format!("t = {time}, {name}"), &a, &b, 1e-5);
            }
        }
    }

    /// Drawing the flow map changes no other channel, and skipping it leaves the map empty: the
    /// drawn map is Σ w·|flow to the next frame| over the dynamic component's blended weights
    /// (the training query's flow through the shared render function).
    #[test]
    fn the_flow_map_is_drawn_only_when_asked_and_changes_nothing_else() {
        let dev = Device::flex();
        let (mut cfg, bounds, _, rays) = untrained_scene(&dev);
        // With the flow network (the video default) and with the shared head's flow.
        for flow_levels in [4, 0] {
            cfg.flow_levels = flow_levels;
            let mut model = NsffModel::new(&cfg, bounds.clone(), vec![0.0, 0.5, 1.0], true, &dev);
            model.occupancy = None;
            model.settings.gate_between = GateBetween::Field;
            let dynamic = model.fields.dynamic.as_ref().unwrap();
            assert_eq!(dynamic.flow.is_some(), flow_levels > 0);
            dynamic.host_params().iter().for_each(|g| g.spread());
            let bg = Some([0.9f32, 0.5, 0.1]);
            let time = 0.5;
            let drawn = render_direct(&model, &rays, time, bg, FlowMap::Draw, &dev).unwrap();
            let skipped = render_direct(&model, &rays, time, bg, FlowMap::Skip, &dev).unwrap();
            assert!(skipped.flow_magnitude.is_empty());
            for (name, a, b) in [
                ("rgb", &drawn.rgb, &skipped.rgb),
                ("depth", &drawn.depth, &skipped.depth),
                ("opacity", &drawn.opacity, &skipped.opacity),
                ("dynamic share", &drawn.dynamic_share, &skipped.dynamic_share),
            ] {
                assert_eq!(a, b, "{name}, flow_levels {flow_levels}");
            }
            let samples = sample_rays(&rays, &bounds, cfg.samples, true, None, None);
            let t = crate::field::time_column(time, samples.num_samples(), &dev);
            let q = query_space_time(&model, dynamic, &rays, &samples, t, &dev);
            let next = host(q.dy.extras.expect(FLOW_NEXT));
            let magnitude: Vec<f32> = next
                .chunks(3)
                .map(|f| (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt())
                .collect();
            let blend = q.st.extras.expect(BLEND) * q.dy.extras.expect(GATE);
            let want = render(
                &rays,
                &samples,
                &[
                    Component::new(q.st.sigma.clone(), q.st.rgb.clone()).blended(blend.clone().neg() + 1.0),
                    Component::new(q.dy.sigma.clone(), q.dy.rgb.clone())
                        .blended(blend)
                        .with(FLOW_MAGNITUDE, tensor(magnitude, 1, &dev)),
                ],
                &Background::from_option(bg),
                render_options(&model),
                &dev,
            );
            let want = host(want.expect(FLOW_MAGNITUDE));
            // The check can fail: an untrained flow's map is not zero.
            assert!(want.iter().any(|m| *m > 1e-4), "a zero flow map tests nothing");
            assert_close(
                &format!("flow map, flow_levels {flow_levels}"),
                &want,
                &drawn.flow_magnitude,
                1e-5,
            );
        }
    }

    /// Between frames the held gate is max(g, frames' gates) half-way and g + w·(max − g) with
    /// w = 1 − |2r − 1| elsewhere, over frames i and i+1 (reach 1) or i−1 … i+2 clipped to the
    /// video (reach 2), the frames' gates read by full queries (not the density-only query the
    /// rule uses); gates at or above the skip threshold stay as they are; on a frame it is the
    /// field's gate, and so is the whole render.
    #[test]
    fn the_held_gate_rises_to_the_neighbouring_frames_gates() {
        let dev = Device::flex();
        let (_, bounds, mut model, rays) = untrained_scene(&dev);
        let dynamic = model.fields.dynamic.as_ref().unwrap();
        // Spread tables, so that the frames' gates differ.
        dynamic.host_params().iter().for_each(|g| g.spread());
        let samples = sample_rays(&rays, &bounds, 8, true, None, None);
        let (pos, dirs) = (samples.positions(&rays), samples.per_sample3(&rays.viewdirs()));
        let gate_at = |t: f32| {
            host(
                query_dynamic(dynamic, tensor(pos.clone(), 3, &dev), t, &dirs)
                    .extras
                    .expect(GATE),
            )
        };
        // The three frames are at 0, 0.5 and 1.
        let frame_gates = [gate_at(0.0), gate_at(0.5), gate_at(1.0)];
        let mut rose = [0.0f32; 2];
        let cases = [
            (0.25f32, 1.0f32, [0..=1, 0..=2]),
            (0.125, 0.5, [0..=1, 0..=2]),
            (0.375, 0.5, [0..=1, 0..=2]),
            (0.75, 1.0, [1..=2, 0..=2]),
            (0.5, 0.0, [1..=2, 0..=2]),
        ];
        let mut skipped = 0;
        for (time, w, read) in cases {
            let own = gate_at(time);
            // The median gate as the threshold, so that both skipped and raised samples occur.
            let mut sorted = own.clone();
            sorted.sort_by(f32::total_cmp);
            let skip = sorted[sorted.len() / 2];
            for (reach, frames) in [1usize, 2].into_iter().zip(read) {
                let mut held = own.clone();
                hold_gate(dynamic, &model.times, time, reach, skip, &pos, &mut held, &dev).unwrap();
                for k in 0..own.len() {
                    let top = frames.clone().map(|f| frame_gates[f][k]).fold(0.0f32, f32::max);
                    let want = if own[k] >= skip {
                        skipped += usize::from(w > 0.0 && top > own[k] + 1e-5);
                        own[k]
                    } else {
                        own[k] + w * (top - own[k]).max(0.0)
                    };
                    assert!(
                        (held[k] - want).abs() <= 1e-6,
                        "t = {time}, reach {reach}, sample {k}: {} vs {want}",
                        held[k]
                    );
                    rose[reach - 1] = rose[reach - 1].max(held[k] - own[k]);
                }
            }
        }
        // The check can fail: the neighbours' gates differ from the in-between one, and the
        // third frame's from the two neighbours'.
        assert!(rose[0] > 1e-5, "the held gate never rose ({rose:?})");
        assert!(
            rose[1] > rose[0] + 1e-5,
            "reach 2 rose no higher than reach 1 ({rose:?})"
        );
        assert!(skipped > 0, "no sample above the threshold would have risen");
        let bg = Some([0.9f32, 0.5, 0.1]);
        let held = render_direct(&model, &rays, 0.5, bg, FlowMap::Skip, &dev).unwrap();
        model.settings.gate_between = GateBetween::Field;
        let field = render_direct(&model, &rays, 0.5, bg, FlowMap::Skip, &dev).unwrap();
        assert_eq!(held.rgb, field.rgb, "on a frame the rule changes nothing");
    }

    /// The static field alone (`nsff eval --static-only`, and a model without a dynamic field)
    /// renders σ_static at full weight: the static pipeline's render of the same field on the
    /// same samples, whatever the blend weight says.
    #[test]
    fn the_static_field_alone_renders_at_full_density() {
        let dev = Device::flex();
        // b_s = 0.5: the combined model would halve the static density.
        let (cfg, bounds, mut model, rays) = untrained_scene(&dev);
        let bg = Some([0.9f32, 0.5, 0.1]);
        let samples = sample_rays(&rays, &bounds, cfg.samples, true, None, None);
        let x = tensor(samples.positions(&rays), 3, &dev);
        let st = model
            .fields
            .static_field
            .query(FieldQuery::new(x, &samples.per_sample3(&rays.viewdirs())));
        let blend = host(st.extras.expect(BLEND));
        assert!(blend.iter().all(|&b| (b - 0.5).abs() < 0.2), "b_s near 0.5");
        let want = render(
            &rays,
            &samples,
            &[Component::new(st.sigma, st.rgb)],
            &Background::from_option(bg),
            render_options(&model),
            &dev,
        );
        let combined = render_direct(&model, &rays, 0.5, bg, FlowMap::Skip, &dev).unwrap();
        model.settings.static_only = true;
        let static_only = render_direct(&model, &rays, 0.5, bg, FlowMap::Skip, &dev).unwrap();
        model.settings.static_only = false;
        model.fields.dynamic = None;
        let no_dynamic = render_direct(&model, &rays, 0.5, bg, FlowMap::Skip, &dev).unwrap();
        for (name, got) in [("--static-only", &static_only), ("no dynamic field", &no_dynamic)] {
            assert_close(name, &host(want.rgb.clone()), &got.rgb, 1e-5);
            assert_close(name, &host(want.opacity.clone()), &got.opacity, 1e-5);
        }
        // The check can fail: the combined model's render differs.
        let gap = host(want.opacity.clone())
            .iter()
            .zip(&combined.opacity)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(gap > 1e-3, "the combined render matched the static one: {gap}");
    }

    /// At a frame time (r = 0) no sample moves and each lands on its own pixel centre, so NSFF's
    /// splatting must reproduce the direct render on the same depth layers (the box holds every
    /// ray's [near, far], no blend skip, no occupancy grid): a check of the projection, the
    /// bilinear splat and its normalisation against the shared compositor. (It caught the splat
    /// counting opacity as 1 − Π(1 − α) where training counts Σ T·(α_dy + α_st), 0.6 % apart.)
    #[test]
    fn splat_at_a_frame_time_is_the_direct_render() {
        let device = Device::flex();
        let mut cfg = NsffConfig::new(Preset::Fast, "unused".into(), Default::default());
        cfg.samples = 32;
        cfg.blend_skip = 0.0;
        let aabb = [[-4.0f32; 3], [4.0; 3]];
        let mut dataset =
            Dataset::blender_object("unused".into(), Format::DNerf, [0.2, 0.3, 0.4], Vec::new());
        dataset.aabb = aabb;
        let bounds = SceneBounds::object(2.0, 6.0, aabb);
        let pose = Pose::look_at([0.3, 0.2, 3.5], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let camera = Camera::new(Intrinsics::centered(20.0, 16, 12), pose);
        let times = vec![0.0f32, 0.5, 1.0];
        let mut model = NsffModel::new(&cfg, bounds, times.clone(), true, &device);
        model.occupancy = None;
        let splat = render_splat(&model, &dataset, &camera, 1.0, &device).unwrap();
        let rays = dataset.rays_for(&camera, 0..16 * 12);
        let direct = render_direct(
            &model,
            &rays,
            times[1],
            dataset.background,
            FlowMap::Skip,
            &device,
        )
        .unwrap();
        let mean_opacity = direct.opacity.iter().sum::<f32>() / direct.opacity.len() as f32;
        assert!(
            mean_opacity > 0.05,
            "the untrained field must absorb some light: {mean_opacity}"
        );
        for (name, a, b) in [
            ("rgb", &splat.rgb, &direct.rgb),
            ("opacity", &splat.opacity, &direct.opacity),
            ("depth", &splat.depth, &direct.depth),
        ] {
            assert_eq!(a.len(), b.len(), "{name}");
            for (i, (x, y)) in a.iter().zip(b.iter()).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-4 * y.abs().max(1.0),
                    "{name}[{i}]: splat {x}, direct {y}"
                );
            }
        }
    }
}
