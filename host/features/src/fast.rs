//! FAST-9 corners (Rosten & Drummond), the standard definition that OpenCV's
//! `FastFeatureDetector` (`TYPE_9_16`) implements, so that the same threshold finds the same
//! corners with the same scores.
//!
//! - Circle: the 16 pixels of the Bresenham circle of radius 3 around `p`.
//! - Segment test: `p` is a corner if 9 contiguous circle pixels (with wrap-around) are all
//!   brighter than `I(p) + t` or all darker than `I(p) − t` (strict).
//! - Score: the largest threshold at which `p` still passes the strict segment test, i.e.
//!   `max over the 16 arcs of 9 of (min over the arc of |I(x) − I(p)|, same sign) − 1`.
//! - Non-maximum suppression: a corner survives if its score is strictly greater than the
//!   score of each of its 8 neighbours (0 where there is no corner).
//! - Candidates: pixels at least 3 from every border.
//!
//! The implementation works a row at a time on 16 pixels at once (32 with AVX2, chosen at run time)
//! in saturating `u8` arithmetic (docs/VISION.md §4 gives the formulation and why it equals the
//! definition); [`reference`] is the plain per-pixel version it is tested against.

use image::GrayImage;
use isa::U8Lanes;
use wide::u8x16;

pub mod reference;

/// The circle, `(dx, dy)`, in OpenCV's order (starting below the centre, counter-clockwise in
/// image coordinates), so arcs and scores are those of the reference implementation.
pub const CIRCLE: [(i32, i32); 16] = [
    (0, 3),
    (1, 3),
    (2, 2),
    (3, 1),
    (3, 0),
    (3, -1),
    (2, -2),
    (1, -3),
    (0, -3),
    (-1, -3),
    (-2, -2),
    (-3, -1),
    (-3, 0),
    (-3, 1),
    (-2, 2),
    (-1, 3),
];

/// Length of the contiguous arc the segment test asks for.
pub const ARC: usize = 9;

/// Circle radius: no candidate lies closer than this to a border.
pub const RADIUS: usize = 3;

/// One FAST corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Corner {
    /// Column, px.
    pub x: u32,
    /// Row, px.
    pub y: u32,
    /// Score (see the module documentation); ≥ the detection threshold.
    pub score: u16,
}

/// The 7 image rows `y − 3 ..= y + 3` around row `y`.
type Rows<'a> = [&'a [u8]; 2 * RADIUS + 1];

/// Circle pixel `k` of the `V::LANES` pixels of a chunk, from the chunk's 7 row windows.
#[inline(always)]
fn circle_at<V: U8Lanes>(isa: V::Isa, win: &Rows<'_>, k: usize) -> V {
    let (dx, dy) = CIRCLE[k];
    let row = win[(dy + RADIUS as i32) as usize];
    V::load(isa, &row[(dx + RADIUS as i32) as usize..])
}

