//! The simulator as an in-process peer of the sender: the controller state
//! machine on the far end of an in-memory pipe, with the serial link's character
//! time emulated in both directions.
//!
//! Run it on a tokio runtime with a paused clock and the whole stream runs in
//! virtual time: tokio jumps the clock to the next timer whenever every task
//! waits, so a ten-minute job simulates in seconds and the timing is the same
//! as on a real link at that baud rate.

use laserd_sim::controller::{Controller, Knot};
use laserd_sim::link::PacedLink;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::sync::watch;
use tokio::time::Instant;

/// Drives `controller` behind `io` until `stop` turns true or the sender hangs up,
/// handing executed motion to `on_knots` as it happens. Returns the controller.
pub async fn run(
    mut controller: Controller,
    mut io: DuplexStream,
    baud: u32,
    origin: Instant,
    mut stop: watch::Receiver<bool>,
    mut on_knots: impl FnMut(Vec<Knot>),
) -> Controller {
    let now = || origin.elapsed().as_secs_f64();
    let mut inbound = PacedLink::new(baud);
    let mut outbound = PacedLink::new(baud);
    let mut buf = [0u8; 4096];
    let mut sender_open = true;
    loop {
        let t = now();
        // Bytes that reached the controller by now, each at its own arrival time.
        let cut = |c: &Controller| c.config().faults.close_link_at_line.is_some_and(|n| c.stats().lines_received >= n);
        for (at, byte) in inbound.pop_due(t) {
            // A device gone after its n-th line receives nothing after it,
            // however many bytes a fast link had on the way.
            if cut(&controller) {
                break;
            }
            controller.advance(at);
            controller.receive(at, byte);
        }
        controller.advance(t);
        let knots = controller.take_knots();
        if !knots.is_empty() {
            on_knots(knots);
        }
        let out = controller.take_output();
        if !out.is_empty() {
            outbound.push(t, &out);
        }
        let due: Vec<u8> = outbound.pop_due(t).into_iter().map(|(_, b)| b).collect();
        if !due.is_empty() && sender_open && io.write_all(&due).await.is_err() {
            sender_open = false;
        }
        let link_cut = cut(&controller);
        if *stop.borrow() || !sender_open || link_cut {
            break;
        }
        let wake = [inbound.next_arrival(), outbound.next_arrival(), controller.next_event()]
            .into_iter()
            .flatten()
            .fold(f64::INFINITY, f64::min);
        // A wake-up never earlier than a microsecond from now, so a controller that
        // keeps asking for "now" still lets time move instead of spinning.
        let sleep = async {
            if wake.is_finite() {
                tokio::time::sleep_until(origin + std::time::Duration::from_secs_f64(wake.max(t + 1e-6))).await;
            } else {
                std::future::pending::<()>().await;
            }
        };
        tokio::select! {
            n = io.read(&mut buf) => match n {
                Ok(0) | Err(_) => sender_open = false,
                Ok(n) => inbound.push(now(), &buf[..n]),
            },
            _ = sleep => {}
            _ = stop.changed() => {}
        }
    }
    // Let the machine finish what it was doing (a safe stop has already emptied
    // its queue); bounded so a stuck state machine cannot hang the run.
    let end = now() + 3600.0;
    for _ in 0..1_000_000 {
        match controller.next_event() {
            Some(t) if t <= end => controller.advance(t),
            _ => break,
        }
    }
    let knots = controller.take_knots();
    if !knots.is_empty() {
        on_knots(knots);
    }
    controller
}
