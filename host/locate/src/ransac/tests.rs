//! Tests of [`super`] (`ransac.rs`).

use super::super::p3p::tests::random_rotation;
use super::*;

/// A 1280×960 camera, 65° horizontal field of view.
const PINHOLE: [f64; 4] = [1000.0, 1000.0, 640.0, 480.0];
const SIZE: [f64; 2] = [1280.0, 960.0];

fn gauss(rng: &mut StdRng) -> f64 {
    use rand_distr::{Distribution, StandardNormal};
    StandardNormal.sample(rng)
}

/// An object about 1 m in front of a 640×480 camera, filling most of the view (points at
/// 0.6..1.4 m depth over the image), the world frame at a random rotation. The first `n_in`
/// matches are true with `noise_px` Gaussian noise, the rest random pixels.
/// Returns (pixels, world points, true q_cw, true t).
type Scene = (
    Vec<Vector2<f64>>,
    Vec<Vector3<f64>>,
    UnitQuaternion<f64>,
    Vector3<f64>,
);

fn scene(rng: &mut StdRng, n: usize, n_in: usize, noise_px: f64) -> Scene {
    let cam = Pinhole {
        fx: PINHOLE[0],
        fy: PINHOLE[1],
        cx: PINHOLE[2],
        cy: PINHOLE[3],
    };
    let q = random_rotation(rng);
    // The world origin (object centre) sits about 1 m ahead.
    let t = Vector3::new(
        rng.random_range(-0.05..0.05),
        rng.random_range(-0.05..0.05),
        1.0,
    );
    let mut u = Vec::with_capacity(n);
    let mut x = Vec::with_capacity(n);
    for i in 0..n {
        let pix = Vector2::new(
            rng.random_range(20.0..SIZE[0] - 20.0),
            rng.random_range(20.0..SIZE[1] - 20.0),
        );
        let xc = cam.bearing(&pix) / cam.bearing(&pix).z * rng.random_range(0.6..1.4);
        let xw = q.inverse() * (xc - t);
        let px = if i < n_in {
            cam.project(&(q * xw + t)) + Vector2::new(gauss(rng), gauss(rng)) * noise_px
        } else {
            Vector2::new(
                rng.random_range(0.0..SIZE[0]),
                rng.random_range(0.0..SIZE[1]),
            )
        };
        u.push(px);
        x.push(xw);
    }
    (u, x, q, t)
}

fn errors(p: &RansacPose, q: &UnitQuaternion<f64>, t: &Vector3<f64>) -> (f64, f64) {
    let dt = (p.t - t).norm();
    // Angle from the matrix difference: accurate for small angles, unlike acos.
    let dr = (p.q_cw.to_rotation_matrix().into_inner() - q.to_rotation_matrix().into_inner())
        .norm()
        / 2f64.sqrt();
    (dt, dr.to_degrees())
}

