//! Nested-part sheets for tests and benchmarks (issue 4, point 6): a sheet
//! filled shelf by shelf, from the corner at the depot, with
//! * **grids** of rectangular parts (1 to 3 rows) where neighbours share their
//!   common edge: one element on two contours, a common cut;
//! * **plates**: rectangular parts with round and rectangular holes;
//! * **round parts**: discs, washers (a central hole) and flanges (a central
//!   hole and a bolt circle);
//! * **frames**: rectangular parts with one to three large windows (holes),
//!   each holding smaller grids, plates or round parts nested in it, whose own
//!   holes are inner contours of theirs.
//!
//! Elements are the lines and arcs of the outlines, each stored by its two end
//! points: a rectangle is 4 lines, a circle 2 to 4 arcs. `inner_outer` holds
//! direct containment only (hole in part, nested part in hole). Anything
//! inside a round outline stays inside the polygon of that outline's end
//! points (what a consumer of the instance sees), so round outlines with
//! something inside have 3 or 4 arcs.
//!
//! Part sizes shrink (by a common scale) when the target does not fit the
//! sheet at full size; the element count lands within 5 % above the target.
//! The first items are a frame and a grid, so that from about 50 elements
//! on a sheet has common cuts, holes and nested parts.
//!
//! [`generate_sheet`] also keeps the centres of the arcs, and [`to_svg`]
//! draws such a sheet as a nesting program would export it (each part whole,
//! arcs as arcs), for `topology` to find the instance again from a drawing.

use std::f64::consts::PI;

use nalgebra::Vector2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::plan::ecp::{Element, Instance, Metric};
use crate::job::Point;

/// What [`generate`] builds.
#[derive(Debug, Clone, PartialEq)]
pub struct SheetParams {
    /// Sheet size in mm; the depot is its corner (0, 0).
    pub width: f64,
    pub height: f64,
    /// How many elements the sheet should have (it gets 0 to 5 % more).
    pub target_elements: usize,
    /// Cost of a pierce, in mm of air move.
    pub pierce_cost: f64,
    /// Clearance from the sheet's edge to the parts, mm.
    pub margin: f64,
    /// Clearance between neighbouring parts, between holes, and between a
    /// nested part and its hole, mm (shrinks with the parts).
    pub gap: f64,
}

impl Default for SheetParams {
    /// A 3000 × 1500 mm sheet of 3000 elements.
    fn default() -> Self {
        SheetParams { width: 3000.0, height: 1500.0, target_elements: 3000, pierce_cost: 10.0, margin: 10.0, gap: 6.0 }
    }
}

impl SheetParams {
    /// The default sheet with another element target.
    pub fn with_target(target_elements: usize) -> Self {
        SheetParams { target_elements, ..Self::default() }
    }
}

/// What a sheet holds, from the instance alone (levels follow `inner_outer`:
/// a part on the sheet is level 0, its holes 1, parts nested in them 2, …).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SheetStats {
    pub elements: usize,
    pub contours: usize,
    /// Parts lying on the sheet itself (level 0).
    pub parts: usize,
    /// Holes: contours directly inside a part (odd levels).
    pub holes: usize,
    /// Parts nested inside a hole of another part (even levels from 2).
    pub nested_parts: usize,
    pub common_cuts: usize,
    pub inner_outer: usize,
    /// `inner_outer` pairs plus common cuts.
    pub precedences: usize,
    pub max_level: usize,
}

/// Counts a sheet's parts, holes, nested parts and relations.
pub fn stats(inst: &Instance) -> SheetStats {
    let level = levels(inst);
    let common_cuts = inst.common_cuts().len();
    SheetStats {
        elements: inst.elements.len(),
        contours: inst.contours.len(),
        parts: level.iter().filter(|&&l| l == 0).count(),
        holes: level.iter().filter(|&&l| l % 2 == 1).count(),
        nested_parts: level.iter().filter(|&&l| l >= 2 && l % 2 == 0).count(),
        common_cuts,
        inner_outer: inst.inner_outer.len(),
        precedences: inst.inner_outer.len() + common_cuts,
        max_level: level.iter().copied().max().unwrap_or(0),
    }
}

/// Each contour's depth in the containment tree.
fn levels(inst: &Instance) -> Vec<usize> {
    let mut outer = vec![None; inst.contours.len()];
    for &(i, o) in &inst.inner_outer {
        outer[i] = Some(o);
    }
    (0..inst.contours.len())
        .map(|mut c| {
            let mut l = 0;
            while let Some(o) = outer[c] {
                c = o;
                l += 1;
            }
            l
        })
        .collect()
}

/// A sheet of nested parts, the same for the same parameters and seed.
pub fn generate(params: &SheetParams, seed: u64) -> Instance {
    generate_sheet(params, seed).instance
}

