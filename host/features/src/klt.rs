//! Photometric KLT: registers a rendered feature patch in the live image while estimating the
//! local contrast and brightness change (docs/VISION.md §5, after Jin, Favaro & Soatto 2001).
//!
//! Model (docs/VISION.md §5): `I(m) ≈ λ · J(m + d) + δ` for every pixel `m` of the window `W`
//! around the feature, with `I` the (blurred) rendering — the template — and `J` the live
//! image. We minimise
//!
//! ```text
//!     E(d₁, d₂, λ, δ) = Σ_W mask(m) · [I(m) − λ J(m + d) − δ]²
//! ```
//!
//! by Gauss-Newton on a first-order Taylor expansion of `J` (forward additive). The residual
//! is evaluated in the live image's units, `ρ = J(m + d) − a I(m) − b` with `a = 1/λ`,
//! `b = −δ/λ`: that is `−(I − λJ − δ)/λ`, the same model and, per window, the objective above
//! divided by `λ²`. Why: the rendering is noise-free and the live image is not; with the
//! residual in template units the noise in `J` biases `λ` towards 0 (errors in variables,
//! measured at −2.4 % for λ = 2.5 and 2 gray levels of noise on gravel), with `J` on the
//! measured side it does not. With `g = ∂ρ/∂α = [∂ₓJ, ∂ᵧJ, −I, −1]` (`J` sampled bilinearly
//! at `m + d`, its gradient by central differences of those samples) the step solves
//! `(Σ g gᵀ) Δα = −Σ g ρ`. The window's grid is placed so that template and live samples have
//! opposite sub-pixel fractions (see `symmetric_grid`): both are then smoothed alike by the
//! bilinear interpolation.
//!
//! `λ, δ` start from the windows' standard deviations and means (and follow them while the
//! position is still far off), `d` from the caller's guess; the estimate runs coarse to fine
//! over the pyramids, `d` doubling from one level to the next; a coarse level that diverges
//! is skipped. A result is accepted when the photometrically normalised SSD
//! `Σ (I − λJ − δ)² / Σ (I − Ī)²` (the fraction of the template's variance the model leaves
//! unexplained) is below a threshold.
//!
//! [`KltModel::Translation`] is the plain 2-parameter KLT (`λ = 1, δ = 0` fixed), kept for
//! comparisons.

use nalgebra::Matrix2;

use super::gray::GrayF32;
use super::pyramid::{MaskPyramid, Pyramid};

pub mod clip;
mod noise;
pub mod reference;
mod solve;
mod window;

use solve::Factor;
use window::{Normal, Pre, Window};

/// Position step (px of the level) below which the photometric parameters join the
/// estimation.
pub(crate) const LOCK_STEP: f64 = 0.5;

/// Position step (px of the level) that ends a level above 0 (see `register`).
const COARSE_MIN_UPDATE: f64 = 0.1;

/// Which parameters are estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KltModel {
    /// `d₁, d₂, λ, δ` (docs/VISION.md §5).
    Photometric,
    /// `d₁, d₂` only; `λ = 1, δ = 0`.
    Translation,
}

