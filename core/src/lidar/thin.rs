//! Thinning of a LiDAR faster than the point buffer's span: one point per direction and per
//! quarter span, instead of the oldest points of the span pushed out.
//!
//! **Why.** The association ([`super::association`]) keeps, at each keyframe, the nearest point
//! per 0.5 deg cell of the keyframe camera's sphere among the points of the last
//! [`AssociationConfig::span_s`](super::AssociationConfig::span_s). A LiDAR delivering more
//! points in that span than the buffer holds (an Ouster OS1-128: 56,000 points a sweep inside
//! the crop to the camera's view, 280,000 in 0.5 s against 131,072) would push the span's
//! older half out whole. Most of what it delivers is redundant for the association: the OS1's
//! 0.35 deg spacing puts two points in every cell each sweep, and five sweeps per span.
//!
//! **When.** A sweep is thinned when its points (after the crop) at the rate it arrives at,
//! `n / (t_due - t_due_prev)` between two sweeps' due times, would fill more than the buffer in
//! one span: `n span > P (t_due - t_due_prev)`. Below that rate every point is kept (the
//! simulator's Livox and Ouster scenarios, its Avia and VLP-16, EuRoC: bit for bit what they
//! gave before); the first sweep, and one after a pause longer than its own rate would fill, is
//! kept whole.
//!
//! **How.** Cells of [`THIN_CELL_RAD`] on a cube map of the LiDAR frame's sphere (six faces of
//! [`THIN_AXIS`] x [`THIN_AXIS`] equal-angle cells: the dominant axis picks the face, the two
//! other coordinates over it are tangents in `[-1, 1]`, binned without trigonometry by
//! `super::angle_index`). Each cell remembers when it last took a point and that point's range.
//! A point of a thinned sweep is kept when its cell took none for `span_s / THIN_PER_SPAN`
//! ([`THIN_PER_SPAN`]), or when it is nearer than [`THIN_NEARER`] times the kept one (a
//! foreground surface, which the association's nearest-per-cell rule prefers); otherwise it is
//! dropped and counted (`Counters::lidar_points_thinned`). The LiDAR and the camera are
//! centimetres apart, so a direction of the LiDAR is one of the camera up to that parallax.
//! With the default 0.5 s span a cell of a 10 Hz LiDAR takes a point every other sweep: an
//! OS1-128 keeps 15,000-18,000 points a sweep, 75,000-90,000 in the span, room to spare in the
//! buffer. A half-span hold (every third sweep) kept fewer recent points and associated up to
//! 19% fewer depths on the simulated car (BENCHMARKS.md, "Thinning a LiDAR faster than the
//! buffer"); a hold of one sweep would not fit the span.
//!
//! Storage: 4 bytes a cell, the time in units of [`THIN_TICK_NS`] (wrapping `u16`: 524 s) and
//! the range in centimetres (`u16`, 0 = never; ranges are gated to 0.1-500 m before). A cell
//! untouched for a multiple of the wrap may look recent once: a point delayed by less than the
//! hold, harmless. All zero bits is the empty grid (a `static` estimator).

use super::angle_index::Axis;

/// Angular size of a thinning cell, rad (the association's default cell).
pub const THIN_CELL_RAD: f64 = 0.5 * core::f64::consts::PI / 180.0;
/// Cells along each axis of a cube face (90 deg of [`THIN_CELL_RAD`]).
pub const THIN_AXIS: usize = 180;
/// Cells of the whole sphere (six faces): the default capacity of a [`ThinGrid`].
pub const THIN_CELLS: usize = 6 * THIN_AXIS * THIN_AXIS;
/// A cell takes a new point at most once per `span_s / THIN_PER_SPAN` (module docs).
pub const THIN_PER_SPAN: f64 = 4.0;
/// A point nearer than this times the cell's kept range is kept anyway (foreground).
pub const THIN_NEARER: f64 = 0.9;
/// Unit of a cell's time, ns (8 ms: a `u16` wraps after 524 s).
pub const THIN_TICK_NS: i64 = 8_000_000;

/// The thinning state (see the module docs): `C` cells, [`THIN_CELLS`] to cover the sphere
/// (fewer leave the faces' last cells unthinned; 0 thins nothing). 4 bytes a cell.
#[derive(Debug, Clone)]
pub struct ThinGrid<const C: usize> {
    /// Per cell: `(tick of the last kept point, its range in cm)`; range 0: never.
    cells: [(u16, u16); C],
    axis: Axis<THIN_AXIS>,
    configured: bool,
}

