//! Camera model: distortion round trips over whole images, undistortion map vs the point
//! formula, calibration files.

use std::path::Path;

use host_vision::camera::{
    Camera, CameraPose, Distortion, Gray32FImage, Pinhole, UndistortMap, read_euroc_sensor_yaml,
    read_kalibr_camchain,
};
use nalgebra::{Vector2, Vector3};

/// EuRoC-like radial-tangential camera (752×480, strong barrel distortion).
fn radtan_camera() -> Camera {
    Camera::new(
        752,
        480,
        Pinhole::new(458.0, 457.0, 367.0, 248.0).with_skew(0.4),
        Distortion::RadTan {
            k1: -0.28,
            k2: 0.074,
            p1: 0.0002,
            p2: 1.8e-5,
            k3: 0.0,
        },
    )
    .unwrap()
}

/// TUM-VI-like equidistant fisheye (512×512, ~190° wide lens).
fn equidistant_camera() -> Camera {
    Camera::new(
        512,
        512,
        Pinhole::new(190.97, 190.98, 254.93, 256.90),
        Distortion::Equidistant {
            k1: 0.0034823,
            k2: 0.0007150,
            k3: -0.0020532,
            k4: 0.0002029,
        },
    )
    .unwrap()
}

/// Max over every pixel of the image of |undistort(distort(p)) − p| and
/// |distort(undistort(q)) − q| in pixels. A fisheye's corners see rays beyond 90° that no
/// pinhole image holds: there undistortion must say so (`None`) instead.
fn round_trip_errors(cam: &Camera) -> (f64, f64) {
    let (mut ideal_err, mut distorted_err) = (0.0f64, 0.0f64);
    // Distorted radius of a ray 86° off axis.
    let r_86 = cam
        .distortion
        .distort(Vector2::new(1.5f64.tan(), 0.0))
        .norm();
    for v in 0..cam.height {
        for u in 0..cam.width {
            let p = Vector2::new(u as f64, v as f64);
            // p as an ideal pixel: distort then undistort.
            let back = cam
                .undistort_pixel(cam.distort_pixel(p))
                .expect("invertible");
            ideal_err = ideal_err.max((back - p).norm());
            // p as a distorted (recorded) pixel: undistort then distort.
            let Some(ideal) = cam.undistort_pixel(p) else {
                let r = cam.pinhole.to_normalised(p).norm();
                assert!(r > r_86, "({u}, {v}) not invertible at radius {r}");
                continue;
            };
            distorted_err = distorted_err.max((cam.distort_pixel(ideal) - p).norm());
        }
    }
    (ideal_err, distorted_err)
}

#[test]
fn radtan_round_trip_below_1e6_px_over_the_image() {
    let (a, b) = round_trip_errors(&radtan_camera());
    println!("radtan: max |u(d(p)) − p| = {a:.2e} px, max |d(u(q)) − q| = {b:.2e} px");
    assert!(a < 1e-6 && b < 1e-6);
}

#[test]
fn equidistant_round_trip_below_1e6_px_over_the_image() {
    let (a, b) = round_trip_errors(&equidistant_camera());
    println!("equidistant: max |u(d(p)) − p| = {a:.2e} px, max |d(u(q)) − q| = {b:.2e} px");
    assert!(a < 1e-6 && b < 1e-6);
}

#[test]
fn projection_matches_k_and_normalised_round_trip() {
    let cam = radtan_camera().ideal();
    let p_c = Vector3::new(0.2, -0.1, 1.5);
    let px = cam.project(p_c).unwrap();
    let k = cam.pinhole.k();
    let h = k * (p_c / p_c.z);
    assert!((px - h.xy()).norm() < 1e-12);
    let n = cam.pixel_to_normalised(px).unwrap();
    assert!((n - Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z)).norm() < 1e-14);
    assert!(cam.project(Vector3::new(0.0, 0.0, -1.0)).is_none());
}

