//! The fusion core on a SpeedyBee F405 V4 (docs/PORTING.md): the core samples its own
//! ICM-42688-P on SPI1, fires the camera on the CAMERA_CONTROL pad, time-stamps both on TIM2
//! (1 MHz), and talks to the host over USB CDC (protocol/PROTOCOL.md §7).
//!
//! One main loop, no executor: the IMU's interrupt (INT1 on PC4, EXTI4) only captures TIM2's
//! count, the time stamp of the sample that raised it, and the loop reads the FIFO
//! (`sample_path::SamplePath`), serves USB and runs the device loop. The FIFO's own time stamps
//! place every sample, so the loop's latency moves no time stamp; it only delays the camera
//! pulse, by at most one correspondence part's processing (see the guide).
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cortex_m_rt::entry;
use embedded_hal_bus::spi::ExclusiveDevice;
use fusion_core::DeviceIo;
use icm42688::{Icm42688, Odr, Settings};
use protocol::{CoreToHost, MAX_FRAME_LEN, encode_frame};
use sample_path::{Clock64, INTERRUPTS_KEPT, SamplePath, TRIGGER_PULSE_US, Timing, TriggerOutput};
use stm32f4xx_hal::gpio::Edge;
use stm32f4xx_hal::otg_fs::{USB, UsbBus};
use stm32f4xx_hal::pac::{self, interrupt};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::spi::{Mode, Phase, Polarity, Spi};
use usb_device::prelude::*;
use usbd_serial::SerialPort;

/// The IMU's output data rate: the host's `Config::imu_rate_hz` must say the same.
const ODR: Odr = Odr::Hz200;

/// SPI clock: the part takes up to 24 MHz; SPI1 on the 84 MHz APB2 divides to 10.5 MHz.
const SPI_HZ: u32 = 10_000_000;

/// The device and its decoder: built at compile time (all zeros, `.bss`), never on the stack.
static mut DEVICE: DeviceIo<f32> = DeviceIo::new();

/// TIM2's count at the IMU's latest interrupts (a ring indexed by `IRQ_COUNT`), how many
/// interrupts there were, and whether the loop has yet to take the latest.
static IRQ_AT: [AtomicU32; INTERRUPTS_KEPT] = [const { AtomicU32::new(0) }; INTERRUPTS_KEPT];
static IRQ_COUNT: AtomicU32 = AtomicU32::new(0);
static IRQ_PENDING: AtomicBool = AtomicBool::new(false);

#[interrupt]
fn EXTI4() {
    // The time first: it stamps the sample that raised the interrupt.
    // SAFETY: a read of TIM2's counter register, which nothing else writes after start.
    let t = unsafe { (*pac::TIM2::ptr()).cnt().read().bits() };
    let n = IRQ_COUNT.load(Ordering::Relaxed);
    if let Some(slot) = IRQ_AT.get(n as usize % INTERRUPTS_KEPT) {
        slot.store(t, Ordering::Relaxed);
    }
    IRQ_COUNT.store(n.wrapping_add(1), Ordering::Release);
    IRQ_PENDING.store(true, Ordering::Release);
    // SAFETY: writing 1 clears line 4's pending bit and touches no other line.
    unsafe { (*pac::EXTI::ptr()).pr().write(|w| w.bits(1 << 4)) };
}

/// Whether the trigger line is high (the compare interrupt's state).
static TRIGGER_HIGH: AtomicBool = AtomicBool::new(false);

/// TIM2's capture/compare 1 flag (SR) and interrupt enable (DIER): bit 1 of both.
const CC1: u32 = 1 << 1;
/// PB14 in GPIOB's BSRR: set, and reset (16 bits up).
const PB14_SET: u32 = 1 << 14;
const PB14_RESET: u32 = 1 << (14 + 16);

/// The camera's trigger on PB14, raised by TIM2's channel 1 compare: the core's clock itself,
/// so the pulse rises at the armed count whatever the main loop is doing (issue 55, point 5),
/// and the compare interrupt lowers it `TRIGGER_PULSE_US` later.
struct TimerTrigger;

impl TriggerOutput for TimerTrigger {
    type Error = core::convert::Infallible;

