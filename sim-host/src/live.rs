//! The live view (`sim-host fly --live`): the flight published as it happens over the Foxglove WebSocket
//! protocol with the Foxglove SDK (`foxglove` crate), for Foxglove or Lichtblick (docs/live-view.md).
//!
//! - Every record the flight log gets goes out on the topics of the MCAP export (`crate::export`) in the same
//!   encodings: our records as JSON with the same JSON Schemas, the poses as `foxglove.PoseInFrame`, the body
//!   frames (`/tf`) and the scene (`/scene`) in the Foxglove SDK's typed (protobuf) schemas, built by the
//!   same code (`crate::foxglove_msgs`).
//! - The cameras as the simulation renders them: the forward image (JPEG) with the detected edges and corners
//!   besides the line reprojected from the estimate (`foxglove.ImageAnnotations`), the downward image with the
//!   tracked features and their flow.
//!
//! Nothing here runs on the simulation's thread but [`LiveTap`]'s hand-over: it copies what it is given into a
//! bounded queue that a publishing thread empties (encoding, JSON, the server). When the queue is full the
//! item is dropped and counted ([`LiveStats`]), so that a slow viewer never slows the flight. Images are
//! sent at most [`IMAGE_RATE_HZ`] per camera and second of wall time: a laptop's viewer keeps up with that,
//! and a faster-than-real-time flight would otherwise queue hundreds per second; the frames between are
//! skipped by design and counted apart.
use crate::export::{self, Body, Msg};
use crate::flightlog::{CameraId, LogRecord};
use crate::foxglove_msgs::{self as fx, Bodies, stamp};
use crate::imageio::{GrayImage, RgbImage};
use crate::live_rate::StepThinning;
use crate::scenario::Scenario;
use crate::sil::FlightTap;
use anyhow::{Context as _, Result};
use foxglove::messages::{
    CompressedImage, FrameTransforms, ImageAnnotations, PoseInFrame, RawImage, SceneUpdate,
};
use foxglove::{Channel, ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};
use geometry::Vec2;
use serde::Serialize;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::{Duration, Instant};
use vision_core::observation::LineObservation;

/// Where the live view listens unless told otherwise (Foxglove's default WebSocket address).
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// Images sent per camera and second of wall time, at most.
pub const IMAGE_RATE_HZ: f64 = 10.0;
/// JPEG quality of the forward images (640x480: about 40 KB each).
pub const FORWARD_JPEG_QUALITY: u8 = 80;
/// The downward image's annotations topic (the tracked features and their flow; live only).
pub const DOWN_ANNOTATIONS: &str = "/camera/down/annotations";
/// A flight faster than real time sends its step-rate records (IMU, the step's report, the truth) at most
/// this many times as densely as a real-time flight would: a viewer keeps up, and the simulation does not spend
/// its time on copies nobody can watch. The radio's and the station's records always go out.
pub const MAX_RECORD_SPEEDUP: f64 = 2.0;
/// Items waiting for the publishing thread, at most (records of a step, or a frame).
pub const QUEUE_LEN: usize = 4096;

/// What the live view sent, skipped and dropped.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq, Eq)]
pub struct LiveStats {
    /// Messages published (all topics; a message is made only for a topic some viewer subscribed to).
    pub messages: u64,
    /// Forward images published.
    pub forward_images: u64,
    /// Downward images published.
    pub down_images: u64,
    /// Frames not sent because the camera's image rate was reached (by design, [`IMAGE_RATE_HZ`]).
    pub frames_skipped_for_rate: u64,
    /// Steps whose records (IMU, report, truth) were not sent because the flight ran faster than
    /// [`MAX_RECORD_SPEEDUP`] times real time (by design; the log has them).
    pub steps_thinned: u64,
    /// Batches of records dropped because the publishing thread was behind (the queue was full).
    pub record_batches_dropped: u64,
    /// Frames dropped because the publishing thread was behind.
    pub frames_dropped: u64,
    /// Messages that could not be encoded or had no channel (a bug if ever non-zero).
    pub messages_failed: u64,
    /// Most viewers connected at once.
    pub max_clients: u64,
}

