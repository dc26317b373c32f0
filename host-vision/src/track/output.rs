//! What a tracking run writes: TUM trajectories (readable by `evo`), a per-frame CSV, a JSON
//! summary, overlay images and plots; and the accuracy figures against ground truth.

use std::collections::BTreeMap;
use std::fmt;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use protocol::{Mode, StatusReason};
use serde::Serialize;

use firmware_sim::board::BoardReport;

// Defined below the plots, which draw it; still reachable here, where it was.
pub use super::frame_row::FrameRow;
use tracker::latency::Percentiles;
use tracker::record::{Fate, Outage};

use super::{
    CoreLog, HostRecord, Record, TrackError, TrackOptions, camera_of_state, overlay, plot,
    state_pose,
};
use crate::locate::database::Provenance;
use frames::euroc::{Dataset, HandEye};

/// What a run writes into its output folder: files, and the files it writes into its folders
/// (`dir/prefix*suffix`; other files there are the user's, and stay).
pub const OUTPUTS: [&str; 8] = [
    "trajectory.tum",
    "trajectory_frames.tum",
    "groundtruth.tum",
    "frames.csv",
    "summary.json",
    "core_imu.csv",
    "overlays/frame_*.png",
    "plots/*_error.svg",
];

/// `n` with its noun: "1 attempt", "3 attempts".
pub fn counted(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// Seconds of a core time stamp [µs] (counted from the first IMU sample). Divided, not
/// multiplied by 1e-6, so that 340 000 µs is 0.34 s and not 0.33999999999999997.
pub fn seconds(t_us: u64) -> f64 {
    t_us as f64 / 1e6
}

/// How many frames a vision-only run tracked ([`super::TrackedRule`]).
#[derive(Debug, Clone, Serialize)]
pub struct TrackedShare {
    /// Frames judged.
    pub frames: usize,
    /// Of them tracked.
    pub tracked: usize,
    /// `tracked / frames`.
    pub share: f64,
    /// The rule.
    pub rule: super::TrackedRule,
    /// Stretches of consecutive judged frames not tracked, `[first, last]` frame times [s]:
    /// occlusions, fast motion, or a wrong pose.
    pub untracked: Vec<[f64; 2]>,
}

/// `[first, last]` times of the runs of consecutive judged rows not tracked.
fn untracked_stretches(rows: &[FrameRow]) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = Vec::new();
    let mut open = false;
    for r in rows {
        match r.tracked {
            Some(false) if open => {
                if let Some(last) = out.last_mut() {
                    last[1] = r.t;
                }
            }
            Some(false) => {
                out.push([r.t, r.t]);
                open = true;
            }
            Some(true) => open = false,
            None => {}
        }
    }
    out
}

/// The cold start of a run: attempts until a pose was verified.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ColdStart {
    /// Attempts made (one per frame until one was accepted).
    pub attempts: usize,
    /// The frame the model was found in, and its time [s], if it was.
    pub found: Option<(usize, f64)>,
    /// Mean time of an attempt on the vision thread [ms].
    pub mean_ms: f64,
    /// Longest attempt [ms].
    pub max_ms: f64,
    /// Frame periods a mean attempt takes (the frames that pass while one attempt runs).
    pub frames_per_attempt: f64,
}

impl ColdStart {
    fn of(searches: &[super::Search], frame_period_s: f64) -> Option<Self> {
        if searches.is_empty() {
            return None;
        }
        let ms: Vec<f64> = searches.iter().map(|s| s.ms).collect();
        let mean_ms = ms.iter().sum::<f64>() / ms.len() as f64;
        Some(Self {
            frames_per_attempt: mean_ms * 1e-3 / frame_period_s,
            attempts: searches.len(),
            found: searches
                .iter()
                .find(|s| s.attempt.accepted())
                .map(|s| (s.index, s.t)),
            mean_ms,
            max_ms: ms.iter().copied().fold(0.0, f64::max),
        })
    }
}

/// What the link's far end reports at the end of a run.
pub(super) struct LinkEnd<'a> {
    /// The simulated board's report.
    pub board: Option<&'a BoardReport>,
    /// The bit errors injected on its line.
    pub noise: Option<&'a core_link::LineNoise>,
}

/// A run over a line with injected bit errors: what was damaged and what each end dropped.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LineSummary {
    /// Probability of a bit flip per byte, in both directions.
    pub byte_error_rate: f64,
    /// Frames the host sent that the line damaged.
    pub damaged_to_core: u64,
    /// Frames the core refused as undecodable (its decode errors).
    pub refused_by_core: Option<u64>,
    /// Messages the core decoded but found invalid (a damaged frame that passed its CRC
    /// would show here).
    pub invalid_at_core: Option<u64>,
    /// Frames the core sent that the line damaged.
    pub damaged_to_host: u64,
    /// Frames the host refused as undecodable.
    pub refused_by_host: u64,
    /// `Hello`s sent again (they, or their answers, were lost).
    pub resent_hellos: usize,
}

/// The median interval between the analysed frames [s] (1/30 s with fewer than two).
fn frame_period(rows: &[FrameRow]) -> f64 {
    let mut dt: Vec<f64> = rows.windows(2).map(|w| w[1].t - w[0].t).collect();
    dt.retain(|d| d.is_finite() && *d > 0.0);
    dt.sort_by(f64::total_cmp);
    dt.get(dt.len() / 2).copied().unwrap_or(1.0 / 30.0)
}

/// The tilt checks of a vision-only run (docs/notes/issue15-cold-start.md §5.2,
/// `tracker::tilt`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct TiltChecks {
    /// Checks run.
    pub checks: usize,
    /// Where one put tracking on the other tilt, with the evidence and whether it held.
    pub flips: Vec<super::tilt::TiltFlip>,
    /// The frames checked whose flip was refused: the last flip had not held.
    pub refused: Vec<usize>,
    /// Frames that passed the tracked rule but are not counted as tracked: on the tilt the
    /// checks disfavour, or flipped and not confirmed.
    pub withheld: usize,
}

impl TiltChecks {
    /// The summary's lines: the checks, each flip with its evidence, the refusals.
    fn print(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "tilt checks  {}, {} put tracking on the other tilt of a face{}",
            self.checks,
            self.flips.len(),
            if self.flips.is_empty() { "" } else { ":" }
        )?;
        let corr = |c: Option<f64>| c.map_or("-".into(), |c| format!("{c:.2}"));
        for t in &self.flips {
            let first = &t.tracked_vs_mirror;
            writeln!(
                f,
                "             frame {} (at {:.2} s): {:.0} mm, {:.1}° away; image correlation \
                 {} tracked vs {} other tilt over {} px, log-odds {}; {}",
                t.frame,
                t.at_s,
                t.jump_m * 1e3,
                t.jump_deg,
                corr(first.contrast.first),
                corr(first.contrast.second),
                first.contrast.pixels,
                first
                    .evidence
                    .map_or("-".into(), |e| format!("{:+.1}", e.log_odds)),
                match t.held {
                    Some(true) => "held",
                    Some(false) => "did not hold (tracking walked back)",
                    None => "not confirmed",
                }
            )?;
        }
        if !self.refused.is_empty() || self.withheld > 0 {
            writeln!(
                f,
                "             {} flips refused after one that did not hold; {} frames not \
                 counted as tracked, on the tilt the checks disfavour or flipped unconfirmed",
                self.refused.len(),
                self.withheld
            )?;
        }
        Ok(())
    }
}

/// A loss and its search.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RecoverySummary {
    /// Frames untracked since [s].
    pub lost_at: f64,
    /// Back at [s]: by a pose found, or by tracking coming back by itself; `None`: still lost
    /// at the end.
    pub ended_at: Option<f64>,
    /// Whether a search found the pose (rather than tracking coming back by itself).
    pub found: bool,
    /// Search attempts made.
    pub attempts: usize,
    /// Mean time of an attempt on the vision thread [ms].
    pub mean_ms: f64,
}

