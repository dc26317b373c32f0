//! The push-driven [`Tracker`]: the program that owns the camera (and the IMU) pushes each
//! frame (and each IMU sample), and the tracker answers with events. It has no files and no
//! clock of its own: time is the sensors'.
//!
//! With an IMU (an inertial model) the program pushes every sample with
//! [`Tracker::push_imu`], and each frame just before the sample that triggered it; the steps
//! of a sample are in [`inertial`]. Without one (the vision-only model) the frames are the
//! clock, and each frame goes through the named steps of `vision_only` (as M3T's tracker
//! loop does). What the tracker tells, the events and the details, is in `tell`.
//!
//! The parts it holds, one job each: the clock of its input mode (`crate::clock`), the one
//! search machine (`crate::searching`), the core session (`crate::session`; its outages in
//! `outage`), the judge (`crate::judge`), and the vision threads (`crate::worker`).

mod cold_start;
pub mod inertial;
mod on_core;
mod outage;
mod tell;
mod vision_only;

use std::collections::VecDeque;
use std::time::Instant;

use camera::CameraPose;
use image::GrayImage;
use protocol::{HostToCore, Init, InitAttitude, ModelKind, StatusReason};
use vision::FrameImage;

use self::inertial::Inertial;
use crate::clock::FrameClock;
use crate::error::TrackerError;
use crate::event::{Detail, LatencyNote};
pub use crate::event::{Event, FrameReport, Pose, State};
use crate::in_process::InProcessCore;
use crate::judge::{Judge, Tally};
use crate::loss::LossRule;
use crate::record::Fate;
use crate::rig::HandEye;
use crate::searching::{Job, SearchMachine};
use crate::session::CoreSession;
use crate::settings::check_config;
pub use crate::settings::{Answers, Frame, ImuOnCore, Start, TrackerConfig};
use crate::tilt::TiltBranch;
use crate::transport::CoreTransport;
use crate::worker::{VisionWorker, is_textured};

/// Events queued at most between two polls: about four minutes of an IMU's poses at 200 Hz.
/// A program that polls after each push never comes near it; one that never polls keeps
/// bounded memory. (Eight in the crate's unit tests, which test the bound.)
pub const MAX_EVENTS: usize = if cfg!(test) { 8 } else { 50_000 };

/// While tracked, one tilt check every this many frames at most (docs/notes/issue15-cold-start.md
/// §5.2): it runs on the search thread, one at a time, and costs about as much as an attempt.
const TILT_CHECK_EVERY: usize = 5;

/// A frame's pose estimated with it, and its judgement.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Judged {
    /// The pose estimated with the frame.
    pub pose: CameraPose,
    /// Whether it counts as tracked (the tracked rule).
    pub tracked: bool,
    /// The frame's id at the core.
    pub frame_id: u32,
    /// The pose's covariance.
    pub cov: Option<camera::PoseCovariance>,
    /// The direction it pins down least (eq. T7).
    pub weakest: Option<camera::WeakDirection>,
}

