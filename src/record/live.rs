//! The recording's topics live (`[service] foxglove`): a Foxglove WebSocket
//! server (the `foxglove` SDK) that every `Recorder` carrying it also writes
//! to, on the same topic, with the same JSON Schema and JSON, stamped with the
//! wall-clock time it was written, so the Foxglove app shows the machine as it
//! runs.
//!
//! Writing never waits for a client: a message is copied into each
//! subscribed client's queue (the SDK's, 1024 messages); a client that reads
//! too slowly loses the oldest. Nothing is serialised for a topic no client
//! subscribed to.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use schemars::JsonSchema;

use crate::error::{Error, Result};

/// A topic's JSON Schema as the recordings carry it: its name and bytes.
pub type SchemaOf = fn() -> (String, Vec<u8>);

/// The JSON Schema of `T`, as recordings and the live server give it.
pub fn schema_of<T: JsonSchema>() -> (String, Vec<u8>) {
    (T::schema_name().to_string(), serde_json::to_vec(&schemars::schema_for!(T)).unwrap_or_default())
}

/// The live server and its channels, one per topic (made on first use).
pub struct Live {
    context: Arc<Context>,
    channels: Mutex<HashMap<&'static str, Arc<RawChannel>>>,
    /// Held for the service's life (the server runs while it is).
    _server: WebSocketServerHandle,
    port: u16,
}

impl Live {
    /// Starts the server at `addr` on the current tokio runtime.
    pub async fn start(addr: SocketAddr) -> Result<Arc<Live>> {
        // A context of its own: nothing else in the process logs to it.
        let context = Context::new();
        let server = WebSocketServer::new()
            .name("laserd")
            .context(&context)
            .bind(addr.ip().to_string(), addr.port())
            .start()
            .await
            .map_err(|e| Error::Io(format!("[service] foxglove = \"{addr}\": cannot listen: {e}")))?;
        let port = server.port();
        Ok(Arc::new(Live { context, channels: Mutex::new(HashMap::new()), _server: server, port }))
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Advertises `topic` before anything is written on it, so a client sees
    /// it from the start.
    pub fn advertise<T: JsonSchema>(&self, topic: &'static str) {
        self.channel(topic, schema_of::<T>);
    }

    /// `topic`'s channel, made with its schema the first time.
    pub(super) fn channel(&self, topic: &'static str, schema: SchemaOf) -> Option<Arc<RawChannel>> {
        let mut channels = self.channels.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(channel) = channels.get(topic) {
            return Some(channel.clone());
        }
        let (name, data) = schema();
        let built = ChannelBuilder::new(topic).context(&self.context).message_encoding("json").schema(Schema::new(name, "jsonschema", data)).build_raw();
        match built {
            Ok(channel) => {
                channels.insert(topic, channel.clone());
                Some(channel)
            }
            Err(e) => {
                tracing::warn!("foxglove: no channel {topic}: {e}");
                None
            }
        }
    }

    /// Sends `data` (JSON) to the clients subscribed to `channel`, at the time now.
    pub(super) fn send(channel: &RawChannel, data: &[u8]) {
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0);
        channel.log_with_meta(data, PartialMetadata::with_log_time(now));
    }
}
