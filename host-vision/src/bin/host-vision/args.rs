//! The command line: subcommands, their options and help texts.
//!
//! Every subcommand takes negative numbers as values (`--start-yaw -10`, `--start-position
//! -0.5,0,0.2`); the ranges are checked afterwards, where the error can name the flag and
//! the limit (`track`'s in `TrackOptions::check`, which knows the dataset).

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use firmware_sim::sim::scenario::ScenarioName;
use host_vision::track::LinkSpec;

/// Vision host of the visual-inertial tracker.
///
/// Exit codes: 0 done; 1 failed (input, link, output); 2 bad command line or option value;
/// 3 nothing found (track: the core accepted no correspondence, tracking never started;
/// locate: no pose); 130 interrupted (Ctrl-C; what was done is written).
#[derive(Parser, Debug)]
#[command(version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Protocol loop-back self-test over a pty pair (a real serial line in one process).
    Selftest {
        /// IMU samples to stream through the link (1 to 100000: both ends keep every message
        /// sent, about 1 KB each, to compare them).
        #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u32).range(1..=100_000))]
        imu_samples: u32,
    },
    /// Writes a synthetic EuRoC-format dataset of one of the paper's test cases.
    Synth(Box<SynthArgs>),
    /// Tracks a EuRoC-layout dataset with the fusion core at the other end of a link.
    Track(Box<TrackArgs>),
    /// Decodes a video, a camera or an image folder without tracking, and reports frame count,
    /// size, time span and decoding speed (checks an input before tracking).
    Frames(Box<FramesArgs>),
    /// The paper's experiments: every scenario with every model; Table 2 and accuracy.
    Eval(Box<EvalArgs>),
    /// The robustness corpus: scenes made to break the tracker, tracked with the IMU and
    /// without; the verdict ("tracked") scored against the ground truth per scene: precision,
    /// recall, and how soon a wrong pose is reported (corpus.md, corpus.json).
    Corpus(Box<CorpusArgs>),
    /// The demo: synthesises the fast desktop sequence (cached), tracks it with the acc and
    /// gyro models over the simulated serial link, prints the summary and where the images are.
    Demo(Box<DemoArgs>),
    /// Finds the model in one image with no pose given (the cold start): prints the pose and
    /// the verification figures, and writes pose.json (a --start-pose file), overlay.png and
    /// locate.json.
    Locate(Box<LocateArgs>),
}

/// Options of `locate`.
#[derive(clap::Args, Debug)]
pub struct LocateArgs {
    /// The image (PNG or JPEG).
    #[arg(long, required_unless_present = "video", conflicts_with = "video")]
    pub image: Option<PathBuf>,
    /// A video, with --frame.
    #[arg(long)]
    pub video: Option<PathBuf>,
    /// The frame of --video, from 0.
    #[arg(long, default_value_t = 0, requires = "video")]
    pub frame: usize,
    /// The model file (.obj, .gltf, .glb), textured.
    #[arg(long)]
    pub model: PathBuf,
    /// The camera: a camera.json (pinhole, no distortion).
    #[arg(long, conflicts_with_all = ["intrinsics", "calib"])]
    pub camera: Option<PathBuf>,
    /// The camera: a Kalibr camchain YAML (its first camera) or a EuRoC sensor.yaml.
    #[arg(long, conflicts_with = "intrinsics")]
    pub calib: Option<PathBuf>,
    /// The camera: pinhole intrinsics without distortion `fx,fy,cx,cy` [px].
    #[arg(long, value_parser = host_vision::camera::parse_intrinsics, allow_hyphen_values = true)]
    pub intrinsics: Option<host_vision::camera::Pinhole>,
    /// Folder of the viewpoint database's cache (default: the user's cache folder,
    /// $XDG_CACHE_HOME/host-vision or ~/.cache/host-vision); rebuilt when the model or the
    /// settings change.
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the outputs of an earlier run in --out.
    #[arg(long)]
    pub overwrite: bool,
}

/// The help of every `--link`.
const LINK_HELP: &str = "The fusion core: sim, sim:f64, inproc, inproc:f64, serial:PATH[@BAUD], tcp:HOST:PORT, qemu or qemu:IMAGE";
const LINK_LONG_HELP: &str = "The fusion core at the other end of the link:
  sim               the simulated board (f32 core) in this process, on a pty pair
  sim:f64           the same with the f64 core
  inproc            the same board called directly: no pty, no thread (inproc:f64 too)
  serial:PATH[@BAUD] a serial device: a board, or `firmware-sim --link pty` in another
                    process (it prints the PATH); BAUD defaults to 921600
  tcp:HOST:PORT     `firmware-sim --link tcp:HOST:PORT` in another process
  qemu              the firmware image under QEMU (`cargo xtask firmware` builds it; run
                    from the repository)
  qemu:IMAGE        a firmware image under QEMU";

