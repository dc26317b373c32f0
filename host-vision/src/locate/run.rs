//! `host-vision locate`: one image and a model give the pose, an overlay and the verification
//! figures. The tool a user runs first on their own object.

use std::path::{Path, PathBuf};

use image::GrayImage;
use nalgebra::Vector3;
use serde::Serialize;

use super::database::{Database, DatabaseConfig, DatabaseError, Provenance, bounding_sphere};
use super::{Attempt, LocateConfig, Locator};
use crate::camera::Camera;
use crate::model::{self, ModelError};
use crate::out_folder::{OutFolder, OutFolderError};
use crate::start_pose::start_pose_json;
use crate::track::vision::Vision;
use crate::track::{TrackError, overlay};
use frames::{FrameError, FrameInput, VideoOptions};

/// The image to locate the model in.
#[derive(Debug, Clone, PartialEq)]
pub enum LocateInput {
    /// An image file (PNG or JPEG).
    Image(PathBuf),
    /// Frame `frame` (from 0) of a video.
    VideoFrame {
        /// The video.
        video: PathBuf,
        /// The frame's index.
        frame: usize,
    },
}

/// What `locate` does.
#[derive(Debug, Clone)]
pub struct LocateOptions {
    /// The image.
    pub input: LocateInput,
    /// The model file.
    pub model: PathBuf,
    /// The camera of the image.
    pub camera: Camera,
    /// Folder of the viewpoint database's cache.
    pub cache: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// Replace the outputs of an earlier run in `out`.
    pub overwrite: bool,
    /// The database's settings.
    pub database: DatabaseConfig,
    /// The attempt's settings.
    pub locate: LocateConfig,
}

