//! `[service] foxglove`: the service's Foxglove WebSocket server, read as the
//! Foxglove app reads it, against `laserd serve` + `laserd sim --pty`: the
//! Foxglove WebSocket protocol v1 (foxglove/ws-protocol's docs/spec.md:
//! `serverInfo` and `advertise` as JSON text, `subscribe` from the client,
//! message data as binary frames) under the subprotocol the foxglove SDK 0.30
//! names it, `foxglove.sdk.v1` (formerly `foxglove.websocket.v1`).

mod common;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use common::service::*;
use common::SimProcess;
use futures_util::{SinkExt, StreamExt};
use hyper::Method;
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

type Socket = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The topics the service advertises from its start.
const TOPICS: [&str; 5] = ["/run/setup", "/link", "/status", "/sim/axes", "/service/status"];

/// A loopback port nobody listens on now.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A live message as a client got it: when, its topic, log time and JSON.
#[derive(Debug, Clone)]
struct Got {
    at: SystemTime,
    topic: String,
    log_time: u64,
    json: Value,
}

/// Connects as Foxglove does (over `stream`), reads `serverInfo` and the
/// advertisements until every topic of `TOPICS` is known: the channels by topic.
async fn connect(stream: tokio::net::TcpStream, port: u16) -> (Socket, BTreeMap<String, Value>) {
    let mut request = format!("ws://127.0.0.1:{port}/").into_client_request().unwrap();
    request.headers_mut().insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, response) = tokio_tungstenite::client_async(request, tokio_tungstenite::MaybeTlsStream::Plain(stream)).await.expect("the WebSocket handshake");
    assert_eq!(response.headers()["Sec-WebSocket-Protocol"], "foxglove.sdk.v1");
    let mut channels = BTreeMap::new();
    let mut server_info = false;
    while !TOPICS.iter().all(|t| channels.contains_key(*t)) {
        let message = tokio::time::timeout(Duration::from_secs(10), ws.next()).await.expect("advertisements come").unwrap().unwrap();
        let Message::Text(text) = message else { panic!("a text frame first: {message:?}") };
        let value: Value = serde_json::from_str(&text).unwrap();
        match value["op"].as_str() {
            Some("serverInfo") => server_info = true,
            Some("advertise") => {
                assert!(server_info, "serverInfo comes first");
                for channel in value["channels"].as_array().unwrap() {
                    channels.insert(channel["topic"].as_str().unwrap().to_string(), channel.clone());
                }
            }
            _ => {}
        }
    }
    (ws, channels)
}

/// Subscribes to every channel, with the channel's id as the subscription's.
async fn subscribe(ws: &mut Socket, channels: &BTreeMap<String, Value>) {
    let subscriptions: Vec<Value> = channels.values().map(|c| json!({ "id": c["id"], "channelId": c["id"] })).collect();
    ws.send(Message::Text(json!({ "op": "subscribe", "subscriptions": subscriptions }).to_string().into())).await.unwrap();
}

/// A message data frame: opcode 1, subscription id (u32), log time (u64), payload.
fn message_data(frame: &[u8], topics: &BTreeMap<u64, String>) -> Option<(String, u64, Value)> {
    if frame.first() != Some(&1) || frame.len() < 13 {
        return None;
    }
    let subscription = u32::from_le_bytes(frame[1..5].try_into().unwrap()) as u64;
    let log_time = u64::from_le_bytes(frame[5..13].try_into().unwrap());
    let json = serde_json::from_slice(&frame[13..]).expect("a message decodes as JSON");
    Some((topics[&subscription].clone(), log_time, json))
}

/// Every message of an MCAP recording, by topic, and each topic's channel
/// encoding with its schema's name, encoding and text.
#[allow(clippy::type_complexity)]
fn read_mcap(bytes: &[u8]) -> (BTreeMap<String, Vec<Value>>, BTreeMap<String, (String, String, String, String)>) {
    let (mut messages, mut schemas) = (BTreeMap::<String, Vec<Value>>::new(), BTreeMap::new());
    for message in mcap::MessageStream::new(bytes).unwrap() {
        let message = message.unwrap();
        let topic = message.channel.topic.clone();
        let schema = message.channel.schema.as_ref().unwrap();
        schemas.insert(topic.clone(), (message.channel.message_encoding.clone(), schema.name.clone(), schema.encoding.clone(), String::from_utf8(schema.data.to_vec()).unwrap()));
        messages.entry(topic).or_default().push(serde_json::from_slice(&message.data).unwrap());
    }
    (messages, schemas)
}

/// Where `part` lies in `whole` as one unbroken run, if it does.
fn run_within(whole: &[&Got], part: &[Value]) -> Option<usize> {
    (0..=whole.len().saturating_sub(part.len())).find(|&i| whole[i..i + part.len()].iter().zip(part).all(|(g, v)| g.json == *v))
}

