//! One correspondence line (docs/VISION.md §9.3, eq. K2-K3): along the normal of a rendered
//! contour point, where the live image's contour lies, from the pixel-wise posteriors of the
//! object's statistics ([`crate::statistics`]), as SRT3D and RBOT model it: the line's pixels
//! are the object's on one side of the contour and the background's on the other, blurred by a
//! smoothed step. A coarse pass over a long line finds it; a fine pass over a short one around
//! it measures it.

use features::GrayF32;
use image::GrayImage;
use nalgebra::Vector2;

use crate::silhouette::{ContourSample, covers};
use crate::statistics::{ColourModel, Histograms};

/// How lines are searched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineConfig {
    /// Spacing of the coarse pass's positions [px]; each averages this many pixels along the
    /// line.
    pub coarse_step_px: usize,
    /// Half length of the coarse line [px] at most: the largest contour offset found.
    pub coarse_half_length_px: f64,
    /// Half length of the coarse line at least [px]; between the two, three times the
    /// prediction's σ along the normal plus two steps (docs/VISION.md §9.3).
    pub min_half_length_px: f64,
    /// Half length of the fine line (1 px steps) around the coarse estimate [px].
    pub fine_half_length_px: f64,
    /// Width of the smoothed step `s` of eq. K2, per pixel of the pass's step.
    pub slope: f64,
    /// Amplitude `α` of the smoothed step (eq. K2): below ½, so that no single pixel decides.
    pub amplitude: f64,
    /// The fine pass's standard deviation above which a line says too little [px].
    pub max_sigma_px: f64,
    /// Floor of a line's standard deviation [px] (the posterior of a sharp, clean edge is
    /// narrower than the edge's true position is known).
    pub min_sigma_px: f64,
    /// Pixels of the object's side the rendering must hold next to the contour.
    pub min_inside_px: usize,
}

impl Default for LineConfig {
    fn default() -> Self {
        Self {
            coarse_step_px: 3,
            coarse_half_length_px: 36.0,
            min_half_length_px: 6.0,
            fine_half_length_px: 8.0,
            slope: 0.8,
            amplitude: 0.36,
            max_sigma_px: 3.0,
            min_sigma_px: 0.5,
            min_inside_px: 3,
        }
    }
}

/// Why a line gives no measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LineRejection {
    /// The line leaves the image.
    Border,
    /// Another part of the model lies on the background side, or the object's side is too
    /// thin in the rendering: the step of eq. K2 is not what the line holds.
    OtherPart,
    /// The contour is not within the line: the posterior piles up at an end of it.
    NotFound,
    /// The posterior is too wide: the object and its background look alike here.
    Ambiguous,
}

/// Where a line found the contour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineResult {
    /// Offset of the live contour from the rendered one along the outward normal [px].
    pub offset_px: f64,
    /// Its standard deviation [px].
    pub sigma_px: f64,
}

/// Eq. K2: the probability that a pixel at signed distance `x` (outward) from the contour is
/// the object's, `h_f(x) = ½ − α tanh(x' / (2s))`, where a ramp of width `w` centred on the
/// contour is neutral: `x' = sign(x) max(|x| − w/2, 0)`. A blurred edge's pixels mix the
/// object's grey with the background's; neither histogram explains them, and the posterior
/// calls them background, which would pull the contour in by half the ramp.
fn h_f(x: f64, alpha: f64, s: f64, w: f64) -> f64 {
    let x = x.signum() * (x.abs() - w / 2.0).max(0.0);
    0.5 - alpha * (x / (2.0 * s)).tanh()
}

/// Hypotheses on either side of the posterior's mode its moments are taken over (eq. K3).
const MODE_WINDOW_STEPS: f64 = 3.0;

/// Least share of the posterior within the mode's window for a line to say where the contour
/// is.
const MODE_SHARE: f64 = 0.2;

/// Widths of the neutral ramp of eq. K2 the fine pass weighs [px]: a sharp edge (anti-aliasing
/// alone) to the blur of fast motion.
const RAMPS_PX: [f64; 4] = [1.0, 2.0, 4.0, 8.0];

/// One pass: positions `r_i = i · step` for `i` in `lo ..= hi` around `centre`, each the mean
/// of `step` pixels along the line; hypotheses `d = j · step` for `j` in `lo + m ..= hi − m`.
/// Returns the posterior's mean and variance of `d` (eq. K3).
struct Pass {
    step: usize,
    lo: i64,
    hi: i64,
}

