//! Audio inputs: multichannel WAV, raw interleaved PCM as ODAS reads it (from a
//! file or standard input) and live capture (feature `live-capture`).
//!
//! Every source delivers **blocks of `hop_len` frames**, interleaved `f32` with
//! ±1 full scale, after the channel map has been applied (output channel `k` is
//! input channel `map[k]`). Each block is stamped with the time of its **first
//! sample**: `start + frames_before / sample_rate_hz`, computed from the sample
//! count, never from the wall clock. The last block of a finite input is
//! zero-padded when the input does not end on a hop boundary, so that no
//! sample is lost.
//!
//! A file's kind is told by its content, not its name ([`AudioInput::from_path`],
//! [`sniff()`]): a RIFF/WAVE header makes a WAV file, anything else is raw PCM,
//! which needs its layout. A WAV file opened as raw PCM, or raw PCM opened as
//! WAV, is an error rather than noise.
//!
//! Bad input is an [`AgentError::Audio`] naming the file (`-` for standard
//! input) and the problem: truncated data, a channel count or sample rate that
//! differs from the configured one, an unsupported sample format, a missing
//! file (`no such file`).

mod live;
mod pcm;
mod raw;
mod sniff;
mod wav;

use std::path::{Path, PathBuf};

use soundmap_proto::Stamp;

use crate::AgentError;

pub use live::LiveSource;
pub use raw::RawSource;
pub use sniff::{AudioFileKind, is_wav_header, sniff};
pub use wav::WavSource;

/// A stream of stamped, fixed-size multichannel audio blocks.
pub trait AudioSource: Send + std::fmt::Debug {
    /// Name for messages: the file path, `-` for standard input, the device for live capture.
    fn name(&self) -> &str;
    /// Channels per frame after the channel map.
    fn channels(&self) -> usize;
    /// Sample rate, Hz.
    fn sample_rate_hz(&self) -> u32;
    /// Frames per block.
    fn hop_len(&self) -> usize;
    /// Fills `out` (exactly `hop_len() * channels()` values, interleaved, ±1 full
    /// scale) with the next block and returns the stamp of its first sample, or
    /// `None` at the end of the input. Does not allocate.
    fn next_block(&mut self, out: &mut [f32]) -> Result<Option<Stamp>, AgentError>;
    /// Frames in the whole input, where it is known before reading (files).
    fn frames_total(&self) -> Option<u64> {
        None
    }
}

/// Sample encodings of raw PCM, as ODAS names them in its `raw` section.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RawFormat {
    /// Signed 16-bit little-endian (2 bytes).
    S16le,
    /// Signed 24-bit little-endian, packed in 3 bytes (ALSA's `S24_3LE`; what ODAS
    /// reads for `nBits = 24`).
    S24le,
    /// Signed 32-bit little-endian (4 bytes).
    S32le,
}

impl RawFormat {
    /// Bytes per sample.
    pub fn bytes(self) -> usize {
        match self {
            RawFormat::S16le => 2,
            RawFormat::S24le => 3,
            RawFormat::S32le => 4,
        }
    }

    /// Decodes one sample (`bytes()` long) to ±1 full scale.
    #[inline]
    pub fn decode(self, b: &[u8]) -> f32 {
        match self {
            RawFormat::S16le => i16::from_le_bytes([b[0], b[1]]) as f32 / 32_768.0,
            RawFormat::S24le => (i32::from_le_bytes([0, b[0], b[1], b[2]]) >> 8) as f32 / 8_388_608.0,
            RawFormat::S32le => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32 / 2_147_483_648.0,
        }
    }

    /// The name used on the command line and in `agent.toml`.
    pub fn name(self) -> &'static str {
        match self {
            RawFormat::S16le => "s16le",
            RawFormat::S24le => "s24le",
            RawFormat::S32le => "s32le",
        }
    }
}

impl std::str::FromStr for RawFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "s16le" => Ok(RawFormat::S16le),
            "s24le" => Ok(RawFormat::S24le),
            "s32le" => Ok(RawFormat::S32le),
            other => Err(format!("unknown raw sample format {other:?} (expected s16le, s24le or s32le)")),
        }
    }
}

/// Where the audio comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum AudioInput {
    /// A WAV file (16/24/32-bit integer or 32-bit float); shape and rate come from its header.
    Wav {
        /// The file.
        path: PathBuf,
    },
    /// A raw interleaved PCM file.
    Raw {
        /// The file.
        path: PathBuf,
        /// The stream's layout.
        layout: RawLayout,
    },
    /// Raw interleaved PCM on standard input.
    Stdin {
        /// The stream's layout.
        layout: RawLayout,
    },
    /// A sound card (feature `live-capture`).
    Live {
        /// ALSA device name, e.g. `hw:1,0`.
        device: String,
        /// The capture layout.
        layout: RawLayout,
    },
}

