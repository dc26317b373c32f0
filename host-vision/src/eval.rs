//! The paper's experiments (`host-vision eval`): each synthetic scenario tracked with each
//! filter model, giving Table 2 (mean prediction error in px per model and sequence), the
//! absolute accuracy against ground truth, where a model lost track, and the two-feature
//! experiment of Fig. 6 (desktop-slow with two features per frame: the gyro model's attitude
//! drifts, the accelerometer keeps the other two stable).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use firmware_sim::sim::scenario::ScenarioName;
use protocol::ModelKind;
use serde::Serialize;

use crate::out_folder::OutFolder;
use crate::synth::{SynthError, SynthOptions};
use crate::track::plot::{Series, line_plot};
use crate::track::{self, CoreTuning, LinkSpec, Summary, TrackError, TrackOptions};

/// Why the evaluation failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// An option is out of range (checked before anything runs).
    #[error("{0}")]
    Option(String),
    /// Making a dataset.
    #[error("synthesising {scenario}: {source}")]
    Synth {
        /// Scenario.
        scenario: ScenarioName,
        /// Cause.
        #[source]
        source: Box<SynthError>,
    },
    /// Tracking.
    #[error("tracking {scenario} with the {model} model: {source}")]
    Track {
        /// Scenario.
        scenario: String,
        /// Model.
        model: String,
        /// Cause.
        #[source]
        source: Box<TrackError>,
    },
    /// A dataset's `manifest.json` is there but cannot be used.
    #[error("{path}: {what}")]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The output folder cannot be used.
    #[error(transparent)]
    OutFolder(#[from] crate::out_folder::OutFolderError),
    /// Writing the report.
    #[error("{path}: {source}")]
    Output {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
}

/// Hints a synthetic dataset's `manifest.json` gives the tracker, as the paper derived its
/// noise settings from the ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DatasetHints {
    /// Peak free acceleration [m/s²].
    pub peak_accel: Option<f64>,
    /// Exposure time [s].
    pub exposure: Option<f64>,
}

/// Reads the hints of `dataset/manifest.json`: all `None` without the file (a dataset not
/// made by `synth`), a hint `None` where the manifest has no such field. A manifest that is
/// there but unreadable, over [`camera::MAX_TEXT_FILE_BYTES`], not JSON, or whose hint is not
/// a finite number of zero or more (zero: no hint) is an error that names it: a hint silently
/// dropped would track with other noise settings than the dataset says.
pub fn dataset_hints(dataset: &Path) -> Result<DatasetHints, EvalError> {
    let path = dataset.join("manifest.json");
    if !path.is_file() {
        return Ok(DatasetHints {
            peak_accel: None,
            exposure: None,
        });
    }
    let manifest = |what: String| EvalError::Manifest {
        path: path.clone(),
        what,
    };
    let text = camera::read_text_file(&path).map_err(|e| manifest(e.to_string()))?;
    parse_dataset_hints(&text).map_err(manifest)
}

/// [`dataset_hints`] on the manifest's text.
pub fn parse_dataset_hints(text: &str) -> Result<DatasetHints, String> {
    let v: serde_json::Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
    let get = |path: &[&str]| -> Result<Option<f64>, String> {
        let mut x = &v;
        for k in path {
            match x.get(k) {
                Some(next) => x = next,
                None => return Ok(None),
            }
        }
        // Zero is a manifest's "none" (a still scenario's peak acceleration): no hint.
        match x.as_f64().filter(|f| f.is_finite() && *f >= 0.0) {
            Some(f) => Ok((f > 0.0).then_some(f)),
            None => Err(format!(
                "{}: expected a number of zero or more, got {x}",
                path.join(".")
            )),
        }
    };
    Ok(DatasetHints {
        peak_accel: get(&["peaks", "free_acceleration_m_s2"])?,
        exposure: get(&["camera", "exposure_s"])?,
    })
}

/// Tracking options for a dataset, with its hints applied.
pub fn options_for(dataset: &Path, out: PathBuf) -> Result<TrackOptions, EvalError> {
    let mut o = TrackOptions::new(dataset.to_owned(), out);
    let hints = dataset_hints(dataset)?;
    o.tuning = CoreTuning {
        expected_accel: hints.peak_accel.unwrap_or(10.0),
        ..CoreTuning::default()
    };
    if let Some(e) = hints.exposure {
        o.vision.exposure = e;
    }
    Ok(o)
}

