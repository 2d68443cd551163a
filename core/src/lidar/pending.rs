//! Sweeps waiting for the INS: a FIFO of raw LiDAR points (LiDAR frame, own times) in a ring of
//! `Q` points, at most `S` sweeps.
//!
//! A sweep can only be de-skewed once the INS has passed its last point
//! ([`super::PointBuffer::push_scan`]); the estimator keeps sweeps here until its processed IMU
//! time reaches their trigger (`max t_point + td_l`), so a caller pushes every sensor as it
//! arrives. Points are packed to 16 bytes (`f32` position, `i32` ns after the sweep's first
//! point): unpacking gives back the pushed [`LidarPoint`] exactly (intensity is not kept: the
//! estimator does not use it).

use super::LidarPoint;
use heapless::Deque;

#[derive(Debug, Clone, Copy)]
struct RawPoint {
    p_l: [f32; 3],
    dt_ns: i32,
}

impl RawPoint {
    const ZERO: RawPoint = RawPoint {
        p_l: [0.0; 3],
        dt_ns: 0,
    };
}

/// One queued sweep: `len` points from ring position `start`.
#[derive(Debug, Clone, Copy)]
struct Sweep {
    t0_ns: i64,
    trigger_ns: i64,
    start: usize,
    len: usize,
    /// Points of the pushed sweep that could not be packed (time more than 2.1 s from the
    /// first point).
    dropped: u32,
    received: u32,
}

/// What [`PendingSweeps::push`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Queued {
    /// Queued; `evicted` points (the first ones pushed) did not fit in the free room and were
    /// dropped, as a full point buffer would evict its oldest points; `outside` were not kept
    /// by the caller's filter ([`PendingSweeps::push_kept`]).
    Queued {
        /// Points dropped for lack of room.
        evicted: u32,
        /// Points the filter did not keep.
        outside: u32,
    },
    /// Refused whole: no free sweep slot, or no room at all for its points.
    Full,
}

/// The queue (see the module docs).
#[derive(Debug, Clone)]
pub struct PendingSweeps<const Q: usize, const S: usize> {
    pts: [RawPoint; Q],
    sweeps: Deque<Sweep, S>,
    /// Ring position of the oldest queued point.
    head: usize,
    /// Points queued.
    len: usize,
}

impl<const Q: usize, const S: usize> Default for PendingSweeps<Q, S> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const Q: usize, const S: usize> PendingSweeps<Q, S> {
    /// An empty queue; `const` (all zero bits) so it can live in a `static` estimator.
    pub const fn new() -> Self {
        PendingSweeps {
            pts: [RawPoint::ZERO; Q],
            sweeps: Deque::new(),
            head: 0,
            len: 0,
        }
    }

    /// Drops every queued sweep.
    pub fn clear(&mut self) {
        self.sweeps.clear();
        self.head = 0;
        self.len = 0;
    }

    /// Sweeps queued.
    pub fn sweeps(&self) -> usize {
        self.sweeps.len()
    }

    /// Queues a sweep due at `trigger_ns` (IMU clock). When its points do not all fit, the
    /// last ones pushed (the newest of a sweep in time order) are kept; refused whole when no
    /// sweep slot is free or no point fits.
    pub fn push(&mut self, points: &[LidarPoint], trigger_ns: i64) -> Queued {
        self.push_kept(points, trigger_ns, |_| true)
    }

    /// [`PendingSweeps::push`] of the points `keep` keeps (the others are counted in
    /// [`Queued::Queued::outside`]; the sweep's times still count all of them).
    pub fn push_kept(
        &mut self,
        points: &[LidarPoint],
        trigger_ns: i64,
        keep: impl Fn(&LidarPoint) -> bool,
    ) -> Queued {
        self.push_kept_shifted(points, trigger_ns, 0, keep)
    }

