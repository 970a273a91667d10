//! A local web viewer for a trained run: one HTTP server on 127.0.0.1 that serves one page
//! (everything it needs comes from this binary) and renders frames on request. The page asks
//! for a coarse frame while the camera moves and a full one once it rests, one request at a
//! time, so it stays responsive on a 2-core CPU.
//!
//! API: `GET /` the page; `GET /info` JSON (start camera, image size, channels, frame times);
//! `GET /frame?azimuth=&elevation=&distance=&width=&height=&channel=&time=` a PNG. Anything
//! else is refused with a 4xx status and a message; nothing a client sends can panic the server.

use std::collections::HashMap;
use std::io::Cursor;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nerf_data::camera::{Camera, Intrinsics};
use nerf_data::{Dataset, Image};
use tiny_http::{Header, Method, Request, Response, Server};

use burn::tensor::Device;

use crate::error::{ModelError, Result};
use crate::field::FieldModule;
use crate::model::StaticModel;
use crate::render::{OrbitFrame, depth_image};

/// The page, served as is.
const PAGE: &str = include_str!("index.html");

/// Largest frame side a client may ask for.
pub const MAX_SIDE: u32 = 1024;

/// What the viewer needs of a trained model.
pub trait ViewModel {
    /// Channels it can show: "rgb", "depth", "opacity" and, for NSFF, "dynamic" and "flow".
    fn channels(&self) -> Vec<&'static str>;
    /// Normalised times of the training frames; empty for a static model (no time slider).
    fn times(&self) -> Vec<f32>;
    /// Renders `channel` of `camera` at `time` as an RGB or grey image in [0, 1].
    fn render(&self, camera: &Camera, time: f32, channel: &str) -> Result<Image>;
}

/// Where the viewer's camera moves: an orbit about the scene, starting at the first training
/// camera, with that camera's intrinsics (scaled to each requested size).
#[derive(Clone, Debug)]
pub struct ViewerScene {
    pub orbit: OrbitFrame,
    pub intrinsics: Intrinsics,
    /// (azimuth, elevation, distance) of the first training camera.
    pub start: (f64, f64, f64),
    pub title: String,
}

impl ViewerScene {
    pub fn of(dataset: &Dataset, title: &str) -> Self {
        let orbit = OrbitFrame::of(dataset);
        let first = &dataset.views[dataset.train.first().copied().unwrap_or(0)].camera;
        ViewerScene {
            orbit,
            intrinsics: first.intrinsics,
            start: orbit.coordinates(first.pose.translation),
            title: title.to_string(),
        }
    }

    /// The camera a frame request describes.
    pub fn camera(&self, q: &FrameQuery) -> Camera {
        let k = self.intrinsics;
        let (sx, sy) = (q.width as f64 / k.width as f64, q.height as f64 / k.height as f64);
        let intrinsics = Intrinsics {
            fx: k.fx * sx,
            fy: k.fy * sy,
            cx: k.cx * sx,
            cy: k.cy * sy,
            width: q.width,
            height: q.height,
        };
        Camera::new(intrinsics, self.orbit.pose(q.azimuth, q.elevation, q.distance))
    }
}

/// A parsed `/frame` request.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameQuery {
    pub azimuth: f64,
    pub elevation: f64,
    pub distance: f64,
    pub width: u32,
    pub height: u32,
    pub channel: String,
    pub time: f32,
}

impl FrameQuery {
    /// Parses the query string of `/frame`; Err: what is wrong, for a 400 answer.
    pub fn parse(query: &str, channels: &[&str]) -> std::result::Result<Self, String> {
        let params: HashMap<&str, &str> = query
            .split('&')
            .filter(|p| !p.is_empty())
            .map(|p| p.split_once('=').unwrap_or((p, "")))
            .collect();
        let number = |key: &str| -> std::result::Result<f64, String> {
            let raw = params
                .get(key)
                .ok_or_else(|| format!("missing parameter '{key}'"))?;
            let v: f64 = raw
                .parse()
                .map_err(|_| format!("'{key}' is not a number: {raw:?}"))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("'{key}' is not finite"))
            }
        };
        let side = |key: &str| -> std::result::Result<u32, String> {
            let v = number(key)?;
            if v.fract() == 0.0 && (8.0..=MAX_SIDE as f64).contains(&v) {
                Ok(v as u32)
            } else {
                Err(format!("'{key}' must be a whole number from 8 to {MAX_SIDE}"))
            }
        };
        let distance = number("distance")?;
        if distance <= 0.0 {
            return Err("'distance' must be positive".into());
        }
        let channel = params.get("channel").copied().unwrap_or("rgb");
        if !channels.contains(&channel) {
            return Err(format!(
                "unknown channel {channel:?} (this run has {})",
                channels.join(", ")
            ));
        }
        let time = match params.get("time") {
            Some(_) => number("time")?,
            None => 0.0,
        };
        if !(0.0..=1.0).contains(&time) {
            return Err("'time' must be in [0, 1]".into());
        }
        let limit = 89f64.to_radians();
        Ok(FrameQuery {
            azimuth: number("azimuth")?,
            elevation: number("elevation")?.clamp(-limit, limit),
            distance,
            width: side("width")?,
            height: side("height")?,
            channel: channel.to_string(),
            time: time as f32,
        })
    }
}

