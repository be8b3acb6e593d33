//! The safe stop every stream that ends early goes through: feed hold until
//! the machine rests (the laser goes off in laser mode), then a soft reset,
//! which flushes what the controller still had queued and switches the laser
//! off. Separate because it is the one path every failure shares.

use laserd_sim::wire::{realtime, MachineState, Response, StatusReport};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::time::{Duration, Instant};

use super::link::{Link, LINK_CLOSED};
use super::LinkEvent;
use crate::error::Error;

/// How a safe stop went.
#[derive(Debug, Default)]
pub(super) struct SafeStop {
    /// The state it left the machine in.
    pub(super) status: Option<StatusReport>,
    /// Alarms the controller raised on the way (`ALARM:3` for a reset while moving).
    pub(super) alarms: Vec<u16>,
    /// What went differently from a hold to rest and a reset.
    pub(super) note: Option<String>,
}

impl<R, W, F> Link<R, W, F>
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin,
    F: FnMut(f64, LinkEvent),
{
    /// Feed hold until stopped (up to `hold_limit`), then soft reset: the
    /// laser ends off, nothing queued is executed any more. Status requests
    /// meanwhile keep to the status rate (`send_realtime`).
    pub(super) async fn safe_stop(&mut self, hold_limit: Duration) -> SafeStop {
        let mut stop = SafeStop::default();
        if self.send_realtime(realtime::FEED_HOLD).await.is_err() {
            return stop;
        }
        let deadline = Instant::now() + hold_limit;
        let mut at_rest = false;
        while !at_rest && Instant::now() < deadline {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.query_status(left.min(Duration::from_millis(500))).await {
                Ok(Some(s)) => {
                    at_rest = matches!(
                        s.state,
                        MachineState::Hold(0) | MachineState::Door(0) | MachineState::Door(1) | MachineState::Idle | MachineState::Alarm
                    );
                }
                Ok(None) => {}
                Err(Error::Stream(m)) if m == LINK_CLOSED => return stop,
                // Garbage while the machine holds: the reset comes anyway,
                // after the time a hold takes.
                Err(_) => {}
            }
        }
        if !at_rest {
            stop.note = Some(format!("no hold to rest within {:.1} s: reset, maybe while moving", hold_limit.as_secs_f64()));
        }
        if self.send_realtime(realtime::SOFT_RESET).await.is_err() {
            return stop;
        }
        let alarms = &mut stop.alarms;
        let _ = self
            .wait_for(Duration::from_secs(3), |r| {
                if let Response::Alarm(code) = r {
                    alarms.push(*code);
                }
                matches!(r, Response::Banner(_))
            })
            .await;
        stop.status = self.query_status(Duration::from_secs(1)).await.ok().flatten();
        stop
    }
}
