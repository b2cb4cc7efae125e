//! Reports and plots of a run: CSV columns and values, θ bins, summary
//! statistics, plot files, the on/off comparison — on synthetic records with
//! known values.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Point3};
use serde_json::Value;
use soundmap_sim::SimError;
use soundmap_sim::report::{
    PLOT_STEMS, RobotPath, RoomOutline, RunRecord, SmoothedRow, SourceTruth, TimelineRow,
    format_comparison_table, format_summary_table, write_comparison, write_reports,
};

const TOL: f64 = 1e-6;

/// A fresh output directory for one test.
fn out_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report-tests").join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A row at `t_s` with true θ `theta_deg` (published θ 1° above it) and an
/// estimate `rse_m` metres from the truth along x.
fn row(t_s: f64, theta_deg: f64, rse_m: f64) -> TimelineRow {
    let truth = Point3::new(2.0, 1.0, 1.2);
    TimelineRow {
        t_s,
        distances_m: vec![1.5, 2.5],
        theta_deg: theta_deg + 1.0,
        true_theta_deg: Some(theta_deg),
        gdop: 1.5,
        estimate_in_map: Some(truth + nalgebra::Vector3::new(rse_m, 0.0, 0.0)),
        triangulation_in_map: None,
        trusted: true,
        method: "ray_pair".into(),
        robots: vec!["r1".into(), "r2".into()],
        truth_in_map: Some(truth),
        covariance: None,
        source_id: 1,
        truth_source: Some(0),
        smoothed: None,
    }
}

fn record(rows: Vec<TimelineRow>, duration_s: f64) -> RunRecord {
    RunRecord {
        name: "synthetic".into(),
        duration_s,
        active_positioning: false,
        theta_band_deg: (40.0, 140.0),
        rows,
        robot_ids: vec!["r1".into(), "r2".into()],
        robots: vec![
            RobotPath {
                id: "r1".into(),
                samples: vec![(0.0, 0.5, 0.5, 0.0), (5.0, 1.0, 0.5, 0.3)],
                goals: vec![(1.0, 1.0, 0.5)],
            },
            RobotPath {
                id: "r2".into(),
                samples: vec![(0.0, 3.5, 0.5, 3.0), (5.0, 3.5, 1.5, 3.0)],
                goals: vec![],
            },
        ],
        sources: vec![SourceTruth::always(vec![
            (0.0, Point3::new(2.0, 1.0, 1.2)),
            (5.0, Point3::new(2.0, 2.0, 1.2)),
        ])],
        room: Some(RoomOutline {
            floor: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]],
            obstacles: vec![vec![[1.5, 2.0], [2.5, 2.0], [2.5, 2.5], [1.5, 2.5]]],
        }),
        seed: Some(7),
        commands: vec![],
    }
}

/// Parsed CSV: header and rows of cells (no quoted commas in these records).
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let rows: Vec<Vec<String>> = lines.map(|l| l.split(',').map(String::from).collect()).collect();
    for r in &rows {
        assert_eq!(r.len(), header.len(), "ragged row {r:?}");
    }
    (header, rows)
}

/// Cells of one CSV row by column name.
fn by_name<'a>(header: &'a [String], row: &'a [String]) -> HashMap<&'a str, &'a str> {
    header.iter().map(String::as_str).zip(row.iter().map(String::as_str)).collect()
}

fn num(cell: &str) -> f64 {
    cell.parse().unwrap_or_else(|_| panic!("not a number: {cell:?}"))
}

