//! The grey levels of the object and of its background next to its contour, learnt while
//! tracking (docs/VISION.md §9.2, eq. K1), and the pixel-wise posterior that a grey level is the
//! object's. Statistics are kept for the whole contour and for regions of it attached to the
//! model (RBOT's local histograms): a background that is a bright wall behind one edge and a
//! floor of the object's own grey below another tells the object apart at the first edge,
//! which one histogram for all of it would not.

use std::collections::HashMap;

use features::GrayF32;
use image::GrayImage;
use nalgebra::Vector3;

use crate::silhouette::{ContourSample, covers};

/// Histogram bins over the grey levels 0–255.
pub const BINS: usize = 32;

/// Probability every bin keeps at least, so that a grey level never seen on one side does not
/// make a posterior of exactly 0 or 1 (one such pixel would veto a contour position).
const FLOOR: f32 = 1e-3;

/// Pixels' worth of the whole contour's distribution a region's counts are mixed with: a region
/// seen by one line (about 10 pixels a side) leans on the whole contour's statistics, one seen
/// by many on its own.
const REGION_PRIOR: f32 = 10.0;

/// Regions per extent of the model's contour points (their bounding box's diagonal).
const REGIONS_ACROSS: f64 = 8.0;

/// An object and a background distribution.
#[derive(Debug, Clone, PartialEq)]
pub struct Histograms {
    fg: [f32; BINS],
    bg: [f32; BINS],
}

impl Histograms {
    const UNIFORM: Histograms = Histograms {
        fg: [1.0 / BINS as f32; BINS],
        bg: [1.0 / BINS as f32; BINS],
    };

    /// Eq. K1: the posterior that a pixel of grey level `grey` belongs to the object,
    /// `p(y|f) / (p(y|f) + p(y|b))` (equal priors).
    pub fn posterior(&self, grey: f32) -> f32 {
        let (lo, hi, w) = bins(grey);
        let f = self.fg[lo] * (1.0 - w) + self.fg[hi] * w;
        let b = self.bg[lo] * (1.0 - w) + self.bg[hi] * w;
        f / (f + b)
    }

    /// How far apart the two distributions are: their total variation distance
    /// `½ Σ |p_f − p_b|`, 0 for identical ones (an object that looks like its background), 1
    /// for disjoint ones. A pixel classified by eq. K1 is wrong with probability at least
    /// `(1 − separation) / 2`.
    pub fn separation(&self) -> f32 {
        0.5 * self
            .fg
            .iter()
            .zip(&self.bg)
            .map(|(f, b)| (f - b).abs())
            .sum::<f32>()
    }

    /// The agreement (eq. K5) a pixel scores on average where the two distributions are
    /// right: `(E_f[P_f], E_b[1 − P_f])`, for a pixel of the object and one of the background.
    /// The most a silhouette at the right pose can expect of these statistics (eq. K5').
    pub fn expected_agreement(&self) -> (f32, f32) {
        let (mut inside, mut outside) = (0.0, 0.0);
        for (f, b) in self.fg.iter().zip(&self.bg) {
            let pf = f / (f + b);
            inside += f * pf;
            outside += b * (1.0 - pf);
        }
        (inside, outside)
    }

    /// `self ← (1 − rate) self + rate new`.
    fn blend(&mut self, new: &Histograms, rate: f32) {
        for (old, new) in self.fg.iter_mut().zip(&new.fg) {
            *old += rate * (new - *old);
        }
        for (old, new) in self.bg.iter_mut().zip(&new.bg) {
            *old += rate * (new - *old);
        }
    }
}

/// Pixel counts of one frame, per side.
#[derive(Debug, Clone)]
struct Counts {
    fg: [f32; BINS],
    bg: [f32; BINS],
}

impl Counts {
    const ZERO: Counts = Counts {
        fg: [0.0; BINS],
        bg: [0.0; BINS],
    };

    /// The distributions, mixed with `prior`'s at `weight` pixels' worth; `None` when a side
    /// has no pixels and no prior.
    fn histograms(&self, prior: Option<(&Histograms, f32)>) -> Option<Histograms> {
        let side = |counts: &[f32; BINS], prior: Option<&[f32; BINS]>, weight: f32| {
            let mut c = *counts;
            if let Some(p) = prior {
                c.iter_mut().zip(p).for_each(|(c, p)| *c += weight * p);
            }
            distribution(&c)
        };
        let (p, w) = prior.map_or((None, 0.0), |(h, w)| (Some(h), w));
        Some(Histograms {
            fg: side(&self.fg, p.map(|h| &h.fg), w)?,
            bg: side(&self.bg, p.map(|h| &h.bg), w)?,
        })
    }
}

