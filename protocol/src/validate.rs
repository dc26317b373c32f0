//! Field validation of host messages. The framing guarantees that a message arrived intact;
//! this guarantees that its numbers mean something before the filter touches them.

use crate::error::InvalidField;
use crate::limits::MAX_PARTS_PER_FRAME;
use crate::messages::{
    Config, ContourPoint, CoreToHost, Correspondence, HostToCore, Init, InitAttitude, InitSigma,
    ModelKind, SampleSource, Sym2, Sym3,
};

/// How far a quaternion's norm may be from 1 and still count as a unit quaternion. Generous
/// enough for f32 round trips of any normalised quaternion.
pub const UNIT_QUATERNION_TOLERANCE: f32 = 1e-3;

/// Largest angular rate an IMU sample may report [rad/s] (about 5700 °/s, far beyond MEMS
/// gyroscope ranges): larger is a corrupted sample.
pub const MAX_GYRO_RAD_S: f32 = 100.0;

/// Largest specific force an IMU sample may report [m/s²] (about 200 g).
pub const MAX_ACCEL_M_S2: f32 = 2000.0;

/// Largest position a host may give the core, per axis [m] (`Init`, `Resume`): 100 km, where
/// an f32 still resolves 8 mm. Far beyond, the state leaves f32's range and the core's reports
/// would carry infinities (issue 55).
pub const MAX_POSITION_M: f32 = 1e5;

/// Largest speed a `Resume` may give [m/s] (Mach 3: no hand-held camera or robot).
pub const MAX_SPEED_M_S: f32 = 1000.0;

/// Largest distance of the camera from the IMU in a `HandEye` [m].
pub const MAX_MOUNT_M: f32 = 10.0;

/// Largest `SampleSource::Core::trigger_every`: one frame per 1000 samples (a 1 Hz camera on a
/// 1 kHz IMU). More is a corrupted request.
pub const MAX_TRIGGER_EVERY: u16 = 1000;

/// Relative tolerance of the semi-definiteness checks of covariances (f32 rounding).
const PSD_TOLERANCE: f32 = 1e-5;

/// How far the covariance threshold must lie above the norm of the initial covariance: the
/// filter dead-reckons from the initial covariance until vision snaps on, and the test must
/// leave it room to do so.
pub const COVARIANCE_THRESHOLD_MARGIN: f32 = 2.0;

impl CoreToHost {
    /// Whether every number in the message is finite. The core sends nothing else: a message
    /// that is not is held back and the filter declared diverged (issue 55).
    pub fn is_finite(&self) -> bool {
        let all = |v: &[f32]| v.iter().all(|x| x.is_finite());
        match self {
            CoreToHost::PosePrediction(p) => all(&p.c_w) && all(&p.q_cw) && all(&p.cov),
            CoreToHost::State(s) => {
                [
                    &s.s_w[..],
                    &s.q_sw,
                    &s.v_w,
                    &s.a_w,
                    &s.omega_s,
                    &s.gyro_bias,
                    &s.accel_bias,
                ]
                .into_iter()
                .all(all)
                    && all(&[
                        s.health.covariance_frobenius,
                        s.health.residual_lowpass,
                        s.health.quaternion_norm_error,
                    ])
                    && all(&s.cov)
            }
            CoreToHost::UpdateReport(u) => all(&u.residuals) && u.prediction_error.is_finite(),
            CoreToHost::RawImu(s) => all(&s.gyro) && all(&s.accel),
            CoreToHost::Sampling(r) => r.drift_ppm.is_finite(),
            CoreToHost::HelloAck(_)
            | CoreToHost::Error(_)
            | CoreToHost::Status(_)
            | CoreToHost::Trigger(_) => true,
        }
    }
}

// Here with the checks rather than with the messages, which the checks use.
impl HostToCore {
    /// Checks every field against its documented range: finite numbers, unit quaternions,
    /// positive semi-definite covariances, part indices in range, parameters in range. The core
    /// calls this on every message before use and answers [`crate::ErrorCode::Invalid`] on
    /// failure.
    pub fn validate(&self) -> Result<(), InvalidField> {
        host_message(self)
    }
}

