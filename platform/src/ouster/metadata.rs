//! The sensor metadata JSON (what `ouster-cli` / the SDK save, and the sensor's
//! `GET /api/v1/sensor/metadata`) and the range-to-XYZ lookup built from it.
//!
//! Two layouts are read:
//! - the legacy flat one (firmware 2.x, SDK < 0.10): every key at the top level, the packet
//!   format under `data_format`;
//! - the nested one (firmware ≥ 2.4 with newer SDKs): `sensor_info` (`prod_line`, `prod_sn`,
//!   `build_rev`), `lidar_data_format`, `beam_intrinsics` (angles, `beam_to_lidar_transform`,
//!   `lidar_origin_to_beam_origin_mm`), `lidar_intrinsics` (`lidar_to_sensor_transform`),
//!   `imu_intrinsics` (`imu_to_sensor_transform`), `config_params` (`lidar_mode`, ports,
//!   `udp_profile_lidar`).
//!
//! A key is looked up at the top level first, then in its nested section.

use super::OusterError;
use serde_json::Value;

/// Ouster's lidar packet profile (`udp_profile_lidar`): the layout of a lidar UDP packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LidarProfile {
    /// Firmware < 2.2 layout (and `LEGACY` afterwards): no packet header, per column a 16-byte
    /// header (timestamp, measurement id, frame id, encoder count), 12 bytes per pixel (range
    /// 20 bits mm, reflectivity, signal, near-IR), a 4-byte status (`0xffffffff` valid).
    Legacy,
    /// `RNG19_RFL8_SIG16_NIR16`: 32-byte packet header and footer, 12-byte column header,
    /// 12 bytes per pixel (range 19 bits mm, reflectivity 8, signal 16, near-IR 16).
    Single,
    /// `RNG19_RFL8_SIG16_NIR16_DUAL`: as [`LidarProfile::Single`] with 16 bytes per pixel (two
    /// returns: range, reflectivity and signal each; near-IR once).
    Dual,
    /// `RNG15_RFL8_NIR8` ("low data rate"): as [`LidarProfile::Single`] with 4 bytes per pixel
    /// (range 15 bits in units of 8 mm, reflectivity 8, near-IR 8 in units of 4).
    LowDataRate,
}

impl LidarProfile {
    /// The profile of a `udp_profile_lidar` name.
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "LEGACY" => LidarProfile::Legacy,
            "RNG19_RFL8_SIG16_NIR16" => LidarProfile::Single,
            "RNG19_RFL8_SIG16_NIR16_DUAL" => LidarProfile::Dual,
            "RNG15_RFL8_NIR8" => LidarProfile::LowDataRate,
            _ => return None,
        })
    }

    /// Ouster's name of the profile.
    pub fn name(self) -> &'static str {
        match self {
            LidarProfile::Legacy => "LEGACY",
            LidarProfile::Single => "RNG19_RFL8_SIG16_NIR16",
            LidarProfile::Dual => "RNG19_RFL8_SIG16_NIR16_DUAL",
            LidarProfile::LowDataRate => "RNG15_RFL8_NIR8",
        }
    }
}

/// The lidar packet header's layout (`lidar_data_format.header_type`, firmware 3.1 and later;
/// absent before, which is [`HeaderType::Standard`]). Not used by the `LEGACY` profile, which
/// has no packet header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HeaderType {
    /// `STANDARD` (firmware 2.2-3.0, and 3.1's default): packet type u16 at byte 0, frame id u16
    /// at 2, init id u24 at 4, serial number u40 at 7.
    #[default]
    Standard,
    /// `FUSA` (firmware 3.1's functional-safety header): packet type u8 at byte 0, init id u24
    /// at 1, frame id **u32** at 4, alert flags at 8, serial number u40 at 11.
    Fusa,
}

