//! Tests of the localizer against exact, frame-level plane waves: spectra
//! built directly as `Xᵢ[k] = S[k] e^{jωₖ pᵢ·d/c}` (no window edge effects),
//! so a noise-free plane wave must be found to numerical precision.

use nalgebra::{Isometry3, Point3, Vector3};
use proptest::prelude::*;
use realfft::num_complex::Complex;

use super::*;
use crate::array::{ArrayGeometry, Microphone, SearchRegion};

const FS: u32 = 16000;
const N: usize = 256;

/// Spectra (channel-major, N/2+1 bins) of plane waves from `dirs` with
/// amplitudes `amps`, each with a deterministic pseudo-random source spectrum.
fn spectra(array: &ArrayGeometry, dirs: &[Vector3<f64>], amps: &[f64], seed: u64) -> Vec<Complex<f32>> {
    let bins = N / 2 + 1;
    let mut out = vec![Complex::new(0.0f32, 0.0); array.channels() * bins];
    let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut next = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) * std::f64::consts::TAU
    };
    for (d, &a) in dirs.iter().zip(amps) {
        for k in 0..bins {
            let phase = next();
            let w = std::f64::consts::TAU * k as f64 * FS as f64 / N as f64;
            for (i, m) in array.microphones.iter().enumerate() {
                let ph = phase + w * m.position_in_array.coords.dot(d) / 343.0;
                out[i * bins + k] += Complex::new((a * ph.cos()) as f32, (a * ph.sin()) as f32);
            }
        }
    }
    out
}

fn localize(array: &ArrayGeometry, config: &SrpConfig, x: &[Complex<f32>]) -> Vec<PotentialSource> {
    let mut srp = Srp::new(array, FS, N, config).unwrap();
    let mut out = Vec::with_capacity(config.max_sources);
    srp.process(x, &mut out);
    out
}

fn deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.angle(b).to_degrees()
}

#[test]
fn tdoa_convention_matches_the_geometry() {
    let array = ArrayGeometry::load("respeaker-4").unwrap();
    let srp = Srp::new(&array, FS, N, &SrpConfig::default()).unwrap();
    // Pair (0, 2): microphones at x = −32 mm and +32 mm. A source along +x
    // reaches microphone 2 first: τ = (p₂ − p₀)·d fs/c > 0 samples.
    let p = 1; // pairs in order (0,1), (0,2), ...
    let t = srp.tdoa_samples(p, &Vector3::x());
    assert!((t - 0.064 * 16000.0 / 343.0).abs() < 1e-9, "{t}");
}

#[test]
fn packed_correlations_peak_at_each_pairs_tdoa() {
    // Three microphones → pairs (0,1), (0,2) share one FFT, (1,2) is alone.
    let mics = [Point3::new(0.0, 0.0, 0.0), Point3::new(0.1, 0.02, 0.0), Point3::new(-0.03, 0.12, 0.05)];
    let array = ArrayGeometry::new(
        "three",
        mics.iter().map(|&p| Microphone::omni(p)).collect(),
        Isometry3::identity(),
        SearchRegion::full_sphere(),
        std::path::Path::new("<test>"),
    )
    .unwrap();
    let d = Vector3::new(0.3, -0.5, 0.8).normalize();
    let mut srp = Srp::new(&array, FS, N, &SrpConfig::default()).unwrap();
    let x = spectra(&array, &[d], &[1.0], 1);
    srp.correlate_only(&x);
    let r = srp.cc.lag_radius as f64;
    for p in 0..3 {
        let row = &srp.cc.cc[p * srp.cc.stride..(p + 1) * srp.cc.stride - 1];
        let (imax, _) =
            row.iter().enumerate().fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
        let expected = srp.tdoa_samples(p, &d) + r;
        assert!(
            (imax as f64 - expected).abs() <= 0.5 + 1e-9,
            "pair {p}: peak at {imax}, TDOA index {expected}"
        );
    }
}

#[test]
fn noise_free_plane_waves_are_found_exactly_on_every_preset() {
    for name in crate::array::presets::NAMES {
        let array = ArrayGeometry::load(name).unwrap();
        for (s, d) in
            [Vector3::new(0.6, 0.3, 0.74), Vector3::new(-0.2, -0.9, 0.1), Vector3::new(0.0, 0.1, 0.99)]
                .iter()
                .enumerate()
        {
            let d = d.normalize();
            let out = localize(&array, &SrpConfig::default(), &spectra(&array, &[d], &[1.0], s as u64));
            let err = deg(&out[0].direction_in_array, &d);
            assert!(err < 0.01, "{name}: error {err}° toward {d:?}");
            assert!((out[0].energy - 1.0).abs() < 1e-3, "{name}: coherence {}", out[0].energy);
        }
    }
}