impl LiveStats {
    /// One line for the terminal.
    pub fn describe(&self) -> String {
        format!(
            "{} messages published ({} forward and {} downward images; {} frames skipped for the image rate, \
             {} steps thinned for the record rate); \
             dropped while the viewer was behind: {} record batches, {} frames; {} failed to encode; \
             at most {} viewer(s)",
            self.messages,
            self.forward_images,
            self.down_images,
            self.frames_skipped_for_rate,
            self.steps_thinned,
            self.record_batches_dropped,
            self.frames_dropped,
            self.messages_failed,
            self.max_clients
        )
    }
}

enum Item {
    Records(Vec<LogRecord>),
    Forward { t_us: u64, img: RgbImage, detection: Option<LineObservation> },
    Down { t_us: u64, img: GrayImage, tracks: Vec<(Vec2, Vec2, bool)> },
}

#[derive(Default)]
struct Counters {
    frames_skipped_for_rate: AtomicU64,
    steps_thinned: AtomicU64,
    record_batches_dropped: AtomicU64,
    frames_dropped: AtomicU64,
}

/// The viewers as the server reports them when they connect and leave: the most connected at once is counted
/// when it happens, not sampled, so a viewer that came and went between two looks is not missed.
#[derive(Default)]
struct ClientCounter {
    connected: AtomicU64,
    max: AtomicU64,
}

impl foxglove::websocket::ServerListener for ClientCounter {
    fn on_client_connect(&self) {
        let now = self.connected.fetch_add(1, Ordering::Relaxed) + 1;
        self.max.fetch_max(now, Ordering::Relaxed);
    }

    fn on_client_disconnect(&self) {
        // Never below zero, whatever the order of the server's calls.
        self.connected.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1)).ok();
    }
}

/// A running live view: the server and its publishing thread.
pub struct LiveView {
    server: foxglove::WebSocketServerHandle,
    runtime: tokio::runtime::Runtime,
    addr: SocketAddr,
    tx: SyncSender<Item>,
    worker: std::thread::JoinHandle<Published>,
    counters: Arc<Counters>,
    viewers: Arc<ClientCounter>,
}

/// The simulation's side of a [`LiveView`] ([`FlightTap`]).
pub struct LiveTap {
    tx: SyncSender<Item>,
    counters: Arc<Counters>,
    last_image: [Option<Instant>; 2],
    thin: Option<StepThinning>,
}

impl LiveView {
    /// Starts the server on `addr` (`HOST:PORT`; port 0 picks a free one) for a flight of `scenario`.
    pub fn start(addr: &str, scenario: &Scenario) -> Result<Self> {
        let sock: SocketAddr = addr
            .parse()
            .with_context(|| format!("--live {addr}: expected HOST:PORT, e.g. {DEFAULT_ADDR}"))?;
        let ctx = Context::new();
        let viewers = Arc::new(ClientCounter::default());
        // The server's own runtime: one worker thread at background priority (the SDK's default runtime has a
        // worker per core at the simulation's priority).
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("live-view-server")
            .on_thread_start(background_priority)
            .enable_all()
            .build()
            .context("starting the live view's runtime")?;
        let server = runtime
            .block_on(
                WebSocketServer::new()
                    .name("wall-line quadrotor (sim-host)")
                    .bind(sock.ip().to_string(), sock.port())
                    .context(&ctx)
                    .listener(viewers.clone())
                    .start(),
            )
            .with_context(|| format!("--live {addr}: cannot start the WebSocket server"))?;
        // A task run on the runtime's worker: once it has run, the worker has started and lowered its priority.
        runtime.block_on(runtime.spawn(async {})).context("starting the live view's runtime worker")?;
        let addr = SocketAddr::new(sock.ip(), server.port());
        let (tx, rx) = sync_channel(QUEUE_LEN);
        let publisher = Publisher::new(ctx, scenario);
        // The publisher says when it runs at its priority, so that every live-view thread does once this returns
        // (a thread takes its name and priority in itself, after the spawn returns).
        let (started_tx, started_rx) = sync_channel(1);
        let worker = std::thread::Builder::new()
            .name("live-view".into())
            .spawn(move || {
                background_priority();
                // The receiver waits below; if it has gone, `start` has failed and nothing waits for this.
                started_tx.send(()).ok();
                publisher.run(rx)
            })
            .context("starting the live view's thread")?;
        started_rx.recv().context("the live view's thread ended as it started")?;
        Ok(Self { server, runtime, addr, tx, worker, counters: Arc::default(), viewers })
    }

