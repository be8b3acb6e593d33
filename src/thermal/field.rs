//! The plate as a grid of square cells, each of the plate's whole thickness,
//! stepped in time by explicit finite differences (seed 000's equation (1)):
//! conduction to the four neighbours, convection from the top and bottom
//! faces, radiation from both, and the heat the laser puts in. A link
//! between two cells that a finished kerf crosses carries nothing (the kerf
//! is an adiabatic boundary), nor do the plate's edges.
//!
//! Speed: only tiles of cells that are warm (or next to warm ones, or
//! heated this step) are stepped; a cold tile's cells are within
//! `cold_below` of the ambient and stay as they are.

use crate::config::{MaterialConfig, ThermalConfig};
use crate::error::{Error, Result};
use crate::job::Point;

pub const STEFAN_BOLTZMANN: f64 = 5.670_374_419e-8;
pub const KELVIN: f64 = 273.15;

/// The plate's physical constants, SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct Physics {
    /// kg/m³, J/(kg·K), W/(m·K).
    pub density: f64,
    pub specific_heat: f64,
    pub conductivity: f64,
    pub emissivity: f64,
    /// m.
    pub thickness: f64,
    /// Top plus bottom convection coefficients, W/(m²·K).
    pub convection: f64,
    /// K.
    pub ambient: f64,
}

impl Physics {
    pub fn of(material: &MaterialConfig, thermal: &ThermalConfig) -> Physics {
        Physics {
            density: material.density,
            specific_heat: material.specific_heat,
            conductivity: material.conductivity,
            emissivity: material.emissivity,
            thickness: material.thickness / 1000.0,
            convection: thermal.convection_top + thermal.convection_bottom,
            ambient: thermal.ambient + KELVIN,
        }
    }

    /// Thermal diffusivity, m²/s.
    pub fn diffusivity(&self) -> f64 {
        self.conductivity / (self.density * self.specific_heat)
    }

    /// Heat per square metre of plate and kelvin, J/(m²·K).
    pub fn areal_capacity(&self) -> f64 {
        self.density * self.specific_heat * self.thickness
    }
}

/// Square cells of `cell` mm over a rectangle of the machine, `nx` by `ny`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub origin: Point,
    pub cell: f64,
    pub nx: usize,
    pub ny: usize,
}

/// Most cells a model may have (two temperature fields of 8 bytes and two
/// link fields each: 32 bytes a cell, 256 MB at most).
pub const MAX_CELLS: usize = 8_000_000;

impl Grid {
    /// The cells covering `lo`..`hi` (mm), refused by name beyond [`MAX_CELLS`].
    pub fn covering(lo: Point, hi: Point, cell: f64) -> Result<Grid> {
        let count = |span: f64| ((span / cell).ceil() as usize).max(1);
        let (nx, ny) = (count(hi.x - lo.x), count(hi.y - lo.y));
        if !(hi.x - lo.x).is_finite() || !(hi.y - lo.y).is_finite() || nx.saturating_mul(ny) > MAX_CELLS {
            return Err(Error::Config(format!(
                "thermal.cell: {cell} mm cells over {:.0} x {:.0} mm make more than {MAX_CELLS} cells; use larger cells",
                hi.x - lo.x,
                hi.y - lo.y
            )));
        }
        Ok(Grid { origin: lo, cell, nx, ny })
    }

    pub fn cells(&self) -> usize {
        self.nx * self.ny
    }

    /// The column and row of the cell `p` lies in (the nearest edge cell
    /// for a point outside).
    pub fn cell_of(&self, p: Point) -> (usize, usize) {
        let at = |v: f64, n: usize| ((v / self.cell).floor().max(0.0) as usize).min(n - 1);
        (at(p.x - self.origin.x, self.nx), at(p.y - self.origin.y, self.ny))
    }