#[test]
fn second_potential_finds_a_second_source_not_a_sidelobe() {
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let (a, b) = (Vector3::new(0.8, 0.3, 0.52).normalize(), Vector3::new(-0.4, -0.7, 0.6).normalize());
    let out = localize(&array, &SrpConfig::default(), &spectra(&array, &[a, b], &[1.0, 0.7], 9));
    assert_eq!(out.len(), 2);
    assert!(deg(&out[0].direction_in_array, &a) < 0.5, "{:?}", out[0]);
    assert!(deg(&out[1].direction_in_array, &b) < 0.5, "{:?}", out[1]);
    // One source only: the second potential is weak (its sidelobes were projected out).
    let single = localize(&array, &SrpConfig::default(), &spectra(&array, &[a], &[1.0], 9));
    assert!(single[1].energy < 0.1, "{:?}", single[1]);
}

/// A small planar array hears diffuse noise as a source at its zenith: under
/// a diffuse field four times as strong as the source, a ReSpeaker 6 reads a
/// source 15° above its plane high; subtracting the diffuse field's expected
/// power (`diffuse_compensation`) takes most of that pull away.
#[test]
fn diffuse_compensation_takes_the_zenith_pull_off_a_small_array() {
    let array = ArrayGeometry::load("respeaker-6").unwrap();
    let d = Vector3::new(15f64.to_radians().cos(), 0.0, 15f64.to_radians().sin());
    // ~Isotropic noise: many plane waves from a Fibonacci sphere.
    let n = 400;
    let mut dirs = vec![d];
    let mut amps = vec![1.0];
    for i in 0..n {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
        let a = i as f64 * 2.399963;
        let r = (1.0 - z * z).sqrt();
        dirs.push(Vector3::new(r * a.cos(), r * a.sin(), z));
        amps.push((4.0 / n as f64).sqrt());
    }
    let bias = |compensation: f64| {
        let config = SrpConfig { diffuse_compensation: compensation, ..SrpConfig::default() };
        let mut errs: Vec<f64> = (0..15)
            .map(|seed| {
                let out = localize(&array, &config, &spectra(&array, &dirs, &amps, seed));
                out[0].direction_in_array.z.asin().to_degrees() - 15.0
            })
            .collect();
        errs.sort_by(f64::total_cmp);
        errs[errs.len() / 2]
    };
    let (raw, compensated) = (bias(0.0), bias(1.0));
    println!("elevation bias: raw {raw:+.1}°, compensated {compensated:+.1}°");
    assert!(raw > 3.0, "the diffuse field should pull the raw peak up: {raw:+.1}°");
    assert!(compensated.abs() < 0.5 * raw, "compensated {compensated:+.1}° against raw {raw:+.1}°");
}

#[test]
fn silence_gives_no_potential() {
    let array = ArrayGeometry::load("uma8").unwrap();
    let x = vec![Complex::new(0.0f32, 0.0); array.channels() * (N / 2 + 1)];
    assert!(localize(&array, &SrpConfig::default(), &x).is_empty());
}

#[test]
fn directional_microphones_still_localize() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/arrays/square-4.toml");
    let mut array = ArrayGeometry::load(path.to_str().unwrap()).unwrap();
    for m in &mut array.microphones {
        m.axis_in_array = Some(Vector3::z_axis());
    }
    let d = Vector3::new(0.5, 0.5, 0.7).normalize();
    let out = localize(&array, &SrpConfig::default(), &spectra(&array, &[d], &[1.0], 4));
    assert!(deg(&out[0].direction_in_array, &d) < 0.01);
    assert!((out[0].energy - 1.0).abs() < 1e-3, "{}", out[0].energy);
}

