//! Bounded buffer of de-skewed LiDAR points in the INS world frame `w`.
//!
//! De-skew: a return `p_l` stamped `t` (LiDAR clock) is taken with the body pose at its own
//! time `t + td_l_s` on the IMU clock, `p_w = R_wb(t) (R_bl p_l + p_bl) + p_wb(t)`, the pose
//! interpolated from the INS window (see `super::deskew`).
//!
//! Storage (16 bytes a point): points are a ring of `P` entries holding `f32` offsets from a
//! per-segment origin and an `i32` time offset from the segment's start time. A segment is a
//! run of consecutive ring entries sharing one `f64` origin (the body position at its first
//! point) and one `i64` start time; each scan opens one, and a scan opens another when a point
//! falls more than [`MAX_OFFSET_M`] from the origin or its time more than `i32` nanoseconds
//! (2.1 s) from the start. Offsets are at most a few hundred metres (range <= 500 m), where an
//! `f32` rounds to 3e-5 m or better (2e-6 m at 30 m): below LiDAR noise, which plain `f32`
//! world coordinates would not be after a few kilometres of travel. The ring evicts the oldest
//! point when full; [`MAX_SEGMENTS`] bounds the segments, evicting the oldest segment whole.

use super::config::LidarConfig;
use super::deskew::InterpCursor;
use super::LidarPoint;
use crate::inertial::window::InsWindow;
use crate::math::Vec3;
use heapless::Deque;

/// Most points the estimator's buffer holds (2 MB): the association's 0.5 s span of a LiDAR
/// delivering up to 262,000 points/s into the camera's view (a Livox Avia's 240,000; an Ouster
/// OS1-128 at 1024 x 10 after the crop to the camera, [`super::crop`]). 65,536 lost a third of
/// the simulated hand-held Livox's points within the span (BENCHMARKS.md, "Real LiDARs").
pub const MAX_LIDAR_POINTS: usize = 131_072;

/// Most segments (scans, or pieces of scans) a [`PointBuffer`] tracks; the oldest is evicted
/// whole to open a new one. 256 sweeps cover 25 s of a 10 Hz LiDAR; at 48 bytes a segment the
/// table costs 12 kB beside the 1 MB of points.
pub const MAX_SEGMENTS: usize = 256;

/// Largest distance of a stored point from its segment origin along any axis, m (keeps the
/// `f32` rounding of the offset below 1.3e-4 m, and far above the 500 m range gate, so only an
/// absurd motion inside one scan opens a segment for it).
pub const MAX_OFFSET_M: f64 = 2048.0;

/// Returns nearer than this are rejected (includes all-zero "no return" points), m.
pub const MIN_RANGE_M: f64 = 0.1;
/// Returns farther than this are rejected, m.
pub const MAX_RANGE_M: f64 = 500.0;

/// A de-skewed point: its time and position in the INS world frame `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldPoint {
    /// Time of the return (LiDAR clock), ns.
    pub t_ns: i64,
    /// Position in `w`, m.
    pub p_w: Vec3,
}

/// What one [`PointBuffer::push_scan`] did with the points it was given.
/// `received = accepted + rejected_nonfinite + rejected_range + rejected_time + thinned`
/// (saturating at `u32::MAX`); `evicted` counts stored points dropped to make room, including points of this
/// very scan when it holds more than the capacity.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanStats {
    /// Points offered.
    pub received: u32,
    /// Points stored.
    pub accepted: u32,
    /// NaN/inf coordinates or time.
    pub rejected_nonfinite: u32,
    /// Too close (incl. all-zero returns) or too far.
    pub rejected_range: u32,
    /// Time outside the INS window (no pose to de-skew with).
    pub rejected_time: u32,
    /// Older points dropped to make room (capacity `P`).
    pub evicted: u32,
    /// Of those, points younger than the association's span
    /// ([`AssociationConfig::span_s`](super::AssociationConfig::span_s)) before the point that
    /// pushed them out: lost before a keyframe could use them all (a buffer too small for the
    /// LiDAR's rate).
    pub evicted_in_span: u32,
    /// Valid points the caller's thinning dropped ([`PointBuffer::push_points_thinned`]).
    pub thinned: u32,
}

