//! Audio inputs: WAV and raw PCM files written to a temporary directory and read back.

use std::io::Cursor;
use std::path::Path;

use soundmap_agent::AgentError;
use soundmap_agent::audio::{self, AudioInput, AudioSource, BlockOptions, RawFormat, RawLayout, RawSource};
use soundmap_proto::Stamp;

/// A scratch directory for one test, removed when dropped.
fn temp_dir(test: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-audio-{test}-")).tempdir().unwrap()
}

fn options(hop_len: usize, channels: usize, rate: u32) -> BlockOptions {
    BlockOptions { hop_len, channels, sample_rate_hz: rate, channel_map: None, start: Stamp::ZERO }
}

/// Sample value (±1 full scale) of frame `f`, channel `c` in the test signals.
fn value(f: usize, c: usize) -> f64 {
    ((f * 7 + c * 3) % 17) as f64 / 17.0 - 0.5
}

fn write_wav(path: &Path, channels: u16, rate: u32, bits: u16, float: bool, frames: usize) {
    let spec = hound::WavSpec {
        channels,
        sample_rate: rate,
        bits_per_sample: bits,
        sample_format: if float { hound::SampleFormat::Float } else { hound::SampleFormat::Int },
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for f in 0..frames {
        for c in 0..channels as usize {
            if float {
                w.write_sample(value(f, c) as f32).unwrap();
            } else {
                let scale = (1i64 << (bits - 1)) as f64;
                w.write_sample((value(f, c) * scale).round() as i32).unwrap();
            }
        }
    }
    w.finalize().unwrap();
}

/// Reads all blocks; returns (stamps, samples).
fn read_all(src: &mut dyn AudioSource) -> Result<(Vec<Stamp>, Vec<f32>), AgentError> {
    let mut block = vec![0.0; src.hop_len() * src.channels()];
    let (mut stamps, mut all) = (vec![], vec![]);
    while let Some(s) = src.next_block(&mut block)? {
        stamps.push(s);
        all.extend_from_slice(&block);
    }
    Ok((stamps, all))
}

#[test]
fn wav_integer_and_float_formats_read_back_at_full_scale() {
    let dir = temp_dir("formats");
    for (bits, float, tol) in [(16, false, 1e-4), (24, false, 1e-6), (32, false, 1e-7), (32, true, 1e-7)] {
        let path = dir.path().join(format!("t{bits}{float}.wav"));
        write_wav(&path, 3, 16_000, bits, float, 10);
        let mut src = audio::open(&AudioInput::Wav { path: path.clone() }, &options(4, 3, 16_000)).unwrap();
        let (stamps, all) = read_all(src.as_mut()).unwrap();
        // 10 frames in hops of 4: 3 blocks, the last one zero-padded after 2 frames.
        assert_eq!(stamps, vec![Stamp::ZERO, Stamp::from_ns(250_000), Stamp::from_ns(500_000)]);
        assert_eq!(all.len(), 12 * 3);
        for f in 0..12 {
            for c in 0..3 {
                let want = if f < 10 { value(f, c) } else { 0.0 };
                let got = all[f * 3 + c] as f64;
                assert!(
                    (got - want).abs() < tol,
                    "{bits}-bit float={float} frame {f} ch {c}: {got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn channel_map_selects_and_reorders() {
    let dir = temp_dir("map");
    let path = dir.path().join("four.wav");
    write_wav(&path, 4, 8_000, 16, false, 8);
    let opts = BlockOptions { channel_map: Some(vec![3, 0]), ..options(8, 2, 8_000) };
    let mut src = audio::open(&AudioInput::Wav { path }, &opts).unwrap();
    assert_eq!(src.channels(), 2);
    let (_, all) = read_all(src.as_mut()).unwrap();
    for f in 0..8 {
        assert!((all[f * 2] as f64 - value(f, 3)).abs() < 1e-4);
        assert!((all[f * 2 + 1] as f64 - value(f, 0)).abs() < 1e-4);
    }
}

#[test]
fn blocks_are_stamped_from_the_sample_count_and_start() {
    let dir = temp_dir("stamps");
    let path = dir.path().join("s.wav");
    write_wav(&path, 2, 48_000, 16, false, 48_000);
    let start = Stamp::from_ns(1_700_000_000_123_456_789);
    let opts = BlockOptions { start, ..options(480, 2, 48_000) };
    let mut src = audio::open(&AudioInput::Wav { path }, &opts).unwrap();
    let (stamps, _) = read_all(src.as_mut()).unwrap();
    assert_eq!(stamps.len(), 100);
    for (k, s) in stamps.iter().enumerate() {
        assert_eq!(*s, start.plus_ns(k as i64 * 10_000_000), "block {k}");
    }
}

fn raw_bytes(format: RawFormat, channels: usize, frames: usize) -> Vec<u8> {
    let mut out = vec![];
    for f in 0..frames {
        for c in 0..channels {
            let v = value(f, c);
            match format {
                RawFormat::S16le => out.extend_from_slice(&((v * 32_768.0).round() as i16).to_le_bytes()),
                RawFormat::S24le => {
                    out.extend_from_slice(&((v * 8_388_608.0).round() as i32).to_le_bytes()[..3])
                }
                RawFormat::S32le => {
                    out.extend_from_slice(&((v * 2_147_483_648.0).round() as i32).to_le_bytes())
                }
            }
        }
    }
    out
}

#[test]
fn raw_files_in_each_format_read_back() {
    let dir = temp_dir("raw");
    for format in [RawFormat::S16le, RawFormat::S24le, RawFormat::S32le] {
        let path = dir.path().join(format!("x.{}", format.name()));
        std::fs::write(&path, raw_bytes(format, 5, 9)).unwrap();
        let layout = RawLayout { format, channels: 5, sample_rate_hz: 16_000 };
        let mut src = audio::open(&AudioInput::Raw { path, layout }, &options(3, 5, 16_000)).unwrap();
        let (stamps, all) = read_all(src.as_mut()).unwrap();
        assert_eq!(stamps.len(), 3, "{format:?}");
        for f in 0..9 {
            for c in 0..5 {
                assert!((all[f * 5 + c] as f64 - value(f, c)).abs() < 1e-4, "{format:?} {f} {c}");
            }
        }
    }
}

#[test]
fn a_raw_stream_is_read_block_by_block_and_may_end_mid_hop() {
    let layout = RawLayout { format: RawFormat::S16le, channels: 2, sample_rate_hz: 16_000 };
    let bytes = raw_bytes(RawFormat::S16le, 2, 5);
    let mut src =
        RawSource::from_reader("pipe", Box::new(Cursor::new(bytes)), layout, &options(4, 2, 16_000)).unwrap();
    let mut block = vec![9.0; 8];
    assert_eq!(src.next_block(&mut block).unwrap(), Some(Stamp::ZERO));
    assert_eq!(src.next_block(&mut block).unwrap(), Some(Stamp::from_ns(250_000)));
    assert!((block[0] as f64 - value(4, 0)).abs() < 1e-4);
    assert_eq!(&block[2..], &[0.0; 6]);
    assert_eq!(src.next_block(&mut block).unwrap(), None);
}

#[test]
fn truncated_wav_is_named_and_explained() {
    let dir = temp_dir("truncated");
    let path = dir.path().join("cut.wav");
    write_wav(&path, 2, 16_000, 16, false, 100);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 41]).unwrap();
    let e = audio::open(&AudioInput::Wav { path: path.clone() }, &options(4, 2, 16_000)).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, AgentError::Audio { .. }), "{e:?}");
    assert!(msg.contains("cut.wav") && msg.contains("truncated"), "{msg}");
}

#[test]
fn raw_file_that_is_not_whole_frames_is_rejected() {
    let dir = temp_dir("rawcut");
    let path = dir.path().join("cut.raw");
    let mut bytes = raw_bytes(RawFormat::S24le, 4, 10);
    bytes.truncate(bytes.len() - 5);
    std::fs::write(&path, bytes).unwrap();
    let layout = RawLayout { format: RawFormat::S24le, channels: 4, sample_rate_hz: 16_000 };
    let msg = audio::open(&AudioInput::Raw { path, layout }, &options(4, 4, 16_000)).unwrap_err().to_string();
    assert!(msg.contains("cut.raw") && msg.contains("not a whole number of frames"), "{msg}");
    // The same on a stream, found when the stream ends.
    let mut bytes = raw_bytes(RawFormat::S16le, 2, 3);
    bytes.pop();
    let layout = RawLayout { format: RawFormat::S16le, channels: 2, sample_rate_hz: 16_000 };
    let mut src =
        RawSource::from_reader("-", Box::new(Cursor::new(bytes)), layout, &options(4, 2, 16_000)).unwrap();
    let msg = src.next_block(&mut [0.0; 8]).unwrap_err().to_string();
    assert!(msg.starts_with("-: ") && msg.contains("ends inside a frame"), "{msg}");
}

#[test]
fn wrong_channel_count_and_sample_rate_are_rejected() {
    let dir = temp_dir("shape");
    let path = dir.path().join("six.wav");
    write_wav(&path, 6, 16_000, 16, false, 10);
    let input = AudioInput::Wav { path };
    let msg = audio::open(&input, &options(4, 8, 16_000)).unwrap_err().to_string();
    assert!(msg.contains("six.wav") && msg.contains("6 channels, expected 8"), "{msg}");
    let msg = audio::open(&input, &options(4, 6, 48_000)).unwrap_err().to_string();
    assert!(
        msg.contains("six.wav") && msg.contains("16000 Hz does not match the configured 48000 Hz"),
        "{msg}"
    );
    let opts = BlockOptions { channel_map: Some(vec![0, 6]), ..options(4, 2, 16_000) };
    let msg = audio::open(&input, &opts).unwrap_err().to_string();
    assert!(msg.contains("selects channel 6 but the input has 6 channels"), "{msg}");
}

#[test]
fn unsupported_wav_encodings_are_rejected() {
    let dir = temp_dir("unsupported");
    let path = dir.path().join("eight.wav");
    write_wav(&path, 2, 16_000, 8, false, 10);
    let msg = audio::open(&AudioInput::Wav { path }, &options(4, 2, 16_000)).unwrap_err().to_string();
    assert!(msg.contains("eight.wav") && msg.contains("8-bit integer samples are not supported"), "{msg}");

    // A 64-bit float WAV (hound cannot write one): RIFF header by hand.
    let path = dir.path().join("f64.wav");
    let (channels, rate, bits) = (2u16, 16_000u32, 64u16);
    let block_align = channels * bits / 8;
    let data = vec![0u8; 4 * block_align as usize];
    let mut b = vec![];
    b.extend_from_slice(b"RIFF");
    b.extend_from_slice(&(4 + 8 + 16 + 8 + data.len() as u32).to_le_bytes());
    b.extend_from_slice(b"WAVEfmt ");
    b.extend_from_slice(&16u32.to_le_bytes());
    b.extend_from_slice(&3u16.to_le_bytes()); // IEEE float
    b.extend_from_slice(&channels.to_le_bytes());
    b.extend_from_slice(&rate.to_le_bytes());
    b.extend_from_slice(&(rate * block_align as u32).to_le_bytes());
    b.extend_from_slice(&block_align.to_le_bytes());
    b.extend_from_slice(&bits.to_le_bytes());
    b.extend_from_slice(b"data");
    b.extend_from_slice(&(data.len() as u32).to_le_bytes());
    b.extend_from_slice(&data);
    std::fs::write(&path, b).unwrap();
    let msg = audio::open(&AudioInput::Wav { path }, &options(4, 2, 16_000)).unwrap_err().to_string();
    assert!(msg.contains("f64.wav") && msg.contains("not a supported WAV"), "{msg}");

    let msg = audio::open(&AudioInput::Wav { path: dir.path().join("missing.wav") }, &options(4, 2, 16_000))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("missing.wav"), "{msg}");
}

