//! Multichannel WAV files: 16/24/32-bit integer PCM and 32-bit float.
//!
//! hound parses the header (format, extensible format, chunks up to `data`);
//! the samples are then read in blocks of bytes and decoded in bulk
//! ([`super::pcm`]), as raw PCM is, rather than one call per sample.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use soundmap_proto::Stamp;

use super::pcm::{BlockReader, PcmEncoding};
use super::sniff::{AudioFileKind, named_wav, open_file, read_kind};
use super::{AudioSource, BlockOptions, FrameClock, audio_error, check_block_len, resolve_shape};
use crate::AgentError;

/// A WAV file read block by block.
pub struct WavSource {
    path: PathBuf,
    name: String,
    /// The file, positioned in the `data` chunk.
    reader: BufReader<File>,
    encoding: PcmEncoding,
    map: Vec<usize>,
    hop_len: usize,
    sample_rate_hz: u32,
    /// Reads and decodes one block at a time.
    blocks: BlockReader,
    clock: FrameClock,
    frames_total: u64,
    frames_read: u64,
}

impl std::fmt::Debug for WavSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WavSource")
            .field("path", &self.path)
            .field("encoding", &self.encoding)
            .field("map", &self.map)
            .field("hop_len", &self.hop_len)
            .field("frames_read", &self.frames_read)
            .field("frames_total", &self.frames_total)
            .finish_non_exhaustive()
    }
}

impl WavSource {
    /// Opens `path` and checks its format, sample rate and channels against `options`.
    pub fn open(path: &Path, options: &BlockOptions) -> Result<Self, AgentError> {
        let mut file = open_file(path)?;
        if read_kind(path, &mut file)? != AudioFileKind::Wav {
            return Err(audio_error(
                path,
                format!(
                    "not a WAV file (no RIFF/WAVE header){}: if it is raw PCM, read it as raw with its \
                     layout (sample format, channels and rate)",
                    if named_wav(path) { " despite its .wav name" } else { "" }
                ),
            ));
        }
        let data_len = check_not_truncated(path, &mut file)?;
        let reader = hound::WavReader::new(BufReader::new(file)).map_err(|e| match e {
            hound::Error::IoError(source) => AgentError::Io { path: path.to_path_buf(), source },
            hound::Error::Unsupported => audio_error(path, format!("unsupported WAV encoding ({SUPPORTED})")),
            other => audio_error(path, format!("not a supported WAV file: {other} ({SUPPORTED})")),
        })?;
        let spec = reader.spec();
        // Container bytes per sample: the data chunk's length over its samples
        // (hound checked it divides exactly).
        let width = data_len.zip((reader.len() > 0).then_some(reader.len() as u64)).map(|(d, n)| d / n);
        let encoding = match (spec.sample_format, spec.bits_per_sample, width) {
            (hound::SampleFormat::Int, 16, None | Some(2)) => PcmEncoding::S16,
            (hound::SampleFormat::Int, 24, None | Some(3)) => PcmEncoding::S24Packed,
            (hound::SampleFormat::Int, 24, Some(4)) => PcmEncoding::S24In32,
            (hound::SampleFormat::Int, 32, None | Some(4)) => PcmEncoding::S32,
            (hound::SampleFormat::Float, 32, None | Some(4)) => PcmEncoding::F32,
            (format, bits @ (16 | 24 | 32), Some(width)) => {
                return Err(audio_error(
                    path,
                    format!(
                        "{bits}-bit {} samples in {width}-byte containers are not supported ({SUPPORTED})",
                        if format == hound::SampleFormat::Int { "integer" } else { "float" }
                    ),
                ));
            }
            (hound::SampleFormat::Int, bits, _) => {
                return Err(audio_error(
                    path,
                    format!("{bits}-bit integer samples are not supported ({SUPPORTED})"),
                ));
            }
            (hound::SampleFormat::Float, bits, _) => {
                return Err(audio_error(
                    path,
                    format!("{bits}-bit float samples are not supported ({SUPPORTED})"),
                ));
            }
        };
        let in_channels = spec.channels as usize;
        let map = resolve_shape(path, in_channels, spec.sample_rate, options)?;
        Ok(WavSource {
            path: path.to_path_buf(),
            name: path.display().to_string(),
            frames_total: reader.duration() as u64,
            reader: reader.into_inner(),
            encoding,
            blocks: BlockReader::new(encoding, in_channels, map.clone(), options.hop_len),
            map,
            hop_len: options.hop_len,
            sample_rate_hz: spec.sample_rate,
            clock: FrameClock::new(options.start, spec.sample_rate),
            frames_read: 0,
        })
    }