impl RecoverySummary {
    fn of(r: &super::Recovery) -> Self {
        let n = r.searches.len();
        Self {
            lost_at: r.lost_at,
            ended_at: r.ended_at,
            found: r.searches.iter().any(|s| s.attempt.accepted()),
            attempts: n,
            mean_ms: r.searches.iter().map(|s| s.ms).sum::<f64>() / n.max(1) as f64,
        }
    }
}

/// Accuracy against ground truth.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Accuracy {
    /// States compared.
    pub samples: usize,
    /// Mean camera position error [m].
    pub mean_position_m: f64,
    /// RMS camera position error [m].
    pub rms_position_m: f64,
    /// Largest camera position error [m].
    pub max_position_m: f64,
    /// Mean absolute Euler angle errors of the IMU orientation (roll, pitch, yaw) [°].
    pub mean_euler_deg: [f64; 3],
    /// Mean attitude error (angle of the error rotation) [°].
    pub mean_attitude_deg: f64,
    /// Share of the states within 5 cm and 5° of the truth (RBOT's success criterion).
    pub within_5cm_5deg: f64,
}

/// A divergence the core reported.
#[derive(Debug, Clone, Serialize)]
pub struct Event {
    /// Time [s].
    pub t: f64,
    /// Mode entered.
    pub mode: String,
    /// Why.
    pub reason: String,
}

/// A stretch where the host saw that the prediction had lost the model: features predicted in
/// view did not register, or registered far from where they were predicted.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct TrackLoss {
    /// First frame off track [s].
    pub start: f64,
    /// First frame back on track [s], or the last frame if tracking never came back.
    pub end: f64,
    /// Whether tracking came back (by registration or after a re-initialisation).
    pub recovered: bool,
}

/// Features tried below which a frame says nothing about the prediction (model hardly in view).
const LOSS_MIN_TRIED: usize = 10;
/// Mean prediction error [px] above which a frame is off track (the paper's models stay near
/// 1 px; the KLT's pyramid still registers features predicted tens of px off).
const LOSS_PREDICTION_PX: f64 = 10.0;
/// With at least this many features tried, fewer than [`LOSS_MIN_SHARE`] of them registering
/// is off track too. Fewer tried say too little: a model leaving the view during a fast turn
/// loses its border features to motion blur while the prediction is still good.
const LOSS_MIN_TRIED_FOR_SHARE: usize = 20;
/// See [`LOSS_MIN_TRIED_FOR_SHARE`].
const LOSS_MIN_SHARE: f64 = 0.1;
/// Registered features (within [`LOSS_PREDICTION_PX`]) that put a frame back on track.
const LOSS_MIN_REGISTERED: usize = 3;
/// Consecutive frames off track that make a loss (single frames are glitches).
const LOSS_MIN_FRAMES: usize = 2;

/// Where the prediction lost the model, from what the host sees (no ground truth needed).
/// Frames with the model in view ([`LOSS_MIN_TRIED`] features tried) are judged: off track
/// when registered features lie more than [`LOSS_PREDICTION_PX`] from their prediction on
/// average, or when fewer than a tenth of [`LOSS_MIN_TRIED_FOR_SHARE`] or more register; on
/// track with [`LOSS_MIN_REGISTERED`] registered within that error. Other frames change
/// nothing. A drift that the KLT's pyramid recovers from shows here and never as a divergence.
pub fn track_losses(rows: &[FrameRow], from: f64) -> Vec<TrackLoss> {
    let mut out = Vec::new();
    let mut open: Option<(f64, usize)> = None;
    for r in rows.iter().filter(|r| r.t >= from) {
        if r.tried < LOSS_MIN_TRIED {
            continue;
        }
        let far = r.registered > 0
            && r.prediction_error_px
                .is_some_and(|e| e > LOSS_PREDICTION_PX);
        let few = r.tried >= LOSS_MIN_TRIED_FOR_SHARE
            && (r.registered as f64) < LOSS_MIN_SHARE * r.tried as f64;
        let on = r.registered >= LOSS_MIN_REGISTERED
            && r.prediction_error_px
                .is_some_and(|e| e <= LOSS_PREDICTION_PX);
        if far || few {
            open = Some(open.map_or((r.t, 1), |(start, n)| (start, n + 1)));
        } else if on
            && let Some((start, n)) = open.take()
            && n >= LOSS_MIN_FRAMES
        {
            out.push(TrackLoss {
                start,
                end: r.t,
                recovered: true,
            });
        }
    }
    if let (Some((start, n)), Some(last)) = (open, rows.last())
        && n >= LOSS_MIN_FRAMES
    {
        out.push(TrackLoss {
            start,
            end: last.t,
            recovered: false,
        });
    }
    out
}

/// How old the poses were when they came out ([`tracker::latency`]), and the frames dropped.
#[derive(Debug, Clone, Serialize)]
pub struct LatencySummary {
    /// Whether the run was live (a camera, a pipe, or `--pacing real-time`).
    pub live: bool,
    /// What the frames' ages count from: `capture` (a camera device: when the frame came out
    /// of its driver), `arrival` (a pipe: when the frame came out of the decoder; the writer's
    /// own delay before it is not seen), `due` (a recording played at its rate: when its clock
    /// said the frame was due), `read` (a replay: when it was read).
    pub clock: &'static str,
    /// Frames taken by the tracker.
    pub frames_taken: usize,
    /// Frames of the input never taken (a live run's frames it had no time for).
    pub dropped_frames: usize,
    /// Capture → taken by the tracker [ms]: the age of the frames analysed.
    pub capture_to_taken: Option<Percentiles>,
    /// Capture → correspondences sent [ms].
    pub capture_to_sent: Option<Percentiles>,
    /// Capture → pose out [ms].
    pub capture_to_pose: Option<Percentiles>,
    /// IMU sample sent → the core's pose for it [ms] (runs with an IMU).
    pub sample_to_pose: Option<Percentiles>,
}

impl LatencySummary {
    fn of(l: &tracker::latency::Latencies, options: &super::TrackOptions) -> Self {
        let clock = match &options.frames {
            Some(f) if f.is_camera() => "capture",
            Some(f) if f.is_live() => "arrival",
            _ if options.live() => "due",
            _ => "read",
        };
        Self {
            live: options.live(),
            clock,
            frames_taken: l.frames.len(),
            dropped_frames: l.dropped(),
            capture_to_taken: l.age_taken(),
            capture_to_sent: l.capture_to_sent(),
            capture_to_pose: l.capture_to_pose(),
            sample_to_pose: l.sample_to_pose(),
        }
    }
}

impl fmt::Display for LatencySummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let from = self.clock;
        writeln!(
            f,
            "latency      {} run: {} frames taken, {} dropped",
            if self.live { "live" } else { "replay" },
            self.frames_taken,
            self.dropped_frames
        )?;
        for (what, p) in [
            ("taken", &self.capture_to_taken),
            ("sent", &self.capture_to_sent),
            ("pose out", &self.capture_to_pose),
        ] {
            if let Some(p) = p {
                writeln!(f, "             {from} -> {what}: {p}")?;
            }
        }
        if let Some(p) = &self.sample_to_pose {
            writeln!(f, "             IMU sample -> pose: {p}")?;
        }
        Ok(())
    }
}

