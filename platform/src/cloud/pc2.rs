//! `sensor_msgs/PointCloud2` point data: the decoder that tells the layout (module docs of
//! [`super`]) and the encoder of each [`Layout`].

use super::datatype::{self, FLOAT32, FLOAT64, INT16, INT32, INT8, UINT16, UINT32, UINT8};
use super::{
    float_to_ns, livox, ns_to_f64_s, CloudCounts, CloudOptions, Decoded, Layout, NoTime, TimeRef,
    TimeSource, TimeSpec, TimeUnit, MAX_SWEEP_SPAN_NS,
};
use crate::dataset::LidarScan;
use crate::ros2::msgs::{PointCloud2, PointField};
use povins_core::lidar::LidarPoint;

/// Names a point time field goes by, in the order they are looked for.
const TIME_FIELDS: [&str; 5] = ["t", "time", "timestamp", "time_stamp", "offset_time"];

/// Points sampled to check a time reading against the stamp.
const FIT_SAMPLES: usize = 33;

/// A field of the cloud, checked to fit inside a point.
#[derive(Debug, Clone, Copy)]
struct Field {
    offset: usize,
    dt: u8,
}

/// A field's value: integers exactly, floats as float64.
#[derive(Debug, Clone, Copy)]
enum Raw {
    Int(i64),
    Float(f64),
}

fn bytes<const N: usize>(p: &[u8], o: usize) -> [u8; N] {
    let mut a = [0u8; N];
    if let Some(s) = p.get(o..o + N) {
        a.copy_from_slice(s);
    }
    a
}

fn read(p: &[u8], f: Field) -> Raw {
    let o = f.offset;
    match f.dt {
        INT8 => Raw::Int(i64::from(i8::from_le_bytes(bytes(p, o)))),
        UINT8 => Raw::Int(i64::from(bytes::<1>(p, o)[0])),
        INT16 => Raw::Int(i64::from(i16::from_le_bytes(bytes(p, o)))),
        UINT16 => Raw::Int(i64::from(u16::from_le_bytes(bytes(p, o)))),
        INT32 => Raw::Int(i64::from(i32::from_le_bytes(bytes(p, o)))),
        UINT32 => Raw::Int(i64::from(u32::from_le_bytes(bytes(p, o)))),
        FLOAT32 => Raw::Float(f64::from(f32::from_le_bytes(bytes(p, o)))),
        _ => Raw::Float(f64::from_le_bytes(bytes(p, o))),
    }
}

fn as_f64(r: Raw) -> f64 {
    match r {
        Raw::Int(v) => v as f64,
        Raw::Float(v) => v,
    }
}

/// The time of a point whose field holds `raw`, read as `unit` from `reference`; `None` when
/// not finite or out of range.
fn time_ns(raw: Raw, unit: TimeUnit, reference: TimeRef, stamp_ns: i64) -> Option<i64> {
    let v = match raw {
        Raw::Int(v) => v.checked_mul(unit.ns())?,
        Raw::Float(v) => float_to_ns(v, unit)?,
    };
    match reference {
        TimeRef::Header => stamp_ns.checked_add(v),
        TimeRef::Absolute => Some(v),
    }
}

/// The readings of a time field to try, and how many of the first ones its name and type
/// suggest (the others are taken with a warning).
fn readings(name: &str, dt: u8) -> (&'static [(TimeUnit, TimeRef)], usize) {
    use TimeRef::{Absolute as A, Header as H};
    use TimeUnit::{Ns, Us, S};
    let float = dt == FLOAT32 || dt == FLOAT64;
    match (name, float) {
        ("timestamp" | "time_stamp", true) => (&[(S, A), (Ns, A), (Us, A), (S, H), (Ns, H)], 2),
        ("timestamp" | "time_stamp", false) => (&[(Ns, A), (Us, A), (Ns, H), (Us, H)], 1),
        (_, true) => (&[(S, H), (S, A), (Ns, A), (Us, H), (Ns, H)], 1),
        (_, false) => (&[(Ns, H), (Us, H), (Ns, A), (Us, A)], 1),
    }
}

