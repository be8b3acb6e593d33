//! The sender against scripted controllers: character counting, errors,
//! silence, garbage, stalls, dwells and lost bytes, end to end through a pipe.

use std::collections::VecDeque;

use laserd_sim::wire::realtime;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

use super::link::LINK_CLOSED;
use super::*;
use crate::error::Result;

/// A scripted controller: banner, status on `?`, one answer per line after a
/// delay, `error:20` on line `fail_on`. Asserts it never holds more than
/// `rx` unanswered bytes (what GRBL's receive buffer could take).
async fn fake_controller(
    mut io: DuplexStream,
    rx: usize,
    fail_on: Option<usize>,
) -> (usize, Vec<u8>) {
    io.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n")
        .await
        .unwrap();
    let mut pending: VecDeque<usize> = VecDeque::new();
    let mut current = 0usize;
    let mut text = String::new();
    let mut lines = 0usize;
    let mut max_in_flight = 0usize;
    let mut realtime_seen = Vec::new();
    let mut buf = [0u8; 256];
    loop {
        let read = tokio::time::timeout(Duration::from_millis(3), io.read(&mut buf)).await;
        match read {
            Ok(Ok(0)) | Ok(Err(_)) => break,
            Ok(Ok(n)) => {
                for &b in &buf[..n] {
                    match b {
                        b'?' => {
                            let state = if realtime_seen.contains(&b'!') {
                                "Hold:0"
                            } else if pending.is_empty() {
                                "Idle"
                            } else {
                                "Run"
                            };
                            io.write_all(
                                format!("<{state}|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n")
                                    .as_bytes(),
                            )
                            .await
                            .unwrap();
                        }
                        b'!' | 0x18 => {
                            realtime_seen.push(b);
                            if b == 0x18 {
                                pending.clear();
                                realtime_seen.retain(|&c| c != b'!');
                                io.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n")
                                    .await
                                    .unwrap();
                            }
                        }
                        b'\n' if text.starts_with('$') => {
                            // The sender's own `$I`: answered at once, not a program line.
                            io.write_all(b"[VER:1.1h:]\r\n[OPT:V,15,128]\r\nok\r\n").await.unwrap();
                            current = 0;
                            text.clear();
                        }
                        b'\n' => {
                            pending.push_back(current + 1);
                            current = 0;
                            text.clear();
                        }
                        _ => {
                            current += 1;
                            text.push(b as char);
                        }
                    }
                }
                let in_flight: usize = pending.iter().sum::<usize>() + current;
                max_in_flight = max_in_flight.max(in_flight);
            }
            Err(_) => {
                // Answer the oldest line once per tick: a slow controller.
                if pending.pop_front().is_some() {
                    lines += 1;
                    let answer = if Some(lines) == fail_on {
                        "error:20\r\n"
                    } else {
                        "ok\r\n"
                    };
                    io.write_all(answer.as_bytes()).await.unwrap();
                }
            }
        }
        assert!(
            max_in_flight <= rx,
            "{max_in_flight} bytes in flight > receive buffer {rx}"
        );
    }
    (lines, realtime_seen)
}

fn program(n: usize) -> Vec<String> {
    (0..n)
        .map(|i| format!("G1X{}.12345Y{}.54321F60000", i, i))
        .collect()
}

#[tokio::test(start_paused = true)]
async fn character_counting_never_overfills_and_every_line_is_acked() {
    let (a, b) = tokio::io::duplex(4096);
    let lines = program(60);
    let opts = SenderOptions::new(128, 5.0);
    let controller = tokio::spawn(fake_controller(b, 128, None));
    let mut sent = 0;
    let out = stream(
        a,
        lines.iter().cloned().map(Ok),
        &opts,
        &|n, _| format!("line {n}"),
        |_, e| {
            if matches!(e, LinkEvent::Sent { line, .. } if line > 0) {
                sent += 1
            }
        },
    )
    .await
    .unwrap();
    assert!(out.completed, "{:?}", out.stop_reason);
    assert_eq!(out.last_acked_line, 60);
    assert_eq!(out.lines_sent, 60);
    assert_eq!(sent, 60);
    assert_eq!(
        out.bytes_sent,
        lines.iter().map(|l| l.len() + 1).sum::<usize>()
    );
    drop(controller);
}

