//! The messages. Units are SI (m, s, rad) unless a field says otherwise; time stamps are
//! microseconds on the IMU's clock. Quaternions are Hamilton, `[w, x, y, z]`, and `q_ba` rotates
//! a vector from frame `a` into frame `b` (docs/FILTER.md §2). Symmetric matrices are sent as their
//! upper triangle, row by row: [`Sym2`] = `[xx, xy, yy]`, [`Sym3`] = `[xx, xy, xz, yy, yz, zz]`,
//! [`Sym6`] = the 21 entries `(0,0), (0,1) … (0,5), (1,1) … (5,5)`.
//!
//! Compatibility rule: the variant index of [`HostToCore::Hello`] (0), [`CoreToHost::HelloAck`]
//! (0), [`CoreToHost::Error`] (1) and [`ErrorCode::VersionMismatch`] (0), and the layout of
//! [`Version`], never change, so that peers of any two versions can tell each other so.

use heapless::Vec;
use serde::{Deserialize, Serialize};

use crate::error::ErrorCode;
use crate::limits::{MAX_CORRESPONDENCES_PER_MESSAGE, MAX_PARTS_PER_FRAME};
use crate::version::Version;

/// Symmetric 2×2 matrix, upper triangle `[xx, xy, yy]`.
pub type Sym2 = [f32; 3];
/// Symmetric 3×3 matrix, upper triangle `[xx, xy, xz, yy, yz, zz]`.
pub type Sym3 = [f32; 6];
/// Symmetric 6×6 matrix, upper triangle row by row (21 entries).
pub type Sym6 = [f32; 21];

/// Index of entry `(r, c)` of an `n`×`n` symmetric matrix stored as its upper triangle.
pub const fn sym_index(n: usize, r: usize, c: usize) -> usize {
    let (r, c) = if r <= c { (r, c) } else { (c, r) };
    r * n - r * (r + 1) / 2 + c
}

// ------------------------------------------------------------------------------------------------
// Host → core
// ------------------------------------------------------------------------------------------------

/// A message from the vision host to the fusion core.
// No heap on the core: the large `Correspondences` variant cannot be boxed, and one message
// value at a time is all either end holds.
#[allow(clippy::large_enum_variant)]
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub enum HostToCore {
    /// Opens a session; the core answers [`CoreToHost::HelloAck`] or, for another major version,
    /// [`CoreToHost::Error`] with [`ErrorCode::VersionMismatch`].
    Hello(Hello),
    /// Chooses the filter model and its parameters. Clears any filter state.
    Configure(Config),
    /// Starts (re)initialisation from a position and an optional orientation.
    Init(Init),
    /// One IMU sample, in time order.
    Imu(ImuSample),
    /// One part of one camera frame's 2D/3D correspondences.
    Correspondences(Correspondences),
    /// Drops all filter state and returns to the configured, uninitialised mode.
    Reset,
    /// Advances the vision-only model's time, in place of an IMU sample (since 2.1). Sent to
    /// an inertial model it is refused with [`ErrorCode::TickInInertialModel`].
    Tick(Tick),
    /// Asks for the core's state (since 3.0): it answers [`CoreToHost::Status`] with
    /// [`StatusReason::Queried`], the time stamp of its last sample and its mode, then, if
    /// its filter runs, a [`CoreToHost::State`]. A host that attaches to a running core
    /// learns from it where to go on (protocol/PROTOCOL.md §8).
    Query,
    /// Starts a configured core from a state it reported before it was reset (since 3.0): the
    /// filter runs at once, from that state at its time, with the initial covariance (the
    /// tilt σ about the vertical too). A device that moves has no still window to level it
    /// from gravity; the state it was tracked in is the better start (protocol/PROTOCOL.md §8).
    Resume(Resume),
    /// Chooses who samples the IMU (since 3.1): the host, which sends [`HostToCore::Imu`]
    /// (the default), or the core, which reads its own IMU, triggers the camera every
    /// `trigger_every`-th sample and reports each trigger as a [`CoreToHost::Trigger`]. The
    /// core answers [`CoreToHost::Sampling`] with [`SamplingEvent::Started`], or
    /// [`ErrorCode::NoOnboardImu`] if it has no IMU of its own (protocol/PROTOCOL.md §7).
    Sampling(Sampling),
    /// One part of one camera frame's contour correspondences (since 3.2): model points on
    /// the object's silhouette, each found in the image along its contour normal. A frame's
    /// [`Correspondences`] and [`Contours`] parts are numbered together
    /// ([`frame_messages`]).
    Contours(Contours),
}

/// Who samples the IMU, and what the core streams of it (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sampling {
    /// Who takes the samples.
    pub source: SampleSource,
    /// Send every sample the core takes as a [`CoreToHost::RawImu`] too (for calibration,
    /// e.g. Kalibr's IMU noise and camera–IMU calibration). Only with [`SampleSource::Core`].
    pub raw_imu: bool,
}

