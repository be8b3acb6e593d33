//! The topology's tests: small drawings whose contours, common cuts and
//! containment are known. A generated sheet's round trip through SVG is in
//! tests/topology.rs (it needs the generator, a later module).

use std::collections::BTreeSet;

use super::*;
use crate::job::{Geometry, Process};

pub(crate) fn p(x: f64, y: f64) -> Point {
    Point::new(x, y)
}

pub(crate) fn shape(points: &[(f64, f64)], closed: bool, name: &str) -> Geometry {
    Geometry { arcs: Vec::new(), profile: Vec::new(),
        points: points.iter().map(|&(x, y)| p(x, y)).collect(),
        closed,
        process: 0,
        source: format!("test.svg: {name}"),
    }
}

/// A rectangle, counter-clockwise from its lower left corner.
pub(crate) fn rect(x0: f64, y0: f64, x1: f64, y1: f64, name: &str) -> Geometry {
    shape(&[(x0, y0), (x1, y0), (x1, y1), (x0, y1)], true, name)
}

pub(crate) fn job(geometries: Vec<Geometry>) -> Job {
    let process = Process { layer: "cut".into(), speed: 10.0, power: 1000.0, passes: 1, fill: false };
    Job { source: "test.svg".into(), geometries, processes: vec![process] }
}

fn model_with(geometries: Vec<Geometry>, options: &TopologyOptions) -> Topology {
    let job = job(geometries);
    let model = Topology::build(&job, options).unwrap();
    check_model(&model, &job, options.common_cut_tolerance_mm);
    model
}

fn model(geometries: Vec<Geometry>) -> Topology {
    model_with(geometries, &TopologyOptions::default())
}

