//! Host side of the polarization compass: the heading Monte Carlo ([`montecarlo`]: flat
//! surface, or a moving sea under a sky), the operating envelope over depth, wind, turbidity
//! and sky ([`envelope`]), sun-based geolocation ([`geoloc`]) and the compass in a light
//! field from outside ([`reference`]: an OSOAA or measured downwelling Stokes field). The field and sensor
//! simulator is `subnav_base::sky` (with the sea of `subnav_base::sea`); the compass itself is
//! `subnav_core::compass`, the same code the firmware runs. [`raw_csv`]: the raw-counts CSV
//! format; [`plot`]: the envelope's figure.

pub mod departure;
pub mod envelope;
pub mod geoloc;
pub mod montecarlo;
pub mod plot;
pub mod raw_csv;
pub mod reference;
