//! LiDAR sweeps as the drivers publish them: `sensor_msgs/PointCloud2` in each common driver's
//! point layout ([`Layout`]) and Livox's `CustomMsg` ([`livox`]), decoded into one
//! [`LidarScan`] (points in the LiDAR frame `l`, each with its own time in integer nanoseconds on
//! the LiDAR's clock) whatever the driver, the container and the encoding.
//!
//! ## Point layouts
//! | layout | time field | time | other fields | bytes |
//! |---|---|---|---|---|
//! | `compact` (povins' own) | `t` uint32 | ns after `header.stamp` | `intensity` f32 | 20 |
//! | `ouster` (ouster-ros) | `t` uint32 | ns after `header.stamp` | `intensity` f32, `reflectivity`, `ring`, `ambient` u16, `range` u32 (mm) | 48 |
//! | `velodyne` (velodyne_pointcloud XYZIRT) | `time` float32 | s after `header.stamp` | `intensity` f32, `ring` u16 | 22 |
//! | `hesai` (Hesai ROS drivers) | `timestamp` float64 | s since the epoch | `intensity` f32, `ring` u16 | 48 |
//! | `robosense` (rslidar_sdk XYZIRT) | `timestamp` float64 | s since the epoch | `intensity` f32, `ring` u16 | 32 |
//! | `livox2` (livox_ros_driver2, PointCloud2) | `timestamp` float64 | ns since the epoch | `intensity` f32, `tag`, `line` u8 | 26 |
//!
//! `x`, `y`, `z` are float32 (float64 is read too) at offsets 0, 4, 8 in every layout.
//! Little-endian only (a big-endian cloud is an error).
//!
//! ## How the layout is told ([`decode_point_cloud2`])
//! The time field is the first of `t`, `time`, `timestamp`, `time_stamp`, `offset_time` the cloud
//! has. Its unit and reference come from its name and type (`t`, `offset_time`: integer ns after
//! the stamp; `time`: s after the stamp; `timestamp`: s since the epoch, or ns when that is what
//! fits), checked against the magnitude of the values: every sampled point must fall within
//! [`MAX_SWEEP_SPAN_NS`] of `header.stamp`. When the expected reading does not fit and another
//! does (ns instead of s, absolute instead of relative), that one is used and
//! [`Decoded::time`] says so, for a warning. When none fits, the cloud is an error naming the
//! field, its first value and the stamp. [`CloudOptions::layout`] forces a layout's reading (the
//! run's `[input] lidar_layout`).
//!
//! A cloud without a time field (Livox ROS driver 1's PointCloud2, some filters' output) is used
//! under [`CloudOptions::no_time`]: all points at the stamp, or spread over a sweep period by
//! azimuth (a spinning LiDAR: the stamp its start or end, the spin direction), and the reader
//! warns once per topic. De-skew is only as good as that assumption.
//!
//! ## What is dropped, and counted ([`CloudCounts`])
//! Points with a non-finite coordinate or time; points at exactly (0, 0, 0) (no return: Ouster
//! and Livox write them so); points the driver flagged as noise (Livox `tag`, [`livox::is_noise`]);
//! points whose time is more than [`MAX_SWEEP_SPAN_NS`] from the stamp.

pub mod livox;
mod pc2;

#[cfg(test)]
mod tests;

pub use pc2::{decode_point_cloud2, encode_points};

use crate::dataset::LidarScan;

/// `sensor_msgs/PointField` datatypes.
pub mod datatype {
    /// `INT8`.
    pub const INT8: u8 = 1;
    /// `UINT8`.
    pub const UINT8: u8 = 2;
    /// `INT16`.
    pub const INT16: u8 = 3;
    /// `UINT16`.
    pub const UINT16: u8 = 4;
    /// `INT32`.
    pub const INT32: u8 = 5;
    /// `UINT32`.
    pub const UINT32: u8 = 6;
    /// `FLOAT32`.
    pub const FLOAT32: u8 = 7;
    /// `FLOAT64`.
    pub const FLOAT64: u8 = 8;

    /// Bytes of one element of `dt`, `None` for an unknown datatype.
    pub fn size(dt: u8) -> Option<usize> {
        match dt {
            INT8 | UINT8 => Some(1),
            INT16 | UINT16 => Some(2),
            INT32 | UINT32 | FLOAT32 => Some(4),
            FLOAT64 => Some(8),
            _ => None,
        }
    }

