//! The sample path: from the IMU's interrupt to [`fusion_core::Device::onboard`]. At each
//! interrupt it reads the FIFO, stamps the samples on the core's clock ([`crate::stamp`]),
//! scales them to SI units with the part's sensitivity, fires the camera trigger at the newest
//! sample when one is due ([`crate::trigger`]), and hands every sample, gap and fault to the
//! device unchanged. [`SamplePath::poll`], called from the main loop, re-checks the part's
//! configuration (PX4's way) and reads the FIFO if the interrupts stopped.

use embedded_hal::delay::DelayNs;
use embedded_hal::digital::OutputPin;
use embedded_hal::spi::SpiDevice;
use fusion_core::Kernels;
use fusion_core::device::{Device, Out};
use fusion_core::onboard::OnboardEvent;
use icm42688::{Check, FIFO_CAPACITY, Icm42688, Packet};
use protocol::{GapCause, ImuSample, SampleGap, SampleSource};

use crate::stamp::Stamper;
use crate::trigger::TriggerCount;

/// How often the part's configuration is read back [µs] (PX4 checks a register per cycle;
/// 100 ms finds a reset part within ten samples at 100 Hz, for a few hundred SPI bytes).
pub const CHECK_EVERY_US: u64 = 100_000;

/// Interrupts missing for this many expected intervals make [`SamplePath::poll`] read the FIFO
/// itself (the interrupt line or its configuration was lost).
pub const MISSED_INTERRUPTS_BEFORE_POLLING: u64 = 3;

/// Width of the camera trigger pulse [µs] (global-shutter cameras want a few µs to a few tens).
pub const TRIGGER_PULSE_US: u32 = 20;

/// A failure of the path's hardware.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PathError<S, P> {
    /// The IMU's driver failed (the SPI bus, or a wrong part).
    Imu(icm42688::Error<S>),
    /// The trigger pin could not be driven.
    TriggerPin(P),
}

impl<S: core::fmt::Debug, P: core::fmt::Debug> core::fmt::Display for PathError<S, P> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PathError::Imu(e) => write!(f, "IMU: {e}"),
            PathError::TriggerPin(e) => write!(f, "camera trigger pin: {e:?}"),
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
    /// The camera was triggered at the newest sample.
    pub triggered: bool,
}

/// The sample path of one IMU and one camera trigger line.
pub struct SamplePath<SPI, PIN> {
    imu: Icm42688<SPI>,
    trigger_pin: PIN,
    stamper: Stamper,
    trigger: TriggerCount,
    /// A fault seen that explains the next gap.
    cause: Option<GapCause>,
    last_read_us: Option<u64>,
    last_check_us: u64,
    packets: [Packet; FIFO_CAPACITY],
    stamps: [u16; FIFO_CAPACITY],
    times: [u64; FIFO_CAPACITY],
}

impl<SPI: SpiDevice, PIN: OutputPin> SamplePath<SPI, PIN> {
    /// A path over a driver (not yet initialised) and the camera's trigger line.
    pub fn new(imu: Icm42688<SPI>, trigger_pin: PIN) -> Self {
        let period = imu.settings().period_us();
        SamplePath {
            imu,
            trigger_pin,
            stamper: Stamper::new(period),
            trigger: TriggerCount::default(),
            cause: None,
            last_read_us: None,
            last_check_us: 0,
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
    pub fn trigger_pin(&self) -> &PIN {
        &self.trigger_pin
    }

    /// Configures the part; `now_us` starts the configuration checks' clock.
    pub fn start(
        &mut self,
        now_us: u64,
        delay: &mut impl DelayNs,
    ) -> Result<(), PathError<SPI::Error, PIN::Error>> {
        self.trigger_pin.set_low().map_err(PathError::TriggerPin)?;
        self.imu.init(delay).map_err(PathError::Imu)?;
        self.last_check_us = now_us;
        Ok(())
    }

    /// The IMU's interrupt, at core time `t_irq_us`: reads, stamps and hands on every sample.
    pub fn on_interrupt<T: Kernels>(
        &mut self,
        t_irq_us: u64,
        device: &mut Device<T>,
        delay: &mut impl DelayNs,
        out: Out,
    ) -> Result<ReadSummary, PathError<SPI::Error, PIN::Error>> {
        let read = self
            .imu
            .read_fifo(&mut self.packets)
            .map_err(PathError::Imu)?;
        self.last_read_us = Some(t_irq_us);
        if read.overflowed {
            self.cause = Some(GapCause::FifoOverflow);
        }
        let n = read.packets.min(FIFO_CAPACITY);
        let mut summary = ReadSummary::default();
        if n > 0 {
            summary = self.hand_on(n, t_irq_us, device, delay, out)?;
        }
        // A corrupt packet ended the read (the FIFO was flushed): the gap shows at the next.
        if read.corrupt {
            self.cause = Some(GapCause::CorruptPacket);
        }
        Ok(summary)
    }

    /// Stamps, scales and hands on the `n` packets read.
    fn hand_on<T: Kernels>(
        &mut self,
        n: usize,
        t_irq_us: u64,
        device: &mut Device<T>,
        delay: &mut impl DelayNs,
        out: Out,
    ) -> Result<ReadSummary, PathError<SPI::Error, PIN::Error>> {
        for (s, p) in self.stamps.iter_mut().zip(&self.packets[..n]) {
            *s = p.timestamp;
        }
        let stamped = self
            .stamper
            .stamp(&self.stamps[..n], t_irq_us, &mut self.times[..n]);
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
        self.cause = None;
        let watermark = usize::from(self.imu.settings().watermark.max(1));
        if n > watermark {
            device.onboard(&OnboardEvent::LateRead, out);
        }
        let every = match device.onboard_state().sampling().source {
            SampleSource::Core { trigger_every } => trigger_every,
            SampleSource::Host => 0,
        };
        let triggered = self.trigger.due(every, n as u32);
        if triggered {
            // Fired now, at the newest sample's interrupt: the camera exposes at its time.
            self.trigger_pin.set_high().map_err(PathError::TriggerPin)?;
            delay.delay_us(TRIGGER_PULSE_US);
            self.trigger_pin.set_low().map_err(PathError::TriggerPin)?;
        }
        let settings = *self.imu.settings();
        for i in 0..n {
            let p = &self.packets[i];
            let sample = ImuSample {
                t_us: self.times[i],
                gyro: p.gyro_rad_s(&settings),
                accel: p.accel_m_s2(&settings),
                trigger: triggered && i + 1 == n,
            };
            device.onboard(&OnboardEvent::Sample(sample), out);
        }
        Ok(ReadSummary {
            samples: n,
            lost: stamped.lost,
            triggered,
        })
    }

    /// The main loop's turn, at core time `now_us`: every [`CHECK_EVERY_US`] the part's
    /// configuration is read back and repaired if it was lost (a brown-out or glitch reset
    /// the part; its samples restart, and the gap is reported as `PartReset`); and if no
    /// interrupt came for [`MISSED_INTERRUPTS_BEFORE_POLLING`] intervals, the FIFO is read here.
    pub fn poll<T: Kernels>(
        &mut self,
        now_us: u64,
        device: &mut Device<T>,
        delay: &mut impl DelayNs,
        out: Out,
    ) -> Result<Option<ReadSummary>, PathError<SPI::Error, PIN::Error>> {
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
            return self.on_interrupt(now_us, device, delay, out).map(Some);
        }
        Ok(None)
    }
}
