//! The real-time driver on a pseudo-terminal, used the way a sender would.

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use laserd_sim::controller::{Controller, Knot, SimConfig};
use laserd_sim::pty::{open_pty, run_realtime, Observed};
use laserd_sim::wire::{Response, BANNER};

#[test]
fn serve_on_pty() {
    let link = std::env::temp_dir().join(format!("laserd-sim-test-{}", std::process::id()));
    let dev = open_pty(Some(&link)).expect("open pty");
    assert_eq!(std::fs::read_link(&link).unwrap(), dev.path());
    let stop = Arc::new(AtomicBool::new(false));
    let knots: Arc<Mutex<Vec<Knot>>> = Arc::default();
    let (stop2, knots2) = (stop.clone(), knots.clone());
    let server = std::thread::spawn(move || {
        run_realtime(Controller::new(SimConfig::with_axes("XY")), dev, 115200, stop2, move |o| {
            if let Observed::Knots(k) = o {
                knots2.lock().unwrap().extend(k)
            }
        })
    });

    let mut port = std::fs::OpenOptions::new().read(true).write(true).open(&link).expect("open slave");
    let mut reader = port.try_clone().unwrap();
    let (tx, rx) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        let mut line = Vec::new();
        let mut b = [0u8; 1];
        while let Ok(1) = reader.read(&mut b) {
            if b[0] == b'\n' {
                let s = String::from_utf8_lossy(&line).trim().to_string();
                line.clear();
                if !s.is_empty() && tx.send(s).is_err() {
                    break;
                }
            } else {
                line.push(b[0]);
            }
        }
    });
    let next = || rx.recv_timeout(Duration::from_secs(5)).expect("reply within 5 s");

    assert_eq!(next(), BANNER);
    port.write_all(b"?").unwrap();
    let status = next();
    assert!(status.starts_with("<Idle|MPos:0.000,0.000,0.000"), "{status}");
    port.write_all(b"G1 X1 F600\n").unwrap();
    assert_eq!(Response::parse(&next()), Response::Ok);
    // 1 mm at 600 mm/min = 0.1 s.
    std::thread::sleep(Duration::from_millis(400));
    port.write_all(b"?").unwrap();
    let status = next();
    assert!(status.starts_with("<Idle|MPos:1.000,0.000,0.000|"), "{status}");
    let k = knots.lock().unwrap().clone();
    assert_eq!(k.len(), 2, "{k:?}");
    assert!((k[1].t - k[0].t - 0.1).abs() < 1e-9);
    assert_eq!(k[1].pos, vec![1.0, 0.0, 0.0]);

    stop.store(true, Ordering::SeqCst);
    server.join().unwrap();
    assert!(std::fs::symlink_metadata(&link).is_err(), "symlink removed when the device is dropped");
}

/// Whether the pty slave is marked exclusive (`TIOCGEXCL`).
fn exclusive(port: &std::fs::File) -> bool {
    use std::os::fd::AsRawFd;
    let mut flag: nix::libc::c_int = 0;
    // SAFETY: TIOCGEXCL writes one int; the fd is open.
    assert_eq!(unsafe { nix::libc::ioctl(port.as_raw_fd(), nix::libc::TIOCGEXCL, &mut flag) }, 0);
    flag != 0
}

fn take_for_itself(port: &std::fs::File) {
    use std::os::fd::AsRawFd;
    // SAFETY: TIOCEXCL takes no argument; the fd is open.
    assert_eq!(unsafe { nix::libc::ioctl(port.as_raw_fd(), nix::libc::TIOCEXCL) }, 0);
}

#[test]
fn a_client_that_took_the_port_for_itself_leaves_it_free_when_it_goes() {
    let dev = open_pty(None).expect("open pty");
    let path = dev.path().to_path_buf();
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let server = std::thread::spawn(move || run_realtime(Controller::new(SimConfig::with_axes("XY")), dev, 115200, stop2, |_| {}));
    let open = || std::fs::OpenOptions::new().read(true).write(true).open(&path).expect("open slave");
    // Settles once the simulator has read the open and close events.
    let settled = || std::thread::sleep(Duration::from_millis(100));

    // The first client takes the port (as serial libraries do); the mark
    // stays while it has the port open.
    let first = open();
    take_for_itself(&first);
    settled();
    assert!(exclusive(&first), "still exclusive while its client has it open");
    // Gone (a kill closes its files the same way): the next client may open
    // the port without privileges, as after a real serial device's close.
    drop(first);
    settled();
    let next = open();
    assert!(!exclusive(&next), "the exclusive mark went with its client");

    stop.store(true, Ordering::SeqCst);
    server.join().unwrap();
}