/// Summary of a run.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Dataset folder.
    pub dataset: String,
    /// Filter model.
    pub model: String,
    /// Link.
    pub link: String,
    /// Renderer adapter.
    pub adapter: String,
    /// Dataset time stamp [ns] of the first IMU sample (vision-only: of the first frame taken):
    /// every time [s] here and in `frames.csv` counts from it; the TUM files carry the
    /// dataset's own stamps.
    pub t0_stamp_ns: u64,
    /// When the core's clock started [s]: 0, or, where a cold start found the model in a later
    /// frame than the first, that frame's time.
    pub streamed_from_s: f64,
    /// Where the data streamed to the core ended [s]: the last sample or tick sent.
    pub duration_s: f64,
    /// Seconds tracked: from snap-on to the last sample sent (0 if never snapped on).
    pub tracked_s: f64,
    /// Frames analysed.
    pub frames: usize,
    /// Every frame taken, counted by what became of it (`frames.csv`'s `outcome`): analysed,
    /// searched (the cold start or a recovery ran on it), no_prediction (the core had no pose
    /// for it yet), unusable (why: `frame_errors`), unsettled (the run ended first).
    pub frame_outcomes: BTreeMap<&'static str, usize>,
    /// Frames that could not be analysed.
    pub frame_errors: Vec<String>,
    /// Correspondences sent.
    pub correspondences_sent: usize,
    /// Accepted by the core.
    pub accepted: usize,
    /// Rejected by the core's gate (or behind the camera, singular).
    pub gated: usize,
    /// Outliers injected by the host.
    pub injected_outliers: usize,
    /// Mean prediction error [px] over frames with registrations (the paper's Table 2).
    pub mean_prediction_error_px: Option<f64>,
    /// Median of the per-frame prediction errors [px].
    pub median_prediction_error_px: Option<f64>,
    /// Mean contour prediction error [px] over frames with contour lines: the distance along
    /// the normals from the contour rendered at the prediction to the one found.
    pub mean_contour_error_px: Option<f64>,
    /// Median of the per-frame contour prediction errors [px].
    pub median_contour_error_px: Option<f64>,
    /// Accuracy of the IMU-rate output from the first accepted update on.
    pub accuracy: Option<Accuracy>,
    /// Time of the first accepted update [s].
    pub snapped_on_at: Option<f64>,
    /// Whether the core had IMU samples (false: the vision-only model, on ticks alone).
    pub imu_used: bool,
    /// Frames judged by the tracked rule, and the rule (docs/VISION.md §10).
    pub tracked: Option<TrackedShare>,
    /// Divergences and re-initialisations.
    pub divergences: Vec<Event>,
    /// Stretches after snap-on without vision (dead reckoning), `[start, end]` [s].
    pub without_vision: Vec<[f64; 2]>,
    /// The cold start (vision-only runs with no start pose): its attempts and where it found
    /// the model.
    pub cold_start: Option<ColdStart>,
    /// The searches' viewpoint database: read from the cache, or built and why.
    pub search_database: Option<String>,
    /// With bit errors injected on the line: what was damaged and dropped.
    pub line: Option<LineSummary>,
    /// Losses of a vision-only run and their searches.
    pub recoveries: Vec<RecoverySummary>,
    /// Tilt checks of tracked poses (vision-only runs), and where one put tracking on the
    /// other tilt of a face.
    pub tilt_checks: TiltChecks,
    /// Outages of the link or the core (protocol/PROTOCOL.md §8), and how each ended.
    pub outages: Vec<Outage>,
    /// With `--attach`: what the host found on the core, and what it did.
    pub attach: Option<String>,
    /// Where the prediction lost the model, as the host saw it (see [`track_losses`]).
    pub track_losses: Vec<TrackLoss>,
    /// Mean time per frame in the host's analysis [ms].
    pub mean_frame_ms: f64,
    /// How old the poses were when they came out, and the frames dropped.
    pub latency: LatencySummary,
    /// Wall-clock time of the run [s].
    pub wall_s: f64,
    /// Core messages refused (errors) and frames from the core that failed to decode.
    pub core_errors: usize,
    /// Frames from the core that failed to decode.
    pub core_rejected_frames: usize,
    /// The run was interrupted or failed before the end of the data.
    pub stopped_early: bool,
    /// Why it failed, if it did.
    pub error: Option<String>,
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.fmt_run(f)?;
        self.fmt_tracking(f)?;
        self.fmt_verdicts(f)?;
        self.fmt_searches(f)?;
        self.fmt_outages(f)?;
        self.fmt_faults(f)?;
        Ok(())
    }
}

/// `v` with its unit, to 3 decimals, or "n/a".
fn opt(v: Option<f64>, unit: &str) -> String {
    match v {
        Some(v) => format!("{v:.3} {unit}"),
        None => "n/a".into(),
    }
}

