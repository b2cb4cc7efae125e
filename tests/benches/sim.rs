//! Speed of the room-acoustics simulation, as a real-time factor (simulated
//! seconds per wall-clock second).
//!
//! The paper's static trial: 112 s, two robots with 16-microphone arrays
//! 0.48 m above the floor, a white-noise loudspeaker at 1.12 m, a 12.5 × 12 × 3 m
//! room (150 m²) at RT60 0.6 s, 16 kHz. Each robot renders on its own thread
//! (`std::thread::scope`, 2 threads). Then the same with both robots driving
//! and turning (every impulse response rebuilt and crossfaded every block), and
//! the cost of direct time-domain convolution on a short excerpt, as a ratio.
//!
//! Each figure is the best of two runs (the machine is shared).
//!
//! Run: `cargo bench -p soundmap-sim --bench sim`

use std::time::Instant;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use soundmap_sim::acoustics::convolution::direct_convolution;
use soundmap_sim::acoustics::noise::DiffuseNoise;
use soundmap_sim::acoustics::{
    ArrayConfig, ArrayRenderer, DiffuseNoiseConfig, RirConfig, Scene, ShoeboxRoom, SourceSignal,
};

const FS: f64 = 16_000.0;
const DURATION_S: f64 = 112.0;

/// 16 microphones: two rings of 8 (radius 0.175 m), 0.1 m apart in height,
/// the upper ring turned by 22.5°; array frame centred, 0.48 m above the base.
fn array_in_base() -> Vec<Point3<f64>> {
    (0..16)
        .map(|i| {
            let ring = (i / 8) as f64;
            let a = (i % 8) as f64 * std::f64::consts::FRAC_PI_4 + ring * std::f64::consts::FRAC_PI_8;
            Point3::new(0.175 * a.cos(), 0.175 * a.sin(), 0.48 - 0.05 + 0.1 * ring)
        })
        .collect()
}

fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// Robot `r` at time `t`: static, or driving a 2 m-radius circle at 0.5 m/s.
fn robot_pose(r: usize, t: f64, moving: bool) -> Isometry3<f64> {
    let (cx, cy) = if r == 0 { (3.5, 4.0) } else { (9.0, 4.5) };
    if !moving {
        return pose(cx, cy, 0.3 + r as f64);
    }
    let w = 0.5 / 2.0 * if r == 0 { 1.0 } else { -1.0 };
    let a = w * t + r as f64;
    pose(cx + 2.0 * a.cos(), cy + 2.0 * a.sin(), a + w.signum() * std::f64::consts::FRAC_PI_2)
}

fn scene() -> Scene {
    Scene {
        room: ShoeboxRoom::from_rt60(Point3::origin(), Vector3::new(12.5, 12.0, 3.0), 0.6)
            .expect("valid room"),
        sources: vec![SourceSignal::white_noise(1.0, 42)],
        rir: RirConfig::default(),
    }
}

