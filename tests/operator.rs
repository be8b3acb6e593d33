//! The operator's view of a running machine: the ETA against the job's
//! executed time, framing, overrides, and the TCP side's login, CSRF and
//! token checks (`laserd serve` on `laserd sim --pty`, both as child
//! processes, in real time).

mod common;

use std::time::{Duration, Instant};

use common::service::*;
use hyper::Method;

/// One status seen while a job ran: when (s from the first), its progress.
struct Seen {
    t: f64,
    time_percent: f64,
    eta: f64,
    line_share: f64,
}

#[test]
fn the_eta_at_a_tenth_half_and_nine_tenths_of_a_job_is_within_2_percent_of_its_executed_time() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    // Reports with `Bf:`: the executed line is known while a job runs.
    let (_rig, service, api) = Rig::start_with(dir.path(), "ttyETA", &["$10=3"]);
    // Hatch lines and their turns: lines of very different times.
    let id = api.submit(&sample("fill-text.svg"));
    let queued = api.wait_job(&id, "queued", Duration::from_secs(120));
    let planned = queued["planned_time_s"].as_f64().unwrap();
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": id })));
    let started = Instant::now();
    let mut seen = Vec::new();
    let ended = loop {
        let s = api.status();
        let t = started.elapsed().as_secs_f64();
        // The job shows once the machine loop has taken it.
        if s["job"].is_null() {
            if seen.is_empty() && t < 5.0 {
                continue;
            }
            break t;
        }
        let job = &s["job"];
        if let (Some(p), Some(eta), Some(line)) = (job["time_percent"].as_f64(), job["eta_s"].as_f64(), job["executed_line"].as_u64()) {
            seen.push(Seen { t, time_percent: p, eta, line_share: line as f64 / job["lines_total"].as_f64().unwrap() });
        }
        assert!(t < 4.0 * planned + 30.0, "the job ends: {s}");
        std::thread::sleep(Duration::from_millis(20));
    };
    let done = api.wait_job(&id, "completed", Duration::from_secs(10));
    let executed = done["executed_time_s"].as_f64().unwrap();
    assert!((executed - ended).abs() < 0.25, "the service's executed time {executed} s, seen {ended} s");
    eprintln!("planned {planned:.2} s, executed {executed:.2} s");
    if std::env::var("LASERD_ETA_TRACE").is_ok() {
        for s in &seen {
            eprintln!("{:.3} {:.3} {:.3} {:.4}", s.t, s.time_percent, s.eta, s.line_share);
        }
    }
    for anchor in [10.0, 50.0, 90.0] {
        let at = seen.iter().find(|s| s.time_percent >= anchor).unwrap_or_else(|| panic!("a status past {anchor} %"));
        let error = (at.t + at.eta - ended) / ended;
        // What a count of lines would have said then.
        let by_lines = (at.t + planned * (1.0 - at.line_share) - ended) / ended;
        eprintln!("at {:.1} % ({:.2} s): ETA {:.2} s, ends {:+.2} % off; by lines {:+.1} % off", at.time_percent, at.t, at.eta, 100.0 * error, 100.0 * by_lines);
        assert!(error.abs() <= 0.02, "at {anchor} % the ETA {} s is {:.2} % off the end at {ended} s", at.eta, 100.0 * error);
    }
    assert!(service.terminate().success());
}

/// A raw HTTP/1.1 exchange on TCP: the status, the head, the body.
fn http(port: u16, method: &str, path: &str, headers: &[(&str, &str)], body: &[u8]) -> (u16, String, String) {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    let mut request = format!("{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\nContent-Length: {}\r\n", body.len());
    for (k, v) in headers {
        request.push_str(&format!("{k}: {v}\r\n"));
    }
    request.push_str("\r\n");
    stream.write_all(request.as_bytes()).unwrap();
    stream.write_all(body).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut answer = Vec::new();
    // An event stream never ends: its head is enough.
    let _ = stream.read_to_end(&mut answer);
    let answer = String::from_utf8_lossy(&answer).into_owned();
    let (head, body) = answer.split_once("\r\n\r\n").unwrap_or((&answer, ""));
    let code = head.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    (code, head.to_string(), body.to_string())
}

/// The service on TCP with a token (no controller: the checks come first).
fn tcp_service(dir: &std::path::Path, token: &str) -> (Service, u16) {
    let port = 20000 + (std::process::id() % 20000) as u16 + 7;
    let token_file = dir.join("token");
    std::fs::write(&token_file, format!("{token}\n")).unwrap();
    let config = config_with_service(dir, &dir.join("ttyNONE"), &format!("tcp = \"127.0.0.1:{port}\"\ntoken_file = {:?}", token_file.to_str().unwrap()));
    (Service::start(&config, &dir.join("state"), &dir.join("api.sock")), port)
}