/// The summary's lines, section by section.
impl Summary {
    /// The run: its input, model, renderer, frames and latencies.
    fn fmt_run(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "dataset      {}", self.dataset)?;
        writeln!(
            f,
            "model        {}{}   link {}",
            self.model,
            if self.imu_used {
                ""
            } else {
                " (vision-only: no IMU used)"
            },
            self.link
        )?;
        writeln!(f, "renderer     {}", self.adapter)?;
        writeln!(
            f,
            "data         {:.2}-{:.2} s streamed, {} frames analysed ({} unusable), wall time {:.1} s, {:.1} ms per frame",
            self.streamed_from_s,
            self.duration_s,
            self.frames,
            self.frame_errors.len(),
            self.wall_s,
            self.mean_frame_ms
        )?;
        let taken: usize = self.frame_outcomes.values().sum();
        if taken > self.frames {
            let ways: Vec<String> = self
                .frame_outcomes
                .iter()
                .map(|(k, n)| format!("{n} {}", k.replace('_', " ")))
                .collect();
            writeln!(
                f,
                "frames       {taken} taken: {} (frames.csv's outcome column)",
                ways.join(", ")
            )?;
        }
        write!(f, "{}", self.latency)?;
        Ok(())
    }

    /// How long it tracked, what vision gave, and the accuracy.
    fn fmt_tracking(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.snapped_on_at {
            Some(t0) => writeln!(
                f,
                "tracked      {:.2} s, from snap-on at {t0:.2} s",
                self.tracked_s
            )?,
            None => writeln!(
                f,
                "tracked      never: the core accepted no correspondence, tracking never started"
            )?,
        }
        writeln!(
            f,
            "vision       {} correspondences sent, {} accepted, {} gated out, {} outliers injected",
            self.correspondences_sent, self.accepted, self.gated, self.injected_outliers
        )?;
        writeln!(
            f,
            "prediction   mean {}, median {}",
            opt(self.mean_prediction_error_px, "px"),
            opt(self.median_prediction_error_px, "px")
        )?;
        if self.mean_contour_error_px.is_some() {
            writeln!(
                f,
                "             contour along its normals: mean {}, median {}",
                opt(self.mean_contour_error_px, "px"),
                opt(self.median_contour_error_px, "px")
            )?;
        }
        match &self.accuracy {
            Some(a) => writeln!(
                f,
                "accuracy     position mean {:.2} mm (rms {:.2}, max {:.2}); Euler errors [{:.2}, {:.2}, {:.2}]°; {:.1} % within 5 cm and 5° (from snap-on)",
                a.mean_position_m * 1e3,
                a.rms_position_m * 1e3,
                a.max_position_m * 1e3,
                a.mean_euler_deg[0],
                a.mean_euler_deg[1],
                a.mean_euler_deg[2],
                a.within_5cm_5deg * 100.0,
            )?,
            None if self.snapped_on_at.is_none() => {
                writeln!(f, "accuracy     n/a (tracking never started)")?
            }
            None => writeln!(f, "accuracy     n/a (the dataset has no ground truth)")?,
        }
        Ok(())
    }

    /// The frames' verdicts and the stretches not tracked.
    fn fmt_verdicts(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(t) = &self.tracked {
            writeln!(
                f,
                "verified     {} of {} frames tracked ({:.1} %): rms <= {} px with >= {} features, their residuals' χ² by their covariances below its quantile at z = {}, and rendered-vs-live correlation >= {}; with fewer features, contour rms <= {} px with >= {} contours, silhouette agreement >= {}, the pose pinned to {:.2} cm and {}° (1 σ) and within the χ²₆ quantile of the lines' own fit, on a track confirmed by {} frames with rms <= {} px and agreement >= {}; vision-only, in either form, the σ of the pose's weakest direction at most {:.0} % of the bound",
                t.tracked,
                t.frames,
                100.0 * t.share,
                t.rule.max_rms_px,
                t.rule.min_features,
                t.rule.consistency_z,
                t.rule.min_ncc,
                t.rule.max_contour_rms_px,
                t.rule.min_contours,
                t.rule.min_silhouette,
                t.rule.max_contour_sigma_m * 100.0,
                t.rule.max_contour_sigma_deg,
                t.rule.confirm_frames,
                t.rule.confirm_contour_rms_px,
                t.rule.confirm_silhouette,
                100.0 * t.rule.max_weak_sigma
            )?;
            if self.imu_used {
                writeln!(
                    f,
                    "             with the IMU: judged at the pose put out at each frame's time (its prediction), the features at the pose they fit, which the prediction must be within {:.2} cm and {}° of",
                    t.rule.max_offset_m * 100.0,
                    t.rule.max_offset_deg
                )?;
            }
            if !t.untracked.is_empty() {
                let mut longest = t.untracked.clone();
                longest.sort_by(|a, b| (b[1] - b[0]).total_cmp(&(a[1] - a[0])));
                let shown: Vec<String> = longest
                    .iter()
                    .take(5)
                    .map(|s| format!("{:.2}-{:.2} s", s[0], s[1]))
                    .collect();
                writeln!(
                    f,
                    "not tracked  {}, the longest: {}",
                    counted(t.untracked.len(), "stretch", "stretches"),
                    shown.join(", ")
                )?;
            }
        }
        Ok(())
    }

    /// The searches: the database, the cold start, the recoveries, the tilt checks.
    fn fmt_searches(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(d) = &self.search_database {
            writeln!(f, "database     {d}")?;
        }
        if let Some(c) = &self.cold_start {
            match c.found {
                Some((frame, t)) => writeln!(
                    f,
                    "cold start   model found in frame {frame} ({t:.2} s) after {}, {:.0} ms per attempt (longest {:.0} ms), {:.1} frame periods each",
                    counted(c.attempts, "attempt", "attempts"),
                    c.mean_ms,
                    c.max_ms,
                    c.frames_per_attempt
                )?,
                None => writeln!(
                    f,
                    "cold start   model not found in {} ({:.0} ms each): nothing tracked",
                    counted(c.attempts, "attempt", "attempts"),
                    c.mean_ms
                )?,
            }
        }
        if !self.recoveries.is_empty() {
            let found = self.recoveries.iter().filter(|r| r.found).count();
            let shown: Vec<String> = self
                .recoveries
                .iter()
                .take(6)
                .map(|r| match (r.ended_at, r.found) {
                    (Some(e), true) => format!(
                        "{:.2} s found at {e:.2} s ({})",
                        r.lost_at,
                        counted(r.attempts, "attempt", "attempts")
                    ),
                    (Some(e), false) => format!(
                        "{:.2} s back by itself at {e:.2} s ({})",
                        r.lost_at,
                        counted(r.attempts, "attempt", "attempts")
                    ),
                    (None, _) => format!(
                        "{:.2} s never back ({})",
                        r.lost_at,
                        counted(r.attempts, "attempt", "attempts")
                    ),
                })
                .collect();
            writeln!(
                f,
                "searched     after {}, {found} found the model: {}{}",
                counted(self.recoveries.len(), "loss", "losses"),
                shown.join(", "),
                if self.recoveries.len() > 6 {
                    ", …"
                } else {
                    ""
                }
            )?;
        }
        if self.tilt_checks.checks > 0 {
            self.tilt_checks.print(f)?;
        }
        Ok(())
    }

    /// The outages and the attach.
    fn fmt_outages(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for o in &self.outages {
            writeln!(
                f,
                "outage       {:.3} s: {:?} ({}); noticed at {:.3} s{}, back at {}, {}, {} samples caught up, tracking again at {}",
                o.injected_s.unwrap_or(o.noticed_s),
                o.kind,
                o.cause,
                o.noticed_s,
                o.notice_wall_ms
                    .map(|ms| format!(" ({ms:.1} ms after the fault)"))
                    .unwrap_or_default(),
                o.resumed_s.map_or("never".into(), |t| format!(
                    "{t:.3} s (a gap of {:.3} s)",
                    t - o.injected_s.unwrap_or(o.noticed_s)
                )),
                counted(o.attempts as usize, "attempt", "attempts"),
                o.backlog,
                opt(o.tracking_s, "s"),
            )?;
        }
        if let Some(a) = &self.attach {
            writeln!(f, "attach       {a}")?;
        }
        Ok(())
    }

    /// Divergences, lost track, stretches without vision, line noise, core errors, an early stop.
    fn fmt_faults(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "divergences  {}", self.divergences.len())?;
        for e in &self.divergences {
            writeln!(f, "  {:8.2} s  {} ({})", e.t, e.mode, e.reason)?;
        }
        if !self.track_losses.is_empty() {
            let shown: Vec<String> = self
                .track_losses
                .iter()
                .map(|l| {
                    format!(
                        "{:.2}-{:.2} s{}",
                        l.start,
                        l.end,
                        if l.recovered { "" } else { " (not recovered)" }
                    )
                })
                .collect();
            writeln!(
                f,
                "lost track   {} (model in view, features not registering or far off): {}",
                match self.track_losses.len() {
                    1 => "once".to_string(),
                    n => format!("{n} times"),
                },
                shown.join(", ")
            )?;
        }
        if !self.without_vision.is_empty() {
            let total: f64 = self.without_vision.iter().map(|w| w[1] - w[0]).sum();
            writeln!(
                f,
                "no vision    {}, {:.2} s in all",
                counted(self.without_vision.len(), "stretch", "stretches"),
                total
            )?;
        }
        if let Some(l) = &self.line {
            writeln!(
                f,
                "line noise   {:e} per byte: {} frames damaged to the core, {} refused there; {} damaged to the host, {} refused here; {} Hellos sent again",
                l.byte_error_rate,
                l.damaged_to_core,
                l.refused_by_core
                    .map_or_else(|| "?".to_string(), |n| n.to_string()),
                l.damaged_to_host,
                l.refused_by_host,
                l.resent_hellos
            )?;
        }
        if self.core_errors + self.core_rejected_frames > 0 {
            writeln!(
                f,
                "core errors  {} refusals, {} undecodable frames",
                self.core_errors, self.core_rejected_frames
            )?;
        }
        if self.stopped_early {
            writeln!(
                f,
                "STOPPED EARLY{}",
                self.error
                    .as_ref()
                    .map(|e| format!(": {e}"))
                    .unwrap_or_default()
            )?;
        }
        Ok(())
    }
}

fn create(path: &Path) -> Result<std::io::BufWriter<std::fs::File>, TrackError> {
    std::fs::File::create(path)
        .map(std::io::BufWriter::new)
        .map_err(|source| TrackError::Output {
            path: path.to_owned(),
            source,
        })
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> TrackError + '_ {
    move |source| TrackError::Output {
        path: path.to_owned(),
        source,
    }
}

/// The states a run gives as its estimate: every state of an inertial run (one per IMU
/// sample); of a vision-only run, the state after each frame's update (its tick 1 µs after the
/// trigger), not the one at the trigger, which is the prediction the frame was analysed at
/// (issue 33: the two alternated in `trajectory.tum`, 1 µs apart, 5.4 mm apart at the median).
fn estimates(log: &CoreLog, vision_only: bool) -> impl Iterator<Item = &protocol::StateReport> {
    log.states
        .iter()
        .filter(move |s| !(vision_only && log.predictions.contains_key(&s.t_us)))
}

