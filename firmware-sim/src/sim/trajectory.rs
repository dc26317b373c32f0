//! Trajectories with analytic position, velocity, acceleration, orientation and angular
//! velocity, so that simulated sensors and ground truth agree exactly.

use nalgebra::{UnitQuaternion, Vector3};

/// Ground truth of the IMU (sensor frame `s`) at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kinematics {
    /// Time [s].
    pub t: f64,
    /// Position `s_w` [m].
    pub p_w: Vector3<f64>,
    /// Velocity [m/s].
    pub v_w: Vector3<f64>,
    /// Free acceleration [m/s²].
    pub a_w: Vector3<f64>,
    /// Orientation: rotation sensor → world, `q_ws`.
    pub q_ws: UnitQuaternion<f64>,
    /// Angular velocity in the sensor frame [rad/s].
    pub omega_s: Vector3<f64>,
}

/// A trajectory with exact derivatives.
pub trait Trajectory {
    /// State at time `t` [s].
    fn at(&self, t: f64) -> Kinematics;
    /// Length [s].
    fn duration(&self) -> f64;
}

/// A sum of sines `Σ a sin(2π f t + φ)` with its first two derivatives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Sines {
    /// Terms `(amplitude, frequency [Hz], phase [rad])`.
    pub terms: Vec<(f64, f64, f64)>,
}

impl Sines {
    /// Value and first two derivatives at `t`.
    pub fn eval(&self, t: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        for &(a, f, ph) in &self.terms {
            let w = 2.0 * std::f64::consts::PI * f;
            let (s, c) = (w * t + ph).sin_cos();
            out[0] += a * s;
            out[1] += a * w * c;
            out[2] -= a * w * w * s;
        }
        out
    }
}

/// Quintic smoothstep from 0 (before `start`) to 1 (after `start + length`), C² continuous:
/// the device rests, then starts moving without a jerk spike the IMU could not follow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ramp {
    /// Start [s].
    pub start: f64,
    /// Length [s].
    pub length: f64,
}

impl Ramp {
    /// Value and first two derivatives.
    pub fn eval(&self, t: f64) -> [f64; 3] {
        if self.length <= 0.0 {
            return if t >= self.start {
                [1.0, 0.0, 0.0]
            } else {
                [0.0; 3]
            };
        }
        let x = (t - self.start) / self.length;
        if x <= 0.0 {
            return [0.0; 3];
        }
        if x >= 1.0 {
            return [1.0, 0.0, 0.0];
        }
        let l = self.length;
        let v = x * x * x * (10.0 - 15.0 * x + 6.0 * x * x);
        let d1 = 30.0 * x * x * (1.0 - x) * (1.0 - x) / l;
        let d2 = 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x) / (l * l);
        [v, d1, d2]
    }
}

/// `r(t) · f(t)` with derivatives by the product rule.
fn ramped(r: [f64; 3], f: [f64; 3]) -> [f64; 3] {
    [
        r[0] * f[0],
        r[1] * f[0] + r[0] * f[1],
        r[2] * f[0] + 2.0 * r[1] * f[1] + r[0] * f[2],
    ]
}

/// Position and z-y-x Euler angles as offsets plus ramped sums of sines.
#[derive(Clone, Debug, PartialEq)]
pub struct Harmonic {
    /// Rest position [m].
    pub centre: Vector3<f64>,
    /// Motion per axis.
    pub position: [Sines; 3],
    /// Rest yaw, pitch, roll [rad] (z-y-x: `R_ws = R_z(ψ) R_y(θ) R_x(φ)`).
    pub attitude0: [f64; 3],
    /// Motion of yaw, pitch, roll.
    pub attitude: [Sines; 3],
    /// Start of motion.
    pub ramp: Ramp,
    /// Length [s].
    pub length: f64,
}

impl Trajectory for Harmonic {
    fn at(&self, t: f64) -> Kinematics {
        let r = self.ramp.eval(t);
        let mut p = [[0.0; 3]; 3];
        for (axis, s) in self.position.iter().enumerate() {
            p[axis] = ramped(r, s.eval(t));
        }
        let mut e = [[0.0; 3]; 3];
        for (k, s) in self.attitude.iter().enumerate() {
            e[k] = ramped(r, s.eval(t));
            e[k][0] += self.attitude0[k];
        }
        let [yaw, pitch, roll] = [e[0], e[1], e[2]];
        let (sp, cp) = pitch[0].sin_cos();
        let (sr, cr) = roll[0].sin_cos();
        // Body rates of z-y-x Euler angles.
        let omega_s = Vector3::new(
            roll[1] - yaw[1] * sp,
            pitch[1] * cr + yaw[1] * cp * sr,
            -pitch[1] * sr + yaw[1] * cp * cr,
        );
        Kinematics {
            t,
            p_w: self.centre + Vector3::new(p[0][0], p[1][0], p[2][0]),
            v_w: Vector3::new(p[0][1], p[1][1], p[2][1]),
            a_w: Vector3::new(p[0][2], p[1][2], p[2][2]),
            q_ws: UnitQuaternion::from_euler_angles(roll[0], pitch[0], yaw[0]),
            omega_s,
        }
    }

    fn duration(&self) -> f64 {
        self.length
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> Harmonic {
        let s = |a: f64, f: f64, ph: f64| Sines {
            terms: vec![(a, f, ph), (a * 0.3, f * 2.7, 0.4)],
        };
        Harmonic {
            centre: Vector3::new(0.0, -1.0, 1.5),
            position: [s(0.3, 0.5, 0.0), s(0.2, 0.35, 1.0), s(0.1, 0.6, 2.0)],
            attitude0: [0.3, -0.1, 0.2],
            attitude: [s(0.5, 0.3, 0.0), s(0.2, 0.4, 0.5), s(0.25, 0.45, 1.5)],
            ramp: Ramp {
                start: 1.0,
                length: 2.0,
            },
            length: 10.0,
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        let tr = example();
        let h = 1e-5;
        for &t in &[0.5, 1.3, 2.2, 4.0, 7.7] {
            let (a, b, k) = (tr.at(t - h), tr.at(t + h), tr.at(t));
            assert!(
                ((b.p_w - a.p_w) / (2.0 * h) - k.v_w).norm() < 1e-7,
                "v at {t}"
            );
            assert!(
                ((b.v_w - a.v_w) / (2.0 * h) - k.a_w).norm() < 1e-6,
                "a at {t}"
            );
            // ω_s from q(t+h) = q(t) ⊙ exp(ω h): the body-frame rotation increment.
            let d = (a.q_ws.inverse() * b.q_ws).scaled_axis() / (2.0 * h);
            assert!(
                (d - k.omega_s).norm() < 1e-6,
                "ω at {t}: {d} vs {}",
                k.omega_s
            );
        }
    }

    #[test]
    fn rests_before_the_ramp() {
        let tr = example();
        let k = tr.at(0.5);
        assert_eq!(k.v_w, Vector3::zeros());
        assert_eq!(k.omega_s, Vector3::zeros());
    }
}
