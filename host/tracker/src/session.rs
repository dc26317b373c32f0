//! The tracker's session with the core: the exchanges that wait for its answers (the
//! handshake, the barrier: a `Hello` whose answer follows everything sent before it, and a
//! `Configure` or `Init` confirmed on a lossy line; protocol/PROTOCOL.md §3, §8), and what the
//! tracker's steps need of what the core said, bounded:
//!
//! | kept | for | bound |
//! |---|---|---|
//! | predictions by trigger time | the frame at that trigger | taken when used; [`KEPT`] at most |
//! | update reports by frame | the vision-only verdict | taken when used; [`KEPT`] frames |
//! | the recent state reports | a found pose's yaw carried to now | [`STATES_KEPT`] |
//! | the last state while tracking | a reset core resumed there | one |
//! | statuses, refusals | what answered a message (by count) | [`KEPT`] each |
//! | the core's samples and triggers | pairing them with frames | taken when used; [`QUEUED`] |
//!
//! Everything it takes is also handed on, once, to the tracker's events where a report keeps
//! it ([`crate::event::Detail::Core`]).

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use protocol::{
    CoreToHost, ErrorReport, HostToCore, Mode, PROTOCOL_VERSION, PosePrediction, StateReport,
    Status, UpdateReport,
};

use crate::error::TrackerError;
use crate::transport::{CoreTransport, Incoming};

/// On a lossy line: a `Hello` unanswered this long is sent again.
const RESEND_AFTER: Duration = Duration::from_millis(300);

/// On a lossy line: tries of a `Configure` or an `Init` before giving up.
const CONFIRM_TRIES: usize = 10;

/// Predictions, frames' update reports, statuses and refusals kept at most: far more than
/// are ever waited on at once (a few frames in flight, a few messages answered).
pub(crate) const KEPT: usize = 256;

/// State reports kept: 20 s at 200 Hz, longer than a search takes (its found pose is carried
/// forward by the core's rotation since its frame).
pub(crate) const STATES_KEPT: usize = 4096;

/// The core's own samples and triggers queued at most before the tracker takes them (it
/// takes them at every pump).
pub(crate) const QUEUED: usize = 65_536;

/// A queue of the last [`KEPT`] items and the count of all, so that "those since the mark"
/// can be asked of it.
#[derive(Debug)]
pub(crate) struct Recent<T> {
    items: VecDeque<T>,
    total: usize,
}

impl<T> Default for Recent<T> {
    fn default() -> Self {
        Self {
            items: VecDeque::new(),
            total: 0,
        }
    }
}

impl<T> Recent<T> {
    /// Keeps `item` (the oldest goes beyond [`KEPT`]).
    pub(crate) fn push(&mut self, item: T) {
        if self.items.len() == KEPT {
            self.items.pop_front();
        }
        self.items.push_back(item);
        self.total += 1;
    }

    /// How many came so far: a mark for [`Self::since`].
    pub(crate) fn mark(&self) -> usize {
        self.total
    }

    /// Those that came since `mark` (the last [`KEPT`] of them at most).
    pub(crate) fn since(&self, mark: usize) -> impl DoubleEndedIterator<Item = &T> {
        let new = self.total.saturating_sub(mark).min(self.items.len());
        self.items.range(self.items.len() - new..)
    }

    /// The last one.
    pub(crate) fn last(&self) -> Option<&T> {
        self.items.back()
    }
}

/// What the tracker's steps need of what the core said, and the exchanges with it.
#[derive(Debug, Default)]
pub(crate) struct CoreSession {
    /// Pose predictions by trigger time [µs], until taken.
    predictions: BTreeMap<u64, PosePrediction>,
    /// Update reports by frame id, until taken.
    updates: BTreeMap<u32, Vec<UpdateReport>>,
    /// The last state reports, oldest first.
    states: VecDeque<StateReport>,
    /// The last state reported while tracking.
    last_tracking: Option<StateReport>,
    /// State reports not yet told as poses.
    untold: VecDeque<StateReport>,
    /// Mode changes.
    pub(crate) statuses: Recent<Status>,
    /// Refusals.
    pub(crate) errors: Recent<ErrorReport>,
    /// The core's own samples (protocol 3.1), until taken.
    raw_imu: VecDeque<protocol::ImuSample>,
    /// The core's camera triggers (protocol 3.1), until taken.
    triggers: VecDeque<protocol::Trigger>,
    /// The core's last sampling report.
    last_sampling: Option<protocol::SamplingReport>,
    /// `HelloAck`s received (handshake and barriers).
    acks: usize,
    /// Everything taken, for the events (only when `keep` is set).
    outbox: Vec<Incoming>,
    /// Whether to keep `outbox`.
    keep: bool,
    /// `Hello`s sent again on a lossy line since the last [`Self::take_resent`].
    resent: usize,
    /// Added to the core's frame ids: a core that was reset numbers its frames from 0 again,
    /// and the session keeps one id per frame across cores (`new_core`).
    frame_offset: u32,
    /// One past the largest frame id taken.
    next_frame: u32,
}

