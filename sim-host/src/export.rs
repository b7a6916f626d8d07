//! Export of a flight log to the formats engineers' tools open: MCAP (Foxglove, Lichtblick, PlotJuggler,
//! Rerun) and CSV (spreadsheets, pandas, MATLAB).
//!
//! Both exports split the log into the same topics (docs/log-format.md, "Export"). In MCAP, whatever has a
//! Foxglove well-known schema goes in the `foxglove` crate's typed schemas, protobuf-encoded, so that 3D and
//! image panels show it without configuration: the poses (`foxglove.PoseInFrame`), the camera images
//! (`foxglove.CompressedImage` for PNG frames, `foxglove.RawImage` for raw ones), the line reprojected from the
//! estimate over the forward image (`foxglove.ImageAnnotations`), the body frames (`foxglove.FrameTransforms`)
//! and the scene (`foxglove.SceneUpdate`, from the log header's scenario). Our own records are JSON messages
//! with a JSON Schema. Message times are the records' clock: a step's outputs at the step's time, a radio
//! message at the step that received it, a frame at its capture time, a station's records at the station's.
use crate::flightlog::{CameraId, LogHeader, LogItem, LogRecord, StationEvent};
use crate::foxglove_msgs::{self as fx, Bodies, Image};
use crate::scenario::Scenario;
use anyhow::{Context, Result};
use foxglove::Encode;
use foxglove::messages::PoseInFrame;
use geometry::Vec3;
use geometry::frames::Attitude;
use serde_json::{Map, Value, json};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// A topic's message: name, schema name, time (us), content.
pub(crate) struct Msg {
    pub(crate) topic: &'static str,
    pub(crate) schema: &'static str,
    pub(crate) time_us: u64,
    pub(crate) body: Body,
}

/// A message's content: one of our records as JSON, or a pose in Foxglove's typed schema.
pub(crate) enum Body {
    /// JSON with the `timestamp` and `t_s` fields first (a JSON Schema named by [`Msg::schema`]).
    Json(Value),
    /// `foxglove.PoseInFrame`.
    Pose(PoseInFrame),
}

impl Body {
    /// The content as JSON (CSV cells; a pose as its `foxglove.PoseInFrame` fields with the time).
    pub(crate) fn to_json(&self, time_us: u64) -> Value {
        match self {
            Body::Json(v) => v.clone(),
            Body::Pose(p) => {
                let (pos, q) = p
                    .pose
                    .as_ref()
                    .map(|x| (x.position.unwrap_or_default(), x.orientation.unwrap_or_default()))
                    .unwrap_or_default();
                with_time(
                    time_us,
                    json!({"frame_id": p.frame_id,
                           "pose": {"position": {"x": pos.x, "y": pos.y, "z": pos.z},
                                    "orientation": {"x": q.x, "y": q.y, "z": q.z, "w": q.w}}}),
                )
            }
        }
    }
}

fn stamp(time_us: u64) -> Value {
    json!({"sec": time_us / 1_000_000, "nsec": (time_us % 1_000_000) * 1000})
}

fn xyz(v: [f32; 3]) -> Value {
    json!({"x": v[0], "y": v[1], "z": v[2]})
}

fn pose_msg(topic: &'static str, time_us: u64, p: [f32; 3], q: geometry::Quat) -> Msg {
    Msg {
        topic,
        schema: "foxglove.PoseInFrame",
        time_us,
        body: Body::Pose(fx::pose_in_frame(time_us, "world", Vec3::new(p[0], p[1], p[2]), q)),
    }
}

/// A JSON message with its time.
fn timed(time_us: u64, v: Value) -> Body {
    Body::Json(with_time(time_us, v))
}

fn with_time(time_us: u64, v: Value) -> Value {
    let mut m = Map::new();
    m.insert("timestamp".into(), stamp(time_us));
    m.insert("t_s".into(), json!(time_us as f64 * 1e-6));
    match v {
        Value::Object(o) => m.extend(o),
        other => {
            m.insert("value".into(), other);
        }
    }
    Value::Object(m)
}

