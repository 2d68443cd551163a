//! # povins-platform
//!
//! The std side of povins for Linux (x86-64 and aarch64): dataset readers and writers (EuRoC ASL
//! folders, MCAP with ROS 2 CDR messages, TUM trajectories), the in-memory [`dataset::Dataset`]
//! they all produce, and the runtime around the `no_std` core: [`pipeline`], the IMU and
//! back-end threads (SPSC queues, pinned cores, `SCHED_FIFO`, latency histograms) fed by a
//! [`pipeline::Source`] and publishing to a [`pipeline::Sink`].

pub mod boxed;
pub mod cdr;
pub mod dataset;
pub mod driver;
pub mod error;
pub mod euroc;
pub mod image_codec;
pub mod images;
pub mod mcap_io;
pub mod odometry;
pub mod pipeline;
pub mod recording;
pub mod ros2;
pub mod source;
pub mod trajectory;

pub use dataset::Dataset;
pub use error::IoError;
