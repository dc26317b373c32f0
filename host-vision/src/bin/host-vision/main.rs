//! `host-vision`: the vision host's command line.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use firmware_sim::sim::scenario::ScenarioName;

/// Vision host of the visual-inertial tracker.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Protocol loop-back self-test over a pty pair (a real serial line in one process).
    Selftest {
        /// IMU samples to stream through the link.
        #[arg(long, default_value_t = 2000)]
        imu_samples: usize,
    },
    /// Writes a synthetic EuRoC-format dataset of one of the paper's test cases.
    Synth(Box<SynthArgs>),
    /// Tracks a EuRoC-layout dataset with the fusion core at the other end of a link.
    Track(Box<TrackArgs>),
    /// The paper's experiments: every scenario with every model; Table 2 and accuracy.
    Eval(Box<EvalArgs>),
    /// The demo: synthesises the fast desktop sequence (cached), tracks it with the acc and
    /// gyro models over the simulated serial link, prints the summary and where the images are.
    Demo(Box<DemoArgs>),
}

/// Options of `demo`.
#[derive(clap::Args, Debug)]
struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "target/demo/out")]
    out: PathBuf,
    /// Where the synthetic dataset is cached.
    #[arg(long, default_value = "target/demo/datasets")]
    cache: PathBuf,
    /// Seconds of the sequence.
    #[arg(long, default_value_t = 15.0)]
    duration: f64,
    /// The core: sim, sim:f64, serial:PATH[@BAUD], tcp:ADDR, qemu or qemu:IMAGE.
    #[arg(long, default_value = "sim")]
    link: host_vision::track::LinkSpec,
}

/// Options of `eval`.
#[derive(clap::Args, Debug)]
struct EvalArgs {
    /// Output folder (eval.md, eval.json, plots, and each run's outputs).
    #[arg(long, default_value = "eval-out")]
    out: PathBuf,
    /// Where synthetic datasets are cached.
    #[arg(long, default_value = "datasets")]
    cache: PathBuf,
    /// Scenarios (repeatable; default: all four).
    #[arg(long = "scenario", value_enum)]
    scenarios: Vec<ScenarioName>,
    /// Models (repeatable; default: gyro, gravity, acc).
    #[arg(long = "filter", value_enum)]
    filters: Vec<FilterArg>,
    /// Shorter scenarios [s] (default: their nominal lengths).
    #[arg(long)]
    duration: Option<f64>,
    /// Seed of the synthetic sensors.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The core: sim, sim:f64, serial:PATH[@BAUD], tcp:ADDR, qemu or qemu:IMAGE.
    #[arg(long, default_value = "sim")]
    link: host_vision::track::LinkSpec,
    /// Skip the two-feature run on desktop-slow (the paper's Fig. 6).
    #[arg(long)]
    no_two_features: bool,
    /// Overlay images every N frames (0: none).
    #[arg(long, default_value_t = 0)]
    overlay_every: usize,
}

/// Options of `track`.
#[derive(clap::Args, Debug)]
struct TrackArgs {
    /// Dataset folder (holding mav0/).
    #[arg(long)]
    dataset: PathBuf,
    /// Output folder (trajectories, frames.csv, summary.json, overlays/, plots/).
    #[arg(long)]
    out: PathBuf,
    /// Model file (.obj, .gltf, .glb); default: the dataset's model/scene.obj.
    #[arg(long)]
    model: Option<PathBuf>,
    /// The core: sim, sim:f64, serial:PATH[@BAUD], tcp:ADDR, qemu or qemu:IMAGE.
    #[arg(long, default_value = "sim")]
    link: host_vision::track::LinkSpec,
    /// Filter model.
    #[arg(long, value_enum, default_value = "acc")]
    filter: FilterArg,
    /// IMU pacing.
    #[arg(long, value_enum, default_value = "lock-step")]
    pacing: host_vision::track::Pacing,
    /// Trigger-to-correspondences latency in lock-step mode [s] (below one frame period, so
    /// that each prediction has the previous frame's update).
    #[arg(long, default_value_t = 0.03)]
    latency: f64,
    /// Features registered per frame.
    #[arg(long, default_value_t = 40)]
    features: usize,
    /// Track only the first N seconds.
    #[arg(long)]
    duration: Option<f64>,
    /// Start position of the IMU `x,y,z` [m] (default: from the ground truth).
    #[arg(long, value_parser = parse_vec3)]
    start_position: Option<[f64; 3]>,
    /// Start yaw of the IMU [deg] (default: from the ground truth).
    #[arg(long)]
    start_yaw: Option<f64>,
    /// Peak free acceleration expected [m/s²] (scales the motion noise; default: from a
    /// synthetic dataset's manifest, else 10).
    #[arg(long)]
    expected_accel: Option<f64>,
    /// Accelerometer measurement noise [m/s²] (default: per model).
    #[arg(long)]
    accel_noise: Option<f64>,
    /// Angular-acceleration noise density [rad/s²/√Hz].
    #[arg(long, default_value_t = 10.0)]
    angular_noise: f64,
    /// Write an overlay image every N frames (0: none).
    #[arg(long, default_value_t = 25)]
    overlay_every: usize,
    /// Replace this fraction of correspondences by outliers (robustness tests).
    #[arg(long, default_value_t = 0.0)]
    outliers: f64,
    /// Corrupt all correspondences for 0.3 s from this time [s] (forces a divergence).
    #[arg(long)]
    corrupt_at: Option<f64>,
}