    /// [`PendingSweeps::push_kept`] of points whose times are `shift_ns` ahead of the queue's
    /// clock (`trigger_ns` is on the queue's clock): they are queued `shift_ns` earlier.
    pub fn push_kept_shifted(
        &mut self,
        points: &[LidarPoint],
        trigger_ns: i64,
        shift_ns: i64,
        keep: impl Fn(&LidarPoint) -> bool,
    ) -> Queued {
        let t0_ns = points.iter().map(|p| p.t_ns).min().unwrap_or(trigger_ns);
        let packs = |p: &LidarPoint| i32::try_from(p.t_ns.saturating_sub(t0_ns)).is_ok();
        let fits = |p: &&LidarPoint| packs(p) && keep(p);
        let all_packable = points.iter().filter(|p| packs(p)).count();
        let packable = points.iter().filter(fits).count();
        let outside = all_packable - packable;
        let free = Q - self.len;
        if self.sweeps.is_full() || (packable > 0 && free == 0) {
            return Queued::Full;
        }
        let evicted = packable.saturating_sub(free);
        let n = packable - evicted;
        let start = (self.head + self.len) % Q.max(1);
        let mut pos = start;
        for p in points.iter().filter(fits).skip(evicted) {
            if let (Some(slot), Ok(dt_ns)) = (
                self.pts.get_mut(pos),
                i32::try_from(p.t_ns.saturating_sub(t0_ns)),
            ) {
                *slot = RawPoint { p_l: p.p_l, dt_ns };
            }
            pos = if pos + 1 == Q { 0 } else { pos + 1 };
        }
        self.len += n;
        let sweep = Sweep {
            t0_ns: t0_ns.saturating_sub(shift_ns),
            trigger_ns,
            start,
            len: n,
            dropped: u32::try_from(points.len() - all_packable).unwrap_or(u32::MAX),
            received: u32::try_from(points.len()).unwrap_or(u32::MAX),
        };
        // Not full (checked above): cannot fail.
        let _ = self.sweeps.push_back(sweep);
        Queued::Queued {
            evicted: u32::try_from(evicted).unwrap_or(u32::MAX),
            outside: u32::try_from(outside).unwrap_or(u32::MAX),
        }
    }

    /// Moves the times of the queued sweeps due after `after_ns` back by `by_ns` (a clock jump:
    /// `estimator::clock_jump`).
    pub fn shift_due_after(&mut self, after_ns: i64, by_ns: i64) {
        for s in self.sweeps.iter_mut().filter(|s| s.trigger_ns > after_ns) {
            s.t0_ns = s.t0_ns.saturating_sub(by_ns);
            s.trigger_ns = s.trigger_ns.saturating_sub(by_ns);
        }
    }

    /// Trigger time of the oldest queued sweep, ns.
    pub fn next_trigger_ns(&self) -> Option<i64> {
        self.sweeps.front().map(|s| s.trigger_ns)
    }

    /// Takes the oldest sweep out: calls `f` with its points (as pushed, intensity 0) and the
    /// number of points pushed with it (received) and of those that could not be queued.
    pub fn pop_with<R>(
        &mut self,
        f: impl FnOnce(&mut dyn ExactSizeIterator<Item = LidarPoint>, u32, u32) -> R,
    ) -> Option<R> {
        let sw = self.sweeps.pop_front()?;
        let (a, b) = if sw.start + sw.len <= Q {
            (
                self.pts.get(sw.start..sw.start + sw.len).unwrap_or(&[]),
                &[][..],
            )
        } else {
            (
                self.pts.get(sw.start..).unwrap_or(&[]),
                self.pts.get(..sw.start + sw.len - Q).unwrap_or(&[]),
            )
        };
        let t0 = sw.t0_ns;
        let mut it = Unpack {
            a: a.iter(),
            b: b.iter(),
            t0,
        };
        let r = f(&mut it, sw.received, sw.dropped);
        self.head = (self.head + sw.len) % Q.max(1);
        self.len -= sw.len.min(self.len);
        Some(r)
    }
}

struct Unpack<'a> {
    a: core::slice::Iter<'a, RawPoint>,
    b: core::slice::Iter<'a, RawPoint>,
    t0: i64,
}

