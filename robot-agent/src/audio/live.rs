//! Live capture from a sound card (feature `live-capture`).
//!
//! With the feature on, capture runs ALSA's `arecord` (package `alsa-utils`) as a
//! child process writing raw interleaved PCM to a pipe, read like any raw stream:
//! no native audio library is linked. The first sample is stamped with the
//! `start` given in the options (the caller passes the time capture starts);
//! later blocks follow from the sample count, so clock drift between the sound
//! card and the system clock accumulates and is not corrected here.
//! Without the feature, opening a live source is an error saying so.

use super::{AudioSource, BlockOptions, RawLayout};
use crate::AgentError;

#[cfg(feature = "live-capture")]
mod imp {
    use std::process::{Child, Command, Stdio};

    use soundmap_proto::Stamp;

    use super::super::{RawFormat, RawSource, audio_error};
    use super::*;

    /// A sound card captured through `arecord`.
    #[derive(Debug)]
    pub struct LiveSource {
        child: Child,
        raw: RawSource,
    }

    impl LiveSource {
        /// Starts capturing `layout` from ALSA device `device` (e.g. `hw:1,0`).
        pub fn open(device: &str, layout: RawLayout, options: &BlockOptions) -> Result<Self, AgentError> {
            let format = match layout.format {
                RawFormat::S16le => "S16_LE",
                RawFormat::S24le => "S24_3LE",
                RawFormat::S32le => "S32_LE",
            };
            let mut child = Command::new("arecord")
                .args(["-q", "-t", "raw", "-D", device, "-f", format])
                .args(["-c", &layout.channels.to_string(), "-r", &layout.sample_rate_hz.to_string()])
                .stdout(Stdio::piped())
                .stdin(Stdio::null())
                .spawn()
                .map_err(|e| {
                    audio_error(device, format!("cannot start arecord (install alsa-utils): {e}"))
                })?;
            let stdout = child.stdout.take().ok_or_else(|| audio_error(device, "arecord has no stdout"))?;
            let raw = RawSource::from_reader(device, Box::new(stdout), layout, options)?;
            Ok(LiveSource { child, raw })
        }
    }

    impl Drop for LiveSource {
        fn drop(&mut self) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }

    impl AudioSource for LiveSource {
        fn name(&self) -> &str {
            self.raw.name()
        }
        fn channels(&self) -> usize {
            self.raw.channels()
        }
        fn sample_rate_hz(&self) -> u32 {
            self.raw.sample_rate_hz()
        }
        fn hop_len(&self) -> usize {
            self.raw.hop_len()
        }
        fn next_block(&mut self, out: &mut [f32]) -> Result<Option<Stamp>, AgentError> {
            self.raw.next_block(out)
        }
    }
}

#[cfg(not(feature = "live-capture"))]
mod imp {
    use soundmap_proto::Stamp;

    use super::super::audio_error;
    use super::*;

    /// Live capture is not compiled in: opening one is an error.
    #[derive(Debug)]
    pub struct LiveSource {
        never: std::convert::Infallible,
    }

    impl LiveSource {
        /// Always fails: this binary was built without the `live-capture` feature.
        pub fn open(device: &str, _layout: RawLayout, _options: &BlockOptions) -> Result<Self, AgentError> {
            Err(audio_error(
                device,
                "live capture is not available: soundmap-agent was not built with the `live-capture` feature \
                 (rebuild with `--features live-capture`, or pipe `arecord -t raw …` into `--input -`)",
            ))
        }
    }

    impl AudioSource for LiveSource {
        fn name(&self) -> &str {
            match self.never {}
        }
        fn channels(&self) -> usize {
            match self.never {}
        }
        fn sample_rate_hz(&self) -> u32 {
            match self.never {}
        }
        fn hop_len(&self) -> usize {
            match self.never {}
        }
        fn next_block(&mut self, _out: &mut [f32]) -> Result<Option<Stamp>, AgentError> {
            match self.never {}
        }
    }
}

pub use imp::LiveSource;