/// Registration parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KltConfig {
    /// Window half size: the window is `(2r + 1)²` pixels at every level.
    pub half_window: usize,
    /// Pyramid levels used (capped by the pyramids given).
    pub levels: usize,
    /// Gauss-Newton iterations allowed per level.
    pub max_iterations: usize,
    /// Stop a level when the position update is below this, px of that level.
    pub min_update: f64,
    /// Accept if the normalised SSD is at most this (0 = perfect, 1 = no better than a
    /// constant).
    pub max_normalised_ssd: f64,
    /// Fewer valid window pixels than this fraction: not registered at that level.
    pub min_valid_fraction: f64,
    /// Largest allowed distance of the result from the initial guess, level-0 px.
    pub max_displacement: f64,
    /// `λ` outside `[1/max_contrast, max_contrast]` counts as diverged.
    pub max_contrast: f64,
    /// Smallest eigenvalue of the position block of the normal matrix (after eliminating
    /// `λ, δ`), per valid pixel, in live-image gray²/px²: below it the window has no usable
    /// texture.
    pub min_eigenvalue: f64,
    /// Gaussian σ (px) both images are smoothed with before registration (on top of the
    /// rendering's anti-aliasing blur). Bilinear interpolation smooths a sample by an amount
    /// that depends on its sub-pixel fraction; on fine texture that left up to 0.054 px of bias
    /// and 1.3× the Cramér-Rao bound in δ. On band-limited images the interpolation is nearly
    /// exact: 0.044 px and 0.99× (`tests/features_klt.rs`).
    pub smoothing: f32,
    /// Estimated parameters.
    pub model: KltModel,
    /// The live camera's clip levels `[lo, hi]` (gray levels): a raw live pixel exactly at
    /// one is censored (docs/VISION.md §5, eq. 5.6). `None` (the default): no clip map is
    /// built. The clipped prediction also needs a template that keeps its unsmoothed image
    /// (`Pyramid::build_keeping_unsmoothed`, `TemplatePyramid::build_keeping_unsmoothed`; the
    /// tracker's templates keep it where this is set). The tracker leaves it off: on the cube
    /// video it tracked 778 frames instead of 783 at 8.2 ms a frame instead of 5.8-6.8 (issue
    /// 54, point 27; README, "Speed of the image processing").
    pub saturation: Option<[f32; 2]>,
}

impl KltConfig {
    /// The live image's pyramid as [`register`] expects it: smoothed by
    /// [`KltConfig::smoothing`], [`KltConfig::levels`] levels.
    pub fn target_pyramid(&self, live: GrayF32) -> Pyramid {
        let Some([lo, hi]) = self.saturation else {
            return Pyramid::build_smoothed(live, self.levels, self.smoothing);
        };
        // The clipped pixels of the raw image, before the smoothing spreads them.
        let flags = clip::ClipMap::raw_flags(&live, lo, hi);
        let pyramid = Pyramid::build_smoothed(live, self.levels, self.smoothing);
        let map = flags.and_then(|f| {
            let radius =
                super::pyramid::gaussian_kernel(pyramid.smoothing()).map_or(0, |k| k.len() - 1);
            let sizes: Vec<_> = pyramid
                .levels()
                .iter()
                .map(|l| (l.width(), l.height()))
                .collect();
            clip::ClipMap::build(&f, [lo, hi], radius, &sizes)
        });
        pyramid.with_clip(map)
    }

    /// The total blur σ for the template: the anti-aliasing blur `antialias` and
    /// [`KltConfig::smoothing`] combined (Gaussians add in variance).
    pub fn template_sigma(&self, antialias: f32) -> f32 {
        let a = if antialias.is_finite() {
            antialias.max(0.0)
        } else {
            0.0
        };
        let s = if self.smoothing.is_finite() {
            self.smoothing.max(0.0)
        } else {
            0.0
        };
        a.hypot(s)
    }
}

impl Default for KltConfig {
    fn default() -> Self {
        Self {
            half_window: 7,
            levels: 4,
            max_iterations: 30,
            min_update: 0.005,
            max_normalised_ssd: 0.25,
            min_valid_fraction: 0.35,
            max_displacement: 80.0,
            max_contrast: 20.0,
            min_eigenvalue: 0.05,
            smoothing: 1.0,
            model: KltModel::Photometric,
            saturation: None,
        }
    }
}

/// Why a registration failed.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum KltFailure {
    /// The feature or its registered position lies outside the images.
    #[error("window out of image")]
    OutOfImage,
    /// Too few pixels valid in both the template mask and the live image.
    #[error("too few valid pixels: {valid} < {needed}")]
    TooFewValidPixels {
        /// Valid pixels.
        valid: usize,
        /// Required.
        needed: usize,
    },
    /// The normal matrix is singular: no texture, or texture in one direction only.
    #[error("singular normal matrix (untextured or edge-like window)")]
    Singular,
    /// The estimate left the allowed range or became non-finite.
    #[error("diverged")]
    Diverged,
    /// Converged, but the model does not explain the window.
    #[error("normalised SSD {ssd:.3} above {threshold:.3}")]
    SsdTooHigh {
        /// Normalised SSD reached.
        ssd: f64,
        /// Threshold.
        threshold: f64,
    },
    /// Bad arguments: non-finite position, empty window, mismatched pyramids.
    #[error("invalid input: {0}")]
    BadInput(&'static str),
}