impl Pass {
    fn posteriors(
        &self,
        live: &GrayF32,
        stats: &Histograms,
        centre: Vector2<f64>,
        normal: Vector2<f64>,
    ) -> Result<Vec<f64>, LineRejection> {
        let step = self.step as f64;
        (self.lo..=self.hi)
            .map(|i| {
                let mut sum = 0.0f32;
                for k in 0..self.step {
                    let r = i as f64 * step + k as f64 - (step - 1.0) / 2.0;
                    let p = centre + normal * r;
                    sum += live.sample(p.x, p.y).ok_or(LineRejection::Border)?;
                }
                Ok(f64::from(stats.posterior(sum / self.step as f32)))
            })
            .collect()
    }

    /// Eq. K3 over the hypotheses: `p(d | line) ∝ Σ_w Π_i [h_f(r_i − d; w) P_i + (1 −
    /// h_f(r_i − d; w)) (1 − P_i)]`, uniform priors over `d` and over the ramp widths `ramps`
    /// (marginalised); its mean and variance [px, px²].
    fn estimate(
        &self,
        post: &[f64],
        cfg: &LineConfig,
        ramps: &[f64],
    ) -> Result<(f64, f64), LineRejection> {
        let step = self.step as f64;
        let s = cfg.slope * step;
        // Hypotheses keep the step's transition on the line.
        let margin = ((2.0 * s / step).ceil() as i64).max(1);
        let (j_lo, j_hi) = (self.lo + margin, self.hi - margin);
        if j_hi < j_lo {
            return Err(LineRejection::OtherPart);
        }
        let span = (self.hi - self.lo) as usize;
        let hypotheses = (j_hi - j_lo + 1) as usize;
        let mut logs = vec![Vec::with_capacity(hypotheses); ramps.len()];
        for (ramp, logs) in ramps.iter().zip(&mut logs) {
            // h_f(r_i − d) depends on i − j only: one table per ramp.
            let table: Vec<f64> = (0..=2 * span)
                .map(|k| {
                    h_f(
                        (k as i64 - span as i64) as f64 * step,
                        cfg.amplitude,
                        s,
                        *ramp,
                    )
                })
                .collect();
            logs.extend((j_lo..=j_hi).map(|j| {
                post.iter()
                    .enumerate()
                    .map(|(k, &p)| {
                        let i = self.lo + k as i64;
                        let hf = table[(i - j + span as i64) as usize];
                        (hf * p + (1.0 - hf) * (1.0 - p)).ln()
                    })
                    .sum::<f64>()
            }));
        }
        let max = logs
            .iter()
            .flatten()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        if !max.is_finite() {
            return Err(LineRejection::Ambiguous);
        }
        let w: Vec<f64> = (0..hypotheses)
            .map(|k| logs.iter().map(|l| (l[k] - max).exp()).sum())
            .collect();
        let d = |k: usize| (j_lo + k as i64) as f64 * step;
        // The moments around the posterior's mode: where the object's statistics are weaker
        // on one side of the contour than the background's on the other, the posterior has a
        // long tail on the weak side, and the mean over all of it is pulled there.
        let mode = w
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(k, _)| k);
        let near = |k: usize| (d(k) - d(mode)).abs() <= MODE_WINDOW_STEPS * step;
        let total: f64 = (0..hypotheses).filter(|&k| near(k)).map(|k| w[k]).sum();
        // Most of the belief must lie at the mode: else the contour is nowhere in particular
        // (a flat posterior) or in two places.
        if total < MODE_SHARE * w.iter().sum::<f64>() {
            return Err(LineRejection::Ambiguous);
        }
        let mean = (0..hypotheses)
            .filter(|&k| near(k))
            .map(|k| w[k] * d(k))
            .sum::<f64>()
            / total;
        let var = (0..hypotheses)
            .filter(|&k| near(k))
            .map(|k| w[k] * (d(k) - mean).powi(2))
            .sum::<f64>()
            / total;
        // At an end: the contour lies beyond the line.
        if mode == 0 || mode + 1 == hypotheses {
            return Err(LineRejection::NotFound);
        }
        // The hypotheses' spacing quantises the estimate.
        Ok((mean, var + step * step / 12.0))
    }
}

/// Extent of the rendering's object side along the line from the contour: how many pixels in
/// stay in the mask (up to `limit`), and whether the background side leaves the mask for
/// `limit` pixels.
fn rendered_sides(mask: &GrayImage, sample: &ContourSample, limit: usize) -> (usize, bool) {
    let at = |t: f64| covers(mask, sample.pixel + sample.normal * t);
    let inside = (1..=limit).take_while(|&t| at(-(t as f64) + 0.5)).count();
    let clear = (1..=limit).all(|t| !at(t as f64 - 0.5));
    (inside, clear)
}

