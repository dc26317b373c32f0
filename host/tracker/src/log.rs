//! What the core said, and the exchanges that wait for its answers: the handshake, the
//! barrier (a `Hello` whose answer follows everything sent before it), and a `Configure` or
//! `Init` confirmed on a lossy line (protocol/PROTOCOL.md §3, §8).

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use protocol::{
    CoreToHost, ErrorReport, HostToCore, PROTOCOL_VERSION, PosePrediction, StateReport, Status,
    UpdateReport,
};

use crate::error::TrackerError;
use crate::transport::{CoreTransport, Incoming};

/// On a lossy line: a `Hello` unanswered this long is sent again.
const RESEND_AFTER: Duration = Duration::from_millis(300);

/// On a lossy line: tries of a `Configure` or an `Init` before giving up.
const CONFIRM_TRIES: usize = 10;

/// Everything the core said, as received.
#[derive(Debug, Default)]
pub struct CoreLog {
    /// State reports (one per IMU sample while running).
    pub states: Vec<StateReport>,
    /// Pose predictions by trigger time [µs].
    pub predictions: BTreeMap<u64, PosePrediction>,
    /// Update reports by frame id.
    pub updates: BTreeMap<u32, Vec<UpdateReport>>,
    /// Mode changes.
    pub statuses: Vec<Status>,
    /// Refusals.
    pub errors: Vec<ErrorReport>,
    /// Camera triggers the core fired while it samples its own IMU (protocol 3.1).
    pub triggers: Vec<protocol::Trigger>,
    /// Samples the core took, when it was asked to stream them (protocol 3.1).
    pub raw_imu: Vec<protocol::ImuSample>,
    /// The core's sampling reports: start, gaps, periodic counters (protocol 3.1).
    pub sampling: Vec<protocol::SamplingReport>,
    /// Frames from the core that failed to decode.
    pub rejected_frames: usize,
    /// `HelloAck`s received (handshake and barriers).
    pub acks: usize,
    /// `Hello`s sent again on a lossy line (lost, or their answer lost).
    pub resent_hellos: usize,
    /// Added to the core's frame ids: a core that was reset numbers its frames from 0 again,
    /// and the log keeps one id per frame across cores (`new_core`).
    frame_offset: u32,
    /// One past the largest frame id logged.
    next_frame: u32,
}

impl CoreLog {
    /// Keeps one item from the core.
    pub fn take(&mut self, item: Incoming) {
        match item {
            Incoming::Rejected(_) => self.rejected_frames += 1,
            Incoming::Message(m) => match m {
                CoreToHost::HelloAck(_) => self.acks += 1,
                CoreToHost::Error(e) => self.errors.push(e),
                CoreToHost::PosePrediction(mut p) => {
                    p.frame_id = self.frame_id(p.frame_id);
                    self.predictions.insert(p.t_us, p);
                }
                // The answer to a `Query` repeats the last state: kept once.
                CoreToHost::State(s) if self.states.last().is_some_and(|l| l.t_us == s.t_us) => {}
                CoreToHost::State(s) => self.states.push(s),
                CoreToHost::UpdateReport(mut r) => {
                    r.frame_id = self.frame_id(r.frame_id);
                    self.updates.entry(r.frame_id).or_default().push(r)
                }
                CoreToHost::Status(s) => self.statuses.push(s),
                CoreToHost::Trigger(t) => self.triggers.push(t),
                CoreToHost::RawImu(s) => self.raw_imu.push(s),
                CoreToHost::Sampling(r) => self.sampling.push(r),
            },
        }
    }

    /// The log's id of the current core's frame `core_id`.
    fn frame_id(&mut self, core_id: u32) -> u32 {
        let id = core_id.wrapping_add(self.frame_offset);
        self.next_frame = self.next_frame.max(id.wrapping_add(1));
        id
    }

    /// The current core's id of the log's frame `id`.
    pub fn core_frame_id(&self, id: u32) -> u32 {
        id.wrapping_sub(self.frame_offset)
    }

    /// A new core (reset, and configured again) numbers its frames from 0: they follow the
    /// old core's in the log.
    pub fn new_core(&mut self) {
        self.frame_offset = self.next_frame;
    }

    /// The current mode (last status).
    pub fn mode(&self) -> Option<protocol::Mode> {
        self.statuses.last().map(|s| s.mode)
    }
}

impl CoreLog {
    /// The handshake: `Hello`, and the version's verdict. Refusals of messages sent before
    /// it (to a core that was reset, say) may come first and are logged.
    pub fn handshake(
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
                    self.acks += 1;
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
            self.resent_hellos += 1;
        }
    }

    /// Sends `Hello` and logs everything up to its answer.
    pub fn barrier(
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

    /// Sends a `Configure` or `Init` and logs the answers. On a lossy line, where it may be
    /// lost, it is sent again until a status with `reason` confirms it.
    pub fn send_confirmed(
        &mut self,
        link: &mut impl CoreTransport,
        msg: &HostToCore,
        reason: protocol::StatusReason,
        timeout: Duration,
    ) -> Result<(), TrackerError> {
        let lossy = link.lossy();
        for _ in 0..CONFIRM_TRIES {
            let (seen, errors) = (self.statuses.len(), self.errors.len());
            link.send(msg)?;
            self.barrier(link, timeout)?;
            let confirmed = self.statuses[seen..].iter().any(|s| s.reason == reason);
            // A refusal ends it (the caller names it); the line's noise does not.
            let refused = self.errors[errors..]
                .iter()
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

    /// Logs everything the core has sent so far, without waiting.
    pub fn drain(&mut self, link: &mut impl CoreTransport) -> Result<(), TrackerError> {
        while let Some(item) = link.try_recv()? {
            self.take(item);
        }
        Ok(())
    }
}

/// Whether the core's error `code` is what a lossy line causes rather than a refusal: a frame
/// the line damaged (`Decode`), or a message that arrived while the damaged `Hello` or
/// `Configure` before it was being sent again (`NoHandshake`, `NotConfigured`).
pub fn is_line_noise(code: &protocol::ErrorCode) -> bool {
    use protocol::ErrorCode::{Decode, NoHandshake, NotConfigured};
    matches!(code, Decode(_) | NoHandshake | NotConfigured)
}

/// The `Hello` of this protocol version.
fn hello() -> HostToCore {
    HostToCore::Hello(protocol::Hello {
        version: PROTOCOL_VERSION,
    })
}