/// Issue 24: with `[service] foxglove` set, a client sees the recording's
/// topics advertised with the recording's JSON Schemas, gets the machine's
/// status while idle, and gets a job's messages while it runs, the same as
/// its MCAP recording holds, each topic's in one unbroken run. A second
/// client that subscribes and never reads does not slow the job: the server
/// drops what it cannot take instead of waiting.
#[test]
fn a_foxglove_client_sees_the_job_live_as_recorded_and_one_that_never_reads_stalls_nothing() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyLASER");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let port = free_port();
    let config = config_with_service(dir.path(), &tty, &format!("foxglove = \"127.0.0.1:{port}\""));
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap();

    // The reading client: every topic advertised as JSON with a JSON Schema.
    let (mut reader, channels) = runtime.block_on(async { connect(tokio::net::TcpStream::connect(("127.0.0.1", port)).await.unwrap(), port).await });
    for topic in TOPICS {
        let c = &channels[topic];
        assert_eq!((c["encoding"].as_str(), c["schemaEncoding"].as_str()), (Some("json"), Some("jsonschema")), "{c}");
        let schema: Value = serde_json::from_str(c["schema"].as_str().unwrap()).expect("the schema is JSON");
        assert!(schema["properties"].is_object() || schema["$defs"].is_object() || schema["oneOf"].is_array(), "{topic}: {schema}");
    }
    let topics: BTreeMap<u64, String> = channels.iter().map(|(t, c)| (c["id"].as_u64().unwrap(), t.clone())).collect();
    runtime.block_on(subscribe(&mut reader, &channels));
    let got: Arc<Mutex<Vec<Got>>> = Arc::default();
    {
        let (got, topics) = (got.clone(), topics.clone());
        runtime.spawn(async move {
            while let Some(Ok(message)) = reader.next().await {
                if let Message::Binary(frame) = message {
                    if let Some((topic, log_time, json)) = message_data(&frame, &topics) {
                        got.lock().unwrap().push(Got { at: SystemTime::now(), topic, log_time, json });
                    }
                }
            }
        });
    }
    // The idle machine: its status reports and the service's status.
    let idle = Instant::now();
    while !["/status", "/service/status", "/sim/axes"].iter().all(|t| got.lock().unwrap().iter().any(|g| g.topic == *t)) {
        assert!(idle.elapsed() < Duration::from_secs(5), "idle status live: {:?}", got.lock().unwrap().iter().map(|g| &g.topic).collect::<Vec<_>>());
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(got.lock().unwrap().iter().find(|g| g.topic == "/service/status").unwrap().json["machine"]["state"], "Idle");

    // The stalled client: a small receive buffer, subscribed, never read again.
    let stalled = runtime.block_on(async {
        let socket = tokio::net::TcpSocket::new_v4().unwrap();
        socket.set_recv_buffer_size(4096).unwrap();
        let (mut ws, channels) = connect(socket.connect(([127, 0, 0, 1], port).into()).await.unwrap(), port).await;
        subscribe(&mut ws, &channels).await;
        ws
    });

    // A short job, then a longer one: far more messages than the stalled
    // client's queue and socket buffers hold.
    for job in [sample("one-field.svg"), galvo("SC278C18.svg")] {
        let id = api.submit(&job);
        let queued = api.wait_job(&id, "queued", Duration::from_secs(60));
        let planned = queued["planned_time_s"].as_f64().unwrap();
        api.ok(Method::POST, "/start", Some(json!({ "id": id })));
        let done = api.wait_job(&id, "completed", Duration::from_secs(120));
        // In about its planned time (the move to its start and the link's
        // set-up come on top), the stalled client notwithstanding.
        let executed = done["executed_time_s"].as_f64().unwrap();
        eprintln!("{}: planned {planned:.2} s, executed {executed:.2} s", job.display());
        assert!(executed < 1.2 * planned + 2.0, "planned {planned} s, executed {executed} s");
        let ended = SystemTime::UNIX_EPOCH + Duration::from_secs_f64(done["ended_at"].as_f64().unwrap());
        // What the job's recording holds, and its schemas.
        let path = dir.path().join(format!("{id}.mcap"));
        api.recording(&id, &path);
        let (recorded, schemas) = read_mcap(&std::fs::read(&path).unwrap());
        std::thread::sleep(Duration::from_millis(500));
        let got = got.lock().unwrap().clone();
        for topic in ["/run/setup", "/link", "/status", "/sim/axes"] {
            let (encoding, name, schema_encoding, schema) = &schemas[topic];
            let c = &channels[topic];
            assert_eq!((c["encoding"].as_str().unwrap(), c["schemaName"].as_str().unwrap(), c["schemaEncoding"].as_str().unwrap(), c["schema"].as_str().unwrap()), (encoding.as_str(), name.as_str(), schema_encoding.as_str(), schema.as_str()), "{topic}: the recording's schema");
            let live: Vec<&Got> = got.iter().filter(|g| g.topic == topic).collect();
            let part = &recorded[topic];
            assert!(!part.is_empty(), "{topic} recorded");
            let at = run_within(&live, part).unwrap_or_else(|| panic!("{topic}: the {} recorded messages are not one run of the {} live ones; first recorded {}", part.len(), live.len(), part[0]));
            // Live, while the job ran: the middle message came before the job ended.
            let middle = live[at + part.len() / 2];
            assert!(middle.at < ended, "{topic}: the middle message came {:?} after the end", middle.at.duration_since(ended).unwrap_or_default());
            // Stamped with the time it was written (ns since the epoch).
            let written = SystemTime::UNIX_EPOCH + Duration::from_nanos(middle.log_time);
            assert!(written <= middle.at && middle.at.duration_since(written).unwrap() < Duration::from_secs(2), "{topic}: log time {written:?}, got {:?}", middle.at);
        }
        assert!(recorded["/link"].len() > 100, "{} link messages", recorded["/link"].len());
        // The service's status: the job running, then done.
        let service_status: Vec<&Value> = got.iter().filter(|g| g.topic == "/service/status").map(|g| &g.json).collect();
        let running = service_status.iter().position(|s| s["job"]["id"] == id.as_str() && s["job"]["state"] == "running").expect("the job running on /service/status");
        assert!(service_status[running..].iter().any(|s| s["job"].is_null() && machine_state(s) == "Idle"), "the job's end on /service/status");
    }
    // The stalled client was still connected, unread, all along (its
    // messages sit in the server's socket buffer, up to 4 MB on Linux, and
    // its queue: `the_live_server_drops_for_a_client_that_never_reads_instead_of_waiting`
    // fills them).
    drop(stalled);
    assert!(service.terminate().success());
}