/// The topics of one record (camera frames aside). `step_us` is the time of the last step.
pub(crate) fn topics(r: &LogRecord, step_us: u64, out: &mut Vec<Msg>) {
    let v = |x: &dyn erased::Ser| x.json();
    match r {
        LogRecord::Step(s) => {
            for i in &s.imu {
                out.push(Msg {
                    topic: "/imu",
                    schema: "wlq.ImuSample",
                    time_us: i.time_us,
                    body: timed(
                        i.time_us,
                        json!({"gyro_rad_s": xyz(i.gyro_rad_s), "accel_m_s2": xyz(i.accel_m_s2)}),
                    ),
                });
            }
            if let Some(m) = s.mag {
                out.push(Msg {
                    topic: "/mag",
                    schema: "wlq.Magnetometer",
                    time_us: s.time_us,
                    body: timed(s.time_us, json!({"field": xyz(m.to_array())})),
                });
            }
        }
        LogRecord::Report(rep) => {
            let c = &rep.control;
            let e = &c.estimate;
            out.push(pose_msg("/estimate/pose", step_us, e.position_m.to_array(), e.q));
            let mut est = v(e);
            if let Value::Object(o) = &mut est {
                o.insert(
                    "attitude_deg".into(),
                    json!({"roll": e.attitude.roll.to_degrees(), "pitch": e.attitude.pitch.to_degrees(),
                           "yaw": e.attitude.yaw.to_degrees()}),
                );
            }
            out.push(Msg {
                topic: "/estimate",
                schema: "wlq.StateEstimate",
                time_us: step_us,
                body: timed(step_us, est),
            });
            out.push(Msg {
                topic: "/setpoint",
                schema: "wlq.Setpoint",
                time_us: step_us,
                body: timed(step_us, v(&c.setpoint)),
            });
            out.push(Msg {
                topic: "/motors",
                schema: "wlq.MotorCommands",
                time_us: step_us,
                body: timed(step_us, json!({"rad_s": c.motors_rad_s})),
            });
            out.push(Msg {
                topic: "/status",
                schema: "wlq.Status",
                time_us: step_us,
                body: timed(step_us, v(&c.status)),
            });
            out.push(Msg {
                topic: "/counters",
                schema: "wlq.Counters",
                time_us: step_us,
                body: timed(
                    step_us,
                    json!({"vision": v(&rep.vision), "flow": v(&rep.flow_counters), "estimator": v(&rep.estimator)}),
                ),
            });
            if let Some(f) = &rep.flow {
                out.push(Msg {
                    topic: "/flow/outcome",
                    schema: "wlq.FlowOutcome",
                    time_us: step_us,
                    body: timed(step_us, v(f)),
                });
            }
        }
        LogRecord::Link(m) => {
            // Packed measurements as the vehicle unpacked them (protocol::packed).
            let (topic, schema, value) = match (m.vision(), m.flow()) {
                (Some(x), _) => ("/link/vision", "wlq.VisionMeasurement", v(&x)),
                (_, Some(x)) => ("/link/flow", "wlq.FlowMeasurement", v(&x)),
                _ => ("/link/other", "wlq.Uplink", v(m)),
            };
            out.push(Msg { topic, schema, time_us: step_us, body: timed(step_us, value) });
        }
        LogRecord::Downlink(d) => {
            let (topic, schema, time_us, value) = match (d.telemetry(), d) {
                (Some(t), _) => ("/downlink/telemetry", "wlq.Telemetry", t.time_us, v(&t)),
                (_, protocol::Downlink::Battery(b)) => {
                    ("/downlink/battery", "wlq.BatteryStatus", step_us, v(b))
                }
                _ => ("/downlink/other", "wlq.Downlink", step_us, v(d)),
            };
            out.push(Msg { topic, schema, time_us, body: timed(time_us, value) });
        }
        LogRecord::Truth { time_us, position_m, velocity_m_s, attitude_rad } => {
            let att = Attitude { roll: attitude_rad[0], pitch: attitude_rad[1], yaw: attitude_rad[2] };
            let q = geometry::Quat::from_mat3(&att.world_from_body());
            out.push(pose_msg("/truth/pose", *time_us, *position_m, q));
            out.push(Msg {
                topic: "/truth",
                schema: "wlq.Truth",
                time_us: *time_us,
                body: timed(
                    *time_us,
                    json!({"position_m": xyz(*position_m), "velocity_m_s": xyz(*velocity_m_s),
                           "attitude_deg": {"roll": attitude_rad[0].to_degrees(),
                                            "pitch": attitude_rad[1].to_degrees(),
                                            "yaw": attitude_rad[2].to_degrees()}}),
                ),
            });
        }
        LogRecord::Reference(r) => {
            let [w, x, y, z] = r.q_world_body;
            let q = geometry::Quat { w, x, y, z };
            let att = Attitude::from_world_from_body(&q.to_mat3());
            out.push(pose_msg("/reference/pose", r.time_us, r.position_m.unwrap_or([0.0; 3]), q));
            out.push(Msg {
                topic: "/reference",
                schema: "wlq.Reference",
                time_us: r.time_us,
                body: timed(
                    r.time_us,
                    json!({"attitude_deg": {"roll": att.roll.to_degrees(), "pitch": att.pitch.to_degrees(),
                                            "yaw": att.yaw.to_degrees()},
                           "q_world_body": r.q_world_body,
                           "position_m": r.position_m.map(xyz),
                           "airborne": r.airborne}),
                ),
            });
        }
        // A ground station's records, at the station's time (us since the Unix epoch).
        LogRecord::Station(e) => {
            let time_us = e.station_time_us();
            let (topic, schema, value) = match e {
                StationEvent::Sent { message, .. } => match (message.vision(), message.flow()) {
                    (Some(x), _) => ("/station/uplink/vision", "wlq.VisionMeasurement", v(&x)),
                    (_, Some(x)) => ("/station/uplink/flow", "wlq.FlowMeasurement", v(&x)),
                    _ => ("/station/uplink/other", "wlq.Uplink", v(message)),
                },
                StationEvent::Received { message, .. } => match message.telemetry() {
                    Some(t) => ("/station/downlink/telemetry", "wlq.Telemetry", v(&t)),
                    None => ("/station/downlink/other", "wlq.Downlink", v(message)),
                },
                StationEvent::Clock { vehicle_time_us, bound_us, .. } => (
                    "/station/clock",
                    "wlq.StationClock",
                    json!({"vehicle_time_us": vehicle_time_us, "bound_us": bound_us}),
                ),
            };
            out.push(Msg { topic, schema, time_us, body: timed(time_us, value) });
        }
        // The pilot's transmitter as the flight stack got it for the next step, at the time of the step before
        // (the record precedes the step it goes to).
        LogRecord::Pilot(p) => out.push(Msg {
            topic: "/pilot",
            schema: "wlq.PilotInput",
            time_us: step_us,
            body: timed(step_us, v(p)),
        }),
        // A battery reading for the next step, likewise.
        LogRecord::Battery(b) => out.push(Msg {
            topic: "/battery/reading",
            schema: "wlq.BatteryReading",
            time_us: step_us,
            body: timed(step_us, v(b)),
        }),
        // Frames have topics of their own; the end record is the file's, not the flight's.
        LogRecord::Frame(_) | LogRecord::End { .. } => {}
    }
}

