//! Real-time driver: the controller served on a pseudo-terminal.

use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::inotify::{AddWatchFlags, InitFlags, Inotify};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

use crate::controller::{Controller, Knot};
use crate::link::PacedLink;
use crate::SimError;

/// An open pty pair. The slave end is kept open while we run so the master
/// never reads EIO between clients.
pub struct PtyDevice {
    master: OwnedFd,
    idle_slave: OwnedFd,
    path: PathBuf,
    link: Option<PathBuf>,
    clients: ClientWatch,
}

/// Watches the slave's closes (inotify).
///
/// A client that takes the port for itself (`TIOCEXCL`, as serial libraries
/// do by default) leaves that mark on the slave after it closes, because
/// the master keeps the pty alive: a new client without `CAP_SYS_ADMIN` (a
/// service running as its own user) would get EBUSY until the simulator
/// restarts. A real serial device forgets the mark on its last close; the
/// simulator forgets it on a client's close (a killed client's too).
/// Counting opens against closes is not possible: inotify merges two opens
/// in a row into one event. While the mark is set only a privileged
/// process can open the port beside its client, and its close clears the
/// mark early; a simulator can live with that.
struct ClientWatch {
    inotify: Inotify,
}

impl ClientWatch {
    fn new(path: &Path) -> Result<ClientWatch, SimError> {
        let inotify = Inotify::init(InitFlags::IN_NONBLOCK | InitFlags::IN_CLOEXEC)?;
        inotify.add_watch(path, AddWatchFlags::IN_OPEN | AddWatchFlags::IN_CLOSE)?;
        Ok(ClientWatch { inotify })
    }

    /// Reads the events since the last call; when the newest is a close,
    /// clears the exclusive mark through our own slave.
    fn update(&mut self, idle_slave: &OwnedFd) {
        let Ok(events) = self.inotify.read_events() else { return };
        if events.last().is_some_and(|e| e.mask.intersects(AddWatchFlags::IN_CLOSE)) {
            // SAFETY: TIOCNXCL takes no argument; the fd is open.
            unsafe { nix::libc::ioctl(idle_slave.as_raw_fd(), nix::libc::TIOCNXCL) };
        }
    }
}

impl PtyDevice {
    /// The slave device path (e.g. `/dev/pts/3`) clients open.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The symlink created for the device, if any.
    pub fn link(&self) -> Option<&Path> {
        self.link.as_deref()
    }
}

impl Drop for PtyDevice {
    fn drop(&mut self) {
        // Remove our symlink only if it still points at our device.
        if let Some(l) = &self.link {
            if std::fs::read_link(l).ok().as_deref() == Some(self.path.as_path()) {
                let _ = std::fs::remove_file(l);
            }
        }
    }
}

/// Opens a pty whose slave is raw (set before the path is published) and
/// optionally points `link` at it, replacing an existing symlink.
pub fn open_pty(link: Option<&Path>) -> Result<PtyDevice, SimError> {
    let pty = nix::pty::openpty(None, None)?;
    let mut tio = tcgetattr(&pty.slave)?;
    cfmakeraw(&mut tio);
    tcsetattr(&pty.slave, SetArg::TCSANOW, &tio)?;
    let flags = OFlag::from_bits_truncate(fcntl(&pty.master, FcntlArg::F_GETFL)?);
    fcntl(&pty.master, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK))?;
    let path = nix::unistd::ttyname(&pty.slave)?;
    let link = match link {
        Some(l) => {
            if let Ok(meta) = std::fs::symlink_metadata(l) {
                if !meta.file_type().is_symlink() {
                    return Err(SimError::LinkOccupied(l.to_path_buf()));
                }
                std::fs::remove_file(l)?;
            }
            std::os::unix::fs::symlink(&path, l)?;
            Some(l.to_path_buf())
        }
        None => None,
    };
    let clients = ClientWatch::new(&path)?;
    Ok(PtyDevice { master: pty.master, idle_slave: pty.slave, path, link, clients })
}

