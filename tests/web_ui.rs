//! The operator's screen in a real browser: Debian's chromium (put in place
//! by `.ci/run` before the tests), driven through the DevTools protocol, against `laserd serve`
//! on TCP and `laserd sim --pty`, all as child processes in real time. The
//! screenshots are kept in the target folder and read back for what they
//! must show.

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use chromiumoxide::browser::{Browser, BrowserConfig};
use chromiumoxide::cdp::browser_protocol::dom::SetFileInputFilesParams;
use chromiumoxide::Page;
use common::service::*;
use common::SimProcess;
use futures_util::StreamExt;
use serde_json::Value;

const CHROMIUM: &str = "/usr/bin/chromium";

/// The browser and the runtime its connection lives on.
struct Screen {
    rt: tokio::runtime::Runtime,
    browser: Option<Browser>,
    page: Page,
    shots: PathBuf,
}

impl Screen {
    fn open(url: &str, profile: &Path, shots: PathBuf) -> Screen {
        assert!(Path::new(CHROMIUM).exists(), "this test needs Debian's chromium at {CHROMIUM}; `.ci/run` puts it there before the tests run");
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
        let config = BrowserConfig::builder()
            .chrome_executable(CHROMIUM)
            .new_headless_mode()
            .no_sandbox()
            .user_data_dir(profile)
            .window_size(1400, 1100)
            .viewport(None)
            // A closed network: nothing but the page itself.
            .args(["--disable-gpu", "--disable-quic", "--no-first-run", "--disable-component-update", "--disable-sync", "--disable-background-networking"])
            .build()
            .unwrap();
        let (browser, page) = rt.block_on(async {
            let (browser, mut handler) = Browser::launch(config).await.expect("chromium starts");
            tokio::spawn(async move { while let Some(Ok(_)) = handler.next().await {} });
            let page = browser.new_page(url).await.expect("the page opens");
            (browser, page)
        });
        std::fs::create_dir_all(&shots).unwrap();
        Screen { rt, browser: Some(browser), page, shots }
    }

    fn eval<T: serde::de::DeserializeOwned>(&self, js: &str) -> T {
        self.rt.block_on(async { self.page.evaluate(js).await.unwrap_or_else(|e| panic!("{js}: {e}")).into_value::<T>().unwrap_or_else(|e| panic!("{js}: {e}")) })
    }

