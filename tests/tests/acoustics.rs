//! Room acoustics: exactness of the direct path, RT60 of the generated
//! responses, block rendering against a slow reference, continuity with a
//! moving source, noise levels and coherence, caching and determinism.

use nalgebra::{Point3, Vector3};
use soundmap_sim::SimError;
use soundmap_sim::acoustics::analysis::{coherence, measure_rt60, rms};
use soundmap_sim::acoustics::convolution::direct_convolution;
use soundmap_sim::acoustics::signals::SignalGenerator;
use soundmap_sim::acoustics::{
    Activity, ArrayConfig, DiffuseNoiseConfig, RirConfig, RirModel, Scene, ShoeboxRoom, SourceSignal,
    Waveform, direct_path_rms, noise_std_for_snr,
};

const FS: f64 = 16_000.0;
const C: f64 = 343.0;

fn paper_room(rt60_s: f64) -> ShoeboxRoom {
    ShoeboxRoom::from_rt60(Point3::origin(), Vector3::new(12.5, 12.0, 3.0), rt60_s).unwrap()
}

fn anechoic() -> RirConfig {
    RirConfig { max_order: 0, tail: false, length_s: 0.05, ..RirConfig::default() }
}

/// Renders `blocks` blocks of a static scene; planar per-channel signals.
fn render_static(
    scene: &Scene,
    cfg: ArrayConfig,
    mics: &[Point3<f64>],
    src: &[Point3<f64>],
    blocks: usize,
) -> Vec<Vec<f32>> {
    let mut r = scene.renderer(cfg).unwrap();
    let b = r.block_len();
    let mut out = vec![0.0f32; mics.len() * b];
    let mut chans = vec![Vec::new(); mics.len()];
    for _ in 0..blocks {
        r.render_block(mics, src, &mut out).unwrap();
        for (m, ch) in chans.iter_mut().enumerate() {
            ch.extend_from_slice(&out[m * b..(m + 1) * b]);
        }
    }
    chans
}