/// A generated sheet: the instance, and which of its elements are arcs.
#[derive(Debug, Clone)]
pub struct Sheet {
    pub instance: Instance,
    /// Per element: the centre of the circle its arc lies on, or None for a
    /// line. Arcs run counter-clockwise from `a` to `b` (the way the generator
    /// goes round), each less than a half circle except the two of a 2-arc circle.
    pub arc_centres: Vec<Option<Point>>,
}

/// [`generate`], keeping the arcs' centres (for drawing the sheet, [`to_svg`]).
pub fn generate_sheet(params: &SheetParams, seed: u64) -> Sheet {
    let target = params.target_elements;
    let usable = (params.width - 2.0 * params.margin).max(0.0) * (params.height - 2.0 * params.margin).max(0.0);
    // Start at the scale where the target should take about 75 % of the
    // sheet, never above full size; shrink further while it does not fit.
    let mut scale = (0.75 * usable / (target.max(1) as f64 * MM2_PER_ELEMENT)).sqrt().min(1.0);
    let mut last = None;
    for _ in 0..100 {
        let (gen, fits) = fill(params, seed, scale);
        let sheet = gen.into_sheet(params);
        if fits {
            return sheet;
        }
        last = Some(sheet);
        scale *= 0.93;
    }
    // Not even tiny parts fit (a target far beyond the sheet): what there is.
    last.expect("at least one attempt")
}

/// Sheet area per element at full scale, measured on generated sheets
/// (shelves, gaps and waste included); too low a guess costs a retry.
const MM2_PER_ELEMENT: f64 = 2000.0;

/// The kinds of item placed side by side on a shelf.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Grid,
    Plate,
    Round,
    Frame,
}

/// Fills the sheet at `scale`; false when it ran out of sheet before the target.
fn fill(params: &SheetParams, seed: u64, scale: f64) -> (Gen, bool) {
    let target = params.target_elements;
    let mut g = Gen {
        rng: ChaCha8Rng::seed_from_u64(seed),
        s: scale,
        gap: params.gap * scale.min(1.0),
        limit: target + target / 20,
        elements: Vec::new(),
        arc_centres: Vec::new(),
        contours: Vec::new(),
        inner_outer: Vec::new(),
    };
    let s = scale;
    // The first items, popped from the end: a frame (nested parts) and a grid
    // (common cuts) even on small sheets.
    let mut forced = vec![Kind::Round, Kind::Plate, Kind::Grid, Kind::Frame];
    let (x0, x1, y1) = (params.margin, params.width - params.margin, params.height - params.margin);
    let mut y = params.margin;
    // left() < 2: not even a 2-arc disc fits the budget, and the count is
    // within one of the target anyway.
    while g.elements.len() < target && g.left() >= 2 {
        let mut shelf = g.rng.random_range(70.0..=280.0) * s;
        if forced.contains(&Kind::Frame) {
            shelf = shelf.max(180.0 * s);
        }
        let shelf = shelf.min(y1 - y);
        if shelf < 40.0 * s {
            return (g, false);
        }
        let mut x = x0;
        while g.elements.len() < target && g.left() >= 2 {
            let avail = x1 - x;
            if avail < 30.0 * s {
                break;
            }
            let kind = forced.pop().unwrap_or_else(|| g.pick(true));
            let at = Point::new(x, y);
            let used = g
                .place(kind, at, avail, shelf, None)
                .or_else(|| g.place(Kind::Plate, at, avail, shelf, None))
                .or_else(|| g.place(Kind::Round, at, avail, shelf, None));
            match used {
                Some(w) => x += w + g.gap,
                None => break,
            }
        }
        y += shelf + g.gap;
    }
    (g, true)
}

struct Gen {
    rng: ChaCha8Rng,
    /// Scale of the part sizes (1: the sizes written below, in mm).
    s: f64,
    gap: f64,
    /// Elements allowed in all; every item is trimmed to what is left.
    limit: usize,
    elements: Vec<Element>,
    /// Per element, as [`Sheet::arc_centres`].
    arc_centres: Vec<Option<Point>>,
    contours: Vec<Vec<usize>>,
    inner_outer: Vec<(usize, usize)>,
}

impl Gen {
    fn into_sheet(self, params: &SheetParams) -> Sheet {
        let instance = Instance {
            elements: self.elements,
            contours: self.contours,
            inner_outer: self.inner_outer,
            depot: Point::new(0.0, 0.0),
            metric: Metric::Euclidean,
            pierce_cost: params.pierce_cost,
            edge_starts: Vec::new(),
            turns: crate::plan::ecp::Turns::default(),
            penalties: Default::default(),
        };
        Sheet { instance, arc_centres: self.arc_centres }
    }

