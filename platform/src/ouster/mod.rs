//! Ouster OS-series LiDAR: the sensor metadata, its lidar and IMU UDP packets, sweeps, and pcap
//! captures of them.
//!
//! ## Frames and units
//! - **Lidar frame** (Ouster's "Lidar Coordinate Frame"): origin on the rotation axis at the
//!   optical mid-plane, `x` towards encoder angle 0 (the connector, the sensor's back), `y`
//!   towards encoder angle 90°, `z` up. Ranges are measured from each beam's origin, which sits
//!   `beam_to_lidar_transform` (mm) off this origin; measurement id `m` fires at encoder angle
//!   `2π (1 - m / columns_per_frame)` (the head spins clockwise seen from above).
//! - **Sensor frame** ("Sensor Coordinate Frame"): the housing's, `x` forward, `z` up, origin at
//!   the base centre: `p_sensor = lidar_to_sensor_transform * p_lidar` (for an OS1 a 180° yaw and
//!   36.18 mm up).
//! - **IMU frame**: the accelerometer/gyro axes, `p_sensor = imu_to_sensor_transform * p_imu`.
//!
//! The metadata's transforms are 4x4 row-major with translations in mm ([`Metadata`] keeps them
//! so; [`Metadata::imu_to_sensor_m`] gives metres). Points produced here ([`XyzLut`],
//! [`SweepAssembler`]) are in the **sensor frame, in metres** — what the Ouster SDK's XYZ lookup
//! gives — so a povins `T_bl` for an Ouster is the body-to-*sensor-frame* extrinsic. Times are
//! the sensor's column / IMU timestamps in integer ns (its `timestamp_mode` clock: internal
//! since power-on, PTP or sync-pulse).
//!
//! ## Packets
//! A lidar packet holds `columns_per_packet` (16) columns; a column is one firing of every
//! channel, with its timestamp, measurement id and valid flag. The layout depends on
//! `udp_profile_lidar` ([`LidarProfile`]): `LEGACY` (per-column header and status, no packet
//! header), and the profiles with a 32-byte packet header (packet type 1, 16-bit frame id,
//! 24-bit init id, 40-bit serial), 12-byte column headers (timestamp u64, measurement id u16,
//! status u16 with bit 0 valid) and a 32-byte footer: `RNG19_RFL8_SIG16_NIR16`, its `_DUAL`,
//! and `RNG15_RFL8_NIR8` (low data rate: range in units of 8 mm). The packet header is the
//! firmware 2.2–3.0 one, or firmware 3.1's `FUSA` header (8-bit packet type, 32-bit frame id)
//! when the metadata's `lidar_data_format.header_type` says so ([`HeaderType`]); the footer's
//! CRC is not checked. The IMU packet (`LEGACY` IMU profile) is 48 bytes ([`decode_imu`]).
//!
//! Entry points: [`Metadata::from_file`], [`Decoder::decode_lidar`], [`decode_imu`],
//! [`SweepAssembler::push`], [`pcap::PcapUdp`], [`read_pcap`] for a whole capture,
//! [`live::OusterUdp`] for a live sensor (a [`crate::source::Source`]), and [`calibration`] for
//! the recording of an Ouster alone (body = IMU frame).

pub mod live;
pub mod metadata;
pub mod packet;
pub mod pcap;
pub mod rosbag;
pub mod sweep;

#[cfg(test)]
mod live_tests;
#[cfg(test)]
mod tests;

pub use live::{LiveCounts, LiveOptions, OusterUdp, StreamDecoder};
pub use metadata::{HeaderType, LidarProfile, Metadata, XyzLut};
pub use packet::{decode_imu, Column, Decoder, ImuPacket, LidarPacket, Pixel, G_MPS2};
pub use pcap::{PcapCounts, PcapUdp, UdpDatagram};
pub use sweep::{Counts, SweepAssembler, SweepInfo};

use crate::dataset::{Calibration, Extrinsic, LidarScan};
use crate::IoError;
use povins_core::inertial::ImuNoise;
use povins_core::math::{Quat, Vec3};
use std::path::Path;

/// The Ouster OS IMU's (InvenSense ICM-20948) noise: the datasheet's white-noise densities
/// (gyro 0.015 deg/s/sqrt(Hz), accelerometer 230 ug/sqrt(Hz)) and bias random walks of the order
/// of a MEMS IMU's (not on the datasheet): a starting point, to override with `[imu_noise]`.
pub const OUSTER_IMU_NOISE: ImuNoise = ImuNoise {
    gyro_noise_density: 2.618e-4,
    accel_noise_density: 2.256e-3,
    gyro_bias_rw: 2.0e-5,
    accel_bias_rw: 3.0e-3,
    bias_corr_time_s: None,
};

