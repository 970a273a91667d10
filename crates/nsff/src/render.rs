//! Space-time rendering: samples along rays, the combined static + dynamic composite, and
//! NSFF's time interpolation by splatting scene-flow-displaced samples.

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use nerf::renderer::{SceneBounds, tensor};
use nerf_core::composite::{self, RayLayout};
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::rays::{Rays, intersect_aabb};
use nerf_core::sampler::{self, MarchConfig, RaySamples, Spacing, stratified};
use nerf_data::{Camera, Dataset};
use rand::rngs::StdRng;

use crate::config::NsffConfig;
use crate::geometry;
use crate::model::{NsffFields, query_dynamic, query_static};

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
    /// Expected scene-flow magnitude to the next frame along each ray (scene units).
    pub flow_magnitude: Vec<f32>,
    /// Dynamic-field evaluations per ray (what the blend-weight skip saves).
    pub dynamic_per_ray: f64,
    pub samples_per_ray: f64,
}

fn host(t: Tensor<2>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap_or_default()
}

/// Renders rays at normalised time `time` with the combined model, no gradients. Samples whose
/// static blend weight is below `cfg.blend_skip` skip the dynamic field. With an occupancy grid the
/// rays march through it.
#[allow(clippy::too_many_arguments)]
pub fn render_direct(
    fields: &NsffFields,
    rays: &Rays,
    time: f32,
    cfg: &NsffConfig,
    bounds: &SceneBounds,
    occupancy: Option<&OccupancyGrid>,
    background: Option<[f32; 3]>,
    device: &Device,
) -> HostRender {
    let plain = device.clone().inner();
    let fields = fields.valid();
    let march = occupancy.map(|g| (g, &cfg.base.fast.march));
    let samples = sample_rays(rays, bounds, cfg.samples, !bounds.open_far, march, None);
    let s_n = samples.num_samples();
    let mut out = HostRender::default();
    if s_n == 0 {
        let bg = background.unwrap_or([0.0; 3]);
        out.rgb = bg.repeat(rays.len()).to_vec();
        out.depth = vec![0.0; rays.len()];
        out.opacity = vec![0.0; rays.len()];
        out.dynamic_share = vec![0.0; rays.len()];
        out.flow_magnitude = vec![0.0; rays.len()];
        return out;
    }
    let pos = samples.positions(rays);
    let dirs = samples.per_sample3(&rays.viewdirs());
    let st = query_static(
        &fields.static_field,
        tensor(pos.clone(), 3, &plain),
        &dirs,
        bounds.aabb,
    );
    let (sigma_st, rgb_st, mut blend) = (host(st.sigma), host(st.rgb), host(st.blend));
    let mut sigma_dy = vec![0.0f32; s_n];
    let mut rgb_dy = vec![0.0f32; 3 * s_n];
    let mut flow_mag = vec![0.0f32; s_n];
    let mut evaluated = 0usize;
    if let Some(dynamic) = &fields.dynamic {
        // b = b_s·g ≤ b_s: where b_s says static, the dynamic field cannot contribute.
        let keep: Vec<usize> = (0..s_n).filter(|&i| blend[i] >= cfg.blend_skip).collect();
        evaluated = keep.len();
        if !keep.is_empty() {
            let sub_pos: Vec<f32> = keep
                .iter()
                .flat_map(|&i| pos[3 * i..3 * i + 3].to_vec())
                .collect();
            let sub_dirs: Vec<f32> = keep
                .iter()
                .flat_map(|&i| dirs[3 * i..3 * i + 3].to_vec())
                .collect();
            let dy = query_dynamic(
                dynamic,
                tensor(sub_pos, 3, &plain),
                time,
                &sub_dirs,
                bounds.aabb,
                cfg.flow_scale,
            );
            let (s, c, f, g) = (host(dy.sigma), host(dy.rgb), host(dy.flow_next), host(dy.gate));
            for (k, &i) in keep.iter().enumerate() {
                blend[i] *= g[k];
                sigma_dy[i] = s[k];
                rgb_dy[3 * i..3 * i + 3].copy_from_slice(&c[3 * k..3 * k + 3]);
                flow_mag[i] = (f[3 * k].powi(2) + f[3 * k + 1].powi(2) + f[3 * k + 2].powi(2)).sqrt();
            }
        }
    }
    // Marched rays end wherever the grid does: they must not absorb the remaining light.
    let layout = samples.layout(rays, bounds.open_far && march.is_none());
    let comp = composite_combined(
        &sigma_st, &rgb_st, &blend, &sigma_dy, &rgb_dy, &flow_mag, &samples.t, &layout, &plain,
    );
    let r = rays.len();
    let bg = background.unwrap_or([0.0; 3]);
    for i in 0..r {
        let row = &comp[COMBINED * i..COMBINED * (i + 1)];
        out.rgb.extend((0..3).map(|c| row[c] + (1.0 - row[6]) * bg[c]));
        out.depth.push(row[3]);
        out.dynamic_share.push(row[4]);
        out.flow_magnitude.push(row[5]);
        out.opacity.push(row[6]);
    }
    out.samples_per_ray = s_n as f64 / r as f64;
    out.dynamic_per_ray = evaluated as f64 / r as f64;
    out
}

