//! The tracker's runs with an IMU: the program pushes every IMU sample, and each frame just
//! before the sample that triggered it. Per sample ([`Tracker::push_imu`]), in this order:
//!
//! 1. an outage in progress is worked on (`super::outage`): the sample waits until the core
//!    is reached again;
//! 2. `deliver_due`: the correspondences of frames analysed since: in a replay
//!    ([`Answers::AtNextFrame`]) exactly `latency` after their trigger, counted in samples,
//!    waiting for the vision thread if needed, so that a replay is deterministic and the
//!    core's delayed-update path is always exercised; live, as soon as they are ready;
//! 3. the cold start's or the recovery's attempt, when due (`super::cold_start`);
//! 4. the sample itself, with the trigger flag when a frame waits for it;
//! 5. at a trigger: a `Hello` as a barrier (the core answers it in order, so the host knows
//!    whether a prediction came), an attempt on the frame when the loss rule asks for one,
//!    and the frame to the vision thread at the core's prediction.
//!
//! A link that fails, or a core that forgot its configuration, begins an outage.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use protocol::{HostToCore, Init, InitAttitude, Mode, StatusReason};
use vision::{FrameImage, FrameJob};

use super::on_core::OnCore;
use super::outage::{Attempt, MAX_BACKLOG_US, Open};
use super::{Answers, Event, Frame, FrameReport, Start, State, Tracker};
use crate::clock::SampleClock;
use crate::error::TrackerError;
use crate::event::{Detail, LatencyNote};
use crate::record::Fate;
use crate::searching::{AtTrigger, Job, SearchMachine};
use crate::transport::CoreTransport;

/// One IMU sample pushed into the tracker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Its time stamp [ns] on the sensors' clock (the frames' clock too).
    pub t_ns: u64,
    /// Angular rate [rad/s], in the IMU's frame.
    pub gyro: [f64; 3],
    /// Specific force [m/s²], in the IMU's frame.
    pub accel: [f64; 3],
}

/// A sample as sent to the core, kept a while for the backlog of an outage.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sent {
    /// Its time [µs from the first sample].
    pub t_us: u64,
    /// The sample.
    pub sample: ImuSample,
    /// Whether it triggered a frame.
    pub trigger: bool,
}

/// A frame whose correspondences are awaited.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pending {
    pub frame_id: u32,
    pub index: usize,
    pub trigger_us: u64,
    /// The sample after which they are delivered (replays).
    pub due: usize,
}

/// The state of a run with an IMU.
#[derive(Debug)]
pub(crate) struct Inertial {
    /// The latency from trigger to correspondences in a replay [samples].
    pub latency_samples: usize,
    /// The clock: the samples, counted, and the frame waiting for the next.
    pub clock: SampleClock,
    /// Live: a frame triggered whose prediction had not come yet, analysed when it comes
    /// (before the next trigger), with its trigger's time [µs] and the sample it is due at.
    pub late: Option<(Frame, u64, usize)>,
    /// Frames with the vision thread.
    pub pending: VecDeque<Pending>,
    /// The samples of the last [`MAX_BACKLOG_US`], for a core that missed them.
    pub recent: VecDeque<Sent>,
    /// The outage in progress.
    pub open: Option<Open>,
    /// Attached to a running core: its last sample's time [µs]; samples up to it are skipped.
    pub attached_after_us: Option<u64>,
    /// The time of the last sample sent [µs].
    pub last_sent_us: Option<u64>,
    /// A link error met while faults were injected: the outage of the next sample.
    pub deferred: Option<String>,
    /// The core samples its own IMU: the pairing of frames with its triggers.
    pub on_core: Option<OnCore>,
}

impl Inertial {
    pub(crate) fn new(latency_samples: usize) -> Self {
        Self {
            latency_samples,
            clock: SampleClock::default(),
            late: None,
            pending: VecDeque::new(),
            recent: VecDeque::new(),
            open: None,
            attached_after_us: None,
            last_sent_us: None,
            deferred: None,
            on_core: None,
        }
    }
}

