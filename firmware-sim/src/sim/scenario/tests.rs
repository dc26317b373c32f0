//! Scenario checks: exact derivatives, the paper's peak numbers, scene facts, dead reckoning
//! of the written IMU files against the written ground truth, and Allan deviations.

use super::euroc::{read_groundtruth_csv, read_imu_csv, write_imu_dataset};
use super::*;
use crate::sim::GRAVITY_W;
use nalgebra::Quaternion;

#[test]
fn scenario_derivatives_match_central_differences() {
    for name in ScenarioName::ALL {
        let sc = Scenario::new(name);
        let h = 1e-5;
        let n = 400;
        let (mut ev, mut ea, mut ew) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..n {
            // Irrational stride: samples land everywhere, not on a grid aligned with events.
            let t = (0.5 + i as f64 * 0.618_033_988_7 * sc.duration() / n as f64 * 1.6)
                % (sc.duration() - 0.01);
            let (a, b, s) = (sc.path.eval(t - h), sc.path.eval(t + h), sc.path.eval(t));
            let (ka, kb, k) = (a.kinematics, b.kinematics, s.kinematics);
            ev = ev.max(((kb.p_w - ka.p_w) / (2.0 * h) - k.v_w).norm());
            ea = ea.max(((kb.v_w - ka.v_w) / (2.0 * h) - k.a_w).norm());
            let w = (ka.q_ws.inverse() * kb.q_ws).scaled_axis() / (2.0 * h);
            ew = ew.max((w - k.omega_s).norm());
        }
        println!("{name}: max FD error v {ev:.1e} m/s, a {ea:.1e} m/s², ω {ew:.1e} rad/s");
        assert!(ev < 1e-6 && ea < 1e-4 && ew < 1e-6, "{name}");
    }
}

/// The issue's numbers: desktop-slow ~1 m/s²; desktop-fast ~10 m/s² and ~3 rad/s; room up to
/// 12.9 m/s² and 9.6 rad/s; foyer: high linear acceleration from off-centre rotation.
#[test]
fn peak_accelerations_and_rates_match_the_paper() {
    let tol_issue = 0.10;
    let peaks: Vec<(ScenarioName, Peaks)> = ScenarioName::ALL
        .iter()
        .map(|&name| (name, Scenario::new(name).path.peaks(1e-3)))
        .collect();
    for &(name, p) in &peaks {
        let sc = Scenario::new(name);
        println!(
            "{name}: duration {:.0} s, peak free acceleration {:.2} m/s², peak rate {:.2} rad/s, \
             pivot acceleration {:.2} m/s², speed {:.2} m/s",
            sc.duration(),
            p.accel,
            p.rate,
            p.pivot_accel,
            p.speed
        );
    }
    for (name, p) in peaks {
        let near = |x: f64, want: f64, tol: f64| (x / want - 1.0).abs() <= tol;
        match name {
            ScenarioName::DesktopSlow => {
                assert!(near(p.accel, 1.0, tol_issue), "{name} accel {}", p.accel);
                assert!(p.rate < 1.5, "{name} rate {}", p.rate);
            }
            ScenarioName::DesktopFast => {
                assert!(near(p.accel, 10.0, tol_issue), "{name} accel {}", p.accel);
                assert!(near(p.rate, 3.0, tol_issue), "{name} rate {}", p.rate);
            }
            ScenarioName::Room => {
                // "Up to": the peaks are the paper's values, within 3 %.
                assert!(near(p.accel, 12.9, 0.03), "{name} accel {}", p.accel);
                assert!(near(p.rate, 9.6, 0.03), "{name} rate {}", p.rate);
            }
            ScenarioName::Foyer => {
                // Off-centre rotation: the device accelerates hard while the person stands.
                assert!(p.accel > 8.0, "{name} accel {}", p.accel);
                assert!(
                    p.pivot_accel < 0.05 * p.accel,
                    "{name} pivot {}",
                    p.pivot_accel
                );
            }
        }
    }
}

/// The camera's view of the model over time, at 100 Hz: (t, share of model points in view).
fn model_in_view(sc: &Scenario) -> Vec<(f64, f64)> {
    let n = (sc.duration() * 100.0) as usize;
    (0..=n)
        .map(|i| {
            let t = i as f64 / 100.0;
            let (c, q) = sc.camera_pose(t);
            (
                t,
                sc.scene
                    .model_points_in_view(&c, &q, &sc.camera.pinhole, 12),
            )
        })
        .collect()
}