/// The camera position [m] and rotation [°] errors of a predicted pose `p` against the
/// ground truth at `stamp` [ns], where there is one.
fn camera_error(dataset: &Dataset, stamp: u64, p: &protocol::PosePrediction) -> Option<(f64, f64)> {
    let (pt, qt) = dataset.groundtruth_at(stamp)?;
    let (c_true, q_cw_true) = dataset.hand_eye.camera_pose(&pt, &qt);
    let (c, q_wc) = super::vision::camera_in_world(p)?;
    Some((
        (c - c_true).norm(),
        q_cw_true.inverse().angle_to(&q_wc).to_degrees(),
    ))
}

/// The pose a frame's verdict is on, with the core's covariance of it (docs/VISION.md §10):
/// vision-only the core's answer to the frame (`answer`, the state just after it), with an IMU
/// its prediction `p`, the pose put out at its time.
fn verdict_pose(
    p: &protocol::PosePrediction,
    answer: Option<&protocol::StateReport>,
    vision_only: bool,
    core_he: &HandEye,
) -> Option<(camera::CameraPose, Option<camera::PoseCovariance>)> {
    if vision_only {
        let s = answer?;
        let (c_w, q_wc) = camera_of_state(s, core_he);
        let pose = camera::CameraPose {
            q_cw: q_wc.inverse(),
            c_w,
        };
        Some((pose, camera::PoseCovariance::from_upper(&s.cov)))
    } else {
        let pose = vision::prediction_pose(p).ok()?;
        Some((pose, camera::PoseCovariance::from_upper(&p.cov)))
    }
}

/// The camera's true pose at `stamp` [ns], where the dataset has ground truth.
fn true_camera(dataset: &Dataset, stamp: u64) -> Option<camera::CameraPose> {
    let (p, q) = dataset.groundtruth_at(stamp)?;
    let (c_w, q_cw) = dataset.hand_eye.camera_pose(&p, &q);
    Some(camera::CameraPose { q_cw, c_w })
}

/// Writes `(stamp ns, position, q_wc)` rows as a TUM trajectory. Each of `gaps`, `(stamp ns
/// of its start, what)`, is marked by a comment line where it falls (a TUM reader such as
/// `evo` skips comments).
pub fn write_tum(
    path: &Path,
    rows: impl Iterator<Item = (u64, Vector3<f64>, UnitQuaternion<f64>)>,
    gaps: &[(u64, String)],
) -> Result<usize, TrackError> {
    let mut w = create(path)?;
    let e = io(path);
    writeln!(w, "# timestamp tx ty tz qx qy qz qw").map_err(&e)?;
    let mut n = 0;
    let mut gaps = gaps.iter().peekable();
    for (stamp, p, q) in rows {
        while let Some((_, what)) = gaps.next_if(|(at, _)| *at < stamp) {
            writeln!(w, "# gap: {what}").map_err(&e)?;
        }
        let q = q.quaternion();
        writeln!(
            w,
            "{}.{:09} {:.6} {:.6} {:.6} {:.7} {:.7} {:.7} {:.7}",
            stamp / 1_000_000_000,
            stamp % 1_000_000_000,
            p.x,
            p.y,
            p.z,
            q.i,
            q.j,
            q.k,
            q.w
        )
        .map_err(&e)?;
        n += 1;
    }
    w.flush().map_err(&e)?;
    Ok(n)
}

/// Wraps an angle difference into (−180°, 180°].
fn wrap_deg(a: f64) -> f64 {
    let mut a = a % 360.0;
    if a > 180.0 {
        a -= 360.0;
    } else if a <= -180.0 {
        a += 360.0;
    }
    a
}

/// Errors of one estimated IMU-rate state against the ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateError {
    /// Camera position [m].
    pub position_m: f64,
    /// Absolute IMU Euler angle errors (roll, pitch, yaw) [°].
    pub euler_deg: [f64; 3],
    /// Angle of the error rotation [°].
    pub attitude_deg: f64,
}

/// [`StateError`] of a state report at `stamp` from a core configured with the mount
/// `core_he` (the dataset's, or none in vision-only runs, whose state is the camera's); `None`
/// without ground truth there.
pub fn state_errors(
    dataset: &Dataset,
    core_he: &HandEye,
    stamp: u64,
    s: &protocol::StateReport,
) -> Option<StateError> {
    let (p_true, q_true) = dataset.groundtruth_at(stamp)?;
    let (c_true, _) = dataset.hand_eye.camera_pose(&p_true, &q_true);
    let (c_est, q_wc_est) = camera_of_state(s, core_he);
    // The IMU's orientation: the state's own, or, for a camera state, through the mount
    // (q_ws = q_wc q_cs).
    let q_ws_est = if *core_he == dataset.hand_eye {
        state_pose(s).1
    } else {
        q_wc_est * dataset.hand_eye.q_cs
    };
    let (r0, p0, y0) = q_true.euler_angles();
    let (r1, p1, y1) = q_ws_est.euler_angles();
    let euler = [
        wrap_deg((r1 - r0).to_degrees()).abs(),
        wrap_deg((p1 - p0).to_degrees()).abs(),
        wrap_deg((y1 - y0).to_degrees()).abs(),
    ];
    Some(StateError {
        position_m: (c_est - c_true).norm(),
        euler_deg: euler,
        attitude_deg: q_true.angle_to(&q_ws_est).to_degrees(),
    })
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// What a run saw, to write: the tracker's record, what the host added, and the renderer.
pub(super) struct Seen<'a> {
    pub record: &'a Record,
    pub host: &'a HostRecord,
    pub adapter: &'a str,
}

/// The columns of `frames.csv`.
const FRAMES_HEADER: &str = "index,t_s,frame_id,model_coverage,visible,added,tried,registered,sent,accepted,gated,contours,contour_error_px,prediction_error_px,position_error_m,estimate_error_m,estimate_error_deg,render_ms,pyramids_ms,klt_ms,total_ms,contour_rms_px,silhouette,contour_sigma_m,contour_sigma_deg,contour_excess,rms_px,consistency,ncc,tracked,age_ms,sent_ms,pose_ms,dropped_before,sigma_pos_m,sigma_rot_deg,weakest,weakest_sigma,nees,cov_00,cov_01,cov_02,cov_03,cov_04,cov_05,cov_11,cov_12,cov_13,cov_14,cov_15,cov_22,cov_23,cov_24,cov_25,cov_33,cov_34,cov_35,cov_44,cov_45,cov_55,outcome";

/// A line of `frames.csv`.
enum FrameLine<'a> {
    /// An analysed frame's row.
    Analysed(&'a FrameRow),
    /// A frame taken and not analysed, at `t` [s].
    Not { index: usize, t: f64, fate: Fate },
}

/// Every frame taken, in the order taken, as its analysed row or with what became of it; then
/// the rows of frames analysed but never taken (none from the tracker).
fn frame_lines<'a>(
    taken: &[tracker::record::TakenFrame],
    rows: &'a [FrameRow],
    stamp0: u64,
) -> Vec<FrameLine<'a>> {
    let mut analysed: BTreeMap<usize, &FrameRow> = rows.iter().map(|r| (r.index, r)).collect();
    let mut lines: Vec<FrameLine> = taken
        .iter()
        .filter_map(|f| match analysed.remove(&f.index) {
            Some(r) => Some(FrameLine::Analysed(r)),
            // Its analysis is the line (a frame analysed twice is one row).
            None if f.fate == Fate::Analysed => None,
            None => Some(FrameLine::Not {
                index: f.index,
                t: (f.t_ns - stamp0 as i64) as f64 * 1e-9,
                fate: f.fate,
            }),
        })
        .collect();
    lines.extend(analysed.into_values().map(FrameLine::Analysed));
    lines
}