impl HeaderType {
    /// The header type of a `header_type` name.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "STANDARD" => Some(HeaderType::Standard),
            "FUSA" => Some(HeaderType::Fusa),
            _ => None,
        }
    }

    /// Ouster's name of the header type.
    pub fn name(self) -> &'static str {
        match self {
            HeaderType::Standard => "STANDARD",
            HeaderType::Fusa => "FUSA",
        }
    }

    /// Frame ids wrap modulo `mask + 1`: 2^16 in the standard header, 2^32 in `FUSA`.
    pub fn frame_id_mask(self) -> u32 {
        match self {
            HeaderType::Standard => 0xffff,
            HeaderType::Fusa => u32::MAX,
        }
    }
}

/// A 4x4 homogeneous transform, row-major, translation in mm (as in the metadata).
pub type Mat4 = [[f64; 4]; 4];

/// The sensor metadata that decoding and the XYZ lookup need.
#[derive(Debug, Clone, PartialEq)]
pub struct Metadata {
    /// Product line, e.g. `OS-1-128` (empty when absent).
    pub prod_line: String,
    /// Serial number (empty when absent).
    pub prod_sn: String,
    /// Firmware revision (`build_rev`, empty when absent).
    pub fw_rev: String,
    /// Lidar mode, e.g. `1024x10` (empty when absent).
    pub lidar_mode: String,
    /// Packet layout of the lidar packets.
    pub profile: LidarProfile,
    /// Layout of the lidar packets' header (not used by [`LidarProfile::Legacy`]).
    pub header_type: HeaderType,
    /// Channels (rows) per column.
    pub pixels_per_column: usize,
    /// Columns per lidar packet.
    pub columns_per_packet: usize,
    /// Columns (measurement ids) per frame (sweep).
    pub columns_per_frame: usize,
    /// First and last measurement id the sensor fires (the azimuth window; may wrap).
    pub column_window: [usize; 2],
    /// Per row, the shift (columns) that destaggers an image; unused by the XYZ lookup.
    pub pixel_shift_by_row: Vec<i64>,
    /// Per row, the beam's elevation, degrees.
    pub beam_altitude_angles_deg: Vec<f64>,
    /// Per row, the beam's azimuth offset, degrees.
    pub beam_azimuth_angles_deg: Vec<f64>,
    /// Beam origin in the lidar frame; when the file has no `beam_to_lidar_transform` (firmware
    /// 2.x), identity with `[0][3] = lidar_origin_to_beam_origin_mm`, as Ouster's docs define.
    pub beam_to_lidar_transform: Mat4,
    /// Lidar frame to sensor frame (`p_s = T * p_l`), translation mm.
    pub lidar_to_sensor_transform: Mat4,
    /// IMU frame to sensor frame (`p_s = T * p_imu`), translation mm.
    pub imu_to_sensor_transform: Mat4,
    /// Destination UDP port of the lidar packets, when given.
    pub udp_port_lidar: Option<u16>,
    /// Destination UDP port of the IMU packets, when given.
    pub udp_port_imu: Option<u16>,
}

fn bad(key: &str, msg: impl Into<String>) -> OusterError {
    OusterError::Metadata {
        key: key.to_string(),
        msg: msg.into(),
    }
}

/// Looks `key` up at the top level, then in each nested `section`.
fn find<'a>(root: &'a Value, sections: &[&str], key: &str) -> Option<&'a Value> {
    if let Some(v) = root.get(key) {
        return Some(v);
    }
    sections
        .iter()
        .find_map(|s| root.get(*s).and_then(|sec| sec.get(key)))
}

fn required<'a>(root: &'a Value, sections: &[&str], key: &str) -> Result<&'a Value, OusterError> {
    find(root, sections, key).ok_or_else(|| bad(key, "missing"))
}

fn as_f64(v: &Value, key: &str) -> Result<f64, OusterError> {
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| bad(key, format!("expected a finite number, found {v}")))
}

fn as_usize(v: &Value, key: &str) -> Result<usize, OusterError> {
    v.as_u64()
        .and_then(|x| usize::try_from(x).ok())
        .ok_or_else(|| bad(key, format!("expected a non-negative integer, found {v}")))
}