impl<T: CoreTransport> Tracker<T> {
    /// The run's inertial state; a vision-only tracker has none.
    pub(crate) fn imu_mut(&mut self) -> Result<&mut Inertial, TrackerError> {
        self.inertial.as_mut().ok_or_else(|| {
            TrackerError::Config(
                "this tracker runs the vision-only model: its clock is the frames', and it takes no IMU samples".into(),
            )
        })
    }

    /// The start of a run with an IMU: the handshake, the latency checked against the core's
    /// buffers, an attach to a running core if asked, the `Configure`, and the `Init` where a
    /// start pose is given.
    pub(crate) fn start_inertial(&mut self) -> Result<(), TrackerError> {
        let ack = self
            .session
            .handshake(&mut self.core, self.config.timeout)?;
        let core_config = crate::config::core_config(
            &self.config.rig,
            self.config.model,
            &self.config.tuning,
            self.session_id,
        );
        crate::config::check_latency(self.config.latency_s, &ack.capacities, &core_config)?;
        let attached = if self.config.attach {
            self.attach(&ack)?
        } else {
            None
        };
        let cold = attached.is_none() && self.config.start == Start::Locate;
        let latency = (self.config.latency_s * self.config.rig.imu_rate_hz).round() as usize;
        // Searches are run in a run that starts cold (and after a relocation).
        self.searching = SearchMachine::new(cold, false);
        let mut inertial = Inertial::new(latency);
        inertial.attached_after_us = attached;
        inertial.on_core = self.config.imu_on_core.map(OnCore::new);
        self.inertial = Some(inertial);
        if attached.is_none() {
            self.send_confirmed(
                &HostToCore::Configure(core_config),
                StatusReason::Configured,
            )?;
            if let Some(on_core) = self.config.imu_on_core {
                self.start_sampling(on_core)?;
            }
            if !cold {
                let init = HostToCore::Init(self.init_message()?);
                self.send_confirmed(&init, StatusReason::HostRequest)?;
            }
        }
        if let Some(e) = self.refusal(0) {
            return Err(TrackerError::Core(format!(
                "refused the configuration: {e}"
            )));
        }
        self.state = match (cold, attached) {
            (true, _) => State::Locating,
            (false, Some(_)) => State::Tracking,
            (false, None) => State::Starting,
        };
        Ok(())
    }

    /// The core's `Init` for the start pose: the camera's whole pose through the mount, or a
    /// position and yaw with roll and pitch from gravity.
    pub(crate) fn init_message(&self) -> Result<Init, TrackerError> {
        match self.config.start {
            Start::Camera(pose) => {
                let (s_w, q_sw) = self.config.rig.hand_eye.sensor_pose_of_camera(&pose);
                let q = q_sw.quaternion();
                Ok(Init {
                    position: [s_w.x as f32, s_w.y as f32, s_w.z as f32],
                    attitude: InitAttitude::Full([q.w as f32, q.i as f32, q.j as f32, q.k as f32]),
                })
            }
            Start::GravityAndYaw { position, yaw } => Ok(Init {
                position: position.map(|v| v as f32),
                attitude: InitAttitude::GravityAndYaw(yaw as f32),
            }),
            Start::Locate => Err(TrackerError::Config(
                "no start pose to initialise the core from: the cold start has not found the model yet".into(),
            )),
        }
    }

    /// Tracks one IMU sample (and the frame pushed just before it, which it triggered). A
    /// sample not after the one before is refused, and the tracker goes on; any other error
    /// stops it.
    pub fn push_imu(&mut self, sample: ImuSample) -> Result<(), TrackerError> {
        if let Some(why) = &self.stopped {
            return Err(TrackerError::Stopped(why.clone()));
        }
        if self.imu_on_core() {
            return Err(TrackerError::Config(
                "the core samples its own IMU in this run: the program pushes frames only".into(),
            ));
        }
        self.imu_mut()?.clock.check(sample.t_ns)?;
        let step = self.imu_step(sample);
        if let Err(e) = &step {
            self.stopped = Some(e.to_string());
        }
        self.tell_poses();
        step
    }

