//! Gaussian image pyramids (factor 2) for coarse-to-fine registration, the matching validity
//! mask pyramid, and the blur applied to the rendering against aliasing (DESIGN.md §5).
//!
//! Level `k + 1` is level `k` smoothed with the 5-tap binomial kernel `[1 4 6 4 1] / 16` and
//! sampled at its even pixels (as OpenCV's `pyrDown`). With integer pixel centres this makes
//! level-`k` coordinates exactly level-0 coordinates divided by `2^k`.

use super::gray::{GrayF32, ImageError, Mask};

/// No level smaller than this on either side is built (a registration window would not fit).
pub const MIN_LEVEL_SIDE: usize = 8;

/// Reflect-101 border index (`… 2 1 | 0 1 2 … n−1 | n−2 …`), as OpenCV's default border.
#[inline]
fn reflect101(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let n = n as isize;
    let mut i = i;
    // Loops only for kernels wider than the image; bounded by the kernel radius.
    while i < 0 || i >= n {
        i = if i < 0 { -i } else { 2 * n - 2 - i };
    }
    i as usize
}

/// Separable convolution with a symmetric kernel (`kernel[0]` is the centre tap), reflect-101
/// borders.
fn convolve_separable(img: &GrayF32, kernel: &[f32]) -> GrayF32 {
    let (w, h) = (img.width(), img.height());
    let r = kernel.len() as isize - 1;
    let src = img.data();
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let mut acc = kernel[0] * row[x];
            for k in 1..=r {
                let a = row[reflect101(x as isize - k, w)];
                let b = row[reflect101(x as isize + k, w)];
                acc += kernel[k as usize] * (a + b);
            }
            tmp[y * w + x] = acc;
        }
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for k in 0..=r {
            let wk = kernel[k as usize];
            let ya = reflect101(y as isize - k, h);
            let yb = reflect101(y as isize + k, h);
            for x in 0..w {
                out[y * w + x] += if k == 0 {
                    wk * tmp[ya * w + x]
                } else {
                    wk * (tmp[ya * w + x] + tmp[yb * w + x])
                };
            }
        }
    }
    // Same size as the input, which was valid.
    GrayF32::new(w, h, out).unwrap_or_else(|_| img.clone())
}

/// Gaussian blur with standard deviation `sigma` (px), kernel radius `ceil(3σ)`; `sigma ≤ 0`
/// or non-finite returns a copy.
pub fn gaussian_blur(img: &GrayF32, sigma: f32) -> GrayF32 {
    if !(sigma.is_finite() && sigma > 0.0) {
        return img.clone();
    }
    let r = (3.0 * sigma).ceil().max(1.0) as usize;
    let mut kernel: Vec<f32> = (0..=r)
        .map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum = kernel[0] + 2.0 * kernel[1..].iter().sum::<f32>();
    kernel.iter_mut().for_each(|v| *v /= sum);
    convolve_separable(img, &kernel)
}

/// The blur of the rendered image against aliasing (DESIGN.md §5): the rendering has hard,
/// aliased texture and silhouette edges the optics of the live camera never produce.
pub fn antialias(rendered: &GrayF32, sigma: f32) -> GrayF32 {
    gaussian_blur(rendered, sigma)
}

/// One pyramid step: binomial smoothing and every second pixel; size `⌈w/2⌉ × ⌈h/2⌉`.
pub fn pyr_down(img: &GrayF32) -> GrayF32 {
    const K: [f32; 3] = [6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let (w, h) = (img.width(), img.height());
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let src = img.data();
    // Horizontal pass only at even columns, then vertical only at even rows.
    let mut tmp = vec![0f32; w2 * h];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x2 in 0..w2 {
            let x = 2 * x2 as isize;
            let mut acc = K[0] * row[x as usize];
            for k in 1..3 {
                acc += K[k as usize] * (row[reflect101(x - k, w)] + row[reflect101(x + k, w)]);
            }
            tmp[y * w2 + x2] = acc;
        }
    }
    let mut out = vec![0f32; w2 * h2];
    for y2 in 0..h2 {
        let y = 2 * y2 as isize;
        let rows = [
            reflect101(y, h),
            reflect101(y - 1, h),
            reflect101(y + 1, h),
            reflect101(y - 2, h),
            reflect101(y + 2, h),
        ];
        let weights = [K[0], K[1], K[1], K[2], K[2]];
        for x2 in 0..w2 {
            out[y2 * w2 + x2] = rows
                .iter()
                .zip(weights)
                .map(|(&r, wk)| wk * tmp[r * w2 + x2])
                .sum();
        }
    }
    GrayF32::new(w2, h2, out).unwrap_or_else(|_| img.clone())
}