/// A large message, for filling buffers.
#[derive(serde::Serialize, schemars::JsonSchema)]
struct Bulk {
    n: usize,
    fill: String,
}

/// The SDK under a client that subscribes and never reads: writing never
/// waits for it (4000 messages of 4 KB, 16 MB, more than the server's socket
/// buffer, 4 MB at most on Linux, and the client's queue of 1024 messages
/// hold, are written at once), and the client, read afterwards, lacks the
/// ones that were dropped.
#[test]
fn the_live_server_drops_for_a_client_that_never_reads_instead_of_waiting() {
    let _turn = take_turn();
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let port = free_port();
    let live = runtime.block_on(laserd::record::live::Live::start(([127, 0, 0, 1], port).into())).unwrap();
    for topic in TOPICS {
        live.advertise::<Bulk>(topic);
    }
    let recorder = laserd::record::Recorder::live_only(live);
    let mut stalled = runtime.block_on(async {
        let socket = tokio::net::TcpSocket::new_v4().unwrap();
        socket.set_recv_buffer_size(4096).unwrap();
        let (mut ws, channels) = connect(socket.connect(([127, 0, 0, 1], port).into()).await.unwrap(), port).await;
        subscribe(&mut ws, &channels).await;
        ws
    });
    // The subscription is taken asynchronously: wait until messages flow.
    std::thread::sleep(Duration::from_millis(300));
    let count = 4000;
    let fill = "x".repeat(4 << 10);
    let started = Instant::now();
    for n in 0..count {
        recorder.write("/link", 0.0, &Bulk { n, fill: fill.clone() });
    }
    let writing = started.elapsed();
    assert!(writing < Duration::from_secs(2), "{count} writes took {writing:?}");
    let got = runtime.block_on(async {
        let (mut got, until) = (Vec::new(), tokio::time::Instant::now() + Duration::from_secs(5));
        while let Ok(Some(Ok(message))) = tokio::time::timeout_at(until, stalled.next()).await {
            if let Message::Binary(frame) = message {
                let json: Value = serde_json::from_slice(&frame[13..]).unwrap();
                got.push(json["n"].as_u64().unwrap() as usize);
                if got.last() == Some(&(count - 1)) {
                    break;
                }
            }
        }
        got
    });
    eprintln!("{count} writes in {writing:?}; the stalled client got {} of them", got.len());
    // The newest is kept; older ones were dropped, in order otherwise.
    assert_eq!(got.last(), Some(&(count - 1)), "the newest message arrives");
    assert!(got.len() < count, "some were dropped: got {}", got.len());
    assert!(got.windows(2).all(|w| w[0] < w[1]), "in order");
}

/// `[service] foxglove` that cannot be had stops the service at its start,
/// naming the setting: an address that is none, and a port in use.
#[test]
fn a_foxglove_address_that_cannot_be_had_stops_the_service_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let in_use = taken.local_addr().unwrap().to_string();
    for (address, why) in [("127.0.0.1", "IP address and port"), (in_use.as_str(), "cannot listen")] {
        let config = config_with_service(dir.path(), &dir.path().join("no-tty"), &format!("foxglove = {address:?}"));
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_laserd"))
            .args(["serve", "--config", config.to_str().unwrap(), "--state-dir", dir.path().join("state").to_str().unwrap(), "--socket", dir.path().join("api.sock").to_str().unwrap()])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{address}: {stderr}");
        assert!(stderr.contains("[service] foxglove") && stderr.contains(why), "{address}: {stderr}");
    }
}
