//! Fuzz the calibration readers on the same text: EuRoC `sensor.yaml`, Kalibr camchain and
//! `camera.json`. An accepted camera has usable numbers only. The files are at most
//! `camera::MAX_TEXT_FILE_BYTES` (1 MiB) and the YAML/JSON readers hold a few times their
//! input: any allocation over 64 MiB aborts.
#![no_main]

use std::path::Path;

use fuzz_support::LimitAlloc;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

fn sound(c: &camera::CameraCalib) {
    assert!(c.camera.width > 0 && c.camera.width <= camera::MAX_IMAGE_SIDE);
    assert!(c.camera.height > 0 && c.camera.height <= camera::MAX_IMAGE_SIDE);
    assert!(c.camera.pinhole.validate().is_ok() && c.camera.distortion.is_finite());
    assert!(c.extrinsics.is_none_or(|m| m.iter().all(|v| v.is_finite())));
    assert!(c.rate_hz.is_none_or(|r| r.is_finite() && r > 0.0));
    assert!(c.timeshift_cam_imu.is_none_or(f64::is_finite));
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let p = Path::new("fuzz.yaml");
    if let Ok(c) = camera::parse_euroc_sensor_yaml(text, p) {
        sound(&c);
    }
    if let Ok(cams) = camera::parse_kalibr_camchain(text, p) {
        cams.iter().for_each(sound);
    }
    if let Ok(c) = camera::parse_camera_json(text, p) {
        assert!(c.pinhole.validate().is_ok());
    }
});
