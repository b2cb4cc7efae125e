//! Property-based fuzzing of the agent's input parsers: WAV and raw PCM audio,
//! TUM pose files, ODAS SST JSON streams and the agent's TOML config. Arbitrary
//! bytes, and valid inputs with bytes flipped, truncated or spliced, must give
//! a result or an error naming what is wrong, never a panic, and audio reading
//! must end (no endless loop on a broken header).
//!
//! ```sh
//! cargo test -p soundmap-agent --test integration fuzz_parsers::
//! PROPTEST_CASES=5000 cargo test --release -p soundmap-agent --test integration fuzz_parsers::   # longer
//! ```

use std::io::Write;
use std::path::Path;

use proptest::prelude::*;
use soundmap_agent::audio::{self, AudioInput, BlockOptions, RawFormat, RawLayout, RawSource};
use soundmap_agent::config::AgentConfig;
use soundmap_agent::odas::{OdasTiming, SstParser};
use soundmap_agent::pose::PoseTimeMapping;
use soundmap_agent::pose::tum::parse_tum;
use soundmap_proto::Stamp;

/// A scratch file unique to this case, removed when dropped.
fn scratch(name: &str, bytes: &[u8]) -> tempfile::NamedTempFile {
    let mut f =
        tempfile::Builder::new().prefix("soundmap-fuzz-").suffix(&format!("-{name}")).tempfile().unwrap();
    f.write_all(bytes).unwrap();
    f
}

/// A valid 4-channel 16 kHz 16-bit WAV file of `frames` frames.
fn wav_bytes(frames: usize) -> Vec<u8> {
    let (channels, rate, bits) = (4u16, 16_000u32, 16u16);
    let data_len = frames * channels as usize * 2;
    let mut b = Vec::new();
    b.extend_from_slice(b"RIFF");
    b.extend_from_slice(&((36 + data_len) as u32).to_le_bytes());
    b.extend_from_slice(b"WAVEfmt ");
    b.extend_from_slice(&16u32.to_le_bytes());
    b.extend_from_slice(&1u16.to_le_bytes());
    b.extend_from_slice(&channels.to_le_bytes());
    b.extend_from_slice(&rate.to_le_bytes());
    b.extend_from_slice(&(rate * channels as u32 * 2).to_le_bytes());
    b.extend_from_slice(&(channels * 2).to_le_bytes());
    b.extend_from_slice(&bits.to_le_bytes());
    b.extend_from_slice(b"data");
    b.extend_from_slice(&(data_len as u32).to_le_bytes());
    for i in 0..frames * channels as usize {
        b.extend_from_slice(&((i as i16).wrapping_mul(37)).to_le_bytes());
    }
    b
}

fn options(hop_len: usize) -> BlockOptions {
    BlockOptions { hop_len, channels: 4, sample_rate_hz: 16_000, channel_map: None, start: Stamp::ZERO }
}

/// Opens `path` as the agent does (told by content) and reads it to the end;
/// the number of blocks is bounded by the file size, so a reader that loops
/// without consuming fails the test instead of hanging it.
fn read_all(path: &Path, raw: Option<RawLayout>, hop_len: usize) -> Result<usize, String> {
    let size = std::fs::metadata(path).unwrap().len() as usize;
    let input = AudioInput::from_path(path, raw).map_err(|e| e.to_string())?;
    let mut source = audio::open(&input, &options(hop_len)).map_err(|e| e.to_string())?;
    let mut block = vec![0.0f32; source.hop_len() * source.channels()];
    let mut blocks = 0;
    while let Some(_stamp) = source.next_block(&mut block).map_err(|e| e.to_string())? {
        assert!(block.iter().all(|v| v.is_finite()), "{}: a non-finite sample", path.display());
        blocks += 1;
        assert!(blocks <= size + 1, "{}: more blocks than bytes", path.display());
    }
    Ok(blocks)
}

