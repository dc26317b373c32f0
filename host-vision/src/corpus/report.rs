//! The corpus's tables: one row per scene and filter (`corpus.md`), and every figure with the
//! runs' summaries (`corpus.json`).

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use super::CorpusRow;
use crate::eval::EvalError;

/// A wrong stretch counts as reported in time when the verdict says so within this many frames
/// of its first wrong frame (issue 56's goal).
pub const REPORT_WITHIN_FRAMES: usize = 3;

/// The corpus's results.
#[derive(Debug, Clone, Default, Serialize)]
pub struct CorpusReport {
    /// The quick form (the suite's) rather than the full one.
    pub quick: bool,
    /// Every run, in the tables' order.
    pub rows: Vec<CorpusRow>,
    /// Stopped by Ctrl-C: the rows are the runs done (the last one possibly cut short).
    pub interrupted: bool,
    /// Scenes not run, with why (a mesh absent).
    pub skipped: Vec<(String, String)>,
}

fn percent(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{:.1} %", 100.0 * v))
}

impl CorpusReport {
    /// The table as Markdown, with the legend.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        if self.interrupted {
            let _ = writeln!(
                s,
                "**Interrupted**: only the runs done are here; † marks one stopped part-way.\n"
            );
        }
        let _ = writeln!(
            s,
            "| scene | filter | frames | right | judged | tracked | precision | recall | recall, half visible | tracked beyond 2× | worst tracked | wrong stretches | reported ≤ {REPORT_WITHIN_FRAMES} frames | never reported | NEES tracked: mean, median, ≤ χ²₆ 95 % | NEES all |"
        );
        let _ = writeln!(
            s,
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        );
        for r in &self.rows {
            let c = &r.score;
            let worst = c.worst_tracked.map_or("-".into(), |[m, deg]| {
                format!("{:.1} cm, {deg:.1}°", m * 100.0)
            });
            let in_time = c
                .report_delays
                .iter()
                .filter(|d| d.is_some_and(|d| d <= REPORT_WITHIN_FRAMES))
                .count();
            // A run that judged no frame reported nothing: its stretches are not "reported".
            let (in_time, never, precision) = if c.judged == 0 {
                ("-".to_string(), "-".to_string(), "no verdict".to_string())
            } else {
                (
                    in_time.to_string(),
                    c.unreported().to_string(),
                    percent(c.precision),
                )
            };
            let nees = |c: Option<super::score::Calibration>| {
                c.map_or("-".into(), |c| {
                    format!(
                        "{:.2}, {:.2}, {}",
                        c.mean,
                        c.median,
                        percent(Some(c.inside_95))
                    )
                })
            };
            let _ = writeln!(
                s,
                "| {} | {}{} | {} | {} | {} | {} | {precision} | {} | {} | {} | {worst} | {} | {in_time} | {never} | {} | {} |",
                r.scene.name,
                r.filter,
                if r.summary.stopped_early { " †" } else { "" },
                c.frames,
                percent(c.success),
                c.judged,
                c.tracked,
                percent(c.recall),
                percent(c.recall_half_visible),
                c.tracked_far,
                c.report_delays.len(),
                nees(c.nees_tracked),
                nees(c.nees_all),
            );
        }
        for (scene, why) in &self.skipped {
            let _ = writeln!(s, "\n**Skipped** {scene}: {why}.");
        }
        let _ = writeln!(
            s,
            "\n- **right**: share of the frames with a pose whose error against the truth is within the bound (5 cm and 5°, or a tenth of the model's bounding-box diagonal if smaller), whatever the verdict said;\n\
             - **judged**: frames given a verdict; **tracked**: flagged tracked;\n\
             - **precision**: share of the tracked frames that are right (of those with a truth to tell); **recall**: share of the right frames flagged tracked; **half visible**: of those with at least half of the model's own pixels in view, unoccluded (the goal's);\n\
             - **wrong stretches**: runs of consecutive wrong frames; **reported**: the verdict said \"not tracked\" within {REPORT_WITHIN_FRAMES} frames of the first (docs/VISION.md §10);\n\
             - **NEES**: the normalised estimation error squared of each pose by the core's covariance (eq. T6), over the tracked frames and over every frame with a pose: χ²₆ where calibrated (mean 6, median 5.3, 95 % below 12.6)."
        );
        s
    }

    /// Writes `corpus.md` and `corpus.json` into `out`.
    pub fn write(&self, out: &Path) -> Result<(), EvalError> {
        let err = |path: &Path| {
            let path = path.to_owned();
            move |source| EvalError::Output { path, source }
        };
        std::fs::create_dir_all(out).map_err(err(out))?;
        let md = out.join("corpus.md");
        let form = if self.quick { "quick" } else { "full" };
        std::fs::write(
            &md,
            format!(
                "# The robustness corpus ({form} form)\n\n{}",
                self.markdown()
            ),
        )
        .map_err(err(&md))?;
        let json = out.join("corpus.json");
        let text = serde_json::to_string_pretty(self).map_err(|e| EvalError::Output {
            path: json.clone(),
            source: std::io::Error::other(e),
        })?;
        std::fs::write(&json, text).map_err(err(&json))
    }
}
