//! Ground truth along a replay (interpolated at the estimator's stamps, streamed beside it) and
//! the percentiles of the run's timings.

use povins_core::estimator::KeyframeReport;
use povins_core::inertial::NavState;

/// Ground-truth state at `t_ns` by linear interpolation (slerp for attitude).
pub fn interpolate_state(gt: &[NavState], t_ns: i64) -> Option<NavState> {
    let k = gt.partition_point(|g| g.t_ns <= t_ns);
    let (a, b) = (
        gt.get(k.checked_sub(1)?)?,
        gt.get(k).unwrap_or(gt.get(k - 1)?),
    );
    Some(interpolate_between(a, b, t_ns))
}

/// The state at `t_ns` between `a` and `b` (`a.t_ns <= t_ns <= b.t_ns`, or `a` itself).
fn interpolate_between(a: &NavState, b: &NavState, t_ns: i64) -> NavState {
    if b.t_ns == a.t_ns {
        return NavState { t_ns, ..*a };
    }
    let w = (t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
    NavState {
        t_ns,
        p_wb: a.p_wb.lerp(&b.p_wb, w),
        q_wb: a.q_wb.slerp(&b.q_wb, w),
        v_wb: a.v_wb.lerp(&b.v_wb, w),
        bg: a.bg.lerp(&b.bg, w),
        ba: a.ba.lerp(&b.ba, w),
    }
}

/// [`interpolate_state`] over a ground-truth stream read once, for stamps that do not decrease
/// (an evaluation that passes over an hour of ground truth without holding it): the same
/// states, `None` before the first or after the last stamp (and for a stamp earlier than the
/// previous one asked). The first error of the stream is kept ([`GtCursor::error`]) and ends it.
pub struct GtCursor<I, E> {
    stream: I,
    /// The last state at or before the stamps asked so far, and the one after it.
    a: Option<NavState>,
    b: Option<NavState>,
    error: Option<E>,
}

impl<E, I: Iterator<Item = Result<NavState, E>>> GtCursor<I, E> {
    /// A cursor at the start of `stream`.
    pub fn new(mut stream: I) -> Self {
        let mut error = None;
        let b = match stream.next() {
            Some(Ok(s)) => Some(s),
            Some(Err(e)) => {
                error = Some(e);
                None
            }
            None => None,
        };
        GtCursor {
            stream,
            a: None,
            b,
            error,
        }
    }

    /// The ground-truth state at `t_ns`, within the stream's span.
    pub fn at(&mut self, t_ns: i64) -> Option<NavState> {
        while let Some(b) = self.b.filter(|b| b.t_ns <= t_ns) {
            self.a = Some(b);
            self.b = match self.stream.next() {
                Some(Ok(s)) if self.error.is_none() => Some(s),
                Some(Err(e)) => {
                    self.error.get_or_insert(e);
                    None
                }
                _ => None,
            };
        }
        let a = self.a.filter(|a| a.t_ns <= t_ns)?;
        match self.b {
            Some(b) => Some(interpolate_between(&a, &b, t_ns)),
            None if a.t_ns == t_ns => Some(a),
            None => None,
        }
    }

    /// The last state, once the stream has ended before the stamps asked.
    pub fn last(&self) -> Option<NavState> {
        self.a.filter(|_| self.b.is_none())
    }

    /// The error that ended the stream, if one did.
    pub fn error(self) -> Option<E> {
        self.error
    }
}

/// One of the reports' `_ns` timings per keyframe, in ms, sorted ascending.
pub fn sorted_ms(reports: &[KeyframeReport], f: impl Fn(&KeyframeReport) -> u64) -> Vec<f64> {
    let mut v: Vec<f64> = reports.iter().map(|r| f(r) as f64 * 1e-6).collect();
    v.sort_by(f64::total_cmp);
    v
}

/// Percentile (nearest rank) of a sorted slice (0 when empty).
pub fn percentile<T: Copy + Into<f64>>(sorted: &[T], p: f64) -> f64 {
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    match sorted.get(rank.clamp(1, sorted.len().max(1)) - 1) {
        Some(&v) => v.into(),
        None => 0.0,
    }
}
