//! G-code as a job: the laser moves of another CAM tool's program (LightBurn,
//! LaserGRBL, Inkscape plug-ins) become geometries, so the file can be
//! re-planned, previewed, estimated and dry-run like a drawing.
//!
//! Lines are cleaned and split into words by the simulator's own Grbl rules
//! (`laserd_sim::gcode`). Read: G0 G1 G2 G3 (I J, or R), G17, G20 G21, G90
//! G91, G92 (offsets), G4 and G94 (ignored), M3 M4 M5 and S, F, M2 M30, and
//! the line numbers N. Each laser-on run (M3 or M4 with S > 0, cutting moves
//! from one laser-off move, M3/M4/M5 or S0 to the next) is one geometry; where
//! its power or feed changes along it (a raster line), its segments keep
//! theirs as the geometry's profile. Processes are the (S, F) pairs: speed
//! F/60 mm/s, power S.
//! Anything else is an error naming the line: laserd does not guess what a
//! word it does not know was meant to do to the laser.

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use super::{Trace, MAX_COORD_MM};
use crate::job::{Geometry, Job, Point, Process};

/// Grbl's error 33 case: an arc whose end is not on its circle, by more
/// than this (mm) and this share of the radius.
const ARC_END_MM: f64 = 0.005;
const ARC_END_SHARE: f64 = 0.001;

/// Most different (S, F) pairs a file may use (each is a process): a raster
/// of 8-bit grey at a few feeds uses hundreds.
const MAX_PROCESSES: usize = 65_536;

/// Extensions of G-code files, as CAM tools and senders write them.
pub const GCODE_EXTENSIONS: [&str; 6] = ["nc", "gcode", "ngc", "gc", "g", "tap"];

struct State {
    at: Point,
    /// G92: the work origin's offset from the machine position.
    offset: Point,
    inch: bool,
    relative: bool,
    motion: u8,
    feed: f64,
    power: f64,
    laser_on: bool,
}

/// A laser-on run: its segments tagged with their (S, F) pair's index in
/// the pairs met so far.
struct Run {
    trace: Trace,
    line: usize,
}

