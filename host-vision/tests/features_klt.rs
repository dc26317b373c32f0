//! Photometric KLT (docs/VISION.md §5) on real images of `../shared/data` with known synthetic
//! warps (skipped with a message when that folder is absent).
//!
//! How the live images are made: the source photograph is smoothed (Gaussian σ = 1 px) and
//! that smoothed image `S` is the "rendering" (template `I = S`). The live image is
//! `J(x) = (S(x − d) − δ) / λ + n`, so that `I(m) = λ J(m + d) + δ` holds up to the noise
//! `n ~ N(0, 2²)` gray levels: the subpixel shift `S(x − d)` is bicubic (Keys, a = −0.5)
//! interpolation of the smoothed image, and everything stays in `f32` **without clipping**
//! (with λ = 0.4 the live image reaches ~800 "gray levels"; a real 8-bit camera would
//! saturate, which these tests do not model). Features are FAST corners of `S` spread over a
//! grid; every registration starts from `d = 0`, i.e. the prediction is off by the full shift.

use std::path::{Path, PathBuf};

use host_vision::features::gray::{GrayF32, Mask};
use host_vision::features::grid::{self, GridConfig};
use host_vision::features::klt::{self, KltConfig, KltFailure, KltModel};
use host_vision::features::pyramid::{self, Pyramid, TemplatePyramid};

mod klt_cases;

fn data_root() -> Option<PathBuf> {
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
    if root.is_dir() {
        Some(root.to_path_buf())
    } else {
        println!(
            "SKIPPED: shared data folder {} absent; real-image KLT checks not run",
            root.display()
        );
        None
    }
}

fn source_images(root: &Path) -> Vec<PathBuf> {
    let euroc = root.join("euroc-v101-micro/mav0/cam0/data");
    vec![
        root.join("textures/skimage/camera.png"),
        root.join("textures/skimage/astronaut.png"),
        root.join("textures/skimage/brick.png"),
        root.join("textures/skimage/gravel.png"),
        root.join("textures/opencv_samples/graf1.png"),
        root.join("textures/opencv_samples/box.png"),
        root.join("textures/opencv_samples/rubberwhale1.png"),
        euroc.join("1403715273262142976.png"),
        euroc.join("1403715275762142976.png"),
    ]
}

/// The smoothed source `S` (the "rendering").
fn smoothed(path: &Path) -> GrayF32 {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_luma8();
    pyramid::gaussian_blur(&GrayF32::from_gray8(&img).unwrap(), 1.0)
}

/// Deterministic normal deviates (xorshift64* + Box-Muller).
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

/// Interpolation kernel half-width of the exact shift, px.
const SINC_RADIUS: i64 = 8;

/// Lanczos-8 weights for the samples `x0 − 7 ..= x0 + 8` around position `x` (`x0 = ⌊x⌋`),
/// normalised to sum 1 so a constant stays exactly constant (no brightness error).
fn sinc_weights(x: f64) -> (i64, [f64; 16]) {
    let x0 = x.floor() as i64;
    let mut w = [0.0; 16];
    for (k, wk) in w.iter_mut().enumerate() {
        let t = x - (x0 - SINC_RADIUS + 1 + k as i64) as f64;
        let sinc = |u: f64| {
            if u.abs() < 1e-12 {
                1.0
            } else {
                (std::f64::consts::PI * u).sin() / (std::f64::consts::PI * u)
            }
        };
        *wk = if t.abs() < SINC_RADIUS as f64 {
            sinc(t) * sinc(t / SINC_RADIUS as f64)
        } else {
            0.0
        };
    }
    let sum: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= sum);
    (x0 - SINC_RADIUS + 1, w)
}

/// `S(x − d)` on the whole pixel grid: separable windowed-sinc interpolation (borders
/// clamped). `S` is smoothed with σ = 1 px, so it is practically band-limited (its spectrum
/// at 0.4 cycles/px is 4 % of DC) and this is the image of the same scene shifted by `d`:
/// same contrast at every sub-pixel shift. A cubic (Keys) shift is not: at fractions near
/// ½ px it smooths, lowering the contrast of `J` by up to ~1 % on fine texture (box.png),
/// which the registration rightly reports as a λ change and, through the window mean, as a
/// δ error of several % (measured: 3.7 % on box.png at λ = 1.6, δ = 20 without noise).
fn shift_image(s: &GrayF32, d: [f64; 2]) -> Vec<f64> {
    let (w, h) = (s.width() as i64, s.height() as i64);
    let px = |x: i64, y: i64| s.data()[(y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize] as f64;
    // Every column (row) has the same fraction: one set of weights per axis.
    let (ox, wx) = sinc_weights(-d[0]);
    let (oy, wy) = sinc_weights(-d[1]);
    let mut rows = vec![0.0; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            rows[(y * w + x) as usize] = wx
                .iter()
                .enumerate()
                .map(|(k, wk)| wk * px(x + ox + k as i64, y))
                .sum();
        }
    }
    let mut out = vec![0.0; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            out[(y * w + x) as usize] = wy
                .iter()
                .enumerate()
                .map(|(k, wk)| wk * rows[((y + oy + k as i64).clamp(0, h - 1) * w + x) as usize])
                .sum();
        }
    }
    out
}

/// `J(x) = (S(x − d) − δ) / λ + n`, f32, unclipped.
fn live(s: &GrayF32, d: [f64; 2], lambda: f64, delta: f64, noise: f64, seed: u64) -> GrayF32 {
    let mut rng = Rng(seed | 1);
    let data = shift_image(s, d)
        .into_iter()
        .map(|v| ((v - delta) / lambda + noise * rng.normal()) as f32)
        .collect();
    GrayF32::new(s.width(), s.height(), data).unwrap()
}

/// Spread FAST corners of `S` at least `margin` from the border.
fn features(s: &GrayF32, margin: usize, max: usize) -> Vec<[f64; 2]> {
    let cfg = GridConfig {
        cell_size: 40,
        fast_threshold: 20,
        per_cell: 1,
        min_mask_fraction: 0.0,
        border: margin,
    };
    let mut corners = grid::extract(&s.to_gray8(), None, &[], &cfg).unwrap();
    corners.sort_by_key(|c| std::cmp::Reverse(c.score));
    corners
        .iter()
        .take(max)
        .map(|c| [c.x as f64, c.y as f64])
        .collect()
}

