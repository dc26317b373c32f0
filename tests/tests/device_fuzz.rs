//! No input panics the core: a running device (f32 and f64) fed a mix of its normal session
//! and random messages of every kind with arbitrary field values (random postcard bodies that
//! happen to decode), then random bytes through the framed byte interface.

use fusion_core::{Device, DeviceIo, Kernels};
use protocol::{HostToCore, Mode, ModelKind};
use tests::harness::{Driver, scenes};

/// Small deterministic generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn bytes(&mut self, max: usize) -> Vec<u8> {
        let n = (self.next() % max as u64) as usize;
        (0..n).map(|_| self.next() as u8).collect()
    }
}

/// A random message of any kind, or `None` when the random body does not decode.
fn random_message(rng: &mut Rng) -> Option<HostToCore> {
    let mut body = rng.bytes(400);
    if let Some(first) = body.first_mut() {
        *first %= 6; // a valid variant index, so that every kind comes up
    }
    postcard::from_bytes::<HostToCore>(&body).ok()
}

fn run<T: Kernels>(model: ModelKind, seed: u64) -> (usize, Mode) {
    let sc = scenes::standard(model, 12.0, 2.0, seed);
    let mut d = Driver::<T>::new(&sc);
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let mut injected = 0;
    while d.k < d.samples() {
        d.step();
        // After the start, now and then a burst of random messages of any kind.
        if d.k > 400 && rng.next().is_multiple_of(2) {
            for _ in 0..1 + rng.next() % 8 {
                if let Some(msg) = random_message(&mut rng) {
                    // Reconfiguring or re-initialising at random is part of the test, but
                    // keep the session alive often enough to reach the deep paths.
                    if matches!(msg, HostToCore::Configure(_) | HostToCore::Reset)
                        && !rng.next().is_multiple_of(4)
                    {
                        continue;
                    }
                    d.send(&msg);
                    injected += 1;
                }
            }
        }
    }
    (injected, d.device.mode())
}

#[test]
fn random_messages_into_a_running_core_never_panic() {
    let mut total = 0;
    for (i, model) in ModelKind::INERTIAL.into_iter().enumerate() {
        let (a, mode_a) = run::<f32>(model, 100 + i as u64);
        let (b, mode_b) = run::<f64>(model, 200 + i as u64);
        println!(
            "{model:?}: {a} + {b} random messages injected; final modes {mode_a:?}, {mode_b:?}"
        );
        total += a + b;
    }
    assert!(
        total > 3000,
        "the generator must produce messages ({total})"
    );
}

#[test]
fn random_bytes_into_the_framed_interface_never_panic() {
    let mut io = DeviceIo::<f32>::new();
    let mut rng = Rng(0xDEAD_BEEF);
    let mut replies = 0usize;
    for _ in 0..20_000 {
        let chunk = rng.bytes(300);
        io.receive(&chunk, &mut |_| replies += 1);
    }
    println!(
        "{replies} replies to 20000 random chunks; {:?}",
        io.device.counters()
    );
    assert!(io.device.counters().decode_errors > 0);
    let _ = Device::<f64>::new();
}