/// Options of `demo`.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "target/demo/out")]
    pub out: PathBuf,
    /// Replace the outputs of an earlier demo in --out.
    #[arg(long)]
    pub overwrite: bool,
    /// Where the synthetic dataset is cached.
    #[arg(long, default_value = "target/demo/datasets")]
    pub cache: PathBuf,
    /// Seconds of the sequence.
    #[arg(long, default_value_t = 15.0, value_parser = parse_seconds)]
    pub duration: f64,
    #[arg(long, default_value = "sim", help = LINK_HELP, long_help = LINK_LONG_HELP)]
    pub link: LinkSpec,
}

/// Options of `eval`.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct EvalArgs {
    /// Output folder (eval.md, eval.json, plots, and each run's outputs).
    #[arg(long, default_value = "eval-out")]
    pub out: PathBuf,
    /// Replace the outputs of an earlier evaluation in --out.
    #[arg(long)]
    pub overwrite: bool,
    /// Where synthetic datasets are cached.
    #[arg(long, default_value = "datasets")]
    pub cache: PathBuf,
    /// Scenarios (repeatable; default: all four).
    #[arg(long = "scenario", value_parser = scenario())]
    pub scenarios: Vec<ScenarioName>,
    /// Models (repeatable; default: gyro, gravity, acc and vision, the last with the IMU
    /// withheld).
    #[arg(long = "filter", value_enum)]
    pub filters: Vec<FilterArg>,
    /// Shorter scenarios [s] (default: their nominal lengths).
    #[arg(long, value_parser = parse_seconds)]
    pub duration: Option<f64>,
    /// Seed of the synthetic sensors.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long, default_value = "sim", help = LINK_HELP, long_help = LINK_LONG_HELP)]
    pub link: LinkSpec,
    /// Skip the two-feature run on desktop-slow (the paper's Fig. 6).
    #[arg(long)]
    pub no_two_features: bool,
    /// Overlay images every N frames (0: none).
    #[arg(long, default_value_t = 0)]
    pub overlay_every: usize,
}

/// Options of `corpus`.
#[derive(clap::Args, Debug)]
pub struct CorpusArgs {
    /// Output folder (corpus.md, corpus.json, and each run's outputs in SCENE/FILTER/).
    #[arg(long, default_value = "corpus-out")]
    pub out: PathBuf,
    /// Replace the outputs of an earlier corpus run in --out.
    #[arg(long)]
    pub overwrite: bool,
    /// Where synthetic datasets are cached.
    #[arg(long, default_value = "datasets")]
    pub cache: PathBuf,
    /// The quick form (the test suite's): a few scenes of a few seconds each.
    #[arg(long)]
    pub quick: bool,
    /// Only this scene (repeatable; default: every scene of the form).
    #[arg(long = "scene")]
    pub scenes: Vec<String>,
    /// The shared data folder, with the meshes some scenes stand in place of their modelled
    /// surfaces (meshes/bunny/bunny.obj); a scene whose mesh is absent is skipped and said.
    #[arg(long, default_value = "../shared/data")]
    pub data: PathBuf,
    /// Seed of the synthetic sensors.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Help of `--video`, shared by `frames` and `track`.
const VIDEO_HELP: &str = "Video file (mp4 or anything ffmpeg reads) or a V4L2 camera such as /dev/video0, decoded by the ffmpeg program into grey frames with the container's time stamps";
/// Help of `--images`.
const IMAGES_HELP: &str = "Folder of PNG/JPG frames in name order (with --fps), or a EuRoC cam0 folder (or a dataset holding mav0/cam0) with its data.csv time stamps";

/// Options of `frames`.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct FramesArgs {
    #[arg(long, help = VIDEO_HELP, required_unless_present = "images", conflicts_with = "images")]
    pub video: Option<PathBuf>,
    #[arg(long, help = IMAGES_HELP)]
    pub images: Option<PathBuf>,
    /// Frame rate of a plain image folder [Hz] (a EuRoC folder has its time stamps).
    #[arg(long, requires = "images", value_parser = parse_fps)]
    pub fps: Option<f64>,
    /// Pinhole intrinsics without distortion `fx,fy,cx,cy` [px], checked against the frames.
    #[arg(long, value_parser = host_vision::camera::parse_intrinsics, allow_hyphen_values = true, conflicts_with = "camera")]
    pub intrinsics: Option<host_vision::camera::Pinhole>,
    /// A camera.json (pinhole, no distortion: model, width, height, fx, fy, cx, cy), checked
    /// against the frames.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Stop after this many frames (a live camera never ends by itself).
    #[arg(long)]
    pub max_frames: Option<usize>,
}