fn median(v: &mut [f64]) -> f64 {
    assert!(!v.is_empty());
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Per-case summary over features.
#[derive(Debug)]
struct Stats {
    tried: usize,
    accepted: usize,
    /// Accepted and within 0.5 px of the truth.
    correct: usize,
    median_shift_err: f64,
    median_lambda_rel_err: f64,
    median_delta_err: f64,
    median_iterations: f64,
}

#[allow(clippy::too_many_arguments)]
fn run_case(
    tmpl: &Pyramid,
    mask: Option<&pyramid::MaskPyramid>,
    j: &GrayF32,
    feats: &[[f64; 2]],
    d: [f64; 2],
    lambda: f64,
    delta: f64,
    cfg: &KltConfig,
) -> (Stats, Vec<Result<klt::KltResult, KltFailure>>) {
    run_case_from(tmpl, mask, j, feats, d, lambda, delta, [0.0; 2], cfg)
}

/// As [`run_case`], every registration starting from displacement `guess`.
#[allow(clippy::too_many_arguments)]
fn run_case_from(
    tmpl: &Pyramid,
    mask: Option<&pyramid::MaskPyramid>,
    j: &GrayF32,
    feats: &[[f64; 2]],
    d: [f64; 2],
    lambda: f64,
    delta: f64,
    guess: [f64; 2],
    cfg: &KltConfig,
) -> (Stats, Vec<Result<klt::KltResult, KltFailure>>) {
    let target = cfg.target_pyramid(j.clone());
    let mut shift = Vec::new();
    let mut lam = Vec::new();
    let mut del = Vec::new();
    let mut its = Vec::new();
    let mut correct = 0;
    let mut results = Vec::new();
    for &p in feats {
        let r = klt::register(tmpl, mask, &target, p, guess, cfg);
        if let Ok(r) = &r {
            let e = (r.displacement[0] - d[0]).hypot(r.displacement[1] - d[1]);
            shift.push(e);
            lam.push((r.lambda - lambda).abs() / lambda);
            del.push((r.delta - delta).abs());
            its.push(r.iterations as f64);
            if e < 0.5 {
                correct += 1;
            }
        }
        results.push(r);
    }
    let med = |v: &mut Vec<f64>| if v.is_empty() { f64::NAN } else { median(v) };
    (
        Stats {
            tried: feats.len(),
            accepted: shift.len(),
            correct,
            median_shift_err: med(&mut shift),
            median_lambda_rel_err: med(&mut lam),
            median_delta_err: med(&mut del),
            median_iterations: med(&mut its),
        },
        results,
    )
}

/// Cramér-Rao bound of `δ` for the feature at `p` (integer pixel) with white noise `sigma` in
/// the live image: the 15×15 window's Fisher information for `[d₁, d₂, a, b]` in the
/// registration's residual `ρ = J − aI − b` (`a = 1/λ`, `b = −δ/λ`, `J` at the truth), mapped
/// to `δ = −b/a`. `δ` is the offset at intensity 0, far outside the window's intensities, so
/// its error is mostly the contrast error times the window mean: `Δδ ≈ −Δλ · J̄`.
fn delta_bound(s: &GrayF32, p: [f64; 2], lambda: f64, delta: f64, sigma: f64) -> f64 {
    let (a, b) = (1.0 / lambda, -delta / lambda);
    let mut h = nalgebra::Matrix4::<f64>::zeros();
    let px = |x: i64, y: i64| s.get(x as usize, y as usize).unwrap() as f64;
    let (cx, cy) = (p[0] as i64, p[1] as i64);
    for y in cy - 7..=cy + 7 {
        for x in cx - 7..=cx + 7 {
            let g = nalgebra::Vector4::new(
                0.5 * a * (px(x + 1, y) - px(x - 1, y)),
                0.5 * a * (px(x, y + 1) - px(x, y - 1)),
                -px(x, y),
                -1.0,
            );
            h += g * g.transpose();
        }
    }
    let cov = h.try_inverse().unwrap() * sigma * sigma;
    let grad = nalgebra::Vector4::new(0.0, 0.0, b / (a * a), -1.0 / a);
    (grad.transpose() * cov * grad)[(0, 0)].sqrt()
}

/// Shift, contrast and brightness cases: λ from 0.4 to 2.5, δ from −60 to +60, shifts up to
/// 20 px in all directions.
fn cases(seed: u64) -> Vec<([f64; 2], f64, f64)> {
    let mut rng = Rng(seed);
    let photometric = [
        (0.4, 60.0),
        (0.4, -60.0),
        (0.6, 30.0),
        (1.0, 0.0),
        (1.0, -40.0),
        (1.6, 20.0),
        (2.5, -60.0),
        (2.5, 60.0),
    ];
    photometric
        .iter()
        .enumerate()
        .map(|(k, &(l, dl))| {
            // Radii cycle through 3..20 px, directions are random.
            let radius = [20.0, 3.3, 12.7, 17.1, 7.45, 20.0, 15.2, 9.9][k];
            let a = 2.0 * std::f64::consts::PI * rng.uniform();
            ([radius * a.cos(), radius * a.sin()], l, dl)
        })
        .collect()
}

/// Cases that miss the targets, left visible rather than hidden by a looser threshold:
/// `(file, λ, δ, check)`. None now. The last one, astronaut.png at λ = 1.6, δ = 20 (median
/// |Δδ| 0.44 gray levels: 2.2 % of |δ|, 1.6× the Cramér-Rao bound's median 0.27), met the δ
/// criterion once that became "2 % of |δ| or 2× the bound" (issue 16): at σ = 2 gray levels
/// a 15×15 window cannot do better than the bound, and 2 % asked for less than it in three
/// cases.
const KNOWN_SHORTFALLS: &[(&str, f64, f64, &str)] = &[];

#[test]
fn recovers_shift_contrast_brightness_on_real_images() {
    let Some(root) = data_root() else { return };
    let cfg = KltConfig::default();
    let mut totals = Totals::default();
    for (i, path) in source_images(&root).iter().enumerate() {
        recover_on_image(i, path, &cfg, &mut totals);
    }
    totals.report(source_images(&root).len() * 8);
}

/// Registers the features of source image `i` (at `path`) under every case of
/// `cases(1000 + i)`, printing each case's figures and adding them to `totals`.
fn recover_on_image(i: usize, path: &Path, cfg: &KltConfig, totals: &mut Totals) {
    // Brick (periodic, bricks ~32 px wide) and gravel (stones ~15 px) hold no structure at
    // the coarse levels: a local method cannot bridge 20 px there, so their shifts are
    // scaled to at most 8 px.
    // Brick is periodic (bricks ~32 px wide, courses ~16 px high) and gravel has no
    // structure left at the coarse levels: from d = 0 a 20 px shift is beyond what a
    // local method can bridge there (shown in
    // `periodic_and_structureless_textures_need_the_prediction`). They start where the
    // tracker starts, at the displacement predicted from the pose: off by ~3 px here.
    let predicted = path.ends_with("brick.png") || path.ends_with("gravel.png");
    let s = smoothed(path);
    let tmpl = Pyramid::build_smoothed(s.clone(), cfg.levels, cfg.smoothing);
    let feats = features(&s, 40, 25);
    assert!(feats.len() >= 10, "{}: too few corners", path.display());
    for (k, (d, lambda, delta)) in cases(1000 + i as u64).into_iter().enumerate() {
        let guess = if predicted {
            let a = 0.9 * k as f64;
            [d[0] + 3.0 * a.cos(), d[1] + 3.0 * a.sin()]
        } else {
            [0.0; 2]
        };
        let j = live(&s, d, lambda, delta, 2.0, (i * 100 + k) as u64 + 7);
        let (st, results) = run_case_from(&tmpl, None, &j, &feats, d, lambda, delta, guess, cfg);
        let delta_floor = delta_noise_floor(&s, &feats, lambda, delta);
        let case = PhotometricCase {
            file: path.file_name().unwrap().to_string_lossy().to_string(),
            s: &s,
            feats: &feats,
            d,
            lambda,
            delta,
            st,
            results,
            delta_floor,
        };
        case.print();
        totals.check(&case);
        totals.add(&case);
    }
}

/// What noise alone allows for δ: median over the features of the bound's median |error|
/// (0.674 σ for a normal error).
fn delta_noise_floor(s: &GrayF32, feats: &[[f64; 2]], lambda: f64, delta: f64) -> f64 {
    let mut bound: Vec<f64> = feats
        .iter()
        .map(|&p| 0.6745 * delta_bound(s, p, lambda, delta, 2.0))
        .collect();
    median(&mut bound)
}

/// One case of the main test on one image, registered: the truth (`d`, `lambda`, `delta`),
/// the registrations' results and summary, and the noise floor of δ.
struct PhotometricCase<'a> {
    /// The source image's file name.
    file: String,
    /// The smoothed source `S`.
    s: &'a GrayF32,
    /// The features registered.
    feats: &'a [[f64; 2]],
    d: [f64; 2],
    lambda: f64,
    delta: f64,
    st: Stats,
    results: Vec<Result<klt::KltResult, KltFailure>>,
    /// See [`delta_noise_floor`].
    delta_floor: f64,
}

