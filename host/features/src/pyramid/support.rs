//! The rectangle holding an image's nonzero values, and the pyramid passes confined to it
//! (docs/VISION.md §2). A rendering is zero wherever the model is not, and blurring,
//! sub-sampling or eroding zeros gives zeros: only the model's rectangle, with the kernels'
//! reach around it, needs the work. Each pass runs the whole-image code on a crop that reaches
//! twice the kernel's radius beyond the nonzero values (or to the image's border), where the
//! crop's reflect-101 border repeats only zeros, so the results equal the whole-image passes'
//! bit for bit (unit tests below).

use super::super::gray::{GrayF32, Mask};
use super::{MAX_RADIUS, blur_in_place, erode, gaussian_kernel, mask_pyr_down, pyr_down};

/// A half-open pixel rectangle `[x0, x1) × [y0, y1)`, never empty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Rect {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

impl Rect {
    /// The whole `w × h` image (`None` when it has no pixel).
    pub(crate) fn whole(w: usize, h: usize) -> Option<Self> {
        (w > 0 && h > 0).then_some(Self {
            x0: 0,
            y0: 0,
            x1: w,
            y1: h,
        })
    }

    /// Grown by `m` on every side, clipped to a `w × h` image.
    fn grown(self, m: usize, w: usize, h: usize) -> Self {
        Self {
            x0: self.x0.saturating_sub(m),
            y0: self.y0.saturating_sub(m),
            x1: (self.x1 + m).min(w),
            y1: (self.y1 + m).min(h),
        }
    }

    /// With its start moved down to even coordinates, so that a crop's even samples are the
    /// image's.
    fn even_start(self) -> Self {
        Self {
            x0: self.x0 & !1,
            y0: self.y0 & !1,
            ..self
        }
    }

    /// Whether it covers the whole `w × h` image.
    fn is_whole(&self, w: usize, h: usize) -> bool {
        (self.x0, self.y0, self.x1, self.y1) == (0, 0, w, h)
    }

    /// The same pixels at the next level (coordinates halved; a level's pixel `i` is its
    /// parent's `2i`), for a `w2 × h2` level.
    fn halved(self, w2: usize, h2: usize) -> Self {
        Self {
            x0: self.x0 / 2,
            y0: self.y0 / 2,
            x1: self.x1.div_ceil(2).min(w2),
            y1: self.y1.div_ceil(2).min(h2),
        }
    }
}

/// The bounding rectangle of the pixels of a `w`-wide, row-major image where `nonzero` holds
/// (`None`: none does). `any` tells whether a row has one, cheaply (it vectorises).
fn bounds<T: Copy>(
    data: &[T],
    w: usize,
    any: impl Fn(&[T]) -> bool,
    nonzero: impl Fn(T) -> bool,
) -> Option<Rect> {
    let mut out: Option<Rect> = None;
    for (y, row) in data.chunks_exact(w).enumerate() {
        if !any(row) {
            continue;
        }
        let (lo, hi) = match out {
            // Only the columns outside the rectangle so far can widen it.
            Some(r) => (
                row[..r.x0].iter().position(|&v| nonzero(v)).unwrap_or(r.x0),
                row[r.x1..]
                    .iter()
                    .rposition(|&v| nonzero(v))
                    .map_or(r.x1, |i| r.x1 + i + 1),
            ),
            None => (
                row.iter().position(|&v| nonzero(v)).unwrap_or(0),
                row.iter().rposition(|&v| nonzero(v)).map_or(w, |i| i + 1),
            ),
        };
        out = Some(match out {
            Some(r) => Rect {
                x0: lo,
                x1: hi,
                y1: y + 1,
                ..r
            },
            None => Rect {
                x0: lo,
                y0: y,
                x1: hi,
                y1: y + 1,
            },
        });
    }
    out
}

/// Where `img` is not `+0.0` (a `−0.0` counts as nonzero: the passes would turn it into
/// `+0.0`, so it must stay inside for the bits to agree).
pub(crate) fn image_support(img: &GrayF32) -> Option<Rect> {
    bounds(
        img.data(),
        img.width(),
        |row| row.iter().fold(0u32, |a, v| a | v.to_bits()) != 0,
        |v| v.to_bits() != 0,
    )
}

/// Where `mask` is valid.
pub(crate) fn mask_support(mask: &Mask) -> Option<Rect> {
    let bytes: &[u8] = bytemuck::cast_slice(mask.data());
    bounds(
        bytes,
        mask.width(),
        |row| row.iter().fold(0u8, |a, &v| a | v) != 0,
        |v| v != 0,
    )
}

/// The pixels of `r` out of a `w`-wide image, row-major.
fn crop<T: Copy>(data: &[T], w: usize, r: Rect) -> Vec<T> {
    let mut out = Vec::with_capacity((r.x1 - r.x0) * (r.y1 - r.y0));
    for y in r.y0..r.y1 {
        out.extend_from_slice(&data[y * w + r.x0..y * w + r.x1]);
    }
    out
}

