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
pub mod config;
mod faults;
mod frame_row;
mod on_core;
pub mod output;
pub mod overlay;
pub mod plot;
pub use ::vision::analysis as vision;
mod vision_only;
pub use tracker::tilt;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nalgebra::{UnitQuaternion, Vector3};
use protocol::{ModelKind, StateReport};
use tracker::{Finished, ImuSample, Tracker, TrackerBuilder, TrackerConfig, TrackerError};

pub use self::assess::{Assessment, Contrast, TrackedRule};
pub use self::config::{CoreTuning, check_latency, core_config};
pub use self::faults::{Faults, FaultyLink};
pub use self::frame_row::FrameRow;
pub use self::output::Summary;
pub use self::vision::{FrameImage, FrameJob, FrameResult, Vision, VisionOptions};
pub use core_link::{CoreLink, LinkSpec};
pub use tracker::Incoming;
pub use tracker::log::CoreLog;
pub use tracker::record::Record;
pub use tracker::record::{Outage, OutageKind};
pub use tracker::search::{Recovery, Search};

use crate::camera::{CalibError, CameraError};
use crate::features::ImageError;
use crate::model::ModelError;
use crate::out_folder::OutFolder;
use crate::render::RenderError;
use frames::euroc::{Dataset, DatasetError};

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
        "{0}: the model has no textured material (an MTL without map_Kd, or a glTF material without a base colour texture): the texture modality registers the model's texture, so an untextured model gives it nothing to follow; track it by its contour (--modality contour, or auto)"
    )]
    Untextured(PathBuf),
    /// The model has no texture, and no start pose was given: the cold start finds a model by
    /// its texture.
    #[error(
        "{0}: the model has no textured material, and no start pose was given: the cold start finds a model by its texture, so an untextured model is tracked by its contour from a start pose (--start-pose, --start-position/--start-yaw, or the dataset's ground truth)"
    )]
    NeedsStartPose(PathBuf),
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
    Frames(#[from] frames::FrameError),
    /// Ctrl-C before any IMU sample was sent: nothing was tracked, nothing written.
    #[error("interrupted before tracking began: nothing written")]
    Interrupted,
    /// The cold start never found the model.
    #[error(
        "cold start: the model was not found in {} (is it in view, and is this its model?); `host-vision locate` on one frame shows the figures",
        if *attempts == 1 { "the one frame tried".to_string() } else { format!("any of the {attempts} frames tried") }
    )]
    NotFound {
        /// Frames tried.
        attempts: usize,
    },
    /// A bad option (named by its command-line flag).
    #[error("{0}")]
    Option(String),
    /// The run failed part-way: what was tracked before the failure is written.
    #[error(
        "{error} (what was tracked before it is written in {}: the trajectories, frames.csv, and summary.json with this error)",
        out.display()
    )]
    Stopped {
        /// Why it stopped.
        error: Box<TrackError>,
        /// The output folder.
        out: PathBuf,
        /// What was written, and the summary of what was tracked.
        written: Box<(Summary, Vec<PathBuf>)>,
    },
    /// The tracker: the link to the core and the core (a run that recovers from faults,
    /// protocol/PROTOCOL.md §8, reconnects; others stop with it), the vision threads, a
    /// frame's analysis, the cold start's database, a refused input.
    #[error(transparent)]
    Tracker(TrackerError),
}

impl From<TrackerError> for TrackError {
    fn from(e: TrackerError) -> Self {
        match e {
            TrackerError::Config(m) => TrackError::Option(m),
            TrackerError::LatencyTooLong {
                latency_s,
                limit_s,
                imu_rate_hz,
                camera_rate_hz,
                frames,
                samples,
            } => TrackError::Option(format!(
                "--latency {latency_s} s is longer than the core can wait for a frame's \
                 correspondences: {limit_s:.3} s at {imu_rate_hz} Hz IMU and {camera_rate_hz} Hz \
                 camera ({frames} frames, {samples} IMU samples kept)"
            )),
            other => TrackError::Tracker(other),
        }
    }
}

/// The largest start position a run takes, per axis [m]: the core's bound.
pub const MAX_START_POSITION_M: f64 = protocol::validate::MAX_POSITION_M as f64;
/// The largest start yaw a run takes [deg] (a hundred turns).
pub const MAX_START_YAW_DEG: f64 = 36_000.0;