#[test]
fn block_buffer_of_the_wrong_size_is_an_error() {
    let layout = RawLayout { format: RawFormat::S16le, channels: 2, sample_rate_hz: 16_000 };
    let mut src =
        RawSource::from_reader("pipe", Box::new(Cursor::new(vec![0u8; 64])), layout, &options(4, 2, 16_000))
            .unwrap();
    let msg = src.next_block(&mut [0.0; 7]).unwrap_err().to_string();
    assert!(msg.contains("expected hop_len × channels = 4 × 2"), "{msg}");
}

#[cfg(not(feature = "live-capture"))]
#[test]
fn live_capture_without_the_feature_says_so() {
    let layout = RawLayout { format: RawFormat::S32le, channels: 8, sample_rate_hz: 16_000 };
    let msg = audio::open(&AudioInput::Live { device: "hw:1,0".into(), layout }, &options(128, 8, 16_000))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("hw:1,0") && msg.contains("live-capture"), "{msg}");
}

#[test]
fn files_are_recognised_by_their_content_not_their_name() {
    let dir = temp_dir("sniff");
    let layout = RawLayout { format: RawFormat::S16le, channels: 2, sample_rate_hz: 16_000 };
    // A WAV file named .raw is a WAV file.
    let wav_named_raw = dir.path().join("take.raw");
    write_wav(&wav_named_raw, 2, 16_000, 16, false, 10);
    assert_eq!(audio::sniff(&wav_named_raw).unwrap(), audio::AudioFileKind::Wav);
    let input = AudioInput::from_path(&wav_named_raw, None).unwrap();
    assert_eq!(input, AudioInput::Wav { path: wav_named_raw.clone() });
    let (_, samples) = read_all(&mut *audio::open(&input, &options(4, 2, 16_000)).unwrap()).unwrap();
    assert!((samples[1] as f64 - value(0, 1)).abs() < 1e-4);
    // ... and a raw layout for it is a clear error, as is opening it as raw PCM.
    let msg = AudioInput::from_path(&wav_named_raw, Some(layout)).unwrap_err().to_string();
    assert!(msg.contains("take.raw") && msg.contains("a WAV file (RIFF/WAVE header)"), "{msg}");
    let raw = AudioInput::Raw { path: wav_named_raw.clone(), layout };
    let msg = audio::open(&raw, &options(4, 2, 16_000)).unwrap_err().to_string();
    assert!(msg.contains("take.raw") && msg.contains("a WAV file (RIFF/WAVE header), not raw PCM"), "{msg}");

    // Raw PCM named .wav is raw PCM: it needs its layout, and is not read as WAV.
    let raw_named_wav = dir.path().join("take.wav");
    std::fs::write(&raw_named_wav, raw_bytes(RawFormat::S16le, 2, 10)).unwrap();
    assert_eq!(audio::sniff(&raw_named_wav).unwrap(), audio::AudioFileKind::Raw);
    let e = AudioInput::from_path(&raw_named_wav, None).unwrap_err();
    assert!(matches!(e, AgentError::Audio { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!(
            "{}: not a WAV file (no RIFF/WAVE header) despite its .wav name",
            raw_named_wav.display()
        )) && msg.contains("needs its layout"),
        "{msg}"
    );
    let input = AudioInput::from_path(&raw_named_wav, Some(layout)).unwrap();
    assert_eq!(input, AudioInput::Raw { path: raw_named_wav.clone(), layout });
    let (_, samples) = read_all(&mut *audio::open(&input, &options(4, 2, 16_000)).unwrap()).unwrap();
    assert_eq!(samples.len(), 12 * 2);
    let wav = AudioInput::Wav { path: raw_named_wav.clone() };
    let msg = audio::open(&wav, &options(4, 2, 16_000)).unwrap_err().to_string();
    assert!(msg.contains("take.wav") && msg.contains("not a WAV file (no RIFF/WAVE header)"), "{msg}");

    // A file shorter than a header is raw PCM too.
    let tiny = dir.path().join("tiny.pcm");
    std::fs::write(&tiny, [0u8; 4]).unwrap();
    assert_eq!(audio::sniff(&tiny).unwrap(), audio::AudioFileKind::Raw);
    // Standard input is raw PCM and needs its layout.
    assert_eq!(AudioInput::from_path(Path::new("-"), Some(layout)).unwrap(), AudioInput::Stdin { layout });
    assert!(
        AudioInput::from_path(Path::new("-"), None).unwrap_err().to_string().contains("needs its layout")
    );
}

#[test]
fn a_missing_file_says_no_such_file_with_its_path() {
    let dir = temp_dir("missing");
    let layout = RawLayout { format: RawFormat::S16le, channels: 2, sample_rate_hz: 16_000 };
    let path = dir.path().join("nowhere.wav");
    let expected = format!("{}: no such file", path.display());
    for result in [
        AudioInput::from_path(&path, None).map(drop),
        AudioInput::from_path(&path, Some(layout)).map(drop),
        audio::sniff(&path).map(drop),
        audio::open(&AudioInput::Wav { path: path.clone() }, &options(4, 2, 16_000)).map(drop),
        audio::open(&AudioInput::Raw { path: path.clone(), layout }, &options(4, 2, 16_000)).map(drop),
    ] {
        let e = result.unwrap_err();
        assert!(matches!(e, AgentError::Audio { .. }), "{e:?}");
        assert_eq!(e.to_string(), expected);
    }
}