#[test]
fn lines_are_cleaned_as_grbl_would() {
    assert_eq!(clean_line("g1 x1.5 (to the edge) y2 ; then stop\r"), "G1X1.5Y2");
    assert_eq!(clean_line("%"), "");
    assert_eq!(clean_line("  (only a comment)"), "");
    assert_eq!(clean_line("$J=G91 X10 F600"), "$J=G91X10F600");
}

#[tokio::test(start_paused = true)]
async fn blank_and_comment_lines_cost_no_round_trip_but_count() {
    let (a, b) = tokio::io::duplex(4096);
    let mut lines = vec!["%".to_string(), "(header)".to_string()];
    for l in program(20) {
        lines.push(format!("{l} ; comment"));
        lines.push(String::new());
    }
    lines.push("%".into());
    let controller = tokio::spawn(fake_controller(b, 128, None));
    let out = stream(a, lines.iter().cloned().map(Ok), &SenderOptions::new(128, 5.0), &|n, _| format!("line {n}"), |_, _| {}).await.unwrap();
    assert!(out.completed, "{:?}", out.stop_reason);
    assert_eq!(out.lines_sent, 20);
    assert_eq!(out.bytes_sent, program(20).iter().map(|l| l.to_ascii_uppercase().len() + 1).sum::<usize>());
    assert_eq!((out.last_acked_line, out.last_executed_line), (lines.len(), Some(lines.len())));
    drop(controller);
}

#[tokio::test(start_paused = true)]
async fn an_error_stops_streaming_and_names_the_line_then_holds_and_resets() {
    let (a, b) = tokio::io::duplex(4096);
    let lines = program(60);
    let opts = SenderOptions::new(128, 5.0);
    let controller = tokio::spawn(fake_controller(b, 128, Some(17)));
    let out = stream(
        a,
        lines.iter().cloned().map(Ok),
        &opts,
        &|n, _| format!("G-code line {n}"),
        |_, _| {},
    )
    .await
    .unwrap();
    assert!(!out.completed);
    assert_eq!(out.errors[0].line, 17);
    assert!(out.stop_reason.unwrap().contains("error:20"));
    assert!(
        out.lines_sent < 17 + 5,
        "stopped sending at the error: {}",
        out.lines_sent
    );
    // The controller answers the lines it had received before the hold
    // (Grbl does too): up to the three behind the failing one.
    assert!((16..=20).contains(&out.last_acked_line), "{}", out.last_acked_line);
    drop(controller);
}

/// Answers what the sender asks when it connects (a status request, then
/// `$I`), as a controller that works so far.
async fn answer_connect(b: &mut DuplexStream) {
    answer_connect_with(b, "V,15,128").await;
}

/// The same, with these build options (`[OPT:...]`); the status reports
/// have no `Bf:` (Grbl's default `$10=1`).
async fn answer_connect_with(b: &mut DuplexStream, options: &str) {
    let mut buf = [0u8; 64];
    let mut seen = Vec::new();
    while !seen.ends_with(b"$I\n") {
        let n = b.read(&mut buf).await.unwrap_or(0);
        if n == 0 {
            return;
        }
        for &c in &buf[..n] {
            if c == b'?' {
                b.write_all(b"<Idle|MPos:0.000,0.000|FS:0,0>\r\n").await.unwrap();
            } else {
                seen.push(c);
            }
        }
    }
    b.write_all(format!("[VER:1.1h:]\r\n[OPT:{options}]\r\nok\r\n").as_bytes()).await.unwrap();
}

/// Streams ten lines to a controller that will not answer them sensibly:
/// the stream must stop, calling the controller silent.
async fn assert_streaming_stops_as_silent(a: DuplexStream) {
    let opts = SenderOptions::new(128, 5.0);
    let lines = program(10).into_iter().map(Ok);
    let out = stream(a, lines, &opts, &|n, _| format!("line {n}"), |_, _| {}).await.unwrap();
    assert!(!out.completed);
    assert!(out.stop_reason.unwrap().contains("silent"));
}

