//! `gen`: new benchmark instances.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use laserd::error::{Error, Result};

use super::common::write_file;

#[derive(clap::Subcommand)]
pub enum GenCommand {
    /// A galvo planning job of one of seed 003's pattern families, as SVG
    /// (300 x 300 mm base, every geometry within a 70 x 70 mm field).
    Galvo {
        /// rnd (scattered rectangles), o (rings of squares), isw (the
        /// letters I, S, W of squares) or mixed (rectangles, circles,
        /// ellipses, polylines, polygons, paths).
        #[arg(long, ignore_case = true)]
        family: laserd::gen::galvo::Family,
        /// Number of geometries (1 to 5000).
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