/// How many frames taken ended each way, by [`Fate::name`].
fn frame_outcomes(taken: &[tracker::record::TakenFrame]) -> BTreeMap<&'static str, usize> {
    let mut counts = BTreeMap::new();
    for f in taken {
        *counts.entry(f.fate.name()).or_insert(0) += 1;
    }
    counts
}

/// What the outputs are computed from: the run's record, the dataset, the options, and the
/// time origin of the files' stamps.
struct Inputs<'a> {
    dataset: &'a Dataset,
    options: &'a TrackOptions,
    record: &'a Record,
    /// Times count from the input's first sample [ns], also where an attached run began
    /// later.
    stamp0: u64,
}

impl Inputs<'_> {
    /// The input's stamp [ns] of the run's time `t_us`.
    fn stamp_of(&self, t_us: u64) -> u64 {
        self.stamp0 + t_us * 1000
    }

    /// The core's estimates (states) that are the trajectory.
    fn estimates(&self) -> impl Iterator<Item = &protocol::StateReport> {
        estimates(&self.record.log, self.options.vision_only())
    }
}

/// Builds the frame rows and the summary, and writes every output file.
pub(super) fn write_all(
    dataset: &Dataset,
    options: &TrackOptions,
    seen: Seen,
    link: LinkEnd,
    stopped_early: bool,
    error: Option<String>,
) -> Result<(Vec<FrameRow>, Summary, Vec<PathBuf>), TrackError> {
    let record = seen.record;
    let stamp0 = match (record.attached_at, record.origin_ns) {
        (Some(_), _) => dataset.imu.first().map_or(0, |r| r.stamp),
        (None, Some(origin)) => u64::try_from(origin).unwrap_or(0),
        (None, None) => record.clock.first().copied().unwrap_or(0),
    };
    let i = Inputs {
        dataset,
        options,
        record,
        stamp0,
    };
    let out = &options.out;
    let mut written = write_trajectories(&i)?;
    let rows = frame_rows(&i);
    let path = out.join("frames.csv");
    write_frames_csv(&path, &i, &rows)?;
    written.push(path);
    // Errors of every state against the ground truth (once: the accuracy and the plot).
    let errors: Vec<(f64, StateError)> = i
        .estimates()
        .filter_map(|s| {
            let e = state_errors(dataset, &record.core_hand_eye, i.stamp_of(s.t_us), s)?;
            Some((seconds(s.t_us), e))
        })
        .collect();
    let summary = summarise(&i, &seen, &link, &rows, &errors, (stopped_early, error));
    let path = out.join("summary.json");
    write_summary_json(&path, &summary, link.board)?;
    written.push(path);
    written.extend(overlay::write_overlays(
        &out.join("overlays"),
        dataset,
        record,
    )?);
    let position_mm: Vec<(f64, f64)> = errors
        .iter()
        .map(|(t, e)| (*t, e.position_m * 1e3))
        .collect();
    written.extend(plot::write_track_plots(
        out,
        &summary.model,
        &rows,
        &position_mm,
    )?);
    Ok((rows, summary, written))
}

/// Writes the trajectories (the states through the core's mount, and the frames' predictions)
/// and the ground truth over the span streamed to the core (through the dataset's mount).
fn write_trajectories(i: &Inputs) -> Result<Vec<PathBuf>, TrackError> {
    let (dataset, record, stamp0) = (i.dataset, i.record, i.stamp0);
    let core_he = record.core_hand_eye;
    let out = &i.options.out;
    // Outages: the poses around them come from a core that had its state (protocol/PROTOCOL.md
    // §8); the hole between is marked.
    let gaps: Vec<(u64, String)> = record
        .outages
        .iter()
        .map(|o| {
            let from = o.injected_s.unwrap_or(o.noticed_s);
            (
                stamp0 + (from * 1e9) as u64,
                format!(
                    "{:?} from {from:.3} s ({}), the core back at {}",
                    o.kind,
                    o.cause,
                    o.resumed_s
                        .map_or("the end: never".into(), |t| format!("{t:.3} s"))
                ),
            )
        })
        .collect();
    let mut written = Vec::new();
    let path = out.join("trajectory.tum");
    write_tum(
        &path,
        i.estimates().map(|s| {
            let (c, q) = camera_of_state(s, &core_he);
            (i.stamp_of(s.t_us), c, q)
        }),
        &gaps,
    )?;
    written.push(path);
    let path = out.join("trajectory_frames.tum");
    write_tum(
        &path,
        record.log.predictions.values().filter_map(|p| {
            let (c, q) = super::vision::camera_in_world(p)?;
            Some((i.stamp_of(p.t_us), c, q))
        }),
        &gaps,
    )?;
    written.push(path);
    if dataset.groundtruth.is_some() {
        let path = out.join("groundtruth.tum");
        write_tum(
            &path,
            record.clock.iter().filter_map(|&stamp| {
                let (p, q) = dataset.groundtruth_at(stamp)?;
                let (c, q_cw) = dataset.hand_eye.camera_pose(&p, &q);
                Some((stamp, c, q_cw.inverse()))
            }),
            &[],
        )?;
        written.push(path);
    }
    Ok(written)
}

/// Every analysed frame's row.
fn frame_rows(i: &Inputs) -> Vec<FrameRow> {
    // Vision-only, each frame's answer by its time (with an IMU the prediction is the pose).
    let answers: BTreeMap<u64, &protocol::StateReport> = if i.options.vision_only() {
        i.estimates().map(|s| (s.t_us, s)).collect()
    } else {
        BTreeMap::new()
    };
    i.record
        .results
        .iter()
        .map(|(frame_id, r)| frame_row(i, &answers, *frame_id, r))
        .collect()
}

/// The row of the frame `frame_id`, analysed as `r` (`answers`: vision-only, the core's
/// answer to each frame by its time).
fn frame_row(
    i: &Inputs,
    answers: &BTreeMap<u64, &protocol::StateReport>,
    frame_id: u32,
    r: &vision::FrameResult,
) -> FrameRow {
    let (dataset, record) = (i.dataset, i.record);
    let rule = record.rule;
    let reports = record.log.updates.get(&frame_id);
    let accepted = reports.map_or(0, |v| v.iter().map(|u| u.accepted as usize).sum());
    let gated = reports.map_or(0, |v| v.iter().map(|u| u.rejected as usize).sum());
    let p = &r.job.prediction;
    let position_error_m = camera_error(dataset, r.job.stamp, p).map(|e| e.0);
    // The pose the frame's verdict is on, its error and its covariance's calibration
    // against the truth (docs/VISION.md §10, eq. T6).
    let verdict = verdict_pose(
        p,
        answers.get(&(p.t_us + 1)).copied(),
        i.options.vision_only(),
        &record.core_hand_eye,
    );
    let truth = true_camera(dataset, i.stamp_of(p.t_us));
    let estimate_error = verdict.zip(truth).map(|((e, _), t)| {
        (
            (e.c_w - t.c_w).norm(),
            t.q_cw.angle_to(&e.q_cw).to_degrees(),
        )
    });
    let cov = verdict.and_then(|(_, c)| c);
    let weakest = verdict.and_then(|(pose, c)| Some(record.weakest(&pose, &c?)));
    let nees = verdict.zip(truth).and_then(|((e, c), t)| c?.nees(&e, &t));
    let judged = record.assessments.get(&frame_id);
    let tracked = record.tracked(frame_id);
    let latency = record.latency.frames.get(&r.job.index);
    FrameRow {
        age_ms: latency.map(|l| l.taken_ms),
        sent_ms: latency.and_then(|l| l.sent_ms),
        pose_ms: latency.and_then(|l| l.pose_ms),
        dropped_before: latency.map_or(0, |l| l.dropped_before),
        rms_px: judged.and_then(|a| a.rms_px),
        consistency: judged
            .and_then(|a| a.consistency)
            .map(|c| c.ratio(rule.consistency_z)),
        ncc: judged.and_then(|a| a.ncc),
        contour_rms_px: judged.and_then(|a| a.contour_rms_px),
        contour_sigma_m: judged.and_then(|a| a.contour_spread).map(|s| s[0]),
        contour_sigma_deg: judged
            .and_then(|a| a.contour_spread)
            .map(|s| s[1].to_degrees()),
        contour_excess: judged.and_then(|a| a.contour_excess),
        silhouette: judged.and_then(|a| a.silhouette),
        contours: r.contours.len(),
        contour_error_px: r.contour_error_px,
        tracked,
        index: r.job.index,
        t: seconds(p.t_us),
        frame_id,
        model_coverage: r.model_coverage,
        visible: r.visible,
        added: r.added,
        tried: r.features.len(),
        registered: r.features.iter().filter(|f| f.registered.is_ok()).count(),
        sent: r.correspondences.len(),
        accepted,
        gated,
        prediction_error_px: r.prediction_error_px,
        position_error_m,
        estimate_error_m: estimate_error.map(|e| e.0),
        estimate_error_deg: estimate_error.map(|e| e.1),
        sigma_pos_m: cov.map(|c| c.position_sigma_m()),
        sigma_rot_deg: cov.map(|c| c.rotation_sigma_rad().to_degrees()),
        weakest: weakest.map(|w| w.name()),
        weakest_sigma: weakest.map(|w| w.sigma),
        nees,
        cov: cov.map(|c| c.upper()),
        render_ms: r.times.render * 1e3,
        pyramids_ms: r.times.pyramids * 1e3,
        klt_ms: r.times.klt * 1e3,
        total_ms: r.times.total * 1e3,
    }
}

