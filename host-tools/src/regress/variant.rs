//! The variant sequences of the suite (`povins regress --variants ...`): how each differs from the
//! standard sequence (8 ms delay not told, started from the true state, the exact extrinsic), and
//! the figures only they report (the in-motion start's delay and coverage, the extrinsic's error).
//!
//! - [`Variant::MotionStart`]: the sequence without its first [`sim::motion_start_s`] seconds (the
//!   scenario's rest plus its ramp to full motion, as `povins simulate --start-s motion` and
//!   `scripts/motion_start.sh`), started by `--init auto`'s path (the in-motion initializer when
//!   no rest is seen), not from the true state.
//! - [`Variant::Extrinsic`]: the configured camera-IMU extrinsic `T_bc` started
//!   [`EXTRINSIC_PERTURBATION_M`] and [`EXTRINSIC_PERTURBATION_DEG`] off, in fixed directions of
//!   the body frame (those of `scripts/extrinsic_conv.sh`: the same for every scenario and seed),
//!   with `estimate_extrinsic = true`; judged on the ATE and the extrinsic's error at the end.
//! - [`Variant::Fault`]: a sensor fault at half the sequence ([`super::faults`]), on the real
//!   sequences too ([`Variant::on_real_data`]); reports the
//!   coverage.

use super::{Fault, RunResult};
use crate::report::{coverage, spans_of};
use crate::runner::{InitMode, RunOutput};
use crate::sim::{self, Scenario, SimConfig};
use povins_core::camera::CameraExtrinsic;
use povins_core::estimator::EstimatorConfig;
use povins_core::math::{Quat, Vec3};
use povins_platform::trajectory::StampedPose;
use serde::Serialize;
use std::collections::BTreeMap;

/// How a simulated sequence of the suite differs from the standard one (8 ms delay not told,
/// started from the true state, exact extrinsic). Each variant is its own group in the tables
/// (`flight/delay-30ms`), with its own stored figures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Variant {
    /// The standard sequence.
    Standard,
    /// A true delay of this many ms, not told (a blind start at 0).
    Delay(i32),
    /// The standard delay, stepping by +10 ms at half the sequence.
    DelayStep,
    /// Started in motion: the scenario's rest and ramp cut away, `--init auto`.
    MotionStart,
    /// The extrinsic started 2 cm and 2 degrees off and estimated.
    Extrinsic,
    /// A sensor fault at half the sequence.
    Fault(Fault),
}

/// The variant groups `povins regress --variants` can add.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum VariantGroup {
    /// Blind starts with true delays of -30, -10 and +30 ms (+8 is the standard sequence).
    Delays,
    /// The delay steps by +10 ms at half the sequence.
    DelayStep,
    /// Started in motion (the scenario's rest and ramp cut away) by the automatic initializer.
    MotionStart,
    /// The camera-IMU extrinsic started 2 cm and 2 degrees off, estimated online.
    Extrinsic,
    /// Sensor faults at half the sequence (simulated and real): a 0.2 s IMU gap, spikes and a
    /// burst, a 3 s camera dropout, a +1 h clock jump, and a 2 s IMU gap on the robot, the
    /// vehicle and the flight.
    Faults,
}

impl VariantGroup {
    /// The variants of the group.
    pub fn variants(self) -> &'static [Variant] {
        match self {
            VariantGroup::Delays => &[Variant::Delay(-30), Variant::Delay(-10), Variant::Delay(30)],
            VariantGroup::DelayStep => &[Variant::DelayStep],
            VariantGroup::MotionStart => &[Variant::MotionStart],
            VariantGroup::Extrinsic => &[Variant::Extrinsic],
            VariantGroup::Faults => &[
                Variant::Fault(Fault::ImuGap),
                Variant::Fault(Fault::ImuGapLong),
                Variant::Fault(Fault::Spikes),
                Variant::Fault(Fault::CameraDropout),
                Variant::Fault(Fault::ClockJump),
            ],
        }
    }
}

