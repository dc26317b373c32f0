//! Composite trajectories with exact derivatives: a pivot moving along sums of smooth signals,
//! an orientation from z-y-x Euler angles (optionally aimed at a target) and an optional lever
//! arm from the pivot to the IMU (off-centre rotations of a hand-held device).
//!
//! Every quantity is carried as a *jet* `[value, d/dt, d²/dt²]`, so position, velocity,
//! acceleration, orientation, angular velocity and angular acceleration come out of one pass
//! with the chain and product rules, without finite differences.

use nalgebra::{UnitQuaternion, Vector3};

use crate::sim::trajectory::{Kinematics, Ramp, Sines, Trajectory};

/// `[value, first derivative, second derivative]` of a scalar function of time.
pub type Jet = [f64; 3];

fn add(a: Jet, b: Jet) -> Jet {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: Jet, b: Jet) -> Jet {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn mul(a: Jet, b: Jet) -> Jet {
    [
        a[0] * b[0],
        a[1] * b[0] + a[0] * b[1],
        a[2] * b[0] + 2.0 * a[1] * b[1] + a[0] * b[2],
    ]
}

fn sin(a: Jet) -> Jet {
    let (s, c) = a[0].sin_cos();
    [s, c * a[1], -s * a[1] * a[1] + c * a[2]]
}

fn cos(a: Jet) -> Jet {
    let (s, c) = a[0].sin_cos();
    [c, -s * a[1], -c * a[1] * a[1] - s * a[2]]
}

fn sqrt(a: Jet) -> Jet {
    let s = a[0].sqrt();
    [
        s,
        a[1] / (2.0 * s),
        a[2] / (2.0 * s) - a[1] * a[1] / (4.0 * s * s * s),
    ]
}

/// `atan2(y, x)` with derivatives (`x, y` not both zero).
fn atan2(y: Jet, x: Jet) -> Jet {
    let r2 = x[0] * x[0] + y[0] * y[0];
    let num = x[0] * y[1] - y[0] * x[1];
    let num_d = x[0] * y[2] - y[0] * x[2];
    let r2_d = 2.0 * (x[0] * x[1] + y[0] * y[1]);
    [
        y[0].atan2(x[0]),
        num / r2,
        (num_d * r2 - num * r2_d) / (r2 * r2),
    ]
}

/// The derivative as a jet; its second derivative is unknown (0), so only `[0]` and `[1]` of
/// results built from it are valid.
fn deriv(a: Jet) -> Jet {
    [a[1], a[2], 0.0]
}

/// A scalar signal of time with two exact derivatives.
#[derive(Clone, Debug, PartialEq)]
pub enum Signal {
    /// `Σ a sin(2π f t + φ)` faded in by `on` and out by `off`: `sines · on · (1 − off)`.
    Sines {
        /// The sines.
        sines: Sines,
        /// Fade-in (quintic, C²).
        on: Ramp,
        /// Fade-out.
        off: Ramp,
    },
    /// A quintic smooth step of height `delta` (a move, a turn).
    Step {
        /// When and how long.
        ramp: Ramp,
        /// Height.
        delta: f64,
    },
}

impl Signal {
    /// Sines active in `[start, end]` with fades of `fade` seconds at both ends.
    pub fn burst(terms: &[(f64, f64, f64)], start: f64, end: f64, fade: f64) -> Self {
        Signal::Sines {
            sines: Sines {
                terms: terms.to_vec(),
            },
            on: Ramp {
                start,
                length: fade,
            },
            off: Ramp {
                start: end - fade,
                length: fade,
            },
        }
    }

    /// A smooth step of `delta` from `start` to `start + length`.
    pub fn step(start: f64, length: f64, delta: f64) -> Self {
        Signal::Step {
            ramp: Ramp { start, length },
            delta,
        }
    }

    /// Value and two derivatives at `t`.
    pub fn eval(&self, t: f64) -> Jet {
        match self {
            Signal::Sines { sines, on, off } => {
                let off = off.eval(t);
                let keep = [1.0 - off[0], -off[1], -off[2]];
                mul(mul(on.eval(t), keep), sines.eval(t))
            }
            Signal::Step { ramp, delta } => ramp.eval(t).map(|v| v * delta),
        }
    }
}

/// Sum of signals at `t`.
pub fn sum(signals: &[Signal], t: f64) -> Jet {
    signals.iter().fold([0.0; 3], |acc, s| add(acc, s.eval(t)))
}

/// A trajectory: pivot `centre + Σ position signals`; orientation from z-y-x Euler angles
/// (`R_ws = R_z(ψ) R_y(θ) R_x(φ)`, body x forward when all are zero); the IMU sits at
/// `lever_arm` (body frame) from the pivot.
#[derive(Clone, Debug, PartialEq)]
pub struct Path {
    /// Rest position of the pivot [m].
    pub centre: Vector3<f64>,
    /// Pivot motion per world axis [m].
    pub position: [Vec<Signal>; 3],
    /// When set, yaw and pitch aim the body x axis from the pivot at this point; the attitude
    /// signals are then offsets to that aim.
    pub look_at: Option<Vector3<f64>>,
    /// Rest yaw, pitch, roll [rad].
    pub attitude0: [f64; 3],
    /// Yaw, pitch, roll motion [rad].
    pub attitude: [Vec<Signal>; 3],
    /// IMU origin relative to the pivot, in the body frame [m] (zero: the IMU is the pivot).
    pub lever_arm: Vector3<f64>,
    /// Length [s].
    pub length: f64,
}

/// Everything [`Path::eval`] computes at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathState {
    /// The IMU's kinematics.
    pub kinematics: Kinematics,
    /// Body angular acceleration [rad/s²].
    pub omega_dot_s: Vector3<f64>,
    /// Free acceleration of the pivot alone [m/s²] (what the person's body does).
    pub pivot_accel: Vector3<f64>,
}