impl PhotometricCase<'_> {
    /// Prints the case's figures, its δ against the noise floor, and its failures.
    fn print(&self) {
        let Self {
            d,
            lambda,
            delta,
            st,
            delta_floor,
            ..
        } = self;
        println!(
            "{:>28} d=({:+6.2},{:+6.2}) λ={lambda:.1} δ={delta:+5.0}: accepted {:>2}/{:>2}, \
             correct {:>2}, median |Δd| {:.4} px, |Δλ|/λ {:.4}, |Δδ| {:.3}, iterations {}",
            self.file,
            d[0],
            d[1],
            st.accepted,
            st.tried,
            st.correct,
            st.median_shift_err,
            st.median_lambda_rel_err,
            st.median_delta_err,
            st.median_iterations
        );
        // A share of |δ| means nothing at δ = 0 (the tolerance there is in gray levels).
        let share = if *delta == 0.0 {
            "δ = 0".to_string()
        } else {
            format!("{:.2} % of |δ|", 100.0 * st.median_delta_err / delta.abs())
        };
        println!(
            "    δ: median |Δδ| {:.3} ({share}); noise floor (Cramér-Rao) {delta_floor:.3}",
            st.median_delta_err
        );
        let failures: Vec<String> = self
            .results
            .iter()
            .filter_map(|r| r.as_ref().err().map(|e| format!("{e}")))
            .collect();
        if !failures.is_empty() {
            println!("    failures: {failures:?}");
        }
    }
}

/// The main test's totals over every image and case, and the criteria each case missed.
#[derive(Default)]
struct Totals {
    all_shift: Vec<f64>,
    all_lambda: Vec<f64>,
    all_delta: Vec<f64>,
    tried: usize,
    accepted: usize,
    correct: usize,
    delta_rel: Vec<f64>,
    violations: Vec<String>,
    noise_limited_cases: Vec<String>,
    shortfalls: usize,
    z2: Vec<f64>,
}

impl Totals {
    /// Notes a criterion `what` that `case` missed (`ok` false): a known shortfall is printed
    /// and counted, anything else is a violation.
    fn note(&mut self, case: &PhotometricCase, ok: bool, what: &str) {
        if ok {
            return;
        }
        let PhotometricCase {
            file,
            lambda,
            delta,
            st,
            ..
        } = case;
        let msg = format!("{file} λ={lambda} δ={delta}: {what}: {st:?}");
        if KNOWN_SHORTFALLS.contains(&(file.as_str(), *lambda, *delta, what)) {
            println!("    KNOWN SHORTFALL (see KNOWN_SHORTFALLS): {msg}");
            self.shortfalls += 1;
        } else {
            self.violations.push(msg);
        }
    }

    /// Checks `case` against the targets (share correct, shift, λ and δ errors), listing it
    /// where noise alone rules out δ's 2 % target.
    fn check(&mut self, case: &PhotometricCase) {
        let (st, delta, delta_floor) = (&case.st, case.delta, case.delta_floor);
        self.note(
            case,
            st.correct as f64 >= 0.8 * st.tried as f64,
            "fewer than 80 % correct",
        );
        self.note(case, st.median_shift_err < 0.05, "median shift error");
        self.note(case, st.median_lambda_rel_err < 0.02, "median λ error");
        // δ's median error within 2 % of |δ| (for δ = 0 within 1 gray level) or within 2×
        // the Cramér-Rao bound's median error: where the noise alone makes 2 % impossible
        // for a 15×15 window (small |δ| with λ ≥ 1.6, where the live image has little
        // contrast), the bound decides; such cases are listed.
        let target = if delta == 0.0 {
            1.0
        } else {
            0.02 * delta.abs()
        };
        let noise_limited = 2.0 * delta_floor > target;
        if noise_limited {
            self.noise_limited_cases.push(format!(
                "{} λ={} δ={delta}: median |Δδ| {:.3}, bound {delta_floor:.3}, 2 % = {target:.3}",
                case.file, case.lambda, st.median_delta_err
            ));
        }
        self.note(
            case,
            st.median_delta_err < target.max(2.0 * delta_floor),
            "median δ error",
        );
    }