/// Options of `track`.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct TrackArgs {
    /// Dataset folder (holding mav0/). Without mav0/imu0 it is tracked vision-only.
    #[arg(long, required_unless_present_any = ["video", "images"])]
    pub dataset: Option<PathBuf>,
    /// Track a video or a live V4L2 camera vision-only (no IMU): decoded by the ffmpeg
    /// program into grey frames with the container's time stamps; needs the camera
    /// (--camera, --calib or --intrinsics) and the model (--model); without --start-pose the
    /// model is found in the frames (the cold start).
    #[arg(long, conflicts_with_all = ["dataset", "images"])]
    pub video: Option<PathBuf>,
    /// Track an image folder vision-only (as --video): PNG/JPG in name order at --fps, or a
    /// EuRoC cam0 folder with its data.csv time stamps.
    #[arg(long, conflicts_with = "dataset")]
    pub images: Option<PathBuf>,
    /// Frame rate of a plain --images folder [Hz].
    #[arg(long, requires = "images", value_parser = parse_fps)]
    pub fps: Option<f64>,
    /// The camera of --video/--images: a camera.json (pinhole, no distortion: model, width,
    /// height, fx, fy, cx, cy).
    #[arg(long, conflicts_with_all = ["intrinsics", "calib"])]
    pub camera: Option<PathBuf>,
    /// The camera of --video/--images: a Kalibr camchain YAML (its first camera) or a EuRoC
    /// sensor.yaml, distortion included.
    #[arg(long, conflicts_with = "intrinsics")]
    pub calib: Option<PathBuf>,
    /// The camera of --video/--images: pinhole intrinsics without distortion `fx,fy,cx,cy`
    /// [px], for frames of the size the first frame has.
    #[arg(long, value_parser = host_vision::camera::parse_intrinsics, allow_hyphen_values = true)]
    pub intrinsics: Option<host_vision::camera::Pinhole>,
    /// Stop after this many frames (vision-only; a live camera never ends by itself).
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Folder of the cold start's viewpoint database (used without a start pose: the model is
    /// found frame by frame until a pose is verified, and again after a loss); default: the
    /// user's cache folder ($XDG_CACHE_HOME/host-vision or ~/.cache/host-vision).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Output folder (trajectories, frames.csv, summary.json, overlays/, plots/); not inside
    /// the dataset.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the outputs of an earlier run in --out (they are removed first).
    #[arg(long)]
    pub overwrite: bool,
    /// Model file (.obj, .gltf, .glb); default: the dataset's model/scene.obj.
    #[arg(long)]
    pub model: Option<PathBuf>,
    #[arg(long, default_value = "sim", help = LINK_HELP, long_help = LINK_LONG_HELP)]
    pub link: LinkSpec,
    /// Filter model (default: acc; vision for --video, --images and datasets without an IMU).
    #[arg(long, value_enum)]
    pub filter: Option<FilterArg>,
    /// Pacing: `lock-step` replays every frame and sample, the same every time; `real-time`
    /// plays the input at its own rate, as live sensors would deliver it: IMU samples by the
    /// clock, and a video or image folder as a camera, the tracker taking the newest frame
    /// and dropping those it had no time for (a camera device is always live).
    #[arg(long, value_enum, default_value = "lock-step")]
    pub pacing: host_vision::track::Pacing,
    /// Trigger-to-correspondences latency in lock-step mode with an IMU [s] (default 0.03): at
    /// least 0 and below one frame period, so that each prediction has the previous frame's
    /// update. Refused where nothing waits for it (vision-only, --pacing real-time).
    #[arg(long)]
    pub latency: Option<f64>,
    /// Features registered per frame (1 to 128, what one frame can send the core).
    #[arg(long, default_value_t = 40)]
    pub features: usize,
    /// What frames measure: the model's texture (KLT features), its contour (the silhouette
    /// along its normals, docs/VISION.md §9), both, or `auto`: the texture of a textured
    /// model, the contour of one without texture.
    #[arg(long, value_enum, default_value = "auto")]
    pub modality: ModalityArg,
    /// Track only the first S seconds of the dataset (longer than the core's 0.3 s
    /// initialisation).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Start position of the IMU `x,y,z` [m] (default: from the ground truth; without one,
    /// give it with --start-yaw, or neither for the cold start).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub start_position: Option<[f64; 3]>,
    /// Start yaw of the IMU [deg] (default: from the ground truth; without one, give it with
    /// --start-position, or neither for the cold start).
    #[arg(long)]
    pub start_yaw: Option<f64>,
    /// Full start pose of the camera in the model (world) frame at the first IMU sample: JSON
    /// with a 4x4 camera-from-model `cMo` [m], or one TUM line `t tx ty tz qx qy qz qw` (camera
    /// centre, camera-to-world quaternion); checked to be rigid. Replaces --start-position and
    /// --start-yaw.
    #[arg(long, conflicts_with_all = ["start_position", "start_yaw"])]
    pub start_pose: Option<PathBuf>,
    /// Find the model in the frames to start (and again after a loss) even where the dataset's
    /// ground truth could give the start, which then only evaluates. Without a ground truth
    /// and without --start-pose/--start-position/--start-yaw this is what happens anyway.
    #[arg(long, conflicts_with_all = ["start_position", "start_yaw", "start_pose"])]
    pub cold_start: bool,
    /// Peak free acceleration expected [m/s²] (scales the motion noise; default: from a
    /// synthetic dataset's manifest, else 10 for a hand-held camera, 5 for an object turned by
    /// hand in --video/--images).
    #[arg(long)]
    pub expected_accel: Option<f64>,
    /// The core's accelerometer measurement noise, a standard deviation per sample [m/s²]
    /// (default: per model). Not synth's --accel-noise, which is the sensor's noise density.
    #[arg(long)]
    pub accel_meas_noise: Option<f64>,
    /// Angular-acceleration noise density of the core's motion model [rad/s²/√Hz] (default:
    /// 10 for a hand-held camera, 6 for an object turned by hand in --video/--images).
    #[arg(long)]
    pub angular_noise: Option<f64>,
    /// Write an overlay image every N frames (0: none).
    #[arg(long, default_value_t = 25)]
    pub overlay_every: usize,
    /// Replace this fraction of correspondences by outliers (robustness tests).
    #[arg(long, default_value_t = 0.0)]
    pub outliers: f64,
    /// Corrupt all correspondences for 0.3 s from this time [s], counted from the dataset's
    /// first IMU sample as frames.csv's t_s (forces a divergence).
    #[arg(long)]
    pub corrupt_at: Option<f64>,
    /// Replace the frames by noise for 2 s from this time [s] (as --corrupt-at): the model is
    /// gone from the images while the camera moves, and must be found again.
    #[arg(long)]
    pub blind_at: Option<f64>,
    /// Garble the line to the simulated board (--link sim): each byte, in both directions,
    /// has one bit flipped with this probability; damaged frames are counted and dropped at
    /// both ends.
    #[arg(long)]
    pub line_errors: Option<f64>,
    /// Reset the core at this time [s] (as --corrupt-at): the simulated board's reset line,
    /// or QEMU killed and booted again (--link sim or qemu). The host must notice, configure
    /// and initialise it again from its last good pose, and resume.
    #[arg(long)]
    pub reset_core_at: Option<f64>,
    /// Pull the cable at this time [s] (as --corrupt-at): the host's end of the line is
    /// closed, and reconnecting fails for --cut-seconds. The core keeps its state; the host
    /// reconnects with back-off and brings the core up to date.
    #[arg(long)]
    pub cut_link_at: Option<f64>,
    /// How long the cable of --cut-link-at stays out [s] (default 0.5).
    #[arg(long, requires = "cut_link_at")]
    pub cut_seconds: Option<f64>,
    /// Attach to a core that is already running (a host restarted while the core went on):
    /// ask for its state and go on from where it is, without configuring or initialising it
    /// again if it is still tracking.
    #[arg(long)]
    pub attach: bool,
    /// The core samples its own IMU and fires the camera every k-th sample, as on sensor
    /// hardware (protocol/PROTOCOL.md §7): the dataset's IMU goes through a simulated
    /// ICM-42688-P and the board's sample path on the in-process board (--link inproc), the
    /// frames are paired with the core's triggers, and the samples the core took are written
    /// as core_imu.csv.
    #[arg(long)]
    pub imu_on_core: bool,
}

