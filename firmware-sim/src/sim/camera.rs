//! Simulated 2D/3D correspondences: model points seen by a pinhole camera rigidly mounted on
//! the IMU, with pixel noise.

use nalgebra::{UnitQuaternion, Vector2, Vector3};
use protocol::Correspondence;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use super::trajectory::Kinematics;

/// Pinhole intrinsics (no skew, no distortion: correspondences are in normalised
/// coordinates, after undistortion).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pinhole {
    /// Focal lengths [px].
    pub fx: f64,
    /// Focal lengths [px].
    pub fy: f64,
    /// Principal point [px].
    pub cx: f64,
    /// Principal point [px].
    pub cy: f64,
    /// Image size [px].
    pub width: u32,
    /// Image size [px].
    pub height: u32,
}

impl Pinhole {
    /// The paper's 320×240 camera with a 60° horizontal field of view.
    pub const PAPER: Pinhole = Pinhole {
        fx: 277.0,
        fy: 277.0,
        cx: 159.5,
        cy: 119.5,
        width: 320,
        height: 240,
    };

    /// Pixel of a normalised point, if inside the image.
    pub fn pixel(&self, m_n: &Vector2<f64>) -> Option<Vector2<f64>> {
        let u = self.fx * m_n[0] + self.cx;
        let v = self.fy * m_n[1] + self.cy;
        let inside =
            u >= 0.0 && v >= 0.0 && u <= self.width as f64 - 1.0 && v <= self.height as f64 - 1.0;
        inside.then(|| Vector2::new(u, v))
    }
}

/// Rigid mount of the camera on the IMU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mount {
    /// Rotation sensor → camera, `q_cs`.
    pub q_cs: UnitQuaternion<f64>,
    /// Camera origin in the sensor frame [m].
    pub c_s: Vector3<f64>,
}

impl Mount {
    /// Camera pose in the world: `(c_w, q_cw)`.
    pub fn camera_pose(&self, k: &Kinematics) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let c_w = k.p_w + k.q_ws * self.c_s;
        let q_cw = self.q_cs * k.q_ws.inverse();
        (c_w, q_cw)
    }

    /// As the wire `HandEye`.
    pub fn to_wire(&self) -> protocol::HandEye {
        let q = self.q_cs.quaternion();
        protocol::HandEye {
            q_cs: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
            c_s: [self.c_s[0] as f32, self.c_s[1] as f32, self.c_s[2] as f32],
        }
    }
}

/// The correspondences of the model points visible at `k`, with pixel noise `pixel_sigma`,
/// at most `max` of them (spread: every visible point up to `max`, in the order given).
pub fn observe(
    points: &[Vector3<f64>],
    k: &Kinematics,
    mount: &Mount,
    cam: &Pinhole,
    pixel_sigma: f64,
    max: usize,
    rng: &mut impl Rng,
) -> Vec<Correspondence> {
    let (c_w, q_cw) = mount.camera_pose(k);
    let sigma_n = pixel_sigma / cam.fx;
    let mut out = Vec::new();
    for m_w in points {
        if out.len() >= max {
            break;
        }
        let p = q_cw * (m_w - c_w);
        if p[2] < 0.05 {
            continue;
        }
        let m_n = Vector2::new(p[0] / p[2], p[1] / p[2]);
        if cam.pixel(&m_n).is_none() {
            continue;
        }
        let nx: f64 = StandardNormal.sample(rng);
        let ny: f64 = StandardNormal.sample(rng);
        let noisy = m_n + Vector2::new(nx, ny) * sigma_n;
        let var_n = (sigma_n * sigma_n) as f32;
        out.push(Correspondence {
            m_n: [noisy[0] as f32, noisy[1] as f32],
            cov_n: [var_n, 0.0, var_n],
            m_w: [m_w[0] as f32, m_w[1] as f32, m_w[2] as f32],
            cov_w: [1e-8, 0.0, 0.0, 1e-8, 0.0, 1e-8],
        });
    }
    out
}

/// Points on a grid over a rectangle in the plane `x = x0` (a wall facing −x), with a
/// deterministic jitter so that the grid does not alias.
pub fn wall_points(
    x0: f64,
    y: (f64, f64),
    z: (f64, f64),
    count: (usize, usize),
) -> Vec<Vector3<f64>> {
    let mut pts = Vec::new();
    for i in 0..count.0 {
        for j in 0..count.1 {
            let fy = (i as f64 + 0.5 + 0.3 * ((i * 7 + j * 3) as f64).sin()) / count.0 as f64;
            let fz = (j as f64 + 0.5 + 0.3 * ((i * 5 + j * 11) as f64).cos()) / count.1 as f64;
            pts.push(Vector3::new(
                x0,
                y.0 + fy * (y.1 - y.0),
                z.0 + fz * (z.1 - z.0),
            ));
        }
    }
    pts
}