/// Gain and phase delay (samples) of `h` at `f_hz`, the phase unwrapped around `expected_delay`.
fn gain_and_delay(h: &[f64], f_hz: f64, expected_delay: f64) -> (f64, f64) {
    let w = 2.0 * std::f64::consts::PI * f_hz / FS;
    let (mut re, mut im) = (0.0, 0.0);
    for (n, v) in h.iter().enumerate() {
        re += v * (w * n as f64).cos();
        im -= v * (w * n as f64).sin();
    }
    let two_pi = 2.0 * std::f64::consts::PI;
    let err =
        (im.atan2(re) + w * expected_delay + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    (re.hypot(im), expected_delay - err / w)
}

#[test]
fn direct_path_delay_and_amplitude_are_exact() {
    let room = paper_room(0.6);
    let exact = RirModel::new(&room, &RirConfig { high_pass_hz: 0.0, ..anechoic() }).unwrap();
    let src = Point3::new(4.0, 5.0, 1.12);
    // Integer delay: exactly one tap of 1/r.
    let r_int = 100.0 * C / FS; // 100 samples
    let mic = src + Vector3::new(r_int * 0.6, r_int * 0.8, 0.0);
    let h = exact.impulse_response(&src, &mic, 0);
    for (i, v) in h.iter().enumerate() {
        let want = if i == 100 { 1.0 / r_int } else { 0.0 };
        assert!((v - want).abs() < 1e-12, "tap {i}: {v} vs {want}");
    }
    // Fractional delays: passband phase delay r/c and gain 1/r.
    for r in [1.0, 2.345, 3.3333, 5.01] {
        let mic = src + Vector3::new(r, 0.0, 0.0);
        let h = exact.impulse_response(&src, &mic, 0);
        let tau = r * FS / C;
        for f_hz in [125.0, 500.0, 1000.0, 2000.0, 4000.0, 6000.0] {
            let (gain, delay) = gain_and_delay(&h, f_hz, tau);
            assert!((gain * r - 1.0).abs() < 2e-3, "r {r} f {f_hz}: gain·r = {}", gain * r);
            assert!((delay - tau).abs() < 1e-3, "r {r} f {f_hz}: delay {delay} vs {tau} samples");
        }
    }
    // With the default 50 Hz high-pass, the same phase shift hits every microphone:
    // delay differences stay exact and the gain is 1/r in the audio band.
    let hp = RirModel::new(&room, &anechoic()).unwrap();
    let mics = [src + Vector3::new(2.0, 0.3, -0.6), src + Vector3::new(2.1234, 0.1, -0.64)];
    let r: Vec<f64> = mics.iter().map(|m| (m - src).norm()).collect();
    let h: Vec<Vec<f64>> = mics.iter().map(|m| hp.impulse_response(&src, m, 0)).collect();
    for f_hz in [200.0, 500.0, 1000.0, 3000.0, 6000.0] {
        let (g0, d0) = gain_and_delay(&h[0], f_hz, r[0] * FS / C);
        let (g1, d1) = gain_and_delay(&h[1], f_hz, r[1] * FS / C);
        let tdoa = (r[1] - r[0]) * FS / C;
        assert!(((d1 - d0) - tdoa).abs() < 1e-3, "f {f_hz}: TDOA {} vs {tdoa} samples", d1 - d0);
        if f_hz >= 500.0 {
            assert!(
                (g0 * r[0] - 1.0).abs() < 0.01 && (g1 * r[1] - 1.0).abs() < 0.01,
                "f {f_hz}: gains {g0} {g1}"
            );
        }
    }
}

#[test]
fn renderer_equals_direct_convolution_of_its_impulse_response() {
    let scene = Scene {
        // The response ends 100 dB down, so that where the high-pass is applied
        // (signal or response) makes no difference at its end.
        room: paper_room(0.3),
        sources: vec![SourceSignal::white_noise(1.0, 3)],
        rir: RirConfig { length_s: 0.5, ..RirConfig::default() },
    };
    let mics = [Point3::new(2.0, 3.0, 0.5), Point3::new(2.2, 3.1, 0.6)];
    let src = [Point3::new(5.0, 6.0, 1.12)];
    let cfg = ArrayConfig { block_len: 256, ..ArrayConfig::new(2, 9) };
    let renderer = scene.renderer(cfg.clone()).unwrap();
    let got = render_static(&scene, cfg, &mics, &src, 40);
    let mut x = vec![0.0f32; got[0].len()];
    SignalGenerator::new(&scene.sources[0], FS).unwrap().fill(0, &mut x);
    for (m, mic) in mics.iter().enumerate() {
        let h = renderer.impulse_response(0, m, &src[0], mic);
        let mut want = vec![0.0; x.len()];
        direct_convolution(&x, &h, &mut want);
        let scale = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let err = got[m].iter().zip(&want).fold(0.0f64, |a, (g, w)| a.max((*g as f64 - w).abs()));
        assert!(err < 1e-5 * scale.max(1.0) + 1e-6, "mic {m}: max error {err} (scale {scale})");
    }
}

#[test]
fn rt60_measured_from_the_impulse_response_matches_the_target() {
    let rooms = [Vector3::new(12.5, 12.0, 3.0), Vector3::new(6.0, 4.5, 2.8)];
    let positions = [
        (Point3::new(1.5, 2.0, 1.12), Point3::new(4.3, 3.1, 0.48)),
        (Point3::new(3.0, 1.0, 1.5), Point3::new(1.0, 3.5, 0.48)),
        (Point3::new(5.0, 4.0, 1.12), Point3::new(2.2, 1.1, 2.0)),
    ];
    let mut failures = Vec::new();
    for size in rooms {
        for target in [0.3, 0.45, 0.6, 0.8] {
            let room = ShoeboxRoom::from_rt60(Point3::origin(), size, target).unwrap();
            let cfg = RirConfig { length_s: 1.2 * target, ..RirConfig::default() };
            let model = RirModel::new(&room, &cfg).unwrap();
            let (mut t20, mut t30) = (0.0, 0.0);
            for (i, (s, m)) in positions.iter().enumerate() {
                let h = model.impulse_response(s, m, i as u64);
                let fit = measure_rt60(&h, FS).expect("decay reaches −35 dB");
                t20 += fit.t20_s / positions.len() as f64;
                t30 += fit.t30_s / positions.len() as f64;
            }
            println!("room {:?} target {target:.2} s: T20 {t20:.3} s, T30 {t30:.3} s", size.as_slice());
            for (name, t) in [("T20", t20), ("T30", t30)] {
                if (t / target - 1.0).abs() >= 0.15 {
                    failures
                        .push(format!("room {:?}: {name} {t:.3} s vs target {target} s", size.as_slice()));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn tail_starts_at_the_energy_of_the_image_series_it_replaces() {
    let room = paper_room(0.6);
    let cfg = RirConfig { length_s: 0.3, image_cutoff_s: 0.08, tail_fade_s: 0.01, ..RirConfig::default() };
    let model = RirModel::new(&room, &cfg).unwrap();
    // Average over positions: image energy just before the fade, tail energy just after the cutoff.
    let (a0, a1) = ((0.050 * FS) as usize, (0.070 * FS) as usize);
    let (b0, b1) = ((0.080 * FS) as usize, (0.100 * FS) as usize);
    let (mut early, mut tail) = (0.0, 0.0);
    let n = 24;
    for i in 0..n {
        let f = i as f64 / n as f64;
        let s = Point3::new(2.0 + 8.0 * f, 3.0 + 5.0 * (7.0 * f).fract(), 1.12);
        let m = Point3::new(10.0 - 7.0 * f, 9.0 - 6.0 * (3.0 * f).fract(), 0.48);
        let h = model.impulse_response(&s, &m, i);
        early += h[a0..a1].iter().map(|v| v * v).sum::<f64>() / n as f64;
        tail += h[b0..b1].iter().map(|v| v * v).sum::<f64>() / n as f64;
    }
    let predicted = |t0: f64, t1: f64| -> f64 {
        (0..200)
            .map(|k| model.image_energy_per_second(t0 + (t1 - t0) * (k as f64 + 0.5) / 200.0))
            .sum::<f64>()
            / 200.0
            * (t1 - t0)
    };
    let early_db = 10.0 * (early / predicted(0.05, 0.07)).log10();
    // The tail decays with the Eyring RT60 from its level at the cutoff.
    let e0 = model.image_energy_per_second(0.08);
    let tail_pred = (0..200)
        .map(|k| e0 * 10f64.powf(-6.0 * (0.02 * (k as f64 + 0.5) / 200.0) / room.rt60_eyring_s()))
        .sum::<f64>()
        / 200.0
        * 0.02;
    let tail_db = 10.0 * (tail / tail_pred).log10();
    println!("image energy vs model {early_db:+.2} dB, tail vs model {tail_db:+.2} dB");
    assert!(early_db.abs() < 1.5, "image series {early_db:+.2} dB off the energy model");
    assert!(tail_db.abs() < 1.0, "tail {tail_db:+.2} dB off its target level");
}

/// Max |second difference| at block boundaries and elsewhere.
fn boundary_vs_interior(y: &[f32], b: usize, skip: usize) -> (f64, f64) {
    let (mut at, mut inside) = (0.0f64, 0.0f64);
    for n in skip.max(1)..y.len() - 1 {
        let d2 = (y[n + 1] as f64 - 2.0 * y[n] as f64 + y[n - 1] as f64).abs();
        if n % b == 0 || n % b == b - 1 { at = at.max(d2) } else { inside = inside.max(d2) }
    }
    (at, inside)
}

#[test]
fn moving_source_output_is_continuous_across_blocks() {
    let tone = SourceSignal {
        waveform: Waveform::Tone { frequency_hz: 220.0, phase_rad: 0.3 },
        ..SourceSignal::white_noise(1.0, 5)
    };
    let scene = Scene { room: paper_room(0.5), sources: vec![tone], rir: RirConfig::default() };
    let mics = [Point3::new(3.0, 3.0, 0.48)];
    let b = 256;
    let render = |crossfade: bool| -> Vec<f32> {
        let cfg = ArrayConfig { block_len: b, crossfade, ..ArrayConfig::new(1, 1) };
        let mut r = scene.renderer(cfg).unwrap();
        let mut out = vec![0.0f32; b];
        let mut y = Vec::new();
        for k in 0..120 {
            // 2 m/s (the paper's top speed) along x, 1.5–3.4 m from the microphone.
            let t_end = ((k + 1) * b) as f64 / FS;
            let src = [Point3::new(4.0 + 2.0 * t_end, 4.0, 1.12)];
            r.render_block(&mics, &src, &mut out).unwrap();
            y.extend_from_slice(&out);
        }
        y
    };
    let skip = (0.7 * FS) as usize; // past the onset transient and the first response
    let (at, inside) = boundary_vs_interior(&render(true), b, skip);
    println!("crossfade: max |Δ²y| at boundaries {at:.3e}, inside blocks {inside:.3e}");
    assert!(at <= 1.2 * inside, "discontinuity at block boundaries: {at:.3e} vs {inside:.3e} inside");
    // The test can see a click: switching responses abruptly makes one.
    let (at_hard, inside_hard) = boundary_vs_interior(&render(false), b, skip);
    println!("hard switch: max |Δ²y| at boundaries {at_hard:.3e}, inside blocks {inside_hard:.3e}");
    assert!(at_hard > 2.0 * inside_hard, "the test should detect a hard switch");
}

#[test]
fn rotating_array_output_is_continuous_and_settles_to_the_static_output() {
    let band = SourceSignal {
        waveform: Waveform::BandNoise { low_hz: 100.0, high_hz: 400.0 },
        ..SourceSignal::white_noise(1.0, 21)
    };
    let scene = Scene {
        room: paper_room(0.4),
        sources: vec![band],
        rir: RirConfig { length_s: 0.4, ..RirConfig::default() },
    };
    let src = [Point3::new(6.0, 7.0, 1.12)];
    let centre = Point3::new(3.0, 3.0, 0.48);
    let ring = |yaw: f64| -> Vec<Point3<f64>> {
        (0..4)
            .map(|i| {
                let a = yaw + i as f64 * std::f64::consts::FRAC_PI_2;
                centre + Vector3::new(0.175 * a.cos(), 0.175 * a.sin(), 0.0)
            })
            .collect()
    };
    let b = 256;
    let blocks = 150;
    let settle = 100; // the array turns at 1 rad/s until this block, then stops
    let yaw_at = |k: usize| ((k.min(settle - 1) + 1) * b) as f64 / FS;
    let mut moving = scene.renderer(ArrayConfig { block_len: b, ..ArrayConfig::new(4, 6) }).unwrap();
    let mut fixed = scene.renderer(ArrayConfig { block_len: b, ..ArrayConfig::new(4, 6) }).unwrap();
    let (mut out_m, mut out_f) = (vec![0.0f32; 4 * b], vec![0.0f32; 4 * b]);
    let mut y = vec![Vec::new(); 4];
    let mut last_diff = 0.0f32;
    for k in 0..blocks {
        moving.render_block(&ring(yaw_at(k)), &src, &mut out_m).unwrap();
        fixed.render_block(&ring(yaw_at(blocks)), &src, &mut out_f).unwrap();
        for m in 0..4 {
            y[m].extend_from_slice(&out_m[m * b..(m + 1) * b]);
        }
        if k == blocks - 1 {
            last_diff = out_m.iter().zip(&out_f).fold(0.0f32, |a, (p, q)| a.max((p - q).abs()));
        }
    }
    for (m, ym) in y.iter().enumerate() {
        let (at, inside) = boundary_vs_interior(&ym[..settle * b], b, (0.5 * FS) as usize);
        assert!(at <= 1.2 * inside, "mic {m}: |Δ²y| {at:.3e} at boundaries vs {inside:.3e} inside");
    }
    // Once stopped for longer than the response, the output is the static one.
    let level = rms(&out_f);
    assert!(last_diff < 1e-4 * level as f32, "after stopping: {last_diff} (level {level})");
    assert_eq!(moving.stats().response_builds, 4 * settle as u64);
}

#[test]
fn sensor_and_diffuse_noise_have_the_snr_asked_for() {
    let scene =
        Scene { room: paper_room(0.6), sources: vec![SourceSignal::white_noise(1.0, 11)], rir: anechoic() };
    let src = [Point3::new(5.0, 5.0, 1.12)];
    let mics = [Point3::new(7.0, 5.0, 1.12), Point3::new(7.0, 5.2, 1.12), Point3::new(7.1, 5.1, 1.0)];
    let d = (mics[0] - src[0]).norm();
    let direct = direct_path_rms(1.0, d);
    let clean = render_static(&scene, ArrayConfig::new(3, 2), &mics, &src, 200);
    let measured_direct = rms(&clean[0][2000..]);
    assert!((measured_direct / direct - 1.0).abs() < 0.03, "direct rms {measured_direct} vs {direct}");
    for (snr_db, diffuse) in [(10.0, false), (0.0, false), (20.0, true), (5.0, true)] {
        let std = noise_std_for_snr(direct, snr_db);
        let mut cfg = ArrayConfig::new(3, 2);
        if diffuse {
            cfg.diffuse_noise = Some(DiffuseNoiseConfig::with_std(std));
        } else {
            cfg.sensor_noise_std = std;
        }
        let noisy = render_static(&scene, cfg, &mics, &src, 200);
        for m in 0..3 {
            let noise: Vec<f32> = noisy[m].iter().zip(&clean[m]).map(|(a, b)| a - b).collect();
            let snr = 20.0 * (direct / rms(&noise[2000..])).log10();
            assert!(
                (snr - snr_db).abs() < 0.3,
                "mic {m} diffuse {diffuse}: SNR {snr:.2} dB, asked {snr_db} dB"
            );
        }
    }
}

#[test]
fn diffuse_noise_coherence_follows_sinc() {
    let scene = Scene {
        room: paper_room(0.6),
        sources: vec![SourceSignal { rms: 0.0, ..SourceSignal::white_noise(0.0, 1) }],
        rir: anechoic(),
    };
    let mics = [Point3::new(6.0, 6.0, 0.48), Point3::new(6.1, 6.0, 0.48), Point3::new(6.0, 6.35, 0.48)];
    let cfg =
        ArrayConfig { diffuse_noise: Some(DiffuseNoiseConfig::with_std(1.0)), ..ArrayConfig::new(3, 4) };
    let y = render_static(&scene, cfg, &mics, &[Point3::new(2.0, 2.0, 1.0)], 250);
    let fft = 256;
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let d = (mics[a] - mics[b]).norm();
        let coh = coherence(&y[a], &y[b], fft);
        let (mut sq, mut n, mut worst_im) = (0.0, 0, 0.0f64);
        for (k, g) in coh.iter().enumerate() {
            let f = k as f64 * FS / fft as f64;
            if !(100.0..7500.0).contains(&f) {
                continue;
            }
            let kd = 2.0 * std::f64::consts::PI * f / C * d;
            sq += (g.re - kd.sin() / kd).powi(2);
            worst_im = worst_im.max(g.im.abs());
            n += 1;
        }
        let rms_err = (sq / n as f64).sqrt();
        println!("d = {d:.3} m: RMS error of Re(coherence) vs sinc(kd) {rms_err:.3}, max |Im| {worst_im:.3}");
        assert!(rms_err < 0.08, "d = {d}: coherence RMS error {rms_err}");
        assert!(worst_im < 0.15, "d = {d}: imaginary coherence {worst_im}");
    }
}

#[test]
fn static_arrays_reuse_their_responses_and_moving_ones_rebuild_them() {
    let scene = Scene {
        room: paper_room(0.6),
        sources: vec![SourceSignal::white_noise(1.0, 1), SourceSignal::white_noise(0.5, 2)],
        rir: RirConfig::default(),
    };
    let src = [Point3::new(5.0, 5.0, 1.12), Point3::new(8.0, 2.0, 1.0)];
    let mics = [Point3::new(2.0, 2.0, 0.48), Point3::new(2.1, 2.0, 0.48)];
    let mut r = scene.renderer(ArrayConfig::new(2, 0)).unwrap();
    let mut out = vec![0.0f32; 2 * 512];
    for _ in 0..20 {
        r.render_block(&mics, &src, &mut out).unwrap();
    }
    assert_eq!(r.stats().response_builds, 4);
    assert_eq!(r.stats().crossfades, 0);
    // Moving below the tolerance does nothing; beyond it rebuilds and crossfades.
    let nudged = [Point3::new(2.0005, 2.0, 0.48), Point3::new(2.1, 2.0, 0.48)];
    r.render_block(&nudged, &src, &mut out).unwrap();
    assert_eq!(r.stats().response_builds, 4);
    let moved = [Point3::new(2.05, 2.0, 0.48), Point3::new(2.15, 2.0, 0.48)];
    r.render_block(&moved, &src, &mut out).unwrap();
    assert_eq!(r.stats().response_builds, 8);
    assert_eq!(r.stats().crossfades, 2);
}

#[test]
fn intermittent_source_falls_silent_between_bursts() {
    let bursts =
        SourceSignal::white_noise(1.0, 8).with_activity(Activity::Intervals(vec![(0.0, 1.0), (2.5, 3.0)]));
    let scene = Scene {
        room: paper_room(0.4),
        sources: vec![bursts],
        rir: RirConfig { length_s: 0.4, ..RirConfig::default() },
    };
    let y = render_static(
        &scene,
        ArrayConfig::new(1, 3),
        &[Point3::new(2.0, 2.0, 0.5)],
        &[Point3::new(4.0, 3.0, 1.1)],
        100,
    );
    let sec = |a: f64, b: f64| rms(&y[0][(a * FS) as usize..(b * FS) as usize]);
    let on = sec(0.5, 1.0);
    // 0.4 s after switching off, the response (0.4 s long) has died out; only the
    // 50 Hz high-pass's exponential ringing is left.
    assert!(sec(1.45, 2.45) < 1e-9 * on, "{} vs {on}", sec(1.45, 2.45));
    assert!(sec(1.0, 1.1) > 0.01 * on, "reverberation continues right after the source stops");
    assert!(sec(2.6, 3.0) > 0.5 * on);
}

#[test]
fn same_seed_same_output() {
    let scene = Scene {
        room: paper_room(0.6),
        sources: vec![SourceSignal::white_noise(1.0, 77)],
        rir: RirConfig::default(),
    };
    let cfg = |seed| ArrayConfig {
        sensor_noise_std: 0.01,
        diffuse_noise: Some(DiffuseNoiseConfig { loop_len: 4096, ..DiffuseNoiseConfig::with_std(0.02) }),
        ..ArrayConfig::new(2, seed)
    };
    let run = |seed| {
        let mut r = scene.renderer(cfg(seed)).unwrap();
        let mut out = vec![0.0f32; 2 * 512];
        let mut all = Vec::new();
        for k in 0..30 {
            let x = 2.0 + 0.01 * k as f64;
            r.render_block(
                &[Point3::new(x, 2.0, 0.48), Point3::new(x + 0.1, 2.0, 0.48)],
                &[Point3::new(6.0, 6.0, 1.12)],
                &mut out,
            )
            .unwrap();
            all.extend_from_slice(&out);
        }
        all
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5), run(6));
}

#[test]
fn renderers_can_move_to_their_own_threads() {
    fn assert_send<T: Send>() {}
    assert_send::<soundmap_sim::acoustics::ArrayRenderer>();
    assert_send::<Scene>();
}

#[test]
fn bad_inputs_are_clear_errors() {
    let scene = Scene {
        room: paper_room(0.6),
        sources: vec![SourceSignal::white_noise(1.0, 1)],
        rir: RirConfig::default(),
    };
    let mut r = scene.renderer(ArrayConfig::new(2, 0)).unwrap();
    let mut out = vec![0.0f32; 2 * 512];
    let inside = Point3::new(1.0, 1.0, 1.0);
    let err = r.render_block(&[inside, Point3::new(13.0, 1.0, 1.0)], &[inside], &mut out).unwrap_err();
    assert!(matches!(err, SimError::OutsideRoom { ref what, .. } if what == "microphone 1"), "{err}");
    let err = r.render_block(&[inside], &[inside], &mut out).unwrap_err();
    assert!(matches!(err, SimError::WrongLength { what: "microphones_in_map", expected: 2, got: 1 }));
    let err = r.render_block(&[inside, inside], &[inside], &mut out[..10]).unwrap_err();
    assert!(matches!(err, SimError::WrongLength { what: "out", .. }));
    assert!(scene.renderer(ArrayConfig { block_len: 0, ..ArrayConfig::new(2, 0) }).is_err());
    let bad = Scene { sources: vec![], ..scene.clone() };
    assert!(bad.renderer(ArrayConfig::new(1, 0)).is_err());
    let bad = Scene { rir: RirConfig { image_cutoff_s: 1.0, ..RirConfig::default() }, ..scene };
    assert!(matches!(
        bad.renderer(ArrayConfig::new(1, 0)),
        Err(SimError::InvalidConfig { field: "rir.image_cutoff_s", .. })
    ));
}
