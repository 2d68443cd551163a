//! The readable half of a golden file: decimated states as CSV (`tests/golden/<name>.csv`), and
//! how far a run moved from them, column by column (as PX4's replay tests show a change).
//!
//! Rows, in time order: `imu`, the first IMU-rate state of every 0.1 s (from the first state);
//! `kf`, every keyframe's state as it left the window (or at the end), with the camera-IMU delay
//! `td` the estimator reported at that keyframe's step. Columns: `kind`, `t_s` (from the first
//! IMU-rate state, whose time is in the header), position and velocity of the body in the world
//! frame (`p_wb`, `v_wb`), attitude `R_wb` as ZYX Euler angles (`R_wb = Rz(yaw) Ry(pitch)
//! Rx(roll)`), the gyro and accelerometer biases (body frame) and `td` (keyframes only). Near
//! pitch +-90 deg roll and yaw trade off: the summary's attitude figure (the angle between the
//! two attitudes) is the one to read then.
//!
//! The digits resolve 1 um, 1e-5 deg, 1 um/s, 1e-7 rad/s, 1 um/s^2 and 0.1 us: enough to show
//! any change that matters, and the file stays tens of kB. The hash file stays the authority:
//! identical bits print identically (the Euler angles come from `libm` through nalgebra's
//! `libm-force`, the same on every target), so a run that matches the hash reproduces this file
//! byte for byte on x86-64 and aarch64 alike; the CSV only explains a mismatch.

use super::RunView;
use nalgebra::UnitQuaternion;
use povins::core::inertial::NavState;
use std::fmt::Write as _;

/// IMU-rate rows: the first state of every this many ns.
pub const DECIMATION_NS: i64 = 100_000_000;

/// The value columns after `kind, t_s`: name and decimals printed.
pub const COLUMNS: [(&str, usize); 16] = [
    ("p_wb_x_m", 6),
    ("p_wb_y_m", 6),
    ("p_wb_z_m", 6),
    ("roll_deg", 5),
    ("pitch_deg", 5),
    ("yaw_deg", 5),
    ("v_wb_x_mps", 6),
    ("v_wb_y_mps", 6),
    ("v_wb_z_mps", 6),
    ("bg_x_rps", 7),
    ("bg_y_rps", 7),
    ("bg_z_rps", 7),
    ("ba_x_mps2", 6),
    ("ba_y_mps2", 6),
    ("ba_z_mps2", 6),
    ("td_ms", 4),
];
const P: usize = 0;
const RPY: usize = 3;
const V: usize = 6;
const BG: usize = 9;
const BA: usize = 12;
const TD: usize = 15;

/// Which states a row holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Kind {
    /// Decimated IMU-rate output.
    Imu,
    /// A keyframe's final state.
    Keyframe,
}

impl Kind {
    fn tag(self) -> &'static str {
        match self {
            Kind::Imu => "imu",
            Kind::Keyframe => "kf",
        }
    }
}

/// One row as printed (and parsed back: both sides of a comparison are the printed numbers).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub kind: Kind,
    /// Time since the first IMU-rate state, s (as printed, to the microsecond).
    pub t_s: String,
    /// The columns of [`COLUMNS`]; `None` where empty (`td` of IMU-rate rows).
    pub vals: [Option<f64>; 16],
}

/// A states file: the time of the first IMU-rate state and the rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub t0_ns: i64,
    pub rows: Vec<Row>,
}

fn row_of(kind: Kind, s: &NavState, t0_ns: i64, td_s: Option<f64>) -> Row {
    let (roll, pitch, yaw) = s.q_wb.euler_angles();
    let mut v = [None; 16];
    let nums = s
        .p_wb
        .iter()
        .copied()
        .chain([roll, pitch, yaw].map(f64::to_degrees))
        .chain(s.v_wb.iter().copied())
        .chain(s.bg.iter().copied())
        .chain(s.ba.iter().copied());
    for (d, x) in v.iter_mut().zip(nums) {
        *d = Some(x);
    }
    v[TD] = td_s.map(|td| td * 1e3);
    let dt_ns = s.t_ns - t0_ns;
    Row {
        kind,
        t_s: format!(
            "{}{}.{:06}",
            if dt_ns < 0 { "-" } else { "" },
            dt_ns.abs() / 1_000_000_000,
            dt_ns.abs() % 1_000_000_000 / 1_000
        ),
        vals: v,
    }
}

