//! # povins-platform
//!
//! The std side of povins for Linux (x86-64 and aarch64): dataset readers and writers (EuRoC ASL
//! folders, MCAP with ROS 2 CDR messages, TUM trajectories), the in-memory [`dataset::Dataset`]
//! they all produce, and the runtime pieces around the `no_std` core.

pub mod cdr;
pub mod dataset;
pub mod error;
pub mod euroc;
pub mod image_codec;
pub mod mcap_io;
pub mod ros2;
pub mod trajectory;

pub use dataset::Dataset;
pub use error::IoError;
