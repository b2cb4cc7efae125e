//! The tf tree of a bag (`/tf` and `/tf_static`) and a robot's base pose in
//! the map from it.
//!
//! Every transform names its parent and child frame; each frame has one
//! parent. The chain from `map_frame` down to `base_frame` is found by walking
//! up from the base (e.g. `r1/base_link → r1/odom → map`), and
//! `map_from_base(t) = map_from_f1(t) · f1_from_f2(t) · … · fn_from_base(t)`.
//! A static link holds one transform; a dynamic link is interpolated at `t`
//! between its two neighbouring samples (translation linearly, rotation by
//! slerp), never extrapolated, as tf2 does.
//!
//! The replay reads the composed pose at every stamp where a dynamic link of
//! the chain has a sample (within the span all dynamic links cover); the agent
//! core then interpolates those poses at each DoA stamp, as it does a SLAM
//! trajectory. For a chain with one dynamic link (odometry or SLAM at 10–100
//! Hz under static links) this is exactly tf2's answer; with several, the
//! difference is second order in the motion between samples.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::cdr::Transform;

/// One link's samples: (stamp ns, parent_from_child), stamps strictly increasing.
#[derive(Clone, Debug, Default)]
struct Link {
    parent: String,
    samples: Vec<(i64, Isometry3<f64>)>,
    is_static: bool,
}

/// All transforms of a bag, by child frame.
#[derive(Clone, Debug, Default)]
pub struct TfTree {
    links: BTreeMap<String, Link>,
}

