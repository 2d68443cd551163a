//! The LiDAR ablation of the paper (Table VI, plus PO-VINS-WO) on simulated sequences.
//!
//! For every scenario and seed one sequence is simulated in memory with the simulator's
//! defaults (LiDAR on, mounting error, wrong tracks and occlusion edges: the LiDAR-depth
//! outliers the rejection exists for) and replayed once per [`Variant`] from the true initial
//! state; only the LiDAR switches differ between the variants.
//!
//! Aggregation per variant:
//! - ATE per scenario: mean over the seeds of the IMU-rate position RMSE (posyaw-aligned);
//!   the overall ATE is the mean of the scenario means (each scenario weighs the same, as the
//!   paper's "Average" row); the change is relative to `po-vins`.
//! - timings (back end, rejection, depth-only optimization): median over every keyframe of
//!   every run of the variant;
//! - LDM and associated depths per keyframe: totals over all runs / keyframes over all runs;
//! - association quality ([`crate::eval::lidar_assoc`]): counts pooled over all runs.
//!
//! Accuracy and association numbers are deterministic and do not depend on `jobs`. Timings are
//! the core's clock: `povins ablation` sets it to each run's thread CPU time
//! ([`crate::runner::use_cpu_time`]), so parallel runs do not count each other's time (they
//! still share caches and memory bandwidth; `--jobs 1` gives the cleanest times).

use crate::config::RunConfigFile;
use crate::eval::lidar_assoc::{self, AssocQuality};
use crate::progress::Progress;
use crate::report::summarize;
use crate::runner::{config_for, percentile, replay, sorted_ms, InitMode};
use crate::sim::{self, LidarKind, Scenario, SimConfig};
use anyhow::{anyhow, ensure, Result};
use povins_core::estimator::{EstimatorConfig, KeyframeReport};
use povins_core::lidar::{LdmMode, LidarConfig};
use povins_platform::Dataset;
use serde::Serialize;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// One estimator configuration of the ablation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    /// MSC-based LDM, uncertainty-based rejection, depth-only optimization.
    PoVins,
    /// No LiDAR (PO-VINS-WO).
    PoVinsWo,
    /// PO-VINS without the uncertainty-based rejection.
    NoRejection,
    /// PO-VINS with the direct LDM instead of the MSC-based one.
    DirectLdm,
    /// PO-VINS without the depth-only optimization.
    NoDepthOpt,
}

impl Variant {
    /// Every variant, in table order.
    pub const ALL: [Variant; 5] = [
        Variant::PoVins,
        Variant::PoVinsWo,
        Variant::NoRejection,
        Variant::DirectLdm,
        Variant::NoDepthOpt,
    ];

    /// Name in tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Variant::PoVins => "po-vins",
            Variant::PoVinsWo => "po-vins-wo",
            Variant::NoRejection => "no-rejection",
            Variant::DirectLdm => "direct-ldm",
            Variant::NoDepthOpt => "no-depth-opt",
        }
    }

    /// Sets the LiDAR switches of this variant (every switch, so a config file cannot leak in).
    pub fn apply(self, l: &mut LidarConfig) {
        l.enabled = self != Variant::PoVinsWo;
        l.ldm = if self == Variant::DirectLdm {
            LdmMode::Direct
        } else {
            LdmMode::Msc
        };
        l.depth_outlier_rejection = self != Variant::NoRejection;
        l.depth_only_opt = self != Variant::NoDepthOpt;
    }
}

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct AblationConfig {
    /// Simulated scenarios (table columns).
    pub scenarios: Vec<Scenario>,
    /// Simulator seeds per scenario.
    pub seeds: Vec<u64>,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Worker threads for the runs (and the LiDAR simulation).
    pub jobs: usize,
    /// Camera-LiDAR rotation error of the simulated calibration, deg (the simulator's default
    /// is 0.5): larger values put more feature depths on the background at object edges.
    pub lidar_extrinsic_error_deg: f64,
    /// Probability that a LiDAR ray passes through a tree crown (the simulator's default is 0).
    pub foliage_porosity: f64,
    /// The LiDAR model simulated on every scenario (`None`: each scenario's default).
    pub lidar: Option<LidarKind>,
}

