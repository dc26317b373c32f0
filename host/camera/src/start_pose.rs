//! A start pose file (`--start-pose FILE` of the CLI): a full 6-DoF start, the camera's pose
//! in the model's frame (which is the world frame of tracking).
//!
//! Two formats:
//! - JSON with a 4×4 camera-from-model transform `cMo` (metres, `X_c = R X_o + t`), as
//!   `../shared/data/visp-cube/frame0_pose.json`: `{"cMo": [[r, r, r, t], …, [0, 0, 0, 1]]}`,
//!   other fields ignored;
//! - one TUM line `t tx ty tz qx qy qz qw` as `track` writes them (`trajectory.tum`,
//!   `groundtruth.tum`): the camera centre in the world and the camera-to-world quaternion,
//!   so a line of an earlier run's file can be used as it is. `#` lines are comments.
//!
//! Both are checked: every number finite; `cMo`'s rotation orthonormal with determinant +1 and
//! its last row `0 0 0 1`, within [`RIGID_TOLERANCE`]; a TUM quaternion of unit norm within
//! [`QUATERNION_TOLERANCE`] (TUM files carry a few digits only).

use std::path::Path;

use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};

use crate::CameraPose;

/// Largest deviation accepted of `RᵀR` from the identity (max entry), of `det R` from 1 and of
/// the last row from `0 0 0 1`: a rigid transform written with 6 or more digits passes.
pub const RIGID_TOLERANCE: f64 = 1e-4;

/// Largest deviation of a TUM quaternion's norm from 1.
pub const QUATERNION_TOLERANCE: f64 = 1e-3;

/// Why a start pose file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum StartPoseError {
    /// The file could not be read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// Neither JSON with `cMo` nor a TUM line.
    #[error("{0}")]
    Format(String),
    /// The transform is not rigid.
    #[error("cMo is not a rigid transform: {0}")]
    NotRigid(String),
}

/// Checks that `m` is a rigid transform (see the module's text).
pub fn check_rigid(m: &Matrix4<f64>) -> Result<(), StartPoseError> {
    let bad = |what: String| Err(StartPoseError::NotRigid(what));
    if !m.iter().all(|v| v.is_finite()) {
        return bad("a value is not finite".into());
    }
    let last = m.row(3);
    let expected = [0.0, 0.0, 0.0, 1.0];
    let off = last
        .iter()
        .zip(expected)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    if off > RIGID_TOLERANCE {
        return bad(format!(
            "the last row is [{}, {}, {}, {}], not [0, 0, 0, 1]",
            last[0], last[1], last[2], last[3]
        ));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let ortho = (r.transpose() * r - Matrix3::identity()).abs().max();
    if ortho > RIGID_TOLERANCE {
        return bad(format!(
            "the rotation is not orthonormal (RᵀR differs from the identity by {ortho:.2e}, more than {RIGID_TOLERANCE:.0e}; scaled or sheared?)"
        ));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > RIGID_TOLERANCE {
        return bad(format!(
            "the rotation's determinant is {det:.6}, not +1 (a reflection)"
        ));
    }
    Ok(())
}

/// The camera pose of a rigid `cMo` (the model frame being the world frame).
pub fn pose_of_cmo(m: &Matrix4<f64>) -> Result<CameraPose, StartPoseError> {
    check_rigid(m)?;
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    let t: Vector3<f64> = m.fixed_view::<3, 1>(0, 3).into_owned();
    // Orthonormalised: the tolerance admits round-off a quaternion should not carry.
    let rot = Rotation3::from_matrix(&r);
    let q_cw = UnitQuaternion::from_rotation_matrix(&rot);
    Ok(CameraPose {
        q_cw,
        c_w: -(rot.inverse() * t),
    })
}

fn parse_json(text: &str) -> Result<CameraPose, StartPoseError> {
    let v: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| StartPoseError::Format(format!("not valid JSON: {e}")))?;
    let rows = v
        .get("cMo")
        .ok_or_else(|| StartPoseError::Format("JSON without a `cMo` field".into()))?;
    let shape = || StartPoseError::Format("`cMo` must be 4 rows of 4 numbers".into());
    let rows = rows.as_array().filter(|r| r.len() == 4).ok_or_else(shape)?;
    let mut m = Matrix4::zeros();
    for (i, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|r| r.len() == 4).ok_or_else(shape)?;
        for (j, x) in row.iter().enumerate() {
            m[(i, j)] = x.as_f64().ok_or_else(shape)?;
        }
    }
    pose_of_cmo(&m)
}

