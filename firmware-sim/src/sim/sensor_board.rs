//! A sensor board on the PC: the scenario's IMU readings fed, at the part's own clock, into the
//! simulated ICM-42688-P ([`icm42688::SimIcm42688`]), whose interrupts run the board's sample
//! path ([`sample_path::SamplePath`]) into the fusion core, in core-sampled mode
//! (protocol/PROTOCOL.md §7). Faults are injected on the way: FIFO overflow (the MCU busy),
//! a corrupt packet, missed interrupts, the part's reset, clock drift between IMU and MCU.

use core::cell::RefCell;
use core::convert::Infallible;
use std::sync::{Arc, Mutex};

use embedded_hal::spi::{Operation, SpiDevice};
use fusion_core::{Device, Kernels};
use icm42688::sim::SharedSim;
use icm42688::{Icm42688, Odr, Settings, SimIcm42688};
use protocol::CoreToHost;
use sample_path::{At, SamplePath};

use super::scenario::ImuSample as Reading;

/// Faults to inject, by sample index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Faults {
    /// The IMU's clock against the MCU's [ppm] (positive: the IMU runs fast).
    pub drift_ppm: f64,
    /// Interrupt latency [µs]: the MCU takes the interrupt this long after the sample.
    pub irq_latency_us: u64,
    /// The MCU serves nothing (no interrupt, no main loop) from the first sample to the
    /// second (exclusive): more than the FIFO holds overflows it.
    pub busy: Option<(usize, usize)>,
    /// The packet of this sample gets a corrupt header.
    pub corrupt_at: Option<usize>,
    /// The interrupts of these samples are missed.
    pub missed_interrupts: Vec<usize>,
    /// The part resets (brown-out) just before this sample.
    pub reset_at: Option<usize>,
}

/// What a run produced.
#[derive(Debug, Default)]
pub struct BoardRun {
    /// Everything the core sent, in order.
    pub sent: Vec<CoreToHost>,
    /// The MCU time [µs] at which each reading was sampled (the truth of its time stamp).
    pub sampled_at_us: Vec<u64>,
    /// Packets the simulated part dropped on overflow.
    pub dropped_on_overflow: u64,
    /// Pulses on the camera's trigger line.
    pub trigger_pulses: u32,
}

/// A no-op delay: the simulated part needs no waiting.
pub struct NoDelay;

impl embedded_hal::delay::DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}

/// The camera's trigger line: counts pulses.
#[derive(Default)]
pub struct TriggerLine {
    /// Rising edges seen.
    pub pulses: u32,
    high: bool,
}