    fn left(&self) -> usize {
        self.limit.saturating_sub(self.elements.len())
    }

    fn seg(&mut self, a: Point, b: Point) -> usize {
        self.elements.push(Element { a, b });
        self.arc_centres.push(None);
        self.elements.len() - 1
    }

    /// An arc counter-clockwise from `a` to `b` about `centre`.
    fn arc(&mut self, a: Point, b: Point, centre: Point) -> usize {
        let e = self.seg(a, b);
        self.arc_centres[e] = Some(centre);
        e
    }

    fn contour(&mut self, elements: Vec<usize>, outer: Option<usize>) -> usize {
        self.contours.push(elements);
        let k = self.contours.len() - 1;
        if let Some(o) = outer {
            self.inner_outer.push((k, o));
        }
        k
    }

    /// A rectangle: 4 lines, in order round it.
    fn rect(&mut self, lo: Point, hi: Point, outer: Option<usize>) -> usize {
        let p = [lo, Point::new(hi.x, lo.y), hi, Point::new(lo.x, hi.y)];
        let e = (0..4).map(|i| self.seg(p[i], p[(i + 1) % 4])).collect();
        self.contour(e, outer)
    }

    /// A circle of `arcs` arcs starting at a random angle, in order round it.
    fn circle(&mut self, c: Point, r: f64, arcs: usize, outer: Option<usize>) -> usize {
        let t0 = self.rng.random_range(0.0..2.0 * PI);
        let p: Vec<Point> = (0..arcs)
            .map(|k| {
                let t = t0 + 2.0 * PI * k as f64 / arcs as f64;
                c + Vector2::new(t.cos(), t.sin()) * r
            })
            .collect();
        let e = (0..arcs).map(|k| self.arc(p[k], p[(k + 1) % arcs], c)).collect();
        self.contour(e, outer)
    }

    /// 2 to 4 arcs, at most `max` (which must be at least 2).
    fn arcs(&mut self, max: usize) -> usize {
        self.rng.random_range(2..=4).min(max)
    }

    /// A random kind: frames only on the sheet itself (not nested).
    fn pick(&mut self, top: bool) -> Kind {
        match self.rng.random_range(0..if top { 10 } else { 8 }) {
            0..=2 => Kind::Grid,
            3..=5 => Kind::Plate,
            6..=7 => Kind::Round,
            _ => Kind::Frame,
        }
    }

    /// Places an item of `kind` with its lower left corner at `lo`, within
    /// `max_w` × `max_h`; its width, or None when it does not fit (space or budget).
    fn place(&mut self, kind: Kind, lo: Point, max_w: f64, max_h: f64, outer: Option<usize>) -> Option<f64> {
        let s = self.s;
        match kind {
            Kind::Grid => self.grid(lo, max_w, max_h, outer),
            Kind::Plate => {
                if max_w < 20.0 * s || max_h < 20.0 * s {
                    return None;
                }
                let w = max_w.min(self.rng.random_range(50.0..=320.0) * s);
                let h = max_h * self.rng.random_range(0.6..=1.0);
                self.plate(lo, w, h, outer).map(|_| w)
            }
            Kind::Round => {
                let r = (0.5 * max_w.min(max_h)).min(150.0 * s) * self.rng.random_range(0.6..=1.0);
                if r < 8.0 * s {
                    return None;
                }
                self.round_part(lo + Vector2::new(r, r), r, outer).map(|_| 2.0 * r)
            }
            Kind::Frame => self.frame(lo, max_w, max_h),
        }
    }

