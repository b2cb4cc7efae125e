//! Several sources over real loopback sockets: robots stream two tracks each;
//! `WatchEstimates` streams every source, `GetState` lists the sound map, and
//! `SetFocus` picks the source active positioning serves.

use crate::common;

use common::*;
use nalgebra::Point3;
use soundmap_proto::wire;
use soundmap_server::CoordinatorConfig;
use tonic::Code;

#[tokio::test]
async fn every_source_is_streamed_mapped_and_can_be_focused() {
    let mut config = CoordinatorConfig::default();
    config.sources.max_sources = 4;
    let (running, clock) = start(config).await;
    let addr = running.local_addr;
    let mut estimates = running.subscribe();
    let mut a = connect(addr, "a").await;
    let mut b = connect(addr, "b").await;
    let (base_a, base_b) = (Point3::new(3.0, -1.0, 0.0), Point3::new(-1.0, 3.0, 0.0));
    let sources = [Point3::new(0.8, 0.6, 1.1), Point3::new(-0.6, -0.4, 1.8)];
    let sigma = 1f64.to_radians();
    let two_tracks = |stamp, base| {
        let mut o = observation_of(stamp, base, 0.0, &sources[0], None, sigma);
        let second = observation_of(stamp, base, 0.0, &sources[1], None, sigma);
        let mut d = second.doas[0].clone();
        d.track_id = 2;
        o.doas.push(d);
        o
    };
    for k in 0..60 {
        let stamp = T0.plus_ns(k * 50_000_000);
        clock.set(stamp.plus_ns(10_000_000));
        let s = a.observe(two_tracks(stamp, base_a)).await;
        a.until_acked(s).await;
        let s = b.observe(two_tracks(stamp.plus_ns(2_000_000), base_b)).await;
        b.until_acked(s).await;
    }
    // Both sources are streamed, each near its truth, with its own id.
    let mut ids = std::collections::BTreeMap::new();
    while let Ok(e) = estimates.try_recv() {
        let p = position(&e);
        let (i, d) = sources
            .iter()
            .enumerate()
            .map(|(i, s)| (i, (s - p).norm()))
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .unwrap();
        assert!(d < 0.3, "estimate {p} is {d:.2} m from every source");
        ids.entry(i).or_insert_with(Vec::new).push(e.source_id);
    }
    assert_eq!(ids.len(), 2, "{ids:?}");
    for v in ids.values_mut() {
        v.dedup();
        assert_eq!(v.len(), 1, "one id per source: {v:?}");
    }
    let mut m = monitoring(addr).await;
    let state = m.get_state(wire::GetStateRequest {}).await.unwrap().into_inner();
    assert_eq!(state.sources.len(), 2, "GetState lists the latest estimate of each source");
    let live: Vec<&wire::MappedSource> = state.sound_map.iter().filter(|s| s.live).collect();
    assert_eq!(live.len(), 2, "{:?}", state.sound_map);
    assert!(live.iter().all(|s| s.covariance_m2.len() == 9 && s.first_heard_ns <= s.last_heard_ns));
    assert_eq!(state.focus_source_id, 0, "all sources by default");
    // Focus: an id never given is refused with a message; a known one is taken.
    let refused = m.set_focus(wire::SetFocusRequest { source_id: 99 }).await.unwrap_err();
    assert_eq!(refused.code(), Code::InvalidArgument);
    assert!(refused.message().contains("source_id"), "{}", refused.message());
    let id = ids[&1][0];
    let focus = m.set_focus(wire::SetFocusRequest { source_id: id }).await.unwrap().into_inner();
    assert_eq!(focus.source_id, id);
    let state = m.get_state(wire::GetStateRequest {}).await.unwrap().into_inner();
    assert_eq!(state.focus_source_id, id);
    running.shutdown().await.unwrap();
}