#[test]
fn undistortion_map_agrees_with_point_formula() {
    for cam in [radtan_camera(), equidistant_camera()] {
        let map = UndistortMap::new(&cam).unwrap();
        let mut max_err = 0.0f64;
        let mut valid = 0usize;
        for v in 0..cam.height {
            for u in 0..cam.width {
                let ideal = Vector2::new(u as f64, v as f64);
                let want = cam.distort_pixel(ideal);
                match map.source_of(u, v) {
                    Some([x, y]) => {
                        valid += 1;
                        max_err = max_err.max((Vector2::new(x as f64, y as f64) - want).norm());
                    }
                    None => assert!(
                        want.x < 0.0
                            || want.y < 0.0
                            || want.x > (cam.width - 1) as f64
                            || want.y > (cam.height - 1) as f64,
                        "({u}, {v}) marked outside but maps to {want:?}"
                    ),
                }
            }
        }
        println!(
            "{:?}: map vs formula max {max_err:.2e} px over {valid} px",
            cam.distortion
        );
        // f32 storage of coordinates below 1000 px.
        assert!(max_err < 1e-4);
        assert!(valid > (cam.width * cam.height / 2) as usize);

        // Remapping an affine image is exact for bilinear interpolation, so the rectified
        // value must be the affine function at the formula's source point.
        let src = Gray32FImage::from_fn(cam.width, cam.height, |x, y| {
            image::Luma([0.5 * x as f32 + 0.25 * y as f32 + 3.0])
        });
        let out = map.remap_f32(&src).unwrap();
        let mut max_val_err = 0.0f64;
        for v in (0..cam.height).step_by(3) {
            for u in (0..cam.width).step_by(3) {
                if map.source_of(u, v).is_none() {
                    assert_eq!(out.get_pixel(u, v).0[0], 0.0);
                    continue;
                }
                let s = cam.distort_pixel(Vector2::new(u as f64, v as f64));
                let want = 0.5 * s.x + 0.25 * s.y + 3.0;
                max_val_err = max_val_err.max((out.get_pixel(u, v).0[0] as f64 - want).abs());
            }
        }
        assert!(max_val_err < 2e-3, "remap error {max_val_err}");
    }
}

#[test]
fn undistortion_map_rejects_wrong_source_size() {
    let cam = radtan_camera();
    let map = UndistortMap::new(&cam).unwrap();
    assert!(map.remap_gray(&image::GrayImage::new(10, 10)).is_err());
    let gray = map.remap_gray(&image::GrayImage::new(752, 480)).unwrap();
    assert_eq!(gray.dimensions(), (752, 480));
}

#[test]
fn bad_cameras_are_errors() {
    let k = Pinhole::new(-1.0, 1.0, 0.0, 0.0);
    assert!(Camera::new(10, 10, k, Distortion::None).is_err());
    let k = Pinhole::new(100.0, 100.0, 5.0, 5.0);
    assert!(Camera::new(0, 10, k, Distortion::None).is_err());
    let nan = Distortion::RadTan {
        k1: f64::NAN,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        k3: 0.0,
    };
    assert!(Camera::new(10, 10, k, nan).is_err());
}

#[test]
fn look_at_points_the_optical_axis_at_the_target() {
    let eye = Vector3::new(1.0, -2.0, 1.5);
    let target = Vector3::new(0.1, 0.2, 0.0);
    let pose = CameraPose::look_at(eye, target, Vector3::z()).unwrap();
    let t_c = pose.world_to_camera(&target);
    assert!(t_c.x.abs() < 1e-12 && t_c.y.abs() < 1e-12 && t_c.z > 0.0);
    // World up appears up in the image (negative camera y).
    let above = pose.world_to_camera(&(target + Vector3::z() * 0.1));
    assert!(above.y < 0.0);
    let back = pose.camera_to_world(&t_c);
    assert!((back - target).norm() < 1e-12);
    // The [w, x, y, z] constructor round-trips.
    let q = pose.q_cw.quaternion();
    let again = CameraPose::from_wxyz([q.w, q.i, q.j, q.k], eye).unwrap();
    assert!((again.world_to_camera(&target) - t_c).norm() < 1e-12);
    assert!(CameraPose::look_at(eye, eye, Vector3::z()).is_err());
}

const EUROC_LIKE: &str = "%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: test camera

T_BS:
  cols: 4
  rows: 4
  data: [0.0, -1.0, 0.0, 0.1,
         1.0, 0.0, 0.0, -0.2,
         0.0, 0.0, 1.0, 0.3,
         0.0, 0.0, 0.0, 1.0]

