//! The live view's cost to the simulator: the README's flight (the paper scenario, rendered cameras, seed 1,
//! the log written, no plots) flown as fast as it goes, without `--live` and with `--live` and a Foxglove
//! WebSocket client connected and subscribed to every topic, alternately, `RUNS` times each. Reported: the
//! real-time factors (median), their ratio (the issue asks at least 0.90), and what the client received.
//!
//! The client runs in this process (a thread, tungstenite, subprotocol `foxglove.sdk.v1`), so it competes for
//! the same cores as a viewer on the same machine would; it counts messages and bytes and keeps nothing.
//!
//! `cargo bench -p sim-host --features live --bench live`
use serde_json::{Value, json};
use sim_host::Scenario;
use sim_host::flightlog::FramePolicy;
use sim_host::fly::{FlyOptions, LiveFly, fly};
use sim_host::sil::{CameraMode, FcChoice};
use std::time::{Duration, Instant};
use tungstenite::Message;
use tungstenite::client::IntoClientRequest;

const RUNS: usize = 5;

fn options(out: &std::path::Path, live: Option<LiveFly>) -> FlyOptions {
    FlyOptions {
        scenario: Scenario::paper(),
        seed: 1,
        duration_s: None,
        camera: CameraMode::Rendered,
        out: out.to_path_buf(),
        plots: false,
        fc: FcChoice::Sil,
        log: true,
        frames: FramePolicy::Drop,
        serve: None,
        mavlink: None,
        live,
        real_time: None,
    }
}

/// A free port on 127.0.0.1 (bound, then released for the live view).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// What the client received.
struct Received {
    messages: u64,
    bytes: u64,
    /// Topics advertised, with the messages received on each.
    topics: std::collections::BTreeMap<String, u64>,
}

/// Connects (retrying until the server is up), subscribes to every channel as it is advertised, and counts
/// what arrives until the server closes.
fn client(port: u16) -> Received {
    let t0 = Instant::now();
    let mut ws = loop {
        let mut req = format!("ws://127.0.0.1:{port}").into_client_request().unwrap();
        req.headers_mut().insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
        match tungstenite::connect(req) {
            Ok((ws, _)) => break ws,
            Err(_) if t0.elapsed() < Duration::from_secs(30) => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("no live view on port {port}: {e}"),
        }
    };
    let (mut messages, mut bytes) = (0u64, 0u64);
    let mut topics = std::collections::BTreeMap::new();
    // Subscription id -> topic.
    let mut subscribed: Vec<String> = Vec::new();
    while let Ok(msg) = ws.read() {
        match msg {
            Message::Text(t) => {
                let v: Value = serde_json::from_str(&t).unwrap();
                if v["op"] == "advertise" {
                    let subs: Vec<Value> = v["channels"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|c| {
                            let topic = c["topic"].as_str().unwrap_or("?").to_string();
                            topics.entry(topic.clone()).or_insert(0);
                            subscribed.push(topic);
                            json!({"id": subscribed.len(), "channelId": c["id"]})
                        })
                        .collect();
                    let m = json!({"op": "subscribe", "subscriptions": subs}).to_string();
                    ws.send(Message::Text(m.into())).unwrap();
                }
            }
            Message::Binary(b) => {
                messages += 1;
                bytes += b.len() as u64;
                // A message data frame: opcode 1, then the subscription id (u32, little-endian).
                if b.len() >= 5 && b[0] == 1 {
                    let id = u32::from_le_bytes([b[1], b[2], b[3], b[4]]) as usize;
                    if let Some(t) = id.checked_sub(1).and_then(|k| subscribed.get(k)) {
                        *topics.entry(t.clone()).or_insert(0) += 1;
                    }
                }
            }
            Message::Close(_) => break,
            _ => {}
        }
    }
    Received { messages, bytes, topics }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let dir = std::env::temp_dir().join(format!("wlq-bench-live-{}", std::process::id()));
    let (mut plain, mut live) = (Vec::new(), Vec::new());
    for run in 0..RUNS {
        let r = fly(&options(&dir.join("plain"), None), |_, _| {}).expect("flight");
        let rtf_plain = r.stats.sim_time_s / r.wall_time_s;
        plain.push(rtf_plain);

        let port = free_port();
        let watcher = std::thread::spawn(move || client(port));
        let opts =
            options(&dir.join("live"), Some(LiveFly { addr: format!("127.0.0.1:{port}"), wait_s: 30.0 }));
        let r = fly(&opts, |_, _| {}).expect("flight with --live");
        let Received { messages, bytes, topics } = watcher.join().expect("the client");
        let silent: Vec<&String> = topics.iter().filter(|(_, n)| **n == 0).map(|(t, _)| t).collect();
        let channels = topics.len();
        let rtf_live = r.stats.sim_time_s / r.wall_time_s;
        live.push(rtf_live);
        println!(
            "run {}: {:.1} s simulated; real-time factor {rtf_plain:.2} without --live, {rtf_live:.2} with a client \
             ({messages} messages, {:.1} MB, {channels} channels advertised, without a message: {silent:?}; live: {})",
            run + 1,
            r.stats.sim_time_s,
            bytes as f64 / 1e6,
            r.summary["live"]
        );
    }
    let (p, l) = (median(plain), median(live));
    println!(
        "live view: real-time factor {p:.2} without, {l:.2} with --live and a connected client (median of {RUNS}): \
         ratio {:.3}",
        l / p
    );
    let _ = std::fs::remove_dir_all(&dir);
}
