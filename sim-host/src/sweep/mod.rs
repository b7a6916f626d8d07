//! `sim-host sweep`: many seeded flights of one mission with the scenario drawn from distributions
//! ([`vary`]), in parallel on all cores, sharded over processes or cluster jobs, and the campaign's report.
//!
//! Run `k` of a sweep with seed `S` flies with the seed [`run_seed`]`(S, k)` and draws its scenario from that
//! seed's `vary` stream, so it is the same run in any shard, and alone (`sim-host fly --vary VARY.toml --run
//! k --seed S`). `runs.csv` has one row per run; `report.json` is computed from those rows alone, so merging
//! the shards' rows (`sim-host sweep merge`) gives the unsharded report byte for byte.
pub mod vary;

use crate::rng::{SimRng, splitmix64};
use crate::scenario::Scenario;
use crate::sil::{CameraMode, RunStats, Sil};
use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use vary::Vary;

/// The seed of run `k` of a sweep seeded `seed`.
pub fn run_seed(seed: u64, k: u32) -> u64 {
    let mut s = seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    splitmix64(&mut s)
}

/// A run's scenario: the base with the run's draw.
pub fn run_scenario(base: &Scenario, vary: &Vary, seed: u64, k: u32) -> Result<vary::Draw> {
    vary.draw(base, &mut SimRng::stream(run_seed(seed, k), "vary"))
}

/// Which runs this process flies: every `count`-th starting at `index` (0-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 0-based.
    pub index: u32,
    /// How many shards.
    pub count: u32,
}

impl Shard {
    /// The whole sweep.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Parses `I/N` (1-based, as the CLI's `--shard`).
    pub fn parse(text: &str) -> Result<Shard> {
        let bad = || anyhow::anyhow!("--shard {text}: expected I/N with 1 <= I <= N, e.g. 2/4");
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let (i, n): (u32, u32) = (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if n == 0 || i == 0 || i > n {
            return Err(bad());
        }
        Ok(Shard { index: i - 1, count: n })
    }

    /// The shard a cluster job array gives: Slurm's `SLURM_ARRAY_TASK_ID` (less `SLURM_ARRAY_TASK_MIN`, 0 by
    /// default) of `SLURM_ARRAY_TASK_COUNT`, or Kubernetes' `JOB_COMPLETION_INDEX` (0-based) of `shards`.
    pub fn from_env(get: impl Fn(&str) -> Option<String>, shards: Option<u32>) -> Result<Option<Shard>> {
        let num = |name: &str| -> Result<Option<u32>> {
            match get(name) {
                None => Ok(None),
                Some(v) => {
                    v.trim().parse().map(Some).map_err(|_| anyhow::anyhow!("{name}={v} is not a number"))
                }
            }
        };
        if let (Some(id), Some(count)) = (num("SLURM_ARRAY_TASK_ID")?, num("SLURM_ARRAY_TASK_COUNT")?) {
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let index = id.checked_sub(min).filter(|i| *i < count).with_context(|| {
                format!(
                    "SLURM_ARRAY_TASK_ID={id} is outside {min}..{} (SLURM_ARRAY_TASK_MIN, _COUNT)",
                    min + count
                )
            })?;
            return Ok(Some(Shard { index, count }));
        }
        if let Some(index) = num("JOB_COMPLETION_INDEX")? {
            let count =
                shards.context("JOB_COMPLETION_INDEX is set: give the number of shards with --shards N")?;
            if index >= count {
                bail!("JOB_COMPLETION_INDEX={index} is not below --shards {count}");
            }
            return Ok(Some(Shard { index, count }));
        }
        Ok(None)
    }

    /// Whether run `k` is this shard's.
    pub fn has(&self, k: u32) -> bool {
        k % self.count == self.index
    }
}

/// What a sweep needs.
#[derive(Clone, Debug)]
pub struct SweepOptions {
    /// The base scenario.
    pub scenario: Scenario,
    /// How it was named on the command line (for the commands that repeat a run).
    pub scenario_arg: String,
    /// The distributions.
    pub vary: Vary,
    /// The VARY.toml path (for the commands).
    pub vary_arg: String,
    /// Runs in the whole sweep.
    pub runs: u32,
    /// The sweep's seed.
    pub seed: u64,
    /// How the forward camera is simulated.
    pub camera: CameraMode,
    /// This process's share.
    pub shard: Shard,
    /// Output directory.
    pub out: PathBuf,
}

/// The columns of `runs.csv` after the varied values.
const RESULT_COLUMNS: &[&str] = &[
    "crashed",
    "crash_reason",
    "landed",
    "wall_contact",
    "min_wall_distance_m",
    "rms_error_x_m",
    "rms_error_y_m",
    "rms_error_z_m",
    "estimate_rms_error_x_m",
    "estimate_rms_error_y_m",
    "estimate_rms_error_z_m",
    "max_tilt_deg",
    "tilt_error_rms_deg",
    "passes",
    "failsafes",
    "touchdown_speed_m_s",
    "sim_time_s",
];

fn num(v: f64) -> String {
    if v.is_finite() { format!("{:.6}", v) } else { String::new() }
}

/// One run's row.
fn row(k: u32, seed: u64, columns: &[String], draw: &vary::Draw, st: &RunStats) -> Vec<String> {
    let mut r = vec![k.to_string(), seed.to_string()];
    for c in columns {
        r.push(draw.values.iter().find(|(n, _)| n == c).map_or(String::new(), |(_, v)| v.clone()));
    }
    let failsafes: Vec<String> = st.failsafes.iter().map(|(t, f)| format!("{f}@{t:.2}")).collect();
    r.extend([
        st.crashed.to_string(),
        st.crash_reason.clone().unwrap_or_default(),
        st.landed.to_string(),
        st.wall_contact.to_string(),
        num(st.min_wall_distance_m),
        num(st.rms_error_m[0]),
        num(st.rms_error_m[1]),
        num(st.rms_error_m[2]),
        num(st.estimate_rms_error_m[0]),
        num(st.estimate_rms_error_m[1]),
        num(st.estimate_rms_error_m[2]),
        num(st.max_tilt_deg),
        num(st.tilt_error_rms_deg),
        st.passes_done.to_string(),
        failsafes.join(" "),
        num(st.max_touchdown_speed_m_s),
        num(st.sim_time_s),
    ]);
    r
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

fn parse_csv_line(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut cur)),
            _ => cur.push(c),
        }
    }
    out.push(cur);
    out
}