    /// [`Self::push_imu`]'s steps for a sample in order.
    fn imu_step(&mut self, sample: ImuSample) -> Result<(), TrackerError> {
        let clock = &mut self.imu_mut()?.clock;
        let first = clock.origin_ns().is_none();
        let (k, t_us, frame) = clock.take(sample.t_ns);
        if first && let Some(t0) = clock.origin_ns() {
            self.tell(Detail::Origin(t0));
        }
        let inertial = self.imu_mut()?;
        if let Some(last_us) = inertial.attached_after_us {
            // Attached: the core had the samples up to its last; the first after goes on.
            if t_us <= last_us {
                return Ok(());
            }
            if t_us - last_us > MAX_BACKLOG_US {
                return Err(TrackerError::Core(format!(
                    "attach: the core's last sample is at t = {:.3} s, and this input's next one at t = {:.3} s: is it the input the core was tracking?",
                    last_us as f64 * 1e-6,
                    t_us as f64 * 1e-6
                )));
            }
            inertial.attached_after_us = None;
            self.tell(Detail::AttachedAt(k));
        }
        let inertial = self.imu_mut()?;
        inertial.recent.push_back(Sent {
            t_us,
            sample,
            trigger: frame.is_some(),
        });
        while inertial
            .recent
            .front()
            .is_some_and(|s| s.t_us + MAX_BACKLOG_US < t_us)
        {
            inertial.recent.pop_front();
        }
        let mut open = inertial.open.take();
        let deferred = inertial.deferred.take();
        let refusals = self.session.errors.mark();
        // While the core is not there, the sample waits for an attempt to reach it.
        let ready = match (open.as_mut(), deferred) {
            (None, Some(e)) => Err(TrackerError::Link(e)),
            (None, None) => Ok(true),
            (Some(o), _) => match self.attempt_resume(o, t_us) {
                Ok(Attempt::Waiting) => Ok(false),
                Ok(Attempt::Resumed) => {
                    if let Some(o) = open.take() {
                        self.tell(Detail::Outage(o.outage));
                    }
                    Ok(true)
                }
                Err(e) => {
                    // Told at the end, as it stood when the run stopped.
                    self.imu_mut()?.open = open;
                    return Err(e);
                }
            },
        };
        let step = ready.and_then(|ready| match ready {
            true => self.sample_step(k, t_us, frame),
            false => Ok(()),
        });
        // A link that failed, or a core that forgot us, is an outage: the frames in flight
        // are dropped, and the host tries to reach the core again.
        let cause = match step {
            Ok(()) if open.is_none() && self.core_forgot(refusals) => Some(
                "the core answered as one not configured since it started: it was reset"
                    .to_string(),
            ),
            Ok(()) => None,
            Err(TrackerError::Link(e)) if open.is_none() => Some(e),
            Err(e) => return Err(e),
        };
        if let Some(cause) = cause {
            open = Some(self.begin_outage(cause, t_us)?);
        }
        self.imu_mut()?.open = open;
        self.judge_inertial(t_us);
        Ok(())
    }

    /// One sample with the core there: the frames due, the search, the sample, and at a
    /// trigger the frame's prediction and its analysis.
    fn sample_step(
        &mut self,
        k: usize,
        t_us: u64,
        frame: Option<Frame>,
    ) -> Result<(), TrackerError> {
        let lock_step = self.config.answers == Answers::AtNextFrame;
        self.deliver_due(k, lock_step)?;
        self.late_step(frame.is_some())?;
        self.poll_search(Some(k).filter(|_| lock_step), t_us)?;
        let sent = self.imu_mut()?.recent.back().copied();
        if let Some(s) = sent {
            self.send_sample(&s)?;
        }
        self.imu_mut()?.last_sent_us = Some(t_us);
        let Some(frame) = frame else {
            return self.session.drain(&mut self.core);
        };
        if lock_step {
            self.barrier()?;
        } else {
            // Live: the prediction is usually back within a millisecond.
            let deadline = Instant::now() + Duration::from_millis(20);
            while !self.session.has_prediction(t_us) && Instant::now() < deadline {
                if let Ok(item) = self.core.recv(Duration::from_millis(2)) {
                    self.session.take(item);
                }
            }
        }
        let due = k + self.imu_mut()?.latency_samples.max(1);
        self.attempt_step(&frame, t_us, due)?;
        if !lock_step && !self.session.has_prediction(t_us) {
            self.imu_mut()?.late = Some((frame, t_us, due));
            return Ok(());
        }
        self.frame_step(frame, t_us, due)
    }

