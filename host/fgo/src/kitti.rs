//! Reader of the KITTI inertial/GPS example data GTSAM ships in its Python wheel
//! (`gtsam/Data/KittiEquivBiasedImu.txt`, `KittiEquivBiasedImu_metadata.txt`,
//! `KittiGps_converted.txt`): a car's 100 Hz IMU (body x forward, y left, z up: the FLU body of
//! [`crate::state`]) and its 1 Hz positions in a local ENU frame, about 470 s.
//!
//! The data is licensed CC BY-NC-SA 3.0: it is read at run time from the installed wheel
//! ([`gtsam_data_dir`]), never copied into this repository.
//!
//! Formats (one header line each, then one record a line):
//! - metadata: `BodyPtx BodyPty BodyPtz BodyPrx BodyPry BodyPrz AccelerometerSigma GyroscopeSigma
//!   IntegrationSigma AccelerometerBiasSigma GyroscopeBiasSigma AverageDeltaT` (space-separated);
//! - IMU: `Time dt accelX accelY accelZ omegaX omegaY omegaZ` (space-separated, s, m/s^2, rad/s);
//!   `dt` is not used (the first row's is not an interval): intervals come from the time stamps;
//! - GPS: `Time,X,Y,Z` (comma-separated, s and m ENU).
//!
//! A malformed row (wrong field count, a field that is not a finite number, a time that does not
//! increase) is an error naming the file and its line number (1-based, header = line 1).
//!
//! Written here: the files are three small text tables; a CSV crate would still leave the
//! per-field checks and the line-numbered errors to write.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::FgoError;
use super::log::ImuSample;

pub const IMU_FILE: &str = "KittiEquivBiasedImu.txt";
pub const METADATA_FILE: &str = "KittiEquivBiasedImu_metadata.txt";
pub const GPS_FILE: &str = "KittiGps_converted.txt";

/// The sensor metadata (noise sigmas as GTSAM's example reads them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metadata {
    /// IMU-in-body translation (m) and rotation (rad, roll/pitch/yaw).
    pub body_t_imu_m: [f64; 3],
    pub body_r_imu_rad: [f64; 3],
    /// Accelerometer white noise, (m/s^2)/sqrt(Hz).
    pub acc_sigma: f64,
    /// Gyro white noise, (rad/s)/sqrt(Hz).
    pub gyro_sigma: f64,
    pub integration_sigma: f64,
    /// Bias random-walk sigmas per IMU sample (GTSAM's example multiplies them by the square
    /// root of the sample count of an interval).
    pub acc_bias_sigma: f64,
    pub gyro_bias_sigma: f64,
    pub average_dt_s: f64,
}

/// One position fix, local ENU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsFix {
    pub t_s: f64,
    pub pos_enu_m: Vector3<f64>,
}

#[derive(Debug, Clone)]
pub struct KittiData {
    pub meta: Metadata,
    pub imu: Vec<ImuSample>,
    pub gps: Vec<GpsFix>,
}

fn err(file: &str, line: usize, what: impl std::fmt::Display) -> FgoError {
    FgoError::Input(format!("{file}:{line}: {what}"))
}

/// Parse `n` finite numbers separated by `sep` (None: any whitespace).
fn numbers(file: &str, line_no: usize, line: &str, sep: Option<char>, n: usize) -> Result<Vec<f64>, FgoError> {
    let fields: Vec<&str> = match sep {
        Some(c) => line.split(c).map(str::trim).collect(),
        None => line.split_whitespace().collect(),
    };
    if fields.len() != n {
        return Err(err(file, line_no, format!("expected {n} fields, found {} in {line:?}", fields.len())));
    }
    fields
        .iter()
        .enumerate()
        .map(|(k, f)| match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(err(file, line_no, format!("field {} is not a finite number: {f:?}", k + 1))),
        })
        .collect()
}