/// One replay.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunResult {
    /// Scenario name.
    pub scenario: String,
    /// Simulator seed.
    pub seed: u64,
    /// Variant.
    pub variant: Variant,
    /// Keyframes.
    pub keyframes: usize,
    /// IMU-rate ATE, position RMSE, m (posyaw); `None` if nothing could be evaluated.
    pub ate_pos_rmse_m: Option<f64>,
    /// Back end per keyframe, median, ms.
    pub backend_ms_median: f64,
    /// Depth association per keyframe, median, ms.
    pub association_ms_median: f64,
    /// Rejection per keyframe, median, ms.
    pub rejection_ms_median: f64,
    /// Depth-only optimization per keyframe, median, ms.
    pub depth_opt_ms_median: f64,
    /// Associated depths summed over the keyframes.
    pub depths_associated: u64,
    /// Rejected depths summed over the keyframes.
    pub depths_rejected: u64,
    /// LDM counts summed over the keyframes.
    pub ldm_total: u64,
    /// LiDAR sweeps the estimator was offered.
    pub lidar_scans_pushed: u64,
    /// Association quality counts (the simulator always has the truth).
    pub assoc: Option<AssocQuality>,
    /// Per-keyframe timings, ms, for pooled medians.
    #[serde(skip)]
    pub timings: Timings,
}

/// Per-keyframe timings of a run, ms.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Timings {
    /// Back end.
    pub backend_ms: Vec<f64>,
    /// Rejection.
    pub rejection_ms: Vec<f64>,
    /// Depth-only optimization.
    pub depth_opt_ms: Vec<f64>,
}

/// Mean ATE of a variant on one scenario.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScenarioAte {
    /// Scenario name.
    pub scenario: String,
    /// Mean over the seeds that could be evaluated, m.
    pub ate_mean_m: Option<f64>,
    /// Seeds run.
    pub runs: usize,
    /// Seeds with an ATE.
    pub evaluated: usize,
}

/// A table row.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VariantRow {
    /// Variant.
    pub variant: Variant,
    /// ATE per scenario, in [`AblationConfig::scenarios`] order.
    pub ate: Vec<ScenarioAte>,
    /// Mean of the scenario means, m.
    pub ate_mean_m: Option<f64>,
    /// `(ate_mean / ate_mean(po-vins) - 1) * 100`.
    pub ate_change_vs_po_vins_pct: Option<f64>,
    /// The same per (scenario, seed) pair: geometric mean of `ATE / ATE(po-vins)` over the pairs,
    /// minus 1, in percent (runs differ by chaotic trajectory details, so pairing removes the
    /// scenario and seed from the comparison).
    pub paired_change_pct: Option<f64>,
    /// Standard error of that mean log ratio, in percent.
    pub paired_se_pct: Option<f64>,
    /// Pairs where po-vins has the lower ATE, and pairs compared.
    pub po_vins_better: (usize, usize),
    /// Back end per keyframe, median over every keyframe of every run, ms.
    pub backend_ms_median: f64,
    /// Rejection per keyframe, median, ms.
    pub rejection_ms_median: f64,
    /// Depth-only optimization per keyframe, median, ms.
    pub depth_opt_ms_median: f64,
    /// Associated depths per keyframe.
    pub depths_associated_per_kf: f64,
    /// LDM per keyframe.
    pub ldm_per_kf: f64,
    /// Associated depths checked against the truth.
    pub assoc_checked: usize,
    /// Share within 3 sigma_dr of the true depth, before rejection.
    pub assoc_within_3sigma_before: Option<f64>,
    /// The same over the depths kept after rejection.
    pub assoc_within_3sigma_after: Option<f64>,
    /// Share of checked depths on edge features, before rejection.
    pub edge_share_before: Option<f64>,
    /// After rejection.
    pub edge_share_after: Option<f64>,
}

/// Everything the ablation produced.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AblationReport {
    /// Scenario names.
    pub scenarios: Vec<String>,
    /// Seeds.
    pub seeds: Vec<u64>,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Worker threads (timings depend on it).
    pub jobs: usize,
    /// Simulated camera-LiDAR rotation error, deg.
    pub lidar_extrinsic_error_deg: f64,
    /// Simulated foliage porosity for the LiDAR.
    pub foliage_porosity: f64,
    /// The LiDAR model simulated (`default`: each scenario's own).
    pub lidar: String,
    /// One row per variant, in [`Variant::ALL`] order.
    pub rows: Vec<VariantRow>,
    /// Every run, scenario-major, then seed, then variant.
    pub runs: Vec<RunResult>,
}

