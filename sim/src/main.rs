//! `laserd-sim`: serve a simulated GRBL laser controller on a pseudo-terminal.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use laserd_sim::{open_pty, run_realtime, Controller, SimConfig};
use nix::sys::signal::{sigaction, SaFlags, SigAction, SigHandler, SigSet, Signal};

#[derive(Parser)]
#[command(about = "GRBL 1.1-compatible laser controller simulator on a pty")]
struct Args {
    /// Axis letters, comma separated.
    #[arg(long, default_value = "X,Y")]
    axes: String,
    /// Create this symlink to the pty device.
    #[arg(long)]
    link: Option<PathBuf>,
    #[arg(long, default_value_t = 115200)]
    baud: u32,
    /// Full SimConfig as JSON (overrides --axes).
    #[arg(long)]
    config: Option<PathBuf>,
}

static SIGNALLED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: nix::libc::c_int) {
    SIGNALLED.store(true, Ordering::SeqCst);
}

fn main() {
    let args = Args::parse();
    if let Err(e) = run(args) {
        eprintln!("laserd-sim: {e}");
        std::process::exit(1);
    }
}

fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let config = match &args.config {
        Some(p) => serde_json::from_str::<SimConfig>(&std::fs::read_to_string(p)?)?,
        None => SimConfig::with_axes(&args.axes.replace(',', "")),
    };
    if let Some(e) = config.flavor_error() {
        return Err(e.into());
    }
    let action = SigAction::new(SigHandler::Handler(on_signal), SaFlags::empty(), SigSet::empty());
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        sigaction(Signal::SIGINT, &action)?;
        sigaction(Signal::SIGTERM, &action)?;
    }
    let dev = open_pty(args.link.as_deref())?;
    println!("{}", dev.path().display());
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let server = std::thread::spawn(move || run_realtime(Controller::new(config), dev, args.baud, stop2, |_| {}));
    while !SIGNALLED.load(Ordering::SeqCst) && !server.is_finished() {
        std::thread::sleep(Duration::from_millis(50));
    }
    stop.store(true, Ordering::SeqCst);
    server.join().map_err(|_| "server thread panicked")?;
    Ok(())
}