/// Data lines after the header (skipping blank lines), with 1-based line numbers.
fn data_lines<'a>(file: &str, text: &'a str, header_first: &str) -> Result<Vec<(usize, &'a str)>, FgoError> {
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim_start().starts_with(header_first) => {}
        Some((_, h)) => return Err(err(file, 1, format!("expected a header starting with {header_first:?}, found {h:?}"))),
        None => return Err(err(file, 1, "empty file")),
    }
    Ok(lines.filter(|(_, l)| !l.trim().is_empty()).map(|(i, l)| (i + 1, l)).collect())
}

pub fn parse_metadata(file: &str, text: &str) -> Result<Metadata, FgoError> {
    let lines = data_lines(file, text, "BodyPtx")?;
    let Some((n, line)) = lines.first() else { return Err(err(file, 2, "no metadata row")) };
    if let Some((n2, _)) = lines.get(1) {
        return Err(err(file, *n2, "more than one metadata row"));
    }
    let v = numbers(file, *n, line, None, 12)?;
    if v[6..11].iter().any(|s| *s < 0.0) || !(v[11] > 0.0) {
        return Err(err(file, *n, "noise sigmas must be >= 0 and AverageDeltaT > 0"));
    }
    Ok(Metadata {
        body_t_imu_m: [v[0], v[1], v[2]],
        body_r_imu_rad: [v[3], v[4], v[5]],
        acc_sigma: v[6],
        gyro_sigma: v[7],
        integration_sigma: v[8],
        acc_bias_sigma: v[9],
        gyro_bias_sigma: v[10],
        average_dt_s: v[11],
    })
}

pub fn parse_imu(file: &str, text: &str) -> Result<Vec<ImuSample>, FgoError> {
    let mut out: Vec<ImuSample> = Vec::new();
    for (n, line) in data_lines(file, text, "Time")? {
        let v = numbers(file, n, line, None, 8)?;
        if let Some(last) = out.last() {
            if !(v[0] > last.t_s) {
                return Err(err(file, n, format!("time {} does not increase (previous {})", v[0], last.t_s)));
            }
        }
        out.push(ImuSample { t_s: v[0], acc_mps2: Vector3::new(v[2], v[3], v[4]), gyro_radps: Vector3::new(v[5], v[6], v[7]) });
    }
    if out.len() < 2 {
        return Err(err(file, 1, "fewer than 2 IMU rows"));
    }
    Ok(out)
}

pub fn parse_gps(file: &str, text: &str) -> Result<Vec<GpsFix>, FgoError> {
    let mut out: Vec<GpsFix> = Vec::new();
    for (n, line) in data_lines(file, text, "Time")? {
        let v = numbers(file, n, line, Some(','), 4)?;
        if let Some(last) = out.last() {
            if !(v[0] > last.t_s) {
                return Err(err(file, n, format!("time {} does not increase (previous {})", v[0], last.t_s)));
            }
        }
        out.push(GpsFix { t_s: v[0], pos_enu_m: Vector3::new(v[1], v[2], v[3]) });
    }
    if out.len() < 3 {
        return Err(err(file, 1, "fewer than 3 GPS rows"));
    }
    Ok(out)
}

fn read(dir: &Path, name: &str) -> Result<(String, String), FgoError> {
    let path = dir.join(name);
    let shown = path.display().to_string();
    let text = std::fs::read_to_string(&path).map_err(|e| FgoError::Input(format!("{shown}: {e}")))?;
    Ok((shown, text))
}

/// Read the three files from `dir` (the wheel's `gtsam/Data`).
pub fn load_dir(dir: &Path) -> Result<KittiData, FgoError> {
    let (f, t) = read(dir, METADATA_FILE)?;
    let meta = parse_metadata(&f, &t)?;
    if meta.body_t_imu_m.iter().chain(meta.body_r_imu_rad.iter()).any(|x| *x != 0.0) {
        return Err(FgoError::Input(format!("{f}: only an IMU frame equal to the body frame is supported (BodyPt/BodyPr = 0)")));
    }
    let (f, t) = read(dir, IMU_FILE)?;
    let imu = parse_imu(&f, &t)?;
    let (f, t) = read(dir, GPS_FILE)?;
    let gps = parse_gps(&f, &t)?;
    Ok(KittiData { meta, imu, gps })
}

