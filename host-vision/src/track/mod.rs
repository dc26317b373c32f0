//! The tracking pipeline (`host-vision track`): a dataset in, the fusion core at the other end
//! of a real byte link, trajectories, per-frame statistics, overlays and plots out.
//!
//! Per IMU sample the host sends `Imu`; at a trigger the core answers with a `PosePrediction`,
//! which goes to the vision worker (a thread of its own, holding the renderer), while the host
//! keeps streaming IMU samples, as the core's integration would go on on hardware. The frame's
//! correspondences are sent when ready:
//! - **lock-step** ([`Pacing::LockStep`]): exactly `latency` after the trigger, counted in IMU
//!   samples, waiting for the worker if needed, so a replay is deterministic and the core's
//!   delayed-update path is always exercised. After each trigger the host sends `Hello` as a
//!   barrier (the core answers it at any time, in order), so it knows whether a prediction came;
//! - **real time** ([`Pacing::RealTime`]): IMU samples paced by the clock, correspondences sent
//!   as soon as the worker has them.

pub use ::vision::assess;
mod cold_start;
pub mod config;
pub mod core;
mod frame_row;
mod outage;
pub mod output;
pub mod overlay;
pub mod plot;
pub mod tilt;
pub use ::vision::analysis as vision;
mod vision_only;

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::{Duration, Instant};

use nalgebra::{UnitQuaternion, Vector3};
use protocol::{
    CoreToHost, Correspondence, ErrorReport, HostToCore, Init, InitAttitude, ModelKind,
    PROTOCOL_VERSION, PosePrediction, StateReport, Status, UpdateReport,
};
use rand::rngs::StdRng;
use rand::{RngExt as _, SeedableRng};

pub use self::assess::{Assessment, Contrast, TrackedRule};
pub use self::config::{CoreTuning, check_latency, core_config};
pub use self::core::{CoreLink, Incoming, LinkSpec};
pub use self::frame_row::FrameRow;
pub use self::output::{Outage, OutageKind, Summary};
pub use self::vision::{FrameImage, FrameJob, FrameResult, Vision, VisionOptions};

use crate::camera::{CalibError, CameraError};
use crate::dataset::{Dataset, DatasetError, HandEye};
use crate::features::ImageError;
use crate::model::ModelError;
use crate::out_folder::OutFolder;
use crate::render::RenderError;

/// Why tracking could not run (or stopped).
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// The dataset.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// The model file.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The renderer.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// Camera parameters.
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// Calibration file.
    #[error(transparent)]
    Calib(#[from] CalibError),
    /// Image buffers.
    #[error(transparent)]
    Features(#[from] ImageError),
    /// The model has no texture, and the tracker registers the texture (issue 33: refused
    /// before anything runs, not half a second into the run by the cold start).
    #[error(
        "{0}: the model has no textured material (an MTL without map_Kd, or a glTF material without a base colour texture): the tracker registers the model's texture, so an untextured model gives it nothing to follow"
    )]
    Untextured(PathBuf),
    /// The transport could not be opened.
    #[error(transparent)]
    Transport(#[from] firmware_sim::transport::TransportError),
    /// The core refused something.
    #[error("core: {0}")]
    Core(String),
    /// The link to the core failed: closed, a transport error, or no answer in time. A run
    /// that recovers from faults (protocol/PROTOCOL.md §8) reconnects; others stop with it.
    #[error("core: {0}")]
    Link(String),
    /// An output file could not be written.
    #[error("{path}: {source}")]
    Output {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// The output folder cannot be used.
    #[error(transparent)]
    OutFolder(#[from] crate::out_folder::OutFolderError),
    /// The frames of a video, camera or image folder could not be read.
    #[error(transparent)]
    Frames(#[from] crate::frames::FrameError),
    /// Ctrl-C before any IMU sample was sent: nothing was tracked, nothing written.
    #[error("interrupted before tracking began: nothing written")]
    Interrupted,
    /// The vision thread could not start or stopped.
    #[error("{0}")]
    VisionThread(String),
    /// A frame could not be analysed.
    #[error(transparent)]
    Vision(#[from] ::vision::VisionError),
    /// The cold start never found the model.
    #[error(
        "cold start: the model was not found in any of the {attempts} frames tried (is it in view, and is this its model?); `host-vision locate` on one frame shows the figures"
    )]
    NotFound {
        /// Frames tried.
        attempts: usize,
    },
    /// The cold start's viewpoint database.
    #[error("cold start: {0}")]
    Database(#[from] crate::locate::database::DatabaseError),
    /// A bad option (named by its command-line flag).
    #[error("{0}")]
    Option(String),
}

/// On a line with injected errors: a `Hello` unanswered this long is sent again.
const RESEND_AFTER: Duration = Duration::from_millis(300);

/// On a line with injected errors: tries of a `Configure` or an `Init` before giving up.
const CONFIRM_TRIES: usize = 10;

/// How the IMU stream is paced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Pacing {
    /// As fast as the link takes it; correspondences after a fixed latency in IMU samples.
    LockStep,
    /// By the clock; correspondences as soon as they are ready.
    RealTime,
}

/// Faults injected by the host, for tests of the core's robustness.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Faults {
    /// Fraction of correspondences replaced by outliers (model point moved 0.1-0.5 m).
    pub outlier_fraction: f64,
    /// From this time [s] on, for `corrupt_seconds`, every correspondence is an outlier:
    /// the core's divergence monitor must fire and tracking must resume.
    pub corrupt_from: Option<f64>,
    /// Length of the corrupted stretch [s].
    pub corrupt_seconds: f64,
    /// From this time [s] on, for `blind_seconds`, every frame is replaced by noise: the model
    /// is gone from the images (a covered lens, garbage frames) while the camera moves. The
    /// core dead-reckons; the model must be found again once the frames are back.
    pub blind_from: Option<f64>,
    /// Length of the blind stretch [s].
    pub blind_seconds: f64,
    /// Bit errors on the line to the simulated board: the probability that a byte has a bit
    /// flipped, in both directions. Damaged frames must be detected and dropped at both ends.
    pub line_errors: Option<f64>,
    /// At this time [s] the core is reset (the simulated board's reset line, or QEMU killed):
    /// the host must notice, configure and initialise it again, and resume.
    pub reset_core_at: Option<f64>,
    /// At this time [s] the cable is pulled: the host's end of the line is closed, and
    /// reconnecting fails for `cut_seconds`.
    pub cut_link_at: Option<f64>,
    /// How long the cable stays out [s].
    pub cut_seconds: f64,
    /// Seed of the injected faults.
    pub seed: u64,
}

/// Where tracking starts (the paper's semi-automatic initialisation: the user holds the
/// camera near a known pose; roll and pitch come from the IMU), or a full 6-DoF pose.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Start {
    /// IMU position [m]; from the ground truth when `None`.
    pub position: Option<[f64; 3]>,
    /// Yaw of the IMU [rad]; from the ground truth when `None`.
    pub yaw: Option<f64>,
    /// The camera's full pose in the model (world) frame at the first IMU sample
    /// (`--start-pose`): the core gets position and orientation, roll and pitch included,
    /// instead of roll and pitch from gravity. Excludes `position` and `yaw`.
    pub pose: Option<crate::camera::CameraPose>,
    /// Find the model in the frames (the cold start, [`crate::locate`]) even where a ground
    /// truth could give the start; it is then used only to evaluate. Excludes the others.
    pub cold: bool,
}

impl Start {
    /// Whether this start is found in the frames rather than given: asked for, or nothing
    /// given and no ground truth to take it from.
    pub fn is_cold(&self, dataset: &Dataset) -> bool {
        self.cold
            || (dataset.groundtruth.is_none()
                && self.pose.is_none()
                && self.position.is_none()
                && self.yaw.is_none())
    }
}

impl Start {
    /// The IMU pose `(s_w, q_sw)` the core expects for the camera pose `pose`, through the
    /// camera's mount (eq. 5-6: `q_cw = q_cs q_sw`, `c_w = s_w + R(q_sw)ᵀ c_s`).
    pub fn imu_pose_of_camera(
        pose: &crate::camera::CameraPose,
        hand_eye: &crate::dataset::HandEye,
    ) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let q_sw = hand_eye.q_cs.inverse() * pose.q_cw;
        let s_w = pose.c_w - q_sw.inverse() * hand_eye.c_s;
        (s_w, q_sw)
    }
}

