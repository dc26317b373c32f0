//! Decoder and encoder throughput on a realistic host→core stream: IMU samples at 8x the
//! camera rate plus full correspondence messages, as on a 200 Hz / 25 Hz link.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use protocol::{
    Correspondences, Decoder, HostToCore, ImuSample, MAX_CORRESPONDENCES_PER_MESSAGE,
    MAX_FRAME_LEN, encode_frame, samples,
};

fn stream() -> (Vec<HostToCore>, Vec<u8>) {
    let all: Vec<_> = (0..MAX_CORRESPONDENCES_PER_MESSAGE)
        .map(|i| samples::correspondence([i as f32 * 0.01, -0.1], [0.1, i as f32 * 0.02, 0.5]))
        .collect();
    let mut msgs = Vec::new();
    for k in 0..4000u64 {
        msgs.push(HostToCore::Imu(ImuSample {
            t_us: k * 5000,
            gyro: [0.01, -0.02, 0.3 + k as f32 * 1e-4],
            accel: [0.2, -0.1, 9.81],
            trigger: k.is_multiple_of(8),
        }));
        if k % 8 == 7 {
            msgs.extend(
                Correspondences::split(k as u32 / 8, k * 5000, &all)
                    .unwrap()
                    .map(HostToCore::Correspondences),
            );
        }
    }
    let mut bytes = Vec::new();
    let mut buf = [0u8; MAX_FRAME_LEN];
    for m in &msgs {
        bytes.extend_from_slice(encode_frame(m, &mut buf).unwrap());
    }
    (msgs, bytes)
}

fn bench(c: &mut Criterion) {
    let (msgs, bytes) = stream();
    let mut group = c.benchmark_group("protocol");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.bench_function("decode stream (one chunk)", |b| {
        b.iter(|| {
            let mut dec = Decoder::new();
            let n = dec.feed::<HostToCore>(&bytes).filter(|r| r.is_ok()).count();
            assert_eq!(n, msgs.len());
        })
    });
    group.bench_function("decode stream (64-byte chunks)", |b| {
        b.iter(|| {
            let mut dec = Decoder::new();
            let mut n = 0;
            for chunk in bytes.chunks(64) {
                n += dec.feed::<HostToCore>(chunk).filter(|r| r.is_ok()).count();
            }
            assert_eq!(n, msgs.len());
        })
    });
    group.bench_function("encode stream", |b| {
        let mut buf = [0u8; MAX_FRAME_LEN];
        b.iter(|| {
            let mut total = 0;
            for m in &msgs {
                total += encode_frame(m, &mut buf).unwrap().len();
            }
            assert_eq!(total, bytes.len());
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
