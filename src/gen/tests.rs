//! The generated instances against the stages that read them: a sheet drawn
//! as SVG, imported, and its topology found again; the cutting constructions
//! and searches on sheets and on a280. Here rather than in those stages'
//! rooms because the generators come later in the pipeline (see
//! tests/layers.rs).

use std::collections::BTreeSet;
use std::time::Instant;

use super::sheet::{self, SheetParams};
use super::tsplib;
use crate::config::MachineConfig;
use crate::import::svg::import_svg;
use crate::job::Point;
use crate::plan::ecp::construct::{construct, contour_order_construction, insertion_in_order};
use crate::plan::ecp::ils::{search_from, SearchOptions, Start};
use crate::plan::ecp::model::CuttingModel;
use crate::plan::ecp::tabu::{tabu_search, TabuOptions};
use crate::plan::ecp::{checker, checker::check, Cut, Instance};
use crate::plan::stop::TimeCap;
use crate::topology::tests::{check_model, length, ring};
use crate::topology::{Topology, TopologyOptions};

/// a280 made precedence-constrained with `seed`, for the searches' tests.
fn a280(seed: u64) -> tsplib::BenchInstance {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/tsplib");
    let tsp = tsplib::read_tsp(&dir.join("a280.tsp")).unwrap();
    let tour = tsplib::read_tour(&dir.join("a280.opt.tour"), 280).unwrap();
    tsplib::bench_instance(&tsp, &tour, seed)
}

#[test]
fn contour_order_construction_cuts_a_sheet_contour_by_contour() {
    let sheet = sheet::generate(&SheetParams::with_target(400), 1);
    let route = contour_order_construction(&sheet);
    assert!(check(&sheet, &route).is_empty());
    // Whole contours: a pierce per contour at most (fewer where cuts run on).
    let pierces = (0..route.len()).filter(|&i| i == 0 || sheet.step(Some(route[i - 1]), route[i]) > 0.0).count();
    assert!(pierces <= sheet.contours.len(), "{pierces} pierces for {} contours", sheet.contours.len());
}

#[test]
fn a_relaxed_start_is_mended_and_beats_the_construction_on_a280() {
    let b = a280(2);
    let construction = b.instance.cost(&insertion_in_order(&b.instance, None));
    let options = SearchOptions { kicks: Some(60_000), ..SearchOptions::new() };
    for start in [Start::Relaxed, Start::Insertion] {
        let found = search_from(&b.instance, start, &options, &TimeCap::none());
        assert!(check(&b.instance, &found.route).is_empty(), "{start:?}");
        assert!(found.cost >= b.optimum, "never below the optimum");
        assert!(found.cost < construction, "{start:?}: {} vs construction {construction}", found.cost);
    }
}

#[test]
fn tabu_improves_on_the_construction_of_a280_and_stays_feasible() {
    let b = a280(1);
    let start = construct(&b.instance);
    assert!(check(&b.instance, &start).is_empty());
    let options = TabuOptions { iterations: 2_000, ..TabuOptions::new(&b.instance) };
    let found = tabu_search(&b.instance, start.clone(), &options, &TimeCap::none());
    assert!(check(&b.instance, &found.route).is_empty());
    assert!(found.cost < b.instance.cost(&start));
    assert!(found.cost >= b.optimum, "never below the optimum");
}

/// Depth of each contour from a generated instance's own `inner_outer`.
fn depth(inst: &Instance) -> Vec<usize> {
    let mut outer = vec![None; inst.contours.len()];
    for &(i, o) in &inst.inner_outer {
        outer[i] = Some(o);
    }
    (0..outer.len()).map(|k| std::iter::successors(outer[k], |&o| outer[o]).count()).collect()
}

/// Each contour's group from a generated instance's own relations (as
/// `Topology::groups` defines them): numbered in contour order.
fn groups(inst: &Instance) -> Vec<usize> {
    let mut group: Vec<Option<usize>> = vec![None; inst.contours.len()];
    let links: Vec<(usize, usize)> = inst.inner_outer.iter().copied().chain(inst.common_cuts().iter().map(|cc| cc.contours)).collect();
    let mut next = 0;
    for k in 0..group.len() {
        if group[k].is_some() {
            continue;
        }
        let mut stack = vec![k];
        while let Some(c) = stack.pop() {
            if group[c].replace(next).is_none() {
                stack.extend(links.iter().filter_map(|&(a, b)| if a == c { Some(b) } else if b == c { Some(a) } else { None }));
            }
        }
        next += 1;
    }
    group.into_iter().map(|g| g.unwrap_or(0)).collect()
}

