//! An open connection: connecting (banner, status, build options) and the
//! commands of the sender's own between jobs (settings, work frame, homing,
//! unlock, jogging). Streaming a program is in `streaming.rs`.

use laserd_sim::wire::{self, realtime, MachineState, Response, StatusReport};
use tokio::io::{AsyncRead, AsyncWrite, ReadHalf, WriteHalf};
use tokio::time::Duration;

use super::book::{Book, ExecutedLine};
use super::link::{Link, LINK_CLOSED};
use super::{Control, LinkEvent, SenderOptions, BUILD_INFO, IN_ALARM};
use crate::error::{Error, Result};

/// An open connection to a GRBL-style controller: announced (banner), its
/// state and buffer sizes known, every answer booked.
pub struct Connection<T, F> {
    pub(super) link: Link<ReadHalf<T>, WriteHalf<T>, F>,
    pub(super) options: SenderOptions,
    /// The receive buffer counted on: the configured one, or the controller's
    /// if that is smaller.
    pub(super) rx_buffer: usize,
    /// The status just read, if nothing was sent since (saves a round trip).
    pub(super) fresh_status: Option<StatusReport>,
    /// The build option codes of `[OPT:]` (e.g. `VNM+`).
    build_codes: String,
    /// The controller's `[VER:]` line: firmware version and build.
    version: Option<String>,
    /// The work coordinate offset (`WCO:`, sent now and then; or set by
    /// `use_program_frame`): work position = machine position − this.
    wco: Option<Vec<f64>>,
}

