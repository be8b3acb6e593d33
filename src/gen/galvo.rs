//! Generated jobs of seed 003's galvo benchmark: a scanner with a 70 x 70 mm
//! field on a 300 x 300 mm base stage, in the pattern families of the paper's
//! twelve test cases, written as SVG in the format of `tests/data/galvo/`
//! (mm, y down, outlines only). The twelve files fix a few sizes; this gives
//! any n (1 to [`MAX_N`]) from a seed, to study how the planners scale.
//!
//! Up to [`BASE_N`] geometries lie on the 300 x 300 mm base. Beyond, every
//! family would need smaller geometries than the benchmark's (ISW already
//! uses its smallest squares at 5000, O cannot place much more than 10,000
//! even with 1 mm squares, scattered pads would shrink below 0.3 mm near
//! 100,000), so the base grows instead ([`base_mm`]): a square of side
//! 300 √(n / 5000) mm, the density of 5000 on 300 x 300 mm (1342 mm for
//! 100,000), and by a tenth more at a time should a family still not fit.
//! A job on a grown base needs a machine config whose stage travel covers it.
//!
//! * [`Family::Rnd`]: rectangles of mixed sizes (mostly small pads, a few
//!   large) scattered without overlap (stencil-like cutting jobs). The spread,
//!   hence the number of fields, is drawn from the seed.
//! * [`Family::O`]: small squares on concentric elliptical rings: one letter
//!   "O", or several when n is large (ordered marking jobs, a logo).
//! * [`Family::Isw`]: small squares along the strokes of the letters I, S and
//!   W, the word repeated when n is large.
//! * [`Family::Mixed`]: like `Rnd`, sparser, with circles, ellipses, open
//!   polylines, polygons and open or closed paths among the rectangles, as in
//!   SC82C24.
//!
//! Every geometry is much smaller than a field and lies inside the base with
//! a 4 mm border; no two bounding boxes touch. The output depends only on
//! (family, n, seed).

use std::collections::HashMap;
use std::f64::consts::PI;
use std::fmt::{self, Write as _};
use std::str::FromStr;

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Side of the base stroke (mm), up to [`BASE_N`] geometries.
pub const BASE_MM: f64 = 300.0;
/// Most geometries on a base of [`BASE_MM`]; beyond, the base grows ([`base_mm`]).
pub const BASE_N: usize = 5000;
/// Side of the scanner field (mm).
pub const FIELD_MM: f64 = 70.0;
/// Largest number of geometries [`generate`] makes.
pub const MAX_N: usize = 100_000;
/// Free border inside the base (mm).
const MARGIN: f64 = 4.0;

/// The side of the base `n` geometries are first laid out on (mm): 300 up to
/// [`BASE_N`], then growing with √n so that the density stays that of
/// [`BASE_N`] on 300 x 300 mm (whole mm).
pub fn base_mm(n: usize) -> f64 {
    if n <= BASE_N {
        BASE_MM
    } else {
        (BASE_MM * (n as f64 / BASE_N as f64).sqrt()).ceil()
    }
}
/// Largest side of a scattered geometry (mm), as in the benchmark files.
const MAX_SIDE: f64 = 15.0;

/// A pattern family of the paper's test cases.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum Family {
    Rnd,
    O,
    Isw,
    Mixed,
}

impl Family {
    pub const ALL: [Family; 4] = [Family::Rnd, Family::O, Family::Isw, Family::Mixed];

    pub fn name(self) -> &'static str {
        match self {
            Family::Rnd => "rnd",
            Family::O => "O",
            Family::Isw => "ISW",
            Family::Mixed => "mixed",
        }
    }
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Family {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "rnd" => Ok(Family::Rnd),
            "o" => Ok(Family::O),
            "isw" => Ok(Family::Isw),
            "mixed" => Ok(Family::Mixed),
            _ => Err(format!("unknown family '{s}' (choices: rnd, o, isw, mixed)")),
        }
    }
}

/// The SVG text of an instance of `family` with exactly `n` geometries.
pub fn generate(family: Family, n: usize, seed: u64) -> Result<String, String> {
    if n == 0 || n > MAX_N {
        return Err(format!("n must be between 1 and {MAX_N}, got {n}"));
    }
    // On the base of `base_mm`, else on one a tenth larger, and so on (a
    // few steps at most: the families hold about 2 to 4 times BASE_N on 300 mm).
    let mut base = base_mm(n);
    let shapes = loop {
        let usable = base - 2.0 * MARGIN;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let shapes = match family {
            Family::Rnd => scatter(&mut rng, n, false, usable),
            Family::Mixed => scatter(&mut rng, n, true, usable),
            Family::O => o_letters(&mut rng, n, usable),
            Family::Isw => isw_words(&mut rng, n, usable),
        };
        match shapes {
            Ok(shapes) => break shapes,
            Err(_) if base < 2.0 * base_mm(n) => base = (1.1 * base).ceil(),
            Err(e) => return Err(e),
        }
    };
    if shapes.len() != n {
        return Err(format!("{family}: made {} geometries instead of {n}", shapes.len()));
    }
    let mut out = String::with_capacity(60 * n + 300);
    out.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let grown = if base > BASE_MM { format!(", base {} mm", num(base)) } else { String::new() };
    let _ = writeln!(out, "<!-- laserd gen galvo ({family}, N={n}, seed={seed}{grown}) -->");
    let _ = writeln!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{b}mm\" height=\"{b}mm\" viewBox=\"0 0 {b} {b}\" \
         fill=\"none\" stroke=\"black\" stroke-width=\"0.1\">",
        b = num(base)
    );
    for s in &shapes {
        s.write_svg(&mut out);
    }
    out.push_str("</svg>\n");
    Ok(out)
}

type P = (f64, f64);

/// An axis-aligned box (mm).
#[derive(Debug, Clone, Copy)]
struct Bounds {
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
}

