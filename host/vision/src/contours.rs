//! The contour modality's part of a frame (docs/VISION.md §9): which modalities a frame uses,
//! the object's statistics kept from frame to frame, the frame's contour correspondences, and
//! the contour form of its judgement.

use features::GrayF32;
use nalgebra::Matrix6;
use protocol::{ContourPoint, PosePrediction, sym_index};
use serde::Serialize;

use camera::{CameraPose, Pinhole};
use contour::measure::{contour_rms, measure, silhouette_agreement};
use contour::outliers::{MIN_LINES, outliers, residual_scale};
use contour::{ColourModel, ContourConfig, ContourMeasurement, ContourSample, Tally};
use features::OutlierRule;
use model::Model;

/// Which measurements a frame makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Modality {
    /// The model's texture: FAST corners registered by the photometric KLT (2D/3D
    /// correspondences).
    #[default]
    Texture,
    /// The model's silhouette: contour correspondences (docs/VISION.md §9).
    Contour,
    /// Both, in one frame.
    Both,
}

impl Modality {
    /// Whether the frame registers the texture.
    pub fn texture(self) -> bool {
        matches!(self, Modality::Texture | Modality::Both)
    }

    /// Whether the frame measures the contour.
    pub fn contour(self) -> bool {
        matches!(self, Modality::Contour | Modality::Both)
    }

    /// What a model gives: its texture where it has one, its contour where it has none.
    pub fn for_model(model: &Model) -> Self {
        if is_textured(model) {
            Modality::Texture
        } else {
            Modality::Contour
        }
    }
}

/// Whether `model` has a textured material, which the texture modality needs.
pub fn is_textured(model: &Model) -> bool {
    model.materials.iter().any(|m| m.texture.is_some())
}

/// Fewest contours found, and the least share of the lines sampled, for a frame to teach the
/// statistics: a frame whose lines mostly failed may have found wrong contours.
const LEARN_MIN_FOUND: usize = 10;

/// One frame's contour measurements.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContourFrame {
    /// The contour correspondences to send, one per measurement, in order.
    pub wire: Vec<ContourPoint>,
    /// The measurements they came from.
    pub measurements: Vec<ContourMeasurement>,
    /// What the lines gave.
    pub tally: Tally,
    /// Mean distance along the normals between the rendered contour and the one found [px]:
    /// the contour's prediction error.
    pub error_px: Option<f64>,
}

/// Beside the texture, each line's σ is at least the scatter of the kept lines about the pose
/// the registrations fit (docs/VISION.md §9.5): where the silhouette and the texture disagree
/// by more than the lines state (a model whose outline is not quite the object's, a shadow
/// along an edge), the contour does not pull the pose off the texture by more than that
/// disagreement says it knows.
fn widen_to_agreement(
    measurements: &mut [ContourMeasurement],
    pose: &CameraPose,
    pinhole: &Pinhole,
) {
    let residuals: Vec<f64> = measurements
        .iter()
        .filter_map(|m| m.residual_px(pose, pinhole))
        .collect();
    if residuals.len() < MIN_LINES {
        return;
    }
    let scale = residual_scale(&residuals);
    for m in measurements.iter_mut() {
        m.line.sigma_px = m.line.sigma_px.max(scale);
    }
}

/// The contour modality between frames: its parameters and the object's statistics.
#[derive(Debug, Clone)]
pub struct ContourState {
    config: ContourConfig,
    colour: ColourModel,
}

impl ContourState {
    /// Nothing learnt yet.
    pub fn new(config: ContourConfig) -> Self {
        Self {
            config,
            colour: ColourModel::new(),
        }
    }

    /// The object's statistics.
    pub fn colour(&self) -> &ColourModel {
        &self.colour
    }

