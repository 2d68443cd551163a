//! The `data.csv` files of an EuRoC folder read row by row: each stream holds one line buffer
//! and at most one message being assembled, whatever the file's length. Errors name the file and
//! the line (times must increase; the rows of a feature frame or LiDAR sweep are consecutive and
//! share its stamp; feature ids are unique within a frame).

use super::csv::CsvLines;
use crate::dataset::{FeatureFrame, ImageFrame, LidarScan};
use crate::error::IoError;
use povins_core::camera::{FeatureObs, PinholeCamera};
use povins_core::inertial::ImuSample;
use povins_core::lidar::LidarPoint;
use povins_core::math::Vec3;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// `imu0/data.csv`: `#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_z [m s^-2]`.
pub struct ImuRows {
    c: CsvLines,
    last: Option<i64>,
}

impl ImuRows {
    /// Opens the file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        Ok(ImuRows {
            c: CsvLines::open(path, 7)?,
            last: None,
        })
    }

    fn row(&mut self) -> Result<Option<ImuSample>, IoError> {
        let c = &mut self.c;
        if !c.next_line()? {
            return Ok(None);
        }
        let f = c.fields::<7>()?;
        let t_ns = c.ns(0, f[0])?;
        c.check_time(self.last, t_ns, false)?;
        self.last = Some(t_ns);
        Ok(Some(ImuSample {
            t_ns,
            gyro_rps: Vec3::new(c.f64(1, f[1])?, c.f64(2, f[2])?, c.f64(3, f[3])?),
            accel_mps2: Vec3::new(c.f64(4, f[4])?, c.f64(5, f[5])?, c.f64(6, f[6])?),
        }))
    }
}

impl Iterator for ImuRows {
    type Item = Result<ImuSample, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.row().transpose()
    }
}

/// Rows grouped into messages by their first column: consecutive rows with one stamp are one
/// message (a feature frame, a LiDAR sweep).
struct Grouped<T> {
    c: CsvLines,
    /// The first row of the next message, read ahead.
    ahead: Option<(i64, T)>,
    last: Option<i64>,
    done: bool,
}

impl<T> Grouped<T> {
    fn open(path: &Path, columns: usize) -> Result<Self, IoError> {
        Ok(Grouped {
            c: CsvLines::open(path, columns)?,
            ahead: None,
            last: None,
            done: false,
        })
    }

    /// The next message's stamp and rows: each row parsed by `parse`, then `admit`ted into the
    /// message it belongs to (which may refuse it, e.g. a repeated id).
    fn next_group(
        &mut self,
        parse: impl Fn(&CsvLines) -> Result<(i64, T), IoError>,
        mut admit: impl FnMut(&CsvLines, i64, &T) -> Result<(), IoError>,
    ) -> Result<Option<(i64, Vec<T>)>, IoError> {
        if self.done {
            return Ok(None);
        }
        let mut rows: Vec<T> = Vec::new();
        let mut t_msg = None;
        if let Some((t, row)) = self.ahead.take() {
            admit(&self.c, t, &row)?;
            t_msg = Some(t);
            rows.push(row);
        }
        loop {
            if !self.c.next_line()? {
                self.done = true;
                return Ok(t_msg.map(|t| (t, rows)));
            }
            let (t, row) = parse(&self.c)?;
            self.c.check_time(self.last, t, true)?;
            self.last = Some(t);
            if t_msg.is_some_and(|tm| tm != t) {
                self.ahead = Some((t, row));
                return Ok(t_msg.map(|tm| (tm, rows)));
            }
            admit(&self.c, t, &row)?;
            t_msg = Some(t);
            rows.push(row);
        }
    }
}

/// `features0/data.csv`: `#timestamp [ns],feature_id,u [px],v [px]`, a frame per stamp.
pub struct FeatureRows {
    g: Grouped<FeatureObs>,
    ids: HashSet<u64>,
}

impl FeatureRows {
    /// Opens the file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        Ok(FeatureRows {
            g: Grouped::open(path, 4)?,
            ids: HashSet::new(),
        })
    }

    fn frame(&mut self) -> Result<Option<FeatureFrame>, IoError> {
        let ids = &mut self.ids;
        ids.clear();
        let parse = |c: &CsvLines| {
            let f = c.fields::<4>()?;
            let t_ns = c.ns(0, f[0])?;
            let obs = FeatureObs {
                id: c.u64(1, f[1])?,
                u_px: c.f64(2, f[2])?,
                v_px: c.f64(3, f[3])?,
            };
            Ok((t_ns, obs))
        };
        let admit = |c: &CsvLines, t_ns: i64, o: &FeatureObs| {
            if ids.insert(o.id) {
                Ok(())
            } else {
                Err(c.err(format!("feature id {} repeated in frame {t_ns}", o.id)))
            }
        };
        let group = self.g.next_group(parse, admit)?;
        Ok(group.map(|(t_ns, obs)| FeatureFrame { t_ns, obs }))
    }
}

