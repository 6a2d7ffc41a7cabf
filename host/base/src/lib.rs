//! subnav-base: what the host's methods and simulators share.
//!
//! - [`trajectory`]: the sensor-head dive's truth trajectory (descent and lawnmower survey).
//! - [`imu`]: IMU synthesis shared by every simulator: specific force and body rate from the
//!   truth, the lawnmower turn schedule, the IMU error model from a grade, the host `ImuSample`.
//! - [`sky`]: the polarized sky and water seen by the compass units (sensor grades from
//!   `subnav_core::head`).
//! - [`osoaa`]: the real field's departure from single scattering, from a table of OSOAA
//!   radiative-transfer fields (used by [`sky::SeaField`]).
//! - [`sea`]: the moving wind-driven sea surface (Elfouhaily spectrum, Cox-Munk slopes).
//! - [`so3`]: SO(3) helpers in f64 (exponential, logarithm, hat, Jacobians).
//! - [`chi2`]: the chi-square CDF and quantile for the gates.
//! - `plot` (feature `plot`): the figures' font lookup for the crates that draw with plotters.
//! - [`limits`]: size limits on what a file can make the host allocate (images, tables).
//! - [`wrap_pi`], [`wrap_deg`]: the one angle wrap in radians and in degrees (re-exported from
//!   `subnav_core::ukf`).
pub mod chi2;
pub mod imu;
pub mod limits;
pub mod osoaa;
#[cfg(feature = "plot")]
pub mod plot;
pub mod sea;
pub mod sky;
pub mod so3;
pub mod trajectory;

pub use subnav_core::ukf::{wrap_deg, wrap_pi};

#[cfg(test)]
mod tests {
    /// `wrap_deg` (no_std: `%` and a sign fix) is `(x + 180).rem_euclid(360) - 180`, the
    /// formula of the three copies it replaced, to the bit.
    #[test]
    fn wrap_deg_is_rem_euclid_to_the_bit() {
        let mut xs = vec![0.0, -0.0, 180.0, -180.0, 179.999, -179.999, 360.0, -360.0, 540.0, -540.0, 1e9, -1e9, 1e-300, -1e-300];
        xs.extend((-2000..=2000).map(|k| k as f64 * 0.7317));
        for x in xs {
            let want = (x + 180.0f64).rem_euclid(360.0) - 180.0;
            assert_eq!(super::wrap_deg(x).to_bits(), want.to_bits(), "{x}");
        }
        assert!(super::wrap_deg(f64::NAN).is_nan());
    }
}