fn summary_json(dir: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

fn close(v: &Value, expected: f64) -> bool {
    v.as_f64().is_some_and(|x| (x - expected).abs() < TOL)
}

#[test]
fn timeline_has_the_columns_and_values_of_the_rows() {
    let mut rows = vec![row(0.0, 30.0, 0.1), row(0.5, 90.0, 0.2), row(1.0, 100.0, 0.0)];
    rows[1].gdop = f64::INFINITY;
    rows[1].triangulation_in_map = Some(Point3::new(2.0, 1.3, 1.2));
    rows[1].method = "kalman_filter".into();
    rows[1].trusted = false;
    rows[2].estimate_in_map = None;
    // A smoothed state 1 s behind the second row, 0.05 m from its truth.
    rows[1].smoothed = Some(SmoothedRow {
        t_s: -0.5,
        estimate_in_map: Point3::new(2.05, 1.0, 1.2),
        covariance: Some(Matrix3::identity() * 0.01),
        truth_in_map: Some(Point3::new(2.0, 1.0, 1.2)),
        true_theta_deg: Some(90.0),
        trusted: true,
    });
    let dir = out_dir("timeline");
    write_reports(&record(rows, 2.0), &dir).unwrap();

    let (header, cells) = read_csv(&dir.join("timeline.csv"));
    let expected = "t_s,d1_m,d2_m,theta_deg,gdop,est_x_m,est_y_m,est_z_m,truth_x_m,truth_y_m,truth_z_m,rse_m,\
                    true_theta_deg,theta_in_band,trusted,method,robots,tri_x_m,tri_y_m,tri_z_m,tri_rse_m,nees,\
                    source_id,truth_source,smooth_t_s,smooth_x_m,smooth_y_m,smooth_z_m,smooth_rse_m,smooth_nees,\
                    smooth_trusted";
    assert_eq!(header.join(","), expected);
    assert_eq!(cells.len(), 3);

    let r0 = by_name(&header, &cells[0]);
    assert!((num(r0["t_s"]) - 0.0).abs() < TOL);
    assert!((num(r0["d1_m"]) - 1.5).abs() < TOL && (num(r0["d2_m"]) - 2.5).abs() < TOL);
    assert!((num(r0["theta_deg"]) - 31.0).abs() < TOL);
    assert!((num(r0["true_theta_deg"]) - 30.0).abs() < TOL);
    assert!((num(r0["est_x_m"]) - 2.1).abs() < TOL && (num(r0["truth_z_m"]) - 1.2).abs() < TOL);
    assert!((num(r0["rse_m"]) - 0.1).abs() < TOL);
    assert_eq!(
        (r0["theta_in_band"], r0["trusted"], r0["method"], r0["robots"]),
        ("false", "true", "ray_pair", "r1;r2")
    );
    assert_eq!((r0["tri_x_m"], r0["tri_rse_m"]), ("", ""));
    assert_eq!((r0["smooth_t_s"], r0["smooth_rse_m"], r0["smooth_trusted"]), ("", "", ""));
    let r1 = by_name(&header, &cells[1]);
    assert!((num(r1["smooth_t_s"]) + 0.5).abs() < TOL && (num(r1["smooth_x_m"]) - 2.05).abs() < TOL);
    assert!((num(r1["smooth_rse_m"]) - 0.05).abs() < TOL);
    assert!((num(r1["smooth_nees"]) - 0.25).abs() < TOL, "0.05² / 0.01");
    assert_eq!(r1["smooth_trusted"], "true");
    let summary = summary_json(&dir);
    assert_eq!(summary["smoothed"]["states"], 1);
    assert!(close(&summary["smoothed"]["rse_p95_in_band_m"], 0.05));

    let r1 = by_name(&header, &cells[1]);
    assert_eq!(r1["gdop"], "inf");
    assert!(num(r1["gdop"]).is_infinite());
    assert_eq!((r1["theta_in_band"], r1["trusted"], r1["method"]), ("true", "false", "kalman_filter"));
    assert!((num(r1["tri_y_m"]) - 1.3).abs() < TOL && (num(r1["tri_rse_m"]) - 0.3).abs() < TOL);

    let r2 = by_name(&header, &cells[2]);
    for col in ["est_x_m", "est_y_m", "est_z_m", "rse_m"] {
        assert_eq!(r2[col], "", "{col} of a row without estimate position");
    }
    assert!((num(r2["truth_x_m"]) - 2.0).abs() < TOL);
}

#[test]
fn three_robots_get_a_d3_column() {
    let mut rows = vec![row(0.0, 60.0, 0.1), row(1.0, 60.0, 0.1)];
    rows.iter_mut().for_each(|r| r.distances_m.push(3.25));
    let mut rec = record(rows, 2.0);
    rec.robot_ids.push("r3".into());
    rec.robots.push(RobotPath {
        id: "r3".into(),
        samples: vec![(0.0, 2.0, 2.8, 0.0)],
        goals: vec![(0.5, 2.0, 2.5)],
    });
    let dir = out_dir("three_robots");
    write_reports(&rec, &dir).unwrap();
    let (header, cells) = read_csv(&dir.join("timeline.csv"));
    assert_eq!(&header[..5], ["t_s", "d1_m", "d2_m", "d3_m", "theta_deg"]);
    assert!((num(by_name(&header, &cells[1])["d3_m"]) - 3.25).abs() < TOL);
}

#[test]
fn a_record_without_truth_has_empty_rse_and_null_statistics() {
    let rows: Vec<TimelineRow> = [(0.0, 20.0), (0.5, 70.0), (1.0, 72.0)]
        .into_iter()
        .map(|(t, theta)| TimelineRow {
            distances_m: vec![],
            true_theta_deg: None,
            truth_in_map: None,
            covariance: None,
            truth_source: None,
            ..row(t, theta - 1.0, 0.0)
        })
        .collect();
    let mut rec = record(rows, 1.5);
    rec.sources.clear();
    rec.room = None;
    rec.robots.clear();
    rec.seed = None;
    let dir = out_dir("no_truth");
    let summary = write_reports(&rec, &dir).unwrap();

    let (header, cells) = read_csv(&dir.join("timeline.csv"));
    assert!(header.contains(&"rse_m".to_string()), "the RSE columns stay, empty");
    for c in &cells {
        let r = by_name(&header, c);
        for col in ["d1_m", "d2_m", "truth_x_m", "truth_y_m", "truth_z_m", "rse_m", "true_theta_deg"] {
            assert_eq!(r[col], "", "{col}");
        }
        assert_ne!(r["est_x_m"], "");
    }

    let json = summary_json(&dir);
    for key in [
        "rse_median_m",
        "rse_p95_m",
        "rse_p95_in_band_m",
        "rse_mean_m",
        "rse_p95_after_convergence_m",
        "seed",
    ] {
        assert!(json[key].is_null(), "{key} = {}", json[key]);
    }
    assert_eq!(json["theta_source"], "published");
    assert_eq!(json["estimates"], 3);
    assert_eq!(json["estimates_with_position"], 3);
    assert_eq!(json["estimates_with_rse"], 0);
    // Published θ: 20 (out), 70, 72 (in) → time to band 0.5 s.
    assert!(close(&json["time_to_band_s"], 0.5));
    assert_eq!(summary.estimates_in_band, 2);

    let (bh, bins) = read_csv(&dir.join("theta_bins.csv"));
    let b1 = by_name(&bh, &bins[1]);
    assert_eq!(
        (b1["theta_source"], b1["estimates"], b1["rse_count"], b1["rse_mean_m"]),
        ("published", "1", "0", "")
    );
    assert_eq!(by_name(&bh, &bins[4])["estimates"], "2");
}

#[test]
fn theta_bins_match_a_hand_computation() {
    // (true θ, RSE): bin 0 gets 0.1 and 0.3; bin 3 gets 1.0; θ = 180 goes to the last bin.
    let mut rows = vec![row(0.0, 10.0, 0.1), row(0.5, 14.0, 0.3), row(1.0, 50.0, 1.0), row(1.5, 180.0, 0.4)];
    // The published θ (true + 1°) of row 1 would fall in bin 1: the true θ must be used.
    rows[0].triangulation_in_map = Some(Point3::new(2.0, 1.0, 1.7));
    rows[1].triangulation_in_map = Some(Point3::new(2.0, 1.0, 1.9));
    let dir = out_dir("bins");
    write_reports(&record(rows, 2.0), &dir).unwrap();
    let (header, bins) = read_csv(&dir.join("theta_bins.csv"));
    assert_eq!(
        header.join(","),
        "theta_lo_deg,theta_hi_deg,theta_mid_deg,theta_source,estimates,rse_count,rse_mean_m,rse_std_m,\
         tri_rse_count,tri_rse_mean_m,tri_rse_std_m"
    );
    assert_eq!(bins.len(), 12);
    for (i, b) in bins.iter().enumerate() {
        let b = by_name(&header, b);
        assert!((num(b["theta_lo_deg"]) - 15.0 * i as f64).abs() < TOL);
        assert!((num(b["theta_hi_deg"]) - 15.0 * (i + 1) as f64).abs() < TOL);
        assert_eq!(b["theta_source"], "true");
    }
    let b0 = by_name(&header, &bins[0]);
    assert_eq!((b0["estimates"], b0["rse_count"]), ("2", "2"));
    assert!((num(b0["rse_mean_m"]) - 0.2).abs() < TOL);
    assert!((num(b0["rse_std_m"]) - 0.02f64.sqrt()).abs() < TOL, "sample std of 0.1, 0.3");
    assert_eq!(b0["tri_rse_count"], "2");
    assert!((num(b0["tri_rse_mean_m"]) - 0.6).abs() < TOL);
    assert!((num(b0["tri_rse_std_m"]) - 0.02f64.sqrt()).abs() < TOL);
    let b3 = by_name(&header, &bins[3]);
    assert_eq!(
        (b3["rse_count"], b3["rse_std_m"], b3["tri_rse_count"], b3["tri_rse_mean_m"]),
        ("1", "", "0", "")
    );
    assert!((num(b3["rse_mean_m"]) - 1.0).abs() < TOL);
    let b11 = by_name(&header, &bins[11]);
    assert!((num(b11["rse_mean_m"]) - 0.4).abs() < TOL);
    assert_eq!(by_name(&header, &bins[1])["estimates"], "0");
}

#[test]
fn summary_statistics_on_known_data() {
    // RSE 0.1, 0.2, … 2.0 at 10 Hz; the first 10 rows in band, the last 10 out.
    let rows: Vec<TimelineRow> =
        (1..=20).map(|k| row(0.1 * k as f64, if k <= 10 { 90.0 } else { 20.0 }, 0.1 * k as f64)).collect();
    let dir = out_dir("summary");
    let summary = write_reports(&record(rows, 2.1), &dir).unwrap();
    let json = summary_json(&dir);
    // Sorted x[0..20] = 0.1 … 2.0: median (x[9] + x[10]) / 2; p95 at h = 19·0.95 = 18.05.
    assert!(close(&json["rse_median_m"], 1.05));
    assert!(close(&json["rse_p95_m"], 1.9 + 0.05 * 0.1));
    assert!(close(&json["rse_mean_m"], 1.05));
    assert!(close(&json["rse_max_m"], 2.0));
    // In band 0.1 … 1.0: p95 at h = 9·0.95 = 8.55 → 0.9 + 0.55·0.1.
    assert!(close(&json["rse_p95_in_band_m"], 0.955));
    assert!(close(&json["rse_p95_out_of_band_m"], 1.955));
    assert!(close(&json["time_in_band_ratio"], 0.5));
    assert!(close(&json["time_to_band_s"], 0.1));
    assert!(close(&json["in_band_ratio_after_convergence"], 0.5));
    assert!(close(&json["trusted_ratio"], 1.0));
    assert_eq!(json["estimates_in_band"], 10);
    assert_eq!(json["estimates_out_of_band"], 10);
    assert_eq!(json["seed"], 7);
    assert_eq!(json["name"], "synthetic");
    assert_eq!(json["active_positioning"], false);
    assert!(json["triangulation"].is_null());
    assert!(close(&json["duration_s"], 2.1));
    assert_eq!(summary.rse_median_m, json["rse_median_m"].as_f64());

    let table = format_summary_table(&summary, &dir);
    for needle in ["RSE median", "1.050 m", "RSE p95, θ in band", "0.955 m", "time in band", "50.0 %", "map"]
    {
        assert!(table.contains(needle), "table lacks {needle:?}:\n{table}");
    }
}

#[test]
fn time_ratios_weigh_rows_by_capped_time_and_start_at_convergence() {
    // Out of band at 0 and 0.5 s; in band at 1, 2, 3 s; a 10 s gap; out of band at 13, 13.5 s.
    let thetas =
        [(0.0, 20.0), (0.5, 20.0), (1.0, 60.0), (2.0, 60.0), (3.0, 60.0), (13.0, 150.0), (13.5, 150.0)];
    let mut rows: Vec<TimelineRow> = thetas.iter().map(|(t, th)| row(*t, *th, 0.1)).collect();
    rows[0].trusted = false;
    rows[0].estimate_in_map = Some(Point3::new(7.0, 1.0, 1.2)); // RSE 5 m before convergence
    let dir = out_dir("time_weights");
    write_reports(&record(rows, 14.0), &dir).unwrap();
    let json = summary_json(&dir);
    // Weights: 0.5, 0.5, 1, 1, 1 (10 s gap capped), 0.5, 0.5 (to the end) → 5 s covered.
    assert!(close(&json["covered_time_s"], 5.0));
    assert!(close(&json["time_in_band_ratio"], 3.0 / 5.0));
    assert!(close(&json["time_to_band_s"], 1.0));
    assert!(close(&json["in_band_ratio_after_convergence"], 3.0 / 4.0));
    assert!(close(&json["rse_p95_after_convergence_m"], 0.1), "the 5 m error came before convergence");
    assert!(close(&json["rse_max_m"], 5.0));
    assert!(close(&json["rse_p95_trusted_m"], 0.1));
    assert!(close(&json["trusted_ratio"], 6.0 / 7.0));
    assert!(close(&json["rse_below_0_3_m_ratio"], 6.0 / 7.0));
}

#[test]
fn never_in_band_and_empty_records_give_nulls() {
    let dir = out_dir("never_in_band");
    write_reports(&record(vec![row(0.0, 10.0, 0.2), row(1.0, 170.0, 0.2)], 2.0), &dir).unwrap();
    let json = summary_json(&dir);
    for key in [
        "time_to_band_s",
        "in_band_ratio_after_convergence",
        "rse_p95_after_convergence_m",
        "rse_p95_in_band_m",
    ] {
        assert!(json[key].is_null(), "{key} = {}", json[key]);
    }
    assert!(close(&json["time_in_band_ratio"], 0.0));

    let dir = out_dir("empty");
    let summary = write_reports(&record(vec![], 0.0), &dir).unwrap();
    let json = summary_json(&dir);
    for key in
        ["rse_median_m", "rse_p95_m", "time_in_band_ratio", "trusted_ratio", "time_to_band_s", "rse_std_m"]
    {
        assert!(json[key].is_null(), "{key} = {}", json[key]);
    }
    assert_eq!(json["estimates"], 0);
    assert_eq!(json["theta_source"], "none");
    assert!(!std::fs::read_to_string(dir.join("summary.json")).unwrap().contains("NaN"));
    assert!(format_summary_table(&summary, &dir).contains("never"));
    assert_plots(&dir, &PLOT_STEMS);
}

/// Every plot is written as a non-empty SVG and a PNG of the figure's size.
fn assert_plots(dir: &Path, stems: &[&str]) {
    for stem in stems {
        let svg = std::fs::read_to_string(dir.join(format!("{stem}.svg"))).unwrap();
        assert!(svg.contains("<svg") && svg.contains("</svg>") && svg.contains("<text"), "{stem}.svg");
        let png = std::fs::read(dir.join(format!("{stem}.png"))).unwrap();
        assert!(png.len() > 2000, "{stem}.png is {} bytes", png.len());
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{stem}.png signature");
        assert_eq!(&png[12..16], b"IHDR");
        let w = u32::from_be_bytes(png[16..20].try_into().unwrap());
        let h = u32::from_be_bytes(png[20..24].try_into().unwrap());
        assert!((600..=2000).contains(&w) && (500..=1500).contains(&h), "{stem}.png is {w}×{h}");
    }
}

#[test]
fn every_plot_is_written_and_outliers_are_clipped() {
    let mut rows: Vec<TimelineRow> =
        (0..40).map(|k| row(0.25 * k as f64, 30.0 + 3.0 * k as f64, 0.05 * (k % 7) as f64)).collect();
    rows[20].estimate_in_map = Some(Point3::new(60.0, 1.0, 1.2)); // 58 m off: clipped, and outside the map
    let dir = out_dir("plots");
    write_reports(&record(rows, 10.0), &dir).unwrap();
    assert_plots(&dir, &PLOT_STEMS);
    let svg = std::fs::read_to_string(dir.join("distances_rse.svg")).unwrap();
    assert!(svg.contains("drawn at 5.0 m"), "the RSE axis says it is clipped");
    assert!(svg.contains("d1 (m), r1") && svg.contains("RSE (m), right axis"), "legend");
    let map = std::fs::read_to_string(dir.join("map.svg")).unwrap();
    assert!(map.contains("outside the map"), "the map says an estimate was drawn at its edge");
    assert!(map.contains("robot r2") && map.contains("x (m), map frame"));
    let theta = std::fs::read_to_string(dir.join("theta_rse.svg")).unwrap();
    assert!(theta.contains("θ band 40–140°"));
}

#[test]
fn comparison_writes_both_reports_side_by_side() {
    let passive = record((0..20).map(|k| row(0.5 * k as f64, 20.0, 1.0)).collect(), 10.0);
    let mut active =
        record((0..20).map(|k| row(0.5 * k as f64, if k < 4 { 20.0 } else { 90.0 }, 0.2)).collect(), 10.0);
    active.active_positioning = true;
    let dir = out_dir("comparison");
    let (on, off) = write_comparison(&active, &passive, &dir).unwrap();
    assert!(on.active_positioning && !off.active_positioning);
    for sub in ["active", "passive"] {
        for f in ["timeline.csv", "theta_bins.csv", "summary.json"] {
            assert!(dir.join(sub).join(f).is_file(), "{sub}/{f}");
        }
        assert_plots(&dir.join(sub), &PLOT_STEMS);
    }
    assert_plots(&dir, &["comparison_theta"]);
    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("comparison.json")).unwrap()).unwrap();
    assert_eq!(json["active"]["active_positioning"], true);
    assert_eq!(json["passive"]["active_positioning"], false);
    assert!(close(&json["active"]["time_to_band_s"], 2.0));
    assert!(json["passive"]["time_to_band_s"].is_null());
    assert!(close(&json["difference"]["rse_median_m"], 0.8));
    assert!(json["difference"]["time_to_band_s"].is_null());

    let table = format_comparison_table(&on, &off, &dir);
    assert!(
        table.contains("active")
            && table.contains("passive")
            && table.contains("2.0 s")
            && table.contains("never")
    );

    let swapped = write_comparison(&passive, &active, &out_dir("comparison_swapped"));
    assert!(
        matches!(swapped, Err(SimError::InvalidConfig { field: "active_positioning", .. })),
        "{swapped:?}"
    );
}