/// Lengths [s] of the stretches where no model point is in view.
fn blind_stretches(view: &[(f64, f64)]) -> Vec<f64> {
    let mut out = Vec::new();
    let mut start = None;
    for &(t, share) in view {
        match (share == 0.0, start) {
            (true, None) => start = Some(t),
            (false, Some(s)) => {
                out.push(t - s);
                start = None;
            }
            _ => {}
        }
    }
    if let (Some(s), Some(&(t, _))) = (start, view.last()) {
        out.push(t - s + 0.01);
    }
    out
}

#[test]
fn desktop_keeps_the_target_at_40_to_60_cm_and_in_view() {
    for name in [ScenarioName::DesktopSlow, ScenarioName::DesktopFast] {
        let sc = Scenario::new(name);
        let centre = Vector3::new(-0.02, 0.0, 0.1);
        let (mut lo, mut hi) = (f64::MAX, 0.0f64);
        for i in 0..=(sc.duration() * 100.0) as usize {
            let (c, _) = sc.camera_pose(i as f64 / 100.0);
            let d = (c - centre).norm();
            lo = lo.min(d);
            hi = hi.max(d);
        }
        let view = model_in_view(&sc);
        let min_view = view.iter().map(|v| v.1).fold(1.0, f64::min);
        println!(
            "{name}: camera-target distance {lo:.3}..{hi:.3} m, min share in view {min_view:.2}"
        );
        assert!(lo >= 0.40 && hi <= 0.60, "{name}: {lo}..{hi}");
        assert!(min_view > 0.8, "{name}: {min_view}");
    }
}

#[test]
fn room_has_two_turns_a_close_approach_and_blind_stretches() {
    let sc = Scenario::new(ScenarioName::Room);
    let (mut min_wall, mut inside) = (f64::MAX, true);
    for i in 0..=(sc.duration() * 100.0) as usize {
        let (c, _) = sc.camera_pose(i as f64 / 100.0);
        min_wall = min_wall.min(c.x);
        inside &= c.x > 0.2 && c.x < 4.8 && c.y > 0.2 && c.y < 3.8 && c.z > 0.5 && c.z < 2.4;
    }
    // Two 360° turns: integrate the yaw rate of the world-z component of ω.
    let mut yaw_turned = Vec::new();
    for (a, b) in [(8.0, 14.5), (38.5, 42.5)] {
        let n = 4000;
        let dt = (b - a) / n as f64;
        let turned: f64 = (0..n)
            .map(|i| {
                let k = sc.path.at(a + (i as f64 + 0.5) * dt);
                (k.q_ws * k.omega_s).z * dt
            })
            .sum();
        yaw_turned.push(turned.to_degrees());
    }
    let blind = blind_stretches(&model_in_view(&sc));
    let longest = blind.iter().cloned().fold(0.0, f64::max);
    println!(
        "room: closest to the wall x=0: {min_wall:.2} m; turns {yaw_turned:.0?}°; \
         blind stretches {blind:.2?} s"
    );
    assert!(inside, "the camera leaves the room");
    assert!(min_wall < 0.6, "no close approach: {min_wall}");
    for t in &yaw_turned {
        assert!((t.abs() - 360.0).abs() < 15.0, "turn {t}°");
    }
    // Facing the unmodelled wall during each turn: dead reckoning periods.
    assert!(blind.len() >= 2 && longest > 0.5, "{blind:?}");
    // The occluder crosses in front of the camera while it faces the modelled wall x = 0.
    let occ = &sc.scene.occluders[0];
    let t_mid = occ.start + occ.duration / 2.0;
    let (c, q) = sc.camera_pose(t_mid);
    let (_, o) = occ.pose_at(t_mid);
    let p = q * (o - c);
    assert!(
        p.z > 0.5 && (p.x / p.z).abs() < 0.5,
        "occluder not in view: {p}"
    );
}

