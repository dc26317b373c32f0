//! The sample path: from the IMU's interrupt to [`fusion_core::Device::onboard`]. At each
//! interrupt it reads the FIFO, stamps the samples on the core's clock ([`crate::stamp`]),
//! scales them to SI units with the part's sensitivity, fires the camera trigger at the newest
//! sample when one is due ([`crate::trigger`]), and hands every sample, gap and fault to the
//! device unchanged. [`SamplePath::poll`], called from the main loop, re-checks the part's
//! configuration (PX4's way), reads the FIFO if the interrupts stopped, and starts again a
//! part that failed to start.

use embedded_hal::delay::DelayNs;
use embedded_hal::spi::SpiDevice;
use fusion_core::Kernels;
use fusion_core::device::{Device, Out};
use fusion_core::onboard::OnboardEvent;
use icm42688::{Check, FIFO_CAPACITY, Icm42688, Packet};
use protocol::{GapCause, ImuSample, SampleGap, SampleSource};

use crate::stamp::Stamper;
use crate::trigger::{TriggerOutput, TriggerPlan};

/// How many of the latest IMU interrupts' times [`Timing::interrupts`] gives.
pub const INTERRUPTS_KEPT: usize = 4;

/// The core's clock and the IMU interrupt's captured times, as the firmware's main loop holds
/// them: the interrupt handler notes the time of each interrupt, the path reads them after the
/// FIFO, so that an interrupt landing during the read is among them ([`crate::stamp`] decides
/// which sample each stamps).
pub trait Timing {
    /// The core's time now [µs].
    fn now_us(&mut self) -> u64;
    /// The core times [µs] of the latest IMU interrupts, oldest first, into `out` (at most
    /// [`INTERRUPTS_KEPT`]); how many were written.
    fn interrupts(&mut self, out: &mut [u64; INTERRUPTS_KEPT]) -> usize;
}

/// A read at `now_us` after the interrupts at `interrupts` (oldest first; the latest
/// [`INTERRUPTS_KEPT`] count). For simulations of the main loop's timing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Served<'a> {
    /// The core's time at the read [µs].
    pub now_us: u64,
    /// The interrupts' times [µs].
    pub interrupts: &'a [u64],
}

impl Timing for Served<'_> {
    fn now_us(&mut self) -> u64 {
        self.now_us
    }
    fn interrupts(&mut self, out: &mut [u64; INTERRUPTS_KEPT]) -> usize {
        let latest = self
            .interrupts
            .get(self.interrupts.len().saturating_sub(INTERRUPTS_KEPT)..)
            .unwrap_or_default();
        for (o, &t) in out.iter_mut().zip(latest) {
            *o = t;
        }
        latest.len()
    }
}

/// A moment at which an interrupt is served at once: now is the interrupt's time, the only one
/// known. For simulations that step the part and the loop together.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct At(pub u64);

impl Timing for At {
    fn now_us(&mut self) -> u64 {
        self.0
    }
    fn interrupts(&mut self, out: &mut [u64; INTERRUPTS_KEPT]) -> usize {
        out[0] = self.0;
        1
    }
}

/// How often the part's configuration is read back [µs] (PX4 checks a register per cycle;
/// 100 ms finds a reset part within ten samples at 100 Hz, for a few hundred SPI bytes).
pub const CHECK_EVERY_US: u64 = 100_000;

/// Interrupts missing for this many expected intervals make [`SamplePath::poll`] read the FIFO
/// itself (the interrupt line or its configuration was lost).
pub const MISSED_INTERRUPTS_BEFORE_POLLING: u64 = 3;

/// How often a part that failed to start is tried again [µs] (a board powered before its IMU,
/// a loose connector): the core serves without it meanwhile (`NoOnboardImu`).
pub const START_RETRY_US: u64 = 1_000_000;

