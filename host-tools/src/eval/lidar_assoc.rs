//! Quality of the LiDAR-depth association against the simulator's truth (paper IV.C).
//!
//! A depth `d_r` associated to feature `id` at the keyframe with camera time `t_cam` is checked
//! against the true depth of that feature's landmark in the *true* camera at that time:
//!
//! ```text
//! t_imu  = t_cam + td_s                                  (LE-VINS clock convention)
//! (R_wb, p_wb) = ground truth interpolated at t_imu      (slerp / lerp)
//! P_b    = R_wb^T (P_w - p_wb)
//! P_c    = R_bc^T (P_b - p_bc)                           (T_bc = calibration camera in body)
//! d_true = z of P_c
//! ```
//!
//! A depth is "within" when `|d_r - d_true| <= 3 sigma_dr`. *Before* rejection counts every
//! `Associated` depth; *after* counts those not later hit by a `Rejected` event of the same
//! landmark (a `Rejected` event applies to the newest earlier association of its id; `Culled`
//! landmarks still count as kept: culling is the visual outlier test, not the depth rejection).
//! The edge shares are the fraction of checked depths whose feature is one of the simulator's
//! `edge_features` (landmarks on an occlusion edge, where the LiDAR may hit the background).

use crate::runner::{interpolate_state, GtCursor, KeyframeDepthEvents};
use povins_core::estimator::{DepthEvent, DepthEventKind};
use povins_core::inertial::NavState;
use povins_core::math::Vec3;
use povins_platform::dataset::{Dataset, Extrinsic, SimTruth};
use std::borrow::Cow;
use std::collections::BTreeMap;

/// Counts of the association check; shares via the methods.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct AssocQuality {
    /// `Associated` events in the run.
    pub associated: usize,
    /// Of those, depths with a true landmark and ground truth at the keyframe time.
    pub checked: usize,
    /// Checked depths within `3 sigma_dr` of the true depth.
    pub within_before: usize,
    /// Checked depths never rejected afterwards.
    pub kept: usize,
    /// Kept depths within `3 sigma_dr` of the true depth.
    pub within_after: usize,
    /// Checked depths of edge features.
    pub edge_before: usize,
    /// Kept depths of edge features.
    pub edge_after: usize,
}

fn share(num: usize, den: usize) -> Option<f64> {
    (den > 0).then(|| num as f64 / den as f64)
}

impl AssocQuality {
    /// Share of checked depths within `3 sigma_dr` of the truth, before rejection.
    pub fn within_3sigma_before(&self) -> Option<f64> {
        share(self.within_before, self.checked)
    }

    /// The same over the depths that survived the rejection.
    pub fn within_3sigma_after(&self) -> Option<f64> {
        share(self.within_after, self.kept)
    }

    /// Share of checked depths on edge features, before rejection.
    pub fn edge_share_before(&self) -> Option<f64> {
        share(self.edge_before, self.checked)
    }

    /// Share of kept depths on edge features.
    pub fn edge_share_after(&self) -> Option<f64> {
        share(self.edge_after, self.kept)
    }

    /// Sum of two counts (pooling runs).
    pub fn add(&self, o: &AssocQuality) -> AssocQuality {
        AssocQuality {
            associated: self.associated + o.associated,
            checked: self.checked + o.checked,
            within_before: self.within_before + o.within_before,
            kept: self.kept + o.kept,
            within_after: self.within_after + o.within_after,
            edge_before: self.edge_before + o.edge_before,
            edge_after: self.edge_after + o.edge_after,
        }
    }
}

/// True depth (z in the true camera) of the world point `p_w` at camera time `t_cam_ns`;
/// `None` outside the ground truth's time span.
pub fn true_depth_m(
    gt: &[NavState],
    t_bc: &Extrinsic,
    td_s: f64,
    t_cam_ns: i64,
    p_w: &Vec3,
) -> Option<f64> {
    let t_imu_ns = imu_time_ns(t_cam_ns, td_s);
    let (first, last) = (gt.first()?, gt.last()?);
    if t_imu_ns < first.t_ns || t_imu_ns > last.t_ns {
        return None;
    }
    Some(depth_in_camera(
        &interpolate_state(gt, t_imu_ns)?,
        t_bc,
        p_w,
    ))
}

