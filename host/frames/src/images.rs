//! A folder of images: PNG/JPG files in name order at a given rate, or a EuRoC `cam0` folder
//! with its `data.csv` time stamps (no `imu0` needed).
//!
//! Files are sorted by name as bytes, so numbers in names must be zero-padded
//! (`frame_000010.png` after `frame_000009.png`), as every recorder writes them.

use std::path::{Path, PathBuf};

use super::{Frame, FrameError, StreamCheck};
use crate::euroc::read_frame_list;

/// Frames read one by one from image files.
#[derive(Debug)]
pub struct ImageFolder {
    dir: PathBuf,
    /// Files and their stamps [ns].
    files: Vec<(PathBuf, i64)>,
    fps: Option<f64>,
    next: usize,
    check: StreamCheck,
    done: bool,
}

fn is_image(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
}

/// `cam0` of a EuRoC folder: `dir` itself, or `dir/mav0/cam0` of a dataset root.
pub fn euroc_cam0(dir: &Path) -> Option<PathBuf> {
    [dir.to_owned(), dir.join("mav0/cam0")]
        .into_iter()
        .find(|d| d.join("data.csv").is_file())
}

impl ImageFolder {
    /// Lists the frames of `dir`: a plain folder needs `fps`; a EuRoC folder takes its time
    /// stamps from `data.csv` and refuses `fps`.
    pub fn open(dir: &Path, fps: Option<f64>) -> Result<Self, FrameError> {
        let invalid = |what: String| FrameError::Invalid {
            path: dir.to_owned(),
            what,
        };
        if !dir.exists() {
            return Err(FrameError::Missing {
                path: dir.to_owned(),
            });
        }
        if !dir.is_dir() {
            return Err(invalid(
                "is a file, not a folder of images (videos are --video)".into(),
            ));
        }
        if let Some(f) = fps
            && !(f.is_finite() && f > 0.0 && f <= 10_000.0)
        {
            return Err(invalid(format!(
                "--fps must be a frame rate in (0, 10000] Hz, got {f}"
            )));
        }
        let files = if let Some(cam0) = euroc_cam0(dir) {
            if fps.is_some() {
                return Err(invalid(format!(
                    "is a EuRoC camera folder: its time stamps come from {}, give no --fps",
                    cam0.join("data.csv").display()
                )));
            }
            let list = read_frame_list(&cam0.join("data.csv"), &cam0.join("data"))
                .map_err(|e| invalid(e.to_string()))?;
            let mut files = Vec::with_capacity(list.len());
            for f in list {
                let t = i64::try_from(f.stamp)
                    .map_err(|_| invalid(format!("time stamp {} ns out of range", f.stamp)))?;
                files.push((f.path, t));
            }
            files
        } else {
            let entries = std::fs::read_dir(dir)
                .map_err(|e| invalid(format!("cannot list the folder: {e}")))?;
            let mut names = Vec::new();
            for e in entries {
                let e = e.map_err(|e| invalid(format!("cannot list the folder: {e}")))?;
                let p = e.path();
                if is_image(&p) && p.is_file() {
                    names.push(p);
                }
            }
            if names.is_empty() {
                return Err(FrameError::Empty {
                    path: dir.to_owned(),
                    what: "no .png, .jpg or .jpeg file, and no EuRoC data.csv".into(),
                });
            }
            names.sort();
            let Some(fps) = fps else {
                return Err(invalid(format!(
                    "a folder of {} images without time stamps needs --fps",
                    names.len()
                )));
            };
            names
                .into_iter()
                .enumerate()
                .map(|(i, p)| (p, (i as f64 * 1e9 / fps).round() as i64))
                .collect()
        };
        Ok(Self {
            dir: dir.to_owned(),
            files,
            fps,
            next: 0,
            check: StreamCheck::default(),
            done: false,
        })
    }

    /// Frames listed.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// True when no frame is listed (never after a successful `open`).
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    /// The `--fps` of a plain folder.
    pub fn fps(&self) -> Option<f64> {
        self.fps
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Iterator for ImageFolder {
    type Item = Result<Frame, FrameError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let index = self.next;
        let (path, t_ns) = self.files.get(index)?.clone();
        self.next += 1;
        let result = camera::read_frame(&path)
            .map_err(|e| FrameError::BadFrame {
                path: path.clone(),
                index,
                what: e.to_string(),
            })
            .map(|img| img.into_luma8())
            .and_then(|image| {
                self.check
                    .check(&path, index, image.dimensions(), t_ns)
                    .map(|()| Frame { index, t_ns, image })
            });
        self.done = result.is_err();
        Some(result)
    }
}
