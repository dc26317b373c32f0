//! A video file or a live V4L2 camera, decoded by the `ffmpeg` program into a pipe.
//!
//! One process, no temporary files:
//!
//! ```text
//! ffmpeg -hide_banner -nostdin -nostats -loglevel level+info [-f v4l2] -copyts -i INPUT
//!        -map 0:v:0 -vf format=gray,showinfo -fps_mode passthrough -f rawvideo -pix_fmt gray pipe:1
//! ```
//!
//! - stdout carries the frames, `width × height` bytes each, nothing else;
//! - stderr carries, per frame, `showinfo`'s line (frame number, integer `pts`, size), written
//!   before the frame's bytes, and the filter's time base: a frame's time is `pts × time_base`,
//!   exact, on the container's own clock (`-copyts` keeps the container's times, a camera's
//!   stamps included, instead of shifting them to start at 0). The size comes from the same line,
//!   so a stream whose size changes is caught at the frame, and a live camera needs no second
//!   process (ffprobe) opening the device first;
//! - `-fps_mode passthrough` keeps every decoded frame once: without it the raw muxer's
//!   constant-rate default would duplicate or drop frames of a variable-rate video;
//! - the error lines (`[error]`, `[fatal]`) are kept and passed on when ffmpeg fails.
//!
//! A live camera (`/dev/video*`) goes through the same code, read as fast as it delivers: the
//! camera paces the stream.

use std::io::{BufRead as _, BufReader, Read as _};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc::{Receiver, channel};
use std::thread::JoinHandle;

use image::GrayImage;

use super::showinfo::{self, Line};
use super::{Frame, FrameError, StreamCheck};
use camera::MAX_IMAGE_SIDE;

/// How ffmpeg is found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VideoOptions {
    /// The ffmpeg program (default: `ffmpeg` on the `PATH`).
    pub ffmpeg: PathBuf,
}

impl Default for VideoOptions {
    fn default() -> Self {
        Self {
            ffmpeg: PathBuf::from("ffmpeg"),
        }
    }
}

/// Frames of a video (or a camera) decoded by ffmpeg.
#[derive(Debug)]
pub struct VideoFrames {
    path: PathBuf,
    child: Child,
    stdout: BufReader<ChildStdout>,
    /// The stderr reader's `Config` and `Frame` lines, in ffmpeg's order.
    events: Receiver<Line>,
    /// Returns ffmpeg's error lines when stderr closes.
    stderr: Option<JoinHandle<Vec<String>>>,
    time_base: Option<(i64, i64)>,
    frame_rate: Option<f64>,
    next_index: usize,
    check: StreamCheck,
    done: bool,
}

/// True for a V4L2 device path (ffmpeg needs `-f v4l2` for those).
pub(crate) fn is_v4l2_device(path: &Path) -> bool {
    path.to_str().is_some_and(|p| p.starts_with("/dev/video"))
}

/// Whether `path` is a stream with no end of its own: a named pipe, a socket or a character
/// device other than a camera. Its frames come at the writer's pace, and its end is the
/// writer's, which cannot tell a writer that finished from one that died.
pub(crate) fn is_pipe(path: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt as _;
    std::fs::metadata(path).is_ok_and(|m| {
        let t = m.file_type();
        t.is_fifo() || t.is_socket() || t.is_char_device()
    }) && !is_v4l2_device(path)
}

