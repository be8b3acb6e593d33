//! The stage in time, and the on-the-fly split of the TCP between stage and
//! scanner.
//!
//! The split works per axis on the scan fields of the plan. While the TCP
//! marks a field, the stage may stand anywhere in the range that keeps all of
//! the field's marks (with the laser-off moves between them) inside the
//! usable field: `[max − h, min + h]`. It stands still, so the program's
//! stage words do not change and no coordinate rounding becomes motion. From
//! one field to the next it moves lazily: to the nearest position of the next
//! field's range (a quarter of the range in from its edge, to leave room for
//! the move), in one jerk-limited rest-to-rest move per axis (a burst) timed
//! while the TCP keeps marking: the burst's start is searched around the
//! field change for the moment at which every TCP position during the move
//! stays within the scanner's reach of the moving stage. Where no such moment
//! exists the TCP is slowed there: it stops, the stage carries it to the next
//! field with the scanner holding (as in step-and-scan), and it goes on.

use super::leg::Leg;
use super::tcp::{Piece, PieceKind, TcpPath};
use crate::config::Limits;
use crate::error::{Error, Result};
use crate::job::Point;

/// One axis of the stage moving from `from` to `to` along `leg`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMove {
    pub start: f64,
    pub from: f64,
    pub to: f64,
    pub leg: Leg,
}

impl AxisMove {
    pub fn end_time(&self) -> f64 {
        self.start + self.leg.duration
    }

    pub fn position(&self, t: f64) -> f64 {
        if self.leg.length <= 0.0 {
            return self.to;
        }
        self.from + (self.to - self.from) * self.leg.position(t - self.start) / self.leg.length
    }
}

/// Where the stage is over time.
#[derive(Debug, Clone)]
pub enum StagePath {
    /// A machine without scanner (or stage-only mode): the stage is the TCP.
    FollowsTcp,
    /// Each axis's moves in time order (none overlapping on one axis).
    Moves { start: Point, axes: [Vec<AxisMove>; 2] },
    /// On the fly, planned over the whole job (`flow`): the approach's moves,
    /// then the flow.
    Flow { start: Point, approach: [Vec<AxisMove>; 2], flow: super::flow::Flow },
}

impl StagePath {
    pub fn position(&self, tcp: &TcpPath, t: f64) -> Point {
        match self {
            StagePath::FollowsTcp => tcp.position(t),
            StagePath::Moves { start, axes } => Point::new(axis_position(&axes[0], start.x, t), axis_position(&axes[1], start.y, t)),
            StagePath::Flow { start, approach, flow } => {
                if t < flow.moves_from {
                    Point::new(axis_position(&approach[0], start.x, t), axis_position(&approach[1], start.y, t))
                } else {
                    flow.position(t)
                }
            }
        }
    }

    /// End of the last stage move.
    pub fn end_time(&self) -> f64 {
        match self {
            StagePath::FollowsTcp => 0.0,
            StagePath::Moves { axes, .. } => axes.iter().flatten().map(AxisMove::end_time).fold(0.0, f64::max),
            StagePath::Flow { flow, .. } => flow.end_time(),
        }
    }

    pub fn shift(&mut self, dt: f64) {
        match self {
            StagePath::FollowsTcp => {}
            StagePath::Moves { axes, .. } => axes.iter_mut().flatten().for_each(|m| m.start += dt),
            StagePath::Flow { approach, flow, .. } => {
                approach.iter_mut().flatten().for_each(|m| m.start += dt);
                flow.shift(dt);
            }
        }
    }

    /// Whether the stage moves at time `t` (on either axis).
    pub fn moving(&self, t: f64) -> bool {
        match self {
            StagePath::FollowsTcp => true,
            StagePath::Moves { axes, .. } => axes_moving(axes, t),
            StagePath::Flow { approach, flow, .. } => axes_moving(approach, t) || flow.moving(t),
        }
    }
}

fn axes_moving(axes: &[Vec<AxisMove>; 2], t: f64) -> bool {
    axes.iter().any(|moves| {
        let k = moves.partition_point(|m| m.start <= t);
        k > 0 && moves[k - 1].end_time() > t
    })
}