    /// The address it listens on.
    pub fn address(&self) -> SocketAddr {
        self.addr
    }

    /// Viewers connected now.
    pub fn clients(&self) -> usize {
        self.server.client_count()
    }

    /// Waits until a viewer connects, `stop` is set or `timeout` passes; whether one connected.
    pub fn wait_for_client(&self, stop: &std::sync::atomic::AtomicBool, timeout: Duration) -> bool {
        let t0 = Instant::now();
        while self.clients() == 0 {
            if stop.load(Ordering::Relaxed) || t0.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        true
    }

    /// The hand-over for the simulation ([`crate::sil::Sil::set_tap`]).
    ///
    /// `paced`: the flight runs at the wall clock's pace (`--real-time`, a station, a MAVLink flight), so every
    /// record goes out; otherwise the step-rate records are thinned to [`MAX_RECORD_SPEEDUP`] times real
    /// time's density.
    pub fn tap(&self, paced: bool) -> LiveTap {
        LiveTap {
            tx: self.tx.clone(),
            counters: self.counters.clone(),
            last_image: [None; 2],
            thin: (!paced).then(|| StepThinning::new(MAX_RECORD_SPEEDUP)),
        }
    }

    /// Publishes what is queued, then stops the server. The taps must have been dropped.
    pub fn finish(self) -> LiveStats {
        let Self { server, runtime, tx, worker, counters, viewers, .. } = self;
        drop(tx);
        // The worker ends when every sender is gone; a panic there is the publisher's bug: say so and keep
        // the flight's own results.
        let Published { messages, forward_images, down_images, failed } =
            worker.join().unwrap_or_else(|_| {
                eprintln!("the live view's publishing thread panicked; its counts are lost");
                Published::default()
            });
        // Give connected viewers a moment to receive the last messages before the server closes.
        std::thread::sleep(Duration::from_millis(200));
        server.stop().wait_blocking();
        runtime.shutdown_timeout(Duration::from_secs(1));
        LiveStats {
            messages,
            forward_images,
            down_images,
            frames_skipped_for_rate: counters.frames_skipped_for_rate.load(Ordering::Relaxed),
            steps_thinned: counters.steps_thinned.load(Ordering::Relaxed),
            record_batches_dropped: counters.record_batches_dropped.load(Ordering::Relaxed),
            frames_dropped: counters.frames_dropped.load(Ordering::Relaxed),
            messages_failed: failed,
            max_clients: viewers.max.load(Ordering::Relaxed),
        }
    }
}

/// Lowers the calling thread to the lowest scheduling priority (nice 19): the live view's threads (encoding,
/// the server) then use the cores the simulation leaves idle, and take little from it when it keeps every core
/// busy (a flight faster than real time); what they cannot keep up with is dropped and counted, not waited
/// for. Linux only (per-thread nice values); elsewhere the threads keep their priority.
fn background_priority() {
    #[cfg(target_os = "linux")]
    if let Err(e) = rustix::process::setpriority_process(Some(rustix::thread::gettid()), 19) {
        eprintln!("live view: could not lower a thread's priority ({e}); it competes with the simulation");
    }
}

impl LiveTap {
    /// Whether camera `k` may send an image now (the image rate), counting the frames it may not.
    fn image_due(&mut self, k: usize) -> bool {
        let now = Instant::now();
        match self.last_image[k] {
            Some(t) if now.duration_since(t).as_secs_f64() < 1.0 / IMAGE_RATE_HZ => {
                self.counters.frames_skipped_for_rate.fetch_add(1, Ordering::Relaxed);
                false
            }
            _ => {
                self.last_image[k] = Some(now);
                true
            }
        }
    }

