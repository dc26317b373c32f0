//! IMU model: truth plus constant initial biases, bias random walks and white noise, with
//! densities in continuous-time units (as in EuRoC's `sensor.yaml`).

use nalgebra::Vector3;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};

use super::GRAVITY_W;
use super::trajectory::Kinematics;

/// Noise of an IMU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuNoise {
    /// Gyro white noise density [rad/s/√Hz].
    pub gyro_density: f64,
    /// Accelerometer white noise density [m/s²/√Hz].
    pub accel_density: f64,
    /// Gyro bias random walk [rad/s²/√Hz].
    pub gyro_walk: f64,
    /// Accelerometer bias random walk [m/s³/√Hz].
    pub accel_walk: f64,
}

impl ImuNoise {
    /// Roughly an XSens MT9-class MEMS IMU (the paper's sensor).
    pub const MT9: ImuNoise = ImuNoise {
        gyro_density: 1.0e-3,
        accel_density: 2.0e-3,
        gyro_walk: 2.0e-5,
        accel_walk: 1.0e-4,
    };

    /// Per-sample standard deviations at `rate_hz`: `(gyro, accel)`.
    pub fn sample_sigmas(&self, rate_hz: f64) -> (f64, f64) {
        let s = rate_hz.sqrt();
        (self.gyro_density * s, self.accel_density * s)
    }
}

/// One simulated reading with the true biases behind it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuReading {
    /// Time [s].
    pub t: f64,
    /// Angular rate [rad/s].
    pub gyro: Vector3<f64>,
    /// Specific force [m/s²].
    pub accel: Vector3<f64>,
    /// True gyro bias.
    pub gyro_bias: Vector3<f64>,
    /// True accelerometer bias.
    pub accel_bias: Vector3<f64>,
}

/// A deterministic IMU simulator (same seed, same readings).
#[derive(Debug)]
pub struct ImuSim {
    noise: ImuNoise,
    rate_hz: f64,
    gyro_bias: Vector3<f64>,
    accel_bias: Vector3<f64>,
    rng: StdRng,
}

impl ImuSim {
    /// An IMU at `rate_hz` with initial biases.
    pub fn new(
        noise: ImuNoise,
        rate_hz: f64,
        gyro_bias: Vector3<f64>,
        accel_bias: Vector3<f64>,
        seed: u64,
    ) -> Self {
        ImuSim {
            noise,
            rate_hz,
            gyro_bias,
            accel_bias,
            rng: StdRng::seed_from_u64(seed),
        }
    }

    fn gauss3(&mut self) -> Vector3<f64> {
        Vector3::from_fn(|_, _| StandardNormal.sample(&mut self.rng))
    }

    /// The reading at `k.t`; the biases walk by one sample interval first.
    pub fn read(&mut self, k: &Kinematics) -> ImuReading {
        let dt = 1.0 / self.rate_hz;
        let gw = self.gauss3() * (self.noise.gyro_walk * dt.sqrt());
        let aw = self.gauss3() * (self.noise.accel_walk * dt.sqrt());
        self.gyro_bias += gw;
        self.accel_bias += aw;
        let (sg, sa) = self.noise.sample_sigmas(self.rate_hz);
        let r_sw = k.q_ws.inverse();
        let g = Vector3::from(GRAVITY_W);
        let gyro = k.omega_s + self.gyro_bias + self.gauss3() * sg;
        let accel = r_sw * (k.a_w - g) + self.accel_bias + self.gauss3() * sa;
        ImuReading {
            t: k.t,
            gyro,
            accel,
            gyro_bias: self.gyro_bias,
            accel_bias: self.accel_bias,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn level_and_still() -> Kinematics {
        Kinematics {
            t: 0.0,
            p_w: Vector3::zeros(),
            v_w: Vector3::zeros(),
            a_w: Vector3::zeros(),
            q_ws: UnitQuaternion::identity(),
            omega_s: Vector3::zeros(),
        }
    }

    #[test]
    fn a_level_still_imu_reads_plus_g_up_and_its_biases() {
        let k = level_and_still();
        let noise = ImuNoise {
            gyro_density: 0.0,
            accel_density: 0.0,
            gyro_walk: 0.0,
            accel_walk: 0.0,
        };
        let mut imu = ImuSim::new(
            noise,
            200.0,
            Vector3::new(0.01, 0.0, 0.0),
            Vector3::new(0.0, 0.1, 0.0),
            1,
        );
        let r = imu.read(&k);
        assert_eq!(r.gyro, Vector3::new(0.01, 0.0, 0.0));
        assert!((r.accel - Vector3::new(0.0, 0.1, 9.81)).norm() < 1e-12);
    }

    #[test]
    fn same_seed_same_readings() {
        let k = level_and_still();
        let mut a = ImuSim::new(ImuNoise::MT9, 100.0, Vector3::zeros(), Vector3::zeros(), 7);
        let mut b = ImuSim::new(ImuNoise::MT9, 100.0, Vector3::zeros(), Vector3::zeros(), 7);
        assert_eq!(a.read(&k), b.read(&k));
    }
}