impl Path {
    /// Pivot position jets per axis.
    fn pivot(&self, t: f64) -> [Jet; 3] {
        std::array::from_fn(|i| {
            let mut j = sum(&self.position[i], t);
            j[0] += self.centre[i];
            j
        })
    }

    /// Full state at `t`.
    pub fn eval(&self, t: f64) -> PathState {
        let p = self.pivot(t);
        let mut e: [Jet; 3] = std::array::from_fn(|k| {
            let mut j = sum(&self.attitude[k], t);
            j[0] += self.attitude0[k];
            j
        });
        if let Some(target) = self.look_at {
            let d: [Jet; 3] = std::array::from_fn(|i| {
                let mut j = p[i].map(|v| -v);
                j[0] += target[i];
                j
            });
            let rho = sqrt(add(mul(d[0], d[0]), mul(d[1], d[1])));
            e[0] = add(e[0], atan2(d[1], d[0]));
            e[1] = add(e[1], atan2(d[2].map(|v| -v), rho));
        }
        let [yaw, pitch, roll] = e;
        let (sp, cp) = (sin(pitch), cos(pitch));
        let (sr, cr) = (sin(roll), cos(roll));
        let (dy, dp, dr) = (deriv(yaw), deriv(pitch), deriv(roll));
        // Body rates of z-y-x Euler angles; as jets, [1] is the angular acceleration.
        let wx = sub(dr, mul(dy, sp));
        let wy = add(mul(dp, cr), mul(mul(dy, cp), sr));
        let wz = sub(mul(mul(dy, cp), cr), mul(dp, sr));
        let omega_s = Vector3::new(wx[0], wy[0], wz[0]);
        let omega_dot_s = Vector3::new(wx[1], wy[1], wz[1]);
        let q_ws = UnitQuaternion::from_euler_angles(roll[0], pitch[0], yaw[0]);
        let r = self.lever_arm;
        let pivot_p = Vector3::new(p[0][0], p[1][0], p[2][0]);
        let pivot_v = Vector3::new(p[0][1], p[1][1], p[2][1]);
        let pivot_a = Vector3::new(p[0][2], p[1][2], p[2][2]);
        // Rigid-body point at r: v = R(ω×r), a = R(ω̇×r + ω×(ω×r)).
        let kinematics = Kinematics {
            t,
            p_w: pivot_p + q_ws * r,
            v_w: pivot_v + q_ws * omega_s.cross(&r),
            a_w: pivot_a + q_ws * (omega_dot_s.cross(&r) + omega_s.cross(&omega_s.cross(&r))),
            q_ws,
            omega_s,
        };
        PathState {
            kinematics,
            omega_dot_s,
            pivot_accel: pivot_a,
        }
    }
}

impl Trajectory for Path {
    fn at(&self, t: f64) -> Kinematics {
        self.eval(t).kinematics
    }

    fn duration(&self) -> f64 {
        self.length
    }
}

/// Peak values of a trajectory, sampled every `dt` seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peaks {
    /// Largest free acceleration norm [m/s²].
    pub accel: f64,
    /// Largest angular rate norm [rad/s].
    pub rate: f64,
    /// Largest free acceleration of the pivot alone [m/s²].
    pub pivot_accel: f64,
    /// Largest speed [m/s].
    pub speed: f64,
}

