//! `host-vision`: the vision host's command line.

mod args;
mod console;
mod progress;

use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser as _;
use firmware_sim::sim::scenario::ScenarioName;

use args::{
    Cli, Command, CorpusArgs, DemoArgs, EvalArgs, FramesArgs, LocateArgs, SynthArgs, TrackArgs,
};
use console::{Failure, exit, note, say};
use progress::Bar;

/// The bar of `track`: IMU samples streamed.
const TRACK_BAR: &str = "{wide_msg} [{bar:20}] {pos}/{len} IMU samples, ETA {eta}";
/// The bar of `synth`: frames rendered.
const SYNTH_BAR: &str = "{wide_msg} [{bar:20}] {pos}/{len} frames, ETA {eta}";
/// The bar of `eval` and `demo`: the current step.
const EVAL_BAR: &str = "{wide_msg} [{bar:20}] {pos}/{len}, {elapsed}";

/// What a command ends with, when it did not fail.
enum Done {
    /// Everything done.
    Complete,
    /// `track` ran, but the core never accepted a correspondence.
    NeverTracked,
    /// `locate` ran, but found no pose.
    NotFound,
    /// Ctrl-C: what was done is written.
    Interrupted,
}

/// A flag set by Ctrl-C, SIGTERM or SIGHUP (a service manager, `kill`, a closed terminal): each
/// stops the run cleanly, its outputs written. A second signal ends the process at once.
fn interrupt_flag() -> Arc<AtomicBool> {
    let interrupt = Arc::new(AtomicBool::new(false));
    let flag = interrupt.clone();
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::Relaxed) {
            std::process::exit(exit::INTERRUPTED.into());
        }
    });
    interrupt
}

/// `--video` or `--images` of `frames` and `track`.
fn frame_input(
    video: &Option<std::path::PathBuf>,
    images: &Option<std::path::PathBuf>,
    fps: Option<f64>,
) -> Option<frames::FrameInput> {
    use frames::FrameInput;
    match (video, images) {
        (Some(v), _) => Some(FrameInput::Video(v.clone())),
        (None, Some(dir)) => Some(FrameInput::Images {
            dir: dir.clone(),
            fps,
        }),
        (None, None) => None,
    }
}

/// The camera of a `track --video/--images` run, from `--camera`, `--calib` or `--intrinsics`
/// (the last needs the frame size: the input's first frame is decoded for it).
fn track_camera(
    a: &TrackArgs,
    input: &frames::FrameInput,
) -> Result<Option<host_vision::camera::Camera>, Failure> {
    let size = || {
        let mut source = input.open(&frames::VideoOptions::default())?;
        match source.next() {
            Some(frame) => Ok(frame?.image.dimensions()),
            None => Err(Failure {
                error: anyhow::anyhow!("{}: no frames", input.path().display()),
                code: exit::FAILED,
            }),
        }
    };
    camera_from(&a.camera, &a.calib, a.intrinsics, (input.path(), size))
}

/// The camera from a camera.json, a calibration file, or pinhole intrinsics for images of the
/// size `size` reads.
fn camera_from(
    camera: &Option<std::path::PathBuf>,
    calib: &Option<std::path::PathBuf>,
    intrinsics: Option<host_vision::camera::Pinhole>,
    (input, size): (&Path, impl FnOnce() -> Result<(u32, u32), Failure>),
) -> Result<Option<host_vision::camera::Camera>, Failure> {
    use host_vision::camera::{
        MAX_IMAGE_SIDE, pinhole_camera, read_camera_json, read_euroc_sensor_yaml,
        read_kalibr_camchain,
    };
    let input = input.display();
    if let Some(path) = camera {
        return Ok(Some(read_camera_json(path)?));
    }
    if let Some(path) = calib {
        let calib = match read_kalibr_camchain(path) {
            Ok(mut cams) if !cams.is_empty() => cams.swap_remove(0),
            _ => read_euroc_sensor_yaml(path)?,
        };
        return Ok(Some(calib.camera));
    }
    let Some(p) = intrinsics else {
        return Ok(None);
    };
    let (w, h) = size()?;
    // The size is the input's: an absurd one is the input's fault, not the intrinsics'.
    if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(Failure {
            error: anyhow::anyhow!(
                "{input}: the frames are {w}x{h} pixels: each side must be 1 to {MAX_IMAGE_SIDE}"
            ),
            code: exit::FAILED,
        });
    }
    Ok(Some(pinhole_camera(w, h, p).map_err(|e| Failure {
        error: anyhow::anyhow!("--intrinsics: {e}"),
        code: exit::USAGE,
    })?))
}