/// Who takes the IMU samples (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleSource {
    /// The host sends every sample as [`HostToCore::Imu`] (or `Tick`): a simulator, a replay,
    /// an IMU wired to the host. The state of a core after `Hello`.
    Host,
    /// The core reads its own IMU. It refuses `Imu` and `Tick` from the host
    /// ([`ErrorCode::HostImuWhileCoreSamples`]).
    Core {
        /// The camera is triggered at every `trigger_every`-th sample (0: never; at most
        /// [`crate::validate::MAX_TRIGGER_EVERY`]).
        trigger_every: u16,
    },
}

/// The state a reset core resumes from: what it last reported in a [`CoreToHost::State`]
/// while tracking, given back by the host (since 3.0). States a model lacks are ignored.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct Resume {
    /// Time of the state [µs]: the first sample after it is propagated from here.
    pub t_us: u64,
    /// IMU origin [m].
    pub s_w: [f32; 3],
    /// Orientation `q_sw` (unit).
    pub q_sw: [f32; 4],
    /// Velocity [m/s].
    pub v_w: [f32; 3],
    /// Free acceleration [m/s²] (acc model).
    pub a_w: [f32; 3],
    /// Angular velocity [rad/s].
    pub omega_s: [f32; 3],
    /// Gyroscope bias [rad/s].
    pub gyro_bias: [f32; 3],
    /// Accelerometer bias [m/s²].
    pub accel_bias: [f32; 3],
}

impl Resume {
    /// The resumable part of a state report.
    pub fn of(s: &StateReport) -> Self {
        Resume {
            t_us: s.t_us,
            s_w: s.s_w,
            q_sw: s.q_sw,
            v_w: s.v_w,
            a_w: s.a_w,
            omega_s: s.omega_s,
            gyro_bias: s.gyro_bias,
            accel_bias: s.accel_bias,
        }
    }
}

/// Session opening.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hello {
    /// The host's protocol version.
    pub version: Version,
}

/// The three system models of the paper (docs/FILTER.md §3), and the vision-only fallback for a
/// camera without an IMU.
///
/// The in-memory discriminants start at 1 so that `Option<ModelKind>`'s `None` (and so an
/// unconfigured core) is all zero bytes: a firmware's device `static` then lands in `.bss`
/// instead of costing its size in flash. The wire encoding is the variant index (0, 1, 2, 3).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ModelKind {
    /// Gyroscopes only: constant velocity, 16 states.
    Gyro = 1,
    /// Gyroscopes + accelerometer as gravity sensor: 19 states.
    Gravity = 2,
    /// Gyroscopes + accelerometer with free acceleration: 22 states.
    Acc = 3,
    /// No inertial sensor (since 2.1): a constant-velocity pose advanced by [`Tick`]s alone,
    /// 13 states (position, velocity, orientation, angular velocity).
    Vision = 4,
}

impl ModelKind {
    /// The paper's three inertial models, in its order.
    pub const INERTIAL: [ModelKind; 3] = [ModelKind::Gyro, ModelKind::Gravity, ModelKind::Acc];
    /// Every model: the inertial ones, then vision-only.
    pub const ALL: [ModelKind; 4] = [
        ModelKind::Gyro,
        ModelKind::Gravity,
        ModelKind::Acc,
        ModelKind::Vision,
    ];

    /// Number of filter states of this model.
    pub const fn state_dim(self) -> usize {
        match self {
            ModelKind::Gyro => 16,
            ModelKind::Gravity => 19,
            ModelKind::Acc => 22,
            ModelKind::Vision => 13,
        }
    }

    /// Lower-case name as used on command lines and in reports.
    pub const fn name(self) -> &'static str {
        match self {
            ModelKind::Gyro => "gyro",
            ModelKind::Gravity => "gravity",
            ModelKind::Acc => "acc",
            ModelKind::Vision => "vision",
        }
    }

    /// Whether the model measures with an IMU (it is advanced by `Imu` samples; the
    /// vision-only model by `Tick`s).
    pub const fn has_imu(self) -> bool {
        !matches!(self, ModelKind::Vision)
    }
}

/// Noise parameters. Process noises are continuous-time white-noise densities (rate
/// independent; the core discretises them with the actual sample interval); measurement
/// noises are standard deviations of one sample.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct NoiseParams {
    /// Density of the motion-model noise `v_s̈`: white acceleration in the constant-velocity
    /// models [m/s²/√Hz], white jerk in the acc model [m/s³/√Hz].
    pub motion: f32,
    /// Density of the angular-velocity noise `v_ω`: white angular acceleration [rad/s²/√Hz].
    pub angular: f32,
    /// Gyroscope bias random walk `v_bω` [rad/s²/√Hz].
    pub gyro_bias_walk: f32,
    /// Accelerometer bias random walk `v_ba` [m/s³/√Hz].
    pub accel_bias_walk: f32,
    /// Gyroscope measurement noise `v_yω`, standard deviation per sample [rad/s].
    pub gyro_meas: f32,
    /// Accelerometer measurement noise `v_ya`, standard deviation per sample [m/s²]. In the
    /// gravity model it also absorbs the free acceleration.
    pub accel_meas: f32,
}