    /// Rectangular parts in 1 to 3 rows and 2 to 8 columns, neighbours sharing
    /// the edge between them (one element, two contours), some with a round
    /// hole. Each cell's contour starts with its left edge, which the cell to
    /// its left (if any) also has.
    fn grid(&mut self, lo: Point, max_w: f64, max_h: f64, outer: Option<usize>) -> Option<f64> {
        let s = self.s;
        let mut rows = match self.rng.random_range(0..10) {
            0..=5 => 1,
            6..=8 => 2,
            _ => 3,
        };
        while rows > 1 && max_h / (rows as f64) < 25.0 * s {
            rows -= 1;
        }
        let ch = max_h * self.rng.random_range(0.6..=1.0) / rows as f64;
        if ch < 12.0 * s {
            return None;
        }
        let want = self.rng.random_range(2..=8);
        let mut widths: Vec<f64> = Vec::new();
        while widths.len() < want {
            let w = self.rng.random_range(40.0..=160.0) * s;
            if widths.iter().sum::<f64>() + w > max_w {
                break;
            }
            widths.push(w);
        }
        // Lines: (rows + 1) · cols horizontal and rows · (cols + 1) vertical.
        let count = |r: usize, c: usize| (r + 1) * c + r * (c + 1);
        while !widths.is_empty() && count(rows, widths.len()) > self.left() {
            widths.pop();
        }
        while rows > 1 && count(rows, widths.len()) > self.left() {
            rows -= 1;
        }
        let cols = widths.len();
        if rows * cols < 2 || count(rows, cols) > self.left() {
            return None;
        }
        let mut xs = vec![lo.x];
        for w in &widths {
            xs.push(xs.last().unwrap() + w);
        }
        let ys: Vec<f64> = (0..=rows).map(|i| lo.y + i as f64 * ch).collect();
        let pt = |i: usize, j: usize| Point::new(xs[j], ys[i]);
        let horizontal: Vec<Vec<usize>> = (0..=rows).map(|i| (0..cols).map(|j| self.seg(pt(i, j), pt(i, j + 1))).collect()).collect();
        let vertical: Vec<Vec<usize>> = (0..rows).map(|i| (0..=cols).map(|j| self.seg(pt(i, j), pt(i + 1, j))).collect()).collect();
        for i in 0..rows {
            for j in 0..cols {
                let cell = vec![vertical[i][j], horizontal[i][j], vertical[i][j + 1], horizontal[i + 1][j]];
                let part = self.contour(cell, outer);
                let r = 0.25 * widths[j].min(ch);
                if r <= 0.5 * widths[j].min(ch) - self.gap && r >= 3.0 * s && self.left() >= 2 && self.rng.random_bool(0.3) {
                    let c = Point::new(0.5 * (xs[j] + xs[j + 1]), 0.5 * (ys[i] + ys[i + 1]));
                    let n = self.arcs(self.left());
                    self.circle(c, r, n, Some(part));
                }
            }
        }
        Some(xs[cols] - lo.x)
    }

    /// A `w` × `h` rectangular part with a grid of round and rectangular
    /// holes, each in its own cell shrunk by half a gap per side.
    fn plate(&mut self, lo: Point, w: f64, h: f64, outer: Option<usize>) -> Option<usize> {
        let s = self.s;
        if self.left() < 4 {
            return None;
        }
        let part = self.rect(lo, lo + Vector2::new(w, h), outer);
        let border = (0.12 * w.min(h)).max(self.gap);
        let (iw, ih) = (w - 2.0 * border, h - 2.0 * border);
        if iw < 8.0 * s || ih < 8.0 * s {
            return Some(part);
        }
        let cell = self.rng.random_range(25.0..=70.0) * s;
        let mut nx = ((iw / cell).floor() as usize).max(1);
        let mut ny = ((ih / cell).floor() as usize).max(1);
        while nx * ny > 24 {
            if nx >= ny {
                nx -= 1;
            } else {
                ny -= 1;
            }
        }
        let (cw, ch) = (iw / nx as f64, ih / ny as f64);
        let (room_w, room_h) = (cw - self.gap, ch - self.gap);
        if room_w.min(room_h) < 3.0 * s {
            return Some(part);
        }
        for j in 0..ny {
            for i in 0..nx {
                if self.left() < 2 {
                    return Some(part);
                }
                if !self.rng.random_bool(0.75) {
                    continue;
                }
                let c = lo + Vector2::new(border + (i as f64 + 0.5) * cw, border + (j as f64 + 0.5) * ch);
                if self.left() < 4 || self.rng.random_bool(0.6) {
                    let r = 0.5 * room_w.min(room_h) * self.rng.random_range(0.5..=0.95);
                    let n = self.arcs(self.left());
                    self.circle(c, r, n, Some(part));
                } else {
                    let half = Vector2::new(room_w * self.rng.random_range(0.4..=0.9), room_h * self.rng.random_range(0.4..=0.9)) * 0.5;
                    self.rect(c - half, c + half, Some(part));
                }
            }
        }
        Some(part)
    }

