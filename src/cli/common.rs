//! What the commands share: finding the machine config, writing reports and
//! files, range checks of flags, exit codes.

use std::cell::Cell;
use std::io::IsTerminal;
use std::path::Path;
use std::time::Duration;

use laserd::config::{ConfigSearch, ConfigSource, FoundConfig, BAUD, TIME_LIMIT};
use laserd::error::{Error, Result};

/// Exit codes besides success; scripts rely on them.
pub mod exit {
    /// An error, its one line on standard error.
    pub const ERROR: u8 = 1;
    /// The job stopped before its end, or a benchmark's result is infeasible.
    pub const STOPPED: u8 = 2;
    /// `replay --to-sim` found figures that differ from the recording's.
    pub const REPLAY_DIFFERS: u8 = 3;
    /// The simulated run broke a limit of the machine.
    pub const LIMIT_BROKEN: u8 = 4;
}

/// The machine config of a command whose text report does not carry it: the
/// search of `ConfigSearch`, and in text mode (`json` false) a line on stderr
/// saying which one was used, unless it is the one given with `--config`.
pub fn machine_config(option: Option<&Path>, json: bool) -> Result<FoundConfig> {
    let search = ConfigSearch::new(option);
    let found = search.find()?;
    match &found.source {
        _ if json => {}
        ConfigSource::Option { .. } => {}
        ConfigSource::Builtin => eprintln!("laserd: machine config: {} (none found at {})", found.source, search.places()),
        other => eprintln!("laserd: machine config: {other}"),
    }
    Ok(found)
}

pub fn print_json<T: serde::Serialize>(value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Io(e.to_string()))?;
    println!("{text}");
    Ok(())
}

/// Writes an output file; the error names it.
pub fn write_file(path: &Path, contents: impl AsRef<[u8]>) -> Result<()> {
    std::fs::write(path, contents).map_err(|e| Error::Io(format!("{}: cannot write: {e}", path.display())))
}

/// `--time-limit`, when given, within the config's range.
pub fn check_time_limit(seconds: Option<f64>) -> std::result::Result<(), String> {
    seconds.map_or(Ok(()), |t| TIME_LIMIT.check("--time-limit", t))
}

/// `--baud`, when given, within the config's range.
pub fn check_baud(baud: Option<u32>) -> std::result::Result<(), String> {
    baud.map_or(Ok(()), |b| BAUD.check("--baud", b))
}

/// The stages of a long `plan` or `dry-run` on standard error when it is a
/// terminal: a spinner with the stage's name and how long it has run, a bar
/// where the share done is known (the simulation); cleared at the end.
pub struct StageProgress {
    bar: indicatif::ProgressBar,
    counting: Cell<bool>,
}

impl StageProgress {
    /// None unless standard error is a terminal, or with `quiet` (`--json`).
    pub fn on_terminal(quiet: bool) -> Option<StageProgress> {
        (!quiet && std::io::stderr().is_terminal()).then(|| {
            let bar = indicatif::ProgressBar::new_spinner();
            bar.enable_steady_tick(Duration::from_millis(120));
            StageProgress { bar, counting: Cell::new(false) }
        })
    }

    fn style(template: &str) -> indicatif::ProgressStyle {
        indicatif::ProgressStyle::with_template(template).unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner())
    }
}

impl laserd::run::Progress for StageProgress {
    fn stage(&self, name: &str) {
        self.counting.set(false);
        self.bar.set_style(Self::style("{spinner} {msg} {elapsed}"));
        self.bar.set_message(name.to_string());
        self.bar.reset_elapsed();
    }

    fn done(&self, share: f64) {
        if !self.counting.replace(true) {
            self.bar.set_style(Self::style("{msg} [{bar:30}] {percent:>3}% {elapsed}, about {eta} left"));
            self.bar.set_length(1000);
        }
        self.bar.set_position((share.clamp(0.0, 1.0) * 1000.0) as u64);
    }
}

impl Drop for StageProgress {
    /// Gone before the report or an error is printed.
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}