/// The IMU time of camera time `t_cam_ns` (`t_imu = t_cam + td`).
fn imu_time_ns(t_cam_ns: i64, td_s: f64) -> i64 {
    t_cam_ns + (td_s * 1e9).round() as i64
}

/// z of the world point `p_w` in the camera of the body at `x`.
fn depth_in_camera(x: &NavState, t_bc: &Extrinsic, p_w: &Vec3) -> f64 {
    let p_b = x.q_wb.inverse_transform_vector(&(p_w - x.p_wb));
    let p_c = t_bc.q_ab.inverse_transform_vector(&(p_b - t_bc.p_ab));
    p_c.z
}

/// Checks the association of a run; `None` without simulator truth or ground truth.
pub fn assess(
    ds: &Dataset,
    steps: &[KeyframeDepthEvents],
    sigma_dr_m: f64,
) -> Option<AssocQuality> {
    let truth = ds.sim_truth.as_ref()?;
    if ds.ground_truth.is_empty() {
        return None;
    }
    Some(assess_with(
        truth,
        &ds.ground_truth,
        &ds.calib.t_bc,
        ds.calib.td_s,
        steps,
        sigma_dr_m,
    ))
}

/// [`assess`] on its parts.
pub fn assess_with(
    truth: &SimTruth,
    gt: &[NavState],
    t_bc: &Extrinsic,
    td_s: f64,
    steps: &[KeyframeDepthEvents],
    sigma_dr_m: f64,
) -> AssocQuality {
    let mut gt = GtCursor::new(gt.iter().copied().map(Ok::<_, std::convert::Infallible>));
    let mut a = Assessor::new(truth, t_bc, td_s, sigma_dr_m);
    for step in steps {
        a.step(step.t_cam_ns, &step.events, |t| gt.at(t));
    }
    a.finish()
}

/// [`assess`] one keyframe at a time, in the order of the run (for a run that does not hold
/// its events): [`Assessor::step`] per keyframe, then [`Assessor::finish`]. It reads the truth
/// in place (a copy only when its ids are not sorted).
pub struct Assessor<'t> {
    /// `truth.landmarks_w` and `truth.edge_features` sorted by id.
    landmarks: Cow<'t, [(u64, Vec3)]>,
    edges: Cow<'t, [u64]>,
    t_bc: Extrinsic,
    td_s: f64,
    sigma_dr_m: f64,
    /// One entry per checked association: (within 3 sigma, on an edge, rejected later).
    samples: Vec<(bool, bool, bool)>,
    /// Newest checked association per landmark id, as an index into `samples`.
    newest: BTreeMap<u64, usize>,
    associated: usize,
}

impl<'t> Assessor<'t> {
    /// An assessment against `truth`, with the calibration's camera extrinsic and delay.
    pub fn new(truth: &'t SimTruth, t_bc: &Extrinsic, td_s: f64, sigma_dr_m: f64) -> Self {
        // A repeated id keeps its last position, as a map built in order would.
        let mut landmarks = Cow::Borrowed(truth.landmarks_w.as_slice());
        if !landmarks.windows(2).all(|w| w[0].0 < w[1].0) {
            let v = landmarks.to_mut();
            v.reverse();
            v.sort_by_key(|l| l.0);
            v.dedup_by_key(|l| l.0);
        }
        let mut edges = Cow::Borrowed(truth.edge_features.as_slice());
        if !edges.windows(2).all(|w| w[0] < w[1]) {
            let v = edges.to_mut();
            v.sort_unstable();
            v.dedup();
        }
        Assessor {
            landmarks,
            edges,
            t_bc: *t_bc,
            td_s,
            sigma_dr_m,
            samples: Vec::new(),
            newest: BTreeMap::new(),
            associated: 0,
        }
    }