/// The tracker: frames in, events out, the core behind `T`.
///
/// A tracker exists only once [`Tracker::new`] has finished starting it (the handshake, the
/// core's configuration and its initialisation), so no frame can be pushed before:
///
/// ```compile_fail
/// let tracker: tracker::Tracker;
/// // error[E0381]: used binding `tracker` isn't initialized
/// tracker.push_frame(tracker::Frame { index: 0, t_ns: 0, image: image::GrayImage::new(1, 1) });
/// ```
pub struct Tracker<T: CoreTransport = InProcessCore> {
    pub(crate) config: TrackerConfig,
    pub(crate) core: T,
    pub(crate) worker: VisionWorker,
    /// The searches' vision thread: vision-only runs, and inertial runs that start cold.
    pub(crate) search: Option<VisionWorker>,
    adapter: String,
    /// The exchanges with the core, and what the steps need of what it said.
    pub(crate) session: CoreSession,
    /// The mount the core was configured with: the rig's, or none (vision-only).
    pub(crate) core_hand_eye: HandEye,
    /// This run's name for its configuration of the core (an attach takes the core's).
    pub(crate) session_id: u32,
    /// The core's outlier gate on `s_i`.
    gate: f64,
    /// The verdicts.
    pub(crate) judge: Judge,
    /// Vision-only: the tilt checks of tracked poses and their flips.
    tilt: TiltBranch,
    /// Vision-only: the clock (the frames', and the ticks sent at them).
    frames: FrameClock,
    /// A frame has been tracked since the core was last given a pose.
    tracked_since_start: bool,
    /// The searches: locating, started, and lost (vision-only, its loss rule takes the
    /// verdicts; with an IMU, the core's mode).
    pub(crate) searching: SearchMachine,
    /// With an IMU: the loss rule of the verdicts, which the state follows.
    loss: LossRule,
    since_check: usize,
    /// Runs with an IMU: their state.
    pub(crate) inertial: Option<Inertial>,
    /// The model, kept for a search thread started on demand ([`Self::relocate`]) where the
    /// run has none.
    model: Option<model::Model>,
    /// An injected fault not yet noticed: when it was injected [s of input], and on the wall
    /// clock.
    pub(crate) injected: Option<(f64, Instant)>,
    pub(crate) events: VecDeque<Event>,
    /// Events lost since the last poll (the oldest, beyond [`MAX_EVENTS`]).
    missed: usize,
    pub(crate) state: State,
    latest: Option<Pose>,
    /// Why the tracker stopped, once it did.
    pub(crate) stopped: Option<String>,
}

/// What [`Tracker::finish`] leaves.
pub struct Finished<T> {
    /// How many frames were judged, and how many count as tracked.
    pub tally: Tally,
    /// The core's transport, to close.
    pub core: T,
    /// The renderer's adapter.
    pub adapter: String,
    /// Whether the run ended cleanly, or the error that stopped it.
    pub result: Result<(), TrackerError>,
    /// What the tracker told that was not polled, the end's included (the last frames'
    /// reports, the core's last poses).
    pub events: Vec<Event>,
}

impl<T: CoreTransport> Tracker<T> {
    /// Starts the tracker for `model` with the core behind `core`: the vision threads (each
    /// with its renderer), the handshake, the core's `Configure`, and its `Init` where the
    /// start pose is given (with an IMU: or an attach to a core already tracking).
    pub fn new(config: TrackerConfig, model: &model::Model, core: T) -> Result<Self, TrackerError> {
        let vision_only = config.model == ModelKind::Vision;
        check_config(&config)?;
        // The texture modality and the searches (the cold start, the tilt checks) need the
        // model's texture; the contour modality tracks a model without one from a start pose.
        let searchable = is_textured(model);
        if config.vision.modality.texture() && !searchable {
            return Err(TrackerError::Untextured);
        }
        if !searchable && config.start == Start::Locate {
            return Err(TrackerError::NeedsStartPose);
        }
        let (worker, ready) =
            VisionWorker::start(config.camera, model.clone(), vision_options(&config))?;
        let search = if searchable && (vision_only || config.start == Start::Locate) {
            Some(search_worker(&config, model.clone())?)
        } else {
            None
        };
        let spare = (search.is_none() && searchable).then(|| model.clone());
        let hand_eye = if vision_only {
            HandEye::IDENTITY
        } else {
            config.rig.hand_eye
        };
        let judge = Judge::new(model.diagonal(), ready.axes.0);
        let rule = *judge.rule();
        let mut tracker = Self {
            gate: 0.0,
            judge,
            session: CoreSession::new(config.details),
            core_hand_eye: hand_eye,
            session_id: config.session_id,
            tilt: TiltBranch::default(),
            frames: FrameClock::default(),
            tracked_since_start: false,
            searching: SearchMachine::new(vision_only, config.start != Start::Locate),
            loss: LossRule::default(),
            since_check: 0,
            inertial: None,
            model: spare,
            injected: None,
            events: VecDeque::new(),
            missed: 0,
            state: State::Locating,
            latest: None,
            stopped: None,
            adapter: ready.adapter,
            config,
            core,
            worker,
            search,
        };
        tracker.tell(Detail::Started {
            core_hand_eye: hand_eye,
            session_id: tracker.session_id,
            axes: ready.axes,
            rule,
            at: Instant::now(),
        });
        if vision_only {
            tracker.start_vision()?;
        } else {
            tracker.start_inertial()?;
        }
        Ok(tracker)
    }

