//! Room acoustics for the simulation: what the robots' microphones hear.
//!
//! - [`room`]: shoebox rooms, absorption from a target RT60 (Eyring).
//! - [`image_source`]: image sources of a shoebox (Allen & Berkley).
//! - [`fractional_delay`]: windowed-sinc fractional delays.
//! - [`rir`]: impulse responses, exact images early plus an energy-matched
//!   stochastic tail.
//! - [`signals`]: source signals (white and band noise, tones, on/off activity).
//! - [`noise`]: sensor noise and diffuse (isotropic) noise, SNR helpers.
//! - [`convolution`]: uniformly partitioned FFT convolution and its slow reference.
//! - [`scene`], [`renderer`]: a scene defined once, and block-by-block rendering
//!   of one array in it with moving sources and arrays.
//! - [`analysis`]: RT60 (Schroeder), levels, coherence.
//!
//! Conventions: positions in the `map` frame (m); a unit source gives pressure 1
//! at 1 m (all levels share that arbitrary unit); sample 0 is the scene start.

pub mod analysis;
pub mod convolution;
pub mod fractional_delay;
pub mod image_source;
pub mod noise;
pub mod renderer;
pub mod rir;
pub mod room;
pub mod scene;
pub mod signals;

pub use noise::{DiffuseNoiseConfig, direct_path_rms, noise_std_for_snr};
pub use renderer::{ArrayConfig, ArrayRenderer, RenderStats};
pub use rir::{RirConfig, RirModel};
pub use room::{SPEED_OF_SOUND_M_PER_S, ShoeboxRoom};
pub use scene::Scene;
pub use signals::{Activity, SourceSignal, Waveform};

/// Combines a seed with a tag or index into a new, well-mixed seed (SplitMix64
/// finalizer), so that independent streams never share a seed by accident.
pub fn mix_seed(seed: u64, tag: u64) -> u64 {
    let mut z = seed ^ tag.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(0x632B_E59B_D9B4_E019);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