/// Writes `frames.csv`: every frame taken, in order, with what became of it; an analysed
/// frame's line has its row.
fn write_frames_csv(path: &Path, i: &Inputs, rows: &[FrameRow]) -> Result<(), TrackError> {
    let mut w = create(path)?;
    let e = io(path);
    writeln!(w, "{FRAMES_HEADER}").map_err(&e)?;
    let empty = ",".repeat(FRAMES_HEADER.matches(',').count() - 2);
    for line in frame_lines(&i.record.frames, rows, i.stamp0) {
        match line {
            FrameLine::Analysed(r) => writeln!(w, "{}", csv_row(r)).map_err(&e)?,
            // A frame taken and not analysed: its index, time and what became of it.
            FrameLine::Not { index, t, fate } => {
                writeln!(w, "{index},{t:.6},{empty}{}", fate.name()).map_err(&e)?
            }
        }
    }
    w.flush().map_err(&e)
}

/// An analysed frame's line of `frames.csv` (the columns of [`FRAMES_HEADER`]).
fn csv_row(r: &FrameRow) -> String {
    let o = |v: Option<f64>| v.map(|v| format!("{v:.4}")).unwrap_or_default();
    let ms = |v: Option<f64>| v.map(|v| format!("{v:.3}")).unwrap_or_default();
    format!(
        "{},{:.6},{},{:.4},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        r.index,
        r.t,
        r.frame_id,
        r.model_coverage,
        r.visible,
        r.added,
        r.tried,
        r.registered,
        r.sent,
        r.accepted,
        r.gated,
        r.contours,
        o(r.contour_error_px),
        o(r.prediction_error_px),
        o(r.position_error_m),
        o(r.estimate_error_m),
        o(r.estimate_error_deg),
        r.render_ms,
        r.pyramids_ms,
        r.klt_ms,
        r.total_ms,
        o(r.contour_rms_px),
        o(r.silhouette),
        o(r.contour_sigma_m),
        o(r.contour_sigma_deg),
        o(r.contour_excess),
        o(r.rms_px),
        o(r.consistency),
        o(r.ncc),
        r.tracked
            .map(|t| if t { "1" } else { "0" })
            .unwrap_or_default(),
        ms(r.age_ms),
        ms(r.sent_ms),
        ms(r.pose_ms),
        r.dropped_before,
        o(r.sigma_pos_m),
        o(r.sigma_rot_deg),
        r.weakest.unwrap_or_default(),
        o(r.weakest_sigma),
        o(r.nees),
        r.cov.map_or(",".repeat(20), |c| c
            .iter()
            .map(|v| format!("{v:.6e}"))
            .collect::<Vec<_>>()
            .join(",")),
        Fate::Analysed.name()
    )
}

/// When the core first took a frame's correspondences (or, attached, was already
/// tracking), its divergences, and the stretches without vision after that.
fn vision_stretches(log: &CoreLog) -> (Option<f64>, Vec<Event>, Vec<[f64; 2]>) {
    let snapped_on_at = log
        .statuses
        .iter()
        .find(|s| {
            // An attached core may have been tracking already when the host asked.
            s.reason == StatusReason::VisionAccepted
                || (s.reason == StatusReason::Queried && s.mode == Mode::Tracking)
        })
        .map(|s| seconds(s.t_us));
    let divergences: Vec<Event> = log
        .statuses
        .iter()
        .filter(|s| matches!(s.mode, Mode::Diverged))
        .map(|s| Event {
            t: seconds(s.t_us),
            mode: format!("{:?}", s.mode),
            reason: format!("{:?}", s.reason),
        })
        .collect();
    let mut without_vision = Vec::new();
    if snapped_on_at.is_some() {
        let mut from: Option<f64> = None;
        for s in &log.statuses {
            let t = seconds(s.t_us);
            match (s.mode, from) {
                (Mode::Tracking, Some(f)) => {
                    // A status that went and came back within one time stamp is no stretch.
                    if t > f {
                        without_vision.push([f, t]);
                    }
                    from = None;
                }
                (Mode::DeadReckoning | Mode::Diverged | Mode::Reinitialising, None)
                    if snapped_on_at.is_some_and(|t0| t > t0) =>
                {
                    from = Some(t);
                }
                _ => {}
            }
        }
        if let (Some(f), Some(last)) = (from, log.states.last()) {
            without_vision.push([f, seconds(last.t_us)]);
        }
    }

    (snapped_on_at, divergences, without_vision)
}

/// The accuracy of the states from snap-on (`snapped_on_at`) against the ground truth.
fn accuracy(errors: &[(f64, StateError)], snapped_on_at: Option<f64>) -> Option<Accuracy> {
    snapped_on_at.and_then(|t0| {
        let mut acc = Accuracy::default();
        let mut sq = 0.0;
        for (_, e) in errors.iter().filter(|(t, _)| *t >= t0) {
            let (pe, euler, att) = (e.position_m, e.euler_deg, e.attitude_deg);
            acc.samples += 1;
            acc.mean_position_m += pe;
            sq += pe * pe;
            acc.max_position_m = acc.max_position_m.max(pe);
            for (m, e) in acc.mean_euler_deg.iter_mut().zip(euler) {
                *m += e;
            }
            acc.mean_attitude_deg += att;
            if pe < 0.05 && att < 5.0 {
                acc.within_5cm_5deg += 1.0;
            }
        }
        (acc.samples > 0).then(|| {
            let n = acc.samples as f64;
            acc.mean_position_m /= n;
            acc.rms_position_m = (sq / n).sqrt();
            acc.mean_euler_deg.iter_mut().for_each(|m| *m /= n);
            acc.mean_attitude_deg /= n;
            acc.within_5cm_5deg /= n;
            acc
        })
    })
}

