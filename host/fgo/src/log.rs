//! Sensor log read by `subnav fgo`: JSON lines, one record per line, tagged by `"type"`:
//! - `{"type":"config", ...}` first: [`LogConfig`] (IMU noise, DVL mounting, lever arms, prior),
//! - `{"type":"imu","t_s":..,"acc_mps2":[..],"gyro_radps":[..]}` body FLU, held on `[t, t_next)`,
//! - `{"type":"dvl","t_s":..,"vel_dvl_mps":[..],"sigma_mps":..}` in the DVL instrument frame,
//! - `{"type":"usbl","t_arrival_s":..,"t_valid_s":..,"pos_enu_m":[..],"sigma_h_m":..,"sigma_v_m":..}`.
//!
//! All in ENU / FLU (see [`super::state`] for the NED conversion). Parse errors name the line.

use std::io::{BufRead, Write};

use serde::{Deserialize, Serialize};

use super::FgoError;
use super::preintegration::ImuParams;

/// An IMU record: the host simulators' sample (serialized `acc_mps2` and `gyro_radps` as arrays).
pub use subnav_base::imu::ImuSample;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DvlObs {
    pub t_s: f64,
    pub vel_dvl_mps: [f64; 3],
    pub sigma_mps: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct UsblObs {
    pub t_arrival_s: f64,
    pub t_valid_s: f64,
    pub pos_enu_m: [f64; 3],
    pub sigma_h_m: f64,
    pub sigma_v_m: f64,
}

/// Initial state prior: mean and sigmas.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PriorConfig {
    pub t_s: f64,
    /// Rotation vector of body(FLU)->ENU, rad.
    pub rotvec_enu_flu: [f64; 3],
    pub pos_enu_m: [f64; 3],
    pub vel_enu_mps: [f64; 3],
    pub bias_acc_mps2: [f64; 3],
    pub bias_gyro_radps: [f64; 3],
    /// Sigmas: attitude rad, position m, velocity m/s, acc bias, gyro bias.
    pub sigmas: [f64; 5],
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LogConfig {
    pub imu: ImuParams,
    /// DVL frame -> body rotation vector, rad.
    pub dvl_rotvec_body: [f64; 3],
    pub dvl_lever_body_m: [f64; 3],
    pub usbl_lever_body_m: [f64; 3],
    pub prior: PriorConfig,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Record {
    Config(LogConfig),
    Imu(ImuSample),
    Dvl(DvlObs),
    Usbl(UsblObs),
}

impl Record {
    /// One JSON line. The `"type"` tag is read first and the record decoded from the parsed
    /// value, not through serde's internally tagged enum: that path buffers numbers, and with
    /// serde_json's `arbitrary_precision` (enabled in the CLI's build by defmt-decoder) a
    /// buffered number no longer reads as an f64.
    pub fn parse(line: &str) -> Result<Self, serde_json::Error> {
        use serde::de::Error as _;
        let mut v: serde_json::Value = serde_json::from_str(line)?;
        let tag = v
            .as_object_mut()
            .and_then(|o| o.remove("type"))
            .ok_or_else(|| serde_json::Error::custom("missing \"type\" (config, imu, dvl or usbl)"))?;
        match tag.as_str() {
            Some("config") => serde_json::from_value(v).map(Record::Config),
            Some("imu") => serde_json::from_value(v).map(Record::Imu),
            Some("dvl") => serde_json::from_value(v).map(Record::Dvl),
            Some("usbl") => serde_json::from_value(v).map(Record::Usbl),
            _ => Err(serde_json::Error::custom(format!("unknown record type {tag} (config, imu, dvl or usbl)"))),
        }
    }
}

/// A whole log, each stream sorted by time.
#[derive(Debug, Clone)]
pub struct SensorLog {
    pub config: LogConfig,
    pub imu: Vec<ImuSample>,
    pub dvl: Vec<DvlObs>,
    pub usbl: Vec<UsblObs>,
}

fn finite(xs: &[f64]) -> bool {
    xs.iter().all(|x| x.is_finite())
}

impl SensorLog {
    /// Check what the estimator relies on; the error says what is wrong.
    pub fn validate(&self) -> Result<(), FgoError> {
        self.config.imu.validate()?;
        let p = &self.config.prior;
        if !finite(&p.rotvec_enu_flu)
            || !finite(&p.pos_enu_m)
            || !finite(&p.vel_enu_mps)
            || !p.sigmas.iter().all(|s| s.is_finite() && *s > 0.0)
        {
            return Err(FgoError::Input("config.prior must be finite with sigmas > 0".into()));
        }
        if self.imu.len() < 2 {
            return Err(FgoError::Input("log has fewer than 2 IMU samples".into()));
        }
        for (i, w) in self.imu.windows(2).enumerate() {
            if !(w[1].t_s > w[0].t_s) {
                return Err(FgoError::Input(format!("IMU time not increasing at sample {} (t={} then {})", i + 1, w[0].t_s, w[1].t_s)));
            }
        }
        for (i, s) in self.imu.iter().enumerate() {
            if !s.t_s.is_finite() || !finite(s.acc_mps2.as_slice()) || !finite(s.gyro_radps.as_slice()) {
                return Err(FgoError::Input(format!("IMU sample {i} has NaN/inf")));
            }
        }
        for (i, d) in self.dvl.iter().enumerate() {
            if !d.t_s.is_finite() || !finite(&d.vel_dvl_mps) || !(d.sigma_mps > 0.0 && d.sigma_mps.is_finite()) {
                return Err(FgoError::Input(format!("DVL observation {i} has NaN/inf or sigma <= 0")));
            }
        }
        for (i, u) in self.usbl.iter().enumerate() {
            let ok = u.t_arrival_s.is_finite()
                && u.t_valid_s.is_finite()
                && u.t_valid_s <= u.t_arrival_s
                && finite(&u.pos_enu_m)
                && u.sigma_h_m > 0.0
                && u.sigma_v_m > 0.0
                && u.sigma_h_m.is_finite()
                && u.sigma_v_m.is_finite();
            if !ok {
                return Err(FgoError::Input(format!("USBL fix {i} invalid (NaN/inf, sigma <= 0, or valid time after arrival)")));
            }
        }
        Ok(())
    }

    pub fn read<R: BufRead>(reader: R) -> Result<Self, FgoError> {
        let mut config = None;
        let (mut imu, mut dvl, mut usbl) = (Vec::new(), Vec::new(), Vec::new());
        for (n, line) in reader.lines().enumerate() {
            let line = line.map_err(|e| FgoError::Input(format!("line {}: {e}", n + 1)))?;
            if line.trim().is_empty() {
                continue;
            }
            let rec = Record::parse(&line).map_err(|e| FgoError::Input(format!("line {}: {e}", n + 1)))?;
            match rec {
                Record::Config(c) => {
                    if config.replace(c).is_some() {
                        return Err(FgoError::Input(format!("line {}: second config record", n + 1)));
                    }
                }
                Record::Imu(s) => imu.push(s),
                Record::Dvl(d) => dvl.push(d),
                Record::Usbl(u) => usbl.push(u),
            }
        }
        let config = config.ok_or_else(|| FgoError::Input("log has no config record".into()))?;
        dvl.sort_by(|a: &DvlObs, b| a.t_s.total_cmp(&b.t_s));
        usbl.sort_by(|a: &UsblObs, b| a.t_arrival_s.total_cmp(&b.t_arrival_s));
        let log = Self { config, imu, dvl, usbl };
        log.validate()?;
        Ok(log)
    }

    pub fn write<W: Write>(&self, mut w: W) -> std::io::Result<()> {
        let mut line = |r: &Record| -> std::io::Result<()> {
            serde_json::to_writer(&mut w, r)?;
            w.write_all(b"\n")
        };
        line(&Record::Config(self.config))?;
        for s in &self.imu {
            line(&Record::Imu(*s))?;
        }
        for d in &self.dvl {
            line(&Record::Dvl(*d))?;
        }
        for u in &self.usbl {
            line(&Record::Usbl(*u))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_logs_give_line_numbered_errors() {
        let e = SensorLog::read("{\"type\":\"imu\",\"t_s\":0}\n".as_bytes()).unwrap_err();
        assert!(e.to_string().contains("line 1"), "{e}");
        let e = SensorLog::read("".as_bytes()).unwrap_err();
        assert!(e.to_string().contains("no config"), "{e}");
        let e = SensorLog::read("not json\n".as_bytes()).unwrap_err();
        assert!(e.to_string().contains("line 1"), "{e}");
    }
}
