//! The crate's error type. Every fallible entry point returns [`Error`]; nothing that input can
//! reach panics.

/// Why an operation on the estimator was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// A measurement contained NaN or infinity.
    NonFinite,
    /// A timestamp went backwards or repeated where strictly increasing time is required.
    TimeNotIncreasing,
    /// A time step was larger than the configured maximum (a gap in the data).
    TimeGap,
    /// A time lies outside the span the buffer holds.
    OutOfRange,
    /// A fixed-capacity container is full.
    CapacityExceeded,
    /// Too little data to do what was asked (e.g. initialization before enough samples).
    NotEnoughData,
    /// The operation needs a state that has not been initialized yet.
    NotInitialized,
    /// Initialization requires the platform to be static and it was not.
    NotStatic,
    /// A configuration value is out of its valid range.
    InvalidConfig,
    /// A linear system was not positive definite (or numerically singular).
    NotPositiveDefinite,
    /// A geometric quantity was degenerate (e.g. zero parallax, point behind the camera).
    Degenerate,
    /// Slice lengths or state indices do not match the dimensions of the problem.
    DimensionMismatch,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let s = match self {
            Error::NonFinite => "measurement is not finite",
            Error::TimeNotIncreasing => "timestamp is not increasing",
            Error::TimeGap => "time gap larger than allowed",
            Error::OutOfRange => "time outside the buffered span",
            Error::CapacityExceeded => "fixed capacity exceeded",
            Error::NotEnoughData => "not enough data",
            Error::NotInitialized => "not initialized",
            Error::NotStatic => "platform is not static",
            Error::InvalidConfig => "invalid configuration",
            Error::NotPositiveDefinite => "matrix not positive definite",
            Error::Degenerate => "degenerate geometry",
            Error::DimensionMismatch => "dimension or index mismatch",
        };
        f.write_str(s)
    }
}

impl core::error::Error for Error {}