/// Serialisation to JSON values of any serde type, behind one object-safe trait. A value serde cannot
/// represent in JSON becomes an object naming the error, never a silent `null`.
mod erased {
    pub trait Ser {
        fn json(&self) -> serde_json::Value;
    }
    impl<T: serde::Serialize> Ser for T {
        fn json(&self) -> serde_json::Value {
            serde_json::to_value(self)
                .unwrap_or_else(|e| serde_json::json!({"serialisation_error": e.to_string()}))
        }
    }
}

/// The image topic of a camera.
pub(crate) fn camera_topic(c: CameraId) -> &'static str {
    match c {
        CameraId::Forward => "/camera/forward/image",
        CameraId::Downward => "/camera/down/image",
    }
}

/// The forward image's annotations topic (the line reprojected from the estimate; live, also the detection).
pub(crate) const FORWARD_ANNOTATIONS: &str = "/camera/forward/annotations";
/// The body frames' topic.
pub(crate) const TRANSFORMS: &str = "/tf";
/// The scene's topic.
pub(crate) const SCENE: &str = "/scene";

/// JSON Schema of one of our records' channels: an object named after the record, with its time fields.
pub(crate) fn schema_of(name: &str) -> Value {
    let time =
        json!({"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}});
    json!({"title": name, "type": "object", "properties": {"timestamp": time, "t_s": {"type": "number"}}})
}

/// The intact records, each with the time of the last step before it (the time of a step's outputs and of the
/// radio messages it received); damaged stretches go to `damage`.
fn with_step_time<'a>(
    records: impl Iterator<Item = LogItem> + 'a,
    damage: &'a mut Vec<crate::flightlog::LogDamage>,
) -> impl Iterator<Item = (u64, LogRecord)> + 'a {
    let mut step_us = 0u64;
    records.filter_map(move |item| match item {
        Ok((_, r)) => {
            if let LogRecord::Step(s) = &r {
                step_us = s.time_us;
            }
            Some((step_us, r))
        }
        Err(d) => {
            damage.push(d);
            None
        }
    })
}

