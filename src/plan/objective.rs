//! Objectives: what a planner minimises over a route of marks, exchangeable
//! without touching the planner (seed 004's idea, carried to every planner).
//!
//! * `length`: the laser-off travel between marks (the seeds' idle stroke).
//! * `time`: the machine time of the route in laserd's motion model, in
//!   closed form: each laser-off move per axis the fastest at the axis'
//!   velocity and acceleration limits from its start state to its end state
//!   (a mark's ends at rest, or at its speed where it is overscanned), plus
//!   the jerk's ramps; marks at their speed; pierces.
//! * `turns`: seed 004's Eq. 10, how far every turn of the tool's path
//!   strays from going straight on (|ij| + |jk| − |ik| at each vertex j).
//! * `heat`: marks made near one another within a cooling time, each pair
//!   weighted by how little time lay between them (the laser's analogue of
//!   constant engagement: heat spreads evenly).
//! * weighted sums: `time+0.2*turns`.

use nalgebra::Vector2;

use crate::config::Limits;
use crate::job::Point;

/// A mark of a route as the objectives see it: where it starts and ends,
/// its length and speed, and how it is entered and left.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mark {
    pub from: Point,
    pub to: Point,
    pub length: f64,
    pub speed: f64,
    /// Direction at its start and end (unit vectors).
    pub dir_in: Vector2<f64>,
    pub dir_out: Vector2<f64>,
    /// Entered and left at its speed (overscan); else from and to rest.
    pub at_speed: bool,
    /// Pierce time at its start (s).
    pub pierce: f64,
}

impl Mark {
    /// A straight mark from `from` to `to`.
    pub fn straight(from: Point, to: Point, speed: f64, at_speed: bool) -> Mark {
        let length = (to - from).norm();
        let dir = if length > 0.0 { (to - from) / length } else { Vector2::x() };
        Mark { from, to, length, speed, dir_in: dir, dir_out: dir, at_speed, pierce: 0.0 }
    }
}

/// The machine's motion in closed form: the axes' limits (the same on X
/// and Y), and whether a mark going on ahead along its line runs through
/// the gap at its speed with the laser off (a stage-only fill's line, as
/// the motion chains it) rather than jumping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionModel {
    pub axis: Limits,
    pub bridges: bool,
}

impl MotionModel {
    /// Time from `from` at velocity `v0` to `to` at velocity `v1`: each
    /// axis the fastest at its limits, the slower axis deciding, plus two
    /// jerk ramps (acceleration / jerk each) when anything moves.
    pub fn move_time(&self, from: Point, v0: Vector2<f64>, to: Point, v1: Vector2<f64>) -> f64 {
        let d = to - from;
        if d.norm() < 1e-12 && (v1 - v0).norm() < 1e-12 {
            return 0.0;
        }
        let Limits { velocity, acceleration, jerk } = self.axis;
        let t = axis_time(d.x, v0.x, v1.x, velocity, acceleration).max(axis_time(d.y, v0.y, v1.y, velocity, acceleration));
        t + 2.0 * acceleration / jerk
    }

    /// Time to mark `mark` (its pierce included), entered and left at its
    /// speed or at rest.
    pub fn mark_time(&self, mark: &Mark, in_at_speed: bool, out_at_speed: bool) -> f64 {
        let Limits { velocity, acceleration: a, jerk } = self.axis;
        let (l, v) = (mark.length, mark.speed.min(velocity));
        let ramp = v * v / (2.0 * a);
        let at = match (in_at_speed, out_at_speed) {
            (true, true) => l / v,
            (false, false) => axis_time(l, 0.0, 0.0, v, a) + 2.0 * a / jerk,
            // One end at rest: a ramp there, or no cruise at all.
            _ if l >= ramp => l / v + v / (2.0 * a) + a / (2.0 * jerk),
            _ => (2.0 * l / a).sqrt() + a / jerk,
        };
        at + mark.pierce
    }

    /// Whether `b` goes on from `a` along the same line ahead, the motion
    /// running through the gap at their speed.
    pub fn bridged(&self, a: &Mark, b: &Mark) -> bool {
        let gap = b.from - a.to;
        self.bridges
            && a.at_speed == b.at_speed
            && (a.speed - b.speed).abs() <= 1e-9 * a.speed
            && a.dir_out.dot(&b.dir_in) > 1.0 - 1e-9
            && gap.dot(&a.dir_out) >= 0.0
            && a.dir_out.perp(&gap).abs() <= 1e-6 * (1.0 + gap.norm())
    }

