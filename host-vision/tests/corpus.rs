//! Issue 56: the robustness corpus, quick form, as a user runs it (`host-vision corpus
//! --quick`). Its table must be what the runs' own `frames.csv` and the ground truth say,
//! and no frame flagged tracked may be beyond twice the bound (issue 56's goal, on the scenes
//! where it holds today).

use std::collections::BTreeMap;
use std::path::Path;

mod common;
use common::*;

/// A frame's error against the truth `(m, °)`, where it has a pose and a truth.
fn error(r: &BTreeMap<String, String>) -> Option<(f64, f64)> {
    Some((
        r["estimate_error_m"].parse().ok()?,
        r["estimate_error_deg"].parse().ok()?,
    ))
}

/// Whether a frame is right: its error within the bound `[m, °]`.
fn is_right(r: &BTreeMap<String, String>, bound: [f64; 2]) -> bool {
    error(r).is_some_and(|(m, deg)| m <= bound[0] && deg <= bound[1])
}

/// `(right, tracked and right)` over the frames of a run whose dataset image has at least half
/// of the model unoccluded (the dataset's `frames.csv`, `model_unoccluded`, line by index).
fn recount_half_visible(run: &Path, dataset: &Path, bound: [f64; 2]) -> (usize, usize) {
    let text = std::fs::read_to_string(dataset.join("frames.csv")).unwrap();
    let mut lines = text.lines();
    let column = lines
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == "model_unoccluded")
        .expect("the dataset's frames.csv says how much of the model is unoccluded");
    let half: Vec<bool> = lines
        .map(|l| {
            l.split(',')
                .nth(column)
                .and_then(|v| v.parse::<f64>().ok())
                .is_some_and(|v| v >= 0.5)
        })
        .collect();
    let rows = frame_rows(run);
    let counted: Vec<_> = rows
        .iter()
        .filter(|r| half[r["index"].parse::<usize>().unwrap()] && is_right(r, bound))
        .collect();
    (
        counted.len(),
        counted.iter().filter(|r| r["tracked"] == "1").count(),
    )
}

/// `(tracked, right, tracked and right, with truth)` recounted from a run's `frames.csv` at
/// the bound `[m, °]`.
fn recount(run: &Path, bound: [f64; 2]) -> (usize, usize, usize, usize) {
    let rows = frame_rows(run);
    let right = |r: &BTreeMap<String, String>| is_right(r, bound);
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
        let dataset = cache.join(format!(
            "corpus-{scene}-{}s-seed0",
            row["scene"]["quick_s"].as_f64().unwrap()
        ));
        let (right_half, tracked_half) =
            recount_half_visible(&out.join(scene).join(filter), &dataset, bound);
        assert_eq!(n("right_half_visible"), right_half, "{scene} {filter}: {c}");
        assert_eq!(
            n("tracked_right_half_visible"),
            tracked_half,
            "{scene} {filter}: {c}"
        );
        if n("tracked_far") > 0 {
            far.push(format!("{scene} {filter}: {c}"));
        }
    }
    assert!(
        far.is_empty(),
        "tracked frames beyond twice the bound: {far:?}"
    );
}