impl<const C: usize> Default for ThinGrid<C> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const C: usize> ThinGrid<C> {
    /// An empty grid (all zero bits), thinning nothing until [`ThinGrid::configure`].
    pub const fn new() -> Self {
        ThinGrid {
            cells: [(0, 0); C],
            axis: Axis::new(),
            configured: false,
        }
    }

    /// Back to [`ThinGrid::new`], in place.
    pub fn reset_to_new(&mut self) {
        self.cells.fill((0, 0));
        self.axis.reset_to_new();
        self.configured = false;
    }

    /// Tabulates the cells and forgets every point.
    pub fn configure(&mut self) {
        self.axis.configure(THIN_CELL_RAD);
        self.cells.fill((0, 0));
        self.configured = true;
    }

    /// Forgets every point (the buffer was cleared).
    pub fn clear(&mut self) {
        self.cells.fill((0, 0));
    }

    /// Whether a sweep of `n` points due `dt_ns` after the previous one should be thinned for
    /// a buffer of `capacity` points and an association span of `span_ns` (module docs).
    pub fn wanted(n: usize, dt_ns: Option<i64>, capacity: usize, span_ns: i64) -> bool {
        match dt_ns {
            Some(dt) if dt > 0 && C > 0 => {
                (n as f64) * (span_ns as f64) > (capacity as f64) * (dt as f64)
            }
            _ => false,
        }
    }

    /// The cell of the direction `p_l` (LiDAR frame), `None` for the zero vector, a non-finite
    /// one or a cell beyond `C`.
    fn cell(&self, p_l: [f32; 3]) -> Option<usize> {
        let [x, y, z] = p_l;
        let (ax, ay, az) = (x.abs(), y.abs(), z.abs());
        // Face: the dominant axis and its sign; (u, v) the other two over it.
        let (face, d, u, v) = if ax >= ay && ax >= az {
            (usize::from(x < 0.0), ax, y, z)
        } else if ay >= az {
            (2 + usize::from(y < 0.0), ay, x, z)
        } else {
            (4 + usize::from(z < 0.0), az, x, y)
        };
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let (u, v) = (u / d, v / d);
        let i = self.axis.cell_in_bin(u, self.axis.bin(u))?;
        let j = self.axis.cell_in_bin(v, self.axis.bin(v))?;
        let k = (face * THIN_AXIS + i) * THIN_AXIS + j;
        (k < C).then_some(k)
    }

