//! Issue 56: the robustness corpus, quick form, as a user runs it (`host-vision corpus
//! --quick`). Its table must be what the runs' own `frames.csv` and the ground truth say,
//! and no frame flagged tracked may be beyond twice the bound (issue 56's goal, on the scenes
//! where it holds today).

use std::collections::BTreeMap;
use std::path::Path;

mod common;
use common::*;

/// `(tracked, right, tracked and right, with truth)` recounted from a run's `frames.csv` at
/// the bound `[m, °]`.
fn recount(run: &Path, bound: [f64; 2]) -> (usize, usize, usize, usize) {
    let rows = frame_rows(run);
    let error = |r: &BTreeMap<String, String>| -> Option<(f64, f64)> {
        Some((
            r["estimate_error_m"].parse().ok()?,
            r["estimate_error_deg"].parse().ok()?,
        ))
    };
    let right = |r: &BTreeMap<String, String>| {
        error(r).is_some_and(|(m, deg)| m <= bound[0] && deg <= bound[1])
    };
    let tracked = rows.iter().filter(|r| r["tracked"] == "1");
    (
        tracked.clone().count(),
        rows.iter().filter(|r| right(r)).count(),
        tracked.filter(|r| right(r)).count(),
        rows.iter().filter(|r| error(r).is_some()).count(),
    )
}

#[test]
fn the_quick_corpus_table_is_what_its_runs_wrote_and_no_tracked_frame_is_far_off() {
    let out = tmp("corpus-quick");
    let cache = tmp("corpus-cache");
    let (stdout, _) = expect(
        &["corpus", "--quick", "--out", s(&out), "--cache", s(&cache)],
        0,
    );
    println!("{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("corpus.json")).unwrap()).unwrap();
    assert_eq!(report["quick"], true);
    let rows = report["rows"].as_array().unwrap();
    let md = std::fs::read_to_string(out.join("corpus.md")).unwrap();
    // Every quick scene, with the IMU and without.
    assert!(rows.len() >= 6, "{} rows", rows.len());
    let mut far = Vec::new();
    for row in rows {
        let (scene, filter) = (
            row["scene"]["name"].as_str().unwrap(),
            row["filter"].as_str().unwrap(),
        );
        assert!(
            md.contains(&format!("| {scene} | {filter} |")),
            "{scene} {filter} not in corpus.md"
        );
        let b = &row["bound"];
        let bound = [
            b["position_m"].as_f64().unwrap(),
            b["rotation_deg"].as_f64().unwrap(),
        ];
        let c = &row["score"];
        let (tracked, right, tracked_right, with_truth) =
            recount(&out.join(scene).join(filter), bound);
        let n = |k: &str| c[k].as_u64().unwrap() as usize;
        assert_eq!(n("tracked"), tracked, "{scene} {filter}: {c}");
        assert_eq!(n("right"), right, "{scene} {filter}: {c}");
        assert_eq!(n("tracked_right"), tracked_right, "{scene} {filter}: {c}");
        assert_eq!(n("with_truth"), with_truth, "{scene} {filter}: {c}");
        // Every frame taken is counted.
        let taken: u64 = row["summary"]["frame_outcomes"]
            .as_object()
            .unwrap()
            .values()
            .map(|v| v.as_u64().unwrap())
            .sum();
        assert_eq!(n("frames") as u64, taken, "{scene} {filter}");
        // Its covariances' calibration is that of the NEES in its frames.csv, one for every
        // frame with an error against the truth (eq. T6).
        let rows = frame_rows(&out.join(scene).join(filter));
        let nees: Vec<f64> = rows.iter().filter_map(|r| r["nees"].parse().ok()).collect();
        let errors = rows
            .iter()
            .filter(|r| !r["estimate_error_m"].is_empty())
            .count();
        assert_eq!(nees.len(), errors, "{scene} {filter}");
        let all = &c["nees_all"];
        assert_eq!(all["frames"].as_u64().unwrap() as usize, nees.len());
        let mean = nees.iter().sum::<f64>() / nees.len() as f64;
        let reported = all["mean"].as_f64().unwrap();
        assert!(
            (mean - reported).abs() <= 1e-3 * reported.max(1.0),
            "{scene} {filter}: NEES mean {mean} against {reported}"
        );
        // The goal's recall counts the right frames with half the model in view, which the
        // synthetic dataset says.
        assert!(n("right_half_visible") <= right, "{scene} {filter}: {c}");
        if right > 0 {
            assert!(
                c["recall_half_visible"].is_f64(),
                "{scene} {filter}: the dataset should say what is visible: {c}"
            );
        }
        if n("tracked_far") > 0 {
            far.push(format!("{scene} {filter}: {c}"));
        }
    }
    assert!(
        far.is_empty(),
        "tracked frames beyond twice the bound: {far:?}"
    );
}
