//! The operator's screen on the TCP API: the pages under `web/` (embedded
//! in the binary), a login that turns the bearer token into a session
//! cookie (HttpOnly, SameSite=Strict), and the checks every TCP request
//! passes: the bearer header, or a session cookie plus, for anything that
//! changes state, the session's CSRF token in `X-CSRF-Token`. A browser
//! never sends that header cross-site, so a forged form post is refused.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::extract::{Path as UrlPath, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};

/// The page files, in the binary (also in debug builds: no file is read at run time).
#[derive(rust_embed::RustEmbed)]
#[folder = "web/"]
struct Assets;

/// The session cookie's name.
const COOKIE: &str = "laserd_session";
/// How long a login lasts.
const SESSION_LIFE: Duration = Duration::from_secs(12 * 3600);
/// Sessions kept at once; a new login beyond it ends the oldest.
const MAX_SESSIONS: usize = 64;
/// A wrong token waits this long: guessing stays slow.
const WRONG_TOKEN_DELAY: Duration = Duration::from_millis(300);

/// The page a request without a valid login gets (with 401).
const LOGIN_PAGE: &str = include_str!("../../web/login.html");

struct Session {
    csrf: String,
    until: Instant,
}

/// The logged-in browsers, by their cookie's value.
#[derive(Default)]
pub struct Sessions {
    by_id: Mutex<HashMap<String, Session>>,
}

impl Sessions {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Session>> {
        self.by_id.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A new session: its cookie value and its CSRF token.
    fn open(&self) -> (String, String) {
        let (id, csrf) = (random_hex(), random_hex());
        let mut sessions = self.lock();
        let now = Instant::now();
        sessions.retain(|_, s| s.until > now);
        if sessions.len() >= MAX_SESSIONS {
            if let Some(oldest) = sessions.iter().min_by_key(|(_, s)| s.until).map(|(k, _)| k.clone()) {
                sessions.remove(&oldest);
            }
        }
        sessions.insert(id.clone(), Session { csrf: csrf.clone(), until: now + SESSION_LIFE });
        (id, csrf)
    }

    /// The CSRF token of the session `id`, while it lasts.
    fn csrf(&self, id: &str) -> Option<String> {
        let sessions = self.lock();
        sessions.iter().find(|(k, s)| same(k.as_bytes(), id.as_bytes()) && s.until > Instant::now()).map(|(_, s)| s.csrf.clone())
    }

    fn close(&self, id: &str) {
        self.lock().remove(id);
    }
}

/// 256 random bits from the OS-seeded generator, as hex.
fn random_hex() -> String {
    let bytes: [u8; 32] = rand::random();
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Compares without stopping at the first difference (no timing hint).
pub fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// What the TCP side needs to check a request.
pub struct Gate {
    token: String,
    sessions: Sessions,
}

impl Gate {
    pub fn new(token: String) -> Arc<Gate> {
        Arc::new(Gate { token, sessions: Sessions::default() })
    }
}

/// The session cookie's value in a request, if any.
fn session_cookie(headers: &HeaderMap) -> Option<String> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|pair| pair.trim().split_once('='))
        .find(|(name, _)| *name == COOKIE)
        .map(|(_, value)| value.to_string())
}

/// A request a browser sent from another site: its `Sec-Fetch-Site` says
/// so, or its `Origin` is not the host it was sent to.
fn cross_site(headers: &HeaderMap) -> bool {
    let text = |name: &str| headers.get(name).and_then(|v| v.to_str().ok());
    if text("sec-fetch-site").is_some_and(|s| s == "cross-site" || s == "same-site") {
        return true;
    }
    match (text("origin"), text("host")) {
        (Some(origin), Some(host)) => origin.split_once("://").map(|(_, rest)| rest) != Some(host),
        (Some(_), None) => true,
        _ => false,
    }
}

fn changes_state(method: &Method) -> bool {
    !matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS)
}

fn refused(code: StatusCode, why: &str) -> Response {
    (code, Json(serde_json::json!({ "error": why }))).into_response()
}

/// 401: the login page for a browser asking for a page, JSON for anything else.
fn unauthorized(headers: &HeaderMap, method: &Method, wrong: bool) -> Response {
    let wants_page = *method == Method::GET && headers.get(header::ACCEPT).and_then(|v| v.to_str().ok()).is_some_and(|a| a.contains("text/html"));
    let mut response = if wants_page {
        let note = if wrong { "That token is not this machine's." } else { "" };
        (StatusCode::UNAUTHORIZED, [(header::CONTENT_TYPE, "text/html; charset=utf-8")], LOGIN_PAGE.replace("{{note}}", note)).into_response()
    } else {
        refused(StatusCode::UNAUTHORIZED, "a bearer token or a login is required")
    };
    response.headers_mut().insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    response
}

/// Every TCP request: the bearer token, or a live session (plus its CSRF
/// token for what changes state); the login form itself only same-site.
pub async fn check(State(gate): State<Arc<Gate>>, request: Request, next: Next) -> Response {
    let (headers, method, path) = (request.headers(), request.method(), request.uri().path());
    if path == "/login" && *method == Method::POST {
        if cross_site(headers) {
            return refused(StatusCode::FORBIDDEN, "a login from another site is refused");
        }
        return next.run(request).await;
    }
    if let Some(given) = headers.get(header::AUTHORIZATION).and_then(|v| v.to_str().ok()).and_then(|v| v.strip_prefix("Bearer ")) {
        if same(given.as_bytes(), gate.token.as_bytes()) {
            return next.run(request).await;
        }
        tokio::time::sleep(WRONG_TOKEN_DELAY).await;
        return unauthorized(headers, method, true);
    }
    let Some(csrf) = session_cookie(headers).and_then(|id| gate.sessions.csrf(&id)) else {
        return unauthorized(headers, method, false);
    };
    if changes_state(method) {
        let given = headers.get("x-csrf-token").and_then(|v| v.to_str().ok()).unwrap_or("");
        if cross_site(headers) || !same(given.as_bytes(), csrf.as_bytes()) {
            return refused(StatusCode::FORBIDDEN, "refused: a request that changes the machine's state needs the page's X-CSRF-Token (a cross-site request never has it)");
        }
    }
    next.run(request).await
}

