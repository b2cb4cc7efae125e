//! Block-by-block multichannel rendering of one microphone array in a scene,
//! with moving sources and a moving array.
//!
//! **Per block** (`B` samples) the caller gives the microphone positions and
//! the source positions (map frame) *at the block's last sample*. The renderer
//!
//! 1. draws each source's next `B` samples and transforms them once
//!    ([`SpectrumHistory::push`]), shared by all microphones;
//! 2. rebuilds the early part of a (source, microphone) impulse response only
//!    when the source or the microphone moved more than
//!    [`ArrayConfig::position_tolerance_m`] from where that response was built
//!    (a static array reuses its responses forever); the late tail is
//!    position-independent ([`super::rir`]) and transformed once at start;
//! 3. convolves by uniformly partitioned overlap-save ([`super::convolution`]);
//! 4. when a response changed, renders the block with both the previous and
//!    the new response and crossfades linearly across the block, so the
//!    effective response moves piecewise-linearly between block ends and the
//!    output has no discontinuity at block boundaries;
//! 5. adds sensor noise and diffuse noise.
//!
//! Sample 0 of the first block is the scene start (sample 0 of every source
//! signal); block `k` covers samples `k·B .. (k+1)·B`. Several arrays in one
//! scene each get their own renderer (they can run on their own threads) and
//! hear the same sources, since source signals are functions of the sample
//! index.
//!
//! Usage, for an array at 3 m from a unit source with sensor noise 20 dB below
//! the direct path (see [`super::noise`]):
//!
//! ```
//! use nalgebra::{Point3, Vector3};
//! use soundmap_sim::acoustics::{
//!     ArrayConfig, RirConfig, Scene, ShoeboxRoom, SourceSignal, direct_path_rms, noise_std_for_snr,
//! };
//!
//! let room = ShoeboxRoom::from_rt60(Point3::origin(), Vector3::new(12.5, 12.0, 3.0), 0.6)?;
//! let scene = Scene { room, sources: vec![SourceSignal::white_noise(1.0, 7)], rir: RirConfig::default() };
//! let mut config = ArrayConfig::new(2, 1);
//! config.sensor_noise_std = noise_std_for_snr(direct_path_rms(1.0, 3.0), 20.0);
//! let mut renderer = scene.renderer(config)?;
//! let mics = [Point3::new(3.0, 3.0, 0.48), Point3::new(3.1, 3.0, 0.48)];
//! let source = [Point3::new(6.0, 3.0, 1.12)];
//! let mut block = vec![0.0f32; 2 * renderer.block_len()]; // planar: mic 0, then mic 1
//! renderer.render_block(&mics, &source, &mut block)?;
//! # Ok::<(), soundmap_sim::SimError>(())
//! ```
//!
//! Cost per block and microphone: `P` complex multiply-adds per bin per source
//! (`P = ⌈IR length / B⌉`), one inverse FFT of `2B`, and for a moved pair an
//! image sum, `P_e` forward FFTs (`P_e` partitions of early response) and one
//! more inverse FFT.

use nalgebra::Point3;

use super::convolution::{SpectrumHistory, Upols, accumulate};
use super::image_source::ImageSource;
use super::mix_seed;
use super::noise::{DiffuseNoise, DiffuseNoiseConfig, SensorNoise};
use super::rir::{Biquad, RirModel};
use super::scene::Scene;
use super::signals::SignalGenerator;
use crate::error::SimError;

const TAIL_TAG: u64 = 0x7A11;
const SENSOR_TAG: u64 = 0x5E45;
const DIFFUSE_TAG: u64 = 0xD1FF;

/// Per-array rendering settings.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayConfig {
    /// Number of microphones.
    pub microphone_count: usize,
    /// Samples per block (also the impulse-response update interval).
    pub block_len: usize,
    /// Standard deviation of each microphone's self-noise (scene pressure units).
    pub sensor_noise_std: f64,
    /// Diffuse background noise, if any.
    pub diffuse_noise: Option<DiffuseNoiseConfig>,
    /// Seed of everything random that belongs to this array (tails, noises).
    /// Give every array of a scene its own seed, or their reverberation tails
    /// and noises will be identical.
    pub seed: u64,
    /// Impulse responses are rebuilt when a source or microphone has moved more
    /// than this from where they were built (m).
    pub position_tolerance_m: f64,
    /// Crossfade from the previous responses across a block when they change
    /// (true; false switches abruptly at the block start, which clicks, and
    /// exists to show that it does).
    pub crossfade: bool,
}