impl Iterator for Unpack<'_> {
    type Item = LidarPoint;

    fn next(&mut self) -> Option<LidarPoint> {
        let q = self.a.next().or_else(|| self.b.next())?;
        Some(LidarPoint {
            t_ns: self.t0.saturating_add(i64::from(q.dt_ns)),
            p_l: q.p_l,
            intensity: 0.0,
        })
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.a.len() + self.b.len();
        (n, Some(n))
    }
}

impl ExactSizeIterator for Unpack<'_> {}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn sweep(t0: i64, n: usize) -> Vec<LidarPoint> {
        (0..n)
            .map(|k| LidarPoint {
                t_ns: t0 + 1000 * k as i64,
                p_l: [k as f32, 0.5, -1.25 * k as f32],
                intensity: 0.0,
            })
            .collect()
    }

    fn pop(q: &mut PendingSweeps<10, 3>) -> Option<(Vec<LidarPoint>, u32, u32)> {
        q.pop_with(|it, rec, drop| (it.collect(), rec, drop))
    }

    #[test]
    fn sweeps_come_back_exactly_in_order_across_the_ring_end() {
        let mut q: PendingSweeps<10, 3> = PendingSweeps::new();
        let (a, b, c) = (sweep(0, 4), sweep(10_000, 4), sweep(20_000, 5));
        const ALL: Queued = Queued::Queued {
            evicted: 0,
            outside: 0,
        };
        assert_eq!(q.push(&a, 5), ALL);
        assert_eq!(q.push(&b, 6), ALL);
        assert_eq!(q.next_trigger_ns(), Some(5));
        assert_eq!(pop(&mut q), Some((a, 4, 0)));
        // Fits, wrapping around the ring's end.
        assert_eq!(q.push(&c, 7), ALL);
        assert_eq!(pop(&mut q), Some((b, 4, 0)));
        assert_eq!(pop(&mut q), Some((c, 5, 0)));
        assert_eq!(pop(&mut q), None);
        assert_eq!(q.sweeps(), 0);
    }

    #[test]
    fn a_sweep_larger_than_the_room_keeps_its_last_points() {
        let mut q: PendingSweeps<10, 3> = PendingSweeps::new();
        let (a, b) = (sweep(0, 7), sweep(10_000, 5));
        assert_eq!(
            q.push(&a, 1),
            Queued::Queued {
                evicted: 0,
                outside: 0
            }
        );
        // 3 points free: the last 3 of b are kept.
        assert_eq!(
            q.push(&b, 2),
            Queued::Queued {
                evicted: 2,
                outside: 0
            }
        );
        assert_eq!(q.push(&b, 3), Queued::Full);
        assert_eq!(pop(&mut q), Some((a, 7, 0)));
        let (kept, received, dropped) = pop(&mut q).expect("b");
        assert_eq!((&kept[..], received, dropped), (&b[2..], 5, 0));
    }

    #[test]
    fn points_too_far_in_time_are_dropped_and_counted() {
        let mut q: PendingSweeps<10, 3> = PendingSweeps::new();
        let mut s = sweep(0, 3);
        s[1].t_ns = i64::MAX;
        assert_eq!(
            q.push(&s, 1),
            Queued::Queued {
                evicted: 0,
                outside: 0
            }
        );
        let (pts, rec, dropped) = pop(&mut q).expect("one sweep");
        assert_eq!((pts.len(), rec, dropped), (2, 3, 1));
        // Empty sweeps and a full slot list.
        for k in 0..3 {
            assert_eq!(
                q.push(&[], k),
                Queued::Queued {
                    evicted: 0,
                    outside: 0
                }
            );
        }
        assert_eq!(q.push(&[], 9), Queued::Full);
    }

    #[test]
    fn zero_capacity_refuses_points_but_not_empty_sweeps() {
        let mut q: PendingSweeps<0, 2> = PendingSweeps::new();
        assert_eq!(q.push(&sweep(0, 1), 1), Queued::Full);
        assert_eq!(
            q.push(&[], 1),
            Queued::Queued {
                evicted: 0,
                outside: 0
            }
        );
        assert_eq!(q.pop_with(|it, _, _| it.len()), Some(0));
    }
}