/// How the input is paced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Pacing {
    /// As fast as the link takes it; correspondences after a fixed latency in IMU samples;
    /// without an IMU, every frame in order.
    LockStep,
    /// By the clock; correspondences as soon as they are ready; without an IMU, the frames
    /// at their own rate, the newest taken when the tracker is ready and the rest dropped.
    RealTime,
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

impl TrackOptions {
    /// These options with the modality `model` (loaded from `path`) is tracked by: the one
    /// asked for, or what the model gives. Refuses the texture modality for a model without
    /// texture, and the cold start for it (which finds models by their texture).
    fn with_modality_for(
        &self,
        model: &crate::model::Model,
        path: &std::path::Path,
        dataset: &Dataset,
    ) -> Result<TrackOptions, TrackError> {
        let textured = ::vision::is_textured(model);
        let modality = self
            .modality
            .unwrap_or_else(|| ::vision::Modality::for_model(model));
        if modality.texture() && !textured {
            return Err(TrackError::Untextured(path.to_path_buf()));
        }
        if !textured && self.start.is_cold(dataset) {
            return Err(TrackError::NeedsStartPose(path.to_path_buf()));
        }
        let mut options = self.clone();
        options.vision.modality = modality;
        Ok(options)
    }
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
    /// The core samples its own IMU and fires the camera (protocol/PROTOCOL.md §7): the
    /// dataset's IMU readings go through a simulated ICM-42688-P and the board's sample path
    /// on the in-process board, and the frames are paired with the core's triggers.
    pub imu_on_core: bool,
    /// Frames from a video, camera or image folder instead of the dataset's (vision-only;
    /// `dataset` is then that input, for reports).
    pub frames: Option<frames::FrameInput>,
    /// The camera of `frames` (its intrinsics), or instead of the dataset's.
    pub camera: Option<crate::camera::Camera>,
    /// Stop after this many frames (vision-only; a live camera never ends by itself).
    pub max_frames: Option<usize>,
    /// Folder of the cold start's viewpoint database ([`crate::locate`]): a vision-only run
    /// with no start pose and no ground truth finds the model itself, frame by frame, until a
    /// pose is verified.
    pub cache: PathBuf,
    /// Which measurements frames make; `None`: what the model gives (its texture where it has
    /// one, its contour where it has none, [`vision::Modality::for_model`]).
    pub modality: Option<::vision::Modality>,
}

impl TrackOptions {
    /// Defaults for a dataset and output folder: simulated board, acc model, lock-step.
    pub fn new(dataset: PathBuf, out: PathBuf) -> Self {
        Self {
            dataset,
            model: None,
            out,
            link: LinkSpec::Sim(tracker::Precision::F32),
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
            imu_on_core: false,
            frames: None,
            camera: None,
            max_frames: None,
            cache: crate::locate::database::default_cache_dir(),
            modality: None,
        }
    }

    /// Whether this run is live: paced by the clock (`--pacing real-time`), or its frames
    /// come from a camera device, at the camera's pace.
    pub fn live(&self) -> bool {
        self.pacing == Pacing::RealTime || matches!(&self.frames, Some(f) if f.is_live())
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
        if self.vision_only() && self.imu_on_core {
            return bad(
                "--imu-on-core: the core's own IMU is for the inertial models (--filter gyro, gravity or acc), not the vision-only one".into(),
            );
        }
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
            Some(d) if let Some(why) = config::duration_refusal(&self.tuning, d) => {
                return bad(why);
            }
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
        self.check_start(dataset)?;
        Ok(end)
    }

