//! CPU cost of the agent's DSP (STFT → SRP-PHAT → DoA tracking) per second of
//! audio, one thread, with the accuracy of the configuration being timed.
//!
//! Run: `cargo bench -p soundmap-agent --bench agent`
//!
//! Audio: 16-channel 16 kHz, `16soundsusb-pioneer` preset, ODAS's frames of
//! 256 samples and hops of 128; 12 segments of 1 s, each a white-noise plane
//! wave from a random direction in the upper hemisphere with independent
//! sensor noise at 20 dB SNR (exact fractional delays). Cost is the thread's
//! CPU time (`/proc/thread-self/schedstat`, first field), best of 5 runs,
//! divided by the audio duration. The reference is the classic exhaustive
//! SRP-PHAT: every point of the full 2562-point icosphere, same
//! cross-correlations, grid resolution only (no refinement), as ODAS's
//! non-hierarchical search would do.
//!
//! Signatures (24 bands, default refresh every 2 hops, and every hop): the
//! stage alone (`Signatures::update` over STFT frames computed beforehand,
//! 1, 2 and 4 tracks, 20 passes per run since the thread clock may tick in
//! 4 ms steps) as a fraction of the default pipeline's CPU time on the same
//! audio (target < 5 %); and on audio with two simultaneous sources (a white
//! one and a high-passed one), the whole default pipeline against the stage
//! for as many tracks as the pipeline signed per hop there (rounded up).

#[path = "../tests/data/synth.rs"]
mod synth;

use soundmap_agent::array::ArrayGeometry;
use soundmap_agent::pipeline::{Pipeline, PipelineConfig};
use soundmap_agent::srp::{RegionConfig, SearchMode};
use soundmap_agent::stft::Stft;
use soundmap_proto::Stamp;

const SEGMENTS: usize = 12;
const SEGMENT_LEN: usize = 16384; // 1.024 s at 16 kHz
const RUNS: usize = 5;

/// CPU time of this thread, nanoseconds.
fn thread_cpu_ns() -> u64 {
    let s =
        std::fs::read_to_string("/proc/thread-self/schedstat").expect("/proc/thread-self/schedstat (Linux)");
    s.split_whitespace().next().and_then(|v| v.parse().ok()).expect("schedstat's first field")
}

struct Audio {
    interleaved: Vec<f32>,
    truth: Vec<nalgebra::Vector3<f64>>,
    seconds: f64,
}

fn audio(array: &ArrayGeometry) -> Audio {
    let mut rng = synth::rng(2024);
    let mics = synth::positions(array);
    let mut interleaved = Vec::new();
    let mut truth = Vec::new();
    for _ in 0..SEGMENTS {
        let d = synth::random_direction(&array.default_region, &mut rng);
        let mut x = synth::plane_wave(&mics, &d, 16000.0, SEGMENT_LEN, &mut rng);
        synth::add_sensor_noise(&mut x, 20.0, &mut rng);
        interleaved.extend(synth::interleave(&x, 0.05));
        truth.push(d);
    }
    Audio { interleaved, truth, seconds: (SEGMENTS * SEGMENT_LEN) as f64 / 16000.0 }
}

struct Measured {
    cpu_per_audio_s: f64,
    median_deg: f64,
    p95_deg: f64,
    tracks: usize,
    /// Per frame: coarse cells opened, fine points evaluated, refinement evaluations.
    work: [f64; 3],
}

fn measure(array: &ArrayGeometry, config: &PipelineConfig, a: &Audio) -> Measured {
    let mut best = f64::INFINITY;
    let mut errors = Vec::new();
    let mut ids = std::collections::BTreeSet::new();
    let mut work = [0.0; 3];
    for run in 0..RUNS {
        let mut p = Pipeline::new(array, config).unwrap();
        let block = p.hop_len() * p.channels();
        let hops_per_segment = SEGMENT_LEN / p.hop_len();
        let t0 = thread_cpu_ns();
        for (h, b) in a.interleaved.chunks_exact(block).enumerate() {
            let r = p.process_hop(Stamp::from_ns(h as i64 * 8_000_000), b);
            if run == 0 {
                // Skip the first frames of a segment (they straddle two directions).
                if h % hops_per_segment >= 3
                    && let Some(s) = r.potentials.first()
                {
                    errors.push(synth::angle_deg(&s.direction_in_array, &a.truth[h / hops_per_segment]));
                }
                ids.extend(r.tracks.iter().filter(|t| t.confirmed).map(|t| t.track_id));
            }
        }
        let dt = (thread_cpu_ns() - t0) as f64 * 1e-9;
        best = best.min(dt);
        let st = p.srp_mut().take_stats();
        let frames = (a.interleaved.len() / block) as f64;
        work = [
            st.cells_opened as f64 / frames,
            st.fine_points as f64 / frames,
            st.refine_evaluations as f64 / frames,
        ];
    }
    let (_, median_deg, p95_deg) = synth::stats(&errors);
    Measured { cpu_per_audio_s: best / a.seconds, median_deg, p95_deg, tracks: ids.len(), work }
}

