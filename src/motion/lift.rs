//! Lift moves (seed 000, collision avoidance): a piece cut free that may tip
//! (`plan::tipping`) stands up out of the sheet, so an air move that would
//! pass over it lifts the head to `[head] lift_height` (h_max) on the way.
//!
//! The XY move stays as planned; the head's Z runs beside it, up from rest
//! and down to rest, so that it is at h_max wherever the nozzle is within
//! `[head] clearance` of such a piece. Where the move reaches that zone
//! before Z can be up (the piece is near its start), the XY move waits at
//! its start for the rest of the lift; where it leaves the zone too late for
//! Z to be down on arrival, it waits at its end: the seed's normal air move
//! when the distance allows, a slower one otherwise.
//!
//! A piece the head stands over when it falls (a hole's lead-out ends in
//! its slug) is left at cutting height: the head is over it already.

use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};

use super::leg::Leg;
use super::tcp::{Motion, Piece, PieceKind, TcpPath};
use crate::config::Limits;
use crate::error::Result;
use crate::job::{bounds_of, segment_crossing, Point};
use crate::topology::{side, Side};

/// Air moves are checked at points this far apart at most (mm).
const SAMPLE_MM: f64 = 0.05;

/// One move of the head's Z axis, from rest to rest.
#[derive(Debug, Clone)]
pub struct ZMove {
    pub start: f64,
    pub from: f64,
    pub to: f64,
    pub leg: Leg,
}

impl ZMove {
    fn z(&self, t: f64) -> f64 {
        let s = self.leg.position(t - self.start);
        self.from + (self.to - self.from).signum() * s
    }

    pub fn end_time(&self) -> f64 {
        self.start + self.leg.duration
    }
}

/// The head's Z over the job: at 0 (cutting height) but during its moves.
#[derive(Debug, Clone, Default)]
pub struct HeadPath {
    /// In time order, none overlapping.
    pub moves: Vec<ZMove>,
}

impl HeadPath {
    pub fn z_at(&self, t: f64) -> f64 {
        let k = self.moves.partition_point(|m| m.start <= t);
        match k.checked_sub(1).map(|i| &self.moves[i]) {
            None => 0.0,
            Some(m) if t >= m.end_time() => m.to,
            Some(m) => m.z(t),
        }
    }

    /// The moves that overlap `a..=b`.
    pub fn moves_in(&self, a: f64, b: f64) -> &[ZMove] {
        let first = self.moves.partition_point(|m| m.end_time() < a);
        let last = first + self.moves[first..].partition_point(|m| m.start <= b);
        &self.moves[first..last]
    }

    /// Times in `a..=b` where Z's motion changes character.
    pub fn breakpoints(&self, a: f64, b: f64, out: &mut Vec<f64>) {
        for m in self.moves_in(a, b) {
            let mut inner = Vec::new();
            m.leg.breakpoints(&mut inner);
            out.extend([m.start, m.end_time()].into_iter().chain(inner.into_iter().map(|x| m.start + x)).filter(|&t| t >= a && t <= b));
        }
    }

    /// Lifts (moves up) in it.
    pub fn lifts(&self) -> usize {
        self.moves.iter().filter(|m| m.to > m.from).count()
    }
}

/// What lifting takes.
#[derive(Debug, Clone, Copy)]
pub struct LiftSettings {
    pub height: f64,
    pub limits: Limits,
    /// How far around a piece the head is up: `[head] clearance` beyond
    /// the program's jump tolerance (an air move's blocks may stray that far
    /// from its plan).
    pub clearance: f64,
}

/// A piece that may tip: its outline, and when it fell.
pub struct Fallen<'a> {
    pub outline: &'a [Point],
    pub at: f64,
}

/// Where an air move (a piece of the TCP path) needs the head up: from `up`
/// to `down` seconds into it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub piece: usize,
    pub up: f64,
    pub down: f64,
}