/// The rows of a run: decimated IMU-rate states and every keyframe state, in time order (the
/// numbers at full precision; [`render`] prints them).
pub fn table_of(run: &RunView<'_>) -> Table {
    let t0_ns = run.imu_rate.first().map_or(0, |s| s.t_ns);
    let mut rows: Vec<(i64, Row)> = Vec::new();
    let mut last_bin = None;
    for s in run.imu_rate {
        let bin = (s.t_ns - t0_ns).div_euclid(DECIMATION_NS);
        if last_bin != Some(bin) {
            last_bin = Some(bin);
            rows.push((s.t_ns, row_of(Kind::Imu, s, t0_ns, None)));
        }
    }
    for k in run.keyframe_states {
        // The keyframe's own step reported its td (report and keyframe share the IMU time).
        let td = run
            .reports
            .iter()
            .find(|r| r.t_ns == k.t_ns)
            .map(|r| r.td_s);
        rows.push((k.t_ns, row_of(Kind::Keyframe, k, t0_ns, td)));
    }
    rows.sort_by_key(|a| (a.0, a.1.kind));
    Table {
        t0_ns,
        rows: rows.into_iter().map(|(_, r)| r).collect(),
    }
}

/// The CSV text of a table (`#` comment lines first).
pub fn render(name: &str, table: &Table, bless: &str) -> String {
    let mut s = format!(
        "# povins golden replay '{name}': the first IMU-rate state of every 0.1 s (imu) and every\n\
         # keyframe's final state with the td reported at its step (kf), for reading. The .hash\n\
         # file is the exact check. Re-bless after an intended change: {bless}\n\
         # t0_ns {}\n",
        table.t0_ns
    );
    s.push_str("kind,t_s");
    for (c, _) in COLUMNS {
        s.push(',');
        s.push_str(c);
    }
    s.push('\n');
    for r in &table.rows {
        s.push_str(r.kind.tag());
        s.push(',');
        s.push_str(&r.t_s);
        for (v, (_, digits)) in r.vals.iter().zip(COLUMNS) {
            s.push(',');
            if let Some(x) = v {
                let _ = write!(s, "{x:.digits$}");
            }
        }
        s.push('\n');
    }
    s
}

/// Parses a states file ([`render`]'s output); `None` if it is malformed.
pub fn parse(text: &str) -> Option<Table> {
    let mut t0_ns = None;
    let mut rows = Vec::new();
    let mut header = false;
    for line in text.lines() {
        if let Some(c) = line.strip_prefix('#') {
            if let Some(t) = c.trim().strip_prefix("t0_ns ") {
                t0_ns = Some(t.trim().parse().ok()?);
            }
            continue;
        }
        if !header {
            header = true;
            let want: Vec<&str> = ["kind", "t_s"]
                .into_iter()
                .chain(COLUMNS.iter().map(|c| c.0))
                .collect();
            if line.split(',').collect::<Vec<_>>() != want {
                return None;
            }
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 2 + COLUMNS.len() {
            return None;
        }
        let kind = match f[0] {
            "imu" => Kind::Imu,
            "kf" => Kind::Keyframe,
            _ => return None,
        };
        let mut vals = [None; 16];
        for (d, x) in vals.iter_mut().zip(&f[2..]) {
            *d = if x.is_empty() {
                None
            } else {
                Some(x.parse().ok()?)
            };
        }
        rows.push(Row {
            kind,
            t_s: f[1].to_string(),
            vals,
        });
    }
    Some(Table {
        t0_ns: t0_ns?,
        rows,
    })
}

/// The largest difference of one column over the rows compared.
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnDiff {
    pub column: &'static str,
    /// Largest `|now - golden|` (yaw and roll wrapped to +-180 deg), in the column's unit.
    pub max_abs: f64,
    /// Where: the row's kind and time, and the two values.
    pub at: Option<(Kind, String, f64, f64)>,
}

/// The largest change of one quantity (a vector's norm, the attitude's angle), in `unit`.
#[derive(Debug, Clone, PartialEq)]
pub struct Moved {
    pub what: &'static str,
    pub unit: &'static str,
    pub max: f64,
    pub at_t_s: Option<String>,
}

/// How far a run is from a golden states file.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// Rows present in both (matched by kind and time).
    pub compared: usize,
    /// Rows of the golden file the run has not (kind, time), and rows only the run has.
    pub only_golden: Vec<(Kind, String)>,
    pub only_now: Vec<(Kind, String)>,
    /// The first IMU-rate state's time, golden and now, when they differ.
    pub t0_ns: Option<(i64, i64)>,
    pub columns: Vec<ColumnDiff>,
    /// Per kind: position, attitude, velocity, biases and td.
    pub summary: Vec<(Kind, Vec<Moved>)>,
}

