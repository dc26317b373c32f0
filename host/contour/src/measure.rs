//! One frame's contour measurements (docs/VISION.md §9.4): the rendering's contour points
//! searched along their normals in the live image, what the lines refused, the contour
//! correspondences sent to the fusion core (eq. K4), and a pose judged by its contour.

use features::GrayF32;
use nalgebra::{Matrix6, Vector2, Vector3};
use rayon::prelude::*;

use camera::{CameraPose, Pinhole};
use features::outliers::pixel_rows;
use protocol::ContourPoint;
use render::Frame;

use crate::line::{LineConfig, LineRejection, LineResult, half_length, search};
use crate::silhouette::{ContourSample, SampleConfig, covers, sample};
use crate::statistics::ColourModel;

/// The contour modality's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContourConfig {
    /// Where contour points are sampled.
    pub sample: SampleConfig,
    /// How each line is searched.
    pub line: LineConfig,
    /// Pixels on each side of the contour the statistics learn from, and the silhouette's
    /// agreement is judged over.
    pub band_px: usize,
    /// Learning rate of the statistics per tracked frame (SRT3D's 0.2).
    pub learn_rate: f32,
}

impl Default for ContourConfig {
    fn default() -> Self {
        Self {
            sample: SampleConfig::default(),
            line: LineConfig::default(),
            band_px: 10,
            learn_rate: 0.2,
        }
    }
}

/// A contour point found in the live image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContourMeasurement {
    /// The rendered contour point.
    pub sample: ContourSample,
    /// Where its line found the live contour.
    pub line: LineResult,
}

impl ContourMeasurement {
    /// The live contour's pixel.
    pub fn found_pixel(&self) -> Vector2<f64> {
        self.sample.pixel + self.sample.normal * self.line.offset_px
    }

    /// Eq. K4: the contour correspondence in the normalised image of the ideal camera
    /// `pinhole`. A line `n_pᵀ(p − p₀) = 0` in pixels is `(K₂ᵀ n_p)ᵀ(u − u₀) = 0` in normalised
    /// coordinates (`K₂` the linear part of `K`), so the normal is `n = K₂ᵀ n_p / k` with
    /// `k = ‖K₂ᵀ n_p‖`, a pixel offset `δ` along `n_p` is `δ / k` along `n`, and
    /// `d = nᵀ K⁻¹ p_found`, `σ_d = σ_δ / k`.
    pub fn to_wire(&self, pinhole: &Pinhole) -> ContourPoint {
        let np = self.sample.normal;
        let kt = Vector2::new(pinhole.fx * np.x, pinhole.skew * np.x + pinhole.fy * np.y);
        let k = kt.norm();
        let n = kt / k;
        let u = pinhole.to_normalised(self.found_pixel());
        let sigma = self.line.sigma_px / k;
        let c = &self.sample.cov_w;
        let m = &self.sample.m_w;
        ContourPoint {
            m_w: [m.x as f32, m.y as f32, m.z as f32],
            cov_w: [
                c[(0, 0)] as f32,
                c[(0, 1)] as f32,
                c[(0, 2)] as f32,
                c[(1, 1)] as f32,
                c[(1, 2)] as f32,
                c[(2, 2)] as f32,
            ],
            n: [n.x as f32, n.y as f32],
            d: n.dot(&u) as f32,
            var_d: (sigma * sigma) as f32,
        }
    }

    /// Signed distance [px] along the normal from the live contour to the model point
    /// projected at `pose` in the ideal camera `pinhole`; `None` behind the camera.
    pub fn residual_px(&self, pose: &CameraPose, pinhole: &Pinhole) -> Option<f64> {
        let p_c: Vector3<f64> = pose.world_to_camera(&self.sample.m_w);
        if p_c.z <= 0.0 {
            return None;
        }
        let proj = pinhole.to_pixel(Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z));
        Some(self.sample.normal.dot(&(proj - self.found_pixel())))
    }
}

/// What one frame's lines gave.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Tally {
    /// Contour points sampled on the rendering.
    pub sampled: usize,
    /// Lines that found the contour.
    pub found: usize,
    /// Lines that left the image.
    pub border: usize,
    /// Lines on which another part of the model lies, or whose object side is too thin.
    pub other_part: usize,
    /// Lines the contour was not within.
    pub not_found: usize,
    /// Lines whose object and background look alike.
    pub ambiguous: usize,
    /// Lines that found a contour no rigid pose explains with the others' (eq. K7), not sent.
    pub outliers: usize,
}