/// Width of the camera trigger pulse [µs] (global-shutter cameras want a few µs to a few tens),
/// for the [`TriggerOutput`] implementations.
pub const TRIGGER_PULSE_US: u32 = 20;

/// A failure of the path's hardware.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PathError<S, P> {
    /// The IMU's driver failed (the SPI bus, or a wrong part).
    Imu(icm42688::Error<S>),
    /// The camera's trigger line could not be driven.
    Trigger(P),
}

impl<S: core::fmt::Debug, P: core::fmt::Debug> core::fmt::Display for PathError<S, P> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PathError::Imu(e) => write!(f, "IMU: {e}"),
            PathError::Trigger(e) => write!(f, "camera trigger line: {e:?}"),
        }
    }
}

impl<S: core::fmt::Debug, P: core::fmt::Debug> core::error::Error for PathError<S, P> {}

/// What one read did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReadSummary {
    /// Samples handed to the device.
    pub samples: usize,
    /// Samples lost before them.
    pub lost: u32,
    /// A trigger went with a sample of this read.
    pub triggered: bool,
}

/// The sample path of one IMU and one camera trigger line.
pub struct SamplePath<SPI, TRG> {
    imu: Icm42688<SPI>,
    trigger_output: TRG,
    stamper: Stamper,
    trigger: TriggerPlan,
    /// A fault seen that explains the next gap.
    cause: Option<GapCause>,
    /// Samples marked invalid since the last valid one handed on, and that one's time.
    invalid: (u32, u64),
    last_read_us: Option<u64>,
    last_check_us: u64,
    /// Whether the part was configured, and when that was last tried.
    started: bool,
    last_start_us: u64,
    packets: [Packet; FIFO_CAPACITY],
    stamps: [u16; FIFO_CAPACITY],
    times: [u64; FIFO_CAPACITY],
}

impl<SPI: SpiDevice, TRG: TriggerOutput> SamplePath<SPI, TRG> {
    /// A path over a driver (not yet initialised) and the camera's trigger line.
    pub fn new(imu: Icm42688<SPI>, trigger_output: TRG) -> Self {
        let settings = imu.settings();
        let stamper = Stamper::new(settings.period_us(), settings.stamp_tick());
        SamplePath {
            imu,
            trigger_output,
            stamper,
            trigger: TriggerPlan::default(),
            cause: None,
            invalid: (0, 0),
            last_read_us: None,
            last_check_us: 0,
            started: false,
            last_start_us: 0,
            packets: [Packet::default(); FIFO_CAPACITY],
            stamps: [0; FIFO_CAPACITY],
            times: [0; FIFO_CAPACITY],
        }
    }

    /// The driver (settings, and the SPI device in tests).
    pub fn imu(&self) -> &Icm42688<SPI> {
        &self.imu
    }

    /// The camera's trigger line.
    pub fn trigger_output(&self) -> &TRG {
        &self.trigger_output
    }

    /// The camera's trigger line, to drive it (a simulation tells it the time).
    pub fn trigger_output_mut(&mut self) -> &mut TRG {
        &mut self.trigger_output
    }

    /// The trigger plan (the pulse armed, if any).
    pub fn trigger_plan(&self) -> &TriggerPlan {
        &self.trigger
    }

    /// Configures the part; `now_us` starts the configuration checks' clock.
    pub fn start(
        &mut self,
        now_us: u64,
        delay: &mut impl DelayNs,
    ) -> Result<(), PathError<SPI::Error, TRG::Error>> {
        self.last_start_us = now_us;
        self.imu.init(delay).map_err(PathError::Imu)?;
        self.started = true;
        self.last_check_us = now_us;
        Ok(())
    }

    /// Whether the part is configured (by [`SamplePath::start`], or by [`SamplePath::poll`]
    /// trying again after a failed start).
    pub fn started(&self) -> bool {
        self.started
    }

