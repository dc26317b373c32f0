//! One IMU step (time update + gyro + accelerometer updates) per model, and one
//! correspondence update, in f32 and f64, on the PC.

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use fusion_core::Kernels;
use fusion_core::filter::{Filter, ImuSample};
use fusion_core::init::{StillWindow, initial_state};
use fusion_core::models::correspondence::{self, Observation};
use fusion_core::params::Params;
use fusion_core::quat;
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use protocol::{InitAttitude, ModelKind};

/// A filter that has run for a while (realistic covariance fill-in).
fn warmed<T: Kernels>(model: ModelKind) -> (Params<T>, Filter<T>) {
    let mut cfg = protocol::samples::config();
    cfg.model = model;
    // No vision here: dead reckoning must not count as divergence.
    cfg.divergence.covariance_frobenius = 1e9;
    let prm = Params::<T>::from_config(&cfg);
    let mut w = StillWindow::default();
    let g = Vector3::new(T::c(0.001), T::c(-0.002), T::c(0.0));
    let a = Vector3::new(T::c(0.05), T::c(0.0), T::c(9.81));
    w.add(&g, &a, 1);
    let st = initial_state(
        &prm,
        &Vector3::new(T::c(0.0), T::c(0.0), T::c(1.0)),
        &InitAttitude::Gravity,
        &w,
    );
    let mut f = Filter::new(st, 0);
    for k in 1..200u64 {
        let s = ImuSample {
            t_us: k * 5000,
            gyro: g,
            accel: a,
        };
        f.imu_step(&prm, &s).unwrap();
    }
    (prm, f)
}

fn imu_step<T: Kernels>(c: &mut Criterion, name: &str) {
    for model in ModelKind::INERTIAL {
        let (prm, filter) = warmed::<T>(model);
        let mut t = filter.t_us;
        let mut f = filter.clone();
        let sample = ImuSample {
            t_us: 0,
            gyro: Vector3::new(T::c(0.01), T::c(-0.02), T::c(0.3)),
            accel: Vector3::new(T::c(0.1), T::c(0.0), T::c(9.8)),
        };
        c.bench_function(&format!("imu step {} {name}", model.name()), |b| {
            b.iter(|| {
                t += 5000;
                let s = ImuSample { t_us: t, ..sample };
                // Reset now and then so the state stays bounded over millions of steps.
                if t % 10_000_000 == 0 {
                    f = filter.clone();
                    f.t_us = t - 5000;
                }
                black_box(f.imu_step(&prm, black_box(&s))).ok();
            })
        });
    }
}

fn correspondence_update<T: Kernels>(c: &mut Criterion, name: &str) {
    let (prm, filter) = warmed::<T>(ModelKind::Acc);
    // A point 2 m in front of the camera, registered close to its projection.
    let pose = fusion_core::state::camera_pose(&filter.st, &prm.hand_eye);
    let m_w = pose.c_w
        + quat::rot(&pose.q_cw).transpose() * Vector3::new(T::c(0.2), T::c(-0.1), T::c(2.0));
    let obs = Observation {
        m_n: Vector2::new(T::c(0.1005), T::c(-0.0498)),
        cov_n: Matrix2::identity() * T::c(1e-5),
        m_w,
        cov_w: Matrix3::identity() * T::c(1e-6),
    };
    c.bench_function(&format!("correspondence update acc {name}"), |b| {
        b.iter_batched_ref(
            || filter.st.clone(),
            |st| black_box(correspondence::update(st, &prm, black_box(&obs))),
            BatchSize::SmallInput,
        )
    });
}

fn benches(c: &mut Criterion) {
    imu_step::<f32>(c, "f32");
    imu_step::<f64>(c, "f64");
    correspondence_update::<f32>(c, "f32");
    correspondence_update::<f64>(c, "f64");
}

criterion_group!(filter, benches);
criterion_main!(filter);
