//! The companion-computer bridge between the sensor head and an autopilot (ArduSub, PX4) over
//! MAVLink 2, on the `mavlink` crate's ardupilotmega dialect: the role the BlueOS Water Linked DVL
//! extension plays for a bare DVL, for the head's whole solution.
//!
//! - [`mapping`]: the head's solution as `VISION_POSITION_ESTIMATE`, `GLOBAL_VISION_POSITION_ESTIMATE`,
//!   `VISION_SPEED_ESTIMATE` and `ODOMETRY` (frames, units, covariances; pure, unit-tested);
//! - [`clock`]: head -> companion -> autopilot time (`TIMESYNC`), so every stamp is the
//!   measurement's time of validity, in our clock (which the autopilot maps with its own
//!   TIMESYNC, as PX4 does) or, on request, in the autopilot's ([`StampClock`]);
//! - [`scan`]: incoming frames with every rejected byte counted;
//! - [`endpoint`]: `udpout:`, `udpin:`, `tcp:`, `serial:`;
//! - [`bridge`]: the running bridge (send, receive, GPS and origin back, counters).

pub mod bridge;
pub mod clock;
pub mod endpoint;
pub mod mapping;
pub mod scan;

pub use bridge::{Bridge, BridgeConfig, BridgeSummary, GpsInput};
pub use clock::HeadClock;
pub use endpoint::{Endpoint, parse_endpoint};
pub use mapping::{Geodetic, OdometryFrame, StampClock};