/// The ffmpeg command that decodes `path` into grey frames on its stdout, with each frame's
/// time stamp in its `showinfo` lines on stderr.
fn ffmpeg_command(path: &Path, options: &VideoOptions) -> Command {
    let mut cmd = Command::new(&options.ffmpeg);
    cmd.args([
        "-hide_banner",
        "-nostdin",
        "-nostats",
        "-loglevel",
        "level+info",
    ]);
    if is_v4l2_device(path) {
        cmd.args(["-f", "v4l2"]);
    }
    if is_pipe(path) {
        // A live stream is not probed for seconds (5 s of an mpegts feed by default, which
        // the run would then stay behind): the first packets say what it holds.
        cmd.args(["-probesize", "32768", "-analyzeduration", "0"]);
    }
    cmd.arg("-copyts")
        .arg("-i")
        .arg(path)
        .args([
            "-map",
            "0:v:0",
            "-vf",
            "format=gray,showinfo",
            "-fps_mode",
            "passthrough",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "gray",
            "pipe:1",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    cmd
}

/// Drains ffmpeg's `stderr` on a thread of its own, so that ffmpeg never blocks on it while
/// the frames wait in the stdout pipe: the frames' `showinfo` events go to the receiver, and
/// the thread returns ffmpeg's error lines.
fn drain_stderr(
    stderr: std::process::ChildStderr,
) -> (Receiver<Line>, std::io::Result<JoinHandle<Vec<String>>>) {
    let (tx, events) = channel();
    let reader = std::thread::Builder::new()
        .name("ffmpeg-stderr".into())
        .spawn(move || {
            let mut errors = Vec::new();
            let mut lines = BufReader::new(stderr);
            let mut buf = Vec::new();
            while matches!(lines.read_until(b'\n', &mut buf), Ok(n) if n > 0) {
                let line = String::from_utf8_lossy(&buf);
                match showinfo::parse(&line) {
                    Line::Error(e) => {
                        if !e.is_empty() && !errors.contains(&e) {
                            errors.push(e);
                        }
                    }
                    Line::Other => {}
                    // The receiver gone means the source was dropped: keep draining.
                    event => {
                        let _ = tx.send(event);
                    }
                }
                buf.clear();
            }
            errors
        });
    (events, reader)
}

impl VideoFrames {
    /// Starts ffmpeg on `path`. A missing file or program is an error here; ffmpeg's own
    /// refusal (an unreadable file) comes with the first frame asked for.
    pub fn open(path: &Path, options: &VideoOptions) -> Result<Self, FrameError> {
        if !path.exists() {
            return Err(FrameError::Missing {
                path: path.to_owned(),
            });
        }
        if path.is_dir() {
            return Err(FrameError::Invalid {
                path: path.to_owned(),
                what: "is a folder, not a video (image folders are --images)".into(),
            });
        }
        let mut cmd = ffmpeg_command(path, options);
        let mut child = cmd.spawn().map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                FrameError::FfmpegMissing {
                    program: options.ffmpeg.clone(),
                }
            } else {
                FrameError::Spawn {
                    program: options.ffmpeg.clone(),
                    source,
                }
            }
        })?;
        let (Some(stdout), Some(stderr)) = (child.stdout.take(), child.stderr.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(FrameError::Spawn {
                program: options.ffmpeg.clone(),
                source: std::io::Error::other("no pipes to ffmpeg"),
            });
        };
        let (events, reader) = drain_stderr(stderr);
        let reader = match reader {
            Ok(r) => r,
            Err(source) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(FrameError::Spawn {
                    program: options.ffmpeg.clone(),
                    source,
                });
            }
        };
        Ok(Self {
            path: path.to_owned(),
            child,
            stdout: BufReader::with_capacity(1 << 20, stdout),
            events,
            stderr: Some(reader),
            time_base: None,
            frame_rate: None,
            next_index: 0,
            check: StreamCheck::default(),
            done: false,
        })
    }

    /// The stream's frame rate as the container states it (known after the first frame).
    pub fn nominal_rate_hz(&self) -> Option<f64> {
        self.frame_rate
    }

    /// Whether this is live: a camera (a V4L2 device) or a pipe, whose frames come at its own
    /// pace.
    pub fn is_live(&self) -> bool {
        is_v4l2_device(self.path()) || is_pipe(self.path())
    }

    /// The input.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Stops ffmpeg (if still running) and returns its exit status and error lines.
    fn finish(&mut self, kill: bool) -> (String, Vec<String>, bool) {
        if kill {
            let _ = self.child.kill();
        }
        let status = self.child.wait();
        let errors = self
            .stderr
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        match status {
            Ok(s) => (s.to_string(), errors, s.success()),
            Err(e) => (format!("wait failed: {e}"), errors, false),
        }
    }

    fn fail(&mut self, error: FrameError) -> Option<Result<Frame, FrameError>> {
        self.done = true;
        self.finish(true);
        Some(Err(error))
    }

    /// The error for ffmpeg ending without a (complete) frame.
    fn ended(&mut self, partial: Option<(usize, usize)>) -> Option<Result<Frame, FrameError>> {
        self.done = true;
        let (status, errors, success) = self.finish(false);
        let path = self.path.clone();
        if !success {
            let reason = if errors.is_empty() {
                "no error message".to_owned()
            } else {
                errors.join("; ")
            };
            return Some(Err(FrameError::Ffmpeg {
                path,
                status,
                reason,
            }));
        }
        if let Some((got, want)) = partial {
            return Some(Err(FrameError::BadFrame {
                path,
                index: self.next_index,
                what: format!("the stream ended after {got} of its {want} bytes"),
            }));
        }
        if self.next_index == 0 {
            return Some(Err(FrameError::Empty {
                path,
                what: "ffmpeg decoded no video frame".into(),
            }));
        }
        // ffmpeg exits 0 on a cut-off file or a pipe whose writer died, and says so only in
        // its error lines (issue 33: such runs exited 0 as complete).
        if !errors.is_empty() {
            return Some(Err(FrameError::EndedAbnormally {
                path,
                frames: self.next_index,
                reason: errors.join("; "),
            }));
        }
        // A pipe's end is its writer's: finished or dead, the stream does not say (issue 54:
        // a writer killed mid-stream exited 0 as complete, ffmpeg saying nothing).
        if is_pipe(&path) {
            return Some(Err(FrameError::PipeClosed {
                path,
                frames: self.next_index,
            }));
        }
        None
    }

    fn next_event(&mut self) -> Option<(usize, Option<i64>, (u32, u32))> {
        loop {
            match self.events.recv().ok()? {
                Line::Config {
                    time_base,
                    frame_rate,
                } => {
                    self.time_base = Some(time_base);
                    self.frame_rate = (frame_rate.0 > 0 && frame_rate.1 > 0)
                        .then(|| frame_rate.0 as f64 / frame_rate.1 as f64);
                }
                Line::Frame { n, pts, size } => return Some((n, pts, size)),
                // The reader sends only the two above.
                Line::Error(_) | Line::Other => {}
            }
        }
    }
}