#[test]
fn records_the_reports_would_misread_are_rejected() {
    let unsorted = record(vec![row(1.0, 60.0, 0.1), row(0.5, 60.0, 0.1)], 2.0);
    let err = write_reports(&unsorted, &out_dir("unsorted")).unwrap_err();
    assert!(matches!(err, SimError::InvalidConfig { field: "rows.t_s", .. }), "{err}");
    let mut band = record(vec![row(0.0, 60.0, 0.1)], 1.0);
    band.theta_band_deg = (140.0, 40.0);
    assert!(matches!(write_reports(&band, &out_dir("band")), Err(SimError::InvalidConfig { .. })));
}

/// A run shaped like a real one: two robots driving, a source moving on a
/// circle, θ from the true geometry, errors that grow as sin θ shrinks, a
/// filtered estimate with the triangulation beside it.
fn realistic_run(active: bool) -> RunRecord {
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut noise = move || {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let duration_s = 60.0;
    let robot_at = |k: usize, t: f64| -> (f64, f64) {
        let u = (t / duration_s).min(1.0);
        match (k, active) {
            (0, _) => (0.8 + 1.5 * u, 0.8),
            (_, true) => {
                let v = (t / 20.0).min(1.0);
                (1.6 + 3.6 * v, 0.6 + 2.2 * v)
            }
            (_, false) => (1.6 + 0.4 * u, 0.6),
        }
    };
    let source_at = |t: f64| Point3::new(3.0 + 1.0 * (0.1 * t).cos(), 2.8 + 0.8 * (0.1 * t).sin(), 1.2);
    let mut rows = Vec::new();
    let mut t = 0.0;
    while t < duration_s {
        if !(30.0..33.0).contains(&t) {
            let s = source_at(t);
            let arrays: Vec<Point3<f64>> =
                (0..2).map(|k| robot_at(k, t)).map(|(x, y)| Point3::new(x, y, 0.6)).collect();
            let (a, b) = (arrays[0] - s, arrays[1] - s);
            let theta = a.angle(&b).to_degrees();
            let spread = 0.05 / theta.to_radians().sin().max(0.05);
            let tri = s + nalgebra::Vector3::new(noise(), noise(), 0.5 * noise()) * spread * 2.0;
            let est = s + nalgebra::Vector3::new(noise(), noise(), 0.5 * noise()) * spread;
            rows.push(TimelineRow {
                t_s: t,
                distances_m: vec![a.norm(), b.norm()],
                theta_deg: theta + noise(),
                true_theta_deg: Some(theta),
                gdop: 1.0 / theta.to_radians().sin().max(1e-3),
                estimate_in_map: Some(est),
                triangulation_in_map: Some(tri),
                trusted: spread < 0.2,
                method: "kalman_filter".into(),
                robots: vec!["r1".into(), "r2".into()],
                truth_in_map: Some(s),
                covariance: None,
                source_id: 1,
                truth_source: Some(0),
                smoothed: None,
            });
        }
        t += 0.1;
    }
    let robots = (0..2)
        .map(|k| RobotPath {
            id: format!("r{}", k + 1),
            samples: (0..=60).map(f64::from).map(|t| (t, robot_at(k, t).0, robot_at(k, t).1, 0.0)).collect(),
            goals: if active && k == 1 { vec![(0.5, 5.2, 2.8)] } else { vec![] },
        })
        .collect();
    RunRecord {
        name: "realistic".into(),
        duration_s,
        active_positioning: active,
        theta_band_deg: (40.0, 140.0),
        rows,
        robot_ids: vec!["r1".into(), "r2".into()],
        robots,
        sources: vec![SourceTruth::always(
            (0..=600).map(|i| f64::from(i) * 0.1).map(|t| (t, source_at(t))).collect(),
        )],
        room: Some(RoomOutline {
            floor: vec![[0.0, 0.0], [6.0, 0.0], [6.0, 5.0], [2.0, 5.0], [0.0, 3.5]],
            obstacles: vec![vec![[0.6, 4.0], [1.4, 4.0], [1.2, 3.2]]],
        }),
        seed: Some(42),
        commands: vec![],
    }
}

#[test]
fn a_realistic_comparison_renders_and_favours_the_band() {
    let dir = out_dir("realistic");
    let (on, off) = write_comparison(&realistic_run(true), &realistic_run(false), &dir).unwrap();
    for s in [&on, &off] {
        let (inside, outside) = (s.rse_p95_in_band_m, s.rse_p95_out_of_band_m);
        if let (Some(i), Some(o)) = (inside, outside) {
            assert!(i < o, "errors grow out of the band by construction: {i} vs {o}");
        }
        let tri = s.triangulation.as_ref().expect("the rows have triangulations");
        assert!(tri.rse_median_m > s.rse_median_m, "the triangulation is twice as noisy");
    }
    assert!(
        on.time_in_band_ratio > off.time_in_band_ratio,
        "{:?} vs {:?}",
        on.time_in_band_ratio,
        off.time_in_band_ratio
    );
    assert!(on.time_to_band_s.is_some_and(|t| t > 0.0 && t < 20.0), "{:?}", on.time_to_band_s);
    let table = format_comparison_table(&on, &off, &dir);
    println!("{table}");
    assert!(table.contains("triangulation RSE p95"), "{table}");
}

#[test]
fn commands_csv_quotes_details_and_keeps_order() {
    let mut rec = record(vec![], 10.0);
    rec.commands = vec![
        (1.25, "r1".into(), "theta 12.0° out of band, goal (1.0, 2.0)".into()),
        (3.5, "r2".into(), "ideal spot is blocked: \"pillar\"".into()),
    ];
    let text = soundmap_sim::report::commands_csv(&rec);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "t_s,robot,detail");
    assert_eq!(lines[1], "1.250,r1,\"theta 12.0° out of band, goal (1.0, 2.0)\"");
    assert_eq!(lines[2], "3.500,r2,\"ideal spot is blocked: \"\"pillar\"\"\"");
    assert_eq!(lines.len(), 3);
}