impl ArrayConfig {
    /// `microphone_count` microphones, 512-sample blocks (32 ms at 16 kHz), no noise,
    /// 1 mm position tolerance, crossfades on.
    pub fn new(microphone_count: usize, seed: u64) -> Self {
        ArrayConfig {
            microphone_count,
            block_len: 512,
            sensor_noise_std: 0.0,
            diffuse_noise: None,
            seed,
            position_tolerance_m: 1e-3,
            crossfade: true,
        }
    }
}

/// Counters of the work done, for benchmarks and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Blocks rendered.
    pub blocks: u64,
    /// Early responses built (per source–microphone pair).
    pub response_builds: u64,
    /// Blocks × microphones rendered with a crossfade.
    pub crossfades: u64,
}

#[derive(Clone, Debug)]
struct SourceState {
    generator: SignalGenerator,
    /// The responses' high-pass, applied to the signal (see [`RirModel::high_pass`]).
    high_pass: Option<Biquad>,
    history: SpectrumHistory,
    images: Vec<ImageSource>,
    images_for: Option<Point3<f64>>,
    /// Incremented when `images` is rebuilt.
    generation: u64,
}

#[derive(Clone, Debug)]
struct PairState {
    /// Tail samples inside the early partitions (time domain).
    tail_head: Vec<f64>,
    /// Spectra of tail partitions `P_e .. P`.
    tail: Vec<f32>,
    /// Spectra of partitions `0 .. P_e` (images + tail head), current and previous.
    early: Vec<f32>,
    early_prev: Vec<f32>,
    /// `early − early_prev` while fading.
    delta: Vec<f32>,
    built_for: Option<(u64, Point3<f64>)>,
    fading: bool,
}

/// Renders one microphone array, block by block.
#[derive(Debug)]
pub struct ArrayRenderer {
    model: RirModel,
    engine: Upols,
    config: ArrayConfig,
    partitions: usize,
    early_partitions: usize,
    sources: Vec<SourceState>,
    /// Index `k·M + m`.
    pairs: Vec<PairState>,
    sensor: SensorNoise,
    diffuse: Option<DiffuseNoise>,
    block_index: u64,
    stats: RenderStats,
    ir: Vec<f64>,
    src_block: Vec<f32>,
    acc: Vec<f32>,
    diff: Vec<f32>,
    y: Vec<f32>,
    y_diff: Vec<f32>,
    ramp: Vec<f32>,
}

impl Scene {
    /// A renderer for one microphone array in this scene.
    pub fn renderer(&self, config: ArrayConfig) -> Result<ArrayRenderer, SimError> {
        ArrayRenderer::new(self, config)
    }
}

