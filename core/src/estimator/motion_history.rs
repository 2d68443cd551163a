//! The IMU's recent motion in blocks: what a long IMU gap is judged by.
//!
//! A gap longer than `imu_gap.bridge_max_s` is bridged only when a line between the samples
//! around it would have followed the motion before it closely enough
//! ([`super::config::ImuGapConfig::long_bridge_max_s`]). Measuring that on windows of the
//! gap's length (up to seconds) needs more history than the keyframe window holds (about
//! 2-3 s), so the estimator keeps this summary of the last [`BLOCKS`] x [`BLOCK_NS`] (9.6 s):
//! per block its first sample and the sums of its samples, fixed capacity, no heap.
//!
//! [`MotionHistory::line_departure`] is [`super::timing`]'s `line_departure` at block
//! resolution: consecutive windows run from a block's first sample to the first sample of the
//! first block at least the span later (a gap runs from the sample before it to the one after),
//! and in each the mean of the samples inside is compared with the midpoint of the two end
//! samples (what the bridge's linear interpolation integrates to); the RMS per axis over the
//! windows is the line's error, the end samples' own noise and vibration counted.

use super::timing::Departure;
use crate::inertial::ImuSample;
use crate::math::Vec3;

/// Length of a block, ns.
pub(super) const BLOCK_NS: i64 = 100_000_000;
/// Blocks kept (9.6 s at [`BLOCK_NS`]).
pub(super) const BLOCKS: usize = 96;

/// One block: its first sample and the sums over all its samples.
#[derive(Debug, Clone, Copy)]
struct Block {
    t0_ns: i64,
    first_a: Vec3,
    first_g: Vec3,
    sum_a: Vec3,
    sum_g: Vec3,
    n: u32,
}

/// The recent IMU samples as block sums (see the module docs). Samples must come in time
/// order without gaps: [`MotionHistory::clear`] at a gap.
#[derive(Debug, Clone)]
pub(super) struct MotionHistory {
    blocks: heapless::Deque<Block, BLOCKS>,
}

impl MotionHistory {
    /// Empty.
    pub(super) const fn new() -> Self {
        Self {
            blocks: heapless::Deque::new(),
        }
    }

    /// Forgets everything (after a gap: a window must not span it).
    pub(super) fn clear(&mut self) {
        self.blocks.clear();
    }

    /// Adds a sample (time order; one not later than the newest is ignored).
    pub(super) fn push(&mut self, s: &ImuSample) {
        if let Some(b) = self.blocks.back_mut() {
            if s.t_ns < b.t0_ns.saturating_add(BLOCK_NS) {
                if s.t_ns > b.t0_ns {
                    b.sum_a += s.accel_mps2;
                    b.sum_g += s.gyro_rps;
                    b.n += 1;
                }
                return;
            }
        }
        if self.blocks.is_full() {
            let _ = self.blocks.pop_front();
        }
        // Not full (made room above): cannot fail.
        let _ = self.blocks.push_back(Block {
            t0_ns: s.t_ns,
            first_a: s.accel_mps2,
            first_g: s.gyro_rps,
            sum_a: s.accel_mps2,
            sum_g: s.gyro_rps,
            n: 1,
        });
    }

    /// How far a line between two samples `span_ns` apart would have missed the motion in
    /// between, over the history (module docs): the RMS per axis of the specific force (m/s^2)
    /// and the angular rate (rad/s) about the line, `None` with fewer than three windows
    /// ([`Departure`], the bridge's own measure's sums).
    pub(super) fn line_departure(&self, span_ns: i64) -> Option<(f64, f64)> {
        let mut it = self.blocks.iter();
        let mut start = it.next()?;
        let (mut sum_a, mut sum_g, mut n) = (Vec3::zeros(), Vec3::zeros(), 0u32);
        let mut dep = Departure::new();
        // The window's inner samples: the start block's after its first sample, then whole
        // blocks until one starts at least the span later (its first sample ends the window).
        fn add_inner(b: &Block, sa: &mut Vec3, sg: &mut Vec3, k: &mut u32, skip_first: bool) {
            *sa += b.sum_a;
            *sg += b.sum_g;
            *k += b.n;
            if skip_first {
                *sa -= b.first_a;
                *sg -= b.first_g;
                *k = k.saturating_sub(1);
            }
        }
        add_inner(start, &mut sum_a, &mut sum_g, &mut n, true);
        for b in it {
            if b.t0_ns < start.t0_ns.saturating_add(span_ns) {
                add_inner(b, &mut sum_a, &mut sum_g, &mut n, false);
                continue;
            }
            dep.add(
                (sum_a, sum_g, n),
                (&start.first_a, &start.first_g),
                (&b.first_a, &b.first_g),
            );
            start = b;
            (sum_a, sum_g, n) = (Vec3::zeros(), Vec3::zeros(), 0);
            add_inner(start, &mut sum_a, &mut sum_g, &mut n, true);
        }
        dep.rms()
    }
}

#[cfg(test)]
mod tests {
    use super::super::timing::line_departure;
    use super::{MotionHistory, BLOCKS, BLOCK_NS};
    use crate::inertial::ImuSample;
    use crate::math::Vec3;

    /// 200 Hz samples of a smooth but not linear motion over `secs`.
    fn samples(secs: f64) -> impl Iterator<Item = ImuSample> {
        (0..(secs * 200.0) as i64).map(|k| {
            let t = k as f64 / 200.0;
            ImuSample {
                t_ns: 1_000_000_000 + k * 5_000_000,
                gyro_rps: Vec3::new(libm::sin(t), 0.1 * t, -0.2),
                accel_mps2: Vec3::new(libm::cos(0.5 * t), 0.0, 9.81 + 0.3 * libm::sin(2.0 * t)),
            }
        })
    }

    #[test]
    fn the_blocks_measure_what_the_samples_measure() {
        // Windows of whole blocks: the block sums give the sample measure's figures.
        let all: heapless::Vec<ImuSample, 2048> = samples(9.0).collect();
        let mut h = MotionHistory::new();
        all.iter().for_each(|s| h.push(s));
        for span_ns in [500_000_000, 1_000_000_000, 2_000_000_000] {
            let (a, g) = h.line_departure(span_ns).expect("three windows");
            let (a0, g0) = line_departure(all.iter(), span_ns).expect("three windows");
            assert!((a - a0).abs() < 1e-9 && (g - g0).abs() < 1e-9, "{span_ns}");
            assert!(a > 0.0 && g > 0.0);
        }
        // Three windows of 3 s need 9 s.
        assert!(h.line_departure(3_000_000_000).is_none());
    }

    #[test]
    fn a_line_is_not_departed_from_and_the_history_is_bounded() {
        let mut h = MotionHistory::new();
        for k in 0..4000 {
            let t = k as f64 / 200.0;
            h.push(&ImuSample {
                t_ns: k * 5_000_000,
                gyro_rps: Vec3::new(0.1 * t, 0.0, 0.0),
                accel_mps2: Vec3::new(0.0, 0.2 * t, 9.81),
            });
        }
        assert_eq!(h.blocks.len(), BLOCKS);
        let back = h.blocks.back().map(|b| b.t0_ns).unwrap_or(0);
        let front = h.blocks.front().map(|b| b.t0_ns).unwrap_or(0);
        assert_eq!(back - front, (BLOCKS as i64 - 1) * BLOCK_NS);
        let (a, g) = h.line_departure(2_000_000_000).expect("windows");
        assert!(a < 1e-9 && g < 1e-9, "{a} {g}");
        h.clear();
        assert!(h.line_departure(500_000_000).is_none());
    }
}
