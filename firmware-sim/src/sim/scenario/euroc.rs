//! EuRoC/ASL dataset files for the inertial part of a simulated recording, and readers for
//! them.
//!
//! Layout under the dataset folder:
//! - `mav0/imu0/data.csv`: `#timestamp [ns],w_RS_S_x [rad s^-1],…,a_RS_S_z [m s^-2]`;
//! - `mav0/imu0/sensor.yaml`: `T_BS` (identity: the IMU is the body), `rate_hz` and the noise
//!   densities in EuRoC's continuous-time units;
//! - `mav0/state_groundtruth_estimate0/data.csv`: the 17 EuRoC columns (timestamp, `p_RS_R`,
//!   `q_RS` as w x y z, `v_RS_R`, `b_w_RS_S`, `b_a_RS_S`) followed by **six extra columns**:
//!   the body angular velocity `w_RS_S` [rad/s] and the free acceleration `a_RS_R` [m/s²]
//!   (world frame, gravity excluded). One row per IMU sample; the biases are the true biases
//!   of the simulated IMU at that sample.
//!
//! Numbers are written in Rust's shortest round-trip form, so reading them back gives the
//! simulated `f64` values exactly.

use std::fmt::Write as _;
use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::{ImuSample, Scenario, T0_NS};

/// Why a dataset could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file or folder could not be created, written or read.
    #[error("{path}: {source}")]
    Io {
        /// File or folder.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// A line of a CSV file is not what the format says.
    #[error("{path}:{line}: {what}")]
    Parse {
        /// File.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        what: String,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Creates `path`'s parent folders and writes `text` to it.
pub fn write_text(path: &Path, text: &str) -> Result<(), DatasetError> {
    if let Some(dir) = path.parent() {
        fs::create_dir_all(dir).map_err(io_err(dir))?;
    }
    fs::write(path, text).map_err(io_err(path))
}

/// Writes lines produced by `row` for every sample, after `header`.
fn write_rows(
    path: &Path,
    header: &str,
    samples: &[ImuSample],
    row: impl Fn(&mut String, &ImuSample),
) -> Result<(), DatasetError> {
    if let Some(dir) = path.parent() {
        fs::create_dir_all(dir).map_err(io_err(dir))?;
    }
    let file = fs::File::create(path).map_err(io_err(path))?;
    let mut w = BufWriter::new(file);
    let mut line = String::with_capacity(512);
    writeln!(w, "{header}").map_err(io_err(path))?;
    for s in samples {
        line.clear();
        let _ = write!(line, "{}", T0_NS + s.ns);
        row(&mut line, s);
        line.push('\n');
        w.write_all(line.as_bytes()).map_err(io_err(path))?;
    }
    w.flush().map_err(io_err(path))
}

fn push(line: &mut String, values: &[f64]) {
    for v in values {
        let _ = write!(line, ",{v}");
    }
}

/// Header of `imu0/data.csv`.
pub const IMU_HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],\
w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]";

/// Header of `state_groundtruth_estimate0/data.csv` (EuRoC's 17 columns + 6 extra).
pub const GROUNDTRUTH_HEADER: &str = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], \
q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], \
v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], \
b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2], w_RS_S_x [rad s^-1], \
w_RS_S_y [rad s^-1], w_RS_S_z [rad s^-1], a_RS_R_x [m s^-2], a_RS_R_y [m s^-2], \
a_RS_R_z [m s^-2]";

/// Writes `imu0/data.csv`.
pub fn write_imu_csv(path: &Path, samples: &[ImuSample]) -> Result<(), DatasetError> {
    write_rows(path, IMU_HEADER, samples, |l, s| {
        let (g, a) = (s.reading.gyro, s.reading.accel);
        push(l, &[g.x, g.y, g.z, a.x, a.y, a.z]);
    })
}

