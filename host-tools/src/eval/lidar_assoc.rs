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
use povins_platform::dataset::{Dataset, Extrinsic, SimLandmark, SimTruth};
use povins_platform::error::IoError;
use povins_platform::recording::Stream;
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap, VecDeque};

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
    let ids: Stream<'_, SimLandmark> = Box::new(truth.landmarks(&[]).into_iter().map(Ok));
    let mut a = Assessor::new(ids, t_bc, td_s, sigma_dr_m);
    for step in steps {
        a.step(step.t_cam_ns, &step.events, |t| gt.at(t));
    }
    // The truth is in memory: its stream cannot fail.
    a.finish().unwrap_or_default()
}

/// An id is taken from the truth's stream this long before its first observation and dropped
/// this long after its last (stamps of the same camera: a margin, not a model).
const LIVE_MARGIN_NS: i64 = 1_000_000_000;

/// A checked association waits this long for a rejection of its landmark before it is counted
/// as kept (a landmark stays in the window after its last observation until its anchor is
/// marginalized: seconds, or as long as the platform stands still).
const PENDING_NS: i64 = 120_000_000_000;

/// [`assess`] one keyframe at a time, in the order of the run (for a run that does not hold
/// its events or its truth): [`Assessor::step`] per keyframe, then [`Assessor::finish`]. It
/// reads the truth as a stream by first observation ([`Recording::sim_landmarks`]) and holds
/// only the ids alive at the keyframe and the associations still open to a rejection, so its
/// memory does not grow with the run.
///
/// [`Recording::sim_landmarks`]: povins_platform::recording::Recording::sim_landmarks
pub struct Assessor<'t> {
    truth: std::iter::Peekable<Stream<'t, SimLandmark>>,
    /// Ids taken from the stream and not yet past their last observation.
    live: BTreeMap<u64, SimLandmark>,
    /// `(last_ns, id)` of `live`, the earliest end first.
    ends: BinaryHeap<Reverse<(i64, u64)>>,
    t_bc: Extrinsic,
    td_s: f64,
    sigma_dr_m: f64,
    /// Newest checked association per landmark id, not yet counted: (within 3 sigma, on an
    /// edge, keyframe stamp).
    open: BTreeMap<u64, (bool, bool, i64)>,
    /// `(keyframe stamp, id)` of `open` in the order checked.
    opened: VecDeque<(i64, u64)>,
    q: AssocQuality,
    error: Option<IoError>,
}

impl<'t> Assessor<'t> {
    /// An assessment against the truth's ids (by increasing first observation), with the
    /// calibration's camera extrinsic and delay.
    pub fn new(
        truth: Stream<'t, SimLandmark>,
        t_bc: &Extrinsic,
        td_s: f64,
        sigma_dr_m: f64,
    ) -> Self {
        Assessor {
            truth: truth.peekable(),
            live: BTreeMap::new(),
            ends: BinaryHeap::new(),
            t_bc: *t_bc,
            td_s,
            sigma_dr_m,
            open: BTreeMap::new(),
            opened: VecDeque::new(),
            q: AssocQuality::default(),
            error: None,
        }
    }

    /// Ids into `live` up to `t_cam_ns`, out of it after their last observation.
    fn advance(&mut self, t_cam_ns: i64) {
        let admit_to = t_cam_ns.saturating_add(LIVE_MARGIN_NS);
        while self.error.is_none() {
            match self
                .truth
                .next_if(|l| l.as_ref().map_or(true, |l| l.first_ns <= admit_to))
            {
                Some(Ok(l)) => {
                    // A repeated id keeps its last position.
                    self.live.insert(l.id, l);
                    self.ends.push(Reverse((l.last_ns, l.id)));
                }
                Some(Err(e)) => self.error = Some(e),
                None => break,
            }
        }
        let drop_before = t_cam_ns.saturating_sub(LIVE_MARGIN_NS);
        while let Some(&Reverse((end, id))) = self.ends.peek() {
            if end >= drop_before {
                break;
            }
            self.ends.pop();
            if self.live.get(&id).is_some_and(|l| l.last_ns == end) {
                self.live.remove(&id);
            }
        }
        while let Some(&(t, id)) = self.opened.front() {
            if t >= t_cam_ns.saturating_sub(PENDING_NS) {
                break;
            }
            self.opened.pop_front();
            if self.open.get(&id).is_some_and(|o| o.2 == t) {
                self.close(id, false);
            }
        }
    }

    /// Counts the open association of `id`, if any.
    fn close(&mut self, id: u64, rejected: bool) {
        if let Some((within, edge, _)) = self.open.remove(&id) {
            let q = &mut self.q;
            q.checked += 1;
            q.within_before += usize::from(within);
            q.edge_before += usize::from(edge);
            if !rejected {
                q.kept += 1;
                q.within_after += usize::from(within);
                q.edge_after += usize::from(edge);
            }
        }
    }

