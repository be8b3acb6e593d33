//! The control API: HTTP/JSON, on a Unix socket (mode 0660: the service's
//! user and group) and, when configured, on TCP with a bearer token. The calls
//! are listed in docs/api.md.

use std::path::Path;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{Path as UrlPath, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::Deserialize;
use tokio::sync::oneshot;

use super::machine::Command;
use super::{Daemon, Event};
use crate::error::{Error, Result};

/// An error as the API answers it: a status code and `{"error": "..."}`.
pub struct ApiError(Error);

impl From<Error> for ApiError {
    fn from(e: Error) -> Self {
        ApiError(e)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let code = match &self.0 {
            Error::NotFound(_) => StatusCode::NOT_FOUND,
            Error::Conflict(_) => StatusCode::CONFLICT,
            Error::Forbidden(_) => StatusCode::FORBIDDEN,
            Error::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Error::Config(_) | Error::Import(_) | Error::Plan(_) => StatusCode::BAD_REQUEST,
            // The controller refused or failed what was asked of it.
            Error::Stream(_) => StatusCode::BAD_GATEWAY,
            _ => StatusCode::INTERNAL_SERVER_ERROR,
        };
        (code, Json(serde_json::json!({ "error": self.0.to_string() }))).into_response()
    }
}

type ApiResult<T> = std::result::Result<T, ApiError>;

pub fn router(daemon: Arc<Daemon>) -> Router {
    Router::new()
        .route("/status", get(status))
        .route("/jobs", get(list_jobs).post(submit))
        .route("/jobs/{id}", get(get_job).delete(remove_job))
        .route("/jobs/{id}/move", post(move_job))
        .route("/jobs/{id}/resume", post(resume_job))
        .route("/jobs/{id}/program", get(program))
        .route("/jobs/{id}/recording", get(recording))
        .route("/start", post(start))
        .route("/pause", post(|s| machine_call(s, Command::Pause)))
        .route("/resume", post(|s| machine_call(s, Command::Resume)))
        .route("/abort", post(|s| machine_call(s, Command::Abort)))
        .route("/home", post(|s| machine_call(s, Command::Home)))
        .route("/unlock", post(|s| machine_call(s, Command::Unlock)))
        .route("/jog", post(jog))
        .route("/frame", post(frame))
        .route("/origin", post(set_origin).delete(clear_origin))
        .route("/override", post(override_call))
        .route("/jobs/{id}/plot", get(plot))
        .route("/events", get(events))
        .fallback(|| async { ApiError(Error::NotFound("no such call (docs/api.md lists them)".into())) })
        // Uploads up to the largest job file; the same JSON errors everywhere.
        .layer(axum::extract::DefaultBodyLimit::max(daemon.machine.import.max_file_bytes()))
        .layer(axum::middleware::map_response(json_errors))
        .with_state(daemon)
}

/// Every error answers `{"error": …}`, also those axum gives itself (a body
/// over the limit, a missing content type, a body of the wrong shape).
async fn json_errors(response: Response) -> Response {
    let status = response.status();
    let is_json = response.headers().get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()).is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, 64 * 1024).await.map(|b| String::from_utf8_lossy(&b).trim().to_string()).unwrap_or_default();
    let why = if text.is_empty() { status.canonical_reason().unwrap_or("error").to_string() } else { text };
    let mut answer = (status, Json(serde_json::json!({ "error": why }))).into_response();
    // Keep what the client needs besides the body (e.g. WWW-Authenticate).
    for (name, value) in parts.headers.iter().filter(|(n, _)| *n != header::CONTENT_TYPE && *n != header::CONTENT_LENGTH) {
        answer.headers_mut().insert(name.clone(), value.clone());
    }
    answer
}

async fn status(State(d): State<Arc<Daemon>>) -> impl IntoResponse {
    Json(d.status.borrow().clone())
}

async fn list_jobs(State(d): State<Arc<Daemon>>) -> impl IntoResponse {
    Json(d.store().list())
}

async fn get_job(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>) -> ApiResult<impl IntoResponse> {
    let job = d.store().get(&id).cloned().ok_or_else(|| Error::NotFound(format!("no job {id}")))?;
    Ok(Json(job))
}

