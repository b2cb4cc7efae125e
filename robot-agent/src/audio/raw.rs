//! Raw interleaved PCM (s16le, s24le packed, s32le), as ODAS reads it, from a
//! file, standard input or any byte stream.

use std::io::Read;
use std::path::Path;

use soundmap_proto::Stamp;

use super::pcm::{BlockReader, PcmEncoding};
use super::sniff::{AudioFileKind, open_file, read_kind};
use super::{
    AudioSource, BlockOptions, FrameClock, RawFormat, RawLayout, audio_error, check_block_len, resolve_shape,
};
use crate::AgentError;

/// Raw PCM read block by block from a byte stream.
pub struct RawSource {
    name: String,
    reader: Box<dyn Read + Send>,
    layout: RawLayout,
    map: Vec<usize>,
    hop_len: usize,
    /// Reads and decodes one block at a time.
    blocks: BlockReader,
    clock: FrameClock,
    ended: bool,
    /// Frames in the file (files only).
    frames_total: Option<u64>,
}

impl std::fmt::Debug for RawSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawSource")
            .field("name", &self.name)
            .field("layout", &self.layout)
            .field("map", &self.map)
            .field("hop_len", &self.hop_len)
            .finish_non_exhaustive()
    }
}

impl RawSource {
    /// Opens a raw PCM file. Its length must be a whole number of frames.
    pub fn open_file(path: &Path, layout: RawLayout, options: &BlockOptions) -> Result<Self, AgentError> {
        let io = |source| AgentError::Io { path: path.to_path_buf(), source };
        let mut file = open_file(path)?;
        if read_kind(path, &mut file)? == AudioFileKind::Wav {
            return Err(audio_error(
                path,
                "a WAV file (RIFF/WAVE header), not raw PCM: read it as WAV (its header gives the sample \
                 format, channels and rate)",
            ));
        }
        let len = file.metadata().map_err(io)?.len();
        let frame_bytes = (layout.channels * layout.format.bytes()) as u64;
        if frame_bytes > 0 && len % frame_bytes != 0 {
            return Err(audio_error(
                path,
                format!(
                    "length {len} bytes is not a whole number of frames ({} channels × {} bytes = {frame_bytes} \
                     bytes per frame; {} bytes left over): truncated, or wrong channel count or format?",
                    layout.channels,
                    layout.format.bytes(),
                    len % frame_bytes
                ),
            ));
        }
        let mut source = Self::from_reader(&path.display().to_string(), Box::new(file), layout, options)?;
        source.frames_total = (frame_bytes > 0).then(|| len / frame_bytes);
        Ok(source)
    }

    /// Raw PCM on standard input (named `-` in messages).
    pub fn stdin(layout: RawLayout, options: &BlockOptions) -> Result<Self, AgentError> {
        Self::from_reader("-", Box::new(std::io::stdin()), layout, options)
    }

    /// Raw PCM from any byte stream; `name` is used in messages.
    pub fn from_reader(
        name: &str,
        reader: Box<dyn Read + Send>,
        layout: RawLayout,
        options: &BlockOptions,
    ) -> Result<Self, AgentError> {
        let map = resolve_shape(Path::new(name), layout.channels, layout.sample_rate_hz, options)?;
        let encoding = match layout.format {
            RawFormat::S16le => PcmEncoding::S16,
            RawFormat::S24le => PcmEncoding::S24Packed,
            RawFormat::S32le => PcmEncoding::S32,
        };
        Ok(RawSource {
            name: name.to_owned(),
            reader,
            layout,
            blocks: BlockReader::new(encoding, layout.channels, map.clone(), options.hop_len),
            map,
            hop_len: options.hop_len,
            clock: FrameClock::new(options.start, layout.sample_rate_hz),
            ended: false,
            frames_total: None,
        })
    }
}

impl AudioSource for RawSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn frames_total(&self) -> Option<u64> {
        self.frames_total
    }

    fn channels(&self) -> usize {
        self.map.len()
    }

    fn sample_rate_hz(&self) -> u32 {
        self.layout.sample_rate_hz
    }

    fn hop_len(&self) -> usize {
        self.hop_len
    }

    fn next_block(&mut self, out: &mut [f32]) -> Result<Option<Stamp>, AgentError> {
        let ch = self.map.len();
        check_block_len(&self.name, out, self.hop_len, ch)?;
        if self.ended {
            return Ok(None);
        }
        let n = self
            .blocks
            .fill(&mut *self.reader, usize::MAX)
            .map_err(|source| AgentError::Io { path: self.name.clone().into(), source })?;
        let width = self.layout.format.bytes();
        let frame_bytes = self.blocks.frame_bytes();
        if n < self.hop_len * frame_bytes {
            self.ended = true;
        }
        if n == 0 {
            return Ok(None);
        }
        if n % frame_bytes != 0 {
            return Err(audio_error(
                &self.name,
                format!(
                    "stream ends inside a frame: {} bytes after the last whole frame ({} channels × {width} \
                     bytes per frame): truncated, or wrong channel count or format?",
                    n % frame_bytes,
                    self.layout.channels
                ),
            ));
        }
        let stamp = self.clock.now();
        self.blocks.decode(n / frame_bytes, out);
        self.clock.advance(self.hop_len);
        Ok(Some(stamp))
    }
}
