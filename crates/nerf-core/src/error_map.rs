//! Error-driven pixel sampling (Instant-NGP's error map): a running estimate of the training
//! error over square tiles of each image, and draws of pixels with tiles chosen in proportion to
//! it. On an object against a plain background most pixels are learnt in a few hundred steps;
//! this puts the rays where the renders are still wrong.

use rand::Rng;

/// Per-tile running squared error of every training image.
#[derive(Clone, Debug)]
pub struct ErrorMap {
    tile: u32,
    /// Per image: width and height in pixels, tiles per row, and the start of its tiles.
    images: Vec<ImageTiles>,
    error: Vec<f32>,
    /// Weight of a new observation in a tile's running estimate.
    rate: f32,
}

#[derive(Clone, Copy, Debug)]
struct ImageTiles {
    width: u32,
    height: u32,
    columns: u32,
    start: usize,
    count: usize,
}

impl ErrorMap {
    /// Tiles of `tile`×`tile` pixels (clipped at the edges) over images of `sizes` (width,
    /// height). Every tile starts at `initial`, above any error it will see, so the first draws
    /// visit tiles not yet seen.
    pub fn new(sizes: &[(u32, u32)], tile: u32, initial: f32) -> Self {
        let tile = tile.max(1);
        let mut images = Vec::with_capacity(sizes.len());
        let mut start = 0;
        for &(width, height) in sizes {
            let columns = width.div_ceil(tile);
            let count = (columns * height.div_ceil(tile)) as usize;
            images.push(ImageTiles {
                width,
                height,
                columns,
                start,
                count,
            });
            start += count;
        }
        ErrorMap {
            tile,
            images,
            error: vec![initial; start],
            rate: 0.25,
        }
    }

    /// `n` pixel indices (`y·width + x`) of image `image`: a tile in proportion to its error,
    /// then a uniform pixel in it. All-zero or non-finite errors fall back to uniform tiles.
    pub fn sample(&self, image: usize, n: usize, rng: &mut impl Rng) -> Vec<u32> {
        let im = self.images[image];
        let errors = &self.error[im.start..im.start + im.count];
        let mut cdf = Vec::with_capacity(im.count);
        let mut total = 0.0f64;
        for &e in errors {
            total += if e.is_finite() { e.max(0.0) as f64 } else { 0.0 };
            cdf.push(total);
        }
        (0..n)
            .map(|_| {
                let t = if total > 0.0 {
                    let u = rng.random::<f64>() * total;
                    cdf.partition_point(|&c| c <= u).min(im.count - 1)
                } else {
                    rng.random_range(0..im.count)
                } as u32;
                let (x0, y0) = ((t % im.columns) * self.tile, (t / im.columns) * self.tile);
                let x = x0 + rng.random_range(0..self.tile.min(im.width - x0));
                let y = y0 + rng.random_range(0..self.tile.min(im.height - y0));
                y * im.width + x
            })
            .collect()
    }

    /// Folds squared errors seen at `pixels` of image `image` into their tiles' estimates.
    pub fn record(&mut self, image: usize, pixels: &[u32], errors: &[f32]) {
        let im = self.images[image];
        for (&p, &e) in pixels.iter().zip(errors) {
            if !e.is_finite() || p >= im.width * im.height {
                continue;
            }
            let i = self.tile_of(&im, p);
            self.error[i] += self.rate * (e - self.error[i]);
        }
    }

    /// The running estimate of the tile holding pixel `pixel` of image `image`.
    pub fn tile_error(&self, image: usize, pixel: u32) -> f32 {
        self.error[self.tile_of(&self.images[image], pixel)]
    }

    /// Index in `error` of the tile holding `pixel` (`y·width + x`) of `im`.
    fn tile_of(&self, im: &ImageTiles, pixel: u32) -> usize {
        let (x, y) = (pixel % im.width, pixel / im.width);
        im.start + ((y / self.tile) * im.columns + x / self.tile) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};

    /// Draws follow the recorded errors: a tile holding 3/4 of an image's error gets about 3/4
    /// of the draws, and every draw lies inside the image (edge tiles are clipped).
    #[test]
    fn draws_follow_the_recorded_error() {
        // 10×7 pixels in tiles of 4: 3 columns × 2 rows, the last column and row clipped.
        let mut map = ErrorMap::new(&[(5, 5), (10, 7)], 4, 0.0);
        // Tile (2, 1) of image 1 covers x 8..10, y 4..7: give it 3, and 1 to tile (0, 0).
        let hot: Vec<u32> = (4..7).flat_map(|y| (8..10).map(move |x| y * 10 + x)).collect();
        for _ in 0..200 {
            map.record(1, &hot, &vec![3.0; hot.len()]);
            map.record(1, &[0, 11], &[1.0, 1.0]);
        }
        assert!((map.tile_error(1, 69) - 3.0).abs() < 1e-4);
        assert!((map.tile_error(1, 0) - 1.0).abs() < 1e-4);
        assert_eq!(map.tile_error(0, 0), 0.0, "image 0 untouched");
        let mut rng = StdRng::seed_from_u64(1);
        let n = 20_000;
        let draws = map.sample(1, n, &mut rng);
        assert!(draws.iter().all(|&p| p < 70));
        let in_hot = draws.iter().filter(|p| hot.contains(p)).count() as f64 / n as f64;
        assert!((in_hot - 0.75).abs() < 0.02, "{in_hot}");
        // Every pixel of the hot tile is drawn: the clipped tile is covered, not just its corner.
        assert!(hot.iter().all(|p| draws.contains(p)));
    }

    /// An image with no error anywhere (or NaN recorded) still yields pixels, uniformly.
    #[test]
    fn zero_or_nan_errors_fall_back_to_uniform_tiles() {
        let mut map = ErrorMap::new(&[(8, 8)], 4, 0.0);
        map.record(0, &[0], &[f32::NAN]);
        assert_eq!(map.tile_error(0, 0), 0.0);
        let mut rng = StdRng::seed_from_u64(2);
        let draws = map.sample(0, 4000, &mut rng);
        let first_tile = draws.iter().filter(|&&p| p % 8 < 4 && p / 8 < 4).count() as f64 / 4000.0;
        assert!((first_tile - 0.25).abs() < 0.03, "{first_tile}");
    }

    /// A fresh map draws the tiles not seen yet: one seen tile, recorded low, is rarely drawn.
    #[test]
    fn unseen_tiles_come_first() {
        let mut map = ErrorMap::new(&[(8, 8)], 4, 1.0);
        for _ in 0..50 {
            map.record(0, &[0], &[0.0]);
        }
        let mut rng = StdRng::seed_from_u64(3);
        let draws = map.sample(0, 3000, &mut rng);
        let seen = draws.iter().filter(|&&p| p % 8 < 4 && p / 8 < 4).count();
        assert!(seen < 10, "{seen}");
    }
}
