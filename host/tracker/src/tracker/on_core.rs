//! The tracker's runs with the core sampling its own IMU (protocol/PROTOCOL.md §7): the
//! program pushes frames only. The core streams the samples it took (`RawImu`), fires the
//! camera every k-th sample and says so (`Trigger`), and predicts the frame at the trigger as
//! it does for a host's trigger flag. [`Tracker::pump`] takes what the core sent, and per
//! sample, in order:
//!
//! 1. the sample's time on the input's clock (the first pair of frame and trigger sets the
//!    offset);
//! 2. the triggers fired up to it, to pair;
//! 3. `deliver_due`: the correspondences due before the core's next sample (in a
//!    replay exactly `latency` after their trigger, counted in samples, as with pushed
//!    samples; live, those ready);
//! 4. pairing (`pair_frames`): each frame with the trigger before it, within the
//!    delay bound, and the pair to the vision thread at the trigger's prediction;
//! 5. the state after the sample.
//!
//! Frames and triggers are paired by their times, in order, so a frame the camera dropped
//! costs its own trigger only. A replay's times are the input's (the clocks' offset from the
//! first pair: the board starts sampling with the replay, so that pair is unambiguous); a
//! live run's are this machine's, when the trigger's message and the frame arrived.
//!
//! Not yet in this mode: the cold start, the attach to a running core, and outages (a link
//! lost stops the run). `TrackerConfig` refuses the first two by name.

use std::collections::VecDeque;
use std::time::Instant;

use protocol::{ErrorCode, HostToCore, SampleSource, Sampling, SamplingEvent};

use super::{Event, Frame, Tracker};
use crate::error::TrackerError;
use crate::event::{Detail, LatencyNote};
use crate::settings::{Answers, ImuOnCore};
use crate::transport::CoreTransport;

/// A trigger the core fired, waiting for its frame.
#[derive(Debug, Clone, Copy)]
struct Fired {
    /// The core's count of the trigger.
    frame_id: u32,
    /// Its sample's time on the core's clock [µs].
    t_us: u64,
    /// The sample's index in the run.
    k: usize,
    /// When it arrived (live runs).
    arrived: Instant,
}

/// A frame waiting for its trigger.
#[derive(Debug)]
struct Waiting {
    frame: Frame,
    arrived: Instant,
}

/// The state of a run with the core's own IMU.
#[derive(Debug)]
pub(crate) struct OnCore {
    config: ImuOnCore,
    triggers: VecDeque<Fired>,
    frames: VecDeque<Waiting>,
    /// The input's clock less the core's [ns], from the first pair.
    offset_ns: Option<i64>,
    /// Samples' times [µs, core clock] taken before the offset was known.
    unclocked: Vec<u64>,
    /// The last sample's time [µs, core clock].
    last_us: Option<u64>,
}

impl OnCore {
    pub(crate) fn new(config: ImuOnCore) -> Self {
        OnCore {
            config,
            triggers: VecDeque::new(),
            frames: VecDeque::new(),
            offset_ns: None,
            unclocked: Vec::new(),
            last_us: None,
        }
    }
}

/// How a frame and a trigger relate.
enum Pairing {
    /// The frame is the trigger's.
    Pair,
    /// The trigger's frame never came (a later trigger is nearer to the frame).
    TriggerAlone,
    /// The frame came before the trigger by more than the bound: not one the core triggered.
    FrameRefused(String),
    /// The frame came after its trigger by more than the bound: both are dropped.
    Late(String),
    /// Not decided yet: the frame may still be the next trigger's.
    Wait,
}

impl<T: CoreTransport> Tracker<T> {
    fn on_core_mut(&mut self) -> Option<&mut OnCore> {
        self.inertial.as_mut().and_then(|i| i.on_core.as_mut())
    }

    /// Whether the core samples its own IMU in this run.
    pub fn imu_on_core(&self) -> bool {
        self.inertial.as_ref().is_some_and(|i| i.on_core.is_some())
    }