#[test]
fn recovers_pose_with_70_percent_outliers() {
    let cfg = RansacConfig::default();
    let (mut worst_t, mut worst_r, mut total_it, mut max_it) = (0.0f64, 0.0f64, 0, 0);
    let mut worst_oracle = 0.0f64;
    let trials = 20;
    for s in 0..trials {
        let mut rng = StdRng::seed_from_u64(1000 + s);
        let (u, x, q, t) = scene(&mut rng, 200, 60, 0.5);
        let (Some(p), stats) = ransac_search(PINHOLE, &u, &x, &cfg) else {
            panic!("scene {s}: no pose");
        };
        let (dt, dr) = errors(&p, &q, &t);
        // The oracle: least squares on the true inliers from the true pose. 0.05° is close to
        // this scene's statistical limit, so also check RANSAC reaches the oracle's accuracy.
        let cam = Pinhole {
            fx: PINHOLE[0],
            fy: PINHOLE[1],
            cx: PINHOLE[2],
            cy: PINHOLE[3],
        };
        let truth: Vec<bool> = (0..200).map(|i| i < 60).collect();
        let (qo, to) = refine(&cam, &u, &x, &truth, q, t).unwrap_or((q, t));
        let (qo, to) = refine(&cam, &u, &x, &truth, qo, to).unwrap_or((qo, to));
        let (dt_o, dr_o) = errors(&p, &qo, &to);
        assert!(
            dt_o < 5e-5 && dr_o < 5e-3,
            "scene {s}: {dt_o:e} m, {dr_o}° from the oracle"
        );
        worst_oracle = worst_oracle.max(dr_o);
        assert!(dt < 1e-3, "scene {s}: translation error {dt:e} m");
        assert!(dr < 0.05, "scene {s}: rotation error {dr}°");
        let true_in = p.inliers[..60].iter().filter(|b| **b).count();
        let false_in = p.inliers[60..].iter().filter(|b| **b).count();
        assert!(true_in >= 57, "scene {s}: {true_in}/60 true inliers");
        assert!(false_in <= 2, "scene {s}: {false_in} outliers accepted");
        worst_t = worst_t.max(dt);
        worst_r = worst_r.max(dr);
        total_it += stats.iterations;
        max_it = max_it.max(stats.iterations);
    }
    println!(
        "ransac 200 matches, 70% outliers, 0.5 px: worst |t-t*| {:.3} mm, worst rot {:.4}°, \
         iterations mean {:.0} max {max_it} (w³ bound {}), worst rot from oracle {worst_oracle:.1e}°",
        worst_t * 1e3,
        worst_r,
        total_it as f64 / trials as f64,
        samples_needed(0.999, 0.3).unwrap_or(0)
    );
    // Performance sanity: the adaptive stop must kick in well before the cap.
    assert!(max_it < 1000, "too many iterations: {max_it}");
}

#[test]
fn clean_data_stops_early_and_is_exact() {
    let mut rng = StdRng::seed_from_u64(7);
    let (u, x, q, t) = scene(&mut rng, 100, 100, 0.0);
    let (p, stats) = ransac_search(PINHOLE, &u, &x, &RansacConfig::default());
    let Some(p) = p else { panic!("no pose") };
    let (dt, dr) = errors(&p, &q, &t);
    println!(
        "clean: {} iterations, |t-t*| {dt:.2e} m, rot {dr:.2e}°",
        stats.iterations
    );
    assert!(stats.iterations <= 5);
    assert!(dt < 1e-9 && dr < 1e-7);
    assert!(p.inliers.iter().all(|b| *b));
}

#[test]
fn pure_outliers_and_too_few_return_none() {
    let mut rng = StdRng::seed_from_u64(8);
    let cfg = RansacConfig::default();
    let (u, x, _, _) = scene(&mut rng, 200, 0, 0.0);
    let r = ransac_pose(PINHOLE, &u, &x, &cfg);
    assert!(
        r.is_none(),
        "pure outliers gave {:?} inliers",
        r.map(|p| p.inliers.iter().filter(|b| **b).count())
    );

    let (u, x, _, _) = scene(&mut rng, 3, 3, 0.0);
    assert!(ransac_pose(PINHOLE, &u, &x, &cfg).is_none());
    let (u, x, _, _) = scene(&mut rng, 20, 20, 0.0);
    assert!(ransac_pose(PINHOLE, &u, &x[..19], &cfg).is_none());
    assert!(ransac_pose(PINHOLE, &[], &[], &cfg).is_none());
    // Fewer inliers than asked for.
    let strict = RansacConfig {
        min_inliers: 21,
        ..cfg
    };
    assert!(ransac_pose(PINHOLE, &u, &x, &strict).is_none());
    assert!(ransac_pose(PINHOLE, &u, &x, &cfg).is_some());
}

