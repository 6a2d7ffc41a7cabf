//! Dive simulator for sensors-in-the-loop runs: the truth trajectory ([`trajectory`]) and the
//! simulated sensor head ([`head`]) that answers the firmware's bus transactions under QEMU,
//! driven by a dive [`scenario`] (the serde file format `subnav sim` writes and `subnav run` reads).

pub mod calibrate;
pub mod chips;
pub mod dive;
pub mod filter;
pub mod head;
pub mod kitti;
pub mod manufacturing;
pub mod map_loop;
pub mod replay;
pub mod run;
pub mod scenario;
pub mod sea_sky;
pub mod sil;

pub use head::SimHead;
pub use scenario::{CameraPlan, DvlPlan, FaultPlan, FixPlan, Scenario, ScheduledFix};
pub use sea_sky::SeaPlan;