#[derive(Deserialize)]
struct SubmitQuery {
    /// The file's name, for an upload (its extension says how to read it).
    name: Option<String>,
    /// Plan and run an order that cuts after a part has fallen out.
    #[serde(default)]
    allow_precedence_violations: bool,
}

/// The JSON body of `POST /jobs` (submit by path). Public for the fuzz targets.
#[derive(Deserialize)]
pub struct SubmitPath {
    /// A file on the machine PC that the service may read.
    pub path: String,
    /// Plan and run an order that cuts after a part has fallen out.
    #[serde(default)]
    pub allow_precedence_violations: bool,
}

/// `POST /jobs?name=part.svg` with the file as the body, or `POST /jobs` with
/// `{"path": "/srv/jobs/part.svg"}`.
async fn submit(State(d): State<Arc<Daemon>>, Query(q): Query<SubmitQuery>, headers: HeaderMap, body: Bytes) -> ApiResult<impl IntoResponse> {
    let is_json = headers.get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()).is_some_and(|v| v.starts_with("application/json"));
    let job = if is_json {
        let SubmitPath { path, allow_precedence_violations } =
            serde_json::from_slice(&body).map_err(|e| Error::Config(format!("request body: expected {{\"path\": \"...\"}}: {e}")))?;
        let service = &d.machine.service;
        let (folders, max) = (service.job_folders.clone(), d.machine.import.max_file_bytes());
        let (name, source) = tokio::task::spawn_blocking(move || super::intake::read_by_path(&path, &folders, max)).await.map_err(|e| Error::Io(e.to_string()))??;
        d.submit(&name, &source, allow_precedence_violations)?
    } else {
        let name = q.name.ok_or_else(|| Error::Config("an upload needs ?name=<file name> (its extension says how to read it)".into()))?;
        if body.is_empty() {
            return Err(Error::Config(format!("{name}: empty upload")).into());
        }
        d.submit(&name, &body, q.allow_precedence_violations)?
    };
    Ok((StatusCode::ACCEPTED, Json(job)))
}

async fn remove_job(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>) -> ApiResult<impl IntoResponse> {
    // Blocking: it waits for the job's planning process to be gone.
    let removed = id.clone();
    tokio::task::spawn_blocking(move || d.remove(&removed)).await.map_err(|e| Error::Io(format!("job {id}: removal stopped: {e}")))??;
    Ok(Json(serde_json::json!({ "removed": id })))
}

/// The JSON body of `POST /jobs/{id}/move`. Public for the fuzz targets.
#[derive(Deserialize)]
pub struct MoveTo {
    /// 0 = next to run.
    pub position: usize,
}

async fn move_job(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>, Json(to): Json<MoveTo>) -> ApiResult<impl IntoResponse> {
    let mut store = d.store();
    store.reorder(&id, to.position)?;
    Ok(Json(store.order().to_vec()))
}

async fn file_of(d: &Daemon, id: &str, which: &str) -> ApiResult<Response> {
    let path = {
        let store = d.store();
        store.get(id).ok_or_else(|| Error::NotFound(format!("no job {id}")))?;
        match which {
            "program" => store.program_path(id),
            "plot" => store.plot_path(id),
            _ => store.recording_path(id),
        }
    };
    let bytes = tokio::fs::read(&path).await.map_err(|_| Error::NotFound(format!("job {id} has no {which} yet")))?;
    let (kind, extension, disposition) = match which {
        "program" => ("text/plain; charset=utf-8", "nc", "attachment"),
        // Shown in the page, never run: the picture is only drawn there.
        "plot" => ("image/svg+xml", "svg", "inline"),
        _ => ("application/octet-stream", "mcap", "attachment"),
    };
    let name = format!("{disposition}; filename=\"{id}.{extension}\"");
    let mut response = ([(header::CONTENT_TYPE, kind.to_string()), (header::CONTENT_DISPOSITION, name)], bytes).into_response();
    if which == "plot" {
        response.headers_mut().insert(header::CONTENT_SECURITY_POLICY, header::HeaderValue::from_static("default-src 'none'; style-src 'unsafe-inline'"));
    }
    Ok(response)
}

async fn plot(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>) -> ApiResult<Response> {
    file_of(&d, &id, "plot").await
}

async fn program(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>) -> ApiResult<Response> {
    file_of(&d, &id, "program").await
}