/// Channels of [`composite_combined`]'s output per ray.
const COMBINED: usize = 7;

/// The combined composite of host arrays: `[R, 7]` — rgb, depth, dynamic share, scene-flow
/// magnitude, opacity. Per component the features are (rgb, t, is-dynamic, |flow|).
#[allow(clippy::too_many_arguments)]
fn composite_combined(
    sigma_st: &[f32],
    rgb_st: &[f32],
    blend: &[f32],
    sigma_dy: &[f32],
    rgb_dy: &[f32],
    flow_mag: &[f32],
    t: &[f32],
    layout: &RayLayout,
    device: &Device,
) -> Vec<f32> {
    let s_n = sigma_st.len();
    let mut sigma = Vec::with_capacity(2 * s_n);
    let mut feats = Vec::with_capacity(12 * s_n);
    let mut blend2 = Vec::with_capacity(2 * s_n);
    for i in 0..s_n {
        sigma.extend([sigma_st[i], sigma_dy[i]]);
        feats.extend_from_slice(&rgb_st[3 * i..3 * i + 3]);
        feats.extend([t[i], 0.0, 0.0]);
        feats.extend_from_slice(&rgb_dy[3 * i..3 * i + 3]);
        feats.extend([t[i], 1.0, flow_mag[i]]);
        blend2.extend([1.0 - blend[i], blend[i]]);
    }
    let out = composite::composite(
        tensor(sigma, 2, device),
        tensor(feats, 12, device),
        Some(tensor(blend2, 2, device)),
        layout,
        0.0,
    );
    host(out)
}