impl CoreSession {
    /// A session that hands on what it takes (`keep`) or not.
    pub(crate) fn new(keep: bool) -> Self {
        Self {
            keep,
            ..Self::default()
        }
    }

    /// Takes one item from the core.
    pub(crate) fn take(&mut self, mut item: Incoming) {
        if let Incoming::Message(m) = &mut item {
            match m {
                CoreToHost::HelloAck(_) => self.acks += 1,
                CoreToHost::Error(e) => self.errors.push(*e),
                CoreToHost::PosePrediction(p) => {
                    p.frame_id = self.frame_id(p.frame_id);
                    self.predictions.insert(p.t_us, *p);
                    bound_map(&mut self.predictions);
                }
                CoreToHost::State(s) => self.take_state(*s),
                CoreToHost::UpdateReport(r) => {
                    r.frame_id = self.frame_id(r.frame_id);
                    self.updates.entry(r.frame_id).or_default().push(r.clone());
                    bound_map(&mut self.updates);
                }
                CoreToHost::Status(s) => self.statuses.push(*s),
                CoreToHost::Trigger(t) => bounded_push(&mut self.triggers, *t),
                CoreToHost::RawImu(s) => bounded_push(&mut self.raw_imu, *s),
                CoreToHost::Sampling(r) => self.last_sampling = Some(*r),
            }
        }
        if self.keep {
            self.outbox.push(item);
        }
    }

    /// A state report: the answer to a `Query` repeats the last one, which is kept once.
    fn take_state(&mut self, s: StateReport) {
        if self.states.back().is_some_and(|l| l.t_us == s.t_us) {
            return;
        }
        if self.states.len() == STATES_KEPT {
            self.states.pop_front();
        }
        self.states.push_back(s);
        if s.health.mode == Mode::Tracking {
            self.last_tracking = Some(s);
        }
        self.untold.push_back(s);
    }

    /// The log's id of the current core's frame `core_id`.
    fn frame_id(&mut self, core_id: u32) -> u32 {
        let id = core_id.wrapping_add(self.frame_offset);
        self.next_frame = self.next_frame.max(id.wrapping_add(1));
        id
    }

    /// The current core's id of the session's frame `id`.
    pub(crate) fn core_frame_id(&self, id: u32) -> u32 {
        id.wrapping_sub(self.frame_offset)
    }

    /// A new core (reset, and configured again) numbers its frames from 0: they follow the
    /// old core's.
    pub(crate) fn new_core(&mut self) {
        self.frame_offset = self.next_frame;
    }

    /// The current mode (last status).
    pub(crate) fn mode(&self) -> Option<Mode> {
        self.statuses.last().map(|s| s.mode)
    }

    /// Whether the prediction for the trigger at `t_us` came.
    pub(crate) fn has_prediction(&self, t_us: u64) -> bool {
        self.predictions.contains_key(&t_us)
    }

    /// Takes the prediction for the trigger at `t_us`, and drops those of earlier triggers
    /// (frames given up).
    pub(crate) fn take_prediction(&mut self, t_us: u64) -> Option<PosePrediction> {
        let later = self.predictions.split_off(&(t_us + 1));
        let p = self.predictions.remove(&t_us);
        self.predictions = later;
        p
    }

    /// Takes the update reports of frame `frame_id` in the order of their parts, and drops
    /// those of earlier frames.
    pub(crate) fn take_updates(&mut self, frame_id: u32) -> Vec<UpdateReport> {
        let later = self.updates.split_off(&(frame_id + 1));
        let mut reports = self.updates.remove(&frame_id).unwrap_or_default();
        self.updates = later;
        reports.sort_by_key(|r| r.part);
        reports
    }

