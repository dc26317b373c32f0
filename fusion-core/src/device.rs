//! The device loop: a `no_std` state machine that turns host messages into filter calls and
//! answers with core messages. The PC simulator and the firmware image both wrap exactly this
//! ([`DeviceIo`] adds the byte framing).

use nalgebra::Vector3;
use protocol::{
    Capacities, Config, CoreToHost, DecodeError, Decoder, ErrorCode, Health, HostToCore, Init,
    InitAttitude, MAX_CORRESPONDENCES_PER_FRAME, MAX_CORRESPONDENCES_PER_MESSAGE, MAX_FRAME_LEN,
    Mode, PosePrediction, StateReport, Status, StatusReason, Sym6, UpdateOutcome, UpdateReport,
    encode_frame, handshake, sym_index,
};

use crate::delay::{DelayLine, IMU_BUFFER, MAX_PENDING_FRAMES, Missing, Snapshot};
use crate::divergence::Monitor;
use crate::filter::{Filter, ImuSample, MAX_STEPS_PER_SAMPLE};
use crate::init::{StillWindow, initialise};
use crate::kernels::Kernels;
use crate::models::correspondence::Rejection;
use crate::onboard::{Onboard, OnboardEvent};
use crate::params::Params;
use crate::part::Part;
use crate::quat::{self, Quat};
use crate::scalar::Scalar;
use crate::state::{self, ACC, ACC_BIAS, GYRO_BIAS, OMEGA, POS, State, VEL};

/// Largest IMU interval integrated as dead reckoning [µs]; a longer jump, or a time stamp
/// going backwards, is refused until the new clock is confirmed. The filter refuses a longer
/// interval too, whatever the device lets through ([`crate::filter::MAX_INTERVAL_US`]).
pub const MAX_GAP_US: u64 = crate::filter::MAX_INTERVAL_US;

/// Most time updates one message can cost, whatever its time stamps say: a sample's own
/// ([`MAX_STEPS_PER_SAMPLE`]), and re-propagating every pending frame and the frame answered
/// through the whole sample ring (each buffered sample was accepted within [`MAX_GAP_US`] of
/// the one before it). `Counters::time_updates` counts them.
pub const MAX_TIME_UPDATES_PER_MESSAGE: u32 =
    MAX_STEPS_PER_SAMPLE * (1 + (MAX_PENDING_FRAMES as u32 + 1) * IMU_BUFFER as u32);

/// Consecutive consistent samples on a new clock after which the core accepts a clock jump
/// and re-initialises.
pub const CLOCK_JUMP_CONFIRM: u8 = 3;

/// Camera periods (of IMU time, so that it holds when triggers stop) without accepted
/// correspondences after which the mode is dead reckoning.
pub const NO_VISION_FRAMES: u16 = 3;

/// A divergence within this time [µs] of the last accepted vision update, with a finite
/// state, is answered by a soft re-initialisation: the estimate is kept (it was anchored by
/// vision a moment ago and dead-reckoned since) and the covariance reset to the initial one,
/// so vision snaps on again at once even while the device moves. Later, or when the state is
/// not finite, the full re-initialisation (still window, the anchor's position and yaw)
/// follows. The same window bounds how long the anchor's yaw is trusted to the tilt σ: a
/// hand-held device turns by more than that within a fraction of a second, so an older yaw
/// restarts with the configured yaw σ, as if none were known.
pub const SOFT_RESET_WINDOW_US: u64 = 500_000;

/// Inputs refused or dropped, by reason. Every counter saturates at `u32::MAX` (it never
/// wraps, so a saturated counter still reads "at least this many"); all go through
/// [`Counters::bump`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Frames the decoder rejected.
    pub decode_errors: u32,
    /// Messages failing field validation.
    pub invalid_messages: u32,
    /// Messages refused for the device's state: before `Hello` or `Configure`, or meant for
    /// another model (`Imu` to the vision-only model, `Tick` to an inertial one, a vision-only
    /// `Init` without the full orientation).
    pub out_of_order: u32,
    /// IMU samples refused for their time stamp.
    pub imu_time_rejected: u32,
    /// IMU samples applied.
    pub imu_applied: u32,
    /// Pose predictions sent.
    pub predictions: u32,
    /// Correspondence parts applied.
    pub parts_applied: u32,
    /// Parts refused (too old, duplicate, unknown, not running).
    pub parts_refused: u32,
    /// Correspondences applied.
    pub accepted: u32,
    /// Correspondences gated out (eq. 17).
    pub gated: u32,
    /// Correspondences with the model point behind the camera.
    pub behind_camera: u32,
    /// Correspondences with a singular innovation covariance.
    pub singular: u32,
    /// Correspondences that passed the gate but were withheld with their part, most of whose
    /// correspondences failed it, after a soft re-initialisation (docs/FILTER.md §7).
    pub withheld: u32,
    /// Divergences detected.
    pub divergences: u32,
    /// Clock jumps accepted.
    pub clock_jumps: u32,
    /// Time-update steps run, re-propagation included: the work the samples cost (at most
    /// [`MAX_TIME_UPDATES_PER_MESSAGE`] per message).
    pub time_updates: u32,
    /// Answers held back because a number in them was not finite (the filter is then declared
    /// diverged).
    pub non_finite_held: u32,
}

impl Counters {
    const ZERO: Counters = Counters {
        decode_errors: 0,
        invalid_messages: 0,
        out_of_order: 0,
        imu_time_rejected: 0,
        imu_applied: 0,
        predictions: 0,
        parts_applied: 0,
        parts_refused: 0,
        accepted: 0,
        gated: 0,
        behind_camera: 0,
        singular: 0,
        withheld: 0,
        divergences: 0,
        clock_jumps: 0,
        time_updates: 0,
        non_finite_held: 0,
    };

    /// Counts one event: saturating, so that no input can overflow a counter (a host can
    /// send junk frames at line rate for years).
    #[inline]
    pub fn bump(counter: &mut u32) {
        *counter = counter.saturating_add(1);
    }
}

/// Where the device is in its life cycle. An explicit tag (first variant 0) keeps the
/// unconfigured device all zero bytes, so a firmware `static` holding it lands in `.bss`.
#[derive(Clone, Debug)]
#[repr(u8)]
enum Phase<T: Scalar> {
    Unconfigured,
    AwaitingInit,
    Initialising {
        position: Vector3<T>,
        attitude: InitAttitude,
        /// Whether the yaw (if given) is known to the tilt σ, or only to the yaw σ.
        yaw_known: bool,
        window: StillWindow<T>,
    },
    Running,
}

/// A candidate new IMU clock: a time stamp refused as a jump, and how many consistent samples
/// followed it.
#[derive(Clone, Copy, Debug)]
struct ClockCandidate {
    last_us: u64,
    count: u8,
}

/// Where a full re-initialisation restarts from: the pose of the last accepted vision update,
/// or, before any, the one the last `Init` gave.
#[derive(Clone, Copy, Debug)]
struct Anchor<T: Scalar> {
    position: Vector3<T>,
    /// Orientation `q_sw` (the vision-only model restarts from all of it; the inertial models
    /// take only the yaw, roll and pitch coming from gravity again). Zero in [`Self::NONE`].
    q_sw: Quat<T>,
    /// Yaw of the sensor in the world [rad], if known (not after a `Gravity` init without
    /// vision since).
    yaw: Option<T>,
    /// Set by accepted vision (not by `Init`).
    from_vision: bool,
    /// IMU time since it was set [µs], saturating; `u64::MAX` (unknown) after a clock jump.
    age_us: u64,
}