#[test]
fn on_tcp_every_page_and_call_needs_the_token_or_a_login_and_a_cross_site_post_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let token = "0123456789abcdef-operator";
    let (service, port) = tcp_service(dir.path(), token);
    let calls = [
        ("GET", "/"), ("GET", "/ui/app.js"), ("GET", "/ui/app.css"), ("GET", "/status"), ("GET", "/jobs"), ("POST", "/jobs?name=a.svg"),
        ("GET", "/jobs/j000001"), ("DELETE", "/jobs/j000001"), ("POST", "/jobs/j000001/move"), ("POST", "/jobs/j000001/resume"),
        ("GET", "/jobs/j000001/program"), ("GET", "/jobs/j000001/recording"), ("GET", "/jobs/j000001/plot"), ("POST", "/start"),
        ("POST", "/pause"), ("POST", "/resume"), ("POST", "/abort"), ("POST", "/home"), ("POST", "/unlock"), ("POST", "/jog"),
        ("POST", "/frame"), ("POST", "/override"), ("GET", "/events"), ("POST", "/logout"), ("GET", "/no-such-page"),
    ];
    let stale = "laserd_session=00000000000000000000000000000000000000000000000000000000000000ff";
    for (method, path) in calls {
        for auth in [None, Some(("Authorization", "Bearer 0123456789abcdef-operatoR")), Some(("Cookie", stale))] {
            let headers: Vec<(&str, &str)> = auth.into_iter().chain([("Accept", "text/html")]).collect();
            let (code, head, _) = http(port, method, path, &headers, b"{}");
            assert_eq!(code, 401, "{method} {path} with {auth:?}: {head}");
        }
    }
    // A page asked for without a login is the login form.
    let (_, _, page) = http(port, "GET", "/", &[("Accept", "text/html")], b"");
    assert!(page.contains("name=\"token\"") && page.contains("action=\"/login\""), "{page}");
    // A wrong token: refused; a login from another site: refused.
    assert_eq!(http(port, "POST", "/login", &[("Content-Type", "application/x-www-form-urlencoded")], b"token=guess").0, 401);
    let from_elsewhere = [("Content-Type", "application/x-www-form-urlencoded"), ("Origin", "http://evil.example")];
    assert_eq!(http(port, "POST", "/login", &from_elsewhere, format!("token={token}").as_bytes()).0, 403);
    // The right one: a session cookie scripts cannot read, never sent cross-site.
    let (code, head, _) = http(port, "POST", "/login", &[("Content-Type", "application/x-www-form-urlencoded"), ("Origin", &format!("http://127.0.0.1:{port}"))], format!("token={token}").as_bytes());
    assert_eq!(code, 303, "{head}");
    let set = head.lines().find(|l| l.to_ascii_lowercase().starts_with("set-cookie:")).expect("a cookie").to_string();
    assert!(set.contains("HttpOnly") && set.contains("SameSite=Strict") && set.contains("Path=/"), "{set}");
    let cookie = set.split_once(':').unwrap().1.trim().split(';').next().unwrap().to_string();
    let (code, head, page) = http(port, "GET", "/", &[("Cookie", &cookie)], b"");
    assert_eq!(code, 200, "{head}");
    assert!(head.contains("content-security-policy: default-src 'self'") && head.contains("x-frame-options: DENY"), "{head}");
    let csrf = page.split("name=\"csrf-token\" content=\"").nth(1).and_then(|r| r.split('"').next()).unwrap().to_string();
    assert_eq!(csrf.len(), 64);
    assert_eq!(http(port, "GET", "/status", &[("Cookie", &cookie)], b"").0, 200);
    // What changes state needs the page's token: a forged form post has none.
    let forged = [("Cookie", cookie.as_str()), ("Content-Type", "application/x-www-form-urlencoded"), ("Origin", "http://evil.example")];
    let svg = std::fs::read(sample("one-field.svg")).unwrap();
    assert_eq!(http(port, "POST", "/jobs?name=x.svg", &forged, &svg).0, 403);
    assert_eq!(http(port, "POST", "/abort", &[("Cookie", &cookie)], b"").0, 403, "no token");
    assert_eq!(http(port, "POST", "/abort", &[("Cookie", &cookie), ("X-CSRF-Token", &csrf), ("Origin", "http://evil.example")], b"").0, 403, "another site");
    let (code, _, job) = http(port, "POST", "/jobs?name=x.svg", &[("Cookie", &cookie), ("X-CSRF-Token", &csrf), ("Origin", &format!("http://127.0.0.1:{port}"))], &svg);
    assert_eq!(code, 202, "{job}");
    // The API's header keeps working; the Unix socket needs neither.
    assert_eq!(http(port, "GET", "/jobs", &[("Authorization", &format!("Bearer {token}"))], b"").0, 200);
    assert_eq!(Api::new(&service.socket).ok(Method::GET, "/jobs", None).as_array().unwrap().len(), 1);
    // Logged out, the cookie opens nothing.
    assert_eq!(http(port, "POST", "/logout", &[("Cookie", &cookie), ("X-CSRF-Token", &csrf)], b"").0, 303);
    assert_eq!(http(port, "GET", "/status", &[("Cookie", &cookie)], b"").0, 401);
    drop(service);
}

