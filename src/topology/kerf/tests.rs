//! Kerf offsets measured against the drawn contour: every vertex of the
//! offset path lies half the kerf from it (1 µm), outward for parts and
//! inward for holes; arcs stay arcs; lost features and collisions are errors.

use super::*;
use crate::job::{arc_circle, Process};

const TOL: f64 = 0.01;

fn process() -> Process {
    Process { layer: "cut".into(), speed: 10.0, power: 100.0, passes: 1, fill: false }
}

fn layer(kerf: f64, corners: KerfCorners) -> KerfLayer {
    KerfLayer { kerf, corners, cuts: true }
}

fn job(geometries: Vec<Geometry>) -> Job {
    Job { source: "t.dxf".into(), geometries, processes: vec![process()] }
}

fn poly(points: &[(f64, f64)], name: &str) -> Geometry {
    Geometry::polyline(points.iter().map(|&(x, y)| Point::new(x, y)).collect(), true, 0, name.into())
}

fn rect(x: f64, y: f64, w: f64, h: f64, name: &str) -> Geometry {
    poly(&[(x, y), (x + w, y), (x + w, y + h), (x, y + h)], name)
}

/// A circle as two half arcs, flattened to `TOL` (as the DXF import makes it).
fn circle(c: (f64, f64), r: f64, name: &str) -> Geometry {
    let (a, b) = (Point::new(c.0 + r, c.1), Point::new(c.0 - r, c.1));
    let mut points = vec![a];
    points.extend(arc_points(a, b, 1.0, TOL));
    let mid = points.len() - 1;
    points.extend(arc_points(b, a, 1.0, TOL));
    points.pop();
    let n = points.len();
    Geometry { arcs: vec![ArcSpan { from: 0, to: mid, bulge: 1.0 }, ArcSpan { from: mid, to: n, bulge: 1.0 }], ..Geometry::polyline(points, true, 0, name.into()) }
}

/// Distance from `p` to the exact drawn contour of `g` (its arcs as arcs).
fn distance_to(g: &Geometry, p: Point) -> f64 {
    let pline = pline_of(g);
    let q = pline.closest_point(CVec::new(p.x, p.y), 1e-12).unwrap();
    q.distance
}

/// Signed side: positive outside the drawn contour.
fn outside(g: &Geometry, p: Point) -> bool {
    pline_of(g).winding_number(CVec::new(p.x, p.y)) == 0
}

fn compensate_one(drawn: &Job, kerf: f64, corners: KerfCorners) -> Job {
    compensate(drawn, &[layer(kerf, corners)], TOL).unwrap().job
}

#[test]
fn a_part_is_cut_outward_and_its_hole_inward_at_half_the_kerf() {
    let drawn = job(vec![rect(0.0, 0.0, 50.0, 30.0, "part"), circle((20.0, 15.0), 5.0, "hole"), rect(35.0, 5.0, 10.0, 8.0, "slot")]);
    for corners in [KerfCorners::Round, KerfCorners::Sharp] {
        let kerfed = compensate_one(&drawn, 0.3, corners);
        let mut worst = 0.0f64;
        for (k, g) in kerfed.geometries.iter().enumerate() {
            let d = &drawn.geometries[k];
            for &p in &g.points {
                let off = distance_to(d, p);
                let sharp_corner = corners == KerfCorners::Sharp && k == 0 && d.points.iter().any(|c| ((p - c).norm() - 0.15 * 2f64.sqrt()).abs() < 1e-6);
                let want = if sharp_corner { 0.15 * 2f64.sqrt() } else { 0.15 };
                assert!((off - want).abs() < 1e-6, "{corners:?} {}: vertex {p:?} is {off} mm off the drawn contour, not {want}", d.source);
                worst = worst.max((off - want).abs());
                assert_eq!(outside(d, p), k == 0, "{}: the part outward, holes inward", d.source);
            }
        }
        eprintln!("kerf 0.3 mm, {corners:?} corners: every vertex within {worst:.1e} mm of half the kerf (the miter at sharp corners)");
        // Round corners: the part's corners are arcs of half the kerf; sharp: none.
        let part = &kerfed.geometries[0];
        match corners {
            KerfCorners::Round => assert_eq!(part.arcs.len(), 4, "{:?}", part.arcs),
            KerfCorners::Sharp => assert!(part.arcs.is_empty() && part.points.len() == 4, "{:?}", part.points),
        }
        assert!(part.arc_error(TOL).is_none() && kerfed.geometries[1].arc_error(TOL).is_none());
    }
}

#[test]
fn a_round_hole_stays_one_true_arc_of_the_smaller_radius() {
    let drawn = job(vec![rect(0.0, 0.0, 40.0, 40.0, "plate"), circle((20.0, 20.0), 6.0, "hole")]);
    let kerfed = compensate_one(&drawn, 0.2, KerfCorners::Round);
    let hole = &kerfed.geometries[1];
    assert!(!hole.arcs.is_empty());
    for a in &hole.arcs {
        let (centre, radius, _, _) = arc_circle(hole.points[a.from], hole.points[a.to % hole.points.len()], a.bulge);
        assert!((radius - 5.9).abs() < 1e-9 && (centre - Point::new(20.0, 20.0)).norm() < 1e-9, "{radius} about {centre:?}");
    }
    // The length is the arc's, not its chords'.
    assert!((hole.length() - 2.0 * std::f64::consts::PI * 5.9).abs() < 1e-9, "{}", hole.length());
}

