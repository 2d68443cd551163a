//! Paired comparison of two runs of the regression suite (`povins regress --compare OLD.json`).
//!
//! The stored figures cover a fixed set of seeds, the ones every kept change was judged on, so
//! they are a biased judge of the next change. Fresh seeds are a fair one, and single simulated
//! runs are chaotic (tens of percent from a microsecond change of one stamp), so two versions
//! are compared seed by seed on the same sequences: per scenario the median of each, the
//! geometric mean of the per-seed ratios new / old, on how many seeds the new one is better,
//! and the divergences of each. Typical use: `povins regress --quick --first-seed 9 --seeds 22
//! --json old.json` on the old binary, the same with `--compare old.json` on the new one.

use crate::regress::RunResult;
use anyhow::{Context, Result};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

/// What the comparison needs of an earlier run (a `--json` file's entries).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OldRun {
    /// Sequence name.
    pub name: String,
    /// Scenario (simulated runs), `None` for the real sequences.
    #[serde(default)]
    pub scenario: Option<String>,
    /// Position ATE, m (`null` in the file: the run never started, infinite).
    #[serde(deserialize_with = "ate_or_infinite")]
    pub ate_m: f64,
    /// Diverged (see `regress`).
    #[serde(default)]
    pub diverged: bool,
}

/// An ATE, or infinity for the `null` JSON writes for a run that never started.
fn ate_or_infinite<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

/// Reads a `--json` file of an earlier run.
pub fn read_old(path: &Path) -> Result<Vec<OldRun>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the earlier run {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: not a `povins regress --json` file (a list of runs with name and ate_m)",
            path.display()
        )
    })
}

/// One scenario (or real sequence) of the comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct PairedRow {
    /// Scenario or sequence name.
    pub name: String,
    /// Sequences present in both runs.
    pub pairs: usize,
    /// Median ATE of the earlier run over the pairs, m.
    pub old_median_m: f64,
    /// Median ATE of this run over the pairs, m.
    pub new_median_m: f64,
    /// Geometric mean of the per-sequence ratios new / old.
    pub geo_mean_ratio: f64,
    /// Sequences where this run's ATE is lower.
    pub better: usize,
    /// Divergences of the earlier run and of this one over the pairs.
    pub diverged: (usize, usize),
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Pairs the runs by sequence name and summarizes them per scenario (real sequences on their
/// own rows), in the order of `new`.
pub fn paired(old: &[OldRun], new: &[RunResult]) -> Vec<PairedRow> {
    let old: BTreeMap<&str, &OldRun> = old.iter().map(|r| (r.name.as_str(), r)).collect();
    let mut groups: Vec<(String, Vec<(&OldRun, &RunResult)>)> = Vec::new();
    for r in new {
        let Some(o) = old.get(r.name.as_str()) else {
            continue;
        };
        let key = r.scenario.clone().unwrap_or_else(|| r.name.clone());
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, v)) => v.push((o, r)),
            None => groups.push((key, vec![(o, r)])),
        }
    }
    groups
        .into_iter()
        .map(|(name, v)| {
            let log_sum: f64 = v.iter().map(|(o, n)| (n.ate_m / o.ate_m).ln()).sum();
            PairedRow {
                name,
                pairs: v.len(),
                old_median_m: median(v.iter().map(|(o, _)| o.ate_m).collect()),
                new_median_m: median(v.iter().map(|(_, n)| n.ate_m).collect()),
                geo_mean_ratio: (log_sum / v.len() as f64).exp(),
                better: v.iter().filter(|(o, n)| n.ate_m < o.ate_m).count(),
                diverged: (
                    v.iter().filter(|(o, _)| o.diverged).count(),
                    v.iter().filter(|(_, n)| n.diverged).count(),
                ),
            }
        })
        .collect()
}

