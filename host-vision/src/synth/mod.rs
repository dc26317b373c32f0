//! Synthetic datasets in the EuRoC/ASL layout for the paper's test cases (issue 6).
//!
//! The trajectory, IMU and inertial files come from the simulator
//! ([`firmware_sim::sim::scenario`]); this module adds what needs the renderer: the scene's
//! meshes and procedural textures ([`texture`], [`scene`]), the model folder (OBJ + MTL + PNG,
//! modelled surfaces only), the live frames ([`frames`]) and the camera's `sensor.yaml`.
//!
//! Output under the chosen folder:
//! ```text
//! manifest.json                      scenario, seed, all parameters, statistics
//! frames.csv                         per frame: model coverage, occluder coverage, the
//!                                    model's unoccluded share, lighting
//! model/scene.obj, scene.mtl, *.png  the CAD model the tracker loads
//! mav0/imu0/data.csv, sensor.yaml
//! mav0/cam0/data.csv, sensor.yaml, data/<timestamp>.png
//! mav0/state_groundtruth_estimate0/data.csv
//! ```

pub mod frames;
pub mod scene;
pub mod shading;
pub mod texture;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use firmware_sim::sim::imu::ImuNoise;
use firmware_sim::sim::scenario::euroc::{self, DatasetError};
use firmware_sim::sim::scenario::{Peaks, Scenario, ScenarioError, ScenarioName, T0_NS};
use rand::SeedableRng;
use rand::rngs::StdRng;

pub use frames::{FrameOptions, FrameSynth, SynthFrame, live_camera};

/// What wrote a dataset (its manifest's `generator`): the version and the layout of its
/// files, so that a cached dataset of another layout is made again (`eval::ensure_synth`).
/// Layout 2: `frames.csv` has `model_unoccluded`.
pub fn generator() -> String {
    format!("host-vision synth {} (layout 2)", env!("CARGO_PKG_VERSION"))
}
pub use scene::{SceneModels, TextureOptions, UNTEXTURED_COLOUR, write_obj};
pub use shading::Shading;

use crate::camera::{Camera, CameraError, Distortion};
use crate::render::RenderError;

/// Why a dataset could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// An IMU noise density is negative or not finite.
    #[error("IMU noise densities must be finite and non-negative, got {0:?}")]
    ImuNoise(ImuNoise),
    /// A file or folder could not be written.
    #[error("{path}: {source}")]
    Io {
        /// File or folder.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// An image could not be written.
    #[error("{path}: {source}")]
    Image {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: image::ImageError,
    },
    /// A user texture could not be read.
    #[error("texture {path}: {source}")]
    Texture {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: image::ImageError,
    },
    /// The output folder already holds a dataset.
    #[error(
        "{0} already contains a dataset (mav0/ or model/); choose another folder or pass --overwrite"
    )]
    Exists(PathBuf),
    /// An option is out of range.
    #[error("{0}")]
    BadOption(String),
    /// Stopped by [`SynthOptions::interrupt`] (Ctrl-C) before the dataset was complete.
    #[error("interrupted before the dataset was complete")]
    Interrupted,
    /// Scenario parameters.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The inertial files.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// Rendering.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// Camera parameters.
    #[error(transparent)]
    Camera(#[from] CameraError),
}

impl SynthError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        SynthError::Io {
            path: path.to_owned(),
            source,
        }
    }
}