    /// The cells whose centres are round `p`, for bilinear weights: the
    /// lower-left one, the upper-right one (the same column or row on a
    /// plate one cell wide), and where `p` lies between them (0 to 1 each
    /// way; clamped to the edge cells' centres).
    pub fn around(&self, p: Point) -> ((usize, usize), (usize, usize), (f64, f64)) {
        let f = |v: f64, o: f64, n: usize| ((v - o) / self.cell - 0.5).clamp(0.0, (n - 1) as f64);
        let (fx, fy) = (f(p.x, self.origin.x, self.nx), f(p.y, self.origin.y, self.ny));
        let (ix, iy) = ((fx.floor() as usize).min(self.nx.saturating_sub(2)), (fy.floor() as usize).min(self.ny.saturating_sub(2)));
        let (ux, uy) = ((fx - ix as f64).clamp(0.0, 1.0), (fy - iy as f64).clamp(0.0, 1.0));
        ((ix, iy), ((ix + 1).min(self.nx - 1), (iy + 1).min(self.ny - 1)), (ux, uy))
    }

    pub fn centre(&self, ix: usize, iy: usize) -> Point {
        self.origin + nalgebra::Vector2::new((ix as f64 + 0.5) * self.cell, (iy as f64 + 0.5) * self.cell)
    }
}

/// How the field is stepped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldOptions {
    /// The time step (s); `None`: 0.9 of the largest stable one.
    pub dt: Option<f64>,
    /// A tile whose cells all lie within this of the ambient (K), and whose
    /// neighbours do too, is not stepped.
    pub cold_below: f64,
}

impl Default for FieldOptions {
    fn default() -> Self {
        FieldOptions { dt: None, cold_below: 1e-4 }
    }
}

/// Cells a side of a tile (the unit of skipping cold plate).
const TILE: usize = 16;

/// The hottest temperature the stability bound allows for radiation, K.
const HOTTEST: f64 = 3_000.0;

/// The plate's temperatures at one time.
#[derive(Debug, Clone)]
pub struct Field {
    pub grid: Grid,
    physics: Physics,
    /// Padded by one cell all round (its links closed): row stride `nx + 2`. K.
    t: Vec<f64>,
    next: Vec<f64>,
    /// Link to the east and north neighbour: 1 open, 0 closed (edge, kerf).
    east: Vec<f32>,
    north: Vec<f32>,
    /// The row kernel may use AVX2 (the same numbers, faster).
    avx2: bool,
    dt: f64,
    time: f64,
    /// Per tile: warm after the last step; stepped in it.
    warm: Vec<bool>,
    stepped: Vec<bool>,
    tiles: (usize, usize),
    cold_below: f64,
    cell_updates: u64,
    /// Per step: conduction, convection, radiation factors; 1 / a cell's heat capacity.
    r: f64,
    beta: f64,
    gamma: f64,
    inv_capacity: f64,
}

impl Field {
    /// The plate at the ambient temperature.
    pub fn new(grid: Grid, physics: Physics, options: FieldOptions) -> Field {
        let a = grid.cell / 1000.0;
        let c = physics.areal_capacity();
        let (r_rate, beta_rate, gamma_rate) = (physics.diffusivity() / (a * a), physics.convection / c, 2.0 * physics.emissivity * STEFAN_BOLTZMANN / c);
        let stable = 1.0 / (4.0 * r_rate + beta_rate + 4.0 * gamma_rate * HOTTEST.powi(3));
        let dt = options.dt.unwrap_or(0.9 * stable);
        let w = grid.nx + 2;
        let size = w * (grid.ny + 2);
        let mut east = vec![0.0; size];
        let mut north = vec![0.0; size];
        for iy in 0..grid.ny {
            for ix in 0..grid.nx {
                let i = (iy + 1) * w + ix + 1;
                east[i] = if ix + 1 < grid.nx { 1.0 } else { 0.0 };
                north[i] = if iy + 1 < grid.ny { 1.0 } else { 0.0 };
            }
        }
        let tiles = (grid.nx.div_ceil(TILE), grid.ny.div_ceil(TILE));
        Field {
            grid,
            t: vec![physics.ambient; size],
            next: vec![physics.ambient; size],
            east,
            north,
            avx2: has_avx2(),
            dt,
            time: 0.0,
            warm: vec![false; tiles.0 * tiles.1],
            stepped: vec![false; tiles.0 * tiles.1],
            tiles,
            cold_below: options.cold_below,
            cell_updates: 0,
            r: r_rate * dt,
            beta: beta_rate * dt,
            gamma: gamma_rate * dt,
            inv_capacity: 1.0 / (c * a * a),
            physics,
        }
    }

