//! Trajectory files.
//!
//! - TUM: `t[s] x y z qx qy qz qw` per line, the body `b` in the world `w`; `#` starts a comment.
//!   Times are written with 9 decimals so nanosecond stamps survive the round trip.
//! - EuRoC ground truth (`state_groundtruth_estimate0/data.csv`): `#timestamp [ns], p_RS_R_x [m],
//!   p_RS_R_y, p_RS_R_z, q_RS_w [], q_RS_x, q_RS_y, q_RS_z, v_RS_R_x [m s^-1], v_RS_R_y, v_RS_R_z,
//!   b_w_RS_S_x [rad s^-1], b_w_RS_S_y, b_w_RS_S_z, b_a_RS_S_x [m s^-2], b_a_RS_S_y, b_a_RS_S_z`:
//!   the full state of the body (`S` = IMU) in the world (`R`), quaternion w first.

use crate::error::IoError;
use nalgebra::Quaternion;
use povins_core::inertial::NavState;
use povins_core::math::{Quat, Vec3};
use std::io::{BufRead, BufWriter, Write};
use std::path::Path;

/// A timestamped pose of the body `b` in the world `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    /// Time, integer nanoseconds.
    pub t_ns: i64,
    /// Position of the body in `w`, m.
    pub p_wb: Vec3,
    /// Rotation body -> world.
    pub q_wb: Quat,
}

impl From<&NavState> for StampedPose {
    fn from(s: &NavState) -> Self {
        StampedPose {
            t_ns: s.t_ns,
            p_wb: s.p_wb,
            q_wb: s.q_wb,
        }
    }
}

/// Seconds (as written in TUM files) to integer nanoseconds, rounding to the nearest.
pub fn seconds_to_ns(t_s: f64) -> i64 {
    (t_s * 1e9).round() as i64
}

/// Integer nanoseconds as exact decimal seconds with 9 decimals.
pub fn ns_to_seconds_string(t_ns: i64) -> String {
    let sign = if t_ns < 0 { "-" } else { "" };
    let a = t_ns.unsigned_abs();
    format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000)
}

/// Parses a decimal-seconds string to integer nanoseconds without going through `f64`, so
/// `ns_to_seconds_string` round-trips exactly; falls back to `f64` for exponents.
fn parse_seconds_ns(s: &str) -> Option<i64> {
    if s.contains(['e', 'E']) {
        let v: f64 = s.parse().ok()?;
        return v.is_finite().then(|| seconds_to_ns(v));
    }
    let (neg, body) = match s.strip_prefix('-') {
        Some(b) => (true, b),
        None => (false, s),
    };
    let (int, frac) = body.split_once('.').unwrap_or((body, ""));
    if int.is_empty() && frac.is_empty() {
        return None;
    }
    let int_v: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let mut frac_ns: i64 = 0;
    let mut scale = 100_000_000;
    for (i, ch) in frac.chars().enumerate() {
        let d = ch.to_digit(10)? as i64;
        if i < 9 {
            frac_ns += d * scale;
            scale /= 10;
        } else if i == 9 && d >= 5 {
            frac_ns += 1;
        }
    }
    let v = int_v.checked_mul(1_000_000_000)?.checked_add(frac_ns)?;
    Some(if neg { -v } else { v })
}

fn open(path: &Path) -> Result<std::io::BufReader<std::fs::File>, IoError> {
    std::fs::File::open(path)
        .map(std::io::BufReader::new)
        .map_err(|e| IoError::io(path, e))
}

fn parse_err(path: &Path, line: usize, msg: impl Into<String>) -> IoError {
    IoError::Parse {
        path: path.into(),
        line,
        msg: msg.into(),
    }
}

fn unit_quat(path: &Path, line: usize, w: f64, x: f64, y: f64, z: f64) -> Result<Quat, IoError> {
    let n = (w * w + x * x + y * y + z * z).sqrt();
    if !(n.is_finite() && (n - 1.0).abs() < 1e-2) {
        return Err(parse_err(
            path,
            line,
            format!("quaternion norm {n} is not 1"),
        ));
    }
    Ok(Quat::from_quaternion(Quaternion::new(w, x, y, z)))
}

