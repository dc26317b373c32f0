//! `firmware-sim`: the simulated board as a program, for a host in another process.
//!
//! ```text
//! firmware-sim --link pty                 # opens a pty, prints the path to give the host
//! firmware-sim --link tcp:127.0.0.1:7000  # listens for one host (--forever: host after host)
//! firmware-sim --link serial:/dev/ttyUSB0 # a real serial line
//! firmware-sim --link stdio               # as a child process
//! ```

use std::io::Write as _;

use anyhow::Context as _;
use clap::Parser;
use firmware_sim::board::{Board, Precision, ResetPin};
use firmware_sim::transport;

/// Prints a line on stderr; a closed stderr (the user's pipe is gone) is not worth a panic.
macro_rules! note {
    ($($arg:tt)*) => {{
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

/// Runs the fusion core's device loop behind a byte transport, exactly as the firmware does
/// behind its UART.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    /// Transport: `pty` (a new pty; its device path, printed, is the host's serial:PATH),
    /// `tcp:HOST:PORT` (listens for one host), `serial:PATH[@BAUD]` (BAUD defaults to 921600)
    /// or `stdio`.
    #[arg(long, default_value = "pty")]
    link: String,
    /// Scalar type of the core.
    #[arg(long, default_value = "f32", value_parser = precision())]
    precision: Precision,
    /// Serve sessions until killed, one after another, with the same core: a host that
    /// restarts, or comes back after its cable was pulled, finds the core as the last one left
    /// it, still tracking (default: one session, which ends when the host closes the link; the
    /// board then prints its report and exits). With pty, each session has a new device path.
    #[arg(long)]
    forever: bool,
}

/// `--precision`'s values (the library's `Precision` knows no command line).
fn precision() -> impl clap::builder::TypedValueParser<Value = Precision> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(["f32", "f64"]).map(|s| match s.as_str() {
        "f64" => Precision::F64,
        _ => Precision::F32,
    })
}

fn open(link: &str) -> anyhow::Result<transport::Duplex> {
    if link == "pty" {
        // The session ends when the host closes the device.
        let (board_end, path) = transport::pty_for_peer()?;
        note!("board: connect the host to serial:{path}");
        return Ok(board_end);
    }
    if link == "stdio" {
        return Ok(transport::stdio());
    }
    if let Some(rest) = link.strip_prefix("serial:") {
        let (path, baud) = match rest.rsplit_once('@') {
            Some((p, b)) => (
                p,
                b.parse()
                    .with_context(|| format!("baud rate `{b}` in --link {link}"))?,
            ),
            None => (rest, 921_600),
        };
        return Ok(transport::serial(path, baud)?);
    }
    anyhow::bail!("unknown --link `{link}`: expected pty, tcp:ADDR, serial:PATH[@BAUD] or stdio")
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let mut board = Board::new(cli.precision, ResetPin::default());
    // A TCP board listens once and takes its hosts one after another.
    let listener = match cli.link.strip_prefix("tcp:") {
        Some(addr) => {
            let l = std::net::TcpListener::bind(addr)
                .with_context(|| format!("listening on {addr}"))?;
            note!("board: waiting for the host on tcp:{}", l.local_addr()?);
            Some(l)
        }
        None => None,
    };
    let mut listener = listener;
    loop {
        let link = match &listener {
            Some(l) => transport::tcp_accept(l)?,
            None => open(&cli.link)?,
        };
        if !cli.forever {
            // One session: a second host is refused at once, not kept waiting for this one
            // to end and then cut off (issue 54).
            listener = None;
        }
        let name = link.name.clone();
        let before = board.report();
        board
            .serve(link)
            .with_context(|| format!("serving the host on {name}"))?;
        let report = board.report();
        // The vision-only model's clock is the host's ticks (issue 33: "400 IMU samples
        // applied" for a session without an IMU).
        let clock = match report.model {
            Some(protocol::ModelKind::Vision) => "vision ticks",
            _ => "IMU samples",
        };
        // This session's share: the board's totals run on from session to session, and its
        // core's counters from its last reset.
        let (c, c0) = (&report.counters, &before.counters);
        let since = |now: u32, then: u32| {
            if report.resets > before.resets {
                now
            } else {
                now.saturating_sub(then)
            }
        };
        note!(
            "board: session on {name} ended: {} bytes in, {} out, {} {clock} applied, {} correspondences accepted, {} gated, {} divergences",
            report.bytes_in - before.bytes_in,
            report.bytes_out - before.bytes_out,
            since(c.imu_applied, c0.imu_applied),
            since(c.accepted, c0.accepted),
            since(c.gated, c0.gated),
            since(c.divergences, c0.divergences)
        );
        if !cli.forever || cli.link == "stdio" {
            return Ok(());
        }
    }
}
