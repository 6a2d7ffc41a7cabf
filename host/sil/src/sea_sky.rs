//! The sea and the sky over a simulated dive: the wind (a moving sea, `subnav_base::sea`) and
//! the sky kind (`subnav_base::sky::SkyKind`), each with an optional change mid-dive, and the
//! polarization units' photodiode source for the ADS1115 models under them.
//!
//! Every plan uses `sky::SeaField`: the sunbeam (and the sky's light) refracted through the sea
//! along each unit's line of sight, with the real field's departure from single scattering
//! (OSOAA's table) when the water has it (`Water::polarization_table`, the default); the
//! default plan (calm, clear, no change) is a flat sea under a clear sky. The four ADCs read
//! their units within a few milliseconds of each other; the Stokes of all units are computed
//! once per 5-ms slot and shared (the sea moves little in 5 ms; each ADC still draws its own
//! photodiode noise at its own conversion).

use std::sync::{Arc, Mutex};

use nalgebra::{Rotation3, Vector3};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use subnav_base::sea::{Sea, SeaConfig};
use subnav_base::sky::{self as polar, SeaField, SensorErrors, SkyKind, Water};
use subnav_base::trajectory::Trajectory;
use subnav_core::compass::{CHANNELS, ChannelCal, UnitModel};

/// The sea state and sky of a dive.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SeaPlan {
    /// Wind speed at 10 m (m/s); 0 is a flat sea.
    pub wind_mps: f64,
    /// Direction the wind blows toward (rad from north, clockwise).
    #[serde(default)]
    pub wind_toward_rad: f64,
    pub sky: SkyKind,
    /// From this time on (s since boot) the wind is this (m/s).
    #[serde(default)]
    pub wind_change: Option<(f64, f64)>,
    /// From this time on (s since boot) the sky is this.
    #[serde(default)]
    pub sky_change: Option<(f64, SkyKind)>,
}

impl SeaPlan {
    /// Calm and clear with no change.
    pub fn is_default_flat(&self) -> bool {
        self.wind_mps == 0.0 && self.sky == SkyKind::Clear && self.wind_change.is_none() && self.sky_change.is_none()
    }

    pub fn wind_at(&self, t_s: f64) -> f64 {
        match self.wind_change {
            Some((tc, w)) if t_s >= tc => w,
            _ => self.wind_mps,
        }
    }

    pub fn sky_at(&self, t_s: f64) -> SkyKind {
        match self.sky_change {
            Some((tc, k)) if t_s >= tc => k,
            _ => self.sky,
        }
    }

    /// Range checks (the error names the field).
    pub fn validate(&self) -> anyhow::Result<()> {
        let wind = |what: &str, w: f64| {
            anyhow::ensure!((0.0..=30.0).contains(&w), "{what} must be in [0, 30] m/s, got {w}");
            Ok(())
        };
        let time = |what: &str, t: f64| {
            anyhow::ensure!(t.is_finite() && t >= 0.0, "{what}'s time must be >= 0 s, got {t}");
            Ok(())
        };
        wind("sea.wind_mps", self.wind_mps)?;
        anyhow::ensure!(self.wind_toward_rad.is_finite(), "sea.wind_toward_rad must be finite");
        if let Some((t, w)) = self.wind_change {
            time("sea.wind_change", t)?;
            wind("sea.wind_change", w)?;
        }
        if let Some((t, _)) = self.sky_change {
            time("sea.sky_change", t)?;
        }
        Ok(())
    }
}

/// Stokes of all units for one 5-ms slot.
type Slot = Option<(u64, Vec<[f64; 3]>, f64)>;

/// The photodiode source of every unit under the plan's sea and sky (shared by the ADCs).
pub struct PolarizationSource {
    plan: SeaPlan,
    seas: [Sea; 2],
    water: Water,
    units: Vec<UnitModel>,
    traj: Arc<Trajectory>,
    sun_ned: Box<dyn Fn(f64) -> Vector3<f64> + Send + Sync>,
    cloud_seed: u64,
    slot: Mutex<Slot>,
}