impl Bounds {
    fn of(points: impl IntoIterator<Item = P>) -> Bounds {
        let mut b = Bounds { x0: f64::INFINITY, y0: f64::INFINITY, x1: f64::NEG_INFINITY, y1: f64::NEG_INFINITY };
        for (x, y) in points {
            b.x0 = b.x0.min(x);
            b.y0 = b.y0.min(y);
            b.x1 = b.x1.max(x);
            b.y1 = b.y1.max(y);
        }
        b
    }
    fn w(&self) -> f64 {
        self.x1 - self.x0
    }
    fn h(&self) -> f64 {
        self.y1 - self.y0
    }
    /// Clearance to `o` along x or y (negative when they overlap).
    fn gap_to(&self, o: &Bounds) -> f64 {
        (o.x0 - self.x1).max(self.x0 - o.x1).max(o.y0 - self.y1).max(self.y0 - o.y1)
    }
}

/// One geometry, in the SVG elements the benchmark files use.
#[derive(Debug, Clone)]
enum Shape {
    Rect { x: f64, y: f64, w: f64, h: f64 },
    Circle { c: P, r: f64 },
    Ellipse { c: P, rx: f64, ry: f64 },
    Polyline(Vec<P>),
    Polygon(Vec<P>),
    Path { points: Vec<P>, closed: bool },
}

impl Shape {
    fn square(c: P, s: f64) -> Shape {
        Shape::Rect { x: c.0 - s / 2.0, y: c.1 - s / 2.0, w: s, h: s }
    }

    fn bounds(&self) -> Bounds {
        match self {
            Shape::Rect { x, y, w, h } => Bounds { x0: *x, y0: *y, x1: x + w, y1: y + h },
            Shape::Circle { c, r } => Bounds { x0: c.0 - r, y0: c.1 - r, x1: c.0 + r, y1: c.1 + r },
            Shape::Ellipse { c, rx, ry } => Bounds { x0: c.0 - rx, y0: c.1 - ry, x1: c.0 + rx, y1: c.1 + ry },
            Shape::Polyline(p) | Shape::Polygon(p) | Shape::Path { points: p, .. } => Bounds::of(p.iter().copied()),
        }
    }

    /// The shape scaled by `k` about the origin, then moved by `d`.
    fn transformed(&self, k: f64, d: P) -> Shape {
        let t = |p: &P| (k * p.0 + d.0, k * p.1 + d.1);
        match self {
            Shape::Rect { x, y, w, h } => Shape::Rect { x: k * x + d.0, y: k * y + d.1, w: k * w, h: k * h },
            Shape::Circle { c, r } => Shape::Circle { c: t(c), r: k * r },
            Shape::Ellipse { c, rx, ry } => Shape::Ellipse { c: t(c), rx: k * rx, ry: k * ry },
            Shape::Polyline(p) => Shape::Polyline(p.iter().map(t).collect()),
            Shape::Polygon(p) => Shape::Polygon(p.iter().map(t).collect()),
            Shape::Path { points, closed } => Shape::Path { points: points.iter().map(t).collect(), closed: *closed },
        }
    }

    fn write_svg(&self, out: &mut String) {
        let pts = |p: &[P], sep: &str, join: &str| p.iter().map(|&(x, y)| format!("{}{sep}{}", num(x), num(y))).collect::<Vec<_>>().join(join);
        let _ = match self {
            Shape::Rect { x, y, w, h } => {
                writeln!(out, "<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\"/>", num(*x), num(*y), num(*w), num(*h))
            }
            Shape::Circle { c, r } => writeln!(out, "<circle cx=\"{}\" cy=\"{}\" r=\"{}\"/>", num(c.0), num(c.1), num(*r)),
            Shape::Ellipse { c, rx, ry } => {
                writeln!(out, "<ellipse cx=\"{}\" cy=\"{}\" rx=\"{}\" ry=\"{}\"/>", num(c.0), num(c.1), num(*rx), num(*ry))
            }
            Shape::Polyline(p) => writeln!(out, "<polyline points=\"{}\"/>", pts(p, ",", " ")),
            Shape::Polygon(p) => writeln!(out, "<polygon points=\"{}\"/>", pts(p, ",", " ")),
            Shape::Path { points, closed } => {
                writeln!(out, "<path d=\"M {}{}\"/>", pts(points, " ", " L "), if *closed { " Z" } else { "" })
            }
        };
    }
}

/// A coordinate with at most 3 decimals, no trailing zeros.
fn num(v: f64) -> String {
    let r = (v * 1000.0).round() / 1000.0;
    if r == 0.0 {
        "0".to_string()
    } else {
        format!("{r}")
    }
}

/// A hasher for grid cells (two integers), much cheaper than the default's
/// SipHash, which the generators' many lookups do not need (FxHash's mix).
#[derive(Default)]
struct CellHasher(u64);

impl std::hash::Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
}

/// The boxes placed so far, bucketed on a grid, to test a new box's clearance.
struct Occupancy {
    cell: f64,
    boxes: Vec<Bounds>,
    grid: HashMap<(i64, i64), Vec<u32>, std::hash::BuildHasherDefault<CellHasher>>,
}

impl Occupancy {
    /// Cells of side `cell`: about the largest box's side keeps both the
    /// cells a box lies in and the boxes in a cell few.
    fn new(cell: f64) -> Occupancy {
        Occupancy { cell, boxes: Vec::new(), grid: HashMap::default() }
    }

    fn cells(&self, b: &Bounds) -> impl Iterator<Item = (i64, i64)> {
        let c = self.cell;
        let (i0, i1) = ((b.x0 / c).floor() as i64, (b.x1 / c).floor() as i64);
        let (j0, j1) = ((b.y0 / c).floor() as i64, (b.y1 / c).floor() as i64);
        (i0..=i1).flat_map(move |i| (j0..=j1).map(move |j| (i, j)))
    }

    /// Whether `b` keeps at least `gap` from every placed box.
    fn free(&self, b: &Bounds, gap: f64) -> bool {
        let grown = Bounds { x0: b.x0 - gap, y0: b.y0 - gap, x1: b.x1 + gap, y1: b.y1 + gap };
        self.cells(&grown).all(|k| self.grid.get(&k).is_none_or(|v| v.iter().all(|&i| self.boxes[i as usize].gap_to(b) >= gap)))
    }