fn run_one(
    ds: &Dataset,
    base: &EstimatorConfig,
    scenario: Scenario,
    seed: u64,
    variant: Variant,
) -> Result<RunResult> {
    let mut cfg = *base;
    variant.apply(&mut cfg.lidar);
    let quiet = Progress::with_visibility(0, "", false);
    let out = replay(ds, cfg, InitMode::Groundtruth, &quiet)?;
    let s = summarize(ds, &format!("{:?}", cfg.mode), InitMode::Groundtruth, &out)?;
    let sum = |f: fn(&KeyframeReport) -> u32| -> u64 {
        out.reports.iter().map(|r| u64::from(f(r))).sum()
    };
    Ok(RunResult {
        scenario: scenario.name().to_string(),
        seed,
        variant,
        keyframes: out.reports.len(),
        ate_pos_rmse_m: s.ate_pos_rmse_m,
        backend_ms_median: s.backend_ms_median,
        association_ms_median: s.association_ms_median,
        rejection_ms_median: s.rejection_ms_median,
        depth_opt_ms_median: s.depth_opt_ms_median,
        depths_associated: sum(|r| r.depths_associated),
        depths_rejected: sum(|r| r.depths_rejected),
        ldm_total: sum(|r| r.ldm_count),
        lidar_scans_pushed: out.counters.lidar_scans,
        assoc: lidar_assoc::assess(ds, &out.lidar_events, cfg.lidar.sigma_dr_m),
        timings: Timings {
            backend_ms: sorted_ms(&out.reports, |r| r.backend_ns()),
            rejection_ms: sorted_ms(&out.reports, |r| r.rejection_ns),
            depth_opt_ms: sorted_ms(&out.reports, |r| r.depth_opt_ns),
        },
    })
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn pooled_median(runs: &[&RunResult], f: impl Fn(&Timings) -> &[f64]) -> f64 {
    let mut all: Vec<f64> = runs.iter().flat_map(|r| f(&r.timings).to_vec()).collect();
    all.sort_by(f64::total_cmp);
    percentile(&all, 50.0)
}

fn aggregate(scenarios: &[Scenario], runs: &[RunResult]) -> Vec<VariantRow> {
    let mut rows: Vec<VariantRow> = Variant::ALL
        .iter()
        .map(|&v| {
            let mine: Vec<&RunResult> = runs.iter().filter(|r| r.variant == v).collect();
            let ate: Vec<ScenarioAte> = scenarios
                .iter()
                .map(|sc| {
                    let of: Vec<&&RunResult> =
                        mine.iter().filter(|r| r.scenario == sc.name()).collect();
                    let ates: Vec<f64> = of.iter().filter_map(|r| r.ate_pos_rmse_m).collect();
                    ScenarioAte {
                        scenario: sc.name().to_string(),
                        ate_mean_m: mean(&ates),
                        runs: of.len(),
                        evaluated: ates.len(),
                    }
                })
                .collect();
            let means: Vec<f64> = ate.iter().filter_map(|a| a.ate_mean_m).collect();
            let keyframes: usize = mine.iter().map(|r| r.keyframes).sum();
            let per_kf = |x: u64| {
                if keyframes == 0 {
                    0.0
                } else {
                    x as f64 / keyframes as f64
                }
            };
            let q = mine
                .iter()
                .filter_map(|r| r.assoc)
                .fold(AssocQuality::default(), |a, b| a.add(&b));
            VariantRow {
                variant: v,
                ate_mean_m: mean(&means),
                ate,
                ate_change_vs_po_vins_pct: None,
                paired_change_pct: None,
                paired_se_pct: None,
                po_vins_better: (0, 0),
                backend_ms_median: pooled_median(&mine, |t| &t.backend_ms),
                rejection_ms_median: pooled_median(&mine, |t| &t.rejection_ms),
                depth_opt_ms_median: pooled_median(&mine, |t| &t.depth_opt_ms),
                depths_associated_per_kf: per_kf(mine.iter().map(|r| r.depths_associated).sum()),
                ldm_per_kf: per_kf(mine.iter().map(|r| r.ldm_total).sum()),
                assoc_checked: q.checked,
                assoc_within_3sigma_before: q.within_3sigma_before(),
                assoc_within_3sigma_after: q.within_3sigma_after(),
                edge_share_before: q.edge_share_before(),
                edge_share_after: q.edge_share_after(),
            }
        })
        .collect();
    let reference = rows
        .iter()
        .find(|r| r.variant == Variant::PoVins)
        .and_then(|r| r.ate_mean_m);
    for r in &mut rows {
        r.ate_change_vs_po_vins_pct = match (r.ate_mean_m, reference) {
            (Some(a), Some(b)) if b > 0.0 => Some((a / b - 1.0) * 100.0),
            _ => None,
        };
        let logs = paired_log_ratios(runs, r.variant);
        let n = logs.len();
        r.po_vins_better = (logs.iter().filter(|&&x| x > 0.0).count(), n);
        if let Some(m) = mean(&logs) {
            r.paired_change_pct = Some((m.exp() - 1.0) * 100.0);
            if n >= 2 {
                let var = logs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1) as f64;
                r.paired_se_pct = Some((var / n as f64).sqrt() * 100.0);
            }
        }
    }
    rows
}

