//! `laserd plan --plot OUT.svg`: a picture of a plan, to see the order and the
//! split between scanner and stage at a glance.
//!
//! Top: the machine's travel with the geometries (grey; with a kerf, the
//! offset paths, the drawn contours thin dashed over them), the scan fields
//! (usable squares, blue), the TCP path (marking solid black, laser-off jumps
//! dashed red), lead-ins (orange), lead-outs (purple), bridges (teal), pierces (red dots),
//! tabs (blue rings), cooling waits (cyan rings, the seconds beside them) and the stage path (green, a dot per stage position). Bottom:
//! the scanner's field use over time (largest |scanner axis| / half the
//! usable field; 1 is the field's edge). Machine y points up; the picture is
//! drawn that way.

use std::fmt::Write;

use crate::config::MachineConfig;
use crate::job::{Job, Point};
use crate::motion::stage::StagePath;
use crate::motion::tcp::{Motion, PieceKind};
use crate::motion::Trajectory;
use crate::plan::Sequence;

/// Height of the time plot, as a share of the picture's width.
const TIME_PLOT_SHARE: f64 = 0.25;
/// Samples of the time plot.
const TIME_SAMPLES: usize = 600;

/// The picture as SVG text (mm units).
pub fn plot(job: &Job, sequence: &Sequence, trajectory: &Trajectory, machine: &MachineConfig, drawn: Option<&Job>) -> String {
    let half = machine.scanner.as_ref().map(|s| s.usable_half_field);
    // The drawing spans the travel and everything drawn (fields may reach past it).
    let (mut lo, mut hi) = (Point::new(0.0, 0.0), Point::new(machine.stage.travel_x, machine.stage.travel_y));
    let mut grow = |p: Point| {
        lo = Point::new(lo.x.min(p.x), lo.y.min(p.y));
        hi = Point::new(hi.x.max(p.x), hi.y.max(p.y));
    };
    for g in &job.geometries {
        g.points.iter().for_each(|&p| grow(p));
    }
    for group in &sequence.groups {
        if let (Some(c), Some(h)) = (group.field_center, half) {
            grow(Point::new(c.x - h, c.y - h));
            grow(Point::new(c.x + h, c.y + h));
        }
    }
    let width = hi.x - lo.x;
    let margin = 0.03 * width.max(hi.y - lo.y);
    let plot_h = TIME_PLOT_SHARE * width;
    let (w, h) = (width + 2.0 * margin, hi.y - lo.y + 3.0 * margin + plot_h);
    let stroke = 0.002 * w.max(h);
    // Machine (x, y) to picture coordinates.
    let at = |p: Point| (p.x - lo.x + margin, hi.y - p.y + margin);
    let mut svg = String::new();
    let _ = writeln!(svg, r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w:.1}mm" height="{h:.1}mm" viewBox="0 0 {w:.3} {h:.3}">"#);
    let _ = writeln!(svg, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let (tx, ty) = at(Point::new(0.0, machine.stage.travel_y));
    let _ = writeln!(
        svg,
        r##"<rect id="travel" x="{tx:.3}" y="{ty:.3}" width="{:.3}" height="{:.3}" fill="none" stroke="#999" stroke-width="{stroke:.3}"/>"##,
        machine.stage.travel_x, machine.stage.travel_y
    );
    let polyline = |svg: &mut String, id: &str, points: &[Point], style: &str| {
        let mut d = String::new();
        for p in points {
            let (x, y) = at(*p);
            let _ = write!(d, "{x:.3},{y:.3} ");
        }
        let _ = writeln!(svg, r#"<polyline {id}points="{}" fill="none" {style}/>"#, d.trim_end());
    };
    let _ = writeln!(svg, r#"<g id="geometries">"#);
    for g in &job.geometries {
        let mut points = g.points.clone();
        if g.closed && !points.is_empty() {
            points.push(points[0]);
        }
        polyline(&mut svg, "", &points, &format!(r##"stroke="#bbb" stroke-width="{:.3}""##, 2.0 * stroke));
    }
    let _ = writeln!(svg, "</g>");
    if let Some(drawn) = drawn {
        let _ = writeln!(svg, r#"<g id="drawn">"#);
        for g in &drawn.geometries {
            let mut points = g.points.clone();
            if g.closed && !points.is_empty() {
                points.push(points[0]);
            }
            polyline(&mut svg, "", &points, &format!(r##"stroke="#555" stroke-width="{:.3}" stroke-dasharray="{:.3}""##, 0.5 * stroke, 2.0 * stroke));
        }
        let _ = writeln!(svg, "</g>");
    }
    if let Some(h) = half {
        let _ = writeln!(svg, r#"<g id="fields">"#);
        for group in &sequence.groups {
            if let Some(c) = group.field_center {
                let (x, y) = at(Point::new(c.x - h, c.y + h));
                let _ = writeln!(
                    svg,
                    r##"<rect x="{x:.3}" y="{y:.3}" width="{:.3}" height="{:.3}" fill="#36c" fill-opacity="0.05" stroke="#36c" stroke-width="{stroke:.3}"/>"##,
                    2.0 * h,
                    2.0 * h
                );
            }
        }
        let _ = writeln!(svg, "</g>");
    }
    // The TCP path, one polyline per run of marking or of laser-off motion.
    let _ = writeln!(svg, r#"<g id="tcp">"#);
    let mut run: Vec<Point> = Vec::new();
    let mut marking = None;
    let flush = |svg: &mut String, run: &mut Vec<Point>, marking: Option<bool>| {
        if run.len() >= 2 {
            let style = if marking == Some(true) {
                format!(r#"class="mark" stroke="black" stroke-width="{stroke:.3}""#)
            } else {
                format!(r#"class="jump" stroke="red" stroke-width="{:.3}" stroke-dasharray="{:.3}""#, 0.6 * stroke, 4.0 * stroke)
            };
            polyline(svg, "", run, &style);
        }
        run.clear();
    };
    for piece in &trajectory.tcp.pieces {
        if piece.duration <= 0.0 || matches!(piece.kind, PieceKind::Pierce { .. } | PieceKind::Cool { .. }) {
            continue;
        }
        let mark = piece.is_marking();
        if marking != Some(mark) {
            let last = run.last().copied();
            flush(&mut svg, &mut run, marking);
            run.extend(last);
            marking = Some(mark);
        }
        // Straight legs need their ends; blended corners and free moves bow.
        let samples = match piece.motion {
            Motion::Leg { .. } if !mark => 1,
            _ => 4,
        };
        for i in 0..=samples {
            let t = piece.start + piece.duration * i as f64 / samples as f64;
            let p = trajectory.tcp.position(t);
            if run.last().is_none_or(|q| (p - q).norm() > 1e-9) {
                run.push(p);
            }
        }
    }
    flush(&mut svg, &mut run, marking);
    let _ = writeln!(svg, "</g>");
    // Cutting technology: leads, pierces, tabs.
    let _ = writeln!(svg, r#"<g id="technology">"#);
    for p in sequence.paths() {
        let bridge = usize::from(p.bridge);
        if p.bridge {
            polyline(&mut svg, "", &p.points[..=1], &format!(r#"class="bridge" stroke="teal" stroke-width="{:.3}""#, 2.0 * stroke));
        }
        if p.lead_in > bridge {
            polyline(&mut svg, "", &p.lead_in_points()[bridge..], &format!(r#"class="lead-in" stroke="orange" stroke-width="{:.3}""#, 1.5 * stroke));
        }
        if p.lead_out > 0 {
            polyline(&mut svg, "", p.lead_out_points(), &format!(r#"class="lead-out" stroke="purple" stroke-width="{:.3}""#, 1.5 * stroke));
        }
        if p.pierce && machine.pierce(&job.processes[p.process].layer).active() {
            let (x, y) = at(p.points[0]);
            let _ = writeln!(svg, r#"<circle class="pierce" cx="{x:.3}" cy="{y:.3}" r="{:.3}" fill="red"/>"#, 1.5 * stroke);
        }
        if p.cooling_wait > 0.0 {
            // The machine stands here, the laser off, before the path (`--thermal`).
            let (x, y) = at(p.points[0]);
            let (r, size) = (4.0 * stroke, 8.0 * stroke);
            let _ = writeln!(
                svg,
                r##"<g class="cooling-wait"><title>cooling wait {w:.1} s</title><circle cx="{x:.3}" cy="{y:.3}" r="{r:.3}" fill="none" stroke="#0bc" stroke-width="{stroke:.3}"/><text x="{tx:.3}" y="{y:.3}" font-size="{size:.3}" fill="#0bc">{w:.0} s</text></g>"##,
                w = p.cooling_wait,
                tx = x + 1.5 * r
            );
        }
    }
    for tab in crate::plan::tabs::place(job, machine).unwrap_or_default().iter().flatten() {
        let (x, y) = at(tab.centre);
        let _ = writeln!(svg, r##"<circle class="tab" cx="{x:.3}" cy="{y:.3}" r="{:.3}" fill="none" stroke="#36c" stroke-width="{stroke:.3}"/>"##, tab.width.max(3.0 * stroke));
    }
    let _ = writeln!(svg, "</g>");
    // The stage path, with a dot where it rests (the start and the end of
    // each of its moves).
    let duration = trajectory.duration();
    let mut stage = Vec::new();
    let mut rests = vec![trajectory.start.stage];
    if !matches!(trajectory.stage, StagePath::FollowsTcp) {
        for k in 0..=TIME_SAMPLES * 4 {
            stage.push(trajectory.state_at(duration * k as f64 / (TIME_SAMPLES * 4) as f64).stage);
        }
    }
    if let StagePath::Moves { axes, .. } = &trajectory.stage {
        let mut ends: Vec<f64> = axes.iter().flatten().map(|m| m.end_time()).collect();
        ends.sort_by(f64::total_cmp);
        for t in ends {
            if !trajectory.stage.moving(t + 1e-12) {
                rests.push(trajectory.state_at(t).stage);
            }
        }
    }
    stage.dedup();
    rests.dedup_by(|a, b| (*a - *b).norm() < 1e-6);
    let _ = writeln!(svg, r#"<g id="stage">"#);
    polyline(&mut svg, "", &stage, &format!(r#"stroke="green" stroke-width="{:.3}""#, 1.5 * stroke));
    for p in &rests {
        let (x, y) = at(*p);
        let _ = writeln!(svg, r#"<circle cx="{x:.3}" cy="{y:.3}" r="{:.3}" fill="green"/>"#, 3.0 * stroke);
    }
    let _ = writeln!(svg, "</g>");
    // Field use over time.
    let top = hi.y - lo.y + 2.0 * margin;
    let _ = writeln!(svg, r#"<g id="field-use">"#);
    let _ = writeln!(
        svg,
        r##"<rect x="{margin:.3}" y="{top:.3}" width="{width:.3}" height="{plot_h:.3}" fill="none" stroke="#999" stroke-width="{stroke:.3}"/>"##
    );
    if let (Some(h), true) = (half, duration > 0.0) {
        let mut points = String::new();
        for k in 0..=TIME_SAMPLES {
            let t = duration * k as f64 / TIME_SAMPLES as f64;
            let state = trajectory.state_at(t);
            let use_ = state.scanner.x.abs().max(state.scanner.y.abs()) / h;
            let x = margin + width * k as f64 / TIME_SAMPLES as f64;
            let y = top + plot_h * (1.0 - use_.min(1.2) / 1.2);
            let _ = write!(points, "{x:.3},{y:.3} ");
        }
        let edge = top + plot_h * (1.0 - 1.0 / 1.2);
        let _ = writeln!(
            svg,
            r##"<line x1="{margin:.3}" y1="{edge:.3}" x2="{:.3}" y2="{edge:.3}" stroke="#36c" stroke-width="{stroke:.3}" stroke-dasharray="{:.3}"/>"##,
            margin + width,
            3.0 * stroke
        );
        let _ = writeln!(svg, r##"<polyline class="use" points="{}" fill="none" stroke="#36c" stroke-width="{stroke:.3}"/>"##, points.trim_end());
    }
    let font = 0.03 * plot_h.max(1.0) + 1.0;
    let _ = writeln!(
        svg,
        r#"<text x="{:.3}" y="{:.3}" font-size="{font:.2}" font-family="sans-serif">scanner field use over {duration:.2} s (dashed: field edge)</text>"#,
        margin + stroke * 4.0,
        top + font * 1.2
    );
    let _ = writeln!(svg, "</g>");
    svg.push_str("</svg>\n");
    svg
}

/// `--plot` with `--thermal`: the plate's temperatures when the operation
/// nearest its critical temperature starts (cells coloured from the coolest
/// to the hottest, a scale beside), the job's geometries over them, and that
/// operation ringed.
pub fn heat_map(job: &Job, grid: &crate::thermal::Grid, snapshot: &crate::thermal::Snapshot, hottest: Option<&crate::report::HottestOperation>) -> String {
    let (w, h) = (grid.nx as f64 * grid.cell, grid.ny as f64 * grid.cell);
    let (lo, hi) = snapshot.celsius.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| (a.min(f64::from(t)), b.max(f64::from(t))));
    let hi = hi.max(lo + 1.0);
    let scale_w = 0.06 * w;
    let (x0, y0) = (grid.origin.x, grid.origin.y);
    let mut s = String::new();
    let margin = 0.04 * w.max(h);
    let _ = writeln!(
        s,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"{} {} {} {}\" width=\"{}mm\" height=\"{}mm\">",
        x0 - margin,
        -(y0 + h) - margin,
        w + scale_w * 2.5 + 2.0 * margin,
        h + 2.0 * margin,
        w + scale_w * 2.5 + 2.0 * margin,
        h + 2.0 * margin
    );
    let font = 0.018 * w.max(h);
    let _ = writeln!(s, "<title>plate temperature at {:.1} s</title>", snapshot.time);
    // Colours: 16 steps from blue (coolest) through yellow to red (hottest).
    const STEPS: usize = 16;
    let colour = |k: usize| {
        let f = k as f64 / (STEPS - 1) as f64;
        let (r, g, b) = if f < 0.5 { (2.0 * f, 2.0 * f, 1.0 - 2.0 * f) } else { (1.0, 2.0 - 2.0 * f, 0.0) };
        format!("#{:02x}{:02x}{:02x}", (255.0 * r) as u8, (255.0 * g) as u8, (255.0 * b) as u8)
    };
    let step_of = |t: f32| (((f64::from(t) - lo) / (hi - lo)) * (STEPS - 1) as f64).round().clamp(0.0, (STEPS - 1) as f64) as usize;
    // One rectangle per run of cells of one colour along a row.
    for iy in 0..grid.ny {
        let row = &snapshot.celsius[iy * grid.nx..(iy + 1) * grid.nx];
        let mut ix = 0;
        while ix < grid.nx {
            let k = step_of(row[ix]);
            let mut end = ix + 1;
            while end < grid.nx && step_of(row[end]) == k {
                end += 1;
            }
            let _ = writeln!(
                s,
                "<rect x=\"{:.3}\" y=\"{:.3}\" width=\"{:.3}\" height=\"{:.3}\" fill=\"{}\"/>",
                x0 + ix as f64 * grid.cell,
                -(y0 + (iy + 1) as f64 * grid.cell),
                (end - ix) as f64 * grid.cell,
                grid.cell,
                colour(k)
            );
            ix = end;
        }
    }
    let stroke = 0.0015 * w.max(h);
    for g in &job.geometries {
        let points: Vec<String> = g.points.iter().map(|p| format!("{:.3},{:.3}", p.x, -p.y)).collect();
        let _ = writeln!(s, "<polyline points=\"{}\" fill=\"none\" stroke=\"#000000\" stroke-width=\"{stroke:.3}\"/>", points.join(" "));
    }
    if let Some(hot) = hottest {
        let _ = writeln!(s, "<circle cx=\"{:.3}\" cy=\"{:.3}\" r=\"{:.3}\" fill=\"none\" stroke=\"#ffffff\" stroke-width=\"{:.3}\"/>", hot.x, -hot.y, 4.0 * grid.cell, 3.0 * stroke);
        let _ = writeln!(
            s,
            "<text x=\"{:.3}\" y=\"{:.3}\" font-size=\"{font:.2}\">the {} nearest its critical temperature: {:.0} °C of {:.0} °C at {:.1} s</text>",
            x0,
            -(y0 + h) - 0.3 * margin,
            hot.feature,
            hot.celsius,
            hot.critical_c,
            hot.time_s
        );
    }
    // The scale: every colour with its temperature.
    let sx = x0 + w + 0.5 * scale_w;
    let band = h / STEPS as f64;
    for k in 0..STEPS {
        let y = -(y0 + (k + 1) as f64 * band);
        let _ = writeln!(s, "<rect x=\"{sx:.3}\" y=\"{y:.3}\" width=\"{:.3}\" height=\"{band:.3}\" fill=\"{}\"/>", scale_w * 0.5, colour(k));
        if k % 3 == 0 || k == STEPS - 1 {
            let t = lo + (hi - lo) * k as f64 / (STEPS - 1) as f64;
            let _ = writeln!(s, "<text x=\"{:.3}\" y=\"{:.3}\" font-size=\"{font:.2}\">{t:.0} °C</text>", sx + scale_w * 0.6, y + band * 0.7);
        }
    }
    s.push_str("</svg>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mode::Mode;
    use crate::plan::{planner, PlanContext, PlannerKind};

    #[test]
    fn the_picture_is_svg_with_every_field_and_both_path_kinds() {
        let machine = MachineConfig::load(None).unwrap();
        let text = r#"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">
            <rect x="10" y="10" width="5" height="5" stroke="black" fill="none"/>
            <rect x="200" y="20" width="5" height="5" stroke="black" fill="none"/>
            <rect x="120" y="250" width="5" height="5" stroke="black" fill="none"/>
            <line x1="20" y1="12" x2="30" y2="12" stroke="black"/></svg>"#;
        let job = crate::import::svg::import_svg(text, "t.svg", &machine).unwrap();
        let ctx = PlanContext { machine: &machine, mode: Mode::StepAndScan, start: Point::origin(), plate: None };
        let sequence = planner(PlannerKind::Hha).plan(&job, &ctx).unwrap();
        let trajectory = crate::motion::build(&job, &sequence, &machine, Mode::StepAndScan, Point::origin()).unwrap();
        let svg = plot(&job, &sequence, &trajectory, &machine, None);
        // It parses as SVG.
        usvg::Tree::from_str(&svg, &usvg::Options::default()).unwrap();
        let fields = svg.split(r#"<g id="fields">"#).nth(1).unwrap().split("</g>").next().unwrap().matches("<rect").count();
        assert_eq!(fields, sequence.scan_fields().unwrap());
        assert!(fields >= 2);
        assert!(svg.contains(r#"class="mark""#) && svg.contains(r#"class="jump""#) && svg.contains(r#"class="use""#));
        // One stage dot per field visited, plus where the stage starts.
        let dots = svg.split(r#"<g id="stage">"#).nth(1).unwrap().split("</g>").next().unwrap().matches("<circle").count();
        assert_eq!(dots, fields + 1);
    }
}
