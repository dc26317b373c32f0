//! Gaussian image pyramids (factor 2) for coarse-to-fine registration, the matching validity
//! mask pyramid, and the blur applied to the rendering against aliasing (docs/VISION.md §2).
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

/// Horizontal pass of a symmetric kernel at output columns `x = step·i` (`i < out.len()`):
/// reflect-101 only within the kernel's reach of the borders, plain slice indexing in between
/// (no index arithmetic per tap there). Same sum order at every pixel.
#[inline]
fn convolve_row(row: &[f32], kernel: &[f32], step: usize, out: &mut [f32]) {
    let w = row.len();
    let r = kernel.len() - 1;
    let border = |x: usize| {
        let mut acc = kernel[0] * row[x];
        for (k, &wk) in kernel.iter().enumerate().skip(1) {
            let k = k as isize;
            acc += wk * (row[reflect101(x as isize - k, w)] + row[reflect101(x as isize + k, w)]);
        }
        acc
    };
    // Outputs whose taps all lie inside the row: x = step·i with r ≤ x < w − r.
    let first = r.div_ceil(step).min(out.len());
    let end = if w > r {
        (w - r).div_ceil(step).clamp(first, out.len())
    } else {
        first
    };
    for (i, o) in out.iter_mut().enumerate().take(first) {
        *o = border(step * i);
    }
    if step == 1 && first < end {
        // Tap by tap over the whole interior: plain slice zips the compiler vectorises.
        let inner = &mut out[first..end];
        for (o, &v) in inner.iter_mut().zip(&row[first..end]) {
            *o = kernel[0] * v;
        }
        for (k, &wk) in kernel.iter().enumerate().skip(1) {
            let (left, right) = (&row[first - k..end - k], &row[first + k..end + k]);
            for ((o, &a), &b) in inner.iter_mut().zip(left).zip(right) {
                *o += wk * (a + b);
            }
        }
    } else if let (2, &[k0, k1, k2]) = (step, kernel) {
        // The pyramid's 5-tap kernel at even columns: fixed-size windows, no index checks.
        let windows = row[2 * first - 2..].windows(5).step_by(2);
        for (o, win) in out[first..end].iter_mut().zip(windows) {
            if let &[a, b, c, d, e] = win {
                *o = k0 * c + k1 * (b + d) + k2 * (a + e);
            }
        }
    } else {
        for (i, o) in out.iter_mut().enumerate().take(end).skip(first) {
            let x = step * i;
            let win = &row[x - r..=x + r];
            let mut acc = kernel[0] * win[r];
            for (k, &wk) in kernel.iter().enumerate().skip(1) {
                acc += wk * (win[r - k] + win[r + k]);
            }
            *o = acc;
        }
    }
    for (i, o) in out.iter_mut().enumerate().skip(end) {
        *o = border(step * i);
    }
}

/// Vertical pass: `out[x] = Σ_k kernel[k] · (rows_above[k][x] + rows_below[k][x])` (centre
/// once), row slices fetched once per output row so the inner loop is a plain zip.
#[inline]
fn convolve_column(tmp: &[f32], w: usize, h: usize, y: usize, kernel: &[f32], out: &mut [f32]) {
    let row = |yy: usize| &tmp[yy * w..(yy + 1) * w];
    let centre = row(y);
    for (o, &c) in out.iter_mut().zip(centre) {
        *o = kernel[0] * c;
    }
    for (k, &wk) in kernel.iter().enumerate().skip(1) {
        let k = k as isize;
        let (a, b) = (
            row(reflect101(y as isize - k, h)),
            row(reflect101(y as isize + k, h)),
        );
        for ((o, &va), &vb) in out.iter_mut().zip(a).zip(b) {
            *o += wk * (va + vb);
        }
    }
}

/// Separable convolution with a symmetric kernel (`kernel[0]` is the centre tap), reflect-101
/// borders.
fn convolve_separable(img: &GrayF32, kernel: &[f32]) -> GrayF32 {
    let (w, h) = (img.width(), img.height());
    let src = img.data();
    let mut tmp = vec![0f32; w * h];
    for (row, t) in src.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        convolve_row(row, kernel, 1, t);
    }
    let mut out = vec![0f32; w * h];
    for (y, o) in out.chunks_exact_mut(w).enumerate() {
        convolve_column(&tmp, w, h, y, kernel, o);
    }
    // Same size as the input, which was valid.
    GrayF32::new(w, h, out).unwrap_or_else(|_| img.clone())
}