/// Everything `track` needs.
#[derive(Debug, Clone)]
pub struct TrackOptions {
    /// Dataset folder.
    pub dataset: PathBuf,
    /// Model file (OBJ or glTF); the dataset's `model/scene.obj` when `None`.
    pub model: Option<PathBuf>,
    /// Output folder.
    pub out: PathBuf,
    /// The core.
    pub link: LinkSpec,
    /// Filter model.
    pub filter: ModelKind,
    /// Core tuning.
    pub tuning: CoreTuning,
    /// Image analysis.
    pub vision: VisionOptions,
    /// Pacing.
    pub pacing: Pacing,
    /// Latency from trigger to correspondences in lock-step mode [s].
    pub latency: f64,
    /// Start pose.
    pub start: Start,
    /// Write an overlay image every this many frames (0: none).
    pub overlay_every: usize,
    /// Track only this many seconds of the dataset.
    pub duration: Option<f64>,
    /// Injected faults.
    pub faults: Faults,
    /// Longest wait for an answer of the core.
    pub timeout: Duration,
    /// Replace the outputs of an earlier run in `out` (otherwise they are refused).
    pub overwrite: bool,
    /// Attach to a core that is already running (protocol/PROTOCOL.md §8): ask for its state
    /// and go on from its last sample, without configuring or initialising it again if it is
    /// still tracking.
    pub attach: bool,
    /// Frames from a video, camera or image folder instead of the dataset's (vision-only;
    /// `dataset` is then that input, for reports).
    pub frames: Option<crate::frames::FrameInput>,
    /// The camera of `frames` (its intrinsics), or instead of the dataset's.
    pub camera: Option<crate::camera::Camera>,
    /// Stop after this many frames (vision-only; a live camera never ends by itself).
    pub max_frames: Option<usize>,
    /// Folder of the cold start's viewpoint database ([`crate::locate`]): a vision-only run
    /// with no start pose and no ground truth finds the model itself, frame by frame, until a
    /// pose is verified.
    pub cache: PathBuf,
}

impl TrackOptions {
    /// Defaults for a dataset and output folder: simulated board, acc model, lock-step.
    pub fn new(dataset: PathBuf, out: PathBuf) -> Self {
        Self {
            dataset,
            model: None,
            out,
            link: LinkSpec::Sim(firmware_sim::board::Precision::F32),
            filter: ModelKind::Acc,
            tuning: CoreTuning::default(),
            vision: VisionOptions::default(),
            pacing: Pacing::LockStep,
            latency: 0.03,
            start: Start::default(),
            overlay_every: 25,
            duration: None,
            faults: Faults::default(),
            timeout: Duration::from_secs(10),
            overwrite: false,
            attach: false,
            frames: None,
            camera: None,
            max_frames: None,
            cache: crate::locate::database::default_cache_dir(),
        }
    }

    /// Whether this run is vision-only (no IMU samples are sent).
    pub fn vision_only(&self) -> bool {
        !self.filter.has_imu()
    }

    /// Checks every option against the dataset before anything is started, naming the
    /// command-line flag of a bad one. Returns how many IMU samples will be streamed.
    pub fn check(&self, dataset: &Dataset) -> Result<usize, TrackError> {
        let bad = |m: String| Err(TrackError::Option(m));
        self.check_common()?;
        if self.vision_only() {
            return self.check_vision().map(|()| 0);
        }
        if !dataset.has_imu() {
            return Err(DatasetError::NoImu {
                path: dataset.root.join("mav0/imu0/data.csv"),
                model: self.filter.name(),
            }
            .into());
        }
        if self.frames.is_some() {
            return bad(format!(
                "--video and --images have no IMU: track them with --filter vision, not {}",
                self.filter.name()
            ));
        }
        let stamp0 = dataset.imu[0].stamp;
        let data_s = (dataset.imu[dataset.imu.len() - 1].stamp - stamp0) as f64 / 1e9;
        let end = match self.duration {
            Some(d) if let Some(why) = self.tuning.duration_refusal(d) => return bad(why),
            Some(d) => dataset
                .imu
                .partition_point(|r| ((r.stamp - stamp0) as f64) / 1e9 <= d),
            None => dataset.imu.len(),
        };
        let tracked_s = self.duration.map_or(data_s, |d| d.min(data_s));
        let frame_period = dataset
            .camera
            .rate_hz
            .filter(|r| r.is_finite() && *r > 0.0)
            .map(|r| 1.0 / r)
            .or_else(|| {
                let f = &dataset.frames;
                (f.len() >= 2).then(|| (f[1].stamp - f[0].stamp) as f64 / 1e9)
            });
        if let Some(period) = frame_period
            && self.latency >= period
        {
            return bad(format!(
                "--latency {} s must be below one frame period ({period:.3} s): each prediction needs the previous frame's update",
                self.latency
            ));
        }
        if let Some(t) = self.faults.corrupt_from
            && !(t.is_finite() && (0.0..tracked_s).contains(&t))
        {
            return bad(format!(
                "--corrupt-at counts seconds from the dataset's first IMU sample and must lie in the tracked span [0, {tracked_s:.2}) s, got {t}"
            ));
        }
        if let Some(p) = self.start.position
            && !p.iter().all(|c| c.is_finite())
        {
            return bad(format!(
                "--start-position must be three finite numbers, got {p:?}"
            ));
        }
        if let Some(y) = self.start.yaw
            && !y.is_finite()
        {
            return bad(format!("--start-yaw must be a finite angle, got {y}"));
        }
        if self.start.pose.is_some() && (self.start.position.is_some() || self.start.yaw.is_some())
        {
            return bad(
                "--start-pose gives the whole pose: leave out --start-position and --start-yaw"
                    .into(),
            );
        }
        if self.start.cold
            && (self.start.pose.is_some()
                || self.start.position.is_some()
                || self.start.yaw.is_some())
        {
            return bad(
                "--cold-start finds the start pose: leave out --start-pose, --start-position and --start-yaw"
                    .into(),
            );
        }
        if !self.start.is_cold(dataset)
            && dataset.groundtruth.is_none()
            && self.start.pose.is_none()
            && (self.start.position.is_none() || self.start.yaw.is_none())
        {
            return bad(
                "the dataset has no ground truth: give both --start-position and --start-yaw, or --start-pose, or neither (the cold start then finds the model)"
                    .into(),
            );
        }
        Ok(end)
    }

