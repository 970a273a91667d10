//! f32 images in [0, 1], interleaved channels, row-major; PNG/JPEG loading and atomic saving.

use std::path::Path;

use crate::error::{DataError, Result};

/// An image with `channels` interleaved f32 values per pixel, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    pub data: Vec<f32>,
}

impl Image {
    pub fn new(width: u32, height: u32, channels: u32) -> Self {
        Image {
            width,
            height,
            channels,
            data: vec![0.0; width as usize * height as usize * channels as usize],
        }
    }

    pub fn from_data(width: u32, height: u32, channels: u32, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width as usize * height as usize * channels as usize);
        Image {
            width,
            height,
            channels,
            data,
        }
    }

    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn pixel(&self, i: usize) -> &[f32] {
        let c = self.channels as usize;
        &self.data[i * c..(i + 1) * c]
    }

    /// Loads PNG or JPEG (8 or 16 bit) as RGB, or RGBA when the file has alpha.
    pub fn load(path: &Path) -> Result<Image> {
        let bytes = crate::error::read_file(path)?;
        let img = image::load_from_memory(&bytes)
            .map_err(|e| DataError::invalid(path, format!("cannot decode image: {e}")))?;
        let (width, height) = (img.width(), img.height());
        if img.color().has_alpha() {
            let rgba = img.into_rgba32f();
            Ok(Image {
                width,
                height,
                channels: 4,
                data: rgba.into_raw(),
            })
        } else {
            let rgb = img.into_rgb32f();
            Ok(Image {
                width,
                height,
                channels: 3,
                data: rgb.into_raw(),
            })
        }
    }

    /// Splits RGBA into RGB composited over `background` (straight alpha) and the alpha channel.
    /// RGB images come back unchanged with no alpha.
    pub fn composite_alpha(self, background: [f32; 3]) -> (Image, Option<Vec<f32>>) {
        if self.channels != 4 {
            return (self, None);
        }
        let n = self.num_pixels();
        let mut rgb = Vec::with_capacity(3 * n);
        let mut alpha = Vec::with_capacity(n);
        for px in self.data.chunks_exact(4) {
            let a = px[3];
            for c in 0..3 {
                rgb.push(px[c] * a + background[c] * (1.0 - a));
            }
            alpha.push(a);
        }
        (Image::from_data(self.width, self.height, 3, rgb), Some(alpha))
    }

    /// Box-filter downscale by an integer factor (each output pixel averages a factor x factor
    /// block; OpenCV's INTER_AREA does the same for integer factors). Sizes round down.
    pub fn downscale(&self, factor: u32) -> Image {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h, c) = (self.width / factor, self.height / factor, self.channels as usize);
        let f = factor as usize;
        let mut out = Image::new(w, h, self.channels);
        let inv = 1.0 / (f * f) as f32;
        for y in 0..h as usize {
            for x in 0..w as usize {
                for dy in 0..f {
                    let row = (y * f + dy) * self.width as usize;
                    for dx in 0..f {
                        let src = (row + x * f + dx) * c;
                        let dst = (y * w as usize + x) * c;
                        for k in 0..c {
                            out.data[dst + k] += self.data[src + k] * inv;
                        }
                    }
                }
            }
        }
        out
    }

    /// Area-averaging resize to any smaller (or equal) size: each output pixel is the
    /// coverage-weighted mean of the input pixels its footprint overlaps.
    pub fn resize_area(&self, width: u32, height: u32) -> Image {
        if width == self.width && height == self.height {
            return self.clone();
        }
        if self.width.is_multiple_of(width)
            && self.height.is_multiple_of(height)
            && self.width / width == self.height / height
        {
            return self.downscale(self.width / width);
        }
        let c = self.channels as usize;
        let weights = |n_in: u32, n_out: u32| -> Vec<Vec<(usize, f32)>> {
            let s = n_in as f64 / n_out as f64;
            (0..n_out)
                .map(|o| {
                    let (a, b) = (o as f64 * s, (o + 1) as f64 * s);
                    let mut w = Vec::new();
                    let mut i = a.floor() as usize;
                    while (i as f64) < b && i < n_in as usize {
                        let overlap = (b.min(i as f64 + 1.0) - a.max(i as f64)).max(0.0);
                        if overlap > 0.0 {
                            w.push((i, (overlap / (b - a)) as f32));
                        }
                        i += 1;
                    }
                    w
                })
                .collect()
        };
        let (wx, wy) = (weights(self.width, width), weights(self.height, height));
        let mut out = Image::new(width, height, self.channels);
        for (y, row_w) in wy.iter().enumerate() {
            for (x, col_w) in wx.iter().enumerate() {
                let dst = (y * width as usize + x) * c;
                for &(sy, ay) in row_w {
                    for &(sx, ax) in col_w {
                        let src = (sy * self.width as usize + sx) * c;
                        for k in 0..c {
                            out.data[dst + k] += ay * ax * self.data[src + k];
                        }
                    }
                }
            }
        }
        out
    }

    /// 8-bit buffer with values clamped to [0, 1] and rounded.
    pub fn to_u8(&self) -> Vec<u8> {
        self.data.iter().map(|v| to_u8(*v)).collect()
    }

    /// Writes a PNG (1, 3 or 4 channels) atomically: a temporary file in the same folder, then rename.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        let color = match self.channels {
            1 => image::ExtendedColorType::L8,
            3 => image::ExtendedColorType::Rgb8,
            4 => image::ExtendedColorType::Rgba8,
            c => {
                return Err(DataError::invalid(
                    path,
                    format!("cannot save a {c}-channel image as PNG"),
                ));
            }
        };
        let mut bytes = Vec::new();
        image::write_buffer_with_format(
            &mut std::io::Cursor::new(&mut bytes),
            &self.to_u8(),
            self.width,
            self.height,
            color,
            image::ImageFormat::Png,
        )
        .map_err(|e| DataError::invalid(path, format!("cannot encode PNG: {e}")))?;
        write_atomic(path, &bytes)
    }
}

pub fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a
/// reader never sees a half-written file and a crash leaves the old file intact.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        DataError::io(path, e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downscale_averages_blocks() {
        let img = Image::from_data(4, 2, 1, vec![0., 1., 2., 3., 4., 5., 6., 7.]);
        let d = img.downscale(2);
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.data, vec![2.5, 4.5]);
        let r = img.resize_area(2, 1);
        assert_eq!(r.data, d.data);
    }

    #[test]
    fn resize_area_preserves_mean() {
        let data: Vec<f32> = (0..7 * 5).map(|i| (i * 37 % 11) as f32).collect();
        let img = Image::from_data(7, 5, 1, data.clone());
        let r = img.resize_area(3, 2);
        let mean_in = data.iter().sum::<f32>() / data.len() as f32;
        let mean_out = r.data.iter().sum::<f32>() / r.data.len() as f32;
        assert!((mean_in - mean_out).abs() < 1e-4);
    }

    #[test]
    fn png_round_trip() {
        let dir = std::env::temp_dir().join(format!("nerf-data-png-{}", std::process::id()));
        let img = Image::from_data(2, 1, 3, vec![0.0, 0.5, 1.0, 0.25, 0.75, 0.0]);
        let path = dir.join("x.png");
        img.save_png(&path).unwrap();
        let back = Image::load(&path).unwrap();
        assert_eq!(back.channels, 3);
        for (a, b) in img.data.iter().zip(&back.data) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
        std::fs::remove_dir_all(dir).unwrap();
    }
}