fn isometry(t: &Transform) -> Isometry3<f64> {
    let [x, y, z, w] = t.rotation;
    Isometry3::from_parts(
        Translation3::new(t.translation[0], t.translation[1], t.translation[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

impl TfTree {
    /// Adds a transform from `/tf` (`is_static` false) or `/tf_static`.
    /// A frame given a second parent keeps its first one and the message is
    /// reported as an error naming both.
    pub fn add(&mut self, t: &Transform, is_static: bool) -> Result<(), String> {
        let link = self.links.entry(t.child.clone()).or_insert_with(|| Link {
            parent: t.parent.clone(),
            samples: Vec::new(),
            is_static,
        });
        if link.parent != t.parent {
            return Err(format!(
                "frame {} has two parents, {} and {}: tf is a tree",
                t.child, link.parent, t.parent
            ));
        }
        let pose = isometry(t);
        if is_static || link.is_static {
            link.is_static = true;
            link.samples = vec![(t.stamp_ns, pose)];
            return Ok(());
        }
        match link.samples.last() {
            Some((last, _)) if t.stamp_ns < *last => {
                let at = link.samples.partition_point(|(s, _)| *s < t.stamp_ns);
                if link.samples.get(at).is_none_or(|(s, _)| *s != t.stamp_ns) {
                    link.samples.insert(at, (t.stamp_ns, pose));
                }
            }
            Some((last, _)) if t.stamp_ns == *last => {}
            _ => link.samples.push((t.stamp_ns, pose)),
        }
        Ok(())
    }

    /// The child frames from `base` up to `map` (base first), or why there is no chain.
    pub fn chain(&self, map: &str, base: &str) -> Result<Vec<String>, String> {
        let mut chain = Vec::new();
        let mut frame = base.to_string();
        while frame != map {
            let Some(link) = self.links.get(&frame) else {
                let walked =
                    chain.iter().chain(std::iter::once(&frame)).cloned().collect::<Vec<_>>().join(" → ");
                let frames: BTreeSet<&str> =
                    self.links.iter().flat_map(|(c, l)| [c.as_str(), l.parent.as_str()]).collect();
                return Err(format!(
                    "broken tf chain from {map} to {base}: {walked} stops at {frame}, which has no parent on /tf or /tf_static (frames in the bag: {})",
                    frames.into_iter().collect::<Vec<_>>().join(", ")
                ));
            };
            if chain.len() > 64 || chain.contains(&frame) {
                return Err(format!("tf loop above {base}"));
            }
            chain.push(frame.clone());
            frame = link.parent.clone();
        }
        Ok(chain)
    }

    /// `map_from_base` at `t_ns` along `chain` ([`Self::chain`]); `None` outside a dynamic link's samples.
    pub fn pose_at(&self, chain: &[String], t_ns: i64) -> Option<Isometry3<f64>> {
        let mut base_up = Isometry3::identity();
        for child in chain {
            let link = &self.links[child];
            base_up = interpolate(&link.samples, t_ns, link.is_static)? * base_up;
        }
        Some(base_up)
    }

    /// The stamps at which the chain's pose is read: every sample of its
    /// dynamic links within the span all of them cover; `None` when the chain
    /// is static.
    pub fn stamps(&self, chain: &[String]) -> Option<Vec<i64>> {
        let dynamic: Vec<&Link> = chain.iter().map(|c| &self.links[c]).filter(|l| !l.is_static).collect();
        if dynamic.is_empty() {
            return None;
        }
        let from = dynamic.iter().map(|l| l.samples[0].0).max().expect("non-empty");
        let to = dynamic.iter().map(|l| l.samples[l.samples.len() - 1].0).min().expect("non-empty");
        let stamps: BTreeSet<i64> = dynamic
            .iter()
            .flat_map(|l| l.samples.iter().map(|(s, _)| *s))
            .filter(|s| (from..=to).contains(s))
            .collect();
        Some(stamps.into_iter().collect())
    }
}

fn interpolate(samples: &[(i64, Isometry3<f64>)], t: i64, is_static: bool) -> Option<Isometry3<f64>> {
    if is_static {
        return samples.first().map(|(_, p)| *p);
    }
    let after = samples.partition_point(|(s, _)| *s < t);
    match (after.checked_sub(1).map(|i| samples[i]), samples.get(after)) {
        (_, Some((s, p))) if *s == t => Some(*p),
        (Some((s0, p0)), Some((s1, p1))) => {
            let f = (t - s0) as f64 / (s1 - s0) as f64;
            let translation = p0.translation.vector.lerp(&p1.translation.vector, f);
            let rotation = p0.rotation.try_slerp(&p1.rotation, f, 1e-12).unwrap_or(p0.rotation);
            Some(Isometry3::from_parts(translation.into(), rotation))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tf(stamp_ns: i64, parent: &str, child: &str, x: f64, yaw: f64) -> Transform {
        Transform {
            stamp_ns,
            parent: parent.into(),
            child: child.into(),
            translation: [x, 0.0, 0.0],
            rotation: [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
        }
    }

    #[test]
    fn chain_composes_static_and_interpolated_dynamic_links() {
        let mut tree = TfTree::default();
        tree.add(&tf(0, "map", "r1/odom", 1.0, std::f64::consts::FRAC_PI_2), true).unwrap();
        tree.add(&tf(0, "r1/odom", "r1/base_link", 0.0, 0.0), false).unwrap();
        tree.add(&tf(1_000_000_000, "r1/odom", "r1/base_link", 2.0, 0.0), false).unwrap();
        let chain = tree.chain("map", "r1/base_link").unwrap();
        assert_eq!(chain, ["r1/base_link", "r1/odom"]);
        // Half way: base at x = 1 in odom, odom turned 90° and 1 m along x in the map.
        let p = tree.pose_at(&chain, 500_000_000).unwrap();
        assert!((p.translation.vector - nalgebra::Vector3::new(1.0, 1.0, 0.0)).norm() < 1e-12, "{p}");
        assert!(tree.pose_at(&chain, 1_500_000_000).is_none(), "no extrapolation");
        assert_eq!(tree.stamps(&chain).unwrap(), [0, 1_000_000_000]);
        let e = tree.chain("map", "r2/base_link").unwrap_err();
        assert!(e.contains("broken tf chain") && e.contains("r2/base_link"), "{e}");
        let e = tree.chain("world", "r1/base_link").unwrap_err();
        assert!(e.contains("stops at map"), "{e}");
        assert!(tree.add(&tf(0, "other", "r1/odom", 0.0, 0.0), true).unwrap_err().contains("two parents"));
    }
}
