//! TSPLIB instances and their optimal tours, turned into cutting instances
//! for `bench ecp` (issues 4 and 25). By default precedence-constrained:
//! * every city is an element of zero length;
//! * cities are grouped at random (seeded) into contours of 3 to 8 cities,
//!   not contiguous on the tour;
//! * common cuts (a city shared by a second contour) and inner/outer pairs are
//!   added at random, but only where the optimal tour satisfies them, so the
//!   optimal tour stays feasible and its length stays the optimum;
//! * the route starts and ends at the tour's first city;
//! * there is no pierce cost (every city is its own cut anyway).
//!
//! Or the plain TSP ([`plain_instance`], `--no-precedence`): the same cities,
//! each its own contour, no precedence at all, the route from a city round
//! to it: a closed tour, the same problem public TSP solvers solve.
//!
//! Distances are TSPLIB 95's, computed exactly as its documentation (and its
//! FAQ, for GEO) defines them: EUC_2D (Euclidean, rounded to the nearest
//! integer), CEIL_2D (rounded up), ATT (pseudo-Euclidean) and GEO
//! (geographical, from DDD.MM coordinates); any other EDGE_WEIGHT_TYPE is
//! refused by name.

use std::path::Path;

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};

use crate::plan::ecp::{checker, Cut, Element, Instance, Metric};
use crate::error::{Error, Result};
use crate::job::Point;

/// The EDGE_WEIGHT_TYPEs read, each as its [`Metric`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EdgeWeight {
    Euc2d,
    Ceil2d,
    Att,
    Geo,
}

impl EdgeWeight {
    fn parse(s: &str) -> Option<EdgeWeight> {
        match s {
            "EUC_2D" => Some(EdgeWeight::Euc2d),
            "CEIL_2D" => Some(EdgeWeight::Ceil2d),
            "ATT" => Some(EdgeWeight::Att),
            "GEO" => Some(EdgeWeight::Geo),
            _ => None,
        }
    }

    /// Its name in TSPLIB files.
    pub fn name(self) -> &'static str {
        match self {
            EdgeWeight::Euc2d => "EUC_2D",
            EdgeWeight::Ceil2d => "CEIL_2D",
            EdgeWeight::Att => "ATT",
            EdgeWeight::Geo => "GEO",
        }
    }

    pub fn metric(self) -> Metric {
        match self {
            EdgeWeight::Euc2d => Metric::TsplibRounded,
            EdgeWeight::Ceil2d => Metric::TsplibCeil,
            EdgeWeight::Att => Metric::TsplibAtt,
            EdgeWeight::Geo => Metric::TsplibGeo,
        }
    }

    /// A city's point as its metric reads it, from the file's coordinates:
    /// themselves for EUC_2D and CEIL_2D, a quarter of them for ATT (exact),
    /// (latitude, longitude) in radians for GEO.
    fn point(self, x: f64, y: f64) -> Point {
        match self {
            EdgeWeight::Euc2d | EdgeWeight::Ceil2d => Point::new(x, y),
            EdgeWeight::Att => Point::new(x / 4.0, y / 4.0),
            EdgeWeight::Geo => Point::new(geo_radians(x), geo_radians(y)),
        }
    }
}

/// A GEO coordinate DDD.MM (degrees, then minutes as the fraction's two
/// digits) in radians, as TSPLIB's FAQ computes it: the degrees truncated,
/// and TSPLIB's own value of pi.
fn geo_radians(v: f64) -> f64 {
    #[allow(clippy::approx_constant)]
    const PI: f64 = 3.141592;
    let degrees = v.trunc();
    let minutes = v - degrees;
    PI * (degrees + 5.0 * minutes / 3.0) / 180.0
}

/// An optimum the .tsp file states (an `OPTIMAL :` or `BEST_KNOWN :` line).
#[derive(Debug, Clone, PartialEq)]
pub struct Stated {
    pub length: f64,
    /// `file:line (KEY)`, for messages.
    pub place: String,
}

