//! Faults in the field, on the host's side (protocol/PROTOCOL.md §8): noticing that the core
//! was reset or the line was lost, reconnecting with back-off, and bringing the core back to
//! where tracking was: the samples it missed if it kept its state, or a new configuration and
//! an initialisation from the last good pose if it did not.

use protocol::{ErrorCode, HostToCore, Init, InitAttitude, Mode, Resume, StatusReason};

use super::{Answers, Tracker};
use crate::error::TrackerError;
use crate::record::{Outage, OutageKind};
use crate::transport::CoreTransport;

/// Seconds of `t_us`.
fn seconds(t_us: u64) -> f64 {
    t_us as f64 / 1e6
}

/// The first wait before reconnecting [µs of the input's clock]; it doubles after each failed
/// attempt, up to [`MAX_BACKOFF_US`].
const FIRST_BACKOFF_US: u64 = 10_000;
/// The longest wait between two attempts [µs].
const MAX_BACKOFF_US: u64 = 1_000_000;
/// A link down this long [µs] stops the run (what was tracked is written).
pub const GIVE_UP_US: u64 = 10_000_000;
/// A core that kept its state is brought up to date with the samples it missed, up to this
/// many [µs]: beyond, dead reckoning on the IMU alone is no estimate worth keeping, and the
/// core is initialised again from the last good pose instead.
pub const MAX_BACKLOG_US: u64 = 5_000_000;
/// A core that lost its state resumes from the last one it reported while tracking if that
/// is at most this old [µs]; older, the motion since is unknown, and the core is initialised
/// from its position and yaw instead. The core's own window for trusting a vision-anchored
/// estimate (`fusion_core::device::SOFT_RESET_WINDOW_US`), for the same reason: a hand-held
/// device turns by more within a fraction of a second.
const RESUME_WITHIN_US: u64 = 500_000;

/// An outage in progress: what is known of it so far, and when to try again.
#[derive(Debug)]
pub(crate) struct Open {
    pub(crate) outage: Outage,
    next_attempt_us: u64,
    backoff_us: u64,
    since_us: u64,
}

/// The outcome of one attempt to reach the core.
pub(crate) enum Attempt {
    /// Not yet: the link is still down, or it is not time to try.
    Waiting,
    /// The core is back and up to date; go on with the current sample.
    Resumed,
}

impl<T: CoreTransport> Tracker<T> {
    /// Whether the core refused a message for want of a handshake or a configuration since
    /// `seen` refusals: it was reset.
    pub(crate) fn core_forgot(&self, seen: usize) -> bool {
        self.session
            .errors
            .since(seen)
            .any(|e| matches!(e.code, ErrorCode::NoHandshake | ErrorCode::NotConfigured))
    }

    /// Records an outage noticed at the sample of time `t_us` because of `cause`. The frames
    /// in flight are recorded but not delivered: their predictions may come from a core that
    /// is gone.
    pub(crate) fn begin_outage(&mut self, cause: String, t_us: u64) -> Result<Open, TrackerError> {
        // A frame still waiting for its prediction waits for a core that is gone: unsettled.
        self.imu_mut()?.late = None;
        while let Some(p) = self.imu_mut()?.pending.pop_front() {
            if let Ok(r) = self.worker.recv()? {
                self.tell_analysed(p.frame_id, r, 0);
            }
        }
        let (injected_s, notice_wall_ms) = match self.injected.take() {
            Some((at, wall)) => (Some(at), Some(wall.elapsed().as_secs_f64() * 1e3)),
            None => (None, None),
        };
        let outage = Outage {
            kind: OutageKind::Unresolved,
            cause,
            noticed_s: seconds(t_us),
            injected_s,
            notice_wall_ms,
            attempts: 0,
            last_failure: None,
            resumed_s: None,
            resumed_on: None,
            backlog: 0,
            tracking_s: None,
        };
        Ok(Open {
            outage,
            next_attempt_us: t_us,
            backoff_us: FIRST_BACKOFF_US,
            since_us: t_us,
        })
    }