#[test]
fn hostile_inputs_do_not_panic() {
    let mut rng = StdRng::seed_from_u64(9);
    let cfg = RansacConfig::default();
    let (mut u, mut x, q, t) = scene(&mut rng, 60, 40, 0.3);
    // A few NaN / infinite pixels and points among good matches: still a good pose.
    u[0].x = f64::NAN;
    u[1].y = f64::INFINITY;
    x[2].z = f64::NAN;
    let p = ransac_pose(PINHOLE, &u, &x, &cfg);
    let Some(p) = p else { panic!("no pose") };
    assert!(!p.inliers[0] && !p.inliers[1] && !p.inliers[2]);
    let (dt, dr) = errors(&p, &q, &t);
    assert!(dt < 2e-3 && dr < 0.1);

    // Everything NaN, all points identical, all pixels identical, bad intrinsics.
    let nan_u = vec![Vector2::new(f64::NAN, f64::NAN); 50];
    assert!(ransac_pose(PINHOLE, &nan_u, &x[..50], &cfg).is_none());
    let same_x = vec![Vector3::new(0.1, 0.2, 0.3); 50];
    assert!(ransac_pose(PINHOLE, &u[..50], &same_x, &cfg).is_none());
    let same_u = vec![Vector2::new(640.0, 480.0); 50];
    let _ = ransac_pose(PINHOLE, &same_u, &x[..50], &cfg);
    // Duplicated matches (each match four times).
    let (u2, x2): (Vec<_>, Vec<_>) = u[3..]
        .iter()
        .zip(&x[3..])
        .flat_map(|(a, b)| [(*a, *b); 4])
        .unzip();
    let p = ransac_pose(PINHOLE, &u2, &x2, &cfg);
    assert!(p.is_some_and(|p| errors(&p, &q, &t).0 < 2e-3));
    for bad in [
        [0.0, 1e3, 640.0, 480.0],
        [f64::NAN, 1e3, 640.0, 480.0],
        [1e3, 1e3, f64::INFINITY, 480.0],
    ] {
        assert!(ransac_pose(bad, &u, &x, &cfg).is_none());
    }
    for thr in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(
            ransac_pose(
                PINHOLE,
                &u,
                &x,
                &RansacConfig {
                    threshold_px: thr,
                    ..cfg
                }
            )
            .is_none()
        );
    }
    // Zero iterations, odd confidences, huge min_inliers.
    assert!(
        ransac_pose(
            PINHOLE,
            &u,
            &x,
            &RansacConfig {
                max_iterations: 0,
                ..cfg
            }
        )
        .is_none()
    );
    for conf in [0.0, 1.0, -3.0, f64::NAN, 2.0] {
        let c = RansacConfig {
            confidence: conf,
            max_iterations: 300,
            ..cfg
        };
        let _ = ransac_pose(PINHOLE, &u, &x, &c);
    }
    let c = RansacConfig {
        min_inliers: usize::MAX,
        ..cfg
    };
    assert!(ransac_pose(PINHOLE, &u, &x, &c).is_none());
    // Points behind the camera only.
    let behind: Vec<Vector3<f64>> = x.iter().map(|v| q.inverse() * (-(q * v + t))).collect();
    let _ = ransac_pose(PINHOLE, &u, &behind, &cfg);
}

#[test]
fn deterministic_for_a_seed() {
    let mut rng = StdRng::seed_from_u64(10);
    let (u, x, _, _) = scene(&mut rng, 200, 60, 0.5);
    let cfg = RansacConfig::default();
    let (a, a_stats) = ransac_search(PINHOLE, &u, &x, &cfg);
    let (b, b_stats) = ransac_search(PINHOLE, &u, &x, &cfg);
    let (Some(a), Some(b)) = (a, b) else {
        panic!("no pose")
    };
    assert_eq!(a_stats, b_stats);
    assert_eq!(a.inliers, b.inliers);
    assert_eq!(a.t, b.t);
}

#[test]
fn iteration_count_follows_inlier_ratio() {
    // Performance sanity without timing: samples drawn versus the theoretical bound.
    let cfg = RansacConfig::default();
    for (n_in, bound) in [(200usize, 10usize), (100, 120), (60, 1000)] {
        let mut total = 0;
        for s in 0..10 {
            let mut rng = StdRng::seed_from_u64(2000 + s);
            let (u, x, _, _) = scene(&mut rng, 200, n_in, 0.5);
            let (Some(_), stats) = ransac_search(PINHOLE, &u, &x, &cfg) else {
                panic!("no pose")
            };
            assert!(
                stats.iterations <= bound,
                "{n_in} inliers: {} iterations",
                stats.iterations
            );
            total += stats.iterations;
        }
        println!(
            "inlier ratio {:.2}: mean iterations {:.1}, theory {}",
            n_in as f64 / 200.0,
            total as f64 / 10.0,
            samples_needed(0.999, n_in as f64 / 200.0).unwrap_or(0)
        );
    }
    assert_eq!(samples_needed(0.999, 1.0), Some(1));
    assert_eq!(samples_needed(0.999, 0.0), None);
    assert_eq!(samples_needed(1.0, 0.5), None);
}

