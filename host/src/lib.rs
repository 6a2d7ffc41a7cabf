//! subnav host library: the telemetry link (decode, QEMU runs) and the host-side methods.
//! The `subnav` binary (`src/main.rs`) is a thin clap front end over [`cli`].

pub mod bathy;
pub mod chips;
pub mod cli;
pub mod compass;
pub mod export;
pub mod fgo;
pub mod filter;
pub mod ice;
pub mod link;
pub mod lmnn;
pub mod polar_image;
pub mod record;
pub mod report;
pub mod sim;
pub mod topo;