#[test]
fn sheet_svg_round_trip_finds_the_generated_topology() {
    let config = MachineConfig::load(None).unwrap();
    for (target, seed) in [(300, 1), (300, 2), (3000, 1), (12000, 3)] {
        let params = SheetParams::with_target(target);
        let generated = sheet::generate_sheet(&params, seed);
        let gen = &generated.instance;
        let svg = sheet::to_svg(&generated, &params);
        let t0 = Instant::now();
        let job = import_svg(&svg, "sheet.svg", &config).unwrap();
        let t1 = Instant::now();
        let options = TopologyOptions::default();
        let topology = Topology::build(&job, &options).unwrap();
        let t2 = Instant::now();
        eprintln!(
            "sheet {target}/{seed}: {} elements, {} contours, {} points imported; import {:.1} ms, topology {:.1} ms",
            gen.elements.len(),
            gen.contours.len(),
            job.geometries.iter().map(|g| g.points.len()).sum::<usize>(),
            (t1 - t0).as_secs_f64() * 1e3,
            (t2 - t1).as_secs_f64() * 1e3
        );
        check_model(&topology, &job, options.common_cut_tolerance_mm);
        let m = CuttingModel::new(topology, Point::new(0.0, 0.0), 0.0);
        let inst = &m.instance;
        assert_eq!(job.geometries.len(), gen.contours.len());
        assert!(job.geometries.iter().all(|g| g.closed));
        // The same relations, contour k being geometry k.
        let found: BTreeSet<(usize, usize)> = inst.inner_outer.iter().copied().collect();
        let made: BTreeSet<(usize, usize)> = gen.inner_outer.iter().copied().collect();
        assert_eq!(found, made, "sheet {target}/{seed}: inner/outer pairs");
        assert_eq!(inst.common_cuts().len(), gen.common_cuts().len());
        assert_eq!(common_pairs(inst), common_pairs(gen));
        assert_eq!(m.topology.levels, depth(gen));
        assert_eq!(m.topology.groups, groups(gen));
        // Rank above 0 exactly for cells whose every edge is shared.
        let mut owners = vec![0; gen.elements.len()];
        for c in &gen.contours {
            for &e in c {
                owners[e] += 1;
            }
        }
        for (k, c) in gen.contours.iter().enumerate() {
            assert_eq!(m.topology.ranks[k] > 0, c.iter().all(|&e| owners[e] == 2), "contour {k}");
            let round = c.iter().all(|&e| generated.arc_centres[e].is_some());
            if round {
                // Drawn as arcs: every imported point on the circle (the
                // import flattens within 0.01 mm the cubics an SVG arc
                // becomes, which are off the circle by up to 0.03 %), and
                // a 2-arc circle is a disc, not a line there and back.
                let centre = generated.arc_centres[c[0]].unwrap();
                let r = (gen.elements[c[0]].a - centre).norm();
                let g = &job.geometries[k];
                let off = g.points.iter().map(|q| ((q - centre).norm() - r).abs()).fold(0.0, f64::max);
                assert!(off < 0.02 + 3e-4 * r, "contour {k} is {off} mm off its circle (r {r})");
                // Flattening loses at most the perimeter times the tolerance.
                let (area, pi) = (polygon_area(&g.points), std::f64::consts::PI);
                assert!((area - pi * r * r).abs() <= 2.0 * pi * r * 0.02, "contour {k}: area {area}, r {r}");
                assert!((2..=4).contains(&inst.contours[k].len()));
            } else {
                assert_eq!(inst.contours[k].len(), c.len(), "contour {k}: one element per line");
            }
        }
        if target >= 3000 {
            assert!(m.topology.ranks.iter().any(|&r| r > 0), "a 3-row grid has inner cells");
        }
        // Deepest contours first, each walked round from where its cut
        // common cuts left it: feasible, and one polyline per run of it.
        let mut order: Vec<usize> = (0..inst.contours.len()).collect();
        order.sort_by_key(|&k| std::cmp::Reverse(m.topology.levels[k]));
        let mut done = vec![false; inst.elements.len()];
        let mut route = Vec::new();
        let mut runs = Vec::new();
        for k in order {
            let cuts: Vec<Cut> = ring(&m.topology, &job, k).into_iter().map(|(element, reversed)| Cut { element, reversed }).collect();
            let n = cuts.len();
            let starts: Vec<usize> =
                (0..n).filter(|&i| !done[cuts[i].element] && done[cuts[(i + n - 1) % n].element]).collect();
            let first = match starts.first() {
                Some(&i) => i,
                None if cuts.iter().all(|c| !done[c.element]) => 0,
                None => continue,
            };
            for _ in 0..starts.len().max(1) {
                runs.push(k);
            }
            for s in 0..n {
                let c = cuts[(first + s) % n];
                if !std::mem::replace(&mut done[c.element], true) {
                    route.push(c);
                }
            }
        }
        assert_eq!(checker::check(inst, &route), vec![], "sheet {target}/{seed}");
        let lines = m.polylines(&route);
        assert_eq!(lines.iter().map(|l| l.geometry).collect::<Vec<_>>(), runs);
        let marked: f64 = lines.iter().map(|l| length(&l.points)).sum();
        let pieces: f64 = m.topology.elements.iter().map(|pc| length(&pc.points)).sum();
        assert!((marked - pieces).abs() < 1e-6 * pieces);
    }
}