/// The object's and the background's grey-level distributions next to the contour: for all of
/// it, and per region of the model.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourModel {
    global: Histograms,
    local: HashMap<[i64; 3], Histograms>,
    /// Side of a region [m], from the first contour learnt from.
    region_m: Option<f64>,
    learnt: bool,
}

impl Default for ColourModel {
    fn default() -> Self {
        Self::new()
    }
}

/// The two bins around grey level `grey` and the weight of the upper one: bins are centred at
/// `(k + ½) · 256 / BINS`, and a grey level between two centres counts for both, linearly (a
/// level on a bin's edge is not all in one bin and none in the other: the smoothed live image
/// and the raw one put a flat object's 128 in different bins otherwise).
fn bins(grey: f32) -> (usize, usize, f32) {
    let b = (grey.clamp(0.0, 255.0) * BINS as f32 / 256.0 - 0.5).clamp(0.0, (BINS - 1) as f32);
    let lo = b.floor() as usize;
    let hi = (lo + 1).min(BINS - 1);
    (lo, hi, b - lo as f32)
}

/// Adds one pixel of grey level `grey` to `counts`.
fn count(counts: &mut [f32; BINS], grey: f32) {
    let (lo, hi, w) = bins(grey);
    counts[lo] += 1.0 - w;
    counts[hi] += w;
}

/// Normalises counts into a distribution with every bin at least [`FLOOR`] (before the final
/// normalisation); `None` when nothing was counted.
fn distribution(counts: &[f32; BINS]) -> Option<[f32; BINS]> {
    let total: f32 = counts.iter().sum();
    if total <= 0.0 {
        return None;
    }
    let mut p = counts.map(|c| (c / total).max(FLOOR));
    let sum: f32 = p.iter().sum();
    p.iter_mut().for_each(|v| *v /= sum);
    Some(p)
}

/// A tenth of the diagonal of the box around `samples`' model points [m] (at least 1 mm).
fn region_size(samples: &[ContourSample]) -> Option<f64> {
    let first = samples.first()?.m_w;
    let (lo, hi) = samples.iter().fold((first, first), |(lo, hi), s| {
        (lo.inf(&s.m_w), hi.sup(&s.m_w))
    });
    Some(((hi - lo).norm() / REGIONS_ACROSS).max(1e-3))
}

impl ColourModel {
    /// Nothing learnt: every posterior is ½.
    pub fn new() -> Self {
        Self {
            global: Histograms::UNIFORM,
            local: HashMap::new(),
            region_m: None,
            learnt: false,
        }
    }

    /// Whether anything was learnt.
    pub fn learnt(&self) -> bool {
        self.learnt
    }

    fn region(&self, m_w: &Vector3<f64>) -> Option<[i64; 3]> {
        let size = self.region_m?;
        let k = m_w.map(|v| (v / size).floor());
        k.iter()
            .all(|v| v.abs() < 1e12)
            .then(|| [k.x as i64, k.y as i64, k.z as i64])
    }

    /// The statistics for the contour at model point `m_w`: its region's where it has been
    /// learnt, else the whole contour's.
    pub fn at(&self, m_w: &Vector3<f64>) -> &Histograms {
        self.region(m_w)
            .and_then(|k| self.local.get(&k))
            .unwrap_or(&self.global)
    }

    /// Eq. K1 with the whole contour's statistics.
    pub fn posterior(&self, grey: f32) -> f32 {
        self.global.posterior(grey)
    }

    /// How far apart the whole contour's two distributions are: their total variation
    /// distance `½ Σ |p_f − p_b|`, 0 for identical ones (an object that looks like its
    /// background), 1 for disjoint ones.
    pub fn separation(&self) -> f32 {
        self.global.separation()
    }