#[test]
fn a_part_nested_in_a_hole_is_cut_outward_again() {
    let drawn = job(vec![rect(0.0, 0.0, 100.0, 100.0, "frame"), rect(10.0, 10.0, 80.0, 80.0, "window"), rect(40.0, 40.0, 20.0, 20.0, "insert")]);
    let kerfed = compensate_one(&drawn, 0.4, KerfCorners::Sharp);
    let (lo, hi) = kerfed.geometries[2].bounds();
    assert!((lo - Point::new(39.8, 39.8)).norm() < 1e-9 && (hi - Point::new(60.2, 60.2)).norm() < 1e-9, "{lo:?} {hi:?}");
    let (lo, hi) = kerfed.geometries[1].bounds();
    assert!((lo - Point::new(10.2, 10.2)).norm() < 1e-9 && (hi - Point::new(89.8, 89.8)).norm() < 1e-9, "{lo:?} {hi:?}");
}

#[test]
fn a_hole_smaller_than_the_kerf_is_an_error_naming_it() {
    let drawn = job(vec![rect(0.0, 0.0, 40.0, 40.0, "plate"), circle((20.0, 20.0), 0.1, "pinhole")]);
    let err = compensate(&drawn, &[layer(0.3, KerfCorners::Round)], TOL).unwrap_err().to_string();
    assert!(err.contains("pinhole") && err.contains("kerf of 0.3 mm") && err.contains("vanishes"), "{err}");
}

#[test]
fn a_slot_narrower_than_the_kerf_is_an_error_naming_it_and_the_place() {
    // A comb: a slot 0.2 wide and 5 deep cut into the part's edge.
    let comb = poly(&[(0.0, 0.0), (20.0, 0.0), (20.0, 10.0), (10.1, 10.0), (10.1, 5.0), (9.9, 5.0), (9.9, 10.0), (0.0, 10.0)], "comb");
    let err = compensate(&job(vec![comb.clone()]), &[layer(0.3, KerfCorners::Round)], TOL).unwrap_err().to_string();
    assert!(err.contains("comb") && err.contains("cannot reach (10.100, "), "{err}");
    // The same slot with room for the beam is cut.
    assert!(compensate(&job(vec![comb]), &[layer(0.15, KerfCorners::Round)], TOL).is_ok());
}

#[test]
fn a_hole_pinched_narrower_than_the_kerf_is_an_error() {
    // Two squares joined by a neck 0.2 wide and 0.4 long.
    let dumbbell = poly(
        &[(10.0, 10.0), (15.0, 10.0), (15.0, 12.4), (15.4, 12.4), (15.4, 10.0), (20.4, 10.0), (20.4, 15.0), (15.4, 15.0), (15.4, 12.6), (15.0, 12.6), (15.0, 15.0), (10.0, 15.0)],
        "dumbbell",
    );
    let drawn = job(vec![rect(0.0, 0.0, 40.0, 40.0, "plate"), dumbbell]);
    let err = compensate(&drawn, &[layer(0.3, KerfCorners::Round)], TOL).unwrap_err().to_string();
    assert!(err.contains("dumbbell") && (err.contains("2 holes") || err.contains("cannot reach")), "{err}");
}

#[test]
fn parts_nested_closer_than_the_kerf_are_an_error_and_a_kerf_apart_share_the_cut() {
    let close = job(vec![rect(0.0, 0.0, 10.0, 10.0, "left"), rect(10.2, 0.0, 10.0, 10.0, "right")]);
    let err = compensate(&close, &[layer(0.3, KerfCorners::Sharp)], TOL).unwrap_err().to_string();
    assert!(err.contains("left and right") && err.contains("closer than the kerf"), "{err}");
    // Exactly a kerf apart: both cuts run on the same line.
    let apart = job(vec![rect(0.0, 0.0, 10.0, 10.0, "left"), rect(10.3, 0.0, 10.0, 10.0, "right")]);
    let kerfed = compensate(&apart, &[layer(0.3, KerfCorners::Sharp)], TOL).unwrap().job;
    assert!((kerfed.geometries[0].bounds().1.x - 10.15).abs() < 1e-9 && (kerfed.geometries[1].bounds().0.x - 10.15).abs() < 1e-9);
}

#[test]
fn layers_without_a_kerf_and_open_paths_are_cut_as_drawn() {
    let mut open = rect(30.0, 0.0, 5.0, 5.0, "line");
    open.closed = false;
    let drawn = job(vec![rect(0.0, 0.0, 10.0, 10.0, "part"), open]);
    let none = compensate(&drawn, &[layer(0.0, KerfCorners::Round)], TOL).unwrap();
    assert_eq!((none.offset, none.kerf_mm), (0, 0.0));
    assert_eq!(none.job.geometries, drawn.geometries);
    let some = compensate(&drawn, &[layer(0.2, KerfCorners::Round)], TOL).unwrap();
    assert_eq!((some.offset, some.kerf_mm), (1, 0.2));
    assert_eq!(some.job.geometries[1], drawn.geometries[1], "the open path as drawn");
}