/// One stored point: offset from its segment's origin (`w` axes, m) and time offset from the
/// segment's start (LiDAR clock, ns).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Packed {
    pub(crate) d_w: [f32; 3],
    pub(crate) dt_ns: i32,
}

impl Packed {
    const ZERO: Packed = Packed {
        d_w: [0.0; 3],
        dt_ns: 0,
    };
}

/// A run of consecutive ring entries sharing an origin and a start time.
#[derive(Debug, Clone, Copy)]
struct Segment {
    origin_w: Vec3,
    t0_ns: i64,
    /// Bounds of the points' `dt_ns` (conservative after evictions), to skip whole segments.
    dt_min: i32,
    dt_max: i32,
    len: usize,
}

/// The points of one segment as (at most) two slices of the ring, oldest first.
pub(crate) struct SegmentView<'a> {
    pub(crate) origin_w: Vec3,
    pub(crate) t0_ns: i64,
    pub(crate) dt_min: i32,
    pub(crate) dt_max: i32,
    pub(crate) parts: [&'a [Packed]; 2],
}

/// Ring buffer of the latest `P` de-skewed points (`P = 0` does not compile). About
/// `16 P + 12 k` bytes: keep it in a `static` or a `Box` for `P` = [`MAX_LIDAR_POINTS`].
#[derive(Debug, Clone)]
pub struct PointBuffer<const P: usize> {
    pts: [Packed; P],
    segs: Deque<Segment, MAX_SEGMENTS>,
    /// Ring index of the oldest point.
    head: usize,
    len: usize,
}

impl<const P: usize> Default for PointBuffer<P> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const P: usize> PointBuffer<P> {
    /// An empty buffer; `const` so it can initialize a `static`. `P = 0` gives a buffer that
    /// stores nothing (an estimator built without LiDAR storage, which never offers it points).
    pub const fn new() -> Self {
        PointBuffer {
            pts: [Packed::ZERO; P],
            segs: Deque::new(),
            head: 0,
            len: 0,
        }
    }

    /// Drops every point.
    pub fn clear(&mut self) {
        self.segs.clear();
        self.head = 0;
        self.len = 0;
    }

    /// Back to the state [`PointBuffer::new`] builds (the ring zeroed too), in place.
    pub fn reset_to_new(&mut self) {
        self.clear();
        self.pts.fill(Packed::ZERO);
    }

    /// Points stored.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// De-skews and stores a sweep: each point with the INS pose at `t + td_l_s` interpolated
    /// from `ins`, and the extrinsic of `cfg`. Invalid points are rejected and counted; never
    /// panics, whatever the input. Point times may come in any order (sorted is fastest).
    pub fn push_scan<const K: usize>(
        &mut self,
        points: &[LidarPoint],
        ins: &InsWindow<K>,
        cfg: &LidarConfig,
    ) -> ScanStats {
        self.push_points(points.iter().copied(), ins, cfg)
    }

    /// [`Self::push_scan`] over any sequence of points (the estimator's queued sweeps).
    pub fn push_points<const K: usize>(
        &mut self,
        points: impl ExactSizeIterator<Item = LidarPoint>,
        ins: &InsWindow<K>,
        cfg: &LidarConfig,
    ) -> ScanStats {
        self.push_points_thinned(points, ins, cfg, |_, _, _| true)
    }

