//! Depth association on the unit sphere of the keyframe camera (LE-VINS, paper III).
//!
//! **Grid.** A buffered point `p_w` is expressed in the camera, `p_c = R_wc^T (p_w - p_wc)`, and
//! binned by its bearing: column `floor(alpha / c + W/2)` with `alpha = atan2(x, z)` (angle about
//! the camera `y` axis), row `floor(beta / c + H/2)` with `beta = atan2(y, hypot(x, z))`
//! (elevation), `c` = [`AssociationConfig::cell_rad`]; the default 256 x 192 cells of 0.5 deg
//! span +-64 deg x +-48 deg around the optical axis. Each cell keeps only its nearest point
//! (the foreground: a background point seen past an edge by the LiDAR is dropped when a nearer
//! one shares its cell). The angles are never computed per point: [`super::angle_index`] maps
//! the tangents `x/z` and `y/hypot(x, z)` to cells exactly with tabulated boundaries.
//!
//! **Association** of a feature at normalized coordinates `x_n`, bearing `b = (x, y, 1)/|.|`:
//! 1. the `k` points of largest `cos(b, p)` among the cells around `b`, no farther than
//!    `max_neighbour_rad` from `b` (else [`AssocReject::NoNeighbours`]); at elevation `beta` an
//!    angle `r` spans `r / cos(beta)` in `alpha`, which sizes the searched columns;
//! 2. range spread `(max |p| - min |p|) / mean |p| <= max_range_spread` (else
//!    [`AssocReject::RangeSpread`]): a foreground and a background surface in one set;
//! 3. total-least-squares plane `n . (p - c) = 0` ([`super::plane`]); every point within
//!    `max_plane_dist_m` of it, and the set not collinear (else [`AssocReject::PlaneFit`]);
//! 4. `|n . b| >= min_incidence_cos` (else [`AssocReject::Incidence`]);
//! 5. ray-plane intersection `P = t b`, `t = (n . c) / (n . b)`: range `t`, **depth = z = t b_z**
//!    (not the range: they differ by `|x_n, 1|`), inside `depth_range_m` (else
//!    [`AssocReject::DepthRange`]).
//!
//! Times: the buffer stamps points on the LiDAR clock and `t_kf_ns` is on the IMU/camera clock;
//! the window `[t_kf - span_s, t_kf]` ignores their offset `td_l_s` (milliseconds against a
//! half-second span).

use super::angle_index::{cell_of, fill_tan_table};
use super::buffer::{seconds_to_ns, unpack, PointBuffer};
use super::config::AssociationConfig;
use super::plane::fit_plane;
use crate::camera::Vec2;
use crate::math::{Quat, Vec3};
use core::f64::consts::FRAC_PI_2;
use heapless::Vec as HVec;

/// Grid width (cells along the horizontal angle) of the estimator's sphere grid.
pub const GRID_W: usize = 256;
/// Grid height of the estimator's sphere grid.
pub const GRID_H: usize = 192;

/// Points nearer the camera plane than this (z, m) are not binned: behind the camera, or so
/// close that their bearing is meaningless for a feature.
const MIN_Z_M: f64 = 0.01;

/// The neighbour search spans at most this many cells on each side of the bearing's cell
/// (bounds the cost for any configuration: at most 49 x 49 cells; the default searches 11 x 13).
const MAX_SEARCH_HALF_CELLS: f64 = 24.0;

/// What [`SphereGrid::build`] saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GridStats {
    /// Buffered points considered (inside the time span).
    pub points: u32,
    /// Of those, in front of the camera and inside the grid.
    pub in_view: u32,
    /// Cells holding a point.
    pub cells_filled: u32,
}

/// A LiDAR depth for one feature bearing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthMeasurement {
    /// Depth: z of the ray-plane intersection in the camera, m.
    pub depth_m: f64,
    /// Range along the ray, m.
    pub range_m: f64,
    /// Neighbours in the plane fit.
    pub neighbours: u8,
    /// RMS distance of the neighbours from the plane, m.
    pub plane_rms_m: f64,
}