impl<T: Scalar> Anchor<T> {
    /// No anchor before the first `Init` (all zero bytes, so that the firmware's `static`
    /// device stays in `.bss`; it is never restarted from).
    const NONE: Anchor<T> = Anchor {
        position: Vector3::new(T::ZERO, T::ZERO, T::ZERO),
        q_sw: Quat::new(T::ZERO, T::ZERO, T::ZERO, T::ZERO),
        yaw: None,
        from_vision: false,
        age_us: 0,
    };

    /// Whether vision anchored the estimate within [`SOFT_RESET_WINDOW_US`].
    fn recent_vision(&self) -> bool {
        self.from_vision && self.age_us <= SOFT_RESET_WINDOW_US
    }
}

/// The fusion core's device loop.
#[derive(Clone, Debug)]
pub struct Device<T: Scalar> {
    greeted: bool,
    config: Option<Config>,
    prm: Option<Params<T>>,
    phase: Phase<T>,
    mode: Mode,
    filter: Filter<T>,
    delay: DelayLine<T>,
    monitor: Monitor<T>,
    last_t_us: Option<u64>,
    clock_candidate: Option<ClockCandidate>,
    anchor: Anchor<T>,
    /// IMU time since the covariance was last checked [µs].
    unchecked_us: u64,
    since_state: u16,
    /// After a soft re-initialisation, until a part is applied: a part most of whose
    /// correspondences fail the gate is withheld whole (docs/FILTER.md §7).
    consensus: bool,
    /// The part's snapshot state before its updates, while `consensus` holds (kept with the
    /// device: on the stack it raised the device loop's high-water mark by 3.7 KB).
    withheld_from: State<T>,
    counters: Counters,
    /// The core's own IMU: who samples, triggers, sampling counters.
    onboard: Onboard,
}

impl<T: Scalar> Default for Device<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// Output sink: every message the device sends goes through it.
pub type Out<'a> = &'a mut dyn FnMut(CoreToHost);

impl<T: Scalar> Device<T> {
    /// A device waiting for `Hello`; `const`, so that firmware can keep it in a `static`
    /// (built at compile time, all zeros, in `.bss`) rather than on the stack.
    pub const fn new() -> Self {
        Device {
            greeted: false,
            config: None,
            prm: None,
            phase: Phase::Unconfigured,
            mode: Mode::Unconfigured,
            filter: Filter::idle(),
            delay: DelayLine::new(),
            monitor: Monitor::new(),
            last_t_us: None,
            clock_candidate: None,
            anchor: Anchor::NONE,
            unchecked_us: 0,
            since_state: 0,
            counters: Counters::ZERO,
            consensus: false,
            withheld_from: State::zeroed(),
            onboard: Onboard::new(),
        }
    }

    /// Declares that the board has an IMU of its own, which the host may then ask the core to
    /// sample ([`protocol::HostToCore::Sampling`]); the board's sample path hands its samples
    /// to [`Device::onboard`]. Boards without one never call this.
    pub fn set_onboard_imu(&mut self, present: bool) {
        self.onboard.set_present(present);
    }

    /// The core's own IMU: who samples, and the sampling counters.
    pub fn onboard_state(&self) -> &Onboard {
        &self.onboard
    }

    /// What the device holds.
    pub fn capacities() -> Capacities {
        Capacities {
            max_frame_len: MAX_FRAME_LEN as u16,
            max_correspondences_per_message: MAX_CORRESPONDENCES_PER_MESSAGE as u16,
            max_correspondences_per_frame: MAX_CORRESPONDENCES_PER_FRAME as u16,
            delay_buffer_samples: IMU_BUFFER as u16,
            max_pending_frames: MAX_PENDING_FRAMES as u16,
            scalar_bits: T::BITS,
        }
    }

    /// Current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Counters of refused and applied inputs.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The live filter (tests, benchmarks).
    pub fn filter(&self) -> &Filter<T> {
        &self.filter
    }

    /// The active parameters, once configured.
    pub fn params(&self) -> Option<&Params<T>> {
        self.prm.as_ref()
    }
}

// What runs the filter needs its hot paths compiled in this crate (`crate::kernels`).
impl<T: Kernels> Device<T> {
    /// Reports a frame the decoder rejected.
    pub fn decode_error(&mut self, e: DecodeError, out: Out) {
        Counters::bump(&mut self.counters.decode_errors);
        out(CoreToHost::error(ErrorCode::Decode(e)));
    }

    /// A host link was opened (a connection accepted, a port opened, USB's DTR raised): whoever
    /// is on it must shake hands before it drives the core (issue 55: a core stayed greeted
    /// until it rebooted, so bytes from a later peer were taken without a `Hello`). The session
    /// itself (configuration, filter) is kept for a host that comes back (protocol/PROTOCOL.md
    /// §8).
    pub fn link_opened(&mut self) {
        self.greeted = false;
    }

    /// Handles one message. Nothing non-finite leaves the core: an answer that would carry an
    /// infinity or a NaN (a state beyond f32's range) is held back and the filter declared
    /// diverged.
    pub fn handle(&mut self, msg: &HostToCore, out: Out) {
        let mut held = false;
        self.handle_checked(msg, &mut |m| hold_non_finite(m, &mut held, out));
        if held {
            self.non_finite_output(out);
        }
    }

    /// Holds back an answer that is not finite.
    fn non_finite_output(&mut self, out: Out) {
        Counters::bump(&mut self.counters.non_finite_held);
        if let Some(prm) = self.prm {
            let mut again = false;
            self.diverged(StatusReason::NonFiniteState, &prm, &mut |m| {
                hold_non_finite(m, &mut again, out)
            });
        }
    }

    fn handle_checked(&mut self, msg: &HostToCore, out: Out) {
        if let Err(field) = msg.validate() {
            Counters::bump(&mut self.counters.invalid_messages);
            out(CoreToHost::error(ErrorCode::Invalid(field)));
            return;
        }
        match msg {
            HostToCore::Hello(h) => {
                let answer = handshake::answer_hello(
                    h.version,
                    self.config.map(|c| c.model),
                    self.config.map_or(0, |c| c.session),
                    Self::capacities(),
                );
                // A refused `Hello` (another major version) changes nothing: the core keeps
                // its session for its own host (protocol/PROTOCOL.md §8).
                self.greeted |= matches!(answer, CoreToHost::HelloAck(_));
                out(answer);
            }
            _ if !self.greeted => {
                Counters::bump(&mut self.counters.out_of_order);
                out(CoreToHost::error(ErrorCode::NoHandshake));
            }
            HostToCore::Configure(c) => self.configure(c, out),
            HostToCore::Init(i) => self.init(i, out),
            HostToCore::Imu(_) | HostToCore::Tick(_) if self.onboard.core_samples() => {
                Counters::bump(&mut self.counters.out_of_order);
                out(CoreToHost::error(ErrorCode::HostImuWhileCoreSamples));
            }
            HostToCore::Imu(s) => self.imu(s, out),
            HostToCore::Tick(t) => self.tick(t, out),
            HostToCore::Sampling(s) => match self.onboard.choose(*s) {
                Ok(report) => out(CoreToHost::Sampling(report)),
                Err(()) => {
                    Counters::bump(&mut self.counters.out_of_order);
                    out(CoreToHost::error(ErrorCode::NoOnboardImu));
                }
            },
            HostToCore::Correspondences(c) => self.correspondences(Part::Points(c), out),
            HostToCore::Contours(c) => self.correspondences(Part::Contours(c), out),
            HostToCore::Query => {
                out(CoreToHost::Status(Status {
                    t_us: self.last_t_us.unwrap_or(0),
                    mode: self.mode,
                    reason: StatusReason::Queried,
                }));
                if matches!(self.phase, Phase::Running) {
                    out(CoreToHost::State(self.state_report()));
                }
            }
            HostToCore::Resume(r) => self.resume(r, out),
            HostToCore::Reset => {
                self.restart_clock();
                if self.prm.is_some() {
                    self.restart_phase(Phase::AwaitingInit);
                    self.set_mode(Mode::AwaitingInit, StatusReason::HostRequest, out);
                } else {
                    self.set_mode(Mode::Unconfigured, StatusReason::HostRequest, out);
                }
            }
        }
    }