    /// The start options of a run with an IMU: in range, and not given twice.
    fn check_start(&self, dataset: &Dataset) -> Result<(), TrackError> {
        let bad = |m: String| Err(TrackError::Option(m));
        // The core takes single floats: beyond these a position or angle loses its precision
        // (an ulp of 8 mm at 100 km, of 0.03 mrad at a hundred turns), and far beyond, its value.
        if let Some(p) = self.start.position
            && !p
                .iter()
                .all(|c| c.is_finite() && c.abs() <= MAX_START_POSITION_M)
        {
            return bad(format!(
                "--start-position must be three finite numbers within ±{MAX_START_POSITION_M} m, got {},{},{}",
                p[0], p[1], p[2]
            ));
        }
        if let Some(y) = self.start.yaw
            && !(y.is_finite() && y.to_degrees().abs() <= MAX_START_YAW_DEG)
        {
            return bad(format!(
                "--start-yaw must be a finite angle within ±{MAX_START_YAW_DEG} degrees, got {}",
                y.to_degrees()
            ));
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
        Ok(())
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
        self.check_faults()?;
        if let Some(a) = self.tuning.accel_noise {
            positive("--accel-meas-noise", a, "m/s²")?;
        }
        Ok(())
    }

    /// The injected faults against the link and the model: times at or after the start, a
    /// core the host can reset, a line it can garble, and a run that can recover.
    fn check_faults(&self) -> Result<(), TrackError> {
        let bad = |m: String| Err(TrackError::Option(m));
        let f = &self.faults;
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
        if let Some(rate) = f.line_errors {
            if !matches!(self.link, LinkSpec::Sim(_)) {
                return bad(format!(
                    "--line-errors garbles the simulated board's line: use --link sim, not {}",
                    self.link
                ));
            }
            if !(rate.is_finite() && (0.0..=1.0).contains(&rate)) {
                return bad(format!(
                    "--line-errors is a probability per byte in [0, 1], got {rate}"
                ));
            }
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

/// The frames of a vision-only run: a video, camera or image folder, or the dataset's own
/// cam0 (its IMU withheld, or absent); `None` with an IMU (the dataset's frames go with it).
fn open_frames(
    options: &TrackOptions,
    dataset: &Dataset,
) -> Result<Option<frames::FrameSource>, TrackError> {
    let video = frames::VideoOptions::default();
    Ok(match (&options.frames, options.vision_only()) {
        (Some(input), _) => Some(input.open(&video)?),
        (None, true) => Some(
            frames::FrameInput::Images {
                dir: dataset.root.join("mav0/cam0"),
                fps: None,
            }
            .open(&video)?,
        ),
        (None, false) => None,
    })
}

/// The link to the core of `--link`, with the faults' line noise and outliers.
fn open_link(options: &TrackOptions) -> Result<FaultyLink, TrackError> {
    let noise = options
        .faults
        .line_errors
        .map(|rate| (rate, options.faults.seed));
    let spec = options
        .link
        .resolve_qemu(config::find_firmware_image)
        .map_err(|e| TrackError::Tracker(TrackerError::Core(e)))?;
    Ok(FaultyLink::new(
        CoreLink::open_noisy(&spec, noise)?,
        &options.faults,
    ))
}

/// Tracks a dataset. `interrupt` stops it early (Ctrl-C); what was tracked is still written.
pub fn run(
    options: &TrackOptions,
    interrupt: Arc<AtomicBool>,
    progress: Progress,
) -> Result<TrackRun, TrackError> {
    let dataset = vision_only::open_dataset(options)?;
    let end = options.check(&dataset)?;
    let model_path = model_path(options, &dataset)?;
    // Opened before anything is started: a bad input fails first.
    let mut frames = open_frames(options, &dataset)?;
    let mut out = OutFolder::prepare(
        &options.out,
        &output::OUTPUTS.map(String::from),
        Some(&dataset.root),
        options.overwrite,
    )?;

    // The link first: it fails most often, and fails before the renderer is made.
    let link = open_link(options)?;
    let model = crate::model::load(&model_path)?;
    let options = &options.with_modality_for(&model, &model_path, &dataset)?;
    let ran = match frames.take() {
        Some(source) => vision_only::track_frames(
            options, &dataset, link, &model, source, &interrupt, progress,
        )?,
        None if options.imu_on_core => {
            on_core::track(options, &dataset, link, &model, end, &interrupt, progress)?
        }
        None => track_imu(options, &dataset, link, &model, end, &interrupt, progress)?,
    };
    let Ran {
        record,
        host,
        adapter,
        outcome,
        link,
    } = ran;
    let damage = link.damage.clone();
    let closed = link.close().map_err(TrackError::from);
    if record.clock.is_empty() {
        // Nothing was tracked (the handshake or the configuration failed): nothing to write.
        return Err(match (outcome, closed) {
            (Err(e), _) | (Ok(_), Err(e)) => e,
            (Ok(true), Ok(_)) if !record.searches.is_empty() => TrackError::NotFound {
                attempts: record.searches.len(),
            },
            (Ok(_), Ok(_)) => TrackError::Interrupted,
        });
    }
    // An inertial cold start that never found the model streamed its IMU to a core that was
    // never initialised: nothing was tracked either.
    let found = record.searches.iter().any(|s| s.attempt.accepted());
    if !options.vision_only() && !record.searches.is_empty() && !found && outcome.is_ok() {
        if let Ok(false) = outcome {
            return Err(TrackError::Interrupted);
        }
        return Err(TrackError::NotFound {
            attempts: record.searches.len(),
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
    let (frames, summary, mut written) = output::write_all(
        &dataset,
        options,
        output::Seen {
            record: &record,
            host: &host,
            adapter: &adapter,
        },
        output::LinkEnd {
            board: board.as_ref(),
            noise: damage.as_ref(),
        },
        stopped_early,
        outcome.as_ref().err().map(|e| e.to_string()),
    )?;
    if options.imu_on_core {
        written.push(on_core::write_core_imu(&options.out, &record)?);
    }
    if let Err(error) = outcome {
        return Err(TrackError::Stopped {
            error: Box::new(error),
            out: options.out.clone(),
            written: Box::new((summary, written)),
        });
    }
    Ok(TrackRun {
        log: record.log,
        frames,
        summary,
        written,
    })
}

/// The model file: `--model`, or the dataset's.
fn model_path(options: &TrackOptions, dataset: &Dataset) -> Result<PathBuf, TrackError> {
    options
        .model
        .clone()
        .or_else(|| dataset.model.clone())
        .ok_or_else(|| {
            TrackError::Option(if options.frames.is_some() {
                format!(
                    "{}: give the object's model with --model (OBJ or glTF; with a texture it is tracked by its texture, without one by its contour)",
                    dataset.root.display()
                )
            } else {
                format!(
                    "{}: no model/scene.obj in the dataset; give the model with --model",
                    dataset.root.display()
                )
            })
        })
}

/// What a run leaves to write.
struct Ran {
    record: Record,
    host: HostRecord,
    adapter: String,
    /// `Ok(false)` when interrupted.
    outcome: Result<bool, TrackError>,
    link: CoreLink,
}

impl Ran {
    /// What the tracker left, with the loop's `record` of its events and `outcome`: an error
    /// of the loop before the tracker's own.
    fn of(
        finished: Finished<FaultyLink>,
        mut record: Record,
        outcome: Result<bool, TrackError>,
    ) -> Self {
        record.observe_all(&finished.events);
        let outcome = match (outcome, finished.result) {
            (Err(e), _) => Err(e),
            (Ok(completed), Ok(())) => Ok(completed),
            (Ok(_), Err(e)) => Err(e.into()),
        };
        Ran {
            host: HostRecord {
                injected_outliers: finished.core.injected,
            },
            record,
            adapter: finished.adapter,
            outcome,
            link: finished.core.into_inner(),
        }
    }
}

/// Tracks a dataset with its IMU (the inertial models): every sample pushed into the
/// library's [`Tracker`], each frame just before the sample that triggered it, with the
/// application's faults put in on the way.
fn track_imu(
    options: &TrackOptions,
    dataset: &Dataset,
    link: FaultyLink,
    model: &crate::model::Model,
    end: usize,
    interrupt: &AtomicBool,
    progress: Progress,
) -> Result<Ran, TrackError> {
    let mut tracker = inertial_tracker(options, dataset, model)?.build_with(link)?;
    let mut record = Record::default();
    let stamp0 = dataset.imu[0].stamp;
    let triggers: BTreeMap<usize, usize> = dataset
        .triggers()
        .into_iter()
        .map(|(f, k)| (k, f))
        .collect();
    let cam = &dataset.camera.camera;
    let start = Instant::now();
    let mut injector = faults::Injector::default();
    let mut outcome = Ok(true);
    for k in 0..end {
        if interrupt.load(Ordering::Relaxed) {
            outcome = Ok(false);
            break;
        }
        let row = &dataset.imu[k];
        if options.pacing == Pacing::RealTime {
            // Until the sample is due, the core's poses come out as it sends them.
            tracker.wait_until(start + Duration::from_nanos(row.stamp - stamp0));
        }
        let t_us = (row.stamp - stamp0) / 1000;
        let step = injector
            .inject(&options.faults, &mut tracker, t_us)
            .and_then(|()| match triggers.get(&k) {
                Some(&f) => {
                    let frame = &dataset.frames[f];
                    let image = if options.faults.blind_at(output::seconds(t_us)) {
                        FrameImage::Decoded(options.faults.noise_frame(cam.width, cam.height, f))
                    } else {
                        FrameImage::File(frame.path.clone())
                    };
                    tracker.push_frame(tracker::Frame {
                        index: f,
                        t_ns: frame.stamp as i64,
                        image,
                        captured: None,
                    })
                }
                None => Ok(()),
            })
            .and_then(|()| {
                tracker.push_imu(ImuSample {
                    t_ns: row.stamp,
                    gyro: row.gyro.into(),
                    accel: row.accel.into(),
                })
            });
        if let Err(e) = step {
            outcome = Err(e.into());
            break;
        }
        sample_progress(&mut tracker, &mut record, k, end, progress);
    }
    Ok(wind_up(tracker, record, outcome, end, progress))
}

/// The tracker's events since into the run's `record`, and the progress bar after sample `k`
/// of `end` (every 50th, and the last).
fn sample_progress(
    tracker: &mut Tracker<FaultyLink>,
    record: &mut Record,
    k: usize,
    end: usize,
    progress: Progress,
) {
    for e in tracker.poll() {
        record.observe(&e);
    }
    if k.is_multiple_of(50) || k + 1 == end {
        progress(k + 1, end, record.results.len(), record.log.mode());
    }
}

/// The end of a run with an IMU: finished, or abandoned where interrupted (`Ok(false)`).
fn wind_up(
    tracker: Tracker<FaultyLink>,
    record: Record,
    outcome: Result<bool, TrackError>,
    end: usize,
    progress: Progress,
) -> Ran {
    let finished = match outcome {
        Ok(false) => tracker.abandon(),
        _ => tracker.finish(),
    };
    let ran = Ran::of(finished, record, outcome);
    let r = &ran.record;
    progress(end, end, r.results.len(), r.log.mode());
    ran
}

/// The tracker of a run with an IMU, to be built on the run's link.
fn inertial_tracker(
    options: &TrackOptions,
    dataset: &Dataset,
    model: &crate::model::Model,
) -> Result<TrackerBuilder, TrackError> {
    let rig = dataset.rig();
    let start = if options.start.is_cold(dataset) {
        tracker::Start::Locate
    } else {
        inertial_start(options, dataset)?
    };
    let attach = options.attach;
    Ok(TrackerBuilder::new(dataset.camera.camera, model.clone())
        .frame_rate_hz(rig.camera_rate_hz.unwrap_or(20.0))
        .imu(options.filter, rig)
        .start(start)
        .latency_s(options.latency)
        .live(options.pacing == Pacing::RealTime)
        .cache(options.cache.clone())
        .configure(command_settings(options))
        .configure(move |c| c.attach = attach))
}

/// The command's settings of a tracker that the builder has no method of its own for: the
/// image analysis, the core's tuning, the wait for the core, the overlays' frames.
fn command_settings(options: &TrackOptions) -> impl Fn(&mut TrackerConfig) + Send + Sync + 'static {
    let (vision, tuning, timeout) = (options.vision, options.tuning, options.timeout);
    let overlay_every = options.overlay_every;
    move |c| {
        c.vision = vision;
        c.tuning = tuning;
        c.timeout = timeout;
        c.keep_image_every = overlay_every;
        // The outputs are written from the details' record.
        c.details = true;
    }
}

/// Where a run with an IMU starts: the given camera pose, or the IMU's position and yaw as
/// given or from the ground truth at the first sample (roll and pitch from gravity).
fn inertial_start(options: &TrackOptions, dataset: &Dataset) -> Result<tracker::Start, TrackError> {
    if let Some(pose) = options.start.pose {
        return Ok(tracker::Start::Camera(pose));
    }
    let gt = dataset.groundtruth_at(dataset.imu[0].stamp);
    let position = match (options.start.position, gt) {
        (Some(p), _) => p,
        (None, Some((p, _))) => [p.x, p.y, p.z],
        (None, None) => {
            return Err(TrackError::Option(
                "the dataset has no ground truth: give the start position (--start-position)"
                    .into(),
            ));
        }
    };
    let yaw = match (options.start.yaw, gt) {
        (Some(y), _) => y,
        (None, Some((_, q))) => q.euler_angles().2,
        (None, None) => {
            return Err(TrackError::Option(
                "the dataset has no ground truth: give the start yaw (--start-yaw)".into(),
            ));
        }
    };
    Ok(tracker::Start::GravityAndYaw { position, yaw })
}

/// What the application adds to the tracker's [`Record`]: the faults it injected.
#[derive(Debug, Default)]
pub struct HostRecord {
    /// Correspondences replaced by outliers.
    pub injected_outliers: usize,
}

pub use tracker::rig::state_pose;

/// Camera pose `(c_w, q_wc)` of a state report (eq. 5-6: `c_w = s_w + R(q_sw)ᵀ c_s`).
pub fn camera_of_state(
    s: &StateReport,
    hand_eye: &frames::euroc::HandEye,
) -> (Vector3<f64>, UnitQuaternion<f64>) {
    hand_eye.camera_of_state(s)
}
