//! `laserd plan --plot OUT.svg`: a picture of a plan, to see the order and the
//! split between scanner and stage at a glance.
//!
//! A title (job, planner, mode, machine time), the plan in a frame with axes
//! in mm (zoomed to the job; the travel drawn when the job fills much of it),
//! a legend naming every colour and mark drawn, a scale bar, and with a
//! scanner its field use over time (largest |scanner axis| / half the usable
//! field; 1 is the field's edge). The picture is in pixels of its own (fonts
//! and strokes keep their size whatever the job's); machine y points up and
//! is drawn so. The root element's `data-mm-to-px="ox oy s"` maps a machine
//! point (x, y) mm to (ox + s·x, oy − s·y) in the picture, for overlays.

use std::fmt::Write;

use crate::config::MachineConfig;
use crate::job::{Job, Point};
use crate::motion::stage::StagePath;
use crate::motion::tcp::{Motion, PieceKind};
use crate::motion::Trajectory;
use crate::plan::Sequence;
use crate::report::{duration, PlanReport};

/// Samples of the time plot.
const TIME_SAMPLES: usize = 800;
/// The picture's width, and its right-hand column (legend, scale bar).
const WIDTH: f64 = 1200.0;
const LEGEND_W: f64 = 270.0;
/// The plan's frame: where it starts, its largest size.
const FRAME_LEFT: f64 = 70.0;
const FRAME_TOP: f64 = 78.0;
const FRAME_MAX_W: f64 = WIDTH - LEGEND_W - FRAME_LEFT - 24.0;
const FRAME_MAX_H: f64 = 570.0;
/// The field-use chart's height.
const CHART_H: f64 = 120.0;
/// Font sizes: title, text, tick labels.
const TITLE_FONT: f64 = 20.0;
const FONT: f64 = 13.0;
const TICK_FONT: f64 = 11.0;

/// What the title says of a plan (`Caption::of` a report).
#[derive(Debug, Clone, Default)]
pub struct Caption {
    /// The job file as given (the title shows its name).
    pub job: String,
    pub planner: String,
    pub mode: String,
    /// Planned machine time, s.
    pub machine_time_s: f64,
}

impl Caption {
    pub fn of(report: &PlanReport) -> Caption {
        Caption { job: report.job.clone(), planner: report.planner.clone(), mode: report.mode.clone(), machine_time_s: report.trajectory_time_s }
    }
}

/// The picture as SVG text; its title says what the job and trajectory
/// tell (`plot_captioned` with a report says more).
pub fn plot(job: &Job, sequence: &Sequence, trajectory: &Trajectory, machine: &MachineConfig, drawn: Option<&Job>) -> String {
    let caption = Caption { job: job.source.clone(), machine_time_s: trajectory.job_time(), ..Caption::default() };
    plot_captioned(job, sequence, trajectory, machine, drawn, &caption)
}

/// `text` fit for SVG text and attributes (job and layer names are the user's).
pub fn escape(text: &str) -> String {
    let mut s = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => s.push_str("&amp;"),
            '<' => s.push_str("&lt;"),
            '>' => s.push_str("&gt;"),
            '"' => s.push_str("&quot;"),
            '\'' => s.push_str("&apos;"),
            c if c.is_control() => s.push(' '),
            c => s.push(c),
        }
    }
    s
}

/// A step of 1, 2 or 5 times a power of ten giving about `count` steps over `range`.
fn nice_step(range: f64, count: f64) -> f64 {
    let raw = (range / count).max(1e-9);
    let unit = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0].into_iter().map(|k| k * unit).find(|&step| step >= raw).unwrap_or(10.0 * unit)
}

/// A tick label of `value` on a scale of `step` (as many decimals as the step has).
fn tick_label(value: f64, step: f64) -> String {
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let text = format!("{value:.decimals$}");
    if text.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') { "0".into() } else { text }
}

/// A time axis label: seconds below two minutes, else minutes, else hours.
fn time_label(t: f64, step: f64) -> String {
    if step >= 3600.0 {
        format!("{} h", tick_label(t / 3600.0, step / 3600.0))
    } else if step >= 60.0 {
        format!("{} min", tick_label(t / 60.0, step / 60.0))
    } else {
        format!("{} s", tick_label(t, step))
    }
}

/// A time step of 1, 2, 5, 10, 15, 30 s, 1, 2, 5, 10, 15, 30 min or hours for about `count` steps.
fn time_step(range: f64, count: f64) -> f64 {
    let raw = range / count;
    if raw < 1.0 {
        return nice_step(range, count);
    }
    const STEPS: [f64; 13] = [1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 60.0, 120.0, 300.0, 600.0, 900.0, 1800.0, 3600.0];
    STEPS.into_iter().find(|&s| s >= raw).unwrap_or_else(|| 3600.0 * nice_step(range / 3600.0, count))
}