/// What to generate.
#[derive(Debug, Clone)]
pub struct SynthOptions {
    /// Scenario.
    pub scenario: ScenarioName,
    /// Output folder.
    pub out: PathBuf,
    /// Seed of noise, biases and vibration.
    pub seed: u64,
    /// Duration [s]; the scenario's nominal one when `None`.
    pub duration: Option<f64>,
    /// IMU rate [Hz] and camera divider; the scenario's (100 Hz, every 4th) when `None`.
    pub rates: Option<(f64, u32)>,
    /// IMU without noise, biases, vibration or clipping.
    pub ideal_imu: bool,
    /// IMU noise densities instead of the scenario's MT9-class ones (ignored with `ideal_imu`).
    pub imu_noise: Option<ImuNoise>,
    /// Frames.
    pub frames: FrameOptions,
    /// Textures.
    pub textures: TextureOptions,
    /// A mesh file (OBJ, glTF) to stand in place of the scenario's modelled surfaces: in
    /// metres, y up, its origin at the centre of its base (the Stanford bunny of
    /// `../shared/data/meshes/bunny`).
    pub object: Option<PathBuf>,
    /// Replace an existing dataset in `out` (its `mav0/` and `model/` folders).
    pub overwrite: bool,
    /// Set (by Ctrl-C) to stop after the current frame, with [`SynthError::Interrupted`].
    pub interrupt: Option<Arc<AtomicBool>>,
}

impl SynthOptions {
    /// Defaults for `scenario` into `out`: seed 0, nominal duration, 320×240.
    pub fn new(scenario: ScenarioName, out: PathBuf) -> Self {
        SynthOptions {
            scenario,
            out,
            seed: 0,
            duration: None,
            rates: None,
            ideal_imu: false,
            imu_noise: None,
            frames: FrameOptions::new(320, 240),
            textures: TextureOptions::generated(),
            object: None,
            overwrite: false,
            interrupt: None,
        }
    }

    /// The scenario these options describe.
    pub fn build_scenario(&self) -> Result<Scenario, SynthError> {
        let mut sc = Scenario::new(self.scenario);
        if let Some(d) = self.duration {
            sc = sc.with_duration(d)?;
        }
        if let Some((hz, every)) = self.rates {
            sc = sc.with_rates(hz, every)?;
        }
        if let Some(noise) = self.imu_noise {
            let all = [
                noise.gyro_density,
                noise.accel_density,
                noise.gyro_walk,
                noise.accel_walk,
            ];
            if !all.iter().all(|v| v.is_finite() && *v >= 0.0) {
                return Err(SynthError::ImuNoise(noise));
            }
            sc.imu.noise = noise;
        }
        if self.ideal_imu {
            sc.imu = sc.imu.without_noise();
        }
        Ok(sc)
    }
}

/// What was generated.
#[derive(Debug, Clone)]
pub struct SynthReport {
    /// Scenario.
    pub scenario: ScenarioName,
    /// Duration [s].
    pub duration: f64,
    /// IMU samples.
    pub imu_samples: usize,
    /// Camera frames.
    pub frames: usize,
    /// Peaks of the trajectory.
    pub peaks: Peaks,
    /// Share of frames where the model covers at least 10 % of the image.
    pub model_visible: f64,
    /// Share of frames where any part of the model is visible.
    pub model_any: f64,
    /// Share of frames with an occluder in view.
    pub occluded: f64,
    /// IMU samples clipped by the saturation.
    pub saturated: usize,
    /// Wall-clock time [s].
    pub seconds: f64,
    /// The renderer's adapter.
    pub adapter: String,
}

impl std::fmt::Display for SynthReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {:.1} s, {} IMU samples, {} frames",
            self.scenario, self.duration, self.imu_samples, self.frames
        )?;
        writeln!(
            f,
            "  peak free acceleration {:.2} m/s², peak angular rate {:.2} rad/s (pivot {:.2} m/s²)",
            self.peaks.accel, self.peaks.rate, self.peaks.pivot_accel
        )?;
        writeln!(
            f,
            "  model visible (≥10 % of the image) in {:.1} % of frames, any part in {:.1} %; \
             occluder in view in {:.1} %",
            100.0 * self.model_visible,
            100.0 * self.model_any,
            100.0 * self.occluded
        )?;
        write!(
            f,
            "  {} saturated IMU samples; generated in {:.1} s on {}",
            self.saturated, self.seconds, self.adapter
        )
    }
}

