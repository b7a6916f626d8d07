//! The live view (`sim-host fly --live`): the flight published as it happens over the Foxglove WebSocket
//! protocol with the Foxglove SDK (`foxglove` crate), for Foxglove or Lichtblick (docs/live-view.md).
//!
//! - Every record the flight log gets goes out on the topics of the MCAP export (`crate::export`): the same
//!   names, JSON messages with the same JSON Schemas (`foxglove.PoseInFrame` for the poses).
//! - Beside them, in the Foxglove SDK's typed (protobuf) schemas: the forward image (JPEG) with the detected
//!   edges and corners and the line reprojected from the estimate (`foxglove.ImageAnnotations`), the
//!   downward image with the tracked features and their flow, the body frames of the estimate and of the
//!   truth (`foxglove.FrameTransforms`), and the wall, the line and the vehicle (`foxglove.SceneUpdate`).
//!
//! Nothing here runs on the simulation's thread but [`LiveTap`]'s hand-over: it copies what it is given into a
//! bounded queue that a publishing thread empties (encoding, JSON, the server). When the queue is full the
//! item is dropped and counted ([`LiveStats`]), so that a slow viewer never slows the flight. Images are
//! sent at most [`IMAGE_RATE_HZ`] per camera and second of wall time: a laptop's viewer keeps up with that,
//! and a faster-than-real-time flight would otherwise queue hundreds per second; the frames between are
//! skipped by design and counted apart.
use crate::export::{self, Msg};
use crate::flightlog::LogRecord;
use crate::imageio::{GrayImage, RgbImage};
use crate::scenario::Scenario;
use crate::sil::FlightTap;
use anyhow::{Context as _, Result};
use foxglove::messages::{
    Color, CompressedImage, CubePrimitive, CylinderPrimitive, FrameTransform, FrameTransforms,
    ImageAnnotations, Point2, PointsAnnotation, Pose, Quaternion, RawImage, SceneEntity, SceneUpdate,
    Timestamp, Vector3, points_annotation,
};
use foxglove::{Channel, ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};
use geometry::{Quat, Vec2, Vec3};
use serde::Serialize;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::{Duration, Instant};
use vision_core::observation::LineObservation;
use vision_core::target::Corner;

/// Where the live view listens unless told otherwise (Foxglove's default WebSocket address).
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// Images sent per camera and second of wall time, at most.
pub const IMAGE_RATE_HZ: f64 = 10.0;
/// JPEG quality of the forward images (640x480: about 40 KB each).
pub const FORWARD_JPEG_QUALITY: u8 = 80;
/// Items waiting for the publishing thread, at most (records of a step, or a frame).
pub const QUEUE_LEN: usize = 4096;
/// Simulated time between two scene updates (us).
const SCENE_EVERY_US: u64 = 100_000;

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
    /// Batches of records dropped because the publishing thread was behind (the queue was full).
    pub record_batches_dropped: u64,
    /// Frames dropped because the publishing thread was behind.
    pub frames_dropped: u64,
    /// Most viewers connected at once.
    pub max_clients: u64,
}