/// `ln(ATE(variant) / ATE(po-vins))` for every (scenario, seed) where both have an ATE.
fn paired_log_ratios(runs: &[RunResult], variant: Variant) -> Vec<f64> {
    runs.iter()
        .filter(|r| r.variant == variant)
        .filter_map(|r| {
            let a = r.ate_pos_rmse_m?;
            let b = runs
                .iter()
                .find(|p| {
                    p.variant == Variant::PoVins && p.scenario == r.scenario && p.seed == r.seed
                })?
                .ate_pos_rmse_m?;
            (a > 0.0 && b > 0.0).then(|| (a / b).ln())
        })
        .collect()
}

/// One simulated sequence and its base configuration, shared by the runs of its variants.
type Prepared = Arc<(Dataset, EstimatorConfig)>;

/// A (scenario, seed) pair: simulated by the first run that needs it, dropped after its last.
struct Pair {
    scenario: Scenario,
    seed: u64,
    data: Mutex<Option<Result<Prepared, String>>>,
    remaining: AtomicUsize,
}

impl Pair {
    fn prepared(
        &self,
        cfg: &AblationConfig,
        overrides: Option<&RunConfigFile>,
        progress: &Progress,
    ) -> Result<Prepared, String> {
        let mut slot = self.data.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(d) = slot.as_ref() {
            return d.clone();
        }
        progress.set_message(format!(
            "{} seed {}: simulating",
            self.scenario.name(),
            self.seed
        ));
        // One thread: the other workers keep estimating meanwhile (the output does not
        // depend on the thread count).
        let mut sim_cfg = SimConfig::new(self.scenario, self.seed, cfg.duration_s);
        sim_cfg.threads = 1;
        sim_cfg.lidar_extrinsic_error_deg = cfg.lidar_extrinsic_error_deg;
        sim_cfg.foliage_porosity = cfg.foliage_porosity;
        sim_cfg.lidar = cfg.lidar;
        let d = sim::simulate(&sim_cfg, &|_, _, _| {})
            .map_err(|e| format!("{e:#}"))
            .and_then(|s| {
                let ds = s.dataset;
                if ds.lidar.is_empty() {
                    return Err(format!(
                        "{}: the simulator produced no LiDAR sweeps",
                        ds.name
                    ));
                }
                let mut base = config_for(&ds);
                if let Some(f) = overrides {
                    f.apply(&mut base).map_err(|e| format!("{e:#}"))?;
                }
                Ok(Arc::new((ds, base)))
            });
        *slot = Some(d.clone());
        d
    }

    /// Called after each run of this pair: the last one frees the sequence.
    fn release(&self) {
        if self.remaining.fetch_sub(1, Ordering::AcqRel) == 1 {
            self.data.lock().unwrap_or_else(|e| e.into_inner()).take();
        }
    }
}

