//! `sim`: the simulated controller as a GRBL device on a pseudo-terminal.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use laserd::config::{in_range, MachineConfig, TRAVEL};
use laserd::error::{Error, Result};
use laserd::record::{Recording, TOPIC_SETUP};
use laserd::run;
use laserd::stream::LinkEvent;
use laserd_sim::controller::{Controller, Faults, Flavor, MotionModel};
use laserd_sim::pty::Observed;
use laserd_sim::wire::realtime;

use super::common::{check_baud, machine_config};

#[derive(clap::Args)]
pub struct SimArgs {
    /// Machine config: the simulated controller's axes, limits and flavour
    /// (default: as for plan).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Serve on a pseudo-terminal (the default, and the only transport in this version).
    #[arg(long)]
    pty: bool,
    /// Stable symlink to the pseudo-terminal device.
    #[arg(long)]
    link: Option<PathBuf>,
    /// The serial rate the simulator paces its bytes at, 300 to 12000000
    /// (default: the config's [serial] baud).
    #[arg(long)]
    baud: Option<u32>,
    /// Run in real time (always so on a pseudo-terminal).
    #[arg(long)]
    realtime: bool,
    /// Record the executed motion to this MCAP file.
    #[arg(long)]
    record: Option<PathBuf>,
    /// How the simulated controller executes blocks (default: the config's
    /// [simulator] motion): timed, or grbl (Grbl 1.1's planner).
    #[arg(long)]
    motion: Option<MotionModel>,
    /// The firmware it answers as (default: the config's [simulator]
    /// flavor): grbl (Grbl 1.1h, axes X Y Z only) or grblhal. For
    /// grblhal also set [serial] rx_buffer and [simulator]
    /// planner_blocks to the board's (1024, 100).
    #[arg(long)]
    flavor: Option<Flavor>,
    /// Inject a fault, e.g. `--fault error-on-line=40`; repeatable. Faults:
    /// error-on-line, drop-byte, corrupt-byte, mute-from-line, reset-at-line,
    /// limit-alarm-at-line, close-link-at-line (=N: lines and bytes count
    /// from 1), probe-contact-mm=D (the probe touches D mm into a G38 move),
    /// homing-switch-missing, homing-pull-off-fails.
    #[arg(long = "fault", value_name = "NAME=N")]
    faults: Vec<String>,
}

pub fn run(args: SimArgs) -> Result<ExitCode> {
    let SimArgs { config, pty: _, link, baud, realtime: _, record, motion, flavor, faults } = args;
    check_baud(baud).map_err(Error::Config)?;
    let faults = parse_faults(&faults)?;
    let mut machine = machine_config(config.as_deref(), false)?.machine;
    machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
    machine.simulator.flavor = flavor.unwrap_or(machine.simulator.flavor);
    sim_on_pty(&machine, link.as_deref(), baud.unwrap_or(machine.serial.baud), record.as_deref(), faults)
}

/// `--fault NAME=N` options into the simulator's faults.
fn parse_faults(specs: &[String]) -> Result<Faults> {
    let mut faults = Faults::default();
    for spec in specs {
        let (name, value) = match spec.split_once('=') {
            Some((n, v)) => (n.trim(), Some(v.trim())),
            None => (spec.trim(), None),
        };
        // Switch faults take no value; the probe's contact distance is in mm.
        match (name, value) {
            ("homing-switch-missing", None) => faults.homing_switch_missing = true,
            ("homing-pull-off-fails", None) => faults.homing_pull_off_fails = true,
            ("probe-contact-mm", Some(v)) => {
                let mm: f64 = v.parse().map_err(|_| Error::Config(format!("--fault {spec}: expected probe-contact-mm=D with D a distance in mm")))?;
                in_range(&format!("--fault {name}"), mm, 0.001, TRAVEL.hi, TRAVEL.unit).map_err(Error::Config)?;
                faults.probe_contact_mm = Some(mm);
            }
            (_, Some(v)) => {
                let slot = match name {
                    "error-on-line" => &mut faults.error_on_line,
                    "drop-byte" => &mut faults.drop_byte,
                    "corrupt-byte" => &mut faults.corrupt_byte,
                    "mute-from-line" => &mut faults.mute_from_line,
                    "reset-at-line" => &mut faults.reset_at_line,
                    "limit-alarm-at-line" => &mut faults.limit_alarm_at_line,
                    "close-link-at-line" => &mut faults.close_link_at_line,
                    other => return Err(Error::Config(format!("--fault {spec}: unknown fault '{other}'"))),
                };
                let n: u64 = v.parse().ok().filter(|n| *n > 0).ok_or_else(|| {
                    Error::Config(format!("--fault {spec}: expected NAME=N with N a positive whole number"))
                })?;
                *slot = Some(n);
            }
            (other, None) => return Err(Error::Config(format!("--fault {spec}: unknown fault '{other}' or missing =N"))),
        }
    }
    Ok(faults)
}

