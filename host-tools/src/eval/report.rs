//! The result of an evaluation: a struct for code, flat JSON for scripts, a table for people.
//!
//! JSON keys are flat and carry units: `ate_pos_{rmse,mean,median,std,min,max,sse}_m`,
//! `ate_rot_{..}_deg`, the alignment (`align_q_wv_wxyz`, `align_t_wv_m`, `align_scale`) and
//! `rte`: one object per segment length with `segment_m`, `pairs`, `pos_{..}_m`, `rot_{..}_deg`
//! (`null` when no segment of that length exists). Per-pose errors are not serialized.

use super::align::{Alignment, Sim3};
use super::rte::RteSegment;
use super::stats::Stats;
use povins_platform::trajectory::StampedPose;
use serde::Serialize;
use serde_json::{json, Map, Value};
use std::fmt;

/// One matched pose after alignment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchedPose {
    /// Ground-truth pose (world `w`).
    pub gt: StampedPose,
    /// Estimated pose mapped into `w` by the alignment; its stamp is the estimate's own.
    pub est_aligned: StampedPose,
    /// Position error, m.
    pub pos_err_m: f64,
    /// Rotation error, degrees.
    pub rot_err_deg: f64,
}

/// Evaluation result of [`super::evaluate`].
#[derive(Debug, Clone, PartialEq)]
pub struct EvalReport {
    /// The transform fitted.
    pub alignment: Alignment,
    /// Poses in the ground truth.
    pub gt_poses: usize,
    /// Poses in the estimate.
    pub est_poses: usize,
    /// Matched pairs used for everything below.
    pub matched_poses: usize,
    /// Matching tolerance, s.
    pub t_max_diff_s: f64,
    /// Offset added to the estimate's stamps, s.
    pub t_offset_s: f64,
    /// Estimate world `v` -> ground-truth world `w`.
    pub transform: Sim3,
    /// ATE, position, m.
    pub ate_pos_m: Stats,
    /// ATE, rotation, degrees.
    pub ate_rot_deg: Stats,
    /// RTE per requested segment length.
    pub rte: Vec<RteSegment>,
    /// Per-pose errors in time order (for plots).
    pub matches: Vec<MatchedPose>,
}

fn put_stats(map: &mut Map<String, Value>, prefix: &str, unit: &str, stats: Option<&Stats>) {
    for (i, name) in ["rmse", "mean", "median", "std", "min", "max", "sse"]
        .iter()
        .enumerate()
    {
        let v = stats.map_or(Value::Null, |s| json!(s.named()[i].1));
        map.insert(format!("{prefix}_{name}_{unit}"), v);
    }
}

impl EvalReport {
    /// The flat JSON object described in the module docs.
    pub fn to_json(&self) -> Value {
        let mut m = Map::new();
        m.insert("alignment".into(), json!(self.alignment.name()));
        m.insert("gt_poses".into(), json!(self.gt_poses));
        m.insert("est_poses".into(), json!(self.est_poses));
        m.insert("matched_poses".into(), json!(self.matched_poses));
        m.insert("t_max_diff_s".into(), json!(self.t_max_diff_s));
        m.insert("t_offset_s".into(), json!(self.t_offset_s));
        let q = self.transform.q_wv.quaternion();
        m.insert("align_q_wv_wxyz".into(), json!([q.w, q.i, q.j, q.k]));
        let t = self.transform.t_wv;
        m.insert("align_t_wv_m".into(), json!([t.x, t.y, t.z]));
        m.insert("align_scale".into(), json!(self.transform.scale));
        put_stats(&mut m, "ate_pos", "m", Some(&self.ate_pos_m));
        put_stats(&mut m, "ate_rot", "deg", Some(&self.ate_rot_deg));
        let rte: Vec<Value> = self
            .rte
            .iter()
            .map(|s| {
                let mut o = Map::new();
                o.insert("segment_m".into(), json!(s.segment_m));
                o.insert("pairs".into(), json!(s.pairs));
                put_stats(&mut o, "pos", "m", s.pos_m.as_ref());
                put_stats(&mut o, "rot", "deg", s.rot_deg.as_ref());
                Value::Object(o)
            })
            .collect();
        m.insert("rte".into(), Value::Array(rte));
        Value::Object(m)
    }
}

impl Serialize for EvalReport {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.to_json().serialize(s)
    }
}

impl fmt::Display for EvalReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let t = &self.transform;
        let (roll, pitch, yaw) = t.q_wv.euler_angles();
        writeln!(
            f,
            "matched {} of {} estimated / {} ground-truth poses (max diff {} s, offset {} s)",
            self.matched_poses, self.est_poses, self.gt_poses, self.t_max_diff_s, self.t_offset_s
        )?;
        writeln!(
            f,
            "alignment {}: t_wv = [{:.4}, {:.4}, {:.4}] m, rpy = [{:.3}, {:.3}, {:.3}] deg, scale = {:.6}",
            self.alignment.name(),
            t.t_wv.x,
            t.t_wv.y,
            t.t_wv.z,
            roll.to_degrees(),
            pitch.to_degrees(),
            yaw.to_degrees(),
            t.scale
        )?;
        writeln!(f)?;
        writeln!(
            f,
            "{:<18} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
            "ATE", "rmse", "mean", "median", "std", "min", "max"
        )?;
        for (label, s) in [
            ("position [m]", &self.ate_pos_m),
            ("rotation [deg]", &self.ate_rot_deg),
        ] {
            writeln!(
                f,
                "{label:<18} {:>10.6} {:>10.6} {:>10.6} {:>10.6} {:>10.6} {:>10.6}",
                s.rmse, s.mean, s.median, s.std, s.min, s.max
            )?;
        }
        if self.rte.is_empty() {
            return Ok(());
        }
        writeln!(f)?;
        writeln!(
            f,
            "{:<12} {:>7} {:>11} {:>11} {:>11} {:>11} {:>11} {:>11}",
            "RTE seg [m]",
            "pairs",
            "pos rmse",
            "pos mean",
            "pos median",
            "rot rmse",
            "rot mean",
            "rot median"
        )?;
        for s in &self.rte {
            match (s.pos_m, s.rot_deg) {
                (Some(p), Some(r)) => writeln!(
                    f,
                    "{:<12} {:>7} {:>9.4} m {:>9.4} m {:>9.4} m {:>7.4} deg {:>7.4} deg {:>7.4} deg",
                    s.segment_m, s.pairs, p.rmse, p.mean, p.median, r.rmse, r.mean, r.median
                )?,
                _ => writeln!(f, "{:<12} {:>7}   (trajectory shorter than the segment)", s.segment_m, 0)?,
            }
        }
        Ok(())
    }
}
