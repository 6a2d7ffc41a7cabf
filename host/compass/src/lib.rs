//! Host side of the polarization compass (issue 3): the physically based underwater
//! polarization-field and sensor simulator ([`sim`]), the heading Monte Carlo ([`montecarlo`])
//! and sun-based geolocation ([`geoloc`]). The compass itself is `subnav_core::compass`, the
//! same code the firmware runs.

pub mod geoloc;
pub mod montecarlo;
