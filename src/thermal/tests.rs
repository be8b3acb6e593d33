//! The heat model against physics: closed-form solutions, energy
//! conservation, grid convergence. Each test states its tolerance.

use super::field::{Field, FieldOptions, Grid, Physics, KELVIN, STEFAN_BOLTZMANN};
use super::timeline::{assess, AssessOptions, Corners, Critical, PathHeat, Timeline};
use crate::job::Point;

/// Mild steel (AISI 1010, Incropera's Table A.1), 6 mm, no losses unless set.
fn steel() -> Physics {
    Physics { density: 7832.0, specific_heat: 434.0, conductivity: 63.9, emissivity: 0.0, thickness: 0.006, convection: 0.0, ambient: 20.0 + KELVIN }
}

fn square(side: f64, cell: f64) -> Grid {
    Grid::covering(Point::new(0.0, 0.0), Point::new(side, side), cell).unwrap()
}

/// An instantaneous point source Q in an infinite plate spreads as the 2D
/// Gaussian ΔT = Q / (ρ c d · 4π α t) · exp(-r² / 4αt). Put into one 1 mm
/// cell, after 20 s (a spread of √(4αt) = 39 mm) the model agrees within 1 %
/// of the peak everywhere, and the peak within 1 %.
#[test]
fn a_point_source_spreads_as_the_gaussian_of_an_infinite_plate() {
    let physics = steel();
    let grid = square(201.0, 1.0);
    let mut field = Field::new(grid, physics.clone(), FieldOptions::default());
    let centre = grid.centre(100, 100);
    let q = 2_000.0;
    field.deposit_in(100, 100, q);
    // The heat enters at the first step: the Gaussian's clock starts there.
    let t_end = 20.0;
    let steps = (t_end / field.dt()).round() as usize;
    for _ in 0..steps {
        field.step();
    }
    let t = field.time() - field.dt();
    let alpha = physics.diffusivity();
    let exact = |r_mm: f64| {
        let r = r_mm / 1000.0;
        q / (physics.areal_capacity() * 4.0 * std::f64::consts::PI * alpha * t) * (-r * r / (4.0 * alpha * t)).exp()
    };
    let peak = exact(0.0);
    assert!(peak > 10.0, "a rise worth measuring: {peak} K");
    let mut worst = 0.0f64;
    for iy in (0..201).step_by(5) {
        for ix in (0..201).step_by(5) {
            let r = (grid.centre(ix, iy) - centre).norm();
            let model = field.celsius(ix, iy) - 20.0;
            worst = worst.max((model - exact(r)).abs());
        }
    }
    assert!(worst < 0.01 * peak, "largest difference {worst} K against a peak of {peak} K");
    assert!(((field.celsius(100, 100) - 20.0) - peak).abs() < 0.01 * peak);
}

/// A uniform plate cooled by convection alone follows Newton's law,
/// ΔT = ΔT₀ · exp(-h t / ρ c d), within 0.1 % of ΔT₀ over 30 minutes.
#[test]
fn a_uniform_plate_cools_by_newtons_law() {
    let physics = Physics { convection: 20.0, ..steel() };
    let mut field = Field::new(square(50.0, 5.0), physics.clone(), FieldOptions::default());
    field.set_uniform(520.0);
    let tau = physics.areal_capacity() / physics.convection;
    while field.time() < 1800.0 {
        field.step();
        let exact = 500.0 * (-field.time() / tau).exp();
        let model = field.celsius(3, 7) - 20.0;
        assert!((model - exact).abs() < 0.5, "at {:.1} s: {model} against {exact}", field.time());
    }
    // It did cool: more than a time constant went by.
    assert!(field.celsius(0, 0) - 20.0 < 500.0 * (-1.0f64).exp());
}