    /// Asks the core to sample its own IMU, fire the camera and stream its samples; a core
    /// with no IMU of its own is named.
    pub(crate) fn start_sampling(&mut self, config: ImuOnCore) -> Result<(), TrackerError> {
        let errors = self.session.errors.mark();
        self.core.send(&HostToCore::Sampling(Sampling {
            source: SampleSource::Core {
                trigger_every: config.trigger_every,
            },
            // The host counts the core's samples by them (the replay's latency is in
            // samples), and a calibration takes them as they are.
            raw_imu: true,
        }))?;
        self.barrier()?;
        if let Some(e) = self.session.errors.since(errors).next() {
            let why = match e.code {
                ErrorCode::NoOnboardImu => "it has no IMU of its own".to_string(),
                code => format!("{code}"),
            };
            return Err(TrackerError::Core(format!(
                "link {}: the core refused to sample its own IMU: {why}",
                self.core.name()
            )));
        }
        let started = self
            .session
            .last_sampling()
            .is_some_and(|r| r.event == SamplingEvent::Started);
        if !started {
            return Err(TrackerError::Core(format!(
                "link {}: the core did not confirm that it samples its own IMU",
                self.core.name()
            )));
        }
        Ok(())
    }

    /// With the core sampling its own IMU: a frame waits for its trigger.
    pub(crate) fn queue_on_core(&mut self, frame: Frame) -> Result<(), TrackerError> {
        let arrived = frame.captured.unwrap_or_else(Instant::now);
        let on_core = self.on_core_mut().ok_or_else(|| {
            TrackerError::Config("the core does not sample its own IMU in this run".into())
        })?;
        on_core.frames.push_back(Waiting { frame, arrived });
        Ok(())
    }

    /// Takes everything the core sent (its samples, triggers, predictions and reports),
    /// pairs the frames with their triggers and delivers the correspondences due. A run with
    /// the core sampling its own IMU calls it after each frame; a live program calls it
    /// between frames too (or [`Self::wait_until`]), so that the poses keep coming.
    pub fn pump(&mut self) -> Result<(), TrackerError> {
        if let Some(why) = &self.stopped {
            return Err(TrackerError::Stopped(why.clone()));
        }
        let step = self.pump_steps();
        if let Err(e) = &step {
            self.stopped = Some(e.to_string());
        }
        self.tell_poses();
        step
    }

    /// [`Self::pump`]'s steps, per sample in order.
    fn pump_steps(&mut self) -> Result<(), TrackerError> {
        if !self.imu_on_core() {
            return Err(TrackerError::Config(
                "the core does not sample its own IMU in this run: push the IMU's samples".into(),
            ));
        }
        self.session.drain(&mut self.core)?;
        let lock_step = self.config.answers == Answers::AtNextFrame;
        loop {
            if !self.imu_on_core() {
                return Ok(());
            }
            let Some(s) = self.session.next_raw_imu() else {
                break;
            };
            let Some(on_core) = self.on_core_mut() else {
                return Ok(());
            };
            on_core.last_us = Some(s.t_us);
            match on_core.offset_ns {
                Some(offset) => self.tell(Detail::Clock(input_ns(offset, s.t_us))),
                None => on_core.unclocked.push(s.t_us),
            }
            let inertial = self.imu_mut()?;
            let k = inertial.clock.count();
            inertial.last_sent_us = Some(s.t_us);
            self.latency(LatencyNote::SampleSent(s.t_us));
            self.take_triggers(k, s.t_us);
            // The core takes its next sample after this one: what is due by then goes now.
            self.deliver_due(k + 1, lock_step)?;
            self.pair_frames(lock_step)?;
            self.judge_inertial(s.t_us);
        }
        if !lock_step {
            let k = self.imu_mut()?.clock.next_index();
            self.deliver_due(k, false)?;
            self.pair_frames(false)?;
        }
        Ok(())
    }

    /// Step 2: the triggers the core fired up to the sample `k` at `t_us`.
    fn take_triggers(&mut self, k: usize, t_us: u64) {
        let Some(on_core) = self.inertial.as_mut().and_then(|i| i.on_core.as_mut()) else {
            return;
        };
        while let Some(t) = self.session.next_trigger_by(t_us) {
            on_core.triggers.push_back(Fired {
                frame_id: t.frame_id,
                t_us: t.t_us,
                k,
                arrived: Instant::now(),
            });
        }
    }