fn f64_array(v: &Value, key: &str, len: Option<usize>) -> Result<Vec<f64>, OusterError> {
    let arr = v
        .as_array()
        .ok_or_else(|| bad(key, "expected an array of numbers"))?;
    if let Some(n) = len {
        if arr.len() != n {
            return Err(bad(
                key,
                format!("expected {n} numbers, found {}", arr.len()),
            ));
        }
    }
    arr.iter().map(|x| as_f64(x, key)).collect()
}

fn mat4(v: &Value, key: &str) -> Result<Mat4, OusterError> {
    let a = f64_array(v, key, Some(16))?;
    let mut m = [[0.0; 4]; 4];
    for (i, x) in a.into_iter().enumerate() {
        m[i / 4][i % 4] = x;
    }
    Ok(m)
}

fn string_or_empty(root: &Value, sections: &[&str], key: &str) -> String {
    match find(root, sections, key) {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Number(n)) => n.to_string(),
        _ => String::new(),
    }
}

fn port(root: &Value, key: &str) -> Result<Option<u16>, OusterError> {
    match find(root, &["config_params"], key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => v
            .as_u64()
            .and_then(|p| u16::try_from(p).ok())
            .map(Some)
            .ok_or_else(|| bad(key, format!("expected a UDP port, found {v}"))),
    }
}

const FORMAT: &[&str] = &["data_format", "lidar_data_format"];
const BEAMS: &[&str] = &["beam_intrinsics"];

impl Metadata {
    /// Parses the metadata JSON text; errors name the key that is missing or wrong (the caller
    /// adds the file, see [`Metadata::from_file`]).
    pub fn from_json(text: &str) -> Result<Self, OusterError> {
        let root: Value =
            serde_json::from_str(text).map_err(|e| bad("(document)", format!("not JSON: {e}")))?;
        if !root.is_object() {
            return Err(bad("(document)", "expected a JSON object"));
        }
        let info: &[&str] = &["sensor_info"];
        let profile_name = find(&root, FORMAT, "udp_profile_lidar")
            .or_else(|| find(&root, &["config_params"], "udp_profile_lidar"));
        let profile = match profile_name {
            None | Some(Value::Null) => LidarProfile::Legacy,
            Some(v) => v
                .as_str()
                .and_then(LidarProfile::from_name)
                .ok_or_else(|| bad("udp_profile_lidar", format!("unsupported profile {v}")))?,
        };
        let header_type = match find(&root, FORMAT, "header_type") {
            None | Some(Value::Null) => HeaderType::Standard,
            Some(v) => v.as_str().and_then(HeaderType::from_name).ok_or_else(|| {
                bad(
                    "header_type",
                    format!("unsupported header type {v} (STANDARD and FUSA are read)"),
                )
            })?,
        };
        let rows = as_usize(
            required(&root, FORMAT, "pixels_per_column")?,
            "pixels_per_column",
        )?;
        let cols_packet = as_usize(
            required(&root, FORMAT, "columns_per_packet")?,
            "columns_per_packet",
        )?;
        let cols_frame = as_usize(
            required(&root, FORMAT, "columns_per_frame")?,
            "columns_per_frame",
        )?;
        if rows == 0 || rows > 1024 {
            return Err(bad(
                "pixels_per_column",
                format!("{rows} is not in 1..=1024"),
            ));
        }
        if cols_packet == 0 || cols_packet > 256 {
            return Err(bad(
                "columns_per_packet",
                format!("{cols_packet} is not in 1..=256"),
            ));
        }
        if cols_frame == 0 || cols_frame > 65536 {
            return Err(bad(
                "columns_per_frame",
                format!("{cols_frame} is not in 1..=65536"),
            ));
        }
        let column_window = match find(&root, FORMAT, "column_window") {
            None => [0, cols_frame - 1],
            Some(v) => {
                let w = v
                    .as_array()
                    .filter(|a| a.len() == 2)
                    .ok_or_else(|| bad("column_window", "expected [first, last]"))?;
                let w = [
                    as_usize(&w[0], "column_window")?,
                    as_usize(&w[1], "column_window")?,
                ];
                if w[0] >= cols_frame || w[1] >= cols_frame {
                    return Err(bad(
                        "column_window",
                        format!("{w:?} is outside 0..{cols_frame}"),
                    ));
                }
                w
            }
        };
        let pixel_shift_by_row = match find(&root, FORMAT, "pixel_shift_by_row") {
            None => vec![0; rows],
            Some(v) => v
                .as_array()
                .filter(|a| a.len() == rows)
                .and_then(|a| a.iter().map(Value::as_i64).collect::<Option<Vec<_>>>())
                .ok_or_else(|| bad("pixel_shift_by_row", format!("expected {rows} integers")))?,
        };
        let alt = f64_array(
            required(&root, BEAMS, "beam_altitude_angles")?,
            "beam_altitude_angles",
            Some(rows),
        )?;
        let azi = f64_array(
            required(&root, BEAMS, "beam_azimuth_angles")?,
            "beam_azimuth_angles",
            Some(rows),
        )?;
        let beam_to_lidar_transform = match find(&root, BEAMS, "beam_to_lidar_transform") {
            Some(v) if !v.is_null() => mat4(v, "beam_to_lidar_transform")?,
            _ => {
                let key = "lidar_origin_to_beam_origin_mm";
                let n = as_f64(required(&root, BEAMS, key)?, key)?;
                let mut m = identity();
                m[0][3] = n;
                m
            }
        };
        let l2s = "lidar_to_sensor_transform";
        let i2s = "imu_to_sensor_transform";
        Ok(Metadata {
            prod_line: string_or_empty(&root, info, "prod_line"),
            prod_sn: string_or_empty(&root, info, "prod_sn"),
            fw_rev: string_or_empty(&root, info, "build_rev"),
            lidar_mode: string_or_empty(&root, &["config_params"], "lidar_mode"),
            profile,
            header_type,
            pixels_per_column: rows,
            columns_per_packet: cols_packet,
            columns_per_frame: cols_frame,
            column_window,
            pixel_shift_by_row,
            beam_altitude_angles_deg: alt,
            beam_azimuth_angles_deg: azi,
            beam_to_lidar_transform,
            lidar_to_sensor_transform: mat4(required(&root, &["lidar_intrinsics"], l2s)?, l2s)?,
            imu_to_sensor_transform: mat4(required(&root, &["imu_intrinsics"], i2s)?, i2s)?,
            udp_port_lidar: port(&root, "udp_port_lidar")?,
            udp_port_imu: port(&root, "udp_port_imu")?,
        })
    }

