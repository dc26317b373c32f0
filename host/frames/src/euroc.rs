//! A recorded or synthetic dataset in the EuRoC/ASL layout, as the tracker reads it.
//!
//! ```text
//! DIR/mav0/imu0/data.csv, sensor.yaml            IMU (the body frame)
//! DIR/mav0/cam0/data.csv, sensor.yaml, data/*.png camera (T_BS: camera → body)
//! DIR/mav0/state_groundtruth_estimate0/data.csv  ground truth (optional)
//! DIR/model/scene.obj                            the textured model (synthetic datasets)
//! ```

use std::path::{Path, PathBuf};

use firmware_sim::sim::scenario::euroc::{self, DatasetError as CsvError, GroundTruthRow, ImuRow};
use nalgebra::{UnitQuaternion, Vector3};
use serde::Deserialize;

use camera::{CalibError, CameraCalib, read_euroc_sensor_yaml};
pub use tracker::{HandEye, ImuNoiseDensities};

/// The file `host-vision synth` writes into a dataset folder first and removes last: a
/// folder that has it is unfinished (interrupted or killed while being written), and
/// [`Dataset::open`] refuses it.
pub const UNFINISHED: &str = ".synth-unfinished";

/// Why a dataset cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The folder or a required file is missing.
    #[error("{path}: missing ({what})")]
    Missing {
        /// Expected path.
        path: PathBuf,
        /// What it should hold.
        what: &'static str,
    },
    /// A CSV file could not be read.
    #[error(transparent)]
    Csv(#[from] CsvError),
    /// The camera calibration could not be read.
    #[error(transparent)]
    Calib(#[from] CalibError),
    /// An inertial model was asked for on a dataset without `imu0`.
    #[error(
        "{path}: missing (IMU samples): the {model} model needs an IMU; `--filter vision` tracks the camera alone"
    )]
    NoImu {
        /// The missing IMU file.
        path: PathBuf,
        /// The model asked for.
        model: &'static str,
    },
    /// A file's content is unusable.
    #[error("{path}: {what}")]
    Invalid {
        /// File.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// One camera frame of the dataset.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameRecord {
    /// Time stamp [ns].
    pub stamp: u64,
    /// Image file.
    pub path: PathBuf,
}

/// A dataset opened for tracking.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Root folder.
    pub root: PathBuf,
    /// IMU samples, time-ordered.
    pub imu: Vec<ImuRow>,
    /// IMU rate [Hz] (from `sensor.yaml`, else from the time stamps).
    pub imu_rate_hz: f64,
    /// IMU noise densities, when `sensor.yaml` gives them.
    pub imu_noise: Option<ImuNoiseDensities>,
    /// The camera.
    pub camera: CameraCalib,
    /// Camera mount.
    pub hand_eye: HandEye,
    /// Frames, time-ordered.
    pub frames: Vec<FrameRecord>,
    /// Ground truth of the IMU (body) pose, when present.
    pub groundtruth: Option<Vec<GroundTruthRow>>,
    /// `model/scene.obj`, when present.
    pub model: Option<PathBuf>,
}

fn require(path: PathBuf, what: &'static str) -> Result<PathBuf, DatasetError> {
    if path.exists() {
        Ok(path)
    } else {
        Err(DatasetError::Missing { path, what })
    }
}

#[derive(Deserialize)]
struct ImuYaml {
    rate_hz: Option<f64>,
    #[serde(flatten)]
    noise: Option<ImuNoiseDensities>,
}

/// Refuses what is no dataset folder: a file, nothing, or an unfinished synthesis.
fn check_root(root: &Path) -> Result<(), DatasetError> {
    if root.is_file() {
        return Err(DatasetError::Invalid {
            path: root.to_owned(),
            what: "is a file, not a dataset folder (the folder holding mav0/)".into(),
        });
    }
    if !root.exists() {
        return Err(DatasetError::Missing {
            path: root.to_owned(),
            what: "dataset folder",
        });
    }
    if root.join(UNFINISHED).exists() {
        return Err(DatasetError::Invalid {
            path: root.to_owned(),
            what: format!(
                "an unfinished dataset: `host-vision synth` was interrupted or killed while writing it ({} is there); run synth into it again",
                UNFINISHED
            ),
        });
    }
    Ok(())
}