    /// The IMU's interrupt was taken: reads the FIFO, stamps every sample (with the interrupts'
    /// times that `timing` holds after the read) and hands each on.
    pub fn on_interrupt<T: Kernels>(
        &mut self,
        timing: &mut impl Timing,
        device: &mut Device<T>,
        out: Out,
    ) -> Result<ReadSummary, PathError<SPI::Error, TRG::Error>> {
        if !self.started {
            return Ok(ReadSummary::default());
        }
        self.read(timing, true, device, out)
    }

    /// Reads the FIFO and hands its samples on; `interrupts`: whether the interrupts' times
    /// stamp them (else the time of the read does: polling).
    fn read<T: Kernels>(
        &mut self,
        timing: &mut impl Timing,
        interrupts: bool,
        device: &mut Device<T>,
        out: Out,
    ) -> Result<ReadSummary, PathError<SPI::Error, TRG::Error>> {
        let read = self
            .imu
            .read_fifo(&mut self.packets)
            .map_err(PathError::Imu)?;
        let read_us = timing.now_us();
        let mut irqs = [0u64; INTERRUPTS_KEPT];
        let k = if interrupts {
            timing.interrupts(&mut irqs).min(INTERRUPTS_KEPT)
        } else {
            0
        };
        self.last_read_us = Some(read_us);
        if read.overflowed {
            self.cause = Some(GapCause::FifoOverflow);
        }
        let n = read.packets.min(FIFO_CAPACITY);
        let mut summary = ReadSummary::default();
        if n > 0 {
            for (s, p) in self.stamps.iter_mut().zip(&self.packets[..n]) {
                *s = p.timestamp;
            }
            let stamped = self.stamper.stamp(
                &self.stamps[..n],
                &irqs[..k],
                read_us,
                read.overflowed,
                &mut self.times[..n],
            );
            if let Some(ppm) = stamped.drift_ppm {
                device.onboard(&OnboardEvent::Drift(ppm as f32), out);
            }
            if stamped.lost > 0 {
                let gap = SampleGap {
                    from_us: stamped.gap_from_us,
                    to_us: self.times[0],
                    lost: stamped.lost,
                    cause: self.cause.unwrap_or(GapCause::Unexplained),
                };
                device.onboard(&OnboardEvent::Gap(gap), out);
            }
            // A full FIFO stopped: what it dropped shows at the next read, and the cause with it.
            if stamped.lost > 0 || !read.overflowed {
                self.cause = None;
            }
            summary = self.hand_on(n, stamped.lost, read_us, device, out)?;
        }
        // A corrupt packet ended the read (the FIFO was flushed): the gap shows at the next.
        if read.corrupt {
            self.cause = Some(GapCause::CorruptPacket);
        }
        Ok(summary)
    }

    /// Scales and hands on the `n` packets read and stamped (`lost` before them), the ones
    /// the part marked invalid as gaps, the trigger with the sample it went with
    /// ([`crate::trigger`]); then arms the next pulse if it is due before the next read.
    fn hand_on<T: Kernels>(
        &mut self,
        n: usize,
        lost: u32,
        read_us: u64,
        device: &mut Device<T>,
        out: Out,
    ) -> Result<ReadSummary, PathError<SPI::Error, TRG::Error>> {
        let watermark = usize::from(self.imu.settings().watermark.max(1));
        if n > watermark {
            device.onboard(&OnboardEvent::LateRead, out);
        }
        let every = trigger_every(device);
        let period = self.stamper.period_us();
        let packets = &self.packets[..n];
        let paired = self
            .trigger
            .take(
                every,
                &self.times[..n],
                |i| packets[i].has_valid_data(),
                period,
                &mut self.trigger_output,
            )
            .map_err(PathError::Trigger)?;
        let settings = *self.imu.settings();
        let mut samples = 0;
        for i in 0..n {
            let (p, t_us) = (&self.packets[i], self.times[i]);
            if !p.has_valid_data() {
                if self.invalid.0 == 0 && i > 0 {
                    self.invalid.1 = self.times[i - 1];
                }
                self.invalid.0 = self.invalid.0.saturating_add(1);
                continue;
            }
            if self.invalid.0 > 0 {
                let gap = SampleGap {
                    from_us: self.invalid.1,
                    to_us: t_us,
                    lost: self.invalid.0,
                    cause: GapCause::InvalidSample,
                };
                device.onboard(&OnboardEvent::Gap(gap), out);
                self.invalid.0 = 0;
            }
            let sample = ImuSample {
                t_us,
                gyro: p.gyro_rad_s(&settings),
                accel: p.accel_m_s2(&settings),
                trigger: paired.index == Some(i),
            };
            device.onboard(&OnboardEvent::Sample(sample), out);
            self.invalid.1 = t_us;
            samples += 1;
        }
        self.trigger
            .plan(
                self.times[n - 1],
                read_us,
                period,
                u32::from(settings.watermark.max(1)),
                &mut self.trigger_output,
            )
            .map_err(PathError::Trigger)?;
        Ok(ReadSummary {
            samples,
            lost,
            triggered: paired.index.is_some(),
        })
    }