    fn send(&mut self, item: Item) {
        let frame = !matches!(item, Item::Records(_));
        match self.tx.try_send(item) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                let c =
                    if frame { &self.counters.frames_dropped } else { &self.counters.record_batches_dropped };
                c.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

impl FlightTap for LiveTap {
    fn records(&mut self, records: &[LogRecord]) {
        // A step's records all go out, or (thinned) only its radio's and a station's.
        let step = records.iter().find_map(|r| match r {
            LogRecord::Step(s) => Some(s.time_us),
            _ => None,
        });
        let step_due = match (&mut self.thin, step) {
            (Some(th), Some(t_us)) => th.due(t_us, Instant::now()),
            _ => true,
        };
        if !step_due {
            self.counters.steps_thinned.fetch_add(1, Ordering::Relaxed);
        }
        // The log's own frame records are not sent: the frames come through `forward_frame` / `down_frame`.
        let kept: Vec<LogRecord> = records
            .iter()
            .filter(|r| match r {
                LogRecord::Frame(_) => false,
                LogRecord::Step(_) | LogRecord::Report(_) | LogRecord::Truth { .. } => step_due,
                _ => true,
            })
            .cloned()
            .collect();
        if !kept.is_empty() {
            self.send(Item::Records(kept));
        }
    }

    fn forward_frame(&mut self, t_us: u64, img: &RgbImage, detection: Option<&LineObservation>) {
        if self.image_due(0) {
            self.send(Item::Forward { t_us, img: img.clone(), detection: detection.copied() });
        }
    }

    fn down_frame(&mut self, t_us: u64, img: &GrayImage, tracks: &[(Vec2, Vec2, bool)]) {
        if self.image_due(1) {
            self.send(Item::Down { t_us, img: img.clone(), tracks: tracks.to_vec() });
        }
    }
}

/// The publishing thread's state: the channels and what the images need of the scenario.
struct Publisher {
    ctx: Arc<Context>,
    json: BTreeMap<&'static str, Arc<RawChannel>>,
    poses: BTreeMap<&'static str, Channel<PoseInFrame>>,
    forward_image: Channel<CompressedImage>,
    forward_annotations: Channel<ImageAnnotations>,
    down_image: Channel<RawImage>,
    down_annotations: Channel<ImageAnnotations>,
    transforms: Channel<FrameTransforms>,
    scene: Channel<SceneUpdate>,
    scenario: Scenario,
    bodies: Bodies,
    messages: u64,
    forward_images: u64,
    down_images: u64,
    failed: u64,
}

/// What the publishing thread did.
#[derive(Default)]
struct Published {
    messages: u64,
    forward_images: u64,
    down_images: u64,
    failed: u64,
}

impl Publisher {
    fn new(ctx: Arc<Context>, scenario: &Scenario) -> Self {
        let typed = |topic: &str| ChannelBuilder::new(topic).context(&ctx);
        Self {
            forward_image: typed(export::camera_topic(CameraId::Forward)).build(),
            forward_annotations: typed(export::FORWARD_ANNOTATIONS).build(),
            down_image: typed(export::camera_topic(CameraId::Downward)).build(),
            down_annotations: typed(DOWN_ANNOTATIONS).build(),
            transforms: typed(export::TRANSFORMS).build(),
            scene: typed(export::SCENE).build(),
            json: BTreeMap::new(),
            poses: BTreeMap::new(),
            ctx,
            scenario: scenario.clone(),
            bodies: Bodies::default(),
            messages: 0,
            forward_images: 0,
            down_images: 0,
            failed: 0,
        }
    }

    fn run(mut self, rx: Receiver<Item>) -> Published {
        while let Ok(item) = rx.recv() {
            match item {
                Item::Records(rs) => {
                    for r in &rs {
                        self.record(r);
                    }
                }
                Item::Forward { t_us, img, detection } => self.forward(t_us, &img, detection.as_ref()),
                Item::Down { t_us, img, tracks } => self.down(t_us, &img, &tracks),
            }
        }
        Published {
            messages: self.messages,
            forward_images: self.forward_images,
            down_images: self.down_images,
            failed: self.failed,
        }
    }

    fn json_channel(&mut self, topic: &'static str, schema: &'static str) -> Option<Arc<RawChannel>> {
        if let Some(c) = self.json.get(topic) {
            return Some(c.clone());
        }
        let data = serde_json::to_vec(&export::schema_of(schema)).ok()?;
        let c = ChannelBuilder::new(topic)
            .context(&self.ctx)
            .message_encoding("json")
            .schema(Schema::new(schema, "jsonschema", data))
            .build_raw()
            .ok()?;
        self.json.insert(topic, c.clone());
        Some(c)
    }

    fn record(&mut self, r: &LogRecord) {
        let changed = self.bodies.update(r);
        let mut msgs: Vec<Msg> = Vec::new();
        export::topics(r, self.bodies.step_us, &mut msgs);
        for m in msgs {
            // Channels are advertised from their first message on; a message is encoded only for a channel
            // some viewer subscribed to.
            match m.body {
                Body::Json(v) => {
                    let Some(c) = self.json_channel(m.topic, m.schema) else {
                        self.failed += 1;
                        continue;
                    };
                    if !c.has_sinks() {
                        continue;
                    }
                    match serde_json::to_vec(&v) {
                        Ok(bytes) => {
                            c.log_with_meta(&bytes, meta(m.time_us));
                            self.messages += 1;
                        }
                        Err(_) => self.failed += 1,
                    }
                }
                Body::Pose(p) => {
                    let ctx = &self.ctx;
                    let c = self
                        .poses
                        .entry(m.topic)
                        .or_insert_with(|| ChannelBuilder::new(m.topic).context(ctx).build());
                    if c.has_sinks() {
                        c.log_with_meta(&p, meta(m.time_us));
                        self.messages += 1;
                    }
                }
            }
        }
        if let Some(t_us) = changed {
            self.frames(t_us);
        }
    }

    /// The body frames of the estimate and the truth, and, when due, the scene.
    fn frames(&mut self, t_us: u64) {
        if self.transforms.has_sinks()
            && let Some(tf) = self.bodies.transforms(t_us)
        {
            self.transforms.log_with_meta(&tf, meta(t_us));
            self.messages += 1;
        }
        if self.scene.has_sinks() && self.bodies.scene_due(t_us) {
            self.scene
                .log_with_meta(&fx::scene(&self.scenario, t_us, self.bodies.truth.is_some()), meta(t_us));
            self.messages += 1;
        }
    }

    fn forward(&mut self, t_us: u64, img: &RgbImage, detection: Option<&LineObservation>) {
        if self.forward_annotations.has_sinks() {
            let annotations = fx::forward_annotations(&self.scenario, t_us, detection, self.bodies.estimate);
            self.forward_annotations.log_with_meta(&annotations, meta(t_us));
            self.messages += 1;
        }
        if !self.forward_image.has_sinks() {
            return;
        }
        let mut jpeg = Vec::new();
        let enc = jpeg_encoder::Encoder::new(&mut jpeg, FORWARD_JPEG_QUALITY);
        if enc.encode(&img.data, img.width as u16, img.height as u16, jpeg_encoder::ColorType::Rgb).is_err() {
            self.failed += 1;
            return;
        }
        let msg = CompressedImage {
            timestamp: stamp(t_us),
            frame_id: fx::camera_frame_id(CameraId::Forward).into(),
            data: jpeg.into(),
            format: "jpeg".into(),
        };
        self.forward_image.log_with_meta(&msg, meta(t_us));
        self.messages += 1;
        self.forward_images += 1;
    }

    fn down(&mut self, t_us: u64, img: &GrayImage, tracks: &[(Vec2, Vec2, bool)]) {
        if self.down_annotations.has_sinks() {
            self.down_annotations.log_with_meta(&fx::down_annotations(t_us, tracks), meta(t_us));
            self.messages += 1;
        }
        if !self.down_image.has_sinks() {
            return;
        }
        let msg = RawImage {
            timestamp: stamp(t_us),
            frame_id: fx::camera_frame_id(CameraId::Downward).into(),
            width: img.width as u32,
            height: img.height as u32,
            encoding: "mono8".into(),
            step: img.width as u32,
            data: img.data.clone().into(),
        };
        self.down_image.log_with_meta(&msg, meta(t_us));
        self.messages += 1;
        self.down_images += 1;
    }
}

fn meta(t_us: u64) -> PartialMetadata {
    PartialMetadata::with_log_time(t_us * 1000)
}