    /// The events of the keyframe at camera time `t_cam_ns`; `gt_at` gives the ground truth at
    /// an IMU time (`None` outside its span), asked with stamps that do not decrease.
    pub fn step(
        &mut self,
        t_cam_ns: i64,
        events: &[DepthEvent],
        mut gt_at: impl FnMut(i64) -> Option<NavState>,
    ) {
        // The ground truth at the keyframe, asked once (and only when a depth needs it).
        let mut x: Option<Option<NavState>> = None;
        for e in events {
            match e.kind {
                DepthEventKind::Associated => {
                    self.associated += 1;
                    let landmark = self.landmarks.binary_search_by_key(&e.id, |l| l.0).ok();
                    let d_true = landmark.and_then(|k| {
                        let p_w = &self.landmarks[k].1;
                        let x = *x.get_or_insert_with(|| gt_at(imu_time_ns(t_cam_ns, self.td_s)));
                        Some(depth_in_camera(&x?, &self.t_bc, p_w))
                    });
                    match d_true {
                        Some(d) => {
                            let within = (e.depth_m - d).abs() <= 3.0 * self.sigma_dr_m;
                            self.newest.insert(e.id, self.samples.len());
                            let edge = self.edges.binary_search(&e.id).is_ok();
                            self.samples.push((within, edge, false));
                        }
                        // A later rejection must not hit an older, checked association.
                        None => {
                            self.newest.remove(&e.id);
                        }
                    }
                }
                DepthEventKind::Rejected => {
                    if let Some(s) = self
                        .newest
                        .remove(&e.id)
                        .and_then(|k| self.samples.get_mut(k))
                    {
                        s.2 = true;
                    }
                }
                DepthEventKind::Culled => {}
            }
        }
    }