/// Splits a data line into numeric fields, by commas or whitespace.
fn fields(path: &Path, line_no: usize, line: &str, want: usize) -> Result<Vec<f64>, IoError> {
    let parts: Vec<&str> = line
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .collect();
    if parts.len() != want {
        return Err(parse_err(
            path,
            line_no,
            format!("expected {want} fields, found {}", parts.len()),
        ));
    }
    parts
        .iter()
        .enumerate()
        .map(|(i, p)| match p.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(parse_err(
                path,
                line_no,
                format!("field {} ({p:?}) is not a finite number", i + 1),
            )),
        })
        .collect()
}

fn check_increasing(path: &Path, line: usize, prev: Option<i64>, t: i64) -> Result<(), IoError> {
    match prev {
        Some(p) if t <= p => Err(parse_err(
            path,
            line,
            format!("time {t} ns does not increase (previous {p} ns)"),
        )),
        _ => Ok(()),
    }
}

/// Reads a TUM trajectory. Blank lines and `#` comments are allowed; anything else must be a
/// valid pose with increasing time.
pub fn read_tum(path: &Path) -> Result<Vec<StampedPose>, IoError> {
    tum_poses(path)?.collect()
}

/// A TUM trajectory read pose by pose ([`read_tum`]'s rules), in memory that does not grow
/// with the file.
pub fn tum_poses(path: &Path) -> Result<TumPoses, IoError> {
    Ok(TumPoses {
        path: path.into(),
        lines: open(path)?.lines(),
        line_no: 0,
        last_ns: None,
        failed: false,
    })
}

/// The iterator of [`tum_poses`]: ends after the first error.
pub struct TumPoses {
    path: std::path::PathBuf,
    lines: std::io::Lines<std::io::BufReader<std::fs::File>>,
    line_no: usize,
    last_ns: Option<i64>,
    failed: bool,
}

impl TumPoses {
    fn parse(&mut self, line: &str) -> Result<Option<StampedPose>, IoError> {
        let (path, line_no) = (self.path.as_path(), self.line_no);
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            return Ok(None);
        }
        let first = l
            .split(|c: char| c == ',' || c.is_whitespace())
            .next()
            .unwrap_or("");
        let t_ns = parse_seconds_ns(first)
            .ok_or_else(|| parse_err(path, line_no, format!("time {first:?} is not a number")))?;
        let v = fields(path, line_no, l, 8)?;
        check_increasing(path, line_no, self.last_ns, t_ns)?;
        let q_wb = unit_quat(path, line_no, v[7], v[4], v[5], v[6])?;
        self.last_ns = Some(t_ns);
        Ok(Some(StampedPose {
            t_ns,
            p_wb: Vec3::new(v[1], v[2], v[3]),
            q_wb,
        }))
    }
}

impl Iterator for TumPoses {
    type Item = Result<StampedPose, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.failed {
            let line = self.lines.next()?;
            self.line_no += 1;
            let r = line
                .map_err(|e| IoError::io(&self.path, e))
                .and_then(|l| self.parse(&l));
            match r {
                Ok(Some(p)) => return Some(Ok(p)),
                Ok(None) => {}
                Err(e) => {
                    self.failed = true;
                    return Some(Err(e));
                }
            }
        }
        None
    }
}

/// Writes a TUM trajectory.
pub fn write_tum(path: &Path, poses: &[StampedPose]) -> Result<(), IoError> {
    let f = std::fs::File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut w = BufWriter::new(f);
    let mut body = || -> std::io::Result<()> {
        write_tum_header(&mut w)?;
        for p in poses {
            write_tum_row(&mut w, p)?;
        }
        w.flush()
    };
    body().map_err(|e| IoError::io(path, e))
}

/// The header line of a TUM trajectory as [`write_tum`] writes it (for a writer that streams
/// the rows with [`write_tum_row`]).
pub fn write_tum_header(w: &mut impl Write) -> std::io::Result<()> {
    writeln!(w, "# t[s] x y z qx qy qz qw (body in world)")
}