/// What frames measure, on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ModalityArg {
    /// The model's texture where it has one, else its contour.
    Auto,
    /// The texture (KLT features).
    Texture,
    /// The contour.
    Contour,
    /// Both.
    Both,
}

impl ModalityArg {
    /// The tracker's choice (`None`: from the model).
    pub fn modality(self) -> Option<vision::Modality> {
        match self {
            ModalityArg::Auto => None,
            ModalityArg::Texture => Some(vision::Modality::Texture),
            ModalityArg::Contour => Some(vision::Modality::Contour),
            ModalityArg::Both => Some(vision::Modality::Both),
        }
    }
}

/// Filter model on the command line.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum FilterArg {
    /// Constant velocity, gyro updates.
    Gyro,
    /// Constant velocity, gyro and accelerometer (gravity direction) updates.
    Gravity,
    /// Constant acceleration, gyro and accelerometer updates.
    Acc,
    /// No IMU: constant velocity advanced by time alone (an IMU in the dataset is withheld).
    Vision,
}

impl From<FilterArg> for protocol::ModelKind {
    fn from(f: FilterArg) -> Self {
        match f {
            FilterArg::Gyro => protocol::ModelKind::Gyro,
            FilterArg::Gravity => protocol::ModelKind::Gravity,
            FilterArg::Acc => protocol::ModelKind::Acc,
            FilterArg::Vision => protocol::ModelKind::Vision,
        }
    }
}