impl<T, F> Connection<T, F>
where
    T: AsyncRead + AsyncWrite,
    F: FnMut(f64, LinkEvent),
{
    /// Connects: waits for the banner (asking with a soft reset if it came
    /// before we listened; nothing moves yet) and reads the first status.
    pub async fn open(io: T, options: &SenderOptions, on_event: F) -> Result<Self> {
        let (read_half, write_half) = tokio::io::split(io);
        let mut link = Link::new(read_half, write_half, on_event, Book::new(options.step_mm), options.status_interval);
        let is_banner = |r: &Response| matches!(r, Response::Banner(_));
        if link
            .wait_for(Duration::from_millis(500), is_banner)
            .await?
            .is_none()
        {
            link.send_realtime(realtime::SOFT_RESET).await?;
            if link
                .wait_for(Duration::from_millis(2500), is_banner)
                .await?
                .is_none()
            {
                return Err(Error::Stream(
                    "no GRBL banner from the controller within 3 s of connecting".into(),
                ));
            }
        }
        let mut connection = Connection {
            link,
            options: options.clone(),
            rx_buffer: options.rx_buffer,
            fresh_status: None,
            build_codes: String::new(),
            version: None,
            wco: None,
        };
        connection.status().await?;
        connection.learn_build_options().await?;
        Ok(connection)
    }

    /// Asks `$I` for the build options, `[OPT:<codes>,<blocks>,<rx bytes>…]`:
    /// the planner's size and the receive buffer, as the controller was built
    /// (the reference: read them, never assume them). A controller that will
    /// not answer it now (busy: error 8) keeps what the status told.
    async fn learn_build_options(&mut self) -> Result<()> {
        let (mut options, mut version) = (None, None);
        self.link
            .command_seeing(BUILD_INFO, Duration::from_secs(3), |r| {
                if let Response::Feedback(f) = r {
                    if let Some(o) = f.strip_prefix("[OPT:").and_then(|o| o.strip_suffix(']')) {
                        options = Some(o.to_string());
                    }
                    if let Some(v) = f.strip_prefix("[VER:").and_then(|v| v.strip_suffix(']')) {
                        // Shown to the operator: printable text, a line's worth.
                        version = Some(v.trim_end_matches(':').chars().filter(|c| !c.is_control()).take(80).collect::<String>());
                    }
                }
            })
            .await?;
        self.version = version.or(self.version.take());
        let fields: Vec<&str> = options.as_deref().unwrap_or("").split(',').collect();
        self.build_codes = fields.first().map_or(String::new(), |c| c.trim().to_string());
        let number = |i: usize| fields.get(i).and_then(|f| f.trim().parse::<usize>().ok()).filter(|n| *n > 0);
        if let Some(blocks) = number(1) {
            self.link.book.planner_blocks = Some(blocks);
        }
        if let Some(rx) = number(2).filter(|rx| *rx < self.rx_buffer) {
            tracing::warn!("the controller's receive buffer is {rx} bytes, less than the configured {}: using {rx}", self.rx_buffer);
            self.rx_buffer = rx;
        }
        // `$I` changes nothing: a status read just before it is still fresh.
        Ok(())
    }

    /// The controller's status now. An idle controller reports its whole
    /// planner and receive buffer free: learn their sizes, and never count on
    /// more receive buffer than it has.
    pub async fn status(&mut self) -> Result<StatusReport> {
        let status = self
            .link
            .query_status(Duration::from_secs(2))
            .await?
            .ok_or_else(|| {
                Error::Stream("the controller does not answer status requests".into())
            })?;
        if let (MachineState::Idle, Some((blocks, rx))) = (&status.state, status.buffer) {
            self.link.book.planner_blocks = Some(blocks as usize);
            // None free at all is not a size but a fault (see `stream_from`).
            if rx > 0 && (rx as usize) < self.rx_buffer {
                // A ring buffer keeps one slot unused (grblHAL's 1024-byte one
                // holds 1023): not worth a warning, only worth counting on.
                if rx as usize + 1 == self.rx_buffer {
                    tracing::debug!("the controller's receive buffer holds {rx} bytes: using {rx}");
                } else {
                    tracing::warn!("the controller's receive buffer is {rx} bytes, less than the configured {}: using {rx}", self.rx_buffer);
                }
                self.rx_buffer = rx as usize;
            }
        }
        if let Some(wco) = &status.wco {
            self.wco = Some(wco.clone());
        }
        self.fresh_status = Some(status.clone());
        Ok(status)
    }

    /// The controller's firmware version and build, as its `$I` says.
    pub fn version(&self) -> Option<&str> {
        self.version.as_deref()
    }

    /// The work coordinate offset last known (machine − work position).
    pub fn work_offset(&self) -> Option<&[f64]> {
        self.wco.as_deref()
    }

    /// The work position (program coordinates) of a status report: `WPos:`
    /// as reported, or `MPos:` less the last work coordinate offset known.
    pub fn work_position(&self, status: &StatusReport) -> Vec<f64> {
        match (&status.wpos, status.wco.as_ref().or(self.wco.as_ref())) {
            (Some(w), _) if status.mpos.is_empty() => w.clone(),
            (_, Some(wco)) => status.mpos.iter().zip(wco.iter().chain(std::iter::repeat(&0.0))).map(|(m, o)| m - o).collect(),
            _ => status.mpos.clone(),
        }
    }

    /// Makes the controller's work coordinates laserd's bed coordinates (see
    /// `frame`): reads `$$` and `$#`, writes G54 (`G10 L2 P1`) if it is not
    /// already the bed's origin, then selects G54 and clears G92. `travel`
    /// is the config's stage travel (X, Y). Returns the origin (machine X, Y
    /// of the bed's 0).
    pub async fn use_program_frame(&mut self, travel: [f64; 2]) -> Result<[f64; 2]> {
        // G10 and G54 are G-code: refused in alarm (error:9).
        if self.status().await?.state == MachineState::Alarm {
            return Err(Error::Stream(IN_ALARM.into()));
        }
        let settings = self.settings().await?;
        let origin = crate::stream::frame::program_origin(&settings, &self.build_codes, travel)?;
        let mut g54 = self.work_origin().await?;
        if g54.len() < 2 {
            return Err(Error::Stream(format!("`$#` gave no G54 origin for X and Y (got {g54:?})")));
        }
        if g54.iter().zip(origin).any(|(a, b)| (a - b).abs() > 5e-4) {
            let [x, y] = origin.map(|v| crate::program::format_number(v, 3));
            self.expect_ok(&format!("G10L2P1X{x}Y{y}")).await?;
            g54[..2].copy_from_slice(&origin);
        }
        self.expect_ok("G54G92.1").await?;
        self.wco = Some(g54);
        Ok(origin)
    }

    /// The G54 origin in machine coordinates, from `$#`.
    async fn work_origin(&mut self) -> Result<Vec<f64>> {
        self.fresh_status = None;
        let mut g54 = None;
        let answer = self
            .link
            .command_seeing("$#", Duration::from_secs(3), |r| {
                if let Response::Feedback(f) = r {
                    if let Some(values) = f.strip_prefix("[G54:").and_then(|v| v.strip_suffix(']')) {
                        g54 = values.split(',').map(|v| v.trim().parse::<f64>().ok()).collect::<Option<Vec<f64>>>();
                    }
                }
            })
            .await?;
        if let Response::Error(code) = answer {
            return Err(Error::Stream(format!("`$#` refused: error:{code} ({})", wire::error_message(code))));
        }
        g54.ok_or_else(|| Error::Stream("`$#` gave no readable `[G54:...]` line".into()))
    }

    /// Sends a command of the sender's own and waits (up to `limit`) for its answer.
    async fn expect_ok_within(&mut self, command: &str, limit: Duration) -> Result<()> {
        self.fresh_status = None;
        match self.link.command_within(command, limit).await? {
            Response::Error(code) => Err(Error::Stream(format!(
                "`{command}` refused: error:{code} ({})",
                wire::error_message(code)
            ))),
            _ => Ok(()),
        }
    }

    pub(super) async fn expect_ok(&mut self, command: &str) -> Result<()> {
        self.expect_ok_within(command, Duration::from_secs(3)).await
    }

    /// The controller's settings (`$$`): number and value of each `$N=value` line.
    pub async fn settings(&mut self) -> Result<Vec<(u32, f64)>> {
        self.fresh_status = None;
        let mut settings = Vec::new();
        let answer = self
            .link
            .command_seeing("$$", Duration::from_secs(3), |r| {
                if let Response::Other(text) = r {
                    let parsed = text.strip_prefix('$').and_then(|t| t.split_once('=')).and_then(|(n, v)| {
                        // grblHAL may add a comment after the value.
                        let v = v.split([' ', '(']).next().unwrap_or(v);
                        Some((n.trim().parse::<u32>().ok()?, v.trim().parse::<f64>().ok()?))
                    });
                    settings.extend(parsed);
                }
            })
            .await?;
        if let Response::Error(code) = answer {
            return Err(Error::Stream(format!("`$$` refused: error:{code} ({})", wire::error_message(code))));
        }
        // Steps per mm (`$100`…`$109`): the longest step tells which moves
        // surely make a planner block (see `Book::sure_blocks`).
        let steps: Vec<f64> = settings.iter().filter(|(n, _)| (100..110).contains(n)).map(|(_, v)| *v).collect();
        self.link.book.step_mm = (!steps.is_empty() && steps.iter().all(|v| v.is_finite() && *v > 0.0))
            .then(|| steps.iter().map(|v| 1.0 / v).fold(0.0, f64::max));
        Ok(settings)
    }

    /// Clears an alarm (`$X`).
    pub async fn unlock(&mut self) -> Result<()> {
        self.expect_ok("$X").await
    }

    /// Runs the homing cycle (`$H`); the answer comes when it is done, which
    /// may take as long as crossing the whole travel at the seek rate. The
    /// controller answers no status requests meanwhile, so none are sent. An
    /// `Abort` from `control` (or its sender gone) stops the cycle with a
    /// soft reset (the controller then raises `ALARM:6`); holds are ignored,
    /// as Grbl does while homing.
    pub async fn home(&mut self, mut control: Option<&mut tokio::sync::mpsc::UnboundedReceiver<Control>>) -> Result<()> {
        const LIMIT: Duration = Duration::from_secs(300);
        self.fresh_status = None;
        let before = self.link.bytes_sent;
        self.link.send_line(0, "$H").await?;
        self.link.book.sent(0, "$H");
        self.link.bytes_sent = before;
        let deadline = tokio::time::sleep(LIMIT);
        tokio::pin!(deadline);
        loop {
            let next_control = async {
                match control.as_deref_mut() {
                    Some(rx) => rx.recv().await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                line = self.link.next_line() => match line? {
                    None => return Err(Error::Stream(LINK_CLOSED.into())),
                    Some((_, Response::Ok, _)) => return Ok(()),
                    Some((_, Response::Error(code), _)) => {
                        return Err(Error::Stream(format!("`$H` refused: error:{code} ({})", wire::error_message(code))));
                    }
                    // A failed cycle: Grbl answers the `$H` `ok` after the
                    // alarm, then resets itself (banner) into Alarm.
                    Some((_, Response::Alarm(code), _)) => {
                        let _ = self.link.wait_for(Duration::from_secs(3), |r| matches!(r, Response::Banner(_))).await;
                        return Err(Error::Stream(format!("homing failed: ALARM:{code} ({}); unlock ($X) or home again", wire::alarm_message(code))));
                    }
                    Some(_) => {}
                },
                command = next_control => match command {
                    Some(Control::Abort) | None => {
                        self.link.send_realtime(realtime::SOFT_RESET).await?;
                        let _ = self.link.wait_for(Duration::from_secs(3), |r| matches!(r, Response::Banner(_))).await;
                        return Err(Error::Stream("homing aborted: the controller was reset and is in alarm; home again or unlock ($X)".into()));
                    }
                    Some(_) => {}
                },
                _ = &mut deadline => {
                    return Err(Error::Stream(format!("no answer to `$H` within {} s", LIMIT.as_secs())));
                }
            }
        }
    }

    /// The axis positions the next program starts from (the sender refuses
    /// to stream it from anywhere else); `None` for programs that start anywhere.
    pub fn expect_start(&mut self, start: Option<Vec<f64>>) {
        self.options.expect_start = start;
    }

    /// Jogs (`$J=` + a block such as `G91 X10 F600`; see `jog_block`).
    pub async fn jog(&mut self, block: &str) -> Result<()> {
        self.expect_ok(&format!("$J={block}")).await
    }

    /// A lower bound on the last program line the controller has executed
    /// (see `Book`), kept up to date while a stream runs: for a watcher that
    /// saves progress. A stream from line `n` starts it at `n - 1`.
    pub fn executed_line(&self) -> ExecutedLine {
        self.link.book.executed_line.clone()
    }

    /// Stops a jog at once and drops the queued jog moves.
    pub async fn jog_cancel(&mut self) -> Result<()> {
        self.fresh_status = None;
        self.link.send_realtime(realtime::JOG_CANCEL).await
    }
}

/// A jog as the operator gives it made a full `$J=` block: without G90 or
/// G91 it is relative (G91: an operator's "X10" means 10 mm from here, not
/// to X10 in whatever mode the last program left), without F it runs at
/// `default_feed` (mm/min), since Grbl refuses a jog without a feed. A
/// block naming both is sent as it is.
pub fn jog_block(block: &str, default_feed: f64) -> String {
    let mut clean = laserd_sim::gcode::LineBuilder::default();
    block.bytes().for_each(|b| clean.push(b));
    let words = clean.finish().and_then(|l| laserd_sim::gcode::split_words(&l).ok()).unwrap_or_default();
    let distance = words.iter().any(|w| w.letter == 'G' && (w.value == 90.0 || w.value == 91.0));
    let feed = words.iter().any(|w| w.letter == 'F');
    let mut full = String::new();
    if !distance {
        full.push_str("G91 ");
    }
    full.push_str(block.trim());
    if !feed {
        full.push_str(&format!(" F{}", crate::program::format_number(default_feed, 1)));
    }
    full
}