    /// The checks of every model: features, faults, noise settings.
    fn check_common(&self) -> Result<(), TrackError> {
        let bad = |m: String| Err(TrackError::Option(m));
        if let Some(t) = self.faults.blind_from
            && !(t.is_finite() && t >= 0.0)
        {
            return bad(format!(
                "--blind-at counts seconds from the start and must be at least 0, got {t}"
            ));
        }
        // Checked for every run (a vision-only run sends its correspondences before the next
        // tick, and has no latency to wait for; issue 33: `-1` was accepted there).
        if !(self.latency.is_finite() && self.latency >= 0.0) {
            return bad(format!(
                "--latency must be a non-negative number of seconds, got {}",
                self.latency
            ));
        }
        let features = self.vision.map.subset_size;
        if features == 0 {
            return bad("--features must be at least 1".into());
        }
        // What one frame can send the core (protocol/PROTOCOL.md §6): more is never used.
        if features > protocol::MAX_CORRESPONDENCES_PER_FRAME {
            return bad(format!(
                "--features must be at most {} (the correspondences one frame can send to the \
                 core), got {features}",
                protocol::MAX_CORRESPONDENCES_PER_FRAME
            ));
        }
        let f = &self.faults;
        if !(0.0..=1.0).contains(&f.outlier_fraction) {
            return bad(format!(
                "--outliers must be a fraction in [0, 1], got {}",
                f.outlier_fraction
            ));
        }
        let positive = |flag: &str, v: f64, unit: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(TrackError::Option(format!(
                    "{flag} must be a positive number [{unit}], got {v}"
                )))
            }
        };
        positive("--expected-accel", self.tuning.expected_accel, "m/s²")?;
        positive("--angular-noise", self.tuning.angular_noise, "rad/s²/√Hz")?;
        for (flag, at) in [
            ("--reset-core-at", f.reset_core_at),
            ("--cut-link-at", f.cut_link_at),
        ] {
            if let Some(t) = at
                && !(t.is_finite() && t >= 0.0)
            {
                return bad(format!(
                    "{flag} counts seconds from the start and must be at least 0, got {t}"
                ));
            }
        }
        if f.cut_link_at.is_some() && !(f.cut_seconds.is_finite() && f.cut_seconds >= 0.0) {
            return bad(format!(
                "--cut-seconds must be a duration of at least 0 [s], got {}",
                f.cut_seconds
            ));
        }
        if f.reset_core_at.is_some()
            && !matches!(
                self.link,
                LinkSpec::Sim(_)
                    | LinkSpec::InProcess(_)
                    | LinkSpec::Qemu(_)
                    | LinkSpec::QemuDefault
            )
        {
            return bad(format!(
                "--reset-core-at needs a core the host can reset: --link sim, inproc or qemu, not {}",
                self.link
            ));
        }
        // Outages are handled in runs with an IMU (docs/notes/issue17-faults.md §6): a
        // vision-only run is refused a link it could lose and not come back from (issue 33:
        // it exited 0.09 s after a board was killed, with no outage recorded).
        if self.vision_only() && matches!(self.link, LinkSpec::Serial { .. } | LinkSpec::Tcp(_)) {
            return bad(format!(
                "--link {}: a vision-only run does not reconnect to a core it loses (runs with an IMU do, protocol/PROTOCOL.md §8); track it with --link sim or qemu",
                self.link
            ));
        }
        if self.vision_only()
            && (f.reset_core_at.is_some() || f.cut_link_at.is_some() || self.attach)
        {
            return bad(
                "--reset-core-at, --cut-link-at and --attach are for runs with an IMU: a vision-only run does not recover from a lost core yet"
                    .into(),
            );
        }
        if let Some(a) = self.tuning.accel_noise {
            positive("--accel-meas-noise", a, "m/s²")?;
        }
        Ok(())
    }

    /// The vision-only run's checks: a whole start pose if one is given, and what its frames
    /// allow.
    fn check_vision(&self) -> Result<(), TrackError> {
        let bad = |m: String| Err(TrackError::Option(m));
        if let Some(d) = self.duration
            && !(d.is_finite() && d > 0.0)
        {
            return bad(format!(
                "--duration must be a positive number of seconds, got {d}"
            ));
        }
        if self.max_frames == Some(0) {
            return bad("--max-frames must be at least 1".into());
        }
        if let Some(t) = self.faults.corrupt_from
            && !(t.is_finite() && t >= 0.0)
        {
            return bad(format!(
                "--corrupt-at counts seconds from the first frame and must be at least 0, got {t}"
            ));
        }
        if self.start.cold && self.start.pose.is_some() {
            return bad("--cold-start finds the start pose: leave out --start-pose".into());
        }
        if self.start.position.is_some() || self.start.yaw.is_some() {
            return bad(
                "the vision-only model has no gravity for roll and pitch: give the whole start pose with --start-pose, not --start-position/--start-yaw"
                    .into(),
            );
        }
        // Without a start pose or a ground truth, the cold start finds the model.
        Ok(())
    }
}

/// Everything the core said, as received.
#[derive(Debug, Default)]
pub struct CoreLog {
    /// State reports (one per IMU sample while running).
    pub states: Vec<StateReport>,
    /// Pose predictions by trigger time [µs].
    pub predictions: BTreeMap<u64, PosePrediction>,
    /// Update reports by frame id.
    pub updates: BTreeMap<u32, Vec<UpdateReport>>,
    /// Mode changes.
    pub statuses: Vec<Status>,
    /// Refusals.
    pub errors: Vec<ErrorReport>,
    /// Frames from the core that failed to decode.
    pub rejected_frames: usize,
    /// `HelloAck`s received (handshake and barriers).
    pub acks: usize,
    /// Added to the core's frame ids: a core that was reset numbers its frames from 0 again,
    /// and the log keeps one id per frame across cores (`new_core`).
    frame_offset: u32,
    /// One past the largest frame id logged.
    next_frame: u32,
}

impl CoreLog {
    fn take(&mut self, item: Incoming) {
        match item {
            Incoming::Rejected(_) => self.rejected_frames += 1,
            Incoming::Message(m) => match m {
                CoreToHost::HelloAck(_) => self.acks += 1,
                CoreToHost::Error(e) => self.errors.push(e),
                CoreToHost::PosePrediction(mut p) => {
                    p.frame_id = self.frame_id(p.frame_id);
                    self.predictions.insert(p.t_us, p);
                }
                // The answer to a `Query` repeats the last state: kept once.
                CoreToHost::State(s) if self.states.last().is_some_and(|l| l.t_us == s.t_us) => {}
                CoreToHost::State(s) => self.states.push(s),
                CoreToHost::UpdateReport(mut r) => {
                    r.frame_id = self.frame_id(r.frame_id);
                    self.updates.entry(r.frame_id).or_default().push(r)
                }
                CoreToHost::Status(s) => self.statuses.push(s),
            },
        }
    }

    /// The log's id of the current core's frame `core_id`.
    fn frame_id(&mut self, core_id: u32) -> u32 {
        let id = core_id.wrapping_add(self.frame_offset);
        self.next_frame = self.next_frame.max(id.wrapping_add(1));
        id
    }

    /// The current core's id of the log's frame `id`.
    fn core_frame_id(&self, id: u32) -> u32 {
        id.wrapping_sub(self.frame_offset)
    }

    /// A new core (reset, and configured again) numbers its frames from 0: they follow the
    /// old core's in the log.
    fn new_core(&mut self) {
        self.frame_offset = self.next_frame;
    }

    /// The current mode (last status).
    pub fn mode(&self) -> Option<protocol::Mode> {
        self.statuses.last().map(|s| s.mode)
    }
}

/// The result of a tracking run.
#[derive(Debug)]
pub struct TrackRun {
    /// What the core said.
    pub log: CoreLog,
    /// One row per frame analysed.
    pub frames: Vec<FrameRow>,
    /// Summary figures.
    pub summary: Summary,
    /// Files written.
    pub written: Vec<PathBuf>,
}

/// Progress callback: `(imu samples done, total, frames analysed, current mode)`.
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize, usize, Option<protocol::Mode>);