/// A successful registration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KltResult {
    /// Registered position in the live image, px (`position + displacement`).
    pub position: [f64; 2],
    /// Displacement `d` from the template position, px.
    pub displacement: [f64; 2],
    /// Contrast `λ`.
    pub lambda: f64,
    /// Brightness `δ`, gray levels of the template.
    pub delta: f64,
    /// Normalised SSD `Σ r² / Σ (I − Ī)²`.
    pub normalised_ssd: f64,
    /// Raw SSD `Σ (I − λJ − δ)²`, gray² of the template.
    pub ssd: f64,
    /// Gauss-Newton iterations over all levels.
    pub iterations: usize,
    /// Valid pixels at level 0.
    pub valid_pixels: usize,
    /// Covariance of the position, px², for white noise in the live image: `σ̂² (H⁻¹ M H⁻¹)_dd`
    /// in live-image units (as the normal matrix `H`), where the live samples are bilinear
    /// interpolations of its pixels (see `interpolated_noise`): `M = Σ_p u_p u_pᵀ` with
    /// `u_p = Σ_m w_mp g_m` over the pixels `p` the samples `m` touch, and
    /// `σ̂² = Σ ρ² / (c (n − p))` with `c = Σ_p w_mp²` the interpolation's variance factor.
    /// Without the correction (`σ̂² H⁻¹` from the raw residuals) it was optimistic by ~1.4× in
    /// σ at sub-pixel shifts near ½ px.
    pub covariance: Matrix2<f64>,
}

/// Where to put the template's sampling grid for feature coordinate `c` and displacement `d`
/// (one axis), given the integer anchor `k` of `d`: near `c`, with the sub-pixel fraction
/// `−f/2` where `f = d − k`, so the live samples at `grid + d` have the fraction `+f/2`.
/// Bilinear interpolation then smooths both windows alike; sampling only the live image at
/// fractional positions lowers its contrast against the template's and biases `λ` (by ~1.5 %
/// at half-pixel shifts on camera images) and the position.
#[inline]
pub(crate) fn symmetric_grid(c: f64, d: f64, k: f64) -> f64 {
    c.round() - 0.5 * (d - k)
}

/// Moves the anchor `k` of `d` only when `d` is more than 0.75 px away from it: the grid is
/// then continuous in `d` except at rare re-anchoring, so iterations near half-pixel
/// fractions do not flip between two grids.
#[inline]
pub(crate) fn anchor(d: f64, k: f64) -> f64 {
    if (d - k).abs() > 0.75 { d.round() } else { k }
}

impl Normal {
    /// Why a window with fewer than `needed` usable pixels cannot be registered: it left the
    /// image, or the mask and image leave too little of it.
    fn shortfall(&self, needed: usize) -> KltFailure {
        if self.outside > 0 {
            KltFailure::OutOfImage
        } else {
            KltFailure::TooFewValidPixels {
                valid: self.count,
                needed,
            }
        }
    }
}

/// Registers the template feature at `position` (level-0 px of the template pyramid) in the
/// live pyramid, starting from displacement `guess`.
///
/// `template` is the blurred rendering's pyramid, `mask` its validity (None: all valid),
/// `target` the live image's pyramid; both pyramids share the pixel grid (the live image is
/// undistorted to the rendering's intrinsics).
pub fn register(
    template: &Pyramid,
    mask: Option<&MaskPyramid>,
    target: &Pyramid,
    position: [f64; 2],
    guess: [f64; 2],
    cfg: &KltConfig,
) -> Result<KltResult, KltFailure> {
    let run = Run::new(template, mask, target, position, guess, cfg)?;
    let mut est = Estimate {
        d: guess,
        a: 1.0,
        b: 0.0,
        locked: !run.photometric,
        iterations: 0,
    };
    let mut win = Window::new(cfg.half_window);
    let mut final_anchor = None;
    for level in (0..run.levels).rev() {
        let k = run.refine_level(level, &mut est, &mut win)?;
        if level == 0 {
            final_anchor = k;
        }
    }
    run.evaluate(&est, final_anchor, &mut win)
}