/// Standard deviations of the initial state (re-used on re-initialisation).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct InitSigma {
    /// Position [m].
    pub position: f32,
    /// Velocity [m/s].
    pub velocity: f32,
    /// Free acceleration, acc model only [m/s²].
    pub acceleration: f32,
    /// Roll and pitch [rad].
    pub tilt: f32,
    /// Yaw [rad], when yaw was not given (otherwise `tilt` applies to yaw too).
    pub yaw: f32,
    /// Angular velocity [rad/s].
    pub angular_velocity: f32,
    /// Gyroscope bias [rad/s].
    pub gyro_bias: f32,
    /// Accelerometer bias [m/s²].
    pub accel_bias: f32,
}

/// Hand-eye calibration: the rigid transform between IMU and camera.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct HandEye {
    /// Rotation from sensor to camera frame, `q_cs`, unit quaternion `[w, x, y, z]`.
    pub q_cs: [f32; 4],
    /// Camera origin in the sensor frame, `c_s` [m].
    pub c_s: [f32; 3],
}

/// Divergence monitor thresholds (docs/FILTER.md §9, paper §4.6).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct DivergenceParams {
    /// Low-pass factor `λ` of `g ← λg + (1−λ)s_i`, in (0, 1).
    pub residual_lowpass: f32,
    /// Divergence when the low-passed normalised residual `g` exceeds this; `f32::MAX`
    /// switches the test off (PROTOCOL.md §5, `DivergenceParams`).
    pub residual_threshold: f32,
    /// Divergence when the Frobenius norm of the state covariance exceeds this.
    pub covariance_frobenius: f32,
    /// Divergence when `|‖q‖ − 1|` before normalisation exceeds this.
    pub quaternion_norm: f32,
}

/// Filter configuration.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// Which system model to run.
    pub model: ModelKind,
    /// Noise parameters.
    pub noise: NoiseParams,
    /// Initial standard deviations.
    pub init_sigma: InitSigma,
    /// Hand-eye calibration.
    pub hand_eye: HandEye,
    /// Outlier gate on the normalised residual `s_i` (eq. 17); χ²₂(0.95) = 5.991.
    pub gate: f32,
    /// Divergence monitor thresholds.
    pub divergence: DivergenceParams,
    /// Nominal IMU rate [Hz].
    pub imu_rate_hz: f32,
    /// Nominal camera rate [Hz].
    pub camera_rate_hz: f32,
    /// IMU samples averaged for roll and pitch at (re)initialisation (device held still).
    pub still_samples: u16,
    /// Send a [`CoreToHost::State`] after every `state_every`-th IMU sample (0: never).
    pub state_every: u16,
    /// The host's name for this configuration (non-zero; since 3.0). The core reports it in
    /// every [`HelloAck`], so that a host coming back to a core tells a core that kept its
    /// state (the same session) from one that was reset (0) or re-configured by another host.
    pub session: u32,
}

/// Orientation given at initialisation.
///
/// In-memory discriminants start at 1 for the same reason as [`ModelKind`]'s; the wire
/// encoding is the variant index.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
#[repr(u8)]
pub enum InitAttitude {
    /// Roll and pitch from gravity; yaw unknown (zero with a large variance).
    Gravity = 1,
    /// Roll and pitch from gravity; yaw of the sensor frame given [rad].
    GravityAndYaw(f32) = 2,
    /// Full orientation `q_sw` given (from an absolute orientation sensor or a pose).
    Full([f32; 4]) = 3,
    /// Position and yaw of the sensor frame given [rad] (a pose the host found, e.g. by its
    /// cold start), roll and pitch kept from gravity: a running filter keeps its own roll and
    /// pitch (the accelerometer has levelled them) and is re-anchored at once, with no still
    /// window; a core not running takes them from a still window, as for `GravityAndYaw`.
    /// Since 2.2.
    KeepTilt(f32) = 4,
}

/// (Re)initialisation request.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct Init {
    /// IMU origin in the world, `s_w` [m].
    pub position: [f32; 3],
    /// Orientation source.
    pub attitude: InitAttitude,
}