/// Tracks a dataset. `interrupt` stops it early (Ctrl-C); what was tracked is still written.
pub fn run(
    options: &TrackOptions,
    interrupt: Arc<AtomicBool>,
    progress: Progress,
) -> Result<TrackRun, TrackError> {
    let dataset = vision_only::open_dataset(options)?;
    let end = options.check(&dataset)?;
    let model_path = options
        .model
        .clone()
        .or_else(|| dataset.model.clone())
        .ok_or_else(|| {
            TrackError::Option(if options.frames.is_some() {
                format!(
                    "{}: give the object's textured model with --model (OBJ or glTF)",
                    dataset.root.display()
                )
            } else {
                format!(
                    "{}: no model/scene.obj in the dataset; give the model with --model",
                    dataset.root.display()
                )
            })
        })?;
    // Vision-only frames: a video, camera or image folder, or the dataset's own cam0 (its IMU
    // withheld, or absent). Opened before anything is started: a bad input fails first.
    let mut frames = match (&options.frames, options.vision_only()) {
        (Some(input), _) => Some(input.open(&crate::frames::VideoOptions::default())?),
        (None, true) => Some(
            crate::frames::FrameInput::Images {
                dir: dataset.root.join("mav0/cam0"),
                fps: None,
            }
            .open(&crate::frames::VideoOptions::default())?,
        ),
        (None, false) => None,
    };
    let mut out = OutFolder::prepare(
        &options.out,
        &output::OUTPUTS.map(String::from),
        Some(&dataset.root),
        options.overwrite,
    )?;

    // The link first: it fails most often, and fails before the renderer is made.
    let noise = options
        .faults
        .line_errors
        .map(|rate| (rate, options.faults.seed));
    let mut link = CoreLink::open_noisy(&options.link, noise)?;
    // The vision worker owns the renderer: created once, on its own thread, and always shut
    // down and joined before this function returns (a renderer torn down by the process's
    // exit crashes in the driver).
    let mut vision = options.vision;
    vision.map.small_object_cells |= options.vision_only();
    let (mut worker, ready) =
        VisionWorker::start(dataset.camera.camera, model_path.clone(), vision)?;
    // Searches for the model (the cold start, and after a loss) run on a thread of their own,
    // with a renderer of their own, so that an attempt never holds up the frames.
    let mut search = if options.vision_only() || options.start.is_cold(&dataset) {
        Some(VisionWorker::start(dataset.camera.camera, model_path, vision)?.0)
    } else {
        None
    };
    let adapter = ready.adapter;
    let mut session = Session {
        options,
        dataset: &dataset,
        core_hand_eye: if options.vision_only() {
            HandEye::IDENTITY
        } else {
            dataset.hand_eye
        },
        clock: Vec::new(),
        assessments: BTreeMap::new(),
        log: CoreLog::default(),
        results: Vec::new(),
        frame_errors: Vec::new(),
        rng: StdRng::seed_from_u64(options.faults.seed),
        resent_hellos: 0,
        injected_outliers: 0,
        sent_correspondences: 0,
        wall: Instant::now(),
        axes: ready.axes,
        searches: Vec::new(),
        recoveries: Vec::new(),
        database: None,
        tilt: tilt::TiltBranch::default(),
        session_id: new_session_id(),
        outages: Vec::new(),
        attached_at: None,
        attach_note: None,
    };
    let outcome = match frames.as_mut() {
        Some(source) => session.drive_vision(
            &mut link,
            &worker,
            search.as_ref(),
            source,
            &interrupt,
            progress,
        ),
        None => session.drive(
            &mut link,
            &worker,
            search.as_ref(),
            end,
            &interrupt,
            progress,
        ),
    };
    worker.stop();
    if let Some(s) = search.as_mut() {
        s.stop();
    }
    let damage = link.damage.clone();
    let closed = link.close();
    if session.clock.is_empty() {
        // Nothing was tracked (the handshake or the configuration failed): nothing to write.
        return Err(match (outcome, closed) {
            (Err(e), _) | (Ok(_), Err(e)) => e,
            (Ok(true), Ok(_)) if !session.searches.is_empty() => TrackError::NotFound {
                attempts: session.searches.len(),
            },
            (Ok(_), Ok(_)) => TrackError::Interrupted,
        });
    }
    // An inertial cold start that never found the model streamed its IMU to a core that was
    // never initialised: nothing was tracked either.
    let found = session.searches.iter().any(|s| s.attempt.accepted());
    if !options.vision_only() && !session.searches.is_empty() && !found && outcome.is_ok() {
        if let Ok(false) = outcome {
            return Err(TrackError::Interrupted);
        }
        return Err(TrackError::NotFound {
            attempts: session.searches.len(),
        });
    }
    // Whatever happened, write what was tracked. A board that failed at the end of an
    // otherwise complete session fails the run too.
    let outcome = match (outcome, closed) {
        (Ok(completed), Ok(board)) => Ok((completed, board)),
        (Ok(_), Err(e)) | (Err(e), _) => Err(e),
    };
    let (stopped_early, board) = match &outcome {
        Ok((completed, board)) => (!completed, *board),
        Err(_) => (true, None),
    };
    out.keep();
    let (frames, summary, written) = output::write_all(
        &dataset,
        options,
        &session,
        &adapter,
        output::LinkEnd {
            board: board.as_ref(),
            noise: damage.as_ref(),
        },
        stopped_early,
        outcome.as_ref().err().map(|e| e.to_string()),
    )?;
    outcome?;
    Ok(TrackRun {
        log: session.log,
        frames,
        summary,
        written,
    })
}

/// A session id for this run: non-zero, and different from run to run (the clock's
/// nanoseconds and the process id), so that a host coming back to a core tells its own
/// configuration from another's.
fn new_session_id() -> u32 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos() ^ (d.as_secs() as u32));
    (nanos ^ std::process::id().rotate_left(16)).max(1)
}

/// The vision thread, with the channels to it. Stopped and joined on drop, so that no early
/// return leaves the renderer to be torn down by the process's exit.
struct VisionWorker {
    jobs: Option<Sender<WorkerJob>>,
    results: Receiver<WorkerDone>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// What the vision thread is asked to do.
enum WorkerJob {
    /// Analyse a frame.
    Frame(FrameJob),
    /// Judge the last analysed frame at the pose estimated with its update, over the
    /// correspondences the core applied.
    Assess(crate::camera::CameraPose, Vec<bool>),
    /// Find the model in a raw frame with no pose given (the cold start), with the viewpoint
    /// database of this cache folder.
    Locate(image::GrayImage, PathBuf),
    /// Check the tilt of a tracked pose in its raw frame ([`crate::locate::choice::check_tilt`]).
    CheckTilt(image::GrayImage, crate::camera::CameraPose),
}

/// An attempt's answer, with the database's provenance on the attempt that loaded it.
type Located = (
    crate::locate::Attempt,
    Option<crate::locate::database::Provenance>,
);

/// What the vision thread answers, in the order of the jobs.
enum WorkerDone {
    Frame(Box<Result<FrameResult, TrackError>>),
    Assess(Result<Assessment, TrackError>),
    /// With the database's provenance, on the attempt that loaded or built it.
    Locate(
        Box<Result<crate::locate::Attempt, TrackError>>,
        Option<crate::locate::database::Provenance>,
    ),
    /// The tilt check's evidence, and the other tilt where it is the pose.
    CheckTilt(Box<Result<crate::locate::choice::TiltCheck, TrackError>>),
}

impl VisionWorker {
    /// Starts the thread and waits until its renderer is set up.
    fn start(
        camera: crate::camera::Camera,
        model_path: PathBuf,
        options: VisionOptions,
    ) -> Result<(Self, Ready), TrackError> {
        let (job_tx, job_rx) = channel::<WorkerJob>();
        let (res_tx, res_rx) = channel::<WorkerDone>();
        let (ready_tx, ready_rx) = channel::<Result<Ready, TrackError>>();
        let handle = std::thread::Builder::new()
            .name("vision".into())
            .spawn(move || vision_worker(camera, model_path, options, job_rx, res_tx, ready_tx))
            .map_err(|e| {
                TrackError::VisionThread(format!("cannot start the vision thread: {e}"))
            })?;
        let worker = VisionWorker {
            jobs: Some(job_tx),
            results: res_rx,
            handle: Some(handle),
        };
        let ready = ready_rx
            .recv()
            .map_err(|_| TrackError::VisionThread("the vision thread stopped".into()))??;
        Ok((worker, ready))
    }

    fn send_job(&self, job: WorkerJob) -> Result<(), TrackError> {
        self.jobs
            .as_ref()
            .and_then(|j| j.send(job).ok())
            .ok_or_else(|| TrackError::VisionThread("the vision thread stopped".into()))
    }

    fn send(&self, job: FrameJob) -> Result<(), TrackError> {
        self.send_job(WorkerJob::Frame(job))
    }

    fn stopped() -> TrackError {
        TrackError::VisionThread("the vision thread stopped".into())
    }

    fn out_of_order() -> TrackError {
        TrackError::VisionThread("the vision thread answered out of order".into())
    }

    fn recv(&self) -> Result<Result<FrameResult, TrackError>, TrackError> {
        match self.results.recv() {
            Ok(WorkerDone::Frame(r)) => Ok(*r),
            Ok(_) => Err(Self::out_of_order()),
            Err(_) => Err(Self::stopped()),
        }
    }

    fn try_recv(&self) -> Option<Result<FrameResult, TrackError>> {
        match self.results.try_recv().ok()? {
            WorkerDone::Frame(r) => Some(*r),
            _ => Some(Err(Self::out_of_order())),
        }
    }

    /// The next answer of any kind: waiting for it (`block`), or only if it is there.
    fn recv_any(&self, block: bool) -> Result<Option<WorkerDone>, TrackError> {
        if block {
            self.results.recv().map(Some).map_err(|_| Self::stopped())
        } else {
            match self.results.try_recv() {
                Ok(d) => Ok(Some(d)),
                Err(std::sync::mpsc::TryRecvError::Empty) => Ok(None),
                Err(std::sync::mpsc::TryRecvError::Disconnected) => Err(Self::stopped()),
            }
        }
    }