    /// The main loop's turn: every [`CHECK_EVERY_US`] the part's configuration is read back
    /// and repaired if it was lost (a brown-out or glitch reset the part; its samples restart,
    /// and the gap is reported as `PartReset`); and if no interrupt came for
    /// [`MISSED_INTERRUPTS_BEFORE_POLLING`] intervals, the FIFO is read here, its newest sample
    /// stamped with the time of the read.
    pub fn poll<T: Kernels>(
        &mut self,
        timing: &mut impl Timing,
        device: &mut Device<T>,
        delay: &mut impl DelayNs,
        out: Out,
    ) -> Result<Option<ReadSummary>, PathError<SPI::Error, TRG::Error>> {
        let now_us = timing.now_us();
        if !self.started {
            // A part that failed to start is tried again every second; once it answers, the
            // core has its IMU (issue 55: it answered NoOnboardImu for good).
            if now_us.saturating_sub(self.last_start_us) >= START_RETRY_US {
                self.start(now_us, delay)?;
                self.stamper.part_restarted();
                device.set_onboard_imu(true);
            }
            return Ok(None);
        }
        if now_us.saturating_sub(self.last_check_us) >= CHECK_EVERY_US {
            self.last_check_us = now_us;
            if let Check::Repaired { .. } = self.imu.check(delay).map_err(PathError::Imu)? {
                self.stamper.part_restarted();
                self.cause = Some(GapCause::PartReset);
                device.onboard(&OnboardEvent::PartReset, out);
            }
        }
        let settings = self.imu.settings();
        let interval = u64::from(settings.period_us()) * u64::from(settings.watermark.max(1));
        let silent = self.last_read_us.is_some_and(|t| {
            now_us.saturating_sub(t) >= MISSED_INTERRUPTS_BEFORE_POLLING * interval
        });
        if silent {
            return self.read(timing, false, device, out).map(Some);
        }
        // A trigger due before the next read (the first after the host's choice) is armed now,
        // from the last sample stamped, while it is recent enough to predict from.
        self.trigger.choose(trigger_every(device));
        let period = self.stamper.period_us();
        let batch = settings.watermark.max(1);
        if let Some(last) = self.stamper.last_us()
            && now_us.saturating_sub(last) < 4 * period * u64::from(batch)
        {
            self.trigger
                .plan(
                    last,
                    now_us,
                    period,
                    u32::from(batch),
                    &mut self.trigger_output,
                )
                .map_err(PathError::Trigger)?;
        }
        Ok(None)
    }
}

/// The host's choice of triggers: every how many samples (0: none, or the host samples).
fn trigger_every<T: Kernels>(device: &Device<T>) -> u16 {
    match device.onboard_state().sampling().source {
        SampleSource::Core { trigger_every } => trigger_every,
        SampleSource::Host => 0,
    }
}
