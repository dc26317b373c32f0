//! Faults in the field, on the host's side (protocol/PROTOCOL.md §8): noticing that the core
//! was reset or the line was lost, reconnecting with back-off, and bringing the core back to
//! where tracking was: the samples it missed if it kept its state, or a new configuration and
//! an initialisation from the last good pose if it did not.

use std::collections::VecDeque;
use std::time::Instant;

use protocol::{ErrorCode, HostToCore, Init, InitAttitude, Mode, Resume, StatusReason};

use super::output::{Outage, OutageKind, seconds};
use super::{FaultyLink, Pending, Session, TrackError, VisionWorker};

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

/// An outage in progress: the record, and when to try again.
#[derive(Debug)]
pub(super) struct Open {
    pub index: usize,
    next_attempt_us: u64,
    backoff_us: u64,
    since_us: u64,
}

/// The outcome of one attempt to reach the core.
pub(super) enum Attempt {
    /// Not yet: the link is still down, or it is not time to try.
    Waiting,
    /// The core is back and up to date; go on with the current sample.
    Resumed,
}

/// Injected faults pending at a sample: when they were injected, for the notice's time.
#[derive(Debug, Default)]
pub(super) struct Injected {
    reset_done: bool,
    cut_done: bool,
    /// The last injection not yet noticed: `(input time [s], wall clock)`.
    pending: Option<(f64, Instant)>,
    /// Until when [µs] the cable is out.
    cut_until_us: Option<u64>,
}