    /// One cold-start attempt on the raw frame `image`, waited for (no frame may be in
    /// flight).
    fn locate(&self, image: image::GrayImage, cache: PathBuf) -> Result<Located, TrackError> {
        self.send_locate(image, cache)?;
        self.locate_result()
    }

    /// Starts an attempt on `image` (its answer comes by [`Self::locate_result`] or
    /// [`Self::try_locate`]).
    fn send_locate(&self, image: image::GrayImage, cache: PathBuf) -> Result<(), TrackError> {
        self.send_job(WorkerJob::Locate(image, cache))
    }

    /// The answer of the attempt sent, waited for.
    fn locate_result(&self) -> Result<Located, TrackError> {
        match self.recv_any(true)? {
            Some(WorkerDone::Locate(r, from)) => r.map(|a| (a, from)),
            Some(_) => Err(Self::out_of_order()),
            None => Err(Self::stopped()),
        }
    }

    /// The answer of the attempt sent, if it is ready.
    fn try_locate(&self) -> Result<Option<Located>, TrackError> {
        match self.recv_any(false)? {
            Some(WorkerDone::Locate(r, from)) => r.map(|a| Some((a, from))),
            Some(_) => Err(Self::out_of_order()),
            None => Ok(None),
        }
    }

    /// Starts the tilt check of the tracked `pose` in its raw frame `image` (its answer comes
    /// by [`Self::tilt_result`]).
    fn send_tilt_check(
        &self,
        image: image::GrayImage,
        pose: crate::camera::CameraPose,
    ) -> Result<(), TrackError> {
        self.send_job(WorkerJob::CheckTilt(image, pose))
    }

    /// The answer of the tilt check sent: waited for (`block`), or only if it is ready
    /// (`Ok(None)` when not).
    fn tilt_result(
        &self,
        block: bool,
    ) -> Result<Option<crate::locate::choice::TiltCheck>, TrackError> {
        match self.recv_any(block)? {
            Some(WorkerDone::CheckTilt(r)) => (*r).map(Some),
            Some(_) => Err(Self::out_of_order()),
            None if block => Err(Self::stopped()),
            None => Ok(None),
        }
    }

    /// Judges the last analysed frame at `pose` over the correspondences `applied` (no frame
    /// may be in flight).
    fn assess(
        &self,
        pose: crate::camera::CameraPose,
        applied: Vec<bool>,
    ) -> Result<Assessment, TrackError> {
        self.send_job(WorkerJob::Assess(pose, applied))?;
        match self.results.recv() {
            Ok(WorkerDone::Assess(r)) => r,
            Ok(_) => Err(Self::out_of_order()),
            Err(_) => Err(Self::stopped()),
        }
    }

    /// Ends the thread (it returns once its job channel is closed) and waits for it.
    fn stop(&mut self) {
        self.jobs = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for VisionWorker {
    fn drop(&mut self) {
        self.stop();
    }
}

fn vision_worker(
    camera: crate::camera::Camera,
    model_path: PathBuf,
    options: VisionOptions,
    jobs: Receiver<WorkerJob>,
    results: Sender<WorkerDone>,
    ready: Sender<Result<Ready, TrackError>>,
) {
    let setup = || -> Result<(Vision, Ready, crate::model::Model), TrackError> {
        let model = crate::model::load(&model_path)?;
        if !model.materials.iter().any(|m| m.texture.is_some()) {
            return Err(TrackError::Untextured(model_path.clone()));
        }
        let vision = Vision::new(camera, &model, options)?;
        let ready = Ready {
            adapter: vision.adapter_summary(),
            axes: model_axes(&model),
        };
        Ok((vision, ready, model))
    };
    let (mut vision, model) = match setup() {
        Ok((v, r, m)) => {
            let _ = ready.send(Ok(r));
            (v, m)
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    // The cold start's database, loaded (or built) on the first attempt.
    let mut locator: Option<crate::locate::Locator> = None;
    let mut provenance = None;
    // Ends when the session drops its sender.
    while let Ok(job) = jobs.recv() {
        let done = match job {
            WorkerJob::Frame(job) => {
                WorkerDone::Frame(Box::new(vision.process(job).map_err(TrackError::from)))
            }
            WorkerJob::Assess(pose, applied) => {
                WorkerDone::Assess(vision.assess(&pose, &applied).map_err(TrackError::from))
            }
            WorkerJob::Locate(image, cache) => {
                let attempt = (|| {
                    if locator.is_none() {
                        let (db, from) = crate::locate::database::Database::load_or_build(
                            &model,
                            &crate::locate::database::DatabaseConfig::default(),
                            &cache,
                            &mut |_, _| {},
                        )?;
                        locator = Some(crate::locate::Locator::new(&db, Default::default()));
                        provenance = Some(from);
                    }
                    match &locator {
                        Some(l) => Ok(l.attempt(&mut vision, &image, false)?.0),
                        None => Err(TrackError::VisionThread("no cold-start database".into())),
                    }
                })();
                WorkerDone::Locate(Box::new(attempt), provenance.take())
            }
            WorkerJob::CheckTilt(image, pose) => WorkerDone::CheckTilt(Box::new(
                crate::locate::choice::check_tilt(
                    &mut vision,
                    &image,
                    &pose,
                    &crate::locate::LocateConfig::default().rule,
                )
                .map_err(TrackError::from),
            )),
        };
        if results.send(done).is_err() {
            return;
        }
    }
}

/// What the vision worker reports once set up.
struct Ready {
    adapter: String,
    axes: (Vector3<f64>, f64),
}

/// Where the overlays draw the model's axes: the centre of its bounding box, a quarter of its
/// largest extent long.
fn model_axes(model: &crate::model::Model) -> (Vector3<f64>, f64) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in model.meshes.iter().flat_map(|m| m.positions.iter()) {
        let p = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    if !(lo.iter().chain(hi.iter()).all(|v| v.is_finite())) {
        return (Vector3::zeros(), 0.1);
    }
    ((lo + hi) * 0.5, ((hi - lo).max() * 0.25).max(0.02))
}

/// A frame whose correspondences are awaited.
#[derive(Debug, Clone, Copy)]
struct Pending {
    frame_id: u32,
    trigger_us: u64,
    due: usize,
}

/// One tracking session's state.
pub struct Session<'a> {
    options: &'a TrackOptions,
    dataset: &'a Dataset,
    /// The mount the core was configured with: the dataset's, or none (the camera is the
    /// sensor) in vision-only runs.
    pub core_hand_eye: HandEye,
    /// Time stamp [ns, the input's clock] of every clock message sent, in order: the IMU
    /// samples, or the vision-only ticks.
    pub clock: Vec<u64>,
    /// Per frame id, the vision-only frame's judgement at the pose estimated with its update.
    pub assessments: BTreeMap<u32, Assessment>,
    /// What the core said.
    pub log: CoreLog,
    /// Frame results with the id the core gave them.
    pub results: Vec<(u32, FrameResult)>,
    /// Frames that could not be analysed, with why.
    pub frame_errors: Vec<(usize, String)>,
    rng: StdRng,
    /// `Hello`s sent again on a noisy line (lost, or their answer lost).
    pub resent_hellos: usize,
    /// Correspondences replaced by outliers.
    pub injected_outliers: usize,
    /// Correspondences sent.
    pub sent_correspondences: usize,
    wall: Instant,
    /// Where the overlays draw the model's axes, and their length.
    pub axes: (Vector3<f64>, f64),
    /// The cold start's attempts, in order (runs with no start pose).
    pub searches: Vec<Search>,
    /// Searches after the model was lost, one entry per loss.
    pub recoveries: Vec<Recovery>,
    /// Where the searches' viewpoint database came from (read from the cache, or built and
    /// why).
    pub database: Option<crate::locate::database::Provenance>,
    /// The tilt checks of tracked poses and their flips (vision-only runs).
    pub tilt: tilt::TiltBranch,
    /// This run's name for its configuration of the core (`Config::session`): a core that
    /// reports it in its `HelloAck` kept the state this run gave it.
    pub session_id: u32,
    /// Outages of the link or the core, and how each ended (protocol/PROTOCOL.md §8).
    pub outages: Vec<Outage>,
    /// With `--attach`: the first sample sent, the one after the core's last.
    pub attached_at: Option<usize>,
    /// With `--attach`: what the host found, and what it did.
    pub attach_note: Option<String>,
}

/// A loss of a vision-only run and its search.
#[derive(Debug, Clone)]
pub struct Recovery {
    /// Since when the frames were not tracked [s from the first frame].
    pub lost_at: f64,
    /// The attempts, in order.
    pub searches: Vec<Search>,
    /// When it ended [s]: by a pose found (the last search's), or by tracking coming back by
    /// itself; `None` while still lost at the end of the run.
    pub ended_at: Option<f64>,
}

impl Session<'_> {
    /// Records a recovery search for a loss that began at `lost_at` [s].
    fn record_recovery(&mut self, lost_at: f64, search: Search) {
        let found = search.attempt.accepted();
        let t = search.t;
        let open = self
            .recoveries
            .last_mut()
            .filter(|r| r.ended_at.is_none() && (r.lost_at - lost_at).abs() < 1e-9);
        let r = match open {
            Some(r) => r,
            None => {
                self.recoveries.push(Recovery {
                    lost_at,
                    searches: Vec::new(),
                    ended_at: None,
                });
                let Some(r) = self.recoveries.last_mut() else {
                    return;
                };
                r
            }
        };
        r.searches.push(search);
        if found {
            r.ended_at = Some(t);
        }
    }

    /// Keeps where the searches' database came from, told by the attempt that loaded it.
    fn keep_provenance(&mut self, from: Option<crate::locate::database::Provenance>) {
        if self.database.is_none() {
            self.database = from;
        }
    }

    /// Closes an open recovery: tracking came back by itself at `t_us`.
    fn end_recovery(&mut self, t_us: u64) {
        if let Some(r) = self.recoveries.last_mut().filter(|r| r.ended_at.is_none()) {
            r.ended_at = Some(t_us as f64 * 1e-6);
        }
    }
}

/// One cold-start attempt of a tracking run.
#[derive(Debug, Clone, Copy)]
pub struct Search {
    /// The frame's index in the input.
    pub index: usize,
    /// Its time [s from the first frame].
    pub t: f64,
    /// Time of the attempt's stages on the vision thread [ms]: detection, matching, RANSAC
    /// and verification, not the database's load or build (once, before the first attempt).
    pub ms: f64,
    /// What it found.
    pub attempt: crate::locate::Attempt,
}

impl Search {
    /// The search of `attempt` on frame `index` at `t_us`.
    fn new(index: usize, t_us: u64, attempt: crate::locate::Attempt) -> Self {
        let t = &attempt.times;
        Self {
            index,
            t: t_us as f64 * 1e-6,
            ms: (t.detect + t.matching + t.ransac + t.verify + t.choose) * 1e3,
            attempt,
        }
    }
}

impl Session<'_> {
    /// Micro-seconds since the first IMU sample.
    fn t_us(&self, k: usize) -> u64 {
        (self.dataset.imu[k].stamp - self.dataset.imu[0].stamp) / 1000
    }

    fn handshake(&mut self, link: &mut CoreLink) -> Result<protocol::HelloAck, TrackError> {
        let hello = HostToCore::Hello(protocol::Hello {
            version: PROTOCOL_VERSION,
        });
        link.send(&hello)?;
        let deadline = Instant::now() + self.options.timeout;
        loop {
            // Refusals of messages sent before this `Hello` (to a core that was reset, say)
            // may come first: only the version's verdict answers it.
            match self.next_or_resend(link, &hello, deadline)? {
                Incoming::Message(
                    m @ (CoreToHost::HelloAck(_)
                    | CoreToHost::Error(protocol::ErrorReport {
                        code: protocol::ErrorCode::VersionMismatch { .. },
                    })),
                ) => {
                    let ack = protocol::handshake::check_answer(&m)
                        .map_err(|e| TrackError::Core(format!("handshake: {e}")))?;
                    self.log.acks += 1;
                    return Ok(ack);
                }
                other => self.log.take(other),
            }
        }
    }

    /// The next item from the core by `deadline`. On a line with injected errors a `Hello` or
    /// its answer may be lost: then `hello` is sent again every [`RESEND_AFTER`].
    fn next_or_resend(
        &mut self,
        link: &mut CoreLink,
        hello: &HostToCore,
        deadline: Instant,
    ) -> Result<Incoming, TrackError> {
        if link.damage.is_none() {
            return link.recv(self.options.timeout);
        }
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if let Some(item) = link.recv_within(left.min(RESEND_AFTER))? {
                return Ok(item);
            }
            if left <= RESEND_AFTER {
                return link.recv(Duration::ZERO);
            }
            link.send(hello)?;
            self.resent_hellos += 1;
        }
    }

