//! Multichannel WAV files through hound: 16/24/32-bit integer PCM and 32-bit float.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use soundmap_proto::Stamp;

use super::sniff::{AudioFileKind, named_wav, open_file, read_kind};
use super::{AudioSource, BlockOptions, FrameClock, audio_error, check_block_len, map_frame, resolve_shape};
use crate::AgentError;

/// How samples are stored in the file.
#[derive(Clone, Copy, Debug)]
enum Encoding {
    /// Integer PCM; divide by `scale` = 2^(bits−1) for ±1 full scale.
    Int { scale: f32 },
    /// IEEE float, already ±1 full scale.
    Float,
}

/// A WAV file read block by block.
pub struct WavSource {
    path: PathBuf,
    name: String,
    reader: hound::WavReader<BufReader<File>>,
    encoding: Encoding,
    map: Vec<usize>,
    hop_len: usize,
    sample_rate_hz: u32,
    /// One input frame, decoded (all file channels).
    frame: Vec<f32>,
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
        check_not_truncated(path, &mut file)?;
        let reader = hound::WavReader::new(BufReader::new(file)).map_err(|e| match e {
            hound::Error::IoError(source) => AgentError::Io { path: path.to_path_buf(), source },
            hound::Error::Unsupported => audio_error(path, format!("unsupported WAV encoding ({SUPPORTED})")),
            other => audio_error(path, format!("not a supported WAV file: {other} ({SUPPORTED})")),
        })?;
        let spec = reader.spec();
        let encoding = match (spec.sample_format, spec.bits_per_sample) {
            (hound::SampleFormat::Int, bits @ (16 | 24 | 32)) => {
                Encoding::Int { scale: (1u64 << (bits - 1)) as f32 }
            }
            (hound::SampleFormat::Float, 32) => Encoding::Float,
            (hound::SampleFormat::Int, bits) => {
                return Err(audio_error(
                    path,
                    format!("{bits}-bit integer samples are not supported ({SUPPORTED})"),
                ));
            }
            (hound::SampleFormat::Float, bits) => {
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
            reader,
            encoding,
            map,
            hop_len: options.hop_len,
            sample_rate_hz: spec.sample_rate,
            frame: vec![0.0; in_channels],
            clock: FrameClock::new(options.start, spec.sample_rate),
            frames_read: 0,
        })
    }

    /// Frames (samples per channel) the header declares.
    pub fn frames_total(&self) -> u64 {
        self.frames_total
    }

    fn read_frame(&mut self) -> Result<(), AgentError> {
        let truncated = |path: &Path, frames_read: u64, total: u64, e: hound::Error| match e {
            hound::Error::IoError(ref io) if io.kind() == std::io::ErrorKind::UnexpectedEof => audio_error(
                path,
                format!(
                    "truncated: the data chunk declares {total} frames but the file ends after {frames_read}"
                ),
            ),
            hound::Error::IoError(source) => AgentError::Io { path: path.to_path_buf(), source },
            other => audio_error(path, format!("bad sample data: {other}")),
        };
        match self.encoding {
            Encoding::Int { scale } => {
                let mut samples = self.reader.samples::<i32>();
                for v in self.frame.iter_mut() {
                    let s = samples.next().unwrap_or_else(|| {
                        Err(hound::Error::IoError(std::io::ErrorKind::UnexpectedEof.into()))
                    });
                    *v = s.map_err(|e| truncated(&self.path, self.frames_read, self.frames_total, e))? as f32
                        / scale;
                }
            }
            Encoding::Float => {
                let mut samples = self.reader.samples::<f32>();
                for v in self.frame.iter_mut() {
                    let s = samples.next().unwrap_or_else(|| {
                        Err(hound::Error::IoError(std::io::ErrorKind::UnexpectedEof.into()))
                    });
                    *v = s.map_err(|e| truncated(&self.path, self.frames_read, self.frames_total, e))?;
                }
            }
        }
        self.frames_read += 1;
        Ok(())
    }
}

const SUPPORTED: &str = "supported: 16, 24 or 32-bit integer PCM, 32-bit float";

impl AudioSource for WavSource {
    fn name(&self) -> &str {
        &self.name
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
        let stamp = self.clock.now();
        for f in 0..self.hop_len {
            let dst = &mut out[f * ch..(f + 1) * ch];
            if self.frames_read < self.frames_total {
                self.read_frame()?;
                map_frame(&self.frame, &self.map, dst);
            } else {
                dst.fill(0.0);
            }
        }
        self.clock.advance(self.hop_len);
        Ok(Some(stamp))
    }
}

/// Walks the RIFF chunks to the `data` chunk and checks the file holds all the
/// bytes its header declares, so that a truncated file fails before any audio is read.
/// Files that are not RIFF/WAVE were rejected before.
fn check_not_truncated(path: &Path, file: &mut File) -> Result<(), AgentError> {
    let io = |source| AgentError::Io { path: path.to_path_buf(), source };
    let file_len = file.metadata().map_err(io)?.len();
    let mut header = [0u8; 12];
    if file.read_exact(&mut header).is_err() || &header[0..4] != b"RIFF" || &header[8..12] != b"WAVE" {
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        return Ok(());
    }
    let mut pos = 12u64;
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
            break;
        }
        pos += 8 + len + (len & 1);
        if file.seek(SeekFrom::Start(pos)).is_err() {
            break;
        }
    }
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(())
}
