//! `host-vision`: the vision host's command line.

use clap::{Parser, Subcommand};

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
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Selftest { imu_samples } => {
            let report = host_vision::selftest::run_over_pty(imu_samples)?;
            println!("{report}");
            println!("self-test passed");
        }
    }
    Ok(())
}