impl ArrayRenderer {
    /// Plans the renderer: FFTs, the late tails of every (source, microphone)
    /// pair, buffers. Nothing is allocated per block afterwards (except the
    /// diffuse-noise loop, synthesized at the first block from its geometry).
    pub fn new(scene: &Scene, config: ArrayConfig) -> Result<Self, SimError> {
        let model = scene.validate()?;
        let m_count = config.microphone_count;
        if m_count == 0 {
            return Err(SimError::invalid("array.microphone_count", "must be ≥ 1"));
        }
        if config.block_len == 0 {
            return Err(SimError::invalid("array.block_len", "must be ≥ 1"));
        }
        if !(config.position_tolerance_m >= 0.0) {
            return Err(SimError::invalid("array.position_tolerance_m", "must be ≥ 0"));
        }
        let mut engine = Upols::new(config.block_len);
        let b = config.block_len;
        let split = engine.split_len();
        let partitions = engine.partitions_for(model.len());
        let early_partitions = engine.partitions_for(model.early_len()).min(partitions);
        let fs = model.config().sample_rate_hz;
        let sources = scene
            .sources
            .iter()
            .map(|s| {
                Ok(SourceState {
                    generator: SignalGenerator::new(s, fs)?,
                    high_pass: model.high_pass(),
                    history: SpectrumHistory::new(&engine, partitions),
                    images: Vec::new(),
                    images_for: None,
                    generation: 0,
                })
            })
            .collect::<Result<Vec<_>, SimError>>()?;
        let early_len = early_partitions * b;
        let mut h = vec![0.0; partitions * b];
        let mut pairs = Vec::with_capacity(sources.len() * m_count);
        for k in 0..sources.len() {
            for m in 0..m_count {
                h.fill(0.0);
                model.add_tail(tail_seed(config.seed, k, m), &mut h);
                let mut tail = vec![0.0f32; (partitions - early_partitions) * split];
                engine.filter_spectra(&h[early_len..], &mut tail);
                let zeros = vec![0.0f32; early_partitions * split];
                pairs.push(PairState {
                    tail_head: h[..early_len].to_vec(),
                    tail,
                    early: zeros.clone(),
                    early_prev: zeros.clone(),
                    delta: zeros,
                    built_for: None,
                    fading: false,
                });
            }
        }
        let ramp = (0..b).map(|i| (i + 1) as f32 / b as f32).collect();
        Ok(ArrayRenderer {
            sensor: SensorNoise::new(config.sensor_noise_std, mix_seed(config.seed, SENSOR_TAG))?,
            diffuse: None,
            ir: vec![0.0; early_len],
            src_block: vec![0.0; b],
            acc: vec![0.0; split],
            diff: vec![0.0; split],
            y: vec![0.0; b],
            y_diff: vec![0.0; b],
            ramp,
            model,
            engine,
            config,
            partitions,
            early_partitions,
            sources,
            pairs,
            block_index: 0,
            stats: RenderStats::default(),
        })
    }

    /// Samples per block.
    pub fn block_len(&self) -> usize {
        self.config.block_len
    }

    /// Number of microphones.
    pub fn microphone_count(&self) -> usize {
        self.config.microphone_count
    }

    /// Sample rate (Hz).
    pub fn sample_rate_hz(&self) -> f64 {
        self.model.config().sample_rate_hz
    }

    /// Index of the next block's first sample (sample 0 = scene start).
    pub fn next_sample(&self) -> u64 {
        self.block_index * self.config.block_len as u64
    }

    /// The impulse-response model.
    pub fn model(&self) -> &RirModel {
        &self.model
    }

    /// Work counters.
    pub fn stats(&self) -> RenderStats {
        self.stats
    }

    /// The exact impulse response this renderer uses between source
    /// `source_index` at `source_in_map` and microphone `mic_index` at `mic_in_map`.
    pub fn impulse_response(
        &self,
        source_index: usize,
        mic_index: usize,
        source_in_map: &Point3<f64>,
        mic_in_map: &Point3<f64>,
    ) -> Vec<f64> {
        self.model.impulse_response(
            source_in_map,
            mic_in_map,
            tail_seed(self.config.seed, source_index, mic_index),
        )
    }