#[test]
fn bad_settings_are_rejected() {
    let array = ArrayGeometry::load("respeaker-4").unwrap();
    let bad = |f: fn(&mut SrpConfig)| {
        let mut c = SrpConfig::default();
        f(&mut c);
        Srp::new(&array, FS, N, &c).unwrap_err()
    };
    assert!(matches!(bad(|c| c.speed_of_sound_m_per_s = 0.0), AgentError::InvalidParameter { .. }));
    assert!(matches!(bad(|c| c.min_frequency_hz = 7990.0), AgentError::InvalidParameter { .. }));
    assert!(matches!(bad(|c| c.coarse_level = 5), AgentError::InvalidParameter { .. }));
    assert!(matches!(bad(|c| c.max_sources = 0), AgentError::InvalidParameter { .. }));
    assert!(matches!(bad(|c| c.diffuse_compensation = 2.5), AgentError::InvalidParameter { .. }));
    let big = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    assert!(Srp::new(&big, 48000, 64, &SrpConfig::default()).is_err(), "frames too short for the aperture");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Noise-free exactness on random non-planar arrays and directions over
    /// the whole sphere.
    #[test]
    fn random_arrays_find_noise_free_sources(
        mics in prop::collection::vec(prop::array::uniform3(-0.08f64..0.08), 5..9),
        dir in prop::array::uniform3(-1.0f64..1.0),
        seed in 0u64..1000,
    ) {
        let d = Vector3::from(dir);
        prop_assume!(d.norm() > 0.2);
        let d = d.normalize();
        let microphones: Vec<_> = mics.iter().map(|&p| Microphone::omni(Point3::from(p))).collect();
        let array = ArrayGeometry::new(
            "random", microphones, Isometry3::identity(), SearchRegion::full_sphere(), std::path::Path::new("<test>"),
        );
        prop_assume!(array.is_ok());
        let array = array.unwrap();
        // Well-spread in 3D: the smallest principal spread is at least 2 cm.
        let c = array.centroid();
        let mut s = nalgebra::Matrix3::zeros();
        for p in array.positions() {
            s += (p - c) * (p - c).transpose();
        }
        prop_assume!((s.symmetric_eigen().eigenvalues.min() / array.channels() as f64).sqrt() > 0.02);
        let config = SrpConfig { region: Some(RegionConfig { axis: [0.0, 0.0, 1.0], max_angle_deg: 180.0 }), ..SrpConfig::default() };
        let out = localize(&array, &config, &spectra(&array, &[d], &[1.0], seed));
        prop_assert!(deg(&out[0].direction_in_array, &d) < 0.01, "error {}°", deg(&out[0].direction_in_array, &d));
        prop_assert!((out[0].energy - 1.0).abs() < 1e-3);
    }
}

/// Spectra of a point source at `source` (array frame, m): spherical
/// wavefronts, `Xᵢ[k] = S[k] e^{jωₖ(ρ − |s − pᵢ|)/c}` (amplitudes equal).
fn point_source_spectra(array: &ArrayGeometry, source: &Vector3<f64>, seed: u64) -> Vec<Complex<f32>> {
    let bins = N / 2 + 1;
    let mut out = vec![Complex::new(0.0f32, 0.0); array.channels() * bins];
    let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let rho = source.norm();
    for k in 0..bins {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let phase = ((state >> 11) as f64 / (1u64 << 53) as f64) * std::f64::consts::TAU;
        let w = std::f64::consts::TAU * k as f64 * FS as f64 / N as f64;
        for (i, m) in array.microphones.iter().enumerate() {
            let lead = (rho - (source - m.position_in_array.coords).norm()) / 343.0;
            let ph = phase + w * lead;
            out[i * bins + k] = Complex::new(ph.cos() as f32, ph.sin() as f32);
        }
    }
    out
}

#[test]
fn near_field_refinement_removes_the_plane_wave_elevation_bias() {
    // 16SoundsUSB (Pioneer): a source 5 m away, 6.8° above the array's plane,
    // as a talker across a room is for a robot. A plane-wave fit puts it
    // about 1.3° low; the spherical wavefront finds it and its range.
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    for (range, elevation_deg, azimuth_deg) in [(5.0, 6.8, 30.0), (2.0, 20.0, -120.0), (1.2, 35.0, 75.0)] {
        let (e, a) = (f64::to_radians(elevation_deg), f64::to_radians(azimuth_deg));
        let d = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
        let x = point_source_spectra(&array, &(d * range), 7);
        let far = SrpConfig { near_field: false, max_sources: 1, ..SrpConfig::default() };
        let near = SrpConfig { near_field: true, max_sources: 1, ..SrpConfig::default() };
        let plane = localize(&array, &far, &x)[0];
        let sphere = localize(&array, &near, &x)[0];
        let (plane_err, sphere_err) =
            (deg(&plane.direction_in_array, &d), deg(&sphere.direction_in_array, &d));
        if range >= 5.0 {
            assert!(plane_err > 0.8, "plane-wave fit at {range} m: {plane_err}°");
        }
        assert!(sphere_err < 0.05, "near-field fit at {range} m: {sphere_err}° (plane wave {plane_err}°)");
        let found_range = 1.0 / sphere.inverse_range_per_m;
        assert!((found_range - range).abs() < 0.05 * range, "range {found_range} m, truth {range} m");
        assert_eq!(plane.inverse_range_per_m, 0.0);
    }
}

