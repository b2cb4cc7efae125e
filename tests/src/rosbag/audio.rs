//! A robot's audio from `audio_common_msgs` messages, written as the float
//! WAV file the replay reads.
//!
//! `AudioInfo` gives channels, rate and sample format; each `AudioDataStamped`
//! holds whole interleaved frames whose first sample is at the header stamp.
//! Samples become ±1 full scale: S16LE / 32768, S32LE / 2³¹, F32LE as is. The
//! WAV's timeline is the sample count from the first message's stamp; each
//! message's stamp is checked against the end of the previous one, and a gap
//! (or an overlap) larger than half a message or [`MIN_GAP_TOLERANCE_NS`]
//! is an error naming the topic and the time, since the pipeline cannot
//! localize across missing audio. Slow drift between the sample clock and the
//! stamps is not a gap.

use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::cdr::AudioInfo;
use crate::error::SimError;

/// Smallest jump between messages' stamps and their sample counts that counts as a gap.
pub const MIN_GAP_TOLERANCE_NS: i64 = 5_000_000;

/// The sample encodings soundmap reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleFormat {
    /// Signed 16-bit little endian.
    S16le,
    /// Signed 32-bit little endian.
    S32le,
    /// 32-bit float little endian.
    F32le,
}

impl SampleFormat {
    /// From `AudioInfo.sample_format`.
    pub fn parse(name: &str) -> Result<Self, String> {
        match name.to_ascii_uppercase().as_str() {
            "S16LE" => Ok(SampleFormat::S16le),
            "S32LE" => Ok(SampleFormat::S32le),
            "F32LE" => Ok(SampleFormat::F32le),
            other => Err(format!("sample_format {other:?} is not supported (S16LE, S32LE, F32LE)")),
        }
    }

    /// Bytes per sample.
    pub fn bytes(self) -> usize {
        match self {
            SampleFormat::S16le => 2,
            SampleFormat::S32le | SampleFormat::F32le => 4,
        }
    }

    /// Appends the samples of `bytes` as ±1 full-scale floats.
    pub fn decode(self, bytes: &[u8], out: &mut Vec<f32>) {
        match self {
            SampleFormat::S16le => out
                .extend(bytes.chunks_exact(2).map(|b| f32::from(i16::from_le_bytes([b[0], b[1]])) / 32768.0)),
            SampleFormat::S32le => {
                out.extend(bytes.chunks_exact(4).map(|b| {
                    (f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])) / 2_147_483_648.0) as f32
                }))
            }
            SampleFormat::F32le => {
                out.extend(bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            }
        }
    }
}

/// One robot's audio being written.
pub struct AudioTrack {
    topic: String,
    path: PathBuf,
    format: SampleFormat,
    channels: usize,
    rate: u32,
    writer: hound::WavWriter<BufWriter<std::fs::File>>,
    /// Stamp of the first sample, ns.
    pub first_ns: Option<i64>,
    /// End (stamp + duration) of the last message, ns.
    end_ns: i64,
    frames: u64,
    scratch: Vec<f32>,
}

impl std::fmt::Debug for AudioTrack {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AudioTrack")
            .field("topic", &self.topic)
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

impl AudioTrack {
    /// A WAV at `path` for the audio of `topic` described by `info`.
    pub fn create(topic: &str, info: &AudioInfo, path: &Path) -> Result<Self, SimError> {
        let bad = |m: String| SimError::Replay(format!("{topic}: {m}"));
        let format = SampleFormat::parse(&info.sample_format).map_err(bad)?;
        let coding = info.coding_format.to_ascii_lowercase();
        if !["", "wave", "wav", "raw", "pcm"].contains(&coding.as_str()) {
            return Err(bad(format!(
                "coding_format {:?}: only uncompressed PCM (wave) is read",
                info.coding_format
            )));
        }
        if info.channels == 0 || info.sample_rate == 0 {
            return Err(bad(format!("AudioInfo has {} channels at {} Hz", info.channels, info.sample_rate)));
        }
        let spec = hound::WavSpec {
            channels: u16::from(info.channels),
            sample_rate: info.sample_rate,
            bits_per_sample: 32,
            sample_format: hound::SampleFormat::Float,
        };
        let writer = hound::WavWriter::create(path, spec)
            .map_err(|e| SimError::Replay(format!("{}: {e}", path.display())))?;
        Ok(AudioTrack {
            topic: topic.into(),
            path: path.into(),
            format,
            channels: usize::from(info.channels),
            rate: info.sample_rate,
            writer,
            first_ns: None,
            end_ns: 0,
            frames: 0,
            scratch: Vec::new(),
        })
    }