    /// Waits (up to `limit`) until `js` is true in the page.
    fn wait(&self, js: &str, limit: Duration, what: &str) {
        let started = Instant::now();
        loop {
            let ok = self.rt.block_on(async { self.page.evaluate(js).await.ok().and_then(|v| v.into_value::<bool>().ok()) });
            if ok == Some(true) {
                return;
            }
            if started.elapsed() > limit {
                let body: String = self.eval("document.body.innerText");
                self.shot("timed-out");
                panic!("waited {limit:?} for {what} ({js}); the page says:\n{body}");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn click(&self, selector: &str) {
        self.rt.block_on(async {
            let element = self.page.find_element(selector).await.unwrap_or_else(|e| panic!("{selector}: {e}"));
            element.click().await.unwrap_or_else(|e| panic!("{selector}: {e}"));
        });
    }

    fn type_into(&self, selector: &str, text: &str) {
        self.rt.block_on(async {
            let element = self.page.find_element(selector).await.unwrap_or_else(|e| panic!("{selector}: {e}"));
            element.click().await.unwrap().type_str(text).await.unwrap();
        });
    }

    /// Chooses `file` in the page's file input, as the operator's file dialog would.
    fn upload(&self, file: &Path) {
        self.rt.block_on(async {
            let input = self.page.find_element("#upload").await.unwrap();
            let choose = SetFileInputFilesParams::builder().files(vec![file.to_str().unwrap().to_string()]).backend_node_id(input.backend_node_id).build().unwrap();
            self.page.execute(choose).await.expect("the file is chosen");
        });
    }

    /// A screenshot of the whole page, kept as `name.png`, and one of `selector`.
    fn shot(&self, name: &str) -> PathBuf {
        let path = self.shots.join(format!("{name}.png"));
        let png = self.rt.block_on(async { self.page.screenshot(chromiumoxide::page::ScreenshotParams::builder().full_page(true).build()).await.unwrap() });
        std::fs::write(&path, &png).unwrap();
        path
    }

    /// The whole page's screenshot cut to `selector`'s box: RGB rows.
    fn element_shot(&self, selector: &str) -> Picture {
        let png = self.rt.block_on(async { self.page.screenshot(chromiumoxide::page::ScreenshotParams::builder().full_page(true).build()).await.unwrap() });
        let js = format!("(() => {{ const r = document.querySelector('{selector}').getBoundingClientRect(); return [r.left + window.scrollX, r.top + window.scrollY, r.width, r.height].map(Math.round); }})()");
        let [x, y, w, h]: [u32; 4] = self.eval(&js);
        let page = Picture::decode(&png);
        let rows = (y..(y + h).min(page.height)).map(|row| page.rgb[(row * page.width + x) as usize * 3..(row * page.width + (x + w).min(page.width)) as usize * 3].to_vec()).collect::<Vec<_>>().concat();
        Picture { width: w.min(page.width - x), height: h.min(page.height - y), rgb: rows }
    }
}

/// A screenshot's pixels, RGB.
struct Picture {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Picture {
    fn decode(png_bytes: &[u8]) -> Picture {
        let mut decoder = png::Decoder::new(std::io::Cursor::new(png_bytes));
        decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = decoder.read_info().unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut pixels).unwrap();
        let channels = info.color_type.samples();
        let rgb = pixels[..info.buffer_size()].chunks_exact(channels).flat_map(|p| [p[0], p[1], p[2]]).collect();
        Picture { width: info.width, height: info.height, rgb }
    }

    /// The share of pixels within `tolerance` of `rgb`.
    fn share_of(&self, rgb: [u8; 3], tolerance: i32) -> f64 {
        let near = self.rgb.chunks_exact(3).filter(|p| (0..3).all(|i| (p[i] as i32 - rgb[i] as i32).abs() <= tolerance)).count();
        near as f64 / (self.width as f64 * self.height as f64).max(1.0)
    }

    /// The share of pixels that are neither white nor light grey: drawing.
    fn drawn_share(&self) -> f64 {
        1.0 - self.share_of([255, 255, 255], 12) - self.share_of([229, 231, 235], 12)
    }
}

impl Drop for Screen {
    fn drop(&mut self) {
        if let Some(mut browser) = self.browser.take() {
            self.rt.block_on(async {
                let _ = browser.close().await;
                let _ = browser.wait().await;
            });
        }
    }
}

#[test]
fn an_operator_logs_in_uploads_frames_runs_pauses_resumes_and_aborts_in_a_real_browser() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyUI");
    let sim = SimProcess::start(&tty, &["--pty"]);
    // Reports with `Bf:`: the executed line is known while a job runs.
    write_settings(&tty, &["$10=3"]);
    let port = 20000 + (std::process::id() % 20000) as u16 + 11;
    let token = "0123456789abcdef-browser";
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, token).unwrap();
    let config = config_with_service(dir.path(), &tty, &format!("tcp = \"127.0.0.1:{port}\"\ntoken_file = {:?}", token_file.to_str().unwrap()));
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
    let shots = Path::new(env!("CARGO_TARGET_TMPDIR")).join("web_ui");
    let screen = Screen::open(&format!("http://127.0.0.1:{port}/"), &dir.path().join("profile"), shots);

    // Log in: the login form, then the machine's screen.
    screen.wait("document.getElementById('token') !== null", Duration::from_secs(10), "the login form");
    screen.type_into("#token", token);
    screen.click("#login-button");
    screen.wait("document.getElementById('state') !== null && document.getElementById('state').textContent === 'Idle'", Duration::from_secs(10), "the machine Idle on the screen");

    screen.wait("document.getElementById('controller').textContent.startsWith('firmware 1.1')", Duration::from_secs(5), "the controller's identity");
    // Upload a job: it is planned, its picture and planned time shown.
    screen.upload(&sample("one-field.svg"));
    screen.wait("(document.getElementById('job-j000001') || {innerText: ''}).innerText.includes('queued')", Duration::from_secs(60), "job 1 queued");
    screen.wait("document.getElementById('plot').complete && document.getElementById('plot').naturalWidth > 0", Duration::from_secs(10), "job 1's picture");
    let job: Value = api.job("j000001");
    let row: String = screen.eval("document.getElementById('job-j000001').innerText");
    assert!(row.contains("one-field.svg") && row.contains(" s"), "the queue shows the name and planned time: {row}");
    let figures: String = screen.eval("document.getElementById('selected-figures').innerText");
    assert!(figures.contains("Geometries") && figures.contains(&job["figures"]["geometries"].to_string()), "{figures}");
    let queued_shot = Picture::decode(&std::fs::read(screen.shot("1-queued")).unwrap());
    assert!(queued_shot.share_of([4, 120, 87], 8) > 0.0, "the Idle badge is in the screenshot");
    assert!(screen.element_shot("#picture").drawn_share() > 0.002, "the picture has a drawing in it");

    // Frame it: the machine traces the job's bounds, laser off, and ends at their corner.
    let bounds: Vec<f64> = job["bounds"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    screen.click("#frame-j000001");
    api.wait_status(Duration::from_secs(5), "framing", |s| machine_state(s) == "Jog");
    let lit = std::cell::Cell::new(false);
    let framed = api.wait_status(Duration::from_secs(30), "the frame traced", |s| {
        lit.set(lit.get() || s["machine"]["laser"].as_f64().unwrap_or(0.0) > 0.0);
        machine_state(s) == "Idle"
    });
    assert!(!lit.get(), "the laser stays off while framing");
    let tcp: Vec<f64> = framed["machine"]["tcp"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((tcp[0] - bounds[0]).abs() < 0.01 && (tcp[1] - bounds[1]).abs() < 0.01, "back at the frame's corner {bounds:?}: {framed}");

    // Start it: progress to 100 %, then the job in the history.
    screen.click("#start-j000001");
    screen.wait("(document.getElementById('history-j000001') || {innerText: ''}).innerText.includes('completed')", Duration::from_secs(30), "job 1 in the history");
    screen.wait("document.getElementById('percent-time').textContent.startsWith('100.0')", Duration::from_secs(5), "progress at 100 %");
    let history: String = screen.eval("document.getElementById('history-j000001').innerText");
    assert!(history.contains("recording"), "its recording to download: {history}");
    screen.shot("2-completed");

    // Another, paused, resumed and aborted part way.
    screen.upload(&sample("marking-300.svg"));
    screen.wait("(document.getElementById('job-j000002') || {innerText: ''}).innerText.includes('queued')", Duration::from_secs(60), "job 2 queued");
    screen.click("#start-j000002");
    api.wait_status(Duration::from_secs(20), "job 2 a fifth done", |s| s["job"]["time_percent"].as_f64().unwrap_or(0.0) > 20.0);
    screen.wait("document.getElementById('eta').textContent.includes(' s')", Duration::from_secs(5), "the time left");
    screen.click("#pause");
    api.wait_status(Duration::from_secs(5), "held", |s| machine_state(s) == "Hold:0");
    screen.wait("document.getElementById('state').textContent === 'Hold:0'", Duration::from_secs(5), "the hold on the screen");
    std::thread::sleep(Duration::from_millis(300));
    let a = api.status();
    std::thread::sleep(Duration::from_millis(600));
    let b = api.status();
    assert_eq!(a["machine"]["position"], b["machine"]["position"], "the position holds");
    assert_eq!(b["machine"]["laser"].as_f64(), Some(0.0), "laser off in the hold: {b}");
    let held_shot = Picture::decode(&std::fs::read(screen.shot("3-held")).unwrap());
    assert!(held_shot.share_of([180, 83, 9], 8) > 0.0, "the amber Hold badge is in the screenshot");
    assert!(screen.element_shot("#picture").share_of([192, 38, 211], 10) > 0.0001, "the tool is drawn over the plan");
    screen.click("#resume");
    api.wait_status(Duration::from_secs(5), "running again", |s| machine_state(s) == "Run");
    api.wait_status(Duration::from_secs(20), "job 2 half done", |s| s["job"]["time_percent"].as_f64().unwrap_or(0.0) > 50.0);
    screen.click("#abort");
    let aborted = api.wait_job("j000002", "aborted", Duration::from_secs(10));
    let last = aborted["last_executed_line"].as_u64().unwrap();
    assert!(last > 0 && last < aborted["lines_total"].as_u64().unwrap(), "stopped part way: {aborted}");
    let idle = api.wait_status(Duration::from_secs(5), "Idle after the abort", |s| machine_state(s) == "Idle" && s["job"].is_null());
    assert_eq!(idle["machine"]["laser"].as_f64(), Some(0.0));
    screen.wait("(document.getElementById('history-j000002') || {innerText: ''}).innerText.includes('aborted')", Duration::from_secs(5), "job 2 aborted in the history");
    let ended = Picture::decode(&std::fs::read(screen.shot("4-aborted")).unwrap());
    assert!(ended.share_of([4, 120, 87], 8) > 0.0, "Idle again on the screen");
    drop(screen);
    assert!(service.terminate().success());
    sim.terminate();
}
