//! A sensor board in the harness (issue 36): the scenario's readings go into the simulated
//! ICM-42688-P at the part's clock, and its interrupt runs the board's sample path into the
//! driver's device, which samples its own IMU (protocol/PROTOCOL.md §7). The device's answers
//! go back to the [`Driver`], which answers the frames as the host would.

use firmware_sim::sim::sensor_board::{NoDelay, SharedPart, TriggerLine};
use fusion_core::Kernels;
use icm42688::{Icm42688, Settings};
use protocol::{CoreToHost, HostToCore, ImuSample, SampleSource, Sampling};
use sample_path::{At, SamplePath, Served};

use crate::harness::Driver;

/// How the MCU serves a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Serve {
    /// Its interrupt, then the main loop's turn.
    Interrupt,
    /// The interrupt is missed; the main loop runs.
    MissedInterrupt,
    /// The MCU is busy: neither runs.
    Nothing,
    /// The previous sample's interrupt is served only now, and this sample arrived (and
    /// interrupted) after the loop took the interrupt and before it read the FIFO's count: the
    /// read holds both, and both interrupts' times are known after it (issue 55, point 4).
    ArrivedDuringRead,
    /// This sample's interrupt is served, and the next sample interrupts after the FIFO's
    /// count was read but before the interrupts' times are read: it is not in the read.
    NextArrivesAfterRead,
}

/// The board: the simulated part and the sample path.
pub struct Board {
    part: SharedPart,
    path: SamplePath<SharedPart, TriggerLine>,
    /// The raw samples the core reported taking (`raw_imu`).
    pub raw: Vec<ImuSample>,
}

impl Board {
    /// A board whose part runs at `settings`, started; the device is told it has an IMU and
    /// asked (as the host would) to sample it, triggering every `trigger_every`-th sample.
    pub fn start<T: Kernels>(
        settings: Settings,
        driver: &mut Driver<'_, T>,
        trigger_every: u16,
    ) -> Board {
        let part = SharedPart::default();
        let mut path = SamplePath::new(
            Icm42688::new(part.clone(), settings),
            TriggerLine::default(),
        );
        path.start(0, &mut NoDelay)
            .expect("the simulated part starts");
        driver.device.set_onboard_imu(true);
        driver.send(&HostToCore::Sampling(Sampling {
            source: SampleSource::Core { trigger_every },
            raw_imu: true,
        }));
        Board {
            part,
            path,
            raw: Vec::new(),
        }
    }

    /// The driver's next sample taken by the board: the reading into the part at the part's
    /// time (no drift: the MCU's time is the scenario's), the interrupt served at once, and
    /// the device's answers to the driver.
    pub fn step<T: Kernels>(&mut self, driver: &mut Driver<'_, T>) {
        self.step_faulty(driver, Serve::Interrupt);
    }

    /// The part resets (a brown-out) now.
    pub fn reset_part(&self) {
        self.part.part().power_on_reset();
    }

    /// The next `n` packets the part stores are marked invalid (a sensor starting up).
    pub fn invalid_next(&self, n: u32) {
        self.part.part().invalid_next(n);
    }

    /// The next packet the part stores gets a corrupt header.
    pub fn corrupt_next(&self) {
        self.part.part().corrupt_next_header();
    }

    /// The next sample, served as `serve` says.
    pub fn step_faulty<T: Kernels>(&mut self, driver: &mut Driver<'_, T>, serve: Serve) {
        let HostToCore::Imu(s) = driver.next_imu() else {
            panic!("the board samples an IMU: an inertial model only")
        };
        let (_, reading) = driver.last.expect("a sample was just taken");
        let f = |v: nalgebra::Vector3<f64>| [v[0], v[1], v[2]];
        self.part
            .part()
            .sample(s.t_us, f(reading.gyro), f(reading.accel), 25.0);
        let mut answers = Vec::new();
        let mut out = |m| answers.push(m);
        let period = u64::from(self.path.imu().settings().period_us());
        // The timer's pulse armed for this sample rises with it.
        let line = self.path.trigger_output_mut();
        line.set_now(s.t_us);
        line.advance(s.t_us + period / 2);
        let interrupts = match serve {
            Serve::Interrupt => vec![s.t_us],
            Serve::ArrivedDuringRead => vec![s.t_us - period, s.t_us],
            Serve::NextArrivesAfterRead => vec![s.t_us, s.t_us + period],
            Serve::MissedInterrupt | Serve::Nothing => vec![],
        };
        if !interrupts.is_empty() && self.part.part().interrupt_pending() {
            let mut timing = Served {
                now_us: s.t_us,
                interrupts: &interrupts,
            };
            self.path
                .on_interrupt(&mut timing, &mut driver.device, &mut out)
                .expect("the simulated part answers");
        }
        if serve != Serve::Nothing {
            self.path
                .poll(&mut At(s.t_us), &mut driver.device, &mut NoDelay, &mut out)
                .expect("the simulated part answers");
        }
        for m in &answers {
            if let CoreToHost::RawImu(r) = m {
                self.raw.push(*r);
            }
        }
        driver.record(&answers);
        driver.answer(answers);
    }
}