/// The pairs of contours that share a common cut, sorted.
fn common_pairs(inst: &Instance) -> Vec<(usize, usize)> {
    let mut pairs: Vec<(usize, usize)> = inst.common_cuts().iter().map(|cc| (cc.contours.0.min(cc.contours.1), cc.contours.0.max(cc.contours.1))).collect();
    pairs.sort();
    pairs
}

fn polygon_area(points: &[Point]) -> f64 {
    let n = points.len();
    0.5 * (0..n).map(|i| points[i].x * points[(i + 1) % n].y - points[(i + 1) % n].x * points[i].y).sum::<f64>().abs()
}

#[test]
fn a_common_cut_that_would_close_both_its_contours_gets_one_of_their_elements_after_it() {
    // Two contours whose every element is a common cut, each around a
    // hole: their common cuts, of the holes' neighbours' depth, may all
    // come before the holes; the last one in then closes both wherever
    // it goes after the holes. In this sheet, some shuffled orders get
    // there: one of the two contours' other elements goes after it.
    let inst = sheet::generate(&SheetParams::with_target(10000), 1);
    let mut moved = 0;
    for seed in 2..5 {
        let (route, how) = crate::plan::ecp::construct::insert_all(&inst, Some(seed), &TimeCap::none()).unwrap();
        assert_eq!(check(&inst, &route), vec![], "seed {seed}");
        assert!(!how.fell_back, "seed {seed}");
        moved += how.moved;
    }
    assert!(moved > 0, "the case came up");
}

#[test]
fn the_insertion_on_sheets_is_feasible_and_as_cheap_as_trying_every_position() {
    use crate::plan::ecp::construct::{insertion, tests::insertion_everywhere};
    let (mut ours, mut reference) = (0.0, 0.0);
    for (target, seed) in [(300, 1), (300, 2), (1500, 1), (3000, 3)] {
        let inst = sheet::generate(&SheetParams::with_target(target), seed);
        let (a, b) = (insertion(&inst), insertion_everywhere(&inst));
        assert_eq!(check(&inst, &a), vec![], "sheet {target}-{seed}");
        assert_eq!(check(&inst, &insertion_in_order(&inst, Some(7))), vec![], "sheet {target}-{seed}, shuffled");
        let (a, b) = (inst.cost(&a), inst.cost(&b));
        assert!(a <= 1.15 * b, "sheet {target}-{seed}: {a} against {b} trying every position");
        ours += a;
        reference += b;
    }
    assert!(ours <= 1.03 * reference, "sheets: {ours} against {reference} trying every position");
}

#[test]
fn constructions_are_deterministic() {
    use crate::plan::ecp::construct::insertion;
    let inst = sheet::generate(&SheetParams::with_target(800), 5);
    for build in [insertion as fn(&Instance) -> Vec<Cut>, contour_order_construction, construct] {
        let route = build(&inst);
        assert_eq!(check(&inst, &route), vec![]);
        assert_eq!(build(&inst), route);
    }
    assert_eq!(insertion_in_order(&inst, Some(3)), insertion_in_order(&inst, Some(3)));
}

#[test]
fn repair_mends_relaxed_sheet_routes_trying_few_places() {
    use crate::plan::ecp::ils::{relaxed_route, repaired};
    let mut mended = 0;
    for seed in 0..8 {
        let inst = sheet::generate(&SheetParams::with_target(600), seed);
        let route = relaxed_route(&inst, seed, 3000);
        let broken = check(&inst, &route).len();
        assert!(broken > 3, "seed {seed}: the relaxed search broke {broken} rules");
        let (ok, route, cost, violations) = repaired(&inst, route, &TimeCap::none());
        assert!((cost - inst.cost(&route)).abs() < 1e-6, "seed {seed}");
        assert_eq!(violations, check(&inst, &route).len(), "seed {seed}");
        assert_eq!(ok, violations == 0, "seed {seed}");
        mended += usize::from(ok);
    }
    assert!(mended >= 7, "{mended} of 8 mended");
}

#[test]
fn past_the_time_cap_the_mending_and_the_search_give_up_with_a_feasible_route() {
    use crate::plan::ecp::ils::{relaxed_route, repaired};
    use crate::plan::stop::SearchStop;
    use std::time::Duration;
    let inst = sheet::generate(&SheetParams::with_target(600), 1);
    let route = relaxed_route(&inst, 1, 3000);
    assert!(!check(&inst, &route).is_empty());
    let cap = TimeCap::after(Some(Duration::ZERO));
    assert!(!repaired(&inst, route, &cap).0);
    assert_eq!(cap.stop(), SearchStop::TimeLimit);
    // Both starts, the cap reached before anything: no insertion (cut
    // short), contour order instead, no kicks, and every rule kept.
    let inst = sheet::generate(&SheetParams::with_target(3000), 2);
    for start in [Start::Relaxed, Start::Insertion] {
        let cap = TimeCap::after(Some(Duration::ZERO));
        let found = search_from(&inst, start, &SearchOptions::new(), &cap);
        assert_eq!(check(&inst, &found.route), vec![], "{start:?}");
        assert_eq!((found.iterations, found.stopped_by), (0, SearchStop::TimeLimit), "{start:?}");
    }
}