/// One frame's contour measurements.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Contours {
    /// The lines that found the contour, in sampling order.
    pub measurements: Vec<ContourMeasurement>,
    /// What the lines gave.
    pub tally: Tally,
}

/// Eq. K8: the standard deviation [px] of `sample`'s contour position along its normal that
/// the prediction implies, from the covariance `cov` of the camera pose `[c_w, θ]` (θ a
/// world-frame rotation vector, protocol `PosePrediction`) at `pose`, in the ideal pinhole
/// `pin`: `J_c Σ_cc J_cᵀ + J_θ Σ_θθ J_θᵀ + 2 |J_c Σ_cθ J_θᵀ|` with `J = n_pᵀ ∂π/∂p_c ∂p_c/∂[c_w,
/// θ]`, `∂p_c/∂c_w = −R_cw`, `∂p_c/∂θ = R_cw [m_w − c_w]×`. The cross term is taken at its
/// worst sign, so the bound holds whichever way round the rotation error is defined.
pub fn predicted_sigma_px(
    sample: &ContourSample,
    pose: &CameraPose,
    pin: &Pinhole,
    cov: &Matrix6<f64>,
) -> f64 {
    let p = pose.world_to_camera(&sample.m_w);
    if p.z <= 0.0 {
        return f64::INFINITY;
    }
    let n = sample.normal;
    // n_pᵀ ∂(u, v)/∂p_c: the translation part of eq. R1's rows.
    let [ju, jv] = pixel_rows(pin, &p);
    let d_p: Vector3<f64> = (ju * n.x + jv * n.y).fixed_rows::<3>(3).into_owned();
    // In the world frame: Rᵀ d_p.
    let d_w = pose.q_cw.inverse() * d_p;
    let j_c = -d_w;
    // d_pᵀ R [v]× δθ = (Rᵀ d_p)ᵀ (v × δθ) = ((Rᵀ d_p) × v)ᵀ δθ.
    let j_t: Vector3<f64> = d_w.cross(&(sample.m_w - pose.c_w));
    let cc = cov.fixed_view::<3, 3>(0, 0);
    let ct = cov.fixed_view::<3, 3>(0, 3);
    let tt = cov.fixed_view::<3, 3>(3, 3);
    let var = (j_c.transpose() * cc * j_c)[0]
        + (j_t.transpose() * tt * j_t)[0]
        + 2.0 * (j_c.transpose() * ct * j_t)[0].abs();
    var.max(0.0).sqrt()
}

/// Samples the contour of `rendering` (the model at the predicted pose) and searches each line
/// in `live` (the undistorted live image) with the statistics `stats`, each as far as the
/// prediction's covariance `cov` of `[c_w, θ]` says (eq. K8; `None`: the longest lines).
pub fn measure(
    rendering: &Frame,
    live: &GrayF32,
    stats: &ColourModel,
    cfg: &ContourConfig,
    cov: Option<&Matrix6<f64>>,
) -> Contours {
    let samples = sample(rendering, &cfg.sample);
    let view = &rendering.view;
    let results: Vec<Result<LineResult, LineRejection>> = samples
        .par_iter()
        .map(|s| {
            let half = match cov {
                Some(cov) => half_length(
                    &cfg.line,
                    predicted_sigma_px(s, &view.pose, &view.pinhole, cov),
                ),
                None => cfg.line.coarse_half_length_px,
            };
            search(live, &rendering.mask, s, stats, &cfg.line, half)
        })
        .collect();
    let mut out = Contours {
        tally: Tally {
            sampled: samples.len(),
            ..Tally::default()
        },
        ..Contours::default()
    };
    for (s, r) in samples.into_iter().zip(results) {
        let t = &mut out.tally;
        match r {
            Ok(line) => {
                t.found += 1;
                out.measurements
                    .push(ContourMeasurement { sample: s, line });
            }
            Err(LineRejection::Border) => t.border += 1,
            Err(LineRejection::OtherPart) => t.other_part += 1,
            Err(LineRejection::NotFound) => t.not_found += 1,
            Err(LineRejection::Ambiguous) => t.ambiguous += 1,
        }
    }
    out
}

