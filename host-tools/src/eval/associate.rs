//! Timestamp association, the rules of evo's `sync.associate_trajectories` (nearest time):
//!
//! 1. The trajectory with fewer poses is the one iterated ("short"); on equal counts that is the
//!    estimate. The time offset is added to the estimate's stamps (so it is subtracted from the
//!    ground truth's when the ground truth is the longer one).
//! 2. A short stamp outside `[long_first - max_diff, long_last + max_diff]` is skipped.
//! 3. Otherwise its candidates are the first long stamp strictly after it (`searchsorted` right,
//!    clamped to the last) and the one before. The later one wins only when strictly closer; on a
//!    tie the earlier one wins. A candidate further than `max_diff` is rejected.
//! 4. Matches are *not* made unique: two short stamps may share one long pose (evo does the same).
//!
//! evo compares `f64` seconds; we compare integer nanoseconds, which gives the same pairs except
//! for differences within float rounding (~0.2 us at epoch-sized stamps) of `max_diff` or of a tie.

/// A matched pair of indices into the ground truth and the estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pair {
    /// Index into the ground truth.
    pub gt: usize,
    /// Index into the estimate.
    pub est: usize,
}

/// Matches each stamp of `short` to its nearest stamp of `long + offset_long_ns`. Both must be
/// sorted ascending. Returns `(short_index, long_index)` pairs in `short` order.
fn match_nearest(
    short: &[i64],
    long: &[i64],
    max_diff_ns: i64,
    offset_long_ns: i64,
) -> Vec<(usize, usize)> {
    let (Some(&first), Some(&last)) = (long.first(), long.last()) else {
        return Vec::new();
    };
    NearestMatch::new(
        short.iter().copied().zip(0..),
        long.iter().copied().zip(0..),
        (first, last),
        max_diff_ns,
        offset_long_ns,
    )
    .collect()
}

/// The rules above over two streams of `(stamp, item)` sorted ascending, one pass over each
/// (the evaluation of a long run passes over its files rather than hold them): yields
/// `(short item, long item)` in `short` order. `long_span` is the first and last stamp of `long`
/// (rule 2 needs them before the stream reaches them).
pub struct NearestMatch<S, L: Iterator> {
    short: S,
    long: L,
    /// The long item before `prev`, the last with a stamp `<= t`, and the first after it.
    before: Option<L::Item>,
    prev: Option<L::Item>,
    next: Option<L::Item>,
    /// `long_span` with the offset, and the tolerance, as `i128` (no overflow).
    span: (i128, i128),
    max: i128,
    offset: i128,
}

impl<A, B: Copy, S: Iterator<Item = (i64, A)>, L: Iterator<Item = (i64, B)>> NearestMatch<S, L> {
    /// Matches `short` against `long + offset_long_ns` within `max_diff_ns`.
    pub fn new(
        short: S,
        mut long: L,
        long_span: (i64, i64),
        max_diff_ns: i64,
        offset_long_ns: i64,
    ) -> Self {
        let offset = i128::from(offset_long_ns);
        let next = long.next();
        NearestMatch {
            short,
            long,
            before: None,
            prev: None,
            next,
            span: (
                i128::from(long_span.0) + offset,
                i128::from(long_span.1) + offset,
            ),
            max: i128::from(max_diff_ns),
            offset,
        }
    }

    fn at(&self, item: &(i64, B)) -> i128 {
        i128::from(item.0) + self.offset
    }
}

impl<A, B: Copy, S: Iterator<Item = (i64, A)>, L: Iterator<Item = (i64, B)>> Iterator
    for NearestMatch<S, L>
{
    type Item = (A, B);

    fn next(&mut self) -> Option<(A, B)> {
        loop {
            let (t, a) = self.short.next()?;
            let t = i128::from(t);
            if t < self.span.0 - self.max || t > self.span.1 + self.max {
                continue;
            }
            while let Some(n) = self.next.filter(|n| self.at(n) <= t) {
                self.before = self.prev.replace(n);
                self.next = self.long.next();
            }
            // `ub`: the first long stamp after `t`, clamped to the last; `lb` the one before.
            let (ub, lb) = match self.next {
                Some(n) => (n, self.prev),
                None => match self.prev {
                    Some(p) => (p, self.before),
                    None => continue,
                },
            };
            let diff_ub = self.at(&ub) - t;
            let diff_lb = lb.map_or(i128::MAX, |l| t - self.at(&l));
            if diff_ub <= self.max && diff_ub < diff_lb {
                return Some((a, ub.1));
            }
            if let Some(l) = lb.filter(|_| diff_lb <= self.max && diff_lb <= diff_ub) {
                return Some((a, l.1));
            }
        }
    }
}