    /// The ROS name of `dt`.
    pub fn name(dt: u8) -> &'static str {
        match dt {
            INT8 => "int8",
            UINT8 => "uint8",
            INT16 => "int16",
            UINT16 => "uint16",
            INT32 => "int32",
            UINT32 => "uint32",
            FLOAT32 => "float32",
            FLOAT64 => "float64",
            _ => "unknown",
        }
    }
}

/// Largest distance of a point's time from `header.stamp` (either side: some drivers stamp the
/// sweep's end), ns. A real sweep spans 0.05-0.2 s.
pub const MAX_SWEEP_SPAN_NS: i64 = 1_000_000_000;

/// Unit of a point time field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TimeUnit {
    /// Nanoseconds.
    Ns,
    /// Microseconds.
    Us,
    /// Seconds.
    S,
}

impl TimeUnit {
    /// Nanoseconds in one unit.
    pub fn ns(self) -> i64 {
        match self {
            TimeUnit::Ns => 1,
            TimeUnit::Us => 1_000,
            TimeUnit::S => 1_000_000_000,
        }
    }

    fn name(self) -> &'static str {
        match self {
            TimeUnit::Ns => "ns",
            TimeUnit::Us => "us",
            TimeUnit::S => "s",
        }
    }
}

/// What a point time counts from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TimeRef {
    /// The message's `header.stamp`.
    Header,
    /// The epoch of the stamps (the same clock as `header.stamp`).
    Absolute,
}

/// How a point's time is read: which field, in what unit, counted from where.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TimeSpec {
    /// Field name.
    pub field: &'static str,
    /// Unit.
    pub unit: TimeUnit,
    /// Reference.
    pub reference: TimeRef,
}

impl std::fmt::Display for TimeSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.reference {
            TimeRef::Header => write!(
                f,
                "`{}` in {} after header.stamp",
                self.field,
                self.unit.name()
            ),
            TimeRef::Absolute => write!(
                f,
                "`{}` in {} since the epoch",
                self.field,
                self.unit.name()
            ),
        }
    }
}

/// A driver's PointCloud2 point layout (see the module docs' table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Layout {
    /// povins' own 20-byte points (`x y z intensity t`), what its writers produce by default.
    Compact,
    /// ouster-ros.
    Ouster,
    /// velodyne_pointcloud's XYZIRT.
    Velodyne,
    /// Hesai's ROS drivers.
    Hesai,
    /// RoboSense rslidar_sdk's XYZIRT.
    Robosense,
    /// livox_ros_driver2's PointCloud2 (`xfer_format` 0).
    Livox2,
}

use datatype::{FLOAT32 as F32, FLOAT64 as F64, UINT16 as U16, UINT32 as U32, UINT8 as U8};

impl Layout {
    /// Every layout.
    pub const ALL: [Layout; 6] = [
        Layout::Compact,
        Layout::Ouster,
        Layout::Velodyne,
        Layout::Hesai,
        Layout::Robosense,
        Layout::Livox2,
    ];

