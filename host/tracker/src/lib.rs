#![deny(missing_docs)]
//! The tracking engine as a library. The vision host's side of the paper's system: frames
//! in, the fusion core behind a [`CoreTransport`], poses out.
//!
//! - [`builder`]: a [`Tracker`] from a camera, a model and what differs from the defaults
//!   ([`TrackerBuilder`]);
//! - [`rig`], [`config`]: the sensors, and the core's configuration that follows from them;
//! - `clock`: a clock per input mode (the frames', or the IMU's samples), each owning its
//!   time base and what waits on it;
//! - [`transport`], `in_process`: the core behind a [`CoreTransport`], and the core called
//!   in-process (the links to a board are the `core-link` crate's);
//! - `session`: the exchanges with the core that wait for its answers, and the bounded
//!   window of what it said that the steps need;
//! - `worker`: the vision threads (a frame's analysis, a search, a tilt check);
//! - [`search`], `searching`, `loss`, [`tilt`], `judge`: the searches and their one
//!   machine (locating, started, lost), the loss rule that sends them, the tilt checks of
//!   tracked poses, and the verdicts;
//! - [`settings`], [`event`]: how a tracker runs and the frames it takes; what it tells,
//!   the details a report needs included;
//! - [`record`], [`log`], [`latency`]: a run's report kept from the events (the tracker
//!   keeps none of it): every frame, search and outage, what the core said, and how old each
//!   pose was when it came out;
//! - [`tracker`]: the push-driven [`Tracker`]: `push_frame`, `poll`, `latest`, `state`,
//!   `relocate`, `finish`, with its steps: without an IMU in `tracker` itself, with one in
//!   [`tracker::inertial`] (`push_imu`), its cold start and its outages (a lost link or a
//!   reset core noticed, reached again and brought up to date) in child modules.
//!
//! Errors: [`TrackerError`]. The crates a program needs beside it are re-exported:
//! [`camera`] (intrinsics, poses, their files), [`model`] (OBJ and glTF models) and
//! [`image`] (the frames' pixels).
//!
//! # Example
//!
//! A program that owns its camera (the README's example; `tests/readme.rs` checks that the
//! two agree):
//!
//! ```no_run
//! # fn my_camera() -> impl Iterator<Item = (i64, tracker::image::GrayImage)> { std::iter::empty() }
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use tracker::{Event, Frame, TrackerBuilder, camera, model};
//!
//! let camera = camera::read_camera_json("camera.json".as_ref())?;
//! let start = camera::start_pose::read_start_pose("frame0_pose.json".as_ref())?;
//! let model = model::load("cube.obj".as_ref())?;
//! let mut tracker = TrackerBuilder::new(camera, model).frame_rate_hz(30.0).start_pose(start).build()?;
//! // Grey frames of the camera's size, with their times [ns]; or .start(Start::Locate) to find the model first.
//! for (index, (t_ns, image)) in my_camera().enumerate() {
//!     tracker.push_frame(Frame::decoded(index, t_ns, image))?;
//!     for event in tracker.poll() {
//!         if let Event::Frame(f) = event {
//!             println!("frame {index}: tracked {:?}, cMo {:?}", f.tracked, f.pose);
//!         }
//!     }
//! }
//! tracker.finish().result?;
//! # Ok(())
//! # }
//! ```

pub mod builder;
mod clock;
pub mod config;
mod error;
pub mod event;
mod in_process;
mod judge;
pub mod latency;
pub mod log;
mod loss;
pub mod record;
pub mod rig;
pub mod search;
mod searching;
mod session;
pub mod settings;
pub mod tilt;
pub mod tracker;
pub mod transport;
mod worker;

pub use builder::TrackerBuilder;
pub use camera;
pub use error::TrackerError;
pub use fusion_core::Precision;
pub use image;
pub use in_process::InProcessCore;
pub use judge::Tally;
pub use model;
pub use rig::{HandEye, ImuNoiseDensities, Rig};
pub use tracker::inertial::ImuSample;
pub use tracker::{
    Answers, Event, Finished, Frame, FrameReport, ImuOnCore, Pose, Start, State, Tracker,
    TrackerConfig,
};
pub use transport::{CoreTransport, Incoming};