    /// [`Self::push_points`] keeping only the valid points (finite, inside the range gate) for
    /// which `keep(p_l, range2_m2, t_ns)` is true (`range2_m2` the squared range, so that a
    /// caller that keeps everything takes no root; the others counted in
    /// [`ScanStats::thinned`]); see [`super::thin`].
    pub fn push_points_thinned<const K: usize>(
        &mut self,
        points: impl ExactSizeIterator<Item = LidarPoint>,
        ins: &InsWindow<K>,
        cfg: &LidarConfig,
        mut keep: impl FnMut([f32; 3], f64, i64) -> bool,
    ) -> ScanStats {
        let mut st = ScanStats {
            received: sat_u32(points.len()),
            ..ScanStats::default()
        };
        let td_ns = seconds_to_ns(cfg.td_l_s);
        let span_ns = seconds_to_ns(cfg.association.span_s);
        let r_bl = cfg.extrinsic.q_bl.to_rotation_matrix().into_inner();
        let p_bl = cfg.extrinsic.p_bl;
        let mut cursor = InterpCursor::new();
        // Whether the newest segment was opened by this scan.
        let mut open = false;
        for pt in points {
            let [x, y, z] = pt.p_l;
            if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                st.rejected_nonfinite = st.rejected_nonfinite.saturating_add(1);
                continue;
            }
            let p_l = Vec3::new(f64::from(x), f64::from(y), f64::from(z));
            let r2 = p_l.norm_squared();
            if !((MIN_RANGE_M * MIN_RANGE_M..=MAX_RANGE_M * MAX_RANGE_M).contains(&r2)) {
                st.rejected_range = st.rejected_range.saturating_add(1);
                continue;
            }
            if !keep(pt.p_l, r2, pt.t_ns) {
                st.thinned = st.thinned.saturating_add(1);
                continue;
            }
            let Some((p_wb, q_wb)) = cursor.pose_at(ins, pt.t_ns.saturating_add(td_ns)) else {
                st.rejected_time = st.rejected_time.saturating_add(1);
                continue;
            };
            let p_w = q_wb * (r_bl * p_l + p_bl) + p_wb;
            // Finite INS states and a finite extrinsic give a finite point; an extrinsic that
            // is not (unvalidated config) is rejected here rather than stored.
            if !p_w.iter().all(|v| v.is_finite()) {
                st.rejected_nonfinite = st.rejected_nonfinite.saturating_add(1);
                continue;
            }
            match self.store(pt.t_ns, &p_w, &p_wb, &mut open, span_ns) {
                Some((evicted, in_span)) => {
                    st.evicted = st.evicted.saturating_add(sat_u32(evicted));
                    st.evicted_in_span = st.evicted_in_span.saturating_add(sat_u32(in_span));
                    st.accepted = st.accepted.saturating_add(1);
                }
                None => st.rejected_range = st.rejected_range.saturating_add(1),
            }
        }
        st
    }

    /// Stored points with time `>= t_min_ns` (LiDAR clock), oldest stored first.
    pub fn iter_since(&self, t_min_ns: i64) -> impl Iterator<Item = WorldPoint> + '_ {
        self.segments()
            .filter(move |s| s.t0_ns.saturating_add(i64::from(s.dt_max)) >= t_min_ns)
            .flat_map(move |s| {
                let (origin, t0) = (s.origin_w, s.t0_ns);
                let [a, b] = s.parts;
                a.iter().chain(b.iter()).filter_map(move |q| {
                    let t_ns = t0.saturating_add(i64::from(q.dt_ns));
                    (t_ns >= t_min_ns).then(|| WorldPoint {
                        t_ns,
                        p_w: origin + unpack(q),
                    })
                })
            })
    }

    /// The segments, oldest first, with their points as ring slices.
    pub(crate) fn segments(&self) -> impl Iterator<Item = SegmentView<'_>> + '_ {
        self.segs.iter().scan(self.head, move |start, seg| {
            let s = *start;
            let end = s + seg.len;
            *start = if end >= P { end - P } else { end };
            let parts = if end <= P {
                [self.pts.get(s..end).unwrap_or(&[]), &[][..]]
            } else {
                [
                    self.pts.get(s..).unwrap_or(&[]),
                    self.pts.get(..end - P).unwrap_or(&[]),
                ]
            };
            Some(SegmentView {
                origin_w: seg.origin_w,
                t0_ns: seg.t0_ns,
                dt_min: seg.dt_min,
                dt_max: seg.dt_max,
                parts,
            })
        })
    }

    /// Appends one de-skewed point (`p_wb`: body position, the origin if a segment opens).
    /// Returns the points evicted for it and how many of them were less than `span_ns` older
    /// than it, or `None` (nothing changed) when the point is more than [`MAX_OFFSET_M`] from
    /// the body, which only an absurd extrinsic offset can cause.
    fn store(
        &mut self,
        t_ns: i64,
        p_w: &Vec3,
        p_wb: &Vec3,
        open: &mut bool,
        span_ns: i64,
    ) -> Option<(usize, usize)> {
        let pack = |seg: &Segment| -> Option<Packed> {
            let dt_ns = i32::try_from(t_ns.checked_sub(seg.t0_ns)?).ok()?;
            let d = p_w - seg.origin_w;
            (d.amax() <= MAX_OFFSET_M).then_some(Packed {
                d_w: [d.x as f32, d.y as f32, d.z as f32],
                dt_ns,
            })
        };
        let fresh = Segment {
            origin_w: *p_wb,
            t0_ns: t_ns,
            dt_min: 0,
            dt_max: 0,
            len: 0,
        };
        let fresh_packed = pack(&fresh)?;
        let (mut evicted, mut in_span) = (0, 0);
        if self.len == P {
            let young = self
                .oldest_time_ns()
                .is_some_and(|t| t_ns.saturating_sub(t) < span_ns);
            self.evict_oldest_point();
            evicted += 1;
            in_span += usize::from(young);
        }
        // Append to this scan's segment if it is still there (only P == 1 evicts it whole
        // above) and the point fits it; otherwise open a segment at the body.
        let packed = match self.segs.back().filter(|_| *open).and_then(pack) {
            Some(p) => p,
            None => {
                if self.segs.is_full() {
                    let young = self.segs.front().is_some_and(|s| {
                        t_ns.saturating_sub(s.t0_ns.saturating_add(i64::from(s.dt_max))) < span_ns
                    });
                    let n = self.evict_oldest_segment();
                    evicted += n;
                    in_span += if young { n } else { 0 };
                }
                // Cannot fail: there is room now. Nothing is stored if it did.
                if self.segs.push_back(fresh).is_err() {
                    return Some((evicted, in_span));
                }
                *open = true;
                fresh_packed
            }
        };
        let tail = self.ring(self.head + self.len);
        if let (Some(slot), Some(seg)) = (self.pts.get_mut(tail), self.segs.back_mut()) {
            *slot = packed;
            seg.dt_min = seg.dt_min.min(packed.dt_ns);
            seg.dt_max = seg.dt_max.max(packed.dt_ns);
            seg.len += 1;
            self.len += 1;
        }
        Some((evicted, in_span))
    }

    /// Time of the oldest stored point (LiDAR clock), ns.
    fn oldest_time_ns(&self) -> Option<i64> {
        let seg = self.segs.front()?;
        let q = self.pts.get(self.head)?;
        Some(seg.t0_ns.saturating_add(i64::from(q.dt_ns)))
    }

    fn evict_oldest_point(&mut self) {
        if let Some(front) = self.segs.front_mut() {
            front.len = front.len.saturating_sub(1);
            if front.len == 0 {
                self.segs.pop_front();
            }
        }
        self.head = self.ring(self.head + 1);
        self.len = self.len.saturating_sub(1);
    }

    fn evict_oldest_segment(&mut self) -> usize {
        let n = self.segs.pop_front().map_or(0, |s| s.len.min(self.len));
        self.head = self.ring(self.head + n);
        self.len -= n;
        n
    }

    /// `i mod P` for `i < 2 P`.
    #[inline]
    fn ring(&self, i: usize) -> usize {
        if i >= P {
            i - P
        } else {
            i
        }
    }
}

