//! Raw interleaved PCM (s16le, s24le packed, s32le), as ODAS reads it, from a
//! file, standard input or any byte stream.

use std::io::{ErrorKind, Read};
use std::path::Path;

use soundmap_proto::Stamp;

use super::sniff::{AudioFileKind, open_file, read_kind};
use super::{
    AudioSource, BlockOptions, FrameClock, RawLayout, audio_error, check_block_len, map_frame, resolve_shape,
};
use crate::AgentError;

/// Raw PCM read block by block from a byte stream.
pub struct RawSource {
    name: String,
    reader: Box<dyn Read + Send>,
    layout: RawLayout,
    map: Vec<usize>,
    hop_len: usize,
    /// One block of input bytes.
    bytes: Vec<u8>,
    /// One input frame, decoded (all stream channels).
    frame: Vec<f32>,
    clock: FrameClock,
    ended: bool,
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
        Self::from_reader(&path.display().to_string(), Box::new(file), layout, options)
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
        Ok(RawSource {
            name: name.to_owned(),
            reader,
            layout,
            map,
            hop_len: options.hop_len,
            bytes: vec![0; options.hop_len * layout.channels * layout.format.bytes()],
            frame: vec![0.0; layout.channels],
            clock: FrameClock::new(options.start, layout.sample_rate_hz),
            ended: false,
        })
    }

    /// Reads until the block buffer is full or the stream ends; returns the bytes read.
    fn fill(&mut self) -> Result<usize, AgentError> {
        let mut n = 0;
        while n < self.bytes.len() {
            match self.reader.read(&mut self.bytes[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(source) => return Err(AgentError::Io { path: self.name.clone().into(), source }),
            }
        }
        Ok(n)
    }
}

impl AudioSource for RawSource {
    fn name(&self) -> &str {
        &self.name
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
        let n = self.fill()?;
        let width = self.layout.format.bytes();
        let frame_bytes = self.layout.channels * width;
        if n < self.bytes.len() {
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
        let frames = n / frame_bytes;
        let stamp = self.clock.now();
        for f in 0..self.hop_len {
            let dst = &mut out[f * ch..(f + 1) * ch];
            if f < frames {
                let src = &self.bytes[f * frame_bytes..(f + 1) * frame_bytes];
                for (v, b) in self.frame.iter_mut().zip(src.chunks_exact(width)) {
                    *v = self.layout.format.decode(b);
                }
                map_frame(&self.frame, &self.map, dst);
            } else {
                dst.fill(0.0);
            }
        }
        self.clock.advance(self.hop_len);
        Ok(Some(stamp))
    }
}
