//! Frame input, as a library (kornia-io is this for kornia): the sources a tracker's frames
//! come from, each a stream of 8-bit grey frames with time stamps, checked as they come (size,
//! order of the time stamps):
//!
//! - [`video`]: a video file, a pipe or a live V4L2 camera, decoded by the `ffmpeg` program;
//! - [`images`]: a folder of images (a plain one at a given rate, or a EuRoC `cam0`);
//! - [`euroc`]: a EuRoC/ASL dataset folder (its camera, IMU samples, ground truth, model);
//! - [`live`]: a live source read on a capture thread that keeps only the newest frame, and a
//!   recording played at its own rate;
//! - [`showinfo`], [`stats`]: ffmpeg's frame lines parsed, and the decoding's figures.
//!
//! Colour is converted to grey as the dataset code does: images through the `image` crate's
//! luma conversion, videos by ffmpeg's `gray` pixel format (the luma plane, full range). A
//! [`Frame`] becomes a [`tracker::Frame`] with `.into()`.

pub mod euroc;
pub mod images;
pub mod live;
pub mod showinfo;
pub mod stats;
pub mod video;

use image::GrayImage;
use std::path::PathBuf;

pub use self::images::ImageFolder;
pub use self::stats::DecodeStats;
pub use self::video::{VideoFrames, VideoOptions};

/// One grey frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Position in the stream, from 0.
    pub index: usize,
    /// Time stamp [ns] on the source's own clock: the container's presentation time of a
    /// video, `data.csv`'s stamp of a EuRoC folder, `index / fps` of a plain folder.
    pub t_ns: i64,
    /// The pixels.
    pub image: GrayImage,
}

impl From<Frame> for tracker::Frame {
    fn from(f: Frame) -> Self {
        tracker::Frame::decoded(f.index, f.t_ns, f.image)
    }
}

/// Why frames cannot be read. Each names the file (or folder) and the problem.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The input does not exist.
    #[error("{path}: no such file or folder")]
    Missing {
        /// The input.
        path: PathBuf,
    },
    /// The `ffmpeg` program could not be found.
    #[error(
        "`{program}` not found: video input needs ffmpeg (Debian: `apt-get install ffmpeg`, or run `cargo xtask setup`)"
    )]
    FfmpegMissing {
        /// The program looked for.
        program: PathBuf,
    },
    /// The `ffmpeg` program could not be started for another reason.
    #[error("cannot start `{program}`: {source}")]
    Spawn {
        /// The program.
        program: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// ffmpeg could not read the input; `reason` is what it said.
    #[error("{path}: ffmpeg cannot decode it ({status}): {reason}")]
    Ffmpeg {
        /// The input.
        path: PathBuf,
        /// ffmpeg's exit status.
        status: String,
        /// ffmpeg's error lines.
        reason: String,
    },
    /// ffmpeg decoded frames, then ended well (exit status 0) but said errors: a file cut off
    /// (`File ended prematurely`), a pipe whose writer died, corrupt packets. The frames
    /// before it were delivered; the run that used them did not see the whole input.
    #[error("{path}: the stream ended abnormally after {frames} frames; ffmpeg said: {reason}")]
    EndedAbnormally {
        /// The input.
        path: PathBuf,
        /// Frames delivered.
        frames: usize,
        /// ffmpeg's error lines.
        reason: String,
    },
    /// A pipe (or socket, or device) was closed by its writer: a live stream has no end of its
    /// own, so the run cannot know it saw the whole input.
    #[error(
        "{path}: the pipe was closed after {frames} frames: its writer finished or died, which a stream does not tell apart (a finite recording is tracked from its file; --max-frames ends a live run on purpose)"
    )]
    PipeClosed {
        /// The input.
        path: PathBuf,
        /// Frames delivered.
        frames: usize,
    },
    /// The input holds no frame.
    #[error("{path}: no frames ({what})")]
    Empty {
        /// The input.
        path: PathBuf,
        /// What was looked for.
        what: String,
    },
    /// A frame could not be read or has an unusable format.
    #[error("{path}: frame {index}: {what}")]
    BadFrame {
        /// The input (or the frame's file).
        path: PathBuf,
        /// Frame index.
        index: usize,
        /// What is wrong.
        what: String,
    },
    /// A frame differs in size from the first one.
    #[error("{path}: frame {index} is {}x{} pixels, the first frame was {}x{}", got.0, got.1, first.0, first.1)]
    WrongSize {
        /// The input (or the frame's file).
        path: PathBuf,
        /// Frame index.
        index: usize,
        /// Its size.
        got: (u32, u32),
        /// The first frame's.
        first: (u32, u32),
    },
    /// Time stamps do not increase.
    #[error(
        "{path}: time stamp of frame {index} ({t_ns} ns) is not after the previous frame's ({previous_ns} ns)"
    )]
    NotMonotonic {
        /// The input.
        path: PathBuf,
        /// Frame index.
        index: usize,
        /// Its stamp [ns].
        t_ns: i64,
        /// The previous frame's [ns].
        previous_ns: i64,
    },
    /// The input's description is unusable (folder contents, `data.csv`, `--fps`).
    #[error("{path}: {what}")]
    Invalid {
        /// The input.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// Where frames come from, as the command line names it.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameInput {
    /// `--video FILE`: anything ffmpeg reads, a V4L2 device such as `/dev/video0` included.
    Video(PathBuf),
    /// `--images DIR`: PNG/JPG files in name order at `fps`, or a EuRoC `cam0` folder (or a
    /// dataset root holding `mav0/cam0`) with its `data.csv` time stamps, when `fps` is `None`.
    Images {
        /// The folder.
        dir: PathBuf,
        /// Frame rate of a plain folder [Hz].
        fps: Option<f64>,
    },
    /// Frames a program already holds (decoded elsewhere, or once for benchmarks), with the
    /// name reports give them. They get the checks of every source.
    Decoded {
        /// What to call them.
        name: PathBuf,
        /// The frames, in order.
        frames: std::sync::Arc<Vec<Frame>>,
        /// Their nominal rate [Hz], if known.
        fps: Option<f64>,
    },
}