    /// Frame ids wrap modulo `mask + 1`: 2^32 with the `FUSA` header, else 2^16 (`LEGACY`
    /// columns carry 16-bit ids whatever the header type says).
    pub fn frame_id_mask(&self) -> u32 {
        if self.profile == LidarProfile::Legacy {
            0xffff
        } else {
            self.header_type.frame_id_mask()
        }
    }

    /// Reads and parses a metadata file; errors name the file and the key.
    pub fn from_file(path: &std::path::Path) -> Result<Self, crate::IoError> {
        let text = std::fs::read_to_string(path).map_err(|e| crate::IoError::io(path, e))?;
        Self::from_json(&text).map_err(|e| crate::IoError::Invalid {
            path: path.to_path_buf(),
            msg: e.to_string(),
        })
    }

    /// Number of measurement ids inside [`Metadata::column_window`] (it may wrap past the last
    /// column): the columns a complete frame has.
    pub fn columns_in_window(&self) -> usize {
        let [a, b] = self.column_window;
        if a <= b {
            b - a + 1
        } else {
            self.columns_per_frame - a + b + 1
        }
    }

    /// Whether measurement id `m` is inside [`Metadata::column_window`].
    pub fn in_window(&self, m: usize) -> bool {
        let [a, b] = self.column_window;
        if a <= b {
            (a..=b).contains(&m)
        } else {
            m >= a || m <= b
        }
    }

    /// The IMU-to-sensor transform with its translation in metres.
    pub fn imu_to_sensor_m(&self) -> Mat4 {
        mm_to_m(self.imu_to_sensor_transform)
    }

    /// The lidar-to-sensor transform with its translation in metres.
    pub fn lidar_to_sensor_m(&self) -> Mat4 {
        mm_to_m(self.lidar_to_sensor_transform)
    }
}