/// Renders `duration_s` for each robot in `robots` on its own thread; wall seconds.
fn run(scene: &Scene, robots: &[usize], moving: bool, duration_s: f64, block_len: usize) -> (f64, u64) {
    let mics = array_in_base();
    let source = [Point3::new(6.2, 7.0, 1.12)];
    let start = Instant::now();
    let builds: u64 = std::thread::scope(|s| {
        let handles: Vec<_> = robots
            .iter()
            .map(|&r| {
                let mics = &mics;
                s.spawn(move || {
                    let mut cfg = ArrayConfig::new(16, 100 + r as u64);
                    cfg.block_len = block_len;
                    cfg.sensor_noise_std = 1e-3;
                    let mut renderer = ArrayRenderer::new(scene, cfg).expect("valid scene");
                    let blocks = (duration_s * FS / block_len as f64).round() as usize;
                    let mut out = vec![0.0f32; 16 * block_len];
                    let mut at = vec![Point3::origin(); 16];
                    let mut checksum = 0.0f64;
                    for b in 0..blocks {
                        let t_end = ((b + 1) * block_len) as f64 / FS;
                        let map_from_base = robot_pose(r, t_end, moving);
                        for (a, m) in at.iter_mut().zip(mics) {
                            *a = map_from_base * m;
                        }
                        renderer.render_block(&at, &source, &mut out).expect("inside the room");
                        checksum += out[block_len / 2] as f64;
                    }
                    std::hint::black_box(checksum);
                    renderer.stats().response_builds
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("render thread")).sum()
    });
    (start.elapsed().as_secs_f64(), builds)
}

fn main() {
    let scene = scene();
    let channels = 32.0;
    println!(
        "soundmap-sim bench: 2 robots × 16 mics, {DURATION_S} s at {FS} Hz, RT60 0.6 s, 12.5×12×3 m, IR 0.6 s"
    );
    for &block_len in &[512usize, 1024, 256] {
        for moving in [false, true] {
            // Best of two: the machine is shared, the minimum is the least disturbed.
            let (a, builds) = run(&scene, &[0, 1], moving, DURATION_S, block_len);
            let (b, _) = run(&scene, &[0, 1], moving, DURATION_S, block_len);
            let wall = a.min(b);
            println!(
                "  B={block_len:4} {:7}: {wall:6.2} s wall, real-time factor {:6.1}× (2 threads), {builds} IR builds",
                if moving { "moving" } else { "static" },
                DURATION_S / wall,
            );
        }
    }
    // Single-thread cost per channel-second of the FFT renderer (static, B = 512).
    let short = 20.0;
    let wall_fft = run(&scene, &[0], false, short, 512).0.min(run(&scene, &[0], false, short, 512).0);
    let fft_per_channel_s = wall_fft / (16.0 * short);
    // Direct convolution of one channel with the full 0.6 s response, on a 2 s excerpt.
    let model = soundmap_sim::acoustics::RirModel::new(&scene.room, &scene.rir).expect("valid");
    let h = model.impulse_response(&Point3::new(6.2, 7.0, 1.12), &Point3::new(3.5, 4.0, 0.48), 1);
    let mut gen_ =
        soundmap_sim::acoustics::signals::SignalGenerator::new(&scene.sources[0], FS).expect("valid");
    let excerpt_s = 2.0;
    let mut x = vec![0.0f32; (excerpt_s * FS) as usize];
    gen_.fill(0, &mut x);
    let mut y = vec![0.0f64; x.len()];
    let mut wall_direct = f64::INFINITY;
    for _ in 0..2 {
        let t0 = Instant::now();
        direct_convolution(&x, &h, &mut y);
        wall_direct = wall_direct.min(t0.elapsed().as_secs_f64());
    }
    std::hint::black_box(&y);
    let direct_per_channel_s = wall_direct / excerpt_s;
    println!(
        "  1 thread, static B=512: {:.3} ms per channel-second; direct convolution ({} taps, {excerpt_s} s excerpt): {:.1} ms per channel-second; direct/FFT = {:.0}×",
        fft_per_channel_s * 1e3,
        h.len(),
        direct_per_channel_s * 1e3,
        direct_per_channel_s / fft_per_channel_s
    );
    // One-off cost: synthesizing a 16-microphone diffuse-noise loop (65 536 samples, 256 plane waves).
    let t0 = Instant::now();
    let loop_ = DiffuseNoise::new(&array_in_base(), &DiffuseNoiseConfig::with_std(0.01), FS, 343.0, 5)
        .expect("valid");
    std::hint::black_box(&loop_);
    println!(
        "  diffuse noise loop for 16 microphones (4.1 s, 256 plane waves): {:.2} s to synthesize, once per array",
        t0.elapsed().as_secs_f64()
    );
    println!(
        "  (direct convolution of the whole 112 s two-robot case would take ≈ {:.0} s on 2 threads: real-time factor {:.2}×)",
        direct_per_channel_s * channels * DURATION_S / 2.0,
        2.0 / (direct_per_channel_s * channels)
    );
}
