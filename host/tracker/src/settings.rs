//! How a [`crate::Tracker`] runs: the model, the sensors, where it starts, and the frames
//! it takes ([`Frame`]).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use camera::{Camera, CameraPose};
use image::GrayImage;
use protocol::ModelKind;
use vision::{FrameImage, VisionOptions};

use crate::config::{CoreTuning, OBJECT_IN_HAND_ACCEL, OBJECT_IN_HAND_ANGULAR_NOISE};
use crate::error::TrackerError;
use crate::rig::{HandEye, Rig};

/// One camera frame pushed into the tracker.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Its number in its input, from 0 (for reports).
    pub index: usize,
    /// Its time stamp [ns] on the camera's clock.
    pub t_ns: i64,
    /// Its grey pixels, of the camera's size, or the image file that holds them (read on the
    /// vision thread).
    pub image: FrameImage,
    /// When it was captured, on this machine's monotonic clock: a live source's delivery of
    /// it (the `frames` crate's `live`); `None`: when it is pushed. Its latencies count from here
    /// ([`crate::latency`]).
    pub captured: Option<Instant>,
}

impl Frame {
    /// Frame `index` at `t_ns` with its grey pixels.
    pub fn decoded(index: usize, t_ns: i64, image: GrayImage) -> Self {
        Self {
            index,
            t_ns,
            image: FrameImage::Decoded(image),
            captured: None,
        }
    }
}

/// Where tracking starts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Start {
    /// Nowhere given: the cold start finds the model in the frames.
    Locate,
    /// The camera's whole pose in the model's frame (`cMo`).
    Camera(CameraPose),
    /// The IMU's position [m] and yaw [rad] in the model's frame, roll and pitch from gravity
    /// (the paper's semi-automatic initialisation; inertial models only).
    GravityAndYaw {
        /// The IMU's position [m].
        position: [f64; 3],
        /// Its yaw [rad].
        yaw: f64,
    },
}

/// How a search's (or a tilt check's) answer is taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Answers {
    /// At the next frame, waiting for it: a replay is the same every time.
    AtNextFrame,
    /// At the first frame where it is ready: a live camera is never held up.
    WhenReady,
}

/// The core samples its own IMU and triggers the camera (protocol/PROTOCOL.md §7): the
/// program pushes frames only, and the tracker pairs each with the core's `Trigger`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuOnCore {
    /// The core fires the camera every this many IMU samples.
    pub trigger_every: u16,
    /// The longest a frame may come after its trigger [s] (exposure, read-out, transfer):
    /// a frame later than that is refused with the delay, and a trigger that no frame
    /// followed within it counts as a frame the camera dropped. Less than the trigger
    /// period, so that a frame pairs with one trigger only.
    pub max_delay_s: f64,
}

impl ImuOnCore {
    /// A trigger every `trigger_every` samples at `imu_rate_hz`, with frames expected within
    /// half the trigger period.
    pub fn new(trigger_every: u16, imu_rate_hz: f64) -> Self {
        ImuOnCore {
            trigger_every,
            max_delay_s: 0.5 * f64::from(trigger_every) / imu_rate_hz,
        }
    }
}

/// How the tracker runs.
#[derive(Debug, Clone)]
pub struct TrackerConfig {
    /// The camera (its intrinsics and image size).
    pub camera: Camera,
    /// The core's filter model: the vision-only one (the frames are its clock), or an
    /// inertial one (the IMU samples are).
    pub model: ModelKind,
    /// The sensors of an inertial model: the IMU's rate and noise, the camera's rate and mount.
    pub rig: Rig,
    /// The frames' nominal rate [Hz] of the vision-only model: its clock of ticks is twice it.
    pub frame_rate_hz: f64,
    /// Where tracking starts.
    pub start: Start,
    /// Inertial models, in a replay: the correspondences of a frame are sent this long after
    /// its trigger [s], counted in IMU samples.
    pub latency_s: f64,
    /// Inertial models: take over a core that is already tracking our model
    /// (protocol/PROTOCOL.md §8) instead of configuring it anew.
    pub attach: bool,
    /// The image analysis.
    pub vision: VisionOptions,
    /// The core's tuning.
    pub tuning: CoreTuning,
    /// Folder of the cold start's viewpoint database (built on the first search, read back
    /// after).
    pub cache: PathBuf,
    /// Longest wait for an answer of the core.
    pub timeout: Duration,
    /// How searches' answers are taken.
    pub answers: Answers,
    /// Keep every this many frames' images in the record, for overlays (0: none).
    pub keep_image_every: usize,
    /// This run's name for its configuration of the core (non-zero).
    pub session_id: u32,
    /// The shortest time a search takes: an answer found sooner is held back until then, as
    /// on a slower machine (zero: none). For reproducing a slow machine's live runs.
    pub search_floor: Duration,
    /// Inertial models: the core samples its own IMU and fires the camera; `None`: the
    /// program pushes the IMU's samples ([`crate::Tracker::push_imu`]).
    pub imu_on_core: Option<ImuOnCore>,
    /// Tell what a run's report needs beyond the poses and frames
    /// ([`crate::event::Event::Detail`]: every message of the core, every frame's analysis,
    /// the searches, the tilt checks, the outages, the latencies), for a
    /// [`crate::record::Record`] to keep. Off, the tracker tells only what a live program
    /// uses.
    pub details: bool,
}

