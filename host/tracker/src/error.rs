//! The tracker's error type.

/// Why the tracker could not start, or stopped, or refused an input.
#[derive(Debug, thiserror::Error)]
pub enum TrackerError {
    /// The model has no texture, and the tracker registers the texture.
    #[error(
        "the model has no textured material (an MTL without map_Kd, or a glTF material without a base colour texture): the tracker registers the model's texture, so an untextured model gives it nothing to follow"
    )]
    Untextured,
    /// The model has no texture, and a pose was to be found without a start pose: the cold
    /// start (and every later search) finds a model by its texture.
    #[error(
        "the model has no textured material: the cold start finds a model by its texture, so an untextured model is tracked by its contour from a start pose (give one), and cannot be searched for when lost"
    )]
    NeedsStartPose,
    /// The transport to the core could not be opened (a pty, a serial device, a TCP peer:
    /// the transport's own error).
    #[error(transparent)]
    Transport(Box<dyn std::error::Error + Send + Sync>),
    /// The core refused something, or answered what it should not.
    #[error("core: {0}")]
    Core(String),
    /// The link to the core failed: closed, a transport error, or no answer in time.
    #[error("core: {0}")]
    Link(String),
    /// A vision thread could not start, or stopped.
    #[error("{0}")]
    VisionThread(String),
    /// A frame could not be analysed, or the renderer not made.
    #[error(transparent)]
    Vision(#[from] vision::VisionError),
    /// The cold start's viewpoint database.
    #[error("cold start: {0}")]
    Database(#[from] locate::database::DatabaseError),
    /// A setting that cannot work.
    #[error("{0}")]
    Config(String),
    /// A frame whose size is not the camera's.
    #[error(
        "frame {index}: the image is {width}x{height} pixels, the camera's are {camera_width}x{camera_height}"
    )]
    ImageSize {
        /// The frame's index in its input.
        index: usize,
        /// Its width [px].
        width: u32,
        /// Its height [px].
        height: u32,
        /// The camera's width [px].
        camera_width: u32,
        /// The camera's height [px].
        camera_height: u32,
    },
    /// A frame or sample not after the one before it: the core's clock only goes forward.
    #[error(
        "{what} at {t_us} µs is not after the previous one at {previous_us} µs: the clock only goes forward"
    )]
    TimeBackwards {
        /// What was pushed ("frame 12", "IMU sample").
        what: String,
        /// Its time [µs from the first].
        t_us: i64,
        /// The previous one's [µs].
        previous_us: i64,
    },
    /// A frame pushed while another waits for its trigger (runs with an IMU: a frame is
    /// triggered by the next sample pushed, one frame per sample).
    #[error(
        "frame {index}: another frame already waits for the next IMU sample, its trigger: push one frame per sample, just before it"
    )]
    NoTrigger {
        /// The frame's index in its input.
        index: usize,
    },
    /// The correspondences' latency is longer than the core can wait for them.
    #[error(
        "a latency of {latency_s} s is longer than the core can wait for a frame's correspondences: {limit_s:.3} s at {imu_rate_hz} Hz IMU and {camera_rate_hz} Hz camera ({frames} frames, {samples} IMU samples kept)"
    )]
    LatencyTooLong {
        /// The latency asked for [s].
        latency_s: f64,
        /// The core's limit [s].
        limit_s: f64,
        /// The IMU rate [Hz].
        imu_rate_hz: f32,
        /// The camera rate [Hz].
        camera_rate_hz: f32,
        /// Frames the core keeps.
        frames: u16,
        /// IMU samples the core keeps.
        samples: u16,
    },
    /// The tracker was finished, or stopped by an earlier error: it takes nothing more.
    #[error("the tracker has stopped ({0}): make a new one")]
    Stopped(String),
}
