//! What the core said over a run, for its reports: a [`crate::record::Record`] keeps it from
//! the tracker's events ([`crate::event::Detail::Core`]). The tracker's own steps keep only a
//! bounded window of it ([`crate::session`]).

use std::collections::BTreeMap;

use protocol::{CoreToHost, ErrorReport, PosePrediction, StateReport, Status, UpdateReport};

use crate::transport::Incoming;

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
}

impl CoreLog {
    /// Keeps one item from the core (frame ids as the tracker's session numbers them: one
    /// per frame across cores that were reset).
    pub fn take(&mut self, item: Incoming) {
        match item {
            Incoming::Rejected(_) => self.rejected_frames += 1,
            Incoming::Message(m) => match m {
                CoreToHost::HelloAck(_) => self.acks += 1,
                CoreToHost::Error(e) => self.errors.push(e),
                CoreToHost::PosePrediction(p) => {
                    self.predictions.insert(p.t_us, p);
                }
                // The answer to a `Query` repeats the last state: kept once.
                CoreToHost::State(s) if self.states.last().is_some_and(|l| l.t_us == s.t_us) => {}
                CoreToHost::State(s) => self.states.push(s),
                CoreToHost::UpdateReport(r) => self.updates.entry(r.frame_id).or_default().push(r),
                CoreToHost::Status(s) => self.statuses.push(s),
                CoreToHost::Trigger(t) => self.triggers.push(t),
                CoreToHost::RawImu(s) => self.raw_imu.push(s),
                CoreToHost::Sampling(r) => self.sampling.push(r),
            },
        }
    }

    /// The current mode (last status).
    pub fn mode(&self) -> Option<protocol::Mode> {
        self.statuses.last().map(|s| s.mode)
    }
}