/// `src` (a `cw`-wide crop) written into a `w`-wide image at `(x0, y0)`.
fn paste<T: Copy>(src: &[T], cw: usize, data: &mut [T], w: usize, (x0, y0): (usize, usize)) {
    for (k, row) in src.chunks_exact(cw).enumerate() {
        let at = (y0 + k) * w + x0;
        data[at..at + cw].copy_from_slice(row);
    }
}

/// A `w × h` image of zeros (`false`) with `part` (`pw` wide) written at `at`.
fn placed<T: Copy + Default>(
    part: &[T],
    pw: usize,
    (w, h): (usize, usize),
    at: (usize, usize),
) -> Vec<T> {
    let mut out = vec![T::default(); w * h];
    paste(part, pw, &mut out, w, at);
    out
}

/// [`super::gaussian_blur`] in place of an image that is zero outside `support`; returns where
/// the result can be nonzero.
pub(crate) fn blur_within(img: &mut GrayF32, sigma: f32, support: Option<Rect>) -> Option<Rect> {
    let (w, h) = (img.width(), img.height());
    let kernel = match gaussian_kernel(sigma) {
        Some(k) if k.len() <= MAX_RADIUS + 1 => k,
        // Wider kernels take the reference's path, over the whole image.
        Some(_) => {
            super::blur_image_in_place(img, sigma);
            return support.and(Rect::whole(w, h));
        }
        None => return support,
    };
    let support = support?;
    let r = kernel.len() - 1;
    let c = support.grown(2 * r, w, h);
    if c.is_whole(w, h) {
        blur_in_place(img.data_mut(), w, h, &kernel);
    } else {
        let cw = c.x1 - c.x0;
        let mut part = crop(img.data(), w, c);
        blur_in_place(&mut part, cw, c.y1 - c.y0, &kernel);
        paste(&part, cw, img.data_mut(), w, (c.x0, c.y0));
    }
    Some(support.grown(r, w, h))
}

/// [`pyr_down`] of an image that is zero outside `support`, and where the result can be
/// nonzero.
pub(crate) fn pyr_down_within(img: &GrayF32, support: Option<Rect>) -> (GrayF32, Option<Rect>) {
    let (w, h) = (img.width(), img.height());
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let Some(support) = support else {
        let zeros = GrayF32::new(w2, h2, vec![0.0; w2 * h2]).unwrap_or_else(|_| img.clone());
        return (zeros, None);
    };
    // The binomial kernel's radius is 2.
    let next = support.grown(2, w, h).halved(w2, h2);
    let c = support.grown(4, w, h).even_start();
    if c.is_whole(w, h) {
        return (pyr_down(img), Some(next));
    }
    let part = GrayF32::new(c.x1 - c.x0, c.y1 - c.y0, crop(img.data(), w, c));
    let Ok(part) = part else {
        return (pyr_down(img), Some(next));
    };
    let down = pyr_down(&part);
    let out = placed(down.data(), down.width(), (w2, h2), (c.x0 / 2, c.y0 / 2));
    let out = GrayF32::new(w2, h2, out).unwrap_or_else(|_| pyr_down(img));
    (out, Some(next))
}

/// [`erode`] of a mask that is invalid outside `support` (erosion only shrinks it, so the
/// support stays).
pub(crate) fn erode_within(mask: &Mask, r: usize, support: Option<Rect>) -> Mask {
    let (w, h) = (mask.width(), mask.height());
    let Some(support) = support else {
        return mask.clone();
    };
    let c = support.grown(r, w, h);
    if r == 0 || c.is_whole(w, h) {
        return erode(mask, r);
    }
    let cw = c.x1 - c.x0;
    let Ok(part) = Mask::new(cw, c.y1 - c.y0, crop(mask.data(), w, c)) else {
        return erode(mask, r);
    };
    let eroded = erode(&part, r);
    let out = placed(eroded.data(), cw, (w, h), (c.x0, c.y0));
    Mask::new(w, h, out).unwrap_or_else(|_| erode(mask, r))
}

/// [`mask_pyr_down`] of a mask that is invalid outside `support`, and where the result can be
/// valid.
pub(crate) fn mask_pyr_down_within(
    mask: &Mask,
    support: Option<Rect>,
) -> Option<(Mask, Option<Rect>)> {
    let (w, h) = (mask.width(), mask.height());
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let Some(support) = support else {
        return Some((Mask::new(w2, h2, vec![false; w2 * h2]).ok()?, None));
    };
    // A coarse pixel is valid only if its own fine pixel is.
    let next = support.halved(w2, h2);
    let c = support.grown(2, w, h).even_start();
    if c.is_whole(w, h) {
        return Some((mask_pyr_down(mask)?, Some(next)));
    }
    let part = Mask::new(c.x1 - c.x0, c.y1 - c.y0, crop(mask.data(), w, c)).ok()?;
    let down = mask_pyr_down(&part)?;
    let out = placed(down.data(), down.width(), (w2, h2), (c.x0 / 2, c.y0 / 2));
    Some((Mask::new(w2, h2, out).ok()?, Some(next)))
}

