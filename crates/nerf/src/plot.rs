//! Small PNG line plots (training curves, benchmark reports) drawn with a built-in bitmap font,
//! so plotting needs no system fonts or extra crates.

use std::path::Path;

use nerf_data::Image;
use nerf_data::error::Result;

use crate::logging::MetricsLog;

/// One named line.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub color: [u8; 3],
}

pub const PALETTE: [[u8; 3]; 6] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
];

/// A chart: title, axis labels, series; optional log-scale x.
#[derive(Clone, Debug)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub log_x: bool,
}

const W: usize = 800;
const H: usize = 500;
const LEFT: usize = 70;
const RIGHT: usize = 20;
const TOP: usize = 40;
const BOTTOM: usize = 60;

impl Chart {
    pub fn save(&self, path: &Path) -> Result<()> {
        let mut c = Canvas::new(W, H);
        let pts: Vec<(f64, f64)> = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(|(x, y)| x.is_finite() && y.is_finite() && (!self.log_x || *x > 0.0))
            .collect();
        let tx = |x: f64| if self.log_x { x.log10() } else { x };
        let (mut x0, mut x1) = pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(tx(p.0)), b.max(tx(p.0)))
        });
        let (mut y0, mut y1) = pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
        if pts.is_empty() {
            (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
        }
        if x1 - x0 < 1e-12 {
            x1 = x0 + 1.0;
        }
        let pad = ((y1 - y0) * 0.05).max(1e-6);
        (y0, y1) = (y0 - pad, y1 + pad);
        let (pw, ph) = ((W - LEFT - RIGHT) as f64, (H - TOP - BOTTOM) as f64);
        let px = |x: f64| LEFT as f64 + (tx(x) - x0) / (x1 - x0) * pw;
        let py = |y: f64| TOP as f64 + (1.0 - (y - y0) / (y1 - y0)) * ph;
        // Grid, ticks and labels.
        for k in 0..=5 {
            let fy = y0 + (y1 - y0) * k as f64 / 5.0;
            let yy = py(fy) as i64;
            c.hline(LEFT as i64, (W - RIGHT) as i64, yy, [225, 225, 225]);
            c.text(4, yy - 3, &fmt_tick(fy), [0, 0, 0]);
            let fx = x0 + (x1 - x0) * k as f64 / 5.0;
            let xx = (LEFT as f64 + pw * k as f64 / 5.0) as i64;
            c.vline(xx, TOP as i64, (H - BOTTOM) as i64, [225, 225, 225]);
            let label = fmt_tick(if self.log_x { 10f64.powf(fx) } else { fx });
            c.text(
                xx - 3 * label.len() as i64,
                (H - BOTTOM + 8) as i64,
                &label,
                [0, 0, 0],
            );
        }
        c.rect(
            LEFT as i64,
            TOP as i64,
            (W - RIGHT) as i64,
            (H - BOTTOM) as i64,
            [0, 0, 0],
        );
        c.text(
            (W / 2) as i64 - 3 * self.title.len() as i64,
            12,
            &self.title,
            [0, 0, 0],
        );
        c.text(
            (W / 2) as i64 - 3 * self.x_label.len() as i64,
            (H - 24) as i64,
            &self.x_label,
            [0, 0, 0],
        );
        c.text(4, (TOP - 14) as i64, &self.y_label, [0, 0, 0]);
        for (i, s) in self.series.iter().enumerate() {
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite() && (!self.log_x || *x > 0.0))
                .collect();
            for w in pts.windows(2) {
                c.line(px(w[0].0), py(w[0].1), px(w[1].0), py(w[1].1), s.color);
            }
            for p in &pts {
                if pts.len() < 40 {
                    c.dot(px(p.0) as i64, py(p.1) as i64, s.color);
                }
            }
            // Legend.
            let ly = (TOP + 10 + 12 * i) as i64;
            c.hline((LEFT + 10) as i64, (LEFT + 30) as i64, ly + 3, s.color);
            c.text((LEFT + 36) as i64, ly, &s.name, [0, 0, 0]);
        }
        c.into_image().save_png(path)
    }
}

fn fmt_tick(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-2..1e5).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

/// Training PSNR (smoothed) and test PSNR against training time from `metrics.jsonl`.
pub fn training_curve(metrics: &Path, out: &Path) -> Result<()> {
    let records = MetricsLog::read(metrics)?;
    let train: Vec<(f64, f64)> = records
        .iter()
        .filter_map(|r| r.train_psnr.map(|p| (r.time, p)))
        .collect();
    // Moving average over ~2% of the run so the noisy per-batch PSNR reads as a curve.
    let k = (train.len() / 50).max(1);
    let smooth: Vec<(f64, f64)> = (0..train.len())
        .step_by(k)
        .map(|i| {
            let w = &train[i.saturating_sub(k)..(i + 1).min(train.len())];
            (train[i].0, w.iter().map(|p| p.1).sum::<f64>() / w.len() as f64)
        })
        .collect();
    let test: Vec<(f64, f64)> = records
        .iter()
        .filter_map(|r| r.test_psnr.map(|p| (r.time, p)))
        .collect();
    let mut series = vec![Series {
        name: "train batch PSNR (smoothed)".into(),
        points: smooth,
        color: PALETTE[0],
    }];
    if !test.is_empty() {
        series.push(Series {
            name: "held-out PSNR".into(),
            points: test,
            color: PALETTE[1],
        });
    }
    Chart {
        title: "PSNR against training time".into(),
        x_label: "training time (s)".into(),
        y_label: "PSNR (dB)".into(),
        series,
        log_x: false,
    }
    .save(out)
}

