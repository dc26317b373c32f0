//! The calibration and pose readers on arbitrary and mutated files (issue 40): a camera or pose
//! whose every number is usable, or a typed error; never a panic. The cargo-fuzz targets in
//! `../fuzz` run the same parsers for longer.

use std::path::Path;

use camera::start_pose::{StartPoseError, parse_start_pose};
use camera::{
    CalibError, CameraCalib, parse_camera_json, parse_euroc_sensor_yaml, parse_intrinsics,
    parse_kalibr_camchain,
};
use proptest::prelude::*;

const SENSOR_YAML: &str = "%YAML:1.0
sensor_type: camera
comment: test cam0
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
  camera_model: pinhole
  distortion_coeffs: [0.003, 0.0007, -0.002, 0.0002]
  distortion_model: equidistant
  intrinsics: [190.9, 190.8, 254.9, 256.8]
  resolution: [512, 512]
  timeshift_cam_imu: 0.0012
cam1:
  camera_model: pinhole
  distortion_coeffs: [-0.28, 0.07, 0.0001, 0.00002]
  distortion_model: radtan
  intrinsics: [457.5, 456.1, 379.9, 255.2]
  resolution: [752, 480]
";

const CAMERA_JSON: &str = r#"{"model": "pinhole", "width": 640, "height": 480, "fx": 605.1,
 "fy": 604.8, "cx": 325.5, "cy": 244.9, "distortion": "none", "source": "test"}"#;

const POSE_JSON: &str = r#"{"cMo": [
 [0.007025480670922024, 0.9958552420364798, 0.09068064583916036, 0.07737004807689539],
 [0.9904134436131532, -0.019440187918363216, 0.13675997149763425, 0.020997510711007653],
 [0.13795598331235054, 0.08885052617831513, -0.98644499627002, 0.4141806089640929],
 [0.0, 0.0, 0.0, 1.0]], "frame": 0}"#;

const TUM: &str = "# t tx ty tz qx qy qz qw\n12.5 0.4 -0.2 1.3 0.1 0.2 0.3 0.9273618495495704\n";

/// The shared data's real files, when the folder is there.
fn real(file: &str) -> Option<String> {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/data")
            .join(file),
    )
    .ok()
}

/// Bit flips, truncations, insertions and overwrites with bytes that matter to YAML/JSON.
fn mutated(seed: String) -> impl Strategy<Value = String> {
    fuzz_support::mutated(seed.into_bytes(), b"0-9.,:[]{} \n&*e")
        .prop_map(|b| String::from_utf8_lossy(&b).into_owned())
}

/// Every number of an accepted calibration is usable.
fn sound(c: &CameraCalib) {
    let cam = &c.camera;
    assert!(cam.width > 0 && cam.height > 0 && cam.width <= camera::MAX_IMAGE_SIDE);
    assert!(cam.pinhole.validate().is_ok());
    assert!(cam.distortion.is_finite());
    assert!(c.extrinsics.is_none_or(|m| m.iter().all(|v| v.is_finite())));
    assert!(c.rate_hz.is_none_or(|r| r.is_finite() && r > 0.0));
    assert!(c.timeshift_cam_imu.is_none_or(f64::is_finite));
}

fn all_calibrations(text: &str) {
    let p = Path::new("fuzz.yaml");
    if let Ok(c) = parse_euroc_sensor_yaml(text, p) {
        sound(&c);
    }
    if let Ok(cams) = parse_kalibr_camchain(text, p) {
        cams.iter().for_each(sound);
    }
    if let Ok(c) = parse_camera_json(text, p) {
        assert!(c.pinhole.validate().is_ok() && c.width > 0 && c.height > 0);
    }
}