impl Variant {
    /// Suffix of the names (empty for the standard sequence); the group is the scenario and the
    /// suffix without its dash (`flight/motion`).
    pub fn suffix(self) -> String {
        match self {
            Variant::Standard => String::new(),
            Variant::Delay(ms) => format!("-delay{ms:+}ms"),
            Variant::DelayStep => "-delaystep+10ms".into(),
            Variant::MotionStart => "-motion".into(),
            Variant::Extrinsic => "-extrinsic".into(),
            Variant::Fault(f) => f.suffix().into(),
        }
    }

    /// Whether the variant is also run on the suite's real sequences: the sensor faults (the
    /// others are made by the simulator).
    pub fn on_real_data(self) -> bool {
        self.applies_to(None)
    }

    /// Whether the variant is run on `scenario` (`None`: the real sequences): every simulated
    /// scenario but for the faults that say otherwise ([`Fault::applies_to`]).
    pub fn applies_to(self, scenario: Option<Scenario>) -> bool {
        match self {
            Variant::Standard => true,
            Variant::Fault(f) => f.applies_to(scenario),
            _ => scenario.is_some(),
        }
    }

    /// Full resets the variant is meant to cause on `scenario` ([`Fault::resets_expected`]).
    pub fn resets_expected(self, scenario: Option<Scenario>) -> u64 {
        match self {
            Variant::Fault(f) => f.resets_expected(scenario),
            _ => 0,
        }
    }

    /// How the estimator starts: the in-motion start through the automatic choice, the others
    /// from the true state (as the peers are run).
    pub fn init(self) -> InitMode {
        match self {
            Variant::MotionStart => InitMode::Auto,
            _ => InitMode::Groundtruth,
        }
    }

    /// Lays the variant's estimator settings over `cfg` (after the defaults and any overlay).
    pub fn configure(self, cfg: &mut EstimatorConfig) {
        if self == Variant::Extrinsic {
            cfg.extrinsic = perturbed_extrinsic(&cfg.extrinsic);
            cfg.estimate_extrinsic = true;
        }
    }
}

/// The simulator settings of a suite sequence (also what `povins simulate` needs to write the
/// same files for the peer: `--td-ms 8 --wrong-track-rate 0.03 --lidar none`, and the
/// variant's `--td-ms MS`, `--td-step-ms 10 --td-step-at-s DURATION/2` or `--start-s motion`).
pub fn sim_config(scenario: Scenario, seed: u64, duration_s: f64, variant: Variant) -> SimConfig {
    let mut c = SimConfig::new(scenario, seed, duration_s);
    c.td_s = 0.008;
    c.wrong_track_rate = Some(0.03);
    c.lidar = Some(sim::LidarKind::None);
    c.threads = 1;
    match variant {
        Variant::Standard | Variant::Extrinsic | Variant::Fault(_) => {}
        Variant::Delay(ms) => c.td_s = f64::from(ms) * 1e-3,
        Variant::DelayStep => {
            c.td_step = Some(sim::TdStep {
                step_s: 0.010,
                at_s: 0.5 * duration_s,
            })
        }
        Variant::MotionStart => c.start_s = sim::motion_start_s(scenario, c.static_s),
    }
    c
}

/// Translation of [`Variant::Extrinsic`]'s start from the configured extrinsic, m.
pub const EXTRINSIC_PERTURBATION_M: f64 = 0.02;
/// Rotation of [`Variant::Extrinsic`]'s start from the configured extrinsic, deg.
pub const EXTRINSIC_PERTURBATION_DEG: f64 = 2.0;

/// `ext` moved by [`EXTRINSIC_PERTURBATION_M`] along `(1, -1, 1)/sqrt(3)` and rotated by
/// [`EXTRINSIC_PERTURBATION_DEG`] about `(1, 2, -1)/sqrt(6)`, both in the body frame
/// (`q_bc <- exp(delta) q_bc`), as `scripts/extrinsic_conv.sh`'s `perturbed_est`.
pub fn perturbed_extrinsic(ext: &CameraExtrinsic) -> CameraExtrinsic {
    let dir_p_b = Vec3::new(1.0, -1.0, 1.0).normalize();
    let axis_b = Vec3::new(1.0, 2.0, -1.0).normalize();
    let dq_b = Quat::from_scaled_axis(axis_b * EXTRINSIC_PERTURBATION_DEG.to_radians());
    CameraExtrinsic {
        p_bc: ext.p_bc + dir_p_b * EXTRINSIC_PERTURBATION_M,
        q_bc: dq_b * ext.q_bc,
    }
}