/// What an export wrote.
#[derive(Clone, Debug, Default)]
pub struct ExportSummary {
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// Damaged stretches of the log (skipped).
    pub damage: Vec<crate::flightlog::LogDamage>,
    /// What could not be written, and why (e.g. the scene of a log whose header has no scenario).
    pub notes: Vec<String>,
}

/// Writes a log's topics as an MCAP file.
pub fn export_mcap(
    header: &LogHeader,
    records: impl Iterator<Item = LogItem>,
    path: &Path,
) -> Result<ExportSummary> {
    export_mcap_to(header, records, crate::files::AtomicFile::create(path)?)
}

/// [`export_mcap`] into `file` (renamed into place when complete). A failed write (a full disk) keeps what
/// was written as `NAME.partial` (an MCAP without its summary, which `mcap recover` reads) and says so.
pub fn export_mcap_to(
    header: &LogHeader,
    records: impl Iterator<Item = LogItem>,
    file: crate::files::AtomicFile,
) -> Result<ExportSummary> {
    let opts =
        mcap::WriteOptions::new().profile("").library(format!("sim-host {}", env!("CARGO_PKG_VERSION")));
    let mut w = opts.create(file)?;
    let result = write_mcap(header, records, &mut w);
    let file = w.into_inner();
    match result {
        Ok(summary) => {
            file.commit()?;
            Ok(summary)
        }
        Err(e) => Err(file.give_up(e)),
    }
}

/// The MCAP writer's channels: one per topic, a schema shared by the topics of one record type.
struct Channels {
    schemas: BTreeMap<String, u16>,
    channels: BTreeMap<&'static str, (u16, u32)>,
}

impl Channels {
    /// Writes one message on `topic` (the channel and its schema are written before its first message).
    #[allow(clippy::too_many_arguments)]
    fn put(
        &mut self,
        w: &mut mcap::Writer<crate::files::AtomicFile>,
        summary: &mut ExportSummary,
        topic: &'static str,
        schema: impl FnOnce() -> Result<foxglove::Schema>,
        message_encoding: &str,
        time_us: u64,
        data: &[u8],
    ) -> Result<()> {
        let (id, seq) = match self.channels.get_mut(topic) {
            Some(c) => c,
            None => {
                let schema = schema()?;
                let sid = match self.schemas.get(&schema.name) {
                    Some(&sid) => sid,
                    None => {
                        let sid = w.add_schema(&schema.name, &schema.encoding, &schema.data)?;
                        self.schemas.insert(schema.name.clone(), sid);
                        sid
                    }
                };
                let id = w.add_channel(sid, topic, message_encoding, &BTreeMap::new())?;
                self.channels.entry(topic).or_insert((id, 0))
            }
        };
        *seq += 1;
        let t = time_us * 1000;
        w.write_to_known_channel(
            &mcap::records::MessageHeader { channel_id: *id, sequence: *seq, log_time: t, publish_time: t },
            data,
        )?;
        *summary.messages.entry(topic.to_string()).or_insert(0) += 1;
        Ok(())
    }

