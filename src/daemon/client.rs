//! `laserd ctl`: the API's client, over the Unix socket or TCP (HTTP/1.1 by hyper).

use std::path::Path;

use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::{Method, Request};
use hyper_util::rt::TokioIo;

use crate::error::{Error, Result};

/// An answer: the HTTP status and the body.
pub struct Answer {
    pub status: u16,
    pub body: Bytes,
}

impl Answer {
    /// The body as JSON, or the API's error message as an error.
    pub fn json(&self) -> Result<serde_json::Value> {
        let value: serde_json::Value = serde_json::from_slice(&self.body).map_err(|e| Error::Io(format!("the service answered {} with no JSON: {e}", self.status)))?;
        if (200..300).contains(&self.status) {
            Ok(value)
        } else {
            let message = value.get("error").and_then(|m| m.as_str()).unwrap_or("no message").to_string();
            Err(match self.status {
                404 => Error::NotFound(message.trim_start_matches("not found: ").to_string()),
                409 => Error::Conflict(message.trim_start_matches("conflict: ").to_string()),
                _ => Error::Io(format!("the service refused ({}): {message}", self.status)),
            })
        }
    }
}

/// Where the service answers: its Unix socket, or its TCP address with the
/// headers each request carries there (the bearer token or a login cookie).
#[derive(Debug, Clone)]
pub enum Endpoint {
    Unix(std::path::PathBuf),
    Tcp { addr: String, headers: Vec<(String, String)> },
}

impl Endpoint {
    fn name(&self) -> String {
        match self {
            Endpoint::Unix(socket) => socket.display().to_string(),
            Endpoint::Tcp { addr, .. } => addr.clone(),
        }
    }

    async fn connect(&self) -> Result<hyper::client::conn::http1::SendRequest<Full<Bytes>>> {
        async fn over<T: hyper::rt::Read + hyper::rt::Write + Unpin + Send + 'static>(io: T, name: &str) -> Result<hyper::client::conn::http1::SendRequest<Full<Bytes>>> {
            let (sender, connection) = hyper::client::conn::http1::handshake(io).await.map_err(|e| Error::Io(format!("{name}: {e}")))?;
            tokio::spawn(async move {
                let _ = connection.await;
            });
            Ok(sender)
        }
        match self {
            Endpoint::Unix(socket) => {
                let stream = tokio::net::UnixStream::connect(socket).await.map_err(|e| Error::Io(format!("{}: cannot connect to laserd: {e} (is `laserd serve` running?)", socket.display())))?;
                over(TokioIo::new(stream), &self.name()).await
            }
            Endpoint::Tcp { addr, .. } => {
                let stream = tokio::net::TcpStream::connect(addr).await.map_err(|e| Error::Io(format!("{addr}: cannot connect to laserd: {e}")))?;
                over(TokioIo::new(stream), addr).await
            }
        }
    }

    fn builder(&self, method: Method, path: &str) -> hyper::http::request::Builder {
        let mut builder = Request::builder().method(method).uri(path);
        match self {
            Endpoint::Unix(_) => builder = builder.header(hyper::header::HOST, "laserd"),
            Endpoint::Tcp { addr, headers } => {
                builder = builder.header(hyper::header::HOST, addr.as_str());
                for (k, v) in headers {
                    builder = builder.header(k.as_str(), v.as_str());
                }
            }
        }
        builder
    }

    /// One request; `body` with its content type.
    pub async fn request(&self, method: Method, path: &str, body: Option<(&str, Vec<u8>)>) -> Result<Answer> {
        let mut sender = self.connect().await?;
        let mut builder = self.builder(method, path);
        let bytes = match body {
            Some((kind, bytes)) => {
                builder = builder.header(hyper::header::CONTENT_TYPE, kind);
                bytes
            }
            None => Vec::new(),
        };
        let request = builder.body(Full::new(Bytes::from(bytes))).map_err(|e| Error::Io(e.to_string()))?;
        let response = sender.send_request(request).await.map_err(|e| Error::Io(format!("{}: {e}", self.name())))?;
        let status = response.status().as_u16();
        let body = response.into_body().collect().await.map_err(|e| Error::Io(e.to_string()))?.to_bytes();
        Ok(Answer { status, body })
    }

    /// Follows `GET /events`, calling `on_event(kind, json)` for each event
    /// until it returns false or the service closes the stream.
    pub async fn follow_events(&self, mut on_event: impl FnMut(&str, &serde_json::Value) -> bool) -> Result<()> {
        let mut sender = self.connect().await?;
        let request = self.builder(Method::GET, "/events").body(Full::new(Bytes::new())).map_err(|e| Error::Io(e.to_string()))?;
        let response = sender.send_request(request).await.map_err(|e| Error::Io(e.to_string()))?;
        let mut body = response.into_body();
        let mut pending = String::new();
        while let Some(frame) = body.frame().await {
            let frame = frame.map_err(|e| Error::Io(e.to_string()))?;
            let Some(data) = frame.data_ref() else { continue };
            pending.push_str(&String::from_utf8_lossy(data));
            // Events end with a blank line.
            while let Some(end) = pending.find("\n\n") {
                let block: String = pending.drain(..end + 2).collect();
                let mut kind = "message";
                let mut data = String::new();
                for line in block.lines() {
                    if let Some(k) = line.strip_prefix("event:") {
                        kind = k.trim();
                    } else if let Some(d) = line.strip_prefix("data:") {
                        data.push_str(d.trim_start());
                    }
                }
                if data.is_empty() {
                    continue;
                }
                let value: serde_json::Value = serde_json::from_str(&data).map_err(|e| Error::Io(format!("event {kind}: {e}")))?;
                if !on_event(kind, &value) {
                    return Ok(());
                }
            }
        }
        Ok(())
    }
}

/// One request on the Unix socket; `body` with its content type.
pub async fn request(socket: &Path, method: Method, path: &str, body: Option<(&str, Vec<u8>)>) -> Result<Answer> {
    Endpoint::Unix(socket.to_path_buf()).request(method, path, body).await
}

/// Follows `GET /events` on the Unix socket (see `Endpoint::follow_events`).
pub async fn follow_events(socket: &Path, on_event: impl FnMut(&str, &serde_json::Value) -> bool) -> Result<()> {
    Endpoint::Unix(socket.to_path_buf()).follow_events(on_event).await
}