/// Why a bearing got no depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AssocReject {
    /// Fewer than the configured neighbours within the angular radius.
    NoNeighbours,
    /// A neighbour is too far from the fitted plane (or the fit is degenerate).
    PlaneFit,
    /// Neighbour ranges spread too much (foreground mixed with background).
    RangeSpread,
    /// The ray grazes the plane.
    Incidence,
    /// The depth is outside the configured range.
    DepthRange,
    /// Non-finite input.
    NonFinite,
}

/// The nearest point of a cell in the camera frame `c` (x right, y down, z forward), m; `r2`
/// its squared range, `+inf` when the cell is empty.
#[derive(Debug, Clone, Copy)]
struct Cell {
    p_c: [f32; 3],
    r2: f32,
}

impl Cell {
    const EMPTY: Cell = Cell {
        p_c: [0.0; 3],
        r2: f32::INFINITY,
    };
}

/// Nearest point per angular cell of a `W x H` grid centred on the optical axis of one camera
/// pose (the frame `c` of the last [`SphereGrid::build`]); 16 bytes a cell (786 kB for
/// [`GRID_W`] x [`GRID_H`]: keep it in a `static` or a `Box`).
#[derive(Debug, Clone)]
pub struct SphereGrid<const W: usize, const H: usize> {
    cells: [[Cell; W]; H],
    /// Lower tangent boundary of each column / row, and the upper one of the last.
    tan_col: [f64; W],
    tan_col_end: f64,
    tan_row: [f64; H],
    tan_row_end: f64,
    /// Cell size of the tables and the contents, rad; 0 until the first build.
    cell_rad: f64,
    filled: u32,
}

impl<const W: usize, const H: usize> Default for SphereGrid<W, H> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const W: usize, const H: usize> SphereGrid<W, H> {
    const NONZERO: () = assert!(W > 0 && H > 0, "SphereGrid needs W > 0 and H > 0");

    /// An empty grid.
    pub fn new() -> Self {
        let () = Self::NONZERO;
        SphereGrid {
            cells: [[Cell::EMPTY; W]; H],
            tan_col: [0.0; W],
            tan_col_end: 0.0,
            tan_row: [0.0; H],
            tan_row_end: 0.0,
            cell_rad: 0.0,
            filled: 0,
        }
    }

    /// Fills the grid with the buffered points of the last `cfg.span_s` before `t_kf_ns`,
    /// expressed in the camera with pose `(p_wc, q_wc)` in `w`. A non-finite pose or cell size
    /// leaves the grid empty.
    pub fn build<const P: usize>(
        &mut self,
        buf: &PointBuffer<P>,
        p_wc: &Vec3,
        q_wc: &Quat,
        t_kf_ns: i64,
        cfg: &AssociationConfig,
    ) -> GridStats {
        for row in self.cells.iter_mut() {
            row.fill(Cell::EMPTY);
        }
        self.filled = 0;
        let mut stats = GridStats::default();
        let pose_ok = p_wc.iter().chain(q_wc.coords.iter()).all(|v| v.is_finite());
        if !(pose_ok && cfg.cell_rad > 0.0 && cfg.cell_rad.is_finite()) {
            self.cell_rad = 0.0;
            return stats;
        }
        if cfg.cell_rad != self.cell_rad {
            self.tan_col_end = fill_tan_table(&mut self.tan_col, cfg.cell_rad);
            self.tan_row_end = fill_tan_table(&mut self.tan_row, cfg.cell_rad);
            self.cell_rad = cfg.cell_rad;
        }
        let r_cw = q_wc.inverse().to_rotation_matrix().into_inner();
        let t_min_ns = t_kf_ns.saturating_sub(seconds_to_ns(cfg.span_s).max(0));
        let bin = Binner {
            inv_cell: 1.0 / self.cell_rad,
            half_w: W as f64 * 0.5,
            half_h: H as f64 * 0.5,
        };
        for seg in buf.segments() {
            // The span in the segment's time offsets.
            let lo = t_min_ns.saturating_sub(seg.t0_ns);
            let hi = t_kf_ns.saturating_sub(seg.t0_ns);
            let (dt_min, dt_max) = (i64::from(seg.dt_min), i64::from(seg.dt_max));
            if dt_max < lo || dt_min > hi {
                continue;
            }
            let all_inside = dt_min >= lo && dt_max <= hi;
            let o_c = r_cw * (seg.origin_w - p_wc);
            for q in seg.parts.iter().flat_map(|s| s.iter()) {
                if !all_inside && !(lo..=hi).contains(&i64::from(q.dt_ns)) {
                    continue;
                }
                stats.points = stats.points.saturating_add(1);
                let p_c = o_c + r_cw * unpack(q);
                if self.insert(&p_c, &bin) {
                    stats.in_view = stats.in_view.saturating_add(1);
                }
            }
        }
        stats.cells_filled = self.filled;
        stats
    }

