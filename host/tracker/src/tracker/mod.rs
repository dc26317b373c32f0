//! The push-driven [`Tracker`]: the program that owns the camera (and the IMU) pushes each
//! frame (and each IMU sample), and the tracker answers with events. It has no files and no
//! clock of its own: time is the sensors'.
//!
//! With an IMU (an inertial model) the program pushes every sample with
//! [`Tracker::push_imu`], and each frame just before the sample that triggered it; the steps
//! of a sample are in [`inertial`]. Without one (the vision-only model) the frames are
//! the clock, and each frame goes through named steps (as M3T's tracker loop does), in this
//! order:
//! 1. `check_frame`: its size and time against the camera and the frame before;
//! 2. `start_step`: while no pose is known (*locating*), a cold-start attempt on
//!    the frame, whose verified pose initialises the core;
//! 3. `take_answers`: the answers of the search and the tilt check sent at an
//!    earlier frame (a verified pose re-initialises the core);
//! 4. `search_step`: while *lost*, a search every few frames
//!    ([`crate::loss`]), on the search thread;
//! 5. `tick`: the core's clock to the frame's time, with the trigger: the core
//!    answers with the frame's prediction;
//! 6. `analyse`: the frame at the prediction (rendering, KLT, correspondences),
//!    its correspondences to the core, the clock just past the frame, and the pose
//!    estimated with it judged (the tracked rule);
//! 7. `check_step`: a tilt check of a tracked pose every few frames;
//! 8. `judge`: the loss rule, the state, and the events.
//!
//! The core runs the vision-only model: its clock is the frames' (`Tick`s, protocol 2.1).

mod cold_start;
pub mod inertial;
mod on_core;
mod outage;

use std::collections::VecDeque;
use std::time::Instant;

use camera::CameraPose;
use image::GrayImage;
use protocol::{HostToCore, Init, InitAttitude, ModelKind, StatusReason, Tick};
use vision::{FrameImage, FrameJob};