    /// A round part of radius `r` about `c`: a disc, a washer or a flange.
    fn round_part(&mut self, c: Point, r: f64, outer: Option<usize>) -> Option<usize> {
        let s = self.s;
        let left = self.left();
        if left < 2 {
            return None;
        }
        let style = self.rng.random_range(0..10);
        if style < 3 || left < 5 || r < 15.0 * s {
            let n = self.arcs(left);
            return Some(self.circle(c, r, n, outer));
        }
        // Holes stay inside the inscribed circle of the outline's end-point
        // polygon, a gap away from it.
        let n = if left < 7 { 3 } else { self.rng.random_range(3..=4) };
        let inner = r * (PI / n as f64).cos() - self.gap;
        let part = self.circle(c, r, n, outer);
        let rc = inner * self.rng.random_range(0.25..=0.5);
        let arcs = self.arcs(self.left());
        self.circle(c, rc, arcs, Some(part));
        if style < 6 || self.left() < 6 {
            return Some(part);
        }
        // Bolt holes half way between the central hole and the rim, a gap
        // from it, from the rim and from each other.
        let mut m = self.rng.random_range(3..=8);
        let rb = 0.5 * (rc + inner);
        let spread = inner - rc;
        let rh = (0.3 * spread).min(rb * (PI / m as f64).sin() - 0.5 * self.gap).min(0.5 * spread - self.gap);
        let arcs = self.rng.random_range(2..=4);
        m = m.min(self.left() / arcs);
        if rh < 1.5 * s || m < 3 {
            return Some(part);
        }
        // m may have dropped: the spacing only grows.
        let t0 = self.rng.random_range(0.0..2.0 * PI);
        for k in 0..m {
            let t = t0 + 2.0 * PI * k as f64 / m as f64;
            self.circle(c + Vector2::new(t.cos(), t.sin()) * rb, rh, arcs, Some(part));
        }
        Some(part)
    }

    /// A rectangular part with one to three large windows, each a hole with
    /// smaller parts nested in it.
    fn frame(&mut self, lo: Point, max_w: f64, max_h: f64) -> Option<f64> {
        let s = self.s;
        if max_h < 110.0 * s || max_w < 150.0 * s || self.left() < 24 {
            return None;
        }
        let h = max_h * self.rng.random_range(0.85..=1.0);
        let w = max_w.min(self.rng.random_range(200.0..=650.0) * s);
        let border = (self.rng.random_range(10.0..=22.0) * s).max(self.gap);
        let part = self.rect(lo, lo + Vector2::new(w, h), None);
        let most = ((w - border) / (h - border)).round().clamp(1.0, 3.0) as usize;
        let windows = self.rng.random_range(1..=most);
        let cw = (w - border * (windows as f64 + 1.0)) / windows as f64;
        let ch = h - 2.0 * border;
        for k in 0..windows {
            if self.left() < 6 {
                break;
            }
            let wlo = lo + Vector2::new(border + k as f64 * (cw + border), border);
            let aspect = cw / ch;
            if (0.7..=1.4).contains(&aspect) && self.rng.random_bool(0.3) {
                // A round window (4 arcs) with one part inside the inscribed
                // circle of its end points, a gap away.
                let r = 0.5 * cw.min(ch);
                let c = wlo + Vector2::new(0.5 * cw, 0.5 * ch);
                let window = self.circle(c, r, 4, Some(part));
                let inner = r * (PI / 4.0).cos() - self.gap;
                if self.rng.random_bool(0.5) {
                    let rr = inner * self.rng.random_range(0.6..=1.0);
                    self.round_part(c, rr, Some(window));
                } else {
                    let side = inner * std::f64::consts::SQRT_2;
                    let (pw, ph) = (side * self.rng.random_range(0.6..=1.0), side * self.rng.random_range(0.6..=1.0));
                    self.plate(c - Vector2::new(pw, ph) * 0.5, pw, ph, Some(window));
                }
            } else {
                // A rectangular window filled left to right, like a shelf.
                let window = self.rect(wlo, wlo + Vector2::new(cw, ch), Some(part));
                let (mut x, x_end, y, mh) = (wlo.x + self.gap, wlo.x + cw - self.gap, wlo.y + self.gap, ch - 2.0 * self.gap);
                while x_end - x >= 20.0 * s && self.left() >= 2 {
                    let kind = self.pick(false);
                    let at = Point::new(x, y);
                    let used = self.place(kind, at, x_end - x, mh, Some(window)).or_else(|| self.place(Kind::Round, at, x_end - x, mh, Some(window)));
                    match used {
                        Some(u) => x += u + self.gap,
                        None => break,
                    }
                }
            }
        }
        Some(w)
    }
}