#[test]
fn foyer_looks_away_from_the_model_for_at_most_half_a_second() {
    let sc = Scenario::new(ScenarioName::Foyer);
    let blind = blind_stretches(&model_in_view(&sc));
    let longest = blind.iter().cloned().fold(0.0, f64::max);
    println!("foyer: blind stretches {blind:.2?} s");
    assert!(blind.len() >= 4, "{blind:?}");
    assert!((0.25..=0.5).contains(&longest), "{blind:?}");
}

/// Dead reckoning of IMU readings (bias-corrected with the ground-truth biases) by RK4: each
/// step spans two sample intervals and uses the middle sample for the half-step evaluations.
fn dead_reckon(imu: &[euroc::ImuRow], gt: &[euroc::GroundTruthRow]) -> (f64, f64) {
    let g = Vector3::from(GRAVITY_W);
    let g0 = &gt[0];
    let (mut q, mut v, mut p) = (*g0.q_ws.quaternion(), g0.v_w, g0.p_w);
    let f = |q: &Quaternion<f64>, v: &Vector3<f64>, w: &Vector3<f64>, a: &Vector3<f64>| {
        let qd = q * Quaternion::from_imag(*w) * 0.5;
        let vd = UnitQuaternion::from_quaternion(*q) * a + g;
        (qd, vd, *v)
    };
    let (mut ep, mut eq) = (0.0f64, 0.0f64);
    let mut k = 0;
    while k + 2 < imu.len() {
        let h = (imu[k + 2].stamp - imu[k].stamp) as f64 * 1e-9;
        let m = |i: usize| {
            (
                imu[i].gyro - gt[i].gyro_bias,
                imu[i].accel - gt[i].accel_bias,
            )
        };
        let ((w0, a0), (w1, a1), (w2, a2)) = (m(k), m(k + 1), m(k + 2));
        let (q1, v1, p1) = f(&q, &v, &w0, &a0);
        let (q2, v2, p2) = f(&(q + q1 * (h / 2.0)), &(v + v1 * (h / 2.0)), &w1, &a1);
        let (q3, v3, p3) = f(&(q + q2 * (h / 2.0)), &(v + v2 * (h / 2.0)), &w1, &a1);
        let (q4, v4, p4) = f(&(q + q3 * h), &(v + v3 * h), &w2, &a2);
        q = (q + (q1 + q2 * 2.0 + q3 * 2.0 + q4) * (h / 6.0)).normalize();
        v += (v1 + v2 * 2.0 + v3 * 2.0 + v4) * (h / 6.0);
        p += (p1 + p2 * 2.0 + p3 * 2.0 + p4) * (h / 6.0);
        k += 2;
        let truth = &gt[k];
        ep = ep.max((p - truth.p_w).norm());
        eq = eq.max(
            (truth.q_ws.inverse() * UnitQuaternion::from_quaternion(q))
                .angle()
                .to_degrees(),
        );
    }
    (ep, eq)
}

/// With noise off, the written IMU samples integrate back to the written ground truth over
/// each whole scenario: within 1 mm and 0.01°. The IMU runs at 1 kHz for this (the default
/// 100 Hz is too coarse for a 4th-order integrator to reach 1 mm over 45 s of 10 rad/s
/// motion); the integrator steps at 500 Hz (RK4 over pairs of samples). Constant non-zero
/// biases check that the ground-truth bias columns match the readings.
#[test]
fn noise_free_imu_dead_reckons_to_the_ground_truth() {
    for name in ScenarioName::ALL {
        let mut sc = Scenario::new(name).with_rates(1000.0, 40).unwrap();
        sc.imu = sc.imu.without_noise();
        sc.imu.initial_bias_sigma = (0.01, 0.1);
        let dir = tempfile::tempdir().unwrap();
        let data = write_imu_dataset(dir.path(), &sc, 5).unwrap();
        assert!(data.samples[0].reading.gyro_bias.norm() > 1e-3);
        let imu = read_imu_csv(&dir.path().join("mav0/imu0/data.csv")).unwrap();
        let gt =
            read_groundtruth_csv(&dir.path().join("mav0/state_groundtruth_estimate0/data.csv"))
                .unwrap();
        assert_eq!(imu.len(), sc.imu_count());
        assert_eq!(gt.len(), imu.len());
        assert!(imu.iter().zip(&gt).all(|(a, b)| a.stamp == b.stamp));
        let (ep, eq) = dead_reckon(&imu, &gt);
        println!(
            "{name}: {:.0} s at 1 kHz, RK4 at 500 Hz: max position error {:.3} mm, \
             max orientation error {:.2e}°",
            sc.duration(),
            ep * 1e3,
            eq
        );
        assert!(ep < 1e-3 && eq < 0.01, "{name}: {ep} m, {eq}°");
    }
}