use self::inertial::Inertial;
use crate::clock::FrameClock;
use crate::config::vision_config;
use crate::error::TrackerError;
use crate::event::{Detail, LatencyNote};
pub use crate::event::{Event, FrameReport, Pose, State};
use crate::in_process::InProcessCore;
use crate::judge::{Judge, Tally};
use crate::loss::LossRule;
use crate::record::Fate;
use crate::rig::HandEye;
use crate::search::Search;
use crate::searching::{Job, SearchMachine};
use crate::session::CoreSession;
use crate::settings::check_config;
pub use crate::settings::{Answers, Frame, ImuOnCore, Start, TrackerConfig};
use crate::tilt::{TiltBranch, TiltNote};
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

    /// The start of a vision-only run: the handshake, the `Configure`, and the `Init` where
    /// the start pose is given. Correspondences go out before the next tick: no latency to
    /// check against the core's buffers.
    fn start_vision(&mut self) -> Result<(), TrackerError> {
        self.session
            .handshake(&mut self.core, self.config.timeout)?;
        let c = &self.config;
        let core_config = vision_config(c.frame_rate_hz, &c.tuning, c.session_id);
        self.gate = f64::from(core_config.gate);
        self.send_confirmed(
            &HostToCore::Configure(core_config),
            StatusReason::Configured,
        )?;
        if let Start::Camera(pose) = &self.config.start {
            let init = HostToCore::Init(init_at(pose));
            self.send_confirmed(&init, StatusReason::HostRequest)?;
        }
        if let Some(e) = self.refusal(0) {
            return Err(TrackerError::Core(format!(
                "refused the configuration: {e}"
            )));
        }
        self.state = if self.searching.started() {
            State::Starting
        } else {
            State::Locating
        };
        Ok(())
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

    /// Step 1 (vision-only): the frame's pixels, size and time. Returns its time [µs from
    /// the first frame] and pixels.
    fn check_frame(&mut self, frame: Frame) -> Result<(u64, GrayImage), TrackerError> {
        let image = match frame.image {
            FrameImage::Decoded(image) => image,
            FrameImage::File(path) => camera::read_frame(&path)
                .map_err(|source| vision::VisionError::Image { path, source })?
                .into_luma8(),
        };
        self.check_size(frame.index, &image)?;
        let first = self.frames.origin_ns().is_none();
        let t_us = self.frames.time_of(frame.index, frame.t_ns);
        if first && let Some(t0) = self.frames.origin_ns() {
            self.tell(Detail::Origin(t0));
        }
        Ok((t_us?, image))
    }

    /// Steps 2 to 8 for the frame `index` at `t_us`.
    fn track(&mut self, index: usize, image: GrayImage, t_us: u64) -> Result<(), TrackerError> {
        if !self.start_step(index, &image, t_us)? {
            // No pose yet: the frame was searched, or taken while a search ran.
            let searched = self.searching.job().is_some_and(|s| s.index == index)
                || self.config.answers == Answers::AtNextFrame;
            let fate = if searched {
                Fate::Searched
            } else {
                Fate::NoPrediction
            };
            self.settle(index, fate);
            return Ok(());
        }
        self.take_answers(t_us)?;
        self.search_step(index, &image, t_us)?;
        self.tick(t_us)?;
        let check_due = self.since_check >= TILT_CHECK_EVERY
            && !self.tilt.in_flight()
            && self.searching.job().is_none()
            && self.searching.loss.untracked_since().is_none();
        let check_image = check_due.then(|| image.clone());
        let (analysed, correspondences) = self.analyse(index, image, t_us)?;
        self.check_step(check_image, analysed, index)?;
        self.judge(analysed, index, t_us, correspondences);
        Ok(())
    }

    /// Step 2: while no pose is known, a cold-start attempt on the frame: waited for in a
    /// replay ([`Answers::AtNextFrame`]); live, on the search thread while the frames go on,
    /// its answer taken at the first frame after it is ready, and a new attempt sent on
    /// that frame where it found nothing. Returns whether the frame goes on to be tracked: it
    /// does once a pose is verified, from that pose (found on its own frame and registered
    /// on this one, which measures the motion since: the vision-only model has no other
    /// sensor of it).
    fn start_step(
        &mut self,
        index: usize,
        image: &GrayImage,
        t_us: u64,
    ) -> Result<bool, TrackerError> {
        if self.searching.started() {
            return Ok(true);
        }
        let answer = if self.config.answers == Answers::AtNextFrame {
            let (a, from) = self
                .searcher()?
                .locate(image.clone(), self.config.cache.clone())?;
            Some((a, from, index, t_us))
        } else {
            match self.searching.job() {
                Some(s) => self.searcher()?.try_locate()?.map(|(a, from)| {
                    self.searching.answered();
                    (a, from, s.index, s.t_us)
                }),
                None => None,
            }
        };
        if let Some((a, from, at, at_us)) = answer {
            let search = Search::new(at, at_us, a).applied(t_us);
            if let Some(pose) = self.searched(None, search, from) {
                self.core.send(&HostToCore::Init(init_at(&pose)))?;
                self.searching.start();
                self.set_state(State::Starting);
                return Ok(true);
            }
        }
        if self.config.answers == Answers::WhenReady && self.searching.job().is_none() {
            self.searcher()?
                .send_locate(image.clone(), self.config.cache.clone())?;
            self.searching.sent(Job {
                index,
                t_us,
                due: 0,
                lost_at: None,
            });
        }
        Ok(false)
    }

    /// Step 3: the answers of the search and the tilt check sent at an earlier frame: waited
    /// for ([`Answers::AtNextFrame`]) or taken if ready. A verified pose of a search
    /// re-initialises the core; so does a tilt check that found tracking on the other tilt of
    /// a face (`crate::tilt`).
    fn take_answers(&mut self, t_us: u64) -> Result<(), TrackerError> {
        let block = self.config.answers == Answers::AtNextFrame;
        // Divergences since the last frame lose the model at once.
        self.searching
            .loss
            .note_statuses(&self.session.statuses, t_us);
        if let Some(s) = self.searching.job() {
            let done = if block {
                Some(self.searcher()?.locate_result()?)
            } else {
                self.searcher()?.try_locate()?
            };
            if let Some((a, from)) = done {
                self.searching.answered();
                let search = Search::new(s.index, s.t_us, a).applied(t_us);
                if let Some(pose) = self.searched(s.lost_at, search, from) {
                    self.core.send(&HostToCore::Init(init_at(&pose)))?;
                    self.tilt.restart();
                    self.tell_tilt();
                    self.searching.found(None);
                    self.tracked_since_start = false;
                }
            }
        }
        if self.tilt.in_flight()
            && let Some(check) = self.searcher()?.tilt_result(block)?
        {
            let flip = self.tilt.answer(&check, t_us as f64 * 1e-6);
            self.tell_tilt();
            if let Some(pose) = flip {
                self.core.send(&HostToCore::Init(init_at(&pose)))?;
            }
        }
        Ok(())
    }

    /// Step 4: while lost, a search on the frame every few frames (one at a time, and not
    /// beside a tilt check); while not, an open loss ends.
    fn search_step(
        &mut self,
        index: usize,
        image: &GrayImage,
        t_us: u64,
    ) -> Result<(), TrackerError> {
        if !self.searching.lost(t_us) {
            self.tell(Detail::RecoveryEnded(t_us));
            return Ok(());
        }
        self.set_state(State::Lost);
        if self.search.is_none() {
            // An untextured model: lost until its contour is found again, never searched.
            return Ok(());
        }
        if let Some(lost_at) = self.searching.due(t_us, self.tilt.in_flight()) {
            self.searcher()?
                .send_locate(image.clone(), self.config.cache.clone())?;
            self.searching.sent(Job {
                index,
                t_us,
                due: 0,
                lost_at: Some(lost_at),
            });
        }
        Ok(())
    }

    /// Step 5: the core's clock to the frame at `t_us`, bridging long gaps, with the trigger;
    /// then everything the core answered.
    fn tick(&mut self, t_us: u64) -> Result<(), TrackerError> {
        for at in self.frames.bridge(t_us) {
            self.send_tick(at, false)?;
        }
        self.send_tick(t_us, true)?;
        self.barrier()
    }

    /// Sends one tick at `t_us` and records its stamp.
    fn send_tick(&mut self, t_us: u64, trigger: bool) -> Result<(), TrackerError> {
        self.core.send(&HostToCore::Tick(Tick { t_us, trigger }))?;
        let stamp = self.frames.ticked(t_us);
        self.tell(Detail::Clock(stamp));
        Ok(())
    }

    /// Step 6: the frame analysed at the core's prediction, its correspondences sent, the
    /// clock moved just past it, and the pose estimated with it judged. Returns that pose and
    /// whether it counts as tracked, where the frame was analysed, and the correspondences
    /// sent.
    fn analyse(
        &mut self,
        index: usize,
        image: GrayImage,
        t_us: u64,
    ) -> Result<(Option<Judged>, usize), TrackerError> {
        let Some(p) = self.session.take_prediction(t_us) else {
            self.settle(index, Fate::NoPrediction);
            return Ok((None, 0));
        };
        let every = self.config.keep_image_every;
        let omega_c = self.omega_c(t_us);
        self.worker.send(FrameJob {
            index,
            stamp: self.frames.stamp_ns(t_us),
            image: FrameImage::Decoded(image),
            prediction: p,
            keep_image: every > 0 && index.is_multiple_of(every),
            omega_c,
        })?;
        let result = self.worker.recv()?;
        let delivered = match self.deliver((p.frame_id, index), t_us, result)? {
            Ok(n) => {
                self.latency(LatencyNote::Sent {
                    index,
                    after_us: t_us,
                });
                Some(n)
            }
            Err(why) => {
                self.emit(Event::FrameSkipped { index, why });
                None
            }
        };
        // The pose estimated with this frame, just after it.
        self.send_tick(t_us + 1, false)?;
        self.barrier()?;
        // The pose out at once, before its judgement.
        self.tell_poses();
        let updated = self.session.last_state().filter(|s| s.t_us == t_us + 1);
        let correspondences = delivered.unwrap_or(0);
        let (true, Some(s)) = (delivered.is_some(), updated) else {
            return Ok((None, correspondences));
        };
        let pose = pose_of_state(s);
        let cov = camera::PoseCovariance::from_upper(&s.cov);
        // Which correspondences the core applied: its reports' residuals, part by part in
        // the order sent, within the gate.
        let applied: Vec<bool> = self
            .session
            .take_updates(p.frame_id)
            .iter()
            .flat_map(|r| r.residuals.iter())
            .map(|&s_i| f64::from(s_i) <= self.gate)
            .collect();
        let a = self.worker.assess(pose, applied)?;
        let v = self.judge.judge(p.frame_id, a, &pose, cov.as_ref(), true);
        self.tell(Detail::Judged {
            frame_id: p.frame_id,
            assessment: v.assessment,
            tracked: v.tracked,
        });
        self.tilt.judged(p.frame_id);
        self.tell_tilt();
        let judged = Judged {
            pose,
            tracked: v.tracked,
            frame_id: p.frame_id,
            cov,
            weakest: v.weakest,
        };
        Ok((Some(judged), correspondences))
    }

    /// Step 7: a tilt check of a tracked pose, when one is due (`image`: the frame, taken
    /// before its analysis).
    fn check_step(
        &mut self,
        image: Option<GrayImage>,
        judged: Option<Judged>,
        index: usize,
    ) -> Result<(), TrackerError> {
        match (image, judged) {
            (Some(image), Some(j)) if j.tracked && self.search.is_some() => {
                self.searcher()?.send_tilt_check(image, j.pose)?;
                self.tilt.sent(index, j.frame_id, j.pose);
                self.tell_tilt();
                self.since_check = 0;
            }
            _ => self.since_check += 1,
        }
        Ok(())
    }

    /// Step 8: the frame's judgement into the loss rule, the state, and the frame's event.
    fn judge(&mut self, judged: Option<Judged>, index: usize, t_us: u64, correspondences: usize) {
        let tracked = judged.is_some_and(|j| j.tracked);
        self.searching.loss.frame(tracked, t_us);
        if tracked {
            self.tracked_since_start = true;
        }
        let state = if self.searching.lost(t_us) {
            State::Lost
        } else if self.tracked_since_start {
            State::Tracking
        } else {
            State::Starting
        };
        self.set_state(state);
        self.emit(Event::Frame(FrameReport {
            index,
            t_us,
            pose: judged.map(|j| j.pose),
            tracked: judged.map(|j| j.tracked),
            correspondences,
            cov: judged.and_then(|j| j.cov),
            weak: judged.and_then(|j| self.judge.weak(j.weakest, j.tracked)),
        }));
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

    /// See [`Self::finish`] (vision-only).
    fn wind_down(&mut self) -> Result<(), TrackerError> {
        if self.tilt.in_flight() {
            self.searcher()?.tilt_result(true)?;
        }
        self.tilt.restart();
        self.tell_tilt();
        if let Some(s) = self.searching.answered() {
            let (a, from) = self.searcher()?.locate_result()?;
            self.tell_search(s.lost_at, Search::new(s.index, s.t_us, a), from);
        }
        self.barrier()
    }

    /// The searches' vision thread.
    fn searcher(&self) -> Result<&VisionWorker, TrackerError> {
        self.search
            .as_ref()
            .ok_or_else(|| TrackerError::VisionThread("no search thread".into()))
    }

    pub(crate) fn set_state(&mut self, state: State) {
        if self.state != state {
            self.state = state;
            self.emit(Event::State(state));
        }
    }

    /// The camera's angular rate at the trigger at `t_us` (the core's state there, through
    /// the mount), for the motion blur's share of a frame's covariance.
    pub(crate) fn omega_c(&self, t_us: u64) -> Option<nalgebra::Vector3<f64>> {
        let s = self.session.last_state().filter(|s| s.t_us == t_us)?;
        Some(self.core_hand_eye.q_cs * nalgebra::Vector3::from(s.omega_s.map(f64::from)))
    }

    /// Tells a search's answer.
    pub(crate) fn tell_located(&mut self, index: usize, pose: Option<CameraPose>) {
        self.emit(Event::Located { index, pose });
    }

    /// Tells what the core said since: its new state reports as poses, and (with details)
    /// everything it said.
    pub(crate) fn tell_poses(&mut self) {
        if self.config.details {
            for item in self.session.take_outbox() {
                self.tell(Detail::Core(item));
            }
            let resent = self.session.take_resent();
            if resent > 0 {
                self.tell(Detail::HellosResent(resent));
            }
        }
        let hand_eye = self.core_hand_eye;
        let mode = self.session.mode();
        let states: Vec<_> = self.session.take_untold().collect();
        for s in states {
            self.latency(LatencyNote::PoseOut(s.t_us));
            let (c_w, q_wc) = hand_eye.camera_of_state(&s);
            let pose = Pose {
                t_us: s.t_us,
                camera: CameraPose {
                    q_cw: q_wc.inverse(),
                    c_w,
                },
                mode,
                cov: camera::PoseCovariance::from_upper(&s.cov),
            };
            self.latest = Some(pose);
            self.emit(Event::Pose(pose));
        }
    }

    /// Queues an event for [`Self::poll`]. A program that never polls loses the oldest beyond
    /// [`MAX_EVENTS`], and is told how many ([`Event::Missed`]).
    pub(crate) fn emit(&mut self, event: Event) {
        if self.events.len() >= MAX_EVENTS {
            self.events.pop_front();
            self.missed += 1;
        }
        self.events.push_back(event);
    }

    /// Tells a detail, where the tracker was asked for them.
    pub(crate) fn tell(&mut self, detail: Detail) {
        if self.config.details {
            self.emit(Event::Detail(Box::new(detail)));
        }
    }

    /// Tells what became of the frame `index`.
    pub(crate) fn settle(&mut self, index: usize, fate: Fate) {
        self.tell(Detail::Settled { index, fate });
    }

    /// Tells a latency's moment, now.
    pub(crate) fn latency(&mut self, note: LatencyNote) {
        if self.config.details {
            self.tell(Detail::Latency(note, Instant::now()));
        }
    }

    /// Tells a search's answer (its attempt, where its database came from, and what it
    /// found), and returns the pose it verified.
    pub(crate) fn searched(
        &mut self,
        lost_at: Option<u64>,
        search: Search,
        from: Option<locate::database::Provenance>,
    ) -> Option<CameraPose> {
        let (index, pose) = (search.index, search.attempt.pose);
        self.tell_search(lost_at, search, from);
        self.tell_located(index, pose);
        pose
    }

    /// Tells a search's attempt, and where its database came from.
    pub(crate) fn tell_search(
        &mut self,
        lost_at: Option<u64>,
        search: Search,
        from: Option<locate::database::Provenance>,
    ) {
        if let Some(from) = from {
            self.tell(Detail::Database(from));
        }
        self.tell(Detail::Search {
            lost_at,
            search: Box::new(search),
        });
    }

    /// Tells what the tilt branch did, and takes its withheld frames off the tally.
    fn tell_tilt(&mut self) {
        for note in self.tilt.take_notes() {
            if let TiltNote::Withheld(ids) = &note {
                self.judge.withhold(ids);
            }
            self.tell(Detail::Tilt(note));
        }
    }

    /// Sends the correspondences of the frame `frame_id` (the input's frame `index`)
    /// triggered at `trigger_us` to the core, and tells its analysis. Returns how many went,
    /// or why a frame whose image cannot be used was skipped (the core dead-reckons); any
    /// other error stops the run.
    pub(crate) fn deliver(
        &mut self,
        (frame_id, index): (u32, usize),
        trigger_us: u64,
        result: Result<vision::FrameResult, TrackerError>,
    ) -> Result<Result<usize, String>, TrackerError> {
        let result = match result {
            Ok(r) => r,
            Err(
                e @ TrackerError::Vision(
                    vision::VisionError::Image { .. } | vision::VisionError::ImageSize { .. },
                ),
            ) => {
                let why = e.to_string();
                self.tell(Detail::FrameError(why.clone()));
                self.settle(index, Fate::Unusable);
                return Ok(Err(why));
            }
            Err(e) => return Err(e),
        };
        let (points, contours) = (&result.correspondences, &result.contours);
        let n = points.len() + contours.len();
        if n > 0 {
            let core_id = self.session.core_frame_id(frame_id);
            let parts = protocol::frame_messages(core_id, trigger_us, points, contours)
                .map_err(|e| TrackerError::Core(format!("frame {frame_id}: {e}")))?;
            for part in parts {
                self.core.send(&part)?;
            }
        }
        self.tell_analysed(frame_id, result, n);
        Ok(Ok(n))
    }

    /// Tells a frame's analysis (`sent`: the correspondences that went to the core).
    pub(crate) fn tell_analysed(
        &mut self,
        frame_id: u32,
        result: vision::FrameResult,
        sent: usize,
    ) {
        // Its fate (analysed) goes with it.
        self.tell(Detail::Analysed {
            frame_id,
            result: Box::new(result),
            sent,
        });
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
