//! Pre-cuts (seed 000, Figure 4): a cut that starts with a pierce on a
//! junction an earlier cut already ran through can start in a kerf instead.
//! When the head passes the junction it cuts `[cutting] precut_length` mm
//! into that element and back (a pre-cut); the later cut then starts there
//! without a pierce. A pre-cut is made where it is faster than the pierce:
//! its length there and back at the cut's speed, and two sharp-angle
//! macros at most (`[cutting] sharp_angle_cost`, in mm of air move as
//! `pierce_cost`, so in seconds at the pierce's rate), against the pierce time.
//!
//! Where several pre-cuts go out from one pass through a junction, they are
//! made in the order with the fewest sharp-angle macros (turns sharper than
//! `[cutting] corner_angle` where the head changes direction at the
//! junction: onto the first pre-cut, from each onto the next, from the last
//! onto the cut going on), ties to the smaller total turn, found by trying
//! every order ([`best_order`]; junctions rarely have more than five).

use std::collections::HashMap;

use super::Sequence;
use crate::config::MachineConfig;
use crate::job::{Job, Point};

/// Junctions with more pre-cuts than this keep them in route order (8! orders
/// are still quick; real junctions have at most five).
pub const MAX_ORDERED: usize = 8;

/// What `add_precuts` did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PrecutCount {
    /// Pre-cuts made, each saving a pierce.
    pub precuts: usize,
    /// Sharp-angle macros at the junctions with pre-cuts, in the order made.
    pub macros: usize,
}

/// Unit headings: arriving at a junction, the pre-cuts going out (each comes
/// back on its reverse), and leaving it; none where the cut begins or ends
/// there.
pub struct Junction {
    pub arriving: Option<nalgebra::Vector2<f64>>,
    pub out: Vec<nalgebra::Vector2<f64>>,
    pub leaving: Option<nalgebra::Vector2<f64>>,
}

/// The sharp-angle macros and the total turn (radians) of making the
/// junction's pre-cuts in `order`: every change of heading at the junction,
/// and the turn at each pre-cut's far end.
pub fn cost(j: &Junction, order: &[usize], cos_sharp: f64) -> (usize, f64) {
    let mut headings: Vec<nalgebra::Vector2<f64>> = Vec::with_capacity(2 * order.len() + 2);
    headings.extend(j.arriving);
    for &k in order {
        headings.push(j.out[k]);
        headings.push(-j.out[k]);
    }
    headings.extend(j.leaving);
    let mut macros = 0;
    let mut turn = 0.0;
    for w in headings.windows(2) {
        let c = w[0].dot(&w[1]).clamp(-1.0, 1.0);
        if c < cos_sharp {
            macros += 1;
        }
        turn += c.acos();
    }
    (macros, turn)
}

/// The order of the junction's pre-cuts with the fewest sharp-angle macros,
/// then the least turn, then the first in route order: every order tried.
pub fn best_order(j: &Junction, cos_sharp: f64) -> Vec<usize> {
    let n = j.out.len();
    let mut order: Vec<usize> = (0..n).collect();
    if !(2..=MAX_ORDERED).contains(&n) {
        return order;
    }
    let mut best = (order.clone(), cost(j, &order, cos_sharp));
    // Heap's algorithm: every permutation once.
    let mut c = vec![0usize; n];
    let mut i = 1;
    while i < n {
        if c[i] < i {
            order.swap(if i % 2 == 0 { 0 } else { c[i] }, i);
            let here = cost(j, &order, cos_sharp);
            let better = here.0 < best.1 .0 || (here.0 == best.1 .0 && (here.1 < best.1 .1 - 1e-12 || ((here.1 - best.1 .1).abs() <= 1e-12 && order < best.0)));
            if better {
                best = (order.clone(), here);
            }
            c[i] += 1;
            i = 1;
        } else {
            c[i] = 0;
            i += 1;
        }
    }
    best.0
}