rate_hz: 20
resolution: [640, 400]
camera_model: pinhole
intrinsics: [400.5, 401.25, 320.75, 199.5] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.25, 0.07, 0.0002, -0.00003]
";

const CAMCHAIN: &str = "cam0:
  T_cam_imu:
  - [0.0, 1.0, 0.0, 0.05]
  - [-1.0, 0.0, 0.0, 0.01]
  - [0.0, 0.0, 1.0, -0.02]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [0.003, 0.0007, -0.002, 0.0002]
  distortion_model: equidistant
  intrinsics: [190.9, 190.8, 254.9, 256.8]
  resolution: [512, 512]
  rostopic: /cam0/image_raw
  timeshift_cam_imu: 0.0012
cam1:
  camera_model: pinhole
  distortion_coeffs: [-0.28, 0.07, 0.0001, 0.00002]
  distortion_model: radtan
  intrinsics: [457.5, 456.1, 379.9, 255.2]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
";

#[test]
fn reads_euroc_sensor_yaml() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sensor.yaml");
    std::fs::write(&path, EUROC_LIKE).unwrap();
    let c = read_euroc_sensor_yaml(&path).unwrap();
    assert_eq!((c.camera.width, c.camera.height), (640, 400));
    assert_eq!(c.camera.pinhole, Pinhole::new(400.5, 401.25, 320.75, 199.5));
    assert_eq!(
        c.camera.distortion,
        Distortion::RadTan {
            k1: -0.25,
            k2: 0.07,
            p1: 0.0002,
            p2: -0.00003,
            k3: 0.0
        }
    );
    let t = c.extrinsics.unwrap();
    assert_eq!((t[(0, 1)], t[(0, 3)], t[(2, 3)]), (-1.0, 0.1, 0.3));
    assert_eq!(c.rate_hz, Some(20.0));

    // Broken files are typed errors, not panics.
    std::fs::write(&path, EUROC_LIKE.replace("[640, 400]", "[640]")).unwrap();
    let e = read_euroc_sensor_yaml(&path).unwrap_err().to_string();
    assert!(e.contains("resolution"), "{e}");
    std::fs::write(&path, EUROC_LIKE.replace("pinhole", "omni")).unwrap();
    assert!(read_euroc_sensor_yaml(&path).is_err());
    std::fs::write(&path, "intrinsics: [1, 2").unwrap();
    assert!(read_euroc_sensor_yaml(&path).is_err());
    assert!(read_euroc_sensor_yaml(&dir.path().join("absent.yaml")).is_err());
}

#[test]
fn reads_kalibr_camchain() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("camchain.yaml");
    std::fs::write(&path, CAMCHAIN).unwrap();
    let cams = read_kalibr_camchain(&path).unwrap();
    assert_eq!(cams.len(), 2);
    assert_eq!(cams[0].name, "cam0");
    assert!(matches!(
        cams[0].camera.distortion,
        Distortion::Equidistant { .. }
    ));
    assert_eq!(cams[0].timeshift_cam_imu, Some(0.0012));
    assert_eq!(cams[0].extrinsics.unwrap()[(1, 0)], -1.0);
    assert!(matches!(
        cams[1].camera.distortion,
        Distortion::RadTan { .. }
    ));
    assert!(cams[1].extrinsics.is_none());
}

/// The real EuRoC files of the shared data folder, when present (never copied here).
#[test]
fn reads_shared_euroc_files_when_present() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    let files = [
        root.join("euroc-v101-micro/mav0/cam0/sensor.yaml"),
        root.join("euroc-imu-april/cam1-sensor.yaml"),
    ];
    for f in files {
        if !f.is_file() {
            eprintln!(
                "note: {} absent, skipping this real-data check",
                f.display()
            );
            continue;
        }
        let c = read_euroc_sensor_yaml(&f).unwrap();
        assert_eq!((c.camera.width, c.camera.height), (752, 480));
        assert!(matches!(c.camera.distortion, Distortion::RadTan { .. }));
        let (a, b) = round_trip_errors(&c.camera);
        println!("{}: round trips {a:.2e} / {b:.2e} px", f.display());
        assert!(a < 1e-6 && b < 1e-6);
    }
}