/// A TSPLIB instance of one of the [`EdgeWeight`] types.
#[derive(Debug, Clone)]
pub struct Tsp {
    pub name: String,
    pub weight: EdgeWeight,
    /// The cities as the metric reads them ([`EdgeWeight::point`]).
    pub cities: Vec<Point>,
    pub stated: Option<Stated>,
}

/// Most cities a .tsp may have here.
pub const MAX_CITIES: usize = 1_000_000;
/// Longest optimum a .tsp or `--optimum` may state.
pub const MAX_OPTIMUM: u64 = 1_000_000_000_000;

fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::Io(format!("{}: cannot read: {e}", path.display())))
}

/// Reads a `.tsp` file of TYPE TSP with a NODE_COORD_SECTION and one of the
/// [`EdgeWeight`] types; ids may be zero-padded, coordinates in exponent form.
pub fn read_tsp(path: &Path) -> Result<Tsp> {
    let text = read(path)?;
    let at = |n: usize, what: &str| Error::Plan(format!("{}:{n}: {what}", path.display()));
    let (mut name, mut dimension, mut weight, mut stated): (String, Option<usize>, Option<EdgeWeight>, Option<Stated>) = (String::new(), None, None, None);
    let mut cities: Vec<Option<Point>> = Vec::new();
    // Outside any section, in the coordinates, or in another section (skipped).
    #[derive(PartialEq)]
    enum Part {
        Header,
        Coords,
        Other,
    }
    let mut part = Part::Header;
    let mut seen_coords = false;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        let n = i + 1;
        if line.is_empty() {
            continue;
        }
        if line == "EOF" {
            break;
        }
        if line.starts_with("NODE_COORD_SECTION") {
            let d = dimension.ok_or_else(|| at(n, "NODE_COORD_SECTION before DIMENSION"))?;
            weight.ok_or_else(|| at(n, "NODE_COORD_SECTION before EDGE_WEIGHT_TYPE"))?;
            if seen_coords {
                return Err(at(n, "a second NODE_COORD_SECTION"));
            }
            cities = vec![None; d];
            part = Part::Coords;
            seen_coords = true;
            continue;
        }
        if line.ends_with("_SECTION") || line.split_once(':').is_some_and(|(k, _)| k.trim().ends_with("_SECTION")) {
            part = Part::Other;
            continue;
        }
        if part == Part::Other {
            continue;
        }
        if part == Part::Coords {
            let f: Vec<&str> = line.split_whitespace().collect();
            let num = |s: &str| s.parse::<f64>().ok().filter(|v| v.is_finite());
            let (Some(id), Some(x), Some(y), 3) = (f.first().and_then(|s| s.parse::<usize>().ok()), f.get(1).and_then(|s| num(s)), f.get(2).and_then(|s| num(s)), f.len()) else {
                return Err(at(n, &format!("expected `id x y`, got `{line}`")));
            };
            if id == 0 || id > cities.len() {
                return Err(at(n, &format!("city {id} outside 1..={}", cities.len())));
            }
            if cities[id - 1].is_some() {
                return Err(at(n, &format!("city {id} given twice")));
            }
            let w = weight.expect("checked at NODE_COORD_SECTION");
            cities[id - 1] = Some(w.point(x, y));
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            return Err(at(n, &format!("expected `KEY : value`, got `{line}`")));
        };
        let (key, value) = (key.trim(), value.trim());
        match key {
            "NAME" => name = value.to_string(),
            "TYPE" if value != "TSP" => return Err(at(n, &format!("TYPE {value} is not supported (TSP is)"))),
            "DIMENSION" => {
                let d = value.parse::<usize>().ok().filter(|d| (3..=MAX_CITIES).contains(d));
                dimension = Some(d.ok_or_else(|| at(n, &format!("DIMENSION `{value}` is not a number of cities from 3 to {MAX_CITIES}")))?);
            }
            "EDGE_WEIGHT_TYPE" => {
                let w = EdgeWeight::parse(value).ok_or_else(|| at(n, &format!("EDGE_WEIGHT_TYPE {value} is not supported (EUC_2D, CEIL_2D, ATT and GEO are)")))?;
                weight = Some(w);
            }
            "OPTIMAL" | "BEST_KNOWN" => {
                let length = value.parse::<f64>().ok().filter(|v| v.fract() == 0.0 && *v >= 1.0 && *v <= MAX_OPTIMUM as f64);
                let length = length.ok_or_else(|| at(n, &format!("{key} `{value}` is not a whole length from 1 to {MAX_OPTIMUM}")))?;
                stated = Some(Stated { length, place: format!("{}:{n} ({key})", path.display()) });
            }
            _ => {}
        }
    }
    if !seen_coords {
        return Err(Error::Plan(format!("{}: no NODE_COORD_SECTION", path.display())));
    }
    let missing = cities.iter().position(Option::is_none);
    if let Some(i) = missing {
        return Err(Error::Plan(format!("{}: city {} has no coordinates", path.display(), i + 1)));
    }
    let weight = weight.expect("checked at NODE_COORD_SECTION");
    Ok(Tsp { name, weight, cities: cities.into_iter().flatten().collect(), stated })
}

