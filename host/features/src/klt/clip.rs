//! Where the live camera's clipping reaches the smoothed live pyramid (docs/VISION.md §5,
//! eq. 5.6).
//!
//! A raw live pixel at a clip level (0 or 255 for an 8-bit camera) says only that the scene
//! was at least that bright (or at most that dark). The registration samples the live image
//! after its Gaussian smoothing and pyramid reduction, so a clipped raw pixel affects every
//! smoothed pixel whose support holds it. For each level, the map says which smoothed pixels
//! high ([`HIGH`]) or low ([`LOW`]) clipping reaches; where it reaches a window, the
//! registration clips its prediction (`Window::accumulate`).

use super::super::gray::GrayF32;

/// Flag: a raw pixel at the upper clip level lies in the pixel's support.
pub const HIGH: u8 = 1;
/// Flag: a raw pixel at the lower clip level lies in the pixel's support.
pub const LOW: u8 = 2;

/// Side of the blocks of [`ClipLevel::any_in`]'s summary, px.
const BLOCK: usize = 8;

/// The flags of one pyramid level.
#[derive(Debug, Clone)]
pub struct ClipLevel {
    width: usize,
    height: usize,
    flags: Vec<u8>,
    /// OR of the flags per `BLOCK × BLOCK` block, so that a window far from any clipping is
    /// recognised with a few look-ups.
    blocks: Vec<u8>,
    bw: usize,
    /// The clip levels `[lo, hi]`.
    range: [f32; 2],
}

impl ClipLevel {
    fn new(width: usize, height: usize, flags: Vec<u8>, range: [f32; 2]) -> Self {
        let (bw, bh) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
        let mut blocks = vec![0u8; bw * bh];
        for (y, row) in flags.chunks_exact(width.max(1)).enumerate() {
            let brow = &mut blocks[(y / BLOCK) * bw..(y / BLOCK + 1) * bw];
            for (b, chunk) in brow.iter_mut().zip(row.chunks(BLOCK)) {
                *b |= chunk.iter().fold(0, |a, &f| a | f);
            }
        }
        Self {
            width,
            height,
            flags,
            blocks,
            bw,
            range,
        }
    }

    /// The clip levels `[lo, hi]`, gray levels.
    pub fn range(&self) -> [f32; 2] {
        self.range
    }

    /// Width of the level.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height of the level.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The flags of pixel `(x, y)` (0 outside the level).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> u8 {
        if x < self.width && y < self.height {
            self.flags[y * self.width + x]
        } else {
            0
        }
    }

    /// Whether any pixel of the rectangle `x0..=x1, y0..=y1` may be flagged (a block-level
    /// test: `false` is exact, `true` may be a neighbour's).
    #[inline]
    pub fn any_in(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> bool {
        if self.width == 0 || self.height == 0 || x0 > x1 || y0 > y1 {
            return false;
        }
        let (x1, y1) = (x1.min(self.width - 1), y1.min(self.height - 1));
        (y0 / BLOCK..=y1 / BLOCK).any(|by| {
            self.blocks[by * self.bw + x0 / BLOCK..=by * self.bw + x1 / BLOCK]
                .iter()
                .any(|&b| b != 0)
        })
    }
}

/// The flags of every level of a live pyramid (see the module documentation).
#[derive(Debug, Clone)]
pub struct ClipMap {
    levels: Vec<ClipLevel>,
}

impl ClipMap {
    /// The flags of the raw live image `raw` (before smoothing): [`HIGH`] where a pixel is at
    /// the clip level `hi`, [`LOW`] at `lo` (exactly: an image that was never clipped has no
    /// reason to hold those values); `None` when no pixel is.
    pub fn raw_flags(raw: &GrayF32, lo: f32, hi: f32) -> Option<Vec<u8>> {
        let flags: Vec<u8> = raw
            .data()
            .iter()
            .map(|&v| (u8::from(v == hi) * HIGH) | (u8::from(v == lo) * LOW))
            .collect();
        flags.iter().any(|&f| f != 0).then_some(flags)
    }

    /// The map for a pyramid whose level 0 is the raw image of `raw_flags` (`sizes[0]`, see
    /// [`ClipMap::raw_flags`]) smoothed with a kernel of radius `radius`, and whose level
    /// sizes are `sizes`; `range` the clip levels `[lo, hi]`; `None` if the sizes do not match.
    pub fn build(
        raw_flags: &[u8],
        range: [f32; 2],
        radius: usize,
        sizes: &[(usize, usize)],
    ) -> Option<Self> {
        let &(w, h) = sizes.first()?;
        if w == 0 || h == 0 || raw_flags.len() != w * h {
            return None;
        }
        // Level 0: the smoothing's square support.
        let mut flags = dilate(raw_flags, w, h, radius);
        let mut levels = vec![ClipLevel::new(w, h, flags.clone(), range)];
        let (mut cw, mut ch) = (w, h);
        for &(w2, h2) in &sizes[1..] {
            // `pyr_down`'s 5×5 binomial support around (2x, 2y).
            if w2 == 0 || h2 == 0 {
                return None;
            }
            let d = dilate(&flags, cw, ch, 2);
            let mut next = vec![0u8; w2 * h2];
            for (y2, row) in next.chunks_exact_mut(w2).enumerate() {
                let src = &d[(2 * y2).min(ch - 1) * cw..];
                for (x2, f) in row.iter_mut().enumerate() {
                    *f = src[(2 * x2).min(cw - 1)];
                }
            }
            levels.push(ClipLevel::new(w2, h2, next.clone(), range));
            (flags, cw, ch) = (next, w2, h2);
        }
        Some(Self { levels })
    }

    /// Level `k`.
    pub fn level(&self, k: usize) -> Option<&ClipLevel> {
        self.levels.get(k)
    }
}

/// OR of the flags over the `(2r + 1)²` square around each pixel (clamped at the borders).
fn dilate(flags: &[u8], w: usize, h: usize, r: usize) -> Vec<u8> {
    if r == 0 {
        return flags.to_vec();
    }
    let mut rows = vec![0u8; w * h];
    for (src, dst) in flags.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        if src.iter().all(|&f| f == 0) {
            continue;
        }
        // Shifted copies OR-ed whole (vectorised by the compiler).
        dst.copy_from_slice(src);
        for k in 1..=r.min(w - 1) {
            for (d, &s) in dst[k..].iter_mut().zip(&src[..w - k]) {
                *d |= s;
            }
            for (d, &s) in dst[..w - k].iter_mut().zip(&src[k..]) {
                *d |= s;
            }
        }
    }
    let mut out = vec![0u8; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        let dst = &mut out[y * w..(y + 1) * w];
        for yy in a..=b {
            for (d, &s) in dst.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
                *d |= s;
            }
        }
    }
    out
}
