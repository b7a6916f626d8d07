//! Replay: the flight stack re-run on a log's inputs, every output compared with the log's bit for bit.
//!
//! The stack is built from the scenario in the log's header (its parameters), optionally with parameters
//! changed; it then steps on each `Step` record with the `Link` records before it, runs the background work
//! after each step as every flight computer does, and compares the report with the log's next `Report`
//! record through their encoded bytes (so a NaN or a signed zero counts). The first difference is named by
//! record, byte offset, time and field path, with both values.
use crate::flightlog::{FlightLog, LogRecord};
use crate::scenario::Scenario;
use anyhow::{Result, bail};
use control_core::ParamOutcome;
use control_core::params::ParamId;
use flight_core::{FlightStack, StepInput, StepReport};
use protocol::Uplink;
use serde_json::Value;

/// The first output that differs.
#[derive(Clone, Debug, PartialEq)]
pub struct Difference {
    /// Index of the `Report` record in the log.
    pub record: usize,
    /// Its byte offset in the file.
    pub offset: usize,
    /// Time of its step (us).
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
            "record {} (byte {}), step at t = {:.3} s: {} logged {} replayed {}",
            self.record,
            self.offset,
            self.time_us as f64 * 1e-6,
            self.field,
            self.logged,
            self.replayed
        )
    }
}

/// What a replay found.
#[derive(Clone, Debug)]
pub struct ReplaySummary {
    /// Steps re-run.
    pub steps: u64,
    /// Radio messages fed.
    pub links: u64,
    /// Reports compared.
    pub compared: u64,
    /// Reports that differ.
    pub differing: u64,
    /// The first difference.
    pub first: Option<Difference>,
    /// Simulated time covered (s).
    pub sim_time_s: f64,
}

/// Re-runs the flight stack over a log. `overrides` change parameters before the first step.
pub fn replay(log: &FlightLog, overrides: &[(ParamId, f32)]) -> Result<ReplaySummary> {
    let scenario = Scenario::from_toml(&log.header.scenario_toml)?;
    let mut stack = FlightStack::new(scenario.flight_config()).map_err(|e| anyhow::anyhow!("{e}"))?;
    for &(id, value) in overrides {
        let r = stack.set_param(id, value);
        if r.outcome != ParamOutcome::Ok {
            bail!("parameter {} = {value} refused: {:?}", id.name(), r.outcome);
        }
    }
    let mut uplink: Vec<Uplink> = Vec::new();
    let mut last: Option<(u64, StepReport)> = None;
    let mut s = ReplaySummary { steps: 0, links: 0, compared: 0, differing: 0, first: None, sim_time_s: 0.0 };
    let mut first_time = None;
    for (index, (offset, rec)) in log.records.iter().enumerate() {
        match rec {
            LogRecord::Link(m) => {
                uplink.push(*m);
                s.links += 1;
            }
            LogRecord::Step(step) => {
                let out = stack.step(&StepInput {
                    time_us: step.time_us,
                    imu: &step.imu,
                    mag: step.mag,
                    uplink: &uplink,
                });
                stack.solve_pending();
                uplink.clear();
                s.steps += 1;
                first_time.get_or_insert(step.time_us);
                s.sim_time_s = (step.time_us - first_time.unwrap_or(step.time_us)) as f64 * 1e-6;
                last = Some((step.time_us, out.report()));
            }
            LogRecord::Report(logged) => {
                let Some((time_us, replayed)) = last.take() else {
                    bail!("record {index} (byte {offset}): a report without a step before it");
                };
                s.compared += 1;
                if postcard::to_allocvec(logged)? != postcard::to_allocvec(&replayed)? {
                    s.differing += 1;
                    if s.first.is_none() {
                        let (field, a, b) = first_field_difference(logged, &replayed);
                        s.first = Some(Difference {
                            record: index,
                            offset: *offset,
                            time_us,
                            field,
                            logged: a,
                            replayed: b,
                        });
                    }
                }
            }
            LogRecord::Truth { .. } => {}
        }
    }
    Ok(s)
}

/// The path and both values of the first field where two reports differ.
fn first_field_difference(a: &StepReport, b: &StepReport) -> (String, String, String) {
    let (va, vb) =
        (serde_json::to_value(a).unwrap_or(Value::Null), serde_json::to_value(b).unwrap_or(Value::Null));
    walk(&va, &vb, String::new()).unwrap_or_else(|| {
        // Equal as JSON numbers but not as bits (e.g. -0.0 and 0.0, or NaN payloads).
        ("(bit pattern of a float)".into(), format!("{a:?}"), format!("{b:?}"))
    })
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
