//! The robustness corpus (`host-vision corpus`, issue 56; docs/VISION.md §10): scenes made to
//! break the tracker, each synthesised with exact ground truth and tracked with the IMU and
//! without, and every frame's verdict scored against the truth ([`score`]): the precision
//! and recall of "tracked", and how long a wrong pose went unreported.
//!
//! - [`scenes`]: what each scene is and tries to break;
//! - [`score`]: the per-frame comparison and the run's figures (eq. T1-T3);
//! - [`report`]: the tables (`corpus.md`, `corpus.json`).

pub mod report;
pub mod scenes;
pub mod score;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use protocol::ModelKind;
use serde::Serialize;

use crate::eval::{EvalError, ensure_synth, options_for};
use crate::out_folder::OutFolder;
use crate::track::{self, LinkSpec, Summary};
use report::CorpusReport;
use scenes::{FILTERS, SCENES, Scene};
use score::{Bound, FrameTruth, Score};

/// What to run.
#[derive(Debug, Clone)]
pub struct CorpusOptions {
    /// The quick form (the suite's): the quick scenes, a few seconds each.
    pub quick: bool,
    /// Only these scenes (by name); all of the form's when empty.
    pub only: Vec<String>,
    /// Where synthetic datasets are cached.
    pub cache: PathBuf,
    /// Where results go.
    pub out: PathBuf,
    /// Seed of the synthetic sensors.
    pub seed: u64,
    /// The shared data folder (`../shared/data`): the meshes of the scenes that stand one in
    /// place of the modelled surfaces. Where a mesh is absent, its scene is skipped and said.
    pub data: PathBuf,
    /// Replace the outputs of an earlier corpus run in `out`.
    pub overwrite: bool,
    /// Set (by Ctrl-C) to stop: the current run writes what it tracked, the report what was
    /// done.
    pub interrupt: Arc<AtomicBool>,
}

/// One tracking run of the corpus, scored.
#[derive(Debug, Clone, Serialize)]
pub struct CorpusRow {
    /// The scene.
    pub scene: Scene,
    /// The filter model (`acc`, `vision`).
    pub filter: String,
    /// When a pose counts as right.
    pub bound: Bound,
    /// The verdict against the truth.
    pub score: Score,
    /// The run's summary (as `track` writes it).
    pub summary: Summary,
}

/// What the corpus reports while it runs.
#[derive(Debug)]
pub enum CorpusEvent<'a> {
    /// A step (synthesis, a tracking run) advanced: `done` of `total`.
    Step {
        /// The step.
        what: &'a str,
        /// Done.
        done: u64,
        /// Total.
        total: u64,
    },
    /// A run finished.
    RunDone(&'a CorpusRow),
    /// A scene was skipped, with why.
    Skipped(&'a Scene, &'a str),
}

/// Progress callback.
pub type CorpusProgress<'a> = &'a mut dyn FnMut(CorpusEvent);

impl CorpusOptions {
    /// The scenes this run covers, in the tables' order; an unknown name is refused.
    pub fn scenes(&self) -> Result<Vec<&'static Scene>, EvalError> {
        if let Some(bad) = self
            .only
            .iter()
            .find(|n| !SCENES.iter().any(|s| s.name == n.as_str()))
        {
            let names: Vec<&str> = SCENES.iter().map(|s| s.name).collect();
            return Err(EvalError::Option(format!(
                "--scene {bad}: no such scene (the corpus has {})",
                names.join(", ")
            )));
        }
        Ok(SCENES
            .iter()
            .filter(|s| {
                if self.only.is_empty() {
                    s.quick || !self.quick
                } else {
                    self.only.iter().any(|n| n == s.name)
                }
            })
            .collect())
    }
}

/// The object's size [m]: the diagonal of its model's bounding box, as the tracked rule
/// takes it (`TrackedRule::for_object`), from the dataset's model.
pub fn object_size(dataset: &Path) -> Result<f64, EvalError> {
    let path = dataset.join("model/scene.obj");
    let model = crate::model::load(&path).map_err(|e| EvalError::Manifest {
        path: path.clone(),
        what: format!("the model cannot be read: {e}"),
    })?;
    Ok(model.diagonal())
}

/// The share of the model's own pixels no occluder hides, per image of a synthetic dataset in
/// order (its `frames.csv`'s `model_unoccluded`; `None` where the model is out of view). Empty
/// where the dataset does not say (not synthetic, or an older layout).
pub fn unoccluded_shares(dataset: &Path) -> Vec<Option<f64>> {
    let Ok(text) = std::fs::read_to_string(dataset.join("frames.csv")) else {
        return Vec::new();
    };
    let mut lines = text.lines();
    let Some(column) = lines
        .next()
        .and_then(|h| h.split(',').position(|c| c == "model_unoccluded"))
    else {
        return Vec::new();
    };
    lines
        .map(|l| l.split(',').nth(column).and_then(|v| v.parse().ok()))
        .collect()
}

