//! `send`: stream an existing G-code file to a controller.

use std::cell::Cell;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use laserd::config::FoundConfig;
use laserd::error::{Error, Result};
use laserd::program::times::PlannedTimes;
use laserd::report::duration;
use laserd::stream::{self, LinkEvent, SenderOptions};

use super::common::{check_baud, exit, machine_config, print_json};

#[derive(clap::Args)]
pub struct SendArgs {
    /// The G-code file, streamed as it is (in bounded memory, whatever its size).
    file: PathBuf,
    /// The controller's serial port, e.g. /dev/ttyUSB0 (or a `laserd sim` pty).
    #[arg(long)]
    port: String,
    /// Baud rate, 300 to 12000000 (default: the config's [serial] baud).
    #[arg(long)]
    baud: Option<u32>,
    /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
    /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Validate only, in the controller's check mode ($C): nothing moves,
    /// every rejected line is reported.
    #[arg(long)]
    check: bool,
    /// Print the report as JSON (for scripts) instead of a line for people.
    #[arg(long)]
    json: bool,
}

pub fn run(args: SendArgs) -> Result<ExitCode> {
    check_baud(args.baud).map_err(Error::Config)?;
    send(&args.file, &args.port, args.baud, args.config.as_deref(), args.check, args.json)
}

fn send(file: &Path, port: &str, baud: Option<u32>, config: Option<&Path>, check: bool, json: bool) -> Result<ExitCode> {
    let FoundConfig { machine, source, .. } = machine_config(config, json)?;
    let shown = file.display().to_string();
    let opened = std::fs::File::open(file).map_err(|e| Error::Io(format!("{shown}: cannot read: {e}")))?;
    let size = opened.metadata().map(|m| m.len()).unwrap_or(0);
    // Read as the controller takes lines: memory stays constant whatever the size.
    // Bytes read so far drive the progress bar (comments never reach the link).
    let read = Cell::new(0u64);
    let lines = stream::FileLines::new(std::io::BufReader::new(opened), &shown).inspect(|l| {
        if let Ok(l) = l {
            read.set(read.get() + l.len() as u64 + 1);
        }
    });
    let baud = baud.unwrap_or(machine.serial.baud);
    let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    options.hold_limit = options.hold_limit_for(machine.stop_time_s());
    options.check_mode = check;
    let progress = (!json && std::io::stderr().is_terminal()).then(|| {
        // A program laserd wrote carries its planned time line by line: the
        // bar and ETA go by it (a rate of lines or bytes misjudges a job
        // whose lines are of very different lengths in time). Else by bytes.
        let planned = std::fs::File::open(file).ok().and_then(|f| PlannedTimes::read(stream::FileLines::new(std::io::BufReader::new(f), &shown)));
        let style = |template: &str| indicatif::ProgressStyle::with_template(template).unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
        let bar = match &planned {
            Some(times) => {
                let bar = indicatif::ProgressBar::new((times.total_s * 1000.0).ceil() as u64);
                bar.set_style(style("{bar:40} {percent:>3}% line {msg}"));
                bar
            }
            None => {
                let bar = indicatif::ProgressBar::new(size);
                bar.set_style(style("{bar:40} {percent:>3}% {bytes}/{total_bytes} line {msg} eta {eta}"));
                bar
            }
        };
        (bar, planned)
    });
    let (started, last_line) = (Cell::new(None), Cell::new(0));
    let runtime = tokio::runtime::Runtime::new().map_err(|e| Error::Io(e.to_string()))?;
    let outcome = runtime.block_on(async {
        use tokio_serial::SerialPortBuilderExt;
        let io = tokio_serial::new(port, baud)
            .open_native_async()
            .map_err(|e| Error::Stream(format!("{port}: cannot open: {e}")))?;
        let describe = |n: usize, text: &str| format!("{shown}:{n} `{text}`");
        let mut connection = stream::Connection::open(io, &options, |_, event| {
            let Some((bar, planned)) = &progress else { return };
            if let LinkEvent::Sent { line, .. } = &event {
                // Lines of the sender's own (line 0) are not the program's.
                if *line > 0 {
                    last_line.set(*line);
                    started.set(started.get().or(Some(std::time::Instant::now())));
                }
            }
            let line = last_line.get();
            match (planned, started.get()) {
                // Any event (status reports too) moves the clock on.
                (Some(times), Some(first)) => {
                    let left = times.left(line, first.elapsed().as_secs_f64());
                    bar.set_position(((times.total_s - left) * 1000.0) as u64);
                    bar.set_message(format!("{line}, {} left of {} planned", duration(left), duration(times.total_s)));
                }
                (Some(_), None) => {}
                (None, _) => {
                    bar.set_position(read.get());
                    bar.set_message(line.to_string());
                }
            }
        })
        .await?;
        // laserd's programs are in bed coordinates: the controller's work
        // coordinates are made those first (G54 from its homing settings).
        connection.use_program_frame([machine.stage.travel_x, machine.stage.travel_y]).await?;
        connection.stream(lines, &describe, None).await
    })?;
    if let Some((bar, _)) = progress {
        bar.finish_and_clear();
    }
    let report = serde_json::json!({
        "file": shown,
        "lines_sent": outcome.lines_sent,
        "bytes_sent": outcome.bytes_sent,
        "stream_time_s": outcome.stream_time_s,
        "link_utilization": stream::link_utilization(outcome.bytes_sent, baud, outcome.stream_time_s),
        "errors": outcome.errors,
        "alarms": outcome.alarms,
        "last_acked_line": outcome.last_acked_line,
        "last_executed_line": outcome.last_executed_line,
        "completed": outcome.completed,
        "config": source,
    });
    if json {
        print_json(&report)?;
    } else {
        println!(
            "{shown}: {} lines, {} bytes in {}{}{}",
            outcome.lines_sent,
            outcome.bytes_sent,
            duration(outcome.stream_time_s),
            if check { " (check mode)" } else { "" },
            if outcome.completed { ", completed" } else { "" }
        );
    }
    if let Some(reason) = outcome.stop_reason {
        eprintln!("laserd: error: job stopped: {reason}");
        return Ok(ExitCode::from(exit::STOPPED));
    }
    Ok(ExitCode::SUCCESS)
}

