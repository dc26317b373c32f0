//! Loop-back self-test of the wire protocol over a real serial line (a pty pair): handshake
//! (refused and accepted), every message kind in both directions, corrupted frames rejected and
//! reported by the board, and IMU-rate traffic timed.

use std::thread;
use std::time::{Duration, Instant};

use anyhow::{Context, bail, ensure};
use firmware_sim::{loopback, transport};
use protocol::{
    CoreToHost, DecodeError, ErrorCode, HostToCore, ImuSample, MAX_FRAME_LEN, PROTOCOL_VERSION,
    Version, body_len, encode_frame, samples,
};

use crate::link::{Link, LinkError};

const TIMEOUT: Duration = Duration::from_secs(10);

/// Encoded size of one sample message.
#[derive(Debug, Clone)]
pub struct SizeRow {
    /// Direction and sample name.
    pub name: String,
    /// Postcard body [bytes].
    pub body: usize,
    /// Whole frame on the wire: body, CRC, COBS overhead and delimiter [bytes].
    pub frame: usize,
}

/// What the self-test checked and measured.
#[derive(Debug, Clone)]
pub struct Report {
    /// Link used.
    pub link: String,
    /// The error a host of another major version gets.
    pub version_mismatch: String,
    /// Host messages that crossed intact (checked by the board's record).
    pub host_messages_checked: usize,
    /// Core messages that crossed intact.
    pub core_messages_checked: usize,
    /// Corrupted frames sent, each rejected by the board and reported back as `Error(Decode)`.
    pub corrupted_frames_rejected: usize,
    /// IMU samples streamed.
    pub imu_samples: usize,
    /// IMU samples per second through the link, end to end.
    pub imu_rate: f64,
    /// Encoded sizes of every sample message.
    pub sizes: Vec<SizeRow>,
}

fn frame_of<T: serde::Serialize>(msg: &T) -> anyhow::Result<Vec<u8>> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    Ok(encode_frame(msg, &mut buf)?.to_vec())
}

fn size_row<T: serde::Serialize>(name: String, msg: &T) -> anyhow::Result<SizeRow> {
    Ok(SizeRow {
        name,
        body: body_len(msg)?,
        frame: frame_of(msg)?.len(),
    })
}

/// The faults injected between messages, and the rejection each must cause.
fn faults() -> anyhow::Result<Vec<(Vec<u8>, DecodeError)>> {
    let mut flipped = frame_of(&samples::host_messages()[4].1)?;
    flipped[3] ^= 0x10; // a data byte: still valid COBS, wrong CRC
    Ok(vec![
        (flipped, DecodeError::Crc),
        (vec![0x05, 0x01, 0x02, 0x00], DecodeError::Cobs),
        // Valid COBS of three bytes: too short for a CRC and a message.
        (vec![0x04, 0x01, 0x02, 0x03, 0x00], DecodeError::Truncated),
        (
            vec![0x7f; MAX_FRAME_LEN + 10]
                .into_iter()
                .chain([0])
                .collect(),
            DecodeError::Oversized,
        ),
    ])
}

/// Runs the self-test over a fresh pty pair with a loop-back board on the other end.
pub fn run_over_pty(imu_samples: usize) -> anyhow::Result<Report> {
    let (host, board) = transport::pty_pair()?;
    let board = thread::Builder::new()
        .name("loopback-board".into())
        .spawn(move || loopback::serve(board))?;
    let mut link = Link::new(host);
    let name = link.name().to_string();
    let result = exchange(&mut link, imu_samples);
    drop(link); // closes the host end: the board sees the end of the stream and returns
    let board = board
        .join()
        .map_err(|_| anyhow::anyhow!("loop-back board thread panicked"))?;
    // The host's failure first: the board's is then its consequence (a closed line).
    let (mut report, sent) = result?;
    let log = board.context("loop-back board")?;
    ensure!(
        log.received == sent,
        "the board received {} messages, expected {}; first difference at {:?}",
        log.received.len(),
        sent.len(),
        log.received.iter().zip(&sent).position(|(a, b)| a != b)
    );
    report.link = name;
    Ok(report)
}