/// Reads a `.tour` file: the cities (0-based) in tour order; it must visit each
/// of the `cities` exactly once.
pub fn read_tour(path: &Path, cities: usize) -> Result<Vec<usize>> {
    let text = read(path)?;
    let mut tour = Vec::with_capacity(cities);
    let mut in_tour = false;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.starts_with("TOUR_SECTION") {
            in_tour = true;
            continue;
        }
        if !in_tour || line.is_empty() {
            continue;
        }
        if line == "-1" || line == "EOF" {
            break;
        }
        for word in line.split_whitespace() {
            let id: i64 = word.parse().map_err(|_| Error::Plan(format!("{}:{}: bad city `{word}`", path.display(), i + 1)))?;
            if id == -1 {
                break;
            }
            if id < 1 || id as usize > cities {
                return Err(Error::Plan(format!("{}:{}: city {id} outside 1..={cities}", path.display(), i + 1)));
            }
            tour.push(id as usize - 1);
        }
    }
    let mut seen = vec![false; cities];
    for &c in &tour {
        if std::mem::replace(&mut seen[c], true) {
            return Err(Error::Plan(format!("{}: city {} appears twice", path.display(), c + 1)));
        }
    }
    if tour.len() != cities {
        return Err(Error::Plan(format!("{}: the tour has {} cities, the instance {cities}", path.display(), tour.len())));
    }
    Ok(tour)
}

/// A benchmark instance and the route that is optimal for it.
#[derive(Debug, Clone)]
pub struct BenchInstance {
    pub instance: Instance,
    /// The optimal tour as a route (from the depot city round to it).
    pub optimal_route: Vec<Cut>,
    /// Its length: the tour's length in TSPLIB's metric.
    pub optimum: f64,
}