async fn recording(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>) -> ApiResult<Response> {
    file_of(&d, &id, "recording").await
}

/// Sends a command to the machine loop and waits for its answer.
async fn ask(d: &Daemon, command: impl FnOnce(oneshot::Sender<Result<String>>) -> Command) -> ApiResult<Json<serde_json::Value>> {
    let (tx, rx) = oneshot::channel();
    d.commands.send(command(tx)).map_err(|_| Error::Io("the machine loop has stopped".into()))?;
    let done = rx.await.map_err(|_| Error::Io("the machine loop dropped the request".into()))??;
    Ok(Json(serde_json::json!({ "done": done })))
}

async fn machine_call(State(d): State<Arc<Daemon>>, command: fn(oneshot::Sender<Result<String>>) -> Command) -> ApiResult<Json<serde_json::Value>> {
    ask(&d, command).await
}

/// The JSON body of `POST /start` (may be empty). Public for the fuzz targets.
#[derive(Deserialize, Default)]
pub struct StartBody {
    pub id: Option<String>,
}

async fn start(State(d): State<Arc<Daemon>>, body: Bytes) -> ApiResult<Json<serde_json::Value>> {
    let StartBody { id } = if body.is_empty() { StartBody::default() } else { serde_json::from_slice(&body).map_err(|e| Error::Config(format!("request body: expected {{\"id\": \"...\"}} or nothing: {e}")))? };
    ask(&d, |reply| Command::Start { id, reply }).await
}

/// `POST /frame`: the job's (or the next queued job's) bounds traced with the laser off.
async fn frame(State(d): State<Arc<Daemon>>, body: Bytes) -> ApiResult<Json<serde_json::Value>> {
    let StartBody { id } = if body.is_empty() { StartBody::default() } else { serde_json::from_slice(&body).map_err(|e| Error::Config(format!("request body: expected {{\"id\": \"...\"}} or nothing: {e}")))? };
    ask(&d, |reply| Command::Frame { id, reply }).await
}

/// The JSON body of `POST /origin` (may be empty: the tool's place now). Public for the fuzz targets.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct OriginBody {
    pub x: f64,
    pub y: f64,
}

/// `POST /origin`: jobs submitted from now on are placed with their
/// lower-left corner here (or at the tool's place now).
async fn set_origin(State(d): State<Arc<Daemon>>, body: Bytes) -> ApiResult<Json<serde_json::Value>> {
    let at = if body.is_empty() {
        let _ = ask(&d, Command::Origin).await?;
        d.status.borrow().origin.ok_or_else(|| Error::Io("the machine loop set no origin".into()))?
    } else {
        let OriginBody { x, y } = serde_json::from_slice(&body).map_err(|e| Error::Config(format!("request body: expected {{\"x\": …, \"y\": …}} or nothing: {e}")))?;
        [x, y]
    };
    let [w, h] = [d.machine.stage.travel_x, d.machine.stage.travel_y];
    if !(at.iter().all(|v| v.is_finite()) && (0.0..=w).contains(&at[0]) && (0.0..=h).contains(&at[1])) {
        return Err(Error::Config(format!("work origin ({}, {}) mm: outside the stage travel (X 0 to {w}, Y 0 to {h} mm)", at[0], at[1])).into());
    }
    d.status.send_modify(|s| s.origin = Some(at));
    Ok(Json(serde_json::json!({ "done": format!("jobs submitted from now on go with their lower-left corner at X {:.3} Y {:.3} mm", at[0], at[1]), "origin": at })))
}

async fn clear_origin(State(d): State<Arc<Daemon>>) -> Json<serde_json::Value> {
    d.status.send_modify(|s| s.origin = None);
    Json(serde_json::json!({ "done": "jobs submitted from now on are placed by [job] anchor" }))
}

/// The JSON body of `POST /override`: each field a step (`"+10"`, `"-10"`,
/// `"+1"`, `"-1"`) or `"100"` (back to the programmed value); rapids
/// `"100"`, `"50"` or `"25"`. Public for the fuzz targets.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct OverrideBody {
    pub feed: Option<String>,
    pub rapid: Option<String>,
    pub power: Option<String>,
}