    /// Adds `case`'s errors and counts to the totals.
    fn add(&mut self, case: &PhotometricCase) {
        let PhotometricCase {
            s,
            feats,
            d,
            lambda,
            delta,
            st,
            results,
            ..
        } = case;
        let (d, lambda, delta) = (*d, *lambda, *delta);
        if delta != 0.0 {
            self.delta_rel.push(st.median_delta_err / delta.abs());
        }
        for (r, p) in results.iter().zip(feats.iter()) {
            if let Ok(r) = r {
                let z = (r.delta - delta) / delta_bound(s, *p, lambda, delta, 2.0);
                self.z2.push(z * z);
            }
        }
        self.tried += st.tried;
        self.accepted += st.accepted;
        self.correct += st.correct;
        for r in results.iter().flatten() {
            self.all_shift
                .push((r.displacement[0] - d[0]).hypot(r.displacement[1] - d[1]));
            self.all_lambda.push((r.lambda - lambda).abs() / lambda);
            self.all_delta.push((r.delta - delta).abs());
        }
    }

    /// Prints the totals over all `cases` cases and asserts the overall criteria: δ as good
    /// as the noise allows, wrong matches rare, no violations, no stale known shortfalls.
    fn report(mut self, cases: usize) {
        let (tried, accepted, correct) = (self.tried, self.accepted, self.correct);
        println!(
            "ALL: {accepted}/{tried} accepted, {correct} within 0.5 px; median |Δd| {:.4} px, \
             median |Δλ|/λ {:.4}, median |Δδ| {:.3} gray levels",
            median(&mut self.all_shift),
            median(&mut self.all_lambda),
            median(&mut self.all_delta)
        );
        self.delta_rel.sort_by(|a, b| a.total_cmp(b));
        println!(
            "per-case median |Δδ|/|δ| (δ ≠ 0): median {:.4}, worst {:.4}",
            median(&mut self.delta_rel.clone()),
            self.delta_rel.last().unwrap()
        );
        let efficiency = self.z2.iter().sum::<f64>() / self.z2.len() as f64;
        let noise_limited_cases = &self.noise_limited_cases;
        println!(
            "δ: mean (Δδ / Cramér-Rao σ)² = {efficiency:.2} (1 = efficient); noise-limited cases \
             ({} of {cases}): {noise_limited_cases:#?}",
            noise_limited_cases.len(),
        );
        // The estimate of δ is as good as the noise allows (bias would show as ≫ 1).
        assert!(
            efficiency <= 1.2,
            "δ errors exceed the Cramér-Rao bound: mean (Δδ/σ)² {efficiency:.3} > 1.2"
        );
        // Wrong matches that pass the SSD test are rare (the core's gate is the second line).
        println!("wrong matches accepted: {}", accepted - correct);
        assert!((accepted - correct) as f64 <= 0.005 * tried as f64);
        let (shortfalls, violations) = (self.shortfalls, &self.violations);
        println!(
            "known shortfalls hit: {shortfalls} of {}",
            KNOWN_SHORTFALLS.len()
        );
        assert!(violations.is_empty(), "{violations:#?}");
        // A listed shortfall that no longer happens is a stale entry: take it off the list.
        assert_eq!(
            shortfalls,
            KNOWN_SHORTFALLS.len(),
            "stale KNOWN_SHORTFALLS entry"
        );
    }
}

/// Brick (periodic: bricks ~32 px wide, courses ~16 px high) and gravel (stones ~15 px, no
/// structure at the coarse levels) with the 20 px shifts of `cases`, started at d = 0, i.e.
/// with no prediction. A local method has no basis to pick the right one of several
/// similar-looking positions there; what matters is that it says so: most registrations fail
/// with a typed reason (diverged, SSD too high) and wrong positions are almost never accepted.
/// The main test covers the same shifts started from the predicted displacement (~3 px off).
#[test]
fn periodic_and_structureless_textures_need_the_prediction() {
    let Some(root) = data_root() else { return };
    let cfg = KltConfig::default();
    let (mut tried, mut correct, mut wrong, mut failed) = (0, 0, 0, 0);
    for (i, path) in source_images(&root).iter().enumerate() {
        if !(path.ends_with("brick.png") || path.ends_with("gravel.png")) {
            continue;
        }
        let s = smoothed(path);
        let tmpl = Pyramid::build_smoothed(s.clone(), cfg.levels, cfg.smoothing);
        let feats = features(&s, 40, 25);
        for (k, (d, lambda, delta)) in cases(1000 + i as u64).into_iter().enumerate() {
            if (d[0].hypot(d[1]) - 20.0).abs() > 1e-9 {
                continue;
            }
            let j = live(&s, d, lambda, delta, 2.0, (i * 100 + k) as u64 + 7);
            let (st, results) = run_case(&tmpl, None, &j, &feats, d, lambda, delta, &cfg);
            let mut reasons = std::collections::BTreeMap::new();
            for r in &results {
                match r {
                    Ok(r) => {
                        let e = [r.displacement[0] - d[0], r.displacement[1] - d[1]];
                        if e[0].hypot(e[1]) >= 0.5 {
                            println!(
                                "    ACCEPTED WRONG: error ({:+.2}, {:+.2}) px, normalised SSD \
                                 {:.3}, λ {:.3}",
                                e[0], e[1], r.normalised_ssd, r.lambda
                            );
                        }
                    }
                    Err(e) => {
                        let key = match e {
                            KltFailure::SsdTooHigh { .. } => "SSD too high".to_string(),
                            other => format!("{other}"),
                        };
                        *reasons.entry(key).or_insert(0) += 1;
                    }
                }
            }
            println!(
                "{} d=({:+.2},{:+.2}) λ={lambda} δ={delta:+} from d = 0: {}/{} correct, {} wrong \
                 accepted, failures {reasons:?}",
                path.file_name().unwrap().to_string_lossy(),
                d[0],
                d[1],
                st.correct,
                st.tried,
                st.accepted - st.correct
            );
            tried += st.tried;
            correct += st.correct;
            wrong += st.accepted - st.correct;
            failed += st.tried - st.accepted;
        }
    }
    println!(
        "from d = 0 at 20 px: {correct}/{tried} correct, {failed} typed failures, {wrong} wrong accepted"
    );
    // Measured: 56/100 correct, 43 typed failures, 1 wrong accepted (gravel, 17 px off with
    // normalised SSD 0.22 and λ 0.49 instead of 0.4: a finding, not hidden).
    assert!(tried > 0);
    assert!(
        wrong as f64 <= 0.02 * tried as f64,
        "{wrong} wrong matches accepted"
    );
    assert_eq!(correct + failed + wrong, tried);
}