    fn insert(&mut self, b: Bounds) {
        let i = u32::try_from(self.boxes.len()).expect("fewer than 2^32 boxes");
        let c = self.cell;
        let (i0, i1) = ((b.x0 / c).floor() as i64, (b.x1 / c).floor() as i64);
        let (j0, j1) = ((b.y0 / c).floor() as i64, (b.y1 / c).floor() as i64);
        for x in i0..=i1 {
            for y in j0..=j1 {
                self.grid.entry((x, y)).or_default().push(i);
            }
        }
        self.boxes.push(b);
    }
}

/// A uniform value in [lo, hi], or lo when the range is empty.
fn pick(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    if hi > lo {
        rng.random_range(lo..=hi)
    } else {
        lo
    }
}

/// Grid shapes (columns, rows) of up to `max` cells, fewest cells first; for
/// equal counts, more columns first when `wide` (tall cells), else more rows.
fn grids(max: usize, wide: bool) -> Vec<(usize, usize)> {
    let mut g: Vec<(usize, usize)> = (1..=max).flat_map(|c| (1..=max / c).map(move |r| (c, r))).collect();
    g.sort_by_key(|&(c, r)| (c * r, if wide { r } else { c }));
    g
}

// ---- rnd and mixed: scattered geometries ----------------------------------

/// `n` geometries scattered without overlap over a random rectangle of the
/// base. The mean spacing is drawn log-uniform (6 to 16 mm for `rnd`, 12 to
/// 32 mm for `mixed`; tighter when n does not fit), sizes follow it (at most
/// [`MAX_SIDE`]), clearance 1 mm (less on very dense instances).
fn scatter(rng: &mut ChaCha8Rng, n: usize, mixed: bool, usable: f64) -> Result<Vec<Shape>, String> {
    let (lo, hi): (f64, f64) = if mixed { (12.0, 32.0) } else { (6.0, 16.0) };
    let spacing = lo * (hi / lo).powf(rng.random::<f64>());
    let area = n as f64 * spacing * spacing;
    let aspect = rng.random_range(1.0..1.8);
    let (mut w, mut h) = ((area * aspect).sqrt(), (area / aspect).sqrt());
    if rng.random_bool(0.5) {
        std::mem::swap(&mut w, &mut h);
    }
    if w > usable {
        (w, h) = (usable, (area / usable).min(usable));
    }
    if h > usable {
        (w, h) = ((area / usable).min(usable), usable);
    }
    let spacing = (w * h / n as f64).sqrt();
    let u = spacing.min(11.0);
    let gap = (0.2 * spacing).min(1.0);
    let x0 = MARGIN + pick(rng, 0.0, usable - w);
    let y0 = MARGIN + pick(rng, 0.0, usable - h);
    let mut region = Bounds { x0, y0, x1: x0 + w, y1: y0 + h };
    let full = Bounds { x0: MARGIN, y0: MARGIN, x1: MARGIN + usable, y1: MARGIN + usable };

    let mut shapes: Vec<Shape> = (0..n).map(|_| if mixed { mixed_shape(rng, u) } else { rect_shape(rng, u) }).collect();
    let area_of = |s: &Shape| {
        let b = s.bounds();
        b.w() * b.h()
    };
    // Largest first: the small ones fill the gaps.
    shapes.sort_by(|a, b| area_of(b).total_cmp(&area_of(a)));
    // Cells about the largest geometry's side (2 u at most, see `mixed_shape`).
    let mut occupied = Occupancy::new((2.0 * u).min(MAX_SIDE) + 1.0);
    let mut placed = Vec::with_capacity(n);
    for mut shape in shapes {
        let mut tries = 0;
        loop {
            let b = shape.bounds();
            if b.w() <= region.w() && b.h() <= region.h() {
                let dx = pick(rng, region.x0, region.x1 - b.w()) - b.x0;
                let dy = pick(rng, region.y0, region.y1 - b.h()) - b.y0;
                let at = Bounds { x0: b.x0 + dx, y0: b.y0 + dy, x1: b.x1 + dx, y1: b.y1 + dy };
                if occupied.free(&at, gap) {
                    occupied.insert(at);
                    placed.push(shape.transformed(1.0, (dx, dy)));
                    break;
                }
            }
            tries += 1;
            if tries % 300 == 0 {
                // Crowded: spread wider, and once on the whole base, shrink.
                if region.w() < usable || region.h() < usable {
                    let (gx, gy) = (0.1 * region.w(), 0.1 * region.h());
                    region = Bounds {
                        x0: (region.x0 - gx).max(full.x0),
                        y0: (region.y0 - gy).max(full.y0),
                        x1: (region.x1 + gx).min(full.x1),
                        y1: (region.y1 + gy).min(full.y1),
                    };
                } else {
                    shape = shape.transformed(0.85, (0.0, 0.0));
                }
            }
            if tries > 12_000 {
                return Err(format!("n = {n}: cannot place that many geometries without overlap"));
            }
        }
    }
    placed.shuffle(rng);
    Ok(placed)
}

/// A pad size on the scale `u`: 80 % small (0.18 to 0.5 u), 20 % large (0.5 to 1.3 u).
fn pad_size(rng: &mut ChaCha8Rng, u: f64) -> f64 {
    u * if rng.random_bool(0.8) { rng.random_range(0.18..0.5) } else { rng.random_range(0.5..1.3) }
}

/// A rectangle of side ratio up to about 2.4.
fn rect_shape(rng: &mut ChaCha8Rng, u: f64) -> Shape {
    let t = pad_size(rng, u);
    let w = (t * rng.random_range(0.65..1.55)).min(MAX_SIDE);
    let h = (t * rng.random_range(0.65..1.55)).min(MAX_SIDE);
    Shape::Rect { x: 0.0, y: 0.0, w, h }
}

