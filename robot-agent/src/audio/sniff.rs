//! What an audio file holds, told by its content (a RIFF/WAVE header at its
//! start), never by its name: a WAV file named `.raw` is a WAV file, and raw PCM
//! named `.wav` is raw PCM.

use std::fs::File;
use std::io::{ErrorKind, Read, Seek, SeekFrom};
use std::path::Path;

use super::audio_error;
use crate::AgentError;

/// What an audio file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AudioFileKind {
    /// A WAV file: starts with a RIFF/WAVE header.
    Wav,
    /// Anything else, read as raw interleaved PCM (which needs its layout).
    Raw,
}

/// Bytes of a RIFF/WAVE header that identify it: `RIFF`, the size, `WAVE`.
const HEADER_LEN: usize = 12;

/// Whether `start` (the first bytes of a file) is a RIFF/WAVE header.
pub fn is_wav_header(start: &[u8]) -> bool {
    start.len() >= HEADER_LEN && &start[0..4] == b"RIFF" && &start[8..12] == b"WAVE"
}

/// Opens `path` for reading. A missing file is an [`AgentError::Audio`] saying
/// `no such file`; other failures are [`AgentError::Io`]; both name the path.
pub(crate) fn open_file(path: &Path) -> Result<File, AgentError> {
    File::open(path).map_err(|source| match source.kind() {
        ErrorKind::NotFound => audio_error(path, "no such file"),
        _ => AgentError::Io { path: path.to_path_buf(), source },
    })
}

/// Reads the start of `file` (named `path` in errors), tells its kind and
/// rewinds it.
pub(crate) fn read_kind(path: &Path, file: &mut File) -> Result<AudioFileKind, AgentError> {
    let io = |source| AgentError::Io { path: path.to_path_buf(), source };
    let mut start = Vec::with_capacity(HEADER_LEN);
    file.by_ref().take(HEADER_LEN as u64).read_to_end(&mut start).map_err(io)?;
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(if is_wav_header(&start) { AudioFileKind::Wav } else { AudioFileKind::Raw })
}

/// The kind of the file at `path`, from its first bytes.
pub fn sniff(path: &Path) -> Result<AudioFileKind, AgentError> {
    read_kind(path, &mut open_file(path)?)
}

/// Whether the file is named like a WAV file (only to explain errors).
pub(crate) fn named_wav(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("wav"))
}