/// The host's side; returns the report and every message sent, for comparison with the board.
fn exchange(link: &mut Link, imu_samples: usize) -> anyhow::Result<(Report, Vec<HostToCore>)> {
    let mut sent = Vec::new();

    // 1. A host of another major version is refused with a clear error.
    let other = Version {
        major: PROTOCOL_VERSION.major + 1,
        minor: 0,
    };
    sent.push(HostToCore::Hello(protocol::Hello { version: other }));
    let version_mismatch = match link.handshake(other, TIMEOUT) {
        Err(e @ LinkError::Handshake { .. }) => e.to_string(),
        Ok(_) => bail!("the board accepted protocol version {other}"),
        Err(e) => return Err(e.into()),
    };

    // 2. The real handshake.
    sent.push(HostToCore::Hello(protocol::Hello {
        version: PROTOCOL_VERSION,
    }));
    let ack = link.handshake(PROTOCOL_VERSION, TIMEOUT)?;
    ensure!(
        ack.capacities == loopback::CAPACITIES,
        "capacities differ: {ack:?}"
    );

    // 3. Every host message kind, with a corrupted frame after each.
    let faults = faults()?;
    let mut expected_rejections = Vec::new();
    for (i, (_, msg)) in samples::host_messages().into_iter().enumerate() {
        if matches!(msg, HostToCore::Hello(_) | HostToCore::Reset) {
            continue;
        }
        link.send(&msg)?;
        sent.push(msg);
        let (bytes, why) = &faults[i % faults.len()];
        link.send_raw(bytes)?;
        expected_rejections.push(*why);
    }
    for (bytes, why) in &faults {
        link.send_raw(bytes)?;
        expected_rejections.push(*why);
    }

    // 4. IMU-rate traffic, then Reset, which makes the board send every core message kind.
    let start = Instant::now();
    for k in 0..imu_samples {
        // A rate that stays in the protocol's range however many samples (issue 33: `0.01 k`
        // left it at 10,000 samples, and the board's refusals filled the line back).
        let msg = HostToCore::Imu(ImuSample {
            t_us: k as u64 * 5_000,
            gyro: [0.01 * (k % 1000) as f32, -0.02, 0.5],
            accel: [0.1, 0.0, 9.81],
            trigger: k.is_multiple_of(4),
        });
        link.send(&msg)?;
        sent.push(msg);
    }
    link.send(&HostToCore::Reset)?;
    sent.push(HostToCore::Reset);

    let mut rejections = Vec::new();
    let expected_core: Vec<CoreToHost> = samples::core_messages()
        .into_iter()
        .map(|(_, m)| m)
        .collect();
    let mut core_received = Vec::new();
    while core_received.len() < expected_core.len() {
        let msg = link.recv(TIMEOUT)?;
        match msg {
            CoreToHost::Error(report) if rejections.len() < expected_rejections.len() => {
                match report.code {
                    ErrorCode::Decode(e) => rejections.push(e),
                    other => bail!("board reported {other} where a decode error was expected"),
                }
            }
            msg => core_received.push(msg),
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    ensure!(
        rejections == expected_rejections,
        "board rejected {rejections:?}, expected {expected_rejections:?}"
    );
    ensure!(
        core_received == expected_core,
        "core messages differ after the trip"
    );

    let mut sizes = Vec::new();
    for (name, msg) in samples::host_messages() {
        sizes.push(size_row(format!("host→core {name}"), &msg)?);
    }
    for (name, msg) in samples::core_messages() {
        sizes.push(size_row(format!("core→host {name}"), &msg)?);
    }
    let report = Report {
        link: String::new(),
        version_mismatch,
        host_messages_checked: sent.len(),
        core_messages_checked: core_received.len(),
        corrupted_frames_rejected: rejections.len(),
        imu_samples,
        imu_rate: imu_samples as f64 / elapsed,
        sizes,
    };
    Ok((report, sent))
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "protocol {PROTOCOL_VERSION} loop-back self-test over {}",
            self.link
        )?;
        writeln!(
            f,
            "  test step, refused on purpose: a host of another major version ({}) gets: {}",
            Version {
                major: PROTOCOL_VERSION.major + 1,
                minor: 0
            },
            self.version_mismatch
        )?;
        writeln!(
            f,
            "  {} host→core and {} core→host messages crossed intact",
            self.host_messages_checked, self.core_messages_checked
        )?;
        writeln!(
            f,
            "  {} corrupted frames rejected by the board and reported back",
            self.corrupted_frames_rejected
        )?;
        writeln!(
            f,
            "  {} IMU samples at {:.0} samples/s end to end ({:.1}x a 200 Hz IMU)",
            self.imu_samples,
            self.imu_rate,
            self.imu_rate / 200.0
        )?;
        writeln!(f, "\n  {:<42} {:>6} {:>6}", "message", "body", "frame")?;
        for row in &self.sizes {
            writeln!(f, "  {:<42} {:>6} {:>6}", row.name, row.body, row.frame)?;
        }
        write!(f, "  (bytes; largest legal frame: {MAX_FRAME_LEN})")
    }
}