    /// Sends `Hello` and takes everything the core says up to its answer.
    pub(crate) fn barrier(&mut self) -> Result<(), TrackerError> {
        self.session.barrier(&mut self.core, self.config.timeout)
    }

    /// Sends a `Configure` or `Init` and logs the answers (confirmed on a lossy line).
    pub(crate) fn send_confirmed(
        &mut self,
        msg: &HostToCore,
        reason: StatusReason,
    ) -> Result<(), TrackerError> {
        self.session
            .send_confirmed(&mut self.core, msg, reason, self.config.timeout)
    }

    /// The first refusal of the core since the mark `from` ([`crate::session::Recent::mark`]):
    /// on a lossy line, its noise ([`crate::session::is_line_noise`]), which
    /// [`Self::send_confirmed`] resends past, is none (issue 54: `--line-errors 0.002` failed
    /// a run as "refused the configuration").
    pub(crate) fn refusal(&self, from: usize) -> Option<String> {
        let lossy = self.core.lossy();
        self.session
            .errors
            .since(from)
            .find(|e| !(lossy && crate::session::is_line_noise(&e.code)))
            .map(|e| e.code.to_string())
    }

    /// The transport, for what the program does to it directly (fault injection, say).
    pub fn core_mut(&mut self) -> &mut T {
        &mut self.core
    }

    /// Tracks one frame. A frame of another size than the camera's, not after the frame
    /// before, or unreadable, is refused with its error, and the tracker goes on. Any other
    /// error stops it: it then refuses every later frame and sample, and [`Self::finish`]
    /// returns what was tracked.
    ///
    /// With an IMU the frame waits for the next sample pushed, which triggered it; with the
    /// core sampling its own IMU, for the core's trigger before it ([`Self::pump`]).
    pub fn push_frame(&mut self, frame: Frame) -> Result<(), TrackerError> {
        if let Some(why) = &self.stopped {
            return Err(TrackerError::Stopped(why.clone()));
        }
        let index = frame.index;
        let captured = frame.captured.unwrap_or_else(Instant::now);
        self.tell(Detail::Taken {
            index,
            t_ns: frame.t_ns,
        });
        let checked = match &self.inertial {
            Some(_) => self.queue_frame(frame).map(|()| None),
            None => self.check_frame(frame).map(Some),
        };
        if checked.is_ok() {
            self.latency(LatencyNote::Taken { index, captured });
        }
        let (t_us, image) = match checked {
            Ok(Some(c)) => c,
            Ok(None) if self.imu_on_core() => return self.pump(),
            Ok(None) => return Ok(()),
            Err(e) => {
                // Refused, and told as a frame that could not be used.
                self.settle(index, Fate::Unusable);
                let why = e.to_string();
                self.tell(Detail::FrameError(format!("{why}: skipped")));
                self.emit(Event::FrameSkipped { index, why });
                return Err(e);
            }
        };
        let step = self.track(index, image, t_us);
        if let Err(e) = &step {
            self.stopped = Some(e.to_string());
        }
        self.tell_poses();
        step
    }

    /// With an IMU: the frame waits for its trigger, the next sample.
    fn queue_frame(&mut self, frame: Frame) -> Result<(), TrackerError> {
        if let FrameImage::Decoded(image) = &frame.image {
            self.check_size(frame.index, image)?;
        }
        if self.imu_on_core() {
            return self.queue_on_core(frame);
        }
        self.imu_mut()?.clock.queue(frame)
    }

    /// Whether `image` is of the camera's size.
    fn check_size(&self, index: usize, image: &GrayImage) -> Result<(), TrackerError> {
        let (w, h) = image.dimensions();
        let camera = &self.config.camera;
        if (w, h) != (camera.width, camera.height) {
            return Err(TrackerError::ImageSize {
                index,
                width: w,
                height: h,
                camera_width: camera.width,
                camera_height: camera.height,
            });
        }
        Ok(())
    }