/// The stored offset as `f64`.
#[inline]
pub(crate) fn unpack(q: &Packed) -> Vec3 {
    Vec3::new(
        f64::from(q.d_w[0]),
        f64::from(q.d_w[1]),
        f64::from(q.d_w[2]),
    )
}

/// Seconds to integer nanoseconds, rounded, saturating (NaN gives 0).
pub(crate) fn seconds_to_ns(s: f64) -> i64 {
    libm::round(s * 1e9) as i64
}

fn sat_u32(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::lidar::testutil::{spiral_cap, sweep, Motion, Shape};
    use crate::lidar::LidarExtrinsic;
    use crate::math::{quat_exp, Quat};
    use std::vec::Vec;

    const MS: i64 = 1_000_000;

    fn room() -> Shape {
        Shape::RoomBox {
            min: Vec3::new(-6.0, -5.0, -2.0),
            max: Vec3::new(8.0, 7.0, 4.0),
        }
    }

    /// Walking at 1.8 m/s and turning at 0.8 rad/s, slightly tilted.
    fn moving() -> Motion {
        Motion {
            p0: Vec3::new(0.2, -0.3, 0.5),
            v: Vec3::new(1.5, 0.8, 0.1),
            q0: quat_exp(&Vec3::new(0.1, -0.05, 0.3)),
            yaw_rate: 0.8,
        }
    }

    fn lidar_cfg() -> LidarConfig {
        LidarConfig {
            extrinsic: LidarExtrinsic {
                q_bl: quat_exp(&Vec3::new(0.2, -0.1, 1.3)),
                p_bl: Vec3::new(0.3, -0.1, 0.2),
            },
            td_l_s: -0.012,
            ..LidarConfig::default()
        }
    }

    /// 4000 returns over 0.1 s (LiDAR clock 100..200 ms), directions over the whole sphere.
    fn box_sweep(m: &Motion, cfg: &LidarConfig) -> Vec<LidarPoint> {
        let dirs = spiral_cap(4000, &Vec3::z(), core::f64::consts::PI);
        let rays = dirs
            .iter()
            .enumerate()
            .map(|(i, d)| (100 * MS + i as i64 * 25_000, *d));
        sweep(m, cfg, &[room()], rays)
    }

    fn stored(buf: &PointBuffer<8192>) -> Vec<WorldPoint> {
        buf.iter_since(i64::MIN).collect()
    }

    #[test]
    fn deskew_puts_every_point_on_the_walls_and_ignoring_motion_would_not() {
        let (m, cfg) = (moving(), lidar_cfg());
        let ins = m.window::<128>(0, 300 * MS, 5 * MS); // 200 Hz
        let pts = box_sweep(&m, &cfg);
        assert_eq!(pts.len(), 4000);
        let mut buf = PointBuffer::<8192>::new();
        let st = buf.push_scan(&pts, &ins, &cfg);
        assert_eq!((st.received, st.accepted, st.evicted), (4000, 4000, 0));
        let out = stored(&buf);
        assert_eq!(out.len(), 4000);
        let worst = out
            .iter()
            .map(|w| room().distance(&w.p_w))
            .fold(0.0, f64::max);
        assert!(worst < 1e-4, "de-skewed point {worst} m off the wall");
        // Times are kept on the LiDAR clock, in push order.
        assert!(out.iter().zip(&pts).all(|(w, p)| w.t_ns == p.t_ns));

        // Same sweep with one pose (the sweep's middle, IMU clock) for every point.
        let (p_wb, q_wb) = m.pose(150 * MS - 12 * MS);
        let ext = cfg.extrinsic;
        let skewed = pts
            .iter()
            .map(|p| {
                let p_l = Vec3::new(p.p_l[0].into(), p.p_l[1].into(), p.p_l[2].into());
                room().distance(&(q_wb * (ext.q_bl * p_l + ext.p_bl) + p_wb))
            })
            .fold(0.0, f64::max);
        assert!(skewed > 0.05, "motion distortion only {skewed} m");
    }

    #[test]
    fn td_shifts_the_pose_used() {
        // The same sweep read with td = 0 instead of -12 ms is off the walls by centimetres.
        let (m, cfg) = (moving(), lidar_cfg());
        let ins = m.window::<128>(0, 300 * MS, 5 * MS);
        let pts = box_sweep(&m, &cfg);
        let mut buf = PointBuffer::<8192>::new();
        buf.push_scan(&pts, &ins, &LidarConfig { td_l_s: 0.0, ..cfg });
        let worst = stored(&buf)
            .iter()
            .map(|w| room().distance(&w.p_w))
            .fold(0.0, f64::max);
        assert!(worst > 0.01, "td ignored? {worst}");
    }

    #[test]
    fn unsorted_and_repeated_times_give_the_same_points() {
        let (m, cfg) = (moving(), lidar_cfg());
        let ins = m.window::<128>(0, 300 * MS, 5 * MS);
        let pts = box_sweep(&m, &cfg);
        // A permutation (7919 is prime to 4000) plus every 10th point repeated.
        let n = pts.len();
        let mut shuffled: Vec<LidarPoint> = (0..n).map(|i| pts[(i * 7919) % n]).collect();
        shuffled.extend(pts.iter().step_by(10).copied());
        let mut buf = PointBuffer::<8192>::new();
        let st = buf.push_scan(&shuffled, &ins, &cfg);
        assert_eq!((st.received, st.accepted), (4400, 4400));
        let out = stored(&buf);
        let worst = out
            .iter()
            .map(|w| room().distance(&w.p_w))
            .fold(0.0, f64::max);
        assert!(worst < 1e-4, "{worst}");
        // Each stored point equals the sorted push's point with the same time.
        let mut sorted_buf = PointBuffer::<8192>::new();
        sorted_buf.push_scan(&pts, &ins, &cfg);
        let reference = stored(&sorted_buf);
        for (w, p) in out.iter().zip(&shuffled) {
            assert_eq!(w.t_ns, p.t_ns);
            let k = ((p.t_ns - 100 * MS) / 25_000) as usize;
            assert!((w.p_w - reference[k].p_w).amax() < 2e-6);
        }
    }

    #[test]
    fn rejects_and_counts_bad_points() {
        let m = moving();
        let cfg = lidar_cfg(); // t_imu = t_lidar - 12 ms
        let ins = m.window::<128>(0, 300 * MS, 5 * MS);
        let p = |t_ms: i64, p_l: [f32; 3]| LidarPoint {
            t_ns: t_ms * MS,
            p_l,
            intensity: 0.0,
        };
        let ok = [3.0f32, 1.0, -0.5];
        let pts = [
            p(100, [f32::NAN, 1.0, 1.0]),
            p(100, [1.0, f32::INFINITY, 1.0]),
            p(100, [1.0, 1.0, f32::NEG_INFINITY]),
            p(100, [0.0, 0.0, 0.0]),
            p(100, [0.05, 0.05, 0.0]),
            p(100, [400.0, 300.0, 10.0]), // 500.1 m
            p(11, ok),                    // IMU time -1 ms: before the window
            p(313, ok),                   // 301 ms: after
            LidarPoint {
                t_ns: i64::MIN,
                ..p(0, ok)
            },
            LidarPoint {
                t_ns: i64::MAX,
                ..p(0, ok)
            },
            p(12, ok),  // IMU time 0: first state
            p(312, ok), // IMU time 300 ms: last state
            p(150, [0.1, 0.0, 0.0]),
            p(150, [499.0, 0.0, 0.0]),
            p(150, ok),
            p(150, ok), // repeated time
            p(120, ok), // out of order
        ];
        let mut buf = PointBuffer::<64>::new();
        let st = buf.push_scan(&pts, &ins, &cfg);
        let want = ScanStats {
            received: 17,
            accepted: 7,
            rejected_nonfinite: 3,
            rejected_range: 3,
            rejected_time: 4,
            evicted: 0,
            evicted_in_span: 0,
            thinned: 0,
        };
        assert_eq!(st, want);
        assert_eq!(buf.len(), 7);
        let times: Vec<i64> = buf.iter_since(i64::MIN).map(|w| w.t_ns / MS).collect();
        assert_eq!(times, [12, 312, 150, 150, 150, 150, 120]);
        // A thinning that drops the valid points at 150 ms: counted apart, the rest as before.
        let mut thinned = PointBuffer::<64>::new();
        let st = thinned.push_points_thinned(pts.iter().copied(), &ins, &cfg, |_, r2, t| {
            assert!((MIN_RANGE_M..=MAX_RANGE_M).contains(&libm::sqrt(r2)));
            t / MS != 150
        });
        let want = ScanStats {
            accepted: 3,
            thinned: 4,
            ..want
        };
        assert_eq!(st, want);
        let times: Vec<i64> = thinned.iter_since(i64::MIN).map(|w| w.t_ns / MS).collect();
        assert_eq!(times, [12, 312, 120]);
        assert_eq!(buf.iter_since(150 * MS).count(), 5);
        assert_eq!(buf.iter_since(313 * MS).count(), 0);

        // No INS state at all: everything valid is a time rejection.
        let empty = InsWindow::<4>::new();
        let st = buf.push_scan(&pts, &empty, &cfg);
        assert_eq!((st.accepted, st.rejected_time), (0, 11));
        assert_eq!(buf.len(), 7);
        buf.clear();
        assert!(buf.is_empty() && buf.iter_since(i64::MIN).next().is_none());
    }

    #[test]
    fn a_scan_of_three_times_the_capacity_keeps_its_last_points() {
        const P: usize = 64;
        let m = moving();
        let cfg = lidar_cfg();
        let ins = m.window::<128>(0, 300 * MS, 5 * MS);
        let mut pts: Vec<LidarPoint> = (0..3 * P as i64)
            .map(|i| LidarPoint {
                t_ns: 20 * MS + i * MS,
                p_l: [2.0 + i as f32 * 0.01, 1.0, 0.5],
                intensity: 0.0,
            })
            .collect();
        pts[5].p_l[0] = f32::NAN;
        pts[190].p_l = [0.0; 3];
        let mut buf = PointBuffer::<P>::new();
        let st = buf.push_scan(&pts, &ins, &cfg);
        assert_eq!(buf.len(), P);
        assert_eq!(st.received, 192);
        assert_eq!(
            (st.accepted, st.rejected_nonfinite, st.rejected_range),
            (190, 1, 1)
        );
        assert_eq!(
            st.received,
            st.accepted + st.rejected_nonfinite + st.rejected_range + st.rejected_time
        );
        assert_eq!(st.evicted, 190 - P as u32);
        // Each evicted point is about P ms older than the one that pushed it out: within the
        // 0.5 s span, not within 50 ms.
        assert_eq!(st.evicted_in_span, st.evicted);
        let mut short = cfg;
        short.association.span_s = 0.05;
        let st_short = PointBuffer::<P>::new().push_scan(&pts, &ins, &short);
        assert_eq!(
            (st_short.evicted, st_short.evicted_in_span),
            (st.evicted, 0)
        );
        // The last P valid ones: indices 127..=191 without 190.
        let want: Vec<i64> = (127..192)
            .filter(|&i| i != 190)
            .map(|i| 20 * MS + i * MS)
            .collect();
        let got: Vec<i64> = buf.iter_since(i64::MIN).map(|w| w.t_ns).collect();
        assert_eq!(got, want);
        // A further scan evicts as many as it stores.
        let st = buf.push_scan(&pts[..10], &ins, &cfg);
        assert_eq!((st.accepted, st.evicted, buf.len()), (9, 9, P));
    }

    #[test]
    fn segment_table_and_tiny_capacity_stay_consistent() {
        let m = moving();
        let cfg = lidar_cfg();
        let ins = m.window::<128>(0, 300 * MS, 5 * MS);
        let one = |i: i64| LidarPoint {
            t_ns: 20 * MS + i * 100_000,
            p_l: [2.0, 1.0, 0.5 + i as f32 * 0.001],
            intensity: 0.0,
        };
        // 300 one-point scans: only MAX_SEGMENTS segments (= points) survive.
        let mut buf = PointBuffer::<1024>::new();
        let mut evicted = 0;
        for i in 0..300 {
            evicted += buf.push_scan(&[one(i)], &ins, &cfg).evicted;
        }
        assert_eq!(buf.len(), MAX_SEGMENTS);
        assert_eq!(evicted as usize, 300 - MAX_SEGMENTS);
        let got: Vec<i64> = buf.iter_since(i64::MIN).map(|w| w.t_ns).collect();
        let want: Vec<i64> = (300 - MAX_SEGMENTS as i64..300)
            .map(|i| one(i).t_ns)
            .collect();
        assert_eq!(got, want);
        // The ring wraps inside a segment: still every point in order.
        let scan: Vec<LidarPoint> = (300..1300).map(one).collect();
        buf.push_scan(&scan, &ins, &cfg);
        let got: Vec<i64> = buf.iter_since(i64::MIN).map(|w| w.t_ns).collect();
        let want: Vec<i64> = (276..1300).map(|i| one(i).t_ns).collect();
        assert_eq!(got, want);

        // Capacity 1: the last valid point of each scan.
        let mut buf = PointBuffer::<1>::new();
        let scan: Vec<LidarPoint> = (0..5).map(one).collect();
        let st = buf.push_scan(&scan, &ins, &cfg);
        assert_eq!((st.accepted, st.evicted, buf.len()), (5, 4, 1));
        assert_eq!(
            buf.iter_since(i64::MIN).next().map(|w| w.t_ns),
            Some(one(4).t_ns)
        );
        buf.push_scan(&scan[..2], &ins, &cfg);
        assert_eq!(
            buf.iter_since(i64::MIN).next().map(|w| w.t_ns),
            Some(one(1).t_ns)
        );
    }

    #[test]
    fn far_travel_and_long_scans_open_segments_without_losing_precision() {
        // 10 km from the origin at 630 m/s for 4 s: offsets beyond MAX_OFFSET_M and time
        // offsets beyond i32 nanoseconds inside one scan.
        let m = Motion {
            p0: Vec3::new(10_000.0, -7_000.0, 30.0),
            v: Vec3::new(600.0, 200.0, 0.0),
            q0: Quat::identity(),
            yaw_rate: 0.1,
        };
        let cfg = lidar_cfg();
        let ins = m.window::<1024>(0, 4_000 * MS, 5 * MS);
        let plane = Shape::Plane {
            n: Vec3::new(0.0, 0.0, 1.0),
            d: 0.0,
        };
        let dirs = spiral_cap(4000, &-Vec3::z(), 1.0);
        // Directions are in l: rotate them so they point down in w.
        let q_lw = cfg.extrinsic.q_bl.inverse();
        let rays = dirs
            .iter()
            .enumerate()
            .map(|(i, d)| (20 * MS + i as i64 * 990_000, q_lw * d));
        let pts = sweep(&m, &cfg, &[plane], rays);
        assert!(pts.len() > 3000);
        let mut buf = PointBuffer::<8192>::new();
        let st = buf.push_scan(&pts, &ins, &cfg);
        assert_eq!(st.accepted as usize, pts.len());
        assert!(buf.segs.len() > 1, "one segment for a 1 km, 4 s scan");
        let worst = buf
            .iter_since(i64::MIN)
            .map(|w| plane.distance(&w.p_w))
            .fold(0.0, f64::max);
        assert!(worst < 1e-4, "{worst}");
    }

    #[test]
    fn storage_is_compact() {
        let per_point =
            core::mem::size_of::<PointBuffer<MAX_LIDAR_POINTS>>() as f64 / MAX_LIDAR_POINTS as f64;
        assert!(per_point <= 16.5, "{per_point} bytes a point");
        assert_eq!(core::mem::size_of::<Packed>(), 16);
    }
}