    /// When each mark of `route` starts (the first at 0, after the move to
    /// it), and when the route ends.
    pub fn timeline(&self, route: &[Mark]) -> (Vec<f64>, f64) {
        let mut starts = Vec::with_capacity(route.len());
        let end = self.walk(route, |t| starts.push(t));
        (starts, end)
    }

    /// When the route ends, `started` told when each mark starts (the
    /// searches price routes millions of times: nothing is allocated).
    fn walk(&self, route: &[Mark], mut started: impl FnMut(f64)) -> f64 {
        let n = route.len();
        let mut t = 0.0;
        let mut came = false;
        for (k, m) in route.iter().enumerate() {
            let goes = k + 1 < n && self.bridged(m, &route[k + 1]);
            if k > 0 {
                let a = &route[k - 1];
                t += if came {
                    (m.from - a.to).norm() / m.speed.min(self.axis.velocity)
                } else {
                    let v0 = if a.at_speed { a.dir_out * a.speed.min(self.axis.velocity) } else { Vector2::zeros() };
                    let v1 = if m.at_speed { m.dir_in * m.speed.min(self.axis.velocity) } else { Vector2::zeros() };
                    self.move_time(a.to, v0, m.from, v1)
                };
            }
            started(t);
            t += self.mark_time(m, m.at_speed || came, m.at_speed || goes);
            came = goes;
        }
        t
    }
}

/// The least time for one axis from velocity `v0` to `v1` over the
/// distance `d`, at speeds up to `vmax` and accelerations up to `a`: full
/// acceleration one way then the other (either way round), cruising at
/// `vmax` where the peak would pass it. Speeds above `vmax` are taken as
/// `vmax`.
pub fn axis_time(d: f64, v0: f64, v1: f64, vmax: f64, a: f64) -> f64 {
    if v0 == 0.0 && v1 == 0.0 {
        // Rest to rest (the most common case, priced millions of times):
        // the arithmetic below, either way round, without its search.
        let peak = (a * d.abs()).sqrt();
        if peak <= vmax {
            return (peak + peak) / a;
        }
        let ramp = vmax * vmax / (2.0 * a);
        return (vmax + vmax) / a + (d.abs() - ramp - ramp) / vmax;
    }
    let (v0, v1) = (v0.clamp(-vmax, vmax), v1.clamp(-vmax, vmax));
    let mut best = f64::INFINITY;
    for s in [1.0, -1.0] {
        // Peak speed of an up-then-down profile (s = 1) or down-then-up (s = -1).
        let q = s * a * d + 0.5 * (v0 * v0 + v1 * v1);
        if q < 0.0 {
            continue;
        }
        let peak = s * q.sqrt();
        let slack = 1e-12 * (1.0 + vmax);
        if s * peak < s * v0 - slack || s * peak < s * v1 - slack {
            continue;
        }
        let t = if peak.abs() <= vmax {
            (s * (peak - v0) + s * (peak - v1)) / a
        } else {
            let vc = s * vmax;
            let (d0, d1) = ((vc * vc - v0 * v0) / (2.0 * s * a), (vc * vc - v1 * v1) / (2.0 * s * a));
            (s * (vc - v0) + s * (vc - v1)) / a + (d - d0 - d1) / vc
        };
        best = best.min(t.max(0.0));
    }
    best
}

/// What an objective needs of the machine and job beyond the route.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectiveContext {
    pub motion: MotionModel,
    /// `heat`: marks closer than this (mm, between their middles) share heat ...
    pub heat_radius: f64,
    /// ... when made less than this apart (s).
    pub cooling_time: f64,
}

/// What a planner minimises over a route: lower is better. The planners
/// take any objective; `of_terms` makes one from the config's grammar.
pub trait Objective: Send + Sync {
    /// As the user wrote it (`time`, `time+0.2*turns`).
    fn name(&self) -> String;
    /// The objective's value on `route`: 0 or more (the searches stop at 0).
    fn cost(&self, route: &[Mark], ctx: &ObjectiveContext) -> f64;
    /// Whether it is the laser-off length alone (the searches' own measure).
    fn is_length(&self) -> bool {
        false
    }
    /// Whether its cost is a sum of terms that each see only a mark and
    /// those beside it, the same on the route read backwards: then a change
    /// can be priced on the marks around it.
    fn is_local(&self) -> bool {
        true
    }
    /// Where it is not local: a time such that marks made further apart
    /// add nothing to each other's terms (then a change is priced on the
    /// marks made within it); `None`: only on the whole route.
    fn horizon(&self, _: &ObjectiveContext) -> Option<f64> {
        None
    }
}