    /// Waits until `deadline` for what the core says, telling its poses as they come: a
    /// program that paces its samples by the clock calls this instead of sleeping, so that
    /// each pose comes out when the core sends it. A link that fails meanwhile is left to
    /// the next push to notice.
    pub fn wait_until(&mut self, deadline: Instant) {
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return;
            }
            if self.stopped.is_some() || self.in_outage() || !self.core.is_connected() {
                std::thread::sleep(left);
                return;
            }
            match self.core.recv_within(left) {
                Ok(Some(item)) => {
                    self.session.take(item);
                    self.tell_poses();
                }
                // Nothing came: a threaded link waited until the deadline, an in-process
                // core (which answers when called) returns at once, so the rest is slept.
                Ok(None) => {
                    std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
                    return;
                }
                Err(_) => {
                    std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
                    return;
                }
            }
        }
    }

    /// The events since the last poll, in order: first, where events were lost because the
    /// queue was not polled, how many ([`Event::Missed`]).
    pub fn poll(&mut self) -> impl Iterator<Item = Event> + '_ {
        let missed = std::mem::take(&mut self.missed);
        (missed > 0)
            .then_some(Event::Missed(missed))
            .into_iter()
            .chain(self.events.drain(..))
    }

    /// The core's latest pose.
    pub fn latest(&self) -> Option<Pose> {
        self.latest
    }

    /// Where the tracker stands.
    pub fn state(&self) -> State {
        self.state
    }

    /// Asks for a search at the next frame (with an IMU: the next trigger), whatever the
    /// frames say: the user knows the model moved (a tracked pose that is wrong, an object put
    /// down elsewhere). A run given its start pose gets its search thread (and renderer) here.
    pub fn relocate(&mut self) -> Result<(), TrackerError> {
        if self.search.is_none() {
            // Without texture there is nothing to search by (the spare model is kept for
            // textured models only).
            let model = self.model.take().ok_or(TrackerError::NeedsStartPose)?;
            self.search = Some(search_worker(&self.config, model)?);
        }
        match self.inertial.as_ref() {
            Some(i) => {
                let t_us = i.recent.back().map_or(0, |s| s.t_us);
                self.searching.force(t_us);
            }
            None if self.searching.started() => self
                .searching
                .loss
                .force(self.frames.last_us().unwrap_or(0)),
            // Still locating: every frame gets an attempt already.
            None => return Ok(()),
        }
        self.set_state(State::Lost);
        Ok(())
    }

    /// How many frames were judged so far, and how many count as tracked.
    pub fn tally(&self) -> Tally {
        self.judge.tally()
    }

    /// The current mode of the core (its last status).
    pub fn core_mode(&self) -> Option<protocol::Mode> {
        self.session.mode()
    }

    /// The renderer's adapter.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// Ends the run: what is in flight is waited for and applied (the frames with the vision
    /// thread, the tilt check, whose unconfirmed flip never held, a search), and everything
    /// the core still had to say is logged.
    pub fn finish(self) -> Finished<T> {
        self.end(false)
    }

    /// Ends the run at once (an interrupt): the frames in flight are recorded, not delivered,
    /// and a search or a tilt check in flight is dropped.
    pub fn abandon(self) -> Finished<T> {
        self.end(true)
    }

    fn end(mut self, interrupted: bool) -> Finished<T> {
        let result = match self.stopped.take() {
            Some(why) => Err(TrackerError::Stopped(why)),
            None if self.inertial.is_some() => self.finish_inertial(interrupted),
            None if interrupted => self.barrier(),
            None => self.wind_down(),
        };
        if let Some(open) = self.inertial.as_mut().and_then(|i| i.open.take()) {
            // An outage the run ended in.
            self.tell(Detail::Outage(open.outage));
        }
        self.tell_poses();
        self.tell(Detail::End { interrupted });
        self.worker.stop();
        if let Some(s) = &mut self.search {
            s.stop();
        }
        Finished {
            tally: self.judge.tally(),
            core: self.core,
            adapter: self.adapter,
            result,
            events: {
                let missed = self.missed;
                (missed > 0)
                    .then_some(Event::Missed(missed))
                    .into_iter()
                    .chain(self.events)
                    .collect()
            },
        }
    }

    /// Sends a search on `image` to the search thread, and tells the search machine.
    pub(crate) fn send_search(&mut self, image: GrayImage, job: Job) -> Result<(), TrackerError> {
        self.searcher()?
            .send_locate(image, self.config.cache.clone())?;
        self.searching.sent(job);
        Ok(())
    }

    /// The searches' vision thread.
    fn searcher(&self) -> Result<&VisionWorker, TrackerError> {
        self.search
            .as_ref()
            .ok_or_else(|| TrackerError::VisionThread("no search thread".into()))
    }

    /// The camera's angular rate at the trigger at `t_us` (the core's state there, through
    /// the mount), for the motion blur's share of a frame's covariance.
    pub(crate) fn omega_c(&self, t_us: u64) -> Option<nalgebra::Vector3<f64>> {
        let s = self.session.last_state().filter(|s| s.t_us == t_us)?;
        Some(self.core_hand_eye.q_cs * nalgebra::Vector3::from(s.omega_s.map(f64::from)))
    }
}