impl TrackerConfig {
    /// Defaults of the vision-only model for `camera` at `frame_rate_hz`: an object turned in
    /// a hand, found by the cold start, replayed deterministically.
    pub fn new(camera: Camera, frame_rate_hz: f64, cache: PathBuf) -> Self {
        let tuning = CoreTuning {
            expected_accel: OBJECT_IN_HAND_ACCEL,
            angular_noise: OBJECT_IN_HAND_ANGULAR_NOISE,
            ..CoreTuning::default()
        };
        Self {
            camera,
            model: ModelKind::Vision,
            rig: Rig {
                imu_rate_hz: 2.0 * frame_rate_hz,
                imu_noise: None,
                camera_rate_hz: Some(frame_rate_hz),
                hand_eye: HandEye::IDENTITY,
            },
            frame_rate_hz,
            start: Start::Locate,
            latency_s: 0.0,
            attach: false,
            vision: VisionOptions::default(),
            tuning,
            cache,
            timeout: Duration::from_secs(10),
            answers: Answers::AtNextFrame,
            keep_image_every: 0,
            session_id: 1,
            search_floor: Duration::ZERO,
            imu_on_core: None,
            details: false,
        }
    }
}

/// A session id for a run ([`TrackerConfig::session_id`]): non-zero, and different from run
/// to run (the clock's nanoseconds and the process id), so that a host coming back to a core
/// tells its own configuration from another's.
pub fn new_session_id() -> u32 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos() ^ (d.as_secs() as u32));
    (nanos ^ std::process::id().rotate_left(16)).max(1)
}

/// Checks what no run can work with.
pub(crate) fn check_config(config: &TrackerConfig) -> Result<(), TrackerError> {
    let bad = |m: String| Err(TrackerError::Config(m));
    if config.model == ModelKind::Vision {
        if !(config.frame_rate_hz.is_finite() && config.frame_rate_hz > 0.0) {
            return bad(format!(
                "the frame rate must be a positive number of frames per second, got {}",
                config.frame_rate_hz
            ));
        }
        if matches!(config.start, Start::GravityAndYaw { .. }) {
            return bad(
                "the vision-only model has no gravity for roll and pitch: start it from the camera's whole pose".into(),
            );
        }
        if config.attach {
            return bad("attaching to a running core is for runs with an IMU".into());
        }
        if config.imu_on_core.is_some() {
            return bad(
                "the core's own IMU is for the inertial models, not the vision-only one".into(),
            );
        }
        if config.latency_s != 0.0 {
            return bad(format!(
                "a latency of the correspondences ({} s) is for runs with an IMU: the vision-only model sends them before its next tick",
                config.latency_s
            ));
        }
        return Ok(());
    }
    let rate = config.rig.imu_rate_hz;
    if !(rate.is_finite() && rate > 0.0) {
        return bad(format!(
            "the IMU rate must be a positive number of samples per second, got {rate}"
        ));
    }
    if !(config.latency_s.is_finite() && config.latency_s >= 0.0) {
        return bad(format!(
            "the latency must be a non-negative number of seconds, got {}",
            config.latency_s
        ));
    }
    if let Some(on_core) = &config.imu_on_core {
        check_imu_on_core(config, on_core)?;
    }
    Ok(())
}

/// What a run with the core's own IMU needs: a trigger it can fire, a delay bound that pairs
/// each frame with one trigger, and a start pose (the cold start and the attach push their
/// own samples' history, which the core's own IMU does not give the host).
fn check_imu_on_core(config: &TrackerConfig, on_core: &ImuOnCore) -> Result<(), TrackerError> {
    let bad = |m: String| Err(TrackerError::Config(m));
    let every = on_core.trigger_every;
    if every == 0 || every > protocol::validate::MAX_TRIGGER_EVERY {
        return bad(format!(
            "the core's trigger must fire every 1 to {} samples, got {every}",
            protocol::validate::MAX_TRIGGER_EVERY
        ));
    }
    let period_s = f64::from(every) / config.rig.imu_rate_hz;
    let d = on_core.max_delay_s;
    if !(d.is_finite() && d > 0.0 && d < period_s) {
        return bad(format!(
            "the frame delay bound must be positive and under the trigger period ({:.1} ms), got {d} s",
            period_s * 1e3
        ));
    }
    if config.start == Start::Locate {
        return bad("with the core sampling its own IMU, give a start pose: the cold start is not supported in that mode yet".into());
    }
    if config.attach {
        return bad(
            "attaching to a running core is not supported with the core sampling its own IMU yet"
                .into(),
        );
    }
    Ok(())
}