/// Synthesises `scenario` into `cache` unless a dataset of the same parameters is there.
pub fn ensure_dataset(
    cache: &Path,
    scenario: ScenarioName,
    duration: Option<f64>,
    seed: u64,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<PathBuf, EvalError> {
    ensure_dataset_until(cache, scenario, duration, seed, None, progress)
}

/// [`ensure_dataset`], stopped by `interrupt` (then the unfinished dataset is removed).
pub fn ensure_dataset_until(
    cache: &Path,
    scenario: ScenarioName,
    duration: Option<f64>,
    seed: u64,
    interrupt: Option<Arc<AtomicBool>>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<PathBuf, EvalError> {
    let name = match duration {
        Some(d) => format!("{scenario}-{d}s-seed{seed}"),
        None => format!("{scenario}-seed{seed}"),
    };
    let options = SynthOptions {
        seed,
        duration,
        overwrite: true,
        interrupt,
        ..SynthOptions::new(scenario, cache.join(name))
    };
    ensure_synth(cache, options, progress)
}

/// Synthesises `options` into `options.out`, a folder of `cache`, unless a complete dataset of
/// this build is there (the folder's name must say every option that changes it). Stopped by
/// `options.interrupt`, the unfinished dataset is removed.
pub fn ensure_synth(
    cache: &Path,
    options: SynthOptions,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<PathBuf, EvalError> {
    let dir = options.out.clone();
    let scenario = options.scenario;
    // A dataset is complete once its manifest is written (it is written last).
    let manifest = dir.join("manifest.json");
    let generator = crate::synth::generator();
    let complete = std::fs::read_to_string(&manifest)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|v| v["generator"] == generator.as_str());
    if !complete && let Err(e) = crate::synth::run(&options, progress) {
        if matches!(e, SynthError::Interrupted) {
            // The cache's own folder, half written: nothing of the user's. The cache itself
            // goes too if that leaves it empty.
            let _ = std::fs::remove_dir_all(&dir);
            let _ = std::fs::remove_dir(cache);
        }
        return Err(EvalError::Synth {
            scenario,
            source: Box::new(e),
        });
    }
    Ok(dir)
}

/// One run of the evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct EvalRow {
    /// Scenario.
    pub scenario: String,
    /// Features per frame.
    pub features: usize,
    /// Model.
    pub model: String,
    /// The run's summary.
    pub summary: Summary,
    /// Share of frames after snap-on with at least one accepted correspondence.
    pub vision_share: f64,
    /// Prediction error per frame `(t, px)`.
    #[serde(skip)]
    pub prediction_errors: Vec<(f64, f64)>,
}

impl EvalRow {
    /// Where the model lost track: the starts of the host's track losses and the core's
    /// divergences, in time order (a divergence inside a loss counts once).
    pub fn lost_at(&self) -> Vec<f64> {
        let losses = &self.summary.track_losses;
        let mut t: Vec<f64> = losses.iter().map(|l| l.start).collect();
        t.extend(
            self.summary
                .divergences
                .iter()
                .map(|e| e.t)
                .filter(|&d| !losses.iter().any(|l| (l.start..=l.end).contains(&d))),
        );
        t.sort_by(f64::total_cmp);
        t
    }
}

/// The evaluation's results.
#[derive(Debug, Clone, Default, Serialize)]
pub struct EvalReport {
    /// Every run.
    pub rows: Vec<EvalRow>,
    /// Stopped by Ctrl-C: the rows are the runs done (the last one possibly cut short).
    pub interrupted: bool,
}

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// Scenarios.
    pub scenarios: Vec<ScenarioName>,
    /// Models.
    pub models: Vec<ModelKind>,
    /// Shorter scenarios (seconds), or the nominal lengths.
    pub duration: Option<f64>,
    /// Where datasets are cached.
    pub cache: PathBuf,
    /// Where results go.
    pub out: PathBuf,
    /// Seed of the synthetic sensors.
    pub seed: u64,
    /// The core.
    pub link: LinkSpec,
    /// Also run desktop-slow with two features per frame (Fig. 6).
    pub two_features: bool,
    /// Overlay images every N frames (0: none).
    pub overlay_every: usize,
    /// Replace the outputs of an earlier evaluation in `out` (otherwise they are refused).
    pub overwrite: bool,
    /// Set (by Ctrl-C) to stop: the current run writes what it tracked, the report what was
    /// done.
    pub interrupt: Arc<AtomicBool>,
}

