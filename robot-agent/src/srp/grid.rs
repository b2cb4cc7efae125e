//! Icosphere grids of directions (ODAS's sphere levels).
//!
//! Level `n` is the regular icosahedron with each triangle split into `4ⁿ`,
//! its vertices pushed onto the unit sphere: `10·4ⁿ + 2` points (12, 42, 162,
//! 642, 2562, …), mean spacing ≈ 63.4°/2ⁿ (level 2: 16°, level 4: 4.2°).
//! The vertices of level `n` are the first points of level `n + 1`.

use std::collections::HashMap;

use nalgebra::Vector3;

/// Points on the unit sphere with their mesh neighbours.
#[derive(Clone, Debug)]
pub struct SphereGrid {
    points: Vec<Vector3<f64>>,
    /// `neighbours[offsets[i]..offsets[i+1]]` are the neighbours of point `i`.
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
}

impl SphereGrid {
    /// The icosphere of subdivision `level` (0..=7).
    ///
    /// # Panics
    /// If `level > 7` (655 362 points; more is never useful here).
    pub fn icosphere(level: u32) -> Self {
        assert!(level <= 7, "icosphere level {level} is too fine");
        let phi = (1.0 + 5f64.sqrt()) / 2.0;
        let mut points: Vec<Vector3<f64>> = [
            (-1.0, phi, 0.0),
            (1.0, phi, 0.0),
            (-1.0, -phi, 0.0),
            (1.0, -phi, 0.0),
            (0.0, -1.0, phi),
            (0.0, 1.0, phi),
            (0.0, -1.0, -phi),
            (0.0, 1.0, -phi),
            (phi, 0.0, -1.0),
            (phi, 0.0, 1.0),
            (-phi, 0.0, -1.0),
            (-phi, 0.0, 1.0),
        ]
        .iter()
        .map(|&(x, y, z)| Vector3::new(x, y, z).normalize())
        .collect();
        let mut faces: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..level {
            let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
            let mut midpoint = |a: u32, b: u32, points: &mut Vec<Vector3<f64>>| -> u32 {
                let key = (a.min(b), a.max(b));
                *mid.entry(key).or_insert_with(|| {
                    points.push((points[a as usize] + points[b as usize]).normalize());
                    (points.len() - 1) as u32
                })
            };
            let mut next = Vec::with_capacity(faces.len() * 4);
            for [a, b, c] in faces {
                let ab = midpoint(a, b, &mut points);
                let bc = midpoint(b, c, &mut points);
                let ca = midpoint(c, a, &mut points);
                next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            faces = next;
        }
        let mut adj: Vec<Vec<u32>> = vec![Vec::new(); points.len()];
        for [a, b, c] in faces {
            for (u, v) in [(a, b), (b, c), (c, a)] {
                if !adj[u as usize].contains(&v) {
                    adj[u as usize].push(v);
                }
                if !adj[v as usize].contains(&u) {
                    adj[v as usize].push(u);
                }
            }
        }
        let mut offsets = Vec::with_capacity(points.len() + 1);
        let mut neighbours = Vec::new();
        offsets.push(0);
        for a in &adj {
            neighbours.extend_from_slice(a);
            offsets.push(neighbours.len() as u32);
        }
        SphereGrid { points, offsets, neighbours }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the grid has no point (never, for an icosphere).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The points (unit vectors).
    pub fn points(&self) -> &[Vector3<f64>] {
        &self.points
    }

    /// Mesh neighbours of point `i` (5 at the 12 original vertices, else 6).
    pub fn neighbours(&self, i: usize) -> &[u32] {
        &self.neighbours[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Mean angle between neighbouring points, radians.
    pub fn mean_spacing_rad(&self) -> f64 {
        let mut sum = 0.0;
        for i in 0..self.len() {
            for &j in self.neighbours(i) {
                sum += self.points[i].angle(&self.points[j as usize]);
            }
        }
        sum / self.neighbours.len() as f64
    }

    /// Index of the point closest to `d` (unit vector), by exhaustive search.
    pub fn nearest(&self, d: &Vector3<f64>) -> usize {
        let mut best = (0, f64::NEG_INFINITY);
        for (i, p) in self.points.iter().enumerate() {
            let c = p.dot(d);
            if c > best.1 {
                best = (i, c);
            }
        }
        best.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_counts_follow_10_4n_plus_2() {
        for (level, n) in [(0, 12), (1, 42), (2, 162), (3, 642), (4, 2562)] {
            let g = SphereGrid::icosphere(level);
            assert_eq!(g.len(), n, "level {level}");
            assert!(g.points().iter().all(|p| (p.norm() - 1.0).abs() < 1e-12));
        }
    }

    #[test]
    fn neighbours_are_five_or_six_close_points() {
        let g = SphereGrid::icosphere(4);
        let spacing = g.mean_spacing_rad();
        assert!((spacing.to_degrees() - 4.2).abs() < 0.3, "{}", spacing.to_degrees());
        let mut fives = 0;
        for i in 0..g.len() {
            let n = g.neighbours(i);
            assert!(n.len() == 5 || n.len() == 6);
            fives += usize::from(n.len() == 5);
            for &j in n {
                assert!(g.neighbours(j as usize).contains(&(i as u32)), "symmetric");
                let a = g.points()[i].angle(&g.points()[j as usize]);
                assert!(a < 1.5 * spacing && a > 0.6 * spacing);
            }
        }
        assert_eq!(fives, 12);
    }

    #[test]
    fn levels_are_nested() {
        let coarse = SphereGrid::icosphere(2);
        let fine = SphereGrid::icosphere(4);
        for (a, b) in coarse.points().iter().zip(fine.points()) {
            assert!((a - b).norm() < 1e-12);
        }
        assert_eq!(fine.nearest(&coarse.points()[17]), 17);
    }
}