#[tokio::test(start_paused = true)]
async fn build_options_set_the_buffers_counted_on() {
    let (a, mut b) = tokio::io::duplex(4096);
    let board = tokio::spawn(async move {
        b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        // No Bf in the reports: only `$I` tells the sizes.
        answer_connect_with(&mut b, "VL,14,64").await;
        b
    });
    let c = Connection::open(a, &SenderOptions::new(128, 5.0), |_, _| {}).await.unwrap();
    assert_eq!((c.rx_buffer, c.link.book.planner_blocks), (64, Some(14)));
    drop(board.await.unwrap());

    // A controller that answers status but not `$I` is not one to stream to.
    let (a, mut b) = tokio::io::duplex(4096);
    let mute = tokio::spawn(async move {
        b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        let mut buf = [0u8; 64];
        while let Ok(n) = b.read(&mut buf).await {
            if n == 0 {
                break;
            }
            if buf[..n].contains(&b'?') {
                b.write_all(b"<Idle|MPos:0.000,0.000|FS:0,0>\r\n").await.unwrap();
            }
        }
    });
    let err = Connection::open(a, &SenderOptions::new(128, 5.0), |_, _| {}).await.err().expect("refused");
    assert!(err.to_string().contains("$I"), "{err}");
    mute.abort();
}

#[tokio::test(start_paused = true)]
async fn a_silent_controller_is_detected() {
    let (a, mut b) = tokio::io::duplex(4096);
    let keep = tokio::spawn(async move {
        b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        answer_connect(&mut b).await;
        // Then never a word again.
        tokio::time::sleep(Duration::from_secs(3600)).await;
    });
    assert_streaming_stops_as_silent(a).await;
    keep.abort();
}