/// The windows of the path's laser-off moves over fallen pieces.
pub fn windows(path: &TcpPath, fallen: &[Fallen], settings: &LiftSettings, max_speed: f64) -> Vec<Window> {
    if fallen.is_empty() {
        return Vec::new();
    }
    let c = settings.clearance;
    let boxes: RTree<GeomWithData<Rectangle<[f64; 2]>, usize>> = RTree::bulk_load(
        fallen
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let (lo, hi) = bounds_of(f.outline.iter());
                GeomWithData::new(Rectangle::from_corners([lo.x - c, lo.y - c], [hi.x + c, hi.y + c]), i)
            })
            .collect(),
    );
    let mut out = Vec::new();
    for (k, piece) in path.pieces.iter().enumerate() {
        if !matches!(piece.kind, PieceKind::Jump) || matches!(piece.motion, Motion::Still(_)) || piece.duration <= 0.0 {
            continue;
        }
        let (lo, hi) = piece.bounds();
        let near: Vec<usize> = boxes.locate_in_envelope_intersecting(AABB::from_corners([lo.x, lo.y], [hi.x, hi.y])).map(|b| b.data).filter(|&i| fallen[i].at <= piece.start + 1e-12).collect();
        if near.is_empty() {
            continue;
        }
        let n = ((piece.duration * max_speed / SAMPLE_MM).ceil() as usize).max(8);
        let times: Vec<f64> = (0..=n).map(|i| piece.duration * i as f64 / n as f64).collect();
        let points: Vec<Point> = times.iter().map(|&t| piece.position(t)).collect();
        let (mut up, mut down) = (f64::INFINITY, f64::NEG_INFINITY);
        for &i in &near {
            if let Some((a, b)) = over(fallen[i].outline, &points, c) {
                up = up.min(times[a]);
                down = down.max(times[b]);
            }
        }
        if up <= down {
            out.push(Window { piece: k, up, down });
        }
    }
    out
}

/// The samples `(first, last)` between which the head must be up for
/// `outline`: around every stretch of the move that enters the piece, as far
/// as the move stays within `clearance` of it. A piece the move starts over
/// counts only once the move has left it.
fn over(outline: &[Point], points: &[Point], clearance: f64) -> Option<(usize, usize)> {
    let inside = |p: Point| side(p, outline, 0.0) == Side::Inside;
    let distance = |p: Point| {
        let n = outline.len();
        (0..n).map(|i| crate::job::segment_distance(p, p, outline[i], outline[(i + 1) % n])).fold(f64::INFINITY, f64::min)
    };
    let crosses = |a: Point, b: Point| {
        let n = outline.len();
        (0..n).any(|i| segment_crossing(a, b, outline[i], outline[(i + 1) % n]).is_some())
    };
    // Over it from the start: not yet.
    let armed = if inside(points[0]) { points.iter().position(|&p| !inside(p))? } else { 0 };
    let enters = |i: usize| i > armed && (inside(points[i]) || crosses(points[i - 1], points[i]));
    let near = |i: usize| inside(points[i]) || distance(points[i]) <= clearance;
    let (mut first, mut last) = (None, None);
    let mut i = armed + 1;
    while i < points.len() {
        if !enters(i) {
            i += 1;
            continue;
        }
        // The stretch within the clearance around this entry.
        let mut a = i - 1;
        while a > 0 && near(a) {
            a -= 1;
        }
        let mut b = i;
        while b + 1 < points.len() && near(b + 1) {
            b += 1;
        }
        b = (b + 1).min(points.len() - 1);
        first = Some(first.map_or(a, |f: usize| f.min(a)));
        last = Some(b);
        i = b + 1;
    }
    first.zip(last)
}

/// Where an air move must come to rest for its lift: it has to wait at an
/// end that it passes at speed. Empty: `apply` can place every lift.
pub fn rest_needed(path: &TcpPath, windows: &[Window], settings: &LiftSettings) -> Result<Vec<Point>> {
    let t_lift = lift_leg(settings)?.duration;
    let mut out = Vec::new();
    for w in windows {
        let p = &path.pieces[w.piece];
        if w.up < t_lift && p.motion.velocity(0.0).norm() > 1e-9 {
            out.push(p.start_point());
        }
        if w.down + t_lift > p.duration && p.motion.velocity(p.duration).norm() > 1e-9 {
            out.push(p.end_point());
        }
    }
    Ok(out)
}

fn lift_leg(settings: &LiftSettings) -> Result<Leg> {
    Leg::new(settings.height, settings.limits, true, true)
}