fn wrap_deg(d: f64) -> f64 {
    let w = d.rem_euclid(360.0);
    if w > 180.0 {
        w - 360.0
    } else {
        w
    }
}

fn vec3(r: &Row, at: usize) -> Option<nalgebra::Vector3<f64>> {
    Some(nalgebra::Vector3::new(
        r.vals[at]?,
        r.vals[at + 1]?,
        r.vals[at + 2]?,
    ))
}

fn attitude(r: &Row) -> Option<UnitQuaternion<f64>> {
    let [roll, pitch, yaw] = [r.vals[RPY]?, r.vals[RPY + 1]?, r.vals[RPY + 2]?];
    Some(UnitQuaternion::from_euler_angles(
        roll.to_radians(),
        pitch.to_radians(),
        yaw.to_radians(),
    ))
}

/// Compares the printed numbers of a run (`now`, rendered and parsed back) with a golden file's.
pub fn compare(golden: &Table, now: &Table) -> Comparison {
    use std::collections::BTreeMap;
    let key = |r: &Row| (r.kind, r.t_s.clone());
    let g: BTreeMap<_, &Row> = golden.rows.iter().map(|r| (key(r), r)).collect();
    let n: BTreeMap<_, &Row> = now.rows.iter().map(|r| (key(r), r)).collect();
    let only_golden = g.keys().filter(|k| !n.contains_key(*k)).cloned().collect();
    let only_now = n.keys().filter(|k| !g.contains_key(*k)).cloned().collect();
    let pairs: Vec<(&Row, &Row)> = now
        .rows
        .iter()
        .filter_map(|r| Some((*g.get(&key(r))?, r)))
        .collect();

    let mut columns: Vec<ColumnDiff> = COLUMNS
        .iter()
        .map(|&(column, _)| ColumnDiff {
            column,
            max_abs: 0.0,
            at: None,
        })
        .collect();
    for (gr, nr) in &pairs {
        for (j, col) in columns.iter_mut().enumerate() {
            let (Some(a), Some(b)) = (gr.vals[j], nr.vals[j]) else {
                continue;
            };
            let d = if j == RPY || j == RPY + 2 {
                wrap_deg(b - a).abs()
            } else {
                (b - a).abs()
            };
            if d > col.max_abs {
                *col = ColumnDiff {
                    column: col.column,
                    max_abs: d,
                    at: Some((nr.kind, nr.t_s.clone(), a, b)),
                };
            }
        }
    }

    // What the summary reports: name, unit and the factor from the columns' SI units.
    const MOVED: [(&str, &str, f64); 6] = [
        ("position", "mm", 1e3),
        ("attitude", "deg", 1.0),
        ("velocity", "mm/s", 1e3),
        ("gyro bias", "deg/h", 3600.0 * 180.0 / std::f64::consts::PI),
        ("accel bias", "mm/s^2", 1e3),
        ("td", "ms", 1.0),
    ];
    let mut summary = Vec::new();
    for kind in [Kind::Imu, Kind::Keyframe] {
        let mut moved: Vec<Moved> = MOVED
            .iter()
            .map(|&(what, unit, _)| Moved {
                what,
                unit,
                max: 0.0,
                at_t_s: None,
            })
            .collect();
        for (gr, nr) in pairs.iter().filter(|(_, r)| r.kind == kind) {
            let norm = |at| Some((vec3(nr, at)? - vec3(gr, at)?).norm());
            let d = [
                norm(P),
                attitude(gr)
                    .zip(attitude(nr))
                    .map(|(a, b)| a.angle_to(&b).to_degrees()),
                norm(V),
                norm(BG),
                norm(BA),
                gr.vals[TD].zip(nr.vals[TD]).map(|(a, b)| (b - a).abs()),
            ];
            for ((m, d), (_, _, scale)) in moved.iter_mut().zip(d).zip(MOVED) {
                if let Some(d) = d.map(|d| d * scale).filter(|&d| d > m.max) {
                    m.max = d;
                    m.at_t_s = Some(nr.t_s.clone());
                }
            }
        }
        if kind == Kind::Imu {
            moved.pop(); // no td at IMU rate
        }
        summary.push((kind, moved));
    }
    Comparison {
        compared: pairs.len(),
        only_golden,
        only_now,
        t0_ns: (golden.t0_ns != now.t0_ns).then_some((golden.t0_ns, now.t0_ns)),
        columns,
        summary,
    }
}

