//! The fusion core as Cortex-M4F firmware under QEMU (`mps2-an386`), driven over its UART by
//! the host exactly as hardware would be: a simulated session replayed into the firmware and
//! into the PC build of the same core must give the same answers within f32 tolerance.
//!
//! Needs `qemu-system-arm` and the image from `cargo xtask firmware`; skips with a message when
//! either is absent, unless `REQUIRE_FIRMWARE` is set (CI sets it through `cargo xtask test`).

use std::io::{Read, Write};
use std::path::Path;
use std::thread;
use std::time::{Duration, Instant};

use firmware_sim::qemu::{QemuBoard, default_image};
use firmware_sim::transport::Duplex;
use protocol::io::{FrameReader, FrameWriter, RecvError};
use protocol::{CoreToHost, Hello, HostToCore, ModelKind, PROTOCOL_VERSION};
use tests::harness::{Driver, scenes};

fn close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn all_close(a: &[f32], b: &[f32], tol: f32) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(&x, &y)| close(x, y, tol))
}

/// Whether two answers agree: same kind and ids, numbers within `tol` (relative).
fn agree(pc: &CoreToHost, fw: &CoreToHost, tol: f32) -> bool {
    match (pc, fw) {
        (CoreToHost::State(a), CoreToHost::State(b)) => {
            a.t_us == b.t_us
                && a.health.mode == b.health.mode
                && all_close(&a.s_w, &b.s_w, tol)
                && all_close(&a.q_sw, &b.q_sw, tol)
                && all_close(&a.v_w, &b.v_w, tol)
                && all_close(&a.a_w, &b.a_w, tol)
                && all_close(&a.gyro_bias, &b.gyro_bias, tol)
                && all_close(&a.accel_bias, &b.accel_bias, tol)
        }
        (CoreToHost::PosePrediction(a), CoreToHost::PosePrediction(b)) => {
            a.frame_id == b.frame_id
                && a.t_us == b.t_us
                && all_close(&a.c_w, &b.c_w, tol)
                && all_close(&a.q_cw, &b.q_cw, tol)
        }
        (CoreToHost::UpdateReport(a), CoreToHost::UpdateReport(b)) => {
            a.frame_id == b.frame_id
                && a.part == b.part
                && a.outcome == b.outcome
                && a.accepted == b.accepted
                && a.rejected == b.rejected
        }
        (a, b) => a == b,
    }
}

#[test]
fn firmware_under_qemu_agrees_with_the_pc_build() {
    // The paper's acc model, and the vision-only model on its ticks.
    for model in [ModelKind::Acc, ModelKind::Vision] {
        if !agrees_with_the_pc_build(model) {
            return;
        }
    }
}

/// The firmware link's incoming frames.
type Reader = FrameReader<Box<dyn Read + Send>>;

/// The firmware link's outgoing frames.
type Writer = FrameWriter<Box<dyn Write + Send>>;

/// Starts the firmware `image` under QEMU; `None` when it cannot be started and the test is
/// skipped (not `required`), after saying why.
fn start_board(image: &Path, required: bool) -> Option<(QemuBoard, Duplex)> {
    match QemuBoard::start(image, Duration::from_secs(20)) {
        Ok(b) => Some(b),
        Err(e) if !required => {
            println!("SKIPPED: {e} (set REQUIRE_FIRMWARE to make this a failure)");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// Runs a session of `model` through the PC build: every message it sent (the opening
/// handshake included, and a final `Hello` that marks the end of the stream) and every answer.
fn pc_session(model: ModelKind) -> (Vec<HostToCore>, Vec<CoreToHost>) {
    // The PC build runs the session first; its transcript is replayed into the firmware.
    let mut sc = scenes::standard(model, 6.0, 2.0, 21);
    sc.config.state_every = 1;
    let mut pc = Driver::<f32>::new(&sc);
    pc.transcript = Some((Vec::new(), Vec::new()));
    // The handshake and configuration were sent before recording: record them too.
    let mut sent = vec![
        HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }),
        HostToCore::Configure(sc.config),
        HostToCore::Init(sc.init),
    ];
    while pc.k < pc.samples() {
        pc.step();
    }
    let (rest, mut pc_answers) = pc.transcript.take().unwrap();
    sent.extend(rest);
    // Answers to the first three messages, from a fresh PC device.
    let mut head = Vec::new();
    let mut fresh = fusion_core::Device::<f32>::new();
    for m in &sent[..3] {
        fresh.handle(m, &mut |a| head.push(a));
    }
    head.append(&mut pc_answers);
    let pc_answers = head;
    // A final Hello marks the end of the stream.
    sent.push(HostToCore::Hello(Hello {
        version: PROTOCOL_VERSION,
    }));
    (sent, pc_answers)
}

/// Reads the firmware's answers on a thread, up to the `HelloAck` of the final `Hello` (not
/// kept); gives them back with the frames that did not decode, and the reader.
fn spawn_reader(
    reader: Box<dyn Read + Send>,
) -> thread::JoinHandle<(Vec<CoreToHost>, usize, Reader)> {
    thread::spawn(move || {
        let mut r = FrameReader::new(reader);
        let mut got = Vec::new();
        let mut decode_errors = 0;
        let deadline = Instant::now() + Duration::from_secs(240);
        while Instant::now() < deadline {
            match r.recv::<CoreToHost>() {
                Ok(CoreToHost::HelloAck(_)) if !got.is_empty() => break,
                Ok(m) => got.push(m),
                Err(RecvError::Frame(_)) => decode_errors += 1,
                Err(RecvError::Io(e)) if firmware_sim::transport::is_poll_timeout(&e) => {}
                Err(e) => panic!("firmware link: {e}"),
            }
        }
        (got, decode_errors, r)
    })
}

/// Sends one message of every kind but `Hello` (answers not compared), so that each handler
/// has run once, then a `Hello`, and waits for its `HelloAck`.
fn run_every_handler(w: &mut Writer, r: &mut Reader) {
    for (_, m) in protocol::samples::host_messages() {
        if !matches!(m, HostToCore::Hello(_)) {
            w.send(&m).expect("send to firmware");
        }
    }
    w.send(&HostToCore::Hello(Hello {
        version: PROTOCOL_VERSION,
    }))
    .expect("send to firmware");
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(
            Instant::now() < deadline,
            "no HelloAck after the other messages"
        );
        match r.recv::<CoreToHost>() {
            Ok(CoreToHost::HelloAck(_)) => break,
            Ok(_) => {}
            Err(RecvError::Io(e)) if firmware_sim::transport::is_poll_timeout(&e) => {}
            Err(e) => panic!("firmware link: {e}"),
        }
    }
}