    /// The events of the keyframe at camera time `t_cam_ns` (not decreasing from step to step);
    /// `gt_at` gives the ground truth at an IMU time (`None` outside its span), asked with
    /// stamps that do not decrease.
    pub fn step(
        &mut self,
        t_cam_ns: i64,
        events: &[DepthEvent],
        mut gt_at: impl FnMut(i64) -> Option<NavState>,
    ) {
        self.advance(t_cam_ns);
        // The ground truth at the keyframe, asked once (and only when a depth needs it).
        let mut x: Option<Option<NavState>> = None;
        for e in events {
            match e.kind {
                DepthEventKind::Associated => {
                    self.q.associated += 1;
                    let landmark = self.live.get(&e.id).and_then(|l| Some((l.p_w?, l.edge)));
                    let truth = landmark.and_then(|(p_w, edge)| {
                        let x = *x.get_or_insert_with(|| gt_at(imu_time_ns(t_cam_ns, self.td_s)));
                        Some((depth_in_camera(&x?, &self.t_bc, &p_w), edge))
                    });
                    // A later rejection hits only the newest checked association of the id.
                    self.close(e.id, false);
                    if let Some((d, edge)) = truth {
                        let within = (e.depth_m - d).abs() <= 3.0 * self.sigma_dr_m;
                        self.open.insert(e.id, (within, edge, t_cam_ns));
                        self.opened.push_back((t_cam_ns, e.id));
                    }
                }
                DepthEventKind::Rejected => self.close(e.id, true),
                DepthEventKind::Culled => {}
            }
        }
    }

    /// The counts; an error when the truth's stream failed (the counts would be partial).
    pub fn finish(mut self) -> Result<AssocQuality, IoError> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        let ids: Vec<u64> = self.open.keys().copied().collect();
        for id in ids {
            self.close(id, false);
        }
        Ok(self.q)
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

    #[test]
    fn the_streamed_truth_holds_only_the_live_tracks_and_counts_the_same() {
        // A camera still at the origin looking along +x; 2000 tracks, one starting every 0.1 s,
        // each seen for 2 s, at 4.1 m + 1 mm per id; every keyframe (10 Hz over 200 s)
        // associates the tracks it sees, every tenth 1 m off, and rejects some of them later.
        let gt = [
            state(0, Vec3::zeros(), 0.0),
            state(300_000_000_000, Vec3::zeros(), 0.0),
        ];
        let ext = camera_forward();
        let s = 1_000_000_000i64;
        let n = 2000u64;
        let lm = |id: u64| SimLandmark {
            id,
            p_w: Some(Vec3::new(4.1 + 0.001 * id as f64, 0.0, 0.0)),
            first_ns: (id as i64) * s / 10,
            last_ns: (id as i64) * s / 10 + 2 * s,
            wrong: false,
            edge: id.is_multiple_of(7),
        };
        let steps: Vec<KeyframeDepthEvents> = (0..2000i64)
            .map(|k| {
                let t = k * s / 10;
                let mut events = Vec::new();
                for id in (0..n).filter(|&id| lm(id).first_ns <= t && t <= lm(id).last_ns) {
                    let d = 4.0
                        + 0.001 * id as f64
                        + if (id + k as u64).is_multiple_of(10) {
                            1.0
                        } else {
                            0.0
                        };
                    events.push(ev(id, DepthEventKind::Associated, d));
                }
                if let Some(id) = (k as u64).checked_sub(5).filter(|id| id.is_multiple_of(3)) {
                    events.push(ev(id, DepthEventKind::Rejected, 0.0));
                }
                KeyframeDepthEvents {
                    t_cam_ns: t,
                    events,
                }
            })
            .collect();
        // Counts, and the most ids held at once; the open associations are checked to be no
        // older than PENDING_NS at every keyframe.
        let run = |ids: Vec<SimLandmark>| {
            let mut cursor =
                GtCursor::new(gt.iter().copied().map(Ok::<_, std::convert::Infallible>));
            let mut a = Assessor::new(Box::new(ids.into_iter().map(Ok)), &ext, 0.0, 0.1);
            let mut most = 0;
            for (k, st) in steps.iter().enumerate() {
                a.step(st.t_cam_ns, &st.events, |t| cursor.at(t));
                most = most.max(a.live.len());
                let recent: usize = steps[..=k]
                    .iter()
                    .filter(|o| o.t_cam_ns >= st.t_cam_ns - PENDING_NS)
                    .map(|o| o.events.len())
                    .sum();
                assert!(a.opened.len() <= recent, "{} open at {k}", a.opened.len());
            }
            (a.finish().unwrap(), most)
        };
        let (streamed, most) = run((0..n).map(lm).collect());
        // The same ids held the whole run (the in-memory truth's form).
        let held = (0..n)
            .map(|id| SimLandmark {
                first_ns: i64::MIN,
                last_ns: i64::MAX,
                ..lm(id)
            })
            .collect();
        let (whole, all) = run(held);
        assert_eq!(streamed, whole);
        assert_eq!(all, n as usize);
        // Tracks live 2 s, one starts every 0.1 s: about 20 (+ the 1 s margins: 40) at a time.
        assert!(most <= 45, "{most} ids held");
        assert!(
            streamed.checked > 30_000 && streamed.kept < streamed.checked,
            "{streamed:?}"
        );
        assert!(streamed.within_before < streamed.checked && streamed.edge_before > 0);
    }

    #[test]
    fn a_failed_truth_stream_is_an_error_not_partial_counts() {
        let ext = camera_forward();
        let ids: Stream<'_, SimLandmark> = Box::new(
            [Err(IoError::Invalid {
                path: "x.mcap".into(),
                msg: "broken".into(),
            })]
            .into_iter(),
        );
        let mut a = Assessor::new(ids, &ext, 0.0, 0.1);
        a.step(0, &[ev(1, DepthEventKind::Associated, 1.0)], |_| None);
        let e = a.finish().expect_err("the stream failed");
        assert!(e.to_string().contains("broken"), "{e}");
    }
}