fn stft_only(array: &ArrayGeometry, a: &Audio) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..RUNS {
        let mut s = Stft::new(array.channels(), 256, 128, Default::default()).unwrap();
        let t0 = thread_cpu_ns();
        for b in a.interleaved.chunks_exact(128 * array.channels()) {
            std::hint::black_box(s.push_hop(b));
        }
        best = best.min((thread_cpu_ns() - t0) as f64 * 1e-9);
    }
    best / a.seconds
}

/// STFT plus PHAT whitening and the GCC-PHAT of every pair (no search).
fn stft_and_gcc(array: &ArrayGeometry, a: &Audio) -> f64 {
    use soundmap_agent::srp::Srp;
    let mut best = f64::INFINITY;
    for _ in 0..RUNS {
        let mut s = Stft::new(array.channels(), 256, 128, Default::default()).unwrap();
        let mut srp = Srp::new(array, 16000, 256, &Default::default()).unwrap();
        let t0 = thread_cpu_ns();
        for b in a.interleaved.chunks_exact(128 * array.channels()) {
            if s.push_hop(b) {
                srp.correlate_only(s.spectra());
            }
        }
        best = best.min((thread_cpu_ns() - t0) as f64 * 1e-9);
    }
    best / a.seconds
}

/// Two simultaneous sources (white from `a`, high-passed white from `b`),
/// 20 dB SNR, for the signature cost.
fn two_source_audio(array: &ArrayGeometry) -> Audio {
    let mut rng = synth::rng(77);
    let mics = synth::positions(array);
    let mut interleaved = Vec::new();
    let mut truth = Vec::new();
    for _ in 0..SEGMENTS / 2 {
        let a = synth::random_direction(&array.default_region, &mut rng);
        let mut b = synth::random_direction(&array.default_region, &mut rng);
        while synth::angle_deg(&a, &b) < 60.0 {
            b = synth::random_direction(&array.default_region, &mut rng);
        }
        let mut x = synth::plane_wave(&mics, &a, 16000.0, SEGMENT_LEN, &mut rng);
        let y = synth::plane_wave(&mics, &b, 16000.0, SEGMENT_LEN, &mut rng);
        for (x, y) in x.iter_mut().zip(&y) {
            // First difference: a gentle high pass (+6 dB/octave).
            for t in 0..SEGMENT_LEN {
                x[t] += y[t] - y[(t + SEGMENT_LEN - 1) % SEGMENT_LEN];
            }
        }
        synth::add_sensor_noise(&mut x, 20.0, &mut rng);
        interleaved.extend(synth::interleave(&x, 0.05));
        truth.push(a);
    }
    Audio { interleaved, truth, seconds: (SEGMENTS / 2 * SEGMENT_LEN) as f64 / 16000.0 }
}

/// CPU-s per audio-s of the pipeline with `config` (best of `RUNS`) and the
/// mean number of tracks with a signature per hop.
fn pipeline_cost(array: &ArrayGeometry, config: &PipelineConfig, a: &Audio) -> (f64, f64) {
    let mut best = f64::INFINITY;
    let (mut signed, mut hops) = (0usize, 0usize);
    for run in 0..RUNS {
        let mut p = Pipeline::new(array, config).unwrap();
        let block = p.hop_len() * p.channels();
        let t0 = thread_cpu_ns();
        for (h, b) in a.interleaved.chunks_exact(block).enumerate() {
            let r = p.process_hop(Stamp::from_ns(h as i64 * 8_000_000), b);
            if run == 0 {
                signed += r.reported.len();
                hops += 1;
            }
            std::hint::black_box(r);
        }
        best = best.min((thread_cpu_ns() - t0) as f64 * 1e-9 / a.seconds);
    }
    (best, signed as f64 / hops.max(1) as f64)
}

/// Passes over the audio per timed run of the signature stage alone (the
/// thread clock may tick in 4 ms steps: a pass takes about that much).
const STAGE_REPEATS: usize = 20;