#[test]
fn near_field_refinement_keeps_plane_waves_exact() {
    // A plane wave is the κ = 0 bound: the near-field fit must not invent a range.
    for preset in ["16soundsusb-pioneer", "respeaker-6"] {
        let array = ArrayGeometry::load(preset).unwrap();
        let d = Vector3::new(0.6, -0.5, 0.4).normalize();
        let x = spectra(&array, &[d], &[1.0], 3);
        let p =
            localize(&array, &SrpConfig { near_field: true, max_sources: 1, ..SrpConfig::default() }, &x)[0];
        assert!(deg(&p.direction_in_array, &d) < 0.01, "{preset}: {}°", deg(&p.direction_in_array, &d));
        assert!(p.inverse_range_per_m < 0.02, "{preset}: κ = {}", p.inverse_range_per_m);
    }
}

/// The hot loops give the same potentials, to the bit, whichever
/// instructions they run with (AVX2 where the CPU has it, the baseline).
#[cfg(target_arch = "x86_64")]
#[test]
fn vector_and_scalar_kernels_agree_to_the_bit() {
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let dirs = [Vector3::new(0.8, 0.5, 0.33).normalize(), Vector3::new(-0.6, 0.7, 0.4).normalize()];
    let config = SrpConfig { max_sources: 3, near_field: true, ..SrpConfig::default() };
    for seed in 0..4 {
        let x = spectra(&array, &dirs, &[1.0, 0.6], seed);
        let run = |arch: Option<pulp::Arch>| {
            let mut srp = Srp::new(&array, FS, N, &config).unwrap();
            if let Some(arch) = arch {
                srp.set_arch(arch);
            }
            let mut out = Vec::with_capacity(3);
            srp.process(&x, &mut out);
            out
        };
        let (best, scalar) = (run(None), run(Some(pulp::Arch::Scalar)));
        assert_eq!(best.len(), 3);
        assert_eq!(best, scalar, "seed {seed}");
    }
}

/// Spectra of a point source at `source` (array frame, m) and its image in
/// a floor `height` m below the array origin with pressure reflection
/// `beta` (spherical spreading, the image's extra delay in every bin; the
/// window's overlap is 1 here, so the image is a little stronger than in a
/// frame of real audio).
fn source_and_floor_image(
    array: &ArrayGeometry,
    source: &Vector3<f64>,
    height: f64,
    beta: f64,
    seed: u64,
) -> Vec<Complex<f32>> {
    let bins = N / 2 + 1;
    let mut out = vec![Complex::new(0.0f32, 0.0); array.channels() * bins];
    let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let rho = source.norm();
    let image = Vector3::new(source.x, source.y, -source.z - 2.0 * height);
    for k in 0..bins {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let phase = ((state >> 11) as f64 / (1u64 << 53) as f64) * std::f64::consts::TAU;
        let w = std::f64::consts::TAU * k as f64 * FS as f64 / N as f64;
        for (i, m) in array.microphones.iter().enumerate() {
            let mut x = Complex::new(0.0f64, 0.0);
            for (s, g) in [(source, 1.0), (&image, beta)] {
                let r = (s - m.position_in_array.coords).norm();
                x += Complex::from_polar(g * rho / r, phase + w * (rho - r) / 343.0);
            }
            out[i * bins + k] = Complex::new(x.re as f32, x.im as f32);
        }
    }
    out
}