    /// Learns from `live` along the normals of `samples`, pixels 1 to `band` px inside the
    /// contour for the object and outside it for the background, where `mask` (the rendering
    /// the samples came from) agrees, if given: `p ← (1 − rate) p + rate p_frame`, or the
    /// frame's distributions outright the first time, for the whole contour and for each
    /// region the samples fall in (a region's frame distribution mixed with the whole
    /// contour's). Without a mask the samples are contours found in `live` (their sides are
    /// what the lines found). Returns whether both sides had pixels.
    pub fn learn(
        &mut self,
        live: &GrayF32,
        mask: Option<&GrayImage>,
        samples: &[ContourSample],
        band: usize,
        rate: f32,
    ) -> bool {
        // Whether the rendering puts p on the object's side (`object`), or no mask says.
        let agrees =
            |p: nalgebra::Vector2<f64>, object: bool| mask.is_none_or(|m| covers(m, p) == object);
        if self.region_m.is_none() {
            self.region_m = region_size(samples);
        }
        let mut all = Counts::ZERO;
        let mut regions: HashMap<[i64; 3], Counts> = HashMap::new();
        for s in samples {
            let mut counts = Counts::ZERO;
            for t in 1..=band {
                // Half a pixel back to the border pixel's centre, then t pixels in or out.
                let t = t as f64 - 0.5;
                let inner = s.pixel - s.normal * t;
                let outer = s.pixel + s.normal * t;
                if let Some(y) = live
                    .sample(inner.x, inner.y)
                    .filter(|_| agrees(inner, true))
                {
                    count(&mut counts.fg, y);
                }
                if let Some(y) = live
                    .sample(outer.x, outer.y)
                    .filter(|_| agrees(outer, false))
                {
                    count(&mut counts.bg, y);
                }
            }
            for k in 0..BINS {
                all.fg[k] += counts.fg[k];
                all.bg[k] += counts.bg[k];
            }
            if let Some(key) = self.region(&s.m_w) {
                let r = regions.entry(key).or_insert(Counts::ZERO);
                for k in 0..BINS {
                    r.fg[k] += counts.fg[k];
                    r.bg[k] += counts.bg[k];
                }
            }
        }
        let Some(global) = all.histograms(None) else {
            return false;
        };
        let first = !self.learnt;
        let rate = if first { 1.0 } else { rate.clamp(0.0, 1.0) };
        self.global.blend(&global, rate);
        for (key, counts) in regions {
            let Some(h) = counts.histograms(Some((&self.global, REGION_PRIOR))) else {
                continue;
            };
            match self.local.get_mut(&key) {
                Some(old) => old.blend(&h, rate),
                None => {
                    self.local.insert(key, h);
                }
            }
        }
        self.learnt = true;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::silhouette::{SampleConfig, sample, tests::disc_frame};

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> GrayF32 {
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect();
        GrayF32::new(w, h, data).unwrap()
    }

    #[test]
    fn a_bright_object_on_a_dark_textured_background_is_told_apart() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 60.0);
        let samples = sample(&frame, &SampleConfig::default());
        let on =
            |x: usize, y: usize| (x as f64 - 160.0).powi(2) + (y as f64 - 120.0).powi(2) <= 3600.0;
        // Object: 200 ± a little; background: a checkerboard of 20 and 90.
        let live = image(320, 240, |x, y| {
            if on(x, y) {
                198.0 + (x % 3) as f32
            } else if (x / 4 + y / 4).is_multiple_of(2) {
                20.0
            } else {
                90.0
            }
        });
        let mut m = ColourModel::new();
        assert!(!m.learnt());
        assert_eq!(m.posterior(200.0), 0.5);
        assert!(m.learn(&live, Some(&frame.mask), &samples, 8, 0.2));
        assert!(m.learnt());
        assert!(m.posterior(199.0) > 0.95, "{}", m.posterior(199.0));
        assert!(m.posterior(20.0) < 0.05 && m.posterior(90.0) < 0.05);
        assert!(m.separation() > 0.9, "{}", m.separation());
        // Learning a second time at rate 0.2 moves the distributions a fifth of the way.
        let flat = image(320, 240, |_, _| 90.0);
        let before = m.posterior(90.0);
        assert!(m.learn(&flat, Some(&frame.mask), &samples, 8, 0.2));
        assert!(m.posterior(90.0) > before && m.posterior(90.0) < 0.5);
    }

    #[test]
    fn an_object_that_looks_like_its_background_separates_nothing() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 60.0);
        let samples = sample(&frame, &SampleConfig::default());
        let live = image(320, 240, |x, y| ((x * 7 + y * 13) % 256) as f32);
        let mut m = ColourModel::new();
        assert!(m.learn(&live, Some(&frame.mask), &samples, 8, 0.2));
        assert!(m.separation() < 0.3, "{}", m.separation());
        // Nothing to learn from: no samples.
        let mut fresh = ColourModel::new();
        assert!(!fresh.learn(&live, Some(&frame.mask), &[], 8, 0.2));
        assert!(!fresh.learnt());
    }
}