#[test]
fn a_work_origin_places_new_jobs_and_framing_traces_their_bounds_with_the_laser_off() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let (_rig, service, api) = Rig::start(dir.path(), "ttyFRAME");
    // The controller says who it is, and the screen shows it.
    let controller = api.status()["machine"]["controller"].as_str().unwrap_or("").to_string();
    let flavour = std::fs::read_to_string(&_rig.config).unwrap();
    let expected = if flavour.contains("flavor = \"grblhal\"") { "1.1f." } else { "1.1h." };
    assert!(controller.starts_with(expected), "the simulator's `$I`: {controller:?}");
    // The tool's place, once jogged there, is the origin of the jobs submitted next.
    api.ok(Method::POST, "/jog", Some(serde_json::json!({ "block": "G90 X50 Y60 F6000" })));
    api.wait_status(Duration::from_secs(10), "at X50 Y60", |s| machine_state(s) == "Idle" && (position(s)[0] - 50.0).abs() < 1e-3 && (position(s)[1] - 60.0).abs() < 1e-3);
    let set = api.ok(Method::POST, "/origin", None);
    assert_eq!(set["origin"], serde_json::json!([50.0, 60.0]), "{set}");
    assert_eq!(api.status()["origin"], serde_json::json!([50.0, 60.0]));
    let id = api.submit(&sample("one-field.svg"));
    let job = api.wait_job(&id, "queued", Duration::from_secs(60));
    let bounds: Vec<f64> = job["bounds"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((bounds[0] - 50.0).abs() < 1e-3 && (bounds[1] - 60.0).abs() < 1e-3, "placed at the origin: {bounds:?}");
    // Outside the travel: refused by name; cleared: back to the config's placement.
    let (code, answer) = api.call(Method::POST, "/origin", Some(serde_json::json!({ "x": 1e6, "y": 0.0 })));
    assert!(code == 400 && answer["error"].as_str().unwrap().contains("outside the stage travel"), "{code} {answer}");
    api.ok(Method::DELETE, "/origin", None);
    assert!(api.status()["origin"].is_null());

    // Framing: round the job's bounds, laser off, ending at their first corner.
    api.ok(Method::POST, "/frame", Some(serde_json::json!({ "id": id })));
    api.wait_status(Duration::from_secs(5), "framing", |s| machine_state(s) == "Jog");
    let corners = std::cell::RefCell::new(Vec::<Vec<f64>>::new());
    let lit = std::cell::Cell::new(false);
    api.wait_status(Duration::from_secs(30), "the frame traced", |s| {
        lit.set(lit.get() || s["machine"]["laser"].as_f64().unwrap_or(0.0) > 0.0);
        corners.borrow_mut().push(position(s));
        machine_state(s) == "Idle"
    });
    assert!(!lit.get(), "the laser stays off");
    let seen = corners.into_inner();
    let (xs, ys): (Vec<f64>, Vec<f64>) = seen.iter().map(|p| (p[0], p[1])).unzip();
    let (x0, x1) = (xs.iter().copied().fold(f64::MAX, f64::min), xs.iter().copied().fold(f64::MIN, f64::max));
    let (y0, y1) = (ys.iter().copied().fold(f64::MAX, f64::min), ys.iter().copied().fold(f64::MIN, f64::max));
    assert!(x0 >= bounds[0] - 1e-3 && x1 <= bounds[2] + 1e-3 && y0 >= bounds[1] - 1e-3 && y1 <= bounds[3] + 1e-3, "inside the bounds: {x0} {y0} {x1} {y1}");
    assert!(x1 - x0 > 0.5 * (bounds[2] - bounds[0]) && y1 - y0 > 0.5 * (bounds[3] - bounds[1]), "round them: {x0} {y0} {x1} {y1} of {bounds:?}");
    let end = seen.last().unwrap();
    assert!((end[0] - bounds[0]).abs() < 1e-3 && (end[1] - bounds[1]).abs() < 1e-3, "back at the first corner: {end:?}");
    // Overrides need a running job; a bad step is refused by name.
    assert_eq!(api.call(Method::POST, "/override", Some(serde_json::json!({ "feed": "+10" }))).0, 409);
    let (code, answer) = api.call(Method::POST, "/override", Some(serde_json::json!({ "feed": "+50" })));
    assert!(code == 400 && answer["error"].as_str().unwrap().contains("override feed"), "{code} {answer}");
    assert!(service.terminate().success());
}