const SLOT_US: u64 = 5_000;

impl PolarizationSource {
    pub fn new(
        plan: SeaPlan,
        seed: u64,
        water: Water,
        units: Vec<UnitModel>,
        traj: Arc<Trajectory>,
        sun_ned: Box<dyn Fn(f64) -> Vector3<f64> + Send + Sync>,
    ) -> Self {
        let sea = |w: f64| Sea::new(SeaConfig { wind_toward_rad: plan.wind_toward_rad, ..SeaConfig::wind(w) }, seed ^ 0x7777);
        let seas = [sea(plan.wind_mps), sea(plan.wind_change.map_or(plan.wind_mps, |c| c.1))];
        PolarizationSource { plan, seas, water, units, traj, sun_ned, cloud_seed: seed ^ 0x8888, slot: Mutex::new(None) }
    }

    /// Stokes of every unit and the light level at `t_us` (shared within a slot).
    fn stokes(&self, t_us: u64) -> (Vec<[f64; 3]>, f64) {
        let key = t_us / SLOT_US;
        if let Ok(g) = self.slot.lock() {
            if let Some((_, s, l)) = g.as_ref().filter(|(k, _, _)| *k == key) {
                return (s.clone(), *l);
            }
        }
        let t = t_us as f64 * 1e-6;
        let truth = self.traj.at(t);
        let r_nb: Rotation3<f64> = truth.att_nb.to_rotation_matrix();
        let depth = truth.pos_ned_m.z.max(0.0);
        let sea = if self.plan.wind_change.is_some_and(|(tc, _)| t >= tc) { &self.seas[1] } else { &self.seas[0] };
        let light = self.plan.sky_at(t).light(t, self.cloud_seed);
        let pos = (truth.pos_ned_m.x, truth.pos_ned_m.y);
        let field = SeaField::new((self.sun_ned)(t), light, sea, self.water, depth, pos, t);
        let (s, level) = (polar::unit_stokes(&field, &r_nb, &self.units), polar::LightField::light_level(&field));
        if let Ok(mut g) = self.slot.lock() {
            *g = Some((key, s.clone(), level));
        }
        (s, level)
    }

    /// Counts of unit `u` at `t_us` (its own noise from `rng`).
    pub fn unit_counts(
        &self,
        u: usize,
        t_us: u64,
        true_cal: &[[ChannelCal; CHANNELS]],
        err: &SensorErrors,
        rng: &mut ChaCha8Rng,
    ) -> Option<[i16; 4]> {
        let (s, level) = self.stokes(t_us);
        let all = polar::counts_from_stokes(&s, level, true_cal, err, rng);
        all.get(u).copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_changes_and_validation() {
        let p =
            SeaPlan { wind_mps: 2.0, wind_change: Some((100.0, 10.0)), sky_change: Some((50.0, SkyKind::Overcast)), ..SeaPlan::default() };
        assert_eq!((p.wind_at(99.0), p.wind_at(100.0)), (2.0, 10.0));
        assert_eq!((p.sky_at(49.0), p.sky_at(50.0)), (SkyKind::Clear, SkyKind::Overcast));
        assert!(p.validate().is_ok());
        assert!(!p.is_default_flat() && SeaPlan::default().is_default_flat());
        for bad in [
            SeaPlan { wind_mps: -1.0, ..p },
            SeaPlan { wind_mps: 40.0, ..p },
            SeaPlan { wind_change: Some((f64::NAN, 3.0)), ..p },
            SeaPlan { wind_change: Some((3.0, 31.0)), ..p },
            SeaPlan { sky_change: Some((-1.0, SkyKind::Clear)), ..p },
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("sea."), "{e}");
        }
        // Older scenario files (no sea) and the JSON names.
        let j = serde_json::to_string(&p).unwrap();
        assert!(j.contains("\"overcast\""), "{j}");
        let back: SeaPlan = serde_json::from_str(&j).unwrap();
        assert_eq!(back, p);
    }
}