/// The mix of SC82C24: of 82, 52 rectangles, 8 circles, 6 ellipses, 6 open
/// polylines, 4 polygons, 3 open and 3 closed paths.
fn mixed_shape(rng: &mut ChaCha8Rng, u: f64) -> Shape {
    match rng.random_range(0..82) {
        0..=51 => rect_shape(rng, u),
        52..=59 => Shape::Circle { c: (0.0, 0.0), r: u * rng.random_range(0.18..0.58) },
        60..=65 => Shape::Ellipse { c: (0.0, 0.0), rx: u * rng.random_range(0.25..0.65), ry: u * rng.random_range(0.25..0.65) },
        66..=71 => {
            let k = rng.random_range(3..=6);
            Shape::Polyline(zigzag(rng, u, k))
        }
        72..=75 => {
            let k = rng.random_range(5..=6);
            Shape::Polygon(regular(rng, u, k))
        }
        76..=78 => Shape::Path { points: zigzag(rng, u, 3), closed: false },
        _ => {
            let points = if rng.random_bool(0.5) { star(rng, u) } else { regular(rng, u, 6) };
            Shape::Path { points, closed: true }
        }
    }
}

/// `k` points at even x steps over 0.9 to 1.3 u, random heights within ±0.45 u.
fn zigzag(rng: &mut ChaCha8Rng, u: f64, k: usize) -> Vec<P> {
    let width = u * rng.random_range(0.9..1.3);
    (0..k).map(|i| (width * i as f64 / (k - 1) as f64, u * rng.random_range(-0.45..0.45))).collect()
}

/// A regular `k`-gon of radius 0.35 to 0.65 u, turned at random.
fn regular(rng: &mut ChaCha8Rng, u: f64, k: usize) -> Vec<P> {
    let r = u * rng.random_range(0.35..0.65);
    let t0 = rng.random_range(0.0..2.0 * PI);
    (0..k).map(|i| polar(r, t0 + 2.0 * PI * i as f64 / k as f64)).collect()
}

/// A five-pointed star, outer radius 0.4 to 0.65 u.
fn star(rng: &mut ChaCha8Rng, u: f64) -> Vec<P> {
    let r = u * rng.random_range(0.4..0.65);
    let t0 = rng.random_range(0.0..2.0 * PI);
    (0..10).map(|i| polar(if i % 2 == 0 { r } else { 0.45 * r }, t0 + PI * i as f64 / 5.0)).collect()
}

fn polar(r: f64, t: f64) -> P {
    (r * t.cos(), r * t.sin())
}

// ---- O: squares on concentric rings ----------------------------------------

/// Square sides tried (mm), largest first; the benchmark's rings use 3 mm.
const O_SQUARES: [f64; 5] = [3.0, 2.5, 2.0, 1.5, 1.0];

/// Letters "O" (tall ellipses, width/height 0.5 to 0.8 from the seed) of
/// squares of side `s`, 1.55 s apart along a ring (at least, the squares are
/// spread evenly), rings 2 s apart, the hole at least half the letter's width.
/// The largest square side and the fewest letters that hold n; among ring
/// counts, the one whose band is closest to 20 % of the letter's half-width
/// (the benchmark's look), each letter as small as possible.
fn o_letters(rng: &mut ChaCha8Rng, n: usize, usable: f64) -> Result<Vec<Shape>, String> {
    let a = rng.random_range(0.5..0.8);
    for s in O_SQUARES {
        let (p, d, g) = (1.55 * s, 2.0 * s, 4.0 * s);
        for (cols, rows) in grids(36, true) {
            let letters = cols * rows;
            if letters > n {
                break;
            }
            let q = n.div_ceil(letters);
            let cell_w = (usable - (cols - 1) as f64 * g) / cols as f64;
            let cell_h = (usable - (rows - 1) as f64 * g) / rows as f64;
            let r_hi = ((cell_h - s) / 2.0).min((cell_w - s) / (2.0 * a));
            let r_lo = 4.0 * s;
            if r_hi < r_lo {
                continue;
            }
            let cap = |r: f64, k: usize| -> usize { (0..k).map(|i| ring_cap(a * r - i as f64 * d, r - i as f64 * d, p)).sum() };
            let mut best: Option<(f64, usize, f64)> = None;
            for k in 1.. {
                let r_min = r_lo.max(2.0 * (k - 1) as f64 * d / a);
                if r_min > r_hi {
                    break;
                }
                if cap(r_hi, k) < q {
                    continue;
                }
                let r = if cap(r_min, k) >= q { r_min } else { bisect(r_min, r_hi, |r| cap(r, k) >= q) };
                let score = ((k - 1) as f64 * d / (a * r) - 0.2).abs();
                if best.is_none_or(|b| score < b.0) {
                    best = Some((score, k, r));
                }
            }
            if let Some((_, k, r)) = best {
                return Ok(build_o(rng, n, a, s, (cols, rows), k, r, usable));
            }
        }
    }
    Err(format!("n = {n}: too many squares for 'O' letters in the base"))
}

/// Squares of pitch `p` a ring of semi-axes `rx`, `ry` holds.
fn ring_cap(rx: f64, ry: f64, p: f64) -> usize {
    (ellipse_perimeter(rx, ry) / p).floor() as usize
}

/// Ramanujan's second approximation.
fn ellipse_perimeter(a: f64, b: f64) -> f64 {
    let h = ((a - b) / (a + b)).powi(2);
    PI * (a + b) * (1.0 + 3.0 * h / (10.0 + (4.0 - 3.0 * h).sqrt()))
}