    /// Takes one event of the board's sample path (docs/ARCHITECTURE.md, "The core's own
    /// IMU"). While the core samples its own IMU, it sends the raw sample (if asked), the
    /// camera trigger and the sampling reports, and runs the filter on the sample exactly as
    /// on an `Imu` message from the host (a `Tick` in the vision-only model): validated, with
    /// the same time-stamp rules. While the host samples, the board's samples are dropped.
    pub fn onboard(&mut self, event: &OnboardEvent, out: Out) {
        let mut held = false;
        self.onboard_checked(event, &mut |m| hold_non_finite(m, &mut held, out));
        if held {
            self.non_finite_output(out);
        }
    }

    fn onboard_checked(&mut self, event: &OnboardEvent, out: Out) {
        let sent = self.onboard.take(event);
        if let Some(raw) = sent.raw {
            out(CoreToHost::RawImu(raw));
        }
        if let Some(trigger) = sent.trigger {
            out(CoreToHost::Trigger(trigger));
        }
        if let Some(report) = sent.report {
            out(CoreToHost::Sampling(report));
        }
        let OnboardEvent::Sample(s) = event else {
            return;
        };
        // A greeted host chose core sampling; the filter runs on through a new link's
        // handshake (`link_opened`), as through the host's absence.
        if !self.onboard.core_samples() || self.config.is_none() {
            return;
        }
        let msg = if self.prm.as_ref().is_some_and(|p| !p.model.has_imu()) {
            HostToCore::Tick(protocol::Tick {
                t_us: s.t_us,
                trigger: s.trigger,
            })
        } else {
            HostToCore::Imu(*s)
        };
        if let Err(field) = msg.validate() {
            Counters::bump(&mut self.counters.invalid_messages);
            out(CoreToHost::error(ErrorCode::Invalid(field)));
            return;
        }
        match msg {
            HostToCore::Tick(t) => self.tick(&t, out),
            _ => self.imu(s, out),
        }
    }

    /// A new session (`Configure`, `Reset`) has a clock of its own: its first time stamp may
    /// be any, as a restarted host's or sensor's is.
    fn restart_clock(&mut self) {
        self.last_t_us = None;
        self.clock_candidate = None;
    }

    fn restart_phase(&mut self, phase: Phase<T>) {
        self.phase = phase;
        self.delay.clear();
        self.monitor = Monitor::default();
        self.unchecked_us = 0;
        self.since_state = 0;
        self.consensus = false;
    }

    fn set_mode(&mut self, mode: Mode, reason: StatusReason, out: Out) {
        self.mode = mode;
        out(CoreToHost::Status(Status {
            t_us: self.last_t_us.unwrap_or(0),
            mode,
            reason,
        }));
    }

    fn configure(&mut self, c: &Config, out: Out) {
        self.config = Some(*c);
        self.prm = Some(Params::from_config(c));
        self.anchor = Anchor::NONE;
        self.restart_clock();
        self.restart_phase(Phase::AwaitingInit);
        self.set_mode(Mode::AwaitingInit, StatusReason::Configured, out);
    }

    fn init(&mut self, i: &Init, out: Out) {
        let Some(prm) = &self.prm else {
            Counters::bump(&mut self.counters.out_of_order);
            out(CoreToHost::error(ErrorCode::NotConfigured));
            return;
        };
        if !prm.model.has_imu() && !matches!(i.attitude, InitAttitude::Full(_)) {
            Counters::bump(&mut self.counters.out_of_order);
            out(CoreToHost::error(ErrorCode::VisionNeedsFullPose));
            return;
        }
        let p = Vector3::new(
            T::from_wire(i.position[0]),
            T::from_wire(i.position[1]),
            T::from_wire(i.position[2]),
        );
        if let InitAttitude::KeepTilt(yaw) = i.attitude
            && matches!(self.phase, Phase::Running)
        {
            let prm = *prm;
            self.reanchor(&p, T::from_wire(yaw), &prm, out);
            return;
        }
        // A later full re-initialisation without vision since restarts from what was given.
        let (yaw, q_sw) = match i.attitude {
            InitAttitude::Gravity => (None, quat::identity()),
            InitAttitude::GravityAndYaw(yaw) | InitAttitude::KeepTilt(yaw) => {
                (Some(T::from_wire(yaw)), quat::identity())
            }
            InitAttitude::Full(q) => {
                let f = T::from_wire;
                let q_sw = Quat::new(f(q[0]), f(q[1]), f(q[2]), f(q[3]));
                (Some(quat::yaw_of(&quat::conj(&q_sw))), q_sw)
            }
        };
        self.anchor = Anchor {
            position: p,
            q_sw,
            yaw,
            from_vision: false,
            age_us: 0,
        };
        self.restart_phase(Phase::Initialising {
            position: p,
            attitude: i.attitude,
            yaw_known: true,
            window: StillWindow::default(),
        });
        self.set_mode(Mode::Initialising, StatusReason::HostRequest, out);
    }

    /// Starts the filter at once from a state the core reported before it was reset
    /// (`HostToCore::Resume`, protocol/PROTOCOL.md §8): the estimate as it was, at its time
    /// (the first sample propagates it from there), with the initial covariance and the tilt
    /// σ about the vertical too, as a soft re-initialisation has. No still window: the device
    /// is moving, and gravity could not level it. The anchor is that state: it was tracked.
    /// The core's clock is the state's time: the next sample must come after it, within
    /// [`MAX_GAP_US`], as after any sample.
    fn resume(&mut self, r: &protocol::Resume, out: Out) {
        let Some(prm) = self.prm else {
            Counters::bump(&mut self.counters.out_of_order);
            out(CoreToHost::error(ErrorCode::NotConfigured));
            return;
        };
        let f = T::from_wire;
        let v = |a: &[f32; 3]| Vector3::new(f(a[0]), f(a[1]), f(a[2]));
        let q = &r.q_sw;
        let q_sw = Quat::new(f(q[0]), f(q[1]), f(q[2]), f(q[3])).normalize();
        let st = &mut self.filter.st;
        st.x.fill(T::zero());
        st.set_v3(POS, &v(&r.s_w));
        st.set_v3(VEL, &v(&r.v_w));
        st.set_q(&q_sw);
        st.set_v3(OMEGA, &v(&r.omega_s));
        if prm.model.has_imu() {
            st.set_v3(GYRO_BIAS, &v(&r.gyro_bias));
        }
        if matches!(
            prm.model,
            protocol::ModelKind::Gravity | protocol::ModelKind::Acc
        ) {
            st.set_v3(ACC_BIAS, &v(&r.accel_bias));
        }
        if prm.model == protocol::ModelKind::Acc {
            st.set_v3(ACC, &v(&r.a_w));
        }
        crate::init::reset_covariance(st, &prm, f(prm.init_sigma.tilt));
        self.filter.t_us = r.t_us;
        self.filter.quat_norm_error = T::zero();
        self.last_t_us = Some(r.t_us);
        self.clock_candidate = None;
        self.anchor = Anchor {
            position: v(&r.s_w),
            q_sw,
            yaw: Some(quat::yaw_of(&quat::conj(&q_sw))),
            from_vision: true,
            age_us: 0,
        };
        self.restart_phase(Phase::Running);
        self.set_mode(Mode::Reinitialising, StatusReason::HostRequest, out);
        self.set_mode(Mode::DeadReckoning, StatusReason::InitComplete, out);
    }

