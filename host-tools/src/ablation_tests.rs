//! Unit tests of `ablation`, compiled only with `#[cfg(test)]` (the parent declares the module so).

use super::*;

fn run(scenario: &str, variant: Variant, ate: Option<f64>, backend: &[f64]) -> RunResult {
    RunResult {
        scenario: scenario.to_string(),
        seed: 1,
        variant,
        keyframes: 10,
        ate_pos_rmse_m: ate,
        backend_ms_median: 0.0,
        association_ms_median: 0.0,
        rejection_ms_median: 0.0,
        depth_opt_ms_median: 0.0,
        depths_associated: 30,
        depths_rejected: 3,
        ldm_total: 20,
        lidar_scans_pushed: 5,
        assoc: Some(AssocQuality {
            associated: 30,
            checked: 30,
            within_before: 24,
            kept: 27,
            within_after: 24,
            edge_before: 3,
            edge_after: 0,
        }),
        timings: Timings {
            backend_ms: backend.to_vec(),
            ..Default::default()
        },
    }
}

#[test]
fn variants_set_exactly_their_switch() {
    let mut l = LidarConfig {
        enabled: false,
        ldm: LdmMode::Direct,
        depth_outlier_rejection: false,
        depth_only_opt: false,
        ..Default::default()
    };
    Variant::PoVins.apply(&mut l);
    assert!(l.enabled && l.depth_outlier_rejection && l.depth_only_opt);
    assert_eq!(l.ldm, LdmMode::Msc);
    let flags = |v: Variant| {
        let mut l = LidarConfig::default();
        v.apply(&mut l);
        (
            l.enabled,
            l.ldm == LdmMode::Msc,
            l.depth_outlier_rejection,
            l.depth_only_opt,
        )
    };
    assert_eq!(flags(Variant::PoVinsWo), (false, true, true, true));
    assert_eq!(flags(Variant::NoRejection), (true, true, false, true));
    assert_eq!(flags(Variant::DirectLdm), (true, false, true, true));
    assert_eq!(flags(Variant::NoDepthOpt), (true, true, true, false));
}

#[test]
fn paired_change_pairs_runs_by_scenario_and_seed() {
    let with_seed = |mut r: RunResult, seed: u64| {
        r.seed = seed;
        r
    };
    let runs = vec![
        with_seed(run("robot", Variant::PoVins, Some(0.1), &[1.0]), 1),
        with_seed(run("robot", Variant::PoVins, Some(0.2), &[1.0]), 2),
        with_seed(run("vehicle", Variant::PoVins, None, &[1.0]), 1),
        // Twice as bad on seed 1, half on seed 2 (where a mean of ATEs would say +25%).
        with_seed(run("robot", Variant::NoRejection, Some(0.2), &[1.0]), 1),
        with_seed(run("robot", Variant::NoRejection, Some(0.1), &[1.0]), 2),
        // No po-vins ATE to pair with: left out.
        with_seed(run("vehicle", Variant::NoRejection, Some(5.0), &[1.0]), 1),
    ];
    let rows = aggregate(&[Scenario::Robot, Scenario::Vehicle], &runs);
    let nr = &rows[2];
    assert_eq!(nr.variant, Variant::NoRejection);
    assert_eq!(nr.po_vins_better, (1, 2));
    assert!(nr.paired_change_pct.unwrap().abs() < 1e-9);
    // Logs +-ln 2: sample sd ln2 * sqrt(2), standard error ln 2.
    assert!((nr.paired_se_pct.unwrap() - 100.0 * 2f64.ln()).abs() < 1e-9);
    let po = &rows[0];
    assert_eq!(po.po_vins_better, (0, 2));
    assert!(po.paired_change_pct.unwrap().abs() < 1e-12);
    // A variant with no runs has nothing to pair.
    assert_eq!(rows[1].po_vins_better, (0, 0));
    assert_eq!(rows[1].paired_change_pct, None);
}

#[test]
fn aggregation_means_scenarios_and_pools_keyframes() {
    let scenarios = [Scenario::Robot, Scenario::Vehicle];
    let mut runs = Vec::new();
    for v in Variant::ALL {
        let k = if v == Variant::PoVins { 1.0 } else { 2.0 };
        runs.push(run("robot", v, Some(0.1 * k), &[1.0, 5.0]));
        runs.push(run("robot", v, Some(0.3 * k), &[2.0]));
        // One vehicle seed failed to evaluate.
        runs.push(run("vehicle", v, Some(1.0 * k), &[3.0]));
        runs.push(run("vehicle", v, None, &[4.0]));
    }
    let rows = aggregate(&scenarios, &runs);
    assert_eq!(rows.len(), 5);
    let po = &rows[0];
    assert_eq!(po.variant, Variant::PoVins);
    assert!((po.ate[0].ate_mean_m.unwrap() - 0.2).abs() < 1e-12);
    assert_eq!((po.ate[1].runs, po.ate[1].evaluated), (4 / 2, 1));
    assert!((po.ate[1].ate_mean_m.unwrap() - 1.0).abs() < 1e-12);
    // Mean of the scenario means, not of the runs.
    assert!((po.ate_mean_m.unwrap() - 0.6).abs() < 1e-12);
    assert!(po.ate_change_vs_po_vins_pct.unwrap().abs() < 1e-9);
    assert!((rows[1].ate_change_vs_po_vins_pct.unwrap() - 100.0).abs() < 1e-9);
    // Pooled median of {1, 5, 2, 3, 4}.
    assert_eq!(po.backend_ms_median, 3.0);
    assert!((po.ldm_per_kf - 2.0).abs() < 1e-12);
    assert!((po.depths_associated_per_kf - 3.0).abs() < 1e-12);
    assert_eq!(po.assoc_checked, 120);
    assert_eq!(po.assoc_within_3sigma_before, Some(0.8));
    assert_eq!(po.edge_share_after, Some(0.0));
    let md = render_markdown(&AblationReport {
        scenarios: vec!["robot".into(), "vehicle".into()],
        seeds: vec![1, 2],
        duration_s: 8.0,
        lidar_extrinsic_error_deg: 0.5,
        foliage_porosity: 0.0,
        lidar: "default".into(),
        jobs: 2,
        rows,
        runs,
    });
    assert!(
        md.contains("| po-vins | 0.200 | 1.000 (1/2) | 0.600 | +0.0% |"),
        "{md}"
    );
    assert!(
        md.contains("| po-vins-wo | 0.400 | 2.000 (1/2) | 1.200 | +100.0% |"),
        "{md}"
    );
}