/// The strength of `V::LANES` pixels at once (see [`strength_scalar`]), or `None` when the
/// compass test rejects them all (the common case, and the reason this path is fast). `win`:
/// the chunk's 7 row windows, each the chunk and `RADIUS` on either side.
///
/// Every difference is a saturating `u8` subtraction: `c ⊖ v` is `c − v` where `c` is brighter
/// and 0 otherwise, so a minimum over an arc is positive only if the whole arc is brighter,
/// exactly the reference's signed arithmetic clamped at 0 (where it starts its maximum).
#[inline(always)]
fn strength_chunk<V: U8Lanes>(isa: V::Isa, win: &Rows<'_>, t: V) -> Option<V> {
    let zero = V::splat(isa, 0);
    let v = V::load(isa, &win[RADIUS][RADIUS..]);
    // Compass points 0, 4, 8, 12: an arc of 9 contains two of them that are neighbours in
    // that order, so a pixel where no such pair is on one side (beyond t) is no corner. As in
    // OpenCV's vector path, this rejects most chunks after a handful of operations.
    let hi = v.saturating_add(t);
    let lo = v.saturating_sub(t);
    // Called out one by one: a closure (`array::map`) would not be inlined, and would run
    // the baseline's code in the AVX2 copy.
    let (c0, c4, c8, c12) = (
        circle_at::<V>(isa, win, 0),
        circle_at::<V>(isa, win, 4),
        circle_at::<V>(isa, win, 8),
        circle_at::<V>(isa, win, 12),
    );
    let (b0, b4, b8, b12) = (
        c0.saturating_sub(hi),
        c4.saturating_sub(hi),
        c8.saturating_sub(hi),
        c12.saturating_sub(hi),
    );
    let (d0, d4, d8, d12) = (
        lo.saturating_sub(c0),
        lo.saturating_sub(c4),
        lo.saturating_sub(c8),
        lo.saturating_sub(c12),
    );
    let pair = (b0.min(b4).max(b4.min(b8)).max(b8.min(b12)).max(b12.min(b0))).or(d0
        .min(d4)
        .max(d4.min(d8))
        .max(d8.min(d12))
        .max(d12.min(d0)));
    if pair.all_zero() {
        return None;
    }
    // Per polarity, the best arc's weakest pixel: `c ↦ c ⊖ v` rises and `c ↦ v ⊖ c` falls with
    // `c`, so they commute with min and max, and
    // max over arcs of min over the arc of (c ⊖ v) = (max over arcs of min over the arc of c) ⊖ v,
    // max over arcs of min over the arc of (v ⊖ c) = v ⊖ (min over arcs of max over the arc of c):
    // sliding minima and maxima of the raw circle (windows of 2, 4, 8, then 8 + 1 by doubling,
    // with wrap-around), and two subtractions instead of 32.
    // Plain loops of constant length, which unroll, rather than `array::from_fn`: that one
    // stayed a call (compiled for the baseline even in the AVX2 copy) or a loop reading
    // `CIRCLE` at run time (FAST took 15 % longer).
    let mut c = [zero; 16];
    for (k, c) in c.iter_mut().enumerate() {
        *c = circle_at(isa, win, k);
    }
    let (mut lo2, mut hi2) = ([zero; 16], [zero; 16]);
    for k in 0..16 {
        lo2[k] = c[k].min(c[(k + 1) & 15]);
        hi2[k] = c[k].max(c[(k + 1) & 15]);
    }
    let (mut lo4, mut hi4) = ([zero; 16], [zero; 16]);
    for k in 0..16 {
        lo4[k] = lo2[k].min(lo2[(k + 2) & 15]);
        hi4[k] = hi2[k].max(hi2[(k + 2) & 15]);
    }
    let (mut lo8, mut hi8) = ([zero; 16], [zero; 16]);
    for k in 0..16 {
        lo8[k] = lo4[k].min(lo4[(k + 4) & 15]);
        hi8[k] = hi4[k].max(hi4[(k + 4) & 15]);
    }
    let (mut max_of_min, mut min_of_max) = (zero, V::splat(isa, u8::MAX));
    for k in 0..16 {
        max_of_min = max_of_min.max(lo8[k].min(c[(k + 8) & 15]));
        min_of_max = min_of_max.min(hi8[k].max(c[(k + 8) & 15]));
    }
    let bright = max_of_min.saturating_sub(v);
    let dark = v.saturating_sub(min_of_max);
    let s = bright.max(dark);
    // A corner at t has an arc whose every difference exceeds t: s > t. Others get 0.
    Some(s.where_nonzero(s.saturating_sub(t)))
}

/// The strength of one pixel: 0 if it fails the segment test at `t`, otherwise the largest
/// `m` such that 9 contiguous circle pixels all differ from it by at least `m` on the same
/// side (so `m > t`, and the score is `m − 1`). The scalar twin of [`strength_chunk`], for rows
/// with fewer than 16 candidate pixels.
fn strength_scalar(rows: &Rows<'_>, x: usize, t: u8) -> u8 {
    let v = rows[RADIUS][x];
    let circle: [u8; 16] = std::array::from_fn(|k| {
        let (dx, dy) = CIRCLE[k];
        rows[(dy + RADIUS as i32) as usize][(x as i32 + dx) as usize]
    });
    let best = |diff: [u8; 16]| {
        (0..16)
            .map(|s| (0..ARC).map(|k| diff[(s + k) & 15]).min().unwrap_or(0))
            .max()
            .unwrap_or(0)
    };
    let s =
        best(circle.map(|c| c.saturating_sub(v))).max(best(circle.map(|c| v.saturating_sub(c))));
    if s > t { s } else { 0 }
}

isa::dispatch! {
    /// Strengths of one row (`out`, the image's width; 0 on the 3-pixel borders), and the
    /// columns where they are non-zero, ascending, appended to `corners`: 32 pixels at a time
    /// with AVX2, 16 without (the same values).
    fn strength_row(rows: &Rows<'_>, t: u8, out: &mut [u8], corners: &mut Vec<u32>) {
        baseline => strength_row_with::<u8x16>((), rows, t, out, corners),
        avx2(proof) => strength_row_with::<isa::U8x32>(proof, rows, t, out, corners),
    }
}