    /// Sends `Hello` and collects everything up to its answer.
    fn barrier(&mut self, link: &mut CoreLink) -> Result<(), TrackError> {
        let hello = HostToCore::Hello(protocol::Hello {
            version: PROTOCOL_VERSION,
        });
        link.send(&hello)?;
        let acks = self.log.acks;
        let deadline = Instant::now() + self.options.timeout;
        while self.log.acks == acks {
            let item = self.next_or_resend(link, &hello, deadline)?;
            self.log.take(item);
        }
        Ok(())
    }

    /// Sends a `Configure` or `Init` and collects the answers. On a line with injected errors,
    /// where it may be lost, it is sent again until a status with `reason` confirms it.
    fn send_confirmed(
        &mut self,
        link: &mut CoreLink,
        msg: &HostToCore,
        reason: protocol::StatusReason,
    ) -> Result<(), TrackError> {
        for _ in 0..CONFIRM_TRIES {
            let seen = self.log.statuses.len();
            link.send(msg)?;
            self.barrier(link)?;
            let confirmed = self.log.statuses[seen..].iter().any(|s| s.reason == reason);
            if link.damage.is_none() || confirmed || !self.log.errors.is_empty() {
                return Ok(());
            }
        }
        Err(TrackError::Core(format!(
            "no confirmation of {msg:?} in {CONFIRM_TRIES} tries over the noisy line"
        )))
    }

    fn drain(&mut self, link: &CoreLink) -> Result<(), TrackError> {
        while let Some(item) = link.try_recv()? {
            self.log.take(item);
        }
        Ok(())
    }

    fn init_message(&self) -> Result<Init, TrackError> {
        if let Some(pose) = &self.options.start.pose {
            let (s_w, q_sw) = Start::imu_pose_of_camera(pose, &self.dataset.hand_eye);
            let q = q_sw.quaternion();
            return Ok(Init {
                position: [s_w.x as f32, s_w.y as f32, s_w.z as f32],
                attitude: InitAttitude::Full([q.w as f32, q.i as f32, q.j as f32, q.k as f32]),
            });
        }
        let gt = self.dataset.groundtruth_at(self.dataset.imu[0].stamp);
        let position = match (self.options.start.position, gt) {
            (Some(p), _) => p,
            (None, Some((p, _))) => [p.x, p.y, p.z],
            (None, None) => {
                return Err(TrackError::Option(
                    "the dataset has no ground truth: give the start position (--start-position)"
                        .into(),
                ));
            }
        };
        let yaw = match (self.options.start.yaw, gt) {
            (Some(y), _) => y,
            (None, Some((_, q))) => q.euler_angles().2,
            (None, None) => {
                return Err(TrackError::Option(
                    "the dataset has no ground truth: give the start yaw (--start-yaw)".into(),
                ));
            }
        };
        Ok(Init {
            position: position.map(|v| v as f32),
            attitude: InitAttitude::GravityAndYaw(yaw as f32),
        })
    }