/// One IMU sample.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    /// Time stamp [µs], strictly increasing.
    pub t_us: u64,
    /// Angular velocity in the sensor frame [rad/s].
    pub gyro: [f32; 3],
    /// Specific force in the sensor frame [m/s²].
    pub accel: [f32; 3],
    /// The camera was triggered at this sample: the core answers with a
    /// [`CoreToHost::PosePrediction`] for this time stamp.
    pub trigger: bool,
}

/// The vision-only model's clock (since 2.1): advances the filter to `t_us` by its motion
/// model alone, with the time-stamp rules of [`ImuSample`].
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// Time stamp [µs], strictly increasing.
    pub t_us: u64,
    /// The camera was triggered at this time: the core answers with a
    /// [`CoreToHost::PosePrediction`] for it.
    pub trigger: bool,
}

/// One 2D/3D correspondence.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    /// Registered image point in normalised coordinates `m_n` (undistorted, `K⁻¹ m_p`).
    pub m_n: [f32; 2],
    /// Covariance of `m_n` (normalised units²).
    pub cov_n: Sym2,
    /// Model point in the world `m_w` [m].
    pub m_w: [f32; 3],
    /// Covariance of `m_w` [m²].
    pub cov_w: Sym3,
}

/// One part of one camera frame's correspondences.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Correspondences {
    /// Frame id from the core's [`PosePrediction`].
    pub frame_id: u32,
    /// Trigger time stamp of that frame [µs].
    pub trigger_us: u64,
    /// Index of this part, `0 ≤ part < parts`.
    pub part: u8,
    /// Number of parts of this frame, `1 ≤ parts ≤ MAX_PARTS_PER_FRAME`.
    pub parts: u8,
    /// The correspondences of this part.
    pub items: Vec<Correspondence, MAX_CORRESPONDENCES_PER_MESSAGE>,
}

/// One contour correspondence (since 3.2): a model point on the object's silhouette, the
/// contour's normal at its predicted projection, and where the contour was found along that
/// normal. It constrains the projection along the normal only (docs/FILTER.md §5, eq. 10c):
/// `nᵀ π(m_w) = d`.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct ContourPoint {
    /// Model point on the silhouette, in the world `m_w` [m].
    pub m_w: [f32; 3],
    /// Its covariance [m²].
    pub cov_w: Sym3,
    /// Unit normal of the contour, normalised image coordinates.
    pub n: [f32; 2],
    /// Where the contour lies along the normal: `d = nᵀ u` for the found contour point `u`
    /// (normalised image coordinates).
    pub d: f32,
    /// Variance of `d` (normalised units²), positive.
    pub var_d: f32,
}

/// One part of one camera frame's contour correspondences (since 3.2). The header is that of
/// [`Correspondences`]; `part` and `parts` count the frame's messages of both kinds.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct Contours {
    /// Frame id from the core's [`PosePrediction`].
    pub frame_id: u32,
    /// Trigger time stamp of that frame [µs].
    pub trigger_us: u64,
    /// Index of this part among the frame's parts of both kinds.
    pub part: u8,
    /// Number of parts of this frame, both kinds, `1 ≤ parts ≤ MAX_PARTS_PER_FRAME`.
    pub parts: u8,
    /// The contour correspondences of this part.
    pub items: Vec<ContourPoint, MAX_CORRESPONDENCES_PER_MESSAGE>,
}

/// A frame's correspondences do not fit into [`MAX_PARTS_PER_FRAME`] messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TooManyCorrespondences {
    /// How many were offered (both kinds).
    pub count: usize,
}

impl core::fmt::Display for TooManyCorrespondences {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} correspondences need more than the protocol's {} messages of {} per frame",
            self.count, MAX_PARTS_PER_FRAME, MAX_CORRESPONDENCES_PER_MESSAGE
        )
    }
}

impl core::error::Error for TooManyCorrespondences {}

/// A `heapless::Vec` of one message's items from a slice of at most its capacity.
fn message_items<T: Copy>(chunk: &[T]) -> Vec<T, MAX_CORRESPONDENCES_PER_MESSAGE> {
    let mut items = Vec::new();
    for c in chunk {
        // Cannot fail: callers chunk by MAX_CORRESPONDENCES_PER_MESSAGE.
        let _ = items.push(*c);
    }
    items
}