    pub fn dt(&self) -> f64 {
        self.dt
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    pub fn physics(&self) -> &Physics {
        &self.physics
    }

    /// Cells stepped so far (a cold tile's cells are not counted).
    pub fn cell_updates(&self) -> u64 {
        self.cell_updates
    }

    fn index(&self, ix: usize, iy: usize) -> usize {
        (iy + 1) * (self.grid.nx + 2) + ix + 1
    }

    fn tile_of(&self, ix: usize, iy: usize) -> usize {
        (iy / TILE) * self.tiles.0 + ix / TILE
    }

    /// Sets every cell to `celsius` (tests, and a plate not at the ambient).
    pub fn set_uniform(&mut self, celsius: f64) {
        let k = celsius + KELVIN;
        for iy in 0..self.grid.ny {
            for ix in 0..self.grid.nx {
                let i = self.index(ix, iy);
                self.t[i] = k;
                self.next[i] = k;
            }
        }
        let warm = (k - self.physics.ambient).abs() > self.cold_below;
        self.warm.fill(warm);
    }

    /// Puts `joules` in at `p`, taken in at the next step: shared between
    /// the four nearest cell centres (bilinear), so that a cut's heat goes
    /// to both sides of its kerf.
    pub fn deposit(&mut self, p: Point, joules: f64) {
        let ((ix, iy), (jx, jy), (ux, uy)) = self.grid.around(p);
        for (x, y, w) in [(ix, iy, (1.0 - ux) * (1.0 - uy)), (jx, iy, ux * (1.0 - uy)), (ix, jy, (1.0 - ux) * uy), (jx, jy, ux * uy)] {
            if w > 0.0 {
                self.deposit_in(x, y, joules * w);
            }
        }
    }

    /// Puts `joules` into cell (`ix`, `iy`) (its temperature rises at once).
    pub fn deposit_in(&mut self, ix: usize, iy: usize, joules: f64) {
        let i = self.index(ix, iy);
        self.t[i] += joules * self.inv_capacity;
        let tile = self.tile_of(ix, iy);
        self.warm[tile] = true;
    }

    /// Puts `joules` along the segment `a`-`b`, evenly by length (points a
    /// quarter cell apart at most).
    pub fn deposit_along(&mut self, a: Point, b: Point, joules: f64) {
        let n = (((b - a).norm() / (self.grid.cell / 4.0)).ceil() as usize).max(1);
        for k in 0..n {
            let f = (k as f64 + 0.5) / n as f64;
            self.deposit(a + (b - a) * f, joules / n as f64);
        }
    }

    /// Closes every link the kerf `a`-`b` crosses (a link joins two cell centres).
    pub fn cut_kerf(&mut self, a: Point, b: Point) {
        let g = self.grid;
        let (ox, oy, s) = (g.origin.x, g.origin.y, g.cell);
        // Links between rows j and j+1 at column i: crossed where the kerf
        // passes the column's centre line between the two centres.
        let close = |field: &mut Field, north: bool, ix: usize, iy: usize| {
            let i = field.index(ix, iy);
            if north { field.north[i] = 0.0 } else { field.east[i] = 0.0 }
        };
        for (along, across, n_along, n_across, north) in [((a.x, b.x, ox), (a.y, b.y, oy), g.nx, g.ny, true), ((a.y, b.y, oy), (a.x, b.x, ox), g.ny, g.nx, false)] {
            let ((p0, p1, o), (q0, q1, oq)) = (along, across);
            if p0 == p1 {
                continue;
            }
            let (lo, hi) = (p0.min(p1), p0.max(p1));
            let first = (((lo - o) / s - 0.5).ceil().max(0.0)) as usize;
            let mut k = first;
            while k < n_along {
                let centre = o + (k as f64 + 0.5) * s;
                if centre > hi {
                    break;
                }
                let q = q0 + (q1 - q0) * (centre - p0) / (p1 - p0);
                let j = ((q - oq) / s - 0.5).floor();
                if j >= 0.0 && (j as usize) + 1 < n_across {
                    let j = j as usize;
                    if north { close(self, true, k, j) } else { close(self, false, j, k) }
                }
                k += 1;
            }
        }
    }

    /// One time step: every warm tile and its neighbours.
    pub fn step(&mut self) {
        let (tx, ty) = self.tiles;
        let mut step_tile = vec![false; tx * ty];
        for y in 0..ty {
            for x in 0..tx {
                if self.warm[y * tx + x] {
                    for (dx, dy) in [(0i64, 0i64), (-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1)] {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        if nx >= 0 && ny >= 0 && (nx as usize) < tx && (ny as usize) < ty {
                            step_tile[ny as usize * tx + nx as usize] = true;
                        }
                    }
                }
            }
        }
        let w = self.grid.nx + 2;
        let amb = self.physics.ambient;
        let amb4 = amb.powi(4);
        let (r, beta, gamma) = (self.r, self.beta, self.gamma);
        let x_of = |txi: usize| (txi * TILE).min(self.grid.nx);
        for tyi in 0..ty {
            let (y0, y1) = (tyi * TILE, ((tyi + 1) * TILE).min(self.grid.ny));
            let mut txi = 0;
            while txi < tx {
                let tile = tyi * tx + txi;
                if !step_tile[tile] {
                    // Cold: its cells keep their values in the next field too.
                    if self.stepped[tile] {
                        let (x0, x1) = (x_of(txi), x_of(txi + 1));
                        for iy in y0..y1 {
                            let row = (iy + 1) * w + 1;
                            self.next[row + x0..row + x1].copy_from_slice(&self.t[row + x0..row + x1]);
                        }
                    }
                    self.stepped[tile] = false;
                    self.warm[tile] = false;
                    txi += 1;
                    continue;
                }
                // A run of tiles to step, a row of cells across all of them at
                // a time (long rows vectorise better than a tile's).
                let end = (txi..tx).find(|&j| !step_tile[tyi * tx + j]).unwrap_or(tx);
                let (x0, x1) = (x_of(txi), x_of(end));
                let first = tile;
                self.warm[first..first + end - txi].fill(false);
                for iy in y0..y1 {
                    let (a, b) = ((iy + 1) * w + 1 + x0, (iy + 1) * w + 1 + x1);
                    let (t, e, n) = (&self.t, &self.east, &self.north);
                    let out = &mut self.next[a..b];
                    let rows = Rows { c: &t[a..b], e: &t[a + 1..b + 1], w: &t[a - 1..b - 1], n: &t[a + w..b + w], s: &t[a - w..b - w] };
                    let links = Links { e: &e[a..b], w: &e[a - 1..b - 1], n: &n[a..b], s: &n[a - w..b - w] };
                    let k = Coefficients { r, beta, gamma, amb, amb4 };
                    if self.avx2 {
                        // SAFETY: the CPU has AVX2 (checked at run time).
                        #[cfg(target_arch = "x86_64")]
                        unsafe {
                            row_avx2(out, &rows, &links, &k)
                        }
                    } else {
                        row(out, &rows, &links, &k);
                    }
                    for (j, cells) in out.chunks(TILE).enumerate() {
                        let warm = &mut self.warm[first + j];
                        *warm = *warm || cells.iter().any(|&v| (v - amb).abs() > self.cold_below);
                    }
                }
                self.cell_updates += ((x1 - x0) * (y1 - y0)) as u64;
                self.stepped[first..first + end - txi].fill(true);
                txi = end;
            }
        }
        std::mem::swap(&mut self.t, &mut self.next);
        self.time += self.dt;
    }

    /// The temperature at `p`, °C: between the four nearest cell centres
    /// (bilinear), or the nearest cell's at the plate's edges.
    pub fn celsius_at(&self, p: Point) -> f64 {
        let ((ix, iy), (jx, jy), (ux, uy)) = self.grid.around(p);
        let at = |x: usize, y: usize| self.t[self.index(x, y)];
        let bottom = at(ix, iy) * (1.0 - ux) + at(jx, iy) * ux;
        let top = at(ix, jy) * (1.0 - ux) + at(jx, jy) * ux;
        bottom * (1.0 - uy) + top * uy - KELVIN
    }

    /// The temperature of cell (`ix`, `iy`), °C.
    pub fn celsius(&self, ix: usize, iy: usize) -> f64 {
        self.t[self.index(ix, iy)] - KELVIN
    }

    /// The heat in the plate above the ambient, J.
    pub fn energy(&self) -> f64 {
        let mut sum = 0.0;
        for iy in 0..self.grid.ny {
            for ix in 0..self.grid.nx {
                sum += self.t[self.index(ix, iy)] - self.physics.ambient;
            }
        }
        sum / self.inv_capacity
    }

    /// The hottest cell's centre and temperature, °C.
    pub fn hottest(&self) -> (Point, f64) {
        let mut best = ((0, 0), f64::NEG_INFINITY);
        for iy in 0..self.grid.ny {
            for ix in 0..self.grid.nx {
                let v = self.t[self.index(ix, iy)];
                if v > best.1 {
                    best = ((ix, iy), v);
                }
            }
        }
        (self.grid.centre(best.0 .0, best.0 .1), best.1 - KELVIN)
    }

    /// Every cell's temperature, °C, row by row from the grid's origin.
    pub fn celsius_rows(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.grid.cells());
        for iy in 0..self.grid.ny {
            for ix in 0..self.grid.nx {
                out.push((self.t[self.index(ix, iy)] - KELVIN) as f32);
            }
        }
        out
    }
}

