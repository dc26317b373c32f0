//! The simulated board as its own process, as a user runs it beside a host: `firmware-sim
//! --link pty` opens a pty and says where; the host opens that device as a serial line and
//! talks the protocol to the fusion core behind it. Also over TCP.

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStderr, Command, Stdio};
use std::time::{Duration, Instant};

use firmware_sim::transport::{self, Duplex};
use protocol::io::{FrameReader, FrameWriter, RecvError};
use protocol::{CoreToHost, Hello, HostToCore, Init, InitAttitude, Mode, PROTOCOL_VERSION};

/// Starts the board with `args` and returns it with the first line it prints on stderr, and
/// its stderr to read on.
fn start_with(args: &[&str]) -> (Child, String, BufReader<ChildStderr>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_firmware-sim"))
        .args(args)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .expect("start firmware-sim");
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    err.read_line(&mut line).unwrap();
    (child, line.trim().to_string(), err)
}

/// Starts the board and returns it with the first line it prints on stderr, and the rest.
fn start(link: &str) -> (Child, String, std::thread::JoinHandle<String>) {
    let (child, line, mut err) = start_with(&["--link", link]);
    // Keep reading, so that the board's last words do not meet a closed pipe.
    let rest = std::thread::spawn(move || std::io::read_to_string(&mut err).unwrap_or_default());
    (child, line, rest)
}

/// Starts the board on a pty: the process, the pty's path, and the rest of what it prints.
fn start_pty() -> (Child, String, std::thread::JoinHandle<String>) {
    let (child, line, rest) = start("pty");
    let path = line
        .rsplit_once("serial:")
        .map(|(_, p)| p.to_string())
        .unwrap_or_else(|| panic!("unexpected first line `{line}`"));
    (child, path, rest)
}