fn axis_position(moves: &[AxisMove], start: f64, t: f64) -> f64 {
    let k = moves.partition_point(|m| m.start <= t);
    if k == 0 {
        start
    } else {
        moves[k - 1].position(t)
    }
}

/// The stage moves of a TCP piece that the stage carries (both axes along the
/// piece's leg).
pub fn carried_moves(piece: &Piece, axes: &mut [Vec<AxisMove>; 2], stage_from: Point) -> Point {
    let (from, to) = (piece.start_point(), piece.end_point());
    let d = to - from;
    let stage_to = stage_from + d;
    if let super::tcp::Motion::Leg { leg, .. } = &piece.motion {
        for (i, moves) in axes.iter_mut().enumerate() {
            if d[i].abs() > 1e-12 {
                moves.push(AxisMove { start: piece.start, from: stage_from[i], to: stage_to[i], leg: *leg });
            }
        }
    }
    stage_to
}

/// What the split needs to know about the machine.
#[derive(Debug, Clone, Copy)]
pub struct SplitSettings {
    /// Half the usable field.
    pub half: f64,
    pub travel: (f64, f64),
    /// Per-axis limits of a stage burst.
    pub burst: Limits,
}

/// A stretch of time and the TCP's bounding box over it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Window {
    pub t0: f64,
    pub t1: f64,
    pub lo: [f64; 2],
    pub hi: [f64; 2],
}

/// Windows no longer than this: the stage moves little within one.
const WINDOW: f64 = 1.0e-3;
/// Most windows of a job: a long, slow one (hours of marking at a tenth of a
/// mm/s) gets longer windows rather than gigabytes of them. Longer windows
/// bound the TCP more loosely, so they only ever make a burst harder to fit.
const MOST_WINDOWS: f64 = 1.0e6;

/// The windows' length for `tcp`: `WINDOW`, or longer on very long jobs.
pub(super) fn window_length(tcp: &TcpPath) -> f64 {
    (tcp.duration() / MOST_WINDOWS).max(WINDOW)
}

pub(super) fn windows(tcp: &TcpPath, length: f64) -> Vec<Window> {
    // Disjoint stretches between piece boundaries, cut to at most `length`;
    // the TCP is sampled inside each (blended corners and free moves bow).
    let mut times: Vec<f64> = tcp.pieces.iter().flat_map(|p| [p.start, p.end_time()]).collect();
    times.sort_by(f64::total_cmp);
    times.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    let mut out = Vec::new();
    for pair in times.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let parts = (((b - a) / length).ceil() as usize).max(1);
        // The piece running from `a` runs until `b`: searched for once.
        let k = tcp.index_at(a);
        let position = |t: f64| tcp.position_among(t, k, k);
        // (a part's end is the next one's start: sampled once)
        let mut start = position(a);
        for i in 0..parts {
            let t0 = a + (b - a) * i as f64 / parts as f64;
            let t1 = a + (b - a) * (i + 1) as f64 / parts as f64;
            let mut w = Window { t0, t1, lo: [f64::INFINITY; 2], hi: [f64::NEG_INFINITY; 2] };
            let (middle, end) = (position(t0 + (t1 - t0) / 2.0), position(t0 + (t1 - t0)));
            for p in [start, middle, end] {
                for a in 0..2 {
                    w.lo[a] = w.lo[a].min(p[a]);
                    w.hi[a] = w.hi[a].max(p[a]);
                }
            }
            start = end;
            out.push(w);
        }
    }
    out
}

/// Per group: the pieces that mark or move within it (not the laser-off
/// pieces leading into it from the group before).
fn group_spans(tcp: &TcpPath, groups: usize) -> Vec<Option<(usize, usize)>> {
    let mut spans: Vec<Option<(usize, usize)>> = vec![None; groups];
    for (k, p) in tcp.pieces.iter().enumerate() {
        if p.kind == PieceKind::Approach {
            continue;
        }
        let own = matches!(p.kind, PieceKind::Mark { .. } | PieceKind::Pierce { .. } | PieceKind::Cool { .. });
        let span = &mut spans[p.group];
        match span {
            None if own => *span = Some((k, k)),
            Some((_, last)) => *last = k,
            None => {}
        }
    }
    spans
}