/// The sweep's identity, written beside each shard's rows (`sweep.json`) and checked when merging.
fn meta(o: &SweepOptions) -> Value {
    json!({
        "scenario": o.scenario_arg,
        "vary": o.vary_arg,
        "runs": o.runs,
        "seed": o.seed,
        "camera": o.camera.name(),
        "shard": {"index": o.shard.index + 1, "count": o.shard.count},
    })
}

/// What a sweep wrote.
#[derive(Clone, Debug)]
pub struct SweepResult {
    /// The report.
    pub report: Value,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Flies this shard's runs (in parallel) and writes `runs.csv`, `sweep.json`, `report.json` and the
/// histograms into `out`.
pub fn sweep(o: &SweepOptions, progress: &(dyn Fn() + Sync)) -> Result<SweepResult> {
    o.vary.check(&o.scenario).context("VARY.toml")?;
    std::fs::create_dir_all(&o.out).with_context(|| format!("cannot create {}", o.out.display()))?;
    let columns = o.vary.columns(&o.scenario)?;
    let ks: Vec<u32> = (0..o.runs).filter(|k| o.shard.has(*k)).collect();
    let rows: Vec<Result<Vec<String>>> = ks
        .par_iter()
        .map(|&k| {
            let draw = run_scenario(&o.scenario, &o.vary, o.seed, k).with_context(|| format!("run {k}"))?;
            let seed = run_seed(o.seed, k);
            let mut sil = Sil::new(&draw.scenario, seed, o.camera).with_context(|| format!("run {k}"))?;
            let st = sil.run(draw.scenario.mission.max_duration_s, |_| {});
            progress();
            Ok(row(k, seed, &columns, &draw, &st))
        })
        .collect();
    let rows: Vec<Vec<String>> = rows.into_iter().collect::<Result<_>>()?;
    let mut header = vec!["run".to_string(), "seed".to_string()];
    header.extend(columns.iter().cloned());
    header.extend(RESULT_COLUMNS.iter().map(|s| s.to_string()));
    let meta = meta(o);
    write_outputs(&o.out, &header, &rows, &meta)
}

/// Every file a sweep or a merge writes into its output directory.
pub fn output_files(out: &Path) -> Vec<PathBuf> {
    [
        "runs.csv",
        "sweep.json",
        "report.json",
        "histogram_rms_x.png",
        "histogram_rms_y.png",
        "histogram_rms_z.png",
    ]
    .into_iter()
    .map(|n| out.join(n))
    .collect()
}

/// Merges shards' outputs into the report of the whole sweep.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<SweepResult> {
    if dirs.is_empty() {
        bail!("nothing to merge: give the shards' directories");
    }
    let mut header: Option<Vec<String>> = None;
    let mut rows: Vec<Vec<String>> = Vec::new();
    let mut meta0: Option<Value> = None;
    let mut shards_seen = Vec::new();
    // Which shard each run came from.
    let mut from: std::collections::HashMap<u64, PathBuf> = std::collections::HashMap::new();
    for d in dirs {
        let m: Value = serde_json::from_str(
            &std::fs::read_to_string(d.join("sweep.json"))
                .with_context(|| format!("{}: no sweep.json", d.display()))?,
        )
        .with_context(|| format!("{}/sweep.json", d.display()))?;
        let mut same = m.clone();
        same.as_object_mut().map(|o| o.remove("shard"));
        match &meta0 {
            None => meta0 = Some(same),
            Some(m0) if *m0 != same => bail!("{}: another sweep ({same} against {m0})", d.display()),
            _ => {}
        }
        shards_seen.push(m["shard"].clone());
        let text = std::fs::read_to_string(d.join("runs.csv"))
            .with_context(|| format!("{}: no runs.csv", d.display()))?;
        let mut lines = text.lines();
        let Some(first) = lines.next() else { bail!("{}/runs.csv: empty (not even a header)", d.display()) };
        let h = parse_csv_line(first);
        match &header {
            None => header = Some(h),
            Some(h0) if *h0 != h => bail!("{}/runs.csv: other columns", d.display()),
            _ => {}
        }
        for (n, line) in lines.enumerate().filter(|(_, l)| !l.is_empty()) {
            let row = parse_csv_line(line);
            let Some(k) = row.first().and_then(|k| k.parse::<u64>().ok()) else {
                bail!("{}/runs.csv line {}: no run index in the first column", d.display(), n + 2);
            };
            if let Some(other) = from.insert(k, d.clone()) {
                bail!("run {k} is in two shards: {} and {}", other.display(), d.display());
            }
            rows.push(row);
        }
    }
    let mut meta = meta0.unwrap_or(Value::Null);
    let total = meta["runs"].as_u64().unwrap_or(0);
    // Every row has a run index (checked above) and no index is there twice.
    rows.sort_by_key(|r| r.first().and_then(|k| k.parse::<u64>().ok()).unwrap_or(u64::MAX));
    let have: Vec<u64> = rows.iter().filter_map(|r| r.first()?.parse().ok()).collect();
    if have.len() as u64 != total || have.iter().enumerate().any(|(i, k)| *k != i as u64) {
        let missing: Vec<u64> = (0..total).filter(|k| !have.contains(k)).take(10).collect();
        bail!(
            "the shards hold {} of {total} runs (missing e.g. {missing:?}; shards given: {shards_seen:?})",
            have.len()
        );
    }
    if let Some(o) = meta.as_object_mut() {
        o.insert("shard".into(), json!({"index": 1, "count": 1}));
    }
    let Some(header) = header else { bail!("nothing to merge: no shard had a runs.csv") };
    write_outputs(out, &header, &rows, &meta)
}