/// [`strength_row`] with `V::LANES` pixels a step.
#[inline(always)]
fn strength_row_with<V: U8Lanes>(
    isa: V::Isa,
    rows: &Rows<'_>,
    t: u8,
    out: &mut [u8],
    corners: &mut Vec<u32>,
) {
    let w = out.len();
    out.fill(0);
    let end = w - RADIUS;
    if end - RADIUS < V::LANES {
        for (x, s) in out.iter_mut().enumerate().take(end).skip(RADIUS) {
            *s = strength_scalar(rows, x, t);
            if *s != 0 {
                corners.push(x as u32);
            }
        }
        return;
    }
    let tv = V::splat(isa, t);
    let span = V::LANES + 2 * RADIUS;
    // Chunks from x = 3; the last one is moved left to end at the border (overlapping its
    // predecessor, whose lanes it recomputes identically) so no pixel needs a scalar tail.
    let mut x0 = RADIUS;
    let mut done = RADIUS;
    while done < end {
        x0 = x0.min(end - V::LANES);
        // Each window exactly `span` long, so the loads' bounds checks fold away.
        let at = |j: usize| &rows[j][x0 - RADIUS..x0 - RADIUS + span];
        // Written out rather than `array::from_fn`: built for AVX2, the compiler kept that
        // one as a loop of seven, and FAST took 15 % longer.
        let win = [at(0), at(1), at(2), at(3), at(4), at(5), at(6)];
        if let Some(s) = strength_chunk(isa, &win, tv) {
            s.store(&mut out[x0..]);
            // Non-zero lanes, less those the previous, overlapping chunk already reported.
            let mut bits = s.nonzero_bits() & (u64::MAX << (done - x0));
            while bits != 0 {
                corners.push((x0 + bits.trailing_zeros() as usize) as u32);
                bits &= bits - 1;
            }
        }
        done = x0 + V::LANES;
        x0 += V::LANES;
    }
}

/// The 7 rows around row `y` of a `w`-wide image.
fn rows_around(raw: &[u8], w: usize, y: usize) -> Rows<'_> {
    std::array::from_fn(|j| &raw[(y + j - RADIUS) * w..(y + j - RADIUS + 1) * w])
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
    let mut row = vec![0u8; w];
    let mut columns = Vec::new();
    for y in RADIUS..h - RADIUS {
        columns.clear();
        strength_row(&rows_around(raw, w, y), threshold, &mut row, &mut columns);
        for &x in &columns {
            scores[y * w + x as usize] = u16::from(row[x as usize] - 1);
        }
    }
    scores
}

/// FAST-9 corners with `threshold`, optionally non-maximum suppressed, in row-major order.
///
/// One pass over the rows: each row's strengths go into a ring of three rows, and a row's
/// corners are suppressed (or not) as soon as the row below it is known, so there is no
/// full-image score map.
pub fn detect(img: &GrayImage, threshold: u8, nonmax_suppression: bool) -> Vec<Corner> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mut out = Vec::new();
    if w < 2 * RADIUS + 1 || h < 2 * RADIUS + 1 {
        return out;
    }
    let raw = img.as_raw();
    let corner = |x: u32, y: usize, strength: u8| Corner {
        x,
        y: y as u32,
        score: u16::from(strength - 1),
    };
    if !nonmax_suppression {
        let mut row = vec![0u8; w];
        let mut columns = Vec::new();
        for y in RADIUS..h - RADIUS {
            columns.clear();
            strength_row(&rows_around(raw, w, y), threshold, &mut row, &mut columns);
            out.extend(columns.iter().map(|&x| corner(x, y, row[x as usize])));
        }
        return out;
    }
    // Ring of three strength rows (above, current, below) with their corner columns; the row
    // above the first candidate row is the border, all zero.
    let mut ring: [(Vec<u8>, Vec<u32>); 3] = std::array::from_fn(|_| (vec![0u8; w], Vec::new()));
    let suppress = |above: &[u8],
                    (here, columns): &(Vec<u8>, Vec<u32>),
                    below: &[u8],
                    y: usize,
                    out: &mut Vec<Corner>| {
        for &x in columns {
            let x = x as usize;
            let s = here[x];
            // Strict maximum of the scores s − 1 (0 for non-corners): a score-0 corner (s = 1)
            // never is one, and otherwise comparing strengths is comparing scores.
            if s >= 2
                && above[x - 1..=x + 1].iter().all(|&n| n < s)
                && below[x - 1..=x + 1].iter().all(|&n| n < s)
                && here[x - 1] < s
                && here[x + 1] < s
            {
                out.push(corner(x as u32, y, s));
            }
        }
    };
    for y in RADIUS..h - RADIUS {
        let (row, columns) = &mut ring[y % 3];
        columns.clear();
        strength_row(&rows_around(raw, w, y), threshold, row, columns);
        if y > RADIUS {
            let [a, b, c] = [(y - 2) % 3, (y - 1) % 3, y % 3];
            suppress(&ring[a].0, &ring[b], &ring[c].0, y - 1, &mut out);
        }
    }
    let last = h - RADIUS - 1;
    let zero = vec![0u8; w];
    suppress(
        &ring[(last + 2) % 3].0,
        &ring[last % 3],
        &zero,
        last,
        &mut out,
    );
    out
}