    /// Appends one message (`stamp_ns` of its first sample).
    pub fn push(&mut self, stamp_ns: i64, bytes: &[u8]) -> Result<(), SimError> {
        let frame_bytes = self.format.bytes() * self.channels;
        if !bytes.len().is_multiple_of(frame_bytes) {
            return Err(SimError::Replay(format!(
                "{}: a message of {} bytes at {stamp_ns} ns is not whole frames of {} channels × {} bytes",
                self.topic,
                bytes.len(),
                self.channels,
                self.format.bytes()
            )));
        }
        let frames = (bytes.len() / frame_bytes) as i64;
        let duration_ns = frames * 1_000_000_000 / i64::from(self.rate);
        if self.first_ns.is_some() {
            let tolerance = (duration_ns / 2).max(MIN_GAP_TOLERANCE_NS);
            let jump = stamp_ns - self.end_ns;
            if jump.abs() > tolerance {
                let what = if jump > 0 { "a gap" } else { "an overlap" };
                return Err(SimError::Replay(format!(
                    "{}: {what} of {:.1} ms in the audio at {:.3} s (message stamped {stamp_ns} ns, previous audio ended at {} ns); the replay needs continuous audio",
                    self.topic,
                    jump.abs() as f64 * 1e-6,
                    (self.end_ns - self.first_ns.unwrap_or(0)) as f64 * 1e-9,
                    self.end_ns
                )));
            }
        } else {
            self.first_ns = Some(stamp_ns);
        }
        self.end_ns = stamp_ns + duration_ns;
        self.scratch.clear();
        self.format.decode(bytes, &mut self.scratch);
        for &s in &self.scratch {
            self.writer
                .write_sample(s)
                .map_err(|e| SimError::Replay(format!("{}: {e}", self.path.display())))?;
        }
        self.frames += frames as u64;
        Ok(())
    }

    /// Finishes the file; returns the frames written.
    pub fn finish(self) -> Result<u64, SimError> {
        self.writer.finalize().map_err(|e| SimError::Replay(format!("{}: {e}", self.path.display())))?;
        Ok(self.frames)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_formats_decode_to_full_scale() {
        let mut out = Vec::new();
        SampleFormat::S16le.decode(&[0x00, 0x80, 0xff, 0x7f, 0x00, 0x40], &mut out);
        assert_eq!(out, [-1.0, 32767.0 / 32768.0, 0.5]);
        out.clear();
        SampleFormat::S32le.decode(&[0, 0, 0, 0x80, 0, 0, 0, 0x40], &mut out);
        assert_eq!(out, [-1.0, 0.5]);
        out.clear();
        SampleFormat::F32le.decode(&0.25f32.to_le_bytes(), &mut out);
        assert_eq!(out, [0.25]);
        assert!(SampleFormat::parse("U8").unwrap_err().contains("S16LE, S32LE, F32LE"));
        assert_eq!(SampleFormat::parse("s16le").unwrap(), SampleFormat::S16le);
    }

    #[test]
    fn a_gap_in_the_audio_is_an_error() {
        let tmp = tempfile::Builder::new().prefix("soundmap-audio-gap-").tempdir().unwrap();
        let dir = tmp.path();
        let info = AudioInfo {
            channels: 2,
            sample_rate: 1000,
            sample_format: "S16LE".into(),
            bitrate: 0,
            coding_format: "wave".into(),
        };
        let mut track = AudioTrack::create("/r1/audio", &info, &dir.join("a.wav")).unwrap();
        let block = vec![0u8; 100 * 4]; // 100 frames: 100 ms
        track.push(0, &block).unwrap();
        track.push(100_000_000, &block).unwrap();
        track.push(201_000_000, &block).unwrap(); // 1 ms of jitter
        let e = track.push(400_000_000, &block).unwrap_err().to_string();
        assert!(e.contains("a gap of 99.0 ms") && e.contains("/r1/audio"), "{e}");
        assert!(track.push(0, &block[..3]).unwrap_err().to_string().contains("whole frames"));
    }
}