/// The cloud's point data, checked: the points' bytes are within `data`.
struct Points<'a> {
    m: &'a PointCloud2,
    step: usize,
    row: usize,
    w: usize,
    h: usize,
}

impl<'a> Points<'a> {
    fn new(m: &'a PointCloud2) -> Result<Self, String> {
        if m.is_bigendian {
            return Err("big-endian point data is not supported".into());
        }
        let (step, row) = (m.point_step as usize, m.row_step as usize);
        let (w, h) = (m.width as usize, m.height as usize);
        if step == 0 && w * h > 0 {
            return Err("point_step is 0".into());
        }
        if w.checked_mul(step).is_none_or(|b| b > row) {
            return Err(format!(
                "width {w} x point_step {step} exceeds row_step {row}"
            ));
        }
        // The last row needs only its points, not its padding.
        let need = h
            .checked_sub(1)
            .map_or(Some(0), |r| r.checked_mul(row)?.checked_add(w * step));
        if need.is_none_or(|b| b > m.data.len()) {
            return Err(format!(
                "{h} rows of {row} bytes ({w} points of {step} bytes) exceed the {} data bytes",
                m.data.len()
            ));
        }
        Ok(Points { m, step, row, w, h })
    }

    fn len(&self) -> usize {
        self.w * self.h
    }

    /// The bytes of point `k` (row-major).
    fn get(&self, k: usize) -> &'a [u8] {
        let (r, c) = (k / self.w.max(1), k % self.w.max(1));
        let start = r * self.row + c * self.step;
        self.m.data.get(start..start + self.step).unwrap_or(&[])
    }

    /// The field `name`, when the cloud has it; an error when it does not fit a point.
    fn field(&self, name: &str) -> Result<Option<Field>, String> {
        let Some(f) = self.m.fields.iter().find(|f| f.name == name) else {
            return Ok(None);
        };
        let size = datatype::size(f.datatype)
            .ok_or_else(|| format!("field {name:?} has unknown datatype {}", f.datatype))?;
        if f.count == 0 {
            return Err(format!("field {name:?} has count 0"));
        }
        if (f.offset as usize).saturating_add(size) > self.step {
            return Err(format!(
                "field {name:?} ({} at offset {}) does not fit the point_step {}",
                datatype::name(f.datatype),
                f.offset,
                self.step
            ));
        }
        Ok(Some(Field {
            offset: f.offset as usize,
            dt: f.datatype,
        }))
    }

    fn coordinate(&self, name: &str) -> Result<Field, String> {
        let f = self.field(name)?.ok_or_else(|| {
            let names: Vec<&str> = self.m.fields.iter().map(|f| f.name.as_str()).collect();
            format!(
                "point field {name:?} is missing (the cloud's fields: {})",
                names.join(", ")
            )
        })?;
        if f.dt != FLOAT32 && f.dt != FLOAT64 {
            return Err(format!(
                "point field {name:?} is {}, expected float32 or float64",
                datatype::name(f.dt)
            ));
        }
        Ok(f)
    }

    /// Whether at least 3/4 of the sampled points' times, read as `(unit, reference)`, are
    /// near the stamp (a few stray times are dropped later, and do not decide the reading).
    fn fits(&self, f: Field, unit: TimeUnit, reference: TimeRef) -> bool {
        let n = self.len();
        let stamp = self.m.header.t_ns;
        let samples = FIT_SAMPLES.min(n);
        let (mut seen, mut near) = (0usize, 0usize);
        for i in 0..samples {
            let k = if samples > 1 {
                i * (n - 1) / (samples - 1)
            } else {
                0
            };
            let raw = read(self.get(k), f);
            if matches!(raw, Raw::Float(v) if !v.is_finite()) {
                continue;
            }
            seen += 1;
            near += usize::from(
                time_ns(raw, unit, reference, stamp)
                    .is_some_and(|t| (t - stamp).abs() <= MAX_SWEEP_SPAN_NS),
            );
        }
        4 * near >= 3 * seen
    }

    /// The time field and how it is read (module docs of [`super`]).
    fn time_reading(&self, opts: &CloudOptions) -> Result<Option<(Field, TimeSpec, bool)>, String> {
        if let Some(layout) = opts.layout {
            let spec = layout.time();
            let f = self.field(spec.field)?.ok_or_else(|| {
                format!(
                    "layout {}: the cloud has no field {:?}",
                    layout.name(),
                    spec.field
                )
            })?;
            return Ok(Some((f, spec, true)));
        }
        for name in TIME_FIELDS {
            let Some(f) = self.field(name)? else {
                continue;
            };
            let (all, expected) = readings(name, f.dt);
            for (k, &(unit, reference)) in all.iter().enumerate() {
                if self.fits(f, unit, reference) {
                    let spec = TimeSpec {
                        field: name,
                        unit,
                        reference,
                    };
                    return Ok(Some((f, spec, k < expected)));
                }
            }
            let first = if self.len() > 0 {
                as_f64(read(self.get(0), f))
            } else {
                f64::NAN
            };
            return Err(format!(
                "the point times in field {name:?} ({}, first value {first}) are not within \
                 1 s of header.stamp {} ns in s, ms or ns, after the stamp or since the epoch; \
                 set the layout ([input] lidar_layout)",
                datatype::name(f.dt),
                self.m.header.t_ns
            ));
        }
        Ok(None)
    }
}