    /// Re-anchors the running filter at a pose the host found (`InitAttitude::KeepTilt`; the
    /// cold start's fusion, docs/notes/issue15-cold-start.md §6): position and yaw from it; roll and pitch
    /// kept, since the accelerometer has levelled them while the filter ran and a single found
    /// pose knows them no better; velocity and acceleration kept with their covariance (a pose
    /// says nothing of them, and the filter knows how far dead reckoning has let them drift);
    /// the biases and angular velocity kept; the rest of the covariance restarted at its
    /// initial σ, the yaw's at the tilt σ (a verified pose knows it that well). No still
    /// window: the device is moving.
    fn reanchor(&mut self, position: &Vector3<T>, yaw: T, prm: &Params<T>, out: Out) {
        let st = &mut self.filter.st;
        let q_ws = quat::conj(&st.q());
        let turn = quat::from_axis_angle(&Vector3::z(), yaw - quat::yaw_of(&q_ws));
        let q_sw = quat::conj(&quat::mul(&turn, &q_ws)).normalize();
        st.set_q(&q_sw);
        st.set_v3(POS, position);
        // The motion's own estimate and its uncertainty, which dead reckoning has grown.
        let p_vel = st.p.fixed_view::<3, 3>(VEL, VEL).into_owned();
        let p_acc = st.p.fixed_view::<3, 3>(ACC, ACC).into_owned();
        crate::init::reset_covariance(st, prm, T::from_wire(prm.init_sigma.tilt));
        st.p.fixed_view_mut::<3, 3>(VEL, VEL).copy_from(&p_vel);
        if prm.model == protocol::ModelKind::Acc {
            st.p.fixed_view_mut::<3, 3>(ACC, ACC).copy_from(&p_acc);
        }
        self.filter.quat_norm_error = T::zero();
        // Pending snapshots hold the old estimate: their frames are refused as too old.
        self.delay.clear();
        self.monitor = Monitor::default();
        self.consensus = false;
        self.anchor = Anchor {
            position: *position,
            q_sw,
            yaw: Some(yaw),
            from_vision: false,
            age_us: 0,
        };
        self.set_mode(Mode::Reinitialising, StatusReason::HostRequest, out);
        self.set_mode(Mode::DeadReckoning, StatusReason::InitComplete, out);
    }

    /// Checks an IMU time stamp; `Ok(true)` when a confirmed clock jump re-anchored the time.
    fn check_time(&mut self, t_us: u64, out: Out) -> Result<bool, ()> {
        let Some(last) = self.last_t_us else {
            return Ok(false);
        };
        if t_us > last && t_us - last <= MAX_GAP_US {
            self.clock_candidate = None;
            return Ok(false);
        }
        // Refused unless it confirms a new clock: see whether one is being confirmed.
        let count = match self.clock_candidate {
            Some(c) if t_us > c.last_us && t_us - c.last_us <= MAX_GAP_US => c.count + 1,
            _ => 1,
        };
        if count >= CLOCK_JUMP_CONFIRM {
            self.clock_candidate = None;
            Counters::bump(&mut self.counters.clock_jumps);
            return Ok(true);
        }
        self.clock_candidate = Some(ClockCandidate {
            last_us: t_us,
            count,
        });
        Counters::bump(&mut self.counters.imu_time_rejected);
        let code = if t_us <= last {
            ErrorCode::TimestampNotIncreasing {
                last_us: last,
                got_us: t_us,
            }
        } else {
            ErrorCode::TimestampGap {
                last_us: last,
                got_us: t_us,
            }
        };
        out(CoreToHost::error(code));
        Err(())
    }

    fn imu(&mut self, wire: &protocol::ImuSample, out: Out) {
        self.advance(&ImuSample::<T>::from_wire(wire), wire.trigger, true, out);
    }

    fn tick(&mut self, t: &protocol::Tick, out: Out) {
        let sample = ImuSample {
            t_us: t.t_us,
            gyro: Vector3::zeros(),
            accel: Vector3::zeros(),
        };
        self.advance(&sample, t.trigger, false, out);
    }

    /// One step of the device's clock: an IMU sample (`inertial`), or a vision-only tick (a
    /// sample without readings, which the vision-only model's step never reads).
    fn advance(&mut self, sample: &ImuSample<T>, trigger: bool, inertial: bool, out: Out) {
        // The parameters are read in place where the work is (a copy of `Params` costs ~180
        // instructions per message), and copied only on the rare paths that need `&mut self`.
        let Some(prm) = self.prm.as_ref() else {
            Counters::bump(&mut self.counters.out_of_order);
            out(CoreToHost::error(ErrorCode::NotConfigured));
            return;
        };
        let (has_imu, still_samples) = (prm.model.has_imu(), prm.still_samples);
        if inertial != has_imu {
            Counters::bump(&mut self.counters.out_of_order);
            out(CoreToHost::error(if inertial {
                ErrorCode::ImuInVisionModel
            } else {
                ErrorCode::TickInInertialModel
            }));
            return;
        }
        let jumped = match self.check_time(sample.t_us, out) {
            Ok(j) => j,
            Err(()) => return,
        };
        // IMU time since the last sample; after a clock jump the time between the two clocks
        // is unknown, and so is the anchor's age.
        let dt = match self.last_t_us {
            Some(last) if !jumped => sample.t_us.saturating_sub(last),
            _ => 0,
        };
        self.anchor.age_us = if jumped {
            u64::MAX
        } else {
            self.anchor.age_us.saturating_add(dt)
        };
        self.unchecked_us = self.unchecked_us.saturating_add(dt);
        self.last_t_us = Some(sample.t_us);
        if jumped
            && matches!(self.phase, Phase::Running)
            && let Some(prm) = self.prm
        {
            self.reinitialise(StatusReason::TimeJump, &prm, out);
        }
        // The vision-only model has no still window: it starts at its first tick, and that
        // tick is also its first step (its trigger is answered).
        let (needed, step_now) = if has_imu {
            (still_samples, false)
        } else {
            (1, true)
        };
        match &mut self.phase {
            Phase::Unconfigured | Phase::AwaitingInit => {}
            Phase::Initialising {
                position,
                attitude,
                yaw_known,
                window,
            } => {
                if window.add(&sample.gyro, &sample.accel, needed)
                    && let Some(prm) = &self.prm
                {
                    initialise(
                        &mut self.filter.st,
                        prm,
                        position,
                        attitude,
                        *yaw_known,
                        window,
                    );
                    self.filter.t_us = sample.t_us;
                    self.filter.quat_norm_error = T::zero();
                    self.restart_phase(Phase::Running);
                    self.set_mode(Mode::DeadReckoning, StatusReason::InitComplete, out);
                    if step_now {
                        self.step(sample, trigger, out);
                    }
                }
            }
            Phase::Running => self.step(sample, trigger, out),
        }
    }

