//! Logging shim: forwards to `defmt` when the `defmt` feature is on, compiles to nothing otherwise
//! (the arguments are still type-checked, so a log line cannot rot while the feature is off).

#[cfg(feature = "defmt")]
#[allow(unused_macros)]
macro_rules! log_debug { ($($t:tt)*) => { defmt::debug!($($t)*) }; }
#[cfg(feature = "defmt")]
#[allow(unused_macros)]
macro_rules! log_info { ($($t:tt)*) => { defmt::info!($($t)*) }; }
#[cfg(feature = "defmt")]
#[allow(unused_macros)]
macro_rules! log_warn { ($($t:tt)*) => { defmt::warn!($($t)*) }; }

#[cfg(not(feature = "defmt"))]
#[allow(unused_macros)]
macro_rules! log_debug { ($($t:tt)*) => { { if false { let _ = ($crate::log::Ignore, $($t)*); } } }; }
#[cfg(not(feature = "defmt"))]
#[allow(unused_macros)]
macro_rules! log_info { ($($t:tt)*) => { { if false { let _ = ($crate::log::Ignore, $($t)*); } } }; }
#[cfg(not(feature = "defmt"))]
#[allow(unused_macros)]
macro_rules! log_warn { ($($t:tt)*) => { { if false { let _ = ($crate::log::Ignore, $($t)*); } } }; }

/// Placeholder that lets the disabled macros accept any argument list.
#[doc(hidden)]
pub struct Ignore;

#[allow(unused_imports)]
pub(crate) use {log_debug, log_info, log_warn};