/// `gtsam/Data` of the GTSAM wheel installed for `python` (asks that interpreter).
pub fn gtsam_data_dir(python: &Path) -> Result<PathBuf, FgoError> {
    let out = std::process::Command::new(python)
        .args(["-c", "import gtsam, os; print(os.path.join(os.path.dirname(gtsam.__file__), 'Data'))"])
        .output()
        .map_err(|e| FgoError::Input(format!("cannot run {}: {e}", python.display())))?;
    if !out.status.success() {
        return Err(FgoError::Input(format!("{} cannot import gtsam: {}", python.display(), String::from_utf8_lossy(&out.stderr))));
    }
    let dir = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
    if !dir.join(IMU_FILE).is_file() {
        return Err(FgoError::Input(format!("{} has no {IMU_FILE}", dir.display())));
    }
    Ok(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    const IMU: &str = "Time dt accelX accelY accelZ omegaX omegaY omegaZ\n\
        10.0 10.0 0.1 0.2 9.8 0.001 0.002 0.003\n\
        10.01 0.01 0.1 0.2 9.8 0.001 0.002 0.003\n";

    #[test]
    fn good_files_parse() {
        let imu = parse_imu("imu.txt", IMU).unwrap();
        assert_eq!(imu.len(), 2);
        assert_eq!(imu[1].gyro_radps, Vector3::new(0.001, 0.002, 0.003));
        let gps = parse_gps("gps.txt", "Time,X,Y,Z\n1.0,1,2,3\n\n2.0,4,5,6\n3.5,7,8,9\n").unwrap();
        assert_eq!(gps[2].pos_enu_m, Vector3::new(7.0, 8.0, 9.0));
        let m = parse_metadata("m.txt", "BodyPtx BodyPty\n0 0 0 0 0 0 0.01 0.000175 0 0.000167 2.91e-006 0.0100395199348279\n").unwrap();
        assert_eq!(m.gyro_bias_sigma, 2.91e-6);
    }

    #[test]
    fn malformed_rows_name_file_and_line() {
        let cases: [(&str, Result<(), FgoError>, &str); 8] = [
            ("missing field", parse_imu("imu.txt", &format!("{IMU}10.02 0.01 0.1 0.2 9.8 0.001 0.002\n")).map(|_| ()), "imu.txt:4:"),
            ("not a number", parse_imu("imu.txt", &format!("{IMU}10.02 0.01 0.1 x 9.8 0.001 0.002 0.003\n")).map(|_| ()), "imu.txt:4:"),
            ("nan", parse_imu("imu.txt", &format!("{IMU}10.02 0.01 0.1 NaN 9.8 0.001 0.002 0.003\n")).map(|_| ()), "imu.txt:4:"),
            ("time back", parse_imu("imu.txt", &format!("{IMU}10.005 0.01 0.1 0.2 9.8 0.001 0.002 0.003\n")).map(|_| ()), "imu.txt:4:"),
            ("gps fields", parse_gps("gps.txt", "Time,X,Y,Z\n1,2,3,4\n2,3,4\n3,1,1,1\n").map(|_| ()), "gps.txt:3:"),
            ("gps repeat", parse_gps("gps.txt", "Time,X,Y,Z\n1,2,3,4\n2,3,4,5\n2,1,1,1\n").map(|_| ()), "gps.txt:4:"),
            ("no header", parse_gps("gps.txt", "1,2,3,4\n2,3,4,5\n").map(|_| ()), "gps.txt:1:"),
            ("meta count", parse_metadata("m.txt", "BodyPtx\n0 0 0 0 0 0 0.01 0.1 0 0.1 0.1\n").map(|_| ()), "m.txt:2:"),
        ];
        for (name, r, prefix) in cases {
            match r {
                Err(FgoError::Input(msg)) => assert!(msg.starts_with(prefix), "[{name}] {msg}"),
                other => panic!("[{name}] expected an input error, got {other:?}"),
            }
        }
    }

    #[test]
    fn missing_directory_is_an_error() {
        let e = load_dir(Path::new("/nonexistent-kitti")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent-kitti/KittiEquivBiasedImu_metadata.txt"), "{e}");
    }
}
