//! `soundmap-sim`: run scenarios, the built-in demo, and replays of recorded trials.
//!
//! ```text
//! soundmap-sim demo [--out DIR]
//! soundmap-sim run SCENARIO [--out DIR] [--seed N] [--active on|off|compare] [--record DIR]
//!                  [--foxglove ADDR] [--realtime] [--mcap FILE.mcap]
//! soundmap-sim replay --robot id=ID,audio=F.wav,poses=F.tum,array=PRESET|F.toml[,start=S][,pose_std_m=M,yaw_std_deg=D] ... [--truth F.tum] --out DIR
//! soundmap-sim replay-mcap FILE.mcap --out DIR [--config coordinator.toml]
//! soundmap-sim list
//! ```

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Parser, Subcommand, ValueEnum};
use soundmap_sim::report;
use soundmap_sim::runner::{self, RunOptions};
use soundmap_sim::scenario::{Scenario, builtin};

/// Simulated rooms and robots, and replays of recorded trials, run through the
/// real coordinator and agents over gRPC, with the paper's reports and plots.
#[derive(Debug, Parser)]
#[command(name = "soundmap-sim", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Active {
    /// As the scenario says.
    Scenario,
    /// Active positioning on.
    On,
    /// Active positioning off.
    Off,
    /// Both, with a comparison report.
    Compare,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The built-in demo: the paper's static trial (`paper-static`).
    Demo {
        /// Output directory.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
    },
    /// Runs a scenario (a built-in name or a TOML file).
    Run {
        /// Built-in scenario name (see `list`) or path to a scenario TOML file.
        scenario: String,
        /// Output directory (default: out/NAME).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Overrides the scenario's seed.
        #[arg(long)]
        seed: Option<u64>,
        /// Active positioning.
        #[arg(long, value_enum, default_value_t = Active::Scenario)]
        active: Active,
        /// Also write the run as a recorded trial (WAV + TUM) into this directory.
        #[arg(long)]
        record: Option<PathBuf>,
        /// The Foxglove live view, the MCAP recording and real-time pacing.
        #[command(flatten)]
        view: soundmap_sim::viewer::ViewArgs,
    },
    /// Replays recorded trials (audio + poses [+ ground truth]) through the same pipeline.
    Replay(soundmap_sim::replay::ReplayArgs),
    /// Re-runs the coordinator on the observations of an MCAP recording (same reports as `replay`).
    ReplayMcap(soundmap_sim::mcap_replay::ReplayMcapArgs),
    /// Lists the built-in scenarios.
    List,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Demo { out } => {
            run_scenario("paper-static", out, None, Active::Scenario, None, Default::default())
        }
        Command::Run { scenario, out, seed, active, record, view } => {
            let out = out.unwrap_or_else(|| PathBuf::from("out").join(scenario_stem(&scenario)));
            run_scenario(&scenario, out, seed, active, record, view)
        }
        Command::ReplayMcap(args) => {
            let started = Instant::now();
            let record = soundmap_sim::mcap_replay::replay_mcap(&args)?;
            let summary = report::write_reports(&record, &args.out)?;
            report::print_summary_table(&summary, &args.out);
            eprintln!(
                "replayed {:.1} s of recording in {:.1} s",
                record.duration_s,
                started.elapsed().as_secs_f64()
            );
            Ok(())
        }
        Command::Replay(args) => {
            let started = Instant::now();
            let record = soundmap_sim::replay::replay(&args)?;
            let summary = report::write_reports(&record, &args.out)?;
            report::print_summary_table(&summary, &args.out);
            eprintln!(
                "replayed {:.1} s of recordings in {:.1} s",
                record.duration_s,
                started.elapsed().as_secs_f64()
            );
            Ok(())
        }
        Command::List => {
            for name in builtin::NAMES {
                let s = Scenario::load(name)?;
                println!("{name:14} {:6.0} s  {}", s.duration_s, s.description);
            }
            Ok(())
        }
    }
}

fn scenario_stem(s: &str) -> String {
    std::path::Path::new(s).file_stem().map_or_else(|| s.to_string(), |x| x.to_string_lossy().to_string())
}

fn run_scenario(
    name: &str,
    out: PathBuf,
    seed: Option<u64>,
    active: Active,
    record: Option<PathBuf>,
    view: soundmap_sim::viewer::ViewArgs,
) -> anyhow::Result<()> {
    let scenario = Scenario::load(name)?;
    let started = Instant::now();
    let options = |active_positioning: Option<bool>| RunOptions {
        seed,
        active_positioning,
        record_dir: record.clone(),
        progress: true,
        view: view.clone(),
    };
    eprintln!(
        "running {} ({:.0} s simulated, seed {})",
        scenario.name,
        scenario.duration_s,
        seed.unwrap_or(scenario.seed)
    );
    if active == Active::Compare {
        let on = runner::run(&scenario, &options(Some(true)))?;
        // The live view and recording follow the first run only (one server, one file).
        let off = runner::run(
            &scenario,
            &RunOptions { record_dir: None, view: Default::default(), ..options(Some(false)) },
        )?;
        let (a, p) = report::write_comparison(&on, &off, &out)
            .with_context(|| format!("writing reports to {}", out.display()))?;
        report::print_summary_table(&a, &out.join("active"));
        report::print_summary_table(&p, &out.join("passive"));
    } else {
        let flag = match active {
            Active::On => Some(true),
            Active::Off => Some(false),
            _ => None,
        };
        let record = runner::run(&scenario, &options(flag))?;
        let summary = report::write_reports(&record, &out)
            .with_context(|| format!("writing reports to {}", out.display()))?;
        report::print_summary_table(&summary, &out);
    }
    eprintln!("simulated {:.0} s in {:.1} s", scenario.duration_s, started.elapsed().as_secs_f64());
    Ok(())
}
