//! Spectral signatures of the reported tracks: two sources that sound
//! different get clearly different signatures, each resembling its own
//! source's spectrum; the level is calibrated (0 dB = unit-variance white
//! noise); at most K tracks go out, most active first; the hello declares the
//! layout; the agent core passes signatures through unchanged.

use crate::synth;

use nalgebra::{Isometry3, Vector3};
use realfft::RealFftPlanner;
use realfft::num_complex::Complex;
use soundmap_agent::agent::{self, Agent, CoreConfig};
use soundmap_agent::array::ArrayGeometry;
use soundmap_agent::pipeline::{FrameResult, Pipeline, PipelineConfig};
use soundmap_agent::pose::StampedPose;
use soundmap_proto::{Hello, Limits, RobotId, Stamp};

const FS: f64 = 16_000.0;

/// Magnitude responses of the two sources: 4th-order Butterworth-like low
/// pass at 1.2 kHz (a fan's rumble) and high pass at 3 kHz (a hiss).
fn low_pass(f: f64) -> f64 {
    1.0 / (1.0 + (f / 1200.0).powi(8)).sqrt()
}
fn high_pass(f: f64) -> f64 {
    let r = (f / 3000.0).powi(8);
    (r / (1.0 + r)).sqrt()
}

/// A plane wave from `d` of white noise shaped by `gain(f)`, exact fractional
/// delays (as in `synth`: microphone at `p` hears it earlier by `p·d/c`),
/// unit power averaged over microphones.
fn shaped_plane_wave(
    mics: &[Vector3<f64>],
    d: &Vector3<f64>,
    gain: fn(f64) -> f64,
    len: usize,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> Vec<Vec<f64>> {
    let mut planner = RealFftPlanner::<f64>::new();
    let (fft, ifft) = (planner.plan_fft_forward(len), planner.plan_fft_inverse(len));
    let mut s = synth::white(rng, len);
    let mut spec = fft.make_output_vec();
    fft.process(&mut s, &mut spec).unwrap();
    let mut out: Vec<Vec<f64>> = mics
        .iter()
        .map(|p| {
            let advance = p.dot(d) / synth::C;
            let mut x: Vec<Complex<f64>> = (0..=len / 2)
                .map(|k| {
                    if k == 0 || k == len / 2 {
                        return Complex::new(0.0, 0.0);
                    }
                    let f = k as f64 * FS / len as f64;
                    let w = 2.0 * std::f64::consts::PI * f * advance;
                    spec[k] * gain(f) * Complex::new(w.cos(), w.sin())
                })
                .collect();
            let mut y = vec![0.0; len];
            ifft.process(&mut x, &mut y).unwrap();
            y
        })
        .collect();
    let power = out.iter().flatten().map(|v| v * v).sum::<f64>() / (out.len() * len) as f64;
    out.iter_mut().flatten().for_each(|v| *v /= power.sqrt());
    out
}

/// `gain²` averaged over each band's bins as the pipeline assigns them (dB),
/// floored 40 dB below the peak: the source's own spectrum, band by band.
fn reference_db(edges: &[f64], gain: fn(f64) -> f64, frame_len: usize) -> Vec<f64> {
    let df = FS / frame_len as f64;
    let bands = edges.len() - 1;
    let v: Vec<f64> = (0..bands)
        .map(|b| {
            let (lo, hi) = (edges[b], edges[b + 1]);
            let ks: Vec<usize> = (1..=frame_len / 2)
                .filter(|&k| {
                    let f = k as f64 * df;
                    f >= lo && (f < hi || (b + 1 == bands && f <= hi))
                })
                .collect();
            let ks = if ks.is_empty() { vec![((lo * hi).sqrt() / df).round() as usize] } else { ks };
            10.0 * (ks.iter().map(|&k| gain(k as f64 * df).powi(2)).sum::<f64>() / ks.len() as f64).log10()
        })
        .collect();
    let max = v.iter().copied().fold(f64::MIN, f64::max);
    v.into_iter().map(|x| x.max(max - 40.0)).collect()
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

fn direction(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
}

struct Scene {
    array: ArrayGeometry,
    dirs: [Vector3<f64>; 2],
    audio: Vec<f32>,
}

/// A low-pass source and a high-pass source at well separated directions,
/// equal power, 30 dB sensor noise, 2 s.
fn two_sources() -> Scene {
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let mics = synth::positions(&array);
    let mut rng = synth::rng(41);
    let dirs = [direction(30.0, 25.0), direction(160.0, 45.0)];
    let len = 1 << 15;
    let a = shaped_plane_wave(&mics, &dirs[0], low_pass, len, &mut rng);
    let b = shaped_plane_wave(&mics, &dirs[1], high_pass, len, &mut rng);
    let mut x: Vec<Vec<f64>> =
        a.iter().zip(&b).map(|(a, b)| a.iter().zip(b).map(|(a, b)| a + b).collect()).collect();
    synth::add_sensor_noise(&mut x, 30.0, &mut rng);
    Scene { array, dirs, audio: synth::interleave(&x, 0.1) }
}

/// The reported track nearest `d` (within 5°) in the last frame.
fn track_near(r: &FrameResult, d: &Vector3<f64>) -> Option<u64> {
    r.reported
        .iter()
        .map(|&i| &r.tracks[i])
        .find(|t| synth::angle_deg(&t.direction_in_array, d) < 5.0)
        .map(|t| t.track_id)
}

#[test]
fn two_different_sources_get_different_signatures_each_like_its_own_spectrum() {
    let scene = two_sources();
    let config = PipelineConfig::default();
    let mut p = Pipeline::new(&scene.array, &config).unwrap();
    let frames = synth::run(&mut p, &scene.audio);
    let last = frames.last().unwrap();
    let edges = p.signatures().band_edges_hz().to_vec();
    assert_eq!(edges.len(), 25);
    let ids: Vec<u64> =
        scene.dirs.iter().map(|d| track_near(last, d).expect("both sources tracked")).collect();
    let sig = |id| last.signature_of(id).unwrap().iter().map(|&v| v as f64).collect::<Vec<f64>>();
    let (sig_lp, sig_hp) = (sig(ids[0]), sig(ids[1]));
    let ref_lp = reference_db(&edges, low_pass, config.frame_len);
    let ref_hp = reference_db(&edges, high_pass, config.frame_len);
    println!("low-pass track:  {sig_lp:.1?}\nhigh-pass track: {sig_hp:.1?}");
    // Delay-and-sum separates directions only where the wavelength is not much
    // longer than the aperture: below c/aperture (0.7 kHz for this 0.49 m array)
    // every steered beam hears every source. Compare the bands above that.
    let f_resolved = synth::C / scene.array.aperture_m();
    let first = edges.iter().position(|&e| e >= f_resolved).unwrap();
    let (sig_lp, sig_hp, ref_lp, ref_hp) =
        (&sig_lp[first..], &sig_hp[first..], &ref_lp[first..], &ref_hp[first..]);
    let own = [correlation(sig_lp, ref_lp), correlation(sig_hp, ref_hp)];
    let cross = [correlation(sig_lp, ref_hp), correlation(sig_hp, ref_lp)];
    let between = correlation(sig_lp, sig_hp);
    println!("bands from {:.0} Hz ({first} of {})", edges[first], edges.len() - 1);
    println!("own {own:.3?}, cross {cross:.3?}, between the tracks {between:.3}");
    // (Measured: own 0.89 and 0.63, cross −0.95 and −0.77, between −0.55; the
    // high-pass track's own figure is lowered by the low-pass source leaking
    // into its beam around 1 kHz, where the beam is still wide.)
    assert!(own.iter().all(|&c| c > 0.5), "each signature follows its own source: {own:?}");
    assert!(cross.iter().all(|&c| c < -0.5), "and not the other one: {cross:?}");
    assert!(own.iter().zip(&cross).all(|(o, c)| o - c > 1.2), "own {own:?} vs cross {cross:?}");
    assert!(between < -0.3, "the two signatures look nothing alike: {between}");
    // In levels: the low band belongs to the low-pass track, the high band to the high-pass one.
    let band_of = |hz: f64| edges.windows(2).position(|e| e[0] <= hz && hz < e[1]).unwrap();
    let (low, high) = (band_of(1000.0) - first, band_of(5000.0) - first);
    assert!(sig_lp[low] - sig_hp[low] > 6.0, "{} vs {}", sig_lp[low], sig_hp[low]);
    assert!(sig_hp[high] - sig_lp[high] > 10.0, "{} vs {}", sig_hp[high], sig_lp[high]);
    // Every reported DoA carries B finite values within the contract's range.
    for d in last.confirmed_doas() {
        let s = d.signature.expect("a signature");
        assert_eq!(s.len(), 24);
        assert!(s.iter().all(|v| v.is_finite() && (-200.0..=200.0).contains(v)));
    }
}

#[test]
fn a_white_plane_wave_reads_its_level_in_every_band() {
    // Unit-variance white noise scaled by 0.1 → −20 dB in every band.
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let mics = synth::positions(&array);
    let mut rng = synth::rng(5);
    let d = direction(-60.0, 30.0);
    let x = synth::plane_wave(&mics, &d, FS, 1 << 14, &mut rng);
    let mut p = Pipeline::new(&array, &PipelineConfig::default()).unwrap();
    let frames = synth::run(&mut p, &synth::interleave(&x, 0.1));
    let last = frames.last().unwrap();
    let id = track_near(last, &d).expect("tracked");
    let s = last.signature_of(id).unwrap();
    let mean = s.iter().sum::<f32>() / s.len() as f32;
    println!("{s:.1?}");
    assert!((mean + 20.0).abs() < 1.0, "mean level {mean} dB, expected −20 dB");
    assert!(s.iter().all(|v| (v - mean).abs() < 3.0), "flat within 3 dB: {s:?}");
}

#[test]
fn at_most_k_tracks_go_out_most_active_first() {
    let scene = two_sources();
    let one = PipelineConfig { max_reported_tracks: 1, ..Default::default() };
    let mut p = Pipeline::new(&scene.array, &one).unwrap();
    let frames = synth::run(&mut p, &scene.audio);
    let last = frames.last().unwrap();
    assert!(last.tracks.iter().filter(|t| t.confirmed).count() >= 2, "two confirmed tracks");
    let doas = last.confirmed_doas();
    assert_eq!(doas.len(), 1);
    let most_active = last.tracks.iter().filter(|t| t.confirmed).map(|t| t.activity).fold(0.0, f64::max);
    assert_eq!(doas[0].activity, most_active);
    assert_eq!(last.signatures_db.len(), 24);
    // With K = 4, both go out, ordered by activity.
    let mut p = Pipeline::new(&scene.array, &PipelineConfig::default()).unwrap();
    for r in synth::run(&mut p, &scene.audio) {
        let doas = r.confirmed_doas();
        assert!(doas.len() <= 4);
        assert!(doas.windows(2).all(|w| w[0].activity >= w[1].activity));
        assert_eq!(r.signatures_db.len(), doas.len() * 24);
    }
    // Signatures off: DoAs without signatures.
    let off = PipelineConfig {
        signature: soundmap_agent::pipeline::SignatureConfig { bands: 0, ..Default::default() },
        ..Default::default()
    };
    let mut p = Pipeline::new(&scene.array, &off).unwrap();
    let frames = synth::run(&mut p, &scene.audio);
    let doas = frames.last().unwrap().confirmed_doas();
    assert!(!doas.is_empty() && doas.iter().all(|d| d.signature.is_none()));
}

#[test]
fn bad_settings_are_named() {
    let array = ArrayGeometry::load("respeaker-4").unwrap();
    let field = |c: PipelineConfig| match Pipeline::new(&array, &c) {
        Err(soundmap_agent::AgentError::InvalidParameter { field, .. }) => field,
        other => panic!("{other:?}"),
    };
    assert_eq!(field(PipelineConfig { max_reported_tracks: 0, ..Default::default() }), "max_reported_tracks");
    assert_eq!(
        field(PipelineConfig { max_reported_tracks: 65, ..Default::default() }),
        "max_reported_tracks"
    );
    let mut c = PipelineConfig::default();
    c.signature.bands = 100;
    assert_eq!(field(c), "signature.bands");
    let c: PipelineConfig = toml::from_str(
        "max_reported_tracks = 2\n[signature]\nbands = 16\nlow_edge_hz = 200.0\ntime_constant_s = 0.05\n",
    )
    .unwrap();
    assert_eq!((c.max_reported_tracks, c.signature.bands, c.signature.low_edge_hz), (2, 16, 200.0));
    assert!(toml::from_str::<PipelineConfig>("[signature]\nband = 3\n").is_err());
}

#[test]
fn the_hello_declares_the_layout_and_the_core_passes_signatures_through() {
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let config = PipelineConfig::default();
    let plain = agent::hello(RobotId::parse("r1", "robot_id").unwrap(), &array, "test".into());
    assert_eq!((plain.signature_bands.as_ref(), plain.max_tracks), (None, None));
    let hello = config.declare_tracks(plain).unwrap();
    assert_eq!(hello.max_tracks, Some(4));
    let edges = hello.signature_bands.clone().unwrap();
    assert_eq!(edges.len(), 25);
    assert!((edges[0] - 100.0).abs() < 1e-9 && (edges[24] - 7200.0).abs() < 1e-9);
    // The coordinator accepts the declared layout as sent.
    let limits = Limits::at(Stamp::from_ns(2_000_000_000_000_000_000));
    let back = Hello::from_wire(&hello.to_wire(), &limits).unwrap();
    assert_eq!(back, hello);
    // Plane-wave elevations by default; the floor fit's are the direct path's,
    // and the flag survives the wire.
    assert!(!hello.array.direct_path_elevations);
    let mut fitted = config.clone();
    fitted.srp.floor_fit = true;
    let plain = agent::hello(RobotId::parse("r1", "robot_id").unwrap(), &array, "test".into());
    let direct = fitted.declare_tracks(plain).unwrap();
    assert!(direct.array.direct_path_elevations);
    assert!(Hello::from_wire(&direct.to_wire(), &limits).unwrap().array.direct_path_elevations);

    // The core passes the pipeline's DoAs, signatures included, through unchanged.
    let scene = two_sources();
    let mut p = Pipeline::new(&scene.array, &config).unwrap();
    let frames = synth::run(&mut p, &scene.audio);
    let last = frames.last().unwrap();
    let doas = last.confirmed_doas();
    assert_eq!(doas.len(), 2);
    let mut core = Agent::new(hello.clone(), CoreConfig::default(), "poses").unwrap();
    let t = |s: f64| Stamp::from_ns(1_000_000_000_000).plus_secs(s);
    let pose = |s: f64| StampedPose { stamp: t(s), map_from_base: Isometry3::identity(), covariance: None };
    core.handle_pose(t(0.0), pose(0.0)).unwrap();
    core.handle_hop(t(0.05), t(0.05), doas.clone());
    core.handle_pose(t(0.1), pose(0.1)).unwrap();
    let obs = core.poll_observation().expect("an observation");
    assert_eq!(obs.doas.len(), 2);
    for (sent, made) in obs.doas.iter().zip(&doas) {
        assert_eq!(sent.track_id, made.track_id);
        assert_eq!(sent.signature, made.signature);
    }
    // And the observation passes the coordinator's checks against this hello.
    let wire = obs.to_wire();
    let back = soundmap_proto::Observation::from_wire(&wire, &Limits::at(t(0.1))).unwrap();
    back.check_against(&hello).unwrap();
}