    /// Live: the frame whose prediction was late, analysed once the prediction came; at the
    /// next trigger (`trigger`) or the end it is given up, as one with no prediction.
    fn late_step(&mut self, trigger: bool) -> Result<(), TrackerError> {
        let Some((frame, t_us, due)) = self.imu_mut()?.late.take() else {
            return Ok(());
        };
        if self.session.has_prediction(t_us) || trigger {
            return self.frame_step(frame, t_us, due);
        }
        self.imu_mut()?.late = Some((frame, t_us, due));
        Ok(())
    }

    /// At a trigger: the loss rule, and an attempt on the frame where it asks for one.
    fn attempt_step(&mut self, frame: &Frame, t_us: u64, due: usize) -> Result<(), TrackerError> {
        let step = self.searching.at_trigger(&self.session.statuses, t_us);
        if step == AtTrigger::Tracking {
            self.tell(Detail::RecoveryEnded(t_us));
        }
        let AtTrigger::Attempt(lost_at) = step else {
            return Ok(());
        };
        if self.search.is_none() {
            return Ok(());
        }
        let image = match &frame.image {
            FrameImage::Decoded(image) => Ok(image.clone()),
            FrameImage::File(path) => camera::read_frame(path)
                .map(|i| i.into_luma8())
                .map_err(|e| format!("{}: {e} (no search on it)", path.display())),
        };
        match image {
            Ok(image) => {
                let job = Job {
                    index: frame.index,
                    t_us,
                    due,
                    lost_at,
                };
                self.send_search(image, job)?;
                self.settle(frame.index, Fate::Searched);
            }
            // An unreadable frame is no attempt, as it is no analysis: reported, and the
            // next frame is tried.
            Err(e) => self.tell(Detail::FrameError(e)),
        }
        Ok(())
    }

    /// At a trigger: the frame to the vision thread at the core's prediction.
    pub(crate) fn frame_step(
        &mut self,
        frame: Frame,
        t_us: u64,
        due: usize,
    ) -> Result<(), TrackerError> {
        let Some(p) = self.session.take_prediction(t_us) else {
            self.settle(frame.index, Fate::NoPrediction);
            return Ok(());
        };
        let omega_c = self.omega_c(t_us);
        let every = self.config.keep_image_every;
        // Judged at its prediction: the pose the core put out at the frame's time.
        self.worker.send_judged(FrameJob {
            index: frame.index,
            stamp: u64::try_from(frame.t_ns).unwrap_or(0),
            image: frame.image,
            prediction: p,
            keep_image: every > 0 && frame.index.is_multiple_of(every),
            omega_c,
        })?;
        self.imu_mut()?.pending.push_back(Pending {
            frame_id: p.frame_id,
            index: frame.index,
            trigger_us: t_us,
            due,
        });
        Ok(())
    }

    /// Sends a sample to the core, and records its stamp.
    pub(crate) fn send_sample(&mut self, s: &Sent) -> Result<(), TrackerError> {
        let f32s = |v: [f64; 3]| v.map(|x| x as f32);
        self.core.send(&HostToCore::Imu(protocol::ImuSample {
            t_us: s.t_us,
            gyro: f32s(s.sample.gyro),
            accel: f32s(s.sample.accel),
            trigger: s.trigger,
        }))?;
        self.tell(Detail::Clock(s.sample.t_ns));
        self.latency(LatencyNote::SampleSent(s.t_us));
        Ok(())
    }

    /// Delivers the frames due at sample `k` (in a replay), or those ready (live).
    pub(crate) fn deliver_due(&mut self, k: usize, lock_step: bool) -> Result<(), TrackerError> {
        loop {
            let Some(p) = self.imu_mut()?.pending.front().copied() else {
                return Ok(());
            };
            let result = if lock_step {
                if p.due > k {
                    return Ok(());
                }
                self.worker.recv()?
            } else {
                match self.worker.try_recv() {
                    Some(r) => r,
                    None => return Ok(()),
                }
            };
            self.imu_mut()?.pending.pop_front();
            self.deliver_frame(p, result)?;
        }
    }