    /// The name used on the command line and in the configuration.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Compact => "compact",
            Layout::Ouster => "ouster",
            Layout::Velodyne => "velodyne",
            Layout::Hesai => "hesai",
            Layout::Robosense => "robosense",
            Layout::Livox2 => "livox2",
        }
    }

    /// The layout named `s` ([`Layout::name`]).
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == s)
    }

    /// Its fields: name, byte offset, datatype.
    pub fn fields(self) -> &'static [(&'static str, u32, u8)] {
        match self {
            Layout::Compact => &[
                ("x", 0, F32),
                ("y", 4, F32),
                ("z", 8, F32),
                ("intensity", 12, F32),
                ("t", 16, U32),
            ],
            Layout::Ouster => &[
                ("x", 0, F32),
                ("y", 4, F32),
                ("z", 8, F32),
                ("intensity", 16, F32),
                ("t", 20, U32),
                ("reflectivity", 24, U16),
                ("ring", 26, U16),
                ("ambient", 28, U16),
                ("range", 32, U32),
            ],
            Layout::Velodyne => &[
                ("x", 0, F32),
                ("y", 4, F32),
                ("z", 8, F32),
                ("intensity", 12, F32),
                ("ring", 16, U16),
                ("time", 18, F32),
            ],
            Layout::Hesai => &[
                ("x", 0, F32),
                ("y", 4, F32),
                ("z", 8, F32),
                ("intensity", 16, F32),
                ("timestamp", 24, F64),
                ("ring", 32, U16),
            ],
            Layout::Robosense => &[
                ("x", 0, F32),
                ("y", 4, F32),
                ("z", 8, F32),
                ("intensity", 16, F32),
                ("ring", 20, U16),
                ("timestamp", 24, F64),
            ],
            Layout::Livox2 => &[
                ("x", 0, F32),
                ("y", 4, F32),
                ("z", 8, F32),
                ("intensity", 12, F32),
                ("tag", 16, U8),
                ("line", 17, U8),
                ("timestamp", 18, F64),
            ],
        }
    }

    /// Bytes per point.
    pub fn point_step(self) -> u32 {
        match self {
            Layout::Compact => 20,
            Layout::Ouster | Layout::Hesai => 48,
            Layout::Velodyne => 22,
            Layout::Robosense => 32,
            Layout::Livox2 => 26,
        }
    }

    /// How its point times are read.
    pub fn time(self) -> TimeSpec {
        let (field, unit, reference) = match self {
            Layout::Compact | Layout::Ouster => ("t", TimeUnit::Ns, TimeRef::Header),
            Layout::Velodyne => ("time", TimeUnit::S, TimeRef::Header),
            Layout::Hesai | Layout::Robosense => ("timestamp", TimeUnit::S, TimeRef::Absolute),
            Layout::Livox2 => ("timestamp", TimeUnit::Ns, TimeRef::Absolute),
        };
        TimeSpec {
            field,
            unit,
            reference,
        }
    }
}

/// How sweeps are written as ROS messages: a PointCloud2 in a driver's layout, or Livox's
/// `CustomMsg` of either driver package ([`livox`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Wire {
    /// `sensor_msgs/PointCloud2` in this layout.
    Cloud(Layout),
    /// `livox_ros_driver/CustomMsg` (ROS 1 only: the driver has no ROS 2 version).
    LivoxCustom,
    /// `livox_ros_driver2/CustomMsg`.
    Livox2Custom,
}

impl Default for Wire {
    fn default() -> Self {
        Wire::Cloud(Layout::Compact)
    }
}

impl Wire {
    /// Every wire format.
    pub fn all() -> Vec<Wire> {
        let mut v: Vec<Wire> = Layout::ALL.into_iter().map(Wire::Cloud).collect();
        v.extend([Wire::LivoxCustom, Wire::Livox2Custom]);
        v
    }

    /// The name on the command line: a layout's, `livox-custom` or `livox2-custom`.
    pub fn name(self) -> &'static str {
        match self {
            Wire::Cloud(l) => l.name(),
            Wire::LivoxCustom => "livox-custom",
            Wire::Livox2Custom => "livox2-custom",
        }
    }

    /// The wire format named `s` ([`Wire::name`]).
    pub fn parse(s: &str) -> Option<Self> {
        Self::all().into_iter().find(|w| w.name() == s)
    }
}

/// What a cloud without per-point times is taken to mean (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum NoTime {
    /// Every point at `header.stamp` (no de-skew).
    #[default]
    Stamp,
    /// A spinning LiDAR: points spread over `period_ns` by azimuth from the first point's,
    /// turning `clockwise` (seen from +z) or not; `header.stamp` is the sweep's start, or its
    /// end when `stamp_is_end`.
    Spin {
        /// Sweep period, ns.
        period_ns: i64,
        /// True when the sensor turns clockwise seen from above (azimuth decreasing).
        clockwise: bool,
        /// True when the stamp is the sweep's end.
        stamp_is_end: bool,
    },
}

/// How clouds are read.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CloudOptions {
    /// The layout whose time reading is used; `None` tells it from the cloud (module docs).
    pub layout: Option<Layout>,
    /// What a cloud without per-point time is taken to mean.
    pub no_time: NoTime,
}