/// The sheet as an SVG document, the way a CAM program would export it for
/// laserd's importer (`import::svg`):
/// * millimetres: `width="…mm" height="…mm"` and a viewBox of the sheet in mm,
///   so one user unit is one mm;
/// * Y flipped: SVG's y runs down from the top edge, the machine's Y up from
///   the bottom one, and the importer maps `y = height - y_svg`; so this writes
///   `y_svg = height - y` and the import lands on the instance's coordinates;
/// * every contour one closed `<path id="c{k}">`, in contour order (the
///   importer's geometry k is contour k), drawn whole: a common cut is drawn
///   twice, once with each of its parts, as a nesting program's export has it,
///   so that whoever reads the file must find the shared edges again;
/// * arcs as SVG arcs about their centres ([`Sheet::arc_centres`]), not as
///   their chords: the chords of a 2-arc circle are a line there and back, no
///   shape at all, and real arcs make the importer flatten them into the
///   polylines of many short segments that a real job has.
pub fn to_svg(sheet: &Sheet, params: &SheetParams) -> String {
    use std::fmt::Write;
    let inst = &sheet.instance;
    let (w, h) = (params.width, params.height);
    let mut out = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}mm\" height=\"{h}mm\" viewBox=\"0 0 {w} {h}\">\n"
    );
    for k in 0..inst.contours.len() {
        let ring = outline(inst, k);
        let (start, _) = ends(inst, ring[0]);
        let mut d = format!("M {} {}", start.x, h - start.y);
        for &(e, reversed) in &ring {
            let (_, to) = ends(inst, (e, reversed));
            match sheet.arc_centres.get(e).copied().flatten() {
                Some(c) => {
                    let r = (inst.elements[e].a - c).norm();
                    // Counter-clockwise on the machine is clockwise in SVG's
                    // y-down frame: sweep flag 0 forwards, 1 reversed. No arc
                    // exceeds a half circle (large-arc flag 0).
                    let sweep = u8::from(reversed);
                    write!(d, " A {r} {r} 0 0 {sweep} {} {}", to.x, h - to.y).unwrap();
                }
                None => write!(d, " L {} {}", to.x, h - to.y).unwrap(),
            }
        }
        writeln!(out, "<path id=\"c{k}\" d=\"{d} Z\" fill=\"none\" stroke=\"#000000\" stroke-width=\"0.1\"/>").unwrap();
    }
    out.push_str("</svg>\n");
    out
}

/// Where an element cut one way starts and ends.
fn ends(inst: &Instance, (e, reversed): (usize, bool)) -> (Point, Point) {
    let el = &inst.elements[e];
    if reversed {
        (el.b, el.a)
    } else {
        (el.a, el.b)
    }
}