    fn step(&mut self, sample: &ImuSample<T>, trigger: bool, out: Out) {
        if let Some(frame) = self.delay.expiring_dirty(trigger)
            && let Some(prm) = self.prm
            && !self.flush(frame, &prm, out)
        {
            return;
        }
        let Some(prm) = &self.prm else { return };
        if let Err(reason) =
            self.filter
                .imu_step_counted(prm, sample, &mut self.counters.time_updates)
        {
            let prm = *prm;
            self.diverged(reason, &prm, out);
            return;
        }
        Counters::bump(&mut self.counters.imu_applied);
        self.delay.push(*sample);
        // Test 2 at each trigger, and at least once per camera period if triggers stop.
        if trigger || self.unchecked_us >= prm.camera_period_us {
            self.unchecked_us = 0;
            if let Some(reason) = Monitor::frame(&self.filter.st, prm) {
                let prm = *prm;
                self.diverged(reason, &prm, out);
                return;
            }
        }
        if trigger {
            let frame_id = self.delay.snapshot(&self.filter);
            Counters::bump(&mut self.counters.predictions);
            out(CoreToHost::PosePrediction(self.prediction(frame_id)));
        }
        if self.mode == Mode::Tracking && self.anchor.age_us >= no_vision_us(prm) {
            self.set_mode(Mode::DeadReckoning, StatusReason::NoVision, out);
        }
        let every = self.config.map_or(0, |c| c.state_every);
        if every > 0 {
            self.since_state += 1;
            if self.since_state >= every {
                self.since_state = 0;
                out(CoreToHost::State(self.state_report()));
            }
        }
    }

    /// Propagates a dirty frame's update to the present; false if that diverged.
    fn flush(&mut self, frame_id: u32, prm: &Params<T>, out: Out) -> bool {
        let steps = &mut self.counters.time_updates;
        match self
            .delay
            .repropagate(frame_id, prm, &mut self.filter, steps)
        {
            Some(Ok(())) => true,
            Some(Err(reason)) => {
                self.diverged(reason, prm, out);
                false
            }
            None => true,
        }
    }

    /// The configured hand-eye (the identity before a configuration).
    fn hand_eye(&self) -> state::HandEye<T> {
        self.prm
            .as_ref()
            .map(|p| p.hand_eye)
            .unwrap_or(state::HandEye {
                q_cs: quat::identity(),
                r_cs: nalgebra::Matrix3::identity(),
                c_s: Vector3::zeros(),
            })
    }

    fn prediction(&self, frame_id: u32) -> PosePrediction {
        let pose = state::camera_pose(&self.filter.st, &self.hand_eye());
        PosePrediction {
            frame_id,
            t_us: self.filter.t_us,
            c_w: v3(&pose.c_w),
            q_cw: [
                pose.q_cw[0].to_wire(),
                pose.q_cw[1].to_wire(),
                pose.q_cw[2].to_wire(),
                pose.q_cw[3].to_wire(),
            ],
            cov: sym6(&pose.cov),
        }
    }

    fn state_report(&self) -> StateReport {
        let st = &self.filter.st;
        let q = st.q();
        StateReport {
            t_us: self.filter.t_us,
            s_w: w3(&st.x.as_slice()[POS..]),
            q_sw: [
                q[0].to_wire(),
                q[1].to_wire(),
                q[2].to_wire(),
                q[3].to_wire(),
            ],
            v_w: w3(&st.x.as_slice()[VEL..]),
            a_w: w3(&st.x.as_slice()[ACC..]),
            omega_s: w3(&st.x.as_slice()[OMEGA..]),
            gyro_bias: w3(&st.x.as_slice()[GYRO_BIAS..]),
            accel_bias: w3(&st.x.as_slice()[ACC_BIAS..]),
            health: Health {
                mode: self.mode,
                covariance_frobenius: st.cov_frobenius().to_wire(),
                residual_lowpass: self.monitor.g.to_wire(),
                quaternion_norm_error: self.filter.quat_norm_error.to_wire(),
            },
            cov: sym6(&state::camera_pose(st, &self.hand_eye()).cov),
        }
    }

    /// Applies one part of a frame's correspondences (points or contours) to the frame's
    /// snapshot and answers with its `UpdateReport`; then restarts on a divergence, or
    /// propagates a completed frame to the present and tracks from an accepted update.
    fn correspondences(&mut self, c: Part<'_>, out: Out) {
        let mut report = UpdateReport {
            frame_id: c.frame_id(),
            part: c.index(),
            outcome: UpdateOutcome::Applied,
            accepted: 0,
            rejected: 0,
            residuals: heapless::Vec::new(),
            prediction_error: 0.0,
        };
        let (Some(prm), Phase::Running) = (self.prm, &self.phase) else {
            self.refuse_part(report, UpdateOutcome::NotRunning, out);
            return;
        };
        // Older frames' pending updates go first, so this frame's snapshot is current.
        if !self.flush_older_frames(c.frame_id(), &prm, out) {
            report.outcome = UpdateOutcome::NotRunning;
            out(CoreToHost::UpdateReport(report));
            return;
        }
        let done = match self.update_snapshot(&c, &prm, &mut report) {
            Ok(done) => done,
            Err(outcome) => {
                self.refuse_part(report, outcome, out);
                return;
            }
        };
        Counters::bump(&mut self.counters.parts_applied);
        let frame_id = c.frame_id();
        out(CoreToHost::UpdateReport(report.clone()));

        if let Some(reason) = done.diverged {
            self.diverged(reason, &prm, out);
            return;
        }
        if done.needs_flush && !self.flush(frame_id, &prm, out) {
            return;
        }
        if report.accepted > 0 {
            self.anchor_on_vision(done.good, out);
        }
    }

    /// Refuses a part: counted, and answered with `outcome`.
    fn refuse_part(&mut self, mut report: UpdateReport, outcome: UpdateOutcome, out: Out) {
        Counters::bump(&mut self.counters.parts_refused);
        report.outcome = outcome;
        out(CoreToHost::UpdateReport(report));
    }

    /// Propagates the pending updates of every frame but `frame_id` to the present; false if
    /// that diverged.
    fn flush_older_frames(&mut self, frame_id: u32, prm: &Params<T>, out: Out) -> bool {
        loop {
            let older = self.delay.dirty_frames().find(|&f| f != frame_id);
            let Some(older) = older else { return true };
            if !self.flush(older, prm, out) {
                return false;
            }
        }
    }

    /// Updates the part's frame snapshot by its correspondences, filling `report`; the
    /// outcome to refuse it with when the snapshot is gone or already has this part.
    fn update_snapshot(
        &mut self,
        c: &Part<'_>,
        prm: &Params<T>,
        report: &mut UpdateReport,
    ) -> Result<PartDone<T>, UpdateOutcome> {
        let snap = part_snapshot(&mut self.delay, c)?;
        // After a soft re-initialisation the part must agree with the state as a whole
        // (docs/FILTER.md §7): a copy to return to if most of it fails the gate.
        if self.consensus {
            self.withheld_from.x.copy_from(&snap.filter.st.x);
            self.withheld_from.p.copy_from(&snap.filter.st.p);
        }
        // Frames on either side of a gap are not consecutive looks at one state
        // (docs/FILTER.md §9, test 1).
        if !c.is_empty() {
            self.monitor.look(c.trigger_us(), no_vision_us(prm));
        }
        // Test 3 judges the frame's updates from the quaternion they started at (docs/FILTER.md
        // §6, §9).
        if snap.parts_done == 0 {
            snap.q_ref = snap.filter.st.q();
        }
        let (gated, mut diverged) =
            apply_items(c, snap, prm, report, &mut self.counters, &mut self.monitor);
        // The few that passed where most were gated are chance passes of outliers, or of a
        // state gone wrong: withheld either way, the part's updates undone.
        if self.consensus && report.accepted > 0 && u32::from(report.accepted) < gated {
            withhold_part(snap, &self.withheld_from, &mut self.counters, report);
        }
        // Applied updates that moved the quaternion off the sphere ask for the full restart.
        if report.accepted > 0
            && crate::ekf::radial_step(&snap.q_ref, &snap.filter.st.q()) > prm.quat_norm_threshold
        {
            diverged = Some(StatusReason::QuaternionNorm);
        }
        Ok(close_part(
            c,
            snap,
            prm,
            report,
            &mut self.monitor,
            diverged,
        ))
    }