/// `sequence` with pre-cuts where they are faster than a pierce, and what
/// was done.
pub fn add_precuts(job: &Job, mut sequence: Sequence, machine: &MachineConfig) -> (Sequence, PrecutCount) {
    let length = machine.cutting.precut_length;
    if length <= 0.0 {
        return (sequence, PrecutCount::default());
    }
    let key = |p: Point| ((p.x * 1e6).round() as i64, (p.y * 1e6).round() as i64);
    let cuts = |process: usize| machine.pierce(&job.processes[process].layer).active();
    let ramp = |speed: f64| speed / machine.stage.max_acceleration;
    let cos_sharp = machine.cutting.corner_angle.to_radians().cos();
    // Per pass (group, path, vertex): the later paths pre-cut there, each
    // with its pre-cut's length.
    let mut wanted: HashMap<(usize, usize, usize), Vec<(usize, f64)>> = HashMap::new();
    for (g, group) in sequence.groups.iter().enumerate() {
        // Where the cuts of this group ran through, first pass first.
        let mut passed: HashMap<(i64, i64), (usize, usize)> = HashMap::new();
        for (k, path) in group.paths.iter().enumerate() {
            let n = path.points.len();
            if path.pierce && cuts(path.process) && n >= 2 {
                let first = (path.points[1] - path.points[0]).norm();
                let process = &job.processes[path.process];
                let speed = process.speed.min(machine.stage.max_velocity);
                let pre = length.min(0.5 * first);
                // Macros are priced in mm of air move, as the pierce is
                // (`pierce_cost`): in seconds at that rate.
                let pierce = machine.pierce(&process.layer).time;
                let macro_time = machine.cutting.sharp_angle_cost * pierce / machine.cutting.pierce_cost.max(1e-9);
                let time = 2.0 * pre / speed + 2.0 * ramp(speed) + 2.0 * macro_time;
                if let Some(&(j, i)) = passed.get(&key(path.points[0])) {
                    if pre > 1e-6 && time < pierce {
                        wanted.entry((g, j, i)).or_default().push((k, pre));
                    }
                }
            }
            if cuts(path.process) {
                // Vertices of the contour (not of its leads).
                let last = n - 1 - path.lead_out;
                for i in path.lead_in..=last {
                    passed.entry(key(path.points[i])).or_insert((k, i));
                }
            }
        }
    }
    let mut count = PrecutCount::default();
    let mut passes: Vec<(usize, usize, usize)> = wanted.keys().copied().collect();
    // Later vertices of a path first: the earlier ones keep their indices.
    passes.sort_by(|a, b| b.cmp(a));
    for (g, j, i) in passes {
        let ks = &wanted[&(g, j, i)];
        let paths = &sequence.groups[g].paths;
        let at = paths[j].points[i];
        let heading = |a: Point, b: Point| (b - a).try_normalize(1e-12);
        let through = &paths[j].points;
        let junction = Junction {
            arriving: i.checked_sub(1).and_then(|h| heading(through[h], at)),
            out: ks.iter().map(|&(k, _)| heading(paths[k].points[0], paths[k].points[1]).expect("a first segment longer than the pre-cut")).collect(),
            leaving: through.get(i + 1).and_then(|&b| heading(at, b)),
        };
        let order = best_order(&junction, cos_sharp);
        count.macros += cost(&junction, &order, cos_sharp).0;
        let mut detour = Vec::with_capacity(2 * order.len());
        for &o in &order {
            detour.push(at + junction.out[o] * ks[o].1);
            detour.push(at);
        }
        let group = &mut sequence.groups[g].paths;
        let path = &mut group[j];
        path.points.splice(i + 1..i + 1, detour);
        for &(k, _) in ks {
            group[k].pierce = false;
        }
        count.precuts += ks.len();
    }
    (sequence, count)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    fn dir(deg: f64) -> Vector2<f64> {
        let a = deg.to_radians();
        Vector2::new(a.cos(), a.sin())
    }

    /// Seed 000's Figure 4: A comes in, D goes on straight, pre-cuts B and C
    /// off to the sides: one order costs three macros, the other one.
    #[test]
    fn the_order_of_two_precuts_is_the_one_with_fewer_sharp_angles() {
        let cos_sharp = 60f64.to_radians().cos();
        // Heading east; B up and back (ahead-left), C down and back (behind-right).
        let j = Junction { arriving: Some(dir(0.0)), out: vec![dir(135.0), dir(-45.0)], leaving: Some(dir(0.0)) };
        let (ab, ba) = (cost(&j, &[0, 1], cos_sharp), cost(&j, &[1, 0], cos_sharp));
        assert_ne!(ab.0, ba.0, "{ab:?} {ba:?}");
        let best = best_order(&j, cos_sharp);
        assert_eq!(cost(&j, &best, cos_sharp).0, ab.0.min(ba.0));
    }
}