    /// Writes a message of one of Foxglove's typed schemas (protobuf).
    fn put_typed<T: Encode>(
        &mut self,
        w: &mut mcap::Writer<crate::files::AtomicFile>,
        summary: &mut ExportSummary,
        topic: &'static str,
        time_us: u64,
        msg: &T,
    ) -> Result<()> {
        let mut buf = Vec::with_capacity(msg.encoded_len().unwrap_or(64));
        msg.encode(&mut buf).map_err(|e| anyhow::anyhow!("{topic}: cannot encode the message: {e}"))?;
        let schema = || T::get_schema().with_context(|| format!("{topic}: the message type has no schema"));
        self.put(w, summary, topic, schema, &T::get_message_encoding(), time_us, &buf)
    }
}

fn write_mcap(
    header: &LogHeader,
    records: impl Iterator<Item = LogItem>,
    w: &mut mcap::Writer<crate::files::AtomicFile>,
) -> Result<ExportSummary> {
    // The log's header as MCAP metadata: the scenario and how it flew.
    let mut meta = BTreeMap::new();
    meta.insert("scenario_toml".to_string(), header.scenario_toml.clone());
    meta.insert("seed".to_string(), header.seed.to_string());
    meta.insert("camera".to_string(), header.camera.clone());
    meta.insert("flight_computer".to_string(), header.flight_computer.clone());
    meta.insert("writer".to_string(), header.writer.clone());
    meta.insert("log_schema_hash".to_string(), header.schema_hash.clone());
    w.write_metadata(&mcap::records::Metadata { name: "flight".into(), metadata: meta })?;
    let mut summary = ExportSummary::default();
    // The scene and the reprojected line need the flight's scenario (the wall, the line, the camera).
    let scenario = match Scenario::from_toml(&header.scenario_toml) {
        Ok(s) => Some(s),
        Err(e) => {
            summary.notes.push(format!(
                "no {SCENE} and no {FORWARD_ANNOTATIONS}: the log header's scenario does not load ({e})"
            ));
            None
        }
    };
    let mut ch = Channels { schemas: BTreeMap::new(), channels: BTreeMap::new() };
    let mut bodies = Bodies::default();
    let mut msgs = Vec::new();
    let mut damage = Vec::new();
    for (_, r) in with_step_time(records, &mut damage) {
        let changed = bodies.update(&r);
        if let LogRecord::Frame(f) = &r {
            let (topic, t) = (camera_topic(f.camera), f.capture_time_us);
            match fx::image_message(f) {
                Image::Compressed(m) => ch.put_typed(w, &mut summary, topic, t, &m)?,
                Image::Raw(m) => ch.put_typed(w, &mut summary, topic, t, &m)?,
            }
            if let (CameraId::Forward, Some(s)) = (f.camera, &scenario) {
                let a = fx::forward_annotations(s, t, None, bodies.estimate);
                ch.put_typed(w, &mut summary, FORWARD_ANNOTATIONS, t, &a)?;
            }
            continue;
        }
        msgs.clear();
        topics(&r, bodies.step_us, &mut msgs);
        for m in &msgs {
            match &m.body {
                Body::Json(v) => {
                    let schema = || {
                        let data = serde_json::to_vec(&schema_of(m.schema))?;
                        Ok(foxglove::Schema::new(m.schema, "jsonschema", data))
                    };
                    ch.put(w, &mut summary, m.topic, schema, "json", m.time_us, &serde_json::to_vec(v)?)?
                }
                Body::Pose(p) => ch.put_typed(w, &mut summary, m.topic, m.time_us, p)?,
            }
        }
        if let Some(t) = changed {
            if let Some(tf) = bodies.transforms(t) {
                ch.put_typed(w, &mut summary, TRANSFORMS, t, &tf)?;
            }
            if let Some(s) = &scenario
                && bodies.scene_due(t)
            {
                ch.put_typed(w, &mut summary, SCENE, t, &fx::scene(s, t, bodies.truth.is_some()))?;
            }
        }
    }
    summary.damage = damage;
    w.finish()?;
    Ok(summary)
}