/// The pages, login and logout (TCP only; behind `check`).
pub fn routes(gate: Arc<Gate>) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/ui/{file}", get(asset))
        .route("/login", get(|| async { Redirect303("/") }).post(login))
        .route("/logout", post(logout))
        .with_state(gate)
}

struct Redirect303(&'static str);

impl IntoResponse for Redirect303 {
    fn into_response(self) -> Response {
        (StatusCode::SEE_OTHER, [(header::LOCATION, self.0)]).into_response()
    }
}

/// Headers every page carries: nothing but its own files runs in it, and
/// no other site may frame it.
fn page_headers(response: &mut Response) {
    let h = response.headers_mut();
    h.insert(header::CONTENT_SECURITY_POLICY, HeaderValue::from_static("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; connect-src 'self'; frame-ancestors 'none'; form-action 'self'; base-uri 'none'"));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
}

/// The main page, with the session's CSRF token for its scripts to send.
async fn index(State(gate): State<Arc<Gate>>, headers: HeaderMap) -> Response {
    // A bearer-token client gets a token of its own session.
    let csrf = match session_cookie(&headers).and_then(|id| gate.sessions.csrf(&id)) {
        Some(csrf) => csrf,
        None => return unauthorized(&headers, &Method::GET, false),
    };
    let page = Assets::get("index.html").map(|f| String::from_utf8_lossy(&f.data).into_owned()).unwrap_or_default();
    let mut response = ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], page.replace("{{csrf}}", &csrf)).into_response();
    page_headers(&mut response);
    response
}

async fn asset(UrlPath(file): UrlPath<String>) -> Response {
    let Some(found) = (file != "index.html").then(|| Assets::get(&file)).flatten() else {
        return refused(StatusCode::NOT_FOUND, "no such page file");
    };
    let kind = match file.rsplit('.').next() {
        Some("js") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("svg") => "image/svg+xml",
        Some("html") => "text/html; charset=utf-8",
        _ => "application/octet-stream",
    };
    let mut response = ([(header::CONTENT_TYPE, kind)], found.data.into_owned()).into_response();
    page_headers(&mut response);
    response
}

#[derive(serde::Deserialize)]
struct LoginForm {
    token: String,
}

/// The login form: the right token opens a session (its cookie HttpOnly,
/// SameSite=Strict) and goes to the main page; a wrong one, 401 after a wait.
async fn login(State(gate): State<Arc<Gate>>, headers: HeaderMap, form: axum::Form<LoginForm>) -> Response {
    if !same(form.token.trim().as_bytes(), gate.token.as_bytes()) {
        tokio::time::sleep(WRONG_TOKEN_DELAY).await;
        let mut page_request = headers.clone();
        page_request.insert(header::ACCEPT, HeaderValue::from_static("text/html"));
        return unauthorized(&page_request, &Method::GET, true);
    }
    let (id, _) = gate.sessions.open();
    let cookie = format!("{COOKIE}={id}; HttpOnly; SameSite=Strict; Path=/; Max-Age={}", SESSION_LIFE.as_secs());
    let mut response = Redirect303("/").into_response();
    if let Ok(value) = HeaderValue::from_str(&cookie) {
        response.headers_mut().insert(header::SET_COOKIE, value);
    }
    response
}

async fn logout(State(gate): State<Arc<Gate>>, headers: HeaderMap) -> Response {
    if let Some(id) = session_cookie(&headers) {
        gate.sessions.close(&id);
    }
    let mut response = Redirect303("/").into_response();
    response.headers_mut().insert(header::SET_COOKIE, HeaderValue::from_static("laserd_session=; HttpOnly; SameSite=Strict; Path=/; Max-Age=0"));
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cross_site_request_is_known_by_its_origin_or_fetch_site() {
        let with = |pairs: &[(&'static str, &'static str)]| {
            let mut h = HeaderMap::new();
            for (k, v) in pairs {
                h.insert(*k, HeaderValue::from_static(v));
            }
            h
        };
        assert!(!cross_site(&with(&[("host", "127.0.0.1:7125")])));
        assert!(!cross_site(&with(&[("host", "127.0.0.1:7125"), ("origin", "http://127.0.0.1:7125"), ("sec-fetch-site", "same-origin")])));
        assert!(cross_site(&with(&[("host", "127.0.0.1:7125"), ("origin", "http://evil.example")])));
        assert!(cross_site(&with(&[("host", "127.0.0.1:7125"), ("sec-fetch-site", "cross-site")])));
        assert!(cross_site(&with(&[("host", "127.0.0.1:7125"), ("origin", "null")])));
    }

    #[test]
    fn sessions_are_unguessable_and_bounded() {
        let sessions = Sessions::default();
        let (a, csrf) = sessions.open();
        assert_eq!(a.len(), 64);
        assert_ne!(a, csrf);
        assert_eq!(sessions.csrf(&a), Some(csrf));
        assert_eq!(sessions.csrf(&a[..63]), None);
        for _ in 0..MAX_SESSIONS + 5 {
            sessions.open();
        }
        assert_eq!(sessions.lock().len(), MAX_SESSIONS);
        sessions.close(&a);
        assert_eq!(sessions.csrf(&a), None);
    }
}