/// The IMU's samples (at least two, in increasing time) and its `sensor.yaml`, if there is one.
fn read_imu(
    imu_csv: &Path,
    imu_yaml_path: &Path,
) -> Result<(Vec<ImuRow>, Option<ImuYaml>), DatasetError> {
    let imu = euroc::read_imu_csv(imu_csv)?;
    if imu.len() < 2 {
        return Err(DatasetError::Invalid {
            path: imu_csv.to_owned(),
            what: format!("{} IMU samples; need at least 2", imu.len()),
        });
    }
    if let Some(w) = imu.windows(2).position(|w| w[1].stamp <= w[0].stamp) {
        return Err(DatasetError::Invalid {
            path: imu_csv.to_owned(),
            what: format!(
                "time stamps not increasing at sample {} ({} after {})",
                w + 1,
                imu[w + 1].stamp,
                imu[w].stamp
            ),
        });
    }
    let imu_yaml = match std::fs::read_to_string(imu_yaml_path) {
        Ok(text) => {
            let text: String = text
                .lines()
                .filter(|l| !l.starts_with("%YAML"))
                .collect::<Vec<_>>()
                .join("\n");
            Some(
                serde_yaml_ng::from_str::<ImuYaml>(&text).map_err(|e| DatasetError::Invalid {
                    path: imu_yaml_path.to_owned(),
                    what: e.to_string(),
                })?,
            )
        }
        Err(_) => None,
    };
    Ok((imu, imu_yaml))
}

impl Dataset {
    /// Opens `root` (the folder holding `mav0/`). A folder with `cam0` and no `imu0` opens
    /// without IMU samples ([`Self::has_imu`] is false): only the vision-only model tracks it.
    pub fn open(root: &Path) -> Result<Self, DatasetError> {
        check_root(root)?;
        let mav0 = require(root.join("mav0"), "EuRoC folder mav0/")?;
        let imu_csv = mav0.join("imu0/data.csv");
        let cam_dir = require(mav0.join("cam0"), "camera folder")?;
        let cam_yaml = require(cam_dir.join("sensor.yaml"), "camera calibration")?;
        let cam_csv = require(cam_dir.join("data.csv"), "camera frame list")?;
        let camera = read_euroc_sensor_yaml(&cam_yaml)?;
        let frames = read_frame_list(&cam_csv, &cam_dir.join("data"))?;
        let gt_path = mav0.join("state_groundtruth_estimate0/data.csv");
        let groundtruth = if gt_path.exists() {
            Some(euroc::read_groundtruth_csv(&gt_path)?)
        } else {
            None
        };
        let model = Some(root.join("model/scene.obj")).filter(|p| p.exists());
        if !imu_csv.exists() {
            // The camera alone: its pose is the filter's (no mount), unless T_BS relates it to
            // a ground truth of the body.
            let hand_eye = camera
                .extrinsics
                .as_ref()
                .and_then(HandEye::from_t_bs)
                .unwrap_or(HandEye::IDENTITY);
            return Ok(Dataset {
                root: root.to_owned(),
                imu: Vec::new(),
                imu_rate_hz: camera.rate_hz.unwrap_or(0.0),
                imu_noise: None,
                camera,
                hand_eye,
                frames,
                groundtruth,
                model,
            });
        }

        let (imu, imu_yaml) = read_imu(&imu_csv, &mav0.join("imu0/sensor.yaml"))?;
        let median_dt = {
            let mut dts: Vec<u64> = imu.windows(2).map(|w| w[1].stamp - w[0].stamp).collect();
            dts.sort_unstable();
            dts[dts.len() / 2] as f64 * 1e-9
        };
        let imu_rate_hz = imu_yaml
            .as_ref()
            .and_then(|y| y.rate_hz)
            .filter(|r| r.is_finite() && *r > 0.0)
            .unwrap_or(1.0 / median_dt);

        let hand_eye = camera
            .extrinsics
            .as_ref()
            .ok_or_else(|| DatasetError::Invalid {
                path: cam_yaml.clone(),
                what: "no T_BS: the camera's mount on the IMU is needed".into(),
            })
            .and_then(|t| {
                HandEye::from_t_bs(t).ok_or_else(|| DatasetError::Invalid {
                    path: cam_yaml.clone(),
                    what: "T_BS is not a rigid transform".into(),
                })
            })?;
        Ok(Dataset {
            root: root.to_owned(),
            imu,
            imu_rate_hz,
            imu_noise: imu_yaml.and_then(|y| y.noise),
            camera,
            hand_eye,
            frames,
            groundtruth,
            model,
        })
    }