/// Points of a cloud, and those dropped by cause (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CloudCounts {
    /// Points in the message.
    pub points: u64,
    /// With a non-finite coordinate or time.
    pub non_finite: u64,
    /// At exactly (0, 0, 0).
    pub no_return: u64,
    /// Flagged as noise by the driver.
    pub flagged_noise: u64,
    /// With a time more than [`MAX_SWEEP_SPAN_NS`] from the stamp.
    pub out_of_sweep: u64,
}

impl CloudCounts {
    /// Points dropped.
    pub fn dropped(&self) -> u64 {
        self.non_finite + self.no_return + self.flagged_noise + self.out_of_sweep
    }

    /// Adds `o`'s counts.
    pub fn add(&mut self, o: &CloudCounts) {
        self.points += o.points;
        self.non_finite += o.non_finite;
        self.no_return += o.no_return;
        self.flagged_noise += o.flagged_noise;
        self.out_of_sweep += o.out_of_sweep;
    }

    /// `N of M points dropped: ...` (the causes with a count).
    pub fn describe(&self) -> String {
        let causes: Vec<String> = [
            (self.non_finite, "non-finite"),
            (self.no_return, "at (0, 0, 0) (no return)"),
            (self.flagged_noise, "flagged as noise by the driver"),
            (self.out_of_sweep, "with a time over 1 s from the stamp"),
        ]
        .into_iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, what)| format!("{n} {what}"))
        .collect();
        format!(
            "{} of {} points dropped ({})",
            self.dropped(),
            self.points,
            causes.join(", ")
        )
    }
}

/// Where the point times came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TimeSource {
    /// A field, read as `spec`; `expected` is false when the reading its name and type suggest
    /// did not fit the values and this one was found instead.
    Field {
        /// How it was read.
        spec: TimeSpec,
        /// Whether it is the reading the field's name and type suggest.
        expected: bool,
    },
    /// The cloud has no time field: the assumption made.
    Assumed(NoTime),
}

impl std::fmt::Display for TimeSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TimeSource::Field { spec, .. } => write!(f, "point time from {spec}"),
            TimeSource::Assumed(NoTime::Stamp) => {
                f.write_str("no point time field: every point taken at header.stamp (no de-skew)")
            }
            TimeSource::Assumed(NoTime::Spin {
                period_ns,
                clockwise,
                stamp_is_end,
            }) => write!(
                f,
                "no point time field: points spread by azimuth over {} s, turning {}, \
                 header.stamp the sweep's {}",
                *period_ns as f64 * 1e-9,
                if *clockwise {
                    "clockwise"
                } else {
                    "counter-clockwise"
                },
                if *stamp_is_end { "end" } else { "start" }
            ),
        }
    }
}

/// A decoded cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    /// The sweep: stamped with `header.stamp`, the points kept.
    pub scan: LidarScan,
    /// What was dropped.
    pub counts: CloudCounts,
    /// Where the point times came from.
    pub time: TimeSource,
}

/// `t_ns` as float64 seconds since the epoch, split so that the fraction keeps its
/// nanoseconds as well as float64 allows (about 0.24 us at today's epoch seconds).
pub fn ns_to_f64_s(t_ns: i64) -> f64 {
    let s = t_ns.div_euclid(1_000_000_000);
    let ns = t_ns.rem_euclid(1_000_000_000);
    s as f64 + ns as f64 * 1e-9
}

/// Float64 seconds since the epoch -> ns, rounded (the inverse of [`ns_to_f64_s`]); `None`
/// when not finite or out of range.
pub fn f64_s_to_ns(v: f64) -> Option<i64> {
    if !v.is_finite() || v.abs() > 9.0e9 {
        return None;
    }
    let s = v.floor();
    let frac_ns = ((v - s) * 1e9).round() as i64;
    Some(s as i64 * 1_000_000_000 + frac_ns)
}

/// A float time value `v` in `unit` -> ns (rounded), `None` when not finite or out of range.
pub(crate) fn float_to_ns(v: f64, unit: TimeUnit) -> Option<i64> {
    match unit {
        TimeUnit::S => f64_s_to_ns(v),
        _ => {
            let ns = v * unit.ns() as f64;
            (ns.is_finite() && ns.abs() < 9.0e18).then(|| ns.round() as i64)
        }
    }
}