/// The laser-off travel between consecutive marks (mm).
pub struct Length;
/// The machine time of the route (s).
pub struct Time;
/// Seed 004's Eq. 10 (mm).
pub struct Turns;
/// Marks made near one another within a cooling time.
pub struct Heat;
/// A weighted sum of objectives.
pub struct Weighted(pub Vec<(f64, Box<dyn Objective>)>);

impl Objective for Length {
    fn name(&self) -> String {
        "length".into()
    }
    fn cost(&self, route: &[Mark], _: &ObjectiveContext) -> f64 {
        route.windows(2).map(|w| (w[1].from - w[0].to).norm()).sum()
    }
    fn is_length(&self) -> bool {
        true
    }
}

impl Objective for Time {
    fn name(&self) -> String {
        "time".into()
    }
    fn cost(&self, route: &[Mark], ctx: &ObjectiveContext) -> f64 {
        route_time(route, &ctx.motion)
    }
}

impl Objective for Turns {
    fn name(&self) -> String {
        "turns".into()
    }
    fn cost(&self, route: &[Mark], _: &ObjectiveContext) -> f64 {
        turns(route).0
    }
}

impl Objective for Heat {
    fn name(&self) -> String {
        "heat".into()
    }
    fn cost(&self, route: &[Mark], ctx: &ObjectiveContext) -> f64 {
        heat(route, ctx)
    }
    /// Heat depends on when marks are made: on everything before them ...
    fn is_local(&self) -> bool {
        false
    }
    /// ... but only on what was made less than the cooling time before.
    fn horizon(&self, ctx: &ObjectiveContext) -> Option<f64> {
        Some(ctx.cooling_time)
    }
}

impl Objective for Weighted {
    fn name(&self) -> String {
        let terms: Vec<String> = self.0.iter().map(|(w, o)| if *w == 1.0 { o.name() } else { format!("{w}*{}", o.name()) }).collect();
        terms.join("+")
    }
    fn cost(&self, route: &[Mark], ctx: &ObjectiveContext) -> f64 {
        self.0.iter().filter(|(w, _)| *w != 0.0).map(|(w, o)| w * o.cost(route, ctx)).sum()
    }
    fn is_length(&self) -> bool {
        self.0.iter().all(|(w, o)| *w == 0.0 || o.is_length())
    }
    fn is_local(&self) -> bool {
        self.0.iter().all(|(w, o)| *w == 0.0 || o.is_local())
    }
    fn horizon(&self, ctx: &ObjectiveContext) -> Option<f64> {
        let terms = self.0.iter().filter(|(w, _)| *w != 0.0);
        terms.map(|(_, o)| if o.is_local() { Some(0.0) } else { o.horizon(ctx) }).try_fold(0.0f64, |h, t| t.map(|t| h.max(t)))
    }
}

/// The objective of a term's name (`config::OBJECTIVE_TERMS`).
pub fn of_term(name: &str) -> Box<dyn Objective> {
    match name {
        "time" => Box::new(Time),
        "turns" => Box::new(Turns),
        "heat" => Box::new(Heat),
        _ => Box::new(Length),
    }
}

/// The objective `spec` names (`time`, `time+0.2*turns`; the grammar is
/// `config::objective_terms`'s).
pub fn parse(spec: &str) -> Result<Box<dyn Objective>, String> {
    let terms = crate::config::objective_terms(spec)?;
    Ok(match terms.as_slice() {
        [(w, name)] if *w == 1.0 => of_term(name),
        _ => Box::new(Weighted(terms.into_iter().map(|(w, name)| (w, of_term(name))).collect())),
    })
}

/// The machine time of `route`: its marks and the moves between them.
pub fn route_time(route: &[Mark], motion: &MotionModel) -> f64 {
    motion.walk(route, |_| {})
}

/// Seed 004's Eq. 10 over the tool's path through the route's mark ends
/// (mm), and the number of turns: vertices where the path changes
/// direction by more than a degree.
pub fn turns(route: &[Mark]) -> (f64, usize) {
    let (mut detour, mut count) = (0.0, 0);
    let straight = 1.0f64.to_radians().cos();
    // The last two vertices of the path (repeats left out), and the length
    // of the edge between them.
    let (mut before, mut last, mut edge): (Option<Point>, Option<Point>, f64) = (None, None, 0.0);
    for p in route.iter().flat_map(|m| [m.from, m.to]) {
        if last.is_some_and(|q| (p - q).norm_squared() <= 1e-18) {
            continue;
        }
        let next = last.map_or(0.0, |j| (p - j).norm());
        if let (Some(i), Some(j)) = (before, last) {
            let (a, b) = (j - i, p - j);
            detour += edge + next - (p - i).norm();
            if a.dot(&b) < straight * edge * next {
                count += 1;
            }
        }
        (before, last, edge) = (last, Some(p), next);
    }
    (detour, count)
}