fn write_outputs(out: &Path, header: &[String], rows: &[Vec<String>], meta: &Value) -> Result<SweepResult> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut csv = header.iter().map(|h| csv_field(h)).collect::<Vec<_>>().join(",") + "\n";
    for r in rows {
        csv += &(r.iter().map(|c| csv_field(c)).collect::<Vec<_>>().join(",") + "\n");
    }
    let runs_csv = out.join("runs.csv");
    crate::files::write_atomic(&runs_csv, csv.as_bytes())?;
    let sweep_json = out.join("sweep.json");
    crate::files::write_atomic(&sweep_json, (serde_json::to_string_pretty(meta)? + "\n").as_bytes())?;
    let report = report(header, rows, meta);
    let report_json = out.join("report.json");
    crate::files::write_atomic(&report_json, (serde_json::to_string_pretty(&report)? + "\n").as_bytes())?;
    let mut files = vec![runs_csv, sweep_json, report_json];
    files.extend(histograms(out, header, rows)?);
    Ok(SweepResult { report, files })
}

fn col(header: &[String], name: &str) -> usize {
    header.iter().position(|h| h == name).unwrap_or(usize::MAX)
}

fn get(r: &[String], i: usize) -> &str {
    r.get(i).map_or("", |s| s.as_str())
}