impl LiveStats {
    /// One line for the terminal.
    pub fn describe(&self) -> String {
        format!(
            "{} messages published ({} forward and {} downward images; {} frames skipped for the image rate); \
             dropped while the viewer was behind: {} record batches, {} frames; at most {} viewer(s)",
            self.messages,
            self.forward_images,
            self.down_images,
            self.frames_skipped_for_rate,
            self.record_batches_dropped,
            self.frames_dropped,
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
    record_batches_dropped: AtomicU64,
    frames_dropped: AtomicU64,
}

/// A running live view: the server and its publishing thread.
pub struct LiveView {
    server: foxglove::WebSocketServerHandle,
    addr: SocketAddr,
    tx: SyncSender<Item>,
    worker: std::thread::JoinHandle<(u64, u64, u64)>,
    counters: Arc<Counters>,
    max_clients: u64,
}

/// The simulation's side of a [`LiveView`] ([`FlightTap`]).
pub struct LiveTap {
    tx: SyncSender<Item>,
    counters: Arc<Counters>,
    last_image: [Option<Instant>; 2],
}

impl LiveView {
    /// Starts the server on `addr` (`HOST:PORT`; port 0 picks a free one) for a flight of `scenario`.
    pub fn start(addr: &str, scenario: &Scenario) -> Result<Self> {
        let sock: SocketAddr = addr
            .parse()
            .with_context(|| format!("--live {addr}: expected HOST:PORT, e.g. {DEFAULT_ADDR}"))?;
        let ctx = Context::new();
        let server = WebSocketServer::new()
            .name("wall-line quadrotor (sim-host)")
            .bind(sock.ip().to_string(), sock.port())
            .context(&ctx)
            .start_blocking()
            .with_context(|| format!("--live {addr}: cannot start the WebSocket server"))?;
        let addr = SocketAddr::new(sock.ip(), server.port());
        let (tx, rx) = sync_channel(QUEUE_LEN);
        let publisher = Publisher::new(ctx, scenario);
        let worker = std::thread::Builder::new()
            .name("live-view".into())
            .spawn(move || publisher.run(rx))
            .context("starting the live view's thread")?;
        Ok(Self { server, addr, tx, worker, counters: Arc::default(), max_clients: 0 })
    }

    /// The address it listens on.
    pub fn address(&self) -> SocketAddr {
        self.addr
    }

    /// Viewers connected now.
    pub fn clients(&mut self) -> usize {
        let n = self.server.client_count();
        self.max_clients = self.max_clients.max(n as u64);
        n
    }

    /// Waits until a viewer connects, `stop` is set or `timeout` passes; whether one connected.
    pub fn wait_for_client(&mut self, stop: &std::sync::atomic::AtomicBool, timeout: Duration) -> bool {
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
    pub fn tap(&self) -> LiveTap {
        LiveTap { tx: self.tx.clone(), counters: self.counters.clone(), last_image: [None; 2] }
    }

    /// Publishes what is queued, then stops the server. The taps must have been dropped.
    pub fn finish(mut self) -> LiveStats {
        self.clients();
        let Self { server, tx, worker, counters, max_clients, .. } = self;
        drop(tx);
        // The worker ends when every sender is gone; a panic there is the publisher's bug: say so and keep
        // the flight's own results.
        let (messages, forward_images, down_images) = worker.join().unwrap_or_else(|_| {
            eprintln!("the live view's publishing thread panicked; its counts are lost");
            (0, 0, 0)
        });
        // Give connected viewers a moment to receive the last messages before the server closes.
        std::thread::sleep(Duration::from_millis(200));
        server.stop().wait_blocking();
        LiveStats {
            messages,
            forward_images,
            down_images,
            frames_skipped_for_rate: counters.frames_skipped_for_rate.load(Ordering::Relaxed),
            record_batches_dropped: counters.record_batches_dropped.load(Ordering::Relaxed),
            frames_dropped: counters.frames_dropped.load(Ordering::Relaxed),
            max_clients,
        }
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
        // The log's own frame records are not sent: the frames come through `forward_frame` / `down_frame`.
        let kept: Vec<LogRecord> =
            records.iter().filter(|r| !matches!(r, LogRecord::Frame(_))).cloned().collect();
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

fn stamp(t_us: u64) -> Option<Timestamp> {
    Some(Timestamp::new((t_us / 1_000_000) as u32, ((t_us % 1_000_000) * 1000) as u32))
}

fn meta(t_us: u64) -> PartialMetadata {
    PartialMetadata::with_log_time(t_us * 1000)
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Option<Color> {
    Some(Color { r, g, b, a })
}

fn v3(v: Vec3) -> Option<Vector3> {
    Some(Vector3 { x: v.x as f64, y: v.y as f64, z: v.z as f64 })
}

fn quat(q: Quat) -> Option<Quaternion> {
    Some(Quaternion { x: q.x as f64, y: q.y as f64, z: q.z as f64, w: q.w as f64 })
}

fn pose(p: Vec3, q: Quat) -> Option<Pose> {
    Some(Pose { position: v3(p), orientation: quat(q) })
}

fn px(p: Vec2) -> Point2 {
    Point2 { x: p.x as f64, y: p.y as f64 }
}

fn points(
    kind: points_annotation::Type,
    pts: Vec<Point2>,
    rgba: [f64; 4],
    thickness: f64,
) -> PointsAnnotation {
    PointsAnnotation {
        timestamp: None,
        r#type: kind as i32,
        points: pts,
        outline_color: color(rgba[0], rgba[1], rgba[2], rgba[3]),
        thickness,
        ..Default::default()
    }
}

/// The publishing thread's state: the channels and what the images need of the scenario.
struct Publisher {
    ctx: Arc<Context>,
    json: BTreeMap<&'static str, Arc<RawChannel>>,
    forward_image: Channel<CompressedImage>,
    forward_annotations: Channel<ImageAnnotations>,
    down_image: Channel<RawImage>,
    down_annotations: Channel<ImageAnnotations>,
    transforms: Channel<FrameTransforms>,
    scene: Channel<SceneUpdate>,
    scenario: Scenario,
    step_us: u64,
    estimate: Option<(Vec3, Quat)>,
    truth: Option<(Vec3, Quat)>,
    next_scene_us: u64,
    messages: u64,
    forward_images: u64,
    down_images: u64,
}

impl Publisher {
    fn new(ctx: Arc<Context>, scenario: &Scenario) -> Self {
        let typed = |topic: &str| ChannelBuilder::new(topic).context(&ctx);
        Self {
            forward_image: typed("/camera/forward/image").build(),
            forward_annotations: typed("/camera/forward/annotations").build(),
            down_image: typed("/camera/down/image").build(),
            down_annotations: typed("/camera/down/annotations").build(),
            transforms: typed("/tf").build(),
            scene: typed("/scene").build(),
            json: BTreeMap::new(),
            ctx,
            scenario: scenario.clone(),
            step_us: 0,
            estimate: None,
            truth: None,
            next_scene_us: 0,
            messages: 0,
            forward_images: 0,
            down_images: 0,
        }
    }

    fn run(mut self, rx: Receiver<Item>) -> (u64, u64, u64) {
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
        (self.messages, self.forward_images, self.down_images)
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
        if let LogRecord::Step(s) = r {
            self.step_us = s.time_us;
        }
        let mut msgs: Vec<Msg> = Vec::new();
        export::topics(r, self.step_us, &mut msgs);
        for m in msgs {
            // Channels are advertised from their first message on; a message is encoded only for a channel
            // some viewer subscribed to.
            let Some(c) = self.json_channel(m.topic, m.schema) else { continue };
            if !c.has_sinks() {
                continue;
            }
            if let Ok(bytes) = serde_json::to_vec(&m.value) {
                c.log_with_meta(&bytes, meta(m.time_us));
                self.messages += 1;
            }
        }
        match r {
            LogRecord::Report(rep) => {
                let e = &rep.control.estimate;
                self.estimate = Some((e.position_m, e.q));
                self.frames(self.step_us);
            }
            // A station's view: the estimate as the telemetry brought it, at the station's clock.
            LogRecord::Station(crate::flightlog::StationEvent::Received { station_time_us, message }) => {
                if let Some(tm) = message.telemetry() {
                    self.estimate = Some((tm.estimate.position_m, tm.estimate.q));
                    self.frames(*station_time_us);
                }
            }
            LogRecord::Truth { position_m, attitude_rad, .. } => {
                let att = geometry::frames::Attitude {
                    roll: attitude_rad[0],
                    pitch: attitude_rad[1],
                    yaw: attitude_rad[2],
                };
                let p = Vec3::new(position_m[0], position_m[1], position_m[2]);
                self.truth = Some((p, Quat::from_mat3(&att.world_from_body())));
            }
            _ => {}
        }
    }

    /// The body frames of the estimate and the truth, and, every `SCENE_EVERY_US`, the scene.
    fn frames(&mut self, t_us: u64) {
        let mut transforms = Vec::new();
        let tf = |child: &str, (p, q): (Vec3, Quat)| FrameTransform {
            timestamp: stamp(t_us),
            parent_frame_id: "world".into(),
            child_frame_id: child.into(),
            translation: v3(p),
            rotation: quat(q),
        };
        if let Some(e) = self.estimate {
            transforms.push(tf("base_link", e));
        }
        if let Some(t) = self.truth {
            transforms.push(tf("base_link_truth", t));
        }
        if !transforms.is_empty() && self.transforms.has_sinks() {
            self.transforms.log_with_meta(&FrameTransforms { transforms }, meta(t_us));
            self.messages += 1;
        }
        if t_us >= self.next_scene_us && self.scene.has_sinks() {
            self.next_scene_us = t_us + SCENE_EVERY_US;
            self.scene.log_with_meta(&scene(&self.scenario, t_us, self.truth.is_some()), meta(t_us));
            self.messages += 1;
        }
    }

    fn forward(&mut self, t_us: u64, img: &RgbImage, detection: Option<&LineObservation>) {
        if self.forward_annotations.has_sinks() {
            let annotations = forward_annotations(&self.scenario, t_us, detection, self.estimate);
            self.forward_annotations.log_with_meta(&annotations, meta(t_us));
            self.messages += 1;
        }
        if !self.forward_image.has_sinks() {
            return;
        }
        let mut jpeg = Vec::new();
        let enc = jpeg_encoder::Encoder::new(&mut jpeg, FORWARD_JPEG_QUALITY);
        if enc.encode(&img.data, img.width as u16, img.height as u16, jpeg_encoder::ColorType::Rgb).is_err() {
            return;
        }
        let msg = CompressedImage {
            timestamp: stamp(t_us),
            frame_id: "camera_forward".into(),
            data: jpeg.into(),
            format: "jpeg".into(),
        };
        self.forward_image.log_with_meta(&msg, meta(t_us));
        self.messages += 1;
        self.forward_images += 1;
    }

    fn down(&mut self, t_us: u64, img: &GrayImage, tracks: &[(Vec2, Vec2, bool)]) {
        if self.down_annotations.has_sinks() {
            self.down_annotations.log_with_meta(&down_annotations(t_us, tracks), meta(t_us));
            self.messages += 1;
        }
        if !self.down_image.has_sinks() {
            return;
        }
        let msg = RawImage {
            timestamp: stamp(t_us),
            frame_id: "camera_down".into(),
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

/// Where the forward camera sees the line's corners from a body pose (world position, attitude), or None
/// when a corner is behind it.
pub fn reprojected_corners(s: &Scenario, (p, q): (Vec3, Quat)) -> Option<[Vec2; 4]> {
    let cam = s.forward_camera_model();
    let mount = s.forward_camera_mount();
    let r_wb = q.to_mat3();
    let target = s.line_target();
    let mut out = [Vec2::ZERO; 4];
    for (o, c) in out.iter_mut().zip(Corner::ALL) {
        let body = r_wb.transpose().mul_vec(target.corner(c) - p) - mount.offset_body_m;
        let pc = mount.body_from_camera.transpose().mul_vec(body);
        if pc.z < 0.05 {
            return None;
        }
        *o = cam.normalized_to_pixel(Vec2::new(pc.x / pc.z, pc.y / pc.z));
    }
    Some(out)
}

/// The forward image's annotations: the detected edges (green, the ends cyan), the corners (yellow) and the
/// line reprojected from the estimate (magenta).
fn forward_annotations(
    s: &Scenario,
    t_us: u64,
    detection: Option<&LineObservation>,
    estimate: Option<(Vec3, Quat)>,
) -> ImageAnnotations {
    let cam = s.forward_camera_model();
    let mut out = ImageAnnotations { timestamp: stamp(t_us), ..Default::default() };
    if let Some(obs) = detection {
        for (edge, rgba) in [
            (Some(obs.top), [0.0, 1.0, 0.0, 1.0]),
            (Some(obs.bottom), [0.0, 1.0, 0.0, 1.0]),
            (obs.start_end, [0.0, 0.8, 1.0, 1.0]),
            (obs.finish_end, [0.0, 0.8, 1.0, 1.0]),
        ] {
            let Some(e) = edge else { continue };
            let (a, b) = e.extent();
            let pts = vec![px(cam.normalized_to_pixel(a)), px(cam.normalized_to_pixel(b))];
            out.points.push(points(points_annotation::Type::LineList, pts, rgba, 2.0));
        }
        let corners: Vec<Point2> = obs.corners_px(&cam).into_iter().flatten().map(px).collect();
        if !corners.is_empty() {
            out.points.push(points(points_annotation::Type::Points, corners, [1.0, 1.0, 0.0, 1.0], 8.0));
        }
    }
    if let Some(c) = estimate.and_then(|e| reprojected_corners(s, e)) {
        out.points.push(points(
            points_annotation::Type::LineLoop,
            c.iter().map(|p| px(*p)).collect(),
            [1.0, 0.0, 1.0, 0.9],
            1.5,
        ));
    }
    out
}

/// The downward image's annotations: each track's start (green when the velocity used it, red when not)
/// and its flow drawn five times longer.
fn down_annotations(t_us: u64, tracks: &[(Vec2, Vec2, bool)]) -> ImageAnnotations {
    const SCALE: f32 = 5.0;
    let mut out = ImageAnnotations { timestamp: stamp(t_us), ..Default::default() };
    for (inlier, rgba) in [(true, [0.0, 1.0, 0.0, 1.0]), (false, [1.0, 0.2, 0.2, 1.0])] {
        let sel: Vec<_> = tracks.iter().filter(|t| t.2 == inlier).collect();
        if sel.is_empty() {
            continue;
        }
        out.points.push(points(
            points_annotation::Type::Points,
            sel.iter().map(|t| px(t.0)).collect(),
            rgba,
            4.0,
        ));
        let lines = sel.iter().flat_map(|t| [px(t.0), px(t.0 + t.1 * SCALE)]).collect();
        out.points.push(points(points_annotation::Type::LineList, lines, rgba, 1.0));
    }
    out
}

/// The wall, the line, and the vehicle as the estimate and (in simulation) the truth place it.
fn scene(s: &Scenario, t_us: u64, with_truth: bool) -> SceneUpdate {
    let target = s.line_target();
    let (x0, x1) = (target.x_start_m.min(0.0) - 1.0, target.x_end_m.max(0.0) + 1.0);
    let height = (target.z_top_m + 1.0).max(2.0);
    let entity =
        |id: &str, frame: &str, cubes: Vec<CubePrimitive>, cylinders: Vec<CylinderPrimitive>| SceneEntity {
            timestamp: stamp(t_us),
            frame_id: frame.into(),
            id: id.into(),
            frame_locked: frame != "world",
            cubes,
            cylinders,
            ..Default::default()
        };
    let cube = |centre: Vec3, size: Vec3, rgba: [f64; 4]| CubePrimitive {
        pose: pose(centre, Quat::IDENTITY),
        size: v3(size),
        color: color(rgba[0], rgba[1], rgba[2], rgba[3]),
    };
    // The wall is the plane y = 0 of the world frame (docs/frames.md), seen from y > 0.
    let wall = cube(
        Vec3::new(0.5 * (x0 + x1), -0.01, 0.5 * height),
        Vec3::new(x1 - x0, 0.02, height),
        [0.85, 0.85, 0.8, 1.0],
    );
    let line = cube(
        Vec3::new(
            0.5 * (target.x_start_m + target.x_end_m),
            0.001,
            0.5 * (target.z_bottom_m + target.z_top_m),
        ),
        Vec3::new(target.length_m(), 0.004, target.height_m()),
        [0.9, 0.05, 0.05, 1.0],
    );
    let vehicle = |alpha: f64| {
        let arm = s.vehicle.arm_length_m;
        let rgba = [0.2, 0.3, 0.9, alpha];
        let cubes = vec![
            cube(Vec3::ZERO, Vec3::new(0.12, 0.12, 0.05), rgba),
            cube(Vec3::ZERO, Vec3::new(2.0 * arm, 0.02, 0.02), rgba),
            cube(Vec3::ZERO, Vec3::new(0.02, 2.0 * arm, 0.02), rgba),
        ];
        let rotors = [
            Vec3::new(arm, 0.0, 0.03),
            Vec3::new(-arm, 0.0, 0.03),
            Vec3::new(0.0, arm, 0.03),
            Vec3::new(0.0, -arm, 0.03),
        ]
        .into_iter()
        .map(|c| CylinderPrimitive {
            pose: pose(c, Quat::IDENTITY),
            size: v3(Vec3::new(0.2, 0.2, 0.01)),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: color(0.1, 0.1, 0.1, alpha * 0.6),
        })
        .collect();
        (cubes, rotors)
    };
    let mut entities = vec![entity("wall", "world", vec![wall, line], vec![])];
    let (cubes, rotors) = vehicle(1.0);
    entities.push(entity("vehicle_estimate", "base_link", cubes, rotors));
    if with_truth {
        let (cubes, rotors) = vehicle(0.35);
        entities.push(entity("vehicle_truth", "base_link_truth", cubes, rotors));
    }
    SceneUpdate { deletions: vec![], entities }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_reprojects_where_the_renderer_draws_it() {
        // Level, 1.3 m from the wall, facing it from the line's middle at its height: the line's image is
        // centred, its long edges horizontal and symmetric about the principal point's column.
        let s = Scenario::paper();
        let t = s.line_target();
        let mount = s.forward_camera_mount();
        let yaw = s.flight_params().trajectory.yaw_d_rad;
        let q = Quat::from_mat3(&geometry::frames::Attitude { roll: 0.0, pitch: 0.0, yaw }.world_from_body());
        let cam_height = 0.5 * (t.z_bottom_m + t.z_top_m);
        let p = Vec3::new(0.5 * (t.x_start_m + t.x_end_m), 1.3, cam_height)
            - q.to_mat3().mul_vec(mount.offset_body_m);
        let c = reprojected_corners(&s, (p, q)).expect("in front of the camera");
        let cam = s.forward_camera_model();
        let mid = (c[0] + c[1] + c[2] + c[3]) * 0.25;
        assert!((mid.x - cam.cx).abs() < 1.0 && (mid.y - cam.cy).abs() < 1.0, "{c:?}");
        // Corner A (start, bottom) and D (finish, bottom) on one row; B and C above them.
        assert!((c[0].y - c[3].y).abs() < 0.5 && (c[1].y - c[2].y).abs() < 0.5, "{c:?}");
        assert!(c[1].y < c[0].y, "{c:?}");
        // The image's size of the line: 2.30 m at 1.3 m with the scenario's focal length.
        let width = (c[3].x - c[0].x).abs();
        let expected = cam.fx * t.length_m() / 1.3;
        assert!((width - expected).abs() < 0.02 * expected, "{width} vs {expected}");
        // Behind the camera: none.
        let behind = Vec3::new(p.x, -1.0, p.z);
        assert!(reprojected_corners(&s, (behind, q)).is_none());
    }

    #[test]
    fn flow_annotations_split_inliers_from_outliers() {
        let tracks = [
            (Vec2::new(10.0, 20.0), Vec2::new(1.0, 0.0), true),
            (Vec2::new(30.0, 40.0), Vec2::new(0.0, 2.0), false),
            (Vec2::new(50.0, 60.0), Vec2::new(-1.0, 0.0), true),
        ];
        let a = down_annotations(7_000_000, &tracks);
        assert_eq!(a.points.len(), 4);
        assert_eq!(a.points[0].points.len(), 2);
        assert_eq!(a.points[1].points.len(), 4);
        assert_eq!(a.points[1].points[1], Point2 { x: 15.0, y: 20.0 });
        assert_eq!(a.points[2].points, vec![Point2 { x: 30.0, y: 40.0 }]);
        assert_eq!(a.timestamp, stamp(7_000_000));
        assert!(down_annotations(0, &[]).points.is_empty());
    }
}