/// One pose of a TUM trajectory: exact decimal seconds, then position and quaternion (x y z w)
/// as the shortest decimals that read back to the same `f64`.
pub fn write_tum_row(w: &mut impl Write, p: &StampedPose) -> std::io::Result<()> {
    let q = p.q_wb.quaternion();
    writeln!(
        w,
        "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?}",
        ns_to_seconds_string(p.t_ns),
        p.p_wb.x,
        p.p_wb.y,
        p.p_wb.z,
        q.i,
        q.j,
        q.k,
        q.w
    )
}

/// Reads an EuRoC `state_groundtruth_estimate0/data.csv` (full state).
pub fn read_euroc_groundtruth(path: &Path) -> Result<Vec<NavState>, IoError> {
    GroundTruthRows::open(path)?.collect()
}

/// The rows of an EuRoC `state_groundtruth_estimate0/data.csv` (full state), one at a time
/// (what [`read_euroc_groundtruth`] collects): an evaluation can pass over an hour of ground
/// truth without holding it. An error (naming the file and line) ends the stream.
pub struct GroundTruthRows {
    path: std::path::PathBuf,
    lines: std::iter::Enumerate<std::io::Lines<std::io::BufReader<std::fs::File>>>,
    last: Option<i64>,
    failed: bool,
}

impl GroundTruthRows {
    /// Opens the file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        Ok(GroundTruthRows {
            path: path.into(),
            lines: open(path)?.lines().enumerate(),
            last: None,
            failed: false,
        })
    }
}

/// One data row of an EuRoC ground-truth CSV, after the row stamped `last`.
fn ground_truth_row(
    path: &Path,
    last: &mut Option<i64>,
    line_no: usize,
    l: &str,
) -> Result<NavState, IoError> {
    let t_str = l.split(',').next().unwrap_or("").trim();
    let t_ns: i64 = t_str.parse().map_err(|_| {
        parse_err(
            path,
            line_no,
            format!("timestamp {t_str:?} is not integer nanoseconds"),
        )
    })?;
    let v = fields(path, line_no, l, 17)?;
    check_increasing(path, line_no, *last, t_ns)?;
    *last = Some(t_ns);
    Ok(NavState {
        t_ns,
        p_wb: Vec3::new(v[1], v[2], v[3]),
        q_wb: unit_quat(path, line_no, v[4], v[5], v[6], v[7])?,
        v_wb: Vec3::new(v[8], v[9], v[10]),
        bg: Vec3::new(v[11], v[12], v[13]),
        ba: Vec3::new(v[14], v[15], v[16]),
    })
}

impl Iterator for GroundTruthRows {
    type Item = Result<NavState, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        for (i, line) in self.lines.by_ref() {
            let r = match line {
                Err(e) => Err(IoError::io(&self.path, e)),
                Ok(line) => {
                    let l = line.trim();
                    if l.is_empty() || l.starts_with('#') {
                        continue;
                    }
                    ground_truth_row(&self.path, &mut self.last, i + 1, l)
                }
            };
            if r.is_err() {
                self.failed = true;
            }
            return Some(r);
        }
        None
    }
}

/// Writes an EuRoC ground-truth CSV (exact `f64` formatting, so reading it back is lossless).
pub fn write_euroc_groundtruth(path: &Path, states: &[NavState]) -> Result<(), IoError> {
    let f = std::fs::File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut w = BufWriter::new(f);
    let mut body = || -> std::io::Result<()> {
        writeln!(
            w,
            "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
        )?;
        for s in states {
            let q = s.q_wb.quaternion();
            writeln!(
                w,
                "{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
                s.t_ns,
                s.p_wb.x, s.p_wb.y, s.p_wb.z,
                q.w, q.i, q.j, q.k,
                s.v_wb.x, s.v_wb.y, s.v_wb.z,
                s.bg.x, s.bg.y, s.bg.z,
                s.ba.x, s.ba.y, s.ba.z
            )?;
        }
        w.flush()
    };
    body().map_err(|e| IoError::io(path, e))
}