/// Filter model on the command line.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum FilterArg {
    Gyro,
    Gravity,
    Acc,
}

impl From<FilterArg> for protocol::ModelKind {
    fn from(f: FilterArg) -> Self {
        match f {
            FilterArg::Gyro => protocol::ModelKind::Gyro,
            FilterArg::Gravity => protocol::ModelKind::Gravity,
            FilterArg::Acc => protocol::ModelKind::Acc,
        }
    }
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

fn progress_bar(template: &str) -> anyhow::Result<indicatif::ProgressBar> {
    use anyhow::Context as _;
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(template)
            .context("progress bar template")?
            .progress_chars("=> "),
    );
    Ok(bar)
}

fn track(a: &TrackArgs) -> anyhow::Result<()> {
    use host_vision::track::{self, Faults, Start};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    if !(0.0..=1.0).contains(&a.outliers) {
        anyhow::bail!(
            "--outliers must be a fraction in [0, 1], got {}",
            a.outliers
        );
    }
    let mut o = host_vision::eval::options_for(&a.dataset, a.out.clone());
    o.model = a.model.clone();
    o.link = a.link.clone();
    o.filter = a.filter.into();
    o.pacing = a.pacing;
    o.latency = a.latency;
    o.vision.map.subset_size = a.features;
    o.duration = a.duration;
    o.start = Start {
        position: a.start_position,
        yaw: a.start_yaw.map(f64::to_radians),
    };
    if let Some(accel) = a.expected_accel {
        o.tuning.expected_accel = accel;
    }
    o.tuning.angular_noise = a.angular_noise;
    o.tuning.accel_noise = a.accel_noise;
    o.overlay_every = a.overlay_every;
    o.faults = Faults {
        outlier_fraction: a.outliers,
        corrupt_from: a.corrupt_at,
        corrupt_seconds: 0.3,
        seed: 1,
    };
    let interrupt = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupt.clone();
        // A second Ctrl-C kills the process as usual.
        let _ = ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::Relaxed) {
                std::process::exit(130);
            }
        });
    }
    let bar =
        progress_bar("{msg} [{bar:40}] {pos}/{len} IMU samples, {elapsed} elapsed, ETA {eta}")?;
    let name = format!("track {:?}", o.filter).to_lowercase();
    let result = track::run(&o, interrupt.clone(), &mut |done, total, frames, mode| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(format!(
            "{name}: {frames} frames, {}",
            mode.map(|m| format!("{m:?}")).unwrap_or_default()
        ));
    });
    bar.finish();
    let run = result?;
    println!("{}", run.summary);
    let interrupted = interrupt.load(Ordering::Relaxed);
    if interrupted {
        println!("interrupted: wrote what was tracked");
    }
    println!("results in {}:", a.out.display());
    for p in run
        .written
        .iter()
        .filter(|p| !p.starts_with(a.out.join("overlays")))
    {
        println!("  {}", p.display());
    }
    let overlays = run
        .written
        .iter()
        .filter(|p| p.starts_with(a.out.join("overlays")))
        .count();
    if overlays > 0 {
        println!(
            "  {} ({overlays} overlay images)",
            a.out.join("overlays").display()
        );
    }
    if interrupted {
        // The shell's convention for a run ended by Ctrl-C.
        std::process::exit(130);
    }
    Ok(())
}