    /// Bins one camera-frame point, keeping the nearer of it and the cell's point. False when it
    /// is behind the camera or outside the grid.
    #[inline]
    fn insert(&mut self, p_c: &Vec3, bin: &Binner) -> bool {
        let (x, y, z) = (p_c.x, p_c.y, p_c.z);
        if !(z > MIN_Z_M) {
            return false;
        }
        let Some(col) = cell_of(
            x / z,
            &self.tan_col,
            self.tan_col_end,
            bin.inv_cell,
            bin.half_w,
        ) else {
            return false;
        };
        let h2 = x * x + z * z;
        let tan_el = y / libm::sqrt(h2);
        let Some(row) = cell_of(
            tan_el,
            &self.tan_row,
            self.tan_row_end,
            bin.inv_cell,
            bin.half_h,
        ) else {
            return false;
        };
        let r2 = (h2 + y * y) as f32;
        let Some(cell) = self.cells.get_mut(row).and_then(|r| r.get_mut(col)) else {
            return false;
        };
        if r2 < cell.r2 {
            if cell.r2 == f32::INFINITY {
                self.filled += 1;
            }
            *cell = Cell {
                p_c: [x as f32, y as f32, z as f32],
                r2,
            };
        }
        true
    }

    /// LiDAR depth of the feature at undistorted normalized coordinates `x_n` (the grid's own
    /// cell size, from its build, is used whatever `cfg.cell_rad` says now).
    pub fn associate(
        &self,
        x_n: &Vec2,
        cfg: &AssociationConfig,
    ) -> Result<DepthMeasurement, AssocReject> {
        if !(x_n.x.is_finite() && x_n.y.is_finite()) {
            return Err(AssocReject::NonFinite);
        }
        let k = cfg.neighbours.clamp(3, AssociationConfig::MAX_NEIGHBOURS);
        let radius = cfg.max_neighbour_rad;
        if self.filled == 0 || !(self.cell_rad > 0.0) || !(radius > 0.0) {
            return Err(AssocReject::NoNeighbours);
        }
        let b = Vec3::new(x_n.x, x_n.y, 1.0).normalize();
        let nb = self.neighbours(&b, radius, k);
        if nb.len() < k {
            return Err(AssocReject::NoNeighbours);
        }
        let mut buf = [Vec3::zeros(); AssociationConfig::MAX_NEIGHBOURS];
        for (d, (_, p)) in buf.iter_mut().zip(nb.iter()) {
            *d = *p;
        }
        let pts = buf.get(..k).unwrap_or(&[]);

        let (mut r_min, mut r_max, mut r_sum) = (f64::INFINITY, 0.0f64, 0.0);
        for p in pts {
            let r = p.norm();
            r_min = r_min.min(r);
            r_max = r_max.max(r);
            r_sum += r;
        }
        let r_mean = r_sum / k as f64;
        if !((r_max - r_min) <= cfg.max_range_spread * r_mean) {
            return Err(AssocReject::RangeSpread);
        }

        let plane = fit_plane(pts).ok_or(AssocReject::PlaneFit)?;
        if !(plane.max_dist_m <= cfg.max_plane_dist_m) {
            return Err(AssocReject::PlaneFit);
        }
        let n_dot_b = plane.normal.dot(&b);
        if !(n_dot_b.abs() >= cfg.min_incidence_cos) {
            return Err(AssocReject::Incidence);
        }
        let range_m = plane.normal.dot(&plane.centroid) / n_dot_b;
        let depth_m = range_m * b.z;
        if !(depth_m >= cfg.depth_range_m.0 && depth_m <= cfg.depth_range_m.1) {
            return Err(AssocReject::DepthRange);
        }
        Ok(DepthMeasurement {
            depth_m,
            range_m,
            neighbours: k as u8,
            plane_rms_m: plane.rms_m,
        })
    }

