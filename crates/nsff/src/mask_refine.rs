//! Motion masks refined by the static field once its warm-up ends.
//!
//! The flow's masks hold many static pixels (occlusion edges, the dilation's ring, surfaces whose
//! flow fails), and the static batch never trains on them. A static field trained on the unmasked
//! pixels alone has still seen most of that static content from other frames, so it renders it
//! at the masked pixel; a mover it has never seen, so there it renders what lies behind. A masked
//! pixel whose 3×3 neighbourhood the static field already renders as well as a typical unmasked
//! pixel (at most the `quantile` of the unmasked pixels' errors) leaves the mask.

/// The `q`-quantile (`q` in [0, 1], linear between order statistics) of the finite values;
/// `None` if there are none.
pub fn quantile(values: impl IntoIterator<Item = f32>, q: f32) -> Option<f32> {
    let finite: Vec<f64> = (values.into_iter())
        .filter(|x| x.is_finite())
        .map(f64::from)
        .collect();
    let value = nerf_data::math::percentile(&finite, 100.0 * f64::from(q));
    (!finite.is_empty()).then_some(value as f32)
}

/// Per pixel of one frame (`[H*W]`, row-major, `width` wide; `error` the squared colour error,
/// `NaN` where not rendered): whether it is masked and the static field explains it, i.e.
/// every masked pixel of its 3×3 neighbourhood (itself included) was rendered with an error at
/// most `threshold`. A masked pixel that was not rendered stays.
pub fn explained(mask: &[bool], error: &[f32], width: usize, threshold: f32) -> Vec<bool> {
    let height = mask.len() / width.max(1);
    let at = |x: i64, y: i64| {
        (x >= 0 && y >= 0 && x < width as i64 && y < height as i64).then(|| y as usize * width + x as usize)
    };
    (0..mask.len())
        .map(|p| {
            if !mask[p] || !error[p].is_finite() {
                return false;
            }
            let (x, y) = ((p % width) as i64, (p / width) as i64);
            (-1..=1).all(|dy| {
                (-1..=1).all(|dx| match at(x + dx, y + dy) {
                    Some(q) if mask[q] => error[q].is_finite() && error[q] <= threshold,
                    _ => true,
                })
            })
        })
        .collect()
}

/// Per frame, the pixels refinement took out of the masks, packed 8 to a byte (the checkpoint's
/// `mask_refined` section): a resumed run recomputes the flow's masks and takes the same pixels
/// out again.
pub fn pack(removed: &[Vec<bool>]) -> Vec<u8> {
    let bits: Vec<bool> = removed.iter().flatten().copied().collect();
    bits.chunks(8)
        .map(|c| {
            c.iter()
                .enumerate()
                .fold(0u8, |b, (i, &x)| b | (u8::from(x) << i))
        })
        .collect()
}

/// [`pack`]'s inverse for `frames` frames of `pixels` pixels; an error if the length differs.
pub fn unpack(bytes: &[u8], frames: usize, pixels: usize) -> Result<Vec<Vec<bool>>, String> {
    let want = (frames * pixels).div_ceil(8);
    if bytes.len() != want {
        return Err(format!(
            "refined motion masks hold {} bytes, {frames} frames of {pixels} pixels need {want}",
            bytes.len()
        ));
    }
    let bit = |i: usize| bytes[i / 8] >> (i % 8) & 1 == 1;
    Ok((0..frames)
        .map(|k| (0..pixels).map(|p| bit(k * pixels + p)).collect())
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Non-finite values are left out, and the quantile interpolates between the sorted finite
    /// values (0.1, 0.2, 0.3, 0.5, 0.7: position q·4), worked by hand.
    #[test]
    fn quantile_interpolates_the_sorted_finite_values() {
        let v = [0.3f32, f32::NAN, 0.1, 0.7, f32::INFINITY, 0.2, 0.5];
        for (q, want) in [(0.0f32, 0.1f64), (0.25, 0.2), (0.5, 0.3), (0.9, 0.62), (1.0, 0.7)] {
            let got = quantile(v, q).unwrap();
            assert!(
                (f64::from(got) - want).abs() < 1e-6,
                "q {q}: {got} against {want}"
            );
        }
        assert_eq!(quantile([f32::NAN], 0.5), None);
    }

    /// A 5×4 frame: a masked 3×3 block whose centre column is badly explained (a mover), and a
    /// masked pixel at the corner rendered well; pixels outside the mask never count.
    #[test]
    fn a_pixel_leaves_the_mask_only_if_its_masked_neighbours_are_explained() {
        let w = 5;
        #[rustfmt::skip]
        let mask = [
            true,  true,  true,  false, false,
            true,  true,  true,  false, false,
            true,  true,  true,  false, false,
            false, false, false, false, true,
        ];
        let n = f32::NAN;
        #[rustfmt::skip]
        let error = [
            0.01, 0.90, 0.01, 5.0, n,
            0.01, 0.90, 0.01, 5.0, n,
            0.01, 0.01, 0.01, n,   n,
            n,    n,    n,    n,   0.02,
        ];
        let out = explained(&mask, &error, w, 0.05);
        // Every pixel of the block touches the bad column; the corner pixel alone is explained.
        let want: Vec<bool> = (0..20).map(|p| p == 19).collect();
        assert_eq!(out, want);
        // Above the bad column's error the whole mask is explained (pixels outside it ignored).
        assert_eq!(explained(&mask, &error, w, 1.0), mask.to_vec());
        // An unrendered masked pixel stays, and so does its neighbours' verdict.
        let mut unrendered = error;
        unrendered[19] = n;
        assert!(!explained(&mask, &unrendered, w, 1.0)[19]);
    }

    #[test]
    fn packed_masks_round_trip_and_refuse_a_wrong_length() {
        let removed = vec![
            (0..13).map(|p| p % 3 == 0).collect::<Vec<bool>>(),
            (0..13).map(|p| p > 9).collect(),
        ];
        let bytes = pack(&removed);
        assert_eq!(bytes.len(), 4);
        assert_eq!(unpack(&bytes, 2, 13).unwrap(), removed);
        let err = unpack(&bytes[..3], 2, 13).unwrap_err();
        assert!(err.contains("3 bytes") && err.contains("need 4"), "{err}");
    }
}
