//! The sender against the simulator's `grbl` motion model (Grbl 1.1's
//! look-ahead planner), streaming what another CAM tool writes: G94 feeds,
//! G0 rapids, M4 laser, many short segments and sharp corners. The sender must
//! keep its books right while the controller plans, brakes and holds.

use std::cell::RefCell;
use std::time::Duration;

use laserd::stream::{in_process, Connection, Control, SenderOptions};
use laserd_sim::controller::{Controller, Knot, MotionModel, SimConfig};
use laserd_sim::limits::LimitChecker;
use laserd_sim::wire::MachineState;
use tokio::sync::{mpsc, watch};

/// A LightBurn-like job: a rapid to each of 12 squares, each traced as 40
/// short G1 segments at 3000 mm/min with the laser on.
fn cam_program() -> Vec<String> {
    let mut lines = vec!["G21G90G94".to_string(), "M4S0".to_string()];
    for k in 0..12 {
        let (x0, y0) = (10.0 + 20.0 * (k % 4) as f64, 10.0 + 20.0 * (k / 4) as f64);
        lines.push(format!("G0X{x0:.3}Y{y0:.3}"));
        for i in 1..=40 {
            let u = i as f64 / 10.0;
            let (x, y) = match i {
                1..=10 => (x0 + 10.0 * u, y0),
                11..=20 => (x0 + 10.0, y0 + 10.0 * (u - 1.0)),
                21..=30 => (x0 + 10.0 * (3.0 - u), y0 + 10.0),
                _ => (x0, y0 + 10.0 * (4.0 - u)),
            };
            lines.push(format!("G1X{x:.3}Y{y:.3}S600F3000"));
        }
    }
    lines.push("M5".into());
    lines
}

#[test]
fn a_cam_program_streams_holds_and_completes_on_grbl_motion() {
    let cfg = SimConfig { motion: MotionModel::Grbl, ..SimConfig::with_axes("XY") };
    let axes = cfg.axes.clone();
    let lines = cam_program();
    let knots = RefCell::new(Vec::<Knot>::new());
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().start_paused(true).build().unwrap();
    let (outcome, heard) = runtime.block_on(async {
        let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
        let origin = tokio::time::Instant::now();
        let (stop_tx, stop_rx) = watch::channel(false);
        let sim = in_process::run(Controller::new(cfg), sim_io, 115200, origin, stop_rx, |k| knots.borrow_mut().extend(k));
        let operator = async {
            let heard = RefCell::new(Vec::<String>::new());
            let options = SenderOptions::new(128, 5.0);
            let mut c = Connection::open(sender_io, &options, |_, e| {
                if let laserd::stream::LinkEvent::Received { text } = e {
                    heard.borrow_mut().push(text);
                }
            })
            .await
            .unwrap();
            let (tx, mut rx) = mpsc::unbounded_channel();
            let buttons = async {
                tokio::time::sleep(Duration::from_millis(2000)).await;
                tx.send(Control::FeedHold).unwrap();
                tokio::time::sleep(Duration::from_millis(1000)).await;
                tx.send(Control::Resume).unwrap();
            };
            let describe = |n: usize, _: &str| format!("line {n}");
            let (outcome, _) = tokio::join!(c.stream(lines.iter().cloned().map(Ok), &describe, Some(&mut rx)), buttons);
            let _ = stop_tx.send(true);
            (outcome.unwrap(), heard.into_inner())
        };
        let (_, out) = tokio::join!(sim, operator);
        out
    });
    assert!(outcome.completed, "{:?}", outcome.stop_reason);
    assert_eq!(outcome.last_executed_line, Some(lines.len()));
    assert!(outcome.errors.is_empty() && outcome.alarms.is_empty());
    assert!(heard.iter().any(|t| t.starts_with("<Hold:0")), "the hold completed");
    assert_eq!(outcome.final_status.unwrap().state, MachineState::Idle);

    // Grbl's planner keeps every axis within its max rate, rapids included.
    // (Not its acceleration in the checker's sense: at a corner Grbl turns the
    // velocity at once, at the junction-deviation speed, and knows no jerk.)
    let knots = knots.into_inner();
    let mut checker = LimitChecker::new(&axes);
    knots.iter().for_each(|k| checker.push(k));
    let report = checker.finish();
    assert!(report.peak_velocity_use.iter().all(|u| *u <= 1.0 + 1e-6 && *u > 0.99), "{report:?}");
    // It ends where the program ends.
    let last = knots.last().unwrap();
    assert!((last.pos[0] - 10.0 - 20.0 * 3.0).abs() < 1e-6 && (last.pos[1] - 50.0).abs() < 1e-6, "{last:?}");
    // The laser was off through the hold: while the machine stood still in it,
    // nothing was marked, and every knot of braking after the hold has power 0.
    assert!(knots.windows(2).all(|w| w[0].pos != w[1].pos || w[1].power == 0.0 || w[1].t == w[0].t));
}
