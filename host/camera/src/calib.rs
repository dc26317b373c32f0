//! Camera calibration files: EuRoC/ASL `sensor.yaml` and Kalibr camchain YAML.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use serde::Deserialize;

use super::{Camera, CameraError, Distortion, Pinhole};

/// Why a calibration file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// The file is not the expected YAML.
    #[error("{path}: not a valid calibration file: {source}")]
    Yaml {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: serde_yaml_ng::Error,
    },
    /// Parsed, but a value is unsupported or invalid.
    #[error("{path}: {what}")]
    Invalid {
        /// File.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The numbers do not make a valid camera.
    #[error("{path}: {source}")]
    Camera {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: CameraError,
    },
}

/// A camera with the extra facts its calibration file gives.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraCalib {
    /// Name (`cam0`, … for Kalibr; the `comment` or file name for EuRoC).
    pub name: String,
    /// Intrinsics, distortion and image size.
    pub camera: Camera,
    /// EuRoC `T_BS` (camera → body) or Kalibr `T_cam_imu` (IMU → camera), when given.
    pub extrinsics: Option<Matrix4<f64>>,
    /// Frame rate, Hz (EuRoC `rate_hz`).
    pub rate_hz: Option<f64>,
    /// Kalibr `timeshift_cam_imu`, s (t_imu = t_cam + shift).
    pub timeshift_cam_imu: Option<f64>,
}

