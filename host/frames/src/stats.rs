//! What `host-vision frames` reports: a whole source decoded, counted and timed.

use std::time::Instant;

use super::{FrameError, FrameSource};

/// Frame count, size, time span and decoding speed of a source read to its end.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodeStats {
    /// Frames decoded.
    pub frames: usize,
    /// Width and height [px].
    pub size: (u32, u32),
    /// First and last time stamp [ns].
    pub first_ns: i64,
    /// Last time stamp [ns].
    pub last_ns: i64,
    /// Shortest and longest interval between frames [s] (`None` for one frame).
    pub interval_s: Option<(f64, f64)>,
    /// The source's stated rate [Hz], when it states one.
    pub nominal_rate_hz: Option<f64>,
    /// Mean intensity of all frames (0-255): shows that pixels arrived, not just bytes.
    pub mean_intensity: f64,
    /// Wall time of the decoding [s].
    pub wall_s: f64,
}

impl DecodeStats {
    /// Reads `source` to its end (or to `limit` frames); `progress` gets the frames done.
    /// The first bad frame is the error.
    pub fn collect(
        mut source: FrameSource,
        limit: Option<usize>,
        progress: &mut dyn FnMut(usize),
    ) -> Result<Self, FrameError> {
        let start = Instant::now();
        let (mut frames, mut size, mut first_ns, mut last_ns) = (0usize, (0, 0), 0i64, 0i64);
        let mut interval: Option<(f64, f64)> = None;
        let mut sum = 0f64;
        for frame in source.by_ref() {
            let frame = frame?;
            if frames == 0 {
                size = frame.image.dimensions();
                first_ns = frame.t_ns;
            } else {
                let dt = (frame.t_ns - last_ns) as f64 * 1e-9;
                interval = Some(interval.map_or((dt, dt), |(lo, hi)| (lo.min(dt), hi.max(dt))));
            }
            last_ns = frame.t_ns;
            let px = frame.image.as_raw();
            sum += px.iter().map(|&v| u64::from(v)).sum::<u64>() as f64 / px.len() as f64;
            frames += 1;
            progress(frames);
            if limit.is_some_and(|l| frames >= l) {
                break;
            }
        }
        Ok(Self {
            frames,
            size,
            first_ns,
            last_ns,
            interval_s: interval,
            nominal_rate_hz: source.nominal_rate_hz(),
            mean_intensity: if frames > 0 { sum / frames as f64 } else { 0.0 },
            wall_s: start.elapsed().as_secs_f64(),
        })
    }

    /// Time span from the first to the last frame [s].
    pub fn span_s(&self) -> f64 {
        (self.last_ns - self.first_ns) as f64 * 1e-9
    }

    /// Frames decoded per second of wall time.
    pub fn decode_fps(&self) -> f64 {
        self.frames as f64 / self.wall_s.max(1e-9)
    }
}

impl std::fmt::Display for DecodeStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "frames:        {} of {}x{} px",
            self.frames, self.size.0, self.size.1
        )?;
        write!(
            f,
            "time stamps:   {:.6} s to {:.6} s, a span of {:.3} s",
            self.first_ns as f64 * 1e-9,
            self.last_ns as f64 * 1e-9,
            self.span_s()
        )?;
        if let Some((lo, hi)) = self.interval_s {
            write!(
                f,
                "; intervals {:.2}-{:.2} ms, {:.3} fps on average",
                lo * 1e3,
                hi * 1e3,
                (self.frames - 1) as f64 / self.span_s().max(1e-12)
            )?;
        }
        writeln!(f)?;
        if let Some(r) = self.nominal_rate_hz {
            writeln!(f, "stated rate:   {r:.3} fps")?;
        }
        writeln!(f, "mean grey:     {:.1}", self.mean_intensity)?;
        write!(
            f,
            "decoded in:    {:.3} s, {:.0} frames/s ({:.2} ms per frame)",
            self.wall_s,
            self.decode_fps(),
            self.wall_s * 1e3 / self.frames.max(1) as f64
        )
    }
}
