//! The link to the controller: bytes out (lines, realtime bytes, the
//! sender's own commands), lines in (bounded, parsed, booked), and waiting for
//! an answer or a status report. Separate so that every byte on the wire goes
//! through one place that records it and books every answer.

use laserd_sim::wire::{realtime, Response, StatusReport};
use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::time::{timeout, Duration, Instant};

use super::book::Book;
use super::{secs, LinkEvent, MAX_CONTROLLER_LINE};
use crate::error::{Error, Result};

pub(super) struct Link<R, W, F> {
    reader: BufReader<R>,
    /// The line being read, at most `MAX_CONTROLLER_LINE` bytes.
    partial: Vec<u8>,
    /// The rest of an over-long line is being skipped.
    skipping: bool,
    writer: W,
    pub(super) origin: Instant,
    on_event: F,
    pub(super) bytes_sent: usize,
    /// Every answer is booked here as it is read, whoever reads it.
    pub(super) book: Book,
    /// Status requests go out at most this often, whoever asks (Grbl's
    /// interface document: about 5 Hz at most), and when the last one went.
    status_interval: Duration,
    pub(super) last_status_request: Option<Instant>,
}

/// Why a stream ends when the other end has gone (a read at its end, a write refused).
pub(super) const LINK_CLOSED: &str = "the controller closed the link";

