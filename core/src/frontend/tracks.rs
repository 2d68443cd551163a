//! Per-frame track processing: validation, undistortion and feature velocities.
//!
//! Velocities are finite differences on the normalized plane (1/s) between the two frames *before*
//! the current one; the time-delay correction `x' = x - (td - td0) v` needs them. The current
//! observation is left out on purpose: a velocity `(x_k - x_{k-1}) / dt` carries the current
//! observation's noise, so the gradient of the reprojection error with respect to the delay,
//! `-v . r`, has the nonzero mean `2 sigma^2 / dt` per observation and biases the delay estimate
//! towards the future (by `2 sigma^2 / (dt |v|^2 + 4 sigma^2 / dt)`: about 20 ms for a slowly
//! moving camera at 20 Hz with 1 px noise, measured). The lag of half a frame this costs only
//! matters in proportion to the change of the delay estimate. A track seen in fewer than two
//! earlier frames, or after a time jump, gets zero velocity.

use crate::camera::{FeatureObs, PinholeCamera};
use crate::Error;
use heapless::Vec;

/// A validated observation on the normalized image plane (`z = 1`) of the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NormalizedObs {
    /// Track id.
    pub id: u64,
    /// Undistorted normalized coordinates `(x/z, y/z)`.
    pub x_n: [f64; 2],
    /// Velocity of `x_n`, 1/s (zero for a new track).
    pub vel: [f64; 2],
}

/// What happened to the observations of one frame (rejections are counted, never silent).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameStats {
    /// Observations offered.
    pub received: u32,
    /// Observations kept.
    pub accepted: u32,
    /// NaN or infinite pixel coordinates.
    pub rejected_nonfinite: u32,
    /// Outside the image (with a one-pixel margin).
    pub rejected_out_of_image: u32,
    /// Repeated id within the frame (the first occurrence is kept).
    pub rejected_duplicate: u32,
    /// Undistortion failed to converge.
    pub rejected_undistort: u32,
    /// More observations than the frame capacity.
    pub rejected_capacity: u32,
}

/// Remembers the two previous frames' observations to give velocities to the next one.
#[derive(Clone)]
pub struct TrackTable<const F: usize> {
    prev: Vec<NormalizedObs, F>,
    prev_t_ns: Option<i64>,
    prev2: Vec<NormalizedObs, F>,
    prev2_t_ns: Option<i64>,
    max_gap_ns: i64,
}

impl<const F: usize> TrackTable<F> {
    /// A table that treats frames further apart than `max_gap_s` as a restart of all tracks.
    pub const fn new(max_gap_s: f64) -> Self {
        TrackTable {
            prev: Vec::new(),
            prev_t_ns: None,
            prev2: Vec::new(),
            prev2_t_ns: None,
            max_gap_ns: (max_gap_s * 1e9) as i64,
        }
    }

    /// Forgets all tracks (e.g. after a reset of the estimator).
    pub fn clear(&mut self) {
        self.prev.clear();
        self.prev_t_ns = None;
        self.prev2.clear();
        self.prev2_t_ns = None;
    }

    /// Back to the state [`TrackTable::new`] builds with `max_gap_s`, in place.
    pub fn reset_to_new(&mut self, max_gap_s: f64) {
        self.clear();
        self.max_gap_ns = (max_gap_s * 1e9) as i64;
    }

    /// Validates and undistorts a frame into `out` (sorted by id). Returns
    /// [`Error::TimeNotIncreasing`] (and changes nothing) if the frame is not newer than the last.
    pub fn process(
        &mut self,
        t_ns: i64,
        obs: &[FeatureObs],
        camera: &PinholeCamera,
        out: &mut Vec<NormalizedObs, F>,
    ) -> Result<FrameStats, Error> {
        if let Some(p) = self.prev_t_ns {
            if t_ns <= p {
                return Err(Error::TimeNotIncreasing);
            }
        }
        out.clear();
        let mut st = FrameStats {
            received: obs.len().min(u32::MAX as usize) as u32,
            ..Default::default()
        };
        let (w, h) = (camera.width as f64, camera.height as f64);
        for o in obs {
            if !(o.u_px.is_finite() && o.v_px.is_finite()) {
                st.rejected_nonfinite += 1;
                continue;
            }
            if o.u_px < -1.0 || o.v_px < -1.0 || o.u_px > w || o.v_px > h {
                st.rejected_out_of_image += 1;
                continue;
            }
            let x = match camera.undistort(o.u_px, o.v_px) {
                Ok(x) => x,
                Err(_) => {
                    st.rejected_undistort += 1;
                    continue;
                }
            };
            let n = NormalizedObs {
                id: o.id,
                x_n: [x.x, x.y],
                vel: [0.0; 2],
            };
            if out.push(n).is_err() {
                st.rejected_capacity += 1;
            }
        }
        // Stable sort keeps the first occurrence of a repeated id first, so dedup is deterministic.
        sort_by_id(out);
        let mut k = 0;
        for i in 0..out.len() {
            if k > 0 && out[k - 1].id == out[i].id {
                st.rejected_duplicate += 1;
                continue;
            }
            out[k] = out[i];
            k += 1;
        }
        out.truncate(k);

        // Velocities from the two previous frames, when both are recent enough.
        let recent =
            |a: Option<i64>, b: i64| a.is_some_and(|a| b.saturating_sub(a) <= self.max_gap_ns);
        if let (true, true, Some(t1), Some(t2)) = (
            recent(self.prev_t_ns, t_ns),
            self.prev_t_ns.is_some_and(|t1| recent(self.prev2_t_ns, t1)),
            self.prev_t_ns,
            self.prev2_t_ns,
        ) {
            let dt_s = t1.saturating_sub(t2) as f64 * 1e-9;
            for o in out.iter_mut() {
                let (Ok(i1), Ok(i2)) = (
                    self.prev.binary_search_by(|p| p.id.cmp(&o.id)),
                    self.prev2.binary_search_by(|p| p.id.cmp(&o.id)),
                ) else {
                    continue;
                };
                if let (Some(p1), Some(p2)) = (self.prev.get(i1), self.prev2.get(i2)) {
                    o.vel = [
                        (p1.x_n[0] - p2.x_n[0]) / dt_s,
                        (p1.x_n[1] - p2.x_n[1]) / dt_s,
                    ];
                }
            }
        }
        core::mem::swap(&mut self.prev, &mut self.prev2);
        self.prev2_t_ns = self.prev_t_ns;
        self.prev.clear();
        for o in out.iter() {
            // Same capacity: cannot fail, and a failure would only drop a velocity.
            let _ = self.prev.push(*o);
        }
        self.prev_t_ns = Some(t_ns);
        st.accepted = out.len() as u32;
        Ok(st)
    }
}

