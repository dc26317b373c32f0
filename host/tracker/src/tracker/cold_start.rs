//! The cold start and the recovery of an inertial run (issue 15; the method is in
//! docs/notes/issue15-cold-start.md, §6):
//!
//! - **Start.** With no start pose given ([`super::Start::Locate`]), the core is
//!   configured but not initialised. At each
//!   trigger with no attempt in flight the frame goes to the vision thread for an attempt
//!   ([`crate::locate`]); the IMU stream goes on meanwhile. The first verified pose gives the
//!   core its `Init`: position and yaw from the pose, roll and pitch from gravity
//!   (`InitAttitude::KeepTilt`, which a core not yet running takes from its still window).
//! - **Loss.** The model is lost by the one loss rule of every run ([`crate::loss`]), here
//!   with the core's mode as the frames' judgement: after a divergence, or when the core has
//!   not been tracking for half a second. While lost, attempts follow at intervals; a
//!   verified pose re-anchors the running filter at once (`KeepTilt`: position and yaw from
//!   the pose, roll and pitch kept from the filter, which gravity levelled).
//!
//! Attempts run on a search thread of their own (with its own renderer), one at a time, so
//! they never hold up the frames. An attempt answers like a frame: after the latency in
//! lock-step (waiting for the search thread if needed, so that a replay is deterministic), as
//! soon as it is ready in real time; the summary reports how many frame periods one takes.
//! The pose it found is for its frame's time; by the time it is applied the device has turned
//! on, so its orientation is carried forward by the core's own rotation since that frame (the
//! gyro's, good to a fraction of a degree over a few frames). Its position is applied as found:
//! the dead-reckoned displacement of a lost filter is what cannot be trusted.

use nalgebra::UnitQuaternion;
use protocol::{HostToCore, Init, InitAttitude};

use camera::CameraPose;

use super::Tracker;
use crate::error::TrackerError;
use crate::search::Search;
use crate::searching::Job;
use crate::transport::CoreTransport;

impl<T: CoreTransport> Tracker<T> {
    /// Applies the attempt with the search thread if it is due: in lock-step
    /// (`lock_step_k`, the IMU sample now) once its due sample is reached, waiting for it; in
    /// real time as soon as it is ready.
    pub(crate) fn poll_search(
        &mut self,
        lock_step_k: Option<usize>,
        now_us: u64,
    ) -> Result<(), TrackerError> {
        let Some(job) = self.searching.job() else {
            return Ok(());
        };
        let Some(search) = &self.search else {
            return Ok(());
        };
        let (attempt, from) = match lock_step_k {
            Some(k) if job.due <= k => search.locate_result()?,
            Some(_) => return Ok(()),
            None => match search.try_locate()? {
                Some(a) => a,
                None => return Ok(()),
            },
        };
        if let Some(from) = from {
            self.tell(crate::event::Detail::Database(from));
        }
        self.searching.answered();
        self.found(job, attempt, now_us)
    }

    /// Applies an attempt's answer: records it, and gives the core a verified pose.
    fn found(
        &mut self,
        job: Job,
        attempt: locate::Attempt,
        now_us: u64,
    ) -> Result<(), TrackerError> {
        let search = Search::new(job.index, job.t_us, attempt).applied(now_us);
        let Some(pose) = self.searched(job.lost_at, search, None) else {
            return Ok(());
        };
        let init = self.keep_tilt_init(&pose, job.t_us, now_us);
        self.core.send(&HostToCore::Init(init))?;
        // The new start gets the same grace as a loss before it counts as lost.
        self.searching.found(Some(now_us));
        Ok(())
    }

    /// The `Init` for a camera pose found in the frame at `frame_us`, applied at `now_us`:
    /// the IMU's position as found, its yaw carried forward by the core's rotation since the
    /// frame (when the core was running then).
    fn keep_tilt_init(&self, pose: &CameraPose, frame_us: u64, now_us: u64) -> Init {
        let (s_w, q_sw) = self.config.rig.hand_eye.sensor_pose_of_camera(pose);
        let q_ws_found = q_sw.inverse();
        let s = &self.session;
        let q_ws = match (s.state_at(frame_us), s.state_at(now_us)) {
            (Some(then), Some(now)) if then.t_us < now.t_us => {
                let (_, q_then) = crate::rig::state_pose(then);
                let (_, q_now) = crate::rig::state_pose(now);
                // The body's rotation from the frame to now, in the body frame.
                let turn: UnitQuaternion<f64> = q_then.inverse() * q_now;
                q_ws_found * turn
            }
            _ => q_ws_found,
        };
        Init {
            position: [s_w.x as f32, s_w.y as f32, s_w.z as f32],
            attitude: InitAttitude::KeepTilt(q_ws.euler_angles().2 as f32),
        }
    }
}