    /// Accepted vision anchors the estimate at `good` (position, orientation) and tracks.
    fn anchor_on_vision(&mut self, good: (Vector3<T>, Quat<T>), out: Out) {
        self.consensus = false;
        self.anchor = Anchor {
            position: good.0,
            q_sw: good.1,
            yaw: Some(quat::yaw_of(&quat::conj(&good.1))),
            from_vision: true,
            age_us: 0,
        };
        if self.mode != Mode::Tracking {
            self.set_mode(Mode::Tracking, StatusReason::VisionAccepted, out);
        }
    }

    fn diverged(&mut self, reason: StatusReason, prm: &Params<T>, out: Out) {
        Counters::bump(&mut self.counters.divergences);
        self.set_mode(Mode::Diverged, reason, out);
        let recent = self.anchor.recent_vision();
        let sane = !matches!(
            reason,
            StatusReason::NonFiniteState | StatusReason::QuaternionNorm
        ) && self.filter.st.is_finite();
        if recent && sane && matches!(self.phase, Phase::Running) {
            // Soft re-initialisation: keep the estimate, restart its uncertainty. Pending
            // snapshots hold the old covariance: drop them (their frames are refused as too
            // old).
            let tilt = T::from_wire(prm.init_sigma.tilt);
            crate::init::reset_covariance(&mut self.filter.st, prm, tilt);
            self.delay.clear();
            self.monitor = Monitor::default();
            // What made it diverge may still be coming: outliers a wide gate lets through.
            self.consensus = true;
            self.set_mode(Mode::Reinitialising, reason, out);
            self.set_mode(Mode::DeadReckoning, StatusReason::InitComplete, out);
            return;
        }
        self.reinitialise(reason, prm, out);
    }

    /// Restarts from the anchor: the last good position and yaw, or those `Init` gave, with
    /// roll and pitch from a new still window. The yaw keeps the tilt σ only while the anchor
    /// is recent ([`SOFT_RESET_WINDOW_US`]); older, it restarts with the configured yaw σ.
    fn reinitialise(&mut self, reason: StatusReason, prm: &Params<T>, out: Out) {
        let a = self.anchor;
        let attitude = match a.yaw {
            // No gravity to level it: the vision-only model restarts from the whole anchor.
            _ if !prm.model.has_imu() => InitAttitude::Full([
                a.q_sw[0].to_wire(),
                a.q_sw[1].to_wire(),
                a.q_sw[2].to_wire(),
                a.q_sw[3].to_wire(),
            ]),
            Some(yaw) => InitAttitude::GravityAndYaw(yaw.to_wire()),
            None => InitAttitude::Gravity,
        };
        self.restart_phase(Phase::Initialising {
            position: a.position,
            attitude,
            yaw_known: a.age_us <= SOFT_RESET_WINDOW_US,
            window: StillWindow::default(),
        });
        self.set_mode(Mode::Reinitialising, reason, out);
    }
}

/// What applying a part leaves to do once it is answered.
struct PartDone<T: Scalar> {
    /// The first divergence the part revealed.
    diverged: Option<StatusReason>,
    /// Whether the part completed its frame, which has updates to propagate to the present.
    needs_flush: bool,
    /// Position and orientation after the part: the anchor, if it had an accepted update.
    good: (Vector3<T>, Quat<T>),
}

/// The snapshot of the part's frame, or the outcome to refuse the part with: too old (its
/// snapshot dropped, or a newer frame already applied), a duplicate, or an unknown frame.
fn part_snapshot<'d, T: Scalar>(
    delay: &'d mut DelayLine<T>,
    c: &Part<'_>,
) -> Result<&'d mut Snapshot<T>, UpdateOutcome> {
    let newer_applied = delay.newer_frame_applied(c.frame_id());
    match delay.find(c.frame_id(), c.trigger_us()) {
        Ok(_) if newer_applied => Err(UpdateOutcome::TooOld),
        Ok(s) if s.parts_done & (1 << c.index()) != 0 => Err(UpdateOutcome::Duplicate),
        Ok(s) => Ok(s),
        Err(Missing::TooOld) => Err(UpdateOutcome::TooOld),
        Err(Missing::Unknown) => Err(UpdateOutcome::UnknownFrame),
    }
}

/// Applies the part's correspondences one by one to the snapshot's state (each gated,
/// eq. 17): fills the report's residuals, counts and mean prediction error, counts each
/// outcome, and feeds the residual test. Returns how many were gated, and the first
/// divergence the residual test found.
fn apply_items<T: Kernels>(
    c: &Part<'_>,
    snap: &mut Snapshot<T>,
    prm: &Params<T>,
    report: &mut UpdateReport,
    counters: &mut Counters,
    monitor: &mut Monitor<T>,
) -> (u32, Option<StatusReason>) {
    let mut gated = 0u32;
    let mut diverged = None;
    let mut error_sum = T::zero();
    let mut error_count = 0u32;
    for item in c.items() {
        let applied = item.apply(&mut snap.filter.st, &snap.predicted, prm);
        if let Some(e) = applied.prediction_error {
            error_sum += e;
            error_count += 1;
        }
        let s_i = applied.nis;
        // Capacity equals the message's, so this cannot fail. A residual that cannot be
        // computed (behind the camera, singular) is infinite here and f32::MAX on the
        // wire: nothing non-finite leaves the core.
        let wire = s_i.to_wire();
        let _ = report
            .residuals
            .push(if wire.is_finite() { wire } else { f32::MAX });
        match applied.result {
            Ok(()) => {
                report.accepted += 1;
                Counters::bump(&mut counters.accepted);
            }
            Err(why) => {
                report.rejected += 1;
                gated += u32::from(why == Rejection::Gated);
                Counters::bump(match why {
                    Rejection::Gated => &mut counters.gated,
                    Rejection::BehindCamera => &mut counters.behind_camera,
                    Rejection::Singular => &mut counters.singular,
                });
            }
        }
        if let Some(reason) = monitor.residual(c.frame_id(), s_i, prm) {
            diverged.get_or_insert(reason);
        }
    }
    if error_count > 0 {
        report.prediction_error = (error_sum / T::c(error_count as f64)).to_wire();
    }
    (gated, diverged)
}

/// Withholds a part's updates: the snapshot's state goes back to `before`, and its accepted
/// correspondences count as withheld and rejected instead.
fn withhold_part<T: Scalar>(
    snap: &mut Snapshot<T>,
    before: &State<T>,
    counters: &mut Counters,
    report: &mut UpdateReport,
) {
    snap.filter.st.x.copy_from(&before.x);
    snap.filter.st.p.copy_from(&before.p);
    counters.withheld = counters.withheld.saturating_add(u32::from(report.accepted));
    counters.accepted = counters.accepted.saturating_sub(u32::from(report.accepted));
    report.rejected += report.accepted;
    report.accepted = 0;
}

