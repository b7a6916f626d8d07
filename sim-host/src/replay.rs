//! Replay: the flight stack re-run on a log's inputs, every output compared with the log's bit for bit.
//!
//! The stack is built from the scenario in the log's header (its parameters), optionally with parameters
//! changed; it then steps on each `Step` record with the `Link` records before it, runs the background work
//! after each step as every flight computer does, and compares the report with the log's next `Report`
//! record and the downlink messages with the log's `Downlink` records, through their encoded bytes (so a NaN
//! or a signed zero counts). The first difference is named by record, byte offset, time and field path, with
//! both values.
//!
//! From frames ([`VisionSource::Frames`]), the ground station's vision runs again on the logged camera frames
//! (`vision-core`'s line detector on the forward frames, its optical flow on the downward frames, with the
//! logged rotation hint): each measurement is compared with the logged one and the recomputed one is what the
//! stack receives, at the logged delivery time.
use crate::downward::GroundFlow;
use crate::flightlog::{CameraId, LogDamage, LogHeader, LogItem, LogRecord, LogWriter};
use crate::imageio::FrameImages;
use crate::scenario::Scenario;
use crate::vision::GroundVision;
use anyhow::{Result, bail};
use control_core::ParamOutcome;
use control_core::params::ParamId;
use flight_core::telemetry::DownlinkSchedule;
use flight_core::{FlightStack, StepInput, StepReport};
use protocol::{Downlink, FlowMeasurement, PackedFlow, PackedVision, Uplink, VisionMeasurement};
use serde::Serialize;
use serde_json::Value;
use std::collections::{HashMap, VecDeque};
use vision_core::LineObservation;
use vision_core::flow::{FlowStats, NoFlowReason};

/// Where the stack's vision measurements come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VisionSource {
    /// The logged measurements (`Link` records): fast.
    Logged,
    /// Recomputed from the logged camera frames by `vision-core`.
    Frames,
}

/// Replay options.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    /// Parameter changes before the first step.
    pub overrides: Vec<(ParamId, f32)>,
    /// Where vision measurements come from.
    pub vision: VisionSource,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self { overrides: Vec::new(), vision: VisionSource::Logged }
    }
}

/// The first output that differs.
#[derive(Clone, Debug, PartialEq)]
pub struct Difference {
    /// Index of the record in the log (counting intact records).
    pub record: usize,
    /// Its byte offset in the file.
    pub offset: usize,
    /// Its kind (`report`, `downlink`, `vision` or `flow` for a measurement recomputed from a frame).
    pub kind: &'static str,
    /// Time of its step or frame (us).
    pub time_us: u64,
    /// Path of the first differing field (`control.motors_rad_s[2]`).
    pub field: String,
    /// The logged value.
    pub logged: String,
    /// The replayed value.
    pub replayed: String,
}

impl std::fmt::Display for Difference {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "record {} ({}, byte {}), t = {:.3} s: {} logged {} replayed {}",
            self.record,
            self.kind,
            self.offset,
            self.time_us as f64 * 1e-6,
            self.field,
            self.logged,
            self.replayed
        )
    }
}

/// What a replay found.
#[derive(Clone, Debug, Default)]
pub struct ReplaySummary {
    /// Steps re-run.
    pub steps: u64,
    /// Radio messages fed.
    pub links: u64,
    /// Reports compared.
    pub compared: u64,
    /// Reports that differ.
    pub differing: u64,
    /// Downlink messages compared.
    pub downlinks_compared: u64,
    /// Downlink messages that differ (or are missing or extra).
    pub downlinks_differing: u64,
    /// Camera frames read.
    pub frames: u64,
    /// Measurements recomputed from frames and compared with the logged ones.
    pub measurements_compared: u64,
    /// Of those, the ones that differ.
    pub measurements_differing: u64,
    /// Logged measurements without their frame (fed as logged).
    pub measurements_without_frame: u64,
    /// Forward frames in which the re-run detector found no line, by its reason.
    pub no_target: crate::vision::NoTargetCounts,
    /// The first difference.
    pub first: Option<Difference>,
    /// Simulated time covered (s).
    pub sim_time_s: f64,
    /// Damaged stretches of the log (skipped).
    pub damage: Vec<LogDamage>,
    /// Logged reports whose step record was lost to damage (not compared: the replay missed that step).
    pub reports_without_step: u64,
    /// Whether the log holds the flight code's outputs (reports or downlinks) to compare with; an imported
    /// dataset holds none.
    pub has_outputs: bool,
    /// A ground station's records (what crossed the radio, on the station's clock): not re-run.
    pub station_records: u64,
    /// The attitude against the log's reference, when it has one (`replay --summary`).
    pub reference: Option<serde_json::Value>,
}