impl AudioInput {
    /// The input read from `path`, told by the file's content: a WAV file when it
    /// starts with a RIFF/WAVE header (whatever its name), raw PCM with layout
    /// `raw` otherwise; `-` is raw PCM on standard input.
    ///
    /// Errors name the path: a missing file (`no such file`), a layout given for
    /// a WAV file (its header gives one), raw PCM without a layout.
    pub fn from_path(path: &Path, raw: Option<RawLayout>) -> Result<AudioInput, AgentError> {
        if path == Path::new("-") {
            let layout = raw.ok_or_else(|| {
                audio_error(
                    path,
                    "raw PCM on standard input needs its layout: sample format, channels and rate",
                )
            })?;
            return Ok(AudioInput::Stdin { layout });
        }
        match (sniff(path)?, raw) {
            (AudioFileKind::Wav, None) => Ok(AudioInput::Wav { path: path.to_path_buf() }),
            (AudioFileKind::Wav, Some(_)) => Err(audio_error(
                path,
                "a WAV file (RIFF/WAVE header): its header gives the sample format, channels and rate, \
                 so a raw PCM layout is not used for it; remove the layout",
            )),
            (AudioFileKind::Raw, Some(layout)) => Ok(AudioInput::Raw { path: path.to_path_buf(), layout }),
            (AudioFileKind::Raw, None) => Err(audio_error(
                path,
                format!(
                    "not a WAV file (no RIFF/WAVE header){}, so raw PCM, which needs its layout: \
                     sample format, channels and rate",
                    if sniff::named_wav(path) { " despite its .wav name" } else { "" }
                ),
            )),
        }
    }
}

/// Layout of a raw PCM stream: what a WAV header would say.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawLayout {
    /// Sample encoding.
    pub format: RawFormat,
    /// Channels per frame in the stream (before the channel map).
    pub channels: usize,
    /// Sample rate, Hz.
    pub sample_rate_hz: u32,
}

/// What the consumer expects from a source and how to stamp it.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockOptions {
    /// Frames per block.
    pub hop_len: usize,
    /// Channels per block frame expected by the consumer (after the channel map).
    pub channels: usize,
    /// Sample rate expected by the consumer, Hz; a source with another rate is an error.
    pub sample_rate_hz: u32,
    /// Input channel feeding each output channel; `None` is the identity.
    pub channel_map: Option<Vec<usize>>,
    /// Time of sample 0.
    pub start: Stamp,
}

/// Opens `input` as a block source shaped by `options`.
pub fn open(input: &AudioInput, options: &BlockOptions) -> Result<Box<dyn AudioSource>, AgentError> {
    Ok(match input {
        AudioInput::Wav { path } => Box::new(WavSource::open(path, options)?),
        AudioInput::Raw { path, layout } => Box::new(RawSource::open_file(path, *layout, options)?),
        AudioInput::Stdin { layout } => Box::new(RawSource::stdin(*layout, options)?),
        AudioInput::Live { device, layout } => Box::new(LiveSource::open(device, *layout, options)?),
    })
}

/// Parses a channel map written as `0,1,2,…` (spaces allowed).
pub fn parse_channel_map(s: &str) -> Result<Vec<usize>, String> {
    s.split(',')
        .map(|t| {
            let t = t.trim();
            t.parse::<usize>().map_err(|_| format!("{t:?} is not a channel index (expected e.g. 0,1,2,3)"))
        })
        .collect()
}

pub(crate) fn audio_error(path: impl AsRef<Path>, message: impl Into<String>) -> AgentError {
    AgentError::Audio { path: path.as_ref().to_path_buf(), message: message.into() }
}