/// Ends a part's update: conditions the covariance, marks the part done and the frame dirty
/// if it was updated, and closes the frame's residual test once all its parts are in.
fn close_part<T: Scalar>(
    c: &Part<'_>,
    snap: &mut Snapshot<T>,
    prm: &Params<T>,
    report: &UpdateReport,
    monitor: &mut Monitor<T>,
    mut diverged: Option<StatusReason>,
) -> PartDone<T> {
    crate::ekf::condition(&mut snap.filter.st.p, prm.n);
    snap.parts_done |= 1 << c.index();
    snap.dirty |= report.accepted > 0;
    let complete = snap.parts_done.count_ones() as u8 >= c.parts();
    let needs_flush = complete && snap.dirty;
    if complete && let Some(reason) = monitor.close_frame(prm) {
        diverged.get_or_insert(reason);
    }
    PartDone {
        diverged,
        needs_flush,
        good: (snap.filter.st.v3(POS), snap.filter.st.q()),
    }
}

/// Passes `m` on if it is finite, else notes that one was held back.
fn hold_non_finite(m: CoreToHost, held: &mut bool, out: Out) {
    if m.is_finite() {
        out(m);
    } else {
        *held = true;
    }
}

/// [`NO_VISION_FRAMES`] camera periods [µs]: the end of tracking, and a gap between frames.
fn no_vision_us<T: Scalar>(prm: &Params<T>) -> u64 {
    prm.camera_period_us
        .saturating_mul(u64::from(NO_VISION_FRAMES))
}

/// A 6×6 covariance's upper triangle for the wire.
fn sym6<T: Scalar>(m: &nalgebra::SMatrix<T, 6, 6>) -> Sym6 {
    let mut cov = [0.0f32; 21];
    for r in 0..6 {
        for c in r..6 {
            cov[sym_index(6, r, c)] = m[(r, c)].to_wire();
        }
    }
    cov
}

/// The first three values of `x` for the wire (read from the state vector in place).
fn w3<T: Scalar>(x: &[T]) -> [f32; 3] {
    match x {
        [a, b, c, ..] => [a.to_wire(), b.to_wire(), c.to_wire()],
        _ => [0.0; 3],
    }
}

fn v3<T: Scalar>(v: &Vector3<T>) -> [f32; 3] {
    [v[0].to_wire(), v[1].to_wire(), v[2].to_wire()]
}

/// The buffer answers are encoded in: kept with the device, so that it is not zeroed for
/// every `receive` (a frame's worth, 1 KB, per call), and off the stack.
#[derive(Clone)]
struct AnswerBuf([u8; MAX_FRAME_LEN]);

impl core::fmt::Debug for AnswerBuf {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("AnswerBuf")
    }
}

impl Default for AnswerBuf {
    fn default() -> Self {
        AnswerBuf([0; MAX_FRAME_LEN])
    }
}

/// The device behind a byte stream: decodes frames, handles them, encodes the answers.
#[derive(Clone, Debug, Default)]
pub struct DeviceIo<T: Scalar> {
    /// The device loop.
    pub device: Device<T>,
    decoder: Decoder,
    answer: AnswerBuf,
}

impl<T: Scalar> DeviceIo<T> {
    /// A new device with an empty decoder (`const`: see [`Device::new`]).
    pub const fn new() -> Self {
        DeviceIo {
            device: Device::new(),
            decoder: Decoder::new(),
            answer: AnswerBuf([0; MAX_FRAME_LEN]),
        }
    }

    /// A host link was opened: a frame begun on the previous link is dropped, and the new
    /// peer must shake hands ([`Device::link_opened`]).
    pub fn link_opened(&mut self) {
        self.decoder = Decoder::new();
        self.device.greeted = false;
    }
}