/// The image analysis of `config`'s vision threads: a vision-only run tracks an object held
/// in a hand, whose map keeps small cells.
fn vision_options(config: &TrackerConfig) -> vision::VisionOptions {
    let mut vision = config.vision;
    vision.map.small_object_cells |= config.model == ModelKind::Vision;
    vision
}

/// The searches' vision thread, its attempts held to the configured floor.
fn search_worker(
    config: &TrackerConfig,
    model: model::Model,
) -> Result<VisionWorker, TrackerError> {
    // Searches find and verify a pose by the model's texture, whatever tracking measures.
    let options = vision::VisionOptions {
        modality: vision::Modality::Texture,
        ..vision_options(config)
    };
    let mut worker = VisionWorker::start(config.camera, model, options)?.0;
    worker.set_search_floor(config.search_floor);
    Ok(worker)
}

/// The camera pose of a vision-only state report (the camera is the sensor).
fn pose_of_state(s: &protocol::StateReport) -> CameraPose {
    let (c_w, q_wc) = HandEye::IDENTITY.camera_of_state(s);
    CameraPose {
        q_cw: q_wc.inverse(),
        c_w,
    }
}

/// The core's `Init` for the camera at `pose` (the vision-only model: the camera is the
/// sensor).
fn init_at(pose: &CameraPose) -> Init {
    let (s_w, q_sw) = HandEye::IDENTITY.sensor_pose_of_camera(pose);
    let q = q_sw.quaternion();
    Init {
        position: [s_w.x as f32, s_w.y as f32, s_w.z as f32],
        attitude: InitAttitude::Full([q.w as f32, q.i as f32, q.j as f32, q.k as f32]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 57: a program that never polls keeps bounded memory, and is told what it lost.
    #[test]
    fn events_not_polled_are_bounded_and_the_loss_is_told() {
        let camera =
            camera::pinhole_camera(320, 240, camera::Pinhole::new(300.0, 300.0, 160.0, 120.0))
                .unwrap();
        let cache = std::env::temp_dir().join("tracker-events-bound");
        let mut config = TrackerConfig::new(camera, 30.0, cache);
        config.start = Start::Camera(
            CameraPose::look_at(
                nalgebra::Vector3::new(1.2, -1.2, 1.0),
                nalgebra::Vector3::new(0.0, 0.0, 0.2),
                nalgebra::Vector3::z(),
            )
            .unwrap(),
        );
        let model = model::procedural::test_scene();
        let mut t = Tracker::new(config, &model, InProcessCore::default()).unwrap();
        let image = GrayImage::from_fn(320, 240, |x, y| {
            image::Luma([((x * 7 + y * 3) % 251) as u8])
        });
        for i in 0..6 {
            t.push_frame(Frame::decoded(i, i as i64 * 33_000_000, image.clone()))
                .unwrap();
        }
        assert_eq!(t.events.len(), MAX_EVENTS);
        let events: Vec<_> = t.poll().collect();
        let Some(Event::Missed(n)) = events.first() else {
            panic!("{events:?}")
        };
        assert!(*n > 0);
        assert_eq!(events.len(), MAX_EVENTS + 1);
        // Polled, nothing is missed.
        t.push_frame(Frame::decoded(6, 6 * 33_000_000, image))
            .unwrap();
        assert!(!t.poll().any(|e| matches!(e, Event::Missed(_))));
        t.finish().result.unwrap();
    }
}
