//! Leads checked against the drawing: the pierce in the waste, the lead
//! crossing nothing, the contour cut whole after it.

use super::*;
use crate::job::{Geometry, Process};
use crate::plan::PathGroup;

fn process() -> Process {
    Process { layer: "cut".into(), speed: 10.0, power: 100.0, passes: 1, fill: false }
}

fn settings(lead_in: LeadKind, lead_out: LeadKind) -> LeadSettings {
    LeadSettings {
        lead_in: Lead { kind: lead_in, length: 2.0, angle_deg: 90.0 },
        lead_out: Lead { kind: lead_out, length: 1.0, angle_deg: 90.0 },
        at: LeadAt::Entry,
        overcut: 0.0,
        closing_gap: 0.0,
        kerf: 0.0,
        corner_angle_deg: 30.0,
        common_cut_mm: 0.01,
        layer: "cut".into(),
    }
}

fn square(x: f64, y: f64, w: f64, name: &str) -> Geometry {
    let points = vec![Point::new(x, y), Point::new(x + w, y), Point::new(x + w, y + w), Point::new(x, y + w)];
    Geometry::polyline(points, true, 0, name.into())
}

fn circle(c: Point, r: f64, name: &str) -> Geometry {
    let points = (0..64).map(|i| c + Vector2::new((i as f64 / 64.0 * std::f64::consts::TAU).cos(), (i as f64 / 64.0 * std::f64::consts::TAU).sin()) * r).collect();
    Geometry::polyline(points, true, 0, name.into())
}

/// Each geometry cut whole from its first vertex, holes first.
fn sequence(job: &Job, order: &[usize]) -> Sequence {
    let paths = order
        .iter()
        .map(|&k| {
            let mut points = job.geometries[k].points.clone();
            points.push(points[0]);
            PlannedPath::new(k, points, 0, true)
        })
        .collect();
    Sequence { groups: vec![PathGroup { field_center: None, paths }] }
}

fn lead(job: &Job, order: &[usize], s: LeadSettings) -> Result<Leads> {
    let waste = Waste::new(job, &[true]);
    add_leads(job, sequence(job, order), &[s], &waste, (Point::new(0.0, 0.0), Point::new(500.0, 500.0)), 0.01)
}

#[test]
fn a_part_is_entered_from_outside_and_its_hole_from_inside() {
    let job = Job { source: "t".into(), geometries: vec![square(10.0, 10.0, 40.0, "part"), circle(Point::new(30.0, 30.0), 5.0, "hole")], processes: vec![process()] };
    let waste = Waste::new(&job, &[true]);
    let leads = lead(&job, &[1, 0], settings(LeadKind::Line, LeadKind::Arc)).unwrap();
    assert_eq!((leads.count.lead_ins, leads.count.lead_outs), (2, 2));
    for p in leads.sequence.paths() {
        let pierce = p.points[0];
        assert!(waste.in_waste(pierce), "{pierce:?}");
        let drawn = &job.geometries[p.geometry];
        // The contour follows the lead-in whole.
        assert_eq!(p.points[p.lead_in], p.points[p.points.len() - 1 - p.lead_out]);
        assert_eq!(p.points.len() - p.lead_in - p.lead_out, drawn.points.len() + 1);
        assert!(((p.points[p.lead_in] - pierce).norm() - 2.0).abs() < 1e-9);
        for q in &p.points[p.points.len() - p.lead_out..] {
            assert!(waste.in_waste(*q), "lead-out {q:?}");
        }
    }
    let hole = &leads.sequence.groups[0].paths[0];
    assert!((hole.points[0] - Point::new(30.0, 30.0)).norm() < 5.0, "inside the hole: {:?}", hole.points[0]);
}

#[test]
fn a_lead_in_with_no_room_at_the_entry_moves_along_the_contour() {
    // A neighbour 1 mm to the left of the part's first corner.
    let job = Job { source: "t".into(), geometries: vec![square(10.0, 10.0, 40.0, "part"), square(2.0, 0.0, 7.0, "neighbour")], processes: vec![process()] };
    let leads = lead(&job, &[0, 1], settings(LeadKind::Line, LeadKind::None)).unwrap();
    assert_eq!(leads.count.moved, 1);
    let part = &leads.sequence.groups[0].paths[0];
    assert!(Waste::new(&job, &[true]).near(part.points[0], part.points[1], 0.1).all(|(g, ..)| g == 0));
}

