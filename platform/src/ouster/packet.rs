//! Lidar and IMU UDP packet decoding. All fields little-endian; every length and index is
//! checked, a packet of the wrong size is an [`OusterError::PacketSize`].

use super::metadata::{HeaderType, LidarProfile, Metadata};
use super::OusterError;

/// Standard gravity, m/s^2 per g (the IMU reports accelerations in g).
pub const G_MPS2: f64 = 9.80665;

/// Size of a `LEGACY` IMU packet, bytes.
pub const IMU_PACKET_BYTES: usize = 48;

/// One pixel (channel) of a column: the first return, and the second in the dual profile.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Pixel {
    /// Range, mm (0: no return).
    pub range_mm: u32,
    /// Reflectivity (16 bits in `LEGACY`, 8 bits otherwise).
    pub reflectivity: u16,
    /// Signal photons (0 in the low-data-rate profile, which has none).
    pub signal: u16,
    /// Near-infrared (ambient) photons (scaled by 4 in the low-data-rate profile).
    pub near_ir: u16,
    /// Second return's range, mm (dual profile; 0 otherwise).
    pub range2_mm: u32,
    /// Second return's reflectivity (dual profile; 0 otherwise).
    pub reflectivity2: u16,
    /// Second return's signal photons (dual profile; 0 otherwise).
    pub signal2: u16,
}

/// One measurement column (one firing of every channel).
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    /// Column timestamp, ns on the sensor clock (`timestamp_mode`: internal, PTP or sync-pulse).
    pub t_ns: i64,
    /// Measurement id: the column's index in the frame, `0..columns_per_frame`.
    pub measurement_id: u16,
    /// Frame id of the column (in `LEGACY` each column carries its own; 16 bits except in the
    /// `FUSA` header's 32).
    pub frame_id: u32,
    /// Encoder count (`LEGACY` only).
    pub encoder_count: Option<u32>,
    /// Whether the column holds data (`LEGACY` status `0xffffffff`, otherwise status bit 0);
    /// an invalid column's pixels are zeros but its timestamp and ids are good.
    pub valid: bool,
    /// `pixels_per_column` pixels, row 0 the top beam.
    pub pixels: Vec<Pixel>,
}

/// A decoded lidar packet.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarPacket {
    /// Frame id of the packet (its first column's in `LEGACY`; 16 bits except in the `FUSA`
    /// header's 32).
    pub frame_id: u32,
    /// Initialization id (`None` in `LEGACY`): changes on every sensor re-init.
    pub init_id: Option<u32>,
    /// Serial number from the packet header (`None` in `LEGACY`).
    pub prod_sn: Option<u64>,
    /// `columns_per_packet` columns in firing order.
    pub columns: Vec<Column>,
}

/// A decoded IMU packet (`LEGACY` IMU profile), in the IMU frame (see
/// [`Metadata::imu_to_sensor_transform`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuPacket {
    /// Time the packet was sent (diagnostic), ns on the sensor clock.
    pub sys_t_ns: i64,
    /// Time of the accelerometer reading, ns on the sensor clock (the lidar columns' clock).
    pub accel_t_ns: i64,
    /// Time of the gyro reading, ns on the sensor clock.
    pub gyro_t_ns: i64,
    /// Specific force, m/s^2 (the packet's g times [`G_MPS2`]).
    pub accel_mps2: [f64; 3],
    /// Angular rate, rad/s (the packet's deg/s).
    pub gyro_rps: [f64; 3],
}

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