#[test]
fn a_plane_tilted_the_other_way_looks_alike_and_a_frontal_one_has_no_mirror() {
    let cam = Pinhole {
        fx: PINHOLE[0],
        fy: PINHOLE[1],
        cx: PINHOLE[2],
        cy: PINHOLE[3],
    };
    // A 10 cm square in the world's z = 0 plane, 1 m ahead, tilted 20° about x.
    let square: Vec<Vector3<f64>> = (0..25)
        .map(|k| {
            Vector3::new(
                0.025 * f64::from(k % 5) - 0.05,
                0.025 * f64::from(k / 5) - 0.05,
                0.0,
            )
        })
        .collect();
    let q = UnitQuaternion::from_euler_angles(20f64.to_radians(), 0.0, 0.0);
    let t = Vector3::new(0.0, 0.0, 1.0);
    let Some((q2, t2)) = mirrored_pose(&q, &t, &square) else {
        panic!("no mirror")
    };
    let turned = q2.angle_to(&q).to_degrees();
    let worst = square
        .iter()
        .map(|x| (cam.project(&(q * x + t)) - cam.project(&(q2 * x + t2))).norm())
        .fold(0.0, f64::max);
    println!("mirror: {turned:.1}° away, images {worst:.2} px apart at most");
    // The tilt reversed (twice 20°), the image the same to a few pixels of the square's
    // 100 px: only the perspective's second order tells them apart.
    assert!((turned - 40.0).abs() < 1.0, "{turned}°");
    assert!(worst < 3.0, "{worst} px");
    // The centroid stays where it was.
    let c = |q: &UnitQuaternion<f64>, t: &Vector3<f64>| {
        square.iter().map(|x| q * x + t).sum::<Vector3<f64>>() / 25.0
    };
    assert!((c(&q, &t) - c(&q2, &t2)).norm() < 1e-9);
    // Face on, the two tilts are one pose; too few points, no plane.
    let frontal = UnitQuaternion::identity();
    assert!(mirrored_pose(&frontal, &t, &square).is_none());
    assert!(mirrored_pose(&q, &t, &square[..2]).is_none());
}

#[test]
fn runners_up_are_other_poses() {
    let mut rng = StdRng::seed_from_u64(12);
    let (u, x, q, _) = scene(&mut rng, 200, 60, 0.5);
    let Some(p) = ransac_pose(PINHOLE, &u, &x, &RansacConfig::default()) else {
        panic!("no pose")
    };
    assert!(p.runners_up.len() <= RUNNERS_UP);
    for (k, (qa, _)) in p.runners_up.iter().enumerate() {
        assert!(
            qa.angle_to(&p.q_cw) >= DISTINCT_RAD,
            "runner-up {k} is the best"
        );
        for (qb, _) in &p.runners_up[k + 1..] {
            assert!(
                qa.angle_to(qb) >= DISTINCT_RAD,
                "two runners-up are one pose"
            );
        }
    }
    assert!(p.q_cw.angle_to(&q) < 0.05f64.to_radians());
}

#[test]
fn samples_are_distinct() {
    // The three-index draw must never repeat an index (checked on small m).
    let mut rng = StdRng::seed_from_u64(11);
    for m in 3..8usize {
        let mut hits = vec![0usize; m];
        for _ in 0..3000 {
            let [i0, i1, i2] = draw3(&mut rng, m);
            assert!(i0 != i1 && i1 != i2 && i0 != i2 && i0 < m && i1 < m && i2 < m);
            for i in [i0, i1, i2] {
                hits[i] += 1;
            }
        }
        // Uniform: each index in about 3/m of the draws.
        let expect = 9000.0 / m as f64;
        assert!(
            hits.iter()
                .all(|&h| (h as f64 - expect).abs() < 0.1 * expect),
            "{hits:?}"
        );
    }
}
