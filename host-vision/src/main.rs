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
    /// Replace a dataset already in the output folder.
    #[arg(long)]
    overwrite: bool,
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
    let options = SynthOptions {
        seed: a.seed,
        duration: a.duration,
        rates: Some((a.imu_rate, a.camera_every)),
        ideal_imu: a.ideal,
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

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Selftest { imu_samples } => {
            let report = host_vision::selftest::run_over_pty(imu_samples)?;
            println!("{report}");
            println!("self-test passed");
        }
        Command::Synth(args) => synth(&args)?,
    }
    Ok(())
}