/// The rms [px] along the normals, at `pose`, of the measurements the core applied
/// (`applied`, one flag per measurement in order), and how many there were.
pub fn contour_rms(
    measurements: &[ContourMeasurement],
    applied: &[bool],
    pose: &CameraPose,
    pinhole: &Pinhole,
) -> (usize, Option<f64>) {
    let mut sum = 0.0;
    let mut n = 0usize;
    for (m, _) in measurements.iter().zip(applied).filter(|(_, a)| **a) {
        if let Some(r) = m.residual_px(pose, pinhole) {
            sum += r * r;
            n += 1;
        }
    }
    (n, (n > 0).then(|| (sum / n as f64).sqrt()))
}

/// Least expected agreement above chance (eq. K5') for the statistics to judge a silhouette:
/// below it the object looks like its background, and no pose can be told from another.
const MIN_EXPECTED_CONTRAST: f64 = 0.05;

/// How well the silhouette of `rendering` (the model at an estimated pose) agrees with `live`
/// by the statistics `stats`, relative to what they expect (eq. K5'): over the pixels within
/// `band` of its contour along the normals, the posterior that each is on the side the
/// rendering puts it on (eq. K5), above chance (½), over the same expected where the
/// statistics are right. 1 is a fit as good as the statistics can tell, 0 a silhouette
/// anywhere. `None` without contour points, before anything was learnt, or where the
/// statistics expect less than [`MIN_EXPECTED_CONTRAST`] above chance.
pub fn silhouette_agreement(
    rendering: &Frame,
    live: &GrayF32,
    stats: &ColourModel,
    cfg: &ContourConfig,
) -> Option<f64> {
    if !stats.learnt() {
        return None;
    }
    let samples = sample(rendering, &cfg.sample);
    let in_mask = |p: Vector2<f64>| covers(&rendering.mask, p);
    let (mut sum, mut expected, mut n) = (0.0f64, 0.0f64, 0usize);
    for s in &samples {
        let h = stats.at(&s.m_w);
        let (e_in, e_out) = h.expected_agreement();
        for t in 1..=cfg.band_px {
            let t = t as f64 - 0.5;
            for (p, object) in [
                (s.pixel - s.normal * t, true),
                (s.pixel + s.normal * t, false),
            ] {
                if in_mask(p) != object {
                    continue;
                }
                if let Some(y) = live.sample(p.x, p.y) {
                    let pf = f64::from(h.posterior(y));
                    sum += if object { pf } else { 1.0 - pf };
                    expected += f64::from(if object { e_in } else { e_out });
                    n += 1;
                }
            }
        }
    }
    let contrast = expected - 0.5 * n as f64;
    (n > 0 && contrast >= MIN_EXPECTED_CONTRAST * n as f64)
        .then(|| (sum - 0.5 * n as f64) / contrast)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::silhouette::tests::disc_frame;

    fn live(c: (f64, f64), r: f64) -> GrayF32 {
        let (w, h) = (320usize, 240usize);
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let d = ((x as f64 - c.0).powi(2) + (y as f64 - c.1).powi(2)).sqrt() - r;
                let a = (0.5 - d).clamp(0.0, 1.0) as f32;
                let bg = if (x / 4 + y / 3).is_multiple_of(2) {
                    40.0
                } else {
                    120.0
                };
                a * 230.0 + (1.0 - a) * bg
            })
            .collect();
        GrayF32::new(w, h, data).unwrap()
    }

    /// The rendered disc at (160, 120); the live one 4 px to the right. The contour
    /// correspondences, through the filter's measurement (`nᵀπ(m_w) − d`, eq. 10c), say so:
    /// each one's residual at the rendered pose is the shift's component along its normal.
    #[test]
    fn correspondences_carry_the_shift_along_each_normal() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 50.0);
        let cfg = ContourConfig::default();
        let mut stats = ColourModel::new();
        let at_rest = live((160.0, 120.0), 50.5);
        let samples = sample(&frame, &cfg.sample);
        assert!(stats.learn(&at_rest, Some(&frame.mask), &samples, cfg.band_px, 1.0));
        let moved = live((164.0, 120.0), 50.5);
        let c = measure(&frame, &moved, &stats, &cfg, None);
        assert_eq!(c.tally.sampled, samples.len());
        assert_eq!(c.tally.found, c.measurements.len());
        assert!(c.tally.found * 10 >= c.tally.sampled * 9, "{:?}", c.tally);
        let pinhole = frame.view.pinhole;
        let mut sq = 0.0;
        for m in &c.measurements {
            let w = m.to_wire(&pinhole);
            assert!(
                protocol::HostToCore::Contours(protocol::Contours {
                    frame_id: 0,
                    trigger_us: 0,
                    part: 0,
                    parts: 1,
                    items: [w].into_iter().collect(),
                })
                .validate()
                .is_ok()
            );
            // The filter's residual at the rendered pose (identity, model points at z = 1).
            let proj = Vector2::new(w.m_w[0] as f64, w.m_w[1] as f64);
            let n = Vector2::new(w.n[0] as f64, w.n[1] as f64);
            let h_px = (n.dot(&proj) - w.d as f64) * pinhole.fx;
            let want = -4.0 * m.sample.normal.x;
            sq += (h_px - want).powi(2);
            assert!(w.var_d > 0.0);
        }
        let rms = (sq / c.measurements.len() as f64).sqrt();
        assert!(rms < 0.6, "rms {rms} px");
        // The pose the frame was rendered at is 4 px off: its rms along the normals says so.
        let applied = vec![true; c.measurements.len()];
        let (n, rms) = contour_rms(&c.measurements, &applied, &frame.view.pose, &pinhole);
        assert_eq!(n, c.measurements.len());
        let rms = rms.unwrap();
        assert!(rms > 2.0 && rms < 3.5, "{rms}");
    }

    /// A camera 1 m from the disc, uncertain by 1 cm along x: the contour point on the right
    /// (normal +x) moves by fx · 0.01 = 5 px per σ, the top one (normal −y) not at all; the
    /// same for a rotation of 0.01 rad about the vertical (world y, the camera's y here).
    #[test]
    fn the_predicted_sigma_along_a_normal_follows_the_pose_covariance() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 50.0);
        let samples = sample(&frame, &ContourConfig::default().sample);
        let right = samples.iter().find(|s| s.normal.x > 0.99).unwrap();
        let top = samples.iter().find(|s| s.normal.y < -0.99).unwrap();
        let (pose, pin) = (&frame.view.pose, &frame.view.pinhole);
        let mut cov = Matrix6::zeros();
        cov[(0, 0)] = 1e-4;
        assert!((predicted_sigma_px(right, pose, pin, &cov) - 5.0).abs() < 0.05);
        assert!(predicted_sigma_px(top, pose, pin, &cov) < 0.05);
        let mut cov = Matrix6::zeros();
        cov[(4, 4)] = 1e-4;
        assert!((predicted_sigma_px(right, pose, pin, &cov) - 5.0).abs() < 0.3);
        assert!(predicted_sigma_px(top, pose, pin, &cov) < 0.3);
        assert_eq!(predicted_sigma_px(right, pose, pin, &Matrix6::zeros()), 0.0);
    }

    #[test]
    fn the_silhouette_agrees_where_it_fits_and_not_elsewhere() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 50.0);
        let cfg = ContourConfig::default();
        let mut stats = ColourModel::new();
        assert_eq!(
            silhouette_agreement(&frame, &live((160.0, 120.0), 50.5), &stats, &cfg),
            None
        );
        let samples = sample(&frame, &cfg.sample);
        stats.learn(
            &live((160.0, 120.0), 50.5),
            Some(&frame.mask),
            &samples,
            cfg.band_px,
            1.0,
        );
        let fit = silhouette_agreement(&frame, &live((160.0, 120.0), 50.5), &stats, &cfg).unwrap();
        let off = silhouette_agreement(&frame, &live((200.0, 150.0), 50.5), &stats, &cfg).unwrap();
        // Relative to what the statistics expect (eq. K5'): 1 where it fits, below the tracked
        // rule's ½ where it does not.
        assert!(fit > 0.95, "{fit}");
        assert!(off < 0.5, "{off}");
        // An object that looks like its background: the statistics cannot judge.
        let flat = GrayF32::new(320, 240, vec![128.0; 320 * 240]).unwrap();
        let mut alike = ColourModel::new();
        alike.learn(&flat, Some(&frame.mask), &samples, cfg.band_px, 1.0);
        assert_eq!(silhouette_agreement(&frame, &flat, &alike, &cfg), None);
    }
}
