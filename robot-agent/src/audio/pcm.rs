//! Bulk decoding of interleaved integer / float PCM into the block buffer, for
//! WAV and raw input alike.
//!
//! A block is read as bytes in one call (`hop_len × frame bytes`, e.g. 128
//! frames × 16 channels × 2 bytes = 4 KiB), then decoded in one pass straight
//! into the output block through the channel map: output channel `k` of frame
//! `f` is `decode(bytes[f·frame_bytes + map[k]·width ..])`. The sample format is
//! matched once per block, not once per sample, so the inner loop is a plain
//! load, sign-extend and multiply that the compiler unrolls. Nothing allocates
//! after [`BlockReader::new`].

use std::io::{ErrorKind, Read};

/// How one sample is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PcmEncoding {
    /// Signed 16-bit little-endian.
    S16,
    /// Signed 24-bit little-endian packed in 3 bytes.
    S24Packed,
    /// Signed 24-bit little-endian in the low 3 bytes of a 4-byte container.
    S24In32,
    /// Signed 32-bit little-endian.
    S32,
    /// IEEE 754 single precision, little-endian, ±1 full scale.
    F32,
}

impl PcmEncoding {
    /// Bytes per sample.
    pub(crate) fn width(self) -> usize {
        match self {
            PcmEncoding::S16 => 2,
            PcmEncoding::S24Packed => 3,
            PcmEncoding::S24In32 | PcmEncoding::S32 | PcmEncoding::F32 => 4,
        }
    }
}

#[inline(always)]
fn s16(b: &[u8]) -> f32 {
    i16::from_le_bytes([b[0], b[1]]) as f32 * (1.0 / 32_768.0)
}

#[inline(always)]
fn s24(b: &[u8]) -> f32 {
    (i32::from_le_bytes([0, b[0], b[1], b[2]]) >> 8) as f32 * (1.0 / 8_388_608.0)
}

#[inline(always)]
fn s32(b: &[u8]) -> f32 {
    i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32 * (1.0 / 2_147_483_648.0)
}