/// The parameters being estimated: the displacement `d` (level-0 px), `a = 1/λ` and
/// `b = −δ/λ`, whether `a, b` are estimated jointly with `d` yet, and the iterations so far.
#[derive(Clone, Copy)]
struct Estimate {
    d: [f64; 2],
    a: f64,
    b: f64,
    locked: bool,
    iterations: usize,
}

/// One registration's inputs, checked, and what follows from them.
struct Run<'a> {
    template: &'a Pyramid,
    mask: Option<&'a MaskPyramid>,
    target: &'a Pyramid,
    position: [f64; 2],
    guess: [f64; 2],
    cfg: &'a KltConfig,
    /// Usable pixels a window needs.
    needed: usize,
    /// Levels used.
    levels: usize,
    photometric: bool,
    /// The admissible range of `a = 1/λ` (the same as λ's).
    a_range: (f64, f64),
    /// The step below which a coarse level stops.
    coarse_stop: f64,
}

/// Whether `p` lies inside `img` (px).
fn inside(img: &GrayF32, p: [f64; 2]) -> bool {
    p[0] >= 0.0
        && p[1] >= 0.0
        && p[0] <= (img.width() - 1) as f64
        && p[1] <= (img.height() - 1) as f64
}

impl<'a> Run<'a> {
    /// Checks the inputs (finite, a window of 1..=64, pyramids and mask that agree, the
    /// feature and its guess inside the images).
    fn new(
        template: &'a Pyramid,
        mask: Option<&'a MaskPyramid>,
        target: &'a Pyramid,
        position: [f64; 2],
        guess: [f64; 2],
        cfg: &'a KltConfig,
    ) -> Result<Self, KltFailure> {
        if !position.iter().chain(guess.iter()).all(|v| v.is_finite()) {
            return Err(KltFailure::BadInput("non-finite position or guess"));
        }
        if cfg.half_window == 0 || cfg.half_window > 64 {
            return Err(KltFailure::BadInput("half window must be 1..=64"));
        }
        let (t0, j0) = match (template.level(0), target.level(0)) {
            (Some(t), Some(j)) => (t, j),
            _ => return Err(KltFailure::BadInput("empty pyramid")),
        };
        if let Some(m) = mask {
            let ok =
                (0..template.len().min(m.len())).all(|k| match (template.level(k), m.level(k)) {
                    (Some(t), Some(mk)) => (t.width(), t.height()) == (mk.width(), mk.height()),
                    _ => false,
                });
            if !ok {
                return Err(KltFailure::BadInput(
                    "mask pyramid does not match the template",
                ));
            }
        }
        if !inside(t0, position) || !inside(j0, [position[0] + guess[0], position[1] + guess[1]]) {
            return Err(KltFailure::OutOfImage);
        }
        let side = 2 * cfg.half_window + 1;
        Ok(Self {
            template,
            mask,
            target,
            position,
            guess,
            cfg,
            needed: ((cfg.min_valid_fraction.clamp(0.0, 1.0) * (side * side) as f64).ceil()
                as usize)
                .max(5),
            levels: cfg
                .levels
                .max(1)
                .min(template.len())
                .min(target.len())
                .min(mask.map_or(usize::MAX, |m| m.len())),
            photometric: cfg.model == KltModel::Photometric,
            a_range: (1.0 / cfg.max_contrast.max(1.0), cfg.max_contrast.max(1.0)),
            coarse_stop: cfg.min_update.max(COARSE_MIN_UPDATE),
        })
    }