fn parse_tum(text: &str) -> Result<CameraPose, StartPoseError> {
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let [line] = lines[..] else {
        return Err(StartPoseError::Format(format!(
            "a TUM start pose is one line `t tx ty tz qx qy qz qw`; the file holds {} lines of data",
            lines.len()
        )));
    };
    let v: Vec<f64> = line
        .split_whitespace()
        .map(|w| {
            w.parse::<f64>()
                .map_err(|e| StartPoseError::Format(format!("TUM line: `{w}`: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let [_, tx, ty, tz, qx, qy, qz, qw] = v[..] else {
        return Err(StartPoseError::Format(format!(
            "a TUM line has 8 numbers `t tx ty tz qx qy qz qw`, this one {}",
            v.len()
        )));
    };
    if !v.iter().all(|x| x.is_finite()) {
        return Err(StartPoseError::NotRigid(
            "a value of the TUM line is not finite".into(),
        ));
    }
    let q = nalgebra::Quaternion::new(qw, qx, qy, qz);
    if (q.norm() - 1.0).abs() > QUATERNION_TOLERANCE {
        return Err(StartPoseError::NotRigid(format!(
            "the TUM line's quaternion has norm {:.6}, not 1",
            q.norm()
        )));
    }
    let q_wc = UnitQuaternion::from_quaternion(q);
    Ok(CameraPose {
        q_cw: q_wc.inverse(),
        c_w: Vector3::new(tx, ty, tz),
    })
}

/// Reads a start pose file: JSON when it starts with `{`, else a TUM line.
pub fn read_start_pose(path: &Path) -> Result<CameraPose, StartPoseError> {
    parse_start_pose(&crate::read_text_file(path)?)
}

/// Parses the text of a start pose file ([`read_start_pose`]).
pub fn parse_start_pose(text: &str) -> Result<CameraPose, StartPoseError> {
    if text.trim_start().starts_with('{') {
        parse_json(text)
    } else {
        parse_tum(text)
    }
}

/// The cMo of a camera pose, as [`read_start_pose`] reads it back.
pub fn cmo_of_pose(pose: &CameraPose) -> Matrix4<f64> {
    let r = pose.q_cw.to_rotation_matrix();
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&(-(r * pose.c_w)));
    m
}

/// The JSON of a start pose file holding `cMo` for `pose`.
pub fn start_pose_json(pose: &CameraPose) -> String {
    let m = cmo_of_pose(pose);
    let rows: Vec<Vec<f64>> = (0..4)
        .map(|i| (0..4).map(|j| m[(i, j)]).collect())
        .collect();
    serde_json::json!({
        "cMo": rows,
        "convention": "X_c = R X_o + t: model (world) to camera, metres",
    })
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> CameraPose {
        CameraPose {
            q_cw: UnitQuaternion::from_euler_angles(0.3, -1.1, 2.5),
            c_w: Vector3::new(0.4, -0.2, 1.3),
        }
    }

    #[test]
    fn json_and_tum_give_the_same_pose() {
        let p = pose();
        let from_json = parse_json(&start_pose_json(&p)).unwrap();
        assert!(from_json.q_cw.angle_to(&p.q_cw) < 1e-12);
        assert!((from_json.c_w - p.c_w).norm() < 1e-12);
        let q = p.q_cw.inverse();
        let line = format!(
            "# t tx ty tz qx qy qz qw\n12.5 {} {} {} {} {} {} {}\n",
            p.c_w.x, p.c_w.y, p.c_w.z, q.i, q.j, q.k, q.w
        );
        let from_tum = parse_tum(&line).unwrap();
        assert!(from_tum.q_cw.angle_to(&p.q_cw) < 1e-12);
        assert!((from_tum.c_w - p.c_w).norm() < 1e-12);
    }

    #[test]
    fn the_shared_frame0_pose_puts_the_cube_in_front_of_the_camera() {
        let text = r#"{"cMo": [
            [0.007025480670922024, 0.9958552420364798, 0.09068064583916036, 0.07737004807689539],
            [0.9904134436131532, -0.019440187918363216, 0.13675997149763425, 0.020997510711007653],
            [0.13795598331235054, 0.08885052617831513, -0.98644499627002, 0.4141806089640929],
            [0.0, 0.0, 0.0, 1.0]], "frame": 0}"#;
        let p = parse_json(text).unwrap();
        // The model origin seen from the camera is cMo's translation: 0.41 m ahead.
        let origin_c = p.q_cw * (Vector3::zeros() - p.c_w);
        assert!((origin_c - Vector3::new(0.07737, 0.0210, 0.41418)).norm() < 1e-4);
    }

    #[test]
    fn non_rigid_transforms_are_refused_with_the_reason() {
        let mut m = cmo_of_pose(&pose());
        m[(0, 0)] *= 1.01;
        let e = pose_of_cmo(&m).unwrap_err().to_string();
        assert!(e.contains("not orthonormal"), "{e}");
        let mut m = cmo_of_pose(&pose());
        m.row_mut(0).neg_mut();
        let e = pose_of_cmo(&m).unwrap_err().to_string();
        assert!(e.contains("determinant is -1"), "{e}");
        let mut m = cmo_of_pose(&pose());
        m[(3, 2)] = 0.5;
        let e = pose_of_cmo(&m).unwrap_err().to_string();
        assert!(e.contains("last row"), "{e}");
        let mut m = cmo_of_pose(&pose());
        m[(1, 3)] = f64::NAN;
        assert!(
            pose_of_cmo(&m)
                .unwrap_err()
                .to_string()
                .contains("not finite")
        );
        // Six digits of round-off pass.
        let m = cmo_of_pose(&pose()).map(|v| (v * 1e6).round() / 1e6);
        assert!(pose_of_cmo(&m).is_ok());
    }

    #[test]
    fn malformed_files_are_named() {
        assert!(
            parse_json("{\"pose\": 1}")
                .unwrap_err()
                .to_string()
                .contains("`cMo`")
        );
        assert!(
            parse_json("{\"cMo\": [[1,0,0],[0,1,0],[0,0,1]]}")
                .unwrap_err()
                .to_string()
                .contains("4 rows of 4")
        );
        assert!(
            parse_tum("1 2 3")
                .unwrap_err()
                .to_string()
                .contains("8 numbers")
        );
        assert!(parse_tum("").unwrap_err().to_string().contains("0 lines"));
        assert!(
            parse_tum("0 0 0 0 0 0 0 2")
                .unwrap_err()
                .to_string()
                .contains("norm 2")
        );
        assert!(
            parse_tum("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1")
                .unwrap_err()
                .to_string()
                .contains("2 lines")
        );
    }
}