impl OverrideBody {
    /// The realtime bytes that make the change.
    pub fn bytes(&self) -> Result<Vec<u8>> {
        use laserd_sim::wire::realtime::*;
        let mut bytes = Vec::new();
        let step = |what: &str, given: &str, [reset, plus10, minus10, plus1, minus1]: [u8; 5]| match given {
            "100" => Ok(reset),
            "+10" => Ok(plus10),
            "-10" => Ok(minus10),
            "+1" => Ok(plus1),
            "-1" => Ok(minus1),
            other => Err(Error::Config(format!("override {what} {other:?}: give \"+10\", \"-10\", \"+1\", \"-1\" or \"100\""))),
        };
        if let Some(feed) = &self.feed {
            bytes.push(step("feed", feed, [FEED_OVR_RESET, FEED_OVR_COARSE_PLUS, FEED_OVR_COARSE_MINUS, FEED_OVR_FINE_PLUS, FEED_OVR_FINE_MINUS])?);
        }
        if let Some(power) = &self.power {
            bytes.push(step("power", power, [SPINDLE_OVR_RESET, SPINDLE_OVR_COARSE_PLUS, SPINDLE_OVR_COARSE_MINUS, SPINDLE_OVR_FINE_PLUS, SPINDLE_OVR_FINE_MINUS])?);
        }
        if let Some(rapid) = &self.rapid {
            bytes.push(match rapid.as_str() {
                "100" => RAPID_OVR_RESET,
                "50" => RAPID_OVR_MEDIUM,
                "25" => RAPID_OVR_LOW,
                other => return Err(Error::Config(format!("override rapid {other:?}: give \"100\", \"50\" or \"25\""))),
            });
        }
        if bytes.is_empty() {
            return Err(Error::Config("override: give feed, rapid or power".into()));
        }
        Ok(bytes)
    }
}

async fn override_call(State(d): State<Arc<Daemon>>, Json(body): Json<OverrideBody>) -> ApiResult<Json<serde_json::Value>> {
    let bytes = body.bytes()?;
    ask(&d, |reply| Command::Override { bytes, reply }).await
}

/// The JSON body of `POST /jobs/{id}/resume`. Public for the fuzz targets.
#[derive(Deserialize)]
pub struct ResumeBody {
    /// The operator's explicit word: resuming starts motion.
    #[serde(default)]
    pub confirm: bool,
    /// Line to resume at (default: after the last executed line).
    pub from: Option<usize>,
}

/// Resumes an interrupted job: its modal state and position are restored,
/// then it runs on from the line. Only with `"confirm": true`.
async fn resume_job(State(d): State<Arc<Daemon>>, UrlPath(id): UrlPath<String>, Json(body): Json<ResumeBody>) -> ApiResult<Json<serde_json::Value>> {
    let job = d.store().get(&id).cloned().ok_or_else(|| Error::NotFound(format!("no job {id}")))?;
    let from = job.resume_line(body.from)?;
    if !body.confirm {
        return Err(Error::Conflict(format!("resuming job {id} moves the machine to line {from} of {} and runs on from there: repeat with {{\"confirm\": true}}", job.lines_total)).into());
    }
    ask(&d, |reply| Command::ResumeJob { id, from: Some(from), reply }).await
}

/// The JSON body of `POST /jog`. Public for the fuzz targets.
#[derive(Deserialize)]
pub struct JogBody {
    /// A jog block, e.g. `G91 X10 F600` (sent as `$J=G91 X10 F600`), or
    /// axis words alone (`X10`: G91 and `[service] jog_feed` are added).
    pub block: String,
}

async fn jog(State(d): State<Arc<Daemon>>, Json(body): Json<JogBody>) -> ApiResult<Json<serde_json::Value>> {
    let block = body.block.trim().to_string();
    if block.is_empty() || block.len() > 70 || !block.chars().all(|c| c.is_ascii_alphanumeric() || " .-".contains(c)) {
        return Err(Error::Config(format!("jog block {block:?}: letters, numbers, '.', '-' and spaces only, at most 70")).into());
    }
    // Axis words alone are a relative jog at the configured feed.
    let block = crate::stream::jog_block(&block, d.machine.service.jog_feed);
    ask(&d, |reply| Command::Jog { block, reply }).await
}

/// The shortest time between two status events to one client.
const STATUS_EVERY: std::time::Duration = std::time::Duration::from_millis(50);