    /// Renders the next block into `out`, planar: microphone `m` at
    /// `out[m·B .. (m+1)·B]`. `microphones_in_map` and `sources_in_map` are the
    /// positions (map frame, m) at the block's last sample, in the order of the
    /// array and of [`Scene::sources`].
    pub fn render_block(
        &mut self,
        microphones_in_map: &[Point3<f64>],
        sources_in_map: &[Point3<f64>],
        out: &mut [f32],
    ) -> Result<(), SimError> {
        let (b, m_count, s_count) = (self.config.block_len, self.config.microphone_count, self.sources.len());
        self.check_inputs(microphones_in_map, sources_in_map, out.len())?;
        if self.block_index == 0
            && let Some(cfg) = &self.config.diffuse_noise
        {
            let room = self.model.room();
            self.diffuse = Some(DiffuseNoise::new(
                microphones_in_map,
                cfg,
                self.model.config().sample_rate_hz,
                room.speed_of_sound_m_per_s(),
                mix_seed(self.config.seed, DIFFUSE_TAG),
            )?);
        }
        // 1. Source spectra, once per block.
        let first = self.next_sample() as i64;
        let tol = self.config.position_tolerance_m;
        for (src, pos) in self.sources.iter_mut().zip(sources_in_map) {
            src.generator.fill(first, &mut self.src_block);
            if let Some(hp) = &mut src.high_pass {
                hp.process_f32(&mut self.src_block);
            }
            src.history.push(&mut self.engine, &self.src_block);
            if src.images_for.is_none_or(|p| (p - pos).norm() > tol) {
                self.model.image_sources_into(pos, &mut src.images);
                src.images_for = Some(*pos);
                src.generation += 1;
            }
        }
        // 2. Responses, convolution, crossfade.
        let (pe, p) = (self.early_partitions, self.partitions);
        for (m, mic) in microphones_in_map.iter().enumerate() {
            let mut any_fading = false;
            for k in 0..s_count {
                let src = &self.sources[k];
                let pair = &mut self.pairs[k * m_count + m];
                let stale =
                    pair.built_for.is_none_or(|(g, at)| g != src.generation || (at - mic).norm() > tol);
                pair.fading = false;
                if stale {
                    let had = pair.built_for.is_some();
                    std::mem::swap(&mut pair.early, &mut pair.early_prev);
                    self.model.early_response(&src.images, mic, &mut self.ir);
                    for (v, t) in self.ir.iter_mut().zip(&pair.tail_head) {
                        *v += t;
                    }
                    self.engine.filter_spectra(&self.ir, &mut pair.early);
                    pair.built_for = Some((src.generation, *mic));
                    self.stats.response_builds += 1;
                    if had && self.config.crossfade {
                        for ((d, e), o) in pair.delta.iter_mut().zip(&pair.early).zip(&pair.early_prev) {
                            *d = e - o;
                        }
                        pair.fading = true;
                        any_fading = true;
                    }
                }
            }
            self.acc.fill(0.0);
            if any_fading {
                self.diff.fill(0.0);
            }
            for k in 0..s_count {
                let hist = &self.sources[k].history;
                let pair = &self.pairs[k * m_count + m];
                accumulate(&mut self.acc, hist, &pair.tail, pe..p);
                if pair.fading {
                    accumulate(&mut self.acc, hist, &pair.early_prev, 0..pe);
                    accumulate(&mut self.diff, hist, &pair.delta, 0..pe);
                } else {
                    accumulate(&mut self.acc, hist, &pair.early, 0..pe);
                }
            }
            self.engine.output_block(&self.acc, &mut self.y);
            let dst = &mut out[m * b..(m + 1) * b];
            if any_fading {
                self.engine.output_block(&self.diff, &mut self.y_diff);
                for (((o, y), d), w) in dst.iter_mut().zip(&self.y).zip(&self.y_diff).zip(&self.ramp) {
                    *o = y + w * d;
                }
                self.stats.crossfades += 1;
            } else {
                dst.copy_from_slice(&self.y);
            }
        }
        // 3. Noise.
        self.sensor.add_to(out);
        if let Some(d) = &mut self.diffuse {
            d.add_to(out);
        }
        self.block_index += 1;
        self.stats.blocks += 1;
        Ok(())
    }

    fn check_inputs(
        &self,
        mics: &[Point3<f64>],
        sources: &[Point3<f64>],
        out_len: usize,
    ) -> Result<(), SimError> {
        let m_count = self.config.microphone_count;
        if mics.len() != m_count {
            return Err(SimError::WrongLength {
                what: "microphones_in_map",
                expected: m_count,
                got: mics.len(),
            });
        }
        if sources.len() != self.sources.len() {
            return Err(SimError::WrongLength {
                what: "sources_in_map",
                expected: self.sources.len(),
                got: sources.len(),
            });
        }
        let expected = m_count * self.config.block_len;
        if out_len != expected {
            return Err(SimError::WrongLength { what: "out", expected, got: out_len });
        }
        let room = self.model.room();
        for (i, p) in mics.iter().enumerate() {
            room.check_inside(p, || format!("microphone {i}"))?;
        }
        for (i, p) in sources.iter().enumerate() {
            room.check_inside(p, || format!("source {i}"))?;
        }
        Ok(())
    }
}

fn tail_seed(array_seed: u64, source: usize, mic: usize) -> u64 {
    mix_seed(mix_seed(mix_seed(array_seed, TAIL_TAG), source as u64), mic as u64)
}
