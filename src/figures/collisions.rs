//! Collisions with pieces that may have tipped, judged from the executed
//! motion alone (not from the plan's lifts): a small piece (`RunSetup::
//! small_pieces`) has fallen once the laser has passed within the tolerance
//! of every point of its outline. From the first moment after that when
//! the head moves with the laser off and is not over it (a lead-out may end
//! over a slug as it drops), the head passing over it with the laser off
//! below the lift height is a collision. Each entry over a piece counts once.

use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};

use crate::job::{bounds_of, points_around, segment_distance, Point};
use crate::topology::{side, Side};
use laserd_sim::controller::Knot;

/// Outlines are followed, and moves looked at, in steps of at most this (mm).
const STEP_MM: f64 = 0.1;

/// Collisions of the head below `lift_height` (Z at axis `z`, none: always
/// at 0) with `pieces` once fallen. `cover`: how near the laser must pass
/// every point of an outline to cut it (the program's tolerance, the
/// corners' and the drawing's flattening); `tol`: how far an executed cut
/// may lie from the plan (the head on a piece's edge is not over it);
/// `graze`: how far an executed air move may (the program's jump
/// tolerance), so how far inside a piece the head must be to count.
pub fn count(knots: &[Knot], pieces: &[Vec<Point>], z: Option<usize>, lift_height: f64, cover: f64, tol: f64, graze: f64) -> u64 {
    if pieces.is_empty() || knots.len() < 2 {
        return 0;
    }
    let mut samples = Vec::new();
    let mut remaining = vec![0usize; pieces.len()];
    for (i, outline) in pieces.iter().enumerate() {
        for p in points_around(outline, STEP_MM) {
            samples.push(GeomWithData::new([p.x, p.y], (i, samples.len())));
            remaining[i] += 1;
        }
    }
    let outline_points = RTree::bulk_load(samples);
    let mut cut = vec![false; outline_points.size()];
    let boxes = RTree::bulk_load(
        pieces
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let (lo, hi) = bounds_of(o.iter());
                GeomWithData::new(Rectangle::from_corners([lo.x, lo.y], [hi.x, hi.y]), i)
            })
            .collect::<Vec<_>>(),
    );
    let xy = |k: &Knot| Point::new(k.pos[0], k.pos.get(1).copied().unwrap_or(0.0));
    let height = |k: &Knot| z.and_then(|i| k.pos.get(i)).copied().unwrap_or(0.0);
    // Fallen and not yet left; left (armed); over now.
    let mut fallen_under_head: Vec<usize> = Vec::new();
    let mut armed = vec![false; pieces.len()];
    let mut over = vec![false; pieces.len()];
    let mut collisions = 0;
    for w in knots.windows(2) {
        let (a, b) = (xy(&w[0]), xy(&w[1]));
        let lasered = w[1].power > 0.0 && a != b;
        if lasered {
            let query = AABB::from_corners([a.x.min(b.x) - cover, a.y.min(b.y) - cover], [a.x.max(b.x) + cover, a.y.max(b.y) + cover]);
            let hit: Vec<(usize, usize)> = outline_points
                .locate_in_envelope_intersecting(query)
                .filter(|s| {
                    let p = Point::new(s.geom()[0], s.geom()[1]);
                    !cut[s.data.1] && segment_distance(p, p, a, b) <= cover
                })
                .map(|s| s.data)
                .collect();
            for (piece, sample) in hit {
                cut[sample] = true;
                remaining[piece] -= 1;
                if remaining[piece] == 0 {
                    fallen_under_head.push(piece);
                }
            }
        }
        let steps = ((b - a).norm() / STEP_MM).ceil().max(1.0) as usize;
        let (za, zb) = (height(&w[0]), height(&w[1]));
        for s in 0..=steps {
            let f = s as f64 / steps as f64;
            let p = a + (b - a) * f;
            // Off the piece (on its edge or beyond) with the laser off: from
            // here on the head must not pass over it low.
            if !lasered {
                fallen_under_head.retain(|&i| {
                    let left = side(p, &pieces[i], tol) != Side::Inside;
                    armed[i] |= left;
                    !left
                });
            }
            if s == 0 {
                continue;
            }
            let low = za + (zb - za) * f < lift_height - 1e-3;
            let here = AABB::from_point([p.x, p.y]);
            for c in boxes.locate_in_envelope_intersecting(here) {
                let i = c.data;
                let now = armed[i] && !lasered && low && side(p, &pieces[i], graze) == Side::Inside;
                if now && !over[i] {
                    collisions += 1;
                }
                over[i] = now;
            }
        }
    }
    collisions
}

#[cfg(test)]
mod tests {
    use super::*;

    fn knot(t: f64, x: f64, y: f64, z: f64, power: f64) -> Knot {
        Knot { t, pos: vec![x, y, z], power, line: 0 }
    }

    /// A square cut whole, then crossed low: one collision; crossed high, or
    /// before it was cut whole, or left from inside: none.
    #[test]
    fn crossing_a_fallen_piece_low_is_a_collision_and_only_that() {
        let square = vec![Point::new(0.0, 0.0), Point::new(10.0, 0.0), Point::new(10.0, 10.0), Point::new(0.0, 10.0)];
        let cut = |z: f64| {
            vec![
                knot(0.0, 0.0, 0.0, z, 0.0),
                knot(1.0, 10.0, 0.0, 0.0, 500.0),
                knot(2.0, 10.0, 10.0, 0.0, 500.0),
                knot(3.0, 0.0, 10.0, 0.0, 500.0),
                knot(4.0, 0.0, 0.0, 0.0, 500.0),
            ]
        };
        let pieces = vec![square];
        let across = |z: f64| vec![knot(5.0, -5.0, 5.0, z, 0.0), knot(6.0, 15.0, 5.0, z, 0.0)];
        let run = |tail: Vec<Knot>| {
            let mut k = cut(0.0);
            k.extend(tail);
            count(&k, &pieces, Some(2), 5.0, 0.01, 0.01, 0.5)
        };
        assert_eq!(run(across(0.0)), 1, "crossed low after it fell");
        assert_eq!(run(across(5.0)), 0, "crossed at the lift height");
        assert_eq!(run(vec![knot(5.0, 5.0, -5.0, 0.0, 0.0), knot(6.0, 5.0, 15.0, 0.0, 0.0), knot(7.0, 5.0, -5.0, 0.0, 0.0)]), 2, "two entries");
        // Not cut whole (the last side left): never fallen.
        let mut open = cut(0.0);
        open.pop();
        open.extend(across(0.0));
        assert_eq!(count(&open, &pieces, Some(2), 5.0, 0.01, 0.01, 0.5), 0);
        // Starting over it (a lead-out into a slug) and leaving: none.
        let mut k = cut(0.0);
        k.extend([knot(4.5, 3.0, 3.0, 0.0, 500.0), knot(5.0, -5.0, 3.0, 0.0, 0.0)]);
        assert_eq!(count(&k, &pieces, Some(2), 5.0, 0.01, 0.01, 0.5), 0);
    }
}