impl ReplaySummary {
    /// Whether every compared output matched bit for bit and nothing was damaged.
    pub fn identical(&self) -> bool {
        self.first.is_none() && self.damage.is_empty()
    }
}

/// The ground station's vision, re-run on frames.
struct FrameVision {
    forward: GroundVision,
    flow: GroundFlow,
    vision: HashMap<u32, Option<LineObservation>>,
    flow_results: HashMap<u32, Option<Result<FlowStats, NoFlowReason>>>,
}

/// Re-runs the flight stack over a log held in memory.
pub fn replay(log: &crate::flightlog::FlightLog, opts: &ReplayOptions) -> Result<ReplaySummary> {
    // The records and the damage in the order of the file, as the streaming reader gives them: a record
    // after a damaged stretch is judged knowing of it (a report whose step was lost is counted, not an error).
    let mut items: Vec<LogItem> = log.records.iter().cloned().map(Ok).collect();
    items.extend(log.damage.iter().cloned().map(Err));
    items.sort_by_key(|item| match item {
        Ok((offset, _)) => (*offset, 1),
        Err(d) => (d.offset, 0),
    });
    replay_stream(&log.header, items.into_iter(), opts, None)
}

/// Re-runs the flight stack over a log's records as they are read; writes the replayed log to `out` if given
/// (the same header and inputs, the replayed measurements, reports and downlinks).
pub fn replay_stream(
    header: &LogHeader,
    records: impl Iterator<Item = LogItem>,
    opts: &ReplayOptions,
    mut out: Option<&mut LogWriter>,
) -> Result<ReplaySummary> {
    let scenario = Scenario::from_toml(&header.scenario_toml)?;
    let mut stack = FlightStack::new(scenario.flight_config()).map_err(|e| anyhow::anyhow!("{e}"))?;
    for &(id, value) in &opts.overrides {
        let r = stack.set_param(id, value);
        if r.outcome != ParamOutcome::Ok {
            bail!("parameter {} = {value} refused: {:?}", id.name(), r.outcome);
        }
    }
    let mut frames = match opts.vision {
        VisionSource::Frames => Some(FrameVision {
            forward: GroundVision::new(&scenario),
            flow: GroundFlow::new(&scenario),
            vision: HashMap::new(),
            flow_results: HashMap::new(),
        }),
        VisionSource::Logged => None,
    };
    let mut score = (!header.reference.is_empty()).then(|| {
        crate::reference::ReferenceScore::new(
            &header.reference,
            header.reference_yaw_absolute,
            scenario.estimator.mag_field_world,
        )
    });
    let mut schedule = DownlinkSchedule::new();
    let mut uplink: Vec<Uplink> = Vec::new();
    // The pilot's transmitter and the battery's reading for the next step, when the log holds them (format 10).
    let mut pilot = None;
    let mut battery = None;
    let mut last: Option<(u64, StepReport)> = None;
    let mut downlinks: VecDeque<Downlink> = VecDeque::new();
    let mut step_time = 0u64;
    let mut s = ReplaySummary::default();
    let mut first_time = None;
    let mut first_orphan: Option<(usize, usize)> = None;
    let writing = out.is_some();
    let mut write = |r: &LogRecord| -> Result<()> {
        match out.as_deref_mut() {
            Some(w) => w.write(r),
            None => Ok(()),
        }
    };
    for (index, item) in records.enumerate() {
        let (offset, rec) = match item {
            Ok(r) => r,
            Err(d) => {
                s.damage.push(d);
                continue;
            }
        };
        match rec {
            LogRecord::Link(m) => {
                let m = match frames.as_mut() {
                    Some(fv) => recompute(fv, m, index, offset, &mut s),
                    None => m,
                };
                write(&LogRecord::Link(m))?;
                uplink.push(m);
                s.links += 1;
            }
            LogRecord::Step(step) => {
                // Downlinks of the previous step the log did not hold (a log without outputs has none to hold).
                if !s.has_outputs {
                    downlinks.clear();
                }
                if !downlinks.is_empty() {
                    s.downlinks_differing += downlinks.len() as u64;
                    note(
                        &mut s.first,
                        index,
                        offset,
                        "downlink",
                        step_time,
                        "(missing from the log)",
                        &"none",
                        &downlinks[0],
                    );
                    downlinks.clear();
                }
                write(&LogRecord::Step(step.clone()))?;
                let o = stack.step(&StepInput {
                    time_us: step.time_us,
                    imu: &step.imu,
                    mag: step.mag,
                    baro_m: step.baro_m,
                    uplink: &uplink,
                    landed: step.landed,
                    pilot: pilot.take(),
                    battery: battery.take(),
                });
                stack.solve_pending();
                if let Some(sc) = score.as_mut() {
                    sc.step(
                        step.time_us,
                        &step.imu,
                        step.mag,
                        &o.control.estimate.q,
                        o.control.estimate.tilt_std_rad
                            < 0.5 * control_core::estimator::UNALIGNED_TILT_SIGMA_RAD,
                        o.control.estimate.yaw_std_rad < 1.0,
                    );
                }
                uplink.clear();
                s.steps += 1;
                step_time = step.time_us;
                first_time.get_or_insert(step.time_us);
                s.sim_time_s = (step.time_us - first_time.unwrap_or(step.time_us)) as f64 * 1e-6;
                let report = o.report();
                schedule.after_step(
                    &o.control,
                    o.param_reply,
                    o.time_sync,
                    step.time_us,
                    0,
                    o.telemetry_every,
                    o.battery,
                    |d| downlinks.push_back(d),
                );
                last = Some((step.time_us, report));
                // A log without reports (an imported dataset) gets the replayed ones.
                if writing {
                    write(&LogRecord::Report(report))?;
                    for d in &downlinks {
                        write(&LogRecord::Downlink(*d))?;
                    }
                }
            }
            LogRecord::Report(logged) => {
                s.has_outputs = true;
                let Some((time_us, replayed)) = last.take() else {
                    // Its step was in a damaged stretch. The damage may be found only further on (a whole
                    // record cut out shows only in the end record's count): judged at the end.
                    first_orphan.get_or_insert((index, offset));
                    s.reports_without_step += 1;
                    continue;
                };
                s.compared += 1;
                if postcard::to_allocvec(&logged)? != postcard::to_allocvec(&replayed)? {
                    s.differing += 1;
                    note(&mut s.first, index, offset, "report", time_us, "", &logged, &replayed);
                }
            }
            LogRecord::Downlink(logged) => {
                s.has_outputs = true;
                s.downlinks_compared += 1;
                let Some(mut replayed) = downlinks.pop_front() else {
                    s.downlinks_differing += 1;
                    note(
                        &mut s.first,
                        index,
                        offset,
                        "downlink",
                        step_time,
                        "(not sent in the replay)",
                        &logged,
                        &"none",
                    );
                    continue;
                };
                // The step cost is the flight computer's measurement, not an output of the code.
                match (&logged, &mut replayed) {
                    (Downlink::Telemetry(l), Downlink::Telemetry(r)) => r.step_cost = l.step_cost,
                    (Downlink::PackedTelemetry(l), Downlink::PackedTelemetry(r)) => r.step_cost = l.step_cost,
                    _ => {}
                }
                if postcard::to_allocvec(&logged)? != postcard::to_allocvec(&replayed)? {
                    s.downlinks_differing += 1;
                    note(&mut s.first, index, offset, "downlink", step_time, "", &logged, &replayed);
                }
            }
            LogRecord::Frame(f) => {
                s.frames += 1;
                if let Some(fv) = frames.as_mut() {
                    match f.camera {
                        CameraId::Forward => {
                            let img = f
                                .to_rgb()
                                .map_err(|e| anyhow::anyhow!("record {index} (byte {offset}): {e:#}"))?;
                            fv.vision.insert(f.seq, s.no_target.record(fv.forward.detect(&img)));
                        }
                        CameraId::Downward => {
                            let img = f
                                .to_gray()
                                .map_err(|e| anyhow::anyhow!("record {index} (byte {offset}): {e:#}"))?;
                            let hint = geometry::Vec3::new(
                                f.rotation_hint_cam[0],
                                f.rotation_hint_cam[1],
                                f.rotation_hint_cam[2],
                            );
                            fv.flow_results.insert(f.seq, fv.flow.add(&img, hint));
                        }
                    }
                }
                write(&LogRecord::Frame(f))?;
            }
            LogRecord::Reference(r) => {
                if let Some(sc) = score.as_mut() {
                    sc.reference(&r);
                }
                write(&LogRecord::Reference(r))?;
            }
            r @ LogRecord::Truth { .. } => write(&r)?,
            // The pilot's transmitter for the next step.
            LogRecord::Pilot(p) => {
                pilot = Some(p);
                write(&LogRecord::Pilot(p))?;
            }
            LogRecord::Battery(b) => {
                battery = Some(b);
                write(&LogRecord::Battery(b))?;
            }
            // A ground station's record of the radio: nothing to re-run, kept in a replayed log.
            LogRecord::Station(e) => {
                s.station_records += 1;
                write(&LogRecord::Station(e))?;
            }
            // The reader has checked it (count and CRC-32); a replayed log gets its own from its writer.
            LogRecord::End { .. } => {}
        }
    }
    s.reference = score.map(|sc| sc.json());
    if let Some((index, offset)) = first_orphan
        && s.damage.is_empty()
    {
        // An intact log (its end record checked) cannot have one: the writer's order is broken.
        bail!("record {index} (byte {offset}): a report without a step before it, in a log without damage");
    }
    if opts.vision == VisionSource::Frames && s.frames == 0 && s.links > 0 {
        bail!(
            "the log holds no camera frames (flown with --camera analytic or --frames none): replay from the \
             logged vision results instead"
        );
    }
    Ok(s)
}

