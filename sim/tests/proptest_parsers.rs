//! Property tests of the simulator's line parser and the status reports both
//! peers parse (`wire`): generated input, on stable, in the normal suite. The
//! fuzz targets in fuzz/ search the same parsers far longer.

mod common;

use common::{cfg, Sim};
use laserd_sim::wire::{realtime, MachineState, Response, StatusReport};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// The same cases on every run and machine (a test that fails, fails
/// again), and no regression files written into the source tree.
fn reproducible() -> ProptestConfig {
    ProptestConfig { rng_seed: RngSeed::Fixed(16), failure_persistence: None, ..ProptestConfig::default() }
}

/// Virtual time to run a line to its answer: a dwell or a move of the sizes
/// generated below ends well within it.
const RUN_S: f64 = 1e6;

/// A number as G-code writes them: integers, decimals, signs, leading dots,
/// and the odd exponent or sign Grbl must refuse.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        (0u32..400).prop_map(|n| n.to_string()),
        (-500.0f64..500.0).prop_map(|x| format!("{x:.3}")),
        (0.0f64..1.0).prop_map(|x| format!("{x:.4}").trim_start_matches('0').to_string()),
        Just("-".to_string()),
        Just("".to_string()),
        Just("1e3".to_string()),
        Just("+2".to_string()),
        Just("0.5.5".to_string()),
    ]
}

/// A G-code word, most of them letters Grbl knows.
fn word() -> impl Strategy<Value = String> {
    let letter = prop_oneof![
        8 => prop::sample::select(vec!['G', 'M', 'X', 'Y', 'Z', 'F', 'S', 'P', 'I', 'J', 'K', 'R', 'L', 'N', 'T']),
        1 => prop::sample::select(vec!['A', 'B', 'C', 'D', 'E', 'H', 'O', 'Q', 'U', 'V', 'W', 'g', 'x']),
    ];
    let code = prop::sample::select(vec![
        "0", "1", "2", "3", "4", "10", "17", "18", "19", "20", "21", "28", "28.1", "30", "30.1", "38.2", "38.3", "38.4",
        "38.5", "40", "43.1", "49", "53", "54", "55", "59", "61", "80", "90", "90.1", "91", "91.1", "92", "92.1", "93", "94",
        "5", "7", "8", "9", "56",
    ]);
    prop_oneof![
        (prop::sample::select(vec!['G', 'M']), code).prop_map(|(l, c)| format!("{l}{c}")),
        (letter, number()).prop_map(|(l, n)| format!("{l}{n}")),
    ]
}

/// A G-code line without program pauses (M0/M1 hold the machine until a cycle
/// start, so later lines would wait for it, as on Grbl): words with spaces,
/// a comment now and then.
fn gcode_line() -> impl Strategy<Value = String> {
    (prop::collection::vec(word(), 0..6), prop::sample::select(vec!["", " ", "(note)", ";end"]))
        // Judged word by word: joined without spaces, `G17M0` is a pause too.
        .prop_filter("no program pause", |(words, _)| {
            !words.iter().any(|w| {
                let u = w.to_ascii_uppercase();
                u.strip_prefix('M').and_then(|v| v.parse::<f64>().ok()).is_some_and(|v| v == 0.0 || v == 1.0)
            })
        })
        .prop_map(|(words, tail)| format!("{}{tail}", words.join(if words.len() % 2 == 0 { "" } else { " " })))
}

/// Any text without line ends or realtime bytes (those act at once, not as a line).
fn any_line() -> impl Strategy<Value = String> {
    prop::collection::vec(any::<char>(), 0..90).prop_map(|cs| {
        cs.into_iter()
            .filter(|c| !(matches!(c, '\n' | '\r') || c.is_ascii() && realtime::is_realtime(*c as u8)))
            .collect()
    })
}

/// Every line the controller sent parses as a response; status reports in full.
fn assert_all_parse(s: &Sim) {
    for l in s.texts() {
        if l.starts_with('<') {
            assert!(StatusReport::parse(l).is_ok(), "{l:?}");
        }
        if l.starts_with("error:") {
            assert!(matches!(Response::parse(l), Response::Error(_)), "{l:?}");
        }
        if l.starts_with("ALARM:") {
            assert!(matches!(Response::parse(l), Response::Alarm(_)), "{l:?}");
        }
    }
}

/// The controller still answers a status request: after a critical alarm
/// (a soft limit: Grbl 1.1h then answers nothing until a reset) once reset.
fn still_reports(s: &mut Sim) -> StatusReport {
    if s.texts().iter().any(|l| l.starts_with("ALARM:")) {
        s.realtime(realtime::SOFT_RESET);
        let t = s.t;
        s.run_until(t + 1.0);
    }
    s.status()
}