/// Waits for the board to exit by itself (a guard against a hang, not a speed requirement).
fn wait_for_exit(child: &mut Child) -> std::process::ExitStatus {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("the board did not end its session after the host hung up");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The address a TCP board says it waits on, from its first line.
fn tcp_address(line: &str) -> String {
    line.trim()
        .rsplit_once("tcp:")
        .map(|(_, a)| a.to_string())
        .unwrap_or_else(|| panic!("unexpected first line `{line}`"))
}

/// A short session: handshake, configuration, still IMU until the filter runs, one trigger.
fn session(link: Duplex) {
    let mut w = FrameWriter::new(link.writer);
    let mut r = FrameReader::new(link.reader);
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut recv = || loop {
        assert!(Instant::now() < deadline, "no answer from the board");
        match r.recv::<CoreToHost>() {
            Ok(m) => return m,
            Err(RecvError::Io(e)) if transport::is_poll_timeout(&e) => {}
            Err(e) => panic!("{e:?}"),
        }
    };
    w.send(&HostToCore::Hello(Hello {
        version: PROTOCOL_VERSION,
    }))
    .unwrap();
    match recv() {
        CoreToHost::HelloAck(a) => assert_eq!(a.capacities.scalar_bits, 32),
        other => panic!("{other:?}"),
    }
    let mut config = protocol::samples::config();
    config.still_samples = 5;
    config.state_every = 0;
    w.send(&HostToCore::Configure(config)).unwrap();
    w.send(&HostToCore::Init(Init {
        position: [0.0, 0.0, 1.0],
        attitude: InitAttitude::Gravity,
    }))
    .unwrap();
    for k in 1..=10u64 {
        w.send(&HostToCore::Imu(protocol::ImuSample {
            t_us: k * 10_000,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            trigger: k == 10,
        }))
        .unwrap();
    }
    let mut modes = Vec::new();
    loop {
        match recv() {
            CoreToHost::Status(s) => modes.push(s.mode),
            CoreToHost::PosePrediction(p) => {
                assert_eq!(p.t_us, 100_000);
                assert!((p.c_w[2] - 1.0).abs() < 0.1, "{:?}", p.c_w);
                break;
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(
        modes,
        [Mode::AwaitingInit, Mode::Initialising, Mode::DeadReckoning]
    );
}

/// `firmware-sim --link pty` serves one session: when the host closes the device, the board
/// prints its report and exits, and a second host finds no device (issue 13, point 3).
#[test]
fn a_host_talks_to_the_board_process_over_its_pty_and_the_session_ends_with_it() {
    let (mut child, path, rest) = start_pty();
    let link = transport::serial(&path, 921_600).expect("open the board's pty");
    session(link);
    let status = wait_for_exit(&mut child);
    assert!(status.success(), "{status}");
    let report = rest.join().unwrap();
    assert!(
        report.starts_with(&format!("board: session on {path} ended: "))
            && report.contains(", 5 IMU samples applied,"),
        "{report}"
    );
    let again = transport::serial(&path, 921_600);
    assert!(again.is_err(), "a second host reached the ended session");
}

/// Issue 33, point 11: a vision-only session's report said "400 IMU samples applied": its
/// clock is the host's ticks, and the report says so.
#[test]
fn a_vision_only_session_reports_ticks() {
    let (mut child, path, rest) = start_pty();
    let link = transport::serial(&path, 921_600).expect("open the board's pty");
    let mut w = FrameWriter::new(link.writer);
    let mut config = protocol::samples::config();
    config.model = protocol::ModelKind::Vision;
    config.state_every = 0;
    let mut msgs = vec![
        HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }),
        HostToCore::Configure(config),
        HostToCore::Init(Init {
            position: [0.0, 0.0, 1.0],
            attitude: InitAttitude::Full([1.0, 0.0, 0.0, 0.0]),
        }),
    ];
    msgs.extend((1..=7u64).map(|k| {
        HostToCore::Tick(protocol::Tick {
            t_us: k * 10_000,
            trigger: false,
        })
    }));
    msgs.push(HostToCore::Query);
    for m in &msgs {
        w.send(m).unwrap();
    }
    // Up to the query's answer, so that the board is done with the ticks before the line
    // closes.
    let mut r = FrameReader::new(link.reader);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        assert!(Instant::now() < deadline, "no answer from the board");
        match r.recv::<CoreToHost>() {
            Ok(CoreToHost::Status(s)) if s.reason == protocol::StatusReason::Queried => break,
            Ok(_) => {}
            Err(RecvError::Io(e)) if transport::is_poll_timeout(&e) => {}
            Err(e) => panic!("{e:?}"),
        }
    }
    drop((w, r));
    let status = wait_for_exit(&mut child);
    assert!(status.success(), "{status}");
    let report = rest.join().unwrap();
    assert!(report.contains(", 7 vision ticks applied,"), "{report}");
}

/// The README's `firmware-sim` commands name only flags its `--help` has.
#[test]
fn readme_names_only_real_flags() {
    let out = Command::new(env!("CARGO_BIN_EXE_firmware-sim"))
        .arg("--help")
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    let readme = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"),
    )
    .unwrap();
    let mut checked = 0;
    for line in readme.lines() {
        for (_, rest) in line
            .match_indices("firmware-sim ")
            .map(|(i, m)| line.split_at(i + m.len()))
        {
            let code = rest.split(['#', '`']).next().unwrap_or("");
            for flag in code
                .split(|c: char| !(c.is_ascii_alphanumeric() || c == '-'))
                .filter(|w| w.starts_with("--") && w.len() > 2)
            {
                // The flag as a whole word (a flag without a value ends its line).
                let named = help.match_indices(flag).any(|(i, _)| {
                    help[i + flag.len()..]
                        .chars()
                        .next()
                        .is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '-'))
                });
                assert!(
                    named,
                    "README: `firmware-sim {flag}` is not in its --help:\n{help}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked >= 1, "no firmware-sim command found in the README");
}

#[test]
fn a_host_talks_to_the_board_process_over_tcp() {
    let (mut child, line, _) = start("tcp:127.0.0.1:0");
    let addr = tcp_address(&line);
    let link = transport::tcp_connect(addr.as_str()).expect("connect to the board");
    session(link);
    // The session ends when the host hangs up; the board then exits by itself.
    let status = child.wait().expect("board exits");
    assert!(status.success(), "{status}");
}

/// Issue 54, point 18: `--forever` reported the board's totals since it started as each
/// session's (the second said twice the first's samples). Each session's report is its own.
#[test]
fn each_session_of_a_board_that_serves_forever_reports_its_own_counts() {
    let (mut child, line, mut err) = start_with(&["--link", "tcp:127.0.0.1:0", "--forever"]);
    let addr = tcp_address(&line);
    let mut reports = Vec::new();
    for _ in 0..2 {
        session(transport::tcp_connect(addr.as_str()).expect("connect to the board"));
        let mut report = String::new();
        err.read_line(&mut report).unwrap();
        reports.push(report);
    }
    let _ = child.kill();
    let _ = child.wait();
    for r in &reports {
        assert!(
            r.starts_with("board: session on ") && r.contains(", 5 IMU samples applied,"),
            "{reports:?}"
        );
    }
    let bytes = |r: &str| -> u64 {
        r.split(" ended: ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    assert_eq!(bytes(&reports[0]), bytes(&reports[1]), "{reports:?}");
}

/// Issue 54, point 19: a second host of a one-session TCP board waited for the first to end,
/// then met a bare `Connection reset by peer`. It is refused at once.
#[test]
fn a_one_session_tcp_board_refuses_a_second_host_at_once() {
    let (mut child, line, _) = start("tcp:127.0.0.1:0");
    let addr = tcp_address(&line);
    let first = transport::tcp_connect(addr.as_str()).expect("connect to the board");
    let mut w = FrameWriter::new(first.writer);
    let mut r = FrameReader::new(first.reader);
    // Answered: the board took this host, and gave up its listener.
    w.send(&HostToCore::Hello(Hello {
        version: PROTOCOL_VERSION,
    }))
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        assert!(Instant::now() < deadline, "no answer from the board");
        match r.recv::<CoreToHost>() {
            Ok(CoreToHost::HelloAck(_)) => break,
            Ok(other) => panic!("{other:?}"),
            Err(RecvError::Io(e)) if transport::is_poll_timeout(&e) => {}
            Err(e) => panic!("{e:?}"),
        }
    }
    let second = transport::tcp_connect(addr.as_str());
    assert!(second.is_err(), "a second host was taken in");
    drop((w, r));
    let status = child.wait().expect("board exits");
    assert!(status.success(), "{status}");
}

#[test]
fn a_bad_link_is_refused_with_a_clear_message() {
    let out = Command::new(env!("CARGO_BIN_EXE_firmware-sim"))
        .args(["--link", "carrier-pigeon"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown --link `carrier-pigeon`"), "{err}");
}
