//! [`TrackerBuilder`]: a [`Tracker`] from a camera, a model and what differs from the
//! defaults, the one place the application, the Python module and the examples set a tracker
//! up. Each setting names what it changes in the [`TrackerConfig`] it builds.

use std::path::PathBuf;

use camera::{Camera, CameraPose};
use protocol::ModelKind;

use crate::config::CoreTuning;
use crate::error::TrackerError;
use crate::in_process::InProcessCore;
use crate::rig::Rig;
use crate::settings::{Answers, ImuOnCore, Start, TrackerConfig, new_session_id};
use crate::tracker::Tracker;
use crate::transport::CoreTransport;

/// The frames' rate assumed where none is given [Hz].
pub const DEFAULT_FRAME_RATE_HZ: f64 = 30.0;

/// A [`Tracker`] to be: the camera, the model, and the settings that differ from the
/// defaults (vision-only at [`DEFAULT_FRAME_RATE_HZ`], the cold start, the viewpoint database
/// in [`locate::database::default_cache_dir`], a replay's deterministic answers, a session id
/// of its own, the core called in-process).
///
/// ```no_run
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// let camera = camera::read_camera_json("camera.json".as_ref())?;
/// let model = model::load("cube.obj".as_ref())?;
/// let mut tracker = tracker::TrackerBuilder::new(camera, model)
///     .frame_rate_hz(30.0)
///     .start_pose(camera::start_pose::read_start_pose("cMo.json".as_ref())?)
///     .build()?;
/// # let _ = &mut tracker;
/// # Ok(())
/// # }
/// ```
pub struct TrackerBuilder {
    camera: Camera,
    model: model::Model,
    frame_rate_hz: f64,
    start: Start,
    inertial: Option<(ModelKind, Rig)>,
    live: bool,
    cache: Option<PathBuf>,
    session_id: Option<u32>,
    imu_on_core: Option<ImuOnCore>,
    latency_s: f64,
    adjust: Vec<Adjust>,
}

/// A setting of [`TrackerBuilder::configure`].
type Adjust = Box<dyn Fn(&mut TrackerConfig) + Send + Sync>;

impl std::fmt::Debug for TrackerBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrackerBuilder")
            .field("config", &self.config())
            .finish_non_exhaustive()
    }
}

impl TrackerBuilder {
    /// A vision-only tracker of `model` seen by `camera`, with the defaults.
    pub fn new(camera: Camera, model: model::Model) -> Self {
        Self {
            camera,
            model,
            frame_rate_hz: DEFAULT_FRAME_RATE_HZ,
            start: Start::Locate,
            inertial: None,
            live: false,
            cache: None,
            session_id: None,
            imu_on_core: None,
            latency_s: 0.0,
            adjust: Vec::new(),
        }
    }

    /// The frames' nominal rate [Hz] ([`TrackerConfig::frame_rate_hz`]; with an IMU, where
    /// the rig gives no camera rate).
    pub fn frame_rate_hz(mut self, hz: f64) -> Self {
        self.frame_rate_hz = hz;
        self
    }

    /// Where tracking starts ([`TrackerConfig::start`]; default [`Start::Locate`]).
    pub fn start(mut self, start: Start) -> Self {
        self.start = start;
        self
    }

    /// Tracking starts from the camera's pose in the model's frame, `cMo`.
    pub fn start_pose(self, c_m_o: CameraPose) -> Self {
        self.start(Start::Camera(c_m_o))
    }

    /// An IMU: the inertial `model` (acc, gyro or gravity) with the sensors of `rig`
    /// ([`TrackerConfig::model`], [`TrackerConfig::rig`]; the core's tuning for a rig, not for
    /// an object turned in a hand). Push its samples with [`Tracker::push_imu`].
    pub fn imu(mut self, model: ModelKind, rig: Rig) -> Self {
        self.inertial = Some((model, rig));
        self
    }

    /// With an IMU, in a replay: the correspondences of a frame reach the core this long after
    /// its trigger [s] ([`TrackerConfig::latency_s`]).
    pub fn latency_s(mut self, latency_s: f64) -> Self {
        self.latency_s = latency_s;
        self
    }

    /// With an IMU: the core samples its own IMU and fires the camera
    /// ([`TrackerConfig::imu_on_core`]).
    pub fn imu_on_core(mut self, on_core: ImuOnCore) -> Self {
        self.imu_on_core = Some(on_core);
        self
    }

    /// A live camera: a search's answer is taken at the first frame where it is ready, so
    /// that no frame waits for it ([`Answers::WhenReady`]); default: a replay, the same every
    /// time ([`Answers::AtNextFrame`]).
    pub fn live(mut self, live: bool) -> Self {
        self.live = live;
        self
    }

    /// The folder of the cold start's viewpoint database ([`TrackerConfig::cache`]).
    pub fn cache(mut self, dir: PathBuf) -> Self {
        self.cache = Some(dir);
        self
    }

    /// This run's name for its configuration of the core ([`TrackerConfig::session_id`];
    /// default: [`new_session_id`], different from run to run).
    pub fn session_id(mut self, id: u32) -> Self {
        self.session_id = Some(id);
        self
    }

    /// Tell the details a run's report needs ([`TrackerConfig::details`]), for a
    /// [`crate::record::Record`] to keep from the events; default: off.
    pub fn details(self, on: bool) -> Self {
        self.configure(move |c| c.details = on)
    }

    /// Any other setting, applied last (in the order given) to the [`TrackerConfig`] built:
    /// `.configure(|c| c.keep_image_every = 10)`.
    pub fn configure(
        mut self,
        adjust: impl Fn(&mut TrackerConfig) + Send + Sync + 'static,
    ) -> Self {
        self.adjust.push(Box::new(adjust));
        self
    }

    /// The settings the tracker will run with.
    pub fn config(&self) -> TrackerConfig {
        let cache = self
            .cache
            .clone()
            .unwrap_or_else(locate::database::default_cache_dir);
        let mut config = TrackerConfig::new(self.camera, self.frame_rate_hz, cache);
        config.start = self.start;
        config.answers = if self.live {
            Answers::WhenReady
        } else {
            Answers::AtNextFrame
        };
        config.session_id = self.session_id.unwrap_or_else(new_session_id);
        if let Some((model, rig)) = self.inertial {
            config.model = model;
            config.rig = rig;
            config.frame_rate_hz = rig.camera_rate_hz.unwrap_or(self.frame_rate_hz);
            config.tuning = CoreTuning::default();
        }
        // Given without an IMU, these are refused when the tracker starts, not dropped.
        config.latency_s = self.latency_s;
        config.imu_on_core = self.imu_on_core;
        for adjust in &self.adjust {
            adjust(&mut config);
        }
        config
    }

    /// The tracker, with the core called in-process ([`InProcessCore`], `f32` as on the
    /// board).
    pub fn build(self) -> Result<Tracker<InProcessCore>, TrackerError> {
        self.build_with(InProcessCore::default())
    }

    /// The tracker, with the core behind `core` (a board through the `core-link` crate, or a
    /// transport of the program's own).
    pub fn build_with<T: CoreTransport>(self, core: T) -> Result<Tracker<T>, TrackerError> {
        Tracker::new(self.config(), &self.model, core)
    }
}