    fn arm(&mut self, at_us: u64) -> Result<(), Self::Error> {
        // TIM2 counts the low 32 bits of the extended clock.
        let at = at_us as u32;
        // SAFETY: TIM2's compare 1 registers are this driver's alone (the counter HAL uses
        // the counter and the update event); the interrupt handler only reads and rewrites them
        // while the pulse is up, which `arm` is never called during (one pulse at a time).
        let tim = unsafe { &*pac::TIM2::ptr() };
        tim.ccr1().write(|w| unsafe { w.bits(at) });
        tim.sr().write(|w| unsafe { w.bits(!CC1) });
        tim.dier().modify(|r, w| unsafe { w.bits(r.bits() | CC1) });
        // Already past (the loop was slower than the lead): raise it at once rather than at the
        // counter's next wrap, 71 minutes on.
        let now = tim.cnt().read().bits();
        if now.wrapping_sub(at) < 1 << 31 {
            tim.ccr1().write(|w| unsafe { w.bits(now.wrapping_add(2)) });
        }
        Ok(())
    }

    fn fire_now(&mut self) -> Result<(), Self::Error> {
        // SAFETY: a read of TIM2's counter.
        let now = unsafe { (*pac::TIM2::ptr()).cnt().read().bits() };
        self.arm(u64::from(now.wrapping_add(2)))
    }
}

#[interrupt]
fn TIM2() {
    // SAFETY: see `TimerTrigger::arm`; GPIOB's BSRR sets or resets PB14 alone.
    let tim = unsafe { &*pac::TIM2::ptr() };
    if tim.sr().read().bits() & CC1 == 0 {
        return;
    }
    tim.sr().write(|w| unsafe { w.bits(!CC1) });
    let gpiob = unsafe { &*pac::GPIOB::ptr() };
    if TRIGGER_HIGH.load(Ordering::Relaxed) {
        gpiob.bsrr().write(|w| unsafe { w.bits(PB14_RESET) });
        TRIGGER_HIGH.store(false, Ordering::Relaxed);
        tim.dier().modify(|r, w| unsafe { w.bits(r.bits() & !CC1) });
    } else {
        gpiob.bsrr().write(|w| unsafe { w.bits(PB14_SET) });
        TRIGGER_HIGH.store(true, Ordering::Relaxed);
        let up = tim.ccr1().read().bits();
        tim.ccr1()
            .write(|w| unsafe { w.bits(up.wrapping_add(TRIGGER_PULSE_US)) });
    }
}

/// The core's clock (TIM2 extended to 64 bits) and the interrupt handler's times, read by the
/// sample path after each FIFO read.
struct LoopTiming<'a> {
    tim2: &'a stm32f4xx_hal::timer::CounterUs<pac::TIM2>,
    clock: &'a mut Clock64,
}

impl Timing for LoopTiming<'_> {
    fn now_us(&mut self) -> u64 {
        self.clock.extend(self.tim2.now().ticks())
    }

    fn interrupts(&mut self, out: &mut [u64; INTERRUPTS_KEPT]) -> usize {
        // The ring and its count copied with the handler held off, so that they agree.
        let (count, raw) = cortex_m::interrupt::free(|_| {
            let count = IRQ_COUNT.load(Ordering::Acquire);
            (count, IRQ_AT.each_ref().map(|a| a.load(Ordering::Relaxed)))
        });
        let k = (count as usize).min(INTERRUPTS_KEPT);
        for (i, o) in out.iter_mut().take(k).enumerate() {
            // Oldest first: interrupt number count - k + i.
            let n = count.wrapping_sub((k - i) as u32) as usize % INTERRUPTS_KEPT;
            *o = self.clock.extend(raw.get(n).copied().unwrap_or(0));
        }
        k
    }
}