/// A CSV table being built: the columns, then each row's (column, cell) pairs.
type Table = (Vec<String>, Vec<Vec<(String, String)>>);

/// Writes a log's topics as CSV files in `dir`, one per topic (`/estimate/pose` -> `estimate_pose.csv`),
/// nested fields flattened into dotted column names; camera frames are listed in `frames.csv`.
pub fn export_csv(
    _header: &LogHeader,
    records: impl Iterator<Item = LogItem>,
    dir: &Path,
) -> Result<ExportSummary> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    // Rows per topic, kept until the end so that each file's columns are the union over its rows.
    let mut tables: BTreeMap<&'static str, Table> = BTreeMap::new();
    let mut summary = ExportSummary::default();
    let mut msgs = Vec::new();
    for (step_us, r) in with_step_time(records, &mut summary.damage) {
        msgs.clear();
        if let LogRecord::Frame(f) = &r {
            msgs.push(Msg {
                topic: "/frames",
                schema: "",
                time_us: f.capture_time_us,
                body: timed(
                    f.capture_time_us,
                    json!({"camera": f.camera, "seq": f.seq, "width": f.width, "height": f.height,
                           "channels": f.channels, "encoding": f.encoding, "bytes": f.data.len()}),
                ),
            });
        } else {
            topics(&r, step_us, &mut msgs);
        }
        for m in msgs.drain(..) {
            let mut row = Vec::new();
            flatten(&m.body.to_json(m.time_us), String::new(), &mut row);
            row.retain(|(k, _)| !k.starts_with("timestamp."));
            let t = tables.entry(m.topic).or_default();
            for (k, _) in &row {
                if !t.0.contains(k) {
                    t.0.push(k.clone());
                }
            }
            t.1.push(row);
            *summary.messages.entry(m.topic.to_string()).or_insert(0) += 1;
        }
    }
    for (topic, (cols, rows)) in &mut tables {
        // Time first.
        if let Some(i) = cols.iter().position(|c| c == "t_s") {
            let c = cols.remove(i);
            cols.insert(0, c);
        }
        let name = format!("{}.csv", topic.trim_start_matches('/').replace('/', "_"));
        let path = dir.join(name);
        let mut s = cols.join(",") + "\n";
        for row in rows {
            let map: BTreeMap<&str, &str> = row.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
            let cells: Vec<&str> = cols.iter().map(|c| map.get(c.as_str()).copied().unwrap_or("")).collect();
            s.push_str(&cells.join(","));
            s.push('\n');
        }
        let mut file = crate::files::AtomicFile::create(&path)?;
        match file.write_all(s.as_bytes()) {
            Ok(()) => file.commit()?,
            Err(e) => return Err(file.give_up(e.into())),
        }
    }
    Ok(summary)
}

/// Flattens JSON into (dotted path, cell) pairs; arrays index as `name[0]`; null is an empty cell.
fn flatten(v: &Value, path: String, out: &mut Vec<(String, String)>) {
    match v {
        Value::Object(o) => {
            for (k, x) in o {
                let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                flatten(x, p, out);
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                flatten(x, format!("{path}[{i}]"), out);
            }
        }
        Value::Null => out.push((path, String::new())),
        Value::String(s) => out.push((path, csv_cell(s))),
        other => out.push((path, other.to_string())),
    }
}

fn csv_cell(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_values_flatten_to_dotted_columns() {
        let mut row = Vec::new();
        flatten(&json!({"a": {"b": 1, "c": [2, 3]}, "d": null, "e": "x,y"}), String::new(), &mut row);
        let cols: Vec<&str> = row.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(cols, ["a.b", "a.c[0]", "a.c[1]", "d", "e"]);
        assert_eq!(row[4].1, "\"x,y\"");
        assert_eq!(row[3].1, "");
    }
}