fn fnum(r: &[String], i: usize) -> f64 {
    get(r, i).parse().unwrap_or(f64::NAN)
}

fn p95(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((0.95 * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)]
}

/// The command that flies run `k` alone.
fn command(meta: &Value, k: &str) -> String {
    format!(
        "sim-host fly --scenario {} --vary {} --run {k} --seed {} --camera {} --out run-{k}",
        meta["scenario"].as_str().unwrap_or("paper"),
        meta["vary"].as_str().unwrap_or("VARY.toml"),
        meta["seed"],
        meta["camera"].as_str().unwrap_or("analytic"),
    )
}

/// The campaign's report, from the rows alone.
fn report(header: &[String], rows: &[Vec<String>], meta: &Value) -> Value {
    let c = |n: &str| col(header, n);
    let (ic, il, iw) = (c("crashed"), c("landed"), c("wall_contact"));
    let rms = |r: &[String]| [c("rms_error_x_m"), c("rms_error_y_m"), c("rms_error_z_m")].map(|i| fnum(r, i));
    let crashed = rows.iter().filter(|r| get(r, ic) == "true").count();
    let landed = rows.iter().filter(|r| get(r, il) == "true").count();
    let walls = rows.iter().filter(|r| get(r, iw) == "true").count();
    let axis = |a: usize| rows.iter().map(|r| rms(r)[a]).collect::<Vec<_>>();
    let maxf = |v: Vec<f64>| v.into_iter().filter(|x| x.is_finite()).fold(f64::NAN, f64::max);
    let xyz = |f: &dyn Fn(usize) -> f64| json!({"x": f(0), "y": f(1), "z": f(2)});
    let entry = |r: &[String], why: String| {
        let k = get(r, 0);
        let e = rms(r);
        json!({
            "run": k.parse::<u64>().unwrap_or(0),
            "seed": get(r, 1).parse::<u64>().unwrap_or(0),
            "command": command(meta, k),
            "why": why,
            "rms_error_m": {"x": e[0], "y": e[1], "z": e[2]},
            "failsafes": get(r, c("failsafes")),
        })
    };
    // Failures: crashed, wall contact, or not landed and disarmed. A run whose fault came before the sweep
    // began and whose failsafe landed it safely never tracked: it is an abort, listed apart (the mission's
    // safe outcome, without a tracking error to rank).
    let failures: Vec<Value> = rows
        .iter()
        .filter_map(|r| {
            let why = if get(r, ic) == "true" {
                format!("crashed: {}", get(r, c("crash_reason")))
            } else if get(r, iw) == "true" {
                "wall contact".to_string()
            } else if get(r, il) != "true" {
                "did not land and disarm".to_string()
            } else {
                return None;
            };
            Some(entry(r, why))
        })
        .collect();
    let aborted: Vec<Value> = rows
        .iter()
        .filter(|r| {
            get(r, ic) != "true"
                && get(r, iw) != "true"
                && get(r, il) == "true"
                && rms(r).iter().any(|v| !v.is_finite())
        })
        .map(|r| entry(r, "landed by a failsafe before tracking".to_string()))
        .collect();
    // The worst tracked runs by the largest RMS error relative to its bound (y, z 4 cm; x 6 cm).
    let mut by: Vec<(f64, &Vec<String>)> = rows
        .iter()
        .filter_map(|r| {
            let e = rms(r);
            let s = (e[0] / 0.06).max(e[1] / 0.04).max(e[2] / 0.04);
            s.is_finite().then_some((s, r))
        })
        .collect();
    by.sort_by(|a, b| b.0.total_cmp(&a.0).then_with(|| get(a.1, 0).cmp(get(b.1, 0))));
    let worst: Vec<Value> =
        by.iter().take(5).map(|(s, r)| entry(r, format!("{s:.3} of the bound"))).collect();
    json!({
        "sweep": meta,
        "runs": rows.len(),
        "crashed": crashed,
        "landed": landed,
        "wall_contacts": walls,
        "failures": failures.len(),
        "p95_rms_error_m": xyz(&|a| p95(axis(a))),
        "max_rms_error_m": xyz(&|a| maxf(axis(a))),
        "p95_max_tilt_deg": p95(rows.iter().map(|r| fnum(r, c("max_tilt_deg"))).collect()),
        "p95_tilt_error_rms_deg": p95(rows.iter().map(|r| fnum(r, c("tilt_error_rms_deg"))).collect()),
        "worst": worst,
        "failed": failures,
        "aborted": aborted.len(),
        "aborted_runs": aborted,
        "definitions": {
            "rms_error_m": "true minus desired position over each run's tracking phase, RMS",
            "landed": "ended on the floor, disarmed",
            "wall_contacts": "runs whose centre came closer to the wall than the arm and a rotor radius",
            "failures": "runs that crashed, touched the wall, or did not land and disarm",
            "aborted": "runs that landed and disarmed by a failsafe before the sweep began (no tracking error)",
        },
    })
}

