//! The one render function: samples along rays plus per-sample field outputs become pixels.
//!
//! Every image the models produce, in training and at inference, comes from [`render`]: a
//! static NeRF is one [`Component`]; NSFF's combined render is a static and a dynamic component
//! blended per sample; its dynamic-only and warped renders are one component with extra channels.
//! [`render`] owns compositing (the fused kernel of [`crate::composite`]), the background and the
//! open-far rule, so that these cannot drift apart between renders.
//!
//! With K components at sample s, interval δ_s (distance units), density σ_{s,k} and share
//! β_{s,k} (1 when absent): α_{s,k} = β_{s,k}(1 − e^{−σ_{s,k} δ_s}), T_s = Π_{j<s} Π_k (1 − α_{j,k}),
//! weight w_{s,k} = T_s α_{s,k}. Every output channel c is Σ_{s,k} w_{s,k} f_{s,k,c}, where a
//! component without channel c contributes 0; `opacity` = Σ w; `depth` = Σ w·t (the expected ray
//! parameter, not divided by the opacity); `rgb` adds (1 − opacity)·background.

use burn::tensor::{Device, Tensor, TensorData};

use crate::composite::{RayLayout, composite};
use crate::rays::Rays;
use crate::sampler::RaySamples;

/// One density component's per-sample outputs (`S` samples).
#[derive(Clone, Debug)]
pub struct Component {
    /// `[S, 1]`, ≥ 0.
    pub sigma: Tensor<2>,
    /// `[S, 3]`, or `None` for a render of extra channels only.
    pub rgb: Option<Tensor<2>>,
    /// `[S, 1]` share β of this component (NSFF's blend), or `None` for 1.
    pub blend: Option<Tensor<2>>,
    /// Named `[S, C]` channels composited into the output's extras.
    pub extras: Vec<(&'static str, Tensor<2>)>,
}

impl Component {
    pub fn new(sigma: Tensor<2>, rgb: Tensor<2>) -> Self {
        Component {
            sigma,
            rgb: Some(rgb),
            blend: None,
            extras: Vec::new(),
        }
    }

    /// A component that composites only `extras` (no colour).
    pub fn channels_only(sigma: Tensor<2>) -> Self {
        Component {
            sigma,
            rgb: None,
            blend: None,
            extras: Vec::new(),
        }
    }

    pub fn blended(mut self, blend: Tensor<2>) -> Self {
        self.blend = Some(blend);
        self
    }

    pub fn with(mut self, name: &'static str, channels: Tensor<2>) -> Self {
        self.extras.push((name, channels));
        self
    }
}

/// What lies behind the scene.
#[allow(clippy::large_enum_variant)] // one per render call; boxing the tensor would not pay
#[derive(Clone, Debug)]
pub enum Background {
    /// Nothing is added (black, or scenes whose far end absorbs all light).
    None,
    /// One colour for every ray.
    Color([f32; 3]),
    /// `[R, 3]`, one colour per ray (random backgrounds while training on RGBA images).
    PerRay(Tensor<2>),
}

impl Background {
    pub fn from_option(color: Option<[f32; 3]>) -> Self {
        color.map_or(Background::None, Background::Color)
    }

    fn tensor(&self, rays: usize, device: &Device) -> Option<Tensor<2>> {
        match self {
            Background::None => None,
            Background::Color(c) => Some(host_tensor(c.repeat(rays), 3, device)),
            Background::PerRay(t) => Some(t.clone()),
        }
    }
}

/// How to composite.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderOptions {
    /// Each ray's last interval absorbs the remaining light (stratified samples up to the far
    /// bound of a real scene without background; never for marched samples, which end wherever
    /// the occupancy grid does).
    pub open_far: bool,
    /// Transmittance below which a ray stops (0: never).
    pub stop_eps: f32,
}

/// Pixels of `R` rays.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// `[R, 3]`, background included (or zeros when no component has colour).
    pub rgb: Tensor<2>,
    /// `[R, 1]` Σ w·t.
    pub depth: Tensor<2>,
    /// `[R, 1]` Σ w.
    pub opacity: Tensor<2>,
    /// Extra channels by name, `[R, C]` each.
    pub extras: Vec<(&'static str, Tensor<2>)>,
    /// The compositing layout (interval lengths as distances) the weights were computed on.
    pub layout: RayLayout,
    /// Samples composited (field evaluations behind this render).
    pub samples: usize,
}

impl RenderOutput {
    pub fn extra(&self, name: &str) -> Option<&Tensor<2>> {
        self.extras.iter().find(|(n, _)| *n == name).map(|(_, t)| t)
    }