pub(crate) fn length(points: &[Point]) -> f64 {
    points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

fn distance_to_segment(q: Point, a: Point, b: Point) -> f64 {
    let d = b - a;
    let t = ((q - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
    (a + d * t - q).norm()
}

/// A contour's elements in its order, each with whether it is walked from
/// its end to its start (reversed) the way round the contour goes; asserts
/// that they form one chain, closed for a closed geometry.
pub(crate) fn ring(model: &Topology, job: &Job, k: usize) -> Vec<(usize, bool)> {
    let c = &model.contours[k];
    let ends = |e: usize| (model.elements[e].start(), model.elements[e].end());
    let start = match c.len() {
        1 => ends(c[0]).0,
        // Where the first element does not meet the second.
        _ if ends(c[0]).0 == ends(c[1]).0 || ends(c[0]).0 == ends(c[1]).1 => ends(c[0]).1,
        _ => ends(c[0]).0,
    };
    let mut here = start;
    let cuts = c
        .iter()
        .map(|&e| {
            let (a, b) = ends(e);
            assert!(a == here || b == here, "contour {k}: element {e} does not go on from {here}");
            let reversed = a != here;
            here = if reversed { a } else { b };
            (e, reversed)
        })
        .collect();
    if job.geometries[k].closed {
        assert_eq!(here, start, "contour {k} is not closed");
    }
    cuts
}

/// What holds for every topology: elements on their geometries, contours as
/// chains, every element on one or two contours, relations consistent.
pub(crate) fn check_model(model: &Topology, job: &Job, tol: f64) {
    assert_eq!(model.contours.len(), job.geometries.len());
    let mut owners = vec![Vec::new(); model.elements.len()];
    for (k, c) in model.contours.iter().enumerate() {
        for &e in c {
            owners[e].push(k);
        }
    }
    for (e, piece) in model.elements.iter().enumerate() {
        assert!(piece.points.len() >= 2);
        let mut on: Vec<usize> = piece.geometries();
        on.sort();
        assert_eq!(owners[e], on, "element {e} is on the contours of its piece's geometries");
        // Every point on the geometry's polyline (welding moves by ≤ tol).
        let g = &job.geometries[piece.geometry];
        let n = g.points.len();
        let segs = if g.closed { n } else { n - 1 };
        for &q in &piece.points {
            let d = (0..segs)
                .map(|i| distance_to_segment(q, g.points[i], g.points[(i + 1) % n]))
                .fold(f64::INFINITY, f64::min);
            assert!(d <= tol * 1.001, "element {e}: {q} is {d} mm off {}", g.source);
        }
    }
    for k in 0..model.contours.len() {
        ring(model, job, k);
    }
    // Marked length: the geometries' less the second copies of common cuts.
    let pieces: f64 = model.elements.iter().map(|pc| length(&pc.points)).sum();
    let shared: f64 = model.elements.iter().filter(|pc| pc.shared_with.is_some()).map(|pc| length(&pc.points)).sum();
    let drawn: f64 = job.geometries.iter().map(Geometry::length).sum();
    let count = model.common_cuts.len() as f64;
    assert!((pieces + shared - drawn).abs() <= 1e-6 * drawn + 4.0 * tol * count, "{pieces} + {shared} vs {drawn}");
    let inner_outer = model.inner_outer();
    for &(i, o) in &inner_outer {
        assert_eq!(model.outer[i], Some(o));
        assert_eq!(model.levels[i], model.levels[o] + 1);
        assert_eq!(model.groups[i], model.groups[o]);
        assert!(job.geometries[o].closed, "an open geometry is never an outer");
    }
    assert_eq!(model.common_cuts, common_cuts(&model.contours, model.elements.len()));
    for cc in &model.common_cuts {
        assert_eq!(model.groups[cc.contours.0], model.groups[cc.contours.1]);
    }
    assert_eq!(model.outer.iter().filter(|o| o.is_some()).count(), inner_outer.len());
}

fn common_pairs(model: &Topology) -> Vec<(usize, usize)> {
    let mut pairs: Vec<(usize, usize)> = model
        .common_cuts
        .iter()
        .map(|cc| (cc.contours.0.min(cc.contours.1), cc.contours.0.max(cc.contours.1)))
        .collect();
    pairs.sort();
    pairs
}

fn ends_of(model: &Topology, e: usize) -> BTreeSet<(i64, i64)> {
    let key = |q: Point| ((q.x * 1e6).round() as i64, (q.y * 1e6).round() as i64);
    [key(model.elements[e].start()), key(model.elements[e].end())].into_iter().collect()
}

fn set(points: &[(f64, f64)]) -> BTreeSet<(i64, i64)> {
    points.iter().map(|&(x, y)| ((x * 1e6).round() as i64, (y * 1e6).round() as i64)).collect()
}

#[test]
fn rectangles_side_by_side_share_one_edge() {
    // The right one counter-clockwise (the shared edge runs the other way
    // round in each) and clockwise (the same way in both).
    let clockwise = shape(&[(10.0, 0.0), (10.0, 10.0), (20.0, 10.0), (20.0, 0.0)], true, "b");
    for right in [rect(10.0, 0.0, 20.0, 10.0, "b"), clockwise] {
        let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), right]);
                assert_eq!(m.elements.len(), 7);
        assert_eq!(m.contours.iter().map(Vec::len).collect::<Vec<_>>(), vec![4, 4]);
        let cc = m.common_cuts.clone();
        assert_eq!(cc.len(), 1);
        assert_eq!(cc[0].contours, (0, 1));
        assert_eq!(ends_of(&m, cc[0].element), set(&[(10.0, 0.0), (10.0, 10.0)]));
        assert_eq!(m.elements[cc[0].element].geometry, 0);
        assert_eq!(m.elements[cc[0].element].shared_with, Some(1));
        assert!(m.inner_outer().is_empty());
        assert_eq!((m.levels.clone(), m.ranks.clone(), m.groups.clone()), (vec![0, 0], vec![0, 0], vec![0, 0]));
    }
    // Apart by a gap: two parts, two groups.
    let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(12.0, 0.0, 22.0, 10.0, "b")]);
    assert_eq!((m.elements.len(), m.common_cuts.len(), m.group_count()), (8, 0, 2));
    // Touching at a corner only (collinear edges meeting end to end): no common cut.
    let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 10.0, 20.0, 20.0, "b")]);
    assert_eq!(m.common_cuts.len(), 0);
}

#[test]
fn partly_overlapping_edges_are_split_at_the_overlap() {
    // Shifted up by half: the overlap is x = 10, y 5..10.
    let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 5.0, 20.0, 15.0, "b")]);
        assert_eq!(m.contours.iter().map(Vec::len).collect::<Vec<_>>(), vec![5, 5]);
    assert_eq!(m.elements.len(), 9);
    let cc = m.common_cuts.clone();
    assert_eq!(cc.len(), 1);
    assert_eq!(ends_of(&m, cc[0].element), set(&[(10.0, 5.0), (10.0, 10.0)]));
    // A smaller part against the middle of the edge: it is split in three.
    let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 2.0, 14.0, 6.0, "b")]);
        assert_eq!(m.contours.iter().map(Vec::len).collect::<Vec<_>>(), vec![6, 4]);
    let cc = m.common_cuts.clone();
    assert_eq!(cc.len(), 1);
    assert_eq!(ends_of(&m, cc[0].element), set(&[(10.0, 2.0), (10.0, 6.0)]));
    // Two parts against one long edge: two common cuts, three contours in a group.
    let m = model(vec![
        rect(0.0, 0.0, 10.0, 30.0, "a"),
        rect(10.0, 0.0, 20.0, 10.0, "b"),
        rect(10.0, 10.0, 20.0, 20.0, "c"),
    ]);
    assert_eq!(common_pairs(&m), vec![(0, 1), (0, 2), (1, 2)]);
    assert_eq!(m.groups, vec![0, 0, 0]);
}