    /// Step 4: each waiting frame with its trigger, and each pair to the vision thread.
    /// Triggers no frame followed, and frames outside the bound, are reported.
    pub(crate) fn pair_frames(&mut self, lock_step: bool) -> Result<(), TrackerError> {
        loop {
            let Some(on_core) = self.on_core_mut() else {
                return Ok(());
            };
            let (Some(t), Some(f)) = (on_core.triggers.front(), on_core.frames.front()) else {
                break;
            };
            let next = on_core.triggers.get(1).copied();
            match judge_pair(on_core, t, f, next, lock_step) {
                Pairing::Wait => break,
                Pairing::TriggerAlone => {
                    let t = on_core.triggers.pop_front().expect("a trigger in front");
                    let why = format!(
                        "trigger {} at t = {:.3} s: no frame came within {:.0} ms (dropped by the camera?)",
                        t.frame_id,
                        t.t_us as f64 * 1e-6,
                        on_core.config.max_delay_s * 1e3
                    );
                    self.tell(Detail::FrameError(why));
                }
                Pairing::FrameRefused(why) => {
                    let w = on_core.frames.pop_front().expect("a frame in front");
                    self.refuse(w.frame.index, why);
                }
                Pairing::Late(why) => {
                    on_core.triggers.pop_front();
                    let w = on_core.frames.pop_front().expect("a frame in front");
                    self.refuse(w.frame.index, why);
                }
                Pairing::Pair => {
                    let t = on_core.triggers.pop_front().expect("a trigger in front");
                    let w = on_core.frames.pop_front().expect("a frame in front");
                    if on_core.offset_ns.is_none() {
                        let offset = w.frame.t_ns - t.t_us as i64 * 1000;
                        on_core.offset_ns = Some(offset);
                        let clock: Vec<u64> = on_core
                            .unclocked
                            .drain(..)
                            .map(|us| input_ns(offset, us))
                            .collect();
                        for t_ns in clock {
                            self.tell(Detail::Clock(t_ns));
                        }
                    }
                    let due = t.k + self.imu_mut()?.latency_samples.max(1);
                    self.frame_step(w.frame, t.t_us, due)?;
                }
            }
        }
        self.expire_frames(lock_step);
        Ok(())
    }

    /// Frames that waited longer than the bound with no trigger before them: refused.
    fn expire_frames(&mut self, lock_step: bool) {
        let Some(on_core) = self.on_core_mut() else {
            return;
        };
        if !on_core.triggers.is_empty() {
            return;
        }
        let bound = on_core.config.max_delay_s;
        let mut refused = Vec::new();
        while let Some(w) = on_core.frames.front() {
            let waited = match (lock_step, on_core.offset_ns, on_core.last_us) {
                (true, Some(offset), Some(last)) => {
                    (input_ns(offset, last) as i64 - w.frame.t_ns) as f64 * 1e-9
                }
                (true, _, _) => 0.0,
                (false, _, _) => w.arrived.elapsed().as_secs_f64(),
            };
            if waited <= bound {
                break;
            }
            let w = on_core.frames.pop_front().expect("a frame in front");
            refused.push((
                w.frame.index,
                format!(
                    "no trigger of the core came within {:.0} ms before it: not a frame the core triggered (a free-running camera?)",
                    bound * 1e3
                ),
            ));
        }
        for (index, why) in refused {
            self.refuse(index, why);
        }
    }

    /// A frame refused with its reason: recorded and told.
    fn refuse(&mut self, index: usize, why: String) {
        self.settle(index, crate::record::Fate::Unusable);
        self.tell(Detail::FrameError(format!("frame {index}: {why}: skipped")));
        self.emit(Event::FrameSkipped { index, why });
    }

    /// The end of a run with the core's own IMU: frames that never got a trigger are
    /// reported.
    pub(crate) fn finish_on_core(&mut self) {
        let left: Vec<usize> = match self.on_core_mut() {
            Some(o) => o.frames.drain(..).map(|w| w.frame.index).collect(),
            None => return,
        };
        for index in left {
            self.refuse(
                index,
                "no trigger of the core came for it before the end".into(),
            );
        }
    }
}

/// A core time [µs] on the input's clock [ns].
fn input_ns(offset_ns: i64, t_us: u64) -> u64 {
    u64::try_from(offset_ns + t_us as i64 * 1000).unwrap_or(0)
}

