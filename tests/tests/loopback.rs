//! The protocol's loop-back self-test over a real pty pair: host-vision's link on one end,
//! firmware-sim's board on the other.

#[test]
fn selftest_over_a_pty_pair_passes_and_reports_every_message_kind() {
    let report = host_vision::selftest::run_over_pty(500).expect("self-test");
    assert_eq!(report.imu_samples, 500);
    // 2 Hellos + the sample messages but Hello and Reset (10 since the Contours of 3.2)
    // + 500 IMU + Reset.
    let samples = protocol::samples::host_messages().len() - 2;
    assert_eq!(samples, 10);
    assert_eq!(report.host_messages_checked, 2 + samples + 500 + 1);
    assert_eq!(
        report.core_messages_checked,
        protocol::samples::core_messages().len()
    );
    // A corrupted frame after each sample message, then the four faults once more.
    assert_eq!(report.corrupted_frames_rejected, samples + 4);
    assert!(
        report.version_mismatch.contains("version mismatch"),
        "{}",
        report.version_mismatch
    );
    assert!(report.imu_rate > 0.0);
    for row in &report.sizes {
        assert!(row.frame <= protocol::MAX_FRAME_LEN, "{row:?}");
        assert!(row.frame > row.body, "{row:?}");
    }
}