/// Server-sent events: the status now, then every job change and the
/// status as it changes, at most every `STATUS_EVERY`.
async fn events(State(d): State<Arc<Daemon>>) -> impl IntoResponse {
    let first = Event::Status(d.status.borrow().clone());
    let events = d.events.subscribe();
    let mut status = d.status.subscribe();
    status.mark_unchanged();
    // The status changes with every line sent: each client gets it at most
    // every STATUS_EVERY (the latest then), so open screens cost the service
    // little however fast the job streams.
    let sent = tokio::time::Instant::now();
    let stream = futures_util::stream::unfold((Some(first), events, status, sent), |(first, mut events, mut status, sent)| async move {
        if let Some(first) = first {
            return Some((first, (None, events, status, sent)));
        }
        let next_status = sent + STATUS_EVERY;
        loop {
            tokio::select! {
                e = events.recv() => match e {
                    Ok(e) => return Some((e, (None, events, status, sent))),
                    // A slow reader missed some: it gets the next ones.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(_) => return None,
                },
                changed = async { tokio::time::sleep_until(next_status).await; status.changed().await } => {
                    if changed.is_err() {
                        return None;
                    }
                    let now = Event::Status(status.borrow_and_update().clone());
                    return Some((now, (None, events, status, tokio::time::Instant::now())));
                }
            }
        }
    });
    let stream = futures_util::StreamExt::map(stream, |e| {
        let kind = match &e {
            Event::Status(_) => "status",
            Event::Job(_) => "job",
        };
        SseEvent::default().event(kind).json_data(&e).map_err(|e| std::io::Error::other(e.to_string()))
    });
    Sse::new(stream).keep_alive(KeepAlive::default())
}

/// Binds the Unix socket (replacing a stale one) with mode 0660.
pub fn bind_unix(path: &Path) -> Result<tokio::net::UnixListener> {
    use std::os::unix::fs::PermissionsExt;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::Io(format!("{}: cannot create: {e}", dir.display())))?;
    }
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        // Only a socket is ever replaced: a file of any other kind there is
        // a mistake in the path, not something to delete.
        if !std::os::unix::fs::FileTypeExt::is_socket(&meta.file_type()) {
            return Err(Error::Io(format!("{}: exists and is not a socket; give the API another path", path.display())));
        }
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            return Err(Error::Io(format!("{}: another laserd is serving there", path.display())));
        }
        std::fs::remove_file(path).map_err(|e| Error::Io(format!("{}: cannot remove the stale socket: {e}", path.display())))?;
    }
    let listener = tokio::net::UnixListener::bind(path).map_err(|e| Error::Io(format!("{}: cannot listen: {e}", path.display())))?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660)).map_err(|e| Error::Io(format!("{}: cannot set its mode: {e}", path.display())))?;
    Ok(listener)
}

pub async fn serve_unix(listener: tokio::net::UnixListener, daemon: Arc<Daemon>) -> Result<()> {
    axum::serve(listener, router(daemon)).await.map_err(|e| Error::Io(format!("API on the Unix socket: {e}")))
}

/// TCP: every request carries the bearer token, or comes from a logged-in
/// page (`web.rs`); the pages themselves are served here too.
pub async fn serve_tcp(listener: tokio::net::TcpListener, daemon: Arc<Daemon>, token: String) -> Result<()> {
    let gate = super::web::Gate::new(token);
    let app = super::web::routes(gate.clone()).merge(router(daemon)).layer(axum::middleware::from_fn_with_state(gate, super::web::check));
    axum::serve(listener, app).await.map_err(|e| Error::Io(format!("API on TCP: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn only_a_stale_socket_is_replaced_never_another_file() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("notes.txt");
        std::fs::write(&file, b"keep me").unwrap();
        let err = bind_unix(&file).expect_err("a regular file is not a socket").to_string();
        assert!(err.contains("not a socket"), "{err}");
        assert_eq!(std::fs::read(&file).unwrap(), b"keep me");
        // A socket nobody serves on any more is replaced.
        let stale = dir.path().join("api.sock");
        drop(std::os::unix::net::UnixListener::bind(&stale).unwrap());
        assert!(bind_unix(&stale).is_ok());
    }
}