/// Associates ground-truth and estimate stamps (both sorted ascending, integer ns) by nearest
/// time within `max_diff_ns`, after adding `offset_est_ns` to the estimate's stamps.
/// Pairs come in increasing time order.
pub fn associate(
    gt_t_ns: &[i64],
    est_t_ns: &[i64],
    max_diff_ns: i64,
    offset_est_ns: i64,
) -> Vec<Pair> {
    if est_t_ns.len() > gt_t_ns.len() {
        match_nearest(gt_t_ns, est_t_ns, max_diff_ns, offset_est_ns)
            .into_iter()
            .map(|(g, e)| Pair { gt: g, est: e })
            .collect()
    } else {
        // The estimate is the short side: shifting it by +offset equals shifting gt by -offset.
        match_nearest(
            est_t_ns,
            gt_t_ns,
            max_diff_ns,
            offset_est_ns.saturating_neg(),
        )
        .into_iter()
        .map(|(e, g)| Pair { gt: g, est: e })
        .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;

    #[test]
    fn nearest_within_tolerance_ties_go_to_the_earlier() {
        let gt = [0, 10 * MS, 20 * MS, 30 * MS, 40 * MS];
        // 4 ms -> 0; 15 ms is a tie between 10 and 20 -> 10; 26 ms -> 30; 55 ms is beyond the
        // last gt stamp by 15 ms -> rejected.
        let est = [4 * MS, 15 * MS, 26 * MS, 55 * MS];
        let pairs = associate(&gt, &est, 10 * MS, 0);
        let got: Vec<(usize, usize)> = pairs.iter().map(|p| (p.gt, p.est)).collect();
        assert_eq!(got, vec![(0, 0), (1, 1), (3, 2)]);
    }

    #[test]
    fn rejects_beyond_max_diff_and_applies_offset_to_estimate() {
        let gt = [0, 100 * MS, 200 * MS];
        let est = [1_000 * MS, 1_103 * MS, 1_250 * MS];
        assert!(associate(&gt, &est, 10 * MS, 0).is_empty());
        let got: Vec<(usize, usize)> = associate(&gt, &est, 10 * MS, -1_000 * MS)
            .iter()
            .map(|p| (p.gt, p.est))
            .collect();
        // est + offset = 0, 103, 250 ms: the last is 50 ms from 200 ms.
        assert_eq!(got, vec![(0, 0), (1, 1)]);
    }

    #[test]
    fn longer_estimate_iterates_ground_truth_and_may_reuse_poses() {
        // gt is short: each gt stamp picks its nearest estimate; est + offset(-5 ms).
        let gt = [10 * MS, 20 * MS];
        let est = [12 * MS, 13 * MS, 14 * MS, 16 * MS, 26 * MS];
        let got: Vec<(usize, usize)> = associate(&gt, &est, 5 * MS, -5 * MS)
            .iter()
            .map(|p| (p.gt, p.est))
            .collect();
        // est - 5 ms = 7, 8, 9, 11, 21: gt 10 -> 9 and 11 tie -> earlier (index 2); gt 20 -> 21.
        assert_eq!(got, vec![(0, 2), (1, 4)]);
        // Non-unique: a dense short trajectory against a sparse long one reuses long poses.
        let long = [0, 100 * MS, 200 * MS, 300 * MS];
        let short = [99 * MS, 101 * MS, 102 * MS];
        let got: Vec<(usize, usize)> = associate(&long, &short, 5 * MS, 0)
            .iter()
            .map(|p| (p.gt, p.est))
            .collect();
        assert_eq!(got, vec![(1, 0), (1, 1), (1, 2)]);
    }

    /// The streaming matcher against the rules as first written (a binary search per short
    /// stamp), on random stamps with ties, offsets and stamps outside the long span.
    #[test]
    fn one_pass_matches_the_binary_search() {
        fn reference(short: &[i64], long: &[i64], max: i64, off: i64) -> Vec<(usize, usize)> {
            let at = |i: usize| long[i] as i128 + off as i128;
            let max = max as i128;
            let mut out = Vec::new();
            if long.is_empty() {
                return out;
            }
            let (first, last) = (at(0), at(long.len() - 1));
            for (i, &t) in short.iter().enumerate() {
                let t = t as i128;
                if t < first - max || t > last + max {
                    continue;
                }
                let ub = long.partition_point(|&s| s as i128 + off as i128 <= t);
                let ub = ub.min(long.len() - 1);
                let diff_ub = at(ub) - t;
                let diff_lb = if ub > 0 { t - at(ub - 1) } else { i128::MAX };
                if diff_ub <= max && diff_ub < diff_lb {
                    out.push((i, ub));
                } else if diff_lb <= max && diff_lb <= diff_ub {
                    out.push((i, ub - 1));
                }
            }
            out
        }
        let mut rng = crate::eval::testutil::Rng::new(7);
        let mut stamps = |n: usize, step: f64| -> Vec<i64> {
            let mut t = (rng.next() * 50.0) as i64;
            (0..n)
                .map(|_| {
                    t += 1 + ((rng.next() + 1.0) * step) as i64;
                    t
                })
                .collect()
        };
        for case in 0..200 {
            let short = stamps(1 + case % 37, 10.0);
            let long = stamps(case % 23, 6.0 + (case % 5) as f64);
            for (max, off) in [(3, 0), (5, -7), (0, 2), (40, 11), (1, -200)] {
                assert_eq!(
                    match_nearest(&short, &long, max, off),
                    reference(&short, &long, max, off),
                    "case {case}, max {max}, offset {off}"
                );
            }
        }
    }
}