    /// A video or image folder at `root` seen by `camera`: no IMU, no ground truth, and the
    /// frames come from the frame source as they are decoded (so the list is empty).
    pub fn frames_only(root: &Path, camera: camera::Camera) -> Self {
        Dataset {
            root: root.to_owned(),
            imu: Vec::new(),
            imu_rate_hz: 0.0,
            imu_noise: None,
            camera: CameraCalib {
                name: root.display().to_string(),
                camera,
                extrinsics: None,
                rate_hz: None,
                timeshift_cam_imu: None,
            },
            hand_eye: HandEye::IDENTITY,
            frames: Vec::new(),
            groundtruth: None,
            model: None,
        }
    }

    /// The rig the core is configured for: the IMU's rate and noise, the camera's rate and
    /// mount.
    pub fn rig(&self) -> tracker::rig::Rig {
        tracker::rig::Rig {
            imu_rate_hz: self.imu_rate_hz,
            imu_noise: self.imu_noise,
            camera_rate_hz: self.camera.rate_hz,
            hand_eye: self.hand_eye,
        }
    }

    /// Whether the dataset has IMU samples (the inertial models need them).
    pub fn has_imu(&self) -> bool {
        !self.imu.is_empty()
    }

    /// Index of the IMU sample that triggered each frame (the nearest within half a sample
    /// period; frames without one are dropped from the list returned).
    pub fn triggers(&self) -> Vec<(usize, usize)> {
        let half = (0.5e9 / self.imu_rate_hz) as u64;
        let mut out = Vec::with_capacity(self.frames.len());
        let mut k = 0usize;
        for (f, frame) in self.frames.iter().enumerate() {
            while k + 1 < self.imu.len() && self.imu[k + 1].stamp <= frame.stamp {
                k += 1;
            }
            let best = [k, (k + 1).min(self.imu.len() - 1)]
                .into_iter()
                .min_by_key(|&i| self.imu[i].stamp.abs_diff(frame.stamp))
                .unwrap_or(k);
            if self.imu[best].stamp.abs_diff(frame.stamp) <= half
                && out.last().is_none_or(|&(_, last)| last < best)
            {
                out.push((f, best));
            }
        }
        out
    }

    /// Ground-truth IMU pose at `stamp` (linear/slerp interpolation; `None` outside).
    pub fn groundtruth_at(&self, stamp: u64) -> Option<(Vector3<f64>, UnitQuaternion<f64>)> {
        let gt = self.groundtruth.as_ref()?;
        let i = gt.partition_point(|r| r.stamp <= stamp);
        if i == 0 {
            return (gt.first()?.stamp == stamp).then(|| (gt[0].p_w, gt[0].q_ws));
        }
        let a = &gt[i - 1];
        if a.stamp == stamp {
            return Some((a.p_w, a.q_ws));
        }
        let b = gt.get(i)?;
        // A gap in the ground truth longer than 50 ms is not interpolated.
        if b.stamp - a.stamp > 50_000_000 {
            return None;
        }
        let s = (stamp - a.stamp) as f64 / (b.stamp - a.stamp) as f64;
        Some((a.p_w.lerp(&b.p_w, s), a.q_ws.slerp(&b.q_ws, s)))
    }
}

/// The frames of a EuRoC `cam0/data.csv` (`timestamp,filename`, increasing stamps), as paths
/// under `data`; the file within the CSV limits ([`euroc::read_csv_text`]).
pub fn read_frame_list(csv: &Path, data: &Path) -> Result<Vec<FrameRecord>, DatasetError> {
    parse_frame_list(&euroc::read_csv_text(csv)?, csv, data)
}

