//! The telemetry link on the host side: decoding the uplink byte stream ([`uplink`]), the defmt
//! log stream ([`defmt_log`]), opening sources (file, TCP, serial: [`source`]) and running the
//! firmware in QEMU ([`qemu`]); output files written atomically ([`output`]); the one scoring of
//! the solutions against a simulated dive's truth ([`score`]).

pub mod defmt_log;
pub mod export;
pub mod live_view;
pub mod output;
pub mod qemu;
pub mod record;
pub mod score;
pub mod source;
pub mod uplink;
pub mod ws_subprotocol;

pub use uplink::{LinkEvent, LinkStats, UplinkDecoder};