    /// Runs the session; `Ok(false)` when interrupted.
    fn drive(
        &mut self,
        link: &mut CoreLink,
        worker: &VisionWorker,
        search: Option<&VisionWorker>,
        end: usize,
        interrupt: &AtomicBool,
        progress: Progress,
    ) -> Result<bool, TrackError> {
        let ack = self.handshake(link)?;
        let config = core_config(
            self.dataset,
            self.options.filter,
            &self.options.tuning,
            self.session_id,
        );
        check_latency(self.options.latency, &ack.capacities, &config)?;
        let attached = if self.options.attach {
            self.attach(link, &ack)?
        } else {
            None
        };
        // A cold start initialises the core once the model is found (and then searches again
        // after a loss).
        let mut searcher = (attached.is_none() && self.options.start.is_cold(self.dataset))
            .then(cold_start::Searcher::default);
        if attached.is_none() {
            self.send_confirmed(
                link,
                &HostToCore::Configure(config),
                protocol::StatusReason::Configured,
            )?;
            if searcher.is_none() {
                let init = HostToCore::Init(self.init_message()?);
                self.send_confirmed(link, &init, protocol::StatusReason::HostRequest)?;
            }
        }
        if let Some(e) = self.log.errors.first() {
            return Err(TrackError::Core(format!(
                "refused the configuration: {}",
                e.code
            )));
        }

        let ds = self.dataset;
        let stamp0 = ds.imu[0].stamp;
        let triggers: BTreeMap<usize, usize> =
            ds.triggers().into_iter().map(|(f, k)| (k, f)).collect();
        let latency_samples = (self.options.latency * ds.imu_rate_hz).round() as usize;
        let mut pending: VecDeque<Pending> = VecDeque::new();
        let start = Instant::now();
        let mut frames_done = 0usize;
        let mut injected = outage::Injected::default();
        let mut open: Option<outage::Open> = None;
        for k in attached.unwrap_or(0)..end {
            if interrupt.load(Ordering::Relaxed) {
                if open.is_none() {
                    self.finish(link, &mut pending, worker, None, true)?;
                }
                return Ok(false);
            }
            let lock_step = self.options.pacing == Pacing::LockStep;
            if !lock_step {
                let due = start + Duration::from_nanos(ds.imu[k].stamp - stamp0);
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
            }
            let t_us = self.t_us(k);
            let refusals = self.log.errors.len();
            // Faults are injected while the core is there; while it is not, the sample waits
            // for an attempt to reach it.
            let ready = match open.as_mut() {
                None => self.inject_faults(link, &mut injected, t_us).map(|()| true),
                Some(o) => match self.attempt_resume(link, o, &injected, k, &triggers)? {
                    outage::Attempt::Waiting => Ok(false),
                    outage::Attempt::Resumed => {
                        open = None;
                        Ok(true)
                    }
                },
            };
            let step = ready.and_then(|ready| {
                if !ready {
                    return Ok(());
                }
                self.sample_step(
                    link,
                    worker,
                    search,
                    searcher.as_mut(),
                    &mut pending,
                    &mut frames_done,
                    (k, lock_step, triggers.get(&k).copied()),
                    latency_samples,
                )
            });
            // A link that failed, or a core that forgot us, is an outage: the frames in
            // flight are dropped, and the host tries to reach the core again.
            let cause = match step {
                Ok(()) if open.is_none() && self.core_forgot(refusals) => Some(
                    "the core answered as one not configured since it started: it was reset"
                        .to_string(),
                ),
                Ok(()) => None,
                Err(TrackError::Link(e)) if open.is_none() => Some(e),
                Err(e) => return Err(e),
            };
            if let Some(cause) = cause {
                open = Some(self.begin_outage(cause, t_us, &mut injected, &mut pending, worker)?);
            }
            if k % 50 == 0 || k + 1 == end {
                progress(k + 1, end, frames_done, self.log.mode());
            }
        }
        // A core not reached again before the end has nothing left to collect.
        if open.is_none() {
            let searching = searcher.as_mut().zip(search);
            self.finish(link, &mut pending, worker, searching, false)?;
        }
        self.close_outages();
        progress(end, end, self.results.len(), self.log.mode());
        // An outage that the input outlasted is a failed run, as one that outlasts the retry
        // window is: the samples after it were never tracked.
        if let Some(o) = open {
            let outage = &self.outages[o.index];
            return Err(TrackError::Link(format!(
                "link {}: the core was not reached again before the input ended, {:.2} s after \
                 the outage began ({} attempts): {}",
                link.name(),
                output::seconds(self.t_us(end.saturating_sub(1))) - outage.noticed_s,
                outage.attempts,
                outage.cause
            )));
        }
        Ok(true)
    }

    /// Sends the IMU sample `k`, with the camera's trigger if it fired there.
    fn send_sample(
        &mut self,
        link: &mut CoreLink,
        k: usize,
        trigger: bool,
    ) -> Result<(), TrackError> {
        let row = &self.dataset.imu[k];
        link.send(&HostToCore::Imu(protocol::ImuSample {
            t_us: self.t_us(k),
            gyro: [row.gyro.x as f32, row.gyro.y as f32, row.gyro.z as f32],
            accel: [row.accel.x as f32, row.accel.y as f32, row.accel.z as f32],
            trigger,
        }))?;
        self.clock.push(row.stamp);
        Ok(())
    }

    /// One IMU sample of [`Self::drive`]: the frames due, the search, the sample, and at a
    /// trigger the frame's prediction and its analysis. `at` is the sample's index, whether
    /// the run is in lock-step, and the frame triggered at it.
    #[allow(clippy::too_many_arguments)]
    fn sample_step(
        &mut self,
        link: &mut CoreLink,
        worker: &VisionWorker,
        search: Option<&VisionWorker>,
        mut searcher: Option<&mut cold_start::Searcher>,
        pending: &mut VecDeque<Pending>,
        frames_done: &mut usize,
        at: (usize, bool, Option<usize>),
        latency_samples: usize,
    ) -> Result<(), TrackError> {
        let (k, lock_step, frame) = at;
        let ds = self.dataset;
        if lock_step {
            while pending.front().is_some_and(|p| p.due <= k) {
                let p = pending.pop_front().unwrap_or_else(|| unreachable!());
                let r = worker.recv()?;
                self.deliver(link, p, r)?;
                *frames_done += 1;
            }
        } else {
            while !pending.is_empty() {
                match worker.try_recv() {
                    Some(r) => {
                        let p = pending.pop_front().unwrap_or_else(|| unreachable!());
                        self.deliver(link, p, r)?;
                        *frames_done += 1;
                    }
                    None => break,
                }
            }
        }
        if let (Some(s), Some(w)) = (searcher.as_deref_mut(), search) {
            self.poll_search(link, s, w, Some(k).filter(|_| lock_step), self.t_us(k))?;
        }
        let t_us = self.t_us(k);
        self.send_sample(link, k, frame.is_some())?;
        let Some(f) = frame else {
            return self.drain(link);
        };
        if lock_step {
            self.barrier(link)?;
        } else {
            // Real time: the prediction is usually back within a millisecond.
            let deadline = Instant::now() + Duration::from_millis(20);
            while !self.log.predictions.contains_key(&t_us) && Instant::now() < deadline {
                if let Ok(item) = link.recv(Duration::from_millis(2)) {
                    self.log.take(item);
                }
            }
        }
        let blind = self.options.faults.blind_at(output::seconds(t_us));
        let cam = &ds.camera.camera;
        let noise = || self.options.faults.noise_frame(cam.width, cam.height, f);
        let step = searcher
            .as_deref_mut()
            .map_or(cold_start::AtTrigger::Wait, |s| {
                s.at_trigger(&self.log.statuses, t_us)
            });
        if step == cold_start::AtTrigger::Tracking {
            self.end_recovery(t_us);
        }
        if let (Some(s), Some(w)) = (searcher, search)
            && let cold_start::AtTrigger::Attempt(lost_at) = step
        {
            let path = &ds.frames[f].path;
            let image = if blind {
                Ok(noise())
            } else {
                image::open(path).map(|i| i.into_luma8())
            };
            match image {
                Ok(image) => {
                    w.send_locate(image, self.options.cache.clone())?;
                    s.sent(cold_start::LocateJob {
                        index: f,
                        t_us,
                        due: k + latency_samples.max(1),
                        lost_at,
                    });
                }
                // An unreadable frame is no attempt, as it is no analysis: reported, and the
                // next frame is tried.
                Err(e) => self.frame_errors.push((
                    self.results.len(),
                    format!("{}: {e} (no search on it)", path.display()),
                )),
            }
        }
        if let Some(p) = self.log.predictions.get(&t_us).copied() {
            let every = self.options.overlay_every;
            let omega_c = self.log.states.last().filter(|s| s.t_us == t_us).map(|s| {
                let w = Vector3::new(
                    s.omega_s[0] as f64,
                    s.omega_s[1] as f64,
                    s.omega_s[2] as f64,
                );
                ds.hand_eye.q_cs * w
            });
            let job = FrameJob {
                index: f,
                stamp: ds.frames[f].stamp,
                image: if blind {
                    FrameImage::Decoded(noise())
                } else {
                    FrameImage::File(ds.frames[f].path.clone())
                },
                prediction: p,
                keep_image: every > 0 && f % every == 0,
                omega_c,
            };
            worker.send(job)?;
            pending.push_back(Pending {
                frame_id: p.frame_id,
                trigger_us: t_us,
                due: k + latency_samples.max(1),
            });
        }
        Ok(())
    }