/// Splits one frame's measurements into as many messages as needed (never truncates): the
/// 2D/3D correspondences' parts first, then the contours', numbered together. A frame with
/// neither still yields one empty [`Correspondences`] part, so the core learns that the frame
/// was processed and saw nothing.
pub fn frame_messages<'a>(
    frame_id: u32,
    trigger_us: u64,
    points: &'a [Correspondence],
    contours: &'a [ContourPoint],
) -> Result<impl Iterator<Item = HostToCore> + 'a, TooManyCorrespondences> {
    let m = MAX_CORRESPONDENCES_PER_MESSAGE;
    let point_parts = points.len().div_ceil(m);
    let contour_parts = contours.len().div_ceil(m);
    let parts = (point_parts + contour_parts).max(1);
    if parts > MAX_PARTS_PER_FRAME {
        return Err(TooManyCorrespondences {
            count: points.len() + contours.len(),
        });
    }
    // Both fit in u8: parts ≤ MAX_PARTS_PER_FRAME (checked above).
    let parts_u8 = parts as u8;
    // `point_parts`, or the one empty part of a frame with nothing.
    let first_contour = parts - contour_parts;
    let point_msgs = (0..first_contour).map(move |k| {
        let chunk = points
            .get(k * m..((k + 1) * m).min(points.len()))
            .unwrap_or(&[]);
        HostToCore::Correspondences(Correspondences {
            frame_id,
            trigger_us,
            part: k as u8,
            parts: parts_u8,
            items: message_items(chunk),
        })
    });
    let contour_msgs = (0..contour_parts).map(move |k| {
        let chunk = &contours[k * m..((k + 1) * m).min(contours.len())];
        HostToCore::Contours(Contours {
            frame_id,
            trigger_us,
            part: (first_contour + k) as u8,
            parts: parts_u8,
            items: message_items(chunk),
        })
    });
    Ok(point_msgs.chain(contour_msgs))
}

impl Correspondences {
    /// Splits one frame's 2D/3D correspondences into as many messages as needed (never
    /// truncates); [`frame_messages`] with no contours.
    pub fn split(
        frame_id: u32,
        trigger_us: u64,
        all: &[Correspondence],
    ) -> Result<impl Iterator<Item = Correspondences> + '_, TooManyCorrespondences> {
        Ok(
            frame_messages(frame_id, trigger_us, all, &[])?.filter_map(|m| match m {
                HostToCore::Correspondences(c) => Some(c),
                _ => None,
            }),
        )
    }
}

const _: () = assert!(MAX_PARTS_PER_FRAME <= u8::MAX as usize);

// ------------------------------------------------------------------------------------------------
// Core → host
// ------------------------------------------------------------------------------------------------

/// A message from the fusion core to the vision host.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub enum CoreToHost {
    /// Answer to a compatible [`HostToCore::Hello`].
    HelloAck(HelloAck),
    /// Something the host sent was refused.
    Error(ErrorReport),
    /// Pose prediction for a triggered camera frame.
    PosePrediction(PosePrediction),
    /// Full filter state after an IMU step.
    State(StateReport),
    /// Result of applying one [`Correspondences`] part.
    UpdateReport(UpdateReport),
    /// Tracking mode change, with the reason.
    Status(Status),
    /// The core triggered the camera (since 3.1, while it samples its own IMU): sent for
    /// every trigger, whether the filter runs or not, so that the host can pair each image
    /// with its trigger time.
    Trigger(Trigger),
    /// One sample the core took, as it reached the filter (since 3.1, with
    /// [`Sampling::raw_imu`]).
    RawImu(ImuSample),
    /// The state of the core's own sampling (since 3.1): when it starts, at every gap in the
    /// samples, and once a second.
    Sampling(SamplingReport),
}

/// A camera trigger the core fired (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trigger {
    /// Triggers fired since sampling started, from 0: the host's image counter, once paired.
    pub frame_id: u32,
    /// Time stamp of the IMU sample the trigger was fired at [µs]: a filter that runs sends a
    /// [`PosePrediction`] with the same `t_us`.
    pub t_us: u64,
}

/// The state of the core's own sampling (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct SamplingReport {
    /// Time stamp of the last sample [µs].
    pub t_us: u64,
    /// Why this report.
    pub event: SamplingEvent,
    /// Samples handed to the filter since sampling started.
    pub samples: u32,
    /// Samples lost since sampling started (the sum of the gaps' `lost`).
    pub lost: u32,
    /// Times the IMU was found reset (brown-out, glitch) and configured again.
    pub part_resets: u32,
    /// Reads that found more samples than one interrupt brings (an interrupt was missed or
    /// served late): nothing is lost while the IMU's buffer holds them.
    pub late_reads: u32,
    /// The IMU's clock against the core's [ppm], measured over the samples (positive: the
    /// IMU runs fast). The time stamps are corrected by it.
    pub drift_ppm: f32,
}

/// Why a [`SamplingReport`] was sent (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum SamplingEvent {
    /// Sampling started (the answer to [`HostToCore::Sampling`]).
    Started,
    /// Samples were lost: the filter integrated across the gap.
    Gap(SampleGap),
    /// The report sent once a second.
    Periodic,
    /// Sampling stopped (the host chose [`SampleSource::Host`] again).
    Stopped,
}

