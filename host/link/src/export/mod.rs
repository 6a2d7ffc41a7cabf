//! Exporting a decoded recording: MCAP for Foxglove ([`mcap`]) and one CSV per message kind
//! ([`csv`]). Both work on a [`Session`](crate::record::session::Session).

pub mod csv;
pub mod mcap;
pub mod schema;
pub mod topics;

/// Which clock stamps exported messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum TimeBase {
    /// Host receive time (absolute, monotonic across sensor-head reboots).
    Host,
    /// Sensor-head time since boot (the firmware's `t_us`; deterministic for QEMU runs).
    /// Messages without their own time (acks, logs) take the latest sensor time seen before them.
    Sensor,
}

/// One event of a decoded recording.
#[derive(Debug, Clone, Copy)]
pub enum Event<'a> {
    Msg(&'a subnav_wire::Uplink),
    Log(&'a crate::defmt_log::LogLine),
    Corrupt(&'a str),
}

/// A session's streams merged in host-time order (each is in order already; at equal times
/// messages before log lines), with their host receive times (µs).
pub fn events(session: &crate::record::session::Session) -> Vec<(u64, Event<'_>)> {
    let mut evs: Vec<(u64, usize, Event)> = Vec::with_capacity(session.messages.len() + session.logs.len() + session.corrupt.len());
    for (i, m) in session.messages.iter().enumerate() {
        evs.push((m.t_host_us, i, Event::Msg(&m.item)));
    }
    for (i, l) in session.logs.iter().enumerate() {
        evs.push((l.t_host_us, i, Event::Log(&l.item)));
    }
    for (i, c) in session.corrupt.iter().enumerate() {
        evs.push((c.t_host_us, i, Event::Corrupt(&c.item)));
    }
    evs.sort_by_key(|(t, i, ev)| (*t, matches!(ev, Event::Log(_)), *i));
    evs.into_iter().map(|(t, _, e)| (t, e)).collect()
}