/// A running viewer's address and its stop switch (set by Ctrl-C, or by tests).
pub struct Viewer {
    server: Server,
    stop: Arc<AtomicBool>,
}

impl Viewer {
    /// Binds `host:port` (port 0: any free port).
    pub fn bind(host: &str, port: u16) -> Result<Self> {
        let server = Server::http((host, port)).map_err(|e| {
            ModelError::usage(format!("{host}:{port}"), format!("cannot start the viewer: {e}"))
        })?;
        Ok(Viewer {
            server,
            stop: Arc::new(AtomicBool::new(false)),
        })
    }

    /// `http://host:port/`.
    pub fn url(&self) -> String {
        match self.server.server_addr().to_ip() {
            Some(addr) => format!("http://{addr}/"),
            None => "(unknown address)".into(),
        }
    }

    /// A switch that stops [`Viewer::serve`] within a fraction of a second.
    pub fn stop_switch(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// Answers requests until the stop switch is set.
    pub fn serve(&self, model: &dyn ViewModel, scene: &ViewerScene) {
        let info = info_json(model, scene);
        while !self.stop.load(Ordering::Relaxed) {
            match self.server.recv_timeout(Duration::from_millis(200)) {
                Ok(Some(request)) => answer(request, model, scene, &info),
                Ok(None) => {}
                Err(e) => eprintln!("viewer: {e}"),
            }
        }
    }
}

fn info_json(model: &dyn ViewModel, scene: &ViewerScene) -> String {
    let (azimuth, elevation, distance) = scene.start;
    serde_json::json!({
        "title": scene.title,
        "width": scene.intrinsics.width,
        "height": scene.intrinsics.height,
        "start": { "azimuth": azimuth, "elevation": elevation, "distance": distance },
        "channels": model.channels(),
        "times": model.times(),
        "max_side": MAX_SIDE,
    })
    .to_string()
}

/// A response header; names and values are constants or numbers formatted here (ASCII).
fn header(name: &str, value: &str) -> Header {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).expect("ASCII header")
}

fn text(status: u16, msg: &str) -> Response<Cursor<Vec<u8>>> {
    Response::from_string(format!("{msg}\n"))
        .with_status_code(status)
        .with_header(header("Content-Type", "text/plain; charset=utf-8"))
}

/// Answers one request; errors go back to the client, and a client that hung up is ignored.
fn answer(request: Request, model: &dyn ViewModel, scene: &ViewerScene, info: &str) {
    let url = request.url().to_string();
    let (path, query) = url.split_once('?').unwrap_or((&url, ""));
    let response = if *request.method() != Method::Get {
        text(405, "only GET is served")
    } else {
        match path {
            "/" | "/index.html" => {
                Response::from_string(PAGE).with_header(header("Content-Type", "text/html; charset=utf-8"))
            }
            "/info" => Response::from_string(info).with_header(header("Content-Type", "application/json")),
            "/frame" => frame(query, model, scene),
            _ => text(404, &format!("no such page: {path}")),
        }
    };
    let _ = request.respond(response);
}

fn frame(query: &str, model: &dyn ViewModel, scene: &ViewerScene) -> Response<Cursor<Vec<u8>>> {
    let q = match FrameQuery::parse(query, &model.channels()) {
        Ok(q) => q,
        Err(msg) => return text(400, &msg),
    };
    let start = Instant::now();
    let png = model
        .render(&scene.camera(&q), q.time, &q.channel)
        .and_then(|img| encode_png(&img));
    match png {
        Ok(bytes) => Response::from_data(bytes)
            .with_header(header("Content-Type", "image/png"))
            .with_header(header("Cache-Control", "no-store"))
            .with_header(header(
                "X-Render-Ms",
                &format!("{:.1}", start.elapsed().as_secs_f64() * 1e3),
            )),
        Err(e) => text(500, &format!("render failed: {e}")),
    }
}