proptest! {
    #![proptest_config(reproducible())]

    /// Each G-code line gets exactly one answer, `ok` or `error:N`, and nothing
    /// panics; afterwards the controller still answers a status request.
    #[test]
    fn every_gcode_line_gets_one_answer(lines in prop::collection::vec(gcode_line(), 1..6)) {
        let mut s = Sim::new(cfg());
        // Soft limits on: a move past them (Grbl's machine space is negative)
        // takes the critical path.
        s.send("$22=1\n$20=1\n");
        s.run_until(0.1);
        let (setup, from) = (s.responses().len(), s.lines.len());
        for l in &lines {
            s.send(&format!("{l}\n"));
        }
        s.run_until(0.1 + RUN_S);
        assert_all_parse(&s);
        let answers = s.responses().len() - setup;
        let texts = &s.texts()[from..];
        match texts.iter().position(|l| *l == "[MSG:Reset to continue]") {
            // A critical alarm (a soft limit) answers its line only after a
            // reset and takes no more until then.
            Some(at) => {
                let before = texts[..at].iter().filter(|l| matches!(Response::parse(l), Response::Ok | Response::Error(_))).count();
                prop_assert_eq!(answers, before, "lines {:?} answered {:?}", lines, texts);
                prop_assert!(before < lines.len());
            }
            None => prop_assert_eq!(answers, lines.len(), "lines {:?} answered {:?}", lines, texts),
        }
        let report = still_reports(&mut s);
        prop_assert!(report.position().iter().all(|x| x.is_finite()), "{:?}", report);
    }

    /// Arbitrary text as a line (including `$` commands and bytes above ASCII)
    /// never panics, and what the controller sends back parses.
    #[test]
    fn any_line_never_panics(line in any_line()) {
        let mut s = Sim::new(cfg());
        s.send(&format!("{line}\n"));
        s.run_until(RUN_S);
        assert_all_parse(&s);
        still_reports(&mut s);
    }
}

fn state() -> impl Strategy<Value = MachineState> {
    prop_oneof![
        Just(MachineState::Idle),
        Just(MachineState::Run),
        (0u8..2).prop_map(MachineState::Hold),
        Just(MachineState::Jog),
        Just(MachineState::Alarm),
        (0u8..4).prop_map(MachineState::Door),
        Just(MachineState::Check),
        Just(MachineState::Home),
        Just(MachineState::Sleep),
        Just(MachineState::Tool),
    ]
}

/// A position as Grbl prints it: three decimals.
fn position(axes: usize) -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec((-1_000_000i64..1_000_000).prop_map(|m| m as f64 / 1000.0), axes)
}

fn report() -> impl Strategy<Value = StatusReport> {
    let head = (state(), 1usize..7, any::<bool>()).prop_flat_map(|(state, axes, work)| (Just(state), position(axes), Just(work), prop::option::of(position(axes))));
    let fields = (
        prop::option::of((0u32..200, 0u32..2048)),
        prop::option::of(any::<u32>()),
        prop::option::of((0u32..100_000, prop::option::of(0u32..100_000))),
        prop::option::of([0u32..256, 0u32..256, 0u32..256]),
        prop::option::of("[XYZPDHRS]{1,4}"),
        prop::option::of("[SCFM]{1,3}"),
    );
    (head, fields).prop_map(|((state, pos, work, wco), (buffer, line, feed, overrides, pins, accessories))| {
        let mut r = StatusReport::new(state, Vec::new());
        if work {
            r.wpos = Some(pos);
        } else {
            r.mpos = pos;
        }
        r.buffer = buffer;
        r.line = line;
        if let Some((f, sp)) = feed {
            r.feed = Some(f as f64);
            r.spindle = sp.map(|s| s as f64);
        }
        r.overrides = overrides;
        r.wco = wco;
        r.pins = pins;
        r.accessories = accessories;
        r
    })
}

proptest! {
    #![proptest_config(reproducible())]

    /// A report as a controller prints it parses back to itself.
    #[test]
    fn status_reports_round_trip(r in report()) {
        let line = r.to_line();
        let back = StatusReport::parse(&line).map_err(|e| TestCaseError::fail(format!("{line}: {e}")))?;
        prop_assert_eq!(&back, &r, "{}", line);
        prop_assert_eq!(Response::parse(&format!("{line}\r\n")), Response::Status(r));
    }

    /// A report with a field cut short or garbled either parses to a report
    /// that prints and parses again the same, or is refused; never a panic.
    #[test]
    fn mangled_status_reports_parse_or_are_refused(r in report(), cut in any::<prop::sample::Index>(), junk in "[<>|:,.0-9A-Za-z -]{0,6}") {
        let line = r.to_line();
        let at = cut.index(line.len() + 1);
        let mangled = format!("{}{junk}{}", &line[..at], &line[at..]);
        if let Ok(parsed) = StatusReport::parse(&mangled) {
            let again = StatusReport::parse(&parsed.to_line()).map_err(|e| TestCaseError::fail(format!("{mangled}: {e}")))?;
            prop_assert_eq!(&again.state, &parsed.state);
            prop_assert_eq!(again.position().len(), parsed.position().len());
        }
    }

    /// Any text at all is classified as some response.
    #[test]
    fn any_text_is_some_response(text in ".{0,120}") {
        let _ = Response::parse(&text);
        let _ = StatusReport::parse(&text);
    }
}
