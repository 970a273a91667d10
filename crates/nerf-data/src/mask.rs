//! Binary pixel masks (`[H*W]`, row-major): morphology with the 3×3 cross, shared by the flow's
//! motion masks (`nerf-flow`) and the generator's given masks (`nerf-synth`).

/// Binary erosion (`erode = true`) or dilation with the 3×3 cross (skimage's `disk(1)`).
/// Pixels outside the image are ignored, so objects touching the border are not eroded away.
pub fn morph_cross(m: &[bool], w: usize, h: usize, erode: bool) -> Vec<bool> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let nb = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then_some(i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then_some(i + w),
            ];
            let mut it = std::iter::once(i).chain(nb.into_iter().flatten());
            if erode { it.all(|j| m[j]) } else { it.any(|j| m[j]) }
        })
        .collect()
}

/// Dilation by `steps` pixels: [`morph_cross`] applied `steps` times (a diamond of radius
/// `steps`, clipped at the border).
pub fn grow(m: &[bool], w: usize, h: usize, steps: usize) -> Vec<bool> {
    (0..steps).fold(m.to_vec(), |m, _| morph_cross(&m, w, h, false))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One pixel in a 4×3 image grows into the cross around it, clipped at the border, and the
    /// cross erodes back to that pixel.
    #[test]
    fn the_cross_dilates_and_erodes_by_hand() {
        let (w, h) = (4, 3);
        let mut m = vec![false; w * h];
        m[w + 1] = true;
        let grown = morph_cross(&m, w, h, false);
        let want: Vec<usize> = vec![1, w, w + 1, w + 2, 2 * w + 1];
        assert_eq!((0..w * h).filter(|&p| grown[p]).collect::<Vec<_>>(), want);
        assert_eq!(morph_cross(&grown, w, h, true), m);
    }

    /// Growing by two steps reaches every pixel within city-block distance 2 of the seed, and no
    /// other; zero steps leave the mask as it is.
    #[test]
    fn growing_reaches_the_city_block_diamond() {
        let (w, h) = (7, 6);
        let mut m = vec![false; w * h];
        m[2 * w + 3] = true;
        let grown = grow(&m, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let d = x.abs_diff(3) + y.abs_diff(2);
                assert_eq!(grown[y * w + x], d <= 2, "pixel ({x}, {y})");
            }
        }
        assert_eq!(grow(&m, w, h, 0), m);
    }
}
