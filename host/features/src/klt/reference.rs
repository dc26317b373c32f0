//! The photometric KLT as it was before its speed path (issue 16): every sample through
//! `GrayF32::sample`, the normal equations in `f64` pixel by pixel, nalgebra's 4×4 Cholesky
//! and eigenvalues per iteration. Kept to test the fast path against (`tests/features_klt.rs`)
//! and to compare it with in `benches/features.rs`; same model, same iterations, same fixed
//! point (docs/VISION.md §5).

use nalgebra::{Matrix4, Vector4};

use super::super::gray::{GrayF32, Mask};
use super::super::pyramid::{MaskPyramid, Pyramid};
use super::{
    Estimate, KltConfig, KltFailure, KltModel, KltResult, LOCK_STEP, Run, anchor, inside,
    symmetric_grid,
};

/// The template window at one level: values and validity, row-major `(2r + 1)²`.
struct Template {
    values: Vec<f32>,
    valid: Vec<bool>,
    count: usize,
}

fn template_window(
    img: &GrayF32,
    mask: Option<&Mask>,
    cx: f64,
    cy: f64,
    r: usize,
    t: &mut Template,
) {
    let side = 2 * r + 1;
    t.values.clear();
    t.valid.clear();
    t.count = 0;
    for j in 0..side {
        for i in 0..side {
            let x = cx + i as f64 - r as f64;
            let y = cy + j as f64 - r as f64;
            let ok_mask = mask.is_none_or(|m| m.valid_bilinear(x, y));
            match (ok_mask, img.sample(x, y)) {
                (true, Some(v)) => {
                    t.values.push(v);
                    t.valid.push(true);
                    t.count += 1;
                }
                _ => {
                    t.values.push(0.0);
                    t.valid.push(false);
                }
            }
        }
    }
}

/// Live-image samples on the window grid shifted by `(cx, cy)`, with a one-pixel rim for the
/// central-difference gradient: `(2r + 3)²` values, NaN outside the image.
fn sample_target(img: &GrayF32, cx: f64, cy: f64, r: usize, out: &mut Vec<f32>) {
    let side = 2 * r + 3;
    out.clear();
    for j in 0..side {
        let y = cy + j as f64 - (r + 1) as f64;
        for i in 0..side {
            let x = cx + i as f64 - (r + 1) as f64;
            out.push(img.sample(x, y).unwrap_or(f32::NAN));
        }
    }
}