/// Gaussian blur with standard deviation `sigma` (px), kernel radius `ceil(3σ)`; `sigma ≤ 0`
/// or non-finite returns a copy.
pub fn gaussian_blur(img: &GrayF32, sigma: f32) -> GrayF32 {
    match gaussian_kernel(sigma) {
        Some(kernel) => convolve_separable(img, &kernel),
        None => img.clone(),
    }
}

/// The normalised half kernel of [`gaussian_blur`] (`kernel[0]` is the centre tap, radius
/// `ceil(3σ)`); `None` for `sigma ≤ 0` or non-finite.
pub fn gaussian_kernel(sigma: f32) -> Option<Vec<f32>> {
    if !(sigma.is_finite() && sigma > 0.0) {
        return None;
    }
    let r = (3.0 * sigma).ceil().max(1.0) as usize;
    let mut kernel: Vec<f32> = (0..=r)
        .map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum = kernel[0] + 2.0 * kernel[1..].iter().sum::<f32>();
    kernel.iter_mut().for_each(|v| *v /= sum);
    Some(kernel)
}

/// The blur of the rendered image against aliasing (docs/VISION.md §2): the rendering has hard,
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
    for (row, t) in src.chunks_exact(w).zip(tmp.chunks_exact_mut(w2)) {
        convolve_row(row, &K, 2, t);
    }
    let mut out = vec![0f32; w2 * h2];
    for (y2, o) in out.chunks_exact_mut(w2).enumerate() {
        convolve_column(&tmp, w2, h, 2 * y2, &K, o);
    }
    GrayF32::new(w2, h2, out).unwrap_or_else(|_| img.clone())
}

/// A Gaussian pyramid; level 0 is the input, or the input smoothed (see
/// [`Pyramid::build_smoothed`]).
#[derive(Debug, Clone)]
pub struct Pyramid {
    levels: Vec<GrayF32>,
    smoothing: f32,
}

impl Pyramid {
    /// Builds up to `levels` levels (at least 1), stopping before a level would be smaller
    /// than [`MIN_LEVEL_SIDE`] on a side.
    pub fn build(base: GrayF32, levels: usize) -> Self {
        Self::build_smoothed(base, levels, 0.0)
    }

    /// As [`Pyramid::build`], with level 0 the input blurred by a Gaussian of `sigma` px
    /// (none for `sigma ≤ 0`). The pyramid remembers `sigma`: the registration's covariance
    /// accounts for the noise correlation the blur introduces.
    pub fn build_smoothed(base: GrayF32, levels: usize, sigma: f32) -> Self {
        let smoothing = if sigma.is_finite() && sigma > 0.0 {
            sigma
        } else {
            0.0
        };
        let base = if smoothing > 0.0 {
            gaussian_blur(&base, smoothing)
        } else {
            base
        };
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
        Self {
            levels: out,
            smoothing,
        }
    }

    /// The Gaussian σ (px) level 0 was smoothed with; 0 for none.
    pub fn smoothing(&self) -> f32 {
        self.smoothing
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
            // A coarse pixel is the AND over its 5×5 support. Reflect-101 only repeats pixels
            // of that (symmetric) support, so this is the radius-2 erosion with the window
            // clipped at the borders, taken at the even pixels: rows at every row, columns only
            // at even rows.
            let mut rows = vec![false; w * h];
            for (row, t) in last.data().chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
                erode_line(row, 2, t);
            }
            let mut data = vec![true; w2 * h2];
            for (y2, o) in data.chunks_exact_mut(w2).enumerate() {
                let y = 2 * y2;
                for yy in y.saturating_sub(2)..=(y + 2).min(h - 1) {
                    for (v, &r) in o
                        .iter_mut()
                        .zip(rows[yy * w..(yy + 1) * w].iter().step_by(2))
                    {
                        *v &= r;
                    }
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

/// One line of [`erode`]: `out[x]` = all of `line[x − r ..= x + r]` (clipped to the line).
/// Shifted ANDs over whole slices (byte-wide, vectorised); `r` is small (the blur's reach).
#[inline]
fn erode_line(line: &[bool], r: usize, out: &mut [bool]) {
    let w = line.len();
    out.copy_from_slice(line);
    for k in 1..=r.min(w.saturating_sub(1)) {
        for (o, &v) in out[k..].iter_mut().zip(&line[..w - k]) {
            *o &= v;
        }
        for (o, &v) in out[..w - k].iter_mut().zip(&line[k..]) {
            *o &= v;
        }
    }
}

/// Square erosion of radius `r` (separable: rows, then columns); outside the image is valid,
/// so only background shrinks the mask.
pub fn erode(mask: &Mask, r: usize) -> Mask {
    if r == 0 {
        return mask.clone();
    }
    let (w, h) = (mask.width(), mask.height());
    let mut rows = vec![false; w * h];
    for (line, out) in mask.data().chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        erode_line(line, r, out);
    }
    // Columns: AND of the whole rows y − r ..= y + r.
    let mut out = vec![true; w * h];
    for (y, o) in out.chunks_exact_mut(w).enumerate() {
        for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
            for (v, &m) in o.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
                *v &= m;
            }
        }
    }
    Mask::new(w, h, out).unwrap_or_else(|_| mask.clone())
}

