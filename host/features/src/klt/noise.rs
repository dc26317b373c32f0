//! How the live image's pixel noise reaches the registered position through the bilinear,
//! smoothed samples: the covariance's correction of `KltResult::covariance`
//! (docs/VISION.md §5). Vectors of the four parameters as `wide::f32x4`.

use nalgebra::Matrix4;
use wide::f32x4;

use super::KltModel;
use super::window::Window;

/// `(c, M)` for the window's current samples, all at the sub-pixel fraction of `origin` (the
/// live grid's origin):
///
/// * a residual has variance `c σ²` with `c = Π_axes ((1 − t)² + t²)` (down to ¼ at `t = ½`):
///   `Σ ρ²` estimates `c σ²`, not `σ²`;
/// * neighbouring samples share pixels, so their noise is correlated and
///   `Cov(Σ_m g_m ρ_m) = σ² M` with `M = Σ_p u_p u_pᵀ`, `u_p = Σ_m w_mp g_m`; for gradients
///   that vary slowly over a pixel `M ≈ H`, not `c H`.
///
/// `M = H` and `c = 1` at integer fractions. `g` as in `Window::accumulate`, without the λ, δ
/// components for [`KltModel::Translation`] (not estimated there).
///
/// When the live image was smoothed with a Gaussian `G` (`smoothing` its σ) before sampling,
/// the white noise is that of the raw pixels `q`: a sample's weights become `v_m = w_m ⊛ G`
/// and `u'_q = Σ_p u_p G(p − q)` (`u ⊛ G`, the kernel being symmetric), so `c = Σ_q v_mq²` and
/// `M = Σ_q u'_q u'_qᵀ`.
pub(super) fn interpolated(
    win: &Window,
    origin: [f64; 2],
    model: KltModel,
    smoothing: f32,
) -> (f64, Matrix4<f64>) {
    let side = win.side();
    let es = win.ext_stride();
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
    let mut u = vec![f32x4::ZERO; us * us];
    let wts = [
        (0, 0, (wx[0] * wy[0]) as f32),
        (1, 0, (wx[1] * wy[0]) as f32),
        (0, 1, (wx[0] * wy[1]) as f32),
        (1, 1, (wx[1] * wy[1]) as f32),
    ];
    let photometric = if model == KltModel::Translation {
        0.0
    } else {
        1.0
    };
    for j in 0..side {
        for i in 0..side {
            let k = win.at(i, j);
            if win.weights()[k] == 0.0 {
                continue;
            }
            let e = win.ext_at(i, j);
            let x = &win.ext;
            let (ia, ib) = win.ab_jacobian(k);
            let g = f32x4::new([
                0.5 * (x[e + 1] - x[e - 1]),
                0.5 * (x[e + es] - x[e - es]),
                -ia * photometric,
                -ib * photometric,
            ]);
            for &(ox, oy, wv) in &wts {
                u[(j + oy) * us + i + ox] += g * f32x4::splat(wv);
            }
        }
    }
    if kernel.len() > 1 {
        // u ⊛ G, separably: rows, then (transposed) columns; M does not depend on the order.
        let k32: Vec<f32> = kernel.iter().map(|&v| v as f32).collect();
        let columns = convolve_lines_transposed(&u, us, &k32);
        u = convolve_lines_transposed(&columns, us + kernel.len() - 1, &k32);
    }
    let mut rows = [f32x4::ZERO; 4];
    for v in &u {
        let a = v.to_array();
        for (row, &ak) in rows.iter_mut().zip(&a) {
            *row += *v * f32x4::splat(ak);
        }
    }
    let mut m = Matrix4::zeros();
    for (r, row) in rows.iter().enumerate() {
        for (c, v) in row.to_array().iter().enumerate() {
            m[(r, c)] = *v as f64;
        }
    }
    (c, m)
}

isa::dispatch! {
    /// Convolves each of the `lines` equal lines of `src` with the full 1-D symmetric `kernel`
    /// and returns the result transposed (line `l`, position `j` at `out[j · lines + l]`): two
    /// passes convolve a field along both axes and restore its orientation.
    fn convolve_lines_transposed(src: &[f32x4], lines: usize, kernel: &[f32]) -> Vec<f32x4> {
        // The default smoothing (σ = 1 px) has 7 taps: a copy with them unrolled.
        match <[f32; 7]>::try_from(kernel) {
            Ok(k) => convolve_fixed(src, lines, k),
            Err(_) => convolve_any(src, lines, kernel),
        }
    }
}

/// [`convolve_lines_transposed`] for a kernel of `N` taps.
#[inline(always)]
fn convolve_fixed<const N: usize>(src: &[f32x4], lines: usize, kernel: [f32; N]) -> Vec<f32x4> {
    let len = src.len() / lines.max(1);
    let out_len = len + N - 1;
    let mut out = vec![f32x4::ZERO; out_len * lines];
    let taps = kernel.map(f32x4::splat);
    let mut padded = vec![f32x4::ZERO; len + 2 * (N - 1)];
    for (l, line) in src.chunks_exact(len.max(1)).enumerate() {
        padded[N - 1..N - 1 + len].copy_from_slice(line);
        for (o, win) in padded.windows(N).enumerate() {
            let win: &[f32x4; N] = match win.try_into() {
                Ok(w) => w,
                Err(_) => continue,
            };
            let mut acc = f32x4::ZERO;
            for k in 0..N {
                acc += win[k] * taps[k];
            }
            if let Some(v) = out.get_mut(o * lines + l) {
                *v = acc;
            }
        }
    }
    out
}

/// [`convolve_lines_transposed`] for any kernel length.
#[inline(always)]
fn convolve_any(src: &[f32x4], lines: usize, kernel: &[f32]) -> Vec<f32x4> {
    let len = src.len() / lines.max(1);
    let mut out = vec![f32x4::ZERO; (len + kernel.len() - 1) * lines];
    for (l, line) in src.chunks_exact(len.max(1)).enumerate() {
        for (i, v) in line.iter().enumerate() {
            for (k, gk) in kernel.iter().enumerate() {
                out[(i + k) * lines + l] += *v * f32x4::splat(*gk);
            }
        }
    }
    out
}
