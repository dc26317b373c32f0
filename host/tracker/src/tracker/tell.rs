//! What the tracker tells ([`crate::event`]): its events queued for the program's polls
//! (bounded, [`super::MAX_EVENTS`]), the poses of the core's state reports, and, where it was
//! asked for them, the details a run's report keeps (every message of the core, every
//! frame's analysis, the searches, the tilt checks, the latencies).

use std::time::Instant;

use camera::CameraPose;

use super::{Event, MAX_EVENTS, Pose, State, Tracker};
use crate::error::TrackerError;
use crate::event::{Detail, LatencyNote};
use crate::record::Fate;
use crate::search::Search;
use crate::tilt::TiltNote;
use crate::transport::CoreTransport;

impl<T: CoreTransport> Tracker<T> {
    pub(crate) fn set_state(&mut self, state: State) {
        if self.state != state {
            self.state = state;
            self.emit(Event::State(state));
        }
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
        // Popped one at a time: a sample's push tells its state without a collection.
        while let Some(s) = self.session.next_untold() {
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
    pub(super) fn tell_tilt(&mut self) {
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