/// Decodes a cloud in any driver layout (module docs of [`super`]).
pub fn decode_point_cloud2(m: &PointCloud2, opts: &CloudOptions) -> Result<Decoded, String> {
    let pts = Points::new(m)?;
    let (fx, fy, fz) = (
        pts.coordinate("x")?,
        pts.coordinate("y")?,
        pts.coordinate("z")?,
    );
    let fi = match pts.field("intensity")? {
        Some(f) => Some(f),
        None => pts.field("reflectivity")?,
    };
    let ftag = pts
        .field("tag")?
        .filter(|f| f.dt == UINT8 && opts.layout.is_none_or(|l| l == Layout::Livox2));
    let reading = pts.time_reading(opts)?;
    let stamp = m.header.t_ns;
    let mut counts = CloudCounts {
        points: pts.len() as u64,
        ..CloudCounts::default()
    };
    let mut points = Vec::with_capacity(pts.len());
    let mut spin = Spin::default();
    for k in 0..pts.len() {
        let p = pts.get(k);
        let xyz = [fx, fy, fz].map(|f| as_f64(read(p, f)));
        if xyz.iter().any(|v| !v.is_finite()) {
            counts.non_finite += 1;
            continue;
        }
        if xyz == [0.0; 3] {
            counts.no_return += 1;
            continue;
        }
        if ftag.is_some_and(|f| matches!(read(p, f), Raw::Int(t) if livox::is_noise(t as u8))) {
            counts.flagged_noise += 1;
            continue;
        }
        let t_ns = match reading {
            Some((f, spec, _)) => {
                let raw = read(p, f);
                match time_ns(raw, spec.unit, spec.reference, stamp) {
                    Some(t) => t,
                    None => {
                        counts.non_finite += 1;
                        continue;
                    }
                }
            }
            None => spin.time(opts.no_time, stamp, xyz),
        };
        if (t_ns - stamp).abs() > MAX_SWEEP_SPAN_NS {
            counts.out_of_sweep += 1;
            continue;
        }
        points.push(LidarPoint {
            t_ns,
            p_l: xyz.map(|v| v as f32),
            intensity: fi.map_or(0.0, |f| as_f64(read(p, f)) as f32),
        });
    }
    let time = match reading {
        Some((_, spec, expected)) => TimeSource::Field { spec, expected },
        None => TimeSource::Assumed(opts.no_time),
    };
    Ok(Decoded {
        scan: LidarScan {
            t_ns: stamp,
            points,
        },
        counts,
        time,
    })
}