/// Writes `state_groundtruth_estimate0/data.csv`.
pub fn write_groundtruth_csv(path: &Path, samples: &[ImuSample]) -> Result<(), DatasetError> {
    write_rows(path, GROUNDTRUTH_HEADER, samples, |l, s| {
        let k = &s.truth;
        let q = k.q_ws.quaternion();
        let (bg, ba) = (s.reading.gyro_bias, s.reading.accel_bias);
        push(l, &[k.p_w.x, k.p_w.y, k.p_w.z, q.w, q.i, q.j, q.k]);
        push(
            l,
            &[
                k.v_w.x, k.v_w.y, k.v_w.z, bg.x, bg.y, bg.z, ba.x, ba.y, ba.z,
            ],
        );
        push(l, &[k.omega_s.x, k.omega_s.y, k.omega_s.z]);
        push(l, &[k.a_w.x, k.a_w.y, k.a_w.z]);
    })
}

/// A 4×4 matrix in EuRoC's `T_BS` block (row-major).
pub fn yaml_matrix(name: &str, m: &[[f64; 4]; 4]) -> String {
    let rows: Vec<String> = m
        .iter()
        .map(|r| format!("{:?}, {:?}, {:?}, {:?}", r[0], r[1], r[2], r[3]))
        .collect();
    format!(
        "{name}:\n  cols: 4\n  rows: 4\n  data: [{}]\n",
        rows.join(",\n         ")
    )
}

/// Writes `imu0/sensor.yaml`.
pub fn write_imu_sensor_yaml(path: &Path, scenario: &Scenario) -> Result<(), DatasetError> {
    let n = &scenario.imu.noise;
    let identity = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let text = format!(
        "%YAML:1.0\n\
         # Simulated IMU (firmware-sim, scenario {name}); the body frame is the IMU frame.\n\
         sensor_type: imu\n\
         comment: simulated MT9-class IMU, scenario {name}\n\
         {tbs}\
         rate_hz: {rate:?}\n\
         # inertial sensor noise model parameters (continuous time)\n\
         gyroscope_noise_density: {gd:e}     # [ rad / s / sqrt(Hz) ]\n\
         gyroscope_random_walk: {gw:e}       # [ rad / s^2 / sqrt(Hz) ]\n\
         accelerometer_noise_density: {ad:e} # [ m / s^2 / sqrt(Hz) ]\n\
         accelerometer_random_walk: {aw:e}   # [ m / s^3 / sqrt(Hz) ]\n",
        name = scenario.name,
        tbs = yaml_matrix("T_BS", &identity),
        rate = scenario.imu.rate_hz,
        gd = n.gyro_density,
        gw = n.gyro_walk,
        ad = n.accel_density,
        aw = n.accel_walk,
    );
    write_text(path, &text)
}

/// What [`write_imu_dataset`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuDataset {
    /// The samples (truth included).
    pub samples: Vec<ImuSample>,
    /// Samples where a gyro or accelerometer axis hit its range.
    pub saturated: usize,
}

/// Simulates the scenario's IMU and writes `mav0/imu0/{data.csv,sensor.yaml}` and
/// `mav0/state_groundtruth_estimate0/data.csv` under `dir`.
pub fn write_imu_dataset(
    dir: &Path,
    scenario: &Scenario,
    seed: u64,
) -> Result<ImuDataset, DatasetError> {
    let samples = super::simulate_imu(scenario, seed);
    let mav0 = dir.join("mav0");
    write_imu_csv(&mav0.join("imu0/data.csv"), &samples)?;
    write_imu_sensor_yaml(&mav0.join("imu0/sensor.yaml"), scenario)?;
    write_groundtruth_csv(&mav0.join("state_groundtruth_estimate0/data.csv"), &samples)?;
    let saturated = match scenario.imu.saturation {
        None => 0,
        Some(s) => samples
            .iter()
            .filter(|x| x.reading.gyro.amax() >= s.gyro || x.reading.accel.amax() >= s.accel)
            .count(),
    };
    Ok(ImuDataset { samples, saturated })
}