/// How the front frame `f` relates to the front trigger `t` (and the one after, `next`).
fn judge_pair(
    on_core: &OnCore,
    t: &Fired,
    f: &Waiting,
    next: Option<Fired>,
    lock_step: bool,
) -> Pairing {
    let bound = on_core.config.max_delay_s;
    // The frame's delay after a trigger [s]: on the input's clock in a replay, on arrival live.
    let delay = |t: &Fired| match (lock_step, on_core.offset_ns) {
        (true, Some(offset)) => (f.frame.t_ns - input_ns(offset, t.t_us) as i64) as f64 * 1e-9,
        // The first pair sets the clocks' offset.
        (true, None) => 0.0,
        (false, _) => {
            f.arrived.saturating_duration_since(t.arrived).as_secs_f64()
                - t.arrived.saturating_duration_since(f.arrived).as_secs_f64()
        }
    };
    let d = delay(t);
    if let Some(n) = next
        && delay(&n) >= -bound
    {
        // A later trigger came before the frame (or just after it): this one's frame never
        // came.
        if d > bound {
            return Pairing::TriggerAlone;
        }
    }
    if d < -bound {
        return Pairing::FrameRefused(format!(
            "came {:.1} ms before the core's next trigger ({}): not a frame the core triggered",
            -d * 1e3,
            t.frame_id
        ));
    }
    if d > bound {
        // Live, the next trigger may still be on its way while the frame is young.
        if next.is_none() && !lock_step && f.arrived.elapsed().as_secs_f64() <= bound {
            return Pairing::Wait;
        }
        return Pairing::Late(format!(
            "came {:.1} ms after its trigger ({} at t = {:.3} s), beyond the bound of {:.0} ms",
            d * 1e3,
            t.frame_id,
            t.t_us as f64 * 1e-6,
            bound * 1e3
        ));
    }
    Pairing::Pair
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run at 100 Hz with a trigger every 4th sample (25 Hz, 40 ms) and frames due within
    /// 20 ms, its clocks' offset known: the input's clock is the core's plus 1 s.
    fn run() -> OnCore {
        let mut o = OnCore::new(ImuOnCore::new(4, 100.0));
        o.offset_ns = Some(1_000_000_000);
        o
    }

    fn trigger(frame_id: u32, t_ms: u64) -> Fired {
        Fired {
            frame_id,
            t_us: t_ms * 1000,
            k: 0,
            arrived: Instant::now(),
        }
    }

    /// A frame stamped `t_ms` on the core's clock.
    fn frame(t_ms: i64) -> Waiting {
        Waiting {
            frame: Frame::decoded(
                0,
                1_000_000_000 + t_ms * 1_000_000,
                image::GrayImage::new(1, 1),
            ),
            arrived: Instant::now(),
        }
    }

    fn judged(t: Fired, f: Waiting, next: Option<Fired>) -> String {
        match judge_pair(&run(), &t, &f, next, true) {
            Pairing::Pair => "pair".into(),
            Pairing::TriggerAlone => "trigger alone".into(),
            Pairing::Wait => "wait".into(),
            Pairing::FrameRefused(why) | Pairing::Late(why) => why,
        }
    }

    #[test]
    fn a_frame_within_the_bound_of_its_trigger_pairs() {
        assert_eq!(ImuOnCore::new(4, 100.0).max_delay_s, 0.02);
        assert_eq!(judged(trigger(3, 120), frame(120), None), "pair");
        assert_eq!(judged(trigger(3, 120), frame(139), None), "pair");
    }

    #[test]
    fn a_frame_beyond_the_bound_is_refused_with_its_delay() {
        let why = judged(trigger(3, 120), frame(145), None);
        assert_eq!(
            why,
            "came 25.0 ms after its trigger (3 at t = 0.120 s), beyond the bound of 20 ms"
        );
        let why = judged(trigger(3, 120), frame(90), None);
        assert!(
            why.starts_with("came 30.0 ms before the core's next trigger (3)"),
            "{why}"
        );
    }

    #[test]
    fn a_trigger_whose_frame_was_dropped_gives_way_to_the_next() {
        // Trigger 3's frame never came: the frame is trigger 4's.
        assert_eq!(
            judged(trigger(3, 120), frame(161), Some(trigger(4, 160))),
            "trigger alone"
        );
        assert_eq!(judged(trigger(4, 160), frame(161), None), "pair");
    }

    #[test]
    fn live_a_young_frame_late_for_its_trigger_waits_for_the_next() {
        let o = run();
        let t = Fired {
            arrived: Instant::now() - std::time::Duration::from_millis(30),
            ..trigger(3, 120)
        };
        assert!(matches!(
            judge_pair(&o, &t, &frame(0), None, false),
            Pairing::Wait
        ));
        let old = Waiting {
            arrived: Instant::now() - std::time::Duration::from_millis(25),
            ..frame(0)
        };
        let t = Fired {
            arrived: Instant::now() - std::time::Duration::from_millis(60),
            ..trigger(3, 120)
        };
        assert!(matches!(
            judge_pair(&o, &t, &old, None, false),
            Pairing::Late(_)
        ));
    }
}
