//! The keyframe step (steps 1-6 of the module docs of [`super`]): marginalization of the
//! oldest keyframe when the window is full, the new keyframe with its closed preintegration and
//! observations, depth association and slot selection, the solve ([`super::solve`]), the health
//! check, and the restart of the INS from the newest optimized keyframe. Also the diagonal
//! priors a new window starts with.

use super::problem::InitialPriors;
use super::{now, Estimator, KeyframeReport};
use crate::frontend::KeyframeDecision;
use crate::inertial::covariance::MaybeCovariance;
use crate::inertial::{ImuSample, NavState};
use crate::Error;

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    /// The keyframe step (steps 1-6 of the module docs of [`super`]) for the frame in
    /// `self.frame_obs` at camera time `t_cam_ns`, with the INS state `nav` at its `sample`.
    // Never inlined: `scripts/keyframe_instructions.sh` counts instructions per keyframe step
    // from its entries.
    #[inline(never)]
    pub(super) fn add_keyframe(
        &mut self,
        t_cam_ns: i64,
        nav: NavState,
        sample: &ImuSample,
        decision: KeyframeDecision,
        t0: u64,
    ) -> Result<KeyframeReport, Error> {
        let mut report = KeyframeReport {
            t_ns: nav.t_ns,
            t_cam_ns,
            decision,
            lidar_points_cropped_total: self.counters.lidar_points_outside_view,
            lidar_points_lost_total: self.counters.lidar_points_evicted_in_span,
            lidar_points_thinned_total: self.counters.lidar_points_thinned,
            ..Default::default()
        };
        self.events.clear();
        // 1. Marginalize the oldest keyframe at the last optimized state.
        self.marginalize_for_keyframe(&mut report);

        // 2. Append the keyframe with the interval's preintegration, start the next interval.
        let sample = self.append_keyframe(t_cam_ns, &nav, sample, &mut report)?;

        // 3-5. Optimize and cull.
        let ts = now(self.clock);
        let before = self.window.poses();
        if self.window.len() >= 2 {
            self.optimize(&mut report);
        }
        report.solve_ns = now(self.clock).saturating_sub(ts);
        let (correction, window_path_m) = self.window_correction(&before);
        report.window_correction_m = correction;
        if self.window.len() >= 2 {
            let health = self.check_health(&nav, &report, window_path_m);
            if let Some(b) = health {
                // The window broke down: INS-only from its own prediction, a new window next.
                report.breakdown = Some(b);
                self.reinitialize_from(nav);
                report.total_ns = now(self.clock).saturating_sub(t0);
                return Ok(report);
            }
        }

        // 6. The INS continues from the newest optimized keyframe, with its covariance when
        // asked for; the open interval is re-linearized at its biases (it holds only the
        // keyframe sample so far).
        let (cov, ext_sd) = self.newest_covariance();
        self.kf_cov = MaybeCovariance::new(cov);
        report.extrinsic_sd = ext_sd;
        self.restart_ins(&nav, &sample)?;
        report.window_len = self.window.len() as u32;
        report.td_s = self.current_td();
        report.extrinsic = Some(self.ext);
        report.imu_noise_scale = self.imu_scale.density_scale();
        report.landmarks_total = self.lms.len() as u32;
        report.total_ns = now(self.clock).saturating_sub(t0);
        Ok(report)
    }

    /// Step 1: marginalizes the oldest keyframe at the last optimized state when the window is
    /// full (on failure: the prior dropped and the keyframe shifted out, counted), with its time
    /// and rank deficiencies in `report`.
    fn marginalize_for_keyframe(&mut self, report: &mut KeyframeReport) {
        if self.window.is_full() {
            let tm = now(self.clock);
            self.last_marg = None;
            if self.marginalize_oldest().is_err() {
                self.counters.marginalization_failures += 1;
                self.prior.clear();
                self.initial = None;
                let _ = self.window.drop_oldest();
                self.lms.shift_out_oldest();
            }
            report.marginalization_ns = now(self.clock).saturating_sub(tm);
            if let Some((m, p)) = self.last_marg {
                report.marginalized_rank_deficiency = m;
                report.prior_rank_deficiency = p;
                if let Some((pos, yaw)) = self.prior.gauge_std() {
                    report.prior_gauge_std = (pos[0].max(pos[1]).max(pos[2]), yaw);
                }
            }
        }
    }

    /// Step 2: appends the keyframe (state `nav`, camera time `t_cam_ns`) with the interval's
    /// preintegration and starts the next interval at `sample` taken at the keyframe time
    /// (returned); adds the frame's observations to the landmarks, associates LiDAR depths and
    /// selects the landmarks that hold the slots.
    fn append_keyframe(
        &mut self,
        t_cam_ns: i64,
        nav: &NavState,
        sample: &ImuSample,
        report: &mut KeyframeReport,
    ) -> Result<ImuSample, Error> {
        let td = self.current_td();
        // The sample at the keyframe time starts the next interval.
        let sample = ImuSample {
            t_ns: nav.t_ns,
            ..*sample
        };
        let at_rest = self.cfg.zupt.enabled
            && self.at_rest_since_last_keyframe()
            && nav.v_wb.norm() <= self.cfg.zupt.max_speed_mps;
        report.at_rest = at_rest;
        // The interval closes: swapped into the keyframe's slot (which hands back storage for
        // the next one).
        let interval = if core::mem::take(&mut self.open_active) {
            // A closed interval is evaluated at every LM step: factor its covariance once.
            let _ = self.open.cache_whitening();
            Some(&mut self.open)
        } else {
            None
        };
        self.window.push(t_cam_ns, *nav, td, at_rest, interval)?;
        if self.window.len() == 1 {
            self.prior.clear();
            self.initial = Some(self.initial_priors(nav, td));
            self.reinit = None;
            self.motion_started = false;
        }
        self.open.restart_with(
            self.imu_scale.apply(self.cfg.imu_noise),
            self.cfg.preint,
            &sample,
            nav.bg,
            nav.ba,
        )?;
        if let Some(gap) = self.gap.filter(|g| g.t1_ns > sample.t_ns) {
            // A keyframe inside a bridged gap: the next interval starts in it too.
            self.open.add_unmeasured(gap)?;
        }
        self.open_active = true;
        let pos = self.window.len() - 1;
        // The observations were taken at `t_cam + td_true`; the keyframe's state is at its sample
        // time, so the delay they are referred to is that time minus the camera time (equal to
        // `td` unless the frame was processed late).
        let td0 = nav.t_ns.saturating_sub(t_cam_ns) as f64 * 1e-9;
        self.lms.add_keyframe(pos, &self.frame_obs, td0)?;
        let (mv_tracks, mv_obs) = self.lms.store().multi_view();
        report.multi_view_tracks = mv_tracks;
        report.multi_view_observations = mv_obs;
        self.counters.keyframes += 1;
        self.associate_depths(pos, nav, report);
        let (promoted, evicted) = self.select_landmarks();
        report.landmarks_promoted = promoted;
        report.landmarks_evicted = evicted;
        Ok(sample)
    }

    /// Step 6: the INS continues from the newest optimized keyframe (the de-skew window corrected
    /// from the INS prediction `nav`); the open interval is re-linearized at its biases (it
    /// holds only the keyframe sample `sample` so far).
    fn restart_ins(&mut self, nav: &NavState, sample: &ImuSample) -> Result<(), Error> {
        if let Some(last) = self.window.last() {
            let st = last.state;
            self.correct_ins_window(nav, &st);
            if let Some(ins) = self.ins.as_mut() {
                ins.set_state(st)?;
                ins.set_covariance(self.kf_cov.get().copied());
            }
            if let Some(open) = self.open_mut() {
                open.reset(sample, st.bg, st.ba)?;
            }
        }
        Ok(())
    }

    fn initial_priors(&self, kf0: &NavState, td: f64) -> InitialPriors {
        let p = match self.reinit {
            Some(_) => &self.cfg.health.reinit_prior,
            None if self.motion_started => &self.cfg.init.motion_prior,
            None => &self.cfg.first_prior,
        };
        let mut kf0_sigma = [p.p_m, p.theta_rad, p.v_mps, p.bg_rps, p.ba_mps2];
        // After a camera dropout the INS carries the healthy window's covariance over it
        // (`imu_step`): attitude, velocity and biases start from that (each block's largest
        // standard deviation); the position stays the new window's anchor.
        let dropout = self
            .reinit
            .and(self.ins.as_ref().and_then(|i| i.covariance()));
        if let Some(c) = dropout {
            let cov = c.state_order();
            for (block, sigma) in kf0_sigma.iter_mut().enumerate().skip(1) {
                let var = (0..3)
                    .filter_map(|i| cov.get((3 * block + i, 3 * block + i)).copied())
                    .fold(0.0, f64::max);
                let sd = libm::sqrt(var);
                if sd.is_finite() && sd > 0.0 {
                    *sigma = sd;
                }
            }
        }
        // An in-motion start given the biases (`[init.biases]`): as well as they are known.
        if let Some(b) = self
            .cfg
            .init
            .biases
            .filter(|_| self.motion_started && self.reinit.is_none())
        {
            kf0_sigma[3] = b.gyro_sd_rps;
            kf0_sigma[4] = b.accel_sd_mps2;
        }
        InitialPriors {
            kf0: *kf0,
            kf0_sigma,
            td0: (td, self.cfg.td.prior_s),
            // The configured extrinsic, or the broken window's estimate after a
            // re-initialization (`Reinit`).
            ext: (
                self.ext,
                self.cfg.extrinsic_prior.0,
                self.cfg.extrinsic_prior.1,
            ),
        }
    }
}