#[cfg(test)]
mod tests {
    use super::super::tests::lcg;
    use super::super::{MaskPyramid, Pyramid, blur_image_in_place};
    use super::*;

    /// A `w × h` image, zero outside a random rectangle (sometimes touching the borders,
    /// sometimes empty), random values and a few `−0.0` inside; and its mask, valid only
    /// inside the rectangle.
    fn case(seed: &mut u64, w: usize, h: usize) -> (GrayF32, Mask) {
        let pick = |seed: &mut u64, n: usize| (lcg(seed) as usize) % (n + 1);
        let (a, b) = (pick(seed, w), pick(seed, w));
        let (c, d) = (pick(seed, h), pick(seed, h));
        let (x0, x1) = (a.min(b), a.max(b));
        let (y0, y1) = (c.min(d), c.max(d));
        // Half the masks are wholly valid inside: their coarse levels reach the support's edge.
        let dense = lcg(seed).is_multiple_of(2);
        let mut data = vec![0f32; w * h];
        let mut valid = vec![false; w * h];
        for y in y0..y1 {
            for x in x0..x1 {
                let v = lcg(seed);
                data[y * w + x] = match v % 13 {
                    0 => -0.0,
                    1 => 0.0,
                    _ => (v % 2560) as f32 / 10.0,
                };
                valid[y * w + x] = dense || !v.is_multiple_of(7);
            }
        }
        (
            GrayF32::new(w, h, data).unwrap(),
            Mask::new(w, h, valid).unwrap(),
        )
    }

    fn same_bits(a: &GrayF32, b: &GrayF32, what: &str) {
        assert_eq!((a.width(), a.height()), (b.width(), b.height()), "{what}");
        for (i, (x, y)) in a.data().iter().zip(b.data()).enumerate() {
            assert_eq!(
                x.to_bits(),
                y.to_bits(),
                "{what}: pixel {i}: {x} against {y}"
            );
        }
    }

    /// The support is the bounding box of the nonzero bits.
    #[test]
    fn supports_bound_the_nonzero_values() {
        let mut seed = 7;
        for (w, h) in [(1, 1), (5, 3), (17, 9), (40, 33)] {
            for _ in 0..20 {
                let (img, mask) = case(&mut seed, w, h);
                let check = |support: Option<Rect>, nonzero: &dyn Fn(usize) -> bool| {
                    let got: Vec<usize> = (0..w * h).filter(|&i| nonzero(i)).collect();
                    match support {
                        None => assert!(got.is_empty()),
                        Some(r) => {
                            let (xs, ys): (Vec<_>, Vec<_>) =
                                got.iter().map(|i| (i % w, i / w)).unzip();
                            let want = Rect {
                                x0: *xs.iter().min().unwrap(),
                                y0: *ys.iter().min().unwrap(),
                                x1: xs.iter().max().unwrap() + 1,
                                y1: ys.iter().max().unwrap() + 1,
                            };
                            assert_eq!(r, want);
                        }
                    }
                };
                check(image_support(&img), &|i| img.data()[i].to_bits() != 0);
                check(mask_support(&mask), &|i| mask.data()[i]);
            }
        }
    }

    /// Blur, pyramid, erosion and mask pyramid within the support equal the whole-image
    /// passes bit for bit, for every kind of support and the kernels the tracker uses.
    #[test]
    fn passes_within_the_support_equal_the_whole_image_passes() {
        let mut seed = 11;
        for (w, h) in [
            (1, 1),
            (3, 2),
            (8, 8),
            (9, 17),
            (23, 40),
            (64, 48),
            (75, 61),
        ] {
            for _ in 0..12 {
                let (img, mask) = case(&mut seed, w, h);
                for sigma in [0.0, 0.7, 1.0, std::f32::consts::SQRT_2, 2.5, 6.0] {
                    let mut whole = img.clone();
                    blur_image_in_place(&mut whole, sigma);
                    let mut within = img.clone();
                    let support = blur_within(&mut within, sigma, image_support(&img));
                    same_bits(&within, &whole, &format!("blur σ {sigma} {w}×{h}"));
                    assert_eq!(support.is_none(), image_support(&whole).is_none());
                    let a = Pyramid::build(whole, 4);
                    let b = Pyramid::build_within(within, 4, support);
                    assert_eq!(a.len(), b.len());
                    for (k, (x, y)) in a.levels().iter().zip(b.levels()).enumerate() {
                        same_bits(y, x, &format!("level {k}, σ {sigma}, {w}×{h}"));
                    }
                }
                for r in 0..4 {
                    let whole = erode(&mask, r);
                    let within = erode_within(&mask, r, mask_support(&mask));
                    assert_eq!(within, whole, "erosion {r}, {w}×{h}");
                    let a = MaskPyramid::build(whole, 4);
                    let b = MaskPyramid::build_within(within, 4, mask_support(&mask));
                    assert_eq!(a.len(), b.len());
                    for k in 0..a.len() {
                        assert_eq!(a.level(k), b.level(k), "mask level {k}, {w}×{h}");
                    }
                }
            }
        }
    }
}