/// [`read_frame_list`] on the file's text (`csv` names it in errors). A file name must be a
/// plain name in `data` (no folder, no `..`): EuRoC's are, and any other would read a file
/// outside the dataset.
pub fn parse_frame_list(
    text: &str,
    csv: &Path,
    data: &Path,
) -> Result<Vec<FrameRecord>, DatasetError> {
    let mut out = Vec::new();
    for (line, row) in euroc::data_lines(text, csv)? {
        let bad = |what: String| {
            DatasetError::Csv(CsvError::Parse {
                path: csv.to_owned(),
                line,
                what,
            })
        };
        let (stamp, name) = row
            .split_once(',')
            .ok_or_else(|| bad("expected `timestamp,filename`".into()))?;
        let stamp: u64 = stamp
            .trim()
            .parse()
            .map_err(|e| bad(format!("time stamp `{stamp}`: {e}")))?;
        if out.last().is_some_and(|f: &FrameRecord| f.stamp >= stamp) {
            return Err(bad(format!("time stamp {stamp} not increasing")));
        }
        let name = name.trim();
        let plain = Path::new(name).file_name().is_some_and(|f| f == name);
        if !plain {
            return Err(bad(format!(
                "file name `{name}`: not a plain file name in {}",
                data.display()
            )));
        }
        out.push(FrameRecord {
            stamp,
            path: data.join(name),
        });
    }
    if out.is_empty() {
        return Err(DatasetError::Invalid {
            path: csv.to_owned(),
            what: "no frames".into(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_eye_from_t_bs_round_trips_a_camera_pose() {
        let q_cs = UnitQuaternion::from_euler_angles(0.3, -1.2, 2.0);
        let c_s = Vector3::new(0.02, -0.01, 0.03);
        let mut t = nalgebra::Matrix4::identity();
        t.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(q_cs.inverse().to_rotation_matrix().matrix());
        t.fixed_view_mut::<3, 1>(0, 3).copy_from(&c_s);
        let he = HandEye::from_t_bs(&t).unwrap();
        assert!(he.q_cs.angle_to(&q_cs) < 1e-12);
        assert!((he.c_s - c_s).norm() < 1e-15);
        let bad = nalgebra::Matrix4::from_element(1.0);
        assert!(HandEye::from_t_bs(&bad).is_none());
    }

    #[test]
    fn missing_folder_is_named() {
        let err = Dataset::open(Path::new("/nonexistent/dataset")).unwrap_err();
        assert_eq!(
            err.to_string(),
            "/nonexistent/dataset: missing (dataset folder)"
        );
        let dir = tempfile::tempdir().unwrap();
        let err = Dataset::open(dir.path()).unwrap_err().to_string();
        assert!(
            err.ends_with("/mav0: missing (EuRoC folder mav0/)"),
            "{err}"
        );
        std::fs::create_dir_all(dir.path().join("mav0/cam0")).unwrap();
        std::fs::write(dir.path().join("mav0/cam0/data.csv"), "1,a.png\n").unwrap();
        let err = Dataset::open(dir.path()).unwrap_err().to_string();
        assert!(
            err.ends_with("/mav0/cam0/sensor.yaml: missing (camera calibration)"),
            "{err}"
        );
        let file = dir.path().join("manifest.json");
        std::fs::write(&file, "{}").unwrap();
        let err = Dataset::open(&file).unwrap_err().to_string();
        assert!(
            err.ends_with(
                "manifest.json: is a file, not a dataset folder (the folder holding mav0/)"
            ),
            "{err}"
        );
    }

    #[test]
    fn frame_lists_refuse_names_outside_the_folder_and_bad_rows() {
        let (csv, data) = (Path::new("cam0/data.csv"), Path::new("cam0/data"));
        let list = parse_frame_list(
            "#timestamp [ns],filename\n10,a.png\n20, b.png \n",
            csv,
            data,
        )
        .unwrap();
        assert_eq!(list.len(), 2);
        assert_eq!(list[1].path, data.join("b.png"));
        for (text, says) in [
            ("10,../secret.png\n", "not a plain file name"),
            ("10,/etc/passwd\n", "not a plain file name"),
            ("10,sub/a.png\n", "not a plain file name"),
            ("10,\n", "not a plain file name"),
            ("10,a.png\n10,b.png\n", "not increasing"),
            ("-5,a.png\n", "time stamp"),
            ("a.png\n", "expected `timestamp,filename`"),
            ("# only a header\n", "no frames"),
        ] {
            let e = parse_frame_list(text, csv, data).unwrap_err().to_string();
            assert!(e.contains(says), "{text:?}: {e}");
        }
    }

    proptest::proptest! {
        /// Arbitrary text: a list of plain names under `data` with increasing stamps, or a
        /// typed error; never a panic.
        #[test]
        fn any_frame_list_is_read_or_refused(text in "[0-9a-z,./# \n-]{0,200}") {
            let data = Path::new("cam0/data");
            if let Ok(list) = parse_frame_list(&text, Path::new("data.csv"), data) {
                proptest::prop_assert!(!list.is_empty());
                for w in list.windows(2) {
                    proptest::prop_assert!(w[0].stamp < w[1].stamp);
                }
                for f in &list {
                    proptest::prop_assert_eq!(f.path.parent(), Some(data));
                }
            }
        }
    }
}