/// A contour's elements in order round it, each with its direction (a grid
/// cell lists its edges left, bottom, right, top, not as a chain).
fn outline(inst: &Instance, k: usize) -> Vec<(usize, bool)> {
    let mut left = inst.contours[k].clone();
    let first = left.remove(0);
    let mut ring = vec![(first, false)];
    let mut here = inst.elements[first].b;
    let at = |p: Point, q: Point| (p - q).norm() < 1e-9;
    while !left.is_empty() {
        let i = left
            .iter()
            .position(|&e| at(inst.elements[e].a, here) || at(inst.elements[e].b, here))
            .expect("a sheet's contours are closed chains of elements");
        let e = left.remove(i);
        let reversed = !at(inst.elements[e].a, here);
        here = ends(inst, (e, reversed)).1;
        ring.push((e, reversed));
    }
    ring
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;
    use crate::plan::ecp::checker::{self, Violation};
    use crate::plan::ecp::Cut;

    fn sheet(target: usize, seed: u64) -> Instance {
        generate(&SheetParams::with_target(target), seed)
    }

    /// Depth of each contour, computed here from `inner_outer`; also checks
    /// that no contour has two direct outers.
    fn depth(inst: &Instance) -> Vec<usize> {
        let mut outer = vec![None; inst.contours.len()];
        for &(i, o) in &inst.inner_outer {
            assert!(outer[i].replace(o).is_none(), "contour {i} has two outers");
        }
        (0..inst.contours.len())
            .map(|c| std::iter::successors(Some(c), |&k| outer[k]).count() - 1)
            .collect()
    }

    /// The contour's elements as segments between their end points.
    fn chords(inst: &Instance, k: usize) -> Vec<(Point, Point)> {
        inst.contours[k].iter().map(|&e| (inst.elements[e].a, inst.elements[e].b)).collect()
    }

    fn points(inst: &Instance, k: usize) -> Vec<Point> {
        chords(inst, k).into_iter().flat_map(|(a, b)| [a, b]).collect()
    }

    /// Crossing-number test: a ray to +x crosses the closed polygon's edges an
    /// odd number of times from inside.
    fn inside(p: Point, edges: &[(Point, Point)]) -> bool {
        let mut odd = false;
        for &(a, b) in edges {
            if (a.y > p.y) != (b.y > p.y) {
                let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
                if x > p.x {
                    odd = !odd;
                }
            }
        }
        odd
    }

    /// Largest gap between two convex end-point polygons along the directions
    /// and normals of their edges: > 0 apart, 0 touching, < 0 overlapping.
    fn separation(p: &[(Point, Point)], q: &[(Point, Point)]) -> f64 {
        let pp: Vec<Point> = p.iter().flat_map(|&(a, b)| [a, b]).collect();
        let qp: Vec<Point> = q.iter().flat_map(|&(a, b)| [a, b]).collect();
        let span = |pts: &[Point], axis: Vector2<f64>| {
            pts.iter().map(|v| v.coords.dot(&axis)).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| (lo.min(d), hi.max(d)))
        };
        let mut best = f64::NEG_INFINITY;
        for &(a, b) in p.iter().chain(q) {
            let d = (b - a).normalize();
            for axis in [d, Vector2::new(-d.y, d.x)] {
                let ((p0, p1), (q0, q1)) = (span(&pp, axis), span(&qp, axis));
                best = best.max((q0 - p1).max(p0 - q1));
            }
        }
        best
    }

    /// Contours joined by common cuts, as a group number per contour.
    fn groups(inst: &Instance) -> Vec<usize> {
        let mut parent: Vec<usize> = (0..inst.contours.len()).collect();
        fn root(parent: &mut [usize], mut k: usize) -> usize {
            while parent[k] != k {
                parent[k] = parent[parent[k]];
                k = parent[k];
            }
            k
        }
        for cc in inst.common_cuts() {
            let (a, b) = (root(&mut parent, cc.contours.0), root(&mut parent, cc.contours.1));
            parent[a] = b;
        }
        (0..inst.contours.len()).map(|k| root(&mut parent, k)).collect()
    }

    /// Deepest contours first (ascending when `outer_first`), each contour's
    /// elements in its order, each element once, continuing from where the
    /// previous cut ended when it can.
    fn level_route(inst: &Instance, outer_first: bool) -> Vec<Cut> {
        let level = depth(inst);
        let mut order: Vec<usize> = (0..inst.contours.len()).collect();
        if outer_first {
            order.sort_by_key(|&k| level[k]);
        } else {
            order.sort_by_key(|&k| std::cmp::Reverse(level[k]));
        }
        let mut done = vec![false; inst.elements.len()];
        let mut route = Vec::new();
        let mut here = inst.depot;
        for k in order {
            for &e in &inst.contours[k] {
                if std::mem::replace(&mut done[e], true) {
                    continue;
                }
                let el = &inst.elements[e];
                let reversed = (el.b - here).norm() < (el.a - here).norm();
                route.push(Cut { element: e, reversed });
                here = if reversed { el.a } else { el.b };
            }
        }
        route
    }

    #[test]
    fn same_seed_same_sheet_and_the_target_is_met() {
        for target in [300, 3000] {
            for seed in 1..=3 {
                let a = sheet(target, seed);
                let n = a.elements.len();
                assert!(n * 10 >= target * 9 && n * 10 <= target * 11, "target {target}, seed {seed}: {n} elements");
                let b = sheet(target, seed);
                assert_eq!(a.elements, b.elements);
                assert_eq!(a.contours, b.contours);
                assert_eq!(a.inner_outer, b.inner_outer);
                assert_eq!((a.depot, a.metric, a.pierce_cost), (Point::new(0.0, 0.0), Metric::Euclidean, 10.0));
            }
            assert_ne!(sheet(target, 1).elements, sheet(target, 2).elements);
        }
        // A target beyond full-size parts shrinks them rather than missing it.
        let n = sheet(12000, 5).elements.len();
        assert!((10800..=13200).contains(&n), "{n} elements for 12000");
    }

    #[test]
    fn inner_contours_lie_inside_and_parts_do_not_overlap() {
        for (target, seed) in [(300, 1), (3000, 1), (3000, 2), (12000, 3)] {
            let inst = sheet(target, seed);
            let p = SheetParams::default();
            for e in &inst.elements {
                for q in [e.a, e.b] {
                    assert!(q.x >= 0.0 && q.x <= p.width && q.y >= 0.0 && q.y <= p.height, "{q} off the sheet");
                }
                assert!((e.b - e.a).norm() > 1e-6, "an element of zero length");
            }
            for &(i, o) in &inst.inner_outer {
                let outline = chords(&inst, o);
                for q in points(&inst, i) {
                    assert!(inside(q, &outline), "seed {seed}: {q} of contour {i} outside its outer {o}");
                }
            }
            let level = depth(&inst);
            let group = groups(&inst);
            // Bounding boxes of the parts on the sheet: apart, or touching
            // without overlap within a group of common cuts.
            let tops: Vec<usize> = (0..inst.contours.len()).filter(|&k| level[k] == 0).collect();
            let boxes: Vec<(Point, Point)> = tops.iter().map(|&k| crate::job::bounds_of(points(&inst, k).iter())).collect();
            for x in 0..tops.len() {
                for y in x + 1..tops.len() {
                    let ((a0, a1), (b0, b1)) = (boxes[x], boxes[y]);
                    let gap = (b0.x - a1.x).max(a0.x - b1.x).max(b0.y - a1.y).max(a0.y - b1.y);
                    if group[tops[x]] == group[tops[y]] {
                        assert!(gap >= -1e-9, "parts {} and {} overlap", tops[x], tops[y]);
                    } else {
                        assert!(gap > 0.0, "parts {} and {} touch or overlap ({gap})", tops[x], tops[y]);
                    }
                }
            }
            // Contours with the same outer (holes of a part, parts in a hole)
            // do not overlap either.
            let mut siblings: HashMap<usize, Vec<usize>> = HashMap::new();
            for &(i, o) in &inst.inner_outer {
                siblings.entry(o).or_default().push(i);
            }
            for list in siblings.values() {
                for (x, &a) in list.iter().enumerate() {
                    for &b in &list[x + 1..] {
                        let gap = separation(&chords(&inst, a), &chords(&inst, b));
                        if group[a] == group[b] {
                            assert!(gap >= -1e-9, "contours {a} and {b} overlap");
                        } else {
                            assert!(gap > 0.0, "contours {a} and {b} touch or overlap ({gap})");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn common_cuts_holes_and_nested_parts_are_all_there() {
        for (target, seed) in [(300, 1), (300, 2), (300, 3), (3000, 1), (3000, 4)] {
            let inst = sheet(target, seed);
            let mut owners = vec![0usize; inst.elements.len()];
            for c in &inst.contours {
                for &e in c {
                    owners[e] += 1;
                }
            }
            assert!(owners.iter().all(|&n| n == 1 || n == 2), "an element on no contour or on three");
            let common = inst.common_cuts();
            assert_eq!(common.len(), owners.iter().filter(|&&n| n == 2).count());
            let level = depth(&inst);
            for cc in &common {
                let (a, b) = cc.contours;
                assert_ne!(a, b);
                assert!(inst.contours[a].contains(&cc.element) && inst.contours[b].contains(&cc.element));
                // Between two parts (even levels) side by side in the same place.
                assert!(level[a].is_multiple_of(2) && level[a] == level[b]);
            }
            // One element per cut: two elements with the same end points are
            // only the two arcs of a 2-arc circle.
            let key = |p: Point| ((p.x * 1e6).round() as i64, (p.y * 1e6).round() as i64);
            let mut same_ends: HashMap<_, Vec<usize>> = HashMap::new();
            for (i, e) in inst.elements.iter().enumerate() {
                let (a, b) = (key(e.a), key(e.b));
                same_ends.entry(if a < b { (a, b) } else { (b, a) }).or_default().push(i);
            }
            for list in same_ends.values().filter(|l| l.len() > 1) {
                let circle = inst.contours.iter().any(|c| c.len() == 2 && c.contains(&list[0]) && c.contains(&list[1]));
                assert!(list.len() == 2 && circle, "elements {list:?} cut the same edge");
            }
            let holes = level.iter().filter(|&&l| l % 2 == 1).count();
            let nested = level.iter().filter(|&&l| l == 2).count();
            assert!(!common.is_empty() && holes > 0 && nested > 0, "seed {seed}: {} common cuts, {holes} holes, {nested} nested", common.len());
            if target >= 3000 {
                // Nested parts with holes of their own.
                assert!(level.contains(&3));
            }
            let st = stats(&inst);
            assert_eq!((st.holes, st.common_cuts, st.precedences), (holes, common.len(), inst.precedences()));
            assert_eq!(st.parts + st.holes + st.nested_parts, inst.contours.len());
        }
    }

    #[test]
    fn deepest_first_route_is_feasible_and_wrong_routes_are_caught() {
        for (target, seed) in [(300, 1), (3000, 1), (3000, 2)] {
            let inst = sheet(target, seed);
            let route = level_route(&inst, false);
            assert_eq!(checker::check(&inst, &route), vec![], "seed {seed}");
            assert!(inst.cost(&route).is_finite());
            // Outer contours first: their holes and nested parts come too late.
            let wrong = checker::check(&inst, &level_route(&inst, true));
            assert!(!wrong.is_empty());
            assert!(wrong.iter().all(|v| matches!(v, Violation::InnerAfterOuter { .. })));
            // A shared edge moved to just after the rest of both its contours
            // closes both.
            let cc = inst.common_cuts()[0];
            let mut moved: Vec<Cut> = route.iter().copied().filter(|c| c.element != cc.element).collect();
            let (a, b) = cc.contours;
            let last = moved.iter().rposition(|c| inst.contours[a].contains(&c.element) || inst.contours[b].contains(&c.element)).unwrap();
            moved.insert(last + 1, Cut { element: cc.element, reversed: false });
            assert_eq!(checker::check(&inst, &moved), vec![Violation::ClosesBoth { element: cc.element, contours: cc.contours }]);
        }
    }
}
