//! The vision-only model's steps: without an IMU the frames are the clock, and each frame
//! goes through named steps (as M3T's tracker loop does), in this order:
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

use image::GrayImage;
use protocol::{HostToCore, StatusReason, Tick};
use vision::{FrameImage, FrameJob};

use super::{
    Answers, Event, Frame, FrameReport, Judged, Start, State, TILT_CHECK_EVERY, Tracker, init_at,
    pose_of_state,
};
use crate::config::vision_config;
use crate::error::TrackerError;
use crate::event::{Detail, LatencyNote};
use crate::record::Fate;
use crate::search::Search;
use crate::searching::Job;
use crate::transport::CoreTransport;

impl<T: CoreTransport> Tracker<T> {
    /// The start of a vision-only run: the handshake, the `Configure`, and the `Init` where
    /// the start pose is given. Correspondences go out before the next tick: no latency to
    /// check against the core's buffers.
    pub(super) fn start_vision(&mut self) -> Result<(), TrackerError> {
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

    /// Step 1 (vision-only): the frame's pixels, size and time. Returns its time [µs from
    /// the first frame] and pixels.
    pub(super) fn check_frame(&mut self, frame: Frame) -> Result<(u64, GrayImage), TrackerError> {
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
    pub(super) fn track(
        &mut self,
        index: usize,
        image: GrayImage,
        t_us: u64,
    ) -> Result<(), TrackerError> {
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
    pub(super) fn start_step(
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
            let job = Job {
                index,
                t_us,
                due: 0,
                lost_at: None,
            };
            self.send_search(image.clone(), job)?;
        }
        Ok(false)
    }

    /// Step 3: the answers of the search and the tilt check sent at an earlier frame: waited
    /// for ([`Answers::AtNextFrame`]) or taken if ready. A verified pose of a search
    /// re-initialises the core; so does a tilt check that found tracking on the other tilt of
    /// a face (`crate::tilt`).
    pub(super) fn take_answers(&mut self, t_us: u64) -> Result<(), TrackerError> {
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
    pub(super) fn search_step(
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
            let job = Job {
                index,
                t_us,
                due: 0,
                lost_at: Some(lost_at),
            };
            self.send_search(image.clone(), job)?;
        }
        Ok(())
    }

    /// Step 5: the core's clock to the frame at `t_us`, bridging long gaps, with the trigger;
    /// then everything the core answered.
    pub(super) fn tick(&mut self, t_us: u64) -> Result<(), TrackerError> {
        for at in self.frames.bridge(t_us) {
            self.send_tick(at, false)?;
        }
        self.send_tick(t_us, true)?;
        self.barrier()
    }

    /// Sends one tick at `t_us` and records its stamp.
    pub(super) fn send_tick(&mut self, t_us: u64, trigger: bool) -> Result<(), TrackerError> {
        self.core.send(&HostToCore::Tick(Tick { t_us, trigger }))?;
        let stamp = self.frames.ticked(t_us);
        self.tell(Detail::Clock(stamp));
        Ok(())
    }

    /// Step 6: the frame analysed at the core's prediction, its correspondences sent, the
    /// clock moved just past it, and the pose estimated with it judged. Returns that pose and
    /// whether it counts as tracked, where the frame was analysed, and the correspondences
    /// sent.
    pub(super) fn analyse(
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
    pub(super) fn check_step(
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
    pub(super) fn judge(
        &mut self,
        judged: Option<Judged>,
        index: usize,
        t_us: u64,
        correspondences: usize,
    ) {
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

    /// See [`Self::finish`] (vision-only).
    pub(super) fn wind_down(&mut self) -> Result<(), TrackerError> {
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
}