/// `locate`: the model found in one image with no pose given.
fn locate(a: &LocateArgs) -> Result<Done, Failure> {
    use host_vision::locate::database::{DatabaseConfig, default_cache_dir};
    use host_vision::locate::run::{LocateInput, LocateOptions, run};
    let input = match (&a.image, &a.video) {
        (Some(p), _) => LocateInput::Image(p.clone()),
        (None, Some(v)) => LocateInput::VideoFrame {
            video: v.clone(),
            frame: a.frame,
        },
        (None, None) => {
            return Err(Failure {
                error: anyhow::anyhow!("give --image FILE, or --video FILE with --frame N"),
                code: exit::USAGE,
            });
        }
    };
    let path = match &input {
        LocateInput::Image(p) | LocateInput::VideoFrame { video: p, .. } => p.as_path(),
    };
    let size = || match &input {
        LocateInput::Image(p) => {
            Ok(image::image_dimensions(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?)
        }
        LocateInput::VideoFrame { video, .. } => {
            let input = frames::FrameInput::Video(video.clone());
            let mut source = input.open(&frames::VideoOptions::default())?;
            match source.next() {
                Some(frame) => Ok(frame?.image.dimensions()),
                None => Err(anyhow::anyhow!("{}: no frames", video.display()).into()),
            }
        }
    };
    let camera =
        camera_from(&a.camera, &a.calib, a.intrinsics, (path, size))?.ok_or_else(|| Failure {
            error: anyhow::anyhow!("give the camera: --camera, --calib or --intrinsics"),
            code: exit::USAGE,
        })?;
    let options = LocateOptions {
        input,
        model: a.model.clone(),
        camera,
        cache: a.cache.clone().unwrap_or_else(default_cache_dir),
        out: a.out.clone(),
        overwrite: a.overwrite,
        database: DatabaseConfig::default(),
        locate: Default::default(),
    };
    let mut bar = Bar::new(EVAL_BAR);
    let report = run(&options, &mut |done, total| {
        bar.update(
            "building the viewpoint database (cached for the next run)",
            done as u64,
            total as u64,
        )
    })?;
    bar.finish();
    say!("{report}");
    // A search that found nothing is not a success (issue 33: it exited 0).
    Ok(if report.accepted {
        Done::Complete
    } else {
        Done::NotFound
    })
}

fn frames(a: &FramesArgs) -> Result<Done, Failure> {
    use frames::{DecodeStats, VideoOptions};
    use host_vision::camera::{pinhole_camera, read_camera_json};
    let usage = |m: String| Failure {
        error: anyhow::anyhow!(m),
        code: exit::USAGE,
    };
    let Some(input) = frame_input(&a.video, &a.images, a.fps) else {
        return Err(usage("give --video FILE or --images DIR".into()));
    };
    if a.max_frames == Some(0) {
        return Err(usage("--max-frames must be at least 1".into()));
    }
    // The calibration is read and checked against the first frame before the whole input is
    // decoded: a wrong one is said at once (issue 33: all 989 frames were decoded and the
    // report printed first), as a usage error, as `track` says it.
    let camera = a.camera.as_deref().map(read_camera_json).transpose()?;
    if a.intrinsics.is_some() || camera.is_some() {
        let mut first = input.open(&VideoOptions::default())?;
        let (w, h) = match first.next() {
            Some(frame) => frame?.image.dimensions(),
            None => return Err(anyhow::anyhow!("{}: no frames", input.path().display()).into()),
        };
        if let Some(p) = a.intrinsics {
            pinhole_camera(w, h, p).map_err(|e| usage(format!("--intrinsics: {e}")))?;
        }
        if let (Some(c), Some(path)) = (&camera, &a.camera)
            && (c.width, c.height) != (w, h)
        {
            return Err(usage(format!(
                "--camera {}: the calibration is for {}x{} images, the frames are {w}x{h}",
                path.display(),
                c.width,
                c.height
            )));
        }
    }
    let source = input.open(&VideoOptions::default())?;
    let stats = DecodeStats::collect(source, a.max_frames, &mut |_| {})?;
    say!("{}", input.path().display());
    say!("{stats}");
    if let Some(p) = a.intrinsics {
        let (w, h) = stats.size;
        say!(
            "intrinsics:    fx {} fy {} cx {} cy {}, no distortion: fit the {w}x{h} frames",
            p.fx,
            p.fy,
            p.cx,
            p.cy
        );
    }
    if let (Some(c), Some(path)) = (camera, &a.camera) {
        say!(
            "camera:        {} fits the frames (fx {} fy {} cx {} cy {})",
            path.display(),
            c.pinhole.fx,
            c.pinhole.fy,
            c.pinhole.cx,
            c.pinhole.cy
        );
    }
    Ok(Done::Complete)
}

/// The filter model of `track`: `--filter`, else acc with an IMU, else the vision-only one
/// (said, with why).
fn track_filter(a: &TrackArgs, dataset: &Path, camera_only: bool) -> protocol::ModelKind {
    match a.filter {
        Some(f) => f.into(),
        None if !camera_only => protocol::ModelKind::Acc,
        None => {
            // Said of an input that is there: a missing one is named by its error alone.
            let with_imu = a.images.is_some()
                && [
                    dataset.join("mav0/imu0/data.csv"),
                    dataset.join("../imu0/data.csv"),
                ]
                .iter()
                .any(|p| p.exists());
            if with_imu {
                note!(
                    "{}: --images takes the frames alone, vision-only (--filter vision): the IMU beside them is not used; --dataset tracks them with it",
                    dataset.display()
                );
            } else if dataset.exists() {
                note!(
                    "{}: no IMU: tracking vision-only (--filter vision)",
                    dataset.display()
                );
            }
            protocol::ModelKind::Vision
        }
    }
}

/// The options of `track` from its arguments.
fn track_options(
    a: &TrackArgs,
    dataset: &Path,
    filter: protocol::ModelKind,
    input: Option<frames::FrameInput>,
    camera: Option<host_vision::camera::Camera>,
) -> Result<host_vision::track::TrackOptions, Failure> {
    use host_vision::track::{self, Faults, Start, TrackError};
    let pose = a
        .start_pose
        .as_deref()
        .map(|p| {
            host_vision::start_pose::read_start_pose(p)
                .map_err(|e| TrackError::Option(format!("--start-pose {}: {e}", p.display())))
        })
        .transpose()?;
    let mut o = host_vision::eval::options_for(dataset, a.out.clone())?;
    o.model = a.model.clone();
    o.link = a.link.clone();
    o.filter = filter;
    o.frames = input;
    o.camera = camera;
    o.max_frames = a.max_frames;
    if let Some(c) = &a.cache {
        o.cache = c.clone();
    }
    o.pacing = a.pacing;
    o.latency = a.latency.unwrap_or(o.latency);
    o.vision.map.subset_size = a.features;
    o.modality = a.modality.modality();
    o.duration = a.duration;
    o.overwrite = a.overwrite;
    o.start = Start {
        position: a.start_position,
        yaw: a.start_yaw.map(f64::to_radians),
        pose,
        cold: a.cold_start,
    };
    // A video or image folder usually shows an object moved by a hand in front of a camera.
    if o.frames.is_some() {
        o.tuning.expected_accel = track::config::OBJECT_IN_HAND_ACCEL;
        o.tuning.angular_noise = track::config::OBJECT_IN_HAND_ANGULAR_NOISE;
    }
    if let Some(accel) = a.expected_accel {
        o.tuning.expected_accel = accel;
    }
    if let Some(angular) = a.angular_noise {
        o.tuning.angular_noise = angular;
    }
    o.tuning.accel_noise = a.accel_meas_noise;
    o.overlay_every = a.overlay_every;
    o.faults = Faults {
        outlier_fraction: a.outliers,
        corrupt_from: a.corrupt_at,
        corrupt_seconds: 0.3,
        blind_from: a.blind_at,
        blind_seconds: 2.0,
        line_errors: a.line_errors,
        reset_core_at: a.reset_core_at,
        cut_link_at: a.cut_link_at,
        cut_seconds: a.cut_seconds.unwrap_or(0.5),
        seed: 1,
    };
    o.attach = a.attach;
    o.imu_on_core = a.imu_on_core;
    Ok(o)
}

fn track(a: &TrackArgs) -> Result<Done, Failure> {
    use host_vision::track::{self, TrackError};
    let input = frame_input(&a.video, &a.images, a.fps);
    let dataset = match (&input, &a.dataset) {
        (Some(i), _) => i.path().to_owned(),
        (None, Some(d)) => d.clone(),
        (None, None) => {
            return Err(Failure {
                error: anyhow::anyhow!("give --dataset DIR, --video FILE or --images DIR"),
                code: exit::USAGE,
            });
        }
    };
    // Without an IMU (a video, an image folder, a dataset without mav0/imu0) the model is
    // vision-only, and a run says so.
    let camera_only = input.is_some()
        || (dataset.join("mav0/cam0/data.csv").exists()
            && !dataset.join("mav0/imu0/data.csv").exists());
    let filter = track_filter(a, &dataset, camera_only);
    ignored_options(a, filter)?;
    let camera = match &input {
        Some(i) => track_camera(a, i)?,
        None if a.camera.is_some() || a.calib.is_some() || a.intrinsics.is_some() => {
            return Err(Failure {
                error: anyhow::anyhow!(
                    "--camera, --calib and --intrinsics give the camera of --video or --images; a dataset has its own (mav0/cam0/sensor.yaml)"
                ),
                code: exit::USAGE,
            });
        }
        None => None,
    };
    let o = track_options(a, &dataset, filter, input, camera)?;
    let interrupt = interrupt_flag();
    let mut bar = Bar::new(TRACK_BAR);
    let name = format!("track {:?}", o.filter).to_lowercase();
    let result = track::run(&o, interrupt.clone(), &mut |done, total, frames, mode| {
        let mode = mode.map(|m| format!(", {m:?}")).unwrap_or_default();
        bar.update(
            &format!("{name}: {frames} frames{mode}"),
            done as u64,
            total as u64,
        );
    });
    bar.finish();
    let run = match result {
        Ok(run) => run,
        Err(TrackError::Stopped {
            error,
            out,
            written,
        }) => {
            // What was tracked before the failure is written: said before the error.
            let (summary, files) = *written;
            say!("{summary}");
            list_outputs(&out, &files);
            return Err(TrackError::Stopped {
                error,
                out,
                written: Box::new((summary, Vec::new())),
            }
            .into());
        }
        Err(e) => return Err(e.into()),
    };
    say!("{}", run.summary);
    let interrupted = interrupt.load(Ordering::Relaxed);
    if interrupted {
        say!("interrupted: wrote what was tracked");
    }
    list_outputs(&a.out, &run.written);
    if interrupted {
        return Ok(Done::Interrupted);
    }
    if run.summary.snapped_on_at.is_none() {
        note!(
            "tracking never started: the core accepted none of the {} correspondences sent over {} frames; check the start pose (--start-pose, or --start-position and --start-yaw), the model and the calibration",
            run.summary.correspondences_sent,
            run.summary.frames
        );
        return Ok(Done::NeverTracked);
    }
    Ok(Done::Complete)
}

/// Options that a run of `filter` would not use, refused with the reason (issue 54: they were
/// silently ignored).
fn ignored_options(a: &TrackArgs, filter: protocol::ModelKind) -> Result<(), Failure> {
    let vision_only = !filter.has_imu();
    let euroc = a.images.as_deref().and_then(frames::images::euroc_cam0);
    let why = if a.fps.is_some() && (a.images.is_none() || euroc.is_some()) {
        Some(
            "--fps is the frame rate of a plain --images folder: a video, a dataset and a EuRoC camera folder (data.csv) carry their own time stamps",
        )
    } else if a.max_frames.is_some() && !vision_only {
        Some(
            "--max-frames counts the frames of a vision-only run: with an IMU, --duration limits the run",
        )
    } else if a.latency.is_some() && vision_only {
        Some(
            "--latency delays the correspondences after their IMU trigger: a vision-only run has no trigger to wait from",
        )
    } else if a.latency.is_some() && a.pacing == host_vision::track::Pacing::RealTime {
        Some(
            "--latency is the lock-step replay's delay: with --pacing real-time the correspondences go as soon as they are ready",
        )
    } else {
        None
    };
    match why {
        Some(why) => Err(Failure {
            error: anyhow::anyhow!("{why}"),
            code: exit::USAGE,
        }),
        None => Ok(()),
    }
}

/// Lists the files written, the overlay images as their folder and count.
fn list_outputs(out: &Path, written: &[std::path::PathBuf]) {
    let overlays = out.join("overlays");
    say!("results in {}:", out.display());
    for p in written.iter().filter(|p| !p.starts_with(&overlays)) {
        say!("  {}", p.display());
    }
    let n = written.iter().filter(|p| p.starts_with(&overlays)).count();
    if n > 0 {
        let images = if n == 1 { "image" } else { "images" };
        say!("  {} ({n} overlay {images})", overlays.display());
    }
}

fn synth(a: &SynthArgs) -> Result<Done, Failure> {
    use host_vision::synth::{FrameOptions, SynthOptions, TextureOptions, run};
    if !(a.texture_scale.is_finite() && a.texture_scale > 0.0 && a.texture_scale <= 4.0) {
        return Err(Failure {
            error: anyhow::anyhow!("--texture-scale must be in (0, 4], got {}", a.texture_scale),
            code: exit::USAGE,
        });
    }
    if a.max_subframes < a.subframes {
        return Err(Failure {
            error: anyhow::anyhow!(
                "--max-subframes {} is below --subframes {}: the most sub-frames must be no fewer than the fewest",
                a.max_subframes,
                a.subframes
            ),
            code: exit::USAGE,
        });
    }
    let mut frames = FrameOptions::new(a.resolution.0, a.resolution.1);
    frames.subframes = a.subframes;
    frames.max_subframes = a.max_subframes;
    frames.supersample = a.supersample;
    frames.shading = a.lit.then(host_vision::synth::Shading::default);
    if a.ideal {
        frames.lighting = false;
        frames.read_noise = 0.0;
        frames.shot_noise = 0.0;
    }
    let overridden = [a.gyro_noise, a.gyro_walk, a.accel_noise, a.accel_walk];
    let imu_noise = overridden.iter().any(Option::is_some).then(|| {
        let d = firmware_sim::sim::imu::ImuNoise::MT9;
        firmware_sim::sim::imu::ImuNoise {
            gyro_density: a.gyro_noise.unwrap_or(d.gyro_density),
            gyro_walk: a.gyro_walk.unwrap_or(d.gyro_walk),
            accel_density: a.accel_noise.unwrap_or(d.accel_density),
            accel_walk: a.accel_walk.unwrap_or(d.accel_walk),
        }
    });
    let options = SynthOptions {
        seed: a.seed,
        duration: a.duration,
        rates: Some((a.imu_rate, a.camera_every)),
        ideal_imu: a.ideal,
        imu_noise,
        frames,
        textures: TextureOptions {
            scale: a.texture_scale,
            user_images: a.textures.clone(),
            untextured: a.untextured.then_some(
                a.untextured_colour
                    .unwrap_or(host_vision::synth::UNTEXTURED_COLOUR),
            ),
            ..TextureOptions::generated()
        },
        object: a.object.clone(),
        overwrite: a.overwrite,
        interrupt: Some(interrupt_flag()),
        ..SynthOptions::new(a.scenario, a.out.clone())
    };
    let mut bar = Bar::new(SYNTH_BAR);
    let label = format!("synth {}", a.scenario);
    let report = match run(&options, &mut |done, total| bar.update(&label, done, total)) {
        Ok(report) => report,
        Err(host_vision::synth::SynthError::Interrupted) => {
            bar.finish();
            // Half a dataset is no dataset: what this run wrote goes (the user's files stay).
            host_vision::synth::remove_written(&a.out)?;
            say!(
                "interrupted: the unfinished dataset was removed from {}",
                a.out.display()
            );
            return Ok(Done::Interrupted);
        }
        Err(e) => {
            return Err(anyhow::Error::from(e)
                .context(format!(
                    "generating {} into {}",
                    a.scenario,
                    a.out.display()
                ))
                .into());
        }
    };
    bar.finish();
    say!("{report}");
    say!("dataset written to {}", a.out.display());
    Ok(Done::Complete)
}

/// Runs an evaluation with one progress bar per step (synthesis, each tracking run) and a
/// line per finished run (also without a terminal, where the bar is not drawn).
fn run_eval(
    options: &host_vision::eval::EvalOptions,
) -> anyhow::Result<host_vision::eval::EvalReport> {
    use host_vision::eval::EvalEvent;
    let mut bar = Bar::new(EVAL_BAR);
    let report = host_vision::eval::run(options, &mut |event| match event {
        EvalEvent::Step { what, done, total } => bar.update(what, done, total),
        EvalEvent::RunDone(row) => {
            let s = &row.summary;
            let px = s
                .mean_prediction_error_px
                .map_or("n/a".into(), |v| format!("{v:.2} px"));
            let snap = s.snapped_on_at.map_or("never snapped on".into(), |t| {
                format!("snapped on at {t:.2} s")
            });
            bar.say(&format!(
                "done: {} {} model{}: prediction error {px}, {snap}, {} divergences, {:.1} s{}",
                row.scenario,
                row.model,
                if row.features == 2 {
                    " (2 features)"
                } else {
                    ""
                },
                s.divergences.len(),
                s.wall_s,
                if s.stopped_early {
                    " (stopped early)"
                } else {
                    ""
                },
            ));
        }
    });
    bar.clear();
    Ok(report?)
}

fn eval(a: &EvalArgs) -> Result<Done, Failure> {
    use host_vision::eval::EvalOptions;
    let options = EvalOptions {
        scenarios: if a.scenarios.is_empty() {
            ScenarioName::ALL.to_vec()
        } else {
            a.scenarios.clone()
        },
        models: if a.filters.is_empty() {
            // The paper's three models, and vision-only with the IMU withheld.
            protocol::ModelKind::ALL.to_vec()
        } else {
            a.filters.iter().map(|&f| f.into()).collect()
        },
        duration: a.duration,
        cache: a.cache.clone(),
        out: a.out.clone(),
        seed: a.seed,
        link: a.link.clone(),
        two_features: !a.no_two_features,
        overlay_every: a.overlay_every,
        overwrite: a.overwrite,
        interrupt: interrupt_flag(),
    };
    let report = run_eval(&options)?;
    if report.rows.is_empty() {
        say!("interrupted before any run finished: nothing written");
        return Ok(Done::Interrupted);
    }
    say!("{}", report.markdown());
    say!(
        "written: {} and {}, plots and each run's outputs in {}",
        a.out.join("eval.md").display(),
        a.out.join("eval.json").display(),
        a.out.display()
    );
    if report.interrupted {
        say!("interrupted: wrote the runs done");
        return Ok(Done::Interrupted);
    }
    Ok(Done::Complete)
}

fn corpus(a: &CorpusArgs) -> Result<Done, Failure> {
    use host_vision::corpus::{CorpusEvent, CorpusOptions};
    let options = CorpusOptions {
        quick: a.quick,
        only: a.scenes.clone(),
        cache: a.cache.clone(),
        out: a.out.clone(),
        seed: a.seed,
        data: a.data.clone(),
        overwrite: a.overwrite,
        interrupt: interrupt_flag(),
    };
    let mut bar = Bar::new(EVAL_BAR);
    let report = host_vision::corpus::run(&options, &mut |event| match event {
        CorpusEvent::Step { what, done, total } => bar.update(what, done, total),
        CorpusEvent::RunDone(row) => {
            let c = &row.score;
            let share = |v: Option<f64>| v.map_or("-".into(), |v| format!("{:.1} %", 100.0 * v));
            bar.say(&format!(
                "done: {} {}: {} frames, right {}, tracked {} (precision {}, recall {}, half visible {}), {} wrong stretches, {} never reported",
                row.scene.name,
                row.filter,
                c.frames,
                share(c.success),
                c.tracked,
                share(c.precision),
                share(c.recall),
                share(c.recall_half_visible),
                c.report_delays.len(),
                c.unreported()
            ));
        }
        CorpusEvent::Skipped(scene, why) => bar.say(&format!("skipped: {}: {why}", scene.name)),
    });
    bar.clear();
    let report = report.map_err(anyhow::Error::from)?;
    if report.rows.is_empty() {
        say!("interrupted before any run finished: nothing written");
        return Ok(Done::Interrupted);
    }
    say!("{}", report.markdown());
    say!(
        "written: {} and {}, and each run's outputs in {}",
        a.out.join("corpus.md").display(),
        a.out.join("corpus.json").display(),
        a.out.display()
    );
    if report.interrupted {
        say!("interrupted: wrote the runs done");
        return Ok(Done::Interrupted);
    }
    Ok(Done::Complete)
}

fn demo(a: &DemoArgs) -> Result<Done, Failure> {
    use host_vision::eval::EvalOptions;
    let scenario = ScenarioName::DesktopFast;
    // Ctrl-C is taken from before the first line: a user (or a test) that interrupts as soon as
    // it appears gets the clean stop, not the default signal death.
    let interrupt = interrupt_flag();
    say!(
        "demo: {scenario} ({} s), tracked by the acc and gyro models; the core: {}",
        a.duration,
        a.link
    );
    let options = EvalOptions {
        scenarios: vec![scenario],
        models: vec![protocol::ModelKind::Gyro, protocol::ModelKind::Acc],
        duration: Some(a.duration),
        cache: a.cache.clone(),
        out: a.out.clone(),
        seed: 0,
        link: a.link.clone(),
        two_features: false,
        overlay_every: 10,
        overwrite: a.overwrite,
        interrupt,
    };
    let report = run_eval(&options)?;
    if report.rows.is_empty() {
        say!("interrupted before any run finished: nothing written");
        return Ok(Done::Interrupted);
    }
    for row in &report.rows {
        say!("── {} model\n{}", row.model, row.summary);
    }
    say!("{}", report.markdown());
    if report.interrupted {
        say!("interrupted: wrote the runs done, in {}", a.out.display());
        return Ok(Done::Interrupted);
    }
    let acc = a.out.join(scenario.as_str()).join("acc");
    say!("look at:");
    say!(
        "  {}   overlays: registered features (green), failed (red), the model's axes",
        acc.join("overlays").display()
    );
    say!(
        "  {}   prediction error of both models (the paper's Fig. 5)",
        a.out
            .join(format!("{scenario}_prediction_error.svg"))
            .display()
    );
    say!(
        "  {}   camera position error against ground truth",
        acc.join("plots/position_error.svg").display()
    );
    say!(
        "  {}   camera trajectory (TUM, for evo; ground truth beside it)",
        acc.join("trajectory.tum").display()
    );
    say!("  {}   the table above", a.out.join("eval.md").display());
    Ok(Done::Complete)
}

fn selftest(imu_samples: u32) -> Result<Done, Failure> {
    let report = host_vision::selftest::run_over_pty(imu_samples as usize)?;
    say!("{report}");
    say!("self-test passed");
    Ok(Done::Complete)
}

/// Mesa's Vulkan and EGL drivers print "XDG_RUNTIME_DIR is invalid or not set" on headless
/// machines, where it is harmless; give them a private folder instead.
#[allow(unsafe_code)]
fn set_runtime_dir() {
    let usable = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| Path::new(&d).is_dir());
    if !usable {
        let dir = std::env::temp_dir();
        // SAFETY: called first thing in `main`, before any other thread exists, so no one
        // reads the environment concurrently.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", dir) };
    }
}

fn main() -> ExitCode {
    set_runtime_dir();
    let done = match Cli::parse().command {
        Command::Selftest { imu_samples } => selftest(imu_samples),
        Command::Synth(args) => synth(&args),
        Command::Track(args) => track(&args),
        Command::Frames(args) => frames(&args),
        Command::Eval(args) => eval(&args),
        Command::Corpus(args) => corpus(&args),
        Command::Demo(args) => demo(&args),
        Command::Locate(args) => locate(&args),
    };
    match done {
        Ok(Done::Complete) => ExitCode::SUCCESS,
        Ok(Done::NeverTracked | Done::NotFound) => ExitCode::from(exit::NEVER_TRACKED),
        Ok(Done::Interrupted) => ExitCode::from(exit::INTERRUPTED),
        Err(f) => console::report(f),
    }
}
