//! Motion smoothness: neighbouring Gaussians should move alike.
//!
//! Each Gaussian's trajectory is its own (a Fourier series per Gaussian), so nothing ties the
//! motion of a Gaussian to that of its neighbours. Where each instant is seen from one camera
//! (monocular captures such as D-NeRF), a trajectory is then constrained by a handful of views
//! and neighbours drift apart in the views in between. A deformation field shared by all
//! Gaussians (the MLP or HexPlane of other methods) is smooth in space by construction; this
//! regulariser asks the same of per-Gaussian trajectories: over the edges (i, j) of a
//! k-nearest-neighbour graph,
//!
//! L_s = λ / |E| · Σ_(i,j)∈E ‖v_i(t) − v_j(t)‖²,
//!
//! with v the velocity of the motion at the sampled time ([`super::deform::fourier_velocity`]).
//! Velocities, not offsets: an offset is relative to each Gaussian's own canonical position,
//! while equal velocities mean the two keep their relative position (locally rigid
//! translation). Dynamic 3D Gaussians' rigidity and Gaussian-Flow's KNN regulariser are of this
//! family.
//!
//! That form also penalises a limb rotating about its joint (the velocity grows with the
//! distance from the axis). [`Penalty::Stretch`] keeps only the component of v_i − v_j along
//! the edge, the rate at which the two's distance changes, which every rigid motion leaves at
//! 0: the infinitesimal form of Dynamic 3D Gaussians' isometry loss.

use glam::Vec3;
use rayon::prelude::*;
use rstar::RTree;
use rstar::primitives::GeomWithData;

/// An undirected graph over points: the union of each point's k nearest neighbours, stored as
/// adjacency lists (compressed rows), each edge in both of its endpoints' lists.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NeighbourGraph {
    /// `start[i]..start[i + 1]` is the range of point i's neighbours in `neighbours`.
    start: Vec<u32>,
    neighbours: Vec<u32>,
}

impl NeighbourGraph {
    /// The k-nearest-neighbour graph of `points`, made undirected: i and j are joined when
    /// either is among the other's k nearest. Points with a non-finite coordinate get no
    /// neighbours and are nobody's neighbour.
    pub fn k_nearest(points: &[Vec3], k: usize) -> Self {
        let finite = |p: &Vec3| p.is_finite();
        let tree = RTree::bulk_load(
            points
                .iter()
                .enumerate()
                .filter(|(_, p)| finite(p))
                .map(|(i, p)| GeomWithData::new(p.to_array(), i as u32))
                .collect(),
        );
        // Directed edges i → j of each point's k nearest (itself excluded), both ways round.
        let mut edges: Vec<(u32, u32)> = points
            .par_iter()
            .enumerate()
            .filter(|(_, p)| finite(p))
            .flat_map_iter(|(i, p)| {
                let i = i as u32;
                tree.nearest_neighbor_iter(&p.to_array())
                    .filter(move |n| n.data != i)
                    .take(k)
                    .flat_map(move |n| [(i, n.data), (n.data, i)])
            })
            .collect();
        edges.par_sort_unstable();
        edges.dedup();
        let mut start = vec![0u32; points.len() + 1];
        for &(i, _) in &edges {
            start[i as usize + 1] += 1;
        }
        for i in 0..points.len() {
            start[i + 1] += start[i];
        }
        Self {
            start,
            neighbours: edges.into_iter().map(|(_, j)| j).collect(),
        }
    }

