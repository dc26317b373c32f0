//! One analysed frame as the outputs record it: a row of `frames.csv`, and what the summary and
//! the plots are computed from.

use serde::Serialize;

/// One analysed frame.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FrameRow {
    /// The image's row in `mav0/cam0/data.csv` (from 0; the frames taken and not analysed are
    /// `frames.csv`'s rows with another `outcome`, [`tracker::record::Fate`]).
    pub index: usize,
    /// Time since the first IMU sample [s].
    pub t: f64,
    /// Frame id the core gave the trigger (from 0, counting the triggers it predicted).
    pub frame_id: u32,
    /// Fraction of the image covered by the model rendered at the prediction.
    pub model_coverage: f64,
    /// Map features predicted visible.
    pub visible: usize,
    /// Features added.
    pub added: usize,
    /// Features registered (tried).
    pub tried: usize,
    /// Registered.
    pub registered: usize,
    /// Correspondences sent.
    pub sent: usize,
    /// Accepted by the core.
    pub accepted: usize,
    /// Gated out (or otherwise rejected) by the core.
    pub gated: usize,
    /// Contour correspondences sent, beside `sent`'s 2D/3D ones (docs/VISION.md §9); `accepted`
    /// and `gated` count both kinds.
    pub contours: usize,
    /// Mean distance along the normals between the predicted contour and the one found [px].
    pub contour_error_px: Option<f64>,
    /// Mean prediction error [px] (predicted → registered).
    pub prediction_error_px: Option<f64>,
    /// Camera position error of the prediction [m], with ground truth.
    pub position_error_m: Option<f64>,
    /// Camera position error [m] against ground truth of the pose the frame's verdict is on,
    /// the core's pose at the frame's time: vision-only, the one estimated with the frame;
    /// with an IMU, its prediction (the frame's own update is applied later).
    pub estimate_error_m: Option<f64>,
    /// The angle [°] of that pose's rotation error.
    pub estimate_error_deg: Option<f64>,
    /// The largest standard deviation of that pose's camera centre [m], by the core's
    /// covariance.
    pub sigma_pos_m: Option<f64>,
    /// The same of its orientation [°].
    pub sigma_rot_deg: Option<f64>,
    /// The direction the covariance pins down least (docs/VISION.md eq. T7).
    pub weakest: Option<&'static str>,
    /// Its standard deviation in units of the bound a right pose is held to.
    pub weakest_sigma: Option<f64>,
    /// The normalised estimation error squared of that pose against the ground truth
    /// (eq. T6): χ²₆ where the covariance is calibrated.
    pub nees: Option<f64>,
    /// The covariance of `[c_w, θ]`, its upper triangle row by row [m², m·rad, rad²].
    #[serde(skip)]
    pub cov: Option<[f64; 21]>,
    /// Rendering [ms].
    pub render_ms: f64,
    /// Pyramids [ms].
    pub pyramids_ms: f64,
    /// Registration [ms].
    pub klt_ms: f64,
    /// Whole frame [ms].
    pub total_ms: f64,
    /// Reprojection rms [px] of the registered features at the pose estimated with this
    /// frame (vision-only runs; [`super::assess`]).
    pub rms_px: Option<f64>,
    /// Eq. T8's χ² of the registrations at the pose judged, over its 0.999 quantile (at most 1
    /// to pass).
    pub consistency: Option<f64>,
    /// Rendered-vs-live correlation over the model's mask at that pose (vision-only runs).
    pub ncc: Option<f64>,
    /// The applied contour correspondences' rms along the normals at that pose [px].
    pub contour_rms_px: Option<f64>,
    /// The silhouette's agreement with the object's statistics at that pose (eq. K5).
    pub silhouette: Option<f64>,
    /// How well the applied contour correspondences alone pin the position at that pose: its
    /// largest standard deviation [m] (eq. K10).
    pub contour_sigma_m: Option<f64>,
    /// The same for the orientation [°].
    pub contour_sigma_deg: Option<f64>,
    /// How much worse that pose explains them than the pose they fit alone, in χ² units
    /// (eq. K11).
    pub contour_excess: Option<f64>,
    /// Whether the frame counts as tracked ([`super::TrackedRule`]; vision-only runs).
    pub tracked: Option<bool>,
    /// The frame's age [ms since its capture, or since it was read in a replay] when the
    /// tracker took it ([`tracker::latency`]).
    pub age_ms: Option<f64>,
    /// Its age when its correspondences were sent to the core [ms].
    pub sent_ms: Option<f64>,
    /// Its age when the pose estimated with it came out [ms].
    pub pose_ms: Option<f64>,
    /// Frames of the input between it and the frame analysed before it, never analysed (a
    /// live run's dropped frames).
    pub dropped_before: usize,
}