/// Options of `synth`.
#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct SynthArgs {
    /// Test case.
    #[arg(long, value_parser = scenario())]
    pub scenario: ScenarioName,
    /// Output folder (created; must not already hold a dataset unless --overwrite).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of sensor noise, biases and vibration.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Image size WxH.
    #[arg(long, default_value = "320x240", value_parser = parse_resolution)]
    pub resolution: (u32, u32),
    /// Duration in seconds, up to an hour (default: the scenario's).
    #[arg(long, value_parser = parse_synth_duration, allow_hyphen_values = true)]
    pub duration: Option<f64>,
    /// IMU rate in Hz (10-10000).
    #[arg(long, default_value_t = 100.0, value_parser = parse_imu_rate, allow_hyphen_values = true)]
    pub imu_rate: f64,
    /// One camera frame every N IMU samples (1 or more).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..))]
    pub camera_every: u32,
    /// Fewest sub-frames averaged over the exposure, 1-64 (with --max-subframes 1: 1 means no
    /// motion blur).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub subframes: u32,
    /// Most sub-frames, 1-64 and no fewer than --subframes (fast frames get about one per
    /// pixel of image motion).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub max_subframes: u32,
    /// Render supersampling per axis (1-4).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub supersample: u32,
    /// Texel density factor of the generated textures.
    #[arg(long, default_value_t = 1.0)]
    pub texture_scale: f64,
    /// Image for the modelled surfaces instead of generated textures (repeatable).
    #[arg(long = "texture")]
    pub textures: Vec<PathBuf>,
    /// The modelled surfaces in one solid colour, without texture (in the model and in the
    /// frames): an object without texture, to track by its contour. The surroundings keep
    /// their textures.
    #[arg(long, conflicts_with = "textures")]
    pub untextured: bool,
    /// The colour of --untextured, linear RGB `r,g,b` in [0, 1] (default: an orange whose grey
    /// lies between the generated textures' dark and bright levels: little contrast in a grey
    /// camera).
    #[arg(long, requires = "untextured", value_parser = parse_colour, allow_hyphen_values = true)]
    pub untextured_colour: Option<[f32; 3]>,
    /// A mesh (OBJ, glTF) in place of the modelled surfaces, stood where they stand: in
    /// metres, y up, its origin at the centre of its base, such as the Stanford bunny of
    /// ../shared/data/meshes/bunny/bunny.obj. It is the dataset's model; with --untextured,
    /// in that colour.
    #[arg(long, conflicts_with = "textures")]
    pub object: Option<PathBuf>,
    /// Lit, shaded frames: a directional light 50° up, turning 10° a second and dimming by
    /// 40 % every 6 s, and an ambient one; Lambert's diffuse term and a highlight (default:
    /// the surfaces' values unlit).
    #[arg(long, conflicts_with = "ideal")]
    pub lit: bool,
    /// Noise-free IMU and frames (no noise, biases, vibration, clipping, lighting changes).
    #[arg(long)]
    pub ideal: bool,
    /// Gyro white-noise density [rad/s/√Hz] (default: the MT9-class 1e-3).
    #[arg(long, value_parser = parse_density)]
    pub gyro_noise: Option<f64>,
    /// Gyro bias random walk [rad/s²/√Hz] (default: 2e-5).
    #[arg(long, value_parser = parse_density)]
    pub gyro_walk: Option<f64>,
    /// Accelerometer white-noise density of the simulated sensor [m/s²/√Hz] (default: 2e-3).
    #[arg(long, value_parser = parse_density)]
    pub accel_noise: Option<f64>,
    /// Accelerometer bias random walk [m/s³/√Hz] (default: 1e-4).
    #[arg(long, value_parser = parse_density)]
    pub accel_walk: Option<f64>,
    /// Replace a dataset already in the output folder.
    #[arg(long)]
    pub overwrite: bool,
}