/// The comparison as a Markdown table.
pub fn render_paired(rows: &[PairedRow], old_name: &str) -> String {
    let mut s = format!(
        "Against {old_name}, sequence by sequence:\n\n| scenario / sequence | pairs | earlier \
         median [m] | this run [m] | change of the median | geometric mean of ratios | better on \
         | diverged (earlier -> now) |\n|---|---:|---:|---:|---:|---:|---:|---|\n"
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {:.4} | {:.4} | {:+.1}% | {:.3} | {} of {} | {} -> {} |\n",
            r.name,
            r.pairs,
            r.old_median_m,
            r.new_median_m,
            100.0 * (r.new_median_m / r.old_median_m - 1.0),
            r.geo_mean_ratio,
            r.better,
            r.pairs,
            r.diverged.0,
            r.diverged.1
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::regress::tests::run as new_run;

    #[test]
    fn pairs_by_name_and_summarizes_per_scenario() {
        let old_json = r#"[
            {"name": "euroc", "scenario": null, "ate_m": 0.03, "diverged": false},
            {"name": "robot-1", "scenario": "robot", "ate_m": 0.2, "diverged": false},
            {"name": "robot-2", "scenario": "robot", "ate_m": 0.4, "diverged": true},
            {"name": "robot-3", "scenario": "robot", "ate_m": 0.1, "max_err_m": 1.0},
            {"name": "only-old", "scenario": "fast", "ate_m": 1.0}
        ]"#;
        let old: Vec<OldRun> = serde_json::from_str(old_json).expect("json");
        let new = [
            new_run("euroc", None, 0.06, false),
            new_run("robot-1", Some("robot"), 0.1, false),
            new_run("robot-2", Some("robot"), 0.2, false),
            new_run("robot-3", Some("robot"), 0.4, true),
            new_run("only-new", Some("fast"), 1.0, false),
        ];
        let rows = paired(&old, &new);
        assert_eq!(rows.len(), 2, "{rows:?}");
        let euroc = &rows[0];
        assert_eq!((euroc.name.as_str(), euroc.pairs), ("euroc", 1));
        assert!((euroc.geo_mean_ratio - 2.0).abs() < 1e-12);
        let robot = &rows[1];
        assert_eq!((robot.name.as_str(), robot.pairs), ("robot", 3));
        assert_eq!((robot.old_median_m, robot.new_median_m), (0.2, 0.2));
        // Ratios 0.5, 0.5, 4: geometric mean 1.
        assert!((robot.geo_mean_ratio - 1.0).abs() < 1e-12);
        assert_eq!(robot.better, 2);
        assert_eq!(robot.diverged, (1, 1));
        let text = render_paired(&rows, "old.json");
        assert!(text.contains("| robot | 3 | 0.2000 | 0.2000 | +0.0% | 1.000 | 2 of 3 | 1 -> 1 |"));
    }

    /// A run that never started is written with an infinite ATE, which JSON writes as `null`:
    /// it reads back as infinite (a missing ATE is still refused).
    #[test]
    fn a_run_that_never_started_reads_back_infinite() {
        let mut r = new_run("m", Some("flight/motion"), f64::INFINITY, true);
        r.keyframes = 0;
        let text = serde_json::to_string(&[r]).expect("json");
        assert!(text.contains(r#""ate_m":null"#), "{text}");
        let old: Vec<OldRun> = serde_json::from_str(&text).expect("read back");
        assert_eq!((old[0].ate_m, old[0].diverged), (f64::INFINITY, true));
        assert!(serde_json::from_str::<Vec<OldRun>>(r#"[{"name": "m"}]"#).is_err());
    }

    #[test]
    fn a_file_that_is_not_a_run_names_itself() {
        let dir = std::env::temp_dir().join(format!("povins-paired-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let p = dir.join("baseline.json");
        std::fs::write(&p, r#"{"note": "", "ate_m": {}}"#).expect("write");
        let e = format!("{:#}", read_old(&p).expect_err("a baseline is not a run"));
        assert!(e.contains("baseline.json") && e.contains("--json"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