impl Iterator for VideoFrames {
    type Item = Result<Frame, FrameError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let index = self.next_index;
        let Some((n, pts, (w, h))) = self.next_event() else {
            // stderr closed: ffmpeg is ending. Whatever is left on stdout is not a frame.
            let mut rest = Vec::new();
            let _ = self.stdout.read_to_end(&mut rest);
            let end = self.ended(None);
            if rest.is_empty() || matches!(end, Some(Err(FrameError::Ffmpeg { .. }))) {
                return end;
            }
            return Some(Err(FrameError::BadFrame {
                path: self.path.clone(),
                index,
                what: format!("{} bytes on the pipe without a frame announced", rest.len()),
            }));
        };
        let path = self.path.clone();
        if n != index {
            return self.fail(FrameError::BadFrame {
                path,
                index,
                what: format!("ffmpeg announced frame {n} instead"),
            });
        }
        if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
            return self.fail(FrameError::BadFrame {
                path,
                index,
                what: format!("unusable size {w}x{h}"),
            });
        }
        let Some((num, den)) = self.time_base.filter(|&(a, b)| a > 0 && b > 0) else {
            return self.fail(FrameError::BadFrame {
                path,
                index,
                what: "ffmpeg gave no time base for the stream".into(),
            });
        };
        let Some(pts) = pts else {
            return self.fail(FrameError::BadFrame {
                path,
                index,
                what: "the container gives it no time stamp".into(),
            });
        };
        let Some(t_ns) = frame_time_ns(pts, (num, den)) else {
            return self.fail(FrameError::BadFrame {
                path,
                index,
                what: format!("time stamp {pts} × {num}/{den} s out of range"),
            });
        };
        if let Err(e) = self.check.check(&path, index, (w, h), t_ns) {
            return self.fail(e);
        }
        let want = w as usize * h as usize;
        let mut data = vec![0u8; want];
        let mut got = 0;
        while got < want {
            match self.stdout.read(&mut data[got..]) {
                Ok(0) => return self.ended(Some((got, want))),
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return self.fail(FrameError::BadFrame {
                        path,
                        index,
                        what: format!("reading the pipe from ffmpeg: {e}"),
                    });
                }
            }
        }
        let Some(image) = GrayImage::from_raw(w, h, data) else {
            return self.fail(FrameError::BadFrame {
                path,
                index,
                what: format!("{want} bytes do not make a {w}x{h} image"),
            });
        };
        self.next_index += 1;
        Some(Ok(Frame { index, t_ns, image }))
    }
}

/// A frame's time [ns]: `pts × num / den` s, `None` where it does not fit an `i64` (or `den`
/// is 0). `pts × num` alone always fits in an `i128`; times 10⁹ it need not (a stream's absurd
/// time base).
pub fn frame_time_ns(pts: i64, (num, den): (i64, i64)) -> Option<i64> {
    if den == 0 {
        return None;
    }
    let t = (i128::from(pts) * i128::from(num)).checked_mul(1_000_000_000)? / i128::from(den);
    i64::try_from(t).ok()
}

impl Drop for VideoFrames {
    fn drop(&mut self) {
        if !self.done {
            self.finish(true);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn frame_times_are_exact_or_refused() {
        assert_eq!(frame_time_ns(505_856, (1, 15_360)), Some(32_933_333_333));
        assert_eq!(frame_time_ns(-3, (1, 1)), Some(-3_000_000_000));
        assert_eq!(frame_time_ns(1, (1, 0)), None);
        // Past what 10⁹ times fits: refused, not wrapped.
        assert_eq!(frame_time_ns(i64::MAX, (i64::MAX, 1)), None);
        assert_eq!(frame_time_ns(i64::MIN, (i64::MAX, 1)), None);
    }

    proptest! {
        /// Any time stamp and time base: a time that is `pts × num / den` s to the
        /// nanosecond, or none; never a panic or a wrapped value. Time bases of every size,
        /// and the small ones of real streams, so that both answers are reached.
        #[test]
        fn any_time_base_gives_the_exact_time_or_none(
            pts in prop_oneof![any::<i64>(), -1_000_000_000i64..1_000_000_000],
            num in prop_oneof![any::<i64>(), 1i64..1001],
            den in prop_oneof![any::<i64>(), 1i64..1_000_001],
        ) {
            if let Some(t) = frame_time_ns(pts, (num, den)) {
                let exact = i128::from(pts) * i128::from(num) * 1_000_000_000 / i128::from(den);
                prop_assert_eq!(i128::from(t), exact);
            }
        }
    }
}
