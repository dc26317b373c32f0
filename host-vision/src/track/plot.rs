//! Plots (SVG, no fonts needed): prediction error over time per model (the paper's Fig. 5 and
//! 12) and position error against ground truth.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::TrackError;
use super::frame_row::FrameRow;

/// One named series of `(t, value)`.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend.
    pub name: String,
    /// Points.
    pub points: Vec<(f64, f64)>,
}

const COLOURS: [RGBColor; 4] = [
    RGBColor(200, 40, 40),
    RGBColor(40, 110, 200),
    RGBColor(30, 150, 60),
    RGBColor(150, 80, 180),
];

fn plot_err(path: &Path, e: impl std::fmt::Display) -> TrackError {
    TrackError::Output {
        path: path.to_owned(),
        source: std::io::Error::other(e.to_string()),
    }
}

/// Splits points into runs without gaps: a gap (frames without a value, e.g. without vision)
/// is more than three times the median spacing, and is left blank rather than bridged.
fn segments(points: &[(f64, f64)]) -> Vec<&[(f64, f64)]> {
    let mut steps: Vec<f64> = points.windows(2).map(|w| w[1].0 - w[0].0).collect();
    steps.sort_by(f64::total_cmp);
    let Some(&median) = steps.get(steps.len() / 2) else {
        return vec![points];
    };
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..points.len() {
        if points[i].0 - points[i - 1].0 > 3.0 * median {
            out.push(&points[start..i]);
            start = i;
        }
    }
    out.push(&points[start..]);
    out
}

/// Draws `series` as lines into an SVG file (gaps left blank).
pub fn line_plot(
    path: &Path,
    title: &str,
    y_label: &str,
    series: &[Series],
    y_cap: Option<f64>,
) -> Result<(), TrackError> {
    let points = series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for &(x, y) in points {
        if x.is_finite() && y.is_finite() {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
    }
    if !(x0.is_finite() && x1 > x0) {
        x0 = 0.0;
        x1 = 1.0;
    }
    let y1 = y_cap.map_or(y1, |c| y1.min(c)).max(1e-9) * 1.05;
    let root = SVGBackend::new(path, (960, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(x0..x1, 0.0..y1)
        .map_err(|e| plot_err(path, e))?;
    chart
        .configure_mesh()
        .x_desc("time [s]")
        .y_desc(y_label)
        .draw()
        .map_err(|e| plot_err(path, e))?;
    for (i, s) in series.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        for (k, run) in segments(&s.points).into_iter().enumerate() {
            let drawn = chart
                .draw_series(LineSeries::new(
                    run.iter().map(|&(x, y)| (x, y.min(y1))),
                    colour.stroke_width(1),
                ))
                .map_err(|e| plot_err(path, e))?;
            if k == 0 {
                drawn
                    .label(s.name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour));
            }
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| plot_err(path, e))?;
    root.present().map_err(|e| plot_err(path, e))?;
    Ok(())
}

/// Prediction error per frame and, with ground truth, the camera position error `(t, mm)`
/// over time, for one run of `model`.
pub fn write_track_plots(
    out: &Path,
    model: &str,
    rows: &[FrameRow],
    position_mm: &[(f64, f64)],
) -> Result<Vec<PathBuf>, TrackError> {
    let dir = out.join("plots");
    std::fs::create_dir_all(&dir).map_err(|source| TrackError::Output {
        path: dir.clone(),
        source,
    })?;
    let mut written = Vec::new();
    let pred = Series {
        name: format!("{model} model"),
        points: rows
            .iter()
            .filter_map(|r| Some((r.t, r.prediction_error_px?)))
            .collect(),
    };
    let contour = Series {
        name: format!("{model} model, contour along its normals"),
        points: rows
            .iter()
            .filter_map(|r| Some((r.t, r.contour_error_px?)))
            .collect(),
    };
    let series: Vec<Series> = [pred, contour]
        .into_iter()
        .filter(|s| !s.points.is_empty())
        .collect();
    let path = dir.join("prediction_error.svg");
    line_plot(
        &path,
        "Prediction error per frame",
        "mean prediction error [px]",
        &series,
        Some(30.0),
    )?;
    written.push(path);
    if !position_mm.is_empty() {
        let pos = Series {
            name: format!("{model} model"),
            points: position_mm.to_vec(),
        };
        let path = dir.join("position_error.svg");
        line_plot(
            &path,
            "Camera position error against ground truth",
            "position error [mm]",
            &[pos],
            Some(200.0),
        )?;
        written.push(path);
    }
    Ok(written)
}