#[test]
fn offsets_within_the_tolerance_are_common_cuts_and_beyond_are_not() {
    let a = || rect(0.0, 0.0, 10.0, 10.0, "a");
    let m = model(vec![a(), rect(10.004, 0.003, 20.0, 10.003, "b")]);
    let cc = &m.common_cuts;
    assert_eq!(cc.len(), 1);
    // The shared edge keeps the first part's coordinates; the second
    // part's neighbouring edges meet it there (check_model: a chain).
    assert_eq!(ends_of(&m, cc[0].element), set(&[(10.0, 0.0), (10.0, 10.0)]));
    assert_eq!(m.elements.len(), 7);
    let m = model(vec![a(), rect(10.02, 0.0, 20.0, 10.0, "b")]);
    assert_eq!((m.common_cuts.len(), m.elements.len()), (0, 8));
    // A wider tolerance takes it.
    let wide = TopologyOptions { common_cut_tolerance_mm: 0.05, ..TopologyOptions::default() };
    let m = model_with(vec![a(), rect(10.02, 0.0, 20.0, 10.0, "b")], &wide);
    assert_eq!(m.common_cuts.len(), 1);
    // Slightly skewed (within the tolerance over the edge): still one.
    let skew = shape(&[(10.0, 0.0), (20.0, 0.0), (20.0, 10.0), (10.008, 10.0)], true, "b");
    assert_eq!(model(vec![a(), skew]).common_cuts.len(), 1);
}

#[test]
fn part_hole_and_nested_part_have_levels_0_1_2() {
    // Listed inside out, with a part of its own beside them.
    let m = model(vec![
        rect(30.0, 30.0, 70.0, 70.0, "nested part"),
        rect(200.0, 0.0, 300.0, 100.0, "other part"),
        rect(0.0, 0.0, 100.0, 100.0, "part"),
        rect(45.0, 45.0, 55.0, 55.0, "hole of the nested part"),
        rect(20.0, 20.0, 80.0, 80.0, "hole"),
    ]);
    assert_eq!(m.outer, vec![Some(4), None, None, Some(0), Some(2)]);
    assert_eq!(m.levels, vec![2, 0, 0, 3, 1]);
    let pairs: BTreeSet<(usize, usize)> = m.inner_outer().iter().copied().collect();
    assert_eq!(pairs, [(0, 4), (3, 0), (4, 2)].into_iter().collect());
    assert_eq!(m.groups, vec![0, 1, 0, 0, 0]);
    assert_eq!(m.group_count(), 2);
    assert_eq!(m.ranks, vec![0; 5]);
}

#[test]
fn a_grid_ranks_its_middle_cell_higher() {
    // 3 × 3 cells of 10 mm, each drawn whole.
    let mut cells = Vec::new();
    for i in 0..3 {
        for j in 0..3 {
            let (x, y) = (10.0 * j as f64, 10.0 * i as f64);
            cells.push(rect(x, y, x + 10.0, y + 10.0, &format!("cell {i} {j}")));
        }
    }
    let m = model(cells);
    assert_eq!(m.common_cuts.len(), 12);
    assert_eq!(m.elements.len(), 24);
    assert_eq!(m.ranks, vec![0, 0, 0, 0, 1, 0, 0, 0, 0]);
    assert_eq!(m.groups, vec![0; 9]);
}

