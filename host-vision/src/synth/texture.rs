//! Procedural textures with natural-image statistics and no repetition.
//!
//! Two ingredients, both generated over the whole surface at once (nothing tiles, so nothing
//! aliases into false matches):
//! - fractal value noise: hashed lattice values per octave, amplitude falling as 1/f, for
//!   plaster, floors and shading;
//! - a *dead-leaves* layer: opaque discs, ellipses and rotated rectangles with power-law
//!   sizes painted over one another, the classic model of natural images' scale invariance,
//!   which also gives the corners FAST needs.
//!
//! Sizes are in metres (through `texels_per_metre`), so detail scales with the surface.
//! Edges are anti-aliased (coverage from the signed distance) so a texture does not alias
//! when it is rendered either.

use firmware_sim::sim::scenario::Surface;
use image::{Rgba, RgbaImage};

/// SplitMix64: a fast, well-mixed hash of one 64-bit word.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A deterministic stream of uniform numbers.
struct Stream(u64);

impl Stream {
    fn next(&mut self) -> f64 {
        self.0 = mix(self.0);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// Lattice value in [-1, 1] at integer `(x, y)` of octave `o`.
fn lattice(seed: u64, o: u32, x: i64, y: i64) -> f64 {
    let h = mix(seed ^ mix((o as u64) << 48 ^ mix(x as u64 ^ mix(y as u64))));
    (h >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

fn smooth(t: f64) -> f64 {
    t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
}

/// Smoothly interpolated value noise at `(x, y)` in lattice units.
fn value_noise(seed: u64, o: u32, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (smooth(x - x0), smooth(y - y0));
    let (ix, iy) = (x0 as i64, y0 as i64);
    let a = lattice(seed, o, ix, iy);
    let b = lattice(seed, o, ix + 1, iy);
    let c = lattice(seed, o, ix, iy + 1);
    let d = lattice(seed, o, ix + 1, iy + 1);
    let top = a + (b - a) * fx;
    let bottom = c + (d - c) * fx;
    top + (bottom - top) * fy
}

/// A greyscale-plus-tint float image being painted.
struct Canvas {
    width: usize,
    height: usize,
    rgb: Vec<[f32; 3]>,
}

impl Canvas {
    fn new(width: u32, height: u32, base: [f32; 3]) -> Self {
        Canvas {
            width: width as usize,
            height: height as usize,
            rgb: vec![base; width as usize * height as usize],
        }
    }

    /// Adds fractal noise of `amplitude` (grey levels at the coarsest octave) with features
    /// from `coarse` down to `fine` texels.
    fn fbm(&mut self, seed: u64, coarse: f64, fine: f64, amplitude: f64, tint: [f32; 3]) {
        let mut octaves = Vec::new();
        let mut period = coarse.max(2.0);
        let mut amp = amplitude;
        while period >= fine.max(1.5) {
            octaves.push((period, amp));
            period /= 2.0;
            amp /= 2.0f64.sqrt();
        }
        for y in 0..self.height {
            for x in 0..self.width {
                let mut v = 0.0;
                for (o, &(p, a)) in octaves.iter().enumerate() {
                    v += a * value_noise(seed, o as u32, x as f64 / p, y as f64 / p);
                }
                let px = &mut self.rgb[y * self.width + x];
                for c in 0..3 {
                    px[c] += (v as f32) * tint[c];
                }
            }
        }
    }

    /// Paints a shape given by its signed distance (texels, negative inside) over the box
    /// `[x0, x1) × [y0, y1)`, blending by the anti-aliased coverage.
    fn paint(
        &mut self,
        bbox: (f64, f64, f64, f64),
        colour: [f32; 3],
        opacity: f32,
        sd: impl Fn(f64, f64) -> f64,
    ) {
        let x0 = bbox.0.floor().max(0.0) as usize;
        let y0 = bbox.1.floor().max(0.0) as usize;
        let x1 = (bbox.2.ceil().max(0.0) as usize).min(self.width);
        let y1 = (bbox.3.ceil().max(0.0) as usize).min(self.height);
        for y in y0..y1 {
            for x in x0..x1 {
                let cov = (0.5 - sd(x as f64, y as f64)).clamp(0.0, 1.0) as f32 * opacity;
                if cov > 0.0 {
                    let px = &mut self.rgb[y * self.width + x];
                    for c in 0..3 {
                        px[c] += (colour[c] - px[c]) * cov;
                    }
                }
            }
        }
    }

    /// Dead leaves: `count` shapes with radii from `r_min` to `r_max` texels, density ∝ r⁻³,
    /// inside the region `(x0, y0, x1, y1)`.
    fn dead_leaves(
        &mut self,
        rng: &mut Stream,
        region: (f64, f64, f64, f64),
        count: usize,
        r_min: f64,
        r_max: f64,
        palette: &dyn Fn(&mut Stream) -> [f32; 3],
    ) {
        let (r_min, r_max) = (r_min.max(0.7), r_max.max(r_min.max(0.7) + 0.1));
        for _ in 0..count {
            // Inverse-CDF sample of p(r) ∝ r⁻³ on [r_min, r_max].
            let u = rng.next();
            let a = 1.0 / (r_min * r_min);
            let b = 1.0 / (r_max * r_max);
            let r = 1.0 / (a - u * (a - b)).sqrt();
            let cx = rng.range(region.0, region.2);
            let cy = rng.range(region.1, region.3);
            let colour = palette(rng);
            let kind = rng.next();
            let angle = rng.range(0.0, std::f64::consts::PI);
            let (s, c) = angle.sin_cos();
            let bbox = (cx - r * 1.5, cy - r * 1.5, cx + r * 1.5, cy + r * 1.5);
            if kind < 0.4 {
                self.paint(bbox, colour, 1.0, |x, y| {
                    ((x - cx).powi(2) + (y - cy).powi(2)).sqrt() - r
                });
            } else if kind < 0.85 {
                let (hw, hh) = (r, r * rng.range(0.25, 1.0));
                self.paint(bbox, colour, 1.0, |x, y| {
                    let (dx, dy) = (x - cx, y - cy);
                    let (u, v) = ((c * dx + s * dy).abs() - hw, (-s * dx + c * dy).abs() - hh);
                    let outside = (u.max(0.0).powi(2) + v.max(0.0).powi(2)).sqrt();
                    outside + u.max(v).min(0.0)
                });
            } else {
                // Ellipse: distance approximated by the scaled radius (exact enough for
                // one-texel anti-aliasing).
                let (ra, rb) = (r, r * rng.range(0.3, 0.8));
                self.paint(bbox, colour, 1.0, |x, y| {
                    let (dx, dy) = (x - cx, y - cy);
                    let (u, v) = ((c * dx + s * dy) / ra, (-s * dx + c * dy) / rb);
                    ((u * u + v * v).sqrt() - 1.0) * rb
                });
            }
        }
    }

    /// Lines of "text": short dark dashes in rows, as on posters and labels.
    fn text(&mut self, rng: &mut Stream, region: (f64, f64, f64, f64), line_h: f64) {
        let ink = [30.0, 30.0, 35.0];
        let mut y = region.1 + line_h;
        while y + line_h < region.3 {
            let mut x = region.0 + rng.range(0.0, 2.0 * line_h);
            let end = region.2 - rng.range(0.0, 0.3) * (region.2 - region.0);
            while x < end {
                let w = line_h * rng.range(0.3, 2.5);
                let h = line_h * rng.range(0.5, 0.8);
                let (cx, cy, hw, hh) = (x + w / 2.0, y - h / 2.0, w / 2.0, h / 2.0);
                self.paint(
                    (x - 1.0, y - h - 1.0, x + w + 1.0, y + 1.0),
                    ink,
                    1.0,
                    |px, py| {
                        let (u, v) = ((px - cx).abs() - hw, (py - cy).abs() - hh);
                        u.max(v)
                    },
                );
                x += w + line_h * rng.range(0.3, 1.0);
            }
            y += line_h * rng.range(1.6, 2.2);
        }
    }

    fn into_image(self) -> RgbaImage {
        let (w, h) = (self.width as u32, self.height as u32);
        let mut img = RgbaImage::new(w, h);
        for (px, c) in img.pixels_mut().zip(self.rgb) {
            *px = Rgba([
                c[0].round().clamp(0.0, 255.0) as u8,
                c[1].round().clamp(0.0, 255.0) as u8,
                c[2].round().clamp(0.0, 255.0) as u8,
                255,
            ]);
        }
        img
    }
}

fn grey_palette(lo: f64, hi: f64, tint: f64) -> impl Fn(&mut Stream) -> [f32; 3] {
    move |rng: &mut Stream| {
        let g = rng.range(lo, hi);
        let t = [
            rng.range(-tint, tint),
            rng.range(-tint, tint),
            rng.range(-tint, tint),
        ];
        [(g + t[0]) as f32, (g + t[1]) as f32, (g + t[2]) as f32]
    }
}

/// Texture size in texels for a surface of `size` metres at `texels_per_metre`, at least
/// 16 and at most `max_side` per side.
pub fn texture_size(size: (f64, f64), texels_per_metre: f64, max_side: u32) -> (u32, u32) {
    let side = |m: f64| ((m * texels_per_metre).round() as u32).clamp(16, max_side.max(16));
    (side(size.0), side(size.1))
}

/// A plastered wall with `posters` on it, `width × height` texels for `size` metres.
fn wall(
    seed: u64,
    rng: &mut Stream,
    posters: u32,
    size: (f64, f64),
    (width, height): (u32, u32),
) -> RgbaImage {
    let tpm = width as f64 / size.0.max(1e-6);
    let m = |metres: f64| metres * tpm;
    let (w, h) = (width as f64, height as f64);
    let area = size.0 * size.1;
    let full = (0.0, 0.0, w, h);
    let mut c = Canvas::new(width, height, [196.0, 190.0, 178.0]);
    c.fbm(seed ^ 2, m(1.5), m(0.004), 10.0, [1.0, 1.0, 1.0]);
    // Specks and scuffs on the plaster.
    let specks = (area * 40.0) as usize;
    c.dead_leaves(
        rng,
        full,
        specks,
        m(0.004),
        m(0.03),
        &grey_palette(120.0, 170.0, 10.0),
    );
    let placed = place_posters(rng, posters, size, (w, h), tpm);
    for &r in &placed {
        poster(&mut c, rng, r, tpm);
    }
    c.into_image()
}

/// Where the posters go: 0.35–1.2 m wide at 0.8–2.0 m above the bottom (or anywhere on short
/// surfaces), a few attempts each to avoid overlaps.
fn place_posters(
    rng: &mut Stream,
    posters: u32,
    size: (f64, f64),
    (w, h): (f64, f64),
    tpm: f64,
) -> Vec<(f64, f64, f64, f64)> {
    let m = |metres: f64| metres * tpm;
    let mut placed: Vec<(f64, f64, f64, f64)> = Vec::new();
    for _ in 0..posters {
        // Posters 0.35–1.2 m wide at 0.8–2.0 m above the bottom (or anywhere on
        // short surfaces); a few attempts to avoid overlaps.
        for _attempt in 0..20 {
            let pw = m(rng.range(0.35, 1.2).min(size.0 * 0.4));
            let ph = pw * rng.range(0.6, 1.5);
            let x0 = rng.range(0.0, (w - pw).max(0.0));
            let y0 = rng.range(0.05 * h, (h - ph).max(0.05 * h + 1.0).min(0.95 * h));
            let r = (x0, y0, x0 + pw, (y0 + ph).min(h));
            let overlaps = placed
                .iter()
                .any(|p| r.0 < p.2 && p.0 < r.2 && r.1 < p.3 && p.1 < r.3);
            if !overlaps {
                placed.push(r);
                break;
            }
        }
    }
    placed
}

/// A poster in the rectangle `r` [texels]: paper, a picture and a caption.
fn poster(c: &mut Canvas, rng: &mut Stream, r: (f64, f64, f64, f64), tpm: f64) {
    let m = |metres: f64| metres * tpm;
    let paper = grey_palette(200.0, 250.0, 15.0)(rng);
    c.paint(
        (r.0 - 1.0, r.1 - 1.0, r.2 + 1.0, r.3 + 1.0),
        paper,
        1.0,
        |x, y| {
            let (u, v) = (
                (x - (r.0 + r.2) / 2.0).abs() - (r.2 - r.0) / 2.0,
                (y - (r.1 + r.3) / 2.0).abs() - (r.3 - r.1) / 2.0,
            );
            u.max(v)
        },
    );
    let border = (r.2 - r.0) * 0.06;
    let pic = (
        r.0 + border,
        r.1 + border,
        r.2 - border,
        r.1 + (r.3 - r.1) * 0.62,
    );
    let pic_area = (pic.2 - pic.0) * (pic.3 - pic.1) / (tpm * tpm);
    let n = (pic_area * 3000.0) as usize + 50;
    let inner = (
        pic.0 + m(0.01),
        pic.1 + m(0.01),
        pic.2 - m(0.01),
        pic.3 - m(0.01),
    );
    c.dead_leaves(
        rng,
        inner,
        n,
        m(0.006),
        m(0.12),
        &grey_palette(15.0, 240.0, 60.0),
    );
    let text = (pic.0, pic.3 + border * 0.5, pic.2, r.3 - border * 0.5);
    c.text(rng, text, m(0.018).max(2.0));
}

/// Generates the texture of a `surface` of `size` metres, `width × height` texels.
pub fn generate(
    surface: Surface,
    seed: u64,
    size: (f64, f64),
    width: u32,
    height: u32,
) -> RgbaImage {
    let mut rng = Stream(mix(seed ^ 0x5eed));
    let tpm = width as f64 / size.0.max(1e-6);
    let m = |metres: f64| metres * tpm;
    let (w, h) = (width as f64, height as f64);
    let area = size.0 * size.1;
    let full = (0.0, 0.0, w, h);
    match surface {
        Surface::Target => {
            let mut c = Canvas::new(width, height, [128.0; 3]);
            let n = (area * 60_000.0) as usize + 200;
            c.dead_leaves(
                &mut rng,
                (-m(0.02), -m(0.02), w + m(0.02), h + m(0.02)),
                n,
                m(0.0015),
                m(0.05),
                &grey_palette(10.0, 245.0, 40.0),
            );
            c.fbm(seed ^ 1, m(0.1), m(0.003), 18.0, [1.0, 1.0, 1.0]);
            c.into_image()
        }
        Surface::Wall { posters } => wall(seed, &mut rng, posters, size, (width, height)),
        Surface::Floor => {
            let mut c = Canvas::new(width, height, [120.0, 108.0, 95.0]);
            c.fbm(seed ^ 3, m(2.0), m(0.003), 22.0, [1.0, 0.95, 0.9]);
            let n = (area * 300.0) as usize + 50;
            c.dead_leaves(
                &mut rng,
                full,
                n,
                m(0.005),
                m(0.08),
                &grey_palette(70.0, 170.0, 12.0),
            );
            c.fbm(seed ^ 4, m(0.3), m(0.01), 12.0, [1.0, 1.0, 1.0]);
            c.into_image()
        }
        Surface::Ceiling => {
            let mut c = Canvas::new(width, height, [225.0, 225.0, 222.0]);
            c.fbm(seed ^ 5, m(3.0), m(0.01), 6.0, [1.0, 1.0, 1.0]);
            c.into_image()
        }
        Surface::Clutter => {
            let mut c = Canvas::new(width, height, [90.0, 80.0, 70.0]);
            let n = (area * 400.0) as usize + 100;
            c.dead_leaves(
                &mut rng,
                full,
                n,
                m(0.01),
                m(0.3),
                &grey_palette(20.0, 220.0, 50.0),
            );
            c.fbm(seed ^ 6, m(0.5), m(0.005), 15.0, [1.0, 1.0, 1.0]);
            c.into_image()
        }
        Surface::Occluder => {
            let mut c = Canvas::new(width, height, [55.0, 50.0, 60.0]);
            c.fbm(seed ^ 7, m(0.6), m(0.004), 20.0, [1.0, 1.0, 1.2]);
            let n = (area * 200.0) as usize + 30;
            c.dead_leaves(
                &mut rng,
                full,
                n,
                m(0.01),
                m(0.15),
                &grey_palette(20.0, 110.0, 25.0),
            );
            c.into_image()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_seed_dependent() {
        let a = generate(Surface::Target, 1, (0.14, 0.2), 70, 100);
        let b = generate(Surface::Target, 1, (0.14, 0.2), 70, 100);
        let c = generate(Surface::Target, 2, (0.14, 0.2), 70, 100);
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    /// Natural-looking: strong contrast at several scales, and no tile repetition (the two
    /// halves of a wide texture differ everywhere, not by a shift).
    #[test]
    fn detail_at_several_scales_without_repetition() {
        let img = generate(Surface::Wall { posters: 3 }, 9, (4.0, 2.0), 512, 256);
        let g: Vec<f64> = img.pixels().map(|p| p.0[1] as f64).collect();
        let (w, h) = (512usize, 256usize);
        let at = |x: usize, y: usize| g[y * w + x];
        // Mean absolute difference between pixels `d` apart, for several `d`.
        let diff = |d: usize| {
            let mut s = 0.0;
            let mut n = 0.0;
            for y in 0..h {
                for x in 0..w - d {
                    s += (at(x + d, y) - at(x, y)).abs();
                    n += 1.0;
                }
            }
            s / n
        };
        let (d1, d8, d64) = (diff(1), diff(8), diff(64));
        println!("mean |Δ| at 1, 8, 64 px: {d1:.1} {d8:.1} {d64:.1}");
        assert!(d1 > 1.0 && d8 > d1 && d64 > d8, "{d1} {d8} {d64}");
        // No period: the best horizontal shift match is much worse than a match.
        let best = (16..256)
            .map(|s| {
                let mut e = 0.0;
                for y in 0..h {
                    for x in 0..w - s {
                        e += (at(x + s, y) - at(x, y)).abs();
                    }
                }
                e / ((w - s) * h) as f64
            })
            .fold(f64::MAX, f64::min);
        assert!(best > 3.0, "a shift of the texture matches itself: {best}");
    }
}
