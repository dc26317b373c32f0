//! Firmware benchmark under QEMU with `-icount shift=0`: instructions per IMU step of each
//! model and per correspondence update, the cost of a whole IMU message through the device
//! loop, and the stack high-water of a realistic session. Reports over semihosting as
//! `BENCH key value` lines, then exits.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use firmware::{stack, timer::Timer};
use fusion_core::filter::{Filter, ImuSample};
use fusion_core::init::{StillWindow, initial_state};
use fusion_core::models::contour::{self, ContourObservation};
use fusion_core::models::correspondence::{self, Observation};
use fusion_core::params::Params;
use fusion_core::{DeviceIo, quat};
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use protocol::{
    Correspondence, Correspondences, Hello, HostToCore, Init, InitAttitude, MAX_FRAME_LEN,
    ModelKind, PROTOCOL_VERSION, encode_frame,
};

static mut DEVICE: DeviceIo<f32> = DeviceIo::new();

const STEPS: u64 = 64;

/// Profiling marks around each timed figure (outside the timed region): empty functions that
/// an execution log (`qemu -d in_asm,exec,nochain`) sees entered, so that a profile can charge
/// the instructions between a start mark and [`mark_stop`] to that figure. Each has its own
/// constant, so that LTO does not merge them into one.
macro_rules! marks {
    ($($(#[$doc:meta])* $name:ident = $id:literal;)*) => {
        $($(#[$doc])* #[inline(never)] fn $name() { core::hint::black_box($id); })*
    };
}
marks! {
    /// Start of `imu_step_*` / `tick_vision` (all 64 steps).
    mark_imu_steps = 1u32;
    /// Start of one `correspondence_update*`.
    mark_correspondence = 2u32;
    /// Start of one message counted in `*_message_through_device*`.
    mark_message = 3u32;
    /// Start of one part of a `frame_40_correspondences*`.
    mark_frame_part = 4u32;
    /// Start of a message of the session that no figure counts.
    mark_other = 5u32;
    /// End of a timed region.
    mark_stop = 6u32;
    /// Start of one `contour_update*`.
    mark_contour = 7u32;
}

/// `timer.instructions(f)` between a start mark and [`mark_stop`].
fn timed<R>(timer: &Timer, start: fn(), f: impl FnOnce() -> R) -> (u64, R) {
    start();
    let r = timer.instructions(f);
    mark_stop();
    r
}

fn config(model: ModelKind) -> protocol::Config {
    let mut c = protocol::samples::config();
    c.model = model;
    c.imu_rate_hz = 200.0;
    // No vision in the filter benchmarks: dead reckoning is not divergence here.
    c.divergence.covariance_frobenius = 1e9;
    c
}

/// A filter that has run for a second (realistic covariance fill-in).
#[inline(never)]
fn warmed(model: ModelKind) -> (Params<f32>, Filter<f32>) {
    let prm = Params::<f32>::from_config(&config(model));
    let mut w = StillWindow::default();
    w.add(
        &Vector3::new(0.001, -0.002, 0.0),
        &Vector3::new(0.05, 0.0, 9.81),
        1,
    );
    // Vision-only has no gravity: it starts from a full pose.
    let attitude = if model.has_imu() {
        InitAttitude::Gravity
    } else {
        InitAttitude::Full([1.0, 0.0, 0.0, 0.0])
    };
    let st = initial_state(&prm, &Vector3::new(0.0, 0.0, 1.0), &attitude, &w);
    let mut f = Filter::new(st, 0);
    for k in 1..200u64 {
        let s = ImuSample {
            t_us: k * 5000,
            gyro: Vector3::new(0.001, -0.002, 0.0),
            accel: Vector3::new(0.05, 0.0, 9.81),
        };
        let _ = f.imu_step(&prm, &s);
    }
    (prm, f)
}

#[inline(never)]
fn bench_imu_steps(timer: &Timer) {
    // Vision-only's step is its tick: the time update alone (the readings are not read).
    for model in ModelKind::ALL {
        let (prm, mut f) = warmed(model);
        let t0 = f.t_us;
        let (ins, _) = timed(timer, mark_imu_steps, || {
            for k in 1..=STEPS {
                let s = ImuSample {
                    t_us: t0 + k * 5000,
                    gyro: Vector3::new(0.01, -0.02, 0.3),
                    accel: Vector3::new(0.1, 0.0, 9.8),
                };
                let _ = f.imu_step(&prm, &s);
            }
        });
        if model.has_imu() {
            hprintln!("BENCH imu_step_{} {}", model.name(), ins / STEPS);
        } else {
            hprintln!("BENCH tick_{} {}", model.name(), ins / STEPS);
        }
    }
}

#[inline(never)]
fn calibrate(timer: &Timer) {
    let a = core::hint::black_box([1.5f32; 484]);
    let mut b = core::hint::black_box([0.5f32; 484]);
    let (ins, _) = timer.instructions(|| {
        for (x, y) in b.iter_mut().zip(&a) {
            *x += y * 0.3;
        }
    });
    core::hint::black_box(&b);
    hprintln!("BENCH calib_axpy_484 {}", ins);
}

#[inline(never)]
fn bench_correspondence(timer: &Timer, model: ModelKind) {
    let (prm, f) = warmed(model);
    let pose = fusion_core::state::camera_pose(&f.st, &prm.hand_eye);
    let r_wc = quat::rot(&pose.q_cw).transpose();
    let mut total = 0;
    let n = 16;
    for i in 0..n {
        let p_c = Vector3::new(-0.3 + 0.04 * i as f32, 0.1 - 0.01 * i as f32, 2.0);
        let obs = Observation {
            m_n: Vector2::new(p_c.x / p_c.z + 0.001, p_c.y / p_c.z - 0.0005),
            cov_n: Matrix2::identity() * 1e-5,
            m_w: pose.c_w + r_wc * p_c,
            cov_w: Matrix3::identity() * 1e-6,
        };
        let mut st = f.st.clone();
        let (ins, _) = timed(timer, mark_correspondence, || {
            correspondence::update(&mut st, &prm, &obs)
        });
        total += ins;
    }
    if model == ModelKind::Acc {
        hprintln!("BENCH correspondence_update {}", total / n);
    } else {
        hprintln!("BENCH correspondence_update_{} {}", model.name(), total / n);
    }
}

/// The same 16 model points as [`bench_correspondence`], each as a contour correspondence
/// (eq. 10c): found 1 px-ish off along a normal that turns from point to point.
#[inline(never)]
fn bench_contour(timer: &Timer, model: ModelKind) {
    let (prm, f) = warmed(model);
    let pose = fusion_core::state::camera_pose(&f.st, &prm.hand_eye);
    let r_wc = quat::rot(&pose.q_cw).transpose();
    let mut total = 0;
    let n = 16;
    for i in 0..n {
        let p_c = Vector3::new(-0.3 + 0.04 * i as f32, 0.1 - 0.01 * i as f32, 2.0);
        let (sin, cos) = fusion_core::trig::sin_cos_f32(0.4 * i as f32);
        let normal = Vector2::new(cos, sin);
        let obs = ContourObservation {
            m_w: pose.c_w + r_wc * p_c,
            cov_w: Matrix3::identity() * 1e-6,
            n: normal,
            d: normal.dot(&Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z)) + 0.001,
            var_d: 1e-5,
        };
        let mut st = f.st.clone();
        let (ins, _) = timed(timer, mark_contour, || contour::update(&mut st, &prm, &obs));
        total += ins;
    }
    if model == ModelKind::Acc {
        hprintln!("BENCH contour_update {}", total / n);
    } else {
        hprintln!("BENCH contour_update_{} {}", model.name(), total / n);
    }
}

/// The 40 correspondences of a session's frame, seen from the resting camera at `c_w` with
/// orientation `r_wc`.
fn frame_correspondences(
    vision: bool,
    c_w: &Vector3<f32>,
    r_wc: &Matrix3<f32>,
) -> [Correspondence; 40] {
    let mut all = [protocol::samples::correspondence([0.0; 2], [0.0; 3]); 40];
    for (i, c) in all.iter_mut().enumerate() {
        // The inertial session's points lie on a line (kept so that its figures stay
        // comparable with earlier ones: gravity makes up the missing directions);
        // without an IMU they must fix the whole pose: an 8 × 5 grid.
        let p_c = if vision {
            let (u, v) = ((i % 8) as f32, (i / 8) as f32);
            Vector3::new(-0.6 + 0.17 * u, -0.4 + 0.2 * v, 2.0)
        } else {
            Vector3::new(-0.6 + 0.03 * i as f32, -0.3 + 0.015 * i as f32, 2.0)
        };
        let m_w = c_w + r_wc * p_c;
        *c = Correspondence {
            m_n: [p_c.x / p_c.z, p_c.y / p_c.z],
            cov_n: [1e-5, 0.0, 1e-5],
            m_w: [m_w.x, m_w.y, m_w.z],
            cov_w: [1e-6, 0.0, 0.0, 1e-6, 0.0, 1e-6],
        };
    }
    all
}

/// The session's clock message at `t_us`: a tick (vision-only) or a resting IMU sample.
fn clock_message(vision: bool, t_us: u64, trigger: bool) -> HostToCore {
    if vision {
        HostToCore::Tick(protocol::Tick { t_us, trigger })
    } else {
        HostToCore::Imu(protocol::ImuSample {
            t_us,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            trigger,
        })
    }
}

/// A session through the device loop, as the host would drive it: handshake, configure, init,
/// a still second, then 25 Hz frames of 40 correspondences arriving 50 ms late. The
/// vision-only model instead gets a tick per frame (25 Hz, every one a trigger), and each
/// frame's correspondences before the next tick.
#[inline(never)]
fn session(timer: &Timer, model: ModelKind) {
    // SAFETY: the only reference to DEVICE.
    // `&mut DEVICE` directly is refused for `static mut` in edition 2024; go through a raw
    // pointer, once.
    #[allow(clippy::deref_addrof)]
    let io = unsafe { &mut *(&raw mut DEVICE) };
    // Each session starts from a device just out of reset: all zero bytes, which is what
    // `DeviceIo::new()` is (that is why the static is in `.bss`). Zeroing it in place needs no
    // stack copy of the 15 KB device.
    // SAFETY: `io` is a valid, exclusive reference, and all zero bytes is a valid `DeviceIo`.
    unsafe { core::ptr::write_bytes(io as *mut DeviceIo<f32>, 0, 1) };
    let mut frame = [0u8; MAX_FRAME_LEN];
    let mut sink = |_: &[u8]| {};
    // The host encodes a message; the device's work, which the figures count, starts at the
    // bytes (decode, filter, answers): the encoding is outside the timed region.
    let mut feed_timed = |io: &mut DeviceIo<f32>, msg: &HostToCore, mark: fn()| {
        let Ok(bytes) = encode_frame(msg, &mut frame) else {
            return 0;
        };
        timed(timer, mark, || io.receive(bytes, &mut sink)).0
    };
    let mut feed = |io: &mut DeviceIo<f32>, msg: &HostToCore| {
        feed_timed(io, msg, mark_other);
    };
    let vision = !model.has_imu();
    let mut cfg = config(model);
    if vision {
        cfg.imu_rate_hz = 25.0;
    }
    cfg.still_samples = 100;
    cfg.state_every = 1;
    cfg.divergence.covariance_frobenius = 100.0;
    feed(
        io,
        &HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }),
    );
    feed(io, &HostToCore::Configure(cfg));
    let init = Init {
        position: [0.0, 0.0, 1.0],
        attitude: if vision {
            InitAttitude::Full([1.0, 0.0, 0.0, 0.0])
        } else {
            InitAttitude::Gravity
        },
    };
    feed(io, &HostToCore::Init(init));
    // Camera pose of the resting device, for consistent correspondences.
    let prm = Params::<f32>::from_config(&cfg);
    let mut rest = fusion_core::state::State::<f32>::default();
    rest.set_v3(fusion_core::state::POS, &Vector3::new(0.0, 0.0, 1.0));
    let pose = fusion_core::state::camera_pose(&rest, &prm.hand_eye);
    let r_wc = quat::rot(&pose.q_cw).transpose();
    let mut imu_total = 0u64;
    let mut imu_count = 0u64;
    let mut pending: Option<(u32, u64, u64)> = None;
    // (first trigger, samples per frame, samples of latency, sample period [µs])
    let (first, every, latency, period) = if vision {
        (1, 1, 0, 40_000)
    } else {
        (100, 8, 6, 5000)
    };
    for k in 0..400u64 {
        let trigger = k >= first && (k - first) % every == 0;
        let msg = clock_message(vision, k * period, trigger);
        let mark = if k >= first { mark_message } else { mark_other };
        let ins = feed_timed(io, &msg, mark);
        if k >= first {
            imu_total += ins;
            imu_count += 1;
        }
        if trigger {
            pending = Some((((k - first) / every) as u32, k * period, k + latency));
        }
        if let Some((frame_id, t_us, due)) = pending
            && due == k
        {
            let all = frame_correspondences(vision, &pose.c_w, &r_wc);
            if let Ok(parts) = Correspondences::split(frame_id, t_us, &all) {
                let mut frame_total = 0;
                for part in parts {
                    let ins = feed_timed(io, &HostToCore::Correspondences(part), mark_frame_part);
                    frame_total += ins;
                }
                if vision {
                    hprintln!("BENCH frame_40_correspondences_vision {}", frame_total);
                } else {
                    hprintln!("BENCH frame_40_correspondences {}", frame_total);
                }
            }
            pending = None;
        }
    }
    let c = io.device.counters();
    let (per_message, name) = (imu_total / imu_count.max(1), model.name());
    if vision {
        hprintln!("BENCH tick_message_through_device_{} {}", name, per_message);
    } else {
        hprintln!("BENCH imu_message_through_device {}", per_message);
    }
    hprintln!("BENCH session_accepted_{} {}", name, c.accepted);
    hprintln!("BENCH session_mode_{} {:?}", name, io.device.mode());
}

/// No trigger line: the camera trigger's cost is a timer register write, outside what the
/// core computes.
struct NoPin;
impl sample_path::TriggerOutput for NoPin {
    type Error = core::convert::Infallible;
    fn arm(&mut self, _: u64) -> Result<(), Self::Error> {
        Ok(())
    }
    fn fire_now(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// No waiting: the pulse width and the part's set-up delays are time, not work.
struct NoDelay;
impl embedded_hal::delay::DelayNs for NoDelay {
    fn delay_ns(&mut self, _: u32) {}
}

/// The board's sample path per IMU sample (issue 36): the FIFO read of one packet from the
/// simulated ICM-42688-P (whose SPI emulation is counted too: an upper bound of the driver's
/// work, where a real bus would wait ~20 µs instead), time stamps, scaling, the trigger
/// decision and `Device::onboard` with the acc model running; and `Device::onboard` alone on
/// the same samples, so that the difference is the path's own cost.
#[inline(never)]
fn bench_sample_path(timer: &Timer) {
    use core::cell::RefCell;
    use fusion_core::onboard::OnboardEvent;
    use icm42688::{Icm42688, Odr, Settings, SimIcm42688, sim::SharedSim};
    use protocol::{CoreToHost, SampleSource, Sampling};
    use sample_path::{At, SamplePath};

    // SAFETY: the only reference to DEVICE; all zero bytes is a valid `DeviceIo` (see
    // `session`).
    #[allow(clippy::deref_addrof)]
    let io = unsafe { &mut *(&raw mut DEVICE) };
    let mut sink = |_: CoreToHost| {};
    let mut run = |through_path: bool| -> u64 {
        // SAFETY: as above.
        unsafe { core::ptr::write_bytes(io as *mut DeviceIo<f32>, 0, 1) };
        let d = &mut io.device;
        d.set_onboard_imu(true);
        let mut cfg = config(ModelKind::Acc);
        cfg.still_samples = 50;
        for msg in [
            HostToCore::Hello(Hello {
                version: PROTOCOL_VERSION,
            }),
            HostToCore::Configure(cfg),
            HostToCore::Init(Init {
                position: [0.0, 0.0, 1.0],
                attitude: InitAttitude::Gravity,
            }),
            HostToCore::Sampling(Sampling {
                source: SampleSource::Core { trigger_every: 8 },
                raw_imu: false,
            }),
        ] {
            d.handle(&msg, &mut sink);
        }
        let part = RefCell::new(SimIcm42688::new());
        let mut path = SamplePath::new(
            Icm42688::new(SharedSim::new(&part), Settings::new(Odr::Hz200)),
            NoPin,
        );
        if path.start(0, &mut NoDelay).is_err() {
            return 0;
        }
        let mut total = 0;
        for k in 0..(100 + STEPS) {
            part.borrow_mut()
                .sample(k * 5000, [0.01, -0.02, 0.3], [0.1, 0.0, 9.8], 25.0);
            let t = 1_000_000 + k * 5000;
            let (ins, _) = if through_path {
                timed(timer, mark_message, || {
                    path.on_interrupt(&mut At(t), d, &mut sink)
                })
            } else {
                // A sample like the path's (the filter's cost does not depend on the values).
                let s = protocol::ImuSample {
                    t_us: t,
                    gyro: [0.01, -0.02, 0.3],
                    accel: [0.1, 0.0, 9.8],
                    trigger: k % 8 == 0,
                };
                (
                    timed(timer, mark_message, || {
                        d.onboard(&OnboardEvent::Sample(s), &mut sink)
                    })
                    .0,
                    Ok(sample_path::ReadSummary::default()),
                )
            };
            if k >= 100 {
                total += ins;
            }
        }
        total / STEPS
    };
    let whole = run(true);
    let device_only = run(false);
    hprintln!("BENCH sample_path_per_sample {}", whole);
    hprintln!("BENCH onboard_sample_device_only {}", device_only);
}

#[entry]
fn main() -> ! {
    let timer = Timer::start();
    bench_imu_steps(&timer);
    bench_correspondence(&timer, ModelKind::Acc);
    bench_correspondence(&timer, ModelKind::Vision);
    bench_contour(&timer, ModelKind::Acc);
    bench_contour(&timer, ModelKind::Vision);
    calibrate(&timer);
    // Stack of the device loop alone: repaint, run the session, measure.
    stack::paint();
    session(&timer, ModelKind::Acc);
    session(&timer, ModelKind::Vision);
    hprintln!("BENCH stack_high_water {}", stack::high_water());
    hprintln!("BENCH static_ram {}", stack::static_ram());
    hprintln!(
        "BENCH device_static {}",
        core::mem::size_of::<DeviceIo<f32>>()
    );
    bench_sample_path(&timer);
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