#[tokio::test(start_paused = true)]
async fn a_controller_answering_garbage_is_detected() {
    let (a, mut b) = tokio::io::duplex(4096);
    let babble = tokio::spawn(async move {
        b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        answer_connect(&mut b).await;
        loop {
            if b.write_all(b"\x07#~garbage~#\r\n").await.is_err() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
    assert_streaming_stops_as_silent(a).await;
    babble.abort();
}

/// A scripted controller that misbehaves as told: the banner, the
/// answers to connecting (`$I`: 15 planner blocks, 128 bytes), then
/// `answer(n, line)` for the n-th program line (`None`: the link closes)
/// and `report(answered)` for every `?`. Returns the realtime bytes it
/// got (`!`, 0x18 ...), which it otherwise ignores.
async fn scripted(
    mut io: DuplexStream,
    mut answer: impl FnMut(usize, &str) -> Option<Vec<u8>>,
    mut report: impl FnMut(usize) -> String,
) -> Vec<u8> {
    io.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
    let (mut line, mut lines, mut realtime_seen) = (Vec::new(), 0, Vec::new());
    let mut buf = [0u8; 256];
    loop {
        let n = match io.read(&mut buf).await {
            Ok(0) | Err(_) => return realtime_seen,
            Ok(n) => n,
        };
        for &b in &buf[..n] {
            let reply = match b {
                b'?' => Some(report(lines).into_bytes()),
                b'\n' => {
                    let text = String::from_utf8_lossy(&std::mem::take(&mut line)).to_string();
                    if text == BUILD_INFO {
                        Some(b"[VER:1.1h:]\r\n[OPT:V,15,128]\r\nok\r\n".to_vec())
                    } else {
                        lines += 1;
                        match answer(lines, &text) {
                            Some(reply) => Some(reply),
                            None => return realtime_seen,
                        }
                    }
                }
                b if realtime::is_realtime(b) || b >= 0x80 => {
                    realtime_seen.push(b);
                    None
                }
                b => {
                    line.push(b);
                    None
                }
            };
            if let Some(reply) = reply {
                if io.write_all(&reply).await.is_err() {
                    return realtime_seen;
                }
            }
        }
    }
}

/// Streams `lines` to `peer`; the outcome and the realtime bytes the
/// peer got. Bounded: a sender that hangs fails the test.
async fn against(lines: Vec<String>, peer: impl std::future::Future<Output = Vec<u8>> + Send + 'static, a: DuplexStream) -> (Result<StreamOutcome>, Vec<u8>) {
    let peer = tokio::spawn(peer);
    let opts = SenderOptions::new(128, 5.0);
    let run = stream(a, lines.into_iter().map(Ok), &opts, &|n, text| format!("line {n} `{text}`"), |_, _| {});
    let out = tokio::time::timeout(Duration::from_secs(600), run).await.expect("the sender ends within 10 minutes");
    (out, peer.await.unwrap())
}

fn ok() -> Option<Vec<u8>> {
    Some(b"ok\r\n".to_vec())
}

#[tokio::test(start_paused = true)]
async fn a_controller_running_forever_after_the_last_ok_is_a_stall_naming_the_executed_line() {
    let (a, b) = tokio::io::duplex(4096);
    // Every line acknowledged, then `Run` forever with one block queued.
    let peer = scripted(b, |_, _| ok(), |_| "<Run|MPos:1.000,2.000|Bf:14,128|FS:600,0>\r\n".into());
    let start = Instant::now();
    let lines: Vec<String> = (0..10).map(|i| format!("G1X{}Y{i}F60000", 10 * i)).collect();
    let (out, realtime_seen) = against(lines, peer, a).await;
    let out = out.unwrap();
    let reason = out.stop_reason.unwrap();
    assert!(!out.completed);
    assert!(reason.contains("stalled") && reason.contains("Run"), "{reason}");
    // One block still queued and up to 5 in Grbl's step-segment buffer
    // (every line but the first, from an unknown place, makes one): the
    // lines up to the 6th from the end have surely run.
    assert_eq!((out.last_acked_line, out.last_executed_line), (10, Some(4)));
    assert!(reason.contains("last acknowledged: line 10 `") && reason.contains("last executed (a lower bound): line 4 `G1X30Y3F60000`"), "{reason}");
    assert!(start.elapsed() < STALL_TIMEOUT + Duration::from_secs(15), "{:?}", start.elapsed());
    assert!(realtime_seen.contains(&realtime::FEED_HOLD) && realtime_seen.contains(&realtime::SOFT_RESET), "{realtime_seen:?}");
}

#[tokio::test(start_paused = true)]
async fn a_dwell_is_not_a_stall() {
    let (a, mut b) = tokio::io::duplex(4096);
    // The dwell's line is answered when it is over (as Grbl does); the
    // machine stands still meanwhile.
    let peer = async move {
        b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        answer_connect_with(&mut b, "V,15,128").await;
        let (mut text, mut buf, mut dwell_ends, mut done) = (Vec::new(), [0u8; 64], None, false);
        loop {
            let n = tokio::select! {
                n = b.read(&mut buf) => n.unwrap_or(0),
                _ = tokio::time::sleep_until(dwell_ends.unwrap_or(Instant::now() + Duration::from_secs(3600))), if dwell_ends.is_some() => {
                    dwell_ends = None;
                    done = true;
                    b.write_all(b"ok\r\n").await.unwrap();
                    continue;
                }
            };
            if n == 0 {
                return Vec::new();
            }
            for &c in &buf[..n] {
                match c {
                    b'?' => {
                        let state = if done { "Idle" } else { "Run" };
                        b.write_all(format!("<{state}|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n").as_bytes()).await.unwrap();
                    }
                    b'\n' => {
                        if text.starts_with(b"G4") {
                            dwell_ends = Some(Instant::now() + Duration::from_secs(30));
                        } else {
                            b.write_all(b"ok\r\n").await.unwrap();
                        }
                        text.clear();
                    }
                    c => text.push(c),
                }
            }
        }
    };
    let (out, _) = against(vec!["G1X1F600".into(), "G4P30".into()], peer, a).await;
    let out = out.unwrap();
    assert!(out.completed, "{:?}", out.stop_reason);
}

#[tokio::test(start_paused = true)]
async fn more_ok_than_lines_sent_is_a_protocol_error() {
    let (a, b) = tokio::io::duplex(4096);
    let peer = scripted(b, |_, _| Some(b"ok\r\nok\r\n".to_vec()), |_| "<Idle|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n".into());
    let (out, realtime_seen) = against(program(10), peer, a).await;
    let out = out.unwrap();
    let reason = out.stop_reason.unwrap();
    assert!(!out.completed);
    assert!(reason.contains("protocol error") && reason.contains("more answers than lines sent"), "{reason}");
    // Within the first status interval no report has said what ran.
    assert!(reason.contains("last executed (a lower bound): "), "{reason}");
    assert!(realtime_seen.contains(&realtime::FEED_HOLD) && realtime_seen.contains(&realtime::SOFT_RESET), "{realtime_seen:?}");
}

#[tokio::test(start_paused = true)]
async fn no_free_receive_buffer_while_idle_is_named_not_blamed_on_a_line() {
    let (a, b) = tokio::io::duplex(4096);
    let peer = scripted(b, |_, _| ok(), |_| "<Idle|MPos:0.000,0.000|Bf:15,0|FS:0,0>\r\n".into());
    let (out, _) = against(program(3), peer, a).await;
    let err = out.expect_err("refused").to_string();
    assert!(err.contains("no free receive buffer while idle (`Bf:15,0`)"), "{err}");
    assert!(!err.contains("line 1"), "{err}");
}

#[tokio::test(start_paused = true)]
async fn a_line_without_end_from_the_controller_is_refused_in_bounded_memory() {
    let (a, b) = tokio::io::duplex(4096);
    // Line 3 is answered by a megabyte without a line end.
    let peer = scripted(b, |n, _| if n == 3 { Some(vec![b'A'; 1 << 20]) } else { ok() }, |_| "<Run|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n".into());
    let (out, realtime_seen) = against(program(10), peer, a).await;
    let out = out.unwrap();
    let reason = out.stop_reason.unwrap();
    assert!(reason.contains(&format!("more than {MAX_CONTROLLER_LINE} bytes without a line end")), "{reason}");
    // The answers after the garbage are not taken for progress.
    assert!(reason.contains("last acknowledged: line 2 `"), "{reason}");
    assert!(out.last_executed_line <= Some(2), "{reason}");
    assert!(realtime_seen.contains(&realtime::FEED_HOLD) && realtime_seen.contains(&realtime::SOFT_RESET), "{realtime_seen:?}");
}

#[tokio::test(start_paused = true)]
async fn a_disconnect_names_the_last_acknowledged_and_executed_line() {
    let (a, b) = tokio::io::duplex(4096);
    let peer = scripted(b, |n, _| (n <= 5).then(|| b"ok\r\n".to_vec()), |_| "<Run|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n".into());
    let (out, _) = against(program(20), peer, a).await;
    let out = out.unwrap();
    let reason = out.stop_reason.unwrap();
    assert!(reason.contains(LINK_CLOSED), "{reason}");
    assert!(reason.contains("last acknowledged: line 5 `G1X4.12345Y4.54321F60000`"), "{reason}");
    // Within the first status interval no report has said what ran.
    assert!(reason.contains("last executed (a lower bound): "), "{reason}");
}

#[tokio::test(start_paused = true)]
async fn an_over_long_line_is_quoted_by_its_first_80_characters() {
    let (a, b) = tokio::io::duplex(4096);
    let controller = tokio::spawn(fake_controller(b, 128, None));
    let long = format!("G1X{}", "1".repeat(1_000_000));
    let lines = vec!["G1X1F600".to_string(), long];
    let out = stream(a, lines.into_iter().map(Ok), &SenderOptions::new(128, 5.0), &|n, text| format!("line {n} `{text}`"), |_, _| {}).await.unwrap();
    let reason = out.stop_reason.unwrap();
    assert!(reason.contains(&format!("line 2 `G1X{}… (1000003 bytes)`", "1".repeat(77))), "{reason}");
    assert!(reason.len() < 600, "{} bytes: {reason}", reason.len());
    drop(controller);
}

#[test]
fn a_jog_of_axis_words_is_relative_at_the_default_feed_and_a_full_block_is_kept() {
    assert_eq!(jog_block("X10", 3000.0), "G91 X10 F3000");
    assert_eq!(jog_block(" x-2.5 y4 ", 1200.5), "G91 x-2.5 y4 F1200.5");
    // A block naming its distance mode and feed goes as it is.
    assert_eq!(jog_block("G91 X10 F600", 3000.0), "G91 X10 F600");
    assert_eq!(jog_block("G90X5Y5F900", 3000.0), "G90X5Y5F900");
    // Each missing part is added alone.
    assert_eq!(jog_block("X10 F600", 3000.0), "G91 X10 F600");
    assert_eq!(jog_block("G90 X5", 3000.0), "G90 X5 F3000");
    // G21 is no distance mode.
    assert_eq!(jog_block("G21 X1", 500.0), "G91 G21 X1 F500");
}