/// A Gaussian pyramid; level 0 is the input.
#[derive(Debug, Clone)]
pub struct Pyramid {
    levels: Vec<GrayF32>,
}

impl Pyramid {
    /// Builds up to `levels` levels (at least 1), stopping before a level would be smaller
    /// than [`MIN_LEVEL_SIDE`] on a side.
    pub fn build(base: GrayF32, levels: usize) -> Self {
        let mut out = vec![base];
        while out.len() < levels.max(1) {
            let last = &out[out.len() - 1];
            if last.width().div_ceil(2) < MIN_LEVEL_SIDE
                || last.height().div_ceil(2) < MIN_LEVEL_SIDE
            {
                break;
            }
            let next = pyr_down(last);
            out.push(next);
        }
        Self { levels: out }
    }

    /// Number of levels built.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Never empty; present for API completeness.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `k` (0 = full resolution).
    pub fn level(&self, k: usize) -> Option<&GrayF32> {
        self.levels.get(k)
    }

    /// All levels, finest first.
    pub fn levels(&self) -> &[GrayF32] {
        &self.levels
    }
}

/// Validity masks matching a [`Pyramid`]: a coarse pixel is valid only if every fine pixel
/// of its 5×5 smoothing support is valid, so that no background leaks into a coarse template.
#[derive(Debug, Clone)]
pub struct MaskPyramid {
    levels: Vec<Mask>,
}

impl MaskPyramid {
    /// Builds `levels` levels (at least 1) with the sizes [`Pyramid::build`] gives.
    pub fn build(base: Mask, levels: usize) -> Self {
        let mut out = vec![base];
        while out.len() < levels.max(1) {
            let last = &out[out.len() - 1];
            let (w, h) = (last.width(), last.height());
            let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
            if w2 < MIN_LEVEL_SIDE || h2 < MIN_LEVEL_SIDE {
                break;
            }
            let mut data = vec![false; w2 * h2];
            for y2 in 0..h2 {
                for x2 in 0..w2 {
                    let (x, y) = (2 * x2 as isize, 2 * y2 as isize);
                    data[y2 * w2 + x2] = (-2..=2).all(|dy| {
                        (-2..=2).all(|dx| last.get(reflect101(x + dx, w), reflect101(y + dy, h)))
                    });
                }
            }
            match Mask::new(w2, h2, data) {
                Ok(m) => out.push(m),
                Err(_) => break,
            }
        }
        Self { levels: out }
    }

    /// Number of levels built.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Never empty; present for API completeness.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `k`.
    pub fn level(&self, k: usize) -> Option<&Mask> {
        self.levels.get(k)
    }
}

/// A rendering prepared for registration: blurred against aliasing, its pyramid and the
/// mask pyramid from the depth buffer.
#[derive(Debug, Clone)]
pub struct TemplatePyramid {
    /// Intensities.
    pub image: Pyramid,
    /// Where the model was rendered.
    pub mask: MaskPyramid,
}

impl TemplatePyramid {
    /// Blurs `rendered` with `blur_sigma` and builds `levels` levels of image and mask.
    pub fn build(
        rendered: &GrayF32,
        mask: Mask,
        levels: usize,
        blur_sigma: f32,
    ) -> Result<Self, ImageError> {
        if (rendered.width(), rendered.height()) != (mask.width(), mask.height()) {
            return Err(ImageError::SizeMismatch {
                a: (rendered.width(), rendered.height()),
                b: (mask.width(), mask.height()),
            });
        }
        // The blur mixes background into pixels near the silhouette: shrink the mask by the
        // blur's reach (2σ) so that those pixels count as background too.
        let reach = if blur_sigma.is_finite() && blur_sigma > 0.0 {
            (2.0 * blur_sigma).ceil() as usize
        } else {
            0
        };
        Ok(Self {
            image: Pyramid::build(antialias(rendered, blur_sigma), levels),
            mask: MaskPyramid::build(erode(&mask, reach), levels),
        })
    }
}

/// Square erosion of radius `r` (separable: rows, then columns); outside the image is valid,
/// so only background shrinks the mask.
pub fn erode(mask: &Mask, r: usize) -> Mask {
    if r == 0 {
        return mask.clone();
    }
    let (w, h) = (mask.width(), mask.height());
    let src = mask.data();
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = src[y * w + a..=y * w + b].iter().all(|&v| v);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (a..=b).all(|yy| rows[yy * w + x]);
        }
    }
    Mask::new(w, h, out).unwrap_or_else(|_| mask.clone())
}
