//! The camera pose as docs/FILTER.md §2 defines it: `q_cw` and the camera centre `c_w`.

use nalgebra::{Matrix3, Matrix4, Quaternion, Rotation3, UnitQuaternion, Vector3};

use super::CameraError;

/// Camera pose: `q_cw` rotates world vectors into the camera frame, `c_w` is the camera
/// centre in the world, so `p_c = R(q_cw) (p_w − c_w)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// World → camera rotation.
    pub q_cw: UnitQuaternion<f64>,
    /// Camera centre in the world frame, metres.
    pub c_w: Vector3<f64>,
}

impl CameraPose {
    /// From a Hamilton quaternion stored `[w, x, y, z]` (normalised here) and `c_w`.
    pub fn from_wxyz(q_cw: [f64; 4], c_w: Vector3<f64>) -> Result<Self, CameraError> {
        let q = Quaternion::new(q_cw[0], q_cw[1], q_cw[2], q_cw[3]);
        let norm = q.norm();
        if !norm.is_finite() || norm < 1e-9 || !c_w.iter().all(|v| v.is_finite()) {
            return Err(CameraError::DegeneratePose(
                "zero or non-finite quaternion/centre",
            ));
        }
        Ok(Self {
            q_cw: UnitQuaternion::from_quaternion(q),
            c_w,
        })
    }

    /// From the extrinsics `x_c = R(q_cw) x_w + t`: the camera centre is `−Rᵀ t`.
    pub fn from_extrinsics(q_cw: UnitQuaternion<f64>, t: &Vector3<f64>) -> Self {
        Self {
            q_cw,
            c_w: -(q_cw.inverse() * t),
        }
    }

    /// The extrinsics' translation `t = −R(q_cw) c_w`.
    pub fn translation(&self) -> Vector3<f64> {
        -(self.q_cw * self.c_w)
    }

    /// A camera at `eye` looking at `target`, with image "up" (−y_c) as close to `up_w` as
    /// possible.
    pub fn look_at(
        eye: Vector3<f64>,
        target: Vector3<f64>,
        up_w: Vector3<f64>,
    ) -> Result<Self, CameraError> {
        let z = (target - eye)
            .try_normalize(1e-12)
            .ok_or(CameraError::DegeneratePose("eye equals target"))?;
        // x right = forward × up; y down = forward × right (right-handed, OpenCV axes).
        let x = z
            .cross(&up_w)
            .try_normalize(1e-9)
            .ok_or(CameraError::DegeneratePose(
                "viewing direction parallel to up",
            ))?;
        let y = z.cross(&x);
        let r_wc = Matrix3::from_columns(&[x, y, z]);
        let r_cw = Rotation3::from_matrix_unchecked(r_wc.transpose());
        Ok(Self {
            q_cw: UnitQuaternion::from_rotation_matrix(&r_cw),
            c_w: eye,
        })
    }

    /// World point → camera frame.
    pub fn world_to_camera(&self, p_w: &Vector3<f64>) -> Vector3<f64> {
        self.q_cw * (p_w - self.c_w)
    }

    /// Camera point → world frame.
    pub fn camera_to_world(&self, p_c: &Vector3<f64>) -> Vector3<f64> {
        self.q_cw.inverse() * p_c + self.c_w
    }

    /// The 4×4 world → camera transform `[R, −R c; 0 1]`.
    pub fn view_matrix(&self) -> Matrix4<f64> {
        let r = self.q_cw.to_rotation_matrix().into_inner();
        let t = -(r * self.c_w);
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
        m
    }
}