/// Builds the precedence-constrained instance of `tsp` whose optimum is `tour`
/// (see the module's description), with a relation for at least every third
/// city where the tour allows it.
pub fn bench_instance(tsp: &Tsp, tour: &[usize], seed: u64) -> BenchInstance {
    let n = tsp.cities.len();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let elements: Vec<Element> = tsp.cities.iter().map(|&p| Element { a: p, b: p }).collect();
    let mut position = vec![0usize; n];
    for (i, &c) in tour.iter().enumerate() {
        position[c] = i;
    }

    // Contours of 3 to 8 random cities (never leaving a tail of 1 or 2).
    let mut shuffled: Vec<usize> = (0..n).collect();
    shuffled.shuffle(&mut rng);
    let mut contours: Vec<Vec<usize>> = Vec::new();
    let mut rest = &shuffled[..];
    while !rest.is_empty() {
        let mut take = rng.random_range(3..=8).min(rest.len());
        if (1..3).contains(&(rest.len() - take)) {
            take = if rest.len() <= 8 { rest.len() } else { rest.len() - 3 };
        }
        contours.push(rest[..take].to_vec());
        rest = &rest[take..];
    }

    let closes = |c: &[usize]| c.iter().map(|&e| position[e]).max().unwrap_or(0);
    let mut owners = vec![1u8; n];
    let mut has_outer = vec![false; contours.len()];
    let mut inner_outer: Vec<(usize, usize)> = Vec::new();
    let mut common = 0usize;
    let target = n.div_ceil(3);
    let k = contours.len();
    for attempt in 0..50 * n {
        if inner_outer.len() + common >= target || k < 2 {
            break;
        }
        let (a, b) = (rng.random_range(0..k), rng.random_range(0..k));
        if a == b {
            continue;
        }
        if attempt % 2 == 0 {
            // A city of `a` shared with `b`: fine unless it would close both.
            let city = contours[a][rng.random_range(0..contours[a].len())];
            if owners[city] > 1 || contours[b].contains(&city) {
                continue;
            }
            let last_of_a = closes(&contours[a]) == position[city];
            let last_of_b = closes(&contours[b]).max(position[city]) == position[city];
            // `b` may now close later: it must still close before its outer.
            let b_closes = closes(&contours[b]).max(position[city]);
            let breaks_outer = inner_outer.iter().any(|&(i, o)| i == b && b_closes >= closes(&contours[o]));
            if (last_of_a && last_of_b) || breaks_outer {
                continue;
            }
            contours[b].push(city);
            owners[city] += 1;
            common += 1;
        } else {
            // `a` inside `b`: the tour must finish `a` before it closes `b`.
            if has_outer[a] || inner_outer.iter().any(|&(i, o)| (i, o) == (b, a)) {
                continue;
            }
            if closes(&contours[a]) >= closes(&contours[b]) {
                continue;
            }
            has_outer[a] = true;
            inner_outer.push((a, b));
        }
    }

    let instance = Instance {
        elements,
        contours,
        inner_outer,
        depot: tsp.cities[tour[0]],
        metric: tsp.weight.metric(),
        pierce_cost: 0.0,
        edge_starts: Vec::new(),
        turns: crate::plan::ecp::Turns::default(),
        penalties: Default::default(),
    };
    let optimal_route = tour_route(tour);
    let optimum = instance.cost(&optimal_route);
    debug_assert!(checker::check(&instance, &optimal_route).is_empty());
    BenchInstance { instance, optimal_route, optimum }
}

/// The plain TSP of `tsp`: every city its own contour, no inner/outer pair,
/// no common cut; the route starts and ends at city `depot` (0-based), so
/// its cost is that of a closed tour through all the cities.
pub fn plain_instance(tsp: &Tsp, depot: usize) -> Instance {
    Instance {
        elements: tsp.cities.iter().map(|&p| Element { a: p, b: p }).collect(),
        contours: (0..tsp.cities.len()).map(|c| vec![c]).collect(),
        inner_outer: Vec::new(),
        depot: tsp.cities[depot],
        metric: tsp.weight.metric(),
        pierce_cost: 0.0,
        edge_starts: Vec::new(),
        turns: crate::plan::ecp::Turns::default(),
        penalties: Default::default(),
    }
}

/// A tour (0-based cities) as a route of either instance.
pub fn tour_route(tour: &[usize]) -> Vec<Cut> {
    tour.iter().map(|&element| Cut { element, reversed: false }).collect()
}

/// An optimum given for the instance, and where (for messages: "given
/// with --optimum", "of pr2392.tsp:2 (OPTIMAL)").
#[derive(Debug, Clone, PartialEq)]
pub struct Published {
    pub length: f64,
    pub given: String,
}