/// The Ouster IMU's sample rate, Hz (100 Hz on OS sensors).
pub const OUSTER_IMU_RATE_HZ: f64 = 100.0;

/// The LiDAR extrinsic of a recording whose body frame is the Ouster's IMU frame: `T_bl` =
/// `imu_to_sensor_transform`^-1 (`p_imu = R^T (p_sensor - t)`), LiDAR points being in the
/// sensor frame. The metadata's rotation is taken to the nearest rotation.
pub fn t_imu_sensor(meta: &Metadata) -> Extrinsic {
    let m = meta.imu_to_sensor_m();
    let r = nalgebra::Matrix3::from_fn(|i, j| m[i][j]);
    let q_sensor_imu = Quat::from_matrix(&r);
    let t = Vec3::new(m[0][3], m[1][3], m[2][3]);
    let q_imu_sensor = q_sensor_imu.inverse();
    Extrinsic {
        q_ab: q_imu_sensor,
        p_ab: -(q_imu_sensor * t),
    }
}

/// The calibration of a recording of an Ouster alone: no camera ([`crate::dataset::no_camera`], as an
/// EuRoC folder without `cam0` reads), body = IMU frame, [`OUSTER_IMU_NOISE`] at
/// [`OUSTER_IMU_RATE_HZ`], `T_bl` from [`t_imu_sensor`].
pub fn calibration(meta: &Metadata) -> Calibration {
    Calibration {
        camera: crate::dataset::no_camera(),
        t_bc: Extrinsic::identity(),
        td_s: 0.0,
        camera_rate_hz: 0.0,
        imu_noise: OUSTER_IMU_NOISE,
        imu_rate_hz: OUSTER_IMU_RATE_HZ,
        gravity_mps2: G_MPS2,
        t_bl: Some(t_imu_sensor(meta)),
        td_l_s: 0.0,
    }
}

/// A metadata or packet decoding failure.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OusterError {
    /// A metadata key is missing or has the wrong type or value.
    #[error("metadata key `{key}`: {msg}")]
    Metadata {
        /// The key.
        key: String,
        /// What is wrong.
        msg: String,
    },
    /// A packet's size does not match the metadata's packet format.
    #[error("{what} ({profile}) of {actual} bytes, expected {expected}")]
    PacketSize {
        /// Lidar or IMU packet.
        what: &'static str,
        /// The profile the size was computed for.
        profile: &'static str,
        /// Expected size, bytes.
        expected: usize,
        /// Actual size, bytes.
        actual: usize,
    },
    /// A packet's content is invalid (wrong packet type, measurement id out of range, ...).
    #[error("bad packet: {0}")]
    Packet(String),
}

/// What [`read_pcap`] (or [`rosbag::read_bag`]) decoded from a recording.
#[derive(Debug, Clone, Default)]
pub struct OusterCapture {
    /// The sweeps, in frame order.
    pub scans: Vec<LidarScan>,
    /// The IMU packets, in arrival order.
    pub imu: Vec<ImuPacket>,
    /// The sweep assembler's counts.
    pub counts: Counts,
    /// The capture reader's counts (zero for a bag).
    pub pcap: PcapCounts,
    /// Lidar or IMU packets that did not decode (wrong size, ...): skipped.
    pub bad_packets: u64,
    /// The first bad packet's error, for a message.
    pub first_error: Option<String>,
}

impl OusterCapture {
    fn bad(&mut self, e: OusterError) {
        self.bad_packets += 1;
        if self.first_error.is_none() {
            self.first_error = Some(e.to_string());
        }
    }
}

/// Decodes a whole pcap capture of one sensor: the lidar packets on `udp_port_lidar` (default
/// 7502) into sweeps, the IMU packets on `udp_port_imu` (default 7503).
pub fn read_pcap(path: &Path, meta: &Metadata) -> Result<OusterCapture, IoError> {
    let lidar_port = meta.udp_port_lidar.unwrap_or(7502);
    let imu_port = meta.udp_port_imu.unwrap_or(7503);
    let mut udp = PcapUdp::open(path)?.ports(&[lidar_port, imu_port]);
    let decoder = Decoder::new(meta);
    let mut asm = SweepAssembler::new(meta);
    let mut out = OusterCapture::default();
    for d in udp.by_ref() {
        let d = d?;
        if d.dst_port == lidar_port {
            match decoder.decode_lidar(&d.payload) {
                Ok(p) => out.scans.extend(asm.push(&p)),
                Err(e) => out.bad(e),
            }
        } else {
            match decode_imu(&d.payload) {
                Ok(p) => out.imu.push(p),
                Err(e) => out.bad(e),
            }
        }
    }
    out.scans.extend(asm.finish());
    out.counts = asm.counts();
    out.pcap = udp.counts();
    Ok(out)
}