fn host_message(msg: &HostToCore) -> Result<(), InvalidField> {
    match msg {
        // A tick's only field is its time stamp, which the core checks against its clock.
        HostToCore::Hello(_) | HostToCore::Reset | HostToCore::Tick(_) | HostToCore::Query => {
            Ok(())
        }
        HostToCore::Configure(c) => config(c),
        HostToCore::Init(i) => init(i),
        HostToCore::Imu(s) => {
            if !all_finite(&s.gyro) || !all_finite(&s.accel) {
                Err(InvalidField::ImuNotFinite)
            } else if norm2(&s.gyro) > MAX_GYRO_RAD_S * MAX_GYRO_RAD_S
                || norm2(&s.accel) > MAX_ACCEL_M_S2 * MAX_ACCEL_M_S2
            {
                Err(InvalidField::ImuOutOfRange)
            } else {
                Ok(())
            }
        }
        HostToCore::Correspondences(c) => {
            part_index(c.part, c.parts)?;
            each(&c.items, correspondence)
        }
        HostToCore::Contours(c) => {
            part_index(c.part, c.parts)?;
            each(&c.items, contour)
        }
        HostToCore::Sampling(s) => match s.source {
            SampleSource::Host if s.raw_imu => Err(InvalidField::Sampling),
            SampleSource::Core { trigger_every } if trigger_every > MAX_TRIGGER_EVERY => {
                Err(InvalidField::Sampling)
            }
            _ => Ok(()),
        },
        // A state the core could have reported: bounded as its inputs are (issue 55: a rate
        // of −1e6 rad/s and a bias of 3e38 gave a quaternion of norm 2e36, reported as
        // dead reckoning).
        HostToCore::Resume(r) => {
            let bounded = [
                (r.s_w, MAX_POSITION_M),
                (r.v_w, MAX_SPEED_M_S),
                (r.a_w, MAX_ACCEL_M_S2),
                (r.omega_s, MAX_GYRO_RAD_S),
                (r.gyro_bias, MAX_GYRO_RAD_S),
                (r.accel_bias, MAX_ACCEL_M_S2),
            ];
            if bounded.iter().all(|(v, max)| within(v, *max)) && is_unit_quaternion(&r.q_sw) {
                Ok(())
            } else {
                Err(InvalidField::Resume)
            }
        }
    }
}

fn norm2(v: &[f32; 3]) -> f32 {
    v.iter().map(|x| x * x).sum()
}

fn all_finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Finite, and each component within `±max`.
fn within(v: &[f32], max: f32) -> bool {
    v.iter().all(|x| x.is_finite() && x.abs() <= max)
}

fn positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

