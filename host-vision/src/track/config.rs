//! The core's configuration ([`tracker::config`]), and the command line's checks against it:
//! the correspondences' latency against what the core advertised, and `--duration` against
//! the core's initialisation.

use std::path::PathBuf;

use protocol::{Capacities, Config};

pub use tracker::config::{
    CoreTuning, OBJECT_IN_HAND_ACCEL, OBJECT_IN_HAND_ANGULAR_NOISE, PUSH_SECONDS, core_config,
    vision_config,
};

use super::TrackError;

/// Why `--duration` `d` is refused, if it is: a run no longer than the core's still window
/// (`tuning.still_seconds`) never snaps on (`track` and `eval` check it alike).
pub fn duration_refusal(tuning: &CoreTuning, d: f64) -> Option<String> {
    let still = tuning.still_seconds;
    (!(d.is_finite() && d > still)).then(|| {
        format!(
            "--duration must be a number of seconds longer than the core's {still:.2} s initialisation, got {d}"
        )
    })
}

/// Checks the correspondences' latency against what the core advertised in `HelloAck`
/// ([`tracker::config::check_latency`]), naming `--latency`. (The host's own rule, below one
/// frame period, is stricter today; this guards a core with fewer buffers.)
pub fn check_latency(latency_s: f64, caps: &Capacities, config: &Config) -> Result<(), TrackError> {
    Ok(tracker::config::check_latency(latency_s, caps, config)?)
}

/// The firmware image's path inside the repository.
const FIRMWARE_IMAGE: &str = "firmware/target/thumbv7em-none-eabihf/release/device";

/// Where `qemu` finds the firmware image: in the current folder or one above it (run from the
/// repository), else beside the program (`target/*/host-vision` in the repository).
pub fn find_firmware_image() -> Result<PathBuf, String> {
    let cwd = std::env::current_dir().ok();
    let exe = std::env::current_exe().ok();
    let roots = cwd.iter().chain(exe.iter()).flat_map(|p| p.ancestors());
    for root in roots {
        let image = root.join(FIRMWARE_IMAGE);
        if image.is_file() {
            return Ok(image);
        }
    }
    Err(format!(
        "link qemu: no firmware image {FIRMWARE_IMAGE} in the current folder, beside this program, or above either; build it with `cargo xtask firmware` in the repository and run from there, or give its path with --link qemu:IMAGE"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 12, defect 9: the reviewer's 225 ms at 200 Hz IMU and 20 Hz camera is refused
    /// against the firmware's capacities (four frames: 195 ms), and what fits is accepted.
    #[test]
    fn a_latency_beyond_the_cores_limit_is_refused() {
        let caps = fusion_core::Device::<f32>::capacities();
        let mut config = protocol::samples::config();
        config.imu_rate_hz = 200.0;
        config.camera_rate_hz = 20.0;
        let err = check_latency(0.225, &caps, &config)
            .unwrap_err()
            .to_string();
        assert_eq!(
            err,
            "--latency 0.225 s is longer than the core can wait for a frame's correspondences: \
             0.195 s at 200 Hz IMU and 20 Hz camera (4 frames, 64 IMU samples kept)"
        );
        assert!(check_latency(0.195, &caps, &config).is_ok());
        config.imu_rate_hz = 100.0;
        config.camera_rate_hz = 25.0;
        assert!(check_latency(0.15, &caps, &config).is_ok());
        assert!(check_latency(0.151, &caps, &config).is_err());
    }
}