/// A rendering whose model covers only vertical stripes 64 px wide (background = black, mask
/// off): features within 2 px of a stripe edge have about half their window on background.
/// The prediction is off by 5 px (the coarse levels, mostly background here, help little).
#[test]
fn converges_with_half_the_window_masked() {
    let Some(root) = data_root() else { return };
    let cfg = KltConfig::default();
    let (d, lambda, delta) = ([4.3, -2.6], 0.6, 30.0);
    let (mut with_mask, mut without_mask) = (Vec::new(), Vec::new());
    let mut errors = Vec::new();
    for name in [
        "textures/skimage/camera.png",
        "textures/opencv_samples/graf1.png",
        "euroc-v101-micro/mav0/cam0/data/1403715273262142976.png",
    ] {
        let s = smoothed(&root.join(name));
        let (w, h) = (s.width(), s.height());
        let on_model = |x: usize| (x / 64).is_multiple_of(2);
        let mut rendered = s.clone();
        let mut mask = Mask::full(w, h).unwrap();
        for y in 0..h {
            for x in 0..w {
                if !on_model(x) {
                    rendered.data_mut()[y * w + x] = 0.0;
                    mask.set(x, y, false);
                }
            }
        }
        // Corners of the real texture next to a stripe edge, on the model side, where half
        // the window is valid once the mask has shrunk by the template blur's reach (2σ).
        let reach = (2.0 * cfg.template_sigma(0.0)).ceil() as usize;
        let cfg_grid = GridConfig {
            cell_size: 8,
            fast_threshold: 15,
            per_cell: 4,
            min_mask_fraction: 0.0,
            border: 40,
        };
        let feats: Vec<[f64; 2]> = grid::extract(&s.to_gray8(), None, &[], &cfg_grid)
            .unwrap()
            .into_iter()
            .filter(|c| {
                let x = c.x as usize;
                let (from_left, from_right) = (x % 64, 63 - x % 64);
                on_model(x) && (from_left.abs_diff(reach) <= 1 || from_right.abs_diff(reach) <= 1)
            })
            .map(|c| [c.x as f64, c.y as f64])
            .collect();
        assert!(feats.len() >= 10, "{name}: {} edge features", feats.len());
        let j = live(&s, d, lambda, delta, 2.0, 99);
        // The product's path: no extra blur here (S is already smooth), mask from "depth".
        let tmpl =
            TemplatePyramid::build(rendered.clone(), mask, cfg.levels, cfg.template_sigma(0.0))
                .unwrap();
        let (st_m, res) = run_case(
            &tmpl.image,
            Some(&tmpl.mask),
            &j,
            &feats,
            d,
            lambda,
            delta,
            &cfg,
        );
        let (st_u, _) = run_case(&tmpl.image, None, &j, &feats, d, lambda, delta, &cfg);
        let masked_fraction = res
            .iter()
            .flatten()
            .map(|r| 1.0 - r.valid_pixels as f64 / 225.0)
            .sum::<f64>()
            / st_m.accepted.max(1) as f64;
        println!(
            "{name}: {} edge features, {:.0} % of the level-0 window masked on average\n  \
             with mask: {st_m:?}\n  without:   {st_u:?}",
            feats.len(),
            100.0 * masked_fraction
        );
        for r in res.iter().flatten() {
            errors.push((r.displacement[0] - d[0]).hypot(r.displacement[1] - d[1]));
        }
        let mut reasons = std::collections::BTreeMap::new();
        for e in res.iter().filter_map(|r| r.as_ref().err()) {
            let key = format!("{e}");
            let key = key.split(':').next().unwrap_or_default().to_string();
            *reasons.entry(key).or_insert(0) += 1;
        }
        println!("  failures with mask: {reasons:?}");
        with_mask.push(st_m);
        without_mask.push(st_u);
    }
    let tried: usize = with_mask.iter().map(|s| s.tried).sum();
    let ok_m: usize = with_mask.iter().map(|s| s.correct).sum();
    let ok_u: usize = without_mask.iter().map(|s| s.correct).sum();
    let med = median(&mut errors);
    println!(
        "masked: {ok_m}/{tried} correct, median error {med:.4} px; unmasked: {ok_u}/{tried} correct"
    );
    assert!(ok_m as f64 >= 0.8 * tried as f64);
    let wrong: usize = with_mask.iter().map(|s| s.accepted - s.correct).sum();
    assert!(
        wrong as f64 <= 0.05 * tried as f64,
        "{wrong} wrong matches accepted"
    );
    assert!(med < 0.05);
    // Without the mask the black background disturbs the registration.
    assert!(ok_u < ok_m);
}

/// Strong illumination changes: the photometric KLT registers, the plain 2-parameter KLT
/// (same windows, levels, iterations and acceptance threshold) does not; under unchanged
/// illumination both do.
#[test]
fn plain_klt_fails_on_strong_illumination_where_photometric_succeeds() {
    let Some(root) = data_root() else { return };
    let photometric = KltConfig::default();
    let plain = KltConfig {
        model: KltModel::Translation,
        ..photometric
    };
    let d = [11.6, -6.2];
    for name in [
        "textures/skimage/camera.png",
        "textures/opencv_samples/graf1.png",
        "euroc-v101-micro/mav0/cam0/data/1403715273262142976.png",
    ] {
        let s = smoothed(&root.join(name));
        let tmpl = Pyramid::build_smoothed(s.clone(), photometric.levels, photometric.smoothing);
        let feats = features(&s, 40, 25);
        for (lambda, delta, strong) in [
            (1.0, 0.0, false),
            (0.4, 60.0, true),
            (2.5, -60.0, true),
            (0.5, -50.0, true),
        ] {
            let j = live(&s, d, lambda, delta, 2.0, 3);
            let (ph, _) = run_case(&tmpl, None, &j, &feats, d, lambda, delta, &photometric);
            let (pl, pl_res) = run_case(&tmpl, None, &j, &feats, d, lambda, delta, &plain);
            let reasons: Vec<String> = pl_res
                .iter()
                .filter_map(|r| r.as_ref().err().map(|e| format!("{e}")))
                .take(3)
                .collect();
            println!(
                "{name} λ={lambda} δ={delta:+}: photometric {}/{} correct (median {:.4} px), \
                 plain {}/{} correct, e.g. {reasons:?}",
                ph.correct, ph.tried, ph.median_shift_err, pl.correct, pl.tried
            );
            assert!(ph.correct as f64 >= 0.8 * ph.tried as f64);
            assert!(ph.median_shift_err < 0.05);
            if strong {
                assert!(pl.correct as f64 <= 0.1 * pl.tried as f64, "{pl:?}");
            } else {
                // The comparison is fair: with unchanged lighting the plain KLT works.
                assert!(pl.correct as f64 >= 0.8 * pl.tried as f64, "{pl:?}");
            }
        }
    }
}