/// Flips, truncates or splices bytes of `valid`.
fn mutate(valid: &[u8], flips: &[(usize, u8)], cut: Option<usize>, splice: &[u8], at: usize) -> Vec<u8> {
    let mut b = valid.to_vec();
    for &(i, v) in flips {
        if !b.is_empty() {
            let n = b.len();
            b[i % n] = v;
        }
    }
    if let Some(c) = cut {
        b.truncate(c % (valid.len() + 1));
    }
    let at = at % (b.len() + 1);
    b.splice(at..at, splice.iter().copied());
    b
}

const SST: &str = r#"{
    "timeStamp": 12,
    "src": [
        { "id": 3, "tag": "dynamic", "x": 0.500, "y": 0.500, "z": 0.707, "activity": 0.9 },
        { "id": 0, "tag": "", "x": 0.000, "y": 0.000, "z": 0.000, "activity": 0.0 },
        { "id": 0, "tag": "", "x": 0.000, "y": 0.000, "z": 0.000, "activity": 0.0 },
        { "id": 0, "tag": "", "x": 0.000, "y": 0.000, "z": 0.000, "activity": 0.0 }
    ]
}
"#;

const TUM: &str = "# t x y z qx qy qz qw\n0.0 1 2 0 0 0 0 1\n0.1 1.1 2 0 0 0 0.0499792 0.9987503\n0.2 1.2 2 0 0 0 0.0998334 0.9950042\n";

const AGENT_TOML: &str = r#"robot_id = "pioneer"
[coordinator]
endpoint = "http://127.0.0.1:50051"
[array]
preset = "16soundsusb-pioneer"
[doa]
source = "own"
[audio]
source = "wav"
path = "robot.wav"
[pose]
source = "tum"
path = "robot.tum"
[navigator]
path = "goals.jsonl"
"#;

fn timing() -> OdasTiming {
    OdasTiming { hop_len: 128, sample_rate_hz: 16_000, start: Stamp::ZERO }
}

#[test]
fn the_valid_inputs_parse() {
    let wav = scratch("ok.wav", &wav_bytes(1000));
    // The last, partial hop is completed with silence.
    assert_eq!(read_all(wav.path(), None, 128), Ok(1000usize.div_ceil(128)));
    let raw = scratch("ok.raw", &vec![0u8; 4 * 2 * 512]);
    let layout = RawLayout { format: RawFormat::S16le, channels: 4, sample_rate_hz: 16_000 };
    assert_eq!(read_all(raw.path(), Some(layout), 128), Ok(4));
    assert_eq!(parse_tum(TUM, "ok.tum", PoseTimeMapping::UNIX).unwrap().len(), 3);
    let frames = SstParser::new().feed(SST.as_bytes());
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].as_ref().unwrap().to_frame(&timing()).unwrap().doas.len(), 1);
    AgentConfig::parse(AGENT_TOML, Path::new("agent.toml")).unwrap();
}