    /// Whether a point of a thinned sweep is kept: `p_l` in the LiDAR frame, `range_m` its
    /// range (gated to the buffer's range), `t_ns` its time, `hold_ns` the time a cell waits
    /// between two points (`span_s / THIN_PER_SPAN`). A kept point is remembered. Points
    /// without a cell (beyond `C`, or before [`ThinGrid::configure`]) are kept.
    pub fn keeps(&mut self, p_l: [f32; 3], range_m: f64, t_ns: i64, hold_ns: i64) -> bool {
        if !self.configured {
            return true;
        }
        let Some(cell) = self.cell(p_l).and_then(|k| self.cells.get_mut(k)) else {
            return true;
        };
        let tick = (t_ns.div_euclid(THIN_TICK_NS)) as u16;
        let hold = (hold_ns.max(0) / THIN_TICK_NS).min(i64::from(u16::MAX)) as u16;
        // At least 1 cm: 0 marks a cell that never took a point.
        let range_cm = (range_m * 100.0).clamp(1.0, f64::from(u16::MAX)) as u16;
        let (last, kept_cm) = *cell;
        let keep = kept_cm == 0
            || tick.wrapping_sub(last) >= hold
            || f64::from(range_cm) < THIN_NEARER * f64::from(kept_cm);
        if keep {
            *cell = (tick, range_cm);
        }
        keep
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn grid() -> ThinGrid<THIN_CELLS> {
        let mut g = ThinGrid::new();
        g.configure();
        g
    }

    const HOLD: i64 = 250_000_000;

    /// Runs `f` on a thread with room for several grids (778 kB each, on the stack in debug).
    fn big_stack(f: impl FnOnce() + Send + 'static) {
        let t = std::thread::Builder::new().stack_size(64 << 20).spawn(f);
        assert!(t.expect("spawn").join().is_ok());
    }

    #[test]
    fn every_direction_of_the_sphere_has_one_cell_and_neighbours_differ() {
        big_stack(directions);
    }

    fn directions() {
        let g = grid();
        let mut seen = std::collections::BTreeSet::new();
        // A fine spiral over the sphere: every direction has a cell, and cells are at most
        // about 0.5 deg wide (points 0.3 deg apart along a meridian change cell at most once).
        for k in 0..20_000 {
            let el = -1.5 + 3.0 * f64::from(k) / 20_000.0;
            let az = 0.7 * f64::from(k);
            let p = [
                (el.cos() * az.cos()) as f32,
                (el.cos() * az.sin()) as f32,
                el.sin() as f32,
            ];
            let c = g.cell(p).expect("every direction has a cell");
            assert!(c < THIN_CELLS);
            seen.insert(c);
        }
        assert!(seen.len() > 15_000, "{} distinct cells", seen.len());
        assert_eq!(g.cell([0.0, 0.0, 0.0]), None);
        assert_eq!(g.cell([f32::NAN, 1.0, 0.0]), None);
        assert_eq!(g.cell([f32::INFINITY, 1.0, 0.0]), None);
        // Along a great circle, 0.3 deg steps: consecutive cells are equal or adjacent.
        let a = |deg: f64| {
            let r = deg.to_radians();
            g.cell([r.cos() as f32, r.sin() as f32, 0.01]).unwrap()
        };
        let cells: Vec<usize> = (0..100).map(|k| a(10.0 + 0.3 * f64::from(k))).collect();
        let changes = cells.windows(2).filter(|w| w[0] != w[1]).count();
        assert!(
            (55..=65).contains(&changes),
            "{changes} cell changes over 30 deg"
        );
    }

    #[test]
    fn a_cell_takes_one_point_per_hold_unless_a_nearer_one_comes() {
        big_stack(holds);
    }

    fn holds() {
        let mut g = grid();
        let p = [10.0f32, 0.2, 0.1];
        assert!(g.keeps(p, 10.0, 0, HOLD));
        // The same direction 0.1 s later: held; 0.26 s later: taken again.
        assert!(!g.keeps(p, 10.0, 100_000_000, HOLD));
        assert!(!g.keeps(p, 9.5, 200_000_000, HOLD));
        assert!(g.keeps(p, 10.0, 260_000_000, HOLD));
        // A foreground point (8.9 m < 0.9 x 10 m) is kept at once.
        assert!(g.keeps(p, 8.9, 270_000_000, HOLD));
        assert!(!g.keeps(p, 8.5, 280_000_000, HOLD));
        // Another direction is another cell.
        assert!(g.keeps([10.0, -3.0, 0.1], 10.4, 280_000_000, HOLD));
        // Times before zero and across the tick's wrap work alike.
        let mut g = grid();
        assert!(g.keeps(p, 10.0, -100_000_000, HOLD));
        assert!(!g.keeps(p, 10.0, 0, HOLD));
        let wrap = THIN_TICK_NS * 65_536;
        let mut g = grid();
        assert!(g.keeps(p, 10.0, wrap - 100_000_000, HOLD));
        assert!(!g.keeps(p, 10.0, wrap + 100_000_000, HOLD));
        assert!(g.keeps(p, 10.0, wrap + 200_000_000, HOLD));
        // Forgotten after clear; an unconfigured grid and a grid of no cells keep everything.
        g.clear();
        assert!(g.keeps(p, 10.0, wrap + 210_000_000, HOLD));
        let mut u = ThinGrid::<THIN_CELLS>::new();
        assert!(u.keeps(p, 10.0, 0, HOLD) && u.keeps(p, 10.0, 1, HOLD));
        let mut z = ThinGrid::<0>::new();
        z.configure();
        assert!(z.keeps(p, 10.0, 0, HOLD) && z.keeps(p, 10.0, 1, HOLD));
    }

    #[test]
    fn only_a_sweep_rate_that_overflows_the_span_is_thinned() {
        type G = ThinGrid<THIN_CELLS>;
        let span = 500_000_000;
        // 56,000 points every 0.1 s: 280,000 in the span against 131,072.
        assert!(G::wanted(56_000, Some(100_000_000), 131_072, span));
        // 24,000 every 0.1 s (a Livox Avia): 120,000, kept.
        assert!(!G::wanted(24_000, Some(100_000_000), 131_072, span));
        // No previous sweep, or one not before: kept.
        assert!(!G::wanted(56_000, None, 131_072, span));
        assert!(!G::wanted(56_000, Some(0), 131_072, span));
        assert!(!G::wanted(56_000, Some(-5), 131_072, span));
        assert!(!ThinGrid::<0>::wanted(
            56_000,
            Some(100_000_000),
            131_072,
            span
        ));
    }
}