/// CPU-s per audio-s of the signature stage alone for `tracks` tracks with
/// fixed directions, over the STFT frames of `a` computed beforehand
/// (`STAGE_REPEATS` passes per run), best of `RUNS`.
fn signature_stage(array: &ArrayGeometry, config: &PipelineConfig, tracks: usize, a: &Audio) -> f64 {
    use soundmap_agent::pipeline::TrackedDirection;
    use soundmap_agent::signature::Signatures;
    let dirs: Vec<TrackedDirection> = (0..tracks)
        .map(|i| TrackedDirection {
            track_id: i as u64 + 1,
            direction_in_array: nalgebra::Unit::new_normalize(nalgebra::Vector3::new(
                (i as f64).cos(),
                (i as f64).sin(),
                0.5,
            )),
            activity: 1.0,
            angular_sigma_rad: 0.01,
            confirmed: true,
            silent_s: 0.0,
            audible_silent_s: 0.0,
            held_by_masking: false,
            coherence: 0.5,
        })
        .collect();
    let reported: Vec<usize> = (0..tracks).collect();
    let mut out = Vec::with_capacity(tracks * config.signature.bands);
    // Every hop's spectra first (not timed), then the stage alone over them.
    let mut stft = Stft::new(array.channels(), config.frame_len, config.hop_len, config.window).unwrap();
    let mut frames: Vec<Vec<realfft::num_complex::Complex<f32>>> = Vec::new();
    for b in a.interleaved.chunks_exact(config.hop_len * array.channels()) {
        if stft.push_hop(b) {
            frames.push(stft.spectra().to_vec());
        }
    }
    let mut best = f64::INFINITY;
    for _ in 0..RUNS {
        let mut sig = Signatures::new(array, &config.signature, &config.signature_layout()).unwrap();
        let t0 = thread_cpu_ns();
        for _ in 0..STAGE_REPEATS {
            for spectra in &frames {
                sig.update(spectra, &dirs, &reported, &mut out);
                std::hint::black_box(&out);
            }
        }
        best = best.min((thread_cpu_ns() - t0) as f64 * 1e-9 / (a.seconds * STAGE_REPEATS as f64));
    }
    best
}