/// Refuses a tour whose length (in the instance's metric) is not the
/// published optimum: a longer one would make the gap look smaller than it
/// is, a shorter one means a wrong instance or a wrong figure.
pub fn check_tour_length(tour: &Path, length: f64, published: &Published) -> Result<()> {
    let (tour, p, given) = (tour.display(), published.length, &published.given);
    if length > p {
        return Err(Error::Config(format!("bench ecp: {tour} is {length} long, not the optimum {p} {given}: the gap would be false")));
    }
    if length < p {
        return Err(Error::Config(format!("bench ecp: {tour} is {length} long, shorter than the optimum {p} {given}: a wrong instance or a wrong figure")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn bench_file(name: &str) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/tsplib").join(name)
    }

    #[test]
    fn a280_keeps_its_published_optimum_under_the_precedences() {
        let tsp = read_tsp(&bench_file("a280.tsp")).unwrap();
        assert_eq!((tsp.name.as_str(), tsp.cities.len()), ("a280", 280));
        let tour = read_tour(&bench_file("a280.opt.tour"), 280).unwrap();
        for seed in 1..=5 {
            let b = bench_instance(&tsp, &tour, seed);
            assert_eq!(b.optimum, 2579.0, "TSPLIB's optimum for a280");
            assert!(checker::check(&b.instance, &b.optimal_route).is_empty());
            assert!(b.instance.precedences() * 3 >= 280, "{} relations", b.instance.precedences());
            assert!(!b.instance.inner_outer.is_empty() && !b.instance.common_cuts().is_empty());
            // Every city on one contour of 3 to 8, plus the shared ones.
            let sizes: usize = b.instance.contours.iter().map(Vec::len).sum();
            assert_eq!(sizes, 280 + b.instance.common_cuts().len());
            assert!(b.instance.contours.iter().all(|c| c.len() >= 3));
        }
        // Different seeds, different instances.
        let (x, y) = (bench_instance(&tsp, &tour, 1), bench_instance(&tsp, &tour, 2));
        assert_ne!(x.instance.contours, y.instance.contours);
    }

    #[test]
    fn pr1002_optimum() {
        let tsp = read_tsp(&bench_file("pr1002.tsp")).unwrap();
        let tour = read_tour(&bench_file("pr1002.opt.tour"), tsp.cities.len()).unwrap();
        let b = bench_instance(&tsp, &tour, 3);
        assert_eq!(b.optimum, 259045.0);
        assert!(checker::check(&b.instance, &b.optimal_route).is_empty());
    }

    /// ATT (att48) and GEO (gr666, zero-padded ids) give TSPLIB's published
    /// optima for the optimal tours, with and without the precedences.
    #[test]
    fn att48_and_gr666_keep_their_published_optima() {
        for (name, weight, optimum) in [("att48", EdgeWeight::Att, 10628.0), ("gr666", EdgeWeight::Geo, 294358.0)] {
            let tsp = read_tsp(&bench_file(&format!("{name}.tsp"))).unwrap();
            assert_eq!((tsp.name.as_str(), tsp.weight, tsp.stated.clone()), (name, weight, None));
            let tour = read_tour(&bench_file(&format!("{name}.opt.tour")), tsp.cities.len()).unwrap();
            for seed in 1..=3 {
                let b = bench_instance(&tsp, &tour, seed);
                assert_eq!(b.instance.metric, weight.metric());
                assert_eq!(b.optimum, optimum, "{name} seed {seed}");
                assert!(checker::check(&b.instance, &b.optimal_route).is_empty());
                assert!(b.instance.precedences() > 0);
            }
            let plain = plain_instance(&tsp, tour[0]);
            assert_eq!(plain.cost(&tour_route(&tour)), optimum, "{name} as a plain TSP");
        }
        // Euclidean rounding of the same att48 cities is another (wrong) length.
        let mut att = read_tsp(&bench_file("att48.tsp")).unwrap();
        att.cities.iter_mut().for_each(|p| *p *= 4.0);
        att.weight = EdgeWeight::Euc2d;
        let tour = read_tour(&bench_file("att48.opt.tour"), 48).unwrap();
        assert_eq!(plain_instance(&att, tour[0]).cost(&tour_route(&tour)), 33522.0);
    }

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let f = dir.join(name);
        std::fs::write(&f, text).unwrap();
        f
    }

    /// CEIL_2D, ATT and GEO on a few cities whose distances are worked out
    /// by hand from TSPLIB 95's definitions.
    #[test]
    fn ceil_att_and_geo_distances_by_hand() {
        let dir = tempfile::tempdir().unwrap();
        let tsp = |weight: &str, coords: &str| {
            let n = coords.lines().count();
            read_tsp(&write(dir.path(), "h.tsp", &format!("NAME : h\nTYPE : TSP\nDIMENSION : {n}\nEDGE_WEIGHT_TYPE : {weight}\nNODE_COORD_SECTION\n{coords}\nEOF\n"))).unwrap()
        };
        let length = |t: &Tsp| plain_instance(t, 0).cost(&tour_route(&(0..t.cities.len()).collect::<Vec<_>>()));
        let d = |t: &Tsp, i: usize, j: usize| {
            let inst = plain_instance(t, 0);
            let (a, b) = (inst.distance(t.cities[i], t.cities[j]), inst.distance(t.cities[j], t.cities[i]));
            assert_eq!(a, b, "symmetric");
            a
        };
        // CEIL_2D: √2 → 2 (EUC_2D: 1), 2 → 2, 5 → 5.
        let ceil = tsp("CEIL_2D", "1 0 0\n2 1 1\n3 2 0\n4 5 4");
        assert_eq!((d(&ceil, 0, 1), d(&ceil, 1, 2), d(&ceil, 0, 2), d(&ceil, 2, 3), d(&ceil, 0, 0)), (2.0, 2.0, 2.0, 5.0, 0.0));
        assert_eq!(length(&ceil), 2.0 + 2.0 + 5.0 + 7.0, "(5, 4) back to (0, 0): √41 = 6.40 → 7");
        // ATT: r = √((dx² + dy²) / 10): (10, 0) → √10 = 3.16 → 3 < r → 4;
        // (20, 10) → √50 = 7.07 → 8; (30, 10) → exactly 10 → 10.
        let att = tsp("ATT", "1 0 0\n2 10 0\n3 30 10");
        assert_eq!((d(&att, 0, 1), d(&att, 1, 2), d(&att, 0, 2), d(&att, 2, 2)), (4.0, 8.0, 10.0, 0.0));
        assert_eq!(length(&att), 22.0);
        // GEO, DDD.MM: 0°30' along the equator is 6378.388 · 3.141592 ·
        // 0.5 / 180 = 55.66 km → 56; 12°59' to 12°00' (truncated degrees:
        // 0.9833°) 109.47 → 110 (rounded degrees would give 36); the same
        // south and along a meridian; ids zero-padded, exponent notation.
        let geo = tsp("GEO", "0001 0.00 0.00\n0002 3.0e-01 0.00\n0003 12.59 0\n0004 1.2e+01 0.0\n0005 -12.59 0\n0006 -12.00 0\n0007 0 0.30");
        assert_eq!((d(&geo, 0, 1), d(&geo, 2, 3), d(&geo, 4, 5), d(&geo, 0, 6), d(&geo, 3, 3)), (56.0, 110.0, 110.0, 56.0, 0.0));
        assert!(d(&geo, 0, 2) > 1000.0 && d(&geo, 2, 4) > 2000.0);
    }

    #[test]
    fn the_plain_tsp_has_no_precedence_and_any_order_is_feasible() {
        let tsp = read_tsp(&bench_file("a280.tsp")).unwrap();
        let tour = read_tour(&bench_file("a280.opt.tour"), 280).unwrap();
        let inst = plain_instance(&tsp, tour[0]);
        assert_eq!((inst.elements.len(), inst.contours.len(), inst.precedences()), (280, 280, 0));
        assert!(inst.contours.iter().enumerate().all(|(i, c)| c == &vec![i]));
        assert_eq!(inst.depot, tsp.cities[tour[0]]);
        let route = tour_route(&tour);
        assert_eq!(inst.cost(&route), 2579.0, "a closed tour from the depot city: the optimum");
        let backwards: Vec<Cut> = route.iter().rev().copied().collect();
        assert!(checker::check(&inst, &backwards).is_empty(), "any order is feasible");
        // The precedence-constrained one from the same tour is not that free.
        let b = bench_instance(&tsp, &tour, 1);
        assert!(!checker::check(&b.instance, &backwards).is_empty());
    }

    #[test]
    fn a_stated_optimum_is_read_and_the_tour_must_be_that_long() {
        let dir = tempfile::tempdir().unwrap();
        let a280 = std::fs::read_to_string(bench_file("a280.tsp")).unwrap();
        let f = write(dir.path(), "a.tsp", &a280.replacen("COMMENT", "OPTIMAL : 2579\nCOMMENT", 1));
        let tsp = read_tsp(&f).unwrap();
        let place = format!("{}:2 (OPTIMAL)", f.display());
        assert_eq!(tsp.stated, Some(Stated { length: 2579.0, place: place.clone() }));
        let f = write(dir.path(), "b.tsp", &a280.replacen("COMMENT", "BEST_KNOWN: 2600\nCOMMENT", 1));
        assert_eq!(read_tsp(&f).unwrap().stated.map(|s| s.length), Some(2600.0));
        let f = write(dir.path(), "c.tsp", &a280.replacen("COMMENT", "OPTIMAL : 25.5\nCOMMENT", 1));
        let e = read_tsp(&f).unwrap_err().to_string();
        assert!(e.contains("c.tsp:2: OPTIMAL `25.5` is not a whole length"), "{e}");

        let tour = Path::new("a280.opt.tour");
        let published = Published { length: 2579.0, given: "given with --optimum".into() };
        assert!(check_tour_length(tour, 2579.0, &published).is_ok());
        let long = check_tour_length(tour, 2580.0, &published).unwrap_err().to_string();
        assert!(long.contains("a280.opt.tour is 2580 long, not the optimum 2579 given with --optimum: the gap would be false"), "{long}");
        let short = check_tour_length(tour, 2578.0, &Published { length: 2579.0, given: format!("of {place}") }).unwrap_err().to_string();
        assert!(short.contains("a280.opt.tour is 2578 long, shorter than the optimum 2579 of ") && short.contains("a.tsp:2 (OPTIMAL)"), "{short}");
    }

    #[test]
    fn bad_files_name_the_place() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("x.tsp");
        for weight in ["MAN_2D", "EXPLICIT", "EUC_3D", "MAX_2D", "XRAY1", "GEOM"] {
            std::fs::write(&f, format!("NAME : x\nDIMENSION : 3\nEDGE_WEIGHT_TYPE : {weight}\nNODE_COORD_SECTION\n1 0 0\n2 1 1\n3 2 2\n")).unwrap();
            let e = read_tsp(&f).unwrap_err().to_string();
            assert!(e.contains(&format!("x.tsp:3: EDGE_WEIGHT_TYPE {weight} is not supported (EUC_2D, CEIL_2D, ATT and GEO are)")), "{e}");
        }
        let cases = [
            ("DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n2 1 nan\n3 0 0\n", "x.tsp:5: expected `id x y`"),
            ("DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n1 1 1\n3 0 0\n", "x.tsp:5: city 1 given twice"),
            ("DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n0004 1 1\n", "x.tsp:5: city 4 outside 1..=3"),
            ("DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n3 1 1\n", "x.tsp: city 2 has no coordinates"),
            ("DIMENSION : 3\nNODE_COORD_SECTION\n1 0 0\n", "x.tsp:2: NODE_COORD_SECTION before EDGE_WEIGHT_TYPE"),
            ("TYPE : ATSP\nDIMENSION : 3\n", "x.tsp:1: TYPE ATSP is not supported (TSP is)"),
            ("DIMENSION : 2\n", "x.tsp:1: DIMENSION `2` is not a number of cities from 3 to"),
            ("DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\n", "x.tsp: no NODE_COORD_SECTION"),
        ];
        for (text, expected) in cases {
            std::fs::write(&f, text).unwrap();
            let e = read_tsp(&f).unwrap_err().to_string();
            assert!(e.contains(expected), "{expected}: {e}");
        }
        // A display section after the coordinates is skipped.
        std::fs::write(&f, "DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n2 3 4\n3 0 4\nDISPLAY_DATA_SECTION\n1 5 5\nEOF\n").unwrap();
        assert_eq!(read_tsp(&f).unwrap().cities[1], Point::new(3.0, 4.0));
        let t = dir.path().join("x.tour");
        std::fs::write(&t, "TOUR_SECTION\n1\n1\n-1\n").unwrap();
        assert!(read_tour(&t, 2).unwrap_err().to_string().contains("appears twice"));
        std::fs::write(&t, "TOUR_SECTION\n1\n3\n-1\n").unwrap();
        assert!(read_tour(&t, 2).unwrap_err().to_string().contains("x.tour:3: city 3"));
    }
}