    /// Sends a frame's correspondences to the core, and tells it.
    fn deliver_frame(
        &mut self,
        p: Pending,
        result: Result<vision::FrameResult, TrackerError>,
    ) -> Result<(), TrackerError> {
        let judged = match &result {
            Ok(r) => r
                .at_prediction
                .map(|a| (a, vision::prediction_pose(&r.job.prediction))),
            Err(_) => None,
        };
        // The prediction's covariance: the pose put out at the frame's time.
        let cov = result
            .as_ref()
            .ok()
            .and_then(|r| camera::PoseCovariance::from_upper(&r.job.prediction.cov));
        let delivered = self.deliver((p.frame_id, p.index), p.trigger_us, result)?;
        if delivered.is_ok() {
            let after = self.imu_mut()?.last_sent_us.unwrap_or(p.trigger_us);
            self.latency(LatencyNote::Sent {
                index: p.index,
                after_us: after,
            });
        }
        let correspondences = delivered.unwrap_or(0);
        // The verdict on the pose put out at the frame's time (docs/VISION.md §10).
        let (pose, tracked, weakest) = match judged {
            Some((a, Ok(pose))) => {
                // Eq. T9 judges vision-only poses: a prediction's covariance holds the process
                // noise of a hand-held camera's peak jerk, and eq. T4 holds it to its frame.
                let v = self.judge.judge(p.frame_id, a, &pose, cov.as_ref(), false);
                self.tell(Detail::Judged {
                    frame_id: p.frame_id,
                    assessment: v.assessment,
                    tracked: v.tracked,
                });
                (Some(pose), Some(v.tracked), v.weakest)
            }
            _ => (None, None, None),
        };
        // The verdicts drive the state as in vision-only runs (docs/VISION.md §10): a frame
        // not judged tracked counts against the model.
        self.loss.frame(tracked == Some(true), p.trigger_us);
        self.tracked_since_start |= tracked == Some(true);
        let cov = pose.and(cov);
        let weak = tracked.and_then(|t| self.judge.weak(weakest, t));
        self.emit(Event::Frame(FrameReport {
            index: p.index,
            t_us: p.trigger_us,
            pose,
            tracked,
            correspondences,
            cov,
            weak,
        }));
        Ok(())
    }

    /// With `attach`: a core that runs our model under a session, and is still tracking,
    /// is taken over as it is. Returns the time of its last sample [µs] (the samples up to it
    /// are skipped), or `None` when there is nothing to take over and the core is configured
    /// anew.
    fn attach(&mut self, ack: &protocol::HelloAck) -> Result<Option<u64>, TrackerError> {
        let model = self.config.model;
        if ack.session == 0 || ack.model != Some(model) {
            self.tell(Detail::AttachNote(match (ack.model, ack.session) {
                (_, 0) | (None, _) => "the core ran no session: configured anew".to_string(),
                (Some(m), s) => format!(
                    "the core ran a session ({s:#010x}) of the {} model, not of the {}: configured anew",
                    m.name(),
                    model.name()
                ),
            }));
            return Ok(None);
        }
        let Some((mode, last_us)) = self.query()? else {
            return Err(TrackerError::Core(
                "attach: the core did not answer the query for its state".into(),
            ));
        };
        if !matches!(mode, Mode::Tracking | Mode::DeadReckoning) {
            self.tell(Detail::AttachNote(format!(
                "the core was {mode:?}, not tracking: configured and initialised anew"
            )));
            return Ok(None);
        }
        self.session_id = ack.session;
        self.tell(Detail::Session(ack.session));
        self.tell(Detail::AttachNote(format!(
            "attached to session {:#010x}, {mode:?} at t = {:.3} s: went on from there",
            ack.session,
            last_us as f64 * 1e-6
        )));
        Ok(Some(last_us))
    }