    /// Number of points the graph was built over.
    pub fn len(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// Whether the graph has no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of undirected edges.
    pub fn edge_count(&self) -> usize {
        self.neighbours.len() / 2
    }

    /// The neighbours of point i.
    pub fn neighbours(&self, i: usize) -> &[u32] {
        &self.neighbours[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

/// Which part of a neighbour's relative velocity d = v_i − v_j is penalised.
#[derive(Clone, Copy, Debug)]
pub enum Penalty<'a> {
    /// All of it: ‖d‖².
    Velocity,
    /// Its component along the edge, (e·d)² with e = (x_i − x_j)/‖x_i − x_j‖ over these
    /// positions (in the graph's order): the rate at which the two's distance changes. A rigid
    /// motion (v = ω × x + c) costs nothing. The positions are held constant in the gradient.
    Stretch(&'a [Vec3]),
}

impl Penalty<'_> {
    /// The penalised part of d = v_i − v_j: d itself, or its projection P·d on the edge. Both
    /// are P·d for a symmetric, idempotent P, so ‖P·d‖² has gradient 2·P·d in d.
    fn part(&self, i: usize, j: usize, d: Vec3) -> Vec3 {
        match self {
            Penalty::Velocity => d,
            Penalty::Stretch(positions) => {
                let e = (positions[i] - positions[j]).normalize_or_zero();
                e * e.dot(d)
            }
        }
    }
}

/// L_s = weight / |E| · Σ over the graph's edges of ‖P·(v_i − v_j)‖² (0 without edges).
pub fn smoothness_loss(
    velocities: &[Vec3],
    graph: &NeighbourGraph,
    weight: f32,
    penalty: Penalty,
) -> f32 {
    if graph.edge_count() == 0 {
        return 0.0;
    }
    let sum: f32 = (0..graph.len())
        .into_par_iter()
        .map(|i| {
            graph
                .neighbours(i)
                .iter()
                .map(|&j| {
                    let j = j as usize;
                    penalty
                        .part(i, j, velocities[i] - velocities[j])
                        .length_squared()
                })
                .sum::<f32>()
        })
        .sum();
    // Each edge is in both endpoints' lists.
    weight * 0.5 * sum / graph.edge_count() as f32
}

/// dL_s/dv_i = 2·weight/|E| · Σ_(j adjacent to i) P·(v_i − v_j), into `d_velocities` (resized
/// to the graph's points; zero without edges).
pub fn smoothness_backward(
    velocities: &[Vec3],
    graph: &NeighbourGraph,
    weight: f32,
    penalty: Penalty,
    d_velocities: &mut Vec<Vec3>,
) {
    let scale = if graph.edge_count() == 0 {
        0.0
    } else {
        2.0 * weight / graph.edge_count() as f32
    };
    (0..graph.len())
        .into_par_iter()
        .map(|i| {
            let v = velocities[i];
            let sum: Vec3 = graph
                .neighbours(i)
                .iter()
                .map(|&j| {
                    let j = j as usize;
                    penalty.part(i, j, v - velocities[j])
                })
                .sum();
            scale * sum
        })
        .collect_into_vec(d_velocities);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::fd::{assert_grad, central};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_points(n: usize, seed: u64) -> Vec<Vec3> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.1..0.1),
                )
            })
            .collect()
    }

    /// The k nearest of point i by brute force (ties broken by index, as no test relies on it).
    fn brute_force(points: &[Vec3], i: usize, k: usize) -> Vec<u32> {
        let mut others: Vec<(f32, u32)> = (0..points.len())
            .filter(|&j| j != i)
            .map(|j| (points[i].distance_squared(points[j]), j as u32))
            .collect();
        others.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        others.into_iter().take(k).map(|(_, j)| j).collect()
    }

    #[test]
    fn graph_is_the_symmetrised_brute_force_k_nearest() {
        let points = random_points(400, 3);
        let k = 6;
        let graph = NeighbourGraph::k_nearest(&points, k);
        assert_eq!(graph.len(), points.len());
        let mut expected = vec![Vec::new(); points.len()];
        for i in 0..points.len() {
            for j in brute_force(&points, i, k) {
                expected[i].push(j);
                expected[j as usize].push(i as u32);
            }
        }
        for (i, list) in expected.iter_mut().enumerate() {
            list.sort_unstable();
            list.dedup();
            assert_eq!(graph.neighbours(i), list.as_slice(), "point {i}");
        }
        let directed: usize = expected.iter().map(Vec::len).sum();
        assert_eq!(graph.edge_count() * 2, directed);
    }

    #[test]
    fn non_finite_points_are_left_out_and_tiny_inputs_work() {
        let mut points = random_points(20, 5);
        points[4] = Vec3::new(f32::NAN, 0.0, 0.0);
        let graph = NeighbourGraph::k_nearest(&points, 3);
        assert!(graph.neighbours(4).is_empty());
        assert!((0..20).all(|i| !graph.neighbours(i).contains(&4)));
        // Fewer points than k: everybody is joined to everybody else.
        let three = NeighbourGraph::k_nearest(&points[..3], 8);
        assert_eq!(three.edge_count(), 3);
        let none = NeighbourGraph::k_nearest(&[], 8);
        assert!(none.is_empty());
        assert_eq!(smoothness_loss(&[], &none, 1.0, Penalty::Velocity), 0.0);
    }

    #[test]
    fn equal_velocities_cost_nothing_and_the_gradient_matches_fd() {
        let points = random_points(60, 11);
        let graph = NeighbourGraph::k_nearest(&points, 4);
        let same = vec![Vec3::new(0.3, -1.0, 2.0); points.len()];
        assert_eq!(smoothness_loss(&same, &graph, 2.0, Penalty::Velocity), 0.0);
        let mut grad = Vec::new();
        smoothness_backward(&same, &graph, 2.0, Penalty::Velocity, &mut grad);
        assert!(grad.iter().all(|g| *g == Vec3::ZERO));

        let velocities = random_points(60, 12);
        assert_gradient_matches_fd(&velocities, &graph, 0.7, Penalty::Velocity, [0, 17, 59]);
    }

    /// smoothness_backward against central differences of smoothness_loss at Gaussians `at`.
    fn assert_gradient_matches_fd(
        velocities: &[Vec3],
        graph: &NeighbourGraph,
        weight: f32,
        penalty: Penalty,
        at: [usize; 3],
    ) {
        let mut grad = Vec::new();
        smoothness_backward(velocities, graph, weight, penalty, &mut grad);
        for i in at {
            for k in 0..3 {
                let fd = central(
                    |x| {
                        let mut v = velocities.to_vec();
                        v[i][k] = x;
                        smoothness_loss(&v, graph, weight, penalty)
                    },
                    velocities[i][k],
                    1e-2,
                );
                assert_grad("velocity", grad[i][k], fd);
            }
        }
    }

    #[test]
    fn stretch_ignores_rigid_motion_and_its_gradient_matches_fd() {
        let points = random_points(80, 21);
        let graph = NeighbourGraph::k_nearest(&points, 5);
        let stretch = Penalty::Stretch(&points);
        // v = ω × x + c: a rigid motion, which moves neighbours apart nowhere.
        let (omega, c) = (Vec3::new(0.4, -1.3, 0.7), Vec3::new(2.0, 0.5, -1.0));
        let rigid: Vec<Vec3> = points.iter().map(|&x| omega.cross(x) + c).collect();
        assert!(smoothness_loss(&rigid, &graph, 1.0, stretch) < 1e-9);
        assert!(smoothness_loss(&rigid, &graph, 1.0, Penalty::Velocity) > 1e-2);
        // v = x: a uniform expansion stretches every edge by its own length, (e·d)² = ‖d‖².
        let expand: Vec<Vec3> = points.clone();
        let (s, v) = (
            smoothness_loss(&expand, &graph, 1.0, stretch),
            smoothness_loss(&expand, &graph, 1.0, Penalty::Velocity),
        );
        assert!((s - v).abs() <= 1e-5 * v, "{s} vs {v}");

        let velocities = random_points(80, 22);
        assert_gradient_matches_fd(&velocities, &graph, 0.9, stretch, [0, 33, 79]);
    }
}