#[entry]
fn main() -> ! {
    let (Some(dp), Some(cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        halt()
    };
    // 8 MHz crystal (Betaflight's SYSTEM_HSE_MHZ), 168 MHz core, 48 MHz for USB.
    let mut rcc = dp
        .RCC
        .freeze(Config::hse(8.MHz()).sysclk(168.MHz()).require_pll48clk());
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);
    let mut delay = cp.SYST.delay(&rcc.clocks);

    // The core's clock: TIM2, 32 bits at 1 MHz, free-running.
    let mut tim2 = dp.TIM2.counter_us(&mut rcc);
    if tim2.start(u32::MAX.micros()).is_err() {
        halt()
    }

    // The IMU: SPI1 (PA5 SCK, PA6 MISO, PA7 MOSI), mode 3, CS on PA4.
    let spi = Spi::new(
        dp.SPI1,
        (Some(gpioa.pa5), Some(gpioa.pa6), Some(gpioa.pa7)),
        Mode {
            polarity: Polarity::IdleHigh,
            phase: Phase::CaptureOnSecondTransition,
        },
        SPI_HZ.Hz(),
        &mut rcc,
    );
    let mut cs = gpioa.pa4.into_push_pull_output();
    cs.set_high();
    // Setting a GPIO of this HAL cannot fail.
    let Ok(spi) = ExclusiveDevice::new_no_delay(spi, cs);
    // The camera trigger on the CAMERA_CONTROL pad (PB14), low when idle.
    // PB14 stays a plain output: TIM2's compare interrupt drives it (`TimerTrigger`).
    let mut trigger_pin = gpiob.pb14.into_push_pull_output();
    trigger_pin.set_low();
    let mut path = SamplePath::new(Icm42688::new(spi, Settings::new(ODR)), TimerTrigger);

    // INT1 on PC4: rising edge (push-pull, active high, pulsed), EXTI4.
    let mut syscfg = dp.SYSCFG.constrain(&mut rcc);
    let mut exti = dp.EXTI;
    let mut int1 = gpioc.pc4.into_pull_down_input();
    int1.make_interrupt_source(&mut syscfg);
    int1.trigger_on_edge(&mut exti, Edge::Rising);
    int1.enable_interrupt(&mut exti);

    // SAFETY: the only reference to DEVICE, taken once before the loop; the interrupt
    // handler does not use it.
    #[allow(clippy::deref_addrof)]
    let device = unsafe { &mut *(&raw mut DEVICE) };
    let mut clock = Clock64::new();
    // Without a working IMU the core still serves a host that samples (it refuses `Sampling`
    // from the core with `NoOnboardImu`); the path tries the part again every second.
    let imu_ok = path
        .start(clock.extend(tim2.now().ticks()), &mut delay)
        .is_ok();
    device.device.set_onboard_imu(imu_ok);
    // SAFETY: the handler only touches atomics and EXTI's pending register.
    unsafe { cortex_m::peripheral::NVIC::unmask(pac::Interrupt::EXTI4) };
    // SAFETY: the handler touches TIM2's compare 1 registers, an atomic and PB14's BSRR bits.
    unsafe { cortex_m::peripheral::NVIC::unmask(pac::Interrupt::TIM2) };

    // USB CDC-ACM on PA11/PA12.
    let Some(ep_memory) = cortex_m::singleton!(: [u32; 1024] = [0; 1024]) else {
        halt()
    };
    let usb = USB::new(
        (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK),
        (gpioa.pa11, gpioa.pa12),
        &rcc.clocks,
    );
    let usb_bus = UsbBus::new(usb, ep_memory);
    let mut serial = SerialPort::new_with_store(&usb_bus, [0u8; 1024], [0u8; 2048]);
    let Ok(builder) = UsbDeviceBuilder::new(&usb_bus, UsbVidPid(0x16c0, 0x27dd))
        .device_class(usbd_serial::USB_CLASS_CDC)
        .strings(&[StringDescriptors::default()
            .manufacturer("fusion-core")
            .product("visual-inertial core")
            .serial_number("F405")])
    else {
        halt()
    };
    let mut usb_dev = builder.build();

    let mut frame = [0u8; MAX_FRAME_LEN];
    let mut rx = [0u8; 64];
    // Whether a host has the port open (DTR): a host that opens it must shake hands before it
    // drives the core (protocol/PROTOCOL.md §8).
    let mut host_dtr = false;
    loop {
        let polled = usb_dev.poll(&mut [&mut serial]);
        if serial.dtr() != host_dtr {
            host_dtr = !host_dtr;
            if host_dtr {
                device.link_opened();
            }
        }
        if polled
            && let Ok(n) = serial.read(&mut rx)
            && n > 0
        {
            device.receive(&rx[..n], &mut |bytes| send(&mut serial, bytes));
        }
        // Readings of the clock may come out of order with the interrupt's (one taken before
        // a reading maps to its past: `Clock64`).
        let mut timing = LoopTiming {
            tim2: &tim2,
            clock: &mut clock,
        };
        let mut out = |msg: CoreToHost| {
            if let Ok(bytes) = encode_frame(&msg, &mut frame) {
                send(&mut serial, bytes);
            }
        };
        if IRQ_PENDING.swap(false, Ordering::Acquire) {
            // A failed SPI transfer loses this read's samples; the next read's time stamps
            // count them and the core reports the gap.
            let _ = path.on_interrupt(&mut timing, &mut device.device, &mut out);
        }
        let _ = path.poll(&mut timing, &mut device.device, &mut delay, &mut out);
    }
}

/// Writes one frame to the host. A frame that does not fit the USB buffer (no host reading)
/// is cut short: the host's decoder rejects it by its CRC and resynchronises at the next
/// delimiter, so a slow host loses whole frames, never reads a wrong one.
fn send<B: usb_device::bus::UsbBus>(
    serial: &mut SerialPort<'_, B, [u8; 1024], [u8; 2048]>,
    bytes: &[u8],
) {
    let _ = serial.write(bytes);
}

/// Stops here (the debugger shows where); only reachable at boot, before any input.
fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    halt()
}