fn pose(text: &str) {
    if let Ok(p) = parse_start_pose(text) {
        assert!(p.c_w.iter().all(|v| v.is_finite()));
        assert!(p.q_cw.coords.iter().all(|v| v.is_finite()));
    }
    if let Ok(p) = parse_intrinsics(text) {
        assert!(p.validate().is_ok());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_text(text in any::<String>()) {
        all_calibrations(&text);
        pose(&text);
    }

    #[test]
    fn sensor_yaml_mutated(text in mutated(SENSOR_YAML.into())) {
        all_calibrations(&text);
    }

    #[test]
    fn camchain_mutated(text in mutated(CAMCHAIN.into())) {
        all_calibrations(&text);
    }

    #[test]
    fn camera_json_mutated(text in mutated(CAMERA_JSON.into())) {
        all_calibrations(&text);
    }

    #[test]
    fn pose_mutated(text in mutated(POSE_JSON.into())) {
        pose(&text);
    }

    #[test]
    fn tum_mutated(text in mutated(TUM.into())) {
        pose(&text);
    }

    #[test]
    fn real_files_mutated(which in 0usize..4, text in mutated(String::new()), cut in any::<prop::sample::Index>()) {
        let file = ["euroc-v101-micro/mav0/cam0/sensor.yaml", "euroc-imu-april/cam1-sensor.yaml",
            "visp-cube/camera.json", "visp-cube/frame0_pose.json"][which];
        let Some(seed) = real(file) else { return Ok(()) };
        // The mutation of the empty string, spliced into the real file.
        let at = cut.index(seed.len() + 1);
        let at = (0..=at).rev().find(|&i| seed.is_char_boundary(i)).unwrap_or(0);
        let spliced = format!("{}{text}{}", &seed[..at], &seed[at..]);
        all_calibrations(&spliced);
        pose(&spliced);
    }
}

#[test]
fn the_seeds_parse() {
    let p = Path::new("seed");
    sound(&parse_euroc_sensor_yaml(SENSOR_YAML, p).unwrap());
    assert_eq!(parse_kalibr_camchain(CAMCHAIN, p).unwrap().len(), 2);
    parse_camera_json(CAMERA_JSON, p).unwrap();
    parse_start_pose(POSE_JSON).unwrap();
    parse_start_pose(TUM).unwrap();
    if let Some(t) = real("euroc-v101-micro/mav0/cam0/sensor.yaml") {
        sound(&parse_euroc_sensor_yaml(&t, p).unwrap());
    }
    if let Some(t) = real("visp-cube/frame0_pose.json") {
        parse_start_pose(&t).unwrap();
    }
}

#[test]
fn a_yaml_matrix_of_15_entries_is_refused_by_name() {
    let text = SENSOR_YAML.replace("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 1.0]");
    let e = parse_euroc_sensor_yaml(&text, Path::new("s.yaml")).unwrap_err();
    assert!(e.to_string().contains("with 15"), "{e}");
}

#[test]
fn non_finite_extrinsics_rates_and_shifts_are_refused() {
    let p = Path::new("s.yaml");
    let text = SENSOR_YAML.replace("0.0, -1.0, 0.0, 0.1", "0.0, -1.0, 0.0, .nan");
    let e = parse_euroc_sensor_yaml(&text, p).unwrap_err();
    assert!(
        matches!(e, CalibError::Invalid { .. }) && e.to_string().contains("T_BS"),
        "{e}"
    );
    let text = SENSOR_YAML.replace("rate_hz: 20", "rate_hz: .inf");
    let e = parse_euroc_sensor_yaml(&text, p).unwrap_err();
    assert!(e.to_string().contains("rate_hz"), "{e}");
    let text = CAMCHAIN.replace("[0.0, 1.0, 0.0, 0.05]", "[0.0, 1.0, 0.0, .inf]");
    let e = parse_kalibr_camchain(&text, p).unwrap_err();
    assert!(e.to_string().contains("cam0: T_cam_imu"), "{e}");
    let text = CAMCHAIN.replace("0.0012", ".nan");
    let e = parse_kalibr_camchain(&text, p).unwrap_err();
    assert!(e.to_string().contains("timeshift_cam_imu"), "{e}");
}

#[test]
fn a_tum_line_with_nan_is_refused() {
    let e = parse_start_pose("0 NaN 0 0 0 0 0 1").unwrap_err();
    assert!(matches!(e, StartPoseError::NotRigid(_)), "{e}");
    assert!(e.to_string().contains("not finite"), "{e}");
}

#[test]
fn files_past_the_size_limit_are_refused_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.yaml");
    let f = std::fs::File::create(&big).unwrap();
    f.set_len(camera::MAX_TEXT_FILE_BYTES + 1).unwrap();
    let e = camera::read_euroc_sensor_yaml(&big).unwrap_err();
    assert!(e.to_string().contains("too large"), "{e}");
    let e = camera::start_pose::read_start_pose(&big).unwrap_err();
    assert!(e.to_string().contains("too large"), "{e}");
}

/// A JPEG whose DC prediction overflows zune-jpeg's `i32` multiply (found by the `frame`
/// fuzz target): decoded to some image or refused, never a panic, in test builds too (the
/// workspace's profile lets that crate's arithmetic wrap, as a release build does).
#[test]
fn a_jpeg_whose_dc_overflows_is_not_a_panic() {
    let bytes = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/regressions/jpeg_dc_overflow.jpg"),
    )
    .unwrap();
    if let Ok(img) = camera::decode_frame(&bytes) {
        assert!(img.width() <= camera::MAX_IMAGE_SIDE && img.height() <= camera::MAX_IMAGE_SIDE);
    }
}