fn non_negative(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

/// Whether `q` is a finite quaternion of norm 1 within [`UNIT_QUATERNION_TOLERANCE`].
pub fn is_unit_quaternion(q: &[f32; 4]) -> bool {
    let n2: f32 = q.iter().map(|x| x * x).sum();
    all_finite(q) && (n2 - 1.0).abs() <= 2.0 * UNIT_QUATERNION_TOLERANCE
}

/// Whether `x > 0` has a square that is a normal, finite f32 (from about 1.1e-19 to 1.8e19):
/// the filter works with variances, and a square that underflows to zero or overflows to
/// infinity in the core's f32 silently changes the model.
fn square_normal(x: f32) -> bool {
    let sq = x * x;
    positive(x) && sq.is_finite() && sq.is_normal()
}

/// Squared Frobenius norm of the initial covariance that `init_sigma` gives for `model` (the diagonal
/// blocks of the active states; the orientation block has eigenvalues `σ²/4` for tilt, tilt
/// and yaw, as fusion-core's `init::reset_covariance` builds it, taking the larger of the yaw
/// and tilt σ since either may apply; its radial part is negligible).
pub fn initial_covariance_frobenius_sq(model: ModelKind, s: &InitSigma) -> f32 {
    let sq = |x: f32| x * x;
    let axes = |active: bool| if active { 3.0 } else { 0.0 };
    let blocks = [
        (s.position, 3.0),
        (s.velocity, 3.0),
        (s.angular_velocity, 3.0),
        (s.gyro_bias, axes(model.has_imu())),
        (
            s.accel_bias,
            axes(model.has_imu() && model != ModelKind::Gyro),
        ),
        (s.acceleration, axes(model == ModelKind::Acc)),
    ];
    let diagonal: f32 = blocks.iter().map(|&(sigma, n)| n * sq(sq(sigma))).sum();
    let yaw = s.yaw.max(s.tilt);
    let orientation = 2.0 * sq(sq(s.tilt) / 4.0) + sq(sq(yaw) / 4.0);
    diagonal + orientation
}

fn config(c: &Config) -> Result<(), InvalidField> {
    let n = &c.noise;
    // Process noises may be zero (a constant bias, say); measurement noises may not, where the
    // model measures with them (the gyro model has no accelerometer, vision-only no IMU).
    let process = [n.motion, n.angular, n.gyro_bias_walk, n.accel_bias_walk];
    let process_ok = process.iter().all(|&x| x == 0.0 || square_normal(x));
    let unused = |used: bool, x: f32| !used && non_negative(x);
    let gyro_ok = unused(c.model.has_imu(), n.gyro_meas) || square_normal(n.gyro_meas);
    let accel_ok = unused(
        c.model.has_imu() && c.model != ModelKind::Gyro,
        n.accel_meas,
    ) || square_normal(n.accel_meas);
    if !process_ok || !gyro_ok || !accel_ok {
        return Err(InvalidField::NoiseParams);
    }
    let s = &c.init_sigma;
    let sigmas = [
        s.position,
        s.velocity,
        s.acceleration,
        s.tilt,
        s.yaw,
        s.angular_velocity,
        s.gyro_bias,
        s.accel_bias,
    ];
    if !sigmas.iter().all(|&x| square_normal(x)) {
        return Err(InvalidField::InitSigma);
    }
    if !is_unit_quaternion(&c.hand_eye.q_cs) || !within(&c.hand_eye.c_s, MAX_MOUNT_M) {
        return Err(InvalidField::HandEye);
    }
    if !positive(c.gate) {
        return Err(InvalidField::Gate);
    }
    let d = &c.divergence;
    let lambda_ok =
        d.residual_lowpass.is_finite() && d.residual_lowpass > 0.0 && d.residual_lowpass < 1.0;
    if !lambda_ok
        || !positive(d.residual_threshold)
        || !positive(d.covariance_frobenius)
        || !positive(d.quaternion_norm)
    {
        return Err(InvalidField::Divergence);
    }
    let margin = COVARIANCE_THRESHOLD_MARGIN * COVARIANCE_THRESHOLD_MARGIN;
    let threshold_sq = d.covariance_frobenius * d.covariance_frobenius;
    if threshold_sq < margin * initial_covariance_frobenius_sq(c.model, s) {
        return Err(InvalidField::CovarianceThreshold);
    }
    if !positive(c.imu_rate_hz) || !positive(c.camera_rate_hz) {
        return Err(InvalidField::Rate);
    }
    if c.session == 0 {
        return Err(InvalidField::Session);
    }
    if c.still_samples == 0 {
        return Err(InvalidField::StillSamples);
    }
    Ok(())
}

fn init(i: &Init) -> Result<(), InvalidField> {
    if !within(&i.position, MAX_POSITION_M) {
        return Err(InvalidField::InitPosition);
    }
    let ok = match &i.attitude {
        InitAttitude::Gravity => true,
        InitAttitude::GravityAndYaw(yaw) | InitAttitude::KeepTilt(yaw) => yaw.is_finite(),
        InitAttitude::Full(q) => is_unit_quaternion(q),
    };
    if ok {
        Ok(())
    } else {
        Err(InvalidField::InitAttitude)
    }
}

fn part_index(part: u8, parts: u8) -> Result<(), InvalidField> {
    if parts == 0 || parts as usize > MAX_PARTS_PER_FRAME || part >= parts {
        return Err(InvalidField::CorrespondencePart);
    }
    Ok(())
}

fn each<T>(items: &[T], check: fn(&T, u8) -> Result<(), InvalidField>) -> Result<(), InvalidField> {
    for (i, item) in items.iter().enumerate() {
        // Fits: items hold at most MAX_CORRESPONDENCES_PER_MESSAGE (< 256) entries.
        check(item, i as u8)?;
    }
    Ok(())
}

fn correspondence(c: &Correspondence, index: u8) -> Result<(), InvalidField> {
    if !all_finite(&c.m_n) || !all_finite(&c.m_w) || !all_finite(&c.cov_n) || !all_finite(&c.cov_w)
    {
        return Err(InvalidField::CorrespondenceNotFinite { index });
    }
    if pd2(&c.cov_n) && psd3(&c.cov_w) {
        Ok(())
    } else {
        Err(InvalidField::CorrespondenceCovariance { index })
    }
}

/// How far a contour normal's norm may be from 1.
pub const UNIT_NORMAL_TOLERANCE: f32 = 1e-3;

fn contour(c: &ContourPoint, index: u8) -> Result<(), InvalidField> {
    if !all_finite(&c.m_w) || !all_finite(&c.cov_w) || !all_finite(&c.n) || !c.d.is_finite() {
        return Err(InvalidField::CorrespondenceNotFinite { index });
    }
    // |‖n‖² − 1| ≈ 2 |‖n‖ − 1| (no square root in core).
    let n2 = c.n[0] * c.n[0] + c.n[1] * c.n[1];
    if (n2 - 1.0).abs() > 2.0 * UNIT_NORMAL_TOLERANCE {
        return Err(InvalidField::ContourNormal { index });
    }
    // A zero variance of d with an exact model point makes the innovation variance zero.
    if c.var_d > 0.0 && c.var_d.is_normal() && psd3(&c.cov_w) {
        Ok(())
    } else {
        Err(InvalidField::CorrespondenceCovariance { index })
    }
}

/// Whether a packed symmetric 2×2 matrix is positive semi-definite (within f32 rounding).
pub fn psd2(m: &Sym2) -> bool {
    let [a, b, d] = *m;
    let scale = a.abs().max(d.abs());
    let tol = PSD_TOLERANCE * scale;
    a >= -tol && d >= -tol && a * d - b * b >= -tol * scale
}

/// Whether a packed symmetric 2×2 matrix is positive definite, well enough conditioned for
/// f32 (condition number below about `1 / PSD_TOLERANCE`) and with a normal determinant. An
/// image point's covariance must be: with a zero one (and an exact model point) the
/// innovation covariance can be singular.
pub fn pd2(m: &Sym2) -> bool {
    let [a, b, d] = *m;
    let det = a * d - b * b;
    a > 0.0 && d > 0.0 && det.is_normal() && det > PSD_TOLERANCE * a.max(d) * a.max(d)
}

/// Whether a packed symmetric 3×3 matrix is positive semi-definite (within f32 rounding):
/// every principal minor is non-negative.
pub fn psd3(m: &Sym3) -> bool {
    let [a, b, c, d, e, f] = *m;
    let scale = a.abs().max(d.abs()).max(f.abs());
    let tol = PSD_TOLERANCE * scale;
    let minors_ok = a * d - b * b >= -tol * scale
        && a * f - c * c >= -tol * scale
        && d * f - e * e >= -tol * scale;
    let det = a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c);
    a >= -tol && d >= -tol && f >= -tol && minors_ok && det >= -tol * scale * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn semi_definite_checks() {
        assert!(psd2(&[1.0, 0.0, 1.0]));
        assert!(psd2(&[0.0, 0.0, 0.0]));
        assert!(psd2(&[1.0, 1.0, 1.0])); // rank 1
        assert!(!psd2(&[1.0, 2.0, 1.0]));
        assert!(!psd2(&[-1.0, 0.0, 1.0]));
        assert!(psd3(&[1.0, 0.0, 0.0, 1.0, 0.0, 1.0]));
        assert!(psd3(&[0.0; 6]));
        assert!(psd3(&[1.0, 1.0, 1.0, 1.0, 1.0, 1.0])); // rank 1
        assert!(!psd3(&[1.0, 0.0, 0.0, 1.0, 0.0, -1.0]));
        // All 2×2 minors fine, determinant negative.
        assert!(!psd3(&[1.0, 0.9, 0.9, 1.0, -0.9, 1.0]));
        // Image points need a definite covariance.
        assert!(pd2(&[1e-8, 0.0, 2e-8]));
        assert!(!pd2(&[0.0, 0.0, 0.0]));
        assert!(!pd2(&[1.0, 1.0, 1.0]));
        assert!(!pd2(&[1.0, 0.0, 1e-9])); // condition number 1e9
        assert!(!pd2(&[1e-20, 0.0, 1e-20])); // determinant not a normal f32
    }

    use crate::messages::*;
    use crate::samples;

    #[test]
    fn every_sample_message_is_valid() {
        for (name, msg) in samples::host_messages() {
            assert_eq!(msg.validate(), Ok(()), "{name}");
        }
    }

    #[test]
    fn bad_fields_are_named() {
        bad_imu_fields_are_named();
        bad_configure_fields_are_named();
        bad_resume_fields_are_named();
        bad_vision_noise_is_named();
        bad_init_fields_are_named();
        bad_correspondence_fields_are_named();
    }

    /// An `Imu` message with the given gyro reading.
    fn imu(gyro: [f32; 3]) -> HostToCore {
        HostToCore::Imu(ImuSample {
            t_us: 1,
            gyro,
            accel: [0.0; 3],
            trigger: false,
        })
    }

    /// The sample configuration, edited, validated.
    fn configure(edit: fn(&mut Config)) -> Result<(), InvalidField> {
        let mut c = samples::config();
        edit(&mut c);
        HostToCore::Configure(c).validate()
    }

    /// The sample configuration of the vision-only model, edited, validated.
    fn vision(edit: fn(&mut Config)) -> Result<(), InvalidField> {
        let mut c = samples::config();
        c.model = ModelKind::Vision;
        edit(&mut c);
        HostToCore::Configure(c).validate()
    }

    /// The sample `Resume`, edited, validated.
    fn resume(edit: fn(&mut crate::Resume)) -> Result<(), InvalidField> {
        let Some((_, HostToCore::Resume(mut r))) = samples::host_messages()
            .into_iter()
            .find(|(_, m)| matches!(m, HostToCore::Resume(_)))
        else {
            panic!("a Resume sample")
        };
        edit(&mut r);
        HostToCore::Resume(r).validate()
    }

    /// An `Init` message, validated.
    fn init_with(position: [f32; 3], attitude: InitAttitude) -> Result<(), InvalidField> {
        HostToCore::Init(Init { position, attitude }).validate()
    }

    /// Part `part` of `parts` with a good correspondence and then `c`, validated.
    fn corr(part: u8, parts: u8, c: Correspondence) -> Result<(), InvalidField> {
        let mut items = heapless::Vec::new();
        let _ = items.push(samples::correspondence([0.0; 2], [0.0; 3]));
        let _ = items.push(c);
        HostToCore::Correspondences(Correspondences {
            frame_id: 1,
            trigger_us: 1,
            part,
            parts,
            items,
        })
        .validate()
    }

    /// Non-finite IMU readings.
    fn bad_imu_fields_are_named() {
        assert_eq!(
            imu([f32::NAN, 0.0, 0.0]).validate(),
            Err(InvalidField::ImuNotFinite)
        );
        assert_eq!(
            imu([0.0, f32::INFINITY, 0.0]).validate(),
            Err(InvalidField::ImuNotFinite)
        );
    }

    /// Each of the configuration's fields out of range.
    fn bad_configure_fields_are_named() {
        assert_eq!(
            configure(|c| c.noise.motion = -1.0),
            Err(InvalidField::NoiseParams)
        );
        assert_eq!(configure(|c| c.session = 0), Err(InvalidField::Session));
        assert_eq!(
            configure(|c| c.hand_eye.c_s = [1e20, 0.0, 0.0]),
            Err(InvalidField::HandEye)
        );
        assert_eq!(
            configure(|c| c.noise.gyro_meas = 0.0),
            Err(InvalidField::NoiseParams)
        );
        assert_eq!(
            configure(|c| c.noise.accel_meas = 0.0),
            Err(InvalidField::NoiseParams)
        );
        assert_eq!(
            configure(|c| c.noise.gyro_meas = 1e-20),
            Err(InvalidField::NoiseParams)
        );
        assert_eq!(
            configure(|c| c.init_sigma.position = 1e20),
            Err(InvalidField::InitSigma)
        );
        assert_eq!(
            configure(|c| c.divergence.covariance_frobenius = 3.0),
            Err(InvalidField::CovarianceThreshold)
        );
        assert_eq!(
            configure(|c| c.init_sigma.yaw = 0.0),
            Err(InvalidField::InitSigma)
        );
        assert_eq!(
            configure(|c| c.hand_eye.q_cs = [1.0, 1.0, 0.0, 0.0]),
            Err(InvalidField::HandEye)
        );
        assert_eq!(
            configure(|c| c.hand_eye.c_s[1] = f32::NAN),
            Err(InvalidField::HandEye)
        );
        assert_eq!(configure(|c| c.gate = 0.0), Err(InvalidField::Gate));
        assert_eq!(
            configure(|c| c.divergence.residual_lowpass = 1.0),
            Err(InvalidField::Divergence)
        );
        assert_eq!(
            configure(|c| c.imu_rate_hz = f32::NAN),
            Err(InvalidField::Rate)
        );
        assert_eq!(
            configure(|c| c.still_samples = 0),
            Err(InvalidField::StillSamples)
        );
    }

    /// A resumed state that is not finite, beyond what a core reports, or not a rotation.
    fn bad_resume_fields_are_named() {
        assert_eq!(resume(|_| {}), Ok(()));
        assert_eq!(resume(|r| r.v_w[1] = f32::NAN), Err(InvalidField::Resume));
        // Issue 55, point 10: finite but far beyond what a core could have reported.
        for edit in [
            (|r: &mut crate::Resume| r.omega_s[2] = -1e6) as fn(&mut crate::Resume),
            |r| r.accel_bias[0] = 3e38,
            |r| r.gyro_bias[1] = 101.0,
            |r| r.s_w[0] = 3.4e38,
            |r| r.v_w[2] = 2000.0,
            |r| r.a_w[0] = -3000.0,
        ] {
            assert_eq!(resume(edit), Err(InvalidField::Resume));
        }
        assert_eq!(
            resume(|r| r.q_sw = [0.9, 0.0, 0.0, 0.0]),
            Err(InvalidField::Resume)
        );
    }

    /// The vision-only model measures with neither gyro nor accelerometer: zero noises are
    /// fine, bad ones not.
    fn bad_vision_noise_is_named() {
        assert_eq!(
            vision(|c| (c.noise.gyro_meas, c.noise.accel_meas) = (0.0, 0.0)),
            Ok(())
        );
        assert_eq!(
            vision(|c| c.noise.gyro_meas = f32::NAN),
            Err(InvalidField::NoiseParams)
        );
        assert_eq!(
            vision(|c| c.noise.accel_meas = -1.0),
            Err(InvalidField::NoiseParams)
        );
    }

    /// An initial position that is not finite or too far, and an attitude that is not one.
    fn bad_init_fields_are_named() {
        assert_eq!(
            init_with([f32::NAN, 0.0, 0.0], InitAttitude::Gravity),
            Err(InvalidField::InitPosition)
        );
        assert_eq!(
            init_with([0.0, 2e5, 0.0], InitAttitude::Gravity),
            Err(InvalidField::InitPosition)
        );
        assert_eq!(
            init_with([0.0; 3], InitAttitude::Full([0.0; 4])),
            Err(InvalidField::InitAttitude)
        );
        assert_eq!(
            init_with([0.0; 3], InitAttitude::GravityAndYaw(f32::INFINITY)),
            Err(InvalidField::InitAttitude)
        );
    }

    /// Part numbers out of range, and a bad correspondence named by its index.
    fn bad_correspondence_fields_are_named() {
        let ok = samples::correspondence([0.1, 0.2], [1.0, 2.0, 3.0]);
        assert_eq!(corr(0, 1, ok), Ok(()));
        assert_eq!(corr(1, 1, ok), Err(InvalidField::CorrespondencePart));
        assert_eq!(corr(0, 0, ok), Err(InvalidField::CorrespondencePart));
        assert_eq!(corr(0, 9, ok), Err(InvalidField::CorrespondencePart));
        let mut bad = ok;
        bad.m_w[2] = f32::NAN;
        assert_eq!(
            corr(0, 1, bad),
            Err(InvalidField::CorrespondenceNotFinite { index: 1 })
        );
        let mut bad = ok;
        bad.cov_n = [0.0; 3];
        assert_eq!(
            corr(0, 1, bad),
            Err(InvalidField::CorrespondenceCovariance { index: 1 })
        );
        let mut bad = ok;
        bad.cov_n = [1.0, 2.0, 1.0];
        assert_eq!(
            corr(0, 1, bad),
            Err(InvalidField::CorrespondenceCovariance { index: 1 })
        );
    }

    #[test]
    fn bad_contour_fields_are_named() {
        let contours = |part, parts, c: ContourPoint| {
            let mut items = heapless::Vec::new();
            let _ = items.push(samples::contour([0.0; 3], [1.0, 0.0], 0.0));
            let _ = items.push(c);
            HostToCore::Contours(Contours {
                frame_id: 1,
                trigger_us: 1,
                part,
                parts,
                items,
            })
            .validate()
        };
        let ok = samples::contour([1.0, 2.0, 3.0], [0.6, 0.8], 0.1);
        assert_eq!(contours(1, 2, ok), Ok(()));
        assert_eq!(contours(2, 2, ok), Err(InvalidField::CorrespondencePart));
        assert_eq!(contours(0, 9, ok), Err(InvalidField::CorrespondencePart));
        let named = |edit: fn(&mut ContourPoint)| {
            let mut c = ok;
            edit(&mut c);
            contours(0, 1, c)
        };
        let index = 1;
        assert_eq!(
            named(|c| c.d = f32::INFINITY),
            Err(InvalidField::CorrespondenceNotFinite { index })
        );
        assert_eq!(
            named(|c| c.n[1] = f32::NAN),
            Err(InvalidField::CorrespondenceNotFinite { index })
        );
        assert_eq!(
            named(|c| c.n = [0.6, 0.81]),
            Err(InvalidField::ContourNormal { index })
        );
        assert_eq!(
            named(|c| c.n = [0.0, 0.0]),
            Err(InvalidField::ContourNormal { index })
        );
        assert_eq!(named(|c| c.n = [0.6, 0.8005]), Ok(()));
        assert_eq!(
            named(|c| c.var_d = 0.0),
            Err(InvalidField::CorrespondenceCovariance { index })
        );
        assert_eq!(
            named(|c| c.var_d = -1e-6),
            Err(InvalidField::CorrespondenceCovariance { index })
        );
        assert_eq!(
            named(|c| c.var_d = f32::MIN_POSITIVE / 2.0),
            Err(InvalidField::CorrespondenceCovariance { index })
        );
        assert_eq!(
            named(|c| c.cov_w = [1.0, 2.0, 0.0, 1.0, 0.0, 1.0]),
            Err(InvalidField::CorrespondenceCovariance { index })
        );
    }

    #[test]
    fn unit_quaternions() {
        assert!(is_unit_quaternion(&[1.0, 0.0, 0.0, 0.0]));
        assert!(is_unit_quaternion(&[0.5, 0.5, 0.5, 0.5]));
        assert!(!is_unit_quaternion(&[1.0, 0.1, 0.0, 0.0]));
        assert!(!is_unit_quaternion(&[f32::NAN, 0.0, 0.0, 0.0]));
    }
}
