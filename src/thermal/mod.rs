//! The plate's heat (seed 000, "Generating thermal feasible tool paths"): a
//! finite-difference model of the whole plate ([`field`]) stepped through a
//! route's pierces and cuts ([`timeline`]), which tells whether every
//! operation starts where the plate is below its critical temperature.
//! The cutting planner (`plan::thermal`) uses it to find routes that keep
//! the plate cool enough; `plan --thermal` reports it.

pub mod field;
pub mod timeline;
#[cfg(test)]
mod tests;

pub use field::{Field, FieldOptions, Grid, Physics, KELVIN};
pub use timeline::{assess, AssessOptions, Assessment, Check, Corners, Critical, Feature, PathHeat, Snapshot, Source, Timeline};

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::job::Point;

/// The heat model of a machine's config: its material's constants and
/// critical temperatures, and the watts its laser puts into the plate at
/// full power. An error names what is missing.
pub fn model_of(machine: &MachineConfig) -> Result<(Physics, Critical, f64)> {
    let material = machine.material.as_ref().ok_or_else(|| Error::Config("--thermal needs a [material] section (see config/flatbed-cutter.toml)".into()))?;
    let watts = machine.laser.watts.ok_or_else(|| Error::Config("--thermal needs laser.watts, the source's output at laser.max_power".into()))?;
    let critical = Critical { pierce: material.critical_pierce, cut: material.critical_cut, corner: material.critical_corner };
    Ok((Physics::of(material, &machine.thermal), critical, watts * material.absorptivity))
}

/// The grid over the plate (`[plate]`), or, without one, over `lo`..`hi`
/// (the job's bounds) with a margin of ten cells round it.
pub fn grid_of(machine: &MachineConfig, lo: Point, hi: Point) -> Result<Grid> {
    let cell = machine.thermal.cell;
    match &machine.plate {
        Some(p) => Grid::covering(Point::new(p.x, p.y), Point::new(p.x + p.width, p.y + p.height), cell),
        None => {
            let m = nalgebra::Vector2::new(10.0 * cell, 10.0 * cell);
            Grid::covering(lo - m, hi + m, cell)
        }
    }
}