    /// The (at most) `k` cell points of largest `cos(b, p) >= cos(radius)`, largest first (ties:
    /// the first found, rows then columns, stays first).
    fn neighbours(&self, b: &Vec3, radius: f64, k: usize) -> Neighbours {
        let mut out = Neighbours::new();
        let c = self.cell_rad;
        let az = libm::atan2(b.x, b.z);
        let el = libm::atan2(b.y, libm::sqrt(b.x * b.x + b.z * b.z));
        let cos_r = if radius >= core::f64::consts::PI {
            -1.0
        } else {
            libm::cos(radius)
        };
        let half_rows = (libm::ceil(radius / c) + 1.0).min(MAX_SEARCH_HALF_CELLS);
        // Columns narrow with elevation: an angle r spans r / cos(el) of azimuth.
        let el_far = (el.abs() + radius).min(FRAC_PI_2);
        let half_cols =
            (libm::ceil(radius / (c * libm::cos(el_far))) + 1.0).min(MAX_SEARCH_HALF_CELLS);
        let Some(rows) = window(el / c + H as f64 * 0.5, half_rows, H) else {
            return out;
        };
        let Some(cols) = window(az / c + W as f64 * 0.5, half_cols, W) else {
            return out;
        };
        for row in self.cells.get(rows).unwrap_or(&[]) {
            for cell in row.get(cols.clone()).unwrap_or(&[]) {
                if cell.r2 == f32::INFINITY {
                    continue;
                }
                let p = Vec3::new(
                    f64::from(cell.p_c[0]),
                    f64::from(cell.p_c[1]),
                    f64::from(cell.p_c[2]),
                );
                let cos_a = b.dot(&p) / p.norm();
                if !(cos_a >= cos_r) {
                    continue;
                }
                if out.len() >= k {
                    if out.last().is_some_and(|l| l.0 >= cos_a) {
                        continue;
                    }
                    out.pop();
                }
                let at = out.iter().position(|e| e.0 < cos_a).unwrap_or(out.len());
                // Cannot fail (k <= capacity and one slot is free).
                let _ = out.insert(at, (cos_a, p));
            }
        }
        out
    }
}

type Neighbours = HVec<(f64, Vec3), { AssociationConfig::MAX_NEIGHBOURS }>;

/// Per-build constants of the binning.
struct Binner {
    inv_cell: f64,
    half_w: f64,
    half_h: f64,
}

/// Cells `floor(centre - half) ..= floor(centre + half)` clipped to `0..n`; `None` if empty.
fn window(centre: f64, half: f64, n: usize) -> Option<core::ops::RangeInclusive<usize>> {
    let lo = libm::floor(centre - half).max(0.0);
    let hi = libm::floor(centre + half).min(n as f64 - 1.0);
    (lo <= hi).then_some(lo as usize..=hi as usize)
}