#[test]
fn a_lead_in_longer_than_the_hole_is_an_error_naming_it_and_the_setting() {
    let job = Job { source: "t".into(), geometries: vec![square(10.0, 10.0, 40.0, "part"), circle(Point::new(30.0, 30.0), 0.8, "small hole")], processes: vec![process()] };
    let err = lead(&job, &[1, 0], settings(LeadKind::Line, LeadKind::None)).unwrap_err().to_string();
    assert!(err.contains("small hole") && err.contains("lead_in_length"), "{err}");
}

#[test]
fn overcut_cuts_past_the_start_and_a_closing_gap_stops_short() {
    let job = Job { source: "t".into(), geometries: vec![square(10.0, 10.0, 40.0, "part")], processes: vec![process()] };
    let over = lead(&job, &[0], LeadSettings { overcut: 3.0, ..settings(LeadKind::Line, LeadKind::None) }).unwrap();
    let p = &over.sequence.groups[0].paths[0];
    let cut: f64 = p.points[p.lead_in..].windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    assert!((cut - 163.0).abs() < 1e-9, "{cut}");
    let gap = lead(&job, &[0], LeadSettings { closing_gap: 1.5, ..settings(LeadKind::Line, LeadKind::Line) }).unwrap();
    let p = &gap.sequence.groups[0].paths[0];
    let cut: f64 = p.points[p.lead_in..].windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    assert!((cut - 158.5).abs() < 1e-9 && p.lead_out == 0, "{cut}, no lead-out after a gap");
}

#[test]
fn lead_in_at_moves_the_start_to_a_corner_or_the_longest_side() {
    let wide = Geometry::polyline(vec![Point::new(10.0, 10.0), Point::new(50.0, 10.0), Point::new(50.0, 20.0), Point::new(10.0, 20.0)], true, 0, "wide".into());
    let job = Job { source: "t".into(), geometries: vec![wide], processes: vec![process()] };
    // The planner entered on the short side, in its middle.
    let entry = vec![Point::new(50.0, 15.0), Point::new(50.0, 20.0), Point::new(10.0, 20.0), Point::new(10.0, 10.0), Point::new(50.0, 10.0), Point::new(50.0, 15.0)];
    let run = |at: LeadAt| {
        let sequence = Sequence { groups: vec![PathGroup { field_center: None, paths: vec![PlannedPath::new(0, entry.clone(), 0, true)] }] };
        let waste = Waste::new(&job, &[true]);
        let leads = add_leads(&job, sequence, &[LeadSettings { at, ..settings(LeadKind::Line, LeadKind::None) }], &waste, (Point::new(0.0, 0.0), Point::new(500.0, 500.0)), 0.01).unwrap();
        let p = leads.sequence.groups[0].paths[0].clone();
        p.points[p.lead_in]
    };
    assert_eq!(run(LeadAt::Entry), Point::new(50.0, 15.0));
    assert_eq!(run(LeadAt::Corner), Point::new(50.0, 20.0));
    let middle = run(LeadAt::Longest);
    assert!((middle - Point::new(30.0, 20.0)).norm() < 1e-12 || (middle - Point::new(30.0, 10.0)).norm() < 1e-12, "{middle:?}");
}

#[test]
fn a_small_circle_kept_as_arcs_is_a_loop_for_its_overcut() {
    // A 1.5 mm hole flattened to 0.01 mm: its chords are 0.2 % shorter than its arcs.
    let (c, r) = (Point::new(30.0, 30.0), 1.5);
    let (a, b) = (c + Vector2::new(r, 0.0), c - Vector2::new(r, 0.0));
    let mut points = vec![a];
    points.extend(crate::job::arc_points(a, b, 1.0, 0.01));
    let mid = points.len() - 1;
    points.extend(crate::job::arc_points(b, a, 1.0, 0.01));
    points.pop();
    let n = points.len();
    let arcs = vec![crate::job::ArcSpan { from: 0, to: mid, bulge: 1.0 }, crate::job::ArcSpan { from: mid, to: n, bulge: 1.0 }];
    let hole = Geometry { arcs, ..Geometry::polyline(points, true, 0, "hole".into()) };
    let job = Job { source: "t".into(), geometries: vec![square(10.0, 10.0, 40.0, "part"), hole], processes: vec![process()] };
    let chords: f64 = (0..n).map(|i| (job.geometries[1].points[(i + 1) % n] - job.geometries[1].points[i]).norm()).sum();
    assert!((job.geometries[1].length() - chords) / chords > 1e-3);
    let leads = lead(&job, &[1], LeadSettings { overcut: 1.0, ..settings(LeadKind::Line, LeadKind::None) }).unwrap();
    let p = &leads.sequence.groups[0].paths[0];
    let cut: f64 = p.points[p.lead_in..].windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    assert!((cut - chords - 1.0).abs() < 1e-9, "{cut} = {chords} + the overcut");
}
