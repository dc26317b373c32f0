//! The EuRoC CSV readers (`imu0/data.csv`, ground truth) on arbitrary and mutated text (issue
//! 40): rows of finite numbers or a typed error naming the line; never a panic.

use std::path::Path;

use firmware_sim::sim::scenario::euroc::{
    DatasetError, IMU_HEADER, MAX_ROWS, parse_groundtruth_csv, parse_imu_csv,
};
use proptest::prelude::*;

fn imu_seed() -> String {
    format!(
        "{IMU_HEADER}\n1403715273262142976,-0.0991,0.1368,0.0342,8.1477,-0.3760,-2.4151\n\
         1403715273267142912,-0.0963,0.1340,0.0356,8.0333,-0.3678,-2.3825\n"
    )
}

fn gt_seed() -> String {
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], \
     q_RS_z [], v_RS_R_x, v_RS_R_y, v_RS_R_z, b_w_x, b_w_y, b_w_z, b_a_x, b_a_y, b_a_z\n\
     1403715273262142976,0.878612,2.142470,0.947262,0.060514,-0.828459,-0.058956,-0.553641,\
     0.009474,-0.014009,-0.002145,-0.002229,0.020700,0.076350,-0.012492,0.547666,0.069073\n"
        .to_owned()
}

/// The first 8 KiB (whole lines) of a real file of the shared data, when it is there.
fn real(file: &str) -> Option<String> {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data")
            .join(file),
    )
    .ok()?;
    let cut = text[..text.len().min(8192)].rfind('\n')?;
    Some(text[..=cut].to_owned())
}

/// Bit flips, truncations, insertions and overwrites with bytes that matter to CSV numbers.
fn mutated(seed: String) -> impl Strategy<Value = String> {
    fuzz_support::mutated(seed.into_bytes(), b"0-9.,e#\n ")
        .prop_map(|b| String::from_utf8_lossy(&b).into_owned())
}

fn all(text: &str) {
    let p = Path::new("fuzz.csv");
    if let Ok(rows) = parse_imu_csv(text, p) {
        assert!(
            rows.iter()
                .all(|r| r.gyro.iter().chain(r.accel.iter()).all(|v| v.is_finite()))
        );
    }
    if let Ok(rows) = parse_groundtruth_csv(text, p) {
        assert!(
            rows.iter().all(|r| r.p_w.iter().all(|v| v.is_finite())
                && r.q_ws.coords.iter().all(|v| v.is_finite()))
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_text(text in any::<String>()) {
        all(&text);
    }

    #[test]
    fn imu_mutated(text in mutated(imu_seed())) {
        all(&text);
    }

    #[test]
    fn groundtruth_mutated(text in mutated(gt_seed())) {
        all(&text);
    }

    #[test]
    fn real_files_mutated(which in 0usize..3, text in mutated(String::new()), at in any::<prop::sample::Index>()) {
        let file = ["euroc-v101-micro/mav0/imu0/data.csv", "euroc-v101-micro/groundtruth_V1_01_easy.csv",
            "euroc-imu-april/imu0.csv"][which];
        let Some(seed) = real(file) else { return Ok(()) };
        let i = at.index(seed.len() + 1);
        let i = (0..=i).rev().find(|&i| seed.is_char_boundary(i)).unwrap_or(0);
        all(&format!("{}{text}{}", &seed[..i], &seed[i..]));
    }
}

#[test]
fn the_seeds_parse() {
    let p = Path::new("seed.csv");
    assert_eq!(parse_imu_csv(&imu_seed(), p).unwrap().len(), 2);
    assert_eq!(parse_groundtruth_csv(&gt_seed(), p).unwrap().len(), 1);
    if let Some(t) = real("euroc-v101-micro/mav0/imu0/data.csv") {
        assert!(!parse_imu_csv(&t, p).unwrap().is_empty());
    }
}

#[test]
fn a_quaternion_whose_norm_overflows_is_refused() {
    let text = gt_seed().replace("0.060514,-0.828459", "1e200,1e200");
    let e = parse_groundtruth_csv(&text, Path::new("gt.csv")).unwrap_err();
    assert!(matches!(e, DatasetError::Parse { line: 2, .. }), "{e}");
}

#[test]
fn too_many_rows_are_refused_before_parsing() {
    let text = "1,0,0,0,0,0,0\n".repeat(MAX_ROWS + 1);
    let e = parse_imu_csv(&text, Path::new("imu.csv")).unwrap_err();
    assert!(e.to_string().contains("too many"), "{e}");
}