/// A magnitude with three significant digits.
fn sig3(x: f64) -> String {
    if x == 0.0 {
        "0".to_string()
    } else if (1e-3..1e6).contains(&x) {
        let decimals = (2 - x.log10().floor() as i32).max(0) as usize;
        format!("{x:.decimals$}")
    } else {
        format!("{x:.2e}")
    }
}

impl Comparison {
    /// True when every compared number printed the same and no row is missing on either side.
    pub fn is_equal(&self) -> bool {
        self.only_golden.is_empty()
            && self.only_now.is_empty()
            && self.columns.iter().all(|c| c.max_abs == 0.0)
    }

    /// The difference of the column `name` (one of [`COLUMNS`]).
    pub fn column(&self, name: &str) -> Option<&ColumnDiff> {
        self.columns.iter().find(|c| c.column == name)
    }

    /// The report: one summary line per kind, then the largest difference of every column.
    pub fn describe(&self) -> String {
        let mut s = String::new();
        if let Some((g, n)) = self.t0_ns {
            let _ = writeln!(
                s,
                "    the first IMU-rate state moved: t0 {n} ns now, {g} ns golden (rows are \
                 matched by time since it)"
            );
        }
        let kinds = |v: &[(Kind, String)]| {
            let n = |k| v.iter().filter(|r| r.0 == k).count();
            format!("{} imu, {} kf", n(Kind::Imu), n(Kind::Keyframe))
        };
        let _ = writeln!(
            s,
            "    {} rows compared; only in the golden file: {}{}; only now: {}{}",
            self.compared,
            kinds(&self.only_golden),
            self.only_golden.first().map_or(String::new(), |r| format!(
                " (first {} at t = {} s)",
                r.0.tag(),
                r.1
            )),
            kinds(&self.only_now),
            self.only_now.first().map_or(String::new(), |r| format!(
                " (first {} at t = {} s)",
                r.0.tag(),
                r.1
            )),
        );
        for (kind, moved) in &self.summary {
            let what = match kind {
                Kind::Imu => "IMU-rate states (every 0.1 s)",
                Kind::Keyframe => "keyframe states",
            };
            let parts: Vec<String> = moved
                .iter()
                .map(|m| {
                    format!(
                        "{} {} {}{}",
                        m.what,
                        sig3(m.max),
                        m.unit,
                        m.at_t_s
                            .as_ref()
                            .map_or(String::new(), |t| format!(" (t = {t} s)"))
                    )
                })
                .collect();
            let _ = writeln!(s, "    {what} moved by at most: {}", parts.join(", "));
        }
        let _ = writeln!(
            s,
            "    largest |now - golden| per column (t from the first IMU-rate state):"
        );
        let _ = writeln!(
            s,
            "      {:<11} {:>12}  {:<4} {:>11}  {:>14} {:>14}",
            "column", "max diff", "row", "t_s", "golden", "now"
        );
        for c in &self.columns {
            match &c.at {
                None => {
                    let _ = writeln!(s, "      {:<11} {:>12}", c.column, "0");
                }
                Some((kind, t, g, n)) => {
                    let _ = writeln!(
                        s,
                        "      {:<11} {:>12}  {:<4} {:>11}  {:>14} {:>14}",
                        c.column,
                        sig3(c.max_abs),
                        kind.tag(),
                        t,
                        g,
                        n
                    );
                }
            }
        }
        s
    }
}