/// PNG bytes of an RGB or grey image in [0, 1].
pub fn encode_png(img: &Image) -> Result<Vec<u8>> {
    let color = match img.channels {
        1 => image::ColorType::L8,
        _ => image::ColorType::Rgb8,
    };
    let mut out = Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        &img.to_u8(),
        img.width,
        img.height,
        color,
        image::ImageFormat::Png,
    )
    .map_err(|e| ModelError::usage("frame.png", format!("cannot encode the frame: {e}")))?;
    Ok(out.into_inner())
}

/// The static model in the viewer: colour, depth and opacity through the one render path.
pub struct StaticView<'a, F: FieldModule> {
    pub model: &'a StaticModel<F>,
    pub dataset: &'a Dataset,
    pub device: &'a Device,
}

impl<F: FieldModule> ViewModel for StaticView<'_, F> {
    fn channels(&self) -> Vec<&'static str> {
        vec!["rgb", "depth", "opacity"]
    }

    fn times(&self) -> Vec<f32> {
        Vec::new()
    }

    fn render(&self, camera: &Camera, _time: f32, channel: &str) -> Result<Image> {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let rays = self.dataset.rays_for(camera, 0..w * h);
        let r = self
            .model
            .render_rays(&rays, self.dataset.background, self.device)?;
        Ok(match channel {
            "depth" => depth_image(w, h, &r.depth, &r.opacity, None),
            "opacity" => Image::from_data(w, h, 1, r.opacity),
            _ => Image::from_data(w, h, 3, r.rgb),
        })
    }
}

/// Runs the viewer until Ctrl-C: prints the URL, then serves.
pub fn run(model: &dyn ViewModel, scene: &ViewerScene, host: &str, port: u16) -> Result<()> {
    let viewer = Viewer::bind(host, port)?;
    let stop = viewer.stop_switch();
    ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
        .map_err(|e| ModelError::usage("viewer", format!("cannot catch Ctrl-C: {e}")))?;
    println!("viewer at {} (Ctrl-C stops it)", viewer.url());
    viewer.serve(model, scene);
    println!("viewer stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const CH: [&str; 3] = ["rgb", "depth", "opacity"];

    #[test]
    fn frame_queries_parse_and_bad_ones_say_why() {
        let q = FrameQuery::parse(
            "azimuth=0.5&elevation=0.2&distance=4&width=64&height=48&channel=depth",
            &CH,
        )
        .unwrap();
        assert_eq!(
            (q.width, q.height, q.channel.as_str(), q.time),
            (64, 48, "depth", 0.0)
        );
        for (query, why) in [
            (
                "azimuth=0&elevation=0&distance=4&width=64",
                "missing parameter 'height'",
            ),
            (
                "azimuth=x&elevation=0&distance=4&width=64&height=48",
                "'azimuth' is not a number",
            ),
            (
                "azimuth=NaN&elevation=0&distance=4&width=64&height=48",
                "not finite",
            ),
            (
                "azimuth=0&elevation=0&distance=-1&width=64&height=48",
                "'distance' must be positive",
            ),
            (
                "azimuth=0&elevation=0&distance=4&width=5000&height=48",
                "'width' must be a whole number",
            ),
            (
                "azimuth=0&elevation=0&distance=4&width=64.5&height=48",
                "'width' must be a whole number",
            ),
            (
                "azimuth=0&elevation=0&distance=4&width=64&height=48&channel=flow",
                "unknown channel",
            ),
            (
                "azimuth=0&elevation=0&distance=4&width=64&height=48&time=2",
                "'time' must be in [0, 1]",
            ),
        ] {
            let err = FrameQuery::parse(query, &CH).unwrap_err();
            assert!(err.contains(why), "{query}: {err}");
        }
        // Elevation is held short of the poles (the look-at frame degenerates there).
        let q = FrameQuery::parse("azimuth=0&elevation=3&distance=1&width=8&height=8", &CH).unwrap();
        assert!(q.elevation < std::f64::consts::FRAC_PI_2);
    }
}
