//! ODAS bridge: SST JSON in ODAS's real (concatenated, pretty-printed) format,
//! from a file and from a TCP connection made by "ODAS".

use std::path::PathBuf;
use std::time::Duration;

use soundmap_agent::AgentError;
use soundmap_agent::odas::{self, LiveStart, OdasTiming, SstParser};
use soundmap_proto::Stamp;
use tokio::io::AsyncWriteExt;

fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/odas_sst_tracked.json")
}

/// 128-sample hops at 16 kHz: 8 ms per hop.
fn timing(start: Stamp) -> OdasTiming {
    OdasTiming { hop_len: 128, sample_rate_hz: 16_000, start }
}

#[test]
fn fixture_file_converts_to_tracked_doas() {
    let start = Stamp::from_ns(1_700_000_000_000_000_000);
    let frames = odas::read_sst_file(&fixture(), &timing(start)).unwrap();
    assert_eq!(frames.len(), 6);
    // Hop 1 is at the start; each hop is 8 ms.
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(f.time_stamp, k as u64 + 1);
        assert_eq!(f.stamp, start.plus_ns(k as i64 * 8_000_000));
    }
    // Empty slots (id 0, zero vector) are skipped.
    let counts: Vec<usize> = frames.iter().map(|f| f.doas.len()).collect();
    assert_eq!(counts, vec![0, 1, 1, 2, 2, 2]);
    let d = &frames[3].doas;
    assert_eq!((d[0].track_id, d[1].track_id), (1, 2));
    assert_eq!(d[1].activity, 0.42);
    // ODAS sends no σ: the bridge attaches the prior of ODAS's DoAs.
    assert_eq!(d[0].angular_sigma_rad, Some(soundmap_agent::odas::PRIOR_SIGMA_DEG.to_radians()));
    // Renormalized exactly; the direction is what the fixture encodes
    // (track 2: azimuth −120°, elevation −5°), to ODAS's 3 printed decimals.
    for f in &frames {
        for doa in &f.doas {
            assert!((doa.direction_in_array.norm() - 1.0).abs() < 1e-12);
        }
    }
    let v = d[1].direction_in_array;
    assert!((v.y.atan2(v.x).to_degrees() + 120.0).abs() < 0.2);
    assert!((v.z.asin().to_degrees() + 5.0).abs() < 0.2);
}

#[test]
fn parser_accepts_arbitrary_chunking() {
    let bytes = std::fs::read(fixture()).unwrap();
    for chunk in [1, 7, 100, 4096] {
        let mut p = SstParser::new();
        let mut n = 0;
        for c in bytes.chunks(chunk) {
            for r in p.feed(c) {
                let f = r.unwrap();
                n += 1;
                assert_eq!(f.time_stamp, n);
                assert_eq!(f.src.len(), 4);
            }
        }
        assert_eq!(n, 6, "chunk {chunk}");
        assert!(!p.has_partial());
    }
}

#[test]
fn malformed_objects_are_reported_with_their_line_and_skipped() {
    let good = std::fs::read_to_string(fixture()).unwrap();
    // Object 2 cut in the middle (as when ODAS is killed), then the rest.
    let cut_at = good.find("\"timeStamp\": 2").unwrap() + 40;
    let resume = good.find("{\n    \"timeStamp\": 3").unwrap();
    let broken = format!("{}\n{}", &good[..cut_at], &good[resume..]);
    let mut p = SstParser::new();
    let results = p.feed(broken.as_bytes());
    let stamps: Vec<u64> = results.iter().filter_map(|r| r.as_ref().ok()).map(|f| f.time_stamp).collect();
    assert_eq!(stamps, vec![1, 3, 4, 5, 6]);
    let errors: Vec<&(usize, String)> = results.iter().filter_map(|r| r.as_ref().err()).collect();
    assert_eq!(errors.len(), 1);
    assert!(errors[0].0 >= 10 && errors[0].0 <= 14, "line {}", errors[0].0);

    // From a file, the first bad object is an error naming file and line.
    let dir = std::env::temp_dir().join(format!("soundmap-odas-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("broken.json");
    std::fs::write(&path, &broken).unwrap();
    let e = odas::read_sst_file(&path, &timing(Stamp::ZERO)).unwrap_err();
    let AgentError::Odas { source_name, .. } = &e else { panic!("{e:?}") };
    assert!(source_name.contains("broken.json:1"), "{e}");
    // A file ending inside an object is truncated.
    std::fs::write(&path, &good[..good.len() - 20]).unwrap();
    let e = odas::read_sst_file(&path, &timing(Stamp::ZERO)).unwrap_err().to_string();
    assert!(e.contains("broken.json") && e.contains("truncated"), "{e}");
    // A direction that is not a unit vector.
    std::fs::write(&path, good.replace("\"x\": 0.779", "\"x\": 1.779")).unwrap();
    let e = odas::read_sst_file(&path, &timing(Stamp::ZERO)).unwrap_err().to_string();
    assert!(e.contains("timeStamp 2") && e.contains("not a unit vector"), "{e}");
}

#[tokio::test]
async fn bridge_listens_for_odas_and_forwards_frames() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let start = Stamp::from_ns(42_000_000_000);
    let bridge = tokio::spawn(odas::serve_tcp(listener, 128, 16_000, LiveStart::Fixed(start), tx));
    let bytes = std::fs::read(fixture()).unwrap();
    // ODAS connects out as a client and sends its objects in whatever chunks.
    let mut odas_side = tokio::net::TcpStream::connect(addr).await.unwrap();
    for c in bytes.chunks(333) {
        odas_side.write_all(c).await.unwrap();
        odas_side.flush().await.unwrap();
    }
    for k in 0..6u64 {
        let f = tokio::time::timeout(Duration::from_secs(5), rx.recv()).await.unwrap().unwrap();
        assert_eq!(f.time_stamp, k + 1);
        assert_eq!(f.stamp, start.plus_ns(k as i64 * 8_000_000));
    }
    drop(odas_side);
    drop(rx);
    bridge.abort();
}

#[tokio::test]
async fn live_stream_without_a_start_is_anchored_at_the_first_frame() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let bridge = tokio::spawn(odas::serve_tcp(listener, 128, 16_000, LiveStart::AtFirstFrame, tx));
    let before = Stamp::now();
    let mut odas_side = tokio::net::TcpStream::connect(addr).await.unwrap();
    odas_side.write_all(&std::fs::read(fixture()).unwrap()).await.unwrap();
    let first = tokio::time::timeout(Duration::from_secs(5), rx.recv()).await.unwrap().unwrap();
    let second = tokio::time::timeout(Duration::from_secs(5), rx.recv()).await.unwrap().unwrap();
    assert!(first.stamp >= before && first.stamp <= Stamp::now());
    assert_eq!(second.stamp - first.stamp, 8_000_000);
    bridge.abort();
}