/// Reads the G-code `text` (`source` names it in messages).
pub fn import_gcode(text: &str, source: &str, config: &MachineConfig) -> Result<Job> {
    let mut s = State { at: Point::origin(), offset: Point::origin(), inch: false, relative: false, motion: 0, feed: 0.0, power: 0.0, laser_on: false };
    let mut runs: Vec<Run> = Vec::new();
    let mut current: Option<Run> = None;
    let mut points = 0u64;
    // The (S, F) pairs met, in order, and each one's index.
    let mut keys: Vec<(u64, u64)> = Vec::new();
    let mut key_index: std::collections::HashMap<(u64, u64), usize> = std::collections::HashMap::new();
    let tolerance = config.import.tolerance;
    let finish = |current: &mut Option<Run>, runs: &mut Vec<Run>| {
        if let Some(r) = current.take() {
            if r.trace.points.len() >= 2 {
                runs.push(r);
            }
        }
    };
    for (index, raw) in text.lines().enumerate() {
        let n = index + 1;
        let at = |what: String| Error::Import(format!("{source}:{n}: {what}: {}", raw.trim().chars().take(80).collect::<String>()));
        let mut builder = laserd_sim::gcode::LineBuilder::with_max(laserd_sim::gcode::MAX_LINE_HAL);
        raw.bytes().for_each(|b| builder.push(b));
        let Some(line) = builder.finish() else { return Err(at("a line longer than 256 characters".into())) };
        if line.is_empty() || line.starts_with('%') {
            continue;
        }
        if line.starts_with('$') {
            return Err(at("a system command ($) is no job line".into()));
        }
        let words = laserd_sim::gcode::split_words(&line).map_err(|code| at(format!("not G-code words (Grbl error {code})")))?;
        let mut target: [Option<f64>; 2] = [None, None];
        let (mut i, mut j, mut r) = (None, None, None);
        let mut g92 = false;
        let mut laser_changed = false;
        for w in &words {
            let v = w.value;
            match w.letter {
                'G' => match (v * 10.0).round() as i64 {
                    0 => s.motion = 0,
                    10 => s.motion = 1,
                    20 => s.motion = 2,
                    30 => s.motion = 3,
                    // Dwell (its P is ignored), feed per minute, XY plane, cutter
                    // compensation off, the first work system: nothing to trace.
                    40 | 940 | 170 | 400 | 540 => {}
                    200 => s.inch = true,
                    210 => s.inch = false,
                    900 => s.relative = false,
                    910 => s.relative = true,
                    920 => g92 = true,
                    other => return Err(at(format!("G{} is not a laser job move laserd reads", other as f64 / 10.0))),
                },
                'M' => match v as i64 {
                    3 | 4 => {
                        laser_changed |= !s.laser_on;
                        s.laser_on = true;
                    }
                    5 => {
                        laser_changed |= s.laser_on;
                        s.laser_on = false;
                    }
                    2 | 30 | 7 | 8 | 9 => {}
                    other => return Err(at(format!("M{other} is not a laser job word laserd reads"))),
                },
                // A new power goes on in the same run (a raster line's profile).
                'S' => s.power = v,
                'F' => s.feed = v,
                'X' => target[0] = Some(v),
                'Y' => target[1] = Some(v),
                'I' => i = Some(v),
                'J' => j = Some(v),
                'R' => r = Some(v),
                'N' | 'P' => {}
                // Z (focus height) and K (the arc centre's Z) move nothing in the plane.
                'Z' | 'K' => {}
                'A' | 'B' | 'C' | 'U' | 'V' | 'W' => return Err(at(format!("axis {} is not one of a laser's X and Y", w.letter))),
                other => return Err(at(format!("word {other} is not one laserd reads in a job"))),
            }
        }
        let scale = if s.inch { 25.4 } else { 1.0 };
        if g92 {
            // G92 X Y: the current position is now these work coordinates.
            let work = |k: usize, m: f64, o: f64| target[k].map_or(m - o, |v| v * scale);
            let (wx, wy) = (work(0, s.at.x, s.offset.x), work(1, s.at.y, s.offset.y));
            s.offset = Point::new(s.at.x - wx, s.at.y - wy);
            continue;
        }
        let on = s.laser_on && s.power > 0.0;
        if laser_changed || !on {
            finish(&mut current, &mut runs);
        }
        if target.iter().all(Option::is_none) && !(s.motion >= 2 && (i.is_some() || j.is_some())) {
            continue;
        }
        let axis = |k: usize, now: f64, origin: f64| match target[k] {
            Some(v) if s.relative => now + v * scale,
            Some(v) => v * scale + origin,
            None => now,
        };
        let end = Point::new(axis(0, s.at.x, s.offset.x), axis(1, s.at.y, s.offset.y));
        if !(end.x.is_finite() && end.y.is_finite()) || end.x.abs() > MAX_COORD_MM || end.y.abs() > MAX_COORD_MM {
            return Err(at(format!("beyond {MAX_COORD_MM} mm")));
        }
        let cutting = on && s.motion != 0;
        let mut path = Trace::of(vec![s.at, end]);
        if s.motion >= 2 {
            path = arc(s.at, end, s.motion == 2, i.map(|v| v * scale), j.map(|v| v * scale), r.map(|v| v * scale), tolerance).map_err(at)?;
        }
        if cutting {
            if s.feed <= 0.0 {
                return Err(at("a cutting move with no feed (F)".into()));
            }
            let key = (s.power.to_bits(), s.feed.to_bits());
            let tag = match key_index.get(&key) {
                Some(&tag) => tag,
                None if keys.len() >= MAX_PROCESSES => {
                    return Err(Error::TooLarge(format!("{source}:{n}: more than {MAX_PROCESSES} different (S, F) pairs, each a process")));
                }
                None => {
                    keys.push(key);
                    key_index.insert(key, keys.len() - 1);
                    keys.len() - 1
                }
            };
            let path = path.tagged(tag);
            let run = current.get_or_insert_with(|| Run { trace: Trace::of(vec![s.at]), line: n });
            points += path.points.len() as u64 - 1;
            if points > config.import.max_points {
                return Err(Error::TooLarge(format!("{source}: more than {} points ([import] max_points)", config.import.max_points)));
            }
            run.trace.append(path);
        } else {
            finish(&mut current, &mut runs);
        }
        s.at = end;
    }
    finish(&mut current, &mut runs);
    if runs.is_empty() {
        return Err(Error::Import(format!("{source}: nothing to mark: no cutting move with the laser on (M3 or M4 with S > 0)")));
    }
    if runs.len() as u64 > config.import.max_elements {
        return Err(Error::TooLarge(format!("{source}: more than {} laser runs ([import] max_elements)", config.import.max_elements)));
    }
    // Processes: the (S, F) pairs that mark, in the order they first do.
    let mut geometries = Vec::with_capacity(runs.len());
    let mut used: Vec<Option<usize>> = vec![None; keys.len()];
    let mut marking: Vec<(u64, u64)> = Vec::new();
    for run in runs {
        let Some((trace, closed)) = super::clean_polyline(run.trace, false) else { continue };
        let mut profile: Vec<usize> = trace
            .tags
            .iter()
            .map(|&t| {
                *used[t].get_or_insert_with(|| {
                    marking.push(keys[t]);
                    marking.len() - 1
                })
            })
            .collect();
        let Some(&process) = profile.first() else { continue };
        if profile.iter().all(|&p| p == process) {
            profile.clear();
        }
        geometries.push(Geometry { points: trace.points, arcs: trace.arcs, profile, closed, process, source: format!("{source}:{}", run.line) });
    }
    let processes = marking
        .iter()
        .map(|&(s, f)| {
            let (s, f) = (f64::from_bits(s), f64::from_bits(f));
            Process { layer: format!("S{s} F{f}"), speed: f / 60.0, power: s, passes: 1, fill: false }
        })
        .collect();
    Ok(Job { source: source.to_string(), geometries, processes })
}

