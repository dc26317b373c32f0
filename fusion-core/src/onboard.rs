//! The core's own IMU (protocol 3.1, protocol/PROTOCOL.md §7): who samples, the triggers'
//! frame ids, and the sampling counters the core reports. The board's sample path reads the
//! part and hands each sample and each fault to [`crate::Device::onboard`]; this module keeps
//! what the core says about them, and the device loop runs the filter on the samples exactly
//! as on samples from the host.

use protocol::{
    ImuSample, SampleGap, SampleSource, Sampling, SamplingEvent, SamplingReport, Trigger,
};

/// Time between two periodic [`SamplingReport`]s [µs].
pub const REPORT_EVERY_US: u64 = 1_000_000;

/// What the board's sample path tells the core.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OnboardEvent {
    /// A sample, time-stamped on the core's clock and scaled to SI units; `trigger` when the
    /// camera was fired at it.
    Sample(ImuSample),
    /// Samples were lost between two samples (from the IMU's own time stamps).
    Gap(SampleGap),
    /// The IMU was found reset and was configured again.
    PartReset,
    /// A read found more samples than one interrupt brings.
    LateRead,
    /// The IMU's clock against the core's [ppm], as now measured.
    Drift(f32),
}

/// The counters of a [`SamplingReport`], kept without its event: an enum whose data-less
/// variants sit in a niche of another's field is not all zero bytes in any of them, and the
/// device must be (see [`Onboard::new`]).
#[derive(Clone, Copy, Debug, Default)]
struct Counts {
    t_us: u64,
    samples: u32,
    lost: u32,
    part_resets: u32,
    late_reads: u32,
    drift_ppm: f32,
}

impl Counts {
    const ZERO: Counts = Counts {
        t_us: 0,
        samples: 0,
        lost: 0,
        part_resets: 0,
        late_reads: 0,
        drift_ppm: 0.0,
    };

    fn report(&self, event: SamplingEvent) -> SamplingReport {
        SamplingReport {
            t_us: self.t_us,
            event,
            samples: self.samples,
            lost: self.lost,
            part_resets: self.part_resets,
            late_reads: self.late_reads,
            drift_ppm: self.drift_ppm,
        }
    }
}

/// The core's sampling state.
#[derive(Clone, Copy, Debug)]
pub struct Onboard {
    /// Whether the board has an IMU of its own (set by the board, never by the host).
    present: bool,
    sampling: Sampling,
    /// Triggers fired since sampling started.
    triggers: u32,
    counts: Counts,
    last_report_us: Option<u64>,
}

impl Default for Onboard {
    fn default() -> Self {
        Self::new()
    }
}

impl Onboard {
    const HOST: Sampling = Sampling {
        source: SampleSource::Host,
        raw_imu: false,
    };

    /// No IMU on board, the host sampling (`const`, for the device's `static`). All zero
    /// bytes, as the device is, so that a firmware `static` holding it stays in `.bss` (a
    /// stored `SamplingReport` moved the whole device, 18 KB, into `.data` and flash).
    pub const fn new() -> Self {
        Onboard {
            present: false,
            sampling: Self::HOST,
            triggers: 0,
            counts: Counts::ZERO,
            last_report_us: None,
        }
    }

    /// Declares whether the board has an IMU of its own.
    pub fn set_present(&mut self, present: bool) {
        self.present = present;
        if !present {
            self.sampling = Self::HOST;
        }
    }

    /// Whether the board has an IMU of its own.
    pub fn present(&self) -> bool {
        self.present
    }

    /// Who samples, as the host last chose.
    pub fn sampling(&self) -> Sampling {
        self.sampling
    }

    /// Whether the core samples its own IMU.
    pub fn core_samples(&self) -> bool {
        matches!(self.sampling.source, SampleSource::Core { .. })
    }

    /// The host's choice; `Err(())` when it asks for the core's IMU and there is none. The
    /// answer to send: a report that sampling started (counters from zero) or stopped.
    pub(crate) fn choose(&mut self, s: Sampling) -> Result<SamplingReport, ()> {
        if matches!(s.source, SampleSource::Core { .. }) && !self.present {
            return Err(());
        }
        self.sampling = s;
        let event = if self.core_samples() {
            self.triggers = 0;
            self.counts = Counts {
                t_us: self.counts.t_us,
                drift_ppm: self.counts.drift_ppm,
                ..Counts::ZERO
            };
            self.last_report_us = None;
            SamplingEvent::Started
        } else {
            SamplingEvent::Stopped
        };
        Ok(self.counts.report(event))
    }

    /// Takes one event from the sample path. Returns what the core sends for it besides the
    /// filter's own answers: the raw sample, the trigger, a report. `None`s when the host
    /// samples (the board's samples are not used then).
    pub(crate) fn take(&mut self, event: &OnboardEvent) -> Outgoing {
        let mut o = Outgoing::default();
        if !self.core_samples() {
            return o;
        }
        match *event {
            OnboardEvent::Sample(s) => {
                self.counts.t_us = s.t_us;
                self.counts.samples = self.counts.samples.saturating_add(1);
                if self.sampling.raw_imu {
                    o.raw = Some(s);
                }
                if s.trigger {
                    o.trigger = Some(Trigger {
                        frame_id: self.triggers,
                        t_us: s.t_us,
                    });
                    self.triggers = self.triggers.wrapping_add(1);
                }
                let due = self
                    .last_report_us
                    .is_none_or(|t| s.t_us < t || s.t_us - t >= REPORT_EVERY_US);
                if due {
                    self.last_report_us = Some(s.t_us);
                    o.report = Some(self.counts.report(SamplingEvent::Periodic));
                }
            }
            OnboardEvent::Gap(g) => {
                // A reset is counted by `PartReset`; its gap says what it cost.
                self.counts.lost = self.counts.lost.saturating_add(g.lost);
                o.report = Some(self.counts.report(SamplingEvent::Gap(g)));
            }
            OnboardEvent::PartReset => {
                self.counts.part_resets = self.counts.part_resets.saturating_add(1);
            }
            OnboardEvent::LateRead => {
                self.counts.late_reads = self.counts.late_reads.saturating_add(1);
            }
            OnboardEvent::Drift(ppm) => {
                if ppm.is_finite() {
                    self.counts.drift_ppm = ppm;
                }
            }
        }
        o
    }

    /// The counters as they stand (as a periodic report would send them).
    pub fn report(&self) -> SamplingReport {
        self.counts.report(SamplingEvent::Periodic)
    }
}

/// What one [`OnboardEvent`] makes the core send, in this order, before the filter's answers.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Outgoing {
    pub raw: Option<ImuSample>,
    pub trigger: Option<Trigger>,
    pub report: Option<SamplingReport>,
}