    /// Measures the contour of `rendering` (the model at `prediction`) in `live`, drops
    /// the lines no rigid pose explains with the others (eq. K7, by `rule`), or, beside the
    /// texture, those the pose its registrations fit (`texture_pose`) does not, and learns the
    /// statistics: from the rendering itself the first time (the start pose is taken as
    /// right), then along the contours found.
    pub fn measure(
        &mut self,
        rendering: &render::Frame,
        live: &GrayF32,
        pinhole: &Pinhole,
        prediction: &PosePrediction,
        rule: Option<&OutlierRule>,
        texture_pose: Option<&CameraPose>,
    ) -> ContourFrame {
        let cfg = &self.config;
        if !self.colour.learnt() {
            let samples = contour::silhouette::sample(rendering, &cfg.sample);
            self.colour
                .learn(live, Some(&rendering.mask), &samples, cfg.band_px, 1.0);
        }
        // The lines reach as far as the prediction's covariance says (eq. K8).
        let cov = Matrix6::from_fn(|r, c| f64::from(prediction.cov[sym_index(6, r, c)]));
        let cov = cov.iter().all(|v| v.is_finite()).then_some(cov);
        let mut c = measure(rendering, live, &self.colour, cfg, cov.as_ref());
        if let Some(rule) = rule {
            let flags = match texture_pose {
                // Beside the texture, a contour must agree with the pose the frame's
                // registrations fit: within three of its σ (at least the rule's floor).
                Some(pose) => c
                    .measurements
                    .iter()
                    .map(|m| {
                        m.residual_px(pose, pinhole)
                            .is_none_or(|r| r.abs() > (3.0 * m.line.sigma_px).max(rule.floor_px))
                    })
                    .collect(),
                None => outliers(pinhole, &rendering.view.pose, &c.measurements, rule),
            };
            let mut flags = flags.into_iter();
            c.measurements.retain(|_| !flags.next().unwrap_or(false));
            c.tally.outliers = c.tally.found - c.measurements.len();
            if let Some(pose) = texture_pose {
                widen_to_agreement(&mut c.measurements, pose, pinhole);
            }
        }
        if c.measurements.len() >= LEARN_MIN_FOUND && 2 * c.tally.found >= c.tally.sampled {
            let found: Vec<ContourSample> = c
                .measurements
                .iter()
                .map(|m| ContourSample {
                    pixel: m.found_pixel(),
                    ..m.sample
                })
                .collect();
            self.colour
                .learn(live, None, &found, cfg.band_px, cfg.learn_rate);
        }
        let n = c.measurements.len();
        let error_px = (n > 0).then(|| {
            c.measurements
                .iter()
                .map(|m| m.line.offset_px.abs())
                .sum::<f64>()
                / n as f64
        });
        ContourFrame {
            wire: c.measurements.iter().map(|m| m.to_wire(pinhole)).collect(),
            measurements: c.measurements,
            tally: c.tally,
            error_px,
        }
    }

    /// The contour form of a frame's judgement at `pose`: the applied measurements' count, rms
    /// along the normals [px], how well they pin the pose (eq. K10) and how far it is from
    /// the pose they fit alone (eq. K11), and the silhouette
    /// agreement (eq. K5') of `rendering` (the model at `pose`) with `live`.
    pub fn judge(
        &self,
        measurements: &[ContourMeasurement],
        applied: &[bool],
        pose: &CameraPose,
        pinhole: &Pinhole,
        rendering: &render::Frame,
        live: &GrayF32,
    ) -> ContourJudgement {
        let (contours, rms_px) = contour_rms(measurements, applied, pose, pinhole);
        let used: Vec<ContourMeasurement> = measurements
            .iter()
            .zip(applied)
            .filter(|(_, a)| **a)
            .map(|(m, _)| *m)
            .collect();
        ContourJudgement {
            contours,
            rms_px,
            spread: contour::outliers::pose_spread(pinhole, pose, &used),
            excess: contour::outliers::fit_excess(pinhole, pose, &used),
            silhouette: silhouette_agreement(rendering, live, &self.colour, &self.config),
        }
    }
}

/// The contour form of a frame's judgement ([`ContourState::judge`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContourJudgement {
    /// Applied contour correspondences in front of the camera.
    pub contours: usize,
    /// Their rms along the normals [px].
    pub rms_px: Option<f64>,
    /// The largest standard deviations of position [m] and orientation [rad] they leave
    /// (eq. K10).
    pub spread: Option<[f64; 2]>,
    /// How much worse the pose explains them than the pose they fit alone (eq. K11).
    pub excess: Option<f64>,
    /// The silhouette agreement (eq. K5').
    pub silhouette: Option<f64>,
}
