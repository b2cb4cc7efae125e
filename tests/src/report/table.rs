//! Compact, aligned terminal tables of one run's summary, or of two side by side.

use std::fmt::Write as _;
use std::path::Path;

use super::summary::Summary;
use super::{COMPARISON_PLOT_STEM, PLOT_STEMS};

/// Width of the label column (characters).
const LABEL_WIDTH: usize = 26;
/// Width of a value column (characters).
const VALUE_WIDTH: usize = 16;

fn metres(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{v:.3} m"))
}

fn seconds(v: Option<f64>) -> String {
    v.map_or_else(|| "never".into(), |v| format!("{v:.1} s"))
}

fn percent(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{:.1} %", 100.0 * v))
}

/// One line of the table: label and how to show a summary's value.
type Line = (&'static str, fn(&Summary) -> String);

/// The lines shown, in order.
fn lines(with_triangulation: bool, with_smoothed: bool, with_multi: bool) -> Vec<Line> {
    let mut lines: Vec<Line> = vec![
        ("active positioning", |s| if s.active_positioning { "on".into() } else { "off".into() }),
        ("seed", |s| s.seed.map_or_else(|| "—".into(), |v| v.to_string())),
        ("duration", |s| format!("{:.1} s", s.duration_s)),
        ("estimates", |s| s.estimates.to_string()),
        ("  with position", |s| s.estimates_with_position.to_string()),
        ("  with RSE (truth)", |s| s.estimates_with_rse.to_string()),
        ("  trusted", |s| percent(s.trusted_ratio)),
        ("RSE median", |s| metres(s.rse_median_m)),
        ("RSE p95", |s| metres(s.rse_p95_m)),
        ("RSE mean", |s| metres(s.rse_mean_m)),
        ("RSE < 0.3 m", |s| percent(s.rse_below_0_3_m_ratio)),
        ("RSE p95, θ in band", |s| metres(s.rse_p95_in_band_m)),
        ("RSE p95, θ out of band", |s| metres(s.rse_p95_out_of_band_m)),
        ("RSE p95, trusted", |s| metres(s.rse_p95_trusted_m)),
        ("NEES mean, trusted (ideal 3)", |s| s.nees_mean_trusted.map_or("—".into(), |v| format!("{v:.2}"))),
        ("estimates in / out band", |s| format!("{} / {}", s.estimates_in_band, s.estimates_out_of_band)),
        ("time in band", |s| percent(s.time_in_band_ratio)),
        ("time to band", |s| seconds(s.time_to_band_s)),
        ("in band after conv.", |s| percent(s.in_band_ratio_after_convergence)),
        ("RSE p95 after conv.", |s| metres(s.rse_p95_after_convergence_m)),
    ];
    if with_triangulation {
        lines.push(("triangulation RSE median", |s| {
            metres(s.triangulation.as_ref().and_then(|t| t.rse_median_m))
        }));
        lines.push(("triangulation RSE p95", |s| metres(s.triangulation.as_ref().and_then(|t| t.rse_p95_m))));
    }
    if with_smoothed {
        lines.push(("smoothed states (lag)", |s| {
            s.smoothed.as_ref().map_or("—".into(), |m| {
                format!("{} ({})", m.states, m.lag_mean_s.map_or("—".into(), |l| format!("{l:.2} s")))
            })
        }));
        lines.push(("smoothed RSE p95, θ in band", |s| {
            metres(s.smoothed.as_ref().and_then(|m| m.rse_p95_in_band_m))
        }));
    }
    if with_multi {
        lines.push(("sources: true / ids", |s| {
            s.multi_target
                .as_ref()
                .map_or("—".into(), |m| format!("{} / {}", m.true_sources, m.published_ids))
        }));
        lines.push(("OSPA mean (c = 1 m)", |s| metres(s.multi_target.as_ref().and_then(|m| m.ospa_mean_m))));
        lines.push(("OSPA p95", |s| metres(s.multi_target.as_ref().and_then(|m| m.ospa_p95_m))));
        lines.push(("detection (≤ 0.5 m)", |s| {
            percent(s.multi_target.as_ref().and_then(|m| m.detection_ratio))
        }));
        lines.push(("ghosts per s", |s| {
            s.multi_target.as_ref().and_then(|m| m.ghosts_per_s).map_or("—".into(), |v| format!("{v:.3}"))
        }));
        lines.push(("id switches", |s| {
            s.multi_target.as_ref().map_or("—".into(), |m| m.id_switches.to_string())
        }));
    }
    lines
}

fn band_line(s: &Summary) -> String {
    format!(
        "θ band {:.0}–{:.0}° ({} θ); time ratios weigh each estimate by the time to the next, capped at {:.1} s",
        s.theta_band_deg[0],
        s.theta_band_deg[1],
        s.theta_source.as_str(),
        s.time_weight_cap_s
    )
}

/// Rows of a table with one value column per summary, titled by `headers`.
fn table(summaries: &[&Summary], headers: &[&str]) -> String {
    let with_tri = summaries.iter().any(|s| s.triangulation.is_some());
    let with_smoothed = summaries.iter().any(|s| s.smoothed.is_some());
    let with_multi = summaries.iter().any(|s| s.multi_target.as_ref().is_some_and(|m| m.true_sources > 1));
    let mut out = String::new();
    let _ = write!(out, "{:<LABEL_WIDTH$}", "");
    for h in headers {
        let _ = write!(out, "{h:>VALUE_WIDTH$}");
    }
    out.push('\n');
    let rule = LABEL_WIDTH + VALUE_WIDTH * headers.len();
    let _ = writeln!(out, "{}", "─".repeat(rule));
    for (label, value) in lines(with_tri, with_smoothed, with_multi) {
        let _ = write!(out, "{label:<LABEL_WIDTH$}");
        for s in summaries {
            let _ = write!(out, "{:>VALUE_WIDTH$}", value(s));
        }
        out.push('\n');
    }
    out
}

/// The table of one run, followed by where its files are.
pub fn format_summary_table(summary: &Summary, out_dir: &Path) -> String {
    let mut out = format!("soundmap-sim report: {}\n", summary.name);
    out.push_str(&table(&[summary], &["value"]));
    let _ = writeln!(out, "{}", band_line(summary));
    let _ = writeln!(
        out,
        "reports: {}",
        out_dir.join("{timeline.csv, theta_bins.csv, summary.json, commands.csv, goals.csv}").display()
    );
    let _ = writeln!(
        out,
        "plots:   {}",
        out_dir.join(format!("{{{}}}.{{svg,png}}", PLOT_STEMS.join(", "))).display()
    );
    out
}

/// Print [`format_summary_table`] to standard output.
pub fn print_summary_table(summary: &Summary, out_dir: &Path) {
    print!("{}", format_summary_table(summary, out_dir));
}

/// The table of two runs of one scenario, active positioning on and off.
pub fn format_comparison_table(on: &Summary, off: &Summary, out_dir: &Path) -> String {
    let mut out = format!("soundmap-sim comparison: {} (active positioning on vs off)\n", on.name);
    out.push_str(&table(&[on, off], &["active", "passive"]));
    let _ = writeln!(out, "{}", band_line(on));
    let _ =
        writeln!(out, "reports: {}  {}", out_dir.join("active").display(), out_dir.join("passive").display());
    let _ = writeln!(
        out,
        "compare: {}  {}",
        out_dir.join("comparison.json").display(),
        out_dir.join(format!("{COMPARISON_PLOT_STEM}.{{svg,png}}")).display()
    );
    out
}

/// Print [`format_comparison_table`] to standard output.
pub fn print_comparison_table(on: &Summary, off: &Summary, out_dir: &Path) {
    print!("{}", format_comparison_table(on, off, out_dir));
}