/// Error of `est` against `truth`: translation, cm, and rotation angle of
/// `q_bc_est * q_bc_true^-1`, deg.
pub fn extrinsic_error(est: &CameraExtrinsic, truth: &CameraExtrinsic) -> (f64, f64) {
    (
        100.0 * (est.p_bc - truth.p_bc).norm(),
        (est.q_bc * truth.q_bc.inverse()).angle().to_degrees(),
    )
}

/// What a run of the in-motion or extrinsic variant reports beyond [`RunResult`]'s figures.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct VariantFigures {
    /// The estimator gave an estimate (a run that never did is also `diverged`, its ATE
    /// infinite).
    pub started: bool,
    /// Time from the first camera frame to the first IMU-rate estimate, s (as `summary.json`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub start_after_camera_s: Option<f64>,
    /// Share of the ground-truth stamps from the first camera frame on with a pose within 10 ms
    /// ([`crate::report::coverage`], `summary.json`'s `coverage`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_coverage: Option<f64>,
    /// Extrinsic translation error at the end (the last keyframe that reported one), cm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extrinsic_err_end_cm: Option<f64>,
    /// Extrinsic rotation error at the end, deg.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extrinsic_err_end_deg: Option<f64>,
}

/// [`coverage`] of an estimate in memory.
fn covers(gt: &[StampedPose], est: &[StampedPose], from_ns: i64) -> Option<f64> {
    let stamps = gt.iter().map(|p| Ok::<_, std::convert::Infallible>(p.t_ns));
    match coverage(stamps, &spans_of(est), from_ns) {
        Ok(c) => c,
        Err(never) => match never {},
    }
}

impl Variant {
    /// The variant's own figures of a run (`None` for the variants without any): `out`'s start,
    /// its coverage of `gt` after the first camera frame, and its last extrinsic against
    /// `true_extrinsic`.
    pub fn figures(
        self,
        out: &RunOutput,
        gt: &[StampedPose],
        est: &[StampedPose],
        true_extrinsic: &CameraExtrinsic,
    ) -> Option<VariantFigures> {
        let started = !est.is_empty();
        match self {
            Variant::MotionStart => Some(VariantFigures {
                started,
                start_after_camera_s: out
                    .first_camera_ns
                    .zip(out.first_estimate_ns)
                    .map(|(c, e)| (e - c) as f64 * 1e-9),
                camera_coverage: out.first_camera_ns.and_then(|t0| covers(gt, est, t0)),
                ..Default::default()
            }),
            Variant::Extrinsic => {
                let err = out
                    .reports
                    .iter()
                    .rev()
                    .find_map(|r| r.extrinsic)
                    .map(|e| extrinsic_error(&e, true_extrinsic));
                Some(VariantFigures {
                    started,
                    extrinsic_err_end_cm: err.map(|e| e.0),
                    extrinsic_err_end_deg: err.map(|e| e.1),
                    ..Default::default()
                })
            }
            Variant::Fault(_) => Some(VariantFigures {
                started,
                camera_coverage: out.first_camera_ns.and_then(|t0| covers(gt, est, t0)),
                ..Default::default()
            }),
            Variant::Standard | Variant::Delay(_) | Variant::DelayStep => None,
        }
    }
}

/// The variant figures of a group's runs.
#[derive(Debug, Default)]
struct GroupFigures {
    runs: usize,
    not_started: usize,
    start_s: Vec<f64>,
    coverage: Vec<f64>,
    ext_cm: Vec<f64>,
    ext_deg: Vec<f64>,
}