/// The run's summary (`summary.json`); `end`: whether it stopped early, and its error.
fn summarise(
    i: &Inputs,
    seen: &Seen,
    link: &LinkEnd,
    rows: &[FrameRow],
    errors: &[(f64, StateError)],
    (stopped_early, error): (bool, Option<String>),
) -> Summary {
    let (dataset, options, record, stamp0) = (i.dataset, i.options, i.record, i.stamp0);
    let (log, board) = (&record.log, link.board);
    let (host, adapter) = (seen.host, seen.adapter);
    let rule = record.rule;
    let (snapped_on_at, divergences, without_vision) = vision_stretches(log);
    let accuracy = accuracy(errors, snapped_on_at);
    let errors_px: Vec<f64> = rows.iter().filter_map(|r| r.prediction_error_px).collect();
    let contour_px: Vec<f64> = rows.iter().filter_map(|r| r.contour_error_px).collect();
    let since_stamp0 =
        |stamp: Option<&u64>| stamp.map_or(0.0, |&stamp| stamp.saturating_sub(stamp0) as f64 / 1e9);
    let duration_s = since_stamp0(record.clock.last());
    Summary {
        dataset: dataset.root.display().to_string(),
        model: format!("{:?}", options.filter).to_lowercase(),
        link: options.link.to_string(),
        adapter: adapter.to_string(),
        t0_stamp_ns: stamp0,
        streamed_from_s: since_stamp0(record.clock.first()),
        duration_s,
        tracked_s: snapped_on_at.map_or(0.0, |t0| (duration_s - t0).max(0.0)),
        frames: rows.len(),
        frame_outcomes: frame_outcomes(&record.frames),
        frame_errors: record.frame_errors.iter().map(|(_, e)| e.clone()).collect(),
        correspondences_sent: record.sent_correspondences,
        accepted: rows.iter().map(|r| r.accepted).sum(),
        gated: rows.iter().map(|r| r.gated).sum(),
        injected_outliers: host.injected_outliers,
        mean_prediction_error_px: (!errors_px.is_empty())
            .then(|| errors_px.iter().sum::<f64>() / errors_px.len() as f64),
        median_prediction_error_px: median(errors_px),
        mean_contour_error_px: (!contour_px.is_empty())
            .then(|| contour_px.iter().sum::<f64>() / contour_px.len() as f64),
        median_contour_error_px: median(contour_px),
        accuracy,
        snapped_on_at,
        imu_used: !options.vision_only(),
        tracked: (!record.assessments.is_empty()).then(|| {
            let judged: Vec<bool> = rows.iter().filter_map(|r| r.tracked).collect();
            let tracked = judged.iter().filter(|&&t| t).count();
            TrackedShare {
                frames: judged.len(),
                tracked,
                share: tracked as f64 / judged.len().max(1) as f64,
                rule,
                untracked: untracked_stretches(rows),
            }
        }),
        divergences,
        without_vision,
        cold_start: ColdStart::of(&record.searches, frame_period(rows)),
        line: link.noise.map(|n| LineSummary {
            byte_error_rate: n.byte_error_rate,
            damaged_to_core: n.to_core.counts().1,
            refused_by_core: board.map(|b| u64::from(b.counters.decode_errors)),
            invalid_at_core: board.map(|b| u64::from(b.counters.invalid_messages)),
            damaged_to_host: n.to_host.counts().1,
            refused_by_host: log.rejected_frames as u64,
            resent_hellos: record.log.resent_hellos,
        }),
        search_database: record.database.as_ref().map(|p| match p {
            Provenance::Cached(path) => format!("{} (from the cache)", path.display()),
            Provenance::Built { path, why } => {
                format!("built: {why}; written to {}", path.display())
            }
        }),
        recoveries: record.recoveries.iter().map(RecoverySummary::of).collect(),
        tilt_checks: TiltChecks {
            checks: record.tilt.checks,
            flips: record.tilt.flips.clone(),
            refused: record.tilt.refused.clone(),
            withheld: record.tilt.withheld.len(),
        },
        outages: record.outages.clone(),
        attach: record.attach_note.clone(),
        track_losses: snapped_on_at.map_or_else(Vec::new, |t0| track_losses(rows, t0)),
        latency: LatencySummary::of(&record.latency, options),
        mean_frame_ms: if rows.is_empty() {
            0.0
        } else {
            rows.iter().map(|r| r.total_ms).sum::<f64>() / rows.len() as f64
        },
        wall_s: record.elapsed(),
        core_errors: log.errors.len(),
        core_rejected_frames: log.rejected_frames,
        stopped_early,
        error,
    }
}

/// Writes the summary, with the simulated `board`'s counters, as `summary.json`.
fn write_summary_json(
    path: &Path,
    summary: &Summary,
    board: Option<&BoardReport>,
) -> Result<(), TrackError> {
    let mut json = serde_json::to_value(summary).map_err(|e| TrackError::Output {
        path: path.to_owned(),
        source: std::io::Error::other(e),
    })?;
    if let Some(b) = board {
        json["board"] = serde_json::json!({
            "bytes_in": b.bytes_in,
            "bytes_out": b.bytes_out,
            "imu_applied": b.counters.imu_applied,
            "accepted": b.counters.accepted,
            "gated": b.counters.gated,
            "divergences": b.counters.divergences,
            "decode_errors": b.counters.decode_errors,
            "invalid_messages": b.counters.invalid_messages,
        });
    }
    round_floats(&mut json);
    let text = serde_json::to_string_pretty(&json).map_err(|e| TrackError::Output {
        path: path.to_owned(),
        source: std::io::Error::other(e),
    })?;
    std::fs::write(path, text + "\n").map_err(io(path))
}

/// Rounds every float in `v` to 9 significant digits: the figures are far less precise than
/// that, and `0.30000000000000004` says nothing `0.3` does not.
pub fn round_floats(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Number(n) if !(n.is_u64() || n.is_i64()) => {
            if let Some(x) = n.as_f64()
                && let Ok(r) = format!("{x:.8e}").parse::<f64>()
                && let Some(r) = serde_json::Number::from_f64(r)
            {
                *n = r;
            }
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(round_floats),
        serde_json::Value::Object(o) => o.values_mut().for_each(round_floats),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(t: f64, tried: usize, registered: usize, error_px: Option<f64>) -> FrameRow {
        FrameRow {
            t,
            tried,
            registered,
            prediction_error_px: error_px,
            ..FrameRow::default()
        }
    }

    #[test]
    fn json_floats_are_rounded_to_nine_digits_and_times_are_exact() {
        assert_eq!(seconds(340_000), 0.34);
        let mut v =
            serde_json::json!({"a": [0.1 + 0.2, 1u64 << 60], "b": {"c": 0.007319247205086048}});
        round_floats(&mut v);
        assert_eq!(
            v.to_string(),
            r#"{"a":[0.3,1152921504606846976],"b":{"c":0.00731924721}}"#
        );
    }

    #[test]
    fn track_losses_need_the_model_in_view_and_two_frames_off() {
        let rows = vec![
            row(0.00, 40, 40, Some(0.5)),
            // One frame far off: a glitch.
            row(0.04, 40, 30, Some(12.0)),
            row(0.08, 40, 40, Some(0.5)),
            // Model out of view, or leaving it with few features tried: nothing to say.
            row(0.12, 0, 0, None),
            row(0.16, 16, 1, Some(2.0)),
            row(0.18, 12, 0, None),
            // In view, nothing registers, then registered far off, then back.
            row(0.20, 30, 0, None),
            row(0.24, 30, 1, Some(20.0)),
            row(0.28, 30, 25, Some(14.0)),
            row(0.32, 30, 30, Some(1.0)),
            // Lost to the end.
            row(0.36, 30, 2, Some(1.0)),
            row(0.40, 0, 0, None),
            row(0.44, 30, 0, None),
        ];
        let losses = track_losses(&rows, 0.0);
        assert_eq!(
            losses,
            vec![
                TrackLoss {
                    start: 0.20,
                    end: 0.32,
                    recovered: true
                },
                TrackLoss {
                    start: 0.36,
                    end: 0.44,
                    recovered: false
                },
            ]
        );
        // Before snap-on nothing counts.
        assert_eq!(track_losses(&rows, 0.34).len(), 1);
    }
}