    /// With `--attach`: a core that runs our model under a session, and is still tracking,
    /// is taken over as it is. Returns the first sample to send (the one after the core's
    /// last), or `None` when there is nothing to take over and the core is configured anew.
    fn attach(
        &mut self,
        link: &mut CoreLink,
        ack: &protocol::HelloAck,
    ) -> Result<Option<usize>, TrackError> {
        if ack.session == 0 || ack.model != Some(self.options.filter) {
            self.attach_note = Some(format!(
                "the core ran no {:?} session (model {:?}, session {}): configured anew",
                self.options.filter, ack.model, ack.session
            ));
            return Ok(None);
        }
        let Some((mode, last_us)) = self.query(link)? else {
            return Err(TrackError::Core(
                "--attach: the core did not answer the query for its state".into(),
            ));
        };
        if !matches!(
            mode,
            protocol::Mode::Tracking | protocol::Mode::DeadReckoning
        ) {
            self.attach_note = Some(format!(
                "the core was {mode:?}, not tracking: configured and initialised anew"
            ));
            return Ok(None);
        }
        let ds = self.dataset;
        let next = (0..ds.imu.len()).find(|&k| self.t_us(k) > last_us);
        match next {
            Some(k) if self.t_us(k) - last_us <= outage::MAX_BACKLOG_US => {
                self.session_id = ack.session;
                self.attached_at = Some(k);
                self.attach_note = Some(format!(
                    "attached to session {:#010x}, {mode:?} at t = {:.3} s: went on from there",
                    ack.session,
                    last_us as f64 * 1e-6
                ));
                Ok(Some(k))
            }
            _ => Err(TrackError::Core(format!(
                "--attach: the core's last sample is at t = {:.3} s, which is not in this dataset's {:.3} s: is it the dataset the core was tracking?",
                last_us as f64 * 1e-6,
                self.t_us(ds.imu.len() - 1) as f64 * 1e-6
            ))),
        }
    }

    /// Delivers the frames still in flight, applies a search still running, and collects
    /// the last answers.
    fn finish(
        &mut self,
        link: &mut CoreLink,
        pending: &mut VecDeque<Pending>,
        worker: &VisionWorker,
        searching: Option<(&mut cold_start::Searcher, &VisionWorker)>,
        interrupted: bool,
    ) -> Result<(), TrackError> {
        while let Some(p) = pending.pop_front() {
            let r = worker.recv()?;
            if interrupted {
                // Record the analysis; the core has no samples left to apply it to.
                if let Ok(r) = r {
                    self.results.push((p.frame_id, r));
                }
            } else {
                self.deliver(link, p, r)?;
            }
        }
        if let Some((s, w)) = searching {
            let now_us = self.clock.len().checked_sub(1).map_or(0, |k| self.t_us(k));
            self.poll_search(link, s, w, Some(usize::MAX), now_us)?;
        }
        self.barrier(link)
    }

    /// Sends a frame's correspondences (after injecting faults, if asked).
    fn deliver(
        &mut self,
        link: &mut CoreLink,
        p: Pending,
        result: Result<FrameResult, TrackError>,
    ) -> Result<(), TrackError> {
        let result = match result {
            Ok(r) => r,
            // A frame whose image cannot be used is skipped (the core dead-reckons), and
            // reported; anything else stops the run.
            Err(
                e @ TrackError::Vision(
                    ::vision::VisionError::Image { .. } | ::vision::VisionError::ImageSize { .. },
                ),
            ) => {
                self.frame_errors.push((self.results.len(), e.to_string()));
                return Ok(());
            }
            Err(e) => return Err(e),
        };
        let t = output::seconds(p.trigger_us);
        let f = &self.options.faults;
        let corrupt = f
            .corrupt_from
            .is_some_and(|from| t >= from && t < from + f.corrupt_seconds);
        let mut items: Vec<Correspondence> = result.correspondences.clone();
        for c in &mut items {
            if corrupt
                || (f.outlier_fraction > 0.0 && self.rng.random::<f64>() < f.outlier_fraction)
            {
                self.injected_outliers += 1;
                outlier(c, &mut self.rng);
            }
        }
        if !items.is_empty() {
            let core_id = self.log.core_frame_id(p.frame_id);
            let parts = protocol::Correspondences::split(core_id, p.trigger_us, &items)
                .map_err(|e| TrackError::Core(format!("frame {}: {e:?}", p.frame_id)))?;
            for part in parts {
                link.send(&HostToCore::Correspondences(part))?;
            }
            self.sent_correspondences += items.len();
        }
        self.results.push((p.frame_id, result));
        Ok(())
    }

    /// Seconds since the session started.
    pub fn elapsed(&self) -> f64 {
        self.wall.elapsed().as_secs_f64()
    }
}

impl Faults {
    /// Whether the frame at `t` [s] is replaced by noise.
    pub fn blind_at(&self, t: f64) -> bool {
        self.blind_from
            .is_some_and(|from| t >= from && t < from + self.blind_seconds)
    }

    /// The noise that replaces frame `index` of a blind stretch (uniform grey levels, the same
    /// in every run of a seed).
    pub fn noise_frame(&self, width: u32, height: u32, index: usize) -> image::GrayImage {
        let mut rng = StdRng::seed_from_u64(self.seed ^ (index as u64).wrapping_mul(0x9E37_79B9));
        image::GrayImage::from_fn(width, height, |_, _| image::Luma([rng.random::<u8>()]))
    }
}

/// Replaces a correspondence's model point by one 0.1-0.5 m away in a random direction.
fn outlier(c: &mut Correspondence, rng: &mut StdRng) {
    let dir = Vector3::new(
        rng.random::<f64>() - 0.5,
        rng.random::<f64>() - 0.5,
        rng.random::<f64>() - 0.5,
    )
    .try_normalize(1e-9)
    .unwrap_or_else(Vector3::x);
    let shift = dir * (0.1 + 0.4 * rng.random::<f64>());
    for (m, s) in c.m_w.iter_mut().zip(shift.iter()) {
        *m += *s as f32;
    }
}

/// IMU pose `(s_w, q_ws)` of a state report.
pub fn state_pose(s: &StateReport) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let q = s.q_sw.map(f64::from);
    let q_sw = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    (Vector3::from(s.s_w.map(f64::from)), q_sw.inverse())
}

/// Camera pose `(c_w, q_wc)` of a state report (eq. 5-6: `c_w = s_w + R(q_sw)ᵀ c_s`).
pub fn camera_of_state(
    s: &StateReport,
    hand_eye: &crate::dataset::HandEye,
) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let (s_w, q_ws) = state_pose(s);
    let (c_w, q_cw) = hand_eye.camera_pose(&s_w, &q_ws);
    (c_w, q_cw.inverse())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraPose;
    use crate::dataset::HandEye;

    #[test]
    fn a_start_pose_maps_to_the_imu_pose_whose_camera_it_is() {
        let hand_eye = HandEye {
            q_cs: UnitQuaternion::from_euler_angles(-1.5, 0.1, 0.2),
            c_s: Vector3::new(0.03, -0.01, 0.05),
        };
        let pose = CameraPose {
            q_cw: UnitQuaternion::from_euler_angles(0.4, -0.7, 2.1),
            c_w: Vector3::new(0.5, 1.0, -0.3),
        };
        let (s_w, q_sw) = Start::imu_pose_of_camera(&pose, &hand_eye);
        let (c_w, q_cw) = hand_eye.camera_pose(&s_w, &q_sw.inverse());
        assert!((c_w - pose.c_w).norm() < 1e-12);
        assert!(q_cw.angle_to(&pose.q_cw) < 1e-12);
    }
}