#[inline(always)]
fn f32le(b: &[u8]) -> f32 {
    f32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// Decodes whole frames of `bytes` (`in_channels` samples of `W` bytes each)
/// into `out` (`map.len()` values per frame) through the channel map.
#[inline(always)]
fn decode_with<const W: usize>(
    bytes: &[u8],
    in_channels: usize,
    map: &[usize],
    identity: bool,
    out: &mut [f32],
    dec: impl Fn(&[u8]) -> f32,
) {
    if identity {
        for (o, b) in out.iter_mut().zip(bytes.chunks_exact(W)) {
            *o = dec(b);
        }
        return;
    }
    let frame_bytes = in_channels * W;
    for (dst, src) in out.chunks_exact_mut(map.len()).zip(bytes.chunks_exact(frame_bytes)) {
        for (o, &c) in dst.iter_mut().zip(map) {
            *o = dec(&src[c * W..c * W + W]);
        }
    }
}

/// Reads blocks of interleaved PCM bytes from a stream and decodes them.
#[derive(Debug)]
pub(crate) struct BlockReader {
    encoding: PcmEncoding,
    in_channels: usize,
    map: Vec<usize>,
    identity: bool,
    hop_len: usize,
    /// One block of input bytes.
    bytes: Vec<u8>,
}

impl BlockReader {
    /// A reader of blocks of `hop_len` frames of `in_channels` channels, mapped by `map`.
    pub(crate) fn new(encoding: PcmEncoding, in_channels: usize, map: Vec<usize>, hop_len: usize) -> Self {
        let identity = map.len() == in_channels && map.iter().enumerate().all(|(k, &c)| k == c);
        BlockReader {
            encoding,
            in_channels,
            identity,
            map,
            hop_len,
            bytes: vec![0; hop_len * in_channels * encoding.width()],
        }
    }

    /// Bytes per input frame.
    pub(crate) fn frame_bytes(&self) -> usize {
        self.in_channels * self.encoding.width()
    }

    /// Reads up to one block (at most `limit` bytes) until the block is full or
    /// the stream ends; returns the bytes read.
    pub(crate) fn fill(&mut self, reader: &mut dyn Read, limit: usize) -> std::io::Result<usize> {
        let want = self.bytes.len().min(limit);
        let mut n = 0;
        while n < want {
            match reader.read(&mut self.bytes[n..want]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(n)
    }

    /// Decodes the first `frames` frames of the last block read into `out`
    /// (`hop_len × map.len()` values) and zero-fills the rest of it.
    pub(crate) fn decode(&self, frames: usize, out: &mut [f32]) {
        let ch = self.map.len();
        debug_assert_eq!(out.len(), self.hop_len * ch);
        let frames = frames.min(self.hop_len);
        let (head, tail) = out.split_at_mut(frames * ch);
        let bytes = &self.bytes[..frames * self.frame_bytes()];
        let (c, map, id) = (self.in_channels, &self.map[..], self.identity);
        match self.encoding {
            PcmEncoding::S16 => decode_with::<2>(bytes, c, map, id, head, s16),
            PcmEncoding::S24Packed => decode_with::<3>(bytes, c, map, id, head, s24),
            PcmEncoding::S24In32 => decode_with::<4>(bytes, c, map, id, head, s24),
            PcmEncoding::S32 => decode_with::<4>(bytes, c, map, id, head, s32),
            PcmEncoding::F32 => decode_with::<4>(bytes, c, map, id, head, f32le),
        }
        tail.fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every encoding, identity and permuting maps, a short last block.
    #[test]
    fn decodes_blocks_through_the_map() {
        let values: [i32; 6] = [0, -32_768, 16_384, 32_767, -1, 7];
        for enc in [
            PcmEncoding::S16,
            PcmEncoding::S24Packed,
            PcmEncoding::S24In32,
            PcmEncoding::S32,
            PcmEncoding::F32,
        ] {
            let (shift, scale) = match enc {
                PcmEncoding::S16 => (0, 32_768.0),
                PcmEncoding::S24Packed | PcmEncoding::S24In32 => (8, 8_388_608.0),
                PcmEncoding::S32 => (16, 2_147_483_648.0),
                PcmEncoding::F32 => (0, 32_768.0),
            };
            let mut bytes = Vec::new();
            for &v in &values {
                let v = v << shift;
                match enc {
                    PcmEncoding::S16 => bytes.extend((v as i16).to_le_bytes()),
                    PcmEncoding::S24Packed => bytes.extend(&v.to_le_bytes()[..3]),
                    PcmEncoding::S24In32 => bytes.extend(&v.to_le_bytes()[..3]),
                    PcmEncoding::S32 => bytes.extend(v.to_le_bytes()),
                    PcmEncoding::F32 => bytes.extend((v as f32 / 32_768.0).to_le_bytes()),
                }
                if enc == PcmEncoding::S24In32 {
                    // Junk in the container's top byte is ignored.
                    bytes.push(0x5a);
                }
            }
            let expect = |i: usize| (values[i] << shift) as f64 / scale;
            // 3 input channels, 2 frames read of a 3-frame block.
            for map in [vec![0, 1, 2], vec![2, 0]] {
                let mut r = BlockReader::new(enc, 3, map.clone(), 3);
                let n = r.fill(&mut &bytes[..], usize::MAX).unwrap();
                assert_eq!(n, bytes.len());
                let mut out = vec![9.0; 3 * map.len()];
                r.decode(n / r.frame_bytes(), &mut out);
                for f in 0..3 {
                    for (k, &c) in map.iter().enumerate() {
                        let want = if f < 2 { expect(f * 3 + c) } else { 0.0 };
                        let got = out[f * map.len() + k] as f64;
                        assert!((got - want).abs() < 1e-7, "{enc:?} map {map:?} f{f} k{k}: {got} vs {want}");
                    }
                }
            }
        }
    }

    #[test]
    fn fill_stops_at_the_limit() {
        let bytes = [1u8; 100];
        let mut r = BlockReader::new(PcmEncoding::S16, 2, vec![0, 1], 10);
        assert_eq!(r.fill(&mut &bytes[..], 12).unwrap(), 12);
        assert_eq!(r.fill(&mut &bytes[..], usize::MAX).unwrap(), 40);
    }
}
