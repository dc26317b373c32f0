//! Pinhole intrinsics given by the user for a camera without a calibration file of the
//! EuRoC/Kalibr kind: `--intrinsics fx,fy,cx,cy`, or a `camera.json` as the shared data has
//! (`{"model": "pinhole", "width", "height", "fx", "fy", "cx", "cy", "distortion": "none"}`).

use std::path::Path;

use serde::Deserialize;

use super::{CalibError, Camera, CameraError, Distortion, Pinhole};

/// Parses `fx,fy,cx,cy` [px]: four finite numbers, positive focal lengths.
pub fn parse_intrinsics(s: &str) -> Result<Pinhole, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("`{p}`: {e}")))
        .collect::<Result<_, _>>()?;
    let [fx, fy, cx, cy] = v[..] else {
        return Err(format!(
            "expected four numbers fx,fy,cx,cy [px], got {} in `{s}`",
            v.len()
        ));
    };
    let pinhole = Pinhole::new(fx, fy, cx, cy);
    pinhole.validate().map_err(|e| e.to_string())?;
    Ok(pinhole)
}

/// A distortion-free camera of `width × height` with `pinhole`, whose principal point lies in
/// the image (a point outside means swapped or mistyped numbers).
pub fn pinhole_camera(width: u32, height: u32, pinhole: Pinhole) -> Result<Camera, CameraError> {
    let camera = Camera::new(width, height, pinhole, Distortion::None)?;
    if !(0.0..=f64::from(width)).contains(&pinhole.cx)
        || !(0.0..=f64::from(height)).contains(&pinhole.cy)
    {
        return Err(CameraError::BadIntrinsics(format!(
            "principal point ({}, {}) outside the {width}x{height} image",
            pinhole.cx, pinhole.cy
        )));
    }
    Ok(camera)
}

/// Other fields (`source`, notes) are allowed: the format is a record, not a schema.
#[derive(Deserialize)]
struct CameraJson {
    model: String,
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    distortion: String,
}

/// Reads a `camera.json` (pinhole, no distortion).
pub fn read_camera_json(path: &Path) -> Result<Camera, CalibError> {
    let text = crate::read_text_file(path).map_err(|source| CalibError::Io {
        path: path.to_owned(),
        source,
    })?;
    parse_camera_json(&text, path)
}

/// Parses the text of a `camera.json` ([`read_camera_json`]); `path` names it in errors.
pub fn parse_camera_json(text: &str, path: &Path) -> Result<Camera, CalibError> {
    let invalid = |what: String| CalibError::Invalid {
        path: path.to_owned(),
        what,
    };
    let c: CameraJson =
        serde_json::from_str(text).map_err(|e| invalid(format!("not a camera.json: {e}")))?;
    if c.model != "pinhole" {
        return Err(invalid(format!(
            "model `{}` unsupported: only `pinhole`",
            c.model
        )));
    }
    if c.distortion != "none" {
        return Err(invalid(format!(
            "distortion `{}` unsupported: only `none` (use a EuRoC/Kalibr sensor.yaml for a distorted lens)",
            c.distortion
        )));
    }
    pinhole_camera(c.width, c.height, Pinhole::new(c.fx, c.fy, c.cx, c.cy)).map_err(|source| {
        CalibError::Camera {
            path: path.to_owned(),
            source,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intrinsics_are_four_finite_numbers_with_positive_focal_lengths() {
        let p = parse_intrinsics("605.1, 604.8,325.5,245").unwrap();
        assert_eq!(
            (p.fx, p.fy, p.cx, p.cy, p.skew),
            (605.1, 604.8, 325.5, 245.0, 0.0)
        );
        assert!(parse_intrinsics("1,2,3").unwrap_err().contains("got 3"));
        assert!(parse_intrinsics("1,2,x,4").unwrap_err().contains("`x`"));
        assert!(parse_intrinsics("-600,600,320,240").is_err());
        assert!(parse_intrinsics("600,600,nan,240").is_err());
        assert!(pinhole_camera(640, 480, Pinhole::new(600.0, 600.0, 320.0, 240.0)).is_ok());
        let e = pinhole_camera(640, 480, Pinhole::new(600.0, 600.0, 240.0, 620.0)).unwrap_err();
        assert!(e.to_string().contains("outside the 640x480 image"), "{e}");
    }

    #[test]
    fn camera_json_is_read_and_checked() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("camera.json");
        std::fs::write(
            &p,
            r#"{"model": "pinhole", "width": 640, "height": 480, "fx": 605.1, "fy": 604.8,
                "cx": 325.5, "cy": 244.9, "distortion": "none", "source": "test"}"#,
        )
        .unwrap();
        let c = read_camera_json(&p).unwrap();
        assert_eq!((c.width, c.height, c.pinhole.fx), (640, 480, 605.1));
        std::fs::write(
            &p,
            r#"{"model": "fisheye", "width": 640, "height": 480, "fx": 1, "fy": 1, "cx": 1, "cy": 1, "distortion": "none"}"#,
        )
        .unwrap();
        assert!(
            read_camera_json(&p)
                .unwrap_err()
                .to_string()
                .contains("model `fisheye`")
        );
        std::fs::write(&p, r#"{"model": "pinhole"}"#).unwrap();
        let e = read_camera_json(&p).unwrap_err().to_string();
        assert!(
            e.contains("not a camera.json") && e.contains("width"),
            "{e}"
        );
    }
}