/// A uniform plate cooled by radiation alone from both faces,
/// dT/dt = -2εσ(T⁴ - T∞⁴) / ρ c d, meets the closed form
/// t = G(T₀) - G(T) with G(T) = [ln((T+T∞)/(T-T∞)) + 2 atan(T/T∞)] / (4 k T∞³)
/// (k = 2εσ/ρcd) within 1 K over an hour from 1000 °C.
#[test]
fn a_uniform_plate_cools_by_radiation_as_the_closed_form() {
    let physics = Physics { emissivity: 0.8, ..steel() };
    let mut field = Field::new(square(50.0, 5.0), physics.clone(), FieldOptions::default());
    field.set_uniform(1000.0);
    let ta = physics.ambient;
    let k = 2.0 * physics.emissivity * STEFAN_BOLTZMANN / physics.areal_capacity();
    let g = |t: f64| (((t + ta) / (t - ta)).ln() + 2.0 * (t / ta).atan()) / (4.0 * k * ta.powi(3));
    // The temperature the closed form gives at time s: G is decreasing in T.
    let exact = |s: f64| {
        let target = g(1000.0 + KELVIN) + s;
        let (mut lo, mut hi) = (ta + 1e-9, 1000.0 + KELVIN);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if g(mid) > target { lo = mid } else { hi = mid }
        }
        0.5 * (lo + hi) - KELVIN
    };
    let mut worst = 0.0f64;
    while field.time() < 3600.0 {
        field.step();
        worst = worst.max((field.celsius(4, 4) - exact(field.time())).abs());
    }
    assert!(worst < 1.0, "largest difference {worst} K");
    assert!(field.celsius(4, 4) < 500.0, "it cooled: {}", field.celsius(4, 4));
}

/// With convection and radiation off, the plate's edges and the kerfs
/// insulate: the heat in the plate is all that pierces, cuts and dwells put
/// in, to 1e-6 of it, through kerfs closing links as they are cut.
#[test]
fn with_all_losses_off_the_plate_keeps_every_joule() {
    let physics = steel();
    let grid = square(300.0, 5.0);
    let p = |x: f64, y: f64| Point::new(x, y);
    let square_path = [p(50.0, 50.0), p(150.0, 50.0), p(150.0, 150.0), p(50.0, 150.0), p(50.0, 50.0)];
    let slit = [p(200.0, 20.0), p(230.0, 280.0)];
    let paths = [
        PathHeat { points: &square_path, start: 0.0, pierce: Some((0.5, 300.0)), speed: 40.0, watts: 400.0 },
        PathHeat { points: &slit, start: 12.0, pierce: Some((0.3, 300.0)), speed: 25.0, watts: 350.0 },
    ];
    let timeline = Timeline::build(&paths, Corners { cos_sharp: 30f64.to_radians().cos(), dwell: 0.2 }, 2.5);
    let put_in: f64 = timeline.sources.iter().map(|s| s.watts * s.duration).sum();
    let critical = Critical { pierce: 1e6, cut: 1e6, corner: 1e6 };
    let mut field_after = None;
    for cold_below in [0.0, FieldOptions::default().cold_below] {
        let options = AssessOptions { field: FieldOptions { cold_below, ..Default::default() }, snapshot_every: None, ..Default::default() };
        let a = assess(grid, &physics, critical, &timeline, &options);
        assert!(a.end > 20.0);
        // The assessment runs to the end of the timeline; measure the field directly too.
        let mut field = Field::new(grid, physics.clone(), options.field);
        let dt = field.dt();
        for s in &timeline.sources {
            // Whole sources at once: the energy does not depend on when.
            field.deposit_along(s.from, s.to, s.watts * s.duration);
            field.cut_kerf(s.from, s.to);
        }
        for _ in 0..(100.0 / dt) as usize {
            field.step();
        }
        let kept = field.energy();
        assert!(((kept - put_in) / put_in).abs() < 1e-6, "cold_below {cold_below}: kept {kept} J of {put_in} J");
        field_after = Some(field);
    }
    // The kerf insulates: the square's inside (cut free) stays apart from
    // the outside; heat put in near the square's edge inside stays in.
    let field = field_after.unwrap();
    let inside = field.celsius_at(p(100.0, 100.0));
    let outside = field.celsius_at(p(100.0, 30.0));
    assert!(inside > 20.0 && outside > 20.0 && (inside - outside).abs() > 1.0, "inside {inside}, outside {outside}");
}