    /// The channel `name`, which the caller asked for in a component.
    pub fn expect(&self, name: &str) -> Tensor<2> {
        self.extra(name)
            .cloned()
            .unwrap_or_else(|| panic!("render has no '{name}' channel"))
    }
}

/// Host data → `[n, w]` tensor.
pub fn host_tensor(data: Vec<f32>, w: usize, device: &Device) -> Tensor<2> {
    let n = data.len() / w.max(1);
    Tensor::from_data(TensorData::new(data, [n, w]), device)
}

/// Composites `components` (each with `samples.num_samples()` rows) along `rays`.
pub fn render(
    rays: &Rays,
    samples: &RaySamples,
    components: &[Component],
    background: &Background,
    options: RenderOptions,
    device: &Device,
) -> RenderOutput {
    let r_n = rays.len();
    let layout = samples.layout(rays, options.open_far);
    // Extra channel names and widths, in first-seen order.
    let mut names: Vec<(&'static str, usize)> = Vec::new();
    for comp in components {
        for (name, t) in &comp.extras {
            if !names.iter().any(|(n, _)| n == name) {
                names.push((name, t.dims()[1]));
            }
        }
    }
    let with_rgb = components.iter().any(|c| c.rgb.is_some());
    let rgb_w = if with_rgb { 3 } else { 0 };
    let channels = rgb_w + 1 + names.iter().map(|(_, w)| w).sum::<usize>();
    let bg = background.tensor(r_n, device);
    let zeros = |w: usize| Tensor::<2>::zeros([r_n, w], device);
    if samples.num_samples() == 0 || components.is_empty() {
        let opacity = zeros(1);
        return RenderOutput {
            rgb: bg.unwrap_or_else(|| zeros(3)),
            depth: zeros(1),
            opacity,
            extras: names.iter().map(|&(n, w)| (n, zeros(w))).collect(),
            layout,
            samples: 0,
        };
    }
    let s_n = samples.num_samples();
    let t_col = host_tensor(samples.t.clone(), 1, device);
    let mut feats = Vec::new();
    for comp in components {
        if with_rgb {
            feats.push(
                comp.rgb
                    .clone()
                    .unwrap_or_else(|| Tensor::zeros([s_n, 3], device)),
            );
        }
        feats.push(t_col.clone());
        for &(name, w) in &names {
            let own = comp.extras.iter().find(|(n, _)| *n == name);
            feats.push(own.map_or_else(|| Tensor::zeros([s_n, w], device), |(_, t)| t.clone()));
        }
    }
    let sigma = Tensor::cat(components.iter().map(|c| c.sigma.clone()).collect(), 1);
    let blend = components.iter().any(|c| c.blend.is_some()).then(|| {
        Tensor::cat(
            components
                .iter()
                .map(|c| c.blend.clone().unwrap_or_else(|| Tensor::ones([s_n, 1], device)))
                .collect(),
            1,
        )
    });
    // Output columns: the channels, then opacity.
    let out = composite(sigma, Tensor::cat(feats, 1), blend, &layout, options.stop_eps);
    let col = |a: usize, b: usize| out.clone().slice([0..r_n, a..b]);
    let opacity = col(channels, channels + 1);
    let rgb = if with_rgb { col(0, 3) } else { zeros(3) };
    let rgb = match bg {
        Some(bg) => rgb + (opacity.clone().neg() + 1.0) * bg,
        None => rgb,
    };
    let mut at = rgb_w + 1;
    let extras = names
        .iter()
        .map(|&(n, w)| {
            at += w;
            (n, col(at - w, at))
        })
        .collect();
    RenderOutput {
        rgb,
        depth: col(rgb_w, rgb_w + 1),
        opacity,
        extras,
        layout,
        samples: s_n,
    }
}

/// Adds a background behind host-composited pixels: `rgb` `[R·3]` premultiplied colour,
/// `opacity` `[R]`. For renders composited outside [`render`] (NSFF's splatting of layers).
pub fn add_background_host(rgb: &mut [f32], opacity: &[f32], background: Option<[f32; 3]>) {
    let Some(bg) = background else {
        return;
    };
    for (px, a) in rgb.chunks_exact_mut(3).zip(opacity) {
        for c in 0..3 {
            px[c] += (1.0 - a) * bg[c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::readback::host;

    /// Two rays through two blended components with an extra channel only the second has,
    /// against the compositing formula recomputed in f64.
    #[test]
    fn render_matches_the_f64_formula_with_blends_extras_and_background() {
        let dev = Device::flex();
        let mut rays = Rays::with_capacity(2);
        rays.push([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]);
        rays.push([0.0, 0.0, 0.0], [0.3, 0.6, -1.0]);
        let mut samples = RaySamples::with_rays(2);
        for (a, b) in [(1.0, 1.5), (1.5, 2.2), (2.2, 3.0)] {
            samples.push(a, b, 0.5 * (a + b));
        }
        samples.finish_ray();
        for (a, b) in [(2.0, 2.5), (2.5, 4.0)] {
            samples.push(a, b, 0.5 * (a + b));
        }
        samples.finish_ray();
        let s_n = 5;
        let sig = [[0.3f32, 2.0, 0.1, 5.0, 0.0], [1.0, 0.2, 3.0, 0.0, 7.0]];
        let rgb: Vec<Vec<f32>> = (0..2)
            .map(|k| {
                (0..3 * s_n)
                    .map(|i| ((i * 7 + k * 3) % 11) as f32 / 10.0)
                    .collect()
            })
            .collect();
        let beta = [0.3f32, 0.9, 0.5, 0.1, 0.6];
        let flow: Vec<f32> = (0..2 * s_n).map(|i| i as f32 * 0.25 - 1.0).collect();
        let comps = [
            Component::new(
                host_tensor(sig[0].to_vec(), 1, &dev),
                host_tensor(rgb[0].clone(), 3, &dev),
            )
            .blended(host_tensor(beta.iter().map(|b| 1.0 - b).collect(), 1, &dev)),
            Component::new(
                host_tensor(sig[1].to_vec(), 1, &dev),
                host_tensor(rgb[1].clone(), 3, &dev),
            )
            .blended(host_tensor(beta.to_vec(), 1, &dev))
            .with("flow", host_tensor(flow.clone(), 2, &dev)),
        ];
        let bg = [0.2f32, 0.5, 1.0];
        let out = render(
            &rays,
            &samples,
            &comps,
            &Background::Color(bg),
            RenderOptions::default(),
            &dev,
        );
        let (rgb_o, depth, opac, fl) = (
            host(out.rgb.clone()),
            host(out.depth.clone()),
            host(out.opacity.clone()),
            host(out.expect("flow")),
        );
        for r in 0..2 {
            let d = rays.direction(r);
            let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() as f64;
            let mut tr = 1.0f64;
            let (mut c, mut dep, mut acc, mut f) = ([0.0f64; 3], 0.0, 0.0, [0.0f64; 2]);
            for s in samples.range(r) {
                let delta = (samples.t_end[s] - samples.t_start[s]) as f64 * norm;
                let b = [1.0 - beta[s] as f64, beta[s] as f64];
                let a: Vec<f64> = (0..2)
                    .map(|k| b[k] * (1.0 - (-(sig[k][s] as f64) * delta).exp()))
                    .collect();
                for k in 0..2 {
                    let w = tr * a[k];
                    for ch in 0..3 {
                        c[ch] += w * rgb[k][3 * s + ch] as f64;
                    }
                    dep += w * samples.t[s] as f64;
                    acc += w;
                    if k == 1 {
                        f[0] += w * flow[2 * s] as f64;
                        f[1] += w * flow[2 * s + 1] as f64;
                    }
                }
                tr *= (1.0 - a[0]) * (1.0 - a[1]);
            }
            let close = |x: f32, y: f64| (x as f64 - y).abs() < 1e-5;
            for ch in 0..3 {
                assert!(close(rgb_o[3 * r + ch], c[ch] + (1.0 - acc) * bg[ch] as f64));
            }
            assert!(close(depth[r], dep) && close(opac[r], acc));
            assert!(close(fl[2 * r], f[0]) && close(fl[2 * r + 1], f[1]));
        }
    }

    /// No samples: background colour, zero opacity and depth, zero extras.
    #[test]
    fn empty_samples_give_the_background() {
        let dev = Device::flex();
        let mut rays = Rays::with_capacity(1);
        rays.push([0.0; 3], [0.0, 0.0, -1.0]);
        let mut samples = RaySamples::with_rays(1);
        samples.finish_ray();
        let comp =
            Component::channels_only(Tensor::zeros([0, 1], &dev)).with("x", Tensor::zeros([0, 2], &dev));
        let out = render(
            &rays,
            &samples,
            &[comp],
            &Background::Color([0.1, 0.2, 0.3]),
            RenderOptions::default(),
            &dev,
        );
        assert_eq!(host(out.expect("x")), vec![0.0, 0.0]);
        assert_eq!(host(out.rgb), vec![0.1, 0.2, 0.3]);
        assert_eq!(host(out.opacity), vec![0.0]);
    }
}