/// The stage range per group and axis that keeps the group's pieces in the field.
fn group_ranges(tcp: &TcpPath, spans: &[Option<(usize, usize)>], s: &SplitSettings) -> Result<Vec<[(f64, f64); 2]>> {
    let travel = [s.travel.0, s.travel.1];
    spans
        .iter()
        .enumerate()
        .map(|(g, span)| {
            let mut lo = [f64::INFINITY; 2];
            let mut hi = [f64::NEG_INFINITY; 2];
            if let Some((a, b)) = span {
                for p in &tcp.pieces[*a..=*b] {
                    let (l, h) = p.bounds();
                    for i in 0..2 {
                        lo[i] = lo[i].min(l[i]);
                        hi[i] = hi[i].max(h[i]);
                    }
                }
            }
            let mut r = [(0.0, 0.0); 2];
            for i in 0..2 {
                if lo[i] > hi[i] {
                    r[i] = (0.0, travel[i]);
                    continue;
                }
                let (a, b) = ((hi[i] - s.half).max(0.0), (lo[i] + s.half).min(travel[i]));
                if a > b + 1e-9 {
                    return Err(Error::Motion(format!(
                        "scan field {}: its marks span {:.3} mm on {}, more than the usable field of {} mm (or they leave the travel)",
                        g + 1,
                        hi[i] - lo[i],
                        ['X', 'Y'][i],
                        2.0 * s.half
                    )));
                }
                r[i] = (a, b.max(a));
            }
            Ok(r)
        })
        .collect()
}

/// Stage position per group: the nearest to the previous one, a quarter of
/// the range in from the edge.
pub fn stage_positions(tcp: &TcpPath, groups: usize, start: Point, s: &SplitSettings) -> Result<Vec<Point>> {
    let spans = group_spans(tcp, groups);
    let ranges = group_ranges(tcp, &spans, s)?;
    let mut at = start;
    Ok(ranges
        .iter()
        .map(|r| {
            for i in 0..2 {
                let (a, b) = r[i];
                let q = 0.25 * (b - a);
                at[i] = at[i].clamp(a + q, b - q);
            }
            at
        })
        .collect())
}

/// The field changes (into these groups) that need the TCP carried.
#[derive(Debug)]
pub struct NoSplit(pub Vec<usize>);

/// The stage's moves for a TCP planned with stage positions `at` (one per
/// group): a burst per axis at each field change where possible; the carried
/// pieces of the TCP move the stage with them. `Err(NoSplit(groups))` names
/// the field changes (by the group they lead into) without a timing for a burst.
pub fn split(tcp: &TcpPath, at: &[Point], s: &SplitSettings) -> Result<std::result::Result<StagePath, NoSplit>> {
    let spans = group_spans(tcp, at.len());
    let window = window_length(tcp);
    let wins = windows(tcp, window);
    let start = at.first().copied().unwrap_or(Point::origin());
    let mut axes: [Vec<AxisMove>; 2] = [Vec::new(), Vec::new()];
    let mut stage = start;
    // Time range of each group's own pieces.
    let span_time = |g: usize| spans[g].map(|(a, b)| (tcp.pieces[a].start, tcp.pieces[b].end_time()));
    let pierces = dwell_times(tcp);
    let mut prev_group: Option<usize> = None;
    let mut failed = Vec::new();
    for (g, &target) in at.iter().enumerate() {
        let Some((g_start, g_end)) = span_time(g) else { continue };
        if let Some(k) = prev_group {
            // Pieces the stage carries into this group.
            let (k_start, k_end) = span_time(k).expect("a previous group has pieces");
            // The laser-off pieces between the two groups' own ones.
            let (after_k, g_first) = (spans[k].expect("a previous group has pieces").1 + 1, spans[g].expect("this group has pieces").0);
            let carried: Vec<&Piece> = tcp.pieces[after_k..g_first].iter().filter(|p| p.kind == PieceKind::Carried).collect();
            if !carried.is_empty() {
                for p in carried {
                    stage = carried_moves(p, &mut axes, stage);
                }
                if (stage - target).norm() > 1e-6 {
                    return Err(Error::Motion(format!("internal: carried stage ends at {stage:?}, not {target:?}")));
                }
                prev_group = Some(g);
                continue;
            }
            let next_end = spans.iter().skip(g + 1).flatten().next().map(|&(a, _)| tcp.pieces[a].start).unwrap_or(f64::INFINITY);
            let mut bursts = Vec::new();
            for i in 0..2 {
                let d = target[i] - stage[i];
                if d.abs() < 1e-9 {
                    continue;
                }
                let leg = Leg::new(d.abs(), s.burst, true, true)?;
                let earliest = axes[i].last().map_or(k_start, |m| m.end_time().max(k_start));
                // The burst ends before the next field begins.
                let latest = g_end.min(next_end) - leg.duration;
                match burst_start(&wins, &pierces, window, i, stage[i], target[i], &leg, earliest, latest, k_end, g_start, s.half) {
                    Some(t0) => bursts.push((i, AxisMove { start: t0, from: stage[i], to: target[i], leg })),
                    None => {
                        // Carried in the next plan; go on to find all such changes at once.
                        failed.push(g);
                        bursts.clear();
                        break;
                    }
                }
            }
            for (i, m) in bursts {
                axes[i].push(m);
            }
            stage = target;
        }
        prev_group = Some(g);
    }
    if !failed.is_empty() {
        return Ok(Err(NoSplit(failed)));
    }
    Ok(Ok(StagePath::Moves { start, axes }))
}