/// EuRoC `cam0/sensor.yaml`: intrinsics, radial-tangential distortion and `T_BS` (camera →
/// body) from the hand-eye mount.
pub fn cam_sensor_yaml(scenario: &Scenario, camera: &Camera) -> String {
    let mount = &scenario.camera.mount;
    let r_sc = mount.q_cs.inverse().to_rotation_matrix().into_inner();
    let c = mount.c_s;
    let t_bs = [
        [r_sc[(0, 0)], r_sc[(0, 1)], r_sc[(0, 2)], c.x],
        [r_sc[(1, 0)], r_sc[(1, 1)], r_sc[(1, 2)], c.y],
        [r_sc[(2, 0)], r_sc[(2, 1)], r_sc[(2, 2)], c.z],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let (k1, k2, p1, p2) = match camera.distortion {
        Distortion::RadTan { k1, k2, p1, p2, .. } => (k1, k2, p1, p2),
        _ => (0.0, 0.0, 0.0, 0.0),
    };
    let p = &camera.pinhole;
    let mut s = String::new();
    let _ = write!(
        s,
        "%YAML:1.0\n\
         # Simulated camera (host-vision synth, scenario {name}); exposure {exp} s centred on\n\
         # the time stamp. T_BS maps camera coordinates into the body (IMU) frame.\n\
         sensor_type: camera\n\
         comment: simulated cam0, scenario {name}\n\
         {tbs}\
         rate_hz: {rate:?}\n\
         resolution: [{w}, {h}]\n\
         camera_model: pinhole\n\
         intrinsics: [{fx:?}, {fy:?}, {cx:?}, {cy:?}] #fu, fv, cu, cv\n\
         distortion_model: radial-tangential\n\
         distortion_coefficients: [{k1:?}, {k2:?}, {p1:?}, {p2:?}]\n",
        name = scenario.name,
        exp = scenario.camera.exposure,
        tbs = euroc::yaml_matrix("T_BS", &t_bs),
        rate = scenario.imu.rate_hz / scenario.camera.every as f64,
        w = camera.width,
        h = camera.height,
        fx = p.fx,
        fy = p.fy,
        cx = p.cx,
        cy = p.cy,
    );
    s
}

// The file that marks a dataset `synth` has not finished writing: made before anything else,
// removed after the last file. A folder that holds it (an interrupted or killed `synth`) is
// refused by `frames::euroc::Dataset::open` and replaced by the next `synth` into it.
use ::frames::euroc::UNFINISHED;

/// What `synth` writes into its folder.
const WRITTEN: [&str; 4] = ["mav0", "model", "frames.csv", "manifest.json"];

fn prepare_out(out: &Path, overwrite: bool) -> Result<(), SynthError> {
    if out.exists() && !out.is_dir() {
        return Err(SynthError::BadOption(format!(
            "{} exists and is not a folder",
            out.display()
        )));
    }
    // An unfinished dataset of ours is replaced as if asked to.
    let unfinished = out.join(UNFINISHED).exists();
    if ["mav0", "model"].iter().any(|p| out.join(p).exists()) {
        if !overwrite && !unfinished {
            return Err(SynthError::Exists(out.to_owned()));
        }
        remove_written(out)?;
    } else if unfinished {
        remove_written(out)?;
    }
    std::fs::create_dir_all(out).map_err(|e| SynthError::io(out, e))?;
    // The mark goes first: it also shows, early and with the folder's name, that the folder
    // can be written.
    let mark = out.join(UNFINISHED);
    std::fs::write(
        &mark,
        "host-vision synth had not finished writing this dataset (interrupted or killed): run synth into this folder again\n",
    )
    .map_err(|e| SynthError::io(out, e))?;
    Ok(())
}

/// Removes what `synth` writes into `out` (its own names only), the unfinished mark last.
pub fn remove_written(out: &Path) -> Result<(), SynthError> {
    for name in WRITTEN {
        let p = out.join(name);
        let removed = if p.is_dir() {
            std::fs::remove_dir_all(&p)
        } else if p.exists() {
            std::fs::remove_file(&p)
        } else {
            Ok(())
        };
        removed.map_err(|e| SynthError::io(&p, e))?;
    }
    let mark = out.join(UNFINISHED);
    if mark.exists() {
        std::fs::remove_file(&mark).map_err(|e| SynthError::io(&mark, e))?;
    }
    Ok(())
}

/// Writes `manifest.json`: the IMU's settings (firmware-sim's part), the camera, the
/// rendering, the scene and the figures of the frames (`report`). Written last: a dataset
/// is complete once it is there.
fn write_manifest(
    options: &SynthOptions,
    scenario: &Scenario,
    imu: &euroc::ImuDataset,
    synth: &FrameSynth,
    report: &SynthReport,
) -> Result<(), SynthError> {
    let mut manifest = euroc::manifest(scenario, options.seed, imu);
    let fo = &options.frames;
    let cam = synth.camera();
    let names = |q: &[firmware_sim::sim::scenario::Quad]| -> Vec<String> {
        q.iter().map(|q| q.name.clone()).collect()
    };
    manifest["generator"] = serde_json::json!(generator());
    manifest["camera"] = serde_json::json!({
        "resolution": [cam.width, cam.height],
        "intrinsics": [cam.pinhole.fx, cam.pinhole.fy, cam.pinhole.cx, cam.pinhole.cy],
        "distortion_model": "radial-tangential",
        "distortion_coefficients": scenario.camera.distortion,
        "every_nth_imu_sample": scenario.camera.every,
        "rate_hz": scenario.imu.rate_hz / scenario.camera.every as f64,
        "exposure_s": scenario.camera.exposure,
        "exposure_note": "centred on the time stamp; motion blur from sub-frames at the mid-points of equal slots",
        "frames": report.frames,
    });
    manifest["rendering"] = serde_json::json!({
        "supersample": fo.supersample,
        "subframes": [fo.subframes, fo.max_subframes.max(fo.subframes)],
        "subframes_note": "per frame about one sub-frame per pixel of image motion, within these bounds",
        "lighting": fo.lighting,
        "read_noise": fo.read_noise,
        "shot_noise_variance_per_level": fo.shot_noise,
        "render_size": synth.render_size(),
        "texture_scale": options.textures.scale,
        "user_textures": options.textures.user_images,
        "untextured": options.textures.untextured,
        "object": options.object,
        "shading": fo.shading.map(|s| serde_json::json!({
            "ambient": s.ambient, "diffuse": s.diffuse, "specular": s.specular,
            "shininess": s.shininess, "elevation_rad": s.elevation,
            "azimuth_rad": s.azimuth.0, "azimuth_rad_per_s": s.azimuth.1,
            "dimming": s.dimming.0, "dimming_period_s": s.dimming.1,
        })),
        "adapter": report.adapter,
    });
    manifest["scene"] = serde_json::json!({
        "model": "model/scene.obj",
        "modelled": names(&scenario.scene.modelled),
        "unmodelled": names(&scenario.scene.unmodelled),
        "occluders": scenario.scene.occluders.iter().map(|o| serde_json::json!({
            "name": o.quad.name, "start_s": o.start, "duration_s": o.duration,
            "from": [o.from.x, o.from.y, o.from.z], "to": [o.to.x, o.to.y, o.to.z],
        })).collect::<Vec<_>>(),
        "note": "textures are fixed per scenario (independent of the seed); unmodelled surfaces and occluders appear only in the live frames",
    });
    manifest["statistics"] = serde_json::json!({
        "model_visible_share_10pct": report.model_visible,
        "model_any_share": report.model_any,
        "occluded_share": report.occluded,
        "generation_seconds": report.seconds,
    });
    euroc::write_json(&options.out.join("manifest.json"), &manifest)?;
    Ok(())
}

/// Generates a complete dataset; `progress(done, total)` is called after every frame.
pub fn run(
    options: &SynthOptions,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<SynthReport, SynthError> {
    let start = Instant::now();
    // Everything that can be checked is checked before anything is written.
    let scenario = options.build_scenario()?;
    options.frames.validate()?;
    let object = match &options.object {
        Some(path) => Some(
            crate::model::load(path)
                .map_err(|e| SynthError::BadOption(format!("--object {}: {e}", path.display())))?,
        ),
        None => None,
    };
    let models = SceneModels::build_with(&scenario.scene, &options.textures, object.as_ref())?;
    prepare_out(&options.out, options.overwrite)?;
    let out = &options.out;

    let imu = euroc::write_imu_dataset(out, &scenario, options.seed)?;
    write_obj(&out.join("model"), &models.model)?;
    let mut synth = FrameSynth::new(&scenario, &models, options.frames)?;
    let cam_dir = out.join("mav0/cam0");
    let data_dir = cam_dir.join("data");
    std::fs::create_dir_all(&data_dir).map_err(|e| SynthError::io(&data_dir, e))?;
    let yaml = cam_dir.join("sensor.yaml");
    std::fs::write(&yaml, cam_sensor_yaml(&scenario, synth.camera()))
        .map_err(|e| SynthError::io(&yaml, e))?;

    let mut rng = StdRng::seed_from_u64(options.seed ^ 0xc0ff_ee00_d00d_f00d);
    let indices: Vec<usize> = scenario.camera_samples().collect();
    let total = indices.len() as u64;
    let mut csv = String::from("#timestamp [ns],filename\n");
    let mut stats = String::from(
        "#timestamp [ns],model_coverage,occluder_coverage,model_unoccluded,gain,offset,gradient_u,gradient_v\n",
    );
    let (mut visible, mut any, mut occluded) = (0usize, 0usize, 0usize);
    for (done, &k) in indices.iter().enumerate() {
        if options
            .interrupt
            .as_ref()
            .is_some_and(|i| i.load(Ordering::Relaxed))
        {
            return Err(SynthError::Interrupted);
        }
        let ns = scenario.imu_ns(k);
        let f = synth.frame(&scenario, ns as f64 * 1e-9, &mut rng)?;
        let stamp = T0_NS + ns;
        let file = format!("{stamp}.png");
        let path = data_dir.join(&file);
        f.image.save(&path).map_err(|source| SynthError::Image {
            path: path.clone(),
            source,
        })?;
        let _ = writeln!(csv, "{stamp},{file}");
        let l = f.light;
        let _ = writeln!(
            stats,
            "{stamp},{:.4},{:.4},{},{:.4},{:.3},{:.4},{:.4}",
            f.model_coverage,
            f.occluder_coverage,
            f.model_unoccluded
                .map_or(String::new(), |v| format!("{v:.4}")),
            l.gain,
            l.offset,
            l.gradient_u,
            l.gradient_v
        );
        visible += usize::from(f.model_coverage >= 0.10);
        any += usize::from(f.model_coverage > 0.0);
        occluded += usize::from(f.occluder_coverage > 0.0);
        progress(done as u64 + 1, total);
    }
    let csv_path = cam_dir.join("data.csv");
    std::fs::write(&csv_path, csv).map_err(|e| SynthError::io(&csv_path, e))?;
    let stats_path = out.join("frames.csv");
    std::fs::write(&stats_path, stats).map_err(|e| SynthError::io(&stats_path, e))?;

    let n = indices.len().max(1) as f64;
    let report = SynthReport {
        scenario: scenario.name,
        duration: scenario.duration(),
        imu_samples: imu.samples.len(),
        frames: indices.len(),
        peaks: scenario.path.peaks(1e-3),
        model_visible: visible as f64 / n,
        model_any: any as f64 / n,
        occluded: occluded as f64 / n,
        saturated: imu.saturated,
        seconds: start.elapsed().as_secs_f64(),
        adapter: synth.adapter_summary(),
    };
    write_manifest(options, &scenario, &imu, &synth, &report)?;
    let mark = out.join(UNFINISHED);
    std::fs::remove_file(&mark).map_err(|e| SynthError::io(&mark, e))?;
    Ok(report)
}