    /// The template before its smoothing at level 0, for the clipped prediction (eq. 5.6).
    fn pre(&self, level: usize, g: [f64; 2]) -> Option<Pre<'a>> {
        self.template.unsmoothed().map(|(img, kernel)| Pre {
            img,
            kernel,
            level,
            gx: g[0],
            gy: g[1],
        })
    }

    /// Where the live image's clipping reaches a level; eq. 5.6 needs the template before its
    /// smoothing, so without it there is no clip work.
    fn jclip(&self, level: usize) -> Option<&'a clip::ClipLevel> {
        self.target
            .clip()
            .filter(|_| self.template.unsmoothed().is_some())
            .and_then(|c| c.level(level))
    }

    /// Gauss-Newton at one pyramid level, from `est`. Returns the window grid's anchor it
    /// ended with (`None` where the level was left to the finer ones); a coarse level that
    /// fails leaves `est` as it found it.
    fn refine_level(
        &self,
        level: usize,
        est: &mut Estimate,
        win: &mut Window,
    ) -> Result<Option<[f64; 2]>, KltFailure> {
        let cfg = self.cfg;
        let scale = (1u32 << level) as f64;
        let (Some(ti), Some(ji)) = (self.template.level(level), self.target.level(level)) else {
            return Ok(None);
        };
        let tmask = self.mask.and_then(|m| m.level(level));
        let jl = self.jclip(level);
        let (cx, cy) = (self.position[0] / scale, self.position[1] / scale);
        let mut dl = [est.d[0] / scale, est.d[1] / scale];
        let (mut a, mut b, mut locked) = (est.a, est.b, est.locked);
        // The window grid in the template (moves by < 1 px, see `symmetric_grid`); since the
        // model is a pure translation, `d` is the same for every grid point.
        let mut k = [dl[0].round(), dl[1].round()];
        let grid = |dl: [f64; 2], k: [f64; 2]| {
            [
                symmetric_grid(cx, dl[0], k[0]),
                symmetric_grid(cy, dl[1], k[1]),
            ]
        };
        let mut g = grid(dl, k);
        win.sample_template(ti, tmask, g[0], g[1]);
        if win.tcount < self.needed {
            if level == 0 {
                return Err(KltFailure::TooFewValidPixels {
                    valid: win.tcount,
                    needed: self.needed,
                });
            }
            // Background fills the coarse window: leave this level to the finer ones.
            return Ok(None);
        }
        for _ in 0..cfg.max_iterations {
            k = [anchor(dl[0], k[0]), anchor(dl[1], k[1])];
            let g_new = grid(dl, k);
            if g_new != g {
                g = g_new;
                win.sample_template(ti, tmask, g[0], g[1]);
            }
            win.sample_live(ji, jl, g[0] + dl[0], g[1] + dl[1]);
            if !locked {
                // The paper's initialisation of λ, δ from the windows' means and standard
                // deviations, repeated while the position is far off: there the windows hardly
                // correlate and a joint step drives λ towards 0 (and the position step, ∝ 1/λ,
                // off). Once the position settles, λ, δ join the Gauss-Newton estimation.
                if let Some((l, dd)) = win.init_photometric() {
                    a = (1.0 / l).clamp(self.a_range.0, self.a_range.1);
                    b = -dd / l;
                }
            }
            let n = win.accumulate(a, b, self.pre(level, g));
            // A coarse level can mislead (texture too fine for it, repetitive patterns): where
            // it fails it contributes nothing and the finer levels start where it started.
            let failed = |e: KltFailure| if level == 0 { Err(e) } else { Ok(None) };
            if n.count < self.needed {
                return failed(n.shortfall(self.needed));
            }
            // The windows' moments ignore the clipping (it shrinks σ_J and moves J̄): where
            // the prediction is clipped (eq. 5.6), λ, δ are estimated jointly from the start.
            locked |= self.photometric && win.clip_model();
            let model = if locked {
                cfg.model
            } else {
                KltModel::Translation
            };
            let Some(factor) = Factor::new(&n, model, cfg.min_eigenvalue) else {
                return failed(KltFailure::Singular);
            };
            let mut step = factor.solve(n.b);
            if model == KltModel::Translation {
                step[2] = 0.0;
                step[3] = 0.0;
            }
            est.iterations += 1;
            dl[0] += step[0];
            dl[1] += step[1];
            a += step[2];
            b += step[3];
            let total = [dl[0] * scale - self.guess[0], dl[1] * scale - self.guess[1]];
            if !(dl[0].is_finite() && dl[1].is_finite() && a.is_finite() && b.is_finite())
                || a < self.a_range.0
                || a > self.a_range.1
                || total[0].hypot(total[1]) > cfg.max_displacement
            {
                return failed(KltFailure::Diverged);
            }
            let step_norm = step[0].hypot(step[1]);
            if !locked {
                locked = step_norm < LOCK_STEP;
                continue;
            }
            let stop = if level == 0 {
                cfg.min_update
            } else {
                self.coarse_stop
            };
            if step_norm < stop {
                break;
            }
        }
        *est = Estimate {
            d: [dl[0] * scale, dl[1] * scale],
            a,
            b,
            locked,
            iterations: est.iterations,
        };
        Ok(Some(k))
    }

    /// The final evaluation at level 0 with the final parameters: SSD, covariance,
    /// acceptance. `final_anchor`: the window grid's anchor level 0 ended with, so that the
    /// SSD and covariance belong to the final `d`.
    fn evaluate(
        &self,
        est: &Estimate,
        final_anchor: Option<[f64; 2]>,
        win: &mut Window,
    ) -> Result<KltResult, KltFailure> {
        let (cfg, d, a, b) = (self.cfg, est.d, est.a, est.b);
        let (Some(t0), Some(j0)) = (self.template.level(0), self.target.level(0)) else {
            return Err(KltFailure::BadInput("empty pyramid"));
        };
        let reg = [self.position[0] + d[0], self.position[1] + d[1]];
        if !inside(j0, reg) {
            return Err(KltFailure::OutOfImage);
        }
        let k = final_anchor.unwrap_or([d[0].round(), d[1].round()]);
        let g = [
            symmetric_grid(self.position[0], d[0], k[0]),
            symmetric_grid(self.position[1], d[1], k[1]),
        ];
        let tmask = self.mask.and_then(|m| m.level(0));
        win.sample_template(t0, tmask, g[0], g[1]);
        win.sample_live(j0, self.jclip(0), g[0] + d[0], g[1] + d[1]);
        let n = win.accumulate(a, b, self.pre(0, g));
        if n.count < self.needed {
            return Err(n.shortfall(self.needed));
        }
        let factor = Factor::new(&n, cfg.model, cfg.min_eigenvalue).ok_or(KltFailure::Singular)?;
        let inv = factor.inverse();
        // The pixels used: censored ones carry no residual (eq. 5.6).
        let count = n.used;
        let var_sum = n.sum_i2 - n.sum_i * n.sum_i / count;
        if var_sum <= 1e-9 * count {
            return Err(KltFailure::Singular);
        }
        // Back in the template's units: I − λJ − δ = −ρ/a.
        let ssd = n.ssd / (a * a);
        let normalised_ssd = ssd / var_sum;
        let params = if self.photometric { 4.0 } else { 2.0 };
        let r = cfg.half_window as f64;
        let (c, m) = noise::interpolated(
            win,
            [g[0] + d[0] - r - 1.0, g[1] + d[1] - r - 1.0],
            cfg.model,
            self.target.smoothing(),
        );
        // Per-pixel noise variance of the live image: the residuals carry it times `c`.
        let sigma2 = n.ssd / (c * (count - params).max(1.0));
        let covariance = (inv * m * inv).fixed_view::<2, 2>(0, 0).into_owned() * sigma2;
        if normalised_ssd.is_nan() || normalised_ssd > cfg.max_normalised_ssd {
            return Err(KltFailure::SsdTooHigh {
                ssd: normalised_ssd,
                threshold: cfg.max_normalised_ssd,
            });
        }
        Ok(KltResult {
            position: reg,
            displacement: d,
            lambda: 1.0 / a,
            delta: -b / a,
            normalised_ssd,
            ssd,
            iterations: est.iterations,
            valid_pixels: n.count,
            covariance,
        })
    }
}