proptest! {
    // 96 cases each in CI; PROPTEST_CASES sets more.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(96),
        ..ProptestConfig::default()
    })]

    #[test]
    fn wav_files_with_broken_bytes_never_panic(
        flips in proptest::collection::vec((0usize..2000, any::<u8>()), 0..6),
        cut in proptest::option::of(0usize..4000),
        splice in proptest::collection::vec(any::<u8>(), 0..16),
        at in any::<usize>(),
        header_only in any::<bool>(),
    ) {
        // Flips land in the 44-byte header half the time.
        let flips: Vec<(usize, u8)> =
            flips.into_iter().map(|(i, v)| (if header_only { i % 44 } else { i }, v)).collect();
        let bytes = mutate(&wav_bytes(400), &flips, cut, &splice, at);
        let file = scratch("m.wav", &bytes);
        let _ = read_all(file.path(), None, 128);
    }

    #[test]
    fn arbitrary_audio_files_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600), wav_start in any::<bool>()) {
        let mut b = bytes;
        if wav_start {
            // A RIFF/WAVE start makes the sniffer take the WAV path.
            let mut h = b"RIFF\x00\x00\x00\x00WAVE".to_vec();
            h.extend(b);
            b = h;
        }
        let file = scratch("a.bin", &b);
        let layout = RawLayout { format: RawFormat::S24le, channels: 4, sample_rate_hz: 16_000 };
        let _ = read_all(file.path(), Some(layout), 64);
        let _ = read_all(file.path(), None, 64);
    }

    #[test]
    fn raw_streams_of_any_length_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..700),
        format in 0usize..3,
        channels in 1usize..6,
    ) {
        let format = [RawFormat::S16le, RawFormat::S24le, RawFormat::S32le][format];
        let layout = RawLayout { format, channels, sample_rate_hz: 16_000 };
        let opts = BlockOptions { channels, ..options(32) };
        let reader = Box::new(std::io::Cursor::new(bytes.clone()));
        if let Ok(mut s) = RawSource::from_reader("fuzz.raw", reader, layout, &opts) {
            use soundmap_agent::audio::AudioSource;
            let mut block = vec![0.0f32; 32 * channels];
            let mut n = 0;
            // A truncated last frame is an error or the end, never a hang.
            while let Ok(Some(_)) = s.next_block(&mut block) {
                n += 1;
                prop_assert!(n <= bytes.len() + 1);
                prop_assert!(block.iter().all(|v| v.is_finite()));
            }
        }
    }

    #[test]
    fn tum_text_never_panics(
        flips in proptest::collection::vec((0usize..200, any::<u8>()), 0..6),
        cut in proptest::option::of(0usize..200),
        splice in "\\PC{0,20}",
        at in any::<usize>(),
        junk in "\\PC{0,120}",
    ) {
        let bytes = mutate(TUM.as_bytes(), &flips, cut, splice.as_bytes(), at);
        let text = String::from_utf8_lossy(&bytes);
        if let Ok(poses) = parse_tum(&text, "m.tum", PoseTimeMapping::UNIX) {
            // What parses is usable: finite, unit rotations, increasing stamps.
            for w in poses.windows(2) {
                prop_assert!(w[0].stamp < w[1].stamp);
            }
            for p in &poses {
                prop_assert!(p.map_from_base.translation.vector.iter().all(|v| v.is_finite()));
                prop_assert!((p.map_from_base.rotation.norm() - 1.0).abs() < 1e-6);
            }
        }
        let _ = parse_tum(&junk, "junk.tum", PoseTimeMapping::UNIX);
    }

    #[test]
    fn sst_streams_never_panic(
        flips in proptest::collection::vec((0usize..600, any::<u8>()), 0..6),
        cut in proptest::option::of(0usize..700),
        splice in "\\PC{0,20}",
        at in any::<usize>(),
        chunk in 1usize..64,
        junk in proptest::collection::vec(any::<u8>(), 0..200),
    ) {
        let valid: Vec<u8> = SST.repeat(3).into_bytes();
        let bytes = mutate(&valid, &flips, cut, splice.as_bytes(), at);
        // Fed in pieces, as a socket delivers it.
        let mut parser = SstParser::new();
        for piece in bytes.chunks(chunk).chain(std::iter::once(&junk[..])) {
            for f in parser.feed(piece).into_iter().flatten() {
                if let Ok(frame) = f.to_frame(&timing()) {
                    for d in &frame.doas {
                        prop_assert!((d.direction_in_array.norm() - 1.0).abs() < 1e-9);
                    }
                }
            }
        }
    }

    #[test]
    fn agent_config_text_never_panics(
        flips in proptest::collection::vec((0usize..400, any::<u8>()), 0..4),
        cut in proptest::option::of(0usize..400),
        splice in "\\PC{0,30}",
        at in any::<usize>(),
    ) {
        let bytes = mutate(AGENT_TOML.as_bytes(), &flips, cut, splice.as_bytes(), at);
        let text = String::from_utf8_lossy(&bytes);
        if let Err(e) = AgentConfig::parse(&text, Path::new("agent.toml")) {
            // Errors name the file.
            prop_assert!(e.to_string().contains("agent.toml"), "{e}");
        }
    }
}
