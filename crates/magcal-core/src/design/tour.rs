//! A visiting order for the attitudes of a design that keeps the vehicle's total rotation short:
//! what a pilot flies.
//!
//! The distance between two attitudes is the angle of the rotation that takes one to the other,
//! `acos((trace(C_a C_b^T) - 1) / 2)` of their direction cosine matrices (\[P1\] eq. (2)), so yaw
//! is periodic and the three angles are weighed as the vehicle turns, not as numbers. The order is
//! an open path (the vehicle does not return to its first attitude): nearest neighbour from every
//! start (from the first attitude only above [`ALL_STARTS_UP_TO`] attitudes), then 2-opt moves
//! (reversing a stretch of the path) while one shortens it. A heuristic, as every practical tour
//! is: it is not claimed optimal, only measured (see the tests).
// Index loops mirror the algorithm.
#![allow(clippy::needless_range_loop)]

use crate::attitude::Attitude;
use crate::small::Mat3;

/// Above this many attitudes the nearest-neighbour path starts from the first attitude only.
pub const ALL_STARTS_UP_TO: usize = 200;
/// Above this many attitudes no order is computed (the distance matrix would not be small): the
/// given order is kept.
pub const MAX_ORDERED: usize = 5000;

/// The angle (radians, in [0, pi]) of the rotation between two attitudes.
pub fn rotation_angle(a: &Attitude, b: &Attitude) -> f64 {
    angle_between(&a.dcm(), &b.dcm())
}

fn angle_between(a: &Mat3, b: &Mat3) -> f64 {
    // trace(A B^T) = sum_ij A_ij B_ij.
    let t: f64 = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| a[i][j] * b[i][j])
        .sum();
    ((t - 1.0) / 2.0).clamp(-1.0, 1.0).acos()
}

/// A short visiting order of `attitudes`: indices into them, each once. Designs of more than
/// [`MAX_ORDERED`] attitudes keep their order.
pub fn flight_order(attitudes: &[Attitude]) -> Vec<usize> {
    let n = attitudes.len();
    if n <= 2 || n > MAX_ORDERED {
        return (0..n).collect();
    }
    let dcm: Vec<Mat3> = attitudes.iter().map(Attitude::dcm).collect();
    let dist: Vec<f64> = (0..n * n).map(|k| angle_between(&dcm[k / n], &dcm[k % n])).collect();
    let d = |i: usize, j: usize| dist[i * n + j];
    let starts = if n <= ALL_STARTS_UP_TO { n } else { 1 };
    let mut best: Option<(f64, Vec<usize>)> = None;
    for s in 0..starts {
        let mut path = nearest_neighbour(n, s, &d);
        two_opt(&mut path, &d);
        let length = path_length(&path, &d);
        // Strictly shorter replaces: ties keep the earlier start.
        if best.as_ref().is_none_or(|(l, _)| length < *l - 1e-12) {
            best = Some((length, path));
        }
    }
    best.map(|b| b.1).unwrap_or_default()
}

/// The total rotation along `order`, radians.
pub fn total_rotation(attitudes: &[Attitude], order: &[usize]) -> f64 {
    order
        .windows(2)
        .map(|w| rotation_angle(&attitudes[w[0]], &attitudes[w[1]]))
        .sum()
}

fn path_length(path: &[usize], d: &impl Fn(usize, usize) -> f64) -> f64 {
    path.windows(2).map(|w| d(w[0], w[1])).sum()
}

fn nearest_neighbour(n: usize, start: usize, d: &impl Fn(usize, usize) -> f64) -> Vec<usize> {
    let mut visited = vec![false; n];
    let mut path = Vec::with_capacity(n);
    let mut at = start;
    visited[at] = true;
    path.push(at);
    for _ in 1..n {
        let next = (0..n)
            .filter(|&j| !visited[j])
            .min_by(|&a, &b| d(at, a).total_cmp(&d(at, b)).then(a.cmp(&b)))
            .expect("an unvisited attitude remains");
        visited[next] = true;
        path.push(next);
        at = next;
    }
    path
}

/// 2-opt on an open path: reverse `path[i..=j]` while that shortens it (at most `n^2` passes of
/// improvement, each pass `O(n^2)`).
fn two_opt(path: &mut [usize], d: &impl Fn(usize, usize) -> f64) {
    let n = path.len();
    for _ in 0..n * n {
        let mut improved = false;
        for i in 0..n - 1 {
            for j in i + 1..n {
                // Edges (i-1, i) and (j, j+1) become (i-1, j) and (i, j+1); an end has no edge.
                let before = if i > 0 { d(path[i - 1], path[i]) } else { 0.0 }
                    + if j + 1 < n { d(path[j], path[j + 1]) } else { 0.0 };
                let after = if i > 0 { d(path[i - 1], path[j]) } else { 0.0 }
                    + if j + 1 < n { d(path[i], path[j + 1]) } else { 0.0 };
                if after < before - 1e-12 {
                    path[i..=j].reverse();
                    improved = true;
                }
            }
        }
        if !improved {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::sources;
    use crate::paper;
    use crate::rng::stream_rng;

    #[test]
    fn rotation_angle_is_the_angle_of_one_axis_turn() {
        let a = Attitude::from_degrees(0.0, 10.0, 0.0);
        let b = Attitude::from_degrees(0.0, -20.0, 0.0);
        assert!((rotation_angle(&a, &b).to_degrees() - 30.0).abs() < 1e-12);
        // Yaw is periodic: 179 and -179 are 2 degrees apart.
        let (c, e) = (
            Attitude::from_degrees(0.0, 179.0, 0.0),
            Attitude::from_degrees(0.0, -179.0, 0.0),
        );
        assert!((rotation_angle(&c, &e).to_degrees() - 2.0).abs() < 1e-9);
        assert!(rotation_angle(&a, &a) < 1e-7);
    }

    #[test]
    fn the_order_is_a_permutation_and_shorter_than_the_given_one() {
        let mut rng = stream_rng(31, 0);
        for (design, shorter_by) in [
            (paper::uniformity_design(), 0.99),
            (sources::random(&paper::auv_box(), 40, &mut rng), 0.5),
            (sources::random(&crate::AttitudeBox::full(), 300, &mut rng), 0.5),
        ] {
            let order = flight_order(&design);
            let mut sorted = order.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..design.len()).collect::<Vec<_>>());
            let given: Vec<usize> = (0..design.len()).collect();
            let (a, b) = (total_rotation(&design, &order), total_rotation(&design, &given));
            assert!(a <= shorter_by * b, "{} attitudes: {a} vs {b}", design.len());
        }
    }

    #[test]
    fn points_on_a_circle_are_visited_around_it() {
        // Twelve yaws given shuffled: the shortest open path goes around, 11 x 30 degrees.
        let yaws = [
            0.0, 180.0, 90.0, -30.0, 60.0, 150.0, -120.0, 30.0, -60.0, 120.0, -150.0, -90.0,
        ];
        let design: Vec<Attitude> = yaws.iter().map(|&y| Attitude::from_degrees(0.0, y, 0.0)).collect();
        let order = flight_order(&design);
        assert!((total_rotation(&design, &order).to_degrees() - 330.0).abs() < 1e-6);
    }
}