/// Samples the core lost (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct SampleGap {
    /// Time stamp of the last sample before the gap [µs].
    pub from_us: u64,
    /// Time stamp of the first sample after it [µs].
    pub to_us: u64,
    /// Samples lost, from the IMU's own time stamps.
    pub lost: u32,
    /// What lost them.
    pub cause: GapCause,
}

/// What lost samples (since 3.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum GapCause {
    /// The IMU's buffer overflowed before the core read it: the oldest samples were lost.
    FifoOverflow,
    /// A sample failed its integrity check: it and the samples after it in that read were
    /// dropped.
    CorruptPacket,
    /// The IMU had reset (brown-out, glitch) and was configured again.
    PartReset,
    /// The IMU's time stamps jumped with no fault seen.
    Unexplained,
    /// The IMU marked samples invalid (−32768 in an axis: a sensor starting up); they keep
    /// their place in time but carry no reading (since 3.3).
    InvalidSample,
}

/// What the core can hold.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capacities {
    /// Largest frame the core accepts [bytes].
    pub max_frame_len: u16,
    /// Most correspondences per message.
    pub max_correspondences_per_message: u16,
    /// Most correspondences per camera frame the core applies.
    pub max_correspondences_per_frame: u16,
    /// IMU samples kept for delayed correspondences (one bound of the longest accepted
    /// latency: see [`Capacities::max_latency_us`]).
    pub delay_buffer_samples: u16,
    /// Camera frames kept awaiting their correspondences at once (the other bound).
    pub max_pending_frames: u16,
    /// Bits of the filter's floating-point scalar (32 on the MCU, 64 on the PC).
    pub scalar_bits: u8,
}

impl Capacities {
    /// The longest correspondence latency [µs], from a frame's trigger to the arrival of its
    /// last part, that the core can still apply at these rates (0 for rates that are not
    /// positive). A frame's snapshot is dropped at the trigger `max_pending_frames` frames
    /// later, so its parts must arrive by the IMU sample before it; and the IMU samples after
    /// the trigger must still be buffered, so no later than `delay_buffer_samples` samples.
    /// A host checks its latency against this at the handshake.
    pub fn max_latency_us(&self, imu_rate_hz: f32, camera_rate_hz: f32) -> u64 {
        let rates_ok = imu_rate_hz.is_finite()
            && camera_rate_hz.is_finite()
            && imu_rate_hz > 0.0
            && camera_rate_hz > 0.0;
        if !rates_ok {
            return 0;
        }
        let imu_period = 1e6 / f64::from(imu_rate_hz);
        let camera_period = 1e6 / f64::from(camera_rate_hz);
        let by_frames = f64::from(self.max_pending_frames) * camera_period - imu_period;
        let by_samples = f64::from(self.delay_buffer_samples) * imu_period;
        // Finite; the cast saturates for absurdly slow rates.
        by_frames.min(by_samples).max(0.0) as u64
    }
}

/// Answer to a compatible `Hello`.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct HelloAck {
    /// The core's protocol version.
    pub version: Version,
    /// Model currently configured, if any.
    pub model: Option<ModelKind>,
    /// The core's capacities.
    pub capacities: Capacities,
    /// The [`Config::session`] of the configuration the core runs; 0 when it has none since
    /// it booted (since 3.0).
    pub session: u32,
}

/// A refusal, with its reason.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct ErrorReport {
    /// What went wrong.
    pub code: ErrorCode,
}

/// Predicted camera pose at a camera trigger (eq. 5-6).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct PosePrediction {
    /// Frame id assigned by the core (increments per trigger).
    pub frame_id: u32,
    /// Trigger time stamp [µs].
    pub t_us: u64,
    /// Camera origin in the world, `c_w` [m].
    pub c_w: [f32; 3],
    /// Camera orientation `q_cw`.
    pub q_cw: [f32; 4],
    /// Covariance of `[c_w, θ]`, where `θ` is the small rotation error of `q_cw` as a rotation
    /// vector in the world frame [m², rad²].
    pub cov: Sym6,
}

/// Tracking mode.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Mode {
    /// No configuration received yet.
    Unconfigured,
    /// Configured, waiting for `Init`.
    AwaitingInit,
    /// Averaging the accelerometer over the still window.
    Initialising,
    /// Vision measurements are being applied.
    Tracking,
    /// No vision measurements recently: IMU only.
    DeadReckoning,
    /// The divergence monitor fired.
    Diverged,
    /// Re-initialising from the last good position after divergence.
    Reinitialising,
}

/// Why the mode changed.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StatusReason {
    /// A `Configure` was applied.
    Configured,
    /// An `Init` or `Reset` was received.
    HostRequest,
    /// The still window is complete; the filter runs.
    InitComplete,
    /// Correspondences were accepted.
    VisionAccepted,
    /// Frames passed without accepted correspondences.
    NoVision,
    /// Low-passed normalised residual above its threshold.
    ResidualLowpass,
    /// Covariance Frobenius norm above its threshold.
    CovarianceNorm,
    /// Quaternion norm far from 1 before normalisation.
    QuaternionNorm,
    /// A state or covariance entry became non-finite.
    NonFiniteState,
    /// The IMU clock jumped; the filter restarts from the last good position.
    TimeJump,
    /// The answer to [`HostToCore::Query`]: nothing changed (since 3.0).
    Queried,
}