impl embedded_hal::digital::ErrorType for TriggerLine {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for TriggerLine {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.high = false;
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Infallible> {
        if !self.high {
            self.pulses += 1;
        }
        self.high = true;
        Ok(())
    }
}

/// The part's output data rate for a scenario's IMU rate, if it has one.
pub fn odr_for(rate_hz: f64) -> Option<Odr> {
    Odr::ALL
        .into_iter()
        .find(|o| (f64::from(o.hz()) - rate_hz).abs() < 1e-6)
}

/// Runs `readings` (a scenario's, at the part's output data rate) through the simulated part
/// and the sample path into `device`, which the caller has greeted, configured and set to
/// sample its own IMU (or not). `before_sample(k, device, out)` lets the caller act between
/// samples (initialise, answer frames).
pub fn run(
    readings: &[Reading],
    settings: Settings,
    faults: &Faults,
    device: &mut Device<f32>,
    mut before_sample: impl FnMut(usize, &mut Device<f32>, &mut Vec<CoreToHost>),
) -> Result<BoardRun, String> {
    let part = RefCell::new(SimIcm42688::new());
    let imu = Icm42688::new(SharedSim::new(&part), settings);
    let mut path = SamplePath::new(imu, TriggerLine::default());
    let mut delay = NoDelay;
    let mut run = BoardRun::default();
    let period_part_us = u64::from(settings.period_us());
    // The MCU's clock starts a second before the first sample (the board booted).
    let t0_us = 1_000_000u64;
    let mcu_us = |k: usize| {
        let part_us = k as f64 * period_part_us as f64;
        t0_us + (part_us * 1e6 / (1e6 + faults.drift_ppm)).round() as u64
    };
    path.start(0, &mut delay).map_err(|e| e.to_string())?;
    for (k, r) in readings.iter().enumerate() {
        let mut sent = Vec::new();
        before_sample(k, device, &mut sent);
        let t = mcu_us(k);
        if faults.reset_at == Some(k) {
            part.borrow_mut().power_on_reset();
        }
        if faults.corrupt_at == Some(k) {
            part.borrow_mut().corrupt_next_header();
        }
        let f = |v: nalgebra::Vector3<f64>| [v[0], v[1], v[2]];
        // The part's time stamp counter: its own µs since the first sample, plus an offset.
        let part_us = 5_000 + k as u64 * period_part_us;
        part.borrow_mut()
            .sample(part_us, f(r.reading.gyro), f(r.reading.accel), 25.0);
        run.sampled_at_us.push(t);
        let busy = faults.busy.is_some_and(|(a, b)| (a..b).contains(&k));
        if busy {
            run.sent.append(&mut sent);
            continue;
        }
        let irq = !faults.missed_interrupts.contains(&k) && part.borrow().interrupt_pending();
        let mut out = |m| sent.push(m);
        if irq {
            path.on_interrupt(
                &mut At(t + faults.irq_latency_us),
                device,
                &mut delay,
                &mut out,
            )
            .map_err(|e| e.to_string())?;
        }
        path.poll(
            &mut At(t + faults.irq_latency_us + 1),
            device,
            &mut delay,
            &mut out,
        )
        .map_err(|e| e.to_string())?;
        run.sent.append(&mut sent);
    }
    run.dropped_on_overflow = part.borrow().dropped_on_overflow();
    run.trigger_pulses = path.trigger_pin().pulses;
    Ok(run)
}

/// The simulated part, shared between the board's driver (through the SPI bus) and the
/// simulation that feeds it readings; `Send`, so a board that holds one can run on a thread.
#[derive(Clone, Default)]
pub struct SharedPart(pub Arc<Mutex<SimIcm42688>>);

impl SharedPart {
    /// The part, for the simulation's side (readings, faults).
    pub fn part(&self) -> std::sync::MutexGuard<'_, SimIcm42688> {
        // A panic elsewhere while the part was held leaves its registers as they were.
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl embedded_hal::spi::ErrorType for SharedPart {
    type Error = Infallible;
}

impl SpiDevice for SharedPart {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), Infallible> {
        self.part().transaction(ops)
    }
}

/// A board's own simulated IMU: the part and the sample path that reads it into the core, for
/// a host that replays recorded readings through the sensor board's path (`track
/// --imu-on-core`). The MCU's clock is the readings' (no drift), and each interrupt is served
/// at once; the faults are [`run`]'s.
pub struct SimulatedImu {
    part: SharedPart,
    path: SamplePath<SharedPart, TriggerLine>,
    /// The offset of the part's time stamp counter from the MCU's clock [µs].
    part_offset_us: u64,
}

impl SimulatedImu {
    /// A part at `settings`, configured by the board's driver at MCU time `now_us`.
    pub fn start(settings: Settings, now_us: u64) -> Result<Self, String> {
        let part = SharedPart::default();
        let mut path = SamplePath::new(
            Icm42688::new(part.clone(), settings),
            TriggerLine::default(),
        );
        path.start(now_us, &mut NoDelay)
            .map_err(|e| e.to_string())?;
        Ok(SimulatedImu {
            part,
            path,
            part_offset_us: 5_000,
        })
    }

    /// The part's settings.
    pub fn settings(&self) -> &Settings {
        self.path.imu().settings()
    }

    /// One reading taken by the part at MCU time `t_us`, and the board's turn: the interrupt
    /// (if the part raised one) and the main loop, into `device`, whose messages go to `out`.
    /// Returns whether the camera's trigger line pulsed.
    pub fn sample<T: Kernels>(
        &mut self,
        t_us: u64,
        gyro: [f64; 3],
        accel: [f64; 3],
        device: &mut Device<T>,
        out: &mut dyn FnMut(CoreToHost),
    ) -> Result<bool, String> {
        self.part
            .part()
            .sample(t_us + self.part_offset_us, gyro, accel, 25.0);
        let pulses = self.path.trigger_pin().pulses;
        let pending = self.part.part().interrupt_pending();
        if pending {
            self.path
                .on_interrupt(&mut At(t_us), device, &mut NoDelay, out)
                .map_err(|e| e.to_string())?;
        }
        self.path
            .poll(&mut At(t_us), device, &mut NoDelay, out)
            .map_err(|e| e.to_string())?;
        Ok(self.path.trigger_pin().pulses != pulses)
    }
}
