//! The scalar FAST-9 implementation, pixel by pixel, straight from the definition in the parent
//! module: kept as the reference the vectorised path in [`super`] is tested against (same
//! corners, same scores), and as the readable statement of what that path computes.

use image::GrayImage;

use super::{ARC, CIRCLE, Corner, RADIUS};

/// Bit `k` set where circle pixel `k` is brighter than `v + t` (`bright`) or darker than
/// `v − t` (`dark`).
#[inline]
fn classify(circle: &[i16; 16], v: i16, t: i16) -> (u32, u32) {
    let mut bright = 0u32;
    let mut dark = 0u32;
    for (k, &c) in circle.iter().enumerate() {
        bright |= ((c > v + t) as u32) << k;
        dark |= ((c < v - t) as u32) << k;
    }
    (bright, dark)
}

/// Whether a 16-bit circular set has `ARC` contiguous members.
#[inline]
fn has_arc(bits: u32) -> bool {
    // Unroll the circle twice so that arcs crossing bit 15 → 0 are plain runs, then AND the
    // shifted copies: runs of 2, 4, 8, then 8 + 1 = 9.
    let m = bits | (bits << 16);
    let r2 = m & (m >> 1);
    let r4 = r2 & (r2 >> 2);
    let r8 = r4 & (r4 >> 4);
    (r8 & (m >> 8)) != 0
}

/// Score of a pixel that passed the segment test: the largest `t` for which it still passes.
#[inline]
fn score(circle: &[i16; 16], v: i16) -> u16 {
    let mut best = 0i16;
    for start in 0..16 {
        let mut min_bright = i16::MAX;
        let mut min_dark = i16::MAX;
        for k in 0..ARC {
            let c = circle[(start + k) & 15];
            min_bright = min_bright.min(c - v);
            min_dark = min_dark.min(v - c);
        }
        best = best.max(min_bright).max(min_dark);
    }
    // Strict test: passing at t needs every difference > t, so the largest such t is one less.
    (best - 1).max(0) as u16
}

#[inline]
fn load_circle(raw: &[u8], width: usize, x: usize, y: usize) -> [i16; 16] {
    let mut circle = [0i16; 16];
    for (c, &(dx, dy)) in circle.iter_mut().zip(CIRCLE.iter()) {
        let xx = (x as i32 + dx) as usize;
        let yy = (y as i32 + dy) as usize;
        *c = raw[yy * width + xx] as i16;
    }
    circle
}

/// Dense score map: the FAST score where the segment test passes with `threshold`, 0 elsewhere
/// (and on the 3-pixel border). Row-major, the image's size.
pub fn score_map(img: &GrayImage, threshold: u8) -> Vec<u16> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mut scores = vec![0u16; w * h];
    if w < 2 * RADIUS + 1 || h < 2 * RADIUS + 1 {
        return scores;
    }
    let raw = img.as_raw();
    let t = threshold as i16;
    let stride = w as isize;
    // Compass points 0, 4, 8, 12 of the circle: any arc of 9 covers at least two of them, so a
    // pixel with fewer than two of them on one side cannot be a corner (cheap rejection).
    let compass = [3 * stride, 3, -3 * stride, -3];
    for y in RADIUS..h - RADIUS {
        for x in RADIUS..w - RADIUS {
            let i = (y * w + x) as isize;
            let v = raw[i as usize] as i16;
            let (mut nb, mut nd) = (0, 0);
            for off in compass {
                let c = raw[(i + off) as usize] as i16;
                nb += (c > v + t) as u32;
                nd += (c < v - t) as u32;
            }
            if nb < 2 && nd < 2 {
                continue;
            }
            let circle = load_circle(raw, w, x, y);
            let (bright, dark) = classify(&circle, v, t);
            if has_arc(bright) || has_arc(dark) {
                // A corner scores ≥ threshold; 0 is reserved for "no corner" (threshold 0
                // corners of score 0 then behave as in OpenCV: they never beat a neighbour).
                scores[y * w + x] = score(&circle, v);
            }
        }
    }
    scores
}

/// Whether pixel `(x, y)` of a score map is a strict 3×3 maximum.
#[inline]
fn is_local_max(scores: &[u16], w: usize, x: usize, y: usize) -> bool {
    let s = scores[y * w + x];
    for yy in y - 1..=y + 1 {
        for xx in x - 1..=x + 1 {
            if (xx, yy) != (x, y) && scores[yy * w + xx] >= s {
                return false;
            }
        }
    }
    true
}

/// FAST-9 corners with `threshold`, optionally non-maximum suppressed, in row-major order.
pub fn detect(img: &GrayImage, threshold: u8, nonmax_suppression: bool) -> Vec<Corner> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let scores = score_map(img, threshold);
    let mut out = Vec::new();
    if w < 2 * RADIUS + 1 || h < 2 * RADIUS + 1 {
        return out;
    }
    let raw = img.as_raw();
    let t = threshold as i16;
    for y in RADIUS..h - RADIUS {
        for x in RADIUS..w - RADIUS {
            let s = scores[y * w + x];
            // A zero score is no corner, or a threshold-0 corner of score 0 (never a strict
            // maximum, so only kept without suppression): tell those apart only then.
            if s == 0 {
                if nonmax_suppression || t > 0 {
                    continue;
                }
                let circle = load_circle(raw, w, x, y);
                let (bright, dark) = classify(&circle, raw[y * w + x] as i16, t);
                if !(has_arc(bright) || has_arc(dark)) {
                    continue;
                }
            }
            if !nonmax_suppression || is_local_max(&scores, w, x, y) {
                out.push(Corner {
                    x: x as u32,
                    y: y as u32,
                    score: s,
                });
            }
        }
    }
    out
}