/// The figures only the in-motion and extrinsic variants report, per group, as a Markdown table
/// (`None` when no run has them: the standard suite prints only the main table). In-motion
/// starts: runs that never gave an estimate, the first estimate's delay after the first camera
/// frame (median and worst of those that started), the share of the ground truth after the
/// first camera frame with a pose (`summary.json`'s `coverage`; lowest). Extrinsic: its error
/// at the end (medians and worst).
pub fn render_variant_figures(runs: &[RunResult]) -> Option<String> {
    let mut groups: BTreeMap<&str, GroupFigures> = BTreeMap::new();
    for r in runs {
        let (Some(g), Some(v)) = (r.scenario.as_deref(), r.variant.as_ref()) else {
            continue;
        };
        let f = groups.entry(g).or_default();
        f.runs += 1;
        f.not_started += usize::from(!v.started);
        f.start_s.extend(v.start_after_camera_s);
        f.coverage.extend(v.camera_coverage);
        f.ext_cm.extend(v.extrinsic_err_end_cm);
        f.ext_deg.extend(v.extrinsic_err_end_deg);
    }
    if groups.is_empty() {
        return None;
    }
    let med_max = |v: &mut Vec<f64>, digits: usize| match super::median(v) {
        Some(m) => format!(
            "{m:.digits$} / {:.digits$}",
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        ),
        None => "n/a".into(),
    };
    let mut s = String::from(
        "| group | runs | never started | start after camera, median / worst [s] | \
         coverage after camera, lowest | extrinsic error end, median / worst [cm] | [deg] |\n\
         |---|---:|---:|---:|---:|---:|---:|\n",
    );
    for (g, mut f) in groups {
        let cov = f.coverage.iter().copied().reduce(f64::min);
        s.push_str(&format!(
            "| {g} | {} | {} | {} | {} | {} | {} |\n",
            f.runs,
            f.not_started,
            med_max(&mut f.start_s, 2),
            cov.map_or("n/a".into(), |c| format!("{c:.3}")),
            med_max(&mut f.ext_cm, 2),
            med_max(&mut f.ext_deg, 3),
        ));
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use super::super::{sequences, Sequence, SCENARIOS};
    use super::*;
    use std::path::Path;

    /// The new groups are named, grouped and simulated as said, after the standard sequences and
    /// beside the delay groups; the standard sequences are unchanged by them.
    #[test]
    fn motion_and_extrinsic_variants_are_named_grouped_and_simulated_as_said() {
        let groups = [VariantGroup::MotionStart, VariantGroup::Extrinsic];
        let seqs = sequences(Path::new("data"), false, Some(3), 1, &groups);
        let sims: Vec<&Sequence> = seqs.iter().filter(|s| s.scenario().is_some()).collect();
        assert_eq!(sims.len(), 3 * SCENARIOS.len() * 3);
        let plain = sequences(Path::new("data"), false, Some(3), 1, &[]);
        assert_eq!(
            seqs[..plain.len()],
            plain[..],
            "the standard ones first, unchanged"
        );
        let names: std::collections::BTreeSet<String> = sims.iter().map(|s| s.name()).collect();
        assert_eq!(names.len(), sims.len(), "names are unique");
        assert!(names.contains("sim-vehicle-seed3-60s-motion"));
        assert!(names.contains("sim-flight-seed1-60s-extrinsic"));
        let gs: std::collections::BTreeSet<String> =
            sims.iter().filter_map(|s| s.group()).collect();
        assert!(gs.contains("vehicle/motion") && gs.contains("flight/extrinsic"));
        assert_eq!(gs.len(), SCENARIOS.len() * 3);
        let all = [
            VariantGroup::Delays,
            VariantGroup::DelayStep,
            VariantGroup::MotionStart,
            VariantGroup::Extrinsic,
        ];
        let seqs = sequences(Path::new("data"), true, Some(1), 1, &all);
        assert_eq!(seqs.len(), 2 + SCENARIOS.len() * 7);

        // In motion: the rest and the ramp cut away (1 s + 2 s; the vehicle's ramp is 8 s),
        // the standard delay, started by the automatic choice.
        let c = sim_config(Scenario::Flight, 1, 60.0, Variant::MotionStart);
        assert_eq!((c.start_s, c.td_s, c.td_step), (3.0, 0.008, None));
        let c = sim_config(Scenario::Vehicle, 1, 60.0, Variant::MotionStart);
        assert_eq!(c.start_s, 9.0);
        assert_eq!(Variant::MotionStart.init(), InitMode::Auto);
        // The extrinsic variant simulates the standard sequence, started from the true state.
        let (std_c, ext_c) = (
            sim_config(Scenario::Robot, 2, 60.0, Variant::Standard),
            sim_config(Scenario::Robot, 2, 60.0, Variant::Extrinsic),
        );
        assert_eq!(format!("{std_c:?}"), format!("{ext_c:?}"));
        assert_eq!(Variant::Extrinsic.init(), InitMode::Groundtruth);
        assert_eq!(Variant::Standard.init(), InitMode::Groundtruth);
    }

    fn ext(p: [f64; 3], axis_angle: [f64; 3]) -> CameraExtrinsic {
        CameraExtrinsic {
            p_bc: Vec3::from(p),
            q_bc: Quat::from_scaled_axis(Vec3::from(axis_angle)),
        }
    }

    /// The perturbation is exactly 2 cm and 2 degrees in its documented directions, on the
    /// identity and on a camera looking forward; the variant also turns estimation on.
    #[test]
    fn the_extrinsic_is_perturbed_by_exactly_2_cm_and_2_degrees() {
        for truth in [
            ext([0.0; 3], [0.0; 3]),
            ext([0.05, -0.01, 0.02], [-1.2, 0.3, -1.1]),
        ] {
            let p = perturbed_extrinsic(&truth);
            let (cm, deg) = extrinsic_error(&p, &truth);
            assert!((cm - 2.0).abs() < 1e-12, "{cm} cm");
            assert!((deg - 2.0).abs() < 1e-12, "{deg} deg");
            let dp = (p.p_bc - truth.p_bc) / 0.02;
            let s = 1.0 / 3f64.sqrt();
            assert!((dp - Vec3::new(s, -s, s)).norm() < 1e-12, "{dp}");
            // The rotation is about (1, 2, -1)/sqrt(6) in the body frame.
            let axis = (p.q_bc * truth.q_bc.inverse()).axis().expect("a rotation");
            let want = Vec3::new(1.0, 2.0, -1.0) / 6f64.sqrt();
            assert!((axis.into_inner() - want).norm() < 1e-12, "{axis:?}");
            assert_eq!(extrinsic_error(&truth, &truth), (0.0, 0.0));
        }
        let truth = ext([0.05, -0.01, 0.02], [-1.2, 0.3, -1.1]);
        let mut cfg = EstimatorConfig::new(
            povins_core::camera::PinholeCamera::EUROC_CAM0,
            truth,
            povins_core::inertial::ImuNoise::EUROC_ADIS16448,
        );
        Variant::Standard.configure(&mut cfg);
        assert_eq!((cfg.extrinsic, cfg.estimate_extrinsic), (truth, false));
        Variant::Extrinsic.configure(&mut cfg);
        assert_eq!(cfg.extrinsic, perturbed_extrinsic(&truth));
        assert!(cfg.estimate_extrinsic);
    }

    /// The variant table lists only the runs with variant figures, counts the runs that never
    /// started and takes medians and worst values over those that did.
    #[test]
    fn the_variant_table_counts_unstarted_runs_and_takes_medians() {
        use super::super::tests::run;
        assert_eq!(
            render_variant_figures(&[run("a", Some("s"), 0.1, false)]),
            None
        );
        let motion = |start: Option<f64>, cov: f64| VariantFigures {
            started: start.is_some(),
            start_after_camera_s: start,
            camera_coverage: Some(cov),
            ..Default::default()
        };
        let mut runs = vec![
            run("plain", Some("flight"), 0.1, false),
            run("m1", Some("flight/motion"), 0.1, false),
            run("m2", Some("flight/motion"), 0.1, false),
            run("m3", Some("flight/motion"), f64::INFINITY, true),
            run("e1", Some("flight/extrinsic"), 0.1, false),
        ];
        runs[1].variant = Some(motion(Some(0.5), 0.97));
        runs[2].variant = Some(motion(Some(1.5), 0.93));
        runs[3].variant = Some(motion(None, 0.0));
        runs[4].variant = Some(VariantFigures {
            started: true,
            extrinsic_err_end_cm: Some(0.4),
            extrinsic_err_end_deg: Some(0.15),
            ..Default::default()
        });
        let t = render_variant_figures(&runs).expect("a table");
        assert!(
            t.contains("| flight/motion | 3 | 1 | 1.00 / 1.50 | 0.000 | n/a | n/a |"),
            "{t}"
        );
        assert!(
            t.contains("| flight/extrinsic | 1 | 0 | n/a | n/a | 0.40 / 0.40 | 0.150 / 0.150 |"),
            "{t}"
        );
        assert!(!t.contains("| flight |"), "{t}");
    }

    fn short(scenario: Scenario, variant: Variant) -> Sequence {
        Sequence::Sim {
            scenario,
            seed: 1,
            duration_s: 12.0,
            variant,
        }
    }

    /// A short flight started in motion starts from the automatic initializer within 3 s of the
    /// first camera frame and covers the rest; with the in-motion start made impossible (an
    /// overlay asking for more excitation than any motion has) it never starts, and the run is
    /// a divergence with an infinite ATE, not an error or a dropped run.
    #[test]
    fn a_short_flight_started_in_motion_starts_and_a_refused_start_diverges() {
        let seq = short(Scenario::Flight, Variant::MotionStart);
        let r = super::super::run_sequence(&seq, None).expect("the run");
        let v = r.variant.clone().expect("motion figures");
        let start = v.start_after_camera_s.expect("a start");
        assert!(v.started && (0.0..3.0).contains(&start), "{r:?}");
        assert!(v.camera_coverage.is_some_and(|c| c > 0.8), "{r:?}");
        assert!(
            r.ate_m.is_finite() && r.ate_m < 1.0 && r.keyframes > 10,
            "{r:?}"
        );
        assert_eq!(r.scenario.as_deref(), Some("flight/motion"));

        let never =
            crate::config::RunConfigFile::parse("[init.motion]\nmin_accel_excitation_mps2 = 1e9\n")
                .expect("toml");
        let r = super::super::run_sequence(&seq, Some(&never)).expect("a refused run");
        let v = r.variant.clone().expect("motion figures");
        assert!(!v.started && v.start_after_camera_s.is_none(), "{r:?}");
        assert!(
            r.diverged && r.ate_m == f64::INFINITY && r.keyframes == 0,
            "{r:?}"
        );
        let t = render_variant_figures(&[r]).expect("a table");
        assert!(t.contains("| flight/motion | 1 | 1 | n/a | 0.000 |"), "{t}");
    }

    /// A short hand-held run started 2 cm / 2 deg off estimates the extrinsic: its error at the
    /// end against the simulator's truth is not zero (the run without the variant's settings
    /// would report the exact extrinsic it was given) and well below the start's (the variant's
    /// start held fixed would report exactly 2 cm / 2 deg).
    #[test]
    fn a_short_hand_held_run_with_a_perturbed_extrinsic_estimates_it() {
        let seq = short(Scenario::Handheld, Variant::Extrinsic);
        let r = super::super::run_sequence(&seq, None).expect("the run");
        let v = r.variant.clone().expect("extrinsic figures");
        let (cm, deg) = (
            v.extrinsic_err_end_cm.expect("cm"),
            v.extrinsic_err_end_deg.expect("deg"),
        );
        assert!(v.started && r.ate_m.is_finite() && !r.diverged, "{r:?}");
        assert!((1e-6..1.0).contains(&deg), "{cm} cm, {deg} deg");
        assert!((1e-6..2.5).contains(&cm), "{cm} cm, {deg} deg");
        eprintln!("hand-held 12 s, extrinsic error at the end: {cm:.3} cm, {deg:.3} deg");
        assert_eq!(r.scenario.as_deref(), Some("handheld/extrinsic"));
    }
}