/// Reads a trajectory in either format, as poses: a file whose first data line has 17
/// comma-separated fields is EuRoC ground truth, otherwise TUM.
pub fn read_trajectory(path: &Path) -> Result<Vec<StampedPose>, IoError> {
    let mut first = None;
    for line in open(path)?.lines() {
        let line = line.map_err(|e| IoError::io(path, e))?;
        let l = line.trim().to_string();
        if !l.is_empty() && !l.starts_with('#') {
            first = Some(l);
            break;
        }
    }
    match first {
        Some(l) if l.split(',').count() == 17 => Ok(read_euroc_groundtruth(path)?
            .iter()
            .map(StampedPose::from)
            .collect()),
        Some(_) => read_tum(path),
        None => Err(IoError::Invalid {
            path: path.into(),
            msg: "no poses in file".into(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The repository's copy (`tests/data`) when there is one, else `../shared/data`.
    fn shared(rel: &str) -> std::path::PathBuf {
        let repo = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data")).join(rel);
        if repo.exists() {
            return repo;
        }
        let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")).join(rel);
        assert!(
            p.exists(),
            "shared data not found at {} (clone the repo next to shared/)",
            p.display()
        );
        p
    }

    #[test]
    fn seconds_strings_round_trip_exactly() {
        for t in [
            0i64,
            1,
            999_999_999,
            1_403_715_273_262_142_976,
            -1_500_000_001,
        ] {
            assert_eq!(parse_seconds_ns(&ns_to_seconds_string(t)), Some(t));
        }
        assert_eq!(parse_seconds_ns("1.5"), Some(1_500_000_000));
        assert_eq!(parse_seconds_ns("2.0000000015"), Some(2_000_000_002));
        assert_eq!(parse_seconds_ns("x"), None);
    }

    #[test]
    fn euroc_groundtruth_reads_real_file_and_round_trips() {
        let p = shared("euroc-v101-30s-features/mav0/state_groundtruth_estimate0/data.csv");
        let gt = read_euroc_groundtruth(&p).unwrap();
        assert!(gt.len() > 500, "{} rows", gt.len());
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("gt.csv");
        write_euroc_groundtruth(&out, &gt).unwrap();
        let back = read_euroc_groundtruth(&out).unwrap();
        assert_eq!(back.len(), gt.len());
        for (a, b) in back.iter().zip(&gt) {
            // Renormalizing an already unit quaternion may move its last bit; all else is exact.
            assert!(a.q_wb.angle_to(&b.q_wb) < 1e-15);
            assert_eq!(
                (a.t_ns, a.p_wb, a.v_wb, a.bg, a.ba),
                (b.t_ns, b.p_wb, b.v_wb, b.bg, b.ba)
            );
        }
        let poses = read_trajectory(&out).unwrap();
        assert_eq!(poses.len(), gt.len());
        let tum = dir.path().join("gt.tum");
        write_tum(&tum, &poses).unwrap();
        let back = read_trajectory(&tum).unwrap();
        assert_eq!(back.len(), poses.len());
        for (a, b) in back.iter().zip(&poses) {
            assert_eq!(a.t_ns, b.t_ns);
            assert_eq!(a.p_wb, b.p_wb);
            assert!(a.q_wb.angle_to(&b.q_wb) < 1e-15);
        }
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.tum");
        let cases = [
            (
                "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0\n",
                2,
                "expected 8 fields",
            ),
            (
                "1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n",
                2,
                "does not increase",
            ),
            ("# c\n1.0 0 0 nan 0 0 0 1\n", 2, "not a finite number"),
            ("1.0 0 0 0 0 0 0 2\n", 1, "quaternion norm"),
        ];
        for (text, line, msg) in cases {
            std::fs::write(&p, text).unwrap();
            match read_tum(&p) {
                Err(IoError::Parse {
                    line: l, msg: m, ..
                }) => {
                    assert_eq!(l, line, "{text:?}");
                    assert!(m.contains(msg), "{m}");
                }
                other => panic!("{text:?}: expected parse error, got {other:?}"),
            }
        }
    }
}