/// The manifest's description of the inertial part (scenario, seed, IMU parameters, peaks,
/// file columns); the renderer adds its own sections.
pub fn manifest(scenario: &Scenario, seed: u64, data: &ImuDataset) -> serde_json::Value {
    let o = &scenario.imu;
    let peaks = scenario.path.peaks(1e-3);
    serde_json::json!({
        "scenario": scenario.name,
        "seed": seed,
        "duration_s": scenario.duration(),
        "t0_ns": T0_NS,
        "time": "simulation time t = (timestamp - t0_ns) / 1e9 s",
        "imu": {
            "rate_hz": o.rate_hz,
            "samples": data.samples.len(),
            "gyroscope_noise_density": o.noise.gyro_density,
            "gyroscope_random_walk": o.noise.gyro_walk,
            "accelerometer_noise_density": o.noise.accel_density,
            "accelerometer_random_walk": o.noise.accel_walk,
            "initial_bias_sigma": { "gyro": o.initial_bias_sigma.0, "accel": o.initial_bias_sigma.1 },
            "vibration": o.vibration,
            "saturation": o.saturation,
            "saturated_samples": data.saturated,
        },
        "peaks": {
            "free_acceleration_m_s2": peaks.accel,
            "angular_rate_rad_s": peaks.rate,
            "pivot_acceleration_m_s2": peaks.pivot_accel,
            "speed_m_s": peaks.speed,
        },
        "groundtruth_columns": GROUNDTRUTH_HEADER.trim_start_matches('#').split(", ").collect::<Vec<_>>(),
        "groundtruth_note": "EuRoC columns plus body angular velocity w_RS_S and free acceleration a_RS_R (world, gravity excluded)",
    })
}

/// Writes a JSON value, pretty-printed.
pub fn write_json(path: &Path, value: &serde_json::Value) -> Result<(), DatasetError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| DatasetError::Io {
        path: path.to_owned(),
        source: std::io::Error::other(e),
    })?;
    write_text(path, &(text + "\n"))
}

/// Largest EuRoC CSV file read (`imu0`, ground truth, `cam0/data.csv`), checked from its size
/// before reading: a ground-truth line is about 300 bytes, so 2 GiB holds [`MAX_ROWS`] of them
/// with room to spare.
pub const MAX_CSV_BYTES: u64 = 2 << 30;

/// Most data rows of a EuRoC CSV file, counted before the rows are allocated: 5 million is
/// 7 hours of a 200 Hz IMU (280 MB of IMU rows, 1 GB of ground-truth rows in memory).
pub const MAX_ROWS: usize = 5_000_000;

/// Reads a CSV file's text, refusing one over [`MAX_CSV_BYTES`] before reading it.
pub fn read_csv_text(path: &Path) -> Result<String, DatasetError> {
    let len = fs::metadata(path).map_err(io_err(path))?.len();
    if len > MAX_CSV_BYTES {
        return Err(DatasetError::Parse {
            path: path.to_owned(),
            line: 0,
            what: format!("{len} bytes: too large (at most {MAX_CSV_BYTES})"),
        });
    }
    fs::read_to_string(path).map_err(io_err(path))
}

/// The data lines of a CSV text (not empty, not `#`), with their 1-based numbers, after
/// checking there are at most [`MAX_ROWS`].
pub fn data_lines<'a>(
    text: &'a str,
    path: &Path,
) -> Result<impl Iterator<Item = (usize, &'a str)>, DatasetError> {
    let lines = || {
        text.lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
    };
    let rows = lines().count();
    if rows > MAX_ROWS {
        return Err(DatasetError::Parse {
            path: path.to_owned(),
            line: 0,
            what: format!("{rows} rows: too many (at most {MAX_ROWS})"),
        });
    }
    Ok(lines())
}

/// Parses a CSV text of numbers (first column an integer time stamp), skipping `#` lines;
/// every data row must have exactly `columns` fields. Each row comes with its 1-based line
/// number, for the callers' own checks to name.
fn read_rows(
    text: &str,
    path: &Path,
    columns: usize,
) -> Result<Vec<(usize, u64, Vec<f64>)>, DatasetError> {
    let lines = data_lines(text, path)?;
    let mut out = Vec::new();
    for (number, line) in lines {
        let bad = |what: String| DatasetError::Parse {
            path: path.to_owned(),
            line: number,
            what,
        };
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != columns {
            return Err(bad(format!("{} fields, expected {columns}", fields.len())));
        }
        let stamp: u64 = fields[0]
            .parse()
            .map_err(|e| bad(format!("time stamp `{}`: {e}", fields[0])))?;
        let values = fields[1..]
            .iter()
            .map(|f| {
                f.parse::<f64>()
                    .map_err(|e| bad(format!("`{f}`: {e}")))
                    .and_then(|v| {
                        if v.is_finite() {
                            Ok(v)
                        } else {
                            Err(bad(format!("non-finite value `{f}`")))
                        }
                    })
            })
            .collect::<Result<Vec<f64>, _>>()?;
        out.push((number, stamp, values));
    }
    Ok(out)
}