    /// The last state report.
    pub(crate) fn last_state(&self) -> Option<&StateReport> {
        self.states.back()
    }

    /// The state report at or just before `t_us`, among the last [`STATES_KEPT`].
    pub(crate) fn state_at(&self, t_us: u64) -> Option<&StateReport> {
        let i = self.states.partition_point(|s| s.t_us <= t_us);
        i.checked_sub(1).and_then(|i| self.states.get(i))
    }

    /// The last state reported while tracking.
    pub(crate) fn last_tracking(&self) -> Option<&StateReport> {
        self.last_tracking.as_ref()
    }

    /// The oldest state report not yet told.
    pub(crate) fn next_untold(&mut self) -> Option<StateReport> {
        self.untold.pop_front()
    }

    /// The next of the core's own samples.
    pub(crate) fn next_raw_imu(&mut self) -> Option<protocol::ImuSample> {
        self.raw_imu.pop_front()
    }

    /// The next of the core's triggers, if it is at or before `t_us`.
    pub(crate) fn next_trigger_by(&mut self, t_us: u64) -> Option<protocol::Trigger> {
        self.triggers
            .front()
            .is_some_and(|t| t.t_us <= t_us)
            .then(|| self.triggers.pop_front())
            .flatten()
    }

    /// The core's last sampling report.
    pub(crate) fn last_sampling(&self) -> Option<&protocol::SamplingReport> {
        self.last_sampling.as_ref()
    }

    /// Everything taken since the last call, in order (kept only when the session was made
    /// to keep it).
    pub(crate) fn take_outbox(&mut self) -> Vec<Incoming> {
        std::mem::take(&mut self.outbox)
    }

    /// `Hello`s sent again on a lossy line since the last call.
    pub(crate) fn take_resent(&mut self) -> usize {
        std::mem::take(&mut self.resent)
    }
}

/// Drops the oldest entries of `map` beyond [`KEPT`].
fn bound_map<K: Ord + Copy, V>(map: &mut BTreeMap<K, V>) {
    while map.len() > KEPT {
        map.pop_first();
    }
}

/// Queues `item`, dropping the oldest beyond [`QUEUED`].
fn bounded_push<T>(queue: &mut VecDeque<T>, item: T) {
    if queue.len() == QUEUED {
        queue.pop_front();
    }
    queue.push_back(item);
}

impl CoreSession {
    /// The handshake: `Hello`, and the version's verdict. Refusals of messages sent before
    /// it (to a core that was reset, say) may come first and are taken.
    pub(crate) fn handshake(
        &mut self,
        link: &mut impl CoreTransport,
        timeout: Duration,
    ) -> Result<protocol::HelloAck, TrackerError> {
        let hello = hello();
        link.send(&hello)?;
        let deadline = Instant::now() + timeout;
        loop {
            match self.next_or_resend(link, &hello, deadline, timeout)? {
                Incoming::Message(
                    m @ (CoreToHost::HelloAck(_)
                    | CoreToHost::Error(protocol::ErrorReport {
                        code: protocol::ErrorCode::VersionMismatch { .. },
                    })),
                ) => {
                    let ack = protocol::handshake::check_answer(&m)
                        .map_err(|e| TrackerError::Core(format!("handshake: {e}")))?;
                    self.take(Incoming::Message(CoreToHost::HelloAck(ack)));
                    return Ok(ack);
                }
                other => self.take(other),
            }
        }
    }

