//! Conformance: the simulator walked through realtime bytes, `$` commands,
//! error and alarm paths of the reference (`shared/reference/grbl-protocol.md`),
//! each checked against the exact text a Grbl 1.1 controller sends.

mod common;

use common::{cfg, Sim};

/// What the controller sends in answer to `input` (lines, without CR/LF).
fn exchange(s: &mut Sim, input: &str) -> Vec<String> {
    let before = s.lines.len();
    s.send(input);
    let t = s.t;
    s.run_until(t + 0.5);
    s.lines[before..].iter().map(|(_, l)| l.clone()).collect()
}

const BANNER: &str = "Grbl 1.1h ['$' for help]";

#[test]
fn responses_match_the_reference_exactly() {
    // (what comes before, input, exact answer)
    let cases: &[(&[&str], &str, &[&str])] = &[
        (&[], "?", &["<Idle|MPos:0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000>"]),
        (&["?"], "?", &["<Idle|MPos:0.000,0.000|Bf:15,128|FS:0,0|Ov:100,100,100>"]),
        (&[], "$\n", &["[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]", "ok"]),
        (&[], "$G\n", &["[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]),
        (&["G91 G93 M4 S250\n"], "$G\n", &["[GC:G0 G54 G17 G21 G91 G93 M4 M9 T0 F0 S250]", "ok"]),
        (&[], "$I\n", &["[VER:1.1h.laserd-sim:]", "[OPT:V,15,128]", "ok"]),
        (&[], "$N\n", &["$N0=", "$N1=", "ok"]),
        (&[], "$X\n", &["ok"]),
        (&[], "$C\n", &["[MSG:Enabled]", "ok"]),
        (&["$C\n"], "$C\n", &["[MSG:Disabled]", "ok", BANNER]),
        (&[], "$SLP\n", &["[MSG:Sleeping]", "ok"]),
        (&[], "$Q\n", &["error:3"]),
        (&[], "$J=X1\n", &["error:22"]),
        (&[], "$J=X1S5F100\n", &["error:16"]),
        (&[], "$J=X-1F100\n", &["error:15"]),
        (&[], "\n", &["ok"]),
        (&[], "(only a comment)\n", &["ok"]),
        (&[], "G1X1\n", &["error:22"]),
        (&[], "G5X1\n", &["error:20"]),
        (&[], "G0G1X1\n", &["error:21"]),
        (&[], "X1X2\n", &["error:25"]),
        (&[], "1\n", &["error:1"]),
        (&[], "X\n", &["error:2"]),
        (&[], "G1.5X1\n", &["error:23"]),
        (&[], "G4\n", &["error:28"]),
        (&[], "G59.1\n", &["error:29"]),
        (&[], "\u{18}", &["", BANNER]),
        (&[], "G0X-1\n", &["ALARM:2", "[MSG:Reset to continue]", "error:9"]),
        (&["G0X-1\n"], "?", &[]),
        (&["G0X-1\n", "\u{18}"], "G0X1\n", &["error:9"]),
        (&["G0X-1\n", "\u{18}"], "$X\n", &["[MSG:Caution: Unlocked]", "ok"]),
        (&["G0X100F100\n"], "\u{18}", &["ALARM:3", "", BANNER, "[MSG:'$H'|'$X' to unlock]"]),
        (&["$SLP\n"], "G0X1\n", &["error:9"]),
        (&[], "M2\n", &["[MSG:Pgm End]", "ok"]),
        (&[], "$RST=$\n", &["[MSG:Restoring defaults]", "ok", BANNER]),
        (&[], "$RST=x\n", &["error:3"]),
    ];
    for (before, input, expected) in cases {
        let mut s = Sim::new(cfg());
        let mut t = 0.0;
        for b in *before {
            s.send(b);
            t += 0.2;
            s.run_until(t);
        }
        let got = exchange(&mut s, input);
        let got: Vec<&str> = got.iter().map(String::as_str).filter(|l| !l.is_empty()).collect();
        let want: Vec<&str> = expected.iter().copied().filter(|l| !l.is_empty()).collect();
        assert_eq!(got, want, "after {before:?}, input {input:?}");
    }
}
