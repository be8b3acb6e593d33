//! Instance generation for benchmarks and `laserd gen`: TSPLIB instances made
//! precedence-constrained, nested-part sheets, and the galvo test families of
//! seed 003. No planner uses these; they only feed `bench` and `gen`.

pub mod galvo;
pub mod sheet;
pub mod tsplib;
#[cfg(test)]
mod tests;