/// Overlapping Allan deviation of `x` (sampled every `dt`) at cluster size `m`.
fn allan(x: &[f64], dt: f64, m: usize) -> f64 {
    let mut theta = Vec::with_capacity(x.len() + 1);
    theta.push(0.0);
    for v in x {
        theta.push(theta.last().copied().unwrap_or(0.0) + v * dt);
    }
    let tau = m as f64 * dt;
    let n = theta.len() - 2 * m;
    let s: f64 = (0..n)
        .map(|k| {
            let d = theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k];
            d * d
        })
        .sum();
    (s / (2.0 * tau * tau * n as f64)).sqrt()
}

fn static_scenario(seconds: f64) -> Scenario {
    let mut sc = Scenario::new(ScenarioName::DesktopSlow);
    sc.path.position = Default::default();
    sc.path.attitude = Default::default();
    sc.with_duration(seconds).unwrap()
}

/// A static recording written to `imu0/data.csv` (1000 s at 100 Hz): the Allan deviation at
/// τ = 1 s equals the configured white-noise densities (σ(τ) = N/√τ) within 10 %.
#[test]
fn allan_deviation_at_one_second_matches_the_white_noise_densities() {
    let sc = static_scenario(1000.0);
    let dir = tempfile::tempdir().unwrap();
    write_imu_dataset(dir.path(), &sc, 11).unwrap();
    let imu = read_imu_csv(&dir.path().join("mav0/imu0/data.csv")).unwrap();
    let dt = 1.0 / sc.imu.rate_hz;
    let m = sc.imu.rate_hz.round() as usize;
    for axis in 0..6 {
        let x: Vec<f64> = imu
            .iter()
            .map(|r| {
                if axis < 3 {
                    r.gyro[axis]
                } else {
                    r.accel[axis - 3]
                }
            })
            .collect();
        let want = if axis < 3 {
            sc.imu.noise.gyro_density
        } else {
            sc.imu.noise.accel_density
        };
        // The random walk adds K²τ/3 to the Allan variance; at τ = 1 s it is below 0.1 %.
        let got = allan(&x, dt, m);
        println!("axis {axis}: σ_A(1 s) = {got:.4e}, density {want:.4e}");
        assert!(
            (got / want - 1.0).abs() < 0.10,
            "axis {axis}: {got} vs {want}"
        );
    }
}

/// A long static recording (72 h at 100 Hz of the IMU model, streamed into 0.1 s cluster
/// means to bound memory): fitting σ²(τ) = N²/τ + K²τ/3 over τ = 0.1…2000 s gives both the
/// white-noise and the random-walk densities within 10 % (the walk dominates above ~100 s).
#[test]
fn allan_deviation_fit_matches_the_random_walk_densities() {
    let noise = ImuNoise::MT9;
    let rate = 100.0;
    let per = 10;
    let clusters = 72 * 3600 * 10;
    let still = static_scenario(1.0).path.at(0.0);
    let mut imu = ImuSim::new(noise, rate, Vector3::zeros(), Vector3::zeros(), 23);
    let mut means: Vec<Vec<f64>> = (0..6).map(|_| Vec::with_capacity(clusters)).collect();
    for _ in 0..clusters {
        let mut acc = [0.0; 6];
        for _ in 0..per {
            let r = imu.read(&still);
            for i in 0..3 {
                acc[i] += r.gyro[i];
                acc[i + 3] += r.accel[i];
            }
        }
        for (m, a) in means.iter_mut().zip(acc) {
            m.push(a / per as f64);
        }
    }
    let dt = per as f64 / rate;
    let taus = [0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0, 2000.0];
    for sensor in 0..2 {
        // Pool the three axes: average their Allan variances.
        let avar: Vec<f64> = taus
            .iter()
            .map(|&tau| {
                let m = (tau / dt).round() as usize;
                (0..3)
                    .map(|axis| allan(&means[3 * sensor + axis], dt, m).powi(2))
                    .sum::<f64>()
                    / 3.0
            })
            .collect();
        // Weighted least squares in (N², K²) with relative weights 1/σ⁴.
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (&tau, &v) in taus.iter().zip(&avar) {
            let (x1, x2, w) = (1.0 / tau, tau / 3.0, 1.0 / (v * v));
            a11 += w * x1 * x1;
            a12 += w * x1 * x2;
            a22 += w * x2 * x2;
            b1 += w * x1 * v;
            b2 += w * x2 * v;
        }
        let det = a11 * a22 - a12 * a12;
        let n = ((a22 * b1 - a12 * b2) / det).sqrt();
        let k = ((a11 * b2 - a12 * b1) / det).sqrt();
        let (wn, wk) = if sensor == 0 {
            (noise.gyro_density, noise.gyro_walk)
        } else {
            (noise.accel_density, noise.accel_walk)
        };
        println!(
            "{}: fitted N {n:.4e} (configured {wn:.4e}), K {k:.4e} (configured {wk:.4e})",
            ["gyro", "accel"][sensor]
        );
        assert!((n / wn - 1.0).abs() < 0.10, "N {n} vs {wn}");
        assert!((k / wk - 1.0).abs() < 0.10, "K {k} vs {wk}");
    }
}