/// One row of `imu0/data.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuRow {
    /// Time stamp [ns].
    pub stamp: u64,
    /// Angular rate [rad/s].
    pub gyro: Vector3<f64>,
    /// Specific force [m/s²].
    pub accel: Vector3<f64>,
}

/// Reads an EuRoC `imu0/data.csv`.
pub fn read_imu_csv(path: &Path) -> Result<Vec<ImuRow>, DatasetError> {
    parse_imu_csv(&read_csv_text(path)?, path)
}

/// Parses the text of an EuRoC `imu0/data.csv` ([`read_imu_csv`]); `path` names it in errors.
pub fn parse_imu_csv(text: &str, path: &Path) -> Result<Vec<ImuRow>, DatasetError> {
    Ok(read_rows(text, path, 7)?
        .into_iter()
        .map(|(_, stamp, v)| ImuRow {
            stamp,
            gyro: Vector3::new(v[0], v[1], v[2]),
            accel: Vector3::new(v[3], v[4], v[5]),
        })
        .collect())
}

/// One row of the ground truth (the extra columns are `None` in plain EuRoC files).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundTruthRow {
    /// Time stamp [ns].
    pub stamp: u64,
    /// Body position [m].
    pub p_w: Vector3<f64>,
    /// Body → world rotation.
    pub q_ws: UnitQuaternion<f64>,
    /// Velocity [m/s].
    pub v_w: Vector3<f64>,
    /// Gyro bias [rad/s].
    pub gyro_bias: Vector3<f64>,
    /// Accelerometer bias [m/s²].
    pub accel_bias: Vector3<f64>,
    /// Body angular velocity and free acceleration, when present.
    pub omega_accel: Option<(Vector3<f64>, Vector3<f64>)>,
}

/// Reads a ground-truth file: EuRoC's 17 columns, or the simulator's 23.
pub fn read_groundtruth_csv(path: &Path) -> Result<Vec<GroundTruthRow>, DatasetError> {
    parse_groundtruth_csv(&read_csv_text(path)?, path)
}

/// Parses the text of a ground-truth file ([`read_groundtruth_csv`]); `path` names it in
/// errors.
pub fn parse_groundtruth_csv(text: &str, path: &Path) -> Result<Vec<GroundTruthRow>, DatasetError> {
    let first = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .map_or(17, |l| l.split(',').count());
    let columns = if first == 23 { 23 } else { 17 };
    let v3 = |v: &[f64], i: usize| Vector3::new(v[i], v[i + 1], v[i + 2]);
    read_rows(text, path, columns)?
        .into_iter()
        .map(|(line, stamp, v)| {
            let q = Quaternion::new(v[3], v[4], v[5], v[6]);
            // A norm far from 1 is a wrong column, not round-off; an infinite one (finite
            // components whose squares overflow) cannot be normalised.
            if q.norm() <= 0.5 || !q.norm().is_finite() {
                return Err(DatasetError::Parse {
                    path: path.to_owned(),
                    line,
                    what: "quaternion far from unit norm".into(),
                });
            }
            Ok(GroundTruthRow {
                stamp,
                p_w: v3(&v, 0),
                q_ws: UnitQuaternion::from_quaternion(q),
                v_w: v3(&v, 7),
                gyro_bias: v3(&v, 10),
                accel_bias: v3(&v, 13),
                omega_accel: (columns == 23).then(|| (v3(&v, 16), v3(&v, 19))),
            })
        })
        .collect()
}