    /// The next item from the core by `deadline`. On a lossy line a `Hello` or its answer may
    /// be lost: then `hello` is sent again every [`RESEND_AFTER`].
    fn next_or_resend(
        &mut self,
        link: &mut impl CoreTransport,
        hello: &HostToCore,
        deadline: Instant,
        timeout: Duration,
    ) -> Result<Incoming, TrackerError> {
        if !link.lossy() {
            return link.recv(timeout);
        }
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if let Some(item) = link.recv_within(left.min(RESEND_AFTER))? {
                return Ok(item);
            }
            if left <= RESEND_AFTER {
                return link.recv(Duration::ZERO);
            }
            link.send(hello)?;
            self.resent += 1;
        }
    }

    /// Sends `Hello` and takes everything up to its answer.
    pub(crate) fn barrier(
        &mut self,
        link: &mut impl CoreTransport,
        timeout: Duration,
    ) -> Result<(), TrackerError> {
        let hello = hello();
        link.send(&hello)?;
        let acks = self.acks;
        let deadline = Instant::now() + timeout;
        while self.acks == acks {
            let item = self.next_or_resend(link, &hello, deadline, timeout)?;
            self.take(item);
        }
        Ok(())
    }

    /// Sends a `Configure` or `Init` and takes the answers. On a lossy line, where it may be
    /// lost, it is sent again until a status with `reason` confirms it.
    pub(crate) fn send_confirmed(
        &mut self,
        link: &mut impl CoreTransport,
        msg: &HostToCore,
        reason: protocol::StatusReason,
        timeout: Duration,
    ) -> Result<(), TrackerError> {
        let lossy = link.lossy();
        for _ in 0..CONFIRM_TRIES {
            let (seen, errors) = (self.statuses.mark(), self.errors.mark());
            link.send(msg)?;
            self.barrier(link, timeout)?;
            let confirmed = self.statuses.since(seen).any(|s| s.reason == reason);
            // A refusal ends it (the caller names it); the line's noise does not.
            let refused = self
                .errors
                .since(errors)
                .any(|e| !(lossy && is_line_noise(&e.code)));
            if !lossy || confirmed || refused {
                return Ok(());
            }
        }
        let what = match msg {
            HostToCore::Configure(_) => "the Configure",
            HostToCore::Init(_) => "the Init",
            _ => "the message",
        };
        Err(TrackerError::Core(format!(
            "no confirmation of {what} in {CONFIRM_TRIES} tries over the noisy line"
        )))
    }

    /// Takes everything the core has sent so far, without waiting.
    pub(crate) fn drain(&mut self, link: &mut impl CoreTransport) -> Result<(), TrackerError> {
        while let Some(item) = link.try_recv()? {
            self.take(item);
        }
        Ok(())
    }
}

/// Whether the core's error `code` is what a lossy line causes rather than a refusal: a frame
/// the line damaged (`Decode`), or a message that arrived while the damaged `Hello` or
/// `Configure` before it was being sent again (`NoHandshake`, `NotConfigured`).
pub(crate) fn is_line_noise(code: &protocol::ErrorCode) -> bool {
    use protocol::ErrorCode::{Decode, NoHandshake, NotConfigured};
    matches!(code, Decode(_) | NoHandshake | NotConfigured)
}

/// The `Hello` of this protocol version.
fn hello() -> HostToCore {
    HostToCore::Hello(protocol::Hello {
        version: PROTOCOL_VERSION,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 57: what the session keeps is bounded however long the run.
    #[test]
    fn the_session_keeps_a_bounded_window_of_what_the_core_said() {
        let mut s = CoreSession::new(false);
        let state = |t_us| StateReport {
            t_us,
            s_w: [0.0; 3],
            q_sw: [1.0, 0.0, 0.0, 0.0],
            v_w: [0.0; 3],
            a_w: [0.0; 3],
            omega_s: [0.0; 3],
            gyro_bias: [0.0; 3],
            accel_bias: [0.0; 3],
            health: protocol::Health {
                mode: Mode::Tracking,
                covariance_frobenius: 0.0,
                residual_lowpass: 0.0,
                quaternion_norm_error: 0.0,
            },
            cov: [0.0; 21],
        };
        for k in 0..(STATES_KEPT as u64 + 10) {
            s.take(Incoming::Message(CoreToHost::State(state(k))));
            s.take(Incoming::Message(CoreToHost::PosePrediction(
                PosePrediction {
                    frame_id: k as u32,
                    t_us: k,
                    c_w: [0.0; 3],
                    q_cw: [1.0, 0.0, 0.0, 0.0],
                    cov: [0.0; 21],
                },
            )));
            while s.next_untold().is_some() {}
        }
        assert_eq!(s.states.len(), STATES_KEPT);
        assert!(s.predictions.len() <= KEPT);
        assert!(s.outbox.is_empty());
        // A prediction taken drops the earlier ones.
        let last = STATES_KEPT as u64 + 9;
        assert!(s.take_prediction(last - 3).is_some());
        assert_eq!(s.predictions.len(), 3);
        // Marks count past the window.
        let mut r = Recent::default();
        let mark = r.mark();
        for i in 0..(KEPT + 5) {
            r.push(i);
        }
        assert_eq!(r.since(mark).count(), KEPT);
        assert_eq!(
            r.since(r.mark() - 2).copied().collect::<Vec<_>>(),
            [KEPT + 3, KEPT + 4]
        );
    }
}
