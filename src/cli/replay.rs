//! `replay`: a recording's figures from the file alone, or re-streamed into a
//! fresh simulator and compared.

use std::path::PathBuf;
use std::process::ExitCode;

use laserd::config::{ConfigSearch, MachineConfig};
use laserd::error::Result;
use laserd::figures::sim_figures;
use laserd::record;
use laserd::report::sim_summary;

use super::common::{exit, print_json};

#[derive(clap::Args)]
pub struct ReplayArgs {
    /// An MCAP recording of laserd (dry-run, send, the service, `sim --record`).
    recording: PathBuf,
    /// Re-stream the recorded program into a fresh simulator and compare.
    #[arg(long)]
    to_sim: bool,
    /// Machine config for --to-sim (default: the shipped one; the recording's
    /// axes and baud rate are used either way).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the figures as JSON only (for scripts).
    #[arg(long)]
    json: bool,
}

pub fn run(args: ReplayArgs) -> Result<ExitCode> {
    let ReplayArgs { recording, to_sim, config, json } = args;
    let replay = record::read(&recording)?;
    let figures = sim_figures(&replay.log);
    if let Some(why) = &replay.truncated {
        eprintln!("laserd: warning: {}: recording ends early ({why}); figures cover what it holds", recording.display());
    }
    if to_sim {
        // The recording's own machine, unless another is asked for;
        // a recording that does not hold it gets the searched one.
        let recorded = replay.log.setup.as_ref().and_then(|s| s.machine.clone());
        let (machine, used, note) = match (config.as_deref(), recorded) {
            (Some(path), recorded) => {
                let machine = MachineConfig::load(Some(path))?;
                let differs = recorded.is_some_and(|r| serde_json::to_value(&r).ok() != serde_json::to_value(&machine).ok());
                let note = differs.then(|| format!("the machine of --config {} is not the recording's", path.display()));
                (machine, format!("{} (--config)", path.display()), note)
            }
            (None, Some(recorded)) => {
                let machine = recorded.checked(&format!("{}: the recorded machine", recording.display()))?;
                (machine, "the recording's".to_string(), None)
            }
            (None, None) => {
                let found = ConfigSearch::new(None).find()?;
                let note = format!("the recording does not hold its machine; re-simulated on {}", found.source);
                (found.machine, found.source.to_string(), Some(note))
            }
        };
        let (again, again_log) = laserd::run::restream(&replay.log, &machine)?;
        let differences = laserd::run::replay_differences(&figures, &replay.log, &again, &again_log, note.as_deref());
        let same = differences.is_empty();
        let report = serde_json::json!({ "recorded": figures, "re_simulated": again, "same": same, "machine": used, "differences": differences });
        if json {
            print_json(&report)?;
        } else {
            println!("{}: recorded", recording.display());
            print!("{}", sim_summary(&figures));
            println!("re-simulated:");
            print!("{}", sim_summary(&again));
            println!("machine: {used}; {}", if same { "the same figures again" } else { "differences:" });
            for d in &differences {
                println!("  {d}");
            }
        }
        return Ok(if same { ExitCode::SUCCESS } else { ExitCode::from(exit::REPLAY_DIFFERS) });
    }
    if json {
        print_json(&figures)?;
    } else {
        println!("{}: {} knots, {} link events", recording.display(), replay.log.knots.len(), replay.log.link.len());
        print!("{}", sim_summary(&figures));
    }
    Ok(ExitCode::SUCCESS)
}