/// The arc from `from` to `to` (clockwise for G2), its centre at offset
/// (I, J) from `from` or from radius R (negative: the long way), flattened
/// within `tolerance` and kept as arcs of at most a half circle.
fn arc(from: Point, to: Point, clockwise: bool, i: Option<f64>, j: Option<f64>, r: Option<f64>, tolerance: f64) -> std::result::Result<Trace, String> {
    let centre = match (i, j, r) {
        (_, _, Some(r)) => {
            let d = to - from;
            let h2 = r * r - d.norm_squared() / 4.0;
            if d.norm() == 0.0 || h2 < -1e-9 {
                return Err(format!("an R arc (R{r}) that cannot reach its end (Grbl error 33)"));
            }
            // The centre left of the chord for a counter-clockwise short arc.
            let h = h2.max(0.0).sqrt() * if clockwise == (r < 0.0) { 1.0 } else { -1.0 };
            let mid = from + d / 2.0;
            mid + nalgebra::Vector2::new(-d.y, d.x) / d.norm() * h
        }
        (None, None, None) => return Err("an arc with neither I/J nor R".into()),
        (i, j, None) => from + nalgebra::Vector2::new(i.unwrap_or(0.0), j.unwrap_or(0.0)),
    };
    let (r0, r1) = ((from - centre).norm(), (to - centre).norm());
    if (r0 - r1).abs() > ARC_END_MM && (r0 - r1).abs() > ARC_END_SHARE * r0 {
        return Err(format!("an arc whose end is {:.4} mm off its circle (Grbl error 33)", (r0 - r1).abs()));
    }
    let a0 = (from.y - centre.y).atan2(from.x - centre.x);
    let a1 = (to.y - centre.y).atan2(to.x - centre.x);
    let tau = std::f64::consts::TAU;
    let mut sweep = if clockwise { -(a0 - a1).rem_euclid(tau) } else { (a1 - a0).rem_euclid(tau) };
    if sweep.abs() < 1e-12 {
        sweep = if clockwise { -tau } else { tau };
    }
    let pieces = (sweep.abs() / std::f64::consts::PI - 1e-9).ceil().max(1.0) as usize;
    let n = (super::arc_segments(r0, sweep, tolerance).min(1e6) as usize).div_ceil(pieces) * pieces;
    let at = |k: usize| if k == n { to } else { centre + nalgebra::Vector2::new((a0 + sweep * k as f64 / n as f64).cos(), (a0 + sweep * k as f64 / n as f64).sin()) * r0 };
    let mut out = Trace::of(vec![from]);
    let (per, bulge) = (n / pieces, (sweep / pieces as f64 / 4.0).tan());
    for piece in 0..pieces {
        out.arc_to((piece * per + 1..=(piece + 1) * per).map(at), bulge);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn import(text: &str) -> Result<Job> {
        import_gcode(text, "t.nc", &crate::import::test_config())
    }

    #[test]
    fn laser_on_runs_become_geometries_with_their_power_and_feed() {
        let job = import("G21 G90\nG0 X10 Y10\nM4 S500 F600\nG1 X20\nG1 Y20\nG2 X10 Y10 I-5 J-5\nM5\nG0 X50 Y50\nM3 S1000\nG1 X60 F1200\nG1 Y60\nM5\n").unwrap();
        assert_eq!(job.geometries.len(), 2);
        assert_eq!(job.processes.len(), 2);
        assert_eq!((job.processes[0].speed, job.processes[0].power), (10.0, 500.0));
        assert_eq!((job.processes[1].speed, job.processes[1].power), (20.0, 1000.0));
        let first = &job.geometries[0];
        assert!(first.closed, "the run ends where it began");
        // Two sides of 10 and a half circle of radius √50 back to the start.
        let expected = 20.0 + std::f64::consts::PI * 50f64.sqrt();
        assert!((first.length() - expected).abs() < 1e-9, "the arc is kept exact: {} vs {expected}", first.length());
        assert_eq!(first.source, "t.nc:4");
    }

    #[test]
    fn g2_and_g3_stay_arcs_of_at_most_a_half_circle_with_exact_length_and_bounds() {
        let job = import("M4 S10 F100\nG0 X10 Y0\nG2 X10 Y0 I-5 J0\nM5\nG0 X20 Y0\nM3\nG3 X30 Y10 R10\nM5\n").unwrap();
        let (circle, quarter) = (&job.geometries[0], &job.geometries[1]);
        assert!(circle.closed && circle.arcs.len() == 2 && circle.arcs.iter().all(|a| (a.bulge + 1.0).abs() < 1e-15), "{:?}", circle.arcs);
        assert!((circle.length() - std::f64::consts::TAU * 5.0).abs() < 1e-9, "{}", circle.length());
        let (lo, hi) = circle.bounds();
        assert!((lo - Point::new(0.0, -5.0)).norm() < 1e-9 && (hi - Point::new(10.0, 5.0)).norm() < 1e-9, "{lo:?} {hi:?}");
        assert!(circle.arc_error(0.01).is_none(), "{:?}", circle.arc_error(0.01));
        assert_eq!(quarter.arcs.len(), 1);
        assert!((quarter.arcs[0].bulge - (std::f64::consts::FRAC_PI_8).tan()).abs() < 1e-12);
        assert!((quarter.length() - std::f64::consts::FRAC_PI_2 * 10.0).abs() < 1e-9, "{}", quarter.length());
    }

    #[test]
    fn inches_relative_moves_and_g92_offsets_are_followed() {
        let job = import("G20 G91\nG0 X1 Y1\nG92 X0 Y0\nM4 S100 F60\nG1 X1\nG90 G1 Y1\nM5\n").unwrap();
        let p = &job.geometries[0].points;
        assert!((p[0] - Point::new(25.4, 25.4)).norm() < 1e-9 && (p[1] - Point::new(50.8, 25.4)).norm() < 1e-9 && (p[2] - Point::new(50.8, 50.8)).norm() < 1e-9, "{p:?}");
    }

    #[test]
    fn a_raster_line_whose_power_changes_is_one_geometry_with_its_power_profile() {
        // Two scan lines as raster engravers write them: S per pixel, an S0
        // gap and a laser-off move between the lines.
        let job = import("G0 X0 Y0\nM4 F3000\nG1 X1 S100\nG1 X2 S200\nG1 X3 S200\nG1 X4 S100\nG1 X5 S0\nG1 X6 S300\nG0 X6 Y1\nG1 X0 S200\nM5\n").unwrap();
        assert_eq!(job.geometries.len(), 3, "the S0 gap and the laser-off move end a run");
        let power = |g: &Geometry| -> Vec<f64> {
            if g.profile.is_empty() { vec![job.processes[g.process].power] } else { g.profile.iter().map(|&p| job.processes[p].power).collect() }
        };
        assert_eq!(power(&job.geometries[0]), vec![100.0, 200.0, 200.0, 100.0]);
        assert_eq!(job.geometries[0].points.len(), 5);
        assert_eq!(job.processes[job.geometries[0].process].power, 100.0);
        assert_eq!((power(&job.geometries[1]), power(&job.geometries[2])), (vec![300.0], vec![200.0]));
        assert!(job.geometries[1].profile.is_empty() && job.geometries[2].profile.is_empty(), "one power: no profile");
        // The processes: the (S, F) pairs that mark, in the order they first do.
        assert_eq!(job.processes.iter().map(|p| p.power).collect::<Vec<_>>(), vec![100.0, 200.0, 300.0]);
        assert!((job.mark_length() - 11.0).abs() < 1e-9);
    }

    #[test]
    fn unknown_words_and_arcs_off_their_circle_name_the_line() {
        let err = |t: &str| import(t).unwrap_err().to_string();
        assert!(err("M4 S10 F100\nG1 X1\nG38.2 X5\n").contains("t.nc:3: G38.2"));
        assert!(err("M4 S10 F100\nG1 X1 Q4\n").contains("t.nc:2: word Q"));
        assert!(err("M4 S10 F100\nG2 X10 Y0 I3 J0\n").contains("t.nc:2: an arc whose end is") );
        assert!(err("M4 S10 F100\nG2 X10 Y0 R2\n").contains("Grbl error 33"));
        assert!(err("$H\n").contains("t.nc:1: a system command"));
        assert!(err("G0 X1\n").contains("nothing to mark"));
        assert!(err("M4 S10\nG1 X1\n").contains("no feed"));
        // Every power its own process: bounded, naming the line.
        let many: String = std::iter::once("M4 F600\n".to_string()).chain((1..=MAX_PROCESSES + 1).map(|k| format!("G1 X{} S{k}\n", k % 7))).collect();
        assert!(err(&many).contains(&format!("t.nc:{}: more than {MAX_PROCESSES} different (S, F) pairs", MAX_PROCESSES + 2)), "{}", err(&many));
    }
}