/// Runs the whole ablation. `overrides` (a `--config` file) is applied to every variant before
/// the variant's LiDAR switches.
///
/// The runs are units of one queue (pair-major) pulled by `jobs` workers, so the workers stay
/// busy across pairs and every run shares the machine alike; within a pair the variant order
/// rotates with the pair index so no variant is always the one overlapping a simulation.
/// Results are stored by (pair, variant): the report does not depend on `jobs` (timings aside).
pub fn run_ablation(
    cfg: &AblationConfig,
    overrides: Option<&RunConfigFile>,
    progress: &Progress,
) -> Result<AblationReport> {
    ensure!(!cfg.scenarios.is_empty(), "no scenario given");
    ensure!(!cfg.seeds.is_empty(), "no seed given");
    ensure!(cfg.jobs >= 1, "--jobs must be at least 1");
    for (i, sc) in cfg.scenarios.iter().enumerate() {
        ensure!(
            !cfg.scenarios[..i].contains(sc),
            "scenario {} given twice",
            sc.name()
        );
    }
    for (i, s) in cfg.seeds.iter().enumerate() {
        ensure!(!cfg.seeds[..i].contains(s), "seed {s} given twice");
    }
    let nv = Variant::ALL.len();
    let pairs: Vec<Pair> = cfg
        .scenarios
        .iter()
        .flat_map(|&scenario| {
            cfg.seeds.iter().map(move |&seed| Pair {
                scenario,
                seed,
                data: Mutex::new(None),
                remaining: AtomicUsize::new(nv),
            })
        })
        .collect();
    let units = pairs.len() * nv;
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let mut slots: Vec<Option<Result<RunResult>>> = (0..units).map(|_| None).collect();
    std::thread::scope(|sc| -> Result<()> {
        let mut workers = Vec::new();
        for _ in 0..cfg.jobs.min(units) {
            let (pairs, next, failed) = (&pairs, &next, &failed);
            let h = std::thread::Builder::new().spawn_scoped(sc, move || {
                let mut done = Vec::new();
                while !failed.load(Ordering::Relaxed) {
                    let u = next.fetch_add(1, Ordering::Relaxed);
                    let Some(pair) = pairs.get(u / nv) else { break };
                    let vi = (u % nv + u / nv) % nv;
                    let v = Variant::ALL[vi];
                    let r = pair
                        .prepared(cfg, overrides, progress)
                        .map_err(|e| anyhow!(e))
                        .and_then(|d| run_one(&d.0, &d.1, pair.scenario, pair.seed, v))
                        .map_err(|e| {
                            e.context(format!(
                                "{} seed {} {}",
                                pair.scenario.name(),
                                pair.seed,
                                v.name()
                            ))
                        });
                    pair.release();
                    match &r {
                        Ok(r) => progress.note(&format!(
                            "{} seed {} {:<12} ATE {} m, {} keyframes, back end median {:.2} ms",
                            r.scenario,
                            r.seed,
                            v.name(),
                            r.ate_pos_rmse_m
                                .map_or("n/a".to_string(), |a| format!("{a:.4}")),
                            r.keyframes,
                            r.backend_ms_median
                        )),
                        Err(_) => failed.store(true, Ordering::Relaxed),
                    }
                    progress.inc(1);
                    done.push((u / nv * nv + vi, r));
                }
                done
            })?;
            workers.push(h);
        }
        for h in workers {
            let done = h
                .join()
                .map_err(|_| anyhow!("an ablation worker panicked"))?;
            for (k, r) in done {
                if let Some(s) = slots.get_mut(k) {
                    *s = Some(r);
                }
            }
        }
        Ok(())
    })?;
    progress.finish();
    let mut runs = Vec::with_capacity(units);
    for r in slots.into_iter().flatten() {
        runs.push(r?);
    }
    ensure!(
        runs.len() == units,
        "only {} of {units} runs finished",
        runs.len()
    );
    Ok(AblationReport {
        scenarios: cfg.scenarios.iter().map(|s| s.name().to_string()).collect(),
        seeds: cfg.seeds.clone(),
        duration_s: cfg.duration_s,
        jobs: cfg.jobs,
        lidar_extrinsic_error_deg: cfg.lidar_extrinsic_error_deg,
        foliage_porosity: cfg.foliage_porosity,
        lidar: lidar_name(cfg.lidar),
        rows: aggregate(&cfg.scenarios, &runs),
        runs,
    })
}

/// The LiDAR model's name as `povins simulate --lidar` takes it (`default` for `None`).
fn lidar_name(kind: Option<LidarKind>) -> String {
    use clap::ValueEnum;
    kind.and_then(|k| k.to_possible_value())
        .map_or_else(|| "default".into(), |v| v.get_name().to_string())
}

/// Runs in the whole ablation (for a progress bar).
pub fn run_count(cfg: &AblationConfig) -> usize {
    cfg.scenarios.len() * cfg.seeds.len() * Variant::ALL.len()
}

fn num(x: Option<f64>, digits: usize) -> String {
    x.map_or("n/a".to_string(), |v| format!("{v:.digits$}"))
}