fn sim_on_pty(machine: &MachineConfig, link: Option<&Path>, baud: u32, record: Option<&Path>, faults: Faults) -> Result<ExitCode> {
    let sim = run::sim_config(machine, faults);
    // `--flavor grbl` with a scanner config: Grbl 1.1h has no U or V.
    if let Some(e) = sim.flavor_error() {
        return Err(Error::Config(format!("--flavor / [simulator] flavor: {e}")));
    }
    let setup = laserd::figures::RunSetup { real_time: true, ..run::run_setup(machine, &sim) };
    let device = laserd_sim::pty::open_pty(link).map_err(|e| Error::Io(format!("cannot open a pseudo-terminal: {e}")))?;
    let recording = record.map(Recording::create).transpose()?;
    let recorder = recording.as_ref().map(|r| r.recorder());
    if let Some(r) = &recorder {
        r.write(TOPIC_SETUP, 0.0, &setup);
    }
    println!("{}", link.map(|l| l.display().to_string()).unwrap_or_else(|| device.path().display().to_string()));
    let _ = std::io::stdout().flush();

    let stop = Arc::new(AtomicBool::new(false));
    let stop_sim = stop.clone();
    let controller = Controller::new(sim);
    let sim_recorder = recorder.clone();
    let (ended_tx, ended_rx) = tokio::sync::oneshot::channel::<()>();
    let thread = std::thread::Builder::new()
        .name("simulator".into())
        .spawn(move || {
            // Tell the main thread when the simulator stops by itself (an
            // injected link closing), so the process ends with it.
            let _ended = DropSignal(Some(ended_tx));
            let mut link = LinkLog::default();
            laserd_sim::pty::run_realtime(controller, device, baud, stop_sim, |observed| {
                if let Some(r) = &sim_recorder {
                    match observed {
                        Observed::Knots(knots) => r.knots(&knots),
                        Observed::FromHost(t, bytes) => link.host_sent(t, &bytes, |t, e| r.link_event(t, &e)),
                        Observed::ToHost(t, bytes) => link.controller_sent(t, &bytes, |t, e| r.link_event(t, &e)),
                    }
                }
            })
        })
        .map_err(|e| Error::Io(format!("cannot start the simulator thread: {e}")))?;
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(|e| Error::Io(e.to_string()))?;
    runtime.block_on(async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending::<()>().await } } => {}
            _ = ended_rx => {}
        }
    });
    stop.store(true, Ordering::SeqCst);
    let _ = thread.join();
    drop(recorder);
    if let Some(r) = recording {
        r.finish()?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Turns the bytes seen on the simulator's side of the link into the same
/// events the sender records: lines the host sent (numbered as the controller
/// counts them), realtime bytes, and lines the controller answered.
#[derive(Default)]
struct LinkLog {
    from_host: Vec<u8>,
    to_host: Vec<u8>,
    lines: usize,
}

impl LinkLog {
    fn host_sent(&mut self, t: f64, bytes: &[u8], mut emit: impl FnMut(f64, LinkEvent)) {
        for &b in bytes {
            if realtime::is_realtime(b) || b >= 0x80 {
                emit(t, LinkEvent::Realtime { byte: b });
            } else if b == b'\n' || b == b'\r' {
                self.lines += 1;
                let text = String::from_utf8_lossy(&self.from_host).to_string();
                self.from_host.clear();
                emit(t, LinkEvent::Sent { line: self.lines, text });
            } else {
                self.from_host.push(b);
            }
        }
    }

    fn controller_sent(&mut self, t: f64, bytes: &[u8], mut emit: impl FnMut(f64, LinkEvent)) {
        for &b in bytes {
            if b == b'\n' {
                let text = String::from_utf8_lossy(&self.to_host).trim().to_string();
                self.to_host.clear();
                if !text.is_empty() {
                    emit(t, LinkEvent::Received { text });
                }
            } else {
                self.to_host.push(b);
            }
        }
    }
}

/// Sends on its channel when dropped, however the owning thread ends.
struct DropSignal(Option<tokio::sync::oneshot::Sender<()>>);

impl Drop for DropSignal {
    fn drop(&mut self) {
        if let Some(tx) = self.0.take() {
            let _ = tx.send(());
        }
    }
}