#[cfg(test)]
mod tests {
    //! The fast passes against direct per-pixel definitions, including images smaller than
    //! the kernels (every border case).
    use super::*;

    fn lcg(seed: &mut u64) -> u64 {
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        *seed >> 33
    }

    fn sizes() -> Vec<(usize, usize)> {
        let mut v = vec![
            (1, 1),
            (1, 7),
            (7, 1),
            (2, 3),
            (3, 2),
            (5, 5),
            (6, 9),
            (17, 12),
        ];
        v.push((40, 31));
        v
    }

    fn conv_ref(img: &GrayF32, kernel: &[f32]) -> Vec<f32> {
        let (w, h) = (img.width(), img.height());
        let r = kernel.len() as isize - 1;
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let v = img.data()
                            [reflect101(y as isize + dy, h) * w + reflect101(x as isize + dx, w)];
                        acc += kernel[dy.unsigned_abs()] * kernel[dx.unsigned_abs()] * v;
                    }
                }
                out[y * w + x] = acc;
            }
        }
        out
    }

    #[test]
    fn blur_and_pyr_down_match_direct_definitions() {
        let mut seed = 7;
        for (w, h) in sizes() {
            let data = (0..w * h).map(|_| (lcg(&mut seed) % 256) as f32).collect();
            let img = GrayF32::new(w, h, data).unwrap();
            let sigma = 1.0f32;
            let mut k: Vec<f32> = (0..=3)
                .map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp())
                .collect();
            let sum = k[0] + 2.0 * k[1..].iter().sum::<f32>();
            k.iter_mut().for_each(|v| *v /= sum);
            let fast = gaussian_blur(&img, sigma);
            for (a, b) in fast.data().iter().zip(conv_ref(&img, &k)) {
                assert!((a - b).abs() < 1e-3, "{w}x{h}: {a} vs {b}");
            }
            let full = conv_ref(&img, &[6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0]);
            let down = pyr_down(&img);
            assert_eq!(
                (down.width(), down.height()),
                (w.div_ceil(2), h.div_ceil(2))
            );
            for y2 in 0..down.height() {
                for x2 in 0..down.width() {
                    let (a, b) = (
                        down.data()[y2 * down.width() + x2],
                        full[2 * y2 * w + 2 * x2],
                    );
                    assert!((a - b).abs() < 1e-3, "{w}x{h}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn erosion_and_mask_pyramid_match_direct_definitions() {
        let mut seed = 11;
        for (w, h) in sizes().into_iter().chain([(64, 48), (33, 70)]) {
            for density in [2, 10, 60] {
                let data = (0..w * h)
                    .map(|_| !lcg(&mut seed).is_multiple_of(density))
                    .collect();
                let m = Mask::new(w, h, data).unwrap();
                for r in [1, 2, 3, 8] {
                    let e = erode(&m, r);
                    for y in 0..h {
                        for x in 0..w {
                            let want = (y.saturating_sub(r)..=(y + r).min(h - 1)).all(|yy| {
                                (x.saturating_sub(r)..=(x + r).min(w - 1)).all(|xx| m.get(xx, yy))
                            });
                            assert_eq!(e.get(x, y), want, "{w}x{h} r={r} at ({x},{y})");
                        }
                    }
                }
                // Big enough for two levels: each coarse pixel is the AND of its 5×5 support.
                if w >= 2 * MIN_LEVEL_SIDE && h >= 2 * MIN_LEVEL_SIDE {
                    let p = MaskPyramid::build(m.clone(), 2);
                    let c = p.level(1).unwrap();
                    for y2 in 0..c.height() {
                        for x2 in 0..c.width() {
                            let (x, y) = (2 * x2 as isize, 2 * y2 as isize);
                            let want = (-2..=2).all(|dy| {
                                (-2..=2)
                                    .all(|dx| m.get(reflect101(x + dx, w), reflect101(y + dy, h)))
                            });
                            assert_eq!(c.get(x2, y2), want);
                        }
                    }
                }
            }
        }
    }
}