impl Session<'_> {
    /// Injects the faults due at the sample of time `t_us` (`--reset-core-at`,
    /// `--cut-link-at`).
    pub(super) fn inject_faults(
        &mut self,
        link: &mut FaultyLink,
        injected: &mut Injected,
        t_us: u64,
    ) -> Result<(), TrackError> {
        let t = seconds(t_us);
        let f = self.options.faults;
        if let Some(at) = f
            .reset_core_at
            .filter(|&at| t >= at && !injected.reset_done)
        {
            injected.reset_done = true;
            // Everything sent before the reset reaches the core first: a repeatable cut.
            self.barrier(link)?;
            link.reset_core()?;
            injected.pending = Some((at, Instant::now()));
        }
        if let Some(at) = f.cut_link_at.filter(|&at| t >= at && !injected.cut_done) {
            injected.cut_done = true;
            self.barrier(link)?;
            link.cut();
            injected.cut_until_us = Some(t_us + (f.cut_seconds.max(0.0) * 1e6) as u64);
            injected.pending = Some((at, Instant::now()));
        }
        Ok(())
    }

    /// Whether the core refused a message for want of a handshake or a configuration since
    /// `seen` refusals: it was reset.
    pub(super) fn core_forgot(&self, seen: usize) -> bool {
        self.record.log.errors[seen.min(self.record.log.errors.len())..]
            .iter()
            .any(|e| matches!(e.code, ErrorCode::NoHandshake | ErrorCode::NotConfigured))
    }

    /// Records an outage noticed at the sample of time `t_us` because of `cause`. The frames
    /// in flight are recorded but not delivered: their predictions may come from a core that
    /// is gone.
    pub(super) fn begin_outage(
        &mut self,
        cause: String,
        t_us: u64,
        injected: &mut Injected,
        pending: &mut VecDeque<Pending>,
        worker: &VisionWorker,
    ) -> Result<Open, TrackError> {
        while let Some(p) = pending.pop_front() {
            if let Ok(r) = worker.recv()? {
                self.record.results.push((p.frame_id, r));
            }
        }
        let (injected_s, notice_wall_ms) = match injected.pending.take() {
            Some((at, wall)) => (Some(at), Some(wall.elapsed().as_secs_f64() * 1e3)),
            None => (None, None),
        };
        self.host.outages.push(Outage {
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
        });
        Ok(Open {
            index: self.host.outages.len() - 1,
            next_attempt_us: t_us,
            backoff_us: FIRST_BACKOFF_US,
            since_us: t_us,
        })
    }

    /// Tries to reach the core again at the sample `k` (of time `t_us`): reconnects if the
    /// link is down, shakes hands, and then either sends a core that kept our session the
    /// samples it missed, or configures and initialises a core that lost it. Between failed
    /// attempts it waits, in the input's time, twice as long as before.
    pub(super) fn attempt_resume(
        &mut self,
        link: &mut FaultyLink,
        open: &mut Open,
        injected: &Injected,
        k: usize,
        triggers: &std::collections::BTreeMap<usize, usize>,
    ) -> Result<Attempt, TrackError> {
        let t_us = self.t_us(k);
        if t_us < open.next_attempt_us {
            return Ok(Attempt::Waiting);
        }
        if t_us.saturating_sub(open.since_us) > GIVE_UP_US {
            return Err(TrackError::Link(format!(
                "link {}: the core could not be reached for {:.1} s ({} attempts): {}",
                link.name(),
                GIVE_UP_US as f64 * 1e-6,
                self.host.outages[open.index].attempts,
                self.host.outages[open.index].cause
            )));
        }
        self.host.outages[open.index].attempts += 1;
        let reached = if injected.cut_until_us.is_some_and(|until| t_us < until) {
            // The cable is out: the device is gone, as a serial adaptor's is.
            Err(TrackError::Link("the cable is out (injected)".into()))
        } else {
            self.reach(link)
                .and_then(|ack| self.bring_up_to_date(link, open.index, &ack, k, triggers))
        };
        match reached {
            Ok(()) => {
                self.host.outages[open.index].resumed_s = Some(seconds(t_us));
                self.host.outages[open.index].resumed_on = Some(link.name().to_string());
                Ok(Attempt::Resumed)
            }
            // Not there, or lost again on the way: the next attempt starts over.
            Err(TrackError::Link(e)) => {
                self.host.outages[open.index].last_failure = Some(e);
                link.cut();
                open.next_attempt_us = t_us + open.backoff_us;
                if self.options.pacing == super::Pacing::LockStep {
                    // A device comes back in real time: in lock-step the wait passes on the
                    // wall clock too, so that the outage is as long on both.
                    std::thread::sleep(std::time::Duration::from_micros(open.backoff_us));
                }
                open.backoff_us = (open.backoff_us * 2).min(MAX_BACKOFF_US);
                Ok(Attempt::Waiting)
            }
            Err(e) => Err(e),
        }
    }

    /// After the handshake `ack` at sample `k`: sends a core that kept our session the
    /// samples it missed, or configures and initialises one that lost it.
    fn bring_up_to_date(
        &mut self,
        link: &mut FaultyLink,
        outage: usize,
        ack: &protocol::HelloAck,
        k: usize,
        triggers: &std::collections::BTreeMap<usize, usize>,
    ) -> Result<(), TrackError> {
        let t_us = self.t_us(k);
        let kept = if ack.session == self.record.session_id {
            self.query(link)?
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
                let missed: Vec<usize> = (0..k)
                    .rev()
                    .take_while(|&j| self.t_us(j) > last_us)
                    .collect();
                for &j in missed.iter().rev() {
                    self.send_sample(link, j, triggers.contains_key(&j))?;
                }
                self.barrier(link)?;
                self.host.outages[outage].backlog = missed.len();
                self.host.outages[outage].kind = OutageKind::LinkLost;
            }
            None => {
                self.configure_again(link, t_us)?;
                self.host.outages[outage].kind = OutageKind::CoreReset;
            }
        }
        Ok(())
    }

    /// Reconnects if needed and shakes hands.
    fn reach(&mut self, link: &mut FaultyLink) -> Result<protocol::HelloAck, TrackError> {
        if !link.is_connected() {
            link.reconnect()?;
        }
        self.handshake(link)
    }

    /// Asks a core for its mode and the time of its last sample.
    pub(super) fn query(
        &mut self,
        link: &mut FaultyLink,
    ) -> Result<Option<(Mode, u64)>, TrackError> {
        let seen = self.record.log.statuses.len();
        link.send(&HostToCore::Query)?;
        self.barrier(link)?;
        Ok(self.record.log.statuses[seen..]
            .iter()
            .rev()
            .find(|s| s.reason == StatusReason::Queried)
            .map(|s| (s.mode, s.t_us)))
    }

    /// Configures a core that lost its state and starts it again where it was: from the last
    /// state it reported while tracking (`Resume`), if that is recent; else from that state's
    /// position and yaw with roll and pitch from gravity again (or from the run's start, if it
    /// never tracked).
    fn configure_again(&mut self, link: &mut FaultyLink, t_us: u64) -> Result<(), TrackError> {
        let config = super::core_config(
            &self.dataset.rig(),
            self.options.filter,
            &self.options.tuning,
            self.record.session_id,
        );
        let errors = self.record.log.errors.len();
        self.send_confirmed(
            link,
            &HostToCore::Configure(config),
            StatusReason::Configured,
        )?;
        // The new core numbers its frames from 0 again.
        self.record.log.new_core();
        let last_good = self
            .record
            .log
            .states
            .iter()
            .rev()
            .find(|s| s.health.mode == Mode::Tracking);
        let start = match last_good {
            Some(s) if t_us.saturating_sub(s.t_us) <= RESUME_WITHIN_US => {
                HostToCore::Resume(Resume::of(s))
            }
            Some(s) => {
                // The yaw of the sensor in the world, as `Init` takes it (`q_ws`, not `q_sw`).
                let (_, q_ws) = super::state_pose(s);
                HostToCore::Init(Init {
                    position: s.s_w,
                    attitude: InitAttitude::GravityAndYaw(q_ws.euler_angles().2 as f32),
                })
            }
            None => HostToCore::Init(self.init_message()?),
        };
        self.send_confirmed(link, &start, StatusReason::HostRequest)?;
        if let Some(e) = self.record.log.errors.get(errors) {
            return Err(TrackError::Core(format!(
                "refused the configuration again: {}",
                e.code
            )));
        }
        Ok(())
    }

    /// Fills in, from the statuses, when the core reported `Tracking` again after each
    /// outage.
    pub(super) fn close_outages(&mut self) {
        for o in &mut self.host.outages {
            let Some(resumed) = o.resumed_s else {
                continue;
            };
            o.tracking_s = self
                .record
                .log
                .statuses
                .iter()
                .map(|s| (seconds(s.t_us), s.mode))
                .find(|&(t, m)| t >= resumed && m == Mode::Tracking)
                .map(|(t, _)| t);
        }
    }
}