/// Checks an input's shape against `options` and returns the resolved channel map.
pub(crate) fn resolve_shape(
    name: &Path,
    input_channels: usize,
    input_rate_hz: u32,
    options: &BlockOptions,
) -> Result<Vec<usize>, AgentError> {
    if options.hop_len == 0 {
        return Err(audio_error(name, "hop length must be at least 1 frame"));
    }
    if input_rate_hz != options.sample_rate_hz {
        return Err(audio_error(
            name,
            format!(
                "sample rate {input_rate_hz} Hz does not match the configured {} Hz",
                options.sample_rate_hz
            ),
        ));
    }
    if input_channels == 0 {
        return Err(audio_error(name, "zero channels"));
    }
    let map = match &options.channel_map {
        None => {
            if input_channels != options.channels {
                return Err(audio_error(
                    name,
                    format!(
                        "{input_channels} channels, expected {} (give a channel map to select channels)",
                        options.channels
                    ),
                ));
            }
            (0..input_channels).collect()
        }
        Some(map) => {
            if map.len() != options.channels {
                return Err(audio_error(
                    name,
                    format!("channel map has {} entries, expected {}", map.len(), options.channels),
                ));
            }
            if let Some((k, &c)) = map.iter().enumerate().find(|&(_, &c)| c >= input_channels) {
                return Err(audio_error(
                    name,
                    format!(
                        "channel map entry {k} selects channel {c} but the input has {input_channels} \
                         channels (0 to {})",
                        input_channels - 1
                    ),
                ));
            }
            map.clone()
        }
    };
    Ok(map)
}

/// Stamps blocks from the number of frames read so far.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FrameClock {
    start: Stamp,
    sample_rate_hz: u32,
    frames: u64,
}

impl FrameClock {
    pub(crate) fn new(start: Stamp, sample_rate_hz: u32) -> Self {
        FrameClock { start, sample_rate_hz, frames: 0 }
    }

    /// Stamp of the next frame to be read.
    pub(crate) fn now(&self) -> Stamp {
        stamp_of_frame(self.start, self.frames, self.sample_rate_hz)
    }

    pub(crate) fn advance(&mut self, frames: usize) {
        self.frames += frames as u64;
    }
}

/// Time of frame `index` of a stream whose frame 0 is at `start`, rounded to the nanosecond.
pub fn stamp_of_frame(start: Stamp, index: u64, sample_rate_hz: u32) -> Stamp {
    let rate = sample_rate_hz.max(1) as u128;
    let ns = (index as u128 * 1_000_000_000 + rate / 2) / rate;
    start.plus_ns(ns.min(i64::MAX as u128) as i64)
}

/// Checks that a block buffer has the size `next_block` requires.
pub(crate) fn check_block_len(
    name: &str,
    out: &[f32],
    hop_len: usize,
    channels: usize,
) -> Result<(), AgentError> {
    if out.len() != hop_len * channels {
        return Err(audio_error(
            name,
            format!(
                "block buffer holds {} values, expected hop_len × channels = {hop_len} × {channels}",
                out.len()
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_full_scale() {
        assert_eq!(RawFormat::S16le.decode(&i16::MIN.to_le_bytes()), -1.0);
        assert_eq!(RawFormat::S16le.decode(&16_384i16.to_le_bytes()), 0.5);
        let b = (-4_194_304i32).to_le_bytes(); // −2^22 in 24 bits = −0.5
        assert_eq!(RawFormat::S24le.decode(&b[..3]), -0.5);
        let b = 8_388_607i32.to_le_bytes();
        assert!((RawFormat::S24le.decode(&b[..3]) - 1.0).abs() < 1e-6);
        assert_eq!(RawFormat::S32le.decode(&i32::MIN.to_le_bytes()), -1.0);
    }

    #[test]
    fn stamps_from_sample_count() {
        let s = Stamp::from_ns(1_000);
        assert_eq!(stamp_of_frame(s, 0, 16_000), s);
        assert_eq!(stamp_of_frame(s, 16_000, 16_000), s.plus_ns(1_000_000_000));
        // 1 frame at 48 kHz is 20833.33 ns: rounded, and no drift after a day.
        assert_eq!(stamp_of_frame(s, 1, 48_000), s.plus_ns(20_833));
        let day = 48_000u64 * 86_400;
        assert_eq!(stamp_of_frame(s, day, 48_000), s.plus_ns(86_400_000_000_000));
    }

    #[test]
    fn channel_maps() {
        assert_eq!(parse_channel_map("3, 0,1").unwrap(), vec![3, 0, 1]);
        assert!(parse_channel_map("0,x").unwrap_err().contains("\"x\""));
        let opts = BlockOptions {
            hop_len: 4,
            channels: 2,
            sample_rate_hz: 16_000,
            channel_map: Some(vec![1, 5]),
            start: Stamp::ZERO,
        };
        let e = resolve_shape(Path::new("a.wav"), 4, 16_000, &opts).unwrap_err().to_string();
        assert!(e.contains("a.wav") && e.contains("selects channel 5"), "{e}");
    }
}