/// One pass over the window at the current parameters.
struct Normal {
    h: Matrix4<f64>,
    b: Vector4<f64>,
    ssd: f64,
    count: usize,
    outside: usize,
    /// `Σ I`, `Σ I²` over the pixels used (for the normalisation of the SSD).
    sum_i: f64,
    sum_i2: f64,
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

/// Accumulates the normal equations for `α = [d₁, d₂, a, b]` with `a = 1/λ`, `b = −δ/λ`,
/// i.e. the residual `ρ = J(m + d) − a I(m) − b = −(I − λJ − δ)/λ` (see the module
/// documentation for why the residual is measured in live-image units).
fn accumulate(t: &Template, ext: &[f32], r: usize, a: f64, b: f64) -> Normal {
    let side = 2 * r + 1;
    let es = side + 2;
    let mut h = [[0f64; 4]; 4];
    let mut rhs = [0f64; 4];
    let (mut ssd, mut count, mut outside, mut sum_i, mut sum_i2) = (0.0, 0, 0, 0.0, 0.0);
    for j in 0..side {
        for i in 0..side {
            let k = j * side + i;
            if !t.valid[k] {
                continue;
            }
            let e = (j + 1) * es + i + 1;
            let (jc, jl, jr, ju, jd) = (ext[e], ext[e - 1], ext[e + 1], ext[e - es], ext[e + es]);
            if jc.is_nan() || jl.is_nan() || jr.is_nan() || ju.is_nan() || jd.is_nan() {
                outside += 1;
                continue;
            }
            let iv = t.values[k] as f64;
            // ∂ρ/∂α: the live image's gradient (central differences of the bilinear samples),
            // −I and −1.
            let g = [0.5 * (jr - jl) as f64, 0.5 * (jd - ju) as f64, -iv, -1.0];
            let res = jc as f64 - a * iv - b;
            for p in 0..4 {
                rhs[p] -= g[p] * res;
                for q in p..4 {
                    h[p][q] += g[p] * g[q];
                }
            }
            ssd += res * res;
            sum_i += iv;
            sum_i2 += iv * iv;
            count += 1;
        }
    }
    let mut hm = Matrix4::zeros();
    for a in 0..4 {
        for c in a..4 {
            hm[(a, c)] = h[a][c];
            hm[(c, a)] = h[a][c];
        }
    }
    Normal {
        h: hm,
        b: Vector4::from(rhs),
        ssd,
        count,
        outside,
        sum_i,
        sum_i2,
    }
}

/// The normal matrix restricted to the estimated parameters, inverted; `None` if singular or
/// the position block (after eliminating `λ, δ`) is too weak.
fn invert(n: &Normal, model: KltModel, min_eigenvalue: f64) -> Option<Matrix4<f64>> {
    let mut h = n.h;
    if model == KltModel::Translation {
        // Fixed λ, δ: decouple them with unit rows so the same 4×4 solve applies.
        for a in 0..4 {
            for c in 0..4 {
                if a >= 2 || c >= 2 {
                    h[(a, c)] = if a == c { 1.0 } else { 0.0 };
                }
            }
        }
    }
    let inv = h.cholesky()?.inverse();
    // (H⁻¹)_dd is the inverse of the Schur complement of the position block.
    let cov_dd = inv.fixed_view::<2, 2>(0, 0).into_owned();
    let schur = cov_dd.try_inverse()?;
    let eig = schur.symmetric_eigenvalues();
    let min_eig = eig.x.min(eig.y);
    if !min_eig.is_finite() || min_eig < min_eigenvalue * n.count as f64 {
        return None;
    }
    Some(inv)
}

/// Registers the template feature at `position` (level-0 px of the template pyramid) in the
/// live pyramid, starting from displacement `guess`.
///
/// `template` is the blurred rendering's pyramid, `mask` its validity (None: all valid),
/// `target` the live image's pyramid; both pyramids share the pixel grid (the live image is
/// undistorted to the rendering's intrinsics). The inputs are checked as the fast path's.
pub fn register(
    template: &Pyramid,
    mask: Option<&MaskPyramid>,
    target: &Pyramid,
    position: [f64; 2],
    guess: [f64; 2],
    cfg: &KltConfig,
) -> Result<KltResult, KltFailure> {
    let run = Run::new(template, mask, target, position, guess, cfg)?;
    let side = 2 * cfg.half_window + 1;
    let mut est = Estimate {
        d: guess,
        a: 1.0,
        b: 0.0,
        locked: !run.photometric,
        iterations: 0,
    };
    let mut ext = Vec::with_capacity((side + 2) * (side + 2));
    let mut t = Template {
        values: Vec::with_capacity(side * side),
        valid: Vec::with_capacity(side * side),
        count: 0,
    };
    let mut final_anchor = None;
    for level in (0..run.levels).rev() {
        let k = refine_level(&run, level, &mut est, &mut t, &mut ext)?;
        if level == 0 {
            final_anchor = k;
        }
    }
    evaluate(&run, &est, final_anchor, &mut t, &mut ext)
}

/// Gauss-Newton at one pyramid level, from `est`, sample by sample. Returns the window
/// grid's anchor it ended with (`None` where the level was left to the finer ones); a coarse
/// level that fails leaves `est` as it found it.
fn refine_level(
    run: &Run<'_>,
    level: usize,
    est: &mut Estimate,
    t: &mut Template,
    ext: &mut Vec<f32>,
) -> Result<Option<[f64; 2]>, KltFailure> {
    let (cfg, r, needed) = (run.cfg, run.cfg.half_window, run.needed);
    let scale = (1u32 << level) as f64;
    let (Some(ti), Some(ji)) = (run.template.level(level), run.target.level(level)) else {
        return Ok(None);
    };
    let mi = run.mask.and_then(|m| m.level(level));
    let (cx, cy) = (run.position[0] / scale, run.position[1] / scale);
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
    template_window(ti, mi, g[0], g[1], r, t);
    if t.count < needed {
        if level == 0 {
            return Err(KltFailure::TooFewValidPixels {
                valid: t.count,
                needed,
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
            template_window(ti, mi, g[0], g[1], r, t);
        }
        sample_target(ji, g[0] + dl[0], g[1] + dl[1], r, ext);
        if !locked {
            // The paper's initialisation of λ, δ from the windows' means and standard
            // deviations, repeated while the position is far off (see the fast path).
            if let Some((l, dd)) = init_photometric(t, ext, r) {
                a = (1.0 / l).clamp(run.a_range.0, run.a_range.1);
                b = -dd / l;
            }
        }
        let n = accumulate(t, ext, r, a, b);
        // A coarse level that fails contributes nothing: the finer levels start where it
        // started.
        let failed = |e: KltFailure| if level == 0 { Err(e) } else { Ok(None) };
        if n.count < needed {
            return failed(n.shortfall(needed));
        }
        let model = if locked {
            cfg.model
        } else {
            KltModel::Translation
        };
        let Some(inv) = invert(&n, model, cfg.min_eigenvalue) else {
            return failed(KltFailure::Singular);
        };
        let mut step = inv * n.b;
        if model == KltModel::Translation {
            step[2] = 0.0;
            step[3] = 0.0;
        }
        est.iterations += 1;
        dl[0] += step[0];
        dl[1] += step[1];
        a += step[2];
        b += step[3];
        let total = [dl[0] * scale - run.guess[0], dl[1] * scale - run.guess[1]];
        if !(dl[0].is_finite() && dl[1].is_finite() && a.is_finite() && b.is_finite())
            || a < run.a_range.0
            || a > run.a_range.1
            || total[0].hypot(total[1]) > cfg.max_displacement
        {
            return failed(KltFailure::Diverged);
        }
        let step_norm = step[0].hypot(step[1]);
        if !locked {
            locked = step_norm < LOCK_STEP;
            continue;
        }
        if step_norm < cfg.min_update {
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

/// The final evaluation at level 0 with the final parameters: SSD, covariance, acceptance
/// (`final_anchor`: the anchor level 0 ended with, so that they belong to the final `d`).
fn evaluate(
    run: &Run<'_>,
    est: &Estimate,
    final_anchor: Option<[f64; 2]>,
    t: &mut Template,
    ext: &mut Vec<f32>,
) -> Result<KltResult, KltFailure> {
    let (cfg, r, needed, d, a, b) = (
        run.cfg,
        run.cfg.half_window,
        run.needed,
        est.d,
        est.a,
        est.b,
    );
    let (Some(t0), Some(j0)) = (run.template.level(0), run.target.level(0)) else {
        return Err(KltFailure::BadInput("empty pyramid"));
    };
    let reg = [run.position[0] + d[0], run.position[1] + d[1]];
    if !inside(j0, reg) {
        return Err(KltFailure::OutOfImage);
    }
    let k = final_anchor.unwrap_or([d[0].round(), d[1].round()]);
    let g = [
        symmetric_grid(run.position[0], d[0], k[0]),
        symmetric_grid(run.position[1], d[1], k[1]),
    ];
    template_window(t0, run.mask.and_then(|m| m.level(0)), g[0], g[1], r, t);
    sample_target(j0, g[0] + d[0], g[1] + d[1], r, ext);
    let n = accumulate(t, ext, r, a, b);
    if n.count < needed {
        return Err(n.shortfall(needed));
    }
    let inv = invert(&n, cfg.model, cfg.min_eigenvalue).ok_or(KltFailure::Singular)?;
    let count = n.count as f64;
    let var_sum = n.sum_i2 - n.sum_i * n.sum_i / count;
    if var_sum <= 1e-9 * count {
        return Err(KltFailure::Singular);
    }
    // Back in the template's units: I − λJ − δ = −ρ/a.
    let ssd = n.ssd / (a * a);
    let normalised_ssd = ssd / var_sum;
    let params = if run.photometric { 4.0 } else { 2.0 };
    let (c, m) = interpolated_noise(
        t,
        ext,
        r,
        [g[0] + d[0], g[1] + d[1]],
        cfg.model,
        run.target.smoothing(),
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

/// How white noise of variance `σ²` in the live image's pixels reaches the estimate through
/// the bilinear samples (all at the same sub-pixel fraction `t`, from the live grid origin
/// `origin`): each sample `m` is `Σ_p w_mp J_p` over 4 pixels, so
///
/// * a residual has variance `c σ²` with `c = Π_axes ((1 − t)² + t²)` (down to ¼ at `t = ½`):
///   `Σ ρ²` estimates `c σ²`, not `σ²`;
/// * neighbouring samples share pixels, so their noise is correlated and
///   `Cov(Σ_m g_m ρ_m) = σ² M` with `M = Σ_p u_p u_pᵀ`, `u_p = Σ_m w_mp g_m`; for gradients
///   that vary slowly over a pixel `M ≈ H`, not `c H`.
///
/// Returns `(c, M)`; `M = H` and `c = 1` at integer fractions. `g` as in [`accumulate`],
/// without the λ, δ components for [`KltModel::Translation`] (not estimated there).
///
/// When the live image was smoothed with a Gaussian `G` (`smoothing` = its σ, see
/// [`KltConfig::smoothing`]) before sampling, the white noise is that of the raw pixels `q`:
/// a sample's weights become `v_m = w_m ⊛ G` and `u'_q = Σ_p u_p G(p − q)` (`u ⊛ G`, the
/// kernel being symmetric), so `c = Σ_q v_mq²` and `M = Σ_q u'_q u'_qᵀ`.
fn interpolated_noise(
    t: &Template,
    ext: &[f32],
    r: usize,
    origin: [f64; 2],
    model: KltModel,
    smoothing: f32,
) -> (f64, Matrix4<f64>) {
    let side = 2 * r + 1;
    let es = side + 2;
    let (tx, ty) = (origin[0] - origin[0].floor(), origin[1] - origin[1].floor());
    let wx = [1.0 - tx, tx];
    let wy = [1.0 - ty, ty];
    let kernel: Vec<f64> = super::super::pyramid::gaussian_kernel(smoothing)
        .map(|half| {
            // The full symmetric kernel, index k ↔ offset k − R.
            let rr = half.len() - 1;
            (0..=2 * rr).map(|k| half[k.abs_diff(rr)] as f64).collect()
        })
        .unwrap_or_else(|| vec![1.0]);
    // Σ of the squared weights of one bilinear axis convolved with the kernel.
    let axis_c = |w: [f64; 2]| -> f64 {
        let mut v = vec![0.0; kernel.len() + 1];
        for (p, wp) in w.iter().enumerate() {
            for (k, gk) in kernel.iter().enumerate() {
                v[p + k] += wp * gk;
            }
        }
        v.iter().map(|x| x * x).sum()
    };
    let c = axis_c(wx) * axis_c(wy);
    // u over the (side + 1)² pixels the samples touch.
    let us = side + 1;
    let mut u = vec![Vector4::<f64>::zeros(); us * us];
    for j in 0..side {
        for i in 0..side {
            if !t.valid[j * side + i] {
                continue;
            }
            let e = (j + 1) * es + i + 1;
            let (jc, jl, jr, ju, jd) = (ext[e], ext[e - 1], ext[e + 1], ext[e - es], ext[e + es]);
            if jc.is_nan() || jl.is_nan() || jr.is_nan() || ju.is_nan() || jd.is_nan() {
                continue;
            }
            let mut g = Vector4::new(
                0.5 * (jr - jl) as f64,
                0.5 * (jd - ju) as f64,
                -(t.values[j * side + i] as f64),
                -1.0,
            );
            if model == KltModel::Translation {
                g[2] = 0.0;
                g[3] = 0.0;
            }
            for (oy, wyv) in wy.iter().enumerate() {
                for (ox, wxv) in wx.iter().enumerate() {
                    u[(j + oy) * us + i + ox] += g * (wxv * wyv);
                }
            }
        }
    }
    if kernel.len() > 1 {
        // u ⊛ G, separably: rows, then (transposed) columns; M does not depend on the order.
        let columns = convolve_lines_transposed(&u, us, &kernel);
        u = convolve_lines_transposed(&columns, us + kernel.len() - 1, &kernel);
    }
    let m = u
        .iter()
        .fold(Matrix4::zeros(), |acc, v| acc + v * v.transpose());
    (c, m)
}

/// Convolves each of the `lines` equal lines of `src` with the full 1-D `kernel` and returns
/// the result transposed (line `l`, position `j` at `out[j · lines + l]`): two passes convolve
/// a field along both axes and restore its orientation.
fn convolve_lines_transposed(
    src: &[Vector4<f64>],
    lines: usize,
    kernel: &[f64],
) -> Vec<Vector4<f64>> {
    let len = src.len() / lines.max(1);
    let mut out = vec![Vector4::<f64>::zeros(); (len + kernel.len() - 1) * lines];
    for (l, line) in src.chunks_exact(len.max(1)).enumerate() {
        for (i, v) in line.iter().enumerate() {
            if *v == Vector4::zeros() {
                continue;
            }
            for (k, gk) in kernel.iter().enumerate() {
                out[(i + k) * lines + l] += v * *gk;
            }
        }
    }
    out
}

/// `λ = σ_I / σ_J`, `δ = Ī − λ J̄` over the pixels valid in both windows (the paper's
/// initialisation from the windows' means and standard deviations).
fn init_photometric(t: &Template, ext: &[f32], r: usize) -> Option<(f64, f64)> {
    let side = 2 * r + 1;
    let es = side + 2;
    let (mut n, mut si, mut si2, mut sj, mut sj2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for j in 0..side {
        for i in 0..side {
            let k = j * side + i;
            let jv = ext[(j + 1) * es + i + 1];
            if !t.valid[k] || jv.is_nan() {
                continue;
            }
            let (iv, jv) = (t.values[k] as f64, jv as f64);
            n += 1.0;
            si += iv;
            si2 += iv * iv;
            sj += jv;
            sj2 += jv * jv;
        }
    }
    if n < 2.0 {
        return None;
    }
    let (mi, mj) = (si / n, sj / n);
    let (vi, vj) = ((si2 / n - mi * mi).max(0.0), (sj2 / n - mj * mj).max(0.0));
    // A flat live window says nothing about contrast: keep λ = 1 and match the means.
    let lambda = if vj > 1e-6 && vi > 1e-6 {
        (vi / vj).sqrt()
    } else {
        1.0
    };
    Some((lambda, mi - lambda * mj))
}