    /// Frames (samples per channel) the header declares.
    pub fn frames_total(&self) -> u64 {
        self.frames_total
    }
}

const SUPPORTED: &str = "supported: 16, 24 or 32-bit integer PCM, 32-bit float";

impl AudioSource for WavSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn frames_total(&self) -> Option<u64> {
        Some(self.frames_total)
    }

    fn channels(&self) -> usize {
        self.map.len()
    }

    fn sample_rate_hz(&self) -> u32 {
        self.sample_rate_hz
    }

    fn hop_len(&self) -> usize {
        self.hop_len
    }

    fn next_block(&mut self, out: &mut [f32]) -> Result<Option<Stamp>, AgentError> {
        let ch = self.map.len();
        check_block_len(&self.name, out, self.hop_len, ch)?;
        if self.frames_read >= self.frames_total {
            return Ok(None);
        }
        let frames = (self.frames_total - self.frames_read).min(self.hop_len as u64) as usize;
        let frame_bytes = self.blocks.frame_bytes();
        let n = self
            .blocks
            .fill(&mut self.reader, frames * frame_bytes)
            .map_err(|source| AgentError::Io { path: self.path.clone(), source })?;
        if n < frames * frame_bytes {
            return Err(audio_error(
                &self.path,
                format!(
                    "truncated: the data chunk declares {} frames but the file ends after {}",
                    self.frames_total,
                    self.frames_read + (n / frame_bytes) as u64
                ),
            ));
        }
        let stamp = self.clock.now();
        self.blocks.decode(frames, out);
        self.frames_read += frames as u64;
        self.clock.advance(self.hop_len);
        Ok(Some(stamp))
    }
}

/// Walks the RIFF chunks to the `data` chunk and checks the file holds all the
/// bytes its header declares, so that a truncated file fails before any audio is read.
/// Files that are not RIFF/WAVE were rejected before. Returns the `data`
/// chunk's length in bytes, if one was found.
fn check_not_truncated(path: &Path, file: &mut File) -> Result<Option<u64>, AgentError> {
    let io = |source| AgentError::Io { path: path.to_path_buf(), source };
    let file_len = file.metadata().map_err(io)?.len();
    let mut header = [0u8; 12];
    if file.read_exact(&mut header).is_err() || &header[0..4] != b"RIFF" || &header[8..12] != b"WAVE" {
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        return Ok(None);
    }
    let mut pos = 12u64;
    let mut data_len = None;
    loop {
        let mut chunk = [0u8; 8];
        if file.read_exact(&mut chunk).is_err() {
            break; // no data chunk: hound reports it
        }
        let len = u32::from_le_bytes([chunk[4], chunk[5], chunk[6], chunk[7]]) as u64;
        if &chunk[0..4] == b"data" {
            let available = file_len.saturating_sub(pos + 8);
            if available < len {
                return Err(audio_error(
                    path,
                    format!(
                        "truncated: the data chunk declares {len} bytes but only {available} bytes follow \
                         (file cut short while writing?)"
                    ),
                ));
            }
            data_len = Some(len);
            break;
        }
        pos += 8 + len + (len & 1);
        if file.seek(SeekFrom::Start(pos)).is_err() {
            break;
        }
    }
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(data_len)
}