/// Checks that the firmware gave the PC build's answers, one for one, and that the session
/// had enough states to compare.
fn compare_answers(pc_answers: &[CoreToHost], fw_answers: &[CoreToHost]) {
    assert_eq!(fw_answers.len(), pc_answers.len());
    let mut worst_state = 0.0f32;
    for (i, (p, f)) in pc_answers.iter().zip(fw_answers).enumerate() {
        assert!(
            agree(p, f, 1e-3),
            "answer {i} differs:\n pc  {p:?}\n fw  {f:?}"
        );
        if let (CoreToHost::State(a), CoreToHost::State(b)) = (p, f) {
            for (x, y) in a.s_w.iter().zip(&b.s_w) {
                worst_state = worst_state.max((x - y).abs());
            }
        }
    }
    let states = pc_answers
        .iter()
        .filter(|a| matches!(a, CoreToHost::State(_)))
        .count();
    println!(
        "{states} states compared; worst position difference {:.2e} m",
        worst_state
    );
    assert!(states > 900);
}

/// One session of `model` through the firmware and the PC build; false if the firmware could
/// not be started (and the test is skipped).
fn agrees_with_the_pc_build(model: ModelKind) -> bool {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let image = std::env::var_os("FIRMWARE_ELF")
        .map(Into::into)
        .unwrap_or_else(|| default_image(&workspace, "device"));
    let required = std::env::var_os("REQUIRE_FIRMWARE").is_some();
    let Some((mut board, link)) = start_board(&image, required) else {
        return false;
    };

    let (sent, pc_answers) = pc_session(model);

    let reader = spawn_reader(link.reader);
    let mut w = FrameWriter::new(link.writer);
    let start = Instant::now();
    for m in &sent {
        w.send(m).expect("send to firmware");
    }
    let (fw_answers, decode_errors, mut r) = reader.join().expect("reader");
    let elapsed = start.elapsed();

    // The device image's own RAM (not the bench's): after the session, one message of every
    // other kind too (Query, Resume, Reset, Tick, ...), so that each handler has run once;
    // then the stack it painted at boot is read from the board.
    run_every_handler(&mut w, &mut r);
    let ram = board.ram_use(&image).expect("read the board's RAM");
    drop(board);

    // The first answer is the HelloAck of the opening Hello (kept by the reader).
    println!(
        "{model:?}: {} messages in, {} answers from the firmware ({} from the PC build) in {:.1} s",
        sent.len(),
        fw_answers.len(),
        pc_answers.len(),
        elapsed.as_secs_f64()
    );
    println!(
        "{model:?}: device image RAM: static {} B + stack high-water {} B = {} B",
        ram.static_bytes,
        ram.stack_high_water,
        ram.static_bytes + ram.stack_high_water
    );
    // Issue 18's goal for the device: static RAM and stack within 24 KiB.
    assert!(
        ram.static_bytes + ram.stack_high_water <= 24 * 1024,
        "device image RAM {ram:?} over 24 KiB"
    );
    assert_eq!(
        decode_errors, 0,
        "every frame from the firmware must decode"
    );
    compare_answers(&pc_answers, &fw_answers);
    true
}