/// An RGB raster with the few drawing primitives the charts need.
struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn new(w: usize, h: usize) -> Self {
        Canvas {
            w,
            h,
            px: vec![255; w * h * 3],
        }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = (y as usize * self.w + x as usize) * 3;
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }

    fn hline(&mut self, x0: i64, x1: i64, y: i64, c: [u8; 3]) {
        (x0..=x1).for_each(|x| self.set(x, y, c));
    }

    fn vline(&mut self, x: i64, y0: i64, y1: i64, c: [u8; 3]) {
        (y0..=y1).for_each(|y| self.set(x, y, c));
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        self.hline(x0, x1, y0, c);
        self.hline(x0, x1, y1, c);
        self.vline(x0, y0, y1, c);
        self.vline(x1, y0, y1, c);
    }

    fn dot(&mut self, x: i64, y: i64, c: [u8; 3]) {
        for dy in -2..=2 {
            for dx in -2..=2 {
                if dx * dx + dy * dy <= 4 {
                    self.set(x + dx, y + dy, c);
                }
            }
        }
    }

    /// A two-pixel-wide line.
    fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, c: [u8; 3]) {
        let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
            self.set(x as i64, y as i64, c);
            self.set(x as i64, y as i64 + 1, c);
        }
    }

    /// 5×7 glyphs at 1× scale (6 px advance).
    fn text(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (i, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (row, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits >> (4 - col) & 1 == 1 {
                        self.set(x + 6 * i as i64 + col, y + row as i64, c);
                    }
                }
            }
        }
    }

    fn into_image(self) -> Image {
        Image::from_data(
            self.w as u32,
            self.h as u32,
            3,
            self.px.iter().map(|v| *v as f32 / 255.0).collect(),
        )
    }
}

/// 5×7 bitmap glyphs (rows top to bottom, 5 low bits each). Lower case maps to upper case.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        'A' => [14, 17, 17, 31, 17, 17, 17],
        'B' => [30, 17, 17, 30, 17, 17, 30],
        'C' => [14, 17, 16, 16, 16, 17, 14],
        'D' => [28, 18, 17, 17, 17, 18, 28],
        'E' => [31, 16, 16, 30, 16, 16, 31],
        'F' => [31, 16, 16, 30, 16, 16, 16],
        'G' => [14, 17, 16, 23, 17, 17, 15],
        'H' => [17, 17, 17, 31, 17, 17, 17],
        'I' => [14, 4, 4, 4, 4, 4, 14],
        'J' => [7, 2, 2, 2, 2, 18, 12],
        'K' => [17, 18, 20, 24, 20, 18, 17],
        'L' => [16, 16, 16, 16, 16, 16, 31],
        'M' => [17, 27, 21, 21, 17, 17, 17],
        'N' => [17, 17, 25, 21, 19, 17, 17],
        'O' => [14, 17, 17, 17, 17, 17, 14],
        'P' => [30, 17, 17, 30, 16, 16, 16],
        'Q' => [14, 17, 17, 17, 21, 18, 13],
        'R' => [30, 17, 17, 30, 20, 18, 17],
        'S' => [15, 16, 16, 14, 1, 1, 30],
        'T' => [31, 4, 4, 4, 4, 4, 4],
        'U' => [17, 17, 17, 17, 17, 17, 14],
        'V' => [17, 17, 17, 17, 17, 10, 4],
        'W' => [17, 17, 17, 21, 21, 21, 10],
        'X' => [17, 17, 10, 4, 10, 17, 17],
        'Y' => [17, 17, 10, 4, 4, 4, 4],
        'Z' => [31, 1, 2, 4, 8, 16, 31],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        ',' => [0, 0, 0, 0, 12, 4, 8],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        '+' => [0, 4, 4, 31, 4, 4, 0],
        '(' => [2, 4, 8, 8, 8, 4, 2],
        ')' => [8, 4, 2, 2, 2, 4, 8],
        '/' => [1, 1, 2, 4, 8, 16, 16],
        ':' => [0, 12, 12, 0, 12, 12, 0],
        '%' => [24, 25, 2, 4, 8, 19, 3],
        '=' => [0, 0, 31, 0, 31, 0, 0],
        '_' => [0, 0, 0, 0, 0, 0, 31],
        '^' => [4, 10, 17, 0, 0, 0, 0],
        'x' | '*' => [0, 17, 10, 4, 10, 17, 0],
        _ => [0; 7],
    }
}
