//! Host side of the navigation filter: the same `subnav_core::nav` code as the firmware, fed
//! from a sensor log ([`replay`]) or a simulated dive ([`sim`]), and the AUKF-vs-UKF Monte Carlo
//! ([`montecarlo`]).

pub mod montecarlo;
pub mod replay;
pub mod sim;

use nalgebra::{UnitQuaternion, Vector3};
use subnav_core::nav::{NavConfig, NavError, NavFilter15, NavInit};

use sim::Event;

/// Counts of what happened to the events of a log.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct EventCounts {
    pub imu: u64,
    pub updates_accepted: u64,
    pub updates_gated: u64,
    pub rejected_nonfinite: u64,
    pub rejected_time: u64,
    pub filter_errors: u64,
}

/// Feed one event to the filter and count the outcome. Errors are counted, never fatal: a bad
/// sample loses nothing else.
pub fn apply(nav: &mut NavFilter15, ev: &Event, counts: &mut EventCounts) {
    let r = match *ev {
        Event::Imu(s) => {
            counts.imu += 1;
            nav.propagate(&s).map(|_| None)
        }
        Event::Heading { t_us, heading_rad, sigma_rad } => nav.update_heading(t_us, heading_rad, sigma_rad).map(Some),
        Event::Depth { t_us, depth_m, sigma_m } => nav.update_depth(t_us, depth_m, sigma_m).map(Some),
        Event::Dvl { t_us, vel_frd_mps, sigma_mps } => nav.update_body_velocity(t_us, vel_frd_mps, sigma_mps).map(Some),
        Event::Fix { t_us, pos_ned_m, cov_ned_m2 } => nav.update_position(t_us, pos_ned_m, cov_ned_m2).map(Some),
    };
    match r {
        Ok(None) => {}
        Ok(Some(rep)) if rep.accepted => counts.updates_accepted += 1,
        Ok(Some(_)) => counts.updates_gated += 1,
        Err(NavError::NonFinite) => counts.rejected_nonfinite += 1,
        Err(NavError::BadTime) => counts.rejected_time += 1,
        Err(_) => counts.filter_errors += 1,
    }
}

/// A filter started at a known pose (level, `yaw_rad`), `t_us`.
pub fn start(cfg: NavConfig, t_us: u64, pos_ned_m: [f32; 3], vel_ned_mps: [f32; 3], yaw_rad: f32) -> anyhow::Result<NavFilter15> {
    let init = NavInit {
        t_us,
        att_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
        vel_ned_mps: Vector3::from(vel_ned_mps),
        pos_ned_m: Vector3::from(pos_ned_m),
    };
    NavFilter15::new(cfg, init).map_err(|e| anyhow::anyhow!("cannot start the navigation filter: {e}"))
}
