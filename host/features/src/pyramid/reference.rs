//! The scalar-order implementations the vectorised passes of [`super`] replaced, kept
//! unchanged as their reference: the tests require the same values (the same sums in the same
//! order, so equal to the last bit) and the same masks. Also the readable statement of what
//! the fast passes compute (docs/VISION.md §2).

use super::super::gray::{GrayF32, Mask};
use super::reflect101;

/// Horizontal pass of a symmetric kernel at output columns `x = step·i` (`i < out.len()`):
/// reflect-101 only within the kernel's reach of the borders, plain slice indexing in between
/// (no index arithmetic per tap there). Same sum order at every pixel.
#[inline]
pub(super) fn convolve_row(row: &[f32], kernel: &[f32], step: usize, out: &mut [f32]) {
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
    match super::gaussian_kernel(sigma) {
        Some(kernel) => convolve_separable(img, &kernel),
        None => img.clone(),
    }
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

/// One level of [`super::MaskPyramid`]: the coarse pixel is the AND over its 5×5 support, at
/// the even pixels; size `⌈w/2⌉ × ⌈h/2⌉` (`None` only if that size is invalid).
pub fn mask_pyr_down(last: &Mask) -> Option<Mask> {
    let (w, h) = (last.width(), last.height());
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
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
    Mask::new(w2, h2, data).ok()
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