    /// Tries to reach the core again at the sample of time `t_us`: reconnects if the link is
    /// down, shakes hands, and then either sends a core that kept our session the samples it
    /// missed, or configures and initialises a core that lost it. Between failed attempts it
    /// waits, in the input's time, twice as long as before.
    pub(crate) fn attempt_resume(
        &mut self,
        open: &mut Open,
        t_us: u64,
    ) -> Result<Attempt, TrackerError> {
        if t_us < open.next_attempt_us {
            return Ok(Attempt::Waiting);
        }
        let outage = &mut open.outage;
        if t_us.saturating_sub(open.since_us) > GIVE_UP_US {
            return Err(TrackerError::Link(format!(
                "link {}: the core could not be reached for {:.1} s ({} attempts): {}",
                self.core.name(),
                GIVE_UP_US as f64 * 1e-6,
                outage.attempts,
                outage.cause
            )));
        }
        outage.attempts += 1;
        let reached = self
            .reach()
            .and_then(|ack| self.bring_up_to_date(outage, &ack, t_us));
        match reached {
            Ok(()) => {
                outage.resumed_s = Some(seconds(t_us));
                outage.resumed_on = Some(self.core.name().to_string());
                Ok(Attempt::Resumed)
            }
            // Not there, or lost again on the way: the next attempt starts over.
            Err(TrackerError::Link(e)) => {
                outage.last_failure = Some(e);
                self.core.disconnect();
                open.next_attempt_us = t_us + open.backoff_us;
                if self.config.answers == Answers::AtNextFrame {
                    // A device comes back in real time: in a replay the wait passes on the
                    // wall clock too, so that the outage is as long on both.
                    std::thread::sleep(std::time::Duration::from_micros(open.backoff_us));
                }
                open.backoff_us = (open.backoff_us * 2).min(MAX_BACKOFF_US);
                Ok(Attempt::Waiting)
            }
            Err(e) => Err(e),
        }
    }

    /// After the handshake `ack` at the sample of time `t_us`: sends a core that kept our
    /// session the samples it missed, or configures and initialises one that lost it.
    fn bring_up_to_date(
        &mut self,
        outage: &mut Outage,
        ack: &protocol::HelloAck,
        t_us: u64,
    ) -> Result<(), TrackerError> {
        let kept = if ack.session == self.session_id {
            self.query()?
        } else {
            None
        };
        match kept.filter(|&(mode, last_us)| {
            matches!(mode, Mode::Tracking | Mode::DeadReckoning)
                && t_us.saturating_sub(last_us) <= MAX_BACKLOG_US
        }) {
            Some((_, last_us)) => {
                // The core went on without us: bring it up to date. Its predictions for the
                // frames of the gap come too late for vision: it dead-reckons through them.
                let missed: Vec<_> = self
                    .imu_mut()?
                    .recent
                    .iter()
                    .filter(|s| s.t_us > last_us && s.t_us < t_us)
                    .copied()
                    .collect();
                for s in &missed {
                    self.send_sample(s)?;
                }
                self.barrier()?;
                outage.backlog = missed.len();
                outage.kind = OutageKind::LinkLost;
            }
            None => {
                self.configure_again(t_us)?;
                outage.kind = OutageKind::CoreReset;
            }
        }
        Ok(())
    }

    /// Reconnects if needed and shakes hands.
    fn reach(&mut self) -> Result<protocol::HelloAck, TrackerError> {
        if !self.core.is_connected() {
            self.core.reconnect()?;
        }
        self.session.handshake(&mut self.core, self.config.timeout)
    }

    /// Asks a core for its mode and the time of its last sample.
    pub(crate) fn query(&mut self) -> Result<Option<(Mode, u64)>, TrackerError> {
        let seen = self.session.statuses.mark();
        self.core.send(&HostToCore::Query)?;
        self.barrier()?;
        Ok(self
            .session
            .statuses
            .since(seen)
            .rev()
            .find(|s| s.reason == StatusReason::Queried)
            .map(|s| (s.mode, s.t_us)))
    }

    /// Configures a core that lost its state and starts it again where it was: from the last
    /// state it reported while tracking (`Resume`), if that is recent; else from that state's
    /// position and yaw with roll and pitch from gravity again (or from the run's start, if it
    /// never tracked).
    fn configure_again(&mut self, t_us: u64) -> Result<(), TrackerError> {
        let config = crate::config::core_config(
            &self.config.rig,
            self.config.model,
            &self.config.tuning,
            self.session_id,
        );
        let errors = self.session.errors.mark();
        self.send_confirmed(&HostToCore::Configure(config), StatusReason::Configured)?;
        // The new core numbers its frames from 0 again.
        self.session.new_core();
        let start = match self.session.last_tracking().copied() {
            Some(s) if t_us.saturating_sub(s.t_us) <= RESUME_WITHIN_US => {
                HostToCore::Resume(Resume::of(&s))
            }
            Some(s) => {
                // The yaw of the sensor in the world, as `Init` takes it (`q_ws`, not `q_sw`).
                let (_, q_ws) = crate::rig::state_pose(&s);
                HostToCore::Init(Init {
                    position: s.s_w,
                    attitude: InitAttitude::GravityAndYaw(q_ws.euler_angles().2 as f32),
                })
            }
            None => HostToCore::Init(self.init_message()?),
        };
        self.send_confirmed(&start, StatusReason::HostRequest)?;
        if let Some(e) = self.refusal(errors) {
            return Err(TrackerError::Core(format!(
                "refused the configuration again: {e}"
            )));
        }
        Ok(())
    }
}