fn pct(x: Option<f64>) -> String {
    x.map_or("n/a".to_string(), |v| format!("{:.1}%", 100.0 * v))
}

/// The report as Markdown: the variant table, then every run.
pub fn render_markdown(r: &AblationReport) -> String {
    let mut s = String::new();
    let seeds: Vec<String> = r.seeds.iter().map(u64::to_string).collect();
    let _ = writeln!(
        s,
        "# LiDAR ablation (simulated: {}; LiDAR {}; seeds {}; {} s each; camera-LiDAR rotation \
         error {} deg; foliage porosity {}; ground-truth init; {} job{})\n",
        r.scenarios.join(", "),
        r.lidar,
        seeds.join(", "),
        r.duration_s,
        r.lidar_extrinsic_error_deg,
        r.foliage_porosity,
        r.jobs,
        if r.jobs == 1 { "" } else { "s" }
    );
    let mut head = "| variant |".to_string();
    let mut rule = "|---|".to_string();
    for sc in &r.scenarios {
        let _ = write!(head, " {sc} ATE (m) |");
        rule.push_str("---:|");
    }
    head.push_str(
        " mean ATE (m) | vs po-vins | paired (± se) | po-vins better | back end (ms) | rejection (ms) | depth-opt (ms) | depths/kf | LDM/kf | within 3σ before | within 3σ after | edge before | edge after |",
    );
    rule.push_str("---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let _ = writeln!(s, "{head}\n{rule}");
    for row in &r.rows {
        let _ = write!(s, "| {} |", row.variant.name());
        for a in &row.ate {
            let partial = if a.evaluated < a.runs {
                format!(" ({}/{})", a.evaluated, a.runs)
            } else {
                String::new()
            };
            let _ = write!(s, " {}{partial} |", num(a.ate_mean_m, 3));
        }
        let change = row
            .ate_change_vs_po_vins_pct
            .map_or("n/a".to_string(), |c| format!("{c:+.1}%"));
        let paired = match (row.paired_change_pct, row.paired_se_pct) {
            _ if row.variant == Variant::PoVins => "reference".to_string(),
            (Some(c), Some(se)) => format!("{c:+.1}% ± {se:.1}"),
            (Some(c), None) => format!("{c:+.1}%"),
            _ => "n/a".to_string(),
        };
        let better = if row.variant == Variant::PoVins {
            "n/a".to_string()
        } else {
            format!("{}/{}", row.po_vins_better.0, row.po_vins_better.1)
        };
        let _ = writeln!(
            s,
            " {} | {change} | {paired} | {better} | {:.2} | {:.3} | {:.3} | {:.1} | {:.1} | {} | {} | {} | {} |",
            num(row.ate_mean_m, 3),
            row.backend_ms_median,
            row.rejection_ms_median,
            row.depth_opt_ms_median,
            row.depths_associated_per_kf,
            row.ldm_per_kf,
            pct(row.assoc_within_3sigma_before),
            pct(row.assoc_within_3sigma_after),
            pct(row.edge_share_before),
            pct(row.edge_share_after),
        );
    }
    s.push_str(
        "\nATE: IMU-rate position RMSE after position + yaw alignment, mean over seeds; the mean \
         ATE is the mean of the scenario means; paired: geometric mean over the (scenario, seed) \
         pairs of ATE / ATE(po-vins), with the standard error of its log, and the pairs where \
         po-vins is better. Times: median over every keyframe of every run (each run's thread CPU \
         time). \
         Association quality: share of associated LiDAR depths within 3 sigma_dr of the true \
         depth (simulator truth), before and after the uncertainty-based rejection; edge: share \
         of them on occlusion-edge features.\n\n## Runs\n\n\
         | scenario | seed | variant | keyframes | ATE (m) | back end (ms) | depths assoc. | rejected | LDM | sweeps |\n\
         |---|---:|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for run in &r.runs {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {:.2} | {} | {} | {} | {} |",
            run.scenario,
            run.seed,
            run.variant.name(),
            run.keyframes,
            num(run.ate_pos_rmse_m, 4),
            run.backend_ms_median,
            run.depths_associated,
            run.depths_rejected,
            run.ldm_total,
            run.lidar_scans_pushed
        );
    }
    s
}

#[cfg(test)]
#[path = "ablation_tests.rs"]
mod tests;