/// Every frame taken in `run`, for the score: the analysed ones in order with their verdict
/// and error, then the others (no pose, no verdict). `unoccluded` is the dataset's
/// [`unoccluded_shares`], by the frame's index.
pub fn frame_truths(run: &track::TrackRun, unoccluded: &[Option<f64>]) -> Vec<FrameTruth> {
    let half_visible = |index: usize| {
        unoccluded
            .get(index)
            .map(|share| share.is_some_and(|s| s >= 0.5))
    };
    let mut frames: Vec<FrameTruth> = run
        .frames
        .iter()
        .map(|r| FrameTruth {
            tracked: r.tracked,
            error: r.estimate_error_m.zip(r.estimate_error_deg),
            nees: r.nees,
            half_visible: half_visible(r.index),
        })
        .collect();
    let taken: usize = run.summary.frame_outcomes.values().sum();
    frames.extend((frames.len()..taken).map(|_| FrameTruth {
        tracked: None,
        error: None,
        nees: None,
        half_visible: None,
    }));
    frames
}

fn filter_name(m: ModelKind) -> String {
    format!("{m:?}").to_lowercase()
}

/// Tracks one scene's dataset with `filter`, in process (deterministic), and scores it.
fn run_one(
    scene: &'static Scene,
    dataset: &std::path::Path,
    filter: ModelKind,
    options: &CorpusOptions,
    progress: CorpusProgress,
) -> Result<CorpusRow, EvalError> {
    let name = filter_name(filter);
    let mut o = options_for(dataset, options.out.join(scene.name).join(&name))?;
    o.filter = filter;
    o.link = LinkSpec::InProcess(tracker::Precision::F32);
    o.overlay_every = 0;
    let what = format!("{} {name}", scene.name);
    let run = track::run(&o, options.interrupt.clone(), &mut |done, total, _, _| {
        progress(CorpusEvent::Step {
            what: &what,
            done: done as u64,
            total: total as u64,
        })
    })
    .map_err(|source| EvalError::Track {
        scenario: scene.name.into(),
        model: name.clone(),
        source: Box::new(source),
    })?;
    let bound = Bound::for_size(object_size(dataset)?);
    Ok(CorpusRow {
        scene: *scene,
        filter: name,
        bound,
        score: score::score(&frame_truths(&run, &unoccluded_shares(dataset)), &bound),
        summary: run.summary,
    })
}

/// The names a corpus run writes into its output folder.
fn outputs() -> Vec<String> {
    let mut names = vec!["corpus.md".to_string(), "corpus.json".to_string()];
    names.extend(SCENES.iter().map(|s| s.name.to_string()));
    names
}

/// Runs the corpus and writes `corpus.md` and `corpus.json` (and each run's outputs in
/// `SCENE/FILTER/`). Stopped by `options.interrupt`, it writes them for the runs done.
pub fn run(options: &CorpusOptions, progress: CorpusProgress) -> Result<CorpusReport, EvalError> {
    let scenes = options.scenes()?;
    let mut out = OutFolder::prepare(&options.out, &outputs(), None, options.overwrite)?;
    let mut report = CorpusReport {
        quick: options.quick,
        ..CorpusReport::default()
    };
    let stop = || options.interrupt.load(Ordering::Relaxed);
    'scenes: for scene in scenes {
        let what = format!("synth {}", scene.name);
        let synth = scene.synth_options(
            options
                .cache
                .join(scene.dataset_name(options.quick, options.seed)),
            &options.data,
            options.quick,
            options.seed,
        );
        if let Some(object) = synth.object.as_ref().filter(|p| !p.is_file()) {
            let why = format!(
                "{} is absent (the shared data folder, --data)",
                object.display()
            );
            progress(CorpusEvent::Skipped(scene, &why));
            report.skipped.push((scene.name.to_string(), why));
            continue;
        }
        let dataset = match ensure_synth(
            &options.cache,
            crate::synth::SynthOptions {
                interrupt: Some(options.interrupt.clone()),
                ..synth
            },
            &mut |done, total| {
                progress(CorpusEvent::Step {
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
        for filter in FILTERS {
            if stop() {
                break 'scenes;
            }
            let row = match run_one(scene, &dataset, filter, options, progress) {
                Ok(row) => row,
                Err(_) if stop() => break 'scenes,
                Err(e) => return Err(e),
            };
            out.keep();
            progress(CorpusEvent::RunDone(&row));
            report.rows.push(row);
        }
    }
    report.interrupted = stop();
    if !report.rows.is_empty() {
        report.write(&options.out)?;
    }
    Ok(report)
}