/// The coarse line's half length [px] for a contour point whose predicted position along its
/// normal has the standard deviation `sigma_px`: `3σ` plus two steps, within the configured
/// bounds. A contour further off than the prediction allows is not looked for: there the
/// background's own steps would be found instead, and the core would gate the finding.
pub fn half_length(cfg: &LineConfig, sigma_px: f64) -> f64 {
    let want = 3.0 * sigma_px + 2.0 * cfg.coarse_step_px as f64;
    if want.is_finite() {
        want.clamp(cfg.min_half_length_px, cfg.coarse_half_length_px)
    } else {
        cfg.coarse_half_length_px
    }
}

/// Searches the line of `sample` in `live` (the undistorted live image, grey 0–255) with the
/// object's statistics `stats`, up to `half_length_px` from the rendered contour ([`half_length`]);
/// `mask` is the rendering the sample came from.
pub fn search(
    live: &GrayF32,
    mask: &GrayImage,
    sample: &ContourSample,
    stats: &ColourModel,
    cfg: &LineConfig,
    half_length_px: f64,
) -> Result<LineResult, LineRejection> {
    let step = cfg.coarse_step_px.max(1);
    // The hypotheses reach `half_length_px`; the samples reach the step's transition further.
    let transition = 2.0 * cfg.slope * step as f64;
    let half =
        ((half_length_px.min(cfg.coarse_half_length_px) + transition) / step as f64).ceil() as i64;
    let (inside, clear) = rendered_sides(mask, sample, half as usize * step);
    if !clear || inside < cfg.min_inside_px {
        return Err(LineRejection::OtherPart);
    }
    // The object's side ends where the rendering's does: beyond, the step model is wrong.
    let lo = -((inside / step) as i64).min(half);
    let coarse = Pass { step, lo, hi: half };
    // The statistics of this part of the contour (its region's, once learnt).
    let stats = stats.at(&sample.m_w);
    let post = coarse.posteriors(live, stats, sample.pixel, sample.normal)?;
    // The coarse pass's own averaging is its ramp.
    let (mean, _) = coarse.estimate(&post, cfg, &[0.0])?;
    // Fine pass around the coarse estimate, still within the object's side.
    let fine_half = cfg.fine_half_length_px.ceil() as i64;
    let centre = sample.pixel + sample.normal * mean;
    let inside_from_centre = inside as f64 + mean;
    let lo = -(inside_from_centre.floor() as i64).clamp(0, fine_half);
    let fine = Pass {
        step: 1,
        lo,
        hi: fine_half,
    };
    let post = fine.posteriors(live, stats, centre, sample.normal)?;
    let (offset, var) = fine.estimate(&post, cfg, &RAMPS_PX)?;
    let sigma = var.sqrt().max(cfg.min_sigma_px);
    if sigma > cfg.max_sigma_px {
        return Err(LineRejection::Ambiguous);
    }
    Ok(LineResult {
        offset_px: mean + offset,
        sigma_px: sigma,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::silhouette::{SampleConfig, sample, tests::disc_frame};

    /// A live image of a disc of grey `fg` and radius `r` at `(cx, cy)` on a background `bg(x,
    /// y)`, anti-aliased over one pixel.
    fn live(
        size: (usize, usize),
        c: (f64, f64),
        r: f64,
        fg: f32,
        bg: impl Fn(usize, usize) -> f32,
    ) -> GrayF32 {
        let (w, h) = size;
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let d = ((x as f64 - c.0).powi(2) + (y as f64 - c.1).powi(2)).sqrt() - r;
                let a = (0.5 - d).clamp(0.0, 1.0) as f32;
                a * fg + (1.0 - a) * bg(x, y)
            })
            .collect();
        GrayF32::new(w, h, data).unwrap()
    }

    fn checker(x: usize, y: usize) -> f32 {
        if (x / 3 + y / 5).is_multiple_of(2) {
            30.0
        } else {
            110.0
        }
    }

    fn learnt(live: &GrayF32, frame: &render::Frame, samples: &[ContourSample]) -> ColourModel {
        let mut m = ColourModel::new();
        assert!(m.learn(live, Some(&frame.mask), samples, 10, 1.0));
        m
    }

    /// The rendered disc of radius 60 px; the live one 5.5 px larger: every line finds the
    /// contour 5.5 px out, within a few tenths of a pixel, on a textured background.
    #[test]
    fn the_contour_is_found_where_it_moved_along_each_normal() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 60.0);
        let samples = sample(&frame, &SampleConfig::default());
        let at_rest = live((320, 240), (160.0, 120.0), 60.5, 220.0, checker);
        let stats = learnt(&at_rest, &frame, &samples);
        let grown = live((320, 240), (160.0, 120.0), 66.0, 220.0, checker);
        let cfg = LineConfig::default();
        let mut errors = Vec::new();
        let mut sigmas = Vec::new();
        for s in &samples {
            let r = search(&grown, &frame.mask, s, &stats, &cfg, 36.0).expect("a clear line");
            errors.push(r.offset_px - 5.5);
            assert!(r.sigma_px >= cfg.min_sigma_px && r.sigma_px < 2.0, "{r:?}");
            sigmas.push(r.sigma_px);
        }
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let mean_sigma = sigmas.iter().sum::<f64>() / sigmas.len() as f64;
        println!(
            "rms {rms:.3} px, mean σ {mean_sigma:.2} px over {} lines",
            errors.len()
        );
        assert!(rms < 0.5, "rms {rms} px over {} lines", errors.len());
        // The error is within the stated σ: the variance sent to the core is honest.
        assert!(rms < mean_sigma, "rms {rms} against σ {mean_sigma}");
        // Found from 25 px off too (the coarse pass), and inward.
        let shrunk = live((320, 240), (160.0, 120.0), 35.5, 220.0, checker);
        for s in samples.iter().take(10) {
            let r = search(&shrunk, &frame.mask, s, &stats, &cfg, 36.0).expect("found");
            assert!((r.offset_px + 25.0).abs() < 1.5, "{r:?}");
        }
    }

    #[test]
    fn lines_that_say_nothing_or_leave_the_image_are_refused_by_name() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 60.0);
        let samples = sample(&frame, &SampleConfig::default());
        let at_rest = live((320, 240), (160.0, 120.0), 60.5, 220.0, checker);
        let stats = learnt(&at_rest, &frame, &samples);
        let cfg = LineConfig::default();
        // The object gone: background everywhere, no contour on any line.
        let gone = live((320, 240), (-500.0, -500.0), 1.0, 220.0, checker);
        let found = samples
            .iter()
            .filter(|s| search(&gone, &frame.mask, s, &stats, &cfg, 36.0).is_ok())
            .count();
        assert_eq!(found, 0);
        // An object that looks like its background: nothing to learn, nothing found.
        let same = live((320, 240), (160.0, 120.0), 60.5, 70.0, |_, _| 70.0);
        let mut flat = ColourModel::new();
        flat.learn(&same, Some(&frame.mask), &samples, 10, 1.0);
        for s in &samples {
            let r = search(&same, &frame.mask, s, &flat, &cfg, 36.0);
            assert!(
                matches!(r, Err(LineRejection::Ambiguous | LineRejection::NotFound)),
                "{r:?}"
            );
        }
        // Near the image's border: the line leaves the image.
        let edge = disc_frame((320, 240), (40.0, 120.0), 30.0);
        let left = sample(&edge, &SampleConfig::default())
            .into_iter()
            .find(|s| s.normal.x < -0.9)
            .expect("a point facing left");
        assert_eq!(
            search(&at_rest, &edge.mask, &left, &stats, &cfg, 36.0),
            Err(LineRejection::Border)
        );
    }

    #[test]
    fn another_part_of_the_model_on_the_background_side_refuses_the_line() {
        // Two discs 10 px apart: the lines between them see the other disc.
        let mut frame = disc_frame((320, 240), (100.0, 120.0), 40.0);
        let other = disc_frame((320, 240), (190.0, 120.0), 40.0);
        for (a, b) in frame.mask.pixels_mut().zip(other.mask.pixels()) {
            a.0[0] = a.0[0].max(b.0[0]);
        }
        let samples = sample(&frame, &SampleConfig::default());
        let facing = samples
            .iter()
            .find(|s| s.normal.x > 0.95 && (s.pixel.y - 120.0).abs() < 5.0)
            .expect("a point facing the other disc");
        let stats = ColourModel::new();
        let live = live((320, 240), (100.0, 120.0), 40.5, 220.0, checker);
        assert_eq!(
            search(
                &live,
                &frame.mask,
                facing,
                &stats,
                &LineConfig::default(),
                36.0
            ),
            Err(LineRejection::OtherPart)
        );
    }
}
