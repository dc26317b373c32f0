//! The rig: the camera's mount on the IMU, and the IMU's rate and noise, from which the core's
//! configuration follows ([`crate::config`]).

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde::Deserialize;

/// Continuous-time IMU noise densities (EuRoC `sensor.yaml` units).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct ImuNoiseDensities {
    /// rad/s/√Hz.
    pub gyroscope_noise_density: f64,
    /// rad/s²/√Hz.
    pub gyroscope_random_walk: f64,
    /// m/s²/√Hz.
    pub accelerometer_noise_density: f64,
    /// m/s³/√Hz.
    pub accelerometer_random_walk: f64,
}

/// Camera mount on the IMU, in the core's convention (docs/FILTER.md §2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandEye {
    /// Rotation sensor → camera.
    pub q_cs: UnitQuaternion<f64>,
    /// Camera origin in the sensor frame [m].
    pub c_s: Vector3<f64>,
}

impl HandEye {
    /// The camera is the sensor: the vision-only model's mount.
    pub const IDENTITY: HandEye = HandEye {
        q_cs: UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(1.0, 0.0, 0.0, 0.0)),
        c_s: Vector3::new(0.0, 0.0, 0.0),
    };

    /// From EuRoC's `T_BS` of the camera (camera → body, the body being the IMU).
    pub fn from_t_bs(t: &nalgebra::Matrix4<f64>) -> Option<Self> {
        let r_sc: Matrix3<f64> = t.fixed_view::<3, 3>(0, 0).into_owned();
        // A proper rotation within round-off.
        let err = (r_sc.transpose() * r_sc - Matrix3::identity()).norm();
        if !(err < 1e-4 && (r_sc.determinant() - 1.0).abs() < 1e-4) {
            return None;
        }
        let r_cs = Rotation3::from_matrix(&r_sc.transpose());
        Some(HandEye {
            q_cs: UnitQuaternion::from_rotation_matrix(&r_cs),
            c_s: t.fixed_view::<3, 1>(0, 3).into_owned(),
        })
    }

    /// Camera pose `(c_w, q_cw)` for an IMU pose `(s_w, q_ws)` (eq. 5-6).
    pub fn camera_pose(
        &self,
        s_w: &Vector3<f64>,
        q_ws: &UnitQuaternion<f64>,
    ) -> (Vector3<f64>, UnitQuaternion<f64>) {
        (s_w + q_ws * self.c_s, self.q_cs * q_ws.inverse())
    }

    /// The IMU pose `(s_w, q_sw)` whose camera is at `pose` (eq. 5-6: `q_cw = q_cs q_sw`,
    /// `c_w = s_w + R(q_sw)ᵀ c_s`).
    pub fn sensor_pose_of_camera(
        &self,
        pose: &camera::CameraPose,
    ) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let q_sw = self.q_cs.inverse() * pose.q_cw;
        let s_w = pose.c_w - q_sw.inverse() * self.c_s;
        (s_w, q_sw)
    }

    /// The camera pose `(c_w, q_wc)` of the core's state report `s`.
    pub fn camera_of_state(
        &self,
        s: &protocol::StateReport,
    ) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let (s_w, q_ws) = state_pose(s);
        let (c_w, q_cw) = self.camera_pose(&s_w, &q_ws);
        (c_w, q_cw.inverse())
    }

    /// As the wire `HandEye`.
    pub fn to_wire(&self) -> protocol::HandEye {
        let q = self.q_cs.quaternion();
        protocol::HandEye {
            q_cs: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
            c_s: [self.c_s.x as f32, self.c_s.y as f32, self.c_s.z as f32],
        }
    }
}

/// What the core's configuration needs to know of the sensors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rig {
    /// IMU sample rate [Hz].
    pub imu_rate_hz: f64,
    /// The IMU's noise densities, where its calibration gives them.
    pub imu_noise: Option<ImuNoiseDensities>,
    /// The camera's frame rate [Hz], where known.
    pub camera_rate_hz: Option<f64>,
    /// The camera's mount on the IMU.
    pub hand_eye: HandEye,
}

/// The IMU pose `(s_w, q_ws)` of the core's state report.
pub fn state_pose(s: &protocol::StateReport) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let q = s.q_sw.map(f64::from);
    let q_sw = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    (Vector3::from(s.s_w.map(f64::from)), q_sw.inverse())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_camera_pose_maps_to_the_imu_pose_whose_camera_it_is() {
        let hand_eye = HandEye {
            q_cs: UnitQuaternion::from_euler_angles(-1.5, 0.1, 0.2),
            c_s: Vector3::new(0.03, -0.01, 0.05),
        };
        let pose = camera::CameraPose {
            q_cw: UnitQuaternion::from_euler_angles(0.4, -0.7, 2.1),
            c_w: Vector3::new(0.5, 1.0, -0.3),
        };
        let (s_w, q_sw) = hand_eye.sensor_pose_of_camera(&pose);
        let (c_w, q_cw) = hand_eye.camera_pose(&s_w, &q_sw.inverse());
        assert!((c_w - pose.c_w).norm() < 1e-12);
        assert!(q_cw.angle_to(&pose.q_cw) < 1e-12);
    }
}