#[derive(Deserialize)]
struct EurocMatrix {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

#[derive(Deserialize)]
#[allow(non_snake_case)]
struct EurocSensor {
    comment: Option<String>,
    T_BS: Option<EurocMatrix>,
    rate_hz: Option<f64>,
    resolution: Vec<u32>,
    camera_model: String,
    intrinsics: Vec<f64>,
    distortion_model: String,
    distortion_coefficients: Vec<f64>,
}

#[derive(Deserialize)]
#[allow(non_snake_case)]
struct KalibrCam {
    T_cam_imu: Option<Vec<Vec<f64>>>,
    camera_model: String,
    intrinsics: Vec<f64>,
    distortion_model: String,
    distortion_coeffs: Vec<f64>,
    resolution: Vec<u32>,
    timeshift_cam_imu: Option<f64>,
}

fn read(path: &Path) -> Result<String, CalibError> {
    crate::read_text_file(path).map_err(|source| CalibError::Io {
        path: path.to_owned(),
        source,
    })
}

/// EuRoC files start with OpenCV's `%YAML:1.0`, which is not a valid YAML directive.
fn without_opencv_directive(text: &str) -> String {
    text.lines()
        .filter(|l| !l.starts_with("%YAML"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// A matrix of finite numbers, or what is wrong with it.
fn finite_matrix(name: &str, data: &[f64]) -> Result<Matrix4<f64>, String> {
    if let Some(v) = data.iter().find(|v| !v.is_finite()) {
        return Err(format!("{name} holds a non-finite value ({v})"));
    }
    Ok(Matrix4::from_row_slice(data))
}

/// An optional number that must be finite, and positive when `positive`.
fn finite(name: &str, v: Option<f64>, positive: bool) -> Result<Option<f64>, String> {
    match v {
        Some(x) if !x.is_finite() || (positive && x <= 0.0) => Err(format!(
            "{name} must be a finite{} number, got {x}",
            if positive { " positive" } else { "" }
        )),
        v => Ok(v),
    }
}

/// Reads an EuRoC/ASL camera `sensor.yaml` (`pinhole` with `radial-tangential` or
/// `equidistant` distortion).
pub fn read_euroc_sensor_yaml(path: &Path) -> Result<CameraCalib, CalibError> {
    parse_euroc_sensor_yaml(&read(path)?, path)
}

/// Parses the text of an EuRoC/ASL camera `sensor.yaml` ([`read_euroc_sensor_yaml`]); `path`
/// names it in errors and in the camera's name when the file has no `comment`.
pub fn parse_euroc_sensor_yaml(text: &str, path: &Path) -> Result<CameraCalib, CalibError> {
    let text = without_opencv_directive(text);
    let s: EurocSensor = serde_yaml_ng::from_str(&text).map_err(|source| CalibError::Yaml {
        path: path.to_owned(),
        source,
    })?;
    let invalid = |what: String| CalibError::Invalid {
        path: path.to_owned(),
        what,
    };
    let extrinsics = match s.T_BS {
        None => None,
        Some(m) if m.rows == 4 && m.cols == 4 && m.data.len() == 16 => {
            Some(finite_matrix("T_BS", &m.data).map_err(invalid)?)
        }
        Some(m) => {
            return Err(invalid(format!(
                "T_BS must be 4x4 with 16 values, got {}x{} with {}",
                m.rows,
                m.cols,
                m.data.len()
            )));
        }
    };
    let camera = build_camera(
        path,
        &s.camera_model,
        &s.intrinsics,
        &s.distortion_model,
        &s.distortion_coefficients,
        &s.resolution,
    )?;
    let rate_hz = finite("rate_hz", s.rate_hz, true).map_err(invalid)?;
    let name = s.comment.unwrap_or_else(|| path.display().to_string());
    Ok(CameraCalib {
        name,
        camera,
        extrinsics,
        rate_hz,
        timeshift_cam_imu: None,
    })
}

/// Reads a Kalibr camchain YAML (`cam0`, `cam1`, …), in camera-name order.
pub fn read_kalibr_camchain(path: &Path) -> Result<Vec<CameraCalib>, CalibError> {
    parse_kalibr_camchain(&read(path)?, path)
}

/// Parses the text of a Kalibr camchain YAML ([`read_kalibr_camchain`]); `path` names it in
/// errors.
pub fn parse_kalibr_camchain(text: &str, path: &Path) -> Result<Vec<CameraCalib>, CalibError> {
    let text = without_opencv_directive(text);
    let cams: BTreeMap<String, KalibrCam> =
        serde_yaml_ng::from_str(&text).map_err(|source| CalibError::Yaml {
            path: path.to_owned(),
            source,
        })?;
    if cams.is_empty() {
        return Err(CalibError::Invalid {
            path: path.to_owned(),
            what: "no cameras in camchain".into(),
        });
    }
    cams.into_iter()
        .map(|(name, c)| {
            let invalid = |what: String| CalibError::Invalid {
                path: path.to_owned(),
                what: format!("{name}: {what}"),
            };
            let extrinsics = match c.T_cam_imu {
                None => None,
                Some(rows) if rows.len() == 4 && rows.iter().all(|r| r.len() == 4) => {
                    let flat: Vec<f64> = rows.concat();
                    Some(finite_matrix("T_cam_imu", &flat).map_err(invalid)?)
                }
                Some(_) => {
                    return Err(CalibError::Invalid {
                        path: path.to_owned(),
                        what: format!("{name}: T_cam_imu must be 4 rows of 4"),
                    });
                }
            };
            let camera = build_camera(
                path,
                &c.camera_model,
                &c.intrinsics,
                &c.distortion_model,
                &c.distortion_coeffs,
                &c.resolution,
            )?;
            let timeshift_cam_imu =
                finite("timeshift_cam_imu", c.timeshift_cam_imu, false).map_err(invalid)?;
            Ok(CameraCalib {
                name,
                camera,
                extrinsics,
                rate_hz: None,
                timeshift_cam_imu,
            })
        })
        .collect()
}

fn build_camera(
    path: &Path,
    model: &str,
    intrinsics: &[f64],
    distortion_model: &str,
    coeffs: &[f64],
    resolution: &[u32],
) -> Result<Camera, CalibError> {
    let invalid = |what: String| CalibError::Invalid {
        path: path.to_owned(),
        what,
    };
    if model != "pinhole" {
        return Err(invalid(format!(
            "camera model `{model}` is not supported (only `pinhole`)"
        )));
    }
    let &[fx, fy, cx, cy] = intrinsics else {
        return Err(invalid(format!(
            "pinhole intrinsics must be [fu, fv, cu, cv], got {} values",
            intrinsics.len()
        )));
    };
    let &[width, height] = resolution else {
        return Err(invalid(format!(
            "resolution must be [width, height], got {} values",
            resolution.len()
        )));
    };
    let distortion = match (distortion_model, coeffs) {
        ("radial-tangential" | "radtan" | "plumb_bob", &[k1, k2, p1, p2]) => Distortion::RadTan {
            k1,
            k2,
            p1,
            p2,
            k3: 0.0,
        },
        ("radial-tangential" | "radtan" | "plumb_bob", &[k1, k2, p1, p2, k3]) => {
            Distortion::RadTan { k1, k2, p1, p2, k3 }
        }
        ("equidistant" | "fisheye", &[k1, k2, k3, k4]) => {
            Distortion::Equidistant { k1, k2, k3, k4 }
        }
        ("none", []) => Distortion::None,
        (m, c) => {
            return Err(invalid(format!(
                "distortion model `{m}` with {} coefficients is not supported \
                 (radial-tangential/radtan: 4 or 5, equidistant: 4)",
                c.len()
            )));
        }
    };
    Camera::new(width, height, Pinhole::new(fx, fy, cx, cy), distortion).map_err(|source| {
        CalibError::Camera {
            path: path.to_owned(),
            source,
        }
    })
}