/// Writes `seconds` of 16-channel 16 kHz audio (a white-noise plane wave from
/// a new random direction every second, 20 dB SNR) as `DIR/agent-cpu.wav`
/// (16-bit PCM) and the same samples as `DIR/agent-cpu.raw` (s16le), for
/// timing the whole agent process on a file.
fn write_audio(array: &ArrayGeometry, dir: &std::path::Path, seconds: usize) {
    let mut rng = synth::rng(4242);
    let mics = synth::positions(array);
    let spec = hound::WavSpec {
        channels: array.channels() as u16,
        sample_rate: 16000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
    let mut wav = hound::WavWriter::create(dir.join("agent-cpu.wav"), spec).unwrap();
    let mut raw = std::io::BufWriter::new(std::fs::File::create(dir.join("agent-cpu.raw")).unwrap());
    for _ in 0..seconds {
        let d = synth::random_direction(&array.default_region, &mut rng);
        let mut x = synth::plane_wave(&mics, &d, 16000.0, 16000usize.next_power_of_two(), &mut rng);
        synth::add_sensor_noise(&mut x, 20.0, &mut rng);
        for t in 0..16000 {
            for ch in &x {
                let v = (ch[t] * 0.1 * 32768.0).round().clamp(-32768.0, 32767.0) as i16;
                wav.write_sample(v).unwrap();
                std::io::Write::write_all(&mut raw, &v.to_le_bytes()).unwrap();
            }
        }
    }
    wav.finalize().unwrap();
    std::io::Write::flush(&mut raw).unwrap();
}

fn main() {
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "--write-audio") {
        let dir = std::path::Path::new(args.get(i + 1).expect("--write-audio DIR"));
        write_audio(&array, dir, 120);
        println!(
            "wrote {0}/agent-cpu.wav and {0}/agent-cpu.raw (120 s, 16 channels, 16 kHz, s16)",
            dir.display()
        );
        return;
    }
    let a = audio(&array);
    let default = PipelineConfig::default();
    let full_sphere = Some(RegionConfig { axis: [0.0, 0.0, 1.0], max_angle_deg: 180.0 });

    let mut one = default.clone();
    one.srp.max_sources = 1;
    let mut sphere = default.clone();
    sphere.srp.region = full_sphere.clone();
    let mut grid_only = default.clone();
    grid_only.srp.refine = false;
    let mut reference = default.clone();
    reference.srp.search = SearchMode::Exhaustive;
    reference.srp.refine = false;
    reference.srp.max_sources = 1;
    reference.srp.region = full_sphere.clone();
    let mut reference_hemi = reference.clone();
    reference_hemi.srp.region = None;

    let rows: Vec<(&str, &PipelineConfig)> = vec![
        ("soundmap default (hierarchical + Newton, 2 potentials, hemisphere)", &default),
        ("  same, 1 potential per frame", &one),
        ("  same, 2 potentials, whole sphere", &sphere),
        ("  same, 2 potentials, no refinement (grid only)", &grid_only),
        ("reference: exhaustive 2562 points, whole sphere, 1 potential, grid only", &reference),
        ("reference: exhaustive 1313 points, hemisphere, 1 potential, grid only", &reference_hemi),
    ];
    println!(
        "agent DSP benchmark: {} , {} channels, 16 kHz, frame 256 / hop 128, {:.1} s of audio, 20 dB SNR plane waves",
        array.name,
        array.channels(),
        a.seconds
    );
    println!("(thread CPU time, best of {RUNS} runs; errors per frame of the strongest potential)\n");
    println!(
        "{:<76} {:>14} {:>9} {:>8} {:>7} {:>6} {:>6} {:>6}",
        "configuration", "CPU-s/audio-s", "median°", "p95°", "tracks", "cells", "fine", "newton"
    );
    // Optional argument: only run configurations whose name contains it (for profiling).
    let filter = args.iter().skip(1).find(|a| !a.starts_with('-'));
    if let Some(f) = &filter {
        for (name, cfg) in rows.iter().filter(|(n, _)| n.contains(f.as_str())) {
            let m = measure(&array, cfg, &a);
            println!(
                "{name:<76} {:>14.5} {:>9.3} {:>8.3} {:>7} {:>6.1} {:>6.0} {:>6.1}",
                m.cpu_per_audio_s, m.median_deg, m.p95_deg, m.tracks, m.work[0], m.work[1], m.work[2]
            );
        }
        return;
    }
    let mut results = Vec::new();
    for (name, cfg) in &rows {
        let m = measure(&array, cfg, &a);
        println!(
            "{name:<76} {:>14.5} {:>9.3} {:>8.3} {:>7} {:>6.1} {:>6.0} {:>6.1}",
            m.cpu_per_audio_s, m.median_deg, m.p95_deg, m.tracks, m.work[0], m.work[1], m.work[2]
        );
        results.push(m);
    }
    let stft = stft_only(&array, &a);
    println!("{:<76} {:>14.5}", "  of which STFT (16 × 256-point real FFT per hop)", stft);
    let gcc = stft_and_gcc(&array, &a);
    println!("{:<76} {:>14.5}", "  of which STFT + PHAT + GCC of 120 pairs on 88 baselines (44 IFFTs)", gcc);
    let two = two_source_audio(&array);
    let (two_cpu, signed) = pipeline_cost(&array, &default, &two);
    let k = (signed.ceil() as usize).max(1);
    let stage = signature_stage(&array, &default, k, &two);
    println!(
        "two-source audio: default pipeline {two_cpu:.5} CPU-s/audio-s with {signed:.2} signed tracks/hop; \
         signature stage alone for {k} tracks {stage:.5}: {:.2} % of it (target < 5 %)",
        100.0 * stage / two_cpu
    );
    let mut every_hop = default.clone();
    every_hop.signature.update_interval_hops = 1;
    for (interval, config) in [(2, &default), (1, &every_hop)] {
        for k in [1, 2, 4] {
            let stage = signature_stage(&array, config, k, &a);
            println!(
                "signature stage alone, {k} track(s) × 24 bands, refreshed every {interval} hop(s): {stage:.5} \
                 CPU-s/audio-s = {:.2} % of the default pipeline ({:.5})",
                100.0 * stage / results[0].cpu_per_audio_s,
                results[0].cpu_per_audio_s
            );
        }
    }
    let ours = &results[0];
    let reference = &results[4];
    println!(
        "\nspeed-up of the default over the exhaustive reference: ×{:.2} (reference / default CPU time)",
        reference.cpu_per_audio_s / ours.cpu_per_audio_s
    );
    println!(
        "target: ≤ 0.015 CPU-s per audio-s with median error < 1°: {} ({:.5} CPU-s/audio-s, median {:.3}°)",
        if ours.cpu_per_audio_s <= 0.015 && ours.median_deg < 1.0 { "met" } else { "NOT met" },
        ours.cpu_per_audio_s,
        ours.median_deg
    );
}
