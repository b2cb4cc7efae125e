//! soundmap-agent: the robot agent.
//!
//! - `soundmap-agent localize`: localize and track sources in a recording with
//!   our SRP-PHAT pipeline; one JSON line per hop ([`soundmap_agent::localize`]).
//! - `soundmap-agent run --config agent.toml`: the live agent: audio through the
//!   pipeline (or ODAS's tracked sources) + SLAM poses → the agent core →
//!   observations streamed to the coordinator; reposition commands to the
//!   navigator ([`soundmap_agent::live`]).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use soundmap_agent::AgentError;
use soundmap_agent::array::ArrayGeometry;
use soundmap_agent::audio::{self, AudioInput, BlockOptions, RawFormat, RawLayout};
use soundmap_agent::config::{self, AgentConfig};
use soundmap_agent::live::LivePlan;
use soundmap_agent::localize::{LineOptions, localize};
use soundmap_agent::pipeline::{Pipeline, PipelineConfig};
use soundmap_proto::Stamp;

#[derive(Debug, Parser)]
#[command(
    name = "soundmap-agent",
    version,
    about = "soundmap robot agent: hears directions, streams them with the robot's pose"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Localize and track sound sources in a recording; writes one JSON line per hop:
    /// {"stamp_ns":…, "sources":[{"id","x","y","z","activity"}]} with (x, y, z) the unit
    /// vector toward the source in the array frame (x forward, y left, z up).
    Localize(LocalizeArgs),
    /// Run the agent: audio + poses → observations to the coordinator; commands → navigator.
    Run {
        /// The agent configuration (see deploy/agent.example.toml).
        #[arg(long)]
        config: PathBuf,
    },
}

#[derive(Debug, Args)]
struct LocalizeArgs {
    /// Array preset name or array .toml file.
    #[arg(long)]
    array: String,
    /// A WAV file, a raw PCM file, or - for raw PCM on standard input (told by content, not name).
    #[arg(long)]
    input: PathBuf,
    /// Raw sample format: s16le, s24le (packed 3 bytes) or s32le.
    #[arg(long)]
    format: Option<RawFormat>,
    /// Raw input: channels per frame in the stream.
    #[arg(long)]
    channels: Option<usize>,
    /// Raw input: sample rate, Hz.
    #[arg(long)]
    rate: Option<u32>,
    /// Input channel of each microphone, in microphone order (e.g. 3,0,1,2).
    #[arg(long, value_delimiter = ',')]
    channel_map: Vec<usize>,
    /// Unix ns of input sample 0 (default 0).
    #[arg(long, default_value_t = 0)]
    start_ns: i64,
    /// Output file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write this hop's SRP peaks: "potentials":[{"x","y","z","energy"}]
    /// (and "range_m" with `[srp] near_field`).
    #[arg(long)]
    potentials: bool,
    /// Also write tentative (unconfirmed) tracks.
    #[arg(long)]
    all_tracks: bool,
    /// Pipeline settings: a TOML file with the fields of agent.toml's [pipeline]
    /// (default: the pipeline defaults at the input's sample rate).
    #[arg(long)]
    pipeline: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .init();
    let result = match cli.command {
        Command::Localize(args) => run_localize(&args),
        Command::Run { config } => run(&config),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(config_path: &Path) -> Result<()> {
    let config = AgentConfig::load(config_path)?;
    LivePlan::prepare(config)?.run()?;
    Ok(())
}

fn run_localize(args: &LocalizeArgs) -> Result<()> {
    let array = ArrayGeometry::load(&args.array)?;
    let layout = match (args.format, args.channels, args.rate) {
        (Some(format), Some(channels), Some(sample_rate_hz)) => {
            Some(RawLayout { format, channels, sample_rate_hz })
        }
        (None, None, None) => None,
        _ => bail!("{}: raw input needs --format, --channels and --rate", args.input.display()),
    };
    let input = AudioInput::from_path(&args.input, layout)?;
    let pipeline_config = match &args.pipeline {
        Some(p) => config::load_pipeline(p)?,
        None => PipelineConfig { sample_rate_hz: input_rate(&input)?, ..PipelineConfig::default() },
    };
    let mut pipeline =
        Pipeline::new(&array, &pipeline_config).map_err(|e| pipeline_error(e, args.pipeline.as_deref()))?;
    let options = BlockOptions {
        hop_len: pipeline.hop_len(),
        channels: array.channels(),
        sample_rate_hz: pipeline.sample_rate_hz(),
        channel_map: (!args.channel_map.is_empty()).then(|| args.channel_map.clone()),
        start: Stamp::from_ns(args.start_ns),
    };
    let mut source = audio::open(&input, &options)?;
    let mut out: Box<dyn Write> = match &args.out {
        Some(p) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("{}: cannot create", p.display()))?,
        )),
        None => Box::new(std::io::BufWriter::new(std::io::stdout().lock())),
    };
    let lines = LineOptions { potentials: args.potentials, all_tracks: args.all_tracks };
    localize(source.as_mut(), &mut pipeline, lines, &mut out)?;
    Ok(())
}

/// The sample rate of an input (WAV header, or the raw layout).
fn input_rate(input: &AudioInput) -> Result<u32> {
    Ok(match input {
        AudioInput::Wav { path } => {
            hound::WavReader::open(path)
                .map_err(|e| AgentError::Audio {
                    path: path.clone(),
                    message: format!("not a supported WAV file: {e}"),
                })?
                .spec()
                .sample_rate
        }
        AudioInput::Raw { layout, .. } | AudioInput::Stdin { layout } | AudioInput::Live { layout, .. } => {
            layout.sample_rate_hz
        }
    })
}

/// Names the pipeline settings' origin in a pipeline construction error.
fn pipeline_error(e: AgentError, file: Option<&Path>) -> anyhow::Error {
    let origin = file.map_or("pipeline".to_owned(), |f| f.display().to_string());
    match e {
        AgentError::InvalidParameter { field, message } => {
            anyhow::anyhow!("{origin}: pipeline.{field}: {message}")
        }
        other => other.into(),
    }
}