/// The reported covariance matches the scatter of the estimates over noise draws.
/// The reported covariance is calibrated: over noise draws, the normalised squared error
/// `eᵀ Σ⁻¹ e` of the position (about the noise-free estimate, which removes the tiny
/// interpolation bias) averages 2, the number of position parameters, at integer, quarter and
/// half pixel shifts (where bilinear sampling correlates the live image's noise and shrinks
/// the residuals by up to 4×, see `KltResult::covariance`), on three images.
#[test]
fn covariance_matches_empirical_scatter() {
    let Some(root) = data_root() else { return };
    let cfg = KltConfig::default();
    let trials = 50u64;
    let (mut all_nees, mut n_all) = (0.0, 0.0);
    let mut groups = Vec::new();
    for (img, name) in [
        "textures/skimage/camera.png",
        "textures/opencv_samples/graf1.png",
        "euroc-v101-micro/mav0/cam0/data/1403715273262142976.png",
    ]
    .into_iter()
    .enumerate()
    {
        let full = smoothed(&root.join(name));
        // A 160×160 crop around the strongest corner keeps the noise draws quick.
        let c = features(&full, 100, 1)[0];
        let (x0, y0) = (c[0] as usize - 80, c[1] as usize - 80);
        let crop: Vec<f32> = (0..160)
            .flat_map(|y| (0..160).map(move |x| (x, y)))
            .map(|(x, y)| full.get(x0 + x, y0 + y).unwrap())
            .collect();
        let s = GrayF32::new(160, 160, crop).unwrap();
        let tmpl = Pyramid::build_smoothed(s.clone(), cfg.levels, cfg.smoothing);
        for (k, d) in [[3.0, -2.0], [3.25, -2.75], [3.5, -2.5], [3.4, -2.7]]
            .into_iter()
            .enumerate()
        {
            // Independent noise for every image and shift.
            let seed0 = 1000 * (1 + 4 * img + k) as u64;
            let register = |j: GrayF32| {
                klt::register(
                    &tmpl,
                    None,
                    &cfg.target_pyramid(j),
                    [80.0, 80.0],
                    [0.0; 2],
                    &cfg,
                )
                .unwrap()
            };
            let r0 = register(live(&s, d, 1.3, 10.0, 0.0, 1));
            let (mut nees, mut ex, mut ey, mut vx, mut vy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for seed in 0..trials {
                let r = register(live(&s, d, 1.3, 10.0, 3.0, seed0 + 2 * seed));
                let e = nalgebra::Vector2::new(
                    r.displacement[0] - r0.displacement[0],
                    r.displacement[1] - r0.displacement[1],
                );
                nees += (e.transpose() * r.covariance.try_inverse().unwrap() * e)[(0, 0)];
                ex += e.x * e.x;
                ey += e.y * e.y;
                vx += r.covariance[(0, 0)];
                vy += r.covariance[(1, 1)];
            }
            let n = trials as f64;
            println!(
                "{name} d=({:+.2},{:+.2}): mean eᵀΣ⁻¹e {:.2}; empirical σ = ({:.4}, {:.4}) px, \
                 reported σ = ({:.4}, {:.4}) px",
                d[0],
                d[1],
                nees / n,
                (ex / n).sqrt(),
                (ey / n).sqrt(),
                (vx / n).sqrt(),
                (vy / n).sqrt()
            );
            groups.push((name, d, nees / n));
            all_nees += nees;
            n_all += n;
        }
    }
    let mean = all_nees / n_all;
    println!("overall mean eᵀΣ⁻¹e {mean:.3} over {n_all} draws (χ²₂: 2)");
    // χ²₂ has standard deviation 2: a mean over 50 draws has σ ≈ 0.28, over all ≈ 0.08.
    for (name, d, m) in &groups {
        assert!(*m > 1.2 && *m < 3.0, "{name} d={d:?}: mean eᵀΣ⁻¹e {m}");
    }
    assert!(mean > 1.7 && mean < 2.4, "overall mean eᵀΣ⁻¹e {mean}");
}

fn synthetic(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> GrayF32 {
    GrayF32::new(w, h, (0..w * h).map(|i| f(i % w, i / w)).collect()).unwrap()
}

/// Each failure reason, from inputs built to cause it; bad input never panics.
#[test]
fn typed_failure_reasons() {
    let cfg = KltConfig::default();
    let (tp, jp) = shifted_texture_pair();
    let ok = klt::register(&tp, None, &jp, [48.0, 48.0], [0.0; 2], &cfg).unwrap();
    assert!((ok.displacement[0] - 6.0).abs() < 0.05 && (ok.displacement[1] - 6.0).abs() < 0.05);

    out_of_image_and_too_few_pixels_are_named(&tp, &jp, &cfg);
    flat_and_one_directional_textures_are_singular(&cfg);
    divergence_and_high_ssd_are_named(&tp, &jp, &cfg);
    bad_inputs_are_named_and_never_panic(&tp, &jp, &cfg);
}

/// The smooth texture of [`typed_failure_reasons`] at pixel `(x, y)`.
fn blob(x: usize, y: usize) -> f32 {
    let (fx, fy) = (x as f32, y as f32);
    128.0 + 60.0 * (fx * 0.31).sin() * (fy * 0.23).cos() + 40.0 * ((fx + 2.0 * fy) * 0.11).sin()
}

/// Pyramids (3 levels) of a 96×96 [`blob`] texture and of that texture shifted by (6, 6) px.
fn shifted_texture_pair() -> (Pyramid, Pyramid) {
    let tex = synthetic(96, 96, blob);
    let shifted = synthetic(96, 96, |x, y| {
        blob(x.saturating_sub(6), y.saturating_sub(6))
    });
    let tp = Pyramid::build(tex.clone(), 3);
    let jp = Pyramid::build(shifted, 3);
    (tp, jp)
}

/// The failure of a registration that was meant to fail (panics where it succeeded).
#[track_caller]
fn failure(r: Result<klt::KltResult, KltFailure>) -> KltFailure {
    r.err().unwrap()
}

/// Windows outside the image, at its corner, or masked to a single column of pixels.
fn out_of_image_and_too_few_pixels_are_named(tp: &Pyramid, jp: &Pyramid, cfg: &KltConfig) {
    assert_eq!(
        failure(klt::register(tp, None, jp, [-3.0, 40.0], [0.0; 2], cfg)),
        KltFailure::OutOfImage
    );
    assert_eq!(
        failure(klt::register(tp, None, jp, [40.0, 40.0], [80.0, 0.0], cfg)),
        KltFailure::OutOfImage
    );
    // Template at the corner: most of the window outside the image.
    assert!(matches!(
        failure(klt::register(tp, None, jp, [0.0, 0.0], [0.0; 2], cfg)),
        KltFailure::TooFewValidPixels { .. } | KltFailure::OutOfImage
    ));
    let mut m = Mask::full(96, 96).unwrap();
    for y in 0..96 {
        for x in 0..96 {
            if !(x == 48 && y < 60) {
                m.set(x, y, false);
            }
        }
    }
    let mp = pyramid::MaskPyramid::build(m, 3);
    assert!(matches!(
        failure(klt::register(
            tp,
            Some(&mp),
            jp,
            [48.0, 48.0],
            [0.0; 2],
            cfg
        )),
        KltFailure::TooFewValidPixels { .. }
    ));
}

/// A flat image and stripes: the registration's normal equations are singular.
fn flat_and_one_directional_textures_are_singular(cfg: &KltConfig) {
    let flat = Pyramid::build(synthetic(96, 96, |_, _| 100.0), 3);
    assert_eq!(
        failure(klt::register(
            &flat,
            None,
            &flat,
            [48.0, 48.0],
            [0.0; 2],
            cfg
        )),
        KltFailure::Singular
    );
    // Texture in one direction only (an edge): the position along it is unobservable.
    let stripes = Pyramid::build(
        synthetic(96, 96, |x, _| 128.0 + 80.0 * (x as f32 * 0.4).sin()),
        3,
    );
    assert_eq!(
        failure(klt::register(
            &stripes,
            None,
            &stripes,
            [48.0, 48.0],
            [0.0; 2],
            cfg
        )),
        KltFailure::Singular
    );
}

/// A shift beyond `max_displacement`, and a target that holds another texture.
fn divergence_and_high_ssd_are_named(tp: &Pyramid, jp: &Pyramid, cfg: &KltConfig) {
    let tight = KltConfig {
        max_displacement: 1.0,
        ..*cfg
    };
    assert_eq!(
        failure(klt::register(tp, None, jp, [48.0, 48.0], [0.0; 2], &tight)),
        KltFailure::Diverged
    );
    let other = Pyramid::build(
        synthetic(96, 96, |x, y| {
            128.0 + 90.0 * ((x * 7 + y * 13) % 17) as f32 / 17.0
        }),
        3,
    );
    assert!(matches!(
        failure(klt::register(tp, None, &other, [48.0, 48.0], [0.0; 2], cfg)),
        KltFailure::SsdTooHigh { .. } | KltFailure::Diverged
    ));
}

/// A NaN position and a zero window are bad input; a mismatched mask, tiny images and every
/// border position give errors, never panics.
fn bad_inputs_are_named_and_never_panic(tp: &Pyramid, jp: &Pyramid, cfg: &KltConfig) {
    assert!(matches!(
        failure(klt::register(tp, None, jp, [f64::NAN, 1.0], [0.0; 2], cfg)),
        KltFailure::BadInput(_)
    ));
    let zero = KltConfig {
        half_window: 0,
        ..*cfg
    };
    assert!(matches!(
        failure(klt::register(tp, None, jp, [48.0, 48.0], [0.0; 2], &zero)),
        KltFailure::BadInput(_)
    ));
    // Mismatched mask, tiny images, every border position: errors, never panics.
    let small_mask = pyramid::MaskPyramid::build(Mask::full(10, 10).unwrap(), 1);
    assert!(klt::register(tp, Some(&small_mask), jp, [48.0, 48.0], [0.0; 2], cfg).is_err());
    let tiny = Pyramid::build(synthetic(1, 1, |_, _| 5.0), 4);
    assert!(klt::register(&tiny, None, &tiny, [0.0, 0.0], [0.0; 2], cfg).is_err());
    for y in [-1.0, 0.0, 0.5, 7.0, 95.0, 95.5, 96.0] {
        for x in [-1.0, 0.0, 3.3, 95.0, 96.0] {
            let _ = klt::register(tp, None, jp, [x, y], [0.0; 2], cfg);
        }
    }
}

/// OpenCV's KLT cases (`tests/klt_cases`): real frames shifted by (7.3, −4.6) px under six
/// illumination changes, the 8-bit targets clipped to 0..255, every registration from a zero
/// guess. OpenCV's 2-parameter LK (21×21, 3 levels) fails on 35-74 % of the changed targets
/// (its script's table); the photometric model is meant for exactly these. Two configurations:
/// the tracker's (no clip prediction, `KltConfig::default()`), and with the camera's clip
/// levels, where the fast path predicts the clipping (eq. 5.6; the reference does not)
/// wherever `a I₀ + b` leaves the range over the window's support (eq. 5.7): 2.5J − 60 fails
/// on 0.0 % there (issue 16 asks for ≤ 5 %). The README's table is these figures (issue 54,
/// point 27: it showed the second configuration as the tracker's).
#[test]
fn registers_opencvs_cases_under_illumination_changes() {
    let Some(cases) = klt_cases::load() else {
        return;
    };
    // The targets come from an 8-bit camera: its clip levels are 0 and 255.
    let clipping = KltConfig {
        saturation: Some([0.0, 255.0]),
        ..KltConfig::default()
    };
    let tracker = KltConfig::default();
    let mut table = Vec::new();
    println!("variant: the tracker's configuration | with the clip prediction | the reference");
    for (v, (name, _, _)) in klt_cases::VARIANTS.iter().enumerate() {
        let (mut tried, mut failed, mut errors) = (0, 0, Vec::new());
        let (mut ref_failed, mut ref_errors) = (0, Vec::new());
        let (mut plain_failed, mut plain_errors) = (0, Vec::new());
        for case in &cases {
            // Keeping the template before its smoothing lets the KLT predict the clipped
            // targets exactly (docs/VISION.md §5, eq. 5.6).
            let tmpl = Pyramid::build_keeping_unsmoothed(
                GrayF32::from_gray8(&case.template).unwrap(),
                clipping.levels,
                clipping.template_sigma(0.0),
            );
            let target = clipping.target_pyramid(GrayF32::from_gray8(&case.targets[v]).unwrap());
            let register = |f: &dyn Fn([f64; 2]) -> Option<[f64; 2]>| -> (usize, Vec<f64>) {
                let found: Vec<Option<[f64; 2]>> = case.points.iter().map(|&p| f(p)).collect();
                klt_cases::score(&case.points, &found)
            };
            let (f, e) = register(&|p| {
                klt::register(&tmpl, None, &target, p, [0.0; 2], &clipping)
                    .ok()
                    .map(|r| r.position)
            });
            tried += case.points.len();
            failed += f;
            errors.extend(e);
            let (f, e) = register(&|p| {
                klt::reference::register(&tmpl, None, &target, p, [0.0; 2], &clipping)
                    .ok()
                    .map(|r| r.position)
            });
            ref_failed += f;
            ref_errors.extend(e);
            // As the tracker registers: its template keeps no unsmoothed image, its live
            // pyramid no clip map.
            let plain_tmpl = Pyramid::build_smoothed(
                GrayF32::from_gray8(&case.template).unwrap(),
                tracker.levels,
                tracker.template_sigma(0.0),
            );
            let plain_target =
                tracker.target_pyramid(GrayF32::from_gray8(&case.targets[v]).unwrap());
            let (f, e) = register(&|p| {
                klt::register(&plain_tmpl, None, &plain_target, p, [0.0; 2], &tracker)
                    .ok()
                    .map(|r| r.position)
            });
            plain_failed += f;
            plain_errors.extend(e);
        }
        let pct = |n: usize| 100.0 * n as f64 / tried as f64;
        let (share, med) = (pct(failed), median(&mut errors));
        let (plain_share, plain_med) = (pct(plain_failed), median(&mut plain_errors));
        println!(
            "{name:>9}: {plain_share:5.1} %, {plain_med:.4} px | {share:5.1} %, {med:.4} px | \
             {:5.1} %, {:.4} px ({tried} registrations)",
            pct(ref_failed),
            median(&mut ref_errors)
        );
        table.push((*name, (plain_share, plain_med), (share, med)));
    }
    for (name, _, (share, med)) in &table {
        let (max_share, max_median) = match *name {
            "none" => (0.5, 0.02),
            "c1.8b-30" => (2.0, 0.03),
            "c2.5b-60" => (5.0, 0.03),
            _ => (1.0, 0.03),
        };
        assert!(
            *share <= max_share,
            "{name}: {share:.1} % failures > {max_share} %"
        );
        assert!(
            *med <= max_median,
            "{name}: median error {med:.4} px > {max_median}"
        );
    }
    // The README's table holds these figures, row by row (its first column in words).
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .unwrap();
    for (name, (ps, pm), (cs, cm)) in &table {
        let row = format!("| {ps:.1} % / {pm:.3} px | {cs:.1} % / {cm:.3} px |");
        assert!(
            readme.lines().any(|l| l.contains(&row)),
            "README: no row `{row}` ({name}): write the table's figures as this run gives them"
        );
    }
}

/// The fast path (`klt::register`) against the reference implementation
/// (`klt::reference::register`): the same model and fixed point, so the same verdicts and
/// positions within the convergence tolerance. They differ in `f32` accumulation and in
/// stopping the coarse levels at 0.1 px instead of `min_update`, so not bit for bit.
#[test]
fn fast_path_agrees_with_the_reference() {
    let Some(root) = data_root() else { return };
    let cfg = KltConfig::default();
    let (mut same_verdict, mut tried, mut diffs) = (0, 0, Vec::new());
    for (i, path) in source_images(&root).iter().enumerate() {
        let s = smoothed(path);
        let tmpl = Pyramid::build_smoothed(s.clone(), cfg.levels, cfg.smoothing);
        let feats = features(&s, 40, 25);
        for (k, (d, lambda, delta)) in cases(1000 + i as u64).into_iter().enumerate().take(4) {
            let target = cfg.target_pyramid(live(&s, d, lambda, delta, 2.0, (i * 100 + k) as u64));
            for &p in &feats {
                let guess = [0.8 * d[0], 0.8 * d[1]];
                let a = klt::register(&tmpl, None, &target, p, guess, &cfg);
                let b = klt::reference::register(&tmpl, None, &target, p, guess, &cfg);
                tried += 1;
                same_verdict += usize::from(a.is_ok() == b.is_ok());
                if let (Ok(a), Ok(b)) = (a, b) {
                    diffs
                        .push((a.position[0] - b.position[0]).hypot(a.position[1] - b.position[1]));
                }
            }
        }
    }
    let agree = same_verdict as f64 / tried as f64;
    diffs.sort_by(|a, b| a.total_cmp(b));
    let p95 = diffs[diffs.len() * 95 / 100];
    println!(
        "{tried} registrations: same verdict {:.1} %, position difference median {:.5} px, \
         95th percentile {p95:.5} px, largest {:.4} px",
        100.0 * agree,
        median(&mut diffs.clone()),
        diffs.last().unwrap()
    );
    assert!(agree >= 0.98, "verdicts agree on {:.1} %", 100.0 * agree);
    assert!(
        p95 <= 0.01,
        "95th percentile position difference {p95:.4} px"
    );
}

/// Each instruction set's copy of the kernels (`isa::dispatch!`: the pyramids, the window's
/// samples and sums, the covariance's convolution) gives the same registrations to the last
/// bit: positions, photometric parameters, covariances, failures.
#[test]
fn every_instruction_set_registers_the_same() {
    let cfg = KltConfig::default();
    let tex = |x: usize, y: usize| {
        let (fx, fy) = (x as f32, y as f32);
        128.0 + 60.0 * (fx * 0.29).sin() * (fy * 0.21).cos() + 40.0 * ((fx + 2.0 * fy) * 0.13).sin()
    };
    let s = synthetic(320, 240, tex);
    let points = features(&s, 20, 60);
    assert!(points.len() >= 15, "{} features", points.len());
    let mut runs = Vec::new();
    isa::each_copy(|_| {
        let tmpl = Pyramid::build_smoothed(s.clone(), cfg.levels, cfg.smoothing);
        let target = cfg.target_pyramid(live(&s, [3.3, -2.6], 0.8, 20.0, 2.0, 11));
        let found: Vec<String> = points
            .iter()
            .map(|&p| {
                format!(
                    "{:?}",
                    klt::register(&tmpl, None, &target, p, [0.0; 2], &cfg)
                )
            })
            .collect();
        runs.push(found);
    });
    let ok = runs[0].iter().filter(|r| r.starts_with("Ok")).count();
    assert!(ok * 2 > points.len(), "{ok} of {} registered", points.len());
    for run in &runs[1..] {
        assert_eq!(run, &runs[0]);
    }
}