fn f32_at(b: &[u8], at: usize) -> Option<f32> {
    Some(f32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn short(what: &str, at: usize) -> OusterError {
    OusterError::Packet(format!("{what}: read past the end at byte {at}"))
}

fn time_ns(raw: u64, what: &str) -> Result<i64, OusterError> {
    i64::try_from(raw)
        .map_err(|_| OusterError::Packet(format!("{what} timestamp {raw} ns exceeds i64")))
}

/// Byte sizes of a profile's packet parts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Layout {
    packet_header: usize,
    column_header: usize,
    channel: usize,
    column_footer: usize,
    packet_footer: usize,
}

impl Layout {
    fn of(profile: LidarProfile) -> Self {
        let modern = |channel| Layout {
            packet_header: 32,
            column_header: 12,
            channel,
            column_footer: 0,
            packet_footer: 32,
        };
        match profile {
            LidarProfile::Legacy => Layout {
                packet_header: 0,
                column_header: 16,
                channel: 12,
                column_footer: 4,
                packet_footer: 0,
            },
            LidarProfile::Single => modern(12),
            LidarProfile::Dual => modern(16),
            LidarProfile::LowDataRate => modern(4),
        }
    }
}

/// Decodes the packets of one sensor configuration ([`Metadata`]).
#[derive(Debug, Clone)]
pub struct Decoder {
    profile: LidarProfile,
    header: HeaderType,
    layout: Layout,
    rows: usize,
    cols_packet: usize,
    cols_frame: usize,
}

impl Decoder {
    /// A decoder for the packets described by `meta`.
    pub fn new(meta: &Metadata) -> Self {
        Decoder {
            profile: meta.profile,
            header: meta.header_type,
            layout: Layout::of(meta.profile),
            rows: meta.pixels_per_column,
            cols_packet: meta.columns_per_packet,
            cols_frame: meta.columns_per_frame,
        }
    }

    /// Size of one column, bytes.
    fn column_bytes(&self) -> usize {
        let l = &self.layout;
        l.column_header + self.rows * l.channel + l.column_footer
    }

    /// The exact size of a lidar packet of this configuration, bytes.
    pub fn lidar_packet_bytes(&self) -> usize {
        let l = &self.layout;
        l.packet_header + self.cols_packet * self.column_bytes() + l.packet_footer
    }

    /// Decodes one lidar packet (a UDP payload); a payload of the wrong size, a wrong packet
    /// type or a measurement id outside the frame is an error.
    pub fn decode_lidar(&self, buf: &[u8]) -> Result<LidarPacket, OusterError> {
        let expected = self.lidar_packet_bytes();
        if buf.len() != expected {
            return Err(OusterError::PacketSize {
                what: "lidar packet",
                profile: self.profile.name(),
                expected,
                actual: buf.len(),
            });
        }
        let (mut frame_id, mut init_id, mut prod_sn) = (0u32, None, None);
        if self.profile != LidarProfile::Legacy {
            let h = self.decode_header(buf)?;
            (frame_id, init_id, prod_sn) = (h.0, Some(h.1), Some(h.2));
        }
        let mut columns = Vec::with_capacity(self.cols_packet);
        for c in 0..self.cols_packet {
            let at = self.layout.packet_header + c * self.column_bytes();
            let bytes = buf
                .get(at..at + self.column_bytes())
                .ok_or_else(|| short("column", at))?;
            let col = self.decode_column(bytes, frame_id, at)?;
            if c == 0 && self.profile == LidarProfile::Legacy {
                frame_id = col.frame_id;
            }
            columns.push(col);
        }
        Ok(LidarPacket {
            frame_id,
            init_id,
            prod_sn,
            columns,
        })
    }

    /// The packet header's frame id, init id (24 bits) and serial number (40 bits), in the
    /// metadata's [`HeaderType`]; a packet type other than 1 (lidar) is an error.
    fn decode_header(&self, buf: &[u8]) -> Result<(u32, u32, u64), OusterError> {
        let (ptype, frame_id, init_at, sn_at) = match self.header {
            HeaderType::Standard => (
                u16_at(buf, 0).ok_or_else(|| short("packet header", 0))?,
                u32::from(u16_at(buf, 2).ok_or_else(|| short("packet header", 2))?),
                4,
                7,
            ),
            HeaderType::Fusa => (
                u16::from(*buf.first().ok_or_else(|| short("packet header", 0))?),
                u32_at(buf, 4).ok_or_else(|| short("packet header", 4))?,
                1,
                11,
            ),
        };
        if ptype != 1 {
            return Err(OusterError::Packet(format!(
                "packet type {ptype}, expected 1 (lidar) in the {} header",
                self.header.name()
            )));
        }
        let id = buf
            .get(init_at..init_at + 3)
            .ok_or_else(|| short("packet header", init_at))?;
        let sn = buf
            .get(sn_at..sn_at + 5)
            .ok_or_else(|| short("packet header", sn_at))?;
        let init_id = id
            .iter()
            .rev()
            .fold(0u32, |acc, &b| acc << 8 | u32::from(b));
        let prod_sn = sn
            .iter()
            .rev()
            .fold(0u64, |acc, &b| acc << 8 | u64::from(b));
        Ok((frame_id, init_id, prod_sn))
    }

    /// Decodes one column (`b` exactly one column's bytes; `at` its offset in the packet).
    fn decode_column(&self, b: &[u8], packet_frame: u32, at: usize) -> Result<Column, OusterError> {
        let err = |off: usize| short("column", at + off);
        let t_ns = time_ns(u64_at(b, 0).ok_or_else(|| err(0))?, "column")?;
        let measurement_id = u16_at(b, 8).ok_or_else(|| err(8))?;
        if usize::from(measurement_id) >= self.cols_frame {
            return Err(OusterError::Packet(format!(
                "measurement id {measurement_id} at byte {} is not below columns_per_frame {}",
                at + 8,
                self.cols_frame
            )));
        }
        let (frame_id, encoder_count, valid) = if self.profile == LidarProfile::Legacy {
            let status_at = b.len().checked_sub(4).ok_or_else(|| err(0))?;
            (
                u32::from(u16_at(b, 10).ok_or_else(|| err(10))?),
                Some(u32_at(b, 12).ok_or_else(|| err(12))?),
                u32_at(b, status_at).ok_or_else(|| err(status_at))? == 0xffff_ffff,
            )
        } else {
            let status = u16_at(b, 10).ok_or_else(|| err(10))?;
            (packet_frame, None, status & 1 == 1)
        };
        let mut pixels = Vec::with_capacity(self.rows);
        for row in 0..self.rows {
            let p_at = self.layout.column_header + row * self.layout.channel;
            let ch = b
                .get(p_at..p_at + self.layout.channel)
                .ok_or_else(|| err(p_at))?;
            pixels.push(self.decode_pixel(ch).ok_or_else(|| err(p_at))?);
        }
        Ok(Column {
            t_ns,
            measurement_id,
            frame_id,
            encoder_count,
            valid,
            pixels,
        })
    }

    /// Decodes one channel data block (`ch` exactly the profile's channel size).
    fn decode_pixel(&self, ch: &[u8]) -> Option<Pixel> {
        Some(match self.profile {
            LidarProfile::Legacy => Pixel {
                range_mm: u32_at(ch, 0)? & 0x000f_ffff,
                reflectivity: u16_at(ch, 4)?,
                signal: u16_at(ch, 6)?,
                near_ir: u16_at(ch, 8)?,
                ..Pixel::default()
            },
            LidarProfile::Single => Pixel {
                range_mm: u32_at(ch, 0)? & 0x0007_ffff,
                reflectivity: u16::from(*ch.get(4)?),
                signal: u16_at(ch, 6)?,
                near_ir: u16_at(ch, 8)?,
                ..Pixel::default()
            },
            LidarProfile::Dual => Pixel {
                range_mm: u32_at(ch, 0)? & 0x0007_ffff,
                reflectivity: u16::from(*ch.get(3)?),
                range2_mm: u32_at(ch, 4)? & 0x0007_ffff,
                reflectivity2: u16::from(*ch.get(7)?),
                signal: u16_at(ch, 8)?,
                signal2: u16_at(ch, 10)?,
                near_ir: u16_at(ch, 12)?,
            },
            LidarProfile::LowDataRate => Pixel {
                range_mm: u32::from(u16_at(ch, 0)? & 0x7fff) * 8,
                reflectivity: u16::from(*ch.get(2)?),
                near_ir: u16::from(*ch.get(3)?) * 4,
                ..Pixel::default()
            },
        })
    }

    /// Decodes one IMU packet (the `LEGACY` IMU profile, 48 bytes).
    pub fn decode_imu(&self, buf: &[u8]) -> Result<ImuPacket, OusterError> {
        decode_imu(buf)
    }
}

/// Decodes one IMU packet (the `LEGACY` IMU profile, 48 bytes): three u64 timestamps (sent,
/// accelerometer, gyro; ns), acceleration x, y, z (f32, g), angular rate x, y, z (f32, deg/s).
pub fn decode_imu(buf: &[u8]) -> Result<ImuPacket, OusterError> {
    if buf.len() != IMU_PACKET_BYTES {
        return Err(OusterError::PacketSize {
            what: "IMU packet",
            profile: "LEGACY",
            expected: IMU_PACKET_BYTES,
            actual: buf.len(),
        });
    }
    let t = |at| {
        u64_at(buf, at)
            .ok_or_else(|| short("IMU packet", at))
            .and_then(|v| time_ns(v, "IMU"))
    };
    let f = |at: usize| {
        f32_at(buf, at)
            .map(f64::from)
            .ok_or_else(|| short("IMU packet", at))
    };
    Ok(ImuPacket {
        sys_t_ns: t(0)?,
        accel_t_ns: t(8)?,
        gyro_t_ns: t(16)?,
        accel_mps2: [f(24)? * G_MPS2, f(28)? * G_MPS2, f(32)? * G_MPS2],
        gyro_rps: [
            f(36)?.to_radians(),
            f(40)?.to_radians(),
            f(44)?.to_radians(),
        ],
    })
}
