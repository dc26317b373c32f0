//! The next mip level of a texture: `image::imageops::resize` with the triangle filter to half
//! the size, pixel for pixel, computed a band of rows at a time. The crate's resize keeps its
//! whole first pass in `f32` RGBA (16 bytes a pixel: 138 MB for the first level of a
//! 5083×3409 texture); a band keeps 16 bytes a pixel of its own rows only.

use image::RgbaImage;

/// Output rows computed at once.
const BAND_ROWS: u32 = 64;

/// The triangle filter's support [input pixels at a ratio of 1].
const SUPPORT: f32 = 1.0;

/// The triangle kernel.
fn triangle(x: f32) -> f32 {
    if x.abs() < 1.0 { 1.0 - x.abs() } else { 0.0 }
}

/// The input samples `[left, right)` and their normalised weights for output sample `out` of
/// `new_len` from `len` (the resize's own arithmetic, step for step).
fn taps(out: u32, len: u32, new_len: u32, weights: &mut Vec<f32>) -> u32 {
    let ratio = len as f32 / new_len as f32;
    let sratio = if ratio < 1.0 { 1.0 } else { ratio };
    let support = SUPPORT * sratio;
    let centre = (out as f32 + 0.5) * ratio;
    let left = ((centre - support).floor() as i64).clamp(0, i64::from(len) - 1) as u32;
    let right =
        ((centre + support).ceil() as i64).clamp(i64::from(left) + 1, i64::from(len)) as u32;
    let centre = centre - 0.5;
    weights.clear();
    let mut sum = 0.0;
    for i in left..right {
        let w = triangle((i as f32 - centre) / sratio);
        weights.push(w);
        sum += w;
    }
    for w in weights.iter_mut() {
        *w /= sum;
    }
    left
}

/// `image` at half its size (at least 1 pixel a side), as
/// `imageops::resize(image, w / 2, h / 2, FilterType::Triangle)` makes it.
pub(crate) fn half(image: &RgbaImage) -> RgbaImage {
    let (width, height) = image.dimensions();
    let (new_width, new_height) = ((width / 2).max(1), (height / 2).max(1));
    // The horizontal taps, the same for every row.
    let mut columns = Vec::with_capacity(new_width as usize);
    let mut weights = Vec::new();
    for x in 0..new_width {
        let left = taps(x, width, new_width, &mut weights);
        columns.push((left, weights.clone()));
    }
    let mut out = RgbaImage::new(new_width, new_height);
    let mut band = vec![[0f32; 4]; (width * BAND_ROWS.min(new_height)) as usize];
    for y0 in (0..new_height).step_by(BAND_ROWS as usize) {
        let rows = BAND_ROWS.min(new_height - y0);
        // First pass: each output row from the input rows around it, in f32.
        for r in 0..rows {
            let top = taps(y0 + r, height, new_height, &mut weights);
            let row = &mut band[(r * width) as usize..((r + 1) * width) as usize];
            for (x, t) in row.iter_mut().enumerate() {
                *t = [0.0; 4];
                for (i, w) in weights.iter().enumerate() {
                    let p = image.get_pixel(x as u32, top + i as u32).0;
                    for c in 0..4 {
                        t[c] += f32::from(p[c]) * w;
                    }
                }
            }
        }
        // Second pass: each output pixel from the first pass's samples around it.
        for r in 0..rows {
            let row = &band[(r * width) as usize..((r + 1) * width) as usize];
            for (x, (left, ws)) in columns.iter().enumerate() {
                let mut t = [0f32; 4];
                for (i, w) in ws.iter().enumerate() {
                    let p = row[*left as usize + i];
                    for c in 0..4 {
                        t[c] += p[c] * w;
                    }
                }
                let px = t.map(|v| v.clamp(0.0, 255.0).round() as u8);
                out.put_pixel(x as u32, y0 + r, image::Rgba(px));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::imageops::{FilterType, resize};

    /// A textured image of any size: every value, in a pattern that is not periodic.
    fn pattern(width: u32, height: u32) -> RgbaImage {
        RgbaImage::from_fn(width, height, |x, y| {
            let v = |k: u32| {
                ((x * 7 + y * 13 + k * 29) ^ (x * y + k)).wrapping_mul(2_654_435_761) >> 24
            };
            image::Rgba([v(0) as u8, v(1) as u8, v(2) as u8, v(3) as u8])
        })
    }

    #[test]
    fn is_the_image_crates_triangle_resize_to_the_byte() {
        // Odd, even, one-pixel and band-crossing sizes.
        for (w, h) in [
            (5083, 131),
            (300, 257),
            (2, 2),
            (1, 9),
            (9, 1),
            (129, 200),
            (3, 3),
        ] {
            let image = pattern(w, h);
            let ours = half(&image);
            let theirs = resize(&image, (w / 2).max(1), (h / 2).max(1), FilterType::Triangle);
            assert_eq!(ours.dimensions(), theirs.dimensions(), "{w}x{h}");
            assert!(
                ours.as_raw() == theirs.as_raw(),
                "{w}x{h}: the pixels differ"
            );
        }
    }
}