/// Histograms of the RMS errors (one PNG per axis).
fn histograms(out: &Path, header: &[String], rows: &[Vec<String>]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for (axis, name) in [("x", "rms_error_x_m"), ("y", "rms_error_y_m"), ("z", "rms_error_z_m")] {
        let i = col(header, name);
        let mm: Vec<f64> = rows.iter().map(|r| fnum(r, i) * 1e3).filter(|v| v.is_finite()).collect();
        if mm.is_empty() {
            continue;
        }
        let hi = mm.iter().copied().fold(1.0, f64::max);
        let bins = 30usize;
        let w = hi / bins as f64;
        let mut counts = vec![0f64; bins];
        for v in &mm {
            counts[((v / w) as usize).min(bins - 1)] += 1.0;
        }
        // The histogram as a step curve.
        let (mut xs, mut ys) = (vec![0.0], vec![0.0]);
        for (b, n) in counts.iter().enumerate() {
            xs.extend([b as f64 * w, (b + 1) as f64 * w]);
            ys.extend([*n, *n]);
        }
        xs.push(hi);
        ys.push(0.0);
        let title = format!("RMS tracking error {axis}, {} runs", mm.len());
        let plot = crate::plot::Plot {
            title: &title,
            x_label: "RMS error (mm)",
            y_label: "runs",
            series: vec![crate::plot::Series {
                name: axis,
                color: [40, 90, 200],
                xs: &xs,
                ys: &ys,
                dashed: false,
            }],
            spans: Vec::new(),
            size: (800, 450),
        };
        let img = crate::plot::render(&plot);
        let path = out.join(format!("histogram_rms_{axis}.png"));
        crate::imageio::write_png_rgb(&path, &img)?;
        files.push(path);
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_and_their_environment() {
        assert_eq!(Shard::parse("2/4").unwrap(), Shard { index: 1, count: 4 });
        for bad in ["0/4", "5/4", "x", "1/0"] {
            assert!(Shard::parse(bad).is_err(), "{bad}");
        }
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| pairs.iter().find(|(n, _)| *n == k).map(|(_, v)| v.to_string())
        };
        let s = Shard::from_env(env(&[("SLURM_ARRAY_TASK_ID", "3"), ("SLURM_ARRAY_TASK_COUNT", "4")]), None)
            .unwrap();
        assert_eq!(s, Some(Shard { index: 3, count: 4 }));
        let s = Shard::from_env(
            env(&[
                ("SLURM_ARRAY_TASK_ID", "4"),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
                ("SLURM_ARRAY_TASK_MIN", "1"),
            ]),
            None,
        )
        .unwrap();
        assert_eq!(s, Some(Shard { index: 3, count: 4 }));
        assert_eq!(
            Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "0")]), Some(2)).unwrap(),
            Some(Shard { index: 0, count: 2 })
        );
        assert!(Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "0")]), None).is_err());
        assert!(Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "2")]), Some(2)).is_err());
        assert_eq!(Shard::from_env(env(&[]), Some(2)).unwrap(), None);
        let runs: Vec<u32> = (0..10).filter(|k| Shard { index: 1, count: 4 }.has(*k)).collect();
        assert_eq!(runs, [1, 5, 9]);
        assert_ne!(run_seed(1, 0), run_seed(1, 1));
        assert_ne!(run_seed(1, 0), run_seed(2, 0));
    }

    #[test]
    fn csv_round_trips() {
        let r = vec!["a,b".to_string(), "say \"hi\"".to_string(), "plain".to_string(), String::new()];
        let line = r.iter().map(|c| csv_field(c)).collect::<Vec<_>>().join(",");
        assert_eq!(parse_csv_line(&line), r);
    }
}