/// A row of cells and its four neighbour rows, K.
struct Rows<'a> {
    c: &'a [f64],
    e: &'a [f64],
    w: &'a [f64],
    n: &'a [f64],
    s: &'a [f64],
}

/// The row's links to its four neighbours (1 open, 0 closed).
struct Links<'a> {
    e: &'a [f32],
    w: &'a [f32],
    n: &'a [f32],
    s: &'a [f32],
}

struct Coefficients {
    r: f64,
    beta: f64,
    gamma: f64,
    amb: f64,
    amb4: f64,
}

/// One step of one row (seed 000's equation (1)): conduction through open
/// links, convection, radiation. Slices cut to one length, so that the loop
/// has no index checks and vectorises.
#[inline(always)]
fn row(out: &mut [f64], t: &Rows, l: &Links, k: &Coefficients) {
    let len = out.len();
    let (tc, te, tw, tn, ts) = (&t.c[..len], &t.e[..len], &t.w[..len], &t.n[..len], &t.s[..len]);
    let (le, lw, ln, ls) = (&l.e[..len], &l.w[..len], &l.n[..len], &l.s[..len]);
    for i in 0..len {
        let c = tc[i];
        let flow = le[i] as f64 * (te[i] - c) + lw[i] as f64 * (tw[i] - c) + ln[i] as f64 * (tn[i] - c) + ls[i] as f64 * (ts[i] - c);
        let c2 = c * c;
        out[i] = c + k.r * flow - k.beta * (c - k.amb) - k.gamma * (c2 * c2 - k.amb4);
    }
}

/// [`row`] compiled for AVX2: the same operations in the same order (Rust
/// never fuses a multiply and an add), so the same numbers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn row_avx2(out: &mut [f64], t: &Rows, l: &Links, k: &Coefficients) {
    row(out, t, l, k)
}

fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