impl FrameInput {
    /// Opens the source (for a video: starts ffmpeg).
    pub fn open(&self, video: &VideoOptions) -> Result<FrameSource, FrameError> {
        Ok(match self {
            FrameInput::Video(path) => FrameSource::Video(VideoFrames::open(path, video)?),
            FrameInput::Images { dir, fps } => FrameSource::Images(ImageFolder::open(dir, *fps)?),
            FrameInput::Decoded { name, frames, fps } => FrameSource::Decoded {
                name: name.clone(),
                frames: frames.clone(),
                next: 0,
                fps: *fps,
                check: StreamCheck::default(),
            },
        })
    }

    /// Whether it names a camera device (V4L2), whose frames carry their capture time.
    pub fn is_camera(&self) -> bool {
        matches!(self, FrameInput::Video(p) if video::is_v4l2_device(p))
    }

    /// Whether it names a live source, whose frames come at its own pace: a camera (a V4L2
    /// device) or a pipe.
    pub fn is_live(&self) -> bool {
        matches!(self, FrameInput::Video(p) if video::is_v4l2_device(p) || video::is_pipe(p))
    }

    /// The file or folder.
    pub fn path(&self) -> &std::path::Path {
        match self {
            FrameInput::Video(p) => p,
            FrameInput::Images { dir, .. } => dir,
            FrameInput::Decoded { name, .. } => name,
        }
    }
}

/// An open frame source: an iterator of frames, ending at the first error.
#[derive(Debug)]
pub enum FrameSource {
    /// Decoded by ffmpeg.
    Video(VideoFrames),
    /// Read from a folder.
    Images(ImageFolder),
    /// Held in memory ([`FrameInput::Decoded`]).
    Decoded {
        /// What to call them.
        name: PathBuf,
        /// The frames.
        frames: std::sync::Arc<Vec<Frame>>,
        /// The next one.
        next: usize,
        /// Their nominal rate [Hz].
        fps: Option<f64>,
        /// Size and order checks.
        check: StreamCheck,
    },
}

impl FrameSource {
    /// Nominal frame rate [Hz], when the source states one (a video's stream rate, `--fps`).
    pub fn nominal_rate_hz(&self) -> Option<f64> {
        match self {
            FrameSource::Video(v) => v.nominal_rate_hz(),
            FrameSource::Images(f) => f.fps(),
            FrameSource::Decoded { fps, .. } => *fps,
        }
    }

    /// Whether the frames come from a live camera, at its own pace (not read at ours).
    pub fn is_live(&self) -> bool {
        matches!(self, FrameSource::Video(v) if v.is_live())
    }

    /// Frames announced in advance (a folder's file count), when known.
    pub fn len_hint(&self) -> Option<usize> {
        match self {
            FrameSource::Video(_) => None,
            FrameSource::Images(f) => Some(f.len()),
            FrameSource::Decoded { frames, .. } => Some(frames.len()),
        }
    }
}

impl Iterator for FrameSource {
    type Item = Result<Frame, FrameError>;

    fn next(&mut self) -> Option<Self::Item> {
        match self {
            FrameSource::Video(v) => v.next(),
            FrameSource::Images(f) => f.next(),
            FrameSource::Decoded {
                name,
                frames,
                next,
                check,
                ..
            } => {
                let frame = frames.get(*next)?.clone();
                *next += 1;
                Some(
                    check
                        .check(name, frame.index, frame.image.dimensions(), frame.t_ns)
                        .map(|()| frame),
                )
            }
        }
    }
}

/// The checks every source applies to each frame: one size for all, increasing time stamps.
#[derive(Debug, Clone, Default)]
pub struct StreamCheck {
    first_size: Option<(u32, u32)>,
    last_ns: Option<i64>,
}

impl StreamCheck {
    fn check(
        &mut self,
        path: &std::path::Path,
        index: usize,
        size: (u32, u32),
        t_ns: i64,
    ) -> Result<(), FrameError> {
        match self.first_size {
            Some(first) if first != size => {
                return Err(FrameError::WrongSize {
                    path: path.to_owned(),
                    index,
                    got: size,
                    first,
                });
            }
            _ => self.first_size = Some(size),
        }
        if let Some(previous_ns) = self.last_ns
            && t_ns <= previous_ns
        {
            return Err(FrameError::NotMonotonic {
                path: path.to_owned(),
                index,
                t_ns,
                previous_ns,
            });
        }
        self.last_ns = Some(t_ns);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stream_check_refuses_a_size_change_and_a_repeated_stamp() {
        let p = std::path::Path::new("in.mp4");
        let mut c = StreamCheck::default();
        c.check(p, 0, (64, 48), 0).unwrap();
        c.check(p, 1, (64, 48), 100).unwrap();
        let e = c.check(p, 2, (32, 48), 200).unwrap_err().to_string();
        assert_eq!(
            e,
            "in.mp4: frame 2 is 32x48 pixels, the first frame was 64x48"
        );
        let e = c.check(p, 2, (64, 48), 100).unwrap_err().to_string();
        assert_eq!(
            e,
            "in.mp4: time stamp of frame 2 (100 ns) is not after the previous frame's (100 ns)"
        );
        c.check(p, 2, (64, 48), 101).unwrap();
    }
}