#[test]
fn floor_fit_recovers_the_direct_path_from_its_floor_image() {
    // 16SoundsUSB (Pioneer) 0.5 m above a floor that reflects 0.8 of the
    // pressure: sources 2.5–5 m away a little above the array. A single
    // specular image barely moves a PHAT peak (0.1–0.6° here, with the
    // plane wave's near-field bias; the pull in rooms comes from the
    // vertical family against a diffuse field, see `floor_fit`), so what
    // this checks is that the fit's search finds the exact model's peak from
    // the plane-wave one: the direct path and the range.
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let height = 0.5;
    let config = SrpConfig {
        floor_fit: true,
        floor_height_m: Some(height),
        floor_reflection: 0.8,
        max_sources: 1,
        ..SrpConfig::default()
    };
    for (range, elevation_deg, azimuth_deg) in [(5.0, 8.0, 30.0), (3.5, 12.0, -120.0), (2.5, 16.0, 75.0)] {
        let (e, a) = (f64::to_radians(elevation_deg), f64::to_radians(azimuth_deg));
        let d = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
        let x = source_and_floor_image(&array, &(d * range), height, 0.8, 11);
        let mut srp = Srp::new(&array, FS, N, &config).unwrap();
        let mut out = Vec::new();
        srp.process(&x, &mut out);
        let plane = out[0].direction_in_array;
        let fitted = srp.fit_floor(&plane).expect("the image model fits better than the direct path alone");
        let (plane_err, fitted_err) = (deg(&plane, &d), deg(&fitted.direction, &d));
        assert!(fitted_err < 0.15, "floor fit at {range} m: {fitted_err}° (plane wave {plane_err}°)");
        assert!((fitted.range_m - range).abs() < 0.15 * range, "range {} m, truth {range} m", fitted.range_m);
        let shifted = srp.shift_elevation(&plane, fitted.offset_rad).unwrap();
        assert!(deg(&shifted, &fitted.direction) < 0.01, "the offset moves the peak onto the fit");
    }
}

#[test]
fn floor_fit_leaves_a_source_without_a_floor_image_alone() {
    // Free field: the image model fits no better than the direct path, so
    // the guard keeps the plane-wave peak (no fit, or one on the peak).
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let d = Vector3::new(0.6, -0.5, 0.2).normalize();
    let x = spectra(&array, &[d], &[1.0], 5);
    let config = SrpConfig { floor_fit: true, max_sources: 1, ..SrpConfig::default() };
    let mut srp = Srp::new(&array, FS, N, &config).unwrap();
    let mut out = Vec::new();
    assert!(srp.fit_floor(&Unit::new_normalize(d)).is_none(), "no frames yet: no fit");
    srp.process(&x, &mut out);
    let plane = out[0].direction_in_array;
    if let Some(f) = srp.fit_floor(&plane) {
        assert!(deg(&f.direction, &plane) < 0.05, "moved {}° off the plane wave", deg(&f.direction, &plane));
    }
    assert!(srp.take_stats().floor_fit_evaluations > 0, "the fit ran");
}

#[test]
fn floor_fit_settings_are_checked() {
    let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
    let bad = |c: SrpConfig, field: &str| {
        let e = Srp::new(&array, FS, N, &c).unwrap_err().to_string();
        assert!(e.contains(field), "{e}");
    };
    let on = SrpConfig { floor_fit: true, ..SrpConfig::default() };
    bad(SrpConfig { floor_reflection: 1.5, ..on.clone() }, "srp.floor_reflection");
    bad(SrpConfig { floor_height_m: Some(f64::NAN), ..on.clone() }, "srp.floor_height_m");
    bad(SrpConfig { ceiling_height_m: Some(0.2), ..on.clone() }, "srp.ceiling_height_m");
    bad(SrpConfig { floor_fit_min_gain: -0.5, ..on.clone() }, "srp.floor_fit_min_gain");
    bad(SrpConfig { floor_fit_frames: 0.5, ..on.clone() }, "srp.floor_fit_frames");
    bad(SrpConfig { floor_fit_every_hops: 0, ..on.clone() }, "srp.floor_fit_every_hops");
    bad(SrpConfig { floor_fit_steady_every_hops: 4, ..on.clone() }, "srp.floor_fit_steady_every_hops");
    assert!(Srp::new(&array, FS, N, &SrpConfig { floor_fit_steady_every_hops: 0, ..on.clone() }).is_ok());
    // An array whose mount gives no height (identity) needs floor_height_m.
    let flat = ArrayGeometry::load("respeaker-4").unwrap();
    let e = Srp::new(&flat, FS, N, &on).unwrap_err().to_string();
    assert!(e.contains("srp.floor_height_m"), "{e}");
    assert!(Srp::new(&flat, FS, N, &SrpConfig { floor_height_m: Some(0.3), ..on }).is_ok());
}