/// Pairs of marks whose middles lie within `heat_radius`, made less than
/// `cooling_time` apart, each weighted 1 − (time between) / cooling time.
pub fn heat(route: &[Mark], ctx: &ObjectiveContext) -> f64 {
    // When each mark starts, and its middle.
    let mut marks: Vec<(f64, Point)> = Vec::with_capacity(route.len());
    let mut k = 0;
    ctx.motion.walk(route, |t| {
        let m = &route[k];
        marks.push((t, Point::from((m.from.coords + m.to.coords) * 0.5)));
        k += 1;
    });
    let starts = |k: usize| marks[k].0;
    let middles = |k: usize| marks[k].1;
    let r = ctx.heat_radius.max(1e-9);
    let r2 = r * r;
    let share = |k: usize, j: usize| {
        let since = starts(k) - starts(j);
        if since < ctx.cooling_time && (middles(j) - middles(k)).norm_squared() <= r2 {
            1.0 - since / ctx.cooling_time
        } else {
            0.0
        }
    };
    // The marks made less than the cooling time before each (a window
    // sliding along the route) ...
    let mut first = 0;
    let mut window = 0usize;
    for k in 0..route.len() {
        while starts(k) - starts(first) >= ctx.cooling_time {
            first += 1;
        }
        window += k - first;
    }
    if window <= 256 * route.len() {
        let mut first = 0;
        let mut total = 0.0;
        for k in 0..route.len() {
            while starts(k) - starts(first) >= ctx.cooling_time {
                first += 1;
            }
            total += (first..k).map(|j| share(k, j)).sum::<f64>();
        }
        return total;
    }
    // ... or, where very many marks are made within it (the window is the
    // quicker up to a few hundred: the fishhead's heat converges 4× faster
    // with 256 than with 16, a galvo fill plans 1.5-2× faster), the marks by cell of `r`,
    // in the route's order within a cell (sorted, not hashed: a search
    // prices whole routes many thousand times).
    let cell = |p: Point| ((p.x / r).floor() as i64, (p.y / r).floor() as i64);
    let mut by_cell: Vec<((i64, i64), u32)> = marks.iter().enumerate().map(|(k, &(_, p))| (cell(p), k as u32)).collect();
    by_cell.sort_unstable();
    let mut total = 0.0;
    for (k, &(_, p)) in marks.iter().enumerate() {
        let (cx, cy) = cell(p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                let key = (cx + dx, cy + dy);
                // The cell's marks made before this one; those less than the
                // cooling time before it are the last of them.
                let end = by_cell.partition_point(|e| *e < (key, k as u32));
                let mut first = end;
                while first > 0 && by_cell[first - 1].0 == key && starts(k) - starts(by_cell[first - 1].1 as usize) < ctx.cooling_time {
                    first -= 1;
                }
                total += by_cell[first..end].iter().map(|&(_, j)| share(k, j as usize)).sum::<f64>();
            }
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> MotionModel {
        MotionModel { axis: Limits { velocity: 500.0, acceleration: 5000.0, jerk: 1e12 }, bridges: false }
    }

    #[test]
    fn one_axis_time_is_the_bang_bang_profile() {
        // Rest to rest: 2·√(d/a) without reaching the top speed.
        assert!((axis_time(10.0, 0.0, 0.0, 500.0, 5000.0) - 2.0 * (10.0f64 / 5000.0).sqrt()).abs() < 1e-12);
        // With a cruise: 100 mm at 500 mm/s and 5000 mm/s²: 0.1 s each ramp (25 mm), 50 mm cruising.
        assert!((axis_time(100.0, 0.0, 0.0, 500.0, 5000.0) - 0.3).abs() < 1e-12);
        // Turning round in place from +v to -v: 2v/a.
        assert!((axis_time(0.0, 400.0, -400.0, 500.0, 5000.0) - 0.16).abs() < 1e-12);
        // Going on at speed over a gap at the top speed: d/v.
        assert!((axis_time(50.0, 500.0, 500.0, 500.0, 5000.0) - 0.1).abs() < 1e-12);
        // Backwards is the mirror image.
        assert!((axis_time(-10.0, 0.0, 0.0, 500.0, 5000.0) - axis_time(10.0, 0.0, 0.0, 500.0, 5000.0)).abs() < 1e-12);
        // Never faster than a simulation of the same limits finds.
        for (d, v0, v1) in [(3.0, 100.0, -200.0), (-7.0, 300.0, 300.0), (0.5, -400.0, 400.0), (40.0, -100.0, 50.0)] {
            let t = axis_time(d, v0, v1, 500.0, 5000.0);
            assert!(t.is_finite() && t >= (v1 - v0).abs() / 5000.0 - 1e-12, "{d} {v0} {v1}: {t}");
        }
    }

    #[test]
    fn the_time_objective_prices_a_turn_round_and_the_length_objective_does_not() {
        let ctx = ObjectiveContext { motion: model(), heat_radius: 1.0, cooling_time: 1.0 };
        let a = Mark::straight(Point::new(0.0, 0.0), Point::new(10.0, 0.0), 400.0, true);
        let back = Mark::straight(Point::new(10.0, 0.1), Point::new(0.0, 0.1), 400.0, true);
        let on = Mark::straight(Point::new(0.0, 0.1), Point::new(10.0, 0.1), 400.0, true);
        // Going back is shorter in air but the machine turns round at speed.
        assert!(Length.cost(&[a, back], &ctx) < Length.cost(&[a, on], &ctx));
        let (t_back, t_on) = (Time.cost(&[a, back], &ctx), Time.cost(&[a, on], &ctx));
        assert!(t_back > 2.0 * 10.0 / 400.0 + 0.15 && t_on > t_back, "{t_back} {t_on}");
        let (_, count) = turns(&[a, back]);
        assert_eq!(count, 2);
        // Made side by side a turn-round apart (about 0.2 s of the 1 s cooling time).
        let h = heat(&[a, back], &ctx);
        assert!(h > 0.7 && h < 0.85, "{h}");
    }

    #[test]
    fn objectives_parse_and_print_weighted_sums() {
        let ctx = ObjectiveContext { motion: model(), heat_radius: 1.0, cooling_time: 1.0 };
        let o = parse("time+0.2*turns").unwrap();
        assert_eq!(o.name(), "time+0.2*turns");
        let route = [Mark::straight(Point::new(0.0, 0.0), Point::new(10.0, 0.0), 400.0, true), Mark::straight(Point::new(10.0, 1.0), Point::new(0.0, 1.0), 400.0, true)];
        assert!((o.cost(&route, &ctx) - (Time.cost(&route, &ctx) + 0.2 * Turns.cost(&route, &ctx))).abs() < 1e-12);
        assert!(parse("length").unwrap().is_length() && !o.is_length());
        for bad in ["speed", "time+x*turns", "-1*time", "0*time", "time+"] {
            assert!(parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn heat_sums_every_near_pair_made_within_the_cooling_time() {
        // Short marks scattered over a few radii (a fixed xorshift sequence),
        // against every pair of marks looked at; a short cooling time (a
        // few marks back, the window) and a long one (all, the cells).
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut uniform = |lo: f64, hi: f64| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            lo + (hi - lo) * (x >> 11) as f64 / (1u64 << 53) as f64
        };
        // 800 marks: with the long cooling time each sees 400 before it on
        // average, past the window's share (256).
        let route: Vec<Mark> = (0..800)
            .map(|_| {
                let from = Point::new(uniform(-4.0, 4.0), uniform(-4.0, 4.0));
                Mark::straight(from, from + Vector2::new(uniform(-1.0, 1.0), uniform(-1.0, 1.0)), 400.0, false)
            })
            .collect();
        let middle = |m: &Mark| Point::from((m.from.coords + m.to.coords) * 0.5);
        for cooling_time in [0.2, 50.0] {
            let ctx = ObjectiveContext { motion: model(), heat_radius: 1.5, cooling_time };
            let (starts, _) = ctx.motion.timeline(&route);
            let mut every_pair = 0.0;
            for k in 0..route.len() {
                for j in 0..k {
                    let since = starts[k] - starts[j];
                    if since < ctx.cooling_time && (middle(&route[j]) - middle(&route[k])).norm() <= ctx.heat_radius {
                        every_pair += 1.0 - since / ctx.cooling_time;
                    }
                }
            }
            assert!(every_pair > 10.0, "the case has near pairs: {every_pair}");
            let got = heat(&route, &ctx);
            assert!((got - every_pair).abs() < 1e-9 * every_pair, "{got} {every_pair}");
        }
    }
}
