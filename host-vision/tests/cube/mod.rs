//! What the tests on the shared cube video (`../shared/data/visp-cube`) track it with.

use std::path::{Path, PathBuf};

use frames::FrameInput;
use host_vision::camera::read_camera_json;
use host_vision::track::{self, TrackOptions};
use protocol::ModelKind;

/// Vision-only tracking of the cube video in `dir` into `out`, as a user runs it: its camera
/// and model, the object-in-hand tuning, no overlays, and the searches' database in the
/// tests' own cache (not the user's). No start pose: a test gives one, or the cold start
/// finds it.
pub fn vision_only(dir: &Path, out: PathBuf) -> TrackOptions {
    let video = dir.join("cube_video.mp4");
    let mut o = TrackOptions::new(video.clone(), out);
    o.filter = ModelKind::Vision;
    o.frames = Some(FrameInput::Video(video));
    o.camera = Some(read_camera_json(&dir.join("camera.json")).expect("camera.json"));
    o.model = Some(dir.join("model/cube.obj"));
    o.tuning.expected_accel = track::config::OBJECT_IN_HAND_ACCEL;
    o.tuning.angular_noise = track::config::OBJECT_IN_HAND_ANGULAR_NOISE;
    o.overlay_every = 0;
    o.cache = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("locate-cache");
    o
}