/// A logged measurement replaced by the one recomputed from its frame, compared on the way.
fn recompute(fv: &mut FrameVision, m: Uplink, index: usize, offset: usize, s: &mut ReplaySummary) -> Uplink {
    match m {
        Uplink::Vision(mut v) => match fv.vision.remove(&v.frame_seq) {
            Some(obs) => {
                s.measurements_compared += 1;
                if postcard::to_allocvec(&obs).ok() != postcard::to_allocvec(&v.observation).ok() {
                    s.measurements_differing += 1;
                    let t = v.capture_time_us;
                    note(&mut s.first, index, offset, "vision", t, "observation", &v.observation, &obs);
                }
                v.observation = obs;
                Uplink::Vision(v)
            }
            None => {
                s.measurements_without_frame += 1;
                m
            }
        },
        // The station's packed forms: the recomputed measurement packed as the station packs it, compared
        // packed.
        Uplink::PackedVision(p) => match fv.vision.remove(&p.frame_seq) {
            Some(obs) => {
                s.measurements_compared += 1;
                let again = PackedVision::pack(&VisionMeasurement { observation: obs, ..p.unpack() });
                if postcard::to_allocvec(&again).ok() != postcard::to_allocvec(&p).ok() {
                    s.measurements_differing += 1;
                    let t = p.capture_time_us;
                    note(
                        &mut s.first,
                        index,
                        offset,
                        "vision",
                        t,
                        "observation",
                        &p.observation,
                        &again.observation,
                    );
                }
                Uplink::PackedVision(again)
            }
            None => {
                s.measurements_without_frame += 1;
                m
            }
        },
        Uplink::PackedFlow(p) => match fv.flow_results.remove(&p.frame_seq) {
            Some(Some(result)) => {
                s.measurements_compared += 1;
                let again = PackedFlow::pack(&FlowMeasurement { result, ..p.unpack() });
                if postcard::to_allocvec(&again).ok() != postcard::to_allocvec(&p).ok() {
                    s.measurements_differing += 1;
                    note(
                        &mut s.first,
                        index,
                        offset,
                        "flow",
                        p.t_next_us,
                        "result",
                        &p.result,
                        &again.result,
                    );
                }
                Uplink::PackedFlow(again)
            }
            Some(None) | None => {
                s.measurements_without_frame += 1;
                m
            }
        },
        Uplink::Flow(mut f) => match fv.flow_results.remove(&f.frame_seq) {
            Some(Some(result)) => {
                s.measurements_compared += 1;
                if postcard::to_allocvec(&result).ok() != postcard::to_allocvec(&f.result).ok() {
                    s.measurements_differing += 1;
                    note(&mut s.first, index, offset, "flow", f.t_next_us, "result", &f.result, &result);
                }
                f.result = result;
                Uplink::Flow(f)
            }
            Some(None) | None => {
                s.measurements_without_frame += 1;
                m
            }
        },
        other => other,
    }
}

