//! `gen`: new benchmark instances.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use laserd::error::{Error, Result};

use super::common::write_file;

#[derive(clap::Subcommand)]
pub enum GenCommand {
    /// A galvo planning job of one of seed 003's pattern families, as SVG
    /// (300 x 300 mm base up to 5000 geometries, every geometry within a
    /// 70 x 70 mm field; beyond 5000 the base grows to keep their density:
    /// 300 √(n / 5000) mm a side, 1342 mm for 100000, and a stage travel
    /// that covers it is needed to plan the job).
    Galvo {
        /// rnd (scattered rectangles), o (rings of squares), isw (the
        /// letters I, S, W of squares) or mixed (rectangles, circles,
        /// ellipses, polylines, polygons, paths).
        #[arg(long, ignore_case = true)]
        family: laserd::gen::galvo::Family,
        /// Number of geometries (1 to 100000).
        #[arg(long)]
        n: usize,
        /// Seed of the random layout (the same seed, the same drawing).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output file (default: standard output).
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
    },
}

pub fn run(command: GenCommand) -> Result<ExitCode> {
    let GenCommand::Galvo { family, n, seed, output } = command;
    laserd::config::in_range("--n", n, 1, laserd::gen::galvo::MAX_N, "geometries").map_err(Error::Config)?;
    let svg = laserd::gen::galvo::generate(family, n, seed).map_err(|e| Error::Io(format!("gen galvo: {e}")))?;
    match &output {
        Some(out) => write_file(out, &svg)?,
        None => {
            let mut stdout = std::io::stdout().lock();
            if let Err(e) = stdout.write_all(svg.as_bytes()).and_then(|_| stdout.flush()) {
                // A reader that stops early (`| head`) is not an error.
                if e.kind() != std::io::ErrorKind::BrokenPipe {
                    return Err(Error::Io(format!("standard output: {e}")));
                }
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