impl<T: Kernels> DeviceIo<T> {
    /// Consumes received bytes; every answer is passed to `send` as one encoded frame.
    pub fn receive(&mut self, bytes: &[u8], send: &mut dyn FnMut(&[u8])) {
        let buf = &mut self.answer.0;
        let device = &mut self.device;
        let mut emit = |msg: CoreToHost| {
            // The core's own messages always fit a frame.
            if let Ok(frame) = encode_frame(&msg, buf) {
                send(frame);
            }
        };
        let mut rest = bytes;
        while !rest.is_empty() {
            // The message is handled where it was decoded (a `HostToCore` is ~1 KB).
            let (used, _) =
                self.decoder
                    .advance_with::<HostToCore, _>(rest, |result| match result {
                        Ok(msg) => device.handle(msg, &mut emit),
                        Err(e) => device.decode_error(e, &mut emit),
                    });
            rest = &rest[used..];
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::state::State;
    use core::mem::size_of;

    /// `m` handled by `d`; its answers.
    fn send<T: Kernels>(d: &mut Device<T>, m: HostToCore) -> std::vec::Vec<CoreToHost> {
        let mut got = std::vec::Vec::new();
        d.handle(&m, &mut |a| got.push(a));
        got
    }

    /// An IMU sample at rest at `t_us`.
    fn still_imu(t_us: u64) -> HostToCore {
        HostToCore::Imu(protocol::ImuSample {
            t_us,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            trigger: false,
        })
    }

    /// A device greeted, configured with `config` and started with `init`.
    fn started<T: Kernels>(config: protocol::Config, init: Init) -> Device<T> {
        let mut d = Device::<T>::new();
        let hello = protocol::Hello {
            version: protocol::PROTOCOL_VERSION,
        };
        send(&mut d, HostToCore::Hello(hello));
        send(&mut d, HostToCore::Configure(config));
        send(&mut d, HostToCore::Init(init));
        d
    }

    /// Defect 10 of issue 12: the counters were incremented with `+= 1`, which panics on
    /// overflow where overflow checks are on (this test profile), and `decode_errors` can be
    /// driven at line rate with 2-byte junk frames. Every counter goes through `bump`: 2³² + 1
    /// increments through it do not panic and saturate, and each counter saturates across the
    /// overflow boundary.
    #[test]
    fn counters_saturate_after_2_pow_32_increments() {
        let mut c = Counters::default();
        for _ in 0..=u64::from(u32::MAX) {
            Counters::bump(std::hint::black_box(&mut c.decode_errors));
        }
        assert_eq!(c.decode_errors, u32::MAX);
        let fields: [fn(&mut Counters) -> &mut u32; 16] = [
            |c| &mut c.decode_errors,
            |c| &mut c.invalid_messages,
            |c| &mut c.out_of_order,
            |c| &mut c.imu_time_rejected,
            |c| &mut c.imu_applied,
            |c| &mut c.predictions,
            |c| &mut c.parts_applied,
            |c| &mut c.parts_refused,
            |c| &mut c.accepted,
            |c| &mut c.gated,
            |c| &mut c.behind_camera,
            |c| &mut c.singular,
            |c| &mut c.withheld,
            |c| &mut c.divergences,
            |c| &mut c.clock_jumps,
            |c| &mut c.time_updates,
        ];
        for field in fields {
            let mut c = Counters::default();
            *field(&mut c) = u32::MAX - 2;
            for _ in 0..5 {
                Counters::bump(field(&mut c));
            }
            assert_eq!(*field(&mut c), u32::MAX);
            // Only that field moved.
            *field(&mut c) = 0;
            assert_eq!(c, Counters::default());
        }
    }

    /// A junk frame's counter goes through the device's own path: it saturates there too.
    #[test]
    fn decode_errors_saturate_through_the_device() {
        let mut d = Device::<f32>::new();
        d.counters.decode_errors = u32::MAX - 1;
        let mut errors = 0;
        for _ in 0..3 {
            d.decode_error(DecodeError::Crc, &mut |_| errors += 1);
        }
        assert_eq!((d.counters.decode_errors, errors), (u32::MAX, 3));
    }

    /// Issue 55, point 11: a state beyond f32's range (an f64 core) went out as ±inf. Now
    /// the answer is held back, counted, and the filter restarts from its anchor; and ‖q‖ far
    /// from 1 with a zero update step is caught by the norm itself.
    #[test]
    fn nothing_non_finite_leaves_the_core_and_the_quaternion_norm_is_tested() {
        let config = protocol::Config {
            state_every: 1,
            ..protocol::samples::config()
        };
        let imu = still_imu;
        let dt = (1e6 / f64::from(config.imu_rate_hz)) as u64;
        let n = u64::from(config.still_samples) + 20;
        for poison in [(0, 1e39), (crate::state::QUAT + 1, 3.0)] {
            let init = Init {
                position: [0.5, 0.0, 1.0],
                attitude: InitAttitude::GravityAndYaw(0.3),
            };
            let mut d = started::<f64>(config, init);
            for k in 1..=n {
                send(&mut d, imu(k * dt));
            }
            assert_eq!(d.mode(), Mode::DeadReckoning);
            d.filter.st.x[poison.0] = poison.1;
            let got = send(&mut d, imu((n + 1) * dt));
            assert!(got.iter().all(CoreToHost::is_finite), "{got:?}");
            assert!(
                got.iter().any(|m| matches!(m, CoreToHost::Status(s)
                    if s.mode == Mode::Diverged)),
                "{got:?}"
            );
            assert_eq!(d.mode(), Mode::Reinitialising, "{poison:?}");
        }
    }

    /// Issue 17 (recovery): `Query` changes nothing, and a reset core resumes where the
    /// state it reported was.
    #[test]
    fn query_reports_the_mode_and_state_and_resume_restarts_a_reset_core_where_it_was() {
        let hello = HostToCore::Hello(protocol::Hello {
            version: protocol::PROTOCOL_VERSION,
        });
        let config = protocol::samples::config();
        let imu = still_imu;
        let mut d = Device::<f32>::new();
        // A core that booted has no session.
        let ack = send(&mut d, hello.clone());
        assert!(matches!(&ack[..], [CoreToHost::HelloAck(a)] if a.session == 0));
        send(&mut d, HostToCore::Configure(config));
        send(
            &mut d,
            HostToCore::Init(Init {
                position: [0.5, 0.0, 1.0],
                attitude: InitAttitude::GravityAndYaw(0.3),
            }),
        );
        let dt = (1e6 / f64::from(config.imu_rate_hz)) as u64;
        let n = u64::from(config.still_samples) + 20;
        for k in 1..=n {
            send(&mut d, imu(k * dt));
        }
        let ack = send(&mut d, hello.clone());
        assert!(matches!(&ack[..], [CoreToHost::HelloAck(a)] if a.session == config.session));
        // Query: the mode and the last sample's time, then the state, changing nothing.
        let got = send(&mut d, HostToCore::Query);
        let state = match &got[..] {
            [CoreToHost::Status(st), CoreToHost::State(s)] => {
                assert_eq!(st.reason, StatusReason::Queried);
                assert_eq!(st.mode, Mode::DeadReckoning);
                assert_eq!((st.t_us, s.t_us), (n * dt, n * dt));
                *s
            }
            other => panic!("{other:?}"),
        };
        assert_eq!(d.mode(), Mode::DeadReckoning);
        // A reset core refuses to resume before it is configured, then resumes at once.
        let mut fresh = Device::<f32>::new();
        send(&mut fresh, hello);
        let resume = HostToCore::Resume(protocol::Resume::of(&state));
        let got = send(&mut fresh, resume.clone());
        assert!(
            matches!(&got[..], [CoreToHost::Error(e)] if e.code == ErrorCode::NotConfigured),
            "{got:?}"
        );
        send(&mut fresh, HostToCore::Configure(config));
        let got = send(&mut fresh, resume);
        assert_eq!(fresh.mode(), Mode::DeadReckoning, "{got:?}");
        send(&mut fresh, imu((n + 1) * dt));
        send(&mut d, imu((n + 1) * dt));
        let after = |d: &mut Device<f32>| match &send(d, HostToCore::Query)[..] {
            [_, CoreToHost::State(s)] => *s,
            other => panic!("{other:?}"),
        };
        let (a, b) = (after(&mut d), after(&mut fresh));
        for i in 0..3 {
            assert!((a.s_w[i] - b.s_w[i]).abs() < 1e-5, "{a:?} {b:?}");
        }
        for i in 0..4 {
            assert!((a.q_sw[i] - b.q_sw[i]).abs() < 1e-5, "{a:?} {b:?}");
        }
    }

    /// Issue 17 (long runs): µs time stamps up to their limit, `u64::MAX`. The core runs to it
    /// and answers its triggers, with no panic (overflow checks are on in this profile), and a
    /// sample at the limit again is refused by name: nothing can come after it.
    #[test]
    fn time_stamps_run_up_to_the_u64_limit_without_a_panic() {
        let config = protocol::samples::config();
        let init = Init {
            position: [0.0; 3],
            attitude: InitAttitude::Gravity,
        };
        let mut d = started::<f32>(config, init);
        let dt = (1e6 / f64::from(config.imu_rate_hz)) as u64;
        let samples = 3 * u64::from(config.imu_rate_hz as u32);
        let (mut predictions, mut errors) = (0, 0);
        for k in (0..=samples).rev() {
            let imu = protocol::ImuSample {
                t_us: u64::MAX - k * dt,
                gyro: [0.01, 0.0, -0.01],
                accel: [0.0, 0.0, 9.81],
                trigger: k % 10 == 0,
            };
            for a in send(&mut d, HostToCore::Imu(imu)) {
                match a {
                    CoreToHost::PosePrediction(_) => predictions += 1,
                    CoreToHost::Error(_) => errors += 1,
                    _ => {}
                }
            }
        }
        assert_eq!(errors, 0);
        assert!(predictions > 20, "{predictions} predictions");
        assert_eq!(d.mode(), Mode::DeadReckoning);
        let again = protocol::ImuSample {
            t_us: u64::MAX,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            trigger: true,
        };
        let got = send(&mut d, HostToCore::Imu(again));
        assert!(
            got.iter().any(|a| matches!(
                a,
                CoreToHost::Error(e) if matches!(e.code, ErrorCode::TimestampNotIncreasing { .. })
            )),
            "{got:?}"
        );
    }

    /// The whole device, and its parts, in bytes (the firmware keeps it in a `static`).
    #[test]
    fn memory_footprint() {
        let sizes = [
            ("State<f32> (mean + covariance)", size_of::<State<f32>>()),
            (
                "DelayLine<f32> (IMU ring + snapshots)",
                size_of::<DelayLine<f32>>(),
            ),
            ("Device<f32>", size_of::<Device<f32>>()),
            (
                "DeviceIo<f32> (device + frame decoder)",
                size_of::<DeviceIo<f32>>(),
            ),
            ("Device<f64>", size_of::<Device<f64>>()),
        ];
        for (name, bytes) in sizes {
            std::println!("{name}: {bytes} bytes");
        }
        // Fits the 32 KiB RAM budget of the smallest Cortex-M4F parts with room for the stack.
        assert!(size_of::<DeviceIo<f32>>() < 20 * 1024);
    }
}