    /// The counts.
    pub fn finish(self) -> AssocQuality {
        let mut q = AssocQuality {
            associated: self.associated,
            ..AssocQuality::default()
        };
        for &(within, edge, rejected) in &self.samples {
            q.checked += 1;
            q.within_before += usize::from(within);
            q.edge_before += usize::from(edge);
            if !rejected {
                q.kept += 1;
                q.within_after += usize::from(within);
                q.edge_after += usize::from(edge);
            }
        }
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::estimator::DepthEvent;
    use povins_core::math::Quat;

    fn state(t_ns: i64, p: Vec3, yaw: f64) -> NavState {
        NavState {
            t_ns,
            p_wb: p,
            q_wb: Quat::from_euler_angles(0.0, 0.0, yaw),
            v_wb: Vec3::zeros(),
            bg: Vec3::zeros(),
            ba: Vec3::zeros(),
        }
    }

    /// Camera looking along body +x (z_c = x_b, x_c = -y_b, y_c = -z_b), 0.1 m ahead of the IMU.
    fn camera_forward() -> Extrinsic {
        let r_bc = nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        Extrinsic {
            q_ab: Quat::from_matrix(&r_bc),
            p_ab: Vec3::new(0.1, 0.0, 0.0),
        }
    }

    fn ev(id: u64, kind: DepthEventKind, depth_m: f64) -> DepthEvent {
        DepthEvent { id, kind, depth_m }
    }

    #[test]
    fn true_depth_follows_the_interpolated_pose_and_the_extrinsic() {
        // Body moves from x = 0 to x = 2 over 1 s, facing +x, then turns to face +y.
        let gt = [
            state(0, Vec3::zeros(), 0.0),
            state(1_000_000_000, Vec3::new(2.0, 0.0, 0.0), 0.0),
            state(
                2_000_000_000,
                Vec3::new(2.0, 0.0, 0.0),
                std::f64::consts::FRAC_PI_2,
            ),
        ];
        let ext = camera_forward();
        let p_w = Vec3::new(10.0, 0.5, 1.0);
        // At 0.25 s the body is at x = 0.5: depth = 10 - 0.5 - 0.1.
        let d = true_depth_m(&gt, &ext, 0.0, 250_000_000, &p_w).unwrap();
        assert!((d - 9.4).abs() < 1e-12, "{d}");
        // td shifts the pose lookup: t_imu = 0.15 + 0.1 s -> the same pose.
        let d = true_depth_m(&gt, &ext, 0.1, 150_000_000, &p_w).unwrap();
        assert!((d - 9.4).abs() < 1e-12, "{d}");
        // Facing +y at 2 s: depth is the y offset minus the lever arm.
        let p_w = Vec3::new(2.3, 7.0, 0.0);
        let d = true_depth_m(&gt, &ext, 0.0, 2_000_000_000, &p_w).unwrap();
        assert!((d - 6.9).abs() < 1e-12, "{d}");
        // Outside the ground truth.
        assert!(true_depth_m(&gt, &ext, 0.0, 2_000_000_001, &p_w).is_none());
        assert!(true_depth_m(&gt, &ext, 0.0, -1, &p_w).is_none());
    }

    #[test]
    fn shares_before_and_after_rejection() {
        let gt = [
            state(0, Vec3::zeros(), 0.0),
            state(10_000_000_000, Vec3::new(10.0, 0.0, 0.0), 0.0),
        ];
        let ext = camera_forward();
        // Landmarks 5.1 m ahead of the camera at t = 0 (x = 5.2), and one 20.1 m ahead.
        let truth = SimTruth {
            landmarks_w: vec![
                (1, Vec3::new(5.2, 0.0, 0.0)),
                (2, Vec3::new(5.2, 1.0, 0.0)),
                (3, Vec3::new(20.2, 0.0, 0.0)),
                (4, Vec3::new(5.2, -1.0, 0.0)),
            ],
            edge_features: vec![3],
            ..Default::default()
        };
        let steps = vec![
            KeyframeDepthEvents {
                t_cam_ns: 0,
                events: vec![
                    ev(1, DepthEventKind::Associated, 5.05), // within (0.05 < 0.3)
                    ev(2, DepthEventKind::Associated, 5.5),  // off by 0.4 > 0.3
                    ev(3, DepthEventKind::Associated, 6.0),  // edge: hit the foreground wall
                    ev(99, DepthEventKind::Associated, 1.0), // no true landmark: unchecked
                ],
            },
            KeyframeDepthEvents {
                // One second later the camera is 1 m closer: landmark 4 at 4.1 m.
                t_cam_ns: 1_000_000_000,
                events: vec![
                    ev(4, DepthEventKind::Associated, 4.2), // within
                    ev(2, DepthEventKind::Rejected, 5.5),
                    ev(3, DepthEventKind::Rejected, 6.0),
                    ev(1, DepthEventKind::Culled, 5.05),
                    ev(99, DepthEventKind::Rejected, 1.0),
                ],
            },
        ];
        let q = assess_with(&truth, &gt, &ext, 0.0, &steps, 0.1);
        assert_eq!(q.associated, 5);
        assert_eq!(q.checked, 4);
        assert_eq!(q.within_before, 2);
        assert_eq!(q.kept, 2);
        assert_eq!(q.within_after, 2);
        assert_eq!((q.edge_before, q.edge_after), (1, 0));
        assert_eq!(q.within_3sigma_before(), Some(0.5));
        assert_eq!(q.within_3sigma_after(), Some(1.0));
        assert_eq!(q.edge_share_before(), Some(0.25));
        assert_eq!(q.edge_share_after(), Some(0.0));
        // A larger sigma_dr accepts landmark 2's depth.
        let q = assess_with(&truth, &gt, &ext, 0.0, &steps, 0.2);
        assert_eq!(q.within_before, 3);
        // Nothing associated: no shares.
        let q = assess_with(&truth, &gt, &ext, 0.0, &[], 0.1);
        assert_eq!(q, AssocQuality::default());
        assert_eq!(q.within_3sigma_before(), None);
    }

    #[test]
    fn a_rejection_hits_only_the_newest_association_of_its_landmark() {
        let gt = [
            state(0, Vec3::zeros(), 0.0),
            state(10_000_000_000, Vec3::zeros(), 0.0),
        ];
        let ext = camera_forward();
        let truth = SimTruth {
            landmarks_w: vec![(7, Vec3::new(3.1, 0.0, 0.0))],
            ..Default::default()
        };
        let step = |t_cam_ns, events| KeyframeDepthEvents { t_cam_ns, events };
        let steps = vec![
            step(0, vec![ev(7, DepthEventKind::Associated, 3.0)]),
            // Re-associated after a re-anchoring, badly, then rejected.
            step(1, vec![ev(7, DepthEventKind::Associated, 4.0)]),
            step(2, vec![ev(7, DepthEventKind::Rejected, 4.0)]),
            // A second rejection has nothing left to hit.
            step(3, vec![ev(7, DepthEventKind::Rejected, 4.0)]),
        ];
        let q = assess_with(&truth, &gt, &ext, 0.0, &steps, 0.1);
        assert_eq!((q.checked, q.within_before), (2, 1));
        assert_eq!((q.kept, q.within_after), (1, 1));
    }
}