/// Options of `synth`.
#[derive(clap::Args, Debug)]
struct SynthArgs {
    /// Test case.
    #[arg(long, value_enum)]
    scenario: ScenarioName,
    /// Output folder (created; must not already hold a dataset unless --overwrite).
    #[arg(long)]
    out: PathBuf,
    /// Seed of sensor noise, biases and vibration.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Image size WxH.
    #[arg(long, default_value = "320x240", value_parser = parse_resolution)]
    resolution: (u32, u32),
    /// Duration in seconds (default: the scenario's).
    #[arg(long)]
    duration: Option<f64>,
    /// IMU rate in Hz.
    #[arg(long, default_value_t = 100.0)]
    imu_rate: f64,
    /// One camera frame every N IMU samples.
    #[arg(long, default_value_t = 4)]
    camera_every: u32,
    /// Fewest sub-frames averaged over the exposure (with --max-subframes 1: 1 means no
    /// motion blur).
    #[arg(long, default_value_t = 4)]
    subframes: u32,
    /// Most sub-frames (fast frames get about one per pixel of image motion).
    #[arg(long, default_value_t = 32)]
    max_subframes: u32,
    /// Render supersampling per axis (1-4).
    #[arg(long, default_value_t = 2)]
    supersample: u32,
    /// Texel density factor of the generated textures.
    #[arg(long, default_value_t = 1.0)]
    texture_scale: f64,
    /// Image for the modelled surfaces instead of generated textures (repeatable).
    #[arg(long = "texture")]
    textures: Vec<PathBuf>,
    /// Noise-free IMU and frames (no noise, biases, vibration, clipping, lighting changes).
    #[arg(long)]
    ideal: bool,
    /// Gyro white-noise density [rad/s/√Hz] (default: the MT9-class 1e-3).
    #[arg(long, value_parser = parse_density)]
    gyro_noise: Option<f64>,
    /// Gyro bias random walk [rad/s²/√Hz] (default: 2e-5).
    #[arg(long, value_parser = parse_density)]
    gyro_walk: Option<f64>,
    /// Accelerometer white-noise density [m/s²/√Hz] (default: 2e-3).
    #[arg(long, value_parser = parse_density)]
    accel_noise: Option<f64>,
    /// Accelerometer bias random walk [m/s³/√Hz] (default: 1e-4).
    #[arg(long, value_parser = parse_density)]
    accel_walk: Option<f64>,
    /// Replace a dataset already in the output folder.
    #[arg(long)]
    overwrite: bool,
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

fn synth(a: &SynthArgs) -> anyhow::Result<()> {
    use anyhow::Context as _;
    use host_vision::synth::{FrameOptions, SynthOptions, TextureOptions, run};
    if !(a.texture_scale.is_finite() && a.texture_scale > 0.0 && a.texture_scale <= 4.0) {
        anyhow::bail!("--texture-scale must be in (0, 4], got {}", a.texture_scale);
    }
    let mut frames = FrameOptions::new(a.resolution.0, a.resolution.1);
    frames.subframes = a.subframes;
    frames.max_subframes = a.max_subframes;
    frames.supersample = a.supersample;
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
            ..TextureOptions::generated()
        },
        overwrite: a.overwrite,
        ..SynthOptions::new(a.scenario, a.out.clone())
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} frames, {elapsed} elapsed, ETA {eta}",
        )
        .context("progress bar template")?
        .progress_chars("=> "),
    );
    bar.set_message(format!("synth {}", a.scenario));
    let report = run(&options, &mut |done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })
    .with_context(|| format!("generating {} into {}", a.scenario, a.out.display()))?;
    bar.finish();
    println!("{report}");
    println!("dataset written to {}", a.out.display());
    Ok(())
}

/// Runs an evaluation with one progress bar per step (synthesis, each tracking run).
fn run_eval(
    options: &host_vision::eval::EvalOptions,
) -> anyhow::Result<host_vision::eval::EvalReport> {
    let bar = progress_bar("{msg:32} [{bar:40}] {pos}/{len}, {elapsed} elapsed")?;
    let report = host_vision::eval::run(options, &mut |what, done, total| {
        if bar.message() != what {
            bar.set_message(what.to_string());
            bar.reset();
        }
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    Ok(report)
}

fn eval(a: &EvalArgs) -> anyhow::Result<()> {
    use host_vision::eval::EvalOptions;
    let options = EvalOptions {
        scenarios: if a.scenarios.is_empty() {
            ScenarioName::ALL.to_vec()
        } else {
            a.scenarios.clone()
        },
        models: if a.filters.is_empty() {
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
    };
    let report = run_eval(&options)?;
    println!("{}", report.markdown());
    println!(
        "written: {} and {}, plots and each run's outputs in {}",
        a.out.join("eval.md").display(),
        a.out.join("eval.json").display(),
        a.out.display()
    );
    Ok(())
}

fn demo(a: &DemoArgs) -> anyhow::Result<()> {
    use host_vision::eval::EvalOptions;
    let scenario = ScenarioName::DesktopFast;
    println!(
        "demo: {scenario} ({} s), tracked by the acc and gyro models; the core runs on the simulated board behind a pty ({:?})",
        a.duration, a.link
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
    };
    let report = run_eval(&options)?;
    for row in &report.rows {
        println!("── {} model\n{}", row.model, row.summary);
    }
    println!("{}", report.markdown());
    let acc = a.out.join(scenario.as_str()).join("acc");
    println!("look at:");
    println!(
        "  {}   overlays: registered features (green), failed (red), the model's axes",
        acc.join("overlays").display()
    );
    println!(
        "  {}   prediction error of both models (the paper's Fig. 5)",
        a.out
            .join(format!("{scenario}_prediction_error.svg"))
            .display()
    );
    println!(
        "  {}   camera position error against ground truth",
        acc.join("plots/position_error.svg").display()
    );
    println!(
        "  {}   camera trajectory (TUM, for evo; ground truth beside it)",
        acc.join("trajectory.tum").display()
    );
    println!("  {}   the table above", a.out.join("eval.md").display());
    Ok(())
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Selftest { imu_samples } => {
            let report = host_vision::selftest::run_over_pty(imu_samples)?;
            println!("{report}");
            println!("self-test passed");
        }
        Command::Synth(args) => synth(&args)?,
        Command::Track(args) => track(&args)?,
        Command::Eval(args) => eval(&args)?,
        Command::Demo(args) => demo(&args)?,
    }
    Ok(())
}