/// Filter health figures.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct Health {
    /// Current mode.
    pub mode: Mode,
    /// Frobenius norm of the state covariance.
    pub covariance_frobenius: f32,
    /// Low-passed normalised residual `g`.
    pub residual_lowpass: f32,
    /// `|‖q‖ − 1|` before the last normalisation.
    pub quaternion_norm_error: f32,
}

/// Full filter state (states a model does not have are zero).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct StateReport {
    /// Time stamp of the last IMU sample applied [µs].
    pub t_us: u64,
    /// IMU origin in the world `s_w` [m].
    pub s_w: [f32; 3],
    /// Orientation `q_sw`.
    pub q_sw: [f32; 4],
    /// Velocity `ṡ_w` [m/s].
    pub v_w: [f32; 3],
    /// Free acceleration `s̈_w` [m/s²].
    pub a_w: [f32; 3],
    /// Angular velocity `ω_s` [rad/s].
    pub omega_s: [f32; 3],
    /// Gyroscope bias `b_ω` [rad/s].
    pub gyro_bias: [f32; 3],
    /// Accelerometer bias `b_a` [m/s²].
    pub accel_bias: [f32; 3],
    /// Health figures.
    pub health: Health,
    /// Covariance of the camera pose this state gives with the configured hand-eye, as
    /// [`PosePrediction::cov`]: `[c_w, θ]`, θ the rotation error of `q_cw` as a world-frame
    /// rotation vector [m², rad²] (since 4.0).
    pub cov: Sym6,
}

/// Whether a correspondence part was applied.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateOutcome {
    /// Applied at the trigger time and re-propagated to the present.
    Applied,
    /// The frame's snapshot has left the delay buffer.
    TooOld,
    /// This part of this frame was already applied.
    Duplicate,
    /// No prediction with this frame id and time stamp was issued.
    UnknownFrame,
    /// The filter is not running (not configured or not initialised).
    NotRunning,
}

/// Result of one correspondence part.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct UpdateReport {
    /// Frame id.
    pub frame_id: u32,
    /// Part index.
    pub part: u8,
    /// Whether the part was applied.
    pub outcome: UpdateOutcome,
    /// Correspondences that passed the gate and were applied.
    pub accepted: u16,
    /// Correspondences rejected by the gate (or as invalid).
    pub rejected: u16,
    /// Normalised residual `s_i` of each correspondence, in the order sent.
    pub residuals: Vec<f32, MAX_CORRESPONDENCES_PER_MESSAGE>,
    /// Mean distance, in normalised image units, between each correspondence's predicted
    /// position (before the update) and its registered position: the paper's prediction error
    /// (multiply by the focal length for pixels).
    pub prediction_error: f32,
}

/// A mode change.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    /// Time stamp of the last IMU sample [µs].
    pub t_us: u64,
    /// New mode.
    pub mode: Mode,
    /// Why.
    pub reason: StatusReason,
}

impl CoreToHost {
    /// Builds an error message.
    pub const fn error(code: ErrorCode) -> Self {
        CoreToHost::Error(ErrorReport { code })
    }
}

impl HostToCore {
    /// Short name of the message kind, for logs and errors.
    pub const fn kind(&self) -> &'static str {
        match self {
            HostToCore::Hello(_) => "Hello",
            HostToCore::Configure(_) => "Configure",
            HostToCore::Init(_) => "Init",
            HostToCore::Imu(_) => "Imu",
            HostToCore::Correspondences(_) => "Correspondences",
            HostToCore::Contours(_) => "Contours",
            HostToCore::Reset => "Reset",
            HostToCore::Tick(_) => "Tick",
            HostToCore::Query => "Query",
            HostToCore::Resume(_) => "Resume",
            HostToCore::Sampling(_) => "Sampling",
        }
    }
}