/// Point times from azimuth for a cloud without them ([`NoTime`]).
#[derive(Debug, Default)]
struct Spin {
    first_azimuth: Option<f64>,
}

impl Spin {
    fn time(&mut self, no_time: NoTime, stamp: i64, xyz: [f64; 3]) -> i64 {
        let NoTime::Spin {
            period_ns,
            clockwise,
            stamp_is_end,
        } = no_time
        else {
            return stamp;
        };
        let a = xyz[1].atan2(xyz[0]);
        let a0 = *self.first_azimuth.get_or_insert(a);
        let turned = if clockwise { a0 - a } else { a - a0 };
        let frac = turned.rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU;
        let into = (frac * period_ns as f64).round() as i64;
        if stamp_is_end {
            stamp - period_ns + into
        } else {
            stamp + into
        }
    }
}

/// Writes `v` into the field at `offset` of type `dt` (a float cast to the field's type).
fn put(buf: &mut [u8], offset: u32, dt: u8, v: f64) {
    let o = offset as usize;
    let mut write = |b: &[u8]| {
        if let Some(s) = buf.get_mut(o..o + b.len()) {
            s.copy_from_slice(b);
        }
    };
    match dt {
        UINT8 => write(&[v as u8]),
        UINT16 => write(&(v as u16).to_le_bytes()),
        UINT32 => write(&(v as u32).to_le_bytes()),
        FLOAT32 => write(&(v as f32).to_le_bytes()),
        _ => write(&v.to_le_bytes()),
    }
}

/// The fields, point step and point data of `scan` in `layout` (little-endian, one row), as the
/// driver writes them: times relative to `scan.t_ns` or since the epoch by the layout; `ring`,
/// `line`, `tag`, `reflectivity` and `ambient` zero; Ouster's `range` the distance in mm. A
/// point time that the layout cannot hold (before the stamp, or 2^32 ns after it, in a `uint32`
/// field) is an error.
pub fn encode_points(
    layout: Layout,
    scan: &LidarScan,
) -> Result<(Vec<PointField>, u32, Vec<u8>), String> {
    let step = layout.point_step() as usize;
    let spec = layout.time();
    let mut data = vec![0u8; step * scan.points.len()];
    for (i, (p, buf)) in scan
        .points
        .iter()
        .zip(data.chunks_exact_mut(step))
        .enumerate()
    {
        let [x, y, z] = p.p_l;
        for &(name, offset, dt) in layout.fields() {
            let v = match name {
                "x" => f64::from(x),
                "y" => f64::from(y),
                "z" => f64::from(z),
                "intensity" => f64::from(p.intensity),
                "range" => (f64::from(x).hypot(f64::from(y)).hypot(f64::from(z)) * 1e3).round(),
                n if n == spec.field => {
                    // Integer times are written exactly, not through a float64.
                    if dt == UINT32 {
                        let d = u32::try_from(p.t_ns - scan.t_ns).map_err(|_| {
                            format!(
                                "point {i} at {} ns is not within 2^32 ns after the sweep stamp \
                                 {} ns",
                                p.t_ns, scan.t_ns
                            )
                        })?;
                        let o = offset as usize;
                        if let Some(s) = buf.get_mut(o..o + 4) {
                            s.copy_from_slice(&d.to_le_bytes());
                        }
                        continue;
                    }
                    match (spec.reference, spec.unit) {
                        (TimeRef::Header, u) => (p.t_ns - scan.t_ns) as f64 / u.ns() as f64,
                        (TimeRef::Absolute, TimeUnit::S) => ns_to_f64_s(p.t_ns),
                        (TimeRef::Absolute, u) => p.t_ns as f64 / u.ns() as f64,
                    }
                }
                _ => 0.0,
            };
            put(buf, offset, dt, v);
        }
    }
    let fields = layout
        .fields()
        .iter()
        .map(|&(name, offset, datatype)| PointField {
            name: name.into(),
            offset,
            datatype,
            count: 1,
        })
        .collect();
    Ok((fields, step as u32, data))
}