#[test]
fn flattened_circle_is_a_few_arcs() {
    let circle: Vec<(f64, f64)> =
        (0..360).map(|k| (k as f64).to_radians()).map(|t| (50.0 + 20.0 * t.cos(), 50.0 + 20.0 * t.sin())).collect();
    let m = model(vec![shape(&circle, true, "circle")]);
    let lengths: Vec<f64> = m.elements.iter().map(|pc| length(&pc.points)).collect();
    assert!((2..=4).contains(&lengths.len()), "{} arcs", lengths.len());
    let total: f64 = lengths.iter().sum();
    for l in &lengths {
        assert!((l - total / lengths.len() as f64).abs() < 0.05 * total, "unequal arcs {lengths:?}");
    }
    // A D: a half circle and its diameter, two corners, two elements.
    let mut d: Vec<(f64, f64)> = (0..=100)
        .map(|k| std::f64::consts::PI * k as f64 / 100.0)
        .map(|t| (20.0 * t.cos(), 20.0 * t.sin()))
        .collect();
    d.push((0.0, 0.0));
    let m = model(vec![shape(&d, true, "D")]);
    let sizes: BTreeSet<usize> = m.elements.iter().map(|pc| pc.points.len()).collect();
    assert_eq!(sizes, [3, 101].into_iter().collect(), "the arc and the diameter (split at the centre vertex)");
    // A teardrop: one corner; still entered at more than one place.
    let mut drop: Vec<(f64, f64)> =
        (0..=90).map(|k| (45.0 + 3.0 * k as f64).to_radians()).map(|t| (10.0 * t.cos(), 10.0 * t.sin())).collect();
    drop.push((10.0 * 2f64.sqrt(), 0.0));
    let m = model(vec![shape(&drop, true, "drop")]);
    assert!(m.contours[0].len() >= 2);
    // A square stays four lines.
    assert_eq!(model(vec![rect(0.0, 0.0, 1.0, 1.0, "square")]).elements.len(), 4);
}

#[test]
fn open_line_inside_a_part_is_its_inner() {
    let m = model(vec![
        rect(0.0, 0.0, 100.0, 100.0, "part"),
        shape(&[(10.0, 10.0), (50.0, 50.0), (90.0, 10.0)], false, "engraving"),
        shape(&[(200.0, 0.0), (210.0, 0.0)], false, "a line on its own"),
    ]);
    assert_eq!(m.inner_outer(), vec![(1, 0)]);
    assert_eq!(m.levels, vec![0, 1, 0]);
    assert_eq!(m.contours[1].len(), 2, "split at its corner");
    assert_eq!(m.elements[m.contours[1][0]].points, vec![p(10.0, 10.0), p(50.0, 50.0)]);
    // An open line round a part is not its outer.
    let m = model(vec![
        shape(&[(-10.0, 110.0), (-10.0, -10.0), (110.0, -10.0), (110.0, 110.0)], false, "bracket"),
        rect(0.0, 0.0, 100.0, 100.0, "part"),
    ]);
    assert_eq!(m.outer, vec![None, None]);
    // An engraving touching the part's edge from inside is still inside.
    let m = model(vec![rect(0.0, 0.0, 100.0, 100.0, "part"), shape(&[(0.0, 50.0), (50.0, 50.0)], false, "tick")]);
    assert_eq!(m.outer, vec![None, Some(0)]);
}

#[test]
fn bad_geometry_is_an_error_naming_its_source() {
    let options = TopologyOptions::default();
    let cases = [
        (shape(&[(0.0, 0.0), (f64::NAN, 1.0), (1.0, 1.0)], true, "path 'nan'"), "not a finite number"),
        (shape(&[(0.0, 0.0), (f64::INFINITY, 1.0)], false, "path 'inf'"), "not a finite number"),
        (shape(&[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)], true, "path 'flat'"), "no area"),
        (shape(&[(0.0, 0.0), (1.0, 1.0), (0.0, 0.0)], true, "path 'two'"), "at least 3"),
        (shape(&[(1.0, 1.0), (1.0, 1.0)], false, "path 'dot'"), "at least 2"),
    ];
    for (bad, why) in cases {
        let source = bad.source.clone();
        let result = Topology::build(&job(vec![rect(0.0, 0.0, 10.0, 10.0, "fine"), bad]), &options);
        match result {
            Err(Error::Plan(msg)) => assert!(msg.contains(&source) && msg.contains(why), "{msg}"),
            other => panic!("{source}: {other:?}"),
        }
    }
    for options in [
        TopologyOptions { common_cut_tolerance_mm: 0.0, ..options },
        TopologyOptions { common_cut_tolerance_mm: f64::NAN, ..options },
        TopologyOptions { corner_angle_deg: 0.0, ..options },
    ] {
        assert!(matches!(Topology::build(&job(vec![]), &options), Err(Error::Plan(_))));
    }
}