impl CoreToHost {
    /// Short name of the message kind, for logs and errors.
    pub const fn kind(&self) -> &'static str {
        match self {
            CoreToHost::HelloAck(_) => "HelloAck",
            CoreToHost::Error(_) => "Error",
            CoreToHost::PosePrediction(_) => "PosePrediction",
            CoreToHost::State(_) => "State",
            CoreToHost::UpdateReport(_) => "UpdateReport",
            CoreToHost::Status(_) => "Status",
            CoreToHost::Trigger(_) => "Trigger",
            CoreToHost::RawImu(_) => "RawImu",
            CoreToHost::Sampling(_) => "Sampling",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sym_index_enumerates_the_upper_triangle_row_by_row() {
        for n in [2usize, 3, 6] {
            let mut k = 0;
            for r in 0..n {
                for c in r..n {
                    assert_eq!(sym_index(n, r, c), k);
                    assert_eq!(sym_index(n, c, r), k);
                    k += 1;
                }
            }
            assert_eq!(k, n * (n + 1) / 2);
        }
    }

    fn corr(i: usize) -> Correspondence {
        Correspondence {
            m_n: [i as f32, 0.0],
            cov_n: [1e-6, 0.0, 1e-6],
            m_w: [0.0, 0.0, i as f32],
            cov_w: [1e-6, 0.0, 0.0, 1e-6, 0.0, 1e-6],
        }
    }

    #[test]
    fn split_never_truncates() {
        for n in [
            0usize,
            1,
            15,
            16,
            17,
            40,
            MAX_CORRESPONDENCES_PER_MESSAGE * MAX_PARTS_PER_FRAME,
        ] {
            let all: heapless::Vec<Correspondence, 128> = (0..n).map(corr).collect();
            let parts: heapless::Vec<Correspondences, 8> =
                Correspondences::split(7, 99, &all).unwrap().collect();
            assert_eq!(
                parts.len(),
                n.div_ceil(MAX_CORRESPONDENCES_PER_MESSAGE).max(1)
            );
            let mut seen = 0;
            for (i, p) in parts.iter().enumerate() {
                assert_eq!((p.frame_id, p.trigger_us, p.part as usize), (7, 99, i));
                assert_eq!(p.parts as usize, parts.len());
                assert_eq!(&p.items[..], &all[seen..seen + p.items.len()]);
                seen += p.items.len();
            }
            assert_eq!(seen, n);
        }
    }

    #[test]
    fn split_refuses_more_than_a_frame_holds() {
        let all = [corr(0); MAX_CORRESPONDENCES_PER_MESSAGE * MAX_PARTS_PER_FRAME + 1];
        assert_eq!(
            Correspondences::split(0, 0, &all).err(),
            Some(TooManyCorrespondences { count: all.len() })
        );
    }

    #[test]
    fn a_frame_of_both_kinds_is_numbered_together_points_first() {
        let points: heapless::Vec<Correspondence, 40> = (0..20).map(corr).collect();
        let contours: heapless::Vec<ContourPoint, 40> = (0..33)
            .map(|i| ContourPoint {
                m_w: [0.0, 0.0, i as f32],
                cov_w: [1e-6, 0.0, 0.0, 1e-6, 0.0, 1e-6],
                n: [1.0, 0.0],
                d: 0.0,
                var_d: 1e-6,
            })
            .collect();
        let msgs: heapless::Vec<HostToCore, 8> =
            frame_messages(3, 5, &points, &contours).unwrap().collect();
        // 2 point parts (16 + 4), then 3 contour parts (16 + 16 + 1).
        assert_eq!(msgs.len(), 5);
        let mut seen_points = 0;
        let mut seen_contours = 0;
        for (i, m) in msgs.iter().enumerate() {
            match m {
                HostToCore::Correspondences(c) => {
                    assert!(i < 2);
                    assert_eq!(
                        (c.frame_id, c.trigger_us, c.part, c.parts),
                        (3, 5, i as u8, 5)
                    );
                    assert_eq!(
                        &c.items[..],
                        &points[seen_points..seen_points + c.items.len()]
                    );
                    seen_points += c.items.len();
                }
                HostToCore::Contours(c) => {
                    assert!(i >= 2);
                    assert_eq!(
                        (c.frame_id, c.trigger_us, c.part, c.parts),
                        (3, 5, i as u8, 5)
                    );
                    let want = &contours[seen_contours..seen_contours + c.items.len()];
                    assert_eq!(&c.items[..], want);
                    seen_contours += c.items.len();
                }
                other => panic!("unexpected {}", other.kind()),
            }
            assert!(m.validate().is_ok());
        }
        assert_eq!((seen_points, seen_contours), (20, 33));
        // Contours alone: no empty point part.
        let only: heapless::Vec<HostToCore, 8> =
            frame_messages(3, 5, &[], &contours).unwrap().collect();
        assert_eq!(only.len(), 3);
        assert!(only.iter().all(|m| matches!(m, HostToCore::Contours(_))));
        // The parts of both kinds are counted against one limit: 8 × 16 points and one contour
        // need nine messages.
        let full = [corr(0); MAX_CORRESPONDENCES_PER_MESSAGE * MAX_PARTS_PER_FRAME];
        assert_eq!(
            frame_messages(0, 0, &full, &contours[..1]).err(),
            Some(TooManyCorrespondences {
                count: full.len() + 1
            })
        );
    }
}