/// Records the first difference (later ones only count).
#[allow(clippy::too_many_arguments)]
fn note<A: Serialize, B: Serialize>(
    first: &mut Option<Difference>,
    record: usize,
    offset: usize,
    kind: &'static str,
    time_us: u64,
    prefix: &str,
    logged: &A,
    replayed: &B,
) {
    if first.is_some() {
        return;
    }
    let (va, vb) = (
        serde_json::to_value(logged).unwrap_or(Value::Null),
        serde_json::to_value(replayed).unwrap_or(Value::Null),
    );
    let (field, a, b) = walk(&va, &vb, prefix.to_string()).unwrap_or_else(|| {
        // Equal as JSON numbers but not as bits (e.g. -0.0 and 0.0, or NaN payloads).
        (format!("{prefix} (bit pattern of a float)"), va.to_string(), vb.to_string())
    });
    *first = Some(Difference { record, offset, kind, time_us, field, logged: a, replayed: b });
}

fn walk(a: &Value, b: &Value, path: String) -> Option<(String, String, String)> {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for (k, va) in x {
                let vb = y.get(k).unwrap_or(&Value::Null);
                let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                if let Some(d) = walk(va, vb, p) {
                    return Some(d);
                }
            }
            None
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            x.iter().zip(y).enumerate().find_map(|(i, (va, vb))| walk(va, vb, format!("{path}[{i}]")))
        }
        _ if a == b => None,
        _ => Some((path, a.to_string(), b.to_string())),
    }
}