/// What the real-time driver reports as it runs (times in controller seconds).
#[derive(Debug, Clone, PartialEq)]
pub enum Observed {
    /// Motion executed since the last report.
    Knots(Vec<Knot>),
    /// Bytes the host wrote, as read from the pseudo-terminal.
    FromHost(f64, Vec<u8>),
    /// Bytes the controller transmitted to the host.
    ToHost(f64, Vec<u8>),
}

/// Serves `controller` on `dev` in wall-clock time until `stop` is set.
/// Bytes in both directions are paced at `baud`; realtime bytes too, since
/// they share the wire. Executed motion and link traffic go to `observe`.
pub fn run_realtime(
    mut controller: Controller,
    mut dev: PtyDevice,
    baud: u32,
    stop: Arc<AtomicBool>,
    mut observe: impl FnMut(Observed),
) {
    let start = Instant::now();
    let clock = |base: f64| base + start.elapsed().as_secs_f64();
    // Controller time continues from wherever it already is.
    let base = controller.now();
    let mut to_ctl = PacedLink::new(baud);
    let mut to_host = PacedLink::new(baud);
    let mut buf = [0u8; 4096];
    while !stop.load(Ordering::Relaxed) {
        if controller.config().faults.close_link_at_line.is_some_and(|n| controller.stats().lines_received >= n) {
            // Fault injection: the device goes away (dropping it closes the pty).
            return;
        }
        let now = clock(base);
        for (t, b) in to_ctl.pop_due(now) {
            controller.receive(t, b);
        }
        controller.advance(now);
        let out = controller.take_output();
        if !out.is_empty() {
            to_host.push(now, &out);
        }
        let knots = controller.take_knots();
        if !knots.is_empty() {
            observe(Observed::Knots(knots));
        }
        let due: Vec<u8> = to_host.pop_due(now).into_iter().map(|(_, b)| b).collect();
        if !due.is_empty() {
            // Nobody listening and the pty queue full: the bytes are lost, as
            // on a serial line without a reader.
            let _ = write_all(&dev.master, &due);
            observe(Observed::ToHost(now, due));
        }

        // Sleep until input, the next due event, or at most 1 ms while busy.
        let busy = !to_ctl.is_empty() || !to_host.is_empty() || controller.next_event().is_some();
        let wake = [to_ctl.next_arrival(), to_host.next_arrival(), controller.next_event()]
            .into_iter()
            .flatten()
            .fold(f64::INFINITY, f64::min);
        let ms = if busy { ((wake - clock(base)) * 1000.0).clamp(0.0, 1.0).ceil() as u16 } else { 10 };
        let mut fds = [PollFd::new(dev.master.as_fd(), PollFlags::POLLIN), PollFd::new(dev.clients.inotify.as_fd(), PollFlags::POLLIN)];
        let (readable, clients_changed) = match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(n) if n > 0 => (
                fds[0].revents().is_some_and(|r| r.intersects(PollFlags::POLLIN | PollFlags::POLLHUP)),
                fds[1].revents().is_some_and(|r| r.contains(PollFlags::POLLIN)),
            ),
            _ => (false, false),
        };
        if clients_changed {
            dev.clients.update(&dev.idle_slave);
        }
        if !readable {
            continue;
        }
        match nix::unistd::read(&dev.master, &mut buf) {
            Ok(0) | Err(Errno::EIO) => {
                // Client went away: keep serving, wait for the next one.
                std::thread::sleep(Duration::from_millis(5));
            }
            Ok(n) => {
                let t = clock(base);
                to_ctl.push(t, &buf[..n]);
                observe(Observed::FromHost(t, buf[..n].to_vec()));
            }
            Err(Errno::EAGAIN) | Err(Errno::EINTR) => {}
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
    }
}

fn write_all(fd: &OwnedFd, mut bytes: &[u8]) -> nix::Result<()> {
    while !bytes.is_empty() {
        match nix::unistd::write(fd, bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(Errno::EINTR) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}
