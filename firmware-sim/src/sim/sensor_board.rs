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
use sample_path::{At, SamplePath, Served, TriggerOutput};

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
/// The main loop's timing, for [`run_loop`]: each turn of the loop (serve USB, answer frames,
/// read the FIFO if an interrupt came) takes `short_us`, or with probability `long_share`
/// a duration up to `long_max_us` drawn uniformly (a frame's correspondences, USB bursts);
/// an interrupt is taken 0 to `irq_jitter_us` after its sample; the IMU's clock runs
/// `drift_ppm` off the MCU's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopModel {
    /// Seed of the durations.
    pub seed: u64,
    /// A short turn [µs].
    pub short_us: u64,
    /// Share of long turns.
    pub long_share: f64,
    /// The longest turn [µs].
    pub long_max_us: u64,
    /// The interrupt's latency after its sample, at most [µs].
    pub irq_jitter_us: u64,
    /// The IMU's clock against the MCU's [ppm] (positive: fast).
    pub drift_ppm: f64,
}

/// What [`run_loop`] produced.
#[derive(Debug, Default)]
pub struct LoopRun {
    /// Everything the core sent, in order.
    pub sent: Vec<CoreToHost>,
    /// The MCU time [µs] of each reading (the truth of its time stamp).
    pub sampled_at_us: Vec<u64>,
    /// Every rising edge of the trigger line: its time [µs], and whether the loop fired it at
    /// once (else the timer, armed ahead).
    pub rises: Vec<(u64, bool)>,
    /// Each FIFO read: the loop's time, and the true time of the newest sample it held (a
    /// pulse fired at the read, as before issue 55, would have been that late).
    pub reads: Vec<(u64, u64)>,
}

/// A no-op delay: the simulated part needs no waiting.
pub struct NoDelay;

impl embedded_hal::delay::DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}

/// The camera's trigger line as the board drives it (`sample_path::TriggerOutput`): a pulse
/// armed on the timer rises at its time, one fired by the loop at the loop's time. The
/// simulation tells the line the time ([`TriggerLine::set_now`], [`TriggerLine::advance`]).
#[derive(Clone, Debug, Default)]
pub struct TriggerLine {
    /// Every rising edge: its core time [µs], and whether the loop fired it at once (else the
    /// timer did, at the time armed).
    pub rises: Vec<(u64, bool)>,
    armed: Option<u64>,
    now_us: u64,
}

impl TriggerLine {
    /// The loop's time now [µs] (when a pulse fired at once rises).
    pub fn set_now(&mut self, now_us: u64) {
        self.now_us = now_us;
    }

    /// Time runs to `t_us`: an armed pulse whose time has come rises (at its time). Whether
    /// one did.
    pub fn advance(&mut self, t_us: u64) -> bool {
        match self.armed {
            Some(at) if at <= t_us => {
                self.rises.push((at, false));
                self.armed = None;
                true
            }
            _ => false,
        }
    }

    /// Pulses so far.
    pub fn pulses(&self) -> u32 {
        u32::try_from(self.rises.len()).unwrap_or(u32::MAX)
    }
}

impl TriggerOutput for TriggerLine {
    type Error = Infallible;
    fn arm(&mut self, at_us: u64) -> Result<(), Infallible> {
        self.armed = Some(at_us);
        Ok(())
    }
    fn fire_now(&mut self) -> Result<(), Infallible> {
        self.rises.push((self.now_us, true));
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
        let line = path.trigger_output_mut();
        line.set_now(t + faults.irq_latency_us);
        line.advance(t + period_part_us / 2);
        if irq {
            path.on_interrupt(&mut At(t + faults.irq_latency_us), device, &mut out)
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
    run.trigger_pulses = path.trigger_output().pulses();
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
        let pulses = self.path.trigger_output().pulses();
        let half_period = u64::from(self.settings().period_us()) / 2;
        let line = self.path.trigger_output_mut();
        line.set_now(t_us);
        // The pulse armed for this sample rises with it (the timer fires within microseconds
        // of the sample, on either side).
        line.advance(t_us + half_period);
        let pending = self.part.part().interrupt_pending();
        if pending {
            self.path
                .on_interrupt(&mut At(t_us), device, out)
                .map_err(|e| e.to_string())?;
        }
        self.path
            .poll(&mut At(t_us), device, &mut NoDelay, out)
            .map_err(|e| e.to_string())?;
        Ok(self.path.trigger_output().pulses() != pulses)
    }
}

/// Runs `readings` through the part and the sample path as the board's main loop would,
/// event by event: samples arrive at their times and interrupt (latency per `model`), the loop
/// turns at the durations `model` draws and reads the FIFO when an interrupt came, and the
/// trigger line's timer fires armed pulses at their times. The device is set up as for [`run`].
pub fn run_loop(
    readings: &[Reading],
    settings: Settings,
    model: &LoopModel,
    device: &mut Device<f32>,
) -> Result<LoopRun, String> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(model.seed);
    let part = RefCell::new(SimIcm42688::new());
    let mut path = SamplePath::new(
        Icm42688::new(SharedSim::new(&part), settings),
        TriggerLine::default(),
    );
    let period = u64::from(settings.period_us());
    let t0 = 1_000_000u64;
    path.start(0, &mut NoDelay).map_err(|e| e.to_string())?;
    // The part samples every `period` of its own clock, `drift_ppm` fast.
    let mut run = LoopRun {
        sampled_at_us: (0..readings.len())
            .map(|k| t0 + (k as f64 * period as f64 * 1e6 / (1e6 + model.drift_ppm)).round() as u64)
            .collect(),
        ..LoopRun::default()
    };
    let f = |v: nalgebra::Vector3<f64>| [v[0], v[1], v[2]];
    let mut interrupts: Vec<u64> = Vec::new();
    let mut pending = false;
    let mut next = 0;
    let mut now = t0 - period;
    let end = run.sampled_at_us.last().map_or(t0, |t| t + 10_000);
    while now < end {
        // The samples that came by now, and their interrupts.
        while let Some(r) = readings.get(next) {
            let t = run.sampled_at_us[next];
            if t > now {
                break;
            }
            let part_us = 5_000 + next as u64 * period;
            part.borrow_mut()
                .sample(part_us, f(r.reading.gyro), f(r.reading.accel), 25.0);
            interrupts.push(t + rng.random_range(0..=model.irq_jitter_us));
            pending = true;
            next += 1;
        }
        let line = path.trigger_output_mut();
        line.advance(now);
        line.set_now(now);
        let mut out = |m| run.sent.push(m);
        let mut timing = Served {
            now_us: now,
            interrupts: &interrupts,
        };
        if pending {
            pending = false;
            let newest = run.sampled_at_us[next - 1];
            path.on_interrupt(&mut timing, device, &mut out)
                .map_err(|e| e.to_string())?;
            run.reads.push((now, newest));
        }
        path.poll(&mut timing, device, &mut NoDelay, &mut out)
            .map_err(|e| e.to_string())?;
        now += if rng.random_bool(model.long_share) {
            rng.random_range(model.short_us..=model.long_max_us)
        } else {
            model.short_us
        };
    }
    run.rises = path.trigger_output().rises.clone();
    Ok(run)
}