/// Renders a whole camera at a continuous frame position `tau` (frame index units). Between
/// frames i and i+1 (r = tau − i), NSFF's splatting: the samples of both neighbouring times are
/// moved along their scene flow by r and 1 − r, projected into the camera, and splatted layer by
/// layer (samples share depths across rays, so layer k is a fronto-parallel slice), then
/// composited front to back. `times[i]` is frame i's normalised time.
#[allow(clippy::too_many_arguments)]
pub fn render_splat(
    fields: &NsffFields,
    dataset: &Dataset,
    camera: &Camera,
    tau: f32,
    times: &[f32],
    cfg: &NsffConfig,
    bounds: &SceneBounds,
    occupancy: Option<&OccupancyGrid>,
    device: &Device,
) -> HostRender {
    let plain = device.clone().inner();
    let rays = dataset.rays_for(camera, 0..camera.intrinsics.num_pixels() as u32);
    let last = times.len() - 1;
    let i = (tau.floor().max(0.0) as usize).min(last.saturating_sub(1));
    let r = (tau - i as f32).clamp(0.0, 1.0);
    let Some(dynamic) = fields.dynamic.as_ref().map(|d| d.valid()) else {
        return render_direct(
            fields,
            &rays,
            times[i],
            cfg,
            bounds,
            occupancy,
            dataset.background,
            device,
        );
    };
    let st_field = fields.static_field.valid();
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let n_rays = rays.len();
    // Same depths for every ray: layers are slices of constant camera depth (or NDC t).
    let s = cfg.samples;
    // Not clipped to the box: every ray needs all `s` layers.
    let samples = sample_rays(&rays, bounds, s, false, None, None);
    let pos = samples.positions(&rays);
    let dirs = samples.per_sample3(&rays.viewdirs());
    let layout = samples.layout(&rays, bounds.open_far);
    let x = tensor(pos.clone(), 3, &plain);
    let st = query_static(&st_field, x.clone(), &dirs, bounds.aabb);
    let (mut sigma_st, rgb_st, blend) = (host(st.sigma), host(st.rgb), host(st.blend));
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
        let dy = query_dynamic(
            &dynamic,
            x.clone(),
            times[frame],
            &dirs,
            bounds.aabb,
            cfg.flow_scale,
        );
        // Move towards the target time: from frame i forward by r, from i+1 backward by 1 − r.
        let (flow, amount) = if m == 0 {
            (dy.flow_next.clone(), r)
        } else {
            (dy.flow_prev.clone(), 1.0 - r)
        };
        let moved = x.clone() + flow * amount;
        let world = match &dataset.ndc {
            Some(ndc) => geometry::ndc_to_world(moved, ndc),
            None => moved,
        };
        let uv = host(geometry::project(world, camera, &plain));
        let mut sigma_dy = host(dy.sigma);
        for (sg, &ok) in sigma_dy.iter_mut().zip(&inside) {
            if !ok {
                *sg = 0.0;
            }
        }
        // This time's blend, b_s·g.
        let b: Vec<f32> = blend.iter().zip(host(dy.gate)).map(|(b, g)| b * g).collect();
        per_time.push((sigma_dy, host(dy.rgb), uv, b));
    }
    let bg = dataset.background.unwrap_or([0.0; 3]);
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
    for ray in 0..n_rays {
        for c in 0..3 {
            rgb[3 * ray + c] += (1.0 - acc[ray]) * bg[c];
        }
    }
    HostRender {
        rgb,
        depth,
        opacity: acc,
        dynamic_share: vec![0.0; n_rays],
        flow_magnitude: vec![0.0; n_rays],
        dynamic_per_ray: 2.0 * s as f64,
        samples_per_ray: s as f64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf::config::Preset;
    use nerf_data::{Format, Intrinsics, Pose};

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
        let fields = NsffFields::new(&cfg, true, &device);
        let aabb = [[-4.0f32; 3], [4.0; 3]];
        let mut dataset =
            Dataset::blender_object("unused".into(), Format::DNerf, [0.2, 0.3, 0.4], Vec::new());
        dataset.aabb = aabb;
        let bounds = SceneBounds {
            near: 2.0,
            far: 6.0,
            aabb,
            open_far: false,
        };
        let pose = Pose::look_at([0.3, 0.2, 3.5], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let camera = Camera::new(Intrinsics::centered(20.0, 16, 12), pose);
        let times = [0.0f32, 0.5, 1.0];
        let splat = render_splat(
            &fields, &dataset, &camera, 1.0, &times, &cfg, &bounds, None, &device,
        );
        let rays = dataset.rays_for(&camera, 0..16 * 12);
        let direct = render_direct(
            &fields,
            &rays,
            times[1],
            &cfg,
            &bounds,
            None,
            dataset.background,
            &device,
        );
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