/// Why `locate` failed (a pose not found is no failure: see [`LocateReport`]).
#[derive(Debug, thiserror::Error)]
pub enum LocateError {
    /// The model.
    #[error("model {path}: {source}")]
    Model {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: ModelError,
    },
    /// The database.
    #[error(transparent)]
    Database(#[from] DatabaseError),
    /// Rendering, registration.
    #[error(transparent)]
    Track(#[from] TrackError),
    /// The frame's analysis (the renderer, the image).
    #[error(transparent)]
    Vision(#[from] vision::VisionError),
    /// The image file.
    #[error("{path}: {source}")]
    Image {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: image::ImageError,
    },
    /// Decoding the video.
    #[error(transparent)]
    Frames(#[from] FrameError),
    /// The video is shorter.
    #[error("{video}: no frame {frame} (the video has {frames})")]
    NoFrame {
        /// The video.
        video: PathBuf,
        /// Asked for.
        frame: usize,
        /// It has.
        frames: usize,
    },
    /// An image of another size than the camera's.
    #[error("{what}: the image is {}x{} pixels, the camera's intrinsics are for {}x{}", got.0, got.1, expected.0, expected.1)]
    ImageSize {
        /// The image.
        what: String,
        /// Its size.
        got: (u32, u32),
        /// The camera's.
        expected: (u32, u32),
    },
    /// The output folder.
    #[error(transparent)]
    Out(#[from] OutFolderError),
    /// Writing an output.
    #[error("{path}: {source}")]
    Output {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
}

/// What `locate` found and wrote.
#[derive(Debug, Clone, Serialize)]
pub struct LocateReport {
    /// The attempt's figures.
    pub attempt: Attempt,
    /// Whether a pose was accepted.
    pub accepted: bool,
    /// The accepted pose's `cMo` rows (model → camera), if any.
    pub c_m_o: Option<[[f64; 4]; 4]>,
    /// The database: renderings, entries, bytes on disk, and where it came from.
    pub database: DatabaseReport,
    /// The renderer's adapter.
    pub adapter: String,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

/// The database's figures.
#[derive(Debug, Clone, Serialize)]
pub struct DatabaseReport {
    /// Renderings.
    pub views: usize,
    /// Keypoints.
    pub entries: usize,
    /// Size of the cache file [bytes].
    pub bytes: u64,
    /// The cache file.
    pub path: PathBuf,
    /// Read from the cache (`None`), or why it was built.
    pub built_because: Option<String>,
}

/// Outputs `locate` writes in its folder.
pub const OUTPUTS: [&str; 3] = ["pose.json", "locate.json", "overlay.png"];

fn read_input(input: &LocateInput) -> Result<(GrayImage, String), LocateError> {
    match input {
        LocateInput::Image(path) => {
            let img = camera::read_frame(path)
                .map_err(|source| LocateError::Image {
                    path: path.clone(),
                    source,
                })?
                .into_luma8();
            Ok((img, path.display().to_string()))
        }
        LocateInput::VideoFrame { video, frame } => {
            let source = FrameInput::Video(video.clone()).open(&VideoOptions::default())?;
            let mut seen = 0;
            for f in source {
                let f = f?;
                if seen == *frame {
                    return Ok((f.image, format!("{} frame {frame}", video.display())));
                }
                seen += 1;
            }
            Err(LocateError::NoFrame {
                video: video.clone(),
                frame: *frame,
                frames: seen,
            })
        }
    }
}

fn output_error(path: &Path) -> impl Fn(std::io::Error) -> LocateError + '_ {
    move |source| LocateError::Output {
        path: path.to_owned(),
        source,
    }
}

/// Locates the model in the image; `progress` follows the database's build (`(done, total)`
/// renderings) when the cache has none.
pub fn run(
    o: &LocateOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<LocateReport, LocateError> {
    let owned: Vec<String> = OUTPUTS.iter().map(|s| s.to_string()).collect();
    let mut out = OutFolder::prepare(&o.out, &owned, None, o.overwrite)?;
    let model = model::load(&o.model).map_err(|source| LocateError::Model {
        path: o.model.clone(),
        source,
    })?;
    let (raw, what) = read_input(&o.input)?;
    let expected = (o.camera.width, o.camera.height);
    if raw.dimensions() != expected {
        return Err(LocateError::ImageSize {
            what,
            got: raw.dimensions(),
            expected,
        });
    }
    let (db, provenance) = Database::load_or_build(&model, &o.database, &o.cache, progress)?;
    let (path, built_because) = match provenance {
        Provenance::Cached(path) => (path, None),
        Provenance::Built { path, why } => (path, Some(why)),
    };
    let database = DatabaseReport {
        views: db.views.len(),
        entries: db.entries.len(),
        bytes: std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0),
        built_because,
        path,
    };
    let mut vision = Vision::new(o.camera, &model, super::vision_options())?;
    let locator = Locator::new(&db, o.locate);
    let (attempt, result) = locator.attempt(&mut vision, &raw, true)?;

    let mut outputs = Vec::new();
    let c_m_o = attempt.pose.map(|pose| {
        let m = crate::start_pose::cmo_of_pose(&pose);
        let mut rows = [[0.0; 4]; 4];
        for (i, row) in rows.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = m[(i, j)];
            }
        }
        rows
    });
    if let Some(pose) = &attempt.pose {
        let p = o.out.join("pose.json");
        std::fs::write(&p, start_pose_json(pose)).map_err(output_error(&p))?;
        outputs.push(p);
    }
    if let Some(img) = result.as_ref().and_then(|r| {
        let (c, radius) = bounding_sphere(&model);
        overlay::draw(r, vision.ideal_camera(), (Vector3::from(c), radius))
    }) {
        let p = o.out.join("overlay.png");
        img.save(&p)
            .map_err(|e| output_error(&p)(std::io::Error::other(e)))?;
        outputs.push(p);
    }
    let mut report = LocateReport {
        accepted: attempt.accepted(),
        attempt,
        c_m_o,
        database,
        adapter: vision.adapter_summary(),
        outputs,
    };
    let p = o.out.join("locate.json");
    report.outputs.push(p.clone());
    let json = serde_json::to_string_pretty(&report)
        .map_err(|e| output_error(&p)(std::io::Error::other(e)))?;
    std::fs::write(&p, json).map_err(output_error(&p))?;
    out.keep();
    Ok(report)
}

impl std::fmt::Display for LocateReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = &self.attempt;
        let d = &self.database;
        writeln!(
            f,
            "database     {} renderings, {} keypoints, {:.1} MB ({}{})",
            d.views,
            d.entries,
            d.bytes as f64 / 1e6,
            d.path.display(),
            d.built_because
                .as_ref()
                .map_or(String::from(", cached"), |w| format!(", built: {w}"))
        )?;
        writeln!(f, "renderer     {}", self.adapter)?;
        if a.candidate.is_some() {
            writeln!(
                f,
                "attempt      {} keypoints, {} matches, {} RANSAC inliers ({} iterations)",
                a.keypoints, a.matches, a.inliers, a.iterations
            )?;
        } else if a.iterations == 0 {
            writeln!(
                f,
                "attempt      {} keypoints, {} matches: too few for RANSAC",
                a.keypoints, a.matches
            )?;
        } else {
            // Issue 33: "0 RANSAC inliers (0 iterations)" was said of a search that ran.
            writeln!(
                f,
                "attempt      {} keypoints, {} matches, no RANSAC pose: the best of {} iterations had {} inliers, too few",
                a.keypoints, a.matches, a.iterations, a.best_inliers
            )?;
        }
        writeln!(
            f,
            "verified     {} features registered, rms {}, correlation {}",
            a.registered,
            a.rms_px.map_or("-".into(), |r| format!("{r:.2} px")),
            a.ncc.map_or("-".into(), |c| format!("{c:.3}"))
        )?;
        let t = &a.times;
        writeln!(
            f,
            "time         detect {:.1} ms, match {:.1} ms, RANSAC {:.1} ms, verify {:.1} ms, choose {:.1} ms",
            t.detect * 1e3,
            t.matching * 1e3,
            t.ransac * 1e3,
            t.verify * 1e3,
            t.choose * 1e3
        )?;
        match &self.c_m_o {
            Some(m) => writeln!(
                f,
                "pose         accepted: model at [{:.4}, {:.4}, {:.4}] m in the camera",
                m[0][3], m[1][3], m[2][3]
            )?,
            None if a.ambiguous => writeln!(
                f,
                "pose         not accepted: ambiguous, poses verified that the image cannot tell apart (the two tilts of a face seen nearly face on?); try another view"
            )?,
            None if a.candidate.is_some() => writeln!(
                f,
                "pose         not accepted: the pose RANSAC found did not pass the verification"
            )?,
            None => writeln!(f, "pose         none found")?,
        }
        for p in &self.outputs {
            writeln!(f, "  {}", p.display())?;
        }
        Ok(())
    }
}