/// What the evaluation reports while it runs.
#[derive(Debug)]
pub enum EvalEvent<'a> {
    /// A step (synthesis, a tracking run) advanced: `done` of `total`.
    Step {
        /// The step.
        what: &'a str,
        /// Done.
        done: u64,
        /// Total.
        total: u64,
    },
    /// A tracking run finished.
    RunDone(&'a EvalRow),
}

/// Progress callback.
pub type EvalProgress<'a> = &'a mut dyn FnMut(EvalEvent);

/// Features per frame of the main runs (the map's default subset).
fn default_features() -> usize {
    crate::features::MapConfig::default().subset_size
}

fn model_name(m: ModelKind) -> String {
    format!("{m:?}").to_lowercase()
}

/// One tracking run of the evaluation.
pub fn run_one(
    dataset: &Path,
    scenario: &str,
    model: ModelKind,
    features: usize,
    options: &EvalOptions,
    progress: EvalProgress,
) -> Result<EvalRow, EvalError> {
    let tag = if features == default_features() {
        model_name(model)
    } else {
        format!("{}-{features}features", model_name(model))
    };
    let mut o = options_for(dataset, options.out.join(scenario).join(&tag))?;
    o.filter = model;
    o.link = options.link.clone();
    o.overlay_every = options.overlay_every;
    o.vision.map.subset_size = features;
    let what = format!("{scenario} {tag}");
    let run = track::run(&o, options.interrupt.clone(), &mut |done, total, _, _| {
        progress(EvalEvent::Step {
            what: &what,
            done: done as u64,
            total: total as u64,
        })
    })
    .map_err(|source| EvalError::Track {
        scenario: scenario.into(),
        model: tag.clone(),
        source: Box::new(source),
    })?;
    let after: Vec<_> = run
        .frames
        .iter()
        .filter(|f| run.summary.snapped_on_at.is_some_and(|t0| f.t >= t0))
        .collect();
    let vision_share = if after.is_empty() {
        0.0
    } else {
        after.iter().filter(|f| f.accepted > 0).count() as f64 / after.len() as f64
    };
    Ok(EvalRow {
        scenario: scenario.into(),
        features,
        model: model_name(model),
        prediction_errors: run
            .frames
            .iter()
            .filter_map(|f| Some((f.t, f.prediction_error_px?)))
            .collect(),
        summary: run.summary,
        vision_share,
    })
}

/// What an evaluation writes into its output folder.
fn outputs() -> Vec<String> {
    let mut names = vec!["eval.md".to_string(), "eval.json".to_string()];
    for sc in ScenarioName::ALL {
        names.push(sc.as_str().to_string());
        names.push(format!("{sc}_prediction_error.svg"));
    }
    names
}

/// Runs the evaluation and writes `eval.md`, `eval.json` and the comparison plots. Stopped by
/// `options.interrupt`, it writes them for the runs done and says so in
/// [`EvalReport::interrupted`].
pub fn run(options: &EvalOptions, progress: EvalProgress) -> Result<EvalReport, EvalError> {
    // As `track` checks it.
    let tuning = crate::track::config::CoreTuning::default();
    if let Some(why) = options
        .duration
        .and_then(|d| track::config::duration_refusal(&tuning, d))
    {
        return Err(EvalError::Option(why));
    }
    let mut out = OutFolder::prepare(&options.out, &outputs(), None, options.overwrite)?;
    let mut report = EvalReport::default();
    let stop = || options.interrupt.load(Ordering::Relaxed);
    'scenarios: for &scenario in &options.scenarios {
        let what = format!("synth {scenario}");
        let dataset = match ensure_dataset_until(
            &options.cache,
            scenario,
            options.duration,
            options.seed,
            Some(options.interrupt.clone()),
            &mut |done, total| {
                progress(EvalEvent::Step {
                    what: &what,
                    done,
                    total,
                })
            },
        ) {
            Ok(d) => d,
            Err(_) if stop() => break,
            Err(e) => return Err(e),
        };
        let mut runs = vec![default_features()];
        if options.two_features && scenario == ScenarioName::DesktopSlow {
            runs.push(2);
        }
        for features in runs {
            for &model in &options.models {
                // Two features cannot fix a pose without an IMU: the experiment (the paper's
                // Fig. 6) is about what the inertial models keep of the attitude.
                if features == 2 && !model.has_imu() {
                    continue;
                }
                if stop() {
                    break 'scenarios;
                }
                let row = match run_one(
                    &dataset,
                    scenario.as_str(),
                    model,
                    features,
                    options,
                    progress,
                ) {
                    Ok(row) => row,
                    Err(_) if stop() => break 'scenarios,
                    Err(e) => return Err(e),
                };
                out.keep();
                progress(EvalEvent::RunDone(&row));
                report.rows.push(row);
            }
        }
        write_plots(&options.out, scenario.as_str(), &report)?;
    }
    report.interrupted = stop();
    if let (true, Some(last)) = (report.interrupted, report.rows.last()) {
        // The interrupted scenario's plots were not written in the loop.
        write_plots(&options.out, &last.scenario, &report)?;
    }
    if !report.rows.is_empty() {
        report.write(&options.out)?;
    }
    Ok(report)
}