/// The time spans of `tcp`'s pierces and cooling waits. The program dwells
/// there (`G4`), which stops every axis: the stage must stand still through them.
pub(super) fn dwell_times(tcp: &TcpPath) -> Vec<(f64, f64)> {
    tcp.pieces.iter().filter(|p| matches!(p.kind, PieceKind::Pierce { .. } | PieceKind::Cool { .. })).map(|p| (p.start, p.end_time())).collect()
}

/// The start of a burst on axis `i` from `from` to `to` along `leg` within
/// `[earliest, latest]` that keeps every TCP window within reach and leaves
/// the `pierces` alone, searched outward from the field change (between
/// `change_start` and `change_end`).
#[allow(clippy::too_many_arguments)]
fn burst_start(wins: &[Window], pierces: &[(f64, f64)], window: f64, i: usize, from: f64, to: f64, leg: &Leg, earliest: f64, latest: f64, change_start: f64, change_end: f64, half: f64) -> Option<f64> {
    if latest < earliest {
        return None;
    }
    let d = leg.duration;
    let at = |t0: f64, t: f64| from + (to - from) * leg.position(t - t0) / leg.length;
    let fits = |t0: f64| {
        if pierces.iter().any(|&(a, b)| a < t0 + d && t0 < b) {
            return false;
        }
        // Windows before the burst are within reach of `from`, after it of
        // `to`, by the choice of the ranges, except those of the field change.
        let (a, b) = (t0.min(change_start), (t0 + d).max(change_end));
        let first = wins.partition_point(|w| w.t1 <= a);
        wins[first..].iter().take_while(|w| w.t0 < b).all(|w| {
            let (s0, s1) = (at(t0, w.t0), at(t0, w.t1));
            let (lo, hi) = (s0.min(s1), s0.max(s1));
            w.hi[i] - half <= lo + 1e-9 && w.lo[i] + half >= hi - 1e-9
        })
    };
    // Centred on the field change first, then earlier and later by steps.
    let centre = (0.5 * (change_start + change_end) - 0.5 * d).clamp(earliest, latest);
    let step = (d / 50.0).max(window);
    let mut k = 0usize;
    loop {
        let off = step * k.div_ceil(2) as f64;
        let t0 = if k % 2 == 1 { centre - off } else { centre + off };
        let below = centre - off < earliest;
        let above = centre + off > latest;
        if below && above {
            return None;
        }
        if (earliest..=latest).contains(&t0) && fits(t0) {
            return Some(t0);
        }
        k += 1;
    }
}