impl Iterator for FeatureRows {
    type Item = Result<FeatureFrame, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.frame().transpose()
    }
}

/// `lidar0/data.csv` (povins extension): `#timestamp [ns],point_timestamp [ns],x [m],y [m],z
/// [m],intensity`, a sweep per stamp (the first column).
pub struct LidarRows {
    g: Grouped<LidarPoint>,
}

impl LidarRows {
    /// Opens the file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        Ok(LidarRows {
            g: Grouped::open(path, 6)?,
        })
    }
}

impl Iterator for LidarRows {
    type Item = Result<LidarScan, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        let parse = |c: &CsvLines| {
            let f = c.fields::<6>()?;
            let t_ns = c.ns(0, f[0])?;
            let p = LidarPoint {
                t_ns: c.ns(1, f[1])?,
                p_l: [c.f32(2, f[2])?, c.f32(3, f[3])?, c.f32(4, f[4])?],
                intensity: c.f32(5, f[5])?,
            };
            Ok((t_ns, p))
        };
        let scan = self.g.next_group(parse, |_, _, _| Ok(()));
        scan.map(|s| s.map(|(t_ns, points)| LidarScan { t_ns, points }))
            .transpose()
    }
}

/// `cam0/data.csv`: `#timestamp [ns],filename`, the images in `cam0/data/`, listed with the
/// camera's resolution (decoded by whoever needs the pixels).
pub struct ImageRows {
    c: CsvLines,
    data_dir: PathBuf,
    width: u32,
    height: u32,
    last: Option<i64>,
}

impl ImageRows {
    /// Opens the list `path` of images in `data_dir` taken by `cam`.
    pub fn open(path: &Path, data_dir: &Path, cam: &PinholeCamera) -> Result<Self, IoError> {
        Ok(ImageRows {
            c: CsvLines::open(path, 2)?,
            data_dir: data_dir.to_path_buf(),
            width: cam.width,
            height: cam.height,
            last: None,
        })
    }

    fn row(&mut self) -> Result<Option<ImageFrame>, IoError> {
        let c = &mut self.c;
        if !c.next_line()? {
            return Ok(None);
        }
        let f = c.fields::<2>()?;
        let t_ns = c.ns(0, f[0])?;
        c.check_time(self.last, t_ns, false)?;
        self.last = Some(t_ns);
        if f[1].is_empty() || f[1].contains(['/', '\\']) {
            return Err(c.err(format!("bad image file name {:?}", f[1])));
        }
        Ok(Some(ImageFrame {
            t_ns,
            width: self.width,
            height: self.height,
            mono8: Vec::new(),
            path: Some(self.data_dir.join(f[1])),
        }))
    }
}

impl Iterator for ImageRows {
    type Item = Result<ImageFrame, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.row().transpose()
    }
}

/// The stamp of the last data row of an EuRoC `data.csv` (read from the file's end), or `None`
/// when it cannot be read.
pub fn last_stamp(path: &Path) -> Option<i64> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path).ok()?;
    let len = f.metadata().ok()?.len();
    let from = len.saturating_sub(4096);
    f.seek(SeekFrom::Start(from)).ok()?;
    let mut tail = Vec::new();
    f.read_to_end(&mut tail).ok()?;
    let text = String::from_utf8_lossy(&tail);
    let line = text.lines().rev().find(|l| !l.trim().is_empty())?;
    line.split(',').next()?.trim().parse().ok()
}

/// Data rows of a `data.csv` (lines that are neither blank nor a `#` header), or `None` when it
/// cannot be read.
pub fn count_rows(path: &Path) -> Option<usize> {
    use std::io::BufRead;
    let f = std::fs::File::open(path).ok()?;
    let mut n = 0;
    for line in std::io::BufReader::new(f).lines() {
        let line = line.ok()?;
        let t = line.trim();
        if !t.is_empty() && !t.starts_with('#') {
            n += 1;
        }
    }
    Some(n)
}