#[test]
fn vibration_and_saturation_act_only_where_configured() {
    let sc = Scenario::new(ScenarioName::DesktopFast)
        .with_duration(8.0)
        .unwrap();
    let mut quiet = sc.clone();
    quiet.imu.vibration = None;
    let (a, b) = (simulate_imu(&sc, 3), simulate_imu(&quiet, 3));
    let rms = |from: usize, to: usize| {
        let s: f64 = (from..to)
            .map(|i| (a[i].reading.accel - b[i].reading.accel).norm_squared())
            .sum();
        (s / (to - from) as f64 / 3.0).sqrt()
    };
    // At rest (first second) no vibration; while moving at speed, the configured RMS.
    let (rest, moving) = (rms(0, 100), rms(500, 800));
    println!("vibration RMS per axis: at rest {rest:.3}, moving {moving:.3} m/s²");
    assert_eq!(rest, 0.0);
    assert!((moving / 0.35 - 1.0).abs() < 0.25, "{moving}");
    // Gyro untouched by the vibration.
    assert!(
        a.iter()
            .zip(&b)
            .all(|(x, y)| x.reading.gyro == y.reading.gyro)
    );

    let mut clipped = sc.clone();
    clipped.imu.saturation = Some(Saturation {
        gyro: 1.0,
        accel: 12.0,
    });
    let c = simulate_imu(&clipped, 3);
    assert!(
        c.iter()
            .all(|s| s.reading.gyro.amax() <= 1.0 && s.reading.accel.amax() <= 12.0)
    );
    assert!(c.iter().any(|s| s.reading.gyro.amax() == 1.0));
}

#[test]
fn same_seed_same_data_other_seed_other_noise() {
    let sc = Scenario::new(ScenarioName::Room)
        .with_duration(2.0)
        .unwrap();
    let (a, b, c) = (
        simulate_imu(&sc, 1),
        simulate_imu(&sc, 1),
        simulate_imu(&sc, 2),
    );
    assert_eq!(a, b);
    assert_ne!(a[10].reading, c[10].reading);
    assert_eq!(a[10].truth, c[10].truth);
}

#[test]
fn bad_parameters_are_errors() {
    let sc = Scenario::new(ScenarioName::Foyer);
    assert!(sc.clone().with_duration(0.0).is_err());
    assert!(sc.clone().with_duration(f64::NAN).is_err());
    assert!(sc.clone().with_duration(1e9).is_err());
    assert!(sc.clone().with_rates(0.5, 4).is_err());
    assert!(sc.clone().with_rates(100.0, 0).is_err());
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not_a_folder");
    std::fs::write(&file, "x").unwrap();
    let err = write_imu_dataset(&file, &sc.with_duration(0.1).unwrap(), 1).unwrap_err();
    assert!(err.to_string().contains("not_a_folder"), "{err}");
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "#h\n1,2,3\n").unwrap();
    assert!(matches!(
        read_imu_csv(&bad),
        Err(euroc::DatasetError::Parse { line: 2, .. })
    ));
}
