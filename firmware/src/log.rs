//! Logging macros: defmt when the `defmt` feature is on (board builds), nothing otherwise
//! (host unit tests), so the application core never depends on a global logger.

#[cfg(feature = "defmt")]
#[macro_export]
macro_rules! info { ($($t:tt)*) => { defmt::info!($($t)*) } }
#[cfg(not(feature = "defmt"))]
#[macro_export]
macro_rules! info {
    ($($t:tt)*) => {{}};
}

#[cfg(feature = "defmt")]
#[macro_export]
macro_rules! warn { ($($t:tt)*) => { defmt::warn!($($t)*) } }
#[cfg(not(feature = "defmt"))]
#[macro_export]
macro_rules! warn {
    ($($t:tt)*) => {{}};
}