impl<R, W, F> Link<R, W, F>
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin,
    F: FnMut(f64, LinkEvent),
{
    /// A link over `reader` and `writer`, its clock starting now.
    pub(super) fn new(reader: R, writer: W, on_event: F, book: Book, status_interval: Duration) -> Self {
        Link {
            reader: BufReader::new(reader),
            partial: Vec::new(),
            skipping: false,
            writer,
            origin: Instant::now(),
            on_event,
            bytes_sent: 0,
            book,
            status_interval,
            last_status_request: None,
        }
    }

    /// Puts bytes on the wire now (flushed: the link must not sit on them).
    pub(super) async fn write(&mut self, bytes: &[u8]) -> Result<()> {
        // A pipe or socket whose reader has gone, or a pseudo-terminal whose
        // other side closed (EIO on Linux): the controller has left the link.
        const EIO: i32 = 5;
        let failed = |e: std::io::Error| match e.kind() {
            std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset => Error::Stream(LINK_CLOSED.into()),
            _ if e.raw_os_error() == Some(EIO) => Error::Stream(LINK_CLOSED.into()),
            _ => Error::Stream(format!("write failed: {e}")),
        };
        self.writer.write_all(bytes).await.map_err(failed)?;
        self.writer.flush().await.map_err(failed)
    }

    pub(super) async fn send_line(&mut self, line: usize, text: &str) -> Result<()> {
        let mut bytes = Vec::with_capacity(text.len() + 1);
        bytes.extend_from_slice(text.as_bytes());
        bytes.push(b'\n');
        self.write(&bytes).await?;
        self.bytes_sent += bytes.len();
        (self.on_event)(
            secs(self.origin),
            LinkEvent::Sent {
                line,
                text: text.to_string(),
            },
        );
        Ok(())
    }

    /// A command of the sender's own (not a program line), answered before
    /// anything else is sent: waits for its `ok` or `error:N`.
    pub(super) async fn command(&mut self, text: &str) -> Result<Response> {
        self.command_within(text, Duration::from_secs(3)).await
    }

    /// `command` for commands that answer only when done (homing).
    pub(super) async fn command_within(&mut self, text: &str, limit: Duration) -> Result<Response> {
        self.command_seeing(text, limit, |_| {}).await
    }

    /// `command_within`, showing `seen` every line read before the answer
    /// (the feedback a `$` command prints).
    pub(super) async fn command_seeing(&mut self, text: &str, limit: Duration, mut seen: impl FnMut(&Response)) -> Result<Response> {
        let before = self.bytes_sent;
        self.send_line(0, text).await?;
        self.book.sent(0, text);
        self.bytes_sent = before;
        self.wait_for(limit, |r| {
            seen(r);
            matches!(r, Response::Ok | Response::Error(_))
        })
        .await?
        .ok_or_else(|| Error::Stream(format!("no answer to `{text}` within {} s", limit.as_secs_f64())))
    }

    /// A status request once the status interval since the last one has
    /// passed (it waits for that): no caller asks faster than the status rate.
    async fn request_status(&mut self) -> Result<()> {
        if let Some(last) = self.last_status_request {
            tokio::time::sleep_until(last + self.status_interval).await;
        }
        self.send_realtime(realtime::STATUS).await
    }

    /// A status request if one is due (the streaming loop's ticks, which
    /// must not wait: the answers they would not read meanwhile are its work).
    pub(super) async fn request_status_if_due(&mut self) -> Result<()> {
        match self.last_status_request {
            Some(last) if last + self.status_interval > Instant::now() => Ok(()),
            _ => self.send_realtime(realtime::STATUS).await,
        }
    }

    pub(super) async fn send_realtime(&mut self, byte: u8) -> Result<()> {
        if byte == realtime::STATUS {
            self.last_status_request = Some(Instant::now());
        }
        self.write(&[byte]).await?;
        if byte == realtime::STATUS {
            self.book.status_requested();
        }
        (self.on_event)(secs(self.origin), LinkEvent::Realtime { byte });
        Ok(())
    }

    /// Next line from the controller without its `\n`, `None` at the end of
    /// the link. A line longer than `MAX_CONTROLLER_LINE` is an error (and its
    /// rest is skipped): memory never grows with what the controller sends.
    /// Cancel-safe: bytes move from the buffer only after the await.
    async fn read_line(&mut self) -> Result<Option<Vec<u8>>> {
        const EIO: i32 = 5;
        loop {
            let available = match self.reader.fill_buf().await {
                Ok(bytes) => bytes,
                // A pseudo-terminal whose other side closed reads EIO.
                Err(e) if e.raw_os_error() == Some(EIO) => return Ok(None),
                Err(e) => return Err(Error::Stream(format!("read failed: {e}"))),
            };
            if available.is_empty() {
                return Ok(None);
            }
            let end = available.iter().position(|&b| b == b'\n');
            let chunk = &available[..end.unwrap_or(available.len())];
            let used = end.map_or(chunk.len(), |i| i + 1);
            let too_long = !self.skipping && self.partial.len() + chunk.len() > MAX_CONTROLLER_LINE;
            if !self.skipping && !too_long {
                self.partial.extend_from_slice(chunk);
            }
            self.reader.consume(used);
            if too_long {
                self.book.distrust();
                self.partial.clear();
                self.skipping = end.is_none();
                return Err(Error::Stream(format!(
                    "the controller sent more than {MAX_CONTROLLER_LINE} bytes without a line end: garbage, not a GRBL answer"
                )));
            }
            if end.is_some() {
                if std::mem::take(&mut self.skipping) {
                    continue;
                }
                return Ok(Some(std::mem::take(&mut self.partial)));
            }
        }
    }

    /// Next line from the controller, parsed and booked, with the line it
    /// answered (for `ok` and `error:N`); `None` when the link closed. Cancel-safe.
    pub(super) async fn next_line(&mut self) -> Result<Option<(String, Response, Option<(usize, String)>)>> {
        loop {
            let Some(line) = self.read_line().await? else { return Ok(None) };
            let text = String::from_utf8_lossy(&line)
                .trim_matches(|c| c == '\r' || c == '\n')
                .to_string();
            if text.is_empty() {
                continue;
            }
            (self.on_event)(
                secs(self.origin),
                LinkEvent::Received { text: text.clone() },
            );
            let response = Response::parse(&text);
            let answered = self.book.answer(&response);
            self.book.publish();
            return Ok(Some((text, response, answered)));
        }
    }

    /// Reads responses until `want` accepts one, or `limit` passes.
    pub(super) async fn wait_for(
        &mut self,
        limit: Duration,
        mut want: impl FnMut(&Response) -> bool,
    ) -> Result<Option<Response>> {
        let deadline = Instant::now() + limit;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match timeout(left, self.next_line()).await {
                Err(_) => return Ok(None),
                Ok(Err(e)) => return Err(e),
                Ok(Ok(None)) => return Err(Error::Stream(LINK_CLOSED.into())),
                Ok(Ok(Some((_, r, _)))) => {
                    if want(&r) {
                        return Ok(Some(r));
                    }
                }
            }
        }
    }

    /// Asks for status until one arrives (up to `limit`).
    pub(super) async fn query_status(&mut self, limit: Duration) -> Result<Option<StatusReport>> {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            self.request_status().await?;
            if let Some(Response::Status(s)) = self
                .wait_for(Duration::from_millis(250), |r| {
                    matches!(r, Response::Status(_))
                })
                .await?
            {
                return Ok(Some(s));
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::AsyncWriteExt;

    #[tokio::test(start_paused = true)]
    async fn the_line_reader_keeps_at_most_the_cap() {
        let (a, mut b) = tokio::io::duplex(1 << 16);
        let (read_half, _write_half) = tokio::io::split(a);
        let mut link = Link { reader: BufReader::new(read_half), partial: Vec::new(), skipping: false, writer: tokio::io::sink(), origin: Instant::now(), on_event: |_, _| {}, bytes_sent: 0, book: Book::default(), status_interval: Duration::from_millis(200), last_status_request: None };
        let mut flood = vec![b'x'; 3 * MAX_CONTROLLER_LINE];
        flood.extend_from_slice(b"\r\nok\r\n");
        b.write_all(&flood).await.unwrap();
        let err = link.next_line().await.expect_err("too long").to_string();
        assert!(err.contains("without a line end"), "{err}");
        assert!(link.partial.capacity() <= 2 * MAX_CONTROLLER_LINE, "{}", link.partial.capacity());
        // The rest of the long line is skipped; the next line reads.
        assert_eq!(link.next_line().await.unwrap().map(|(t, _, _)| t), Some("ok".to_string()));
    }
}