/// Heat put in on one side of a closed kerf never reaches the other side.
#[test]
fn a_closed_kerf_is_an_adiabatic_boundary() {
    let grid = square(100.0, 2.0);
    let mut field = Field::new(grid, steel(), FieldOptions::default());
    let p = |x: f64, y: f64| Point::new(x, y);
    let ring = [p(30.0, 30.0), p(70.0, 30.0), p(70.0, 70.0), p(30.0, 70.0), p(30.0, 30.0)];
    for w in ring.windows(2) {
        field.cut_kerf(w[0], w[1]);
    }
    field.deposit_in(25, 25, 500.0);
    for _ in 0..2000 {
        field.step();
    }
    assert_eq!(field.celsius_at(p(10.0, 10.0)), 20.0, "outside the ring: untouched");
    assert!(field.celsius_at(p(35.0, 35.0)) > 20.0, "inside the ring: warmed");
    // The ring's inside holds all of it, evenly by now: 500 J over 40 x 40 mm.
    let physics = steel();
    let rise = 500.0 / (physics.areal_capacity() * 0.04 * 0.04);
    assert!((field.celsius_at(p(50.0, 50.0)) - 20.0 - rise).abs() < 0.02 * rise);
}

/// Halving the cell size changes the peak temperature that a 200 mm cut
/// leaves 15 mm beside it (where the next cut would run) by less than 1 % of
/// the rise from 5 to 2.5 mm cells, and less again from 2.5 to 1.25 mm.
#[test]
fn halving_the_cells_changes_the_peak_beside_a_cut_by_under_one_percent() {
    let p = |x: f64, y: f64| Point::new(x, y);
    let line = [p(50.0, 100.0), p(250.0, 100.0)];
    let probe = p(150.0, 115.0);
    let peak = |cell: f64| {
        let grid = Grid::covering(p(0.0, 0.0), p(300.0, 200.0), cell).unwrap();
        let physics = Physics { convection: 20.0, emissivity: 0.8, ..steel() };
        let paths = [PathHeat { points: &line, start: 0.0, pierce: Some((0.5, 600.0)), speed: 30.0, watts: 600.0 }];
        let timeline = Timeline::build(&paths, Corners { cos_sharp: 0.5, dwell: 0.0 }, cell / 2.0);
        let mut field = Field::new(grid, physics, FieldOptions::default());
        let mut best = f64::NEG_INFINITY;
        let mut k = 0;
        while field.time() < 30.0 {
            let (t0, t1) = (field.time(), field.time() + field.dt());
            for s in &timeline.sources {
                let (a, b) = (t0.max(s.start), t1.min(s.start + s.duration));
                if b > a {
                    field.deposit_along(s.at(a), s.at(b), s.watts * (b - a));
                    if s.kerf {
                        field.cut_kerf(s.at(a), s.at(b));
                    }
                }
            }
            field.step();
            best = best.max(field.celsius_at(probe));
            k += 1;
        }
        assert!(k > 10);
        best - 20.0
    };
    let (coarse, mid, fine) = (peak(5.0), peak(2.5), peak(1.25));
    assert!(coarse > 10.0, "a rise worth measuring: {coarse} K");
    let (first, second) = ((mid - coarse).abs() / fine, (fine - mid).abs() / fine);
    assert!(first < 0.01, "5 → 2.5 mm: {coarse:.2} → {mid:.2} K ({:.2} %)", 100.0 * first);
    assert!(second < first.max(0.005), "2.5 → 1.25 mm: {mid:.2} → {fine:.2} K");
    eprintln!("peak 15 mm beside the cut: {coarse:.3} / {mid:.3} / {fine:.3} K at 5 / 2.5 / 1.25 mm");
}

