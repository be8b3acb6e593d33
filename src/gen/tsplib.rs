//! TSPLIB instances (EUC_2D) and their optimal tours, turned into
//! precedence-constrained cutting instances for `bench ecp` (issue 4):
//! * every city is an element of zero length;
//! * cities are grouped at random (seeded) into contours of 3 to 8 cities,
//!   not contiguous on the tour;
//! * common cuts (a city shared by a second contour) and inner/outer pairs are
//!   added at random, but only where the optimal tour satisfies them, so the
//!   optimal tour stays feasible and its length stays the optimum;
//! * the route starts and ends at the tour's first city;
//! * distances are TSPLIB's (Euclidean, rounded to the nearest integer), and
//!   there is no pierce cost (every city is its own cut anyway).

use std::path::Path;

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};

use crate::plan::ecp::{checker, Cut, Element, Instance, Metric};
use crate::error::{Error, Result};
use crate::job::Point;

/// A TSPLIB EUC_2D instance.
#[derive(Debug, Clone)]
pub struct Tsp {
    pub name: String,
    pub cities: Vec<Point>,
}

fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::Io(format!("{}: cannot read: {e}", path.display())))
}

/// Reads a `.tsp` file with `EDGE_WEIGHT_TYPE: EUC_2D` and a `NODE_COORD_SECTION`.
pub fn read_tsp(path: &Path) -> Result<Tsp> {
    let text = read(path)?;
    let at = |n: usize, what: &str| Error::Plan(format!("{}:{n}: {what}", path.display()));
    let (mut name, mut dimension, mut weight) = (String::new(), None, None);
    let mut cities: Vec<Option<Point>> = Vec::new();
    let mut in_coords = false;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        let n = i + 1;
        if line.is_empty() {
            continue;
        }
        if line == "EOF" {
            break;
        }
        if in_coords {
            let f: Vec<&str> = line.split_whitespace().collect();
            let num = |s: &str| s.parse::<f64>().ok().filter(|v| v.is_finite());
            let (Some(id), Some(x), Some(y)) = (f.first().and_then(|s| s.parse::<usize>().ok()), f.get(1).and_then(|s| num(s)), f.get(2).and_then(|s| num(s))) else {
                return Err(at(n, &format!("expected `id x y`, got `{line}`")));
            };
            if id == 0 || id > cities.len() {
                return Err(at(n, &format!("city {id} outside 1..={}", cities.len())));
            }
            cities[id - 1] = Some(Point::new(x, y));
            continue;
        }
        if line.starts_with("NODE_COORD_SECTION") {
            let d = dimension.ok_or_else(|| at(n, "NODE_COORD_SECTION before DIMENSION"))?;
            if weight.as_deref() != Some("EUC_2D") {
                return Err(at(n, &format!("EDGE_WEIGHT_TYPE {} is not supported (EUC_2D only)", weight.as_deref().unwrap_or("missing"))));
            }
            cities = vec![None; d];
            in_coords = true;
            continue;
        }
        if let Some((key, value)) = line.split_once(':') {
            let value = value.trim();
            match key.trim() {
                "NAME" => name = value.to_string(),
                "DIMENSION" => dimension = Some(value.parse::<usize>().map_err(|_| at(n, &format!("bad DIMENSION `{value}`")))?),
                "EDGE_WEIGHT_TYPE" => weight = Some(value.to_string()),
                _ => {}
            }
        }
    }
    if !in_coords {
        return Err(Error::Plan(format!("{}: no NODE_COORD_SECTION", path.display())));
    }
    let missing = cities.iter().position(Option::is_none);
    if let Some(i) = missing {
        return Err(Error::Plan(format!("{}: city {} has no coordinates", path.display(), i + 1)));
    }
    Ok(Tsp { name, cities: cities.into_iter().flatten().collect() })
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
        metric: Metric::TsplibRounded,
        pierce_cost: 0.0,
        edge_starts: Vec::new(),
        turns: crate::plan::ecp::Turns::default(),
        penalties: Default::default(),
    };
    let optimal_route: Vec<Cut> = tour.iter().map(|&element| Cut { element, reversed: false }).collect();
    let optimum = instance.cost(&optimal_route);
    debug_assert!(checker::check(&instance, &optimal_route).is_empty());
    BenchInstance { instance, optimal_route, optimum }
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

    #[test]
    fn bad_files_name_the_place() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("x.tsp");
        std::fs::write(&f, "NAME : x\nDIMENSION : 2\nEDGE_WEIGHT_TYPE : GEO\nNODE_COORD_SECTION\n1 0 0\n2 1 1\n").unwrap();
        assert!(read_tsp(&f).unwrap_err().to_string().contains("x.tsp:4: EDGE_WEIGHT_TYPE GEO"));
        std::fs::write(&f, "DIMENSION : 2\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n2 1 nan\n").unwrap();
        assert!(read_tsp(&f).unwrap_err().to_string().contains("x.tsp:5"));
        let t = dir.path().join("x.tour");
        std::fs::write(&t, "TOUR_SECTION\n1\n1\n-1\n").unwrap();
        assert!(read_tour(&t, 2).unwrap_err().to_string().contains("appears twice"));
        std::fs::write(&t, "TOUR_SECTION\n1\n3\n-1\n").unwrap();
        assert!(read_tour(&t, 2).unwrap_err().to_string().contains("x.tour:3: city 3"));
    }
}