/// The smallest x in [lo, hi] with `ok(x)`, given `ok(hi)` and not `ok(lo)`
/// (to 0.005 mm).
fn bisect(mut lo: f64, mut hi: f64, ok: impl Fn(f64) -> bool) -> f64 {
    while hi - lo > 0.005 {
        let mid = 0.5 * (lo + hi);
        if ok(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

#[allow(clippy::too_many_arguments)]
fn build_o(rng: &mut ChaCha8Rng, n: usize, a: f64, s: f64, (cols, rows): (usize, usize), k: usize, r: f64, usable: f64) -> Vec<Shape> {
    let (p, d, g) = (1.55 * s, 2.0 * s, 4.0 * s);
    let (lw, lh) = (2.0 * a * r + s, 2.0 * r + s);
    let total_w = cols as f64 * lw + (cols - 1) as f64 * g;
    let total_h = rows as f64 * lh + (rows - 1) as f64 * g;
    let ox = MARGIN + pick(rng, 0.0, usable - total_w);
    let oy = MARGIN + pick(rng, 0.0, usable - total_h);
    let letters = cols * rows;
    let mut out = Vec::with_capacity(n);
    for l in 0..letters {
        let (i, j) = (l % cols, l / cols);
        let centre = (ox + lw / 2.0 + i as f64 * (lw + g), oy + lh / 2.0 + j as f64 * (lh + g));
        let q = n / letters + usize::from(l < n % letters);
        let rings: Vec<(f64, f64)> = (0..k).map(|i| (a * r - i as f64 * d, r - i as f64 * d)).collect();
        let perims: Vec<f64> = rings.iter().map(|&(rx, ry)| ellipse_perimeter(rx, ry)).collect();
        let caps: Vec<usize> = rings.iter().map(|&(rx, ry)| ring_cap(rx, ry, p)).collect();
        // One square at a time to the ring where it leaves the widest spacing.
        let mut counts = vec![0usize; k];
        for _ in 0..q {
            let best = (0..k)
                .filter(|&i| counts[i] < caps[i])
                .max_by(|&x, &y| (perims[x] / (counts[x] + 1) as f64).total_cmp(&(perims[y] / (counts[y] + 1) as f64)));
            // The rings hold q squares (chosen so); a missing one is caught by `generate`.
            if let Some(best) = best {
                counts[best] += 1;
            }
        }
        for (&(rx, ry), &m) in rings.iter().zip(&counts) {
            let start = rng.random::<f64>();
            for c in ellipse_points(rx, ry, m, start) {
                out.push(Shape::square((centre.0 + c.0, centre.1 + c.1), s));
            }
        }
    }
    out
}

/// `m` points evenly spaced by arc length on the ellipse (semi-axes `rx`,
/// `ry`, centre at the origin), the first at fraction `start` of the way round.
fn ellipse_points(rx: f64, ry: f64, m: usize, start: f64) -> Vec<P> {
    if m == 0 {
        return Vec::new();
    }
    const SAMPLES: usize = 2048;
    let pts: Vec<P> = (0..=SAMPLES).map(|i| (rx * (2.0 * PI * i as f64 / SAMPLES as f64).cos(), ry * (2.0 * PI * i as f64 / SAMPLES as f64).sin())).collect();
    let mut cum = vec![0.0];
    for w in pts.windows(2) {
        cum.push(cum[cum.len() - 1] + dist(w[0], w[1]));
    }
    let total = cum[SAMPLES];
    (0..m)
        .map(|j| {
            let t = ((start + j as f64 / m as f64) % 1.0) * total;
            let i = cum.partition_point(|&c| c <= t).clamp(1, SAMPLES);
            let f = (t - cum[i - 1]) / (cum[i] - cum[i - 1]);
            lerp(pts[i - 1], pts[i], f)
        })
        .collect()
}

fn dist(a: P, b: P) -> f64 {
    (b.0 - a.0).hypot(b.1 - a.1)
}

fn lerp(a: P, b: P, f: f64) -> P {
    (a.0 + (b.0 - a.0) * f, a.1 + (b.1 - a.1) * f)
}

// ---- ISW: squares along the strokes of the letters I, S, W -------------------

/// (square side, clearance) tried (mm), largest first: the benchmark uses
/// 2.5 + 1 and 2 + 1.
const ISW_SQUARES: [(f64, f64); 4] = [(2.5, 1.0), (2.0, 1.0), (1.5, 0.75), (1.0, 0.5)];

/// The letters' widths and spacing in fractions of the width scale, the W's
/// middle apex in fractions of the height; from the seed.
struct IswStyle {
    i_width: f64,
    s_width: f64,
    w_width: f64,
    w_apex: f64,
    letter_gap: f64,
}

/// One word's square centres for letter height `h`, width scale `x`, strokes
/// `c` squares wide (the I's stem one more) at pitch `p`, with the size of
/// its box of squares of side `s`, which starts at (0, 0).
fn isw_word(st: &IswStyle, h: f64, x: f64, s: f64, p: f64, c: usize) -> (Vec<P>, P) {
    let mut placed: Vec<P> = Vec::new();
    let mut occupied = Occupancy::new(4.0 * p);
    let mut stroke = |cands: Vec<P>| {
        for q in cands {
            let b = Bounds { x0: q.0, y0: q.1, x1: q.0, y1: q.1 };
            if occupied.free(&b, p - 1e-9) {
                occupied.insert(b);
                placed.push(q);
            }
        }
    };
    let half = (c - 1) as f64 / 2.0 * p;
    // I: serifs, then the stem.
    let wi = st.i_width * x;
    stroke(line_stroke((0.0, half), (wi, half), c, p));
    stroke(line_stroke((0.0, h - half), (wi, h - half), c, p));
    stroke(line_stroke((wi / 2.0, half), (wi / 2.0, h - half), c + 1, p));
    // S: an upper bowl turning left from its upper right end, a lower bowl
    // turning right, each an ellipse arc of 240 degrees.
    let left = wi + st.letter_gap * x;
    let ws = st.s_width * x;
    let (cx, rx, ry) = (left + ws / 2.0, ws / 2.0 - half, h / 4.0 - half / 2.0);
    const ARC: usize = 240;
    let upper = (0..=ARC).map(|i| (-30.0 - i as f64).to_radians()).map(|t| (cx + rx * t.cos(), half + ry + ry * t.sin()));
    let lower = (1..=ARC).map(|i| (-90.0 + i as f64).to_radians()).map(|t| (cx + rx * t.cos(), h - half - ry + ry * t.sin()));
    let spine: Vec<P> = upper.chain(lower).collect();
    stroke(curve_stroke(&spine, c, p));
    // W: four strokes.
    let left = left + ws + st.letter_gap * x;
    let ww = st.w_width * x;
    let corners = [
        (left, half),
        (left + 0.25 * ww, h - half),
        (left + 0.5 * ww, st.w_apex * h),
        (left + 0.75 * ww, h - half),
        (left + ww, half),
    ];
    for w in corners.windows(2) {
        stroke(line_stroke(w[0], w[1], c, p));
    }
    let b = Bounds::of(placed.iter().copied());
    let shift = (s / 2.0 - b.x0, s / 2.0 - b.y0);
    for q in &mut placed {
        *q = (q.0 + shift.0, q.1 + shift.1);
    }
    (placed, (b.w() + s, b.h() + s))
}

/// Centres on a straight stroke from `a` to `b`, `cols` squares wide: a
/// lattice along and across the stroke whose neighbours are at least `p`
/// apart along x or y.
fn line_stroke(a: P, b: P, cols: usize, p: f64) -> Vec<P> {
    let len = dist(a, b);
    let (dx, dy) = if len > 0.0 { ((b.0 - a.0) / len, (b.1 - a.1) / len) } else { (1.0, 0.0) };
    let q = p / dx.abs().max(dy.abs());
    let count = (len / q).floor() as usize + 1;
    let step = if count > 1 { len / (count - 1) as f64 } else { 0.0 };
    let mut out = Vec::with_capacity(count * cols);
    for i in 0..count {
        for j in 0..cols {
            let o = (j as f64 - (cols - 1) as f64 / 2.0) * q;
            out.push((a.0 + dx * step * i as f64 - dy * o, a.1 + dy * step * i as f64 + dx * o));
        }
    }
    out
}

/// Centres along the polyline `spine`, `cols` squares wide: each column a
/// parallel of the spine (a little wider apart than on straight strokes, as
/// the columns do not line up), walked at the local spacing of
/// [`line_stroke`].
fn curve_stroke(spine: &[P], cols: usize, p: f64) -> Vec<P> {
    let n = spine.len();
    let tangent = |i: usize| {
        let (a, b) = (spine[i.saturating_sub(1)], spine[(i + 1).min(n - 1)]);
        let l = dist(a, b);
        ((b.0 - a.0) / l, (b.1 - a.1) / l)
    };
    let mut out = Vec::new();
    for j in 0..cols {
        let o = (j as f64 - (cols - 1) as f64 / 2.0) * 1.2 * p;
        let column: Vec<P> = (0..n)
            .map(|i| {
                let (tx, ty) = tangent(i);
                let k = o / tx.abs().max(ty.abs());
                (spine[i].0 - ty * k, spine[i].1 + tx * k)
            })
            .collect();
        out.push(column[0]);
        let mut since = 0.0;
        for w in column.windows(2) {
            let l = dist(w[0], w[1]);
            if l == 0.0 {
                continue;
            }
            // 3 % over the pitch: chords on a bend are shorter than the arc.
            let q = 1.03 * p * l / (w[1].0 - w[0].0).abs().max((w[1].1 - w[0].1).abs());
            let mut t = 0.0;
            while since + (l - t) >= q {
                t += q - since;
                since = 0.0;
                out.push(lerp(w[0], w[1], t / l));
            }
            since += l - t;
        }
    }
    out
}

/// One arrangement of ISW words: square side, pitch, stroke width, words in
/// columns and rows, and the largest width scale that lets the columns fit.
#[derive(Clone, Copy)]
struct IswLayout {
    s: f64,
    p: f64,
    c: usize,
    cols: usize,
    rows: usize,
    x_max: f64,
    /// Side of the square the words are placed in.
    usable: f64,
}

impl IswLayout {
    fn words(&self) -> usize {
        self.cols * self.rows
    }
    /// The smallest letter height: 5 stroke widths.
    fn h_lo(&self) -> f64 {
        5.0 * self.c as f64 * self.p
    }
    /// Gaps between words across and down, for width scale `x` and height `h`.
    fn gaps(&self, x: f64, h: f64) -> (f64, f64) {
        ((0.4 * x).max(2.0 * self.p), (0.15 * h).max(2.0 * self.p))
    }
    /// One word at height `h` (letters no wider than at `x_max`), and the
    /// size of the whole block of words.
    fn block(&self, st: &IswStyle, h: f64) -> (Vec<P>, P, P) {
        let x = h.min(self.x_max);
        let (word, size) = isw_word(st, h, x, self.s, self.p, self.c);
        let (gx, gy) = self.gaps(x, h);
        let total = (self.cols as f64 * size.0 + (self.cols - 1) as f64 * gx, self.rows as f64 * size.1 + (self.rows - 1) as f64 * gy);
        (word, size, total)
    }
    /// The block fits the base, letters at most 3.5 times their width scale.
    fn fits(&self, st: &IswStyle, h: f64) -> bool {
        let (_, _, total) = self.block(st, h);
        total.0 <= self.usable && total.1 <= self.usable && h <= 3.5 * self.x_max
    }
    fn capacity(&self, st: &IswStyle, h: f64) -> usize {
        self.words() * self.block(st, h).0.len()
    }
}

/// Words "ISW" of small squares, in the benchmark's manner: letters grow
/// taller with n, wider only while the words fit across the base, so large
/// words are tall and narrow (up to 3.5 times their width scale). Preferred:
/// the fewest words (first with 2.5 or 2 mm squares, then with smaller ones),
/// the largest squares, strokes 2 squares wide (else 1, else 3), then the
/// smallest letters that hold n. The few squares beyond n are dropped, evenly
/// spread; below the smallest word (about 40 squares) the word is thinned
/// that way.
fn isw_words(rng: &mut ChaCha8Rng, n: usize, usable: f64) -> Result<Vec<Shape>, String> {
    let st = IswStyle {
        i_width: rng.random_range(0.45..0.55),
        s_width: rng.random_range(0.5..0.6),
        w_width: rng.random_range(0.8..0.95),
        w_apex: rng.random_range(0.3..0.45),
        letter_gap: rng.random_range(0.25..0.4),
    };
    // Squares per word at the smallest height, per (square size, stroke width).
    let mut per_word_lo: HashMap<(u64, usize), usize> = HashMap::new();
    // Widest letters for (square size, stroke width, columns of words).
    let mut x_max_of: HashMap<(u64, usize, usize), f64> = HashMap::new();
    let mut fallback: Option<(usize, IswLayout, f64)> = None;
    let mut chosen = None;
    'search: for squares in [&ISW_SQUARES[..2], &ISW_SQUARES[2..]] {
        for (cols, rows) in grids(64, false) {
            for &(s, gap) in squares {
                for c in [2, 1, 3] {
                    let mut layout = IswLayout { s, p: s + gap, c, cols, rows, x_max: usable, usable };
                    let h_lo = layout.h_lo();
                    let lo = *per_word_lo.entry((s.to_bits(), c)).or_insert_with(|| layout.block(&st, h_lo).0.len());
                    if layout.words() * lo >= n {
                        if layout.words() == 1 && fallback.is_none_or(|f| lo - n < f.0) {
                            fallback = Some((lo - n, layout, h_lo));
                        }
                        continue;
                    }
                    // Words narrower than the base over the columns and lower
                    // than it over the rows (or 3.5 times their width) hold at
                    // most this many: when too few, skip the bisections below
                    // (what makes large n take long).
                    let x_ub = usable / cols as f64;
                    let h_ub = (usable / rows as f64).min(3.5 * x_ub);
                    if h_ub >= h_lo && layout.words() * isw_word(&st, h_ub, h_ub.min(x_ub), s, layout.p, c).0.len() < n {
                        continue;
                    }
                    // The widest letters that fit across, then the tallest.
                    let across = |l: &IswLayout, x: f64| {
                        let (_, size) = isw_word(&st, x, x, l.s, l.p, l.c);
                        cols as f64 * size.0 + (cols - 1) as f64 * l.gaps(x, x).0 <= usable
                    };
                    let x_max = *x_max_of.entry((s.to_bits(), c, cols)).or_insert_with(|| {
                        if !across(&layout, h_lo) {
                            0.0
                        } else if across(&layout, usable) {
                            usable
                        } else {
                            bisect(h_lo, usable, |x| !across(&layout, x)) - 0.01
                        }
                    });
                    if x_max < h_lo {
                        continue;
                    }
                    layout.x_max = x_max;
                    if !layout.fits(&st, h_lo) {
                        continue;
                    }
                    let h_hi = if layout.fits(&st, usable) { usable } else { bisect(h_lo, usable, |h| !layout.fits(&st, h)) - 0.01 };
                    if layout.capacity(&st, h_hi) < n {
                        continue;
                    }
                    let h = bisect(h_lo, h_hi, |h| layout.capacity(&st, h) >= n);
                    chosen = Some((layout, h));
                    break 'search;
                }
            }
        }
        if fallback.is_some() {
            // n is below the smallest word: thin it rather than shrink the squares.
            break;
        }
    }
    let (layout, h) =
        chosen.or(fallback.map(|f| (f.1, f.2))).ok_or_else(|| format!("n = {n}: too many squares for 'ISW' words in the base"))?;
    let (word, size, total) = layout.block(&st, h);
    let (gx, gy) = layout.gaps(h.min(layout.x_max), h);
    let ox = MARGIN + pick(rng, 0.0, usable - total.0);
    let oy = MARGIN + pick(rng, 0.0, usable - total.1);
    let mut centres = Vec::with_capacity(word.len() * layout.words());
    for j in 0..layout.rows {
        for i in 0..layout.cols {
            let (x, y) = (ox + i as f64 * (size.0 + gx), oy + j as f64 * (size.1 + gy));
            centres.extend(word.iter().map(|q| (q.0 + x, q.1 + y)));
        }
    }
    let excess = centres.len().saturating_sub(n);
    if excess > 0 {
        let len = centres.len();
        let mut drop = (0..excess).map(|i| (2 * i + 1) * len / (2 * excess)).peekable();
        let mut kept = Vec::with_capacity(n);
        for (k, q) in centres.into_iter().enumerate() {
            if drop.peek() == Some(&k) {
                drop.next();
            } else {
                kept.push(q);
            }
        }
        centres = kept;
    }
    Ok(centres.into_iter().map(|q| Shape::square(q, layout.s)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::svg::import_svg;
    use crate::import::test_config;
    use crate::job::Point;

    /// The side of the base an SVG says it has (its viewBox).
    fn base_of(svg: &str) -> f64 {
        let view = svg.split("viewBox=\"0 0 ").nth(1).and_then(|v| v.split('"').next()).expect("a viewBox");
        let sides: Vec<f64> = view.split(' ').map(|v| v.parse().unwrap()).collect();
        assert_eq!(sides.len(), 2);
        assert_eq!(sides[0], sides[1], "a square base");
        assert!(svg.contains(&format!("width=\"{}mm\" height=\"{}mm\"", sides[0], sides[0])));
        sides[0]
    }

    /// Generates, imports with the job importer and checks the instance;
    /// returns the SVG text and the geometries' bounds.
    fn checked(family: Family, n: usize, seed: u64) -> (String, Vec<(Point, Point)>) {
        let svg = generate(family, n, seed).unwrap_or_else(|e| panic!("{family} n={n} seed={seed}: {e}"));
        let job = import_svg(&svg, "gen.svg", &test_config()).unwrap();
        let case = format!("{family} n={n} seed={seed}");
        assert_eq!(job.geometries.len(), n, "{case}");
        let base = base_of(&svg);
        assert!(base >= base_mm(n) && base <= 2.0 * base_mm(n), "{case}: base {base} mm");
        let bounds: Vec<(Point, Point)> = job.geometries.iter().map(|g| g.bounds()).collect();
        for (i, (lo, hi)) in bounds.iter().enumerate() {
            assert!(hi.x - lo.x <= FIELD_MM - 20.0 && hi.y - lo.y <= FIELD_MM - 20.0, "{case}: geometry {i} too large");
            assert!(hi.x - lo.x > 0.3 || hi.y - lo.y > 0.3, "{case}: geometry {i} degenerate");
            assert!(lo.x >= 0.0 && lo.y >= 0.0 && hi.x <= base && hi.y <= base, "{case}: geometry {i} outside the base");
        }
        assert_no_overlap(&bounds, &case);
        (svg, bounds)
    }

    /// No two boxes overlap or touch (sweep along x).
    fn assert_no_overlap(bounds: &[(Point, Point)], case: &str) {
        let mut order: Vec<usize> = (0..bounds.len()).collect();
        order.sort_by(|&a, &b| bounds[a].0.x.total_cmp(&bounds[b].0.x));
        for (k, &a) in order.iter().enumerate() {
            for &b in &order[k + 1..] {
                if bounds[b].0.x > bounds[a].1.x + 0.01 {
                    break;
                }
                let clear_y = bounds[b].0.y > bounds[a].1.y + 0.01 || bounds[a].0.y > bounds[b].1.y + 0.01;
                assert!(clear_y, "{case}: geometries {a} and {b} overlap: {:?} {:?}", bounds[a], bounds[b]);
            }
        }
    }

    #[test]
    fn generate_every_family_imports_into_n_separate_geometries_within_a_field() {
        for family in Family::ALL {
            for n in [32, 200, 1017] {
                for seed in [1, 2] {
                    checked(family, n, seed);
                }
            }
        }
    }

    #[test]
    fn generate_extreme_sizes() {
        for family in Family::ALL {
            for n in [1, 2, 7, 110, BASE_N, BASE_N + 1, MAX_N] {
                checked(family, n, 3);
            }
        }
    }

    /// Up to BASE_N on the 300 mm base; beyond, on a base growing with √n,
    /// hence at most as dense as BASE_N on 300 mm (for the scattered
    /// families, geometries as large as theirs).
    #[test]
    fn the_base_grows_beyond_base_n_keeping_the_density() {
        assert_eq!((base_mm(1), base_mm(BASE_N), base_mm(BASE_N + 1), base_mm(4 * BASE_N), base_mm(MAX_N)), (300.0, 300.0, 301.0, 600.0, 1342.0));
        for family in Family::ALL {
            let small = generate(family, BASE_N, 5).unwrap();
            assert_eq!(base_of(&small), 300.0, "{family}");
            assert!(small.contains("viewBox=\"0 0 300 300\"") && !small.contains(", base "), "{family}");
            let (svg, bounds) = checked(family, 4 * BASE_N, 5);
            let base = base_of(&svg);
            assert!(svg.contains(&format!(", base {base} mm) -->")), "{family}");
            let (lo, hi) = bounds.iter().fold(((f64::MAX, f64::MAX), (0.0f64, 0.0f64)), |(lo, hi), b| ((lo.0.min(b.0.x), lo.1.min(b.0.y)), (hi.0.max(b.1.x), hi.1.max(b.1.y))));
            // The layout spreads beyond the old base, not crowded into it.
            assert!(hi.0 - lo.0 > 320.0 || hi.1 - lo.1 > 320.0, "{family}: {lo:?} to {hi:?} on {base} mm");
            if matches!(family, Family::Rnd | Family::Mixed) {
                let median_side = |b: &[(Point, Point)]| {
                    let mut s: Vec<f64> = b.iter().map(|(lo, hi)| (hi.x - lo.x).max(hi.y - lo.y)).collect();
                    s.sort_by(f64::total_cmp);
                    s[s.len() / 2]
                };
                let (_, at_base) = checked(family, BASE_N, 5);
                assert!(median_side(&bounds) > 0.8 * median_side(&at_base), "{family}: geometries shrank");
            }
        }
    }

    #[test]
    fn generate_is_deterministic_per_seed() {
        for family in Family::ALL {
            for n in [32, 489] {
                let a = generate(family, n, 7).unwrap();
                assert_eq!(a, generate(family, n, 7).unwrap(), "{family} n={n}");
                assert_ne!(a, generate(family, n, 8).unwrap(), "{family} n={n}");
            }
        }
    }

    #[test]
    fn generate_rejects_bad_n_and_unknown_families() {
        for n in [0, MAX_N + 1] {
            let e = generate(Family::Rnd, n, 1).unwrap_err();
            assert!(e.contains("between 1 and 100000") && e.contains(&n.to_string()), "{e}");
        }
        assert_eq!("ISW".parse::<Family>(), Ok(Family::Isw));
        assert_eq!(" Mixed".parse::<Family>(), Ok(Family::Mixed));
        assert_eq!("o".parse::<Family>(), Ok(Family::O));
        let e = "circles".parse::<Family>().unwrap_err();
        assert!(e.contains("'circles'") && e.contains("rnd, o, isw, mixed"), "{e}");
    }

    /// The families look like the benchmark files: the element kinds, the
    /// ordered families' square sides, the scattered sizes.
    #[test]
    fn generate_matches_the_benchmark_families() {
        let kinds = |svg: &str| -> Vec<&str> {
            ["<rect ", "<circle ", "<ellipse ", "<polyline ", "<polygon ", "<path "].into_iter().filter(|k| svg.contains(k)).collect()
        };
        for seed in [1, 2] {
            let (svg, _) = checked(Family::Mixed, 200, seed);
            assert_eq!(kinds(&svg).len(), 6, "mixed seed {seed}: {:?}", kinds(&svg));
            assert!(svg.contains(" Z\"/>") && svg.contains("<path d=\"M ") && svg.matches("<rect ").count() > 100);
            for family in [Family::Rnd, Family::O, Family::Isw] {
                let (svg, bounds) = checked(family, 564, seed);
                assert_eq!(kinds(&svg), ["<rect "], "{family}");
                let sides: Vec<f64> = bounds.iter().flat_map(|(lo, hi)| [hi.x - lo.x, hi.y - lo.y]).collect();
                let (min, max) = sides.iter().fold((f64::MAX, 0.0f64), |(a, b), &s| (a.min(s), b.max(s)));
                match family {
                    Family::O => assert!((min - 3.0).abs() < 1e-3 && (max - 3.0).abs() < 1e-3, "O squares {min}..{max}"),
                    Family::Isw => assert!(min >= 2.0 - 1e-3 && max <= 2.5 + 1e-3 && max - min < 1e-3, "ISW squares {min}..{max}"),
                    _ => assert!(min >= 0.5 && max <= MAX_SIDE + 1e-3 && max > 3.0 * min, "rnd sides {min}..{max}"),
                }
            }
        }
    }
}
