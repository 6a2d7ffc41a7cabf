//! Dive simulator for sensors-in-the-loop runs: truth trajectory ([`trajectory`]), and (with the
//! chip models) the simulated sensor head that answers the firmware's bus transactions.

pub mod trajectory;