/// Insertion sort by id: stable, allocation-free, and fast for the nearly sorted frames a
/// tracker produces.
fn sort_by_id(v: &mut [NormalizedObs]) {
    for i in 1..v.len() {
        let x = v[i];
        let mut j = i;
        while j > 0 && v[j - 1].id > x.id {
            v[j] = v[j - 1];
            j -= 1;
        }
        v[j] = x;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;

    fn cam() -> PinholeCamera {
        PinholeCamera {
            width: 640,
            height: 480,
            fx: 400.0,
            fy: 400.0,
            cx: 320.0,
            cy: 240.0,
            distortion: Distortion::None,
        }
    }

    fn o(id: u64, u: f64, v: f64) -> FeatureObs {
        FeatureObs {
            id,
            u_px: u,
            v_px: v,
        }
    }

    #[test]
    fn bad_observations_are_counted_and_velocities_follow_tracks() {
        let mut t: TrackTable<8> = TrackTable::new(0.5);
        let mut out = Vec::new();
        let s = t
            .process(
                0,
                &[
                    o(5, 320.0, 240.0),
                    o(2, f64::NAN, 1.0),
                    o(3, 1e6, 1.0),
                    o(5, 1.0, 1.0),
                    o(1, 360.0, 240.0),
                ],
                &cam(),
                &mut out,
            )
            .unwrap();
        assert_eq!((s.received, s.accepted), (5, 2));
        assert_eq!(
            (
                s.rejected_nonfinite,
                s.rejected_out_of_image,
                s.rejected_duplicate
            ),
            (1, 1, 1)
        );
        assert_eq!(
            out.iter().map(|x| x.id).collect::<Vec<u64, 8>>().as_slice(),
            &[1, 5]
        );
        // The first occurrence of the repeated id 5 was kept.
        assert_eq!(out[1].x_n, [0.0, 0.0]);
        assert_eq!(out[1].vel, [0.0, 0.0]);

        let s = t
            .process(
                100_000_000,
                &[o(5, 360.0, 240.0), o(9, 1.0, 1.0)],
                &cam(),
                &mut out,
            )
            .unwrap();
        assert_eq!(s.accepted, 2);
        // Only one earlier frame: no velocity yet (the current observation is never used).
        assert_eq!(out[0].vel, [0.0, 0.0]);
        assert_eq!(out[1].vel, [0.0, 0.0]);
        // Third frame: the velocity of the two earlier ones, 40 px in 0.1 s at f = 400 px, 1 /s
        // on the normalized plane, whatever the current observation says.
        t.process(150_000_000, &[o(5, 600.0, 300.0)], &cam(), &mut out)
            .unwrap();
        assert!((out[0].vel[0] - 1.0).abs() < 1e-12 && out[0].vel[1] == 0.0);

        assert_eq!(
            t.process(150_000_000, &[], &cam(), &mut out),
            Err(Error::TimeNotIncreasing)
        );
        // After a gap longer than 0.5 s, tracks restart with zero velocity.
        t.process(2_000_000_000, &[o(5, 400.0, 240.0)], &cam(), &mut out)
            .unwrap();
        assert_eq!(out[0].vel, [0.0, 0.0]);
        // Capacity: 8 slots, 10 valid observations.
        let many: Vec<FeatureObs, 10> = (0..10).map(|i| o(i, 10.0 + i as f64, 10.0)).collect();
        let s = t.process(2_050_000_000, &many, &cam(), &mut out).unwrap();
        assert_eq!((s.accepted, s.rejected_capacity), (8, 2));
    }
}
