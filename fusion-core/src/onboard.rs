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

/// The core's sampling state.
#[derive(Clone, Copy, Debug)]
pub struct Onboard {
    /// Whether the board has an IMU of its own (set by the board, never by the host).
    present: bool,
    sampling: Sampling,
    /// Triggers fired since sampling started.
    triggers: u32,
    report: SamplingReport,
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

    /// No IMU on board, the host sampling (`const`, for the device's `static`).
    pub const fn new() -> Self {
        Onboard {
            present: false,
            sampling: Self::HOST,
            triggers: 0,
            report: SamplingReport {
                t_us: 0,
                event: SamplingEvent::Stopped,
                samples: 0,
                lost: 0,
                part_resets: 0,
                late_reads: 0,
                drift_ppm: 0.0,
            },
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
        let t_us = self.report.t_us;
        let event = if self.core_samples() {
            self.triggers = 0;
            self.report = SamplingReport {
                t_us,
                event: SamplingEvent::Started,
                samples: 0,
                lost: 0,
                part_resets: 0,
                late_reads: 0,
                drift_ppm: self.report.drift_ppm,
            };
            self.last_report_us = None;
            SamplingEvent::Started
        } else {
            SamplingEvent::Stopped
        };
        Ok(SamplingReport {
            event,
            ..self.report
        })
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
                self.report.t_us = s.t_us;
                self.report.samples = self.report.samples.saturating_add(1);
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
                    o.report = Some(SamplingReport {
                        event: SamplingEvent::Periodic,
                        ..self.report
                    });
                }
            }
            OnboardEvent::Gap(g) => {
                // A reset is counted by `PartReset`; its gap says what it cost.
                self.report.lost = self.report.lost.saturating_add(g.lost);
                o.report = Some(SamplingReport {
                    event: SamplingEvent::Gap(g),
                    ..self.report
                });
            }
            OnboardEvent::PartReset => {
                self.report.part_resets = self.report.part_resets.saturating_add(1);
            }
            OnboardEvent::LateRead => {
                self.report.late_reads = self.report.late_reads.saturating_add(1);
            }
            OnboardEvent::Drift(ppm) => {
                if ppm.is_finite() {
                    self.report.drift_ppm = ppm;
                }
            }
        }
        o
    }

    /// The counters as they stand.
    pub fn report(&self) -> SamplingReport {
        self.report
    }
}

/// What one [`OnboardEvent`] makes the core send, in this order, before the filter's answers.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Outgoing {
    pub raw: Option<ImuSample>,
    pub trigger: Option<Trigger>,
    pub report: Option<SamplingReport>,
}