impl Path {
    /// Peaks over the whole path, sampled every `dt` seconds.
    pub fn peaks(&self, dt: f64) -> Peaks {
        let n = (self.length / dt).ceil() as usize;
        let mut out = Peaks {
            accel: 0.0,
            rate: 0.0,
            pivot_accel: 0.0,
            speed: 0.0,
        };
        for i in 0..=n {
            let s = self.eval((i as f64 * dt).min(self.length));
            let k = s.kinematics;
            out.accel = out.accel.max(k.a_w.norm());
            out.rate = out.rate.max(k.omega_s.norm());
            out.pivot_accel = out.pivot_accel.max(s.pivot_accel.norm());
            out.speed = out.speed.max(k.v_w.norm());
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example(look_at: bool, lever: bool) -> Path {
        let on = |a: f64, f: f64, ph: f64| vec![Signal::burst(&[(a, f, ph)], 0.5, 4.5, 0.8)];
        Path {
            centre: Vector3::new(-0.5, 0.1, 0.3),
            position: [
                vec![
                    Signal::step(1.0, 1.5, 0.4),
                    Signal::burst(&[(0.1, 0.7, 0.2)], 0.3, 5.0, 1.0),
                ],
                on(0.12, 0.9, 1.0),
                on(0.05, 1.3, -0.4),
            ],
            look_at: look_at.then(|| Vector3::new(0.2, -0.1, 0.1)),
            attitude0: [0.3, -0.2, 0.1],
            attitude: [
                vec![Signal::step(2.0, 1.0, 1.2)],
                on(0.3, 0.8, 0.0),
                on(0.2, 1.1, 0.7),
            ],
            lever_arm: if lever {
                Vector3::new(0.35, -0.05, 0.1)
            } else {
                Vector3::zeros()
            },
            length: 5.0,
        }
    }

    /// Velocity, acceleration, angular velocity and angular acceleration against central
    /// differences of the quantity one order lower.
    #[test]
    fn derivatives_match_central_differences() {
        for (look, lever) in [(false, false), (true, false), (false, true), (true, true)] {
            let tr = example(look, lever);
            let h = 1e-5;
            for &t in &[0.7, 1.2, 1.9, 2.4, 2.95, 3.6, 4.2] {
                let (a, b, s) = (tr.eval(t - h), tr.eval(t + h), tr.eval(t));
                let (ka, kb, k) = (a.kinematics, b.kinematics, s.kinematics);
                let tag = format!("t {t} look {look} lever {lever}");
                let dv = (kb.p_w - ka.p_w) / (2.0 * h) - k.v_w;
                assert!(dv.norm() < 1e-7, "v {tag}: {dv}");
                let da = (kb.v_w - ka.v_w) / (2.0 * h) - k.a_w;
                assert!(da.norm() < 1e-6, "a {tag}: {da}");
                let w = (ka.q_ws.inverse() * kb.q_ws).scaled_axis() / (2.0 * h);
                assert!((w - k.omega_s).norm() < 1e-7, "ω {tag}");
                let dw = (kb.omega_s - ka.omega_s) / (2.0 * h) - s.omega_dot_s;
                assert!(dw.norm() < 1e-5, "ω̇ {tag}: {dw}");
            }
        }
    }

    #[test]
    fn look_at_points_the_body_x_axis_at_the_target() {
        let mut tr = example(true, false);
        tr.attitude = Default::default();
        tr.attitude0 = [0.0; 3];
        for &t in &[0.0, 1.7, 3.3] {
            let k = tr.at(t);
            let x = k.q_ws * Vector3::x();
            let to = (Vector3::new(0.2, -0.1, 0.1) - k.p_w).normalize();
            assert!((x - to).norm() < 1e-12, "t {t}");
        }
    }

    #[test]
    fn steps_and_bursts_are_at_rest_outside_their_windows() {
        let s = Signal::burst(&[(1.0, 2.0, 0.3)], 1.0, 3.0, 0.5);
        assert_eq!(s.eval(0.9), [0.0; 3]);
        assert_eq!(s.eval(3.1), [0.0; 3]);
        let st = Signal::step(1.0, 2.0, 5.0);
        assert_eq!(st.eval(0.5), [0.0; 3]);
        assert_eq!(st.eval(3.5), [5.0, 0.0, 0.0]);
        assert!((st.eval(2.0)[0] - 2.5).abs() < 1e-12);
    }
}