#[test]
fn goals_csv_lists_goals_in_time_order_with_their_true_range() {
    let mut rec = record(vec![], 10.0);
    rec.robots[1].goals = vec![(0.5, 2.0, 1.0), (4.0, 2.0, 2.5)];
    let text = soundmap_sim::report::goals_csv(&rec);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "t_s,robot,x_m,y_m,true_range_m");
    // r2's goal at 0.5 s lies on the source (then at (2, 1.1)): 0.1 m away.
    assert_eq!(lines[1], "0.500,r2,2.000,1.000,0.100");
    // r1's at 1 s: (1, 0.5) against the source at (2, 1.2).
    assert_eq!(lines[2], format!("1.000,r1,1.000,0.500,{:.3}", 1.0f64.hypot(0.7)));
    assert_eq!(lines[3], "4.000,r2,2.000,2.500,0.700");
    assert_eq!(lines.len(), 4);
    // Without a known source the range is left empty.
    rec.sources.clear();
    assert!(soundmap_sim::report::goals_csv(&rec).lines().nth(1).unwrap().ends_with("0.500,r2,2.000,1.000,"));
}

#[test]
fn nees_uses_the_published_covariance() {
    let mut r = row(1.0, 90.0, 0.2);
    assert_eq!(r.nees(), None, "no covariance");
    // Error 0.2 m along x, variance 0.01 m² on x: NEES = 0.04 / 0.01 = 4.
    r.covariance = Some(nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(0.01, 1.0, 1.0)));
    assert!((r.nees().unwrap() - 4.0).abs() < 1e-9);
    r.covariance = Some(nalgebra::Matrix3::zeros());
    assert_eq!(r.nees(), None, "not positive definite");
    let mut rec = record(vec![r.clone(), r], 2.0);
    for row in &mut rec.rows {
        row.trusted = true;
        row.covariance = Some(nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(0.001, 1.0, 1.0)));
    }
    let s = soundmap_sim::report::Summary::new(&rec, &soundmap_sim::report::derived::Derived::new(&rec));
    assert!((s.nees_mean_trusted.unwrap() - 40.0).abs() < 1e-9);
    assert_eq!(s.nees_above_chi2_99_trusted_ratio, Some(1.0));
}
