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
    let dir = scratch("broken");
    let path = dir.path().join("broken.json");
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

/// The fixture's objects, each as ODAS writes it (with its trailing newline).
fn fixture_objects() -> Vec<String> {
    let text = std::fs::read_to_string(fixture()).unwrap();
    let objects: Vec<String> = text.split_inclusive("\n}\n").map(str::to_owned).collect();
    assert_eq!(objects.len(), 6);
    objects
}

async fn next(rx: &mut tokio::sync::mpsc::Receiver<odas::OdasFrame>) -> odas::OdasFrame {
    tokio::time::timeout(Duration::from_secs(5), rx.recv()).await.expect("a frame within 5 s").expect("open")
}

/// A scratch directory for one test, removed when dropped.
fn scratch(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-odas-{name}-")).tempdir().unwrap()
}

#[tokio::test]
async fn a_followed_file_is_read_as_odas_appends_to_it() {
    let dir = scratch("follow");
    let path = dir.path().join("tracks.json");
    let objects = fixture_objects();
    // ODAS has written three objects when the agent starts.
    std::fs::write(&path, objects[..3].concat()).unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let started = Stamp::now();
    let follower = tokio::spawn(odas::follow_file(path.clone(), 128, 16_000, LiveStart::AtFirstFrame, tx));
    tokio::time::sleep(Duration::from_millis(100)).await;
    let after_start = Stamp::now();
    // It appends the rest, one object split over two writes.
    let append = |bytes: &str| {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(bytes.as_bytes()).unwrap();
    };
    append(&objects[3]);
    let (a, b) = objects[4].split_at(objects[4].len() / 2);
    append(a);
    tokio::time::sleep(Duration::from_millis(60)).await;
    append(b);
    append(&objects[5]);
    // What was there is skipped; the newest object there (timeStamp 3) was
    // taken as written when the agent opened the file.
    let frames = [next(&mut rx).await, next(&mut rx).await, next(&mut rx).await];
    assert_eq!(frames.iter().map(|f| f.time_stamp).collect::<Vec<_>>(), vec![4, 5, 6]);
    let hop3 = frames[0].stamp.plus_ns(-8_000_000);
    assert!(hop3 >= started && hop3 <= after_start, "hop 3 at {hop3}, agent started at {started}");
    assert_eq!(frames[2].stamp - frames[1].stamp, 8_000_000);

    // ODAS restarts and rewrites the file from timeStamp 1: read again from
    // its start and anchored anew (hop 1 is now).
    let before = Stamp::now();
    std::fs::write(&path, objects[..2].concat()).unwrap();
    let again = [next(&mut rx).await, next(&mut rx).await];
    assert_eq!(again.iter().map(|f| f.time_stamp).collect::<Vec<_>>(), vec![1, 2]);
    assert!(again[0].stamp >= before && again[0].stamp <= Stamp::now());
    follower.abort();
}

#[tokio::test]
async fn a_followed_file_may_appear_after_the_agent_starts() {
    let dir = scratch("follow-late");
    let path = dir.path().join("later.json");
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let start = Stamp::now().plus_ns(-10_000_000_000);
    let follower = tokio::spawn(odas::follow_file(path.clone(), 128, 16_000, LiveStart::Fixed(start), tx));
    tokio::time::sleep(Duration::from_millis(100)).await;
    std::fs::write(&path, fixture_objects().concat()).unwrap();
    // With a known start, every object counts, from the first.
    for k in 0..6u64 {
        let f = next(&mut rx).await;
        assert_eq!((f.time_stamp, f.stamp), (k + 1, start.plus_ns(k as i64 * 8_000_000)));
    }
    follower.abort();
}

#[tokio::test]
async fn the_socket_bridge_waits_for_odas_to_reconnect_and_reanchors_a_restarted_one() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    // A known start in the past: the first connection is timed from it.
    let start = Stamp::now().plus_ns(-5_000_000_000);
    let bridge = tokio::spawn(odas::serve_tcp(listener, 128, 16_000, LiveStart::Fixed(start), tx));
    let objects = fixture_objects();
    let mut odas_side = tokio::net::TcpStream::connect(addr).await.unwrap();
    odas_side.write_all(objects[..4].concat().as_bytes()).await.unwrap();
    for k in 0..4u64 {
        assert_eq!(next(&mut rx).await.stamp, start.plus_ns(k as i64 * 8_000_000));
    }
    // ODAS goes away, and comes back restarted: its counter begins at 1 again,
    // so start_ns no longer holds and the connection is timed from its first object.
    drop(odas_side);
    tokio::time::sleep(Duration::from_millis(100)).await;
    let before = Stamp::now();
    let mut restarted = tokio::net::TcpStream::connect(addr).await.unwrap();
    restarted.write_all(objects[..2].concat().as_bytes()).await.unwrap();
    let (a, b) = (next(&mut rx).await, next(&mut rx).await);
    assert_eq!((a.time_stamp, b.time_stamp), (1, 2));
    assert!(a.stamp >= before && a.stamp <= Stamp::now(), "re-anchored on arrival");
    assert_eq!(b.stamp - a.stamp, 8_000_000);
    bridge.abort();
}

#[tokio::test]
async fn hops_ahead_of_the_agents_clock_are_held_until_due() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    // ODAS "started" 300 ms from now (as when it reads a file faster than real time).
    let start = Stamp::now().plus_ns(300_000_000);
    let bridge = tokio::spawn(odas::serve_tcp(listener, 128, 16_000, LiveStart::Fixed(start), tx));
    let mut odas_side = tokio::net::TcpStream::connect(addr).await.unwrap();
    odas_side.write_all(&std::fs::read(fixture()).unwrap()).await.unwrap();
    for k in 0..6u64 {
        let f = next(&mut rx).await;
        let received = Stamp::now();
        assert_eq!(f.stamp, start.plus_ns(k as i64 * 8_000_000));
        assert!(received >= f.stamp, "hop {} sent {} ns before it was due", f.time_stamp, f.stamp - received);
    }
    bridge.abort();
}

#[tokio::test]
async fn hops_far_ahead_are_skipped_not_held() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let start = Stamp::now().plus_ns(-1_000_000_000);
    let bridge = tokio::spawn(odas::serve_tcp(listener, 128, 16_000, LiveStart::Fixed(start), tx));
    // A broken counter: an object 2.5 hours ahead, then the fixture's objects.
    let broken = fixture_objects()[1].replace("\"timeStamp\": 2", "\"timeStamp\": 1000000");
    let mut odas_side = tokio::net::TcpStream::connect(addr).await.unwrap();
    odas_side.write_all(broken.as_bytes()).await.unwrap();
    odas_side.write_all(&std::fs::read(fixture()).unwrap()).await.unwrap();
    // Skipped, not held for hours: the next objects come at once.
    for k in 1..=6u64 {
        assert_eq!(next(&mut rx).await.time_stamp, k);
    }
    bridge.abort();
}