fn identity() -> Mat4 {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

fn mm_to_m(mut m: Mat4) -> Mat4 {
    for row in m.iter_mut().take(3) {
        row[3] *= 1e-3;
    }
    m
}

/// Per (measurement id, row): the unit direction and the offset (m) so that a range `r` (mm)
/// is the point `r * 1e-3 * direction + offset_m` in the **sensor** frame.
///
/// Following Ouster's "Lidar Range to XYZ" (firmware user manual), with `b = beam_to_lidar`
/// (mm), `n = sqrt(b[0][3]^2 + b[2][3]^2)`, the encoder angle of measurement id `m`
/// `θe = 2π (1 - m / columns_per_frame)`, the beam's azimuth `θa = -2π azimuth_deg / 360` and
/// elevation `φ = 2π altitude_deg / 360`, the point in the lidar frame is
/// `x = (r - n) cos(θe + θa) cos φ + b[0][3] cos θe`,
/// `y = (r - n) sin(θe + θa) cos φ + b[0][3] sin θe`,
/// `z = (r - n) sin φ + b[2][3]`; it is then mapped by `lidar_to_sensor_transform`.
#[derive(Debug, Clone, PartialEq)]
pub struct XyzLut {
    rows: usize,
    cols: usize,
    /// Unit direction, sensor frame, index `m * rows + row`.
    direction: Vec<[f64; 3]>,
    /// Offset, m, sensor frame, index `m * rows + row`.
    offset_m: Vec<[f64; 3]>,
}

impl XyzLut {
    /// Builds the lookup for every measurement id and row of `meta`.
    pub fn new(meta: &Metadata) -> Self {
        let (rows, cols) = (meta.pixels_per_column, meta.columns_per_frame);
        let b = &meta.beam_to_lidar_transform;
        let t = &meta.lidar_to_sensor_transform;
        let n = (b[0][3] * b[0][3] + b[2][3] * b[2][3]).sqrt();
        let rot = |v: [f64; 3]| -> [f64; 3] {
            core::array::from_fn(|i| t[i][0] * v[0] + t[i][1] * v[1] + t[i][2] * v[2])
        };
        let mut direction = Vec::with_capacity(rows * cols);
        let mut offset_m = Vec::with_capacity(rows * cols);
        for m in 0..cols {
            let enc = 2.0 * std::f64::consts::PI * (1.0 - m as f64 / cols as f64);
            for row in 0..rows {
                // Parsed metadata has one angle per row; hand-edited fields may not (0 then).
                let azi = -meta
                    .beam_azimuth_angles_deg
                    .get(row)
                    .map_or(0.0, |a| a.to_radians());
                let alt = meta
                    .beam_altitude_angles_deg
                    .get(row)
                    .map_or(0.0, |a| a.to_radians());
                let d = [
                    (enc + azi).cos() * alt.cos(),
                    (enc + azi).sin() * alt.cos(),
                    alt.sin(),
                ];
                // Lidar-frame offset (mm): the point at r is (r - n) d + o.
                let o = [
                    b[0][3] * enc.cos() - n * d[0],
                    b[0][3] * enc.sin() - n * d[1],
                    b[2][3] - n * d[2],
                ];
                let os = rot(o);
                direction.push(rot(d));
                offset_m.push(core::array::from_fn(|i| (os[i] + t[i][3]) * 1e-3));
            }
        }
        XyzLut {
            rows,
            cols,
            direction,
            offset_m,
        }
    }

    /// The point (m, sensor frame) of range `range_mm` at measurement id `m` and `row`;
    /// `None` when `m` or `row` is out of range.
    pub fn point_m(&self, m: usize, row: usize, range_mm: u32) -> Option<[f64; 3]> {
        if m >= self.cols || row >= self.rows {
            return None;
        }
        let i = m * self.rows + row;
        let (d, o) = (self.direction.get(i)?, self.offset_m.get(i)?);
        let r_m = f64::from(range_mm) * 1e-3;
        Some(core::array::from_fn(|k| r_m * d[k] + o[k]))
    }
}