/// `--scenario`'s values, with their descriptions (the simulator's names know no command
/// line).
fn scenario() -> impl clap::builder::TypedValueParser<Value = ScenarioName> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser as _};
    let names = ScenarioName::ALL.map(|s| PossibleValue::new(s.as_str()).help(s.describe()));
    PossibleValuesParser::new(names).try_map(|s| s.parse::<ScenarioName>())
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("`{p}`: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!("expected three finite numbers x,y,z, got `{s}`")),
    }
}

fn parse_colour(s: &str) -> Result<[f32; 3], String> {
    let [r, g, b] = parse_vec3(s)?;
    if [r, g, b].iter().all(|c| (0.0..=1.0).contains(c)) {
        Ok([r as f32, g as f32, b as f32])
    } else {
        Err(format!(
            "expected a linear RGB colour r,g,b with each in [0, 1], got `{s}`"
        ))
    }
}

fn parse_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("`{s}`: {e}"))?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("must be a positive number of seconds, got `{s}`"))
    }
}

/// `synth --duration`: (0, 3600] s.
fn parse_synth_duration(s: &str) -> Result<f64, String> {
    let v = parse_seconds(s)?;
    if v <= firmware_sim::sim::scenario::MAX_DURATION {
        Ok(v)
    } else {
        Err(format!(
            "at most {} s (an hour), got `{s}`",
            firmware_sim::sim::scenario::MAX_DURATION
        ))
    }
}

/// `synth --imu-rate`: [10, 10000] Hz, as the simulated sensor takes it.
fn parse_imu_rate(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (10.0..=10_000.0).contains(&v) => Ok(v),
        _ => Err(format!("an IMU rate in [10, 10000] Hz, got `{s}`")),
    }
}

fn parse_density(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("`{s}`: {e}"))?;
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(format!(
            "a noise density must be finite and non-negative, got `{s}`"
        ))
    }
}

fn parse_resolution(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WxH, e.g. 320x240, got `{s}`"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|e| format!("`{v}` in `{s}`: {e}"))
    };
    let (w, h) = (parse(w)?, parse(h)?);
    if !(16..=4096).contains(&w) || !(16..=4096).contains(&h) {
        return Err(format!("each side must be 16..=4096 pixels, got {w}x{h}"));
    }
    Ok((w, h))
}

/// `--fps`: a frame rate in (0, 10000] Hz, refused as a usage error before anything is read
/// (issue 33: `0`, `1e9` and `NaN` reached the image folder and exited 1).
fn parse_fps(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(f) if f.is_finite() && f > 0.0 && f <= 10_000.0 => Ok(f),
        _ => Err(format!("a frame rate in (0, 10000] Hz, got {text}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory as _;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn negative_numbers_are_values() {
        let cli = Cli::try_parse_from([
            "host-vision",
            "track",
            "--dataset",
            "d",
            "--out",
            "o",
            "--start-position",
            "-0.5,0,0.2",
            "--start-yaw",
            "-10",
            "--latency",
            "-1",
        ])
        .unwrap();
        let Command::Track(a) = cli.command else {
            panic!("not track")
        };
        assert_eq!(a.start_position, Some([-0.5, 0.0, 0.2]));
        assert_eq!(a.start_yaw, Some(-10.0));
        assert_eq!(a.latency, Some(-1.0));
    }
}