/// The path with each window's lift placed (waits added where Z needs them,
/// everything after shifted), and the head's Z. The windows' moves must be
/// at rest where they wait (`rest_needed` empty).
pub fn apply(path: TcpPath, windows: &[Window], settings: &LiftSettings) -> Result<(TcpPath, HeadPath)> {
    let leg = lift_leg(settings)?;
    let t = leg.duration;
    let mut pieces = Vec::with_capacity(path.pieces.len() + 2 * windows.len());
    let mut head = HeadPath::default();
    let mut shift = 0.0;
    let mut next = windows.iter().peekable();
    for (k, mut piece) in path.pieces.into_iter().enumerate() {
        piece.start += shift;
        let Some(w) = next.next_if(|w| w.piece == k) else {
            pieces.push(piece);
            continue;
        };
        let wait_before = (t - w.up).max(0.0);
        let wait_after = (w.down + t - piece.duration).max(0.0);
        let (from, to) = (piece.start_point(), piece.end_point());
        let still = |at: Point, start: f64, duration: f64| Piece { kind: PieceKind::Jump, group: piece.group, start, duration, motion: Motion::Still(at) };
        if wait_before > 0.0 {
            pieces.push(still(from, piece.start, wait_before));
        }
        let moving_from = piece.start + wait_before;
        head.moves.push(ZMove { start: moving_from + w.up - t, from: 0.0, to: settings.height, leg });
        head.moves.push(ZMove { start: moving_from + w.down, from: settings.height, to: 0.0, leg });
        let end = moving_from + piece.duration;
        let group = piece.group;
        piece.start = moving_from;
        pieces.push(piece);
        if wait_after > 0.0 {
            pieces.push(Piece { kind: PieceKind::Jump, group, start: end, duration: wait_after, motion: Motion::Still(to) });
        }
        shift += wait_before + wait_after;
    }
    Ok((TcpPath::new(pieces), head))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> LiftSettings {
        LiftSettings { height: 5.0, limits: Limits { velocity: 100.0, acceleration: 2000.0, jerk: 1e5 }, clearance: 1.0 }
    }

    fn square(x: f64, y: f64, size: f64) -> Vec<Point> {
        vec![Point::new(x, y), Point::new(x + size, y), Point::new(x + size, y + size), Point::new(x, y + size)]
    }

    fn jump(from: Point, to: Point, start: f64) -> Piece {
        let d = to - from;
        let leg = Leg::new(d.norm(), Limits { velocity: 500.0, acceleration: 5000.0, jerk: 2.5e5 }, true, true).unwrap();
        Piece { kind: PieceKind::Jump, group: 0, start, duration: leg.duration, motion: Motion::Leg { from, dir: d / d.norm(), leg } }
    }

    /// A long move over a fallen square lifts without waiting; one that
    /// meets the square at once waits at its start; one that only leaves a
    /// square's side, or passes by it, stays down; Z is up all the way over.
    #[test]
    fn the_head_is_up_wherever_the_move_passes_over_a_fallen_piece() {
        let s = settings();
        let piece = square(100.0, -5.0, 10.0);
        let fallen = [Fallen { outline: &piece, at: 0.0 }];
        let long = jump(Point::new(0.0, 0.0), Point::new(200.0, 0.0), 0.0);
        let at_once = jump(Point::new(100.0, 6.0), Point::new(100.0, 50.0), long.end_time());
        let start = at_once.end_time();
        let away = jump(Point::new(110.0, 0.0), Point::new(150.0, 0.0), start);
        let by = jump(Point::new(150.0, 20.0), Point::new(50.0, 20.0), away.end_time());
        let path = TcpPath::new(vec![long, at_once, away, by]);
        let w = windows(&path, &fallen, &s, 500.0);
        assert_eq!(w.iter().map(|w| w.piece).collect::<Vec<_>>(), vec![0], "{w:?}");
        let t_lift = lift_leg(&s).unwrap().duration;
        assert!(w[0].up > t_lift, "far enough to lift on the way: {w:?}");
        assert!(rest_needed(&path, &w, &s).unwrap().is_empty());
        let before = path.duration();
        let (lifted, head) = apply(path, &w, &s).unwrap();
        assert_eq!(head.lifts(), 1);
        assert!((lifted.duration() - before).abs() < 1e-12, "no time added");
        for k in 0..=2000 {
            let t = lifted.pieces[0].duration * k as f64 / 2000.0;
            let p = lifted.pieces[0].position(t);
            let x_near = p.x > 100.0 - s.clearance && p.x < 110.0 + s.clearance;
            if x_near {
                assert!((head.z_at(t) - s.height).abs() < 1e-9, "down over the piece at t={t}, {p:?}: z={}", head.z_at(t));
            }
        }
        // Meeting the piece at once (from its edge, across it): a wait at the start.
        let across = jump(Point::new(100.0, -5.0), Point::new(115.0, 10.0), 0.0);
        let path = TcpPath::new(vec![across]);
        let w = windows(&path, &fallen, &s, 500.0);
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].up, 0.0);
        let (lifted, head) = apply(path, &w, &s).unwrap();
        assert!(matches!(lifted.pieces[0].motion, Motion::Still(_)) && (lifted.pieces[0].duration - t_lift).abs() < 1e-12);
        assert!((head.z_at(t_lift) - s.height).abs() < 1e-9);
        // Starting over it (a lead-out ended in a slug): leaving is fine.
        let leaving = jump(Point::new(105.0, 0.0), Point::new(150.0, 0.0), 0.0);
        assert!(windows(&TcpPath::new(vec![leaving]), &fallen, &s, 500.0).is_empty());
        // Not yet fallen: nothing.
        let later = [Fallen { outline: &piece, at: 1e9 }];
        assert!(windows(&TcpPath::new(vec![jump(Point::new(0.0, 0.0), Point::new(200.0, 0.0), 0.0)]), &later, &s, 500.0).is_empty());
    }
}