    /// The end of a run with an IMU: the frames still in flight delivered (or, `interrupted`,
    /// only recorded: the core has no samples left to apply them to), a search still running
    /// applied, and the last answers collected. An outage the input outlasted fails the run.
    pub(crate) fn finish_inertial(&mut self, interrupted: bool) -> Result<(), TrackerError> {
        let open = self.imu_mut()?.open.take();
        if let Some(last_us) = self.imu_mut()?.attached_after_us {
            return Err(TrackerError::Core(format!(
                "attach: the core's last sample is at t = {:.3} s, after this input's end: is it the input the core was tracking?",
                last_us as f64 * 1e-6
            )));
        }
        if open.is_none() {
            if !interrupted {
                self.late_step(true)?;
            }
            while let Some(p) = self.imu_mut()?.pending.pop_front() {
                let r = self.worker.recv()?;
                if interrupted {
                    if let Ok(r) = r {
                        self.tell_analysed(p.frame_id, r, 0);
                    }
                } else {
                    self.deliver_frame(p, r)?;
                }
            }
            if !interrupted {
                let now_us = self.imu_mut()?.last_sent_us.unwrap_or(0);
                self.poll_search(Some(usize::MAX), now_us)?;
            }
            self.barrier()?;
        }
        self.finish_on_core();
        if interrupted {
            // Told as it stands at the end.
            self.imu_mut()?.open = open;
            return Ok(());
        }
        // An outage that the input outlasted is a failed run, as one that outlasts the retry
        // window is: the samples after it were never tracked.
        if let Some(o) = open {
            let outage = o.outage.clone();
            self.tell(Detail::Outage(o.outage));
            let end_us = self
                .inertial
                .as_ref()
                .and_then(|i| i.recent.back())
                .map_or(0, |s| s.t_us);
            return Err(TrackerError::Link(format!(
                "link {}: the core was not reached again before the input ended, {:.2} s after \
                 the outage began ({} attempts): {}",
                self.core.name(),
                end_us as f64 * 1e-6 - outage.noticed_s,
                outage.attempts,
                outage.cause
            )));
        }
        Ok(())
    }

    /// The state after a sample at `t_us`: locating until the cold start found the model;
    /// lost while a loss rule says so (the search's, by the core's mode; the verdicts', after
    /// a divergence or half a second of frames not tracked, until a frame is tracked again);
    /// tracking while the core tracks (or dead-reckons a short stretch) after a tracked
    /// frame; starting before.
    pub(crate) fn judge_inertial(&mut self, t_us: u64) {
        self.loss.note_statuses(&self.session.statuses, t_us);
        let mode = self.session.mode();
        let s = &self.searching;
        let state = match s.active().then(|| (s.started(), s.lost(t_us))) {
            Some((false, _)) => State::Locating,
            Some((true, true)) => State::Lost,
            _ => match mode {
                Some(Mode::Diverged) => State::Lost,
                _ if self.loss.lost(t_us) => State::Lost,
                Some(Mode::Tracking | Mode::DeadReckoning) if self.tracked_since_start => {
                    State::Tracking
                }
                _ if self.state == State::Tracking => State::Lost,
                _ => State::Starting,
            },
        };
        self.set_state(state);
    }

    /// Whether the core is out of reach (an outage in progress): samples wait for it.
    pub fn in_outage(&self) -> bool {
        self.inertial.as_ref().is_some_and(|i| i.open.is_some())
    }

    /// Fault injection: everything sent so far reaches the core first (a barrier, so that
    /// the fault is repeatable), then `inject` does something to the transport (resets the
    /// core, pulls the cable); `at_s` is noted for the outage's report. A link that fails on
    /// the way is the next sample's outage.
    pub fn inject(
        &mut self,
        at_s: f64,
        inject: impl FnOnce(&mut T) -> Result<(), TrackerError>,
    ) -> Result<(), TrackerError> {
        let done = self.barrier().and_then(|()| inject(&mut self.core));
        match done {
            Ok(()) => self.injected = Some((at_s, Instant::now())),
            Err(TrackerError::Link(e)) => self.imu_mut()?.deferred = Some(e),
            Err(e) => return Err(e),
        }
        Ok(())
    }
}
