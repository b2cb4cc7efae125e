//! Writes a simulated run as a recorded trial: per robot a multichannel WAV
//! (32-bit float) and a TUM file of the poses its agent saw at each DoA
//! stamp, and a TUM file of each true source's path ([`source_tum_name`]) —
//! what `soundmap-sim replay` reads back (`replay-command.txt` gives the call,
//! with each source's on/off intervals).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};
use soundmap_proto::Stamp;

use crate::error::SimError;

/// Formats nanoseconds since the start as exact TUM seconds.
pub fn tum_time(ns: i64) -> String {
    let sign = if ns < 0 { "-" } else { "" };
    let a = ns.unsigned_abs();
    format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000)
}

/// One TUM line for a pose (values printed in full precision, so they read back exactly).
pub fn tum_line(ns: i64, pose: &Isometry3<f64>) -> String {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    format!("{} {} {} {} {} {} {} {}", tum_time(ns), t.x, t.y, t.z, q.i, q.j, q.k, q.w)
}

/// A recorder of one robot's audio and poses.
pub struct RobotRecorder {
    wav: hound::WavWriter<BufWriter<File>>,
    tum: BufWriter<File>,
    wav_path: PathBuf,
    tum_path: PathBuf,
}

impl std::fmt::Debug for RobotRecorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotRecorder").field("wav", &self.wav_path).field("tum", &self.tum_path).finish()
    }
}

impl RobotRecorder {
    /// Creates `dir/ID.wav` and `dir/ID.tum`.
    pub fn create(dir: &Path, id: &str, channels: usize, sample_rate_hz: u32) -> Result<Self, SimError> {
        let wav_path = dir.join(format!("{id}.wav"));
        let tum_path = dir.join(format!("{id}.tum"));
        let spec = hound::WavSpec {
            channels: channels as u16,
            sample_rate: sample_rate_hz,
            bits_per_sample: 32,
            sample_format: hound::SampleFormat::Float,
        };
        let wav = hound::WavWriter::create(&wav_path, spec)
            .map_err(|source| SimError::Wav { path: wav_path.clone(), source })?;
        let mut tum = BufWriter::new(File::create(&tum_path).map_err(|e| SimError::file(&tum_path, e))?);
        writeln!(
            tum,
            "# {id}: map_from_base as the agent saw it (SLAM), at each DoA stamp; t in s from the start"
        )
        .map_err(|e| SimError::file(&tum_path, e))?;
        Ok(RobotRecorder { wav, tum, wav_path, tum_path })
    }

    /// Appends interleaved samples.
    pub fn audio(&mut self, interleaved: &[f32]) -> Result<(), SimError> {
        for s in interleaved {
            self.wav
                .write_sample(*s)
                .map_err(|source| SimError::Wav { path: self.wav_path.clone(), source })?;
        }
        Ok(())
    }

    /// Appends a pose at `stamp` (relative to `t0`).
    pub fn pose(&mut self, stamp: Stamp, t0: Stamp, pose: &Isometry3<f64>) -> Result<(), SimError> {
        writeln!(self.tum, "{}", tum_line(stamp - t0, pose)).map_err(|e| SimError::file(&self.tum_path, e))
    }

    /// Flushes both files.
    pub fn finish(self) -> Result<(), SimError> {
        let wav_path = self.wav_path.clone();
        self.wav.finalize().map_err(|source| SimError::Wav { path: wav_path, source })?;
        let mut tum = self.tum;
        tum.flush().map_err(|e| SimError::file(&self.tum_path, e))
    }
}

/// File name of source `k`'s true path in a recording: `source.tum` for
/// source 0 (as single-source recordings always had), `source-K.tum` after it.
pub fn source_tum_name(k: usize) -> String {
    if k == 0 { "source.tum".into() } else { format!("source-{k}.tum") }
}

/// Writes the true source path as TUM (identity orientation).
pub fn write_source_tum(path: &Path, samples: &[(i64, Point3<f64>)]) -> Result<(), SimError> {
    let mut out = BufWriter::new(File::create(path).map_err(|e| SimError::file(path, e))?);
    let io = |e: std::io::Error| SimError::file(path, e);
    writeln!(out, "# true source position; t in s from the start").map_err(io)?;
    for (ns, p) in samples {
        writeln!(out, "{} {} {} {} 0 0 0 1", tum_time(*ns), p.x, p.y, p.z).map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tum_times_are_exact() {
        assert_eq!(tum_time(1_500_000_001), "1.500000001");
        assert_eq!(tum_time(8_000_000), "0.008000000");
        assert_eq!(tum_time(-2), "-0.000000002");
    }
}