/// The picture with `caption`'s title.
pub fn plot_captioned(job: &Job, sequence: &Sequence, trajectory: &Trajectory, machine: &MachineConfig, drawn: Option<&Job>, caption: &Caption) -> String {
    let half = machine.scanner.as_ref().map(|s| s.usable_half_field);
    let travel = Point::new(machine.stage.travel_x, machine.stage.travel_y);
    // The view: the job and its fields; the whole travel where the job
    // fills much of it (else a small job would be a speck in it).
    let (mut lo, mut hi) = (Point::new(f64::INFINITY, f64::INFINITY), Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY));
    let mut grow = |p: Point| {
        lo = Point::new(lo.x.min(p.x), lo.y.min(p.y));
        hi = Point::new(hi.x.max(p.x), hi.y.max(p.y));
    };
    for g in job.geometries.iter().chain(drawn.iter().flat_map(|d| &d.geometries)) {
        g.points.iter().for_each(|&p| grow(p));
    }
    if !lo.x.is_finite() {
        (lo, hi) = (Point::origin(), travel);
    }
    // The fields too where they are not much larger than the job (a
    // small job's letters would be small in a whole field).
    let (mut flo, mut fhi) = (lo, hi);
    for group in &sequence.groups {
        if let (Some(c), Some(h)) = (group.field_center, half) {
            (flo, fhi) = (Point::new(flo.x.min(c.x - h), flo.y.min(c.y - h)), Point::new(fhi.x.max(c.x + h), fhi.y.max(c.y + h)));
        }
    }
    if fhi.x - flo.x <= 2.0 * (hi.x - lo.x) && fhi.y - flo.y <= 2.0 * (hi.y - lo.y) {
        (lo, hi) = (flo, fhi);
    }
    let whole_travel = travel.x <= 2.0 * (hi.x - lo.x) && travel.y <= 2.0 * (hi.y - lo.y);
    if whole_travel {
        (lo, hi) = (Point::new(lo.x.min(0.0), lo.y.min(0.0)), Point::new(hi.x.max(travel.x), hi.y.max(travel.y)));
    }
    // A margin, and no side thinner than a quarter of the other (a long
    // strip keeps room for its ticks).
    let size = (hi.x - lo.x).max(hi.y - lo.y).max(1e-3);
    let pad = |lo: f64, hi: f64| {
        let grow = (0.25 * size - (hi - lo)).max(0.0) / 2.0 + 0.03 * size;
        (lo - grow, hi + grow)
    };
    let ((x0, x1), (y0, y1)) = (pad(lo.x, hi.x), pad(lo.y, hi.y));
    let scale = (FRAME_MAX_W / (x1 - x0)).min(FRAME_MAX_H / (y1 - y0));
    let (frame_w, frame_h) = ((x1 - x0) * scale, (y1 - y0) * scale);
    let (ox, oy) = (FRAME_LEFT - scale * x0, FRAME_TOP + scale * y1);
    // Machine (x, y) mm to picture coordinates.
    let at = |p: Point| (ox + scale * p.x, oy - scale * p.y);
    let frame_bottom = FRAME_TOP + frame_h;
    let chart = half.filter(|_| !matches!(trajectory.stage, StagePath::FollowsTcp) && trajectory.job_time() > 0.0);
    let chart_top = frame_bottom + 70.0;
    let chart_w = WIDTH - FRAME_LEFT - 30.0;
    let height = if chart.is_some() { chart_top + CHART_H + 50.0 } else { frame_bottom + 50.0 }.max(FRAME_TOP + 460.0);
    // Strokes after the job's detail: the median geometry's size in the picture.
    let mut sizes: Vec<f64> = job.geometries.iter().map(|g| {
        let (a, b) = g.bounds();
        (b - a).norm() * scale
    }).filter(|d| d.is_finite()).collect();
    sizes.sort_by(f64::total_cmp);
    let detail = sizes.get(sizes.len() / 2).copied().unwrap_or(100.0);
    let stroke = (detail / 40.0).clamp(0.5, 1.4);

    let mut svg = String::new();
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height:.0}" viewBox="0 0 {WIDTH} {height:.3}" font-family="sans-serif" data-mm-to-px="{ox:.6} {oy:.6} {scale:.8}">"#
    );
    let _ = writeln!(svg, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(svg, r#"<clipPath id="view"><rect x="{FRAME_LEFT}" y="{FRAME_TOP}" width="{frame_w:.3}" height="{frame_h:.3}"/></clipPath>"#);

    // Title: what the job is, how it was planned, how long it runs.
    let name = std::path::Path::new(&caption.job).file_name().map_or(caption.job.clone(), |n| n.to_string_lossy().into_owned());
    let mut how = Vec::new();
    if !caption.planner.is_empty() {
        how.push(format!("planner {}", caption.planner));
    }
    if !caption.mode.is_empty() {
        how.push(caption.mode.clone());
    }
    how.push(format!("machine time {}", duration(caption.machine_time_s)));
    let fields = sequence.scan_fields();
    let mut facts = vec![format!("{} geometries", job.geometries.len()), format!("marking {:.0} mm", job.mark_length()), format!("laser-off travel {:.0} mm", sequence.idle_stroke())];
    if let Some(n) = fields {
        facts.push(format!("{n} scan fields"));
    }
    facts.push(match (half, chart) {
        (None, _) => "no scanner: no field-use chart".to_string(),
        (Some(_), None) => "the scanner stays centred (stage only): no field-use chart".to_string(),
        (Some(_), Some(_)) => "scanner field use below".to_string(),
    });
    let _ = writeln!(svg, r#"<g id="title">"#);
    let _ = writeln!(svg, r#"<text x="{FRAME_LEFT}" y="30" font-size="{TITLE_FONT}" font-weight="bold">{} — {}</text>"#, escape(&name), escape(&how.join(", ")));
    let _ = writeln!(svg, r##"<text x="{FRAME_LEFT}" y="54" font-size="{FONT}" fill="#444">{}</text>"##, escape(&facts.join(" · ")));
    let _ = writeln!(svg, "</g>");

    // Axes: ticks and numbers in mm along the frame's bottom and left, a
    // light grid; ticks at least 60 px apart.
    let step = nice_step(60.0 / scale, 1.0);
    let _ = writeln!(svg, r#"<g id="axes">"#);
    let mut k = (x0 / step).ceil() as i64;
    while (k as f64) * step <= x1 + 1e-9 * step {
        let v = k as f64 * step;
        let (x, _) = at(Point::new(v, 0.0));
        let _ = writeln!(
            svg,
            r##"<line x1="{x:.2}" y1="{FRAME_TOP}" x2="{x:.2}" y2="{frame_bottom:.2}" stroke="#eee"/><line class="tick" x1="{x:.2}" y1="{frame_bottom:.2}" x2="{x:.2}" y2="{:.2}" stroke="#444"/><text x="{x:.2}" y="{:.2}" font-size="{TICK_FONT}" text-anchor="middle">{}</text>"##,
            frame_bottom + 5.0,
            frame_bottom + 18.0,
            tick_label(v, step)
        );
        k += 1;
    }
    let mut k = (y0 / step).ceil() as i64;
    while (k as f64) * step <= y1 + 1e-9 * step {
        let v = k as f64 * step;
        let (_, y) = at(Point::new(0.0, v));
        let _ = writeln!(
            svg,
            r##"<line x1="{FRAME_LEFT}" y1="{y:.2}" x2="{:.2}" y2="{y:.2}" stroke="#eee"/><line class="tick" x1="{:.2}" y1="{y:.2}" x2="{FRAME_LEFT}" y2="{y:.2}" stroke="#444"/><text x="{:.2}" y="{:.2}" font-size="{TICK_FONT}" text-anchor="end">{}</text>"##,
            FRAME_LEFT + frame_w,
            FRAME_LEFT - 5.0,
            FRAME_LEFT - 8.0,
            y + 4.0,
            tick_label(v, step)
        );
        k += 1;
    }
    let _ = writeln!(svg, r##"<rect x="{FRAME_LEFT}" y="{FRAME_TOP}" width="{frame_w:.3}" height="{frame_h:.3}" fill="none" stroke="#444"/>"##);
    let _ = writeln!(svg, r#"<text x="{:.2}" y="{:.2}" font-size="{FONT}" text-anchor="middle">x (mm)</text>"#, FRAME_LEFT + frame_w / 2.0, frame_bottom + 36.0);
    let _ = writeln!(
        svg,
        r#"<text x="18" y="{:.2}" font-size="{FONT}" text-anchor="middle" transform="rotate(-90 18 {:.2})">y (mm)</text>"#,
        FRAME_TOP + frame_h / 2.0,
        FRAME_TOP + frame_h / 2.0
    );
    let _ = writeln!(svg, "</g>");

    let _ = writeln!(svg, r#"<g clip-path="url(#view)">"#);
    let (tx, ty) = at(Point::new(0.0, travel.y));
    let _ = writeln!(
        svg,
        r##"<rect id="travel" x="{tx:.3}" y="{ty:.3}" width="{:.3}" height="{:.3}" fill="none" stroke="#999" stroke-width="{:.3}" stroke-dasharray="8 4"/>"##,
        travel.x * scale,
        travel.y * scale,
        1.5 * stroke
    );
    // Lines of one kind are one path each (a large job's picture stays small).
    let new_path = || Path::new(ox, oy, scale);
    let mut geometries = new_path();
    for g in &job.geometries {
        geometries.add(&g.points, g.closed);
    }
    let _ = writeln!(svg, r#"<g id="geometries">"#);
    geometries.write(&mut svg, &format!(r##"class="geometry" stroke="#ccc" stroke-width="{:.3}" stroke-linejoin="round""##, 3.0 * stroke));
    let _ = writeln!(svg, "</g>");
    if let Some(drawn) = drawn {
        let mut contours = new_path();
        for g in &drawn.geometries {
            contours.add(&g.points, g.closed);
        }
        let _ = writeln!(svg, r#"<g id="drawn">"#);
        contours.write(&mut svg, &format!(r##"stroke="#555" stroke-width="{:.3}" stroke-dasharray="{:.3}""##, 0.6 * stroke, 4.0 * stroke));
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
                    2.0 * h * scale,
                    2.0 * h * scale
                );
            }
        }
        let _ = writeln!(svg, "</g>");
    }
    // The TCP path: runs of marking, runs of laser-off motion.
    let _ = writeln!(svg, r#"<g id="tcp">"#);
    let mut run: Vec<Point> = Vec::new();
    let mut marking = None;
    let (mut marks, mut jumps) = (new_path(), new_path());
    let mut flush = |run: &mut Vec<Point>, marking: Option<bool>| {
        if run.len() >= 2 {
            if marking == Some(true) { &mut marks } else { &mut jumps }.add(run, false);
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
            flush(&mut run, marking);
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
    flush(&mut run, marking);
    marks.write(&mut svg, &format!(r#"class="mark" stroke="black" stroke-width="{stroke:.3}" stroke-linejoin="round""#));
    jumps.write(&mut svg, &format!(r#"class="jump" stroke="red" stroke-opacity="0.7" stroke-width="{:.3}" stroke-dasharray="{:.3}""#, 0.7 * stroke, 4.0 * stroke));
    let _ = writeln!(svg, "</g>");
    // Cutting technology: leads, pierces, tabs.
    let mut used = Used::default();
    let _ = writeln!(svg, r#"<g id="technology">"#);
    let dot = (2.0 * stroke).max(1.5);
    let (mut bridges, mut lead_ins, mut lead_outs) = (new_path(), new_path(), new_path());
    for p in sequence.paths() {
        let bridge = usize::from(p.bridge);
        if p.bridge {
            used.bridges += 1;
            bridges.add(&p.points[..=1], false);
        }
        if p.lead_in > bridge {
            used.lead_ins += 1;
            lead_ins.add(&p.lead_in_points()[bridge..], false);
        }
        if p.lead_out > 0 {
            used.lead_outs += 1;
            lead_outs.add(p.lead_out_points(), false);
        }
        if p.pierce && machine.pierce(&job.processes[p.process].layer).active() {
            used.pierces += 1;
            let (x, y) = at(p.points[0]);
            let _ = writeln!(svg, r#"<circle class="pierce" cx="{x:.2}" cy="{y:.2}" r="{dot:.2}" fill="red"/>"#);
        }
        if p.cooling_wait > 0.0 {
            // The machine stands here, the laser off, before the path (`--thermal`).
            used.cooling_waits += 1;
            let (x, y) = at(p.points[0]);
            let r = 4.0 * dot;
            let _ = writeln!(
                svg,
                r##"<g class="cooling-wait"><title>cooling wait {}</title><circle cx="{x:.2}" cy="{y:.2}" r="{r:.2}" fill="none" stroke="#0bc" stroke-width="{:.2}"/><text x="{tx:.2}" y="{y:.2}" font-size="{TICK_FONT}" fill="#08a">{}</text></g>"##,
                duration(p.cooling_wait),
                1.5 * stroke,
                duration(p.cooling_wait),
                tx = x + 1.3 * r
            );
        }
    }
    bridges.write(&mut svg, &format!(r#"class="bridge" stroke="teal" stroke-width="{:.3}""#, 2.0 * stroke));
    lead_ins.write(&mut svg, &format!(r#"class="lead-in" stroke="orange" stroke-width="{:.3}""#, 1.5 * stroke));
    lead_outs.write(&mut svg, &format!(r#"class="lead-out" stroke="purple" stroke-width="{:.3}""#, 1.5 * stroke));
    for tab in crate::plan::tabs::place(job, machine).unwrap_or_default().iter().flatten() {
        used.tabs += 1;
        let (x, y) = at(tab.centre);
        let _ = writeln!(svg, r##"<circle class="tab" cx="{x:.2}" cy="{y:.2}" r="{:.2}" fill="none" stroke="#36c" stroke-width="{stroke:.3}"/>"##, (tab.width * scale).max(3.0 * dot));
    }
    let _ = writeln!(svg, "</g>");
    // The stage path, with a dot where it rests (the start and the end of
    // each of its moves).
    let duration_s = trajectory.duration();
    let mut stage = Vec::new();
    let mut rests = vec![trajectory.start.stage];
    if !matches!(trajectory.stage, StagePath::FollowsTcp) {
        for k in 0..=TIME_SAMPLES * 4 {
            stage.push(trajectory.state_at(duration_s * k as f64 / (TIME_SAMPLES * 4) as f64).stage);
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
    let stage_drawn = stage.len() >= 2;
    let _ = writeln!(svg, r#"<g id="stage">"#);
    if stage_drawn {
        let mut path = new_path();
        path.add(&stage, false);
        path.write(&mut svg, &format!(r#"stroke="green" stroke-width="{:.3}" stroke-opacity="0.8""#, 1.5 * stroke));
        for p in &rests {
            let (x, y) = at(*p);
            let _ = writeln!(svg, r#"<circle cx="{x:.2}" cy="{y:.2}" r="{:.2}" fill="green"/>"#, 1.5 * dot);
        }
    }
    let _ = writeln!(svg, "</g>");
    let _ = writeln!(svg, "</g>");

    // The legend: every colour and mark drawn, with how many.
    let lx = WIDTH - LEGEND_W + 8.0;
    let mut ly = FRAME_TOP + 4.0;
    let _ = writeln!(svg, r#"<g id="legend" font-size="{FONT}">"#);
    let _ = writeln!(svg, r#"<text x="{lx}" y="{ly:.1}" font-weight="bold">Legend</text>"#);
    ly += 22.0;
    let mut entry = |svg: &mut String, sample: String, text: &str| {
        let _ = writeln!(svg, r#"<g transform="translate({lx} {ly:.1})">{sample}<text x="38" y="4">{}</text></g>"#, escape(text));
        ly += 21.0;
    };
    let line = |colour: &str, width: f64, dash: &str| format!(r#"<line x1="0" y1="0" x2="28" y2="0" stroke="{colour}" stroke-width="{width:.2}"{dash}/>"#);
    // The travel's edge shows where the view reaches past it.
    if whole_travel || x0 < 0.0 || y0 < 0.0 || x1 > travel.x || y1 > travel.y {
        entry(&mut svg, line("#999", 1.5, r#" stroke-dasharray="8 4""#), "edge of the machine's travel");
    }
    if drawn.is_some() {
        entry(&mut svg, line("#ccc", 4.0, ""), "path offset by half the kerf");
        entry(&mut svg, line("#555", 1.0, r#" stroke-dasharray="4""#), "contour as drawn");
    } else {
        entry(&mut svg, line("#ccc", 4.0, ""), "job geometry");
    }
    if !marks.is_empty() {
        entry(&mut svg, line("black", 1.4, ""), "laser on (marking or cutting)");
    }
    if !jumps.is_empty() {
        entry(&mut svg, line("red", 1.0, r#" stroke-dasharray="4""#), "laser off (jump)");
    }
    if let Some(n) = fields.filter(|_| half.is_some()) {
        entry(&mut svg, r##"<rect x="4" y="-9" width="18" height="18" fill="#36c" fill-opacity="0.05" stroke="#36c"/>"##.into(), &format!("usable scan field ({n})"));
    }
    if stage_drawn {
        entry(&mut svg, line("green", 2.0, "") + r#"<circle cx="14" cy="0" r="3.5" fill="green"/>"#, &format!("stage path, dots where it rests ({})", rests.len()));
    }
    for (count, colour, what) in [(used.lead_ins, "orange", "lead-ins"), (used.lead_outs, "purple", "lead-outs"), (used.bridges, "teal", "bridges across the waste")] {
        if count > 0 {
            entry(&mut svg, line(colour, 2.0, ""), &format!("{what} ({count})"));
        }
    }
    if used.pierces > 0 {
        entry(&mut svg, r#"<circle cx="14" cy="0" r="3" fill="red"/>"#.into(), &format!("pierces ({})", used.pierces));
    }
    if used.tabs > 0 {
        entry(&mut svg, r##"<circle cx="14" cy="0" r="5" fill="none" stroke="#36c"/>"##.into(), &format!("tabs left uncut ({})", used.tabs));
    }
    if used.cooling_waits > 0 {
        entry(&mut svg, r##"<circle cx="14" cy="0" r="6" fill="none" stroke="#0bc" stroke-width="1.5"/>"##.into(), &format!("cooling waits ({})", used.cooling_waits));
    }
    let mut layers: Vec<&str> = Vec::new();
    for g in &job.geometries {
        let layer = job.processes[g.process].layer.as_str();
        if !layers.contains(&layer) {
            layers.push(layer);
        }
    }
    ly += 8.0;
    if !layers.is_empty() {
        const SHOWN: usize = 6;
        let more = if layers.len() > SHOWN { format!(" and {} more", layers.len() - SHOWN) } else { String::new() };
        let _ = writeln!(svg, r##"<text x="{lx}" y="{ly:.1}" fill="#444">layers: {}{}</text>"##, escape(&layers[..layers.len().min(SHOWN)].join(", ")), more);
        ly += 21.0;
    }
    if !whole_travel {
        let _ = writeln!(svg, r##"<text x="{lx}" y="{ly:.1}" fill="#444">zoomed to the job; travel {:.0} × {:.0} mm</text>"##, travel.x, travel.y);
        ly += 21.0;
    }
    let _ = writeln!(svg, "</g>");
    // The scale bar: a round length about a third of the column.
    let bar_mm = nice_step(0.45 * (LEGEND_W - 40.0) / scale, 1.0);
    let bar = bar_mm * scale;
    let by = ly + 18.0;
    let _ = writeln!(
        svg,
        r#"<g id="scale-bar"><rect x="{lx}" y="{by:.1}" width="{bar:.2}" height="6" fill="black"/><rect x="{lx}" y="{by:.1}" width="{:.2}" height="6" fill="white" stroke="black" stroke-width="0.8"/><text x="{lx}" y="{:.1}" font-size="{FONT}">{} mm</text></g>"#,
        bar / 2.0,
        by + 22.0,
        tick_label(bar_mm, bar_mm)
    );

    // Field use over the job's machine time.
    if let Some(h) = chart {
        let job_time = trajectory.job_time();
        let (top, bottom) = (chart_top, chart_top + CHART_H);
        let y_of = |u: f64| bottom - CHART_H * u.min(1.2) / 1.2;
        let _ = writeln!(svg, r#"<g id="field-use" font-size="{TICK_FONT}">"#);
        let _ = writeln!(
            svg,
            r#"<text x="{FRAME_LEFT}" y="{:.2}" font-size="{FONT}">scanner field use: largest |scanner axis| / half the usable field ({h} mm); 1 = the field's edge</text>"#,
            top - 10.0
        );
        for u in [0.0, 0.25, 0.5, 0.75, 1.0] {
            let y = y_of(u);
            let edge = if u == 1.0 { r#" stroke-dasharray="6 3""# } else { "" };
            let colour = if u == 1.0 { "#36c" } else { "#eee" };
            let _ = writeln!(
                svg,
                r##"<line x1="{FRAME_LEFT}" y1="{y:.2}" x2="{:.2}" y2="{y:.2}" stroke="{colour}"{edge}/><line class="tick" x1="{:.2}" y1="{y:.2}" x2="{FRAME_LEFT}" y2="{y:.2}" stroke="#444"/><text x="{:.2}" y="{:.2}" text-anchor="end">{u}</text>"##,
                FRAME_LEFT + chart_w,
                FRAME_LEFT - 5.0,
                FRAME_LEFT - 8.0,
                y + 4.0
            );
        }
        let step = time_step(job_time, 8.0);
        let mut k = 0;
        while k as f64 * step <= job_time * (1.0 + 1e-9) {
            let t = k as f64 * step;
            let x = FRAME_LEFT + chart_w * t / job_time;
            let _ = writeln!(
                svg,
                r##"<line class="tick" x1="{x:.2}" y1="{bottom:.2}" x2="{x:.2}" y2="{:.2}" stroke="#444"/><text x="{x:.2}" y="{:.2}" text-anchor="middle">{}</text>"##,
                bottom + 5.0,
                bottom + 18.0,
                time_label(t, step)
            );
            k += 1;
        }
        let _ = writeln!(svg, r##"<rect x="{FRAME_LEFT}" y="{top:.2}" width="{chart_w:.2}" height="{CHART_H}" fill="none" stroke="#444"/>"##);
        let mut points = String::new();
        for k in 0..=TIME_SAMPLES {
            let t = trajectory.job_start + job_time * k as f64 / TIME_SAMPLES as f64;
            let state = trajectory.state_at(t);
            let use_ = state.scanner.x.abs().max(state.scanner.y.abs()) / h;
            let x = FRAME_LEFT + chart_w * k as f64 / TIME_SAMPLES as f64;
            let _ = write!(points, "{x:.2},{:.2} ", y_of(use_));
        }
        let _ = writeln!(svg, r##"<polyline class="use" points="{}" fill="none" stroke="#36c" stroke-width="1.2"/>"##, points.trim_end());
        let _ = writeln!(
            svg,
            r#"<text x="{:.2}" y="{:.2}" font-size="{FONT}" text-anchor="middle">machine time (job clock; {} in all)</text>"#,
            FRAME_LEFT + chart_w / 2.0,
            bottom + 36.0,
            duration(job_time)
        );
        let _ = writeln!(svg, "</g>");
    }
    svg.push_str("</svg>\n");
    svg
}

/// SVG path data in the picture's pixels, a tenth of one enough: points
/// that round to the one before are left out.
struct Path {
    d: String,
    last: (i64, i64),
    ox: f64,
    oy: f64,
    scale: f64,
}

impl Path {
    fn new(ox: f64, oy: f64, scale: f64) -> Path {
        Path { d: String::new(), last: (i64::MIN, i64::MIN), ox, oy, scale }
    }

    fn is_empty(&self) -> bool {
        self.d.is_empty()
    }

    /// A line through `points`, closed back to the first if `closed`.
    fn add(&mut self, points: &[Point], closed: bool) {
        for (k, p) in points.iter().enumerate() {
            let tenths = ((10.0 * (self.ox + self.scale * p.x)).round() as i64, (10.0 * (self.oy - self.scale * p.y)).round() as i64);
            if k > 0 && tenths == self.last {
                continue;
            }
            let at = |v: i64| format!("{}{}.{}", if v < 0 { "-" } else { "" }, v.abs() / 10, v.abs() % 10);
            let _ = write!(self.d, "{}{},{}", if k == 0 { "M" } else { " " }, at(tenths.0), at(tenths.1));
            self.last = tenths;
        }
        if closed && points.len() > 2 {
            self.d.push('Z');
        }
    }

    fn write(&self, svg: &mut String, style: &str) {
        if !self.is_empty() {
            let _ = writeln!(svg, r#"<path d="{}" fill="none" {style}/>"#, self.d);
        }
    }
}

/// What the technology layer drew, for the legend.
#[derive(Default)]
struct Used {
    lead_ins: usize,
    lead_outs: usize,
    bridges: usize,
    pierces: usize,
    tabs: usize,
    cooling_waits: usize,
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

    /// `text` imported as `name` on `machine` and planned by hha in `mode`.
    fn planned(machine: &MachineConfig, text: &str, name: &str, mode: Mode) -> (Job, Sequence, Trajectory) {
        let job = crate::import::svg::import_svg(text, name, machine).unwrap();
        let ctx = PlanContext { machine, mode, start: Point::origin(), plate: None };
        let sequence = planner(PlannerKind::Hha).plan(&job, &ctx).unwrap();
        let trajectory = crate::motion::build(&job, &sequence, machine, mode, Point::origin()).unwrap();
        (job, sequence, trajectory)
    }

    /// The part of `svg` from the group `id` to the next group with an id.
    fn group<'a>(svg: &'a str, id: &str) -> &'a str {
        svg.split(&format!(r#"<g id="{id}""#)).nth(1).unwrap_or_else(|| panic!("no group {id}")).split(r#"<g id=""#).next().unwrap()
    }

    /// The numbers of an attribute of the first element in `part` that has it.
    fn numbers(part: &str, attribute: &str) -> Vec<f64> {
        let value = part.split(&format!(r#" {attribute}=""#)).nth(1).unwrap().split('"').next().unwrap();
        value.split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-')).filter(|w| !w.is_empty()).map(|w| w.parse().unwrap()).collect()
    }

    const FOUR_SQUARES: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">
            <rect x="10" y="10" width="5" height="5" stroke="black" fill="none"/>
            <rect x="200" y="20" width="5" height="5" stroke="black" fill="none"/>
            <rect x="120" y="250" width="5" height="5" stroke="black" fill="none"/>
            <line x1="20" y1="12" x2="30" y2="12" stroke="black"/></svg>"#;

    #[test]
    fn the_picture_is_svg_with_every_field_and_both_path_kinds() {
        let machine = MachineConfig::load(None).unwrap();
        let (job, sequence, trajectory) = planned(&machine, FOUR_SQUARES, "t.svg", Mode::StepAndScan);
        let svg = plot(&job, &sequence, &trajectory, &machine, None);
        // It parses as SVG.
        usvg::Tree::from_str(&svg, &usvg::Options::default()).unwrap();
        let fields = group(&svg, "fields").matches("<rect").count();
        assert_eq!(fields, sequence.scan_fields().unwrap());
        assert!(fields >= 2);
        assert!(svg.contains(r#"class="mark""#) && svg.contains(r#"class="jump""#) && svg.contains(r#"class="use""#));
        // One stage dot per field visited, plus where the stage starts.
        let dots = group(&svg, "stage").matches("<circle").count();
        assert_eq!(dots, fields + 1);
    }

    #[test]
    fn a_job_point_is_drawn_where_the_mm_to_px_attribute_maps_it() {
        let machine = MachineConfig::load(None).unwrap();
        // A 10 mm job: the picture zooms to it.
        let text = r#"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">
            <polygon points="140,150 143,150 143,156 140,156" stroke="black" fill="none"/>
            <polygon points="145,150 150,150 150,152 145,152" stroke="black" fill="none"/></svg>"#;
        let (job, sequence, trajectory) = planned(&machine, text, "small.svg", Mode::OnTheFly);
        let svg = plot(&job, &sequence, &trajectory, &machine, None);
        let map = numbers(&svg, "data-mm-to-px");
        let [ox, oy, s] = map[..] else { panic!("data-mm-to-px: {map:?}") };
        let view = svg.split("<clipPath").nth(1).unwrap();
        let (left, top, width, height) = (numbers(view, "x")[0], numbers(view, "y")[0], numbers(view, "width")[0], numbers(view, "height")[0]);
        assert!(s > 20.0, "a 10 mm job fills the frame: {s} px per mm");
        // Every corner of every geometry is a point of the geometries' path at the mapped place.
        let drawn = numbers(group(&svg, "geometries"), "d");
        let drawn: Vec<(f64, f64)> = drawn.chunks(2).map(|c| (c[0], c[1])).collect();
        for p in job.geometries.iter().flat_map(|g| &g.points) {
            let (x, y) = (ox + s * p.x, oy - s * p.y);
            assert!(drawn.iter().any(|&(a, b)| (a - x).abs() <= 0.051 && (b - y).abs() <= 0.051), "({}, {}) mm at ({x}, {y}) px is not drawn", p.x, p.y);
            assert!(x > left && x < left + width && y > top && y < top + height, "({x}, {y}) inside the frame");
        }
        // The tool's marks pass the middle of each side at the mapped place.
        let d = group(&svg, "tcp").split(r#"d=""#).nth(1).unwrap().split('"').next().unwrap();
        let runs: Vec<Vec<f64>> = d.split('M').filter(|r| !r.is_empty()).map(|r| numbers(&format!(r#" d="{r}""#), "d")).collect();
        let near = |x: f64, y: f64| {
            runs.iter().flat_map(|r| r.chunks(2).zip(r.chunks(2).skip(1))).map(|(a, b)| {
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let t = (((x - a[0]) * dx + (y - a[1]) * dy) / (dx * dx + dy * dy).max(1e-12)).clamp(0.0, 1.0);
                (a[0] + t * dx - x).hypot(a[1] + t * dy - y)
            }).fold(f64::INFINITY, f64::min)
        };
        for g in &job.geometries {
            for k in 0..g.points.len() {
                let p = crate::job::Point::from((g.points[k].coords + g.points[(k + 1) % g.points.len()].coords) / 2.0);
                assert!(near(ox + s * p.x, oy - s * p.y) < 0.5, "the marks pass ({}, {})", p.x, p.y);
            }
        }
    }

    #[test]
    fn the_picture_has_a_title_legend_axes_and_a_scale_bar() {
        let machine = MachineConfig::load(None).unwrap();
        let (job, sequence, trajectory) = planned(&machine, FOUR_SQUARES, "t.svg", Mode::OnTheFly);
        let caption = Caption { job: "jobs/t.svg".into(), planner: "hha".into(), mode: "on-the-fly".into(), machine_time_s: 263.0 };
        let svg = plot_captioned(&job, &sequence, &trajectory, &machine, None, &caption);
        usvg::Tree::from_str(&svg, &usvg::Options::default()).unwrap();
        let title = group(&svg, "title");
        assert!(title.contains("t.svg") && !title.contains("jobs/") && title.contains("planner hha") && title.contains("on-the-fly") && title.contains("4 min 23 s"), "{title}");
        // The legend names each kind of line drawn.
        let legend = group(&svg, "legend");
        for said in ["job geometry", "laser on", "laser off", "usable scan field", "stage path"] {
            assert!(legend.contains(said), "the legend says {said}: {legend}");
        }
        assert!(!legend.contains("pierces") && !legend.contains("lead-ins"), "nothing undrawn is named: {legend}");
        // Axes: ticks with numbers in mm, 60 px or more apart.
        let axes = group(&svg, "axes");
        assert!(axes.contains("x (mm)") && axes.contains("y (mm)"));
        let ticks: Vec<f64> = axes.split(r#"class="tick" x1=""#).skip(1).map(|t| t.split('"').next().unwrap().parse().unwrap()).collect();
        let xs: Vec<f64> = ticks.iter().copied().filter(|&x| x > FRAME_LEFT).collect();
        assert!(xs.len() >= 3, "{ticks:?}");
        assert!(xs.windows(2).all(|w| w[1] - w[0] >= 60.0 - 1e-6), "{xs:?}");
        let scale = numbers(&svg, "data-mm-to-px")[2];
        let labels: Vec<f64> = axes.split(r#"text-anchor="middle">"#).skip(1).filter_map(|t| t.split('<').next().unwrap().parse().ok()).collect();
        assert!(((labels[1] - labels[0]) * scale - (xs[1] - xs[0])).abs() < 0.01, "the numbers are mm at the picture's scale: {labels:?}");
        // The scale bar is as long as its number says.
        let bar = group(&svg, "scale-bar");
        let mm: f64 = bar.split(r#"font-size="13">"#).nth(1).unwrap().split(" mm").next().unwrap().parse().unwrap();
        assert!((numbers(bar, "width")[0] - mm * scale).abs() < 0.01, "{bar}");
        // The field-use chart has its ticks: 0 to 1 in use, seconds in time.
        let chart = group(&svg, "field-use");
        assert!(chart.matches(r#"class="tick""#).count() >= 5 + 3 && chart.contains(">1</text>") && chart.contains(" s</text>"), "{chart}");
    }

    #[test]
    fn without_a_scanner_there_is_no_empty_chart_and_names_are_escaped() {
        let mut machine = MachineConfig::load(None).unwrap();
        machine.scanner = None;
        let (job, sequence, trajectory) = planned(&machine, FOUR_SQUARES, "<b>&'x\".svg", Mode::StageOnly);
        let svg = plot(&job, &sequence, &trajectory, &machine, None);
        usvg::Tree::from_str(&svg, &usvg::Options::default()).unwrap();
        assert!(!svg.contains(r#"id="field-use""#) && svg.contains("no scanner: no field-use chart"));
        assert!(svg.contains("&lt;b&gt;&amp;&apos;x&quot;.svg") && !svg.contains("<b>"));
        assert!(!group(&svg, "legend").contains("scan field"));
        assert_eq!(escape("a<b>&\"c'"), "a&lt;b&gt;&amp;&quot;c&apos;");
    }

    #[test]
    fn ticks_fall_on_round_numbers() {
        assert_eq!(nice_step(7.0, 1.0), 10.0);
        assert_eq!(nice_step(0.3, 1.0), 0.5);
        assert_eq!(nice_step(180.0, 1.0), 200.0);
        assert_eq!(tick_label(0.5, 0.5), "0.5");
        assert_eq!(tick_label(-1e-12, 10.0), "0");
        assert_eq!(time_step(263.0, 8.0), 60.0);
        assert_eq!(time_label(120.0, 60.0), "2 min");
        assert_eq!(time_label(0.25, 0.05), "0.25 s");
    }
}