fn write_plots(out: &Path, scenario: &str, report: &EvalReport) -> Result<(), EvalError> {
    let series: Vec<Series> = report
        .rows
        .iter()
        .filter(|r| r.scenario == scenario && r.features == default_features())
        .map(|r| Series {
            name: format!("{} model", r.model),
            points: r.prediction_errors.clone(),
        })
        .collect();
    if series.is_empty() {
        return Ok(());
    }
    let path = out.join(format!("{scenario}_prediction_error.svg"));
    std::fs::create_dir_all(out).map_err(|source| EvalError::Output {
        path: out.to_owned(),
        source,
    })?;
    line_plot(
        &path,
        &format!("{scenario}: prediction error per frame"),
        "mean prediction error [px]",
        &series,
        Some(20.0),
    )
    .map_err(|e| EvalError::Track {
        scenario: scenario.into(),
        model: "plot".into(),
        source: Box::new(e),
    })
}

impl EvalReport {
    /// The rows of a scenario and feature count, in model order.
    fn cell(&self, scenario: &str, features: usize, model: &str) -> Option<&EvalRow> {
        self.rows
            .iter()
            .find(|r| r.scenario == scenario && r.features == features && r.model == model)
    }

    /// The report as Markdown: Table 2, accuracy, the two-feature experiment, lost tracks.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let mut scenarios: Vec<&str> = Vec::new();
        let mut models: Vec<&str> = Vec::new();
        for r in &self.rows {
            if !scenarios.contains(&r.scenario.as_str()) {
                scenarios.push(&r.scenario);
            }
            if !models.contains(&r.model.as_str()) {
                models.push(&r.model);
            }
        }
        if self.interrupted {
            let _ = writeln!(
                s,
                "**Interrupted**: only the runs done are here; † marks one stopped part-way, whose figures cover only what it ran.\n"
            );
        }
        // A run stopped part-way is marked wherever its figures appear.
        let partial = |r: &EvalRow| if r.summary.stopped_early { " †" } else { "" };
        let _ = writeln!(
            s,
            "## Table 2: mean prediction error [px] (share of frames with vision after snap-on)\n"
        );
        let _ = writeln!(s, "| sequence | {} |", models.join(" | "));
        let _ = writeln!(s, "|---|{}", "---:|".repeat(models.len()));
        for sc in &scenarios {
            let cells: Vec<String> = models
                .iter()
                .map(|m| match self.cell(sc, default_features(), m) {
                    Some(r) => format!(
                        "{} ({:.0} %){}",
                        r.summary
                            .mean_prediction_error_px
                            .map_or("n/a".into(), |v| format!("{v:.2}")),
                        100.0 * r.vision_share,
                        partial(r)
                    ),
                    None => "-".into(),
                })
                .collect();
            let _ = writeln!(s, "| {sc} | {} |", cells.join(" | "));
        }
        let _ = writeln!(
            s,
            "\n## Accuracy against ground truth (IMU-rate output from snap-on)\n"
        );
        let _ = writeln!(
            s,
            "| sequence | features | model | position mean [mm] | position max [mm] | Euler errors roll, pitch, yaw [°] | divergences | lost track at [s] |"
        );
        let _ = writeln!(s, "|---|---:|---|---:|---:|---|---:|---|");
        for r in &self.rows {
            let (mean, max, euler) = match &r.summary.accuracy {
                Some(a) => (
                    format!("{:.2}", a.mean_position_m * 1e3),
                    format!("{:.1}", a.max_position_m * 1e3),
                    format!(
                        "{:.2}, {:.2}, {:.2}",
                        a.mean_euler_deg[0], a.mean_euler_deg[1], a.mean_euler_deg[2]
                    ),
                ),
                None => ("n/a".into(), "n/a".into(), "n/a".into()),
            };
            let diverged = r.summary.divergences.len();
            let lost = r.lost_at();
            let lost = if lost.is_empty() {
                "never".to_string()
            } else {
                let shown: Vec<String> = lost.iter().take(5).map(|t| format!("{t:.1}")).collect();
                format!(
                    "{}{}",
                    shown.join(", "),
                    if lost.len() > 5 { ", …" } else { "" }
                )
            };
            let _ = writeln!(
                s,
                "| {} | {} | {}{} | {mean} | {max} | {euler} | {diverged} | {lost} |",
                r.scenario,
                r.features,
                r.model,
                partial(r)
            );
        }
        for r in self.rows.iter().filter(|r| r.summary.stopped_early) {
            let _ = writeln!(
                s,
                "\n† {} {}: stopped after {:.2} s of the data{}.",
                r.scenario,
                r.model,
                r.summary.duration_s,
                r.summary
                    .error
                    .as_deref()
                    .map_or(" (interrupted)".into(), |e| format!(": {e}"))
            );
        }
        s
    }

    /// Writes `eval.md` and `eval.json` into `out`.
    pub fn write(&self, out: &Path) -> Result<(), EvalError> {
        std::fs::create_dir_all(out).map_err(|source| EvalError::Output {
            path: out.to_owned(),
            source,
        })?;
        let md = out.join("eval.md");
        std::fs::write(&md, format!("# Evaluation\n\n{}", self.markdown())).map_err(|source| {
            EvalError::Output {
                path: md.clone(),
                source,
            }
        })?;
        let json = out.join("eval.json");
        let text = serde_json::to_string_pretty(self).map_err(|e| EvalError::Output {
            path: json.clone(),
            source: std::io::Error::other(e),
        })?;
        std::fs::write(&json, text + "\n").map_err(|source| EvalError::Output {
            path: json.clone(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manifest_hints_are_read_or_refused_by_name() {
        let h = parse_dataset_hints(
            r#"{"peaks": {"free_acceleration_m_s2": 7.5}, "camera": {"exposure_s": 0.004}}"#,
        )
        .unwrap();
        assert_eq!(h.peak_accel, Some(7.5));
        assert_eq!(h.exposure, Some(0.004));
        let none = parse_dataset_hints(r#"{"generator": "x"}"#).unwrap();
        assert_eq!((none.peak_accel, none.exposure), (None, None));
        let zero = parse_dataset_hints(r#"{"peaks": {"free_acceleration_m_s2": 0.0}}"#).unwrap();
        assert_eq!(zero.peak_accel, None);
        let deep = "[".repeat(200);
        for (text, says) in [
            (r#"{"camera": {"exposure_s": -1}}"#, "camera.exposure_s"),
            (
                r#"{"peaks": {"free_acceleration_m_s2": "fast"}}"#,
                "peaks.free_acceleration_m_s2",
            ),
            (r#"{"camera": {"exposure_s": null}}"#, "zero or more"),
            (r#"{"camera": "#, "EOF"),
            (deep.as_str(), "recursion limit"),
        ] {
            let e = parse_dataset_hints(text).unwrap_err();
            assert!(e.contains(says), "{text}: {e}");
        }
    }

    proptest::proptest! {
        /// Arbitrary text: hints that are positive finite numbers, or an error; never a panic.
        #[test]
        fn any_manifest_gives_usable_hints_or_an_error(text in "\\PC{0,120}") {
            if let Ok(h) = parse_dataset_hints(&text) {
                for v in [h.peak_accel, h.exposure].into_iter().flatten() {
                    proptest::prop_assert!(v.is_finite() && v > 0.0);
                }
            }
        }
    }
}
