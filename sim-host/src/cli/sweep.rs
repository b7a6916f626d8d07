//! `sim-host sweep`: a campaign of seeded flights with the scenario drawn from distributions.
use super::common::progress_bar;
use super::fly::CameraSim;
use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use sim_host::Scenario;
use sim_host::sweep::vary::Vary;
use sim_host::sweep::{Shard, SweepOptions};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub(crate) struct SweepArgs {
    #[command(subcommand)]
    pub(crate) merge: Option<SweepCommand>,
    #[command(flatten)]
    pub(crate) run: Option<SweepRunArgs>,
}

#[derive(Subcommand, Debug)]
pub(crate) enum SweepCommand {
    /// Merge the outputs of a sweep's shards into the report the unsharded sweep gives.
    Merge(MergeArgs),
}

#[derive(Args, Debug)]
pub(crate) struct MergeArgs {
    /// The shards' output directories.
    #[arg(required = true)]
    pub(crate) dirs: Vec<PathBuf>,
    /// Where the merged runs.csv, report.json and histograms go.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

#[derive(Args, Debug)]
pub(crate) struct SweepRunArgs {
    /// The base scenario: a built-in name (`paper`, `webcam`) or a TOML file.
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// The distributions each run's scenario is drawn from (docs/robustness.md).
    #[arg(long, value_name = "VARY.toml")]
    pub(crate) vary: PathBuf,
    /// Runs in the whole sweep.
    #[arg(long)]
    pub(crate) runs: u32,
    /// The sweep's seed: run K flies with a seed derived from (SEED, K).
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// How the forward camera is simulated.
    #[arg(long, value_enum, default_value = "analytic")]
    pub(crate) camera: CameraSim,
    /// Fly every N-th run starting at I (1-based), e.g. 2/4. Without it, a Slurm job array
    /// (SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_COUNT) or a Kubernetes Indexed Job (JOB_COMPLETION_INDEX with
    /// --shards) selects the shard.
    #[arg(long, value_name = "I/N")]
    pub(crate) shard: Option<String>,
    /// The number of shards of a Kubernetes Indexed Job (with JOB_COMPLETION_INDEX).
    #[arg(long, value_name = "N")]
    pub(crate) shards: Option<u32>,
    /// Output directory: runs.csv, report.json, sweep.json, histogram_rms_{x,y,z}.png.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Bounds of the 95th percentile of the RMS errors x, y, z (m): exit 3 when one is exceeded (a gate for
    /// CI, like a failed run).
    #[arg(long, value_name = "X,Y,Z")]
    pub(crate) p95_max: Option<String>,
}

pub(crate) fn sweep(a: &SweepArgs) -> Result<ExitCode> {
    match (&a.merge, &a.run) {
        (Some(SweepCommand::Merge(m)), _) => merge(m),
        (None, Some(r)) => run(r),
        (None, None) => {
            bail!("give --scenario/--vary/--runs/--out, or `merge DIR... --out DIR` (see --help)")
        }
    }
}

fn run(a: &SweepRunArgs) -> Result<ExitCode> {
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let p95_max = match &a.p95_max {
        None => None,
        Some(t) => {
            let v: Vec<f64> = t
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| anyhow::anyhow!("--p95-max {t}: expected three numbers X,Y,Z (m)"))?;
            match v.as_slice() {
                [x, y, z] if v.iter().all(|b| b.is_finite() && *b > 0.0) => Some([*x, *y, *z]),
                _ => bail!("--p95-max {t}: expected three positive numbers X,Y,Z (m)"),
            }
        }
    };
    let shard = match &a.shard {
        Some(s) => Shard::parse(s)?,
        None => Shard::from_env(|k| std::env::var(k).ok(), a.shards)?.unwrap_or(Shard::ALL),
    };
    let outputs = sim_host::sweep::output_files(&a.out);
    sim_host::files::refuse_overwrites(
        &outputs.iter().map(|p| p.as_path()).collect::<Vec<_>>(),
        &[std::path::Path::new(&a.scenario), &a.vary],
    )?;
    let opts = SweepOptions {
        scenario: Scenario::load(&a.scenario)?,
        scenario_arg: a.scenario.clone(),
        vary: Vary::load(&a.vary)?,
        vary_arg: a.vary.display().to_string(),
        runs: a.runs,
        seed: a.seed,
        camera: a.camera.mode(),
        shard,
        out: a.out.clone(),
    };
    let mine = (0..a.runs).filter(|k| shard.has(*k)).count() as u64;
    let bar =
        progress_bar(mine, "{spinner} flying [{bar:40}] {pos}/{len} runs ({elapsed} elapsed, {eta} left)");
    let done = AtomicU64::new(0);
    let t0 = std::time::Instant::now();
    let r = sim_host::sweep::sweep(&opts, &|| {
        bar.set_position(done.fetch_add(1, Ordering::Relaxed) + 1);
    })?;
    bar.finish_and_clear();
    let wall = t0.elapsed().as_secs_f64();
    let cores = rayon::current_num_threads();
    eprintln!(
        "shard {}/{}: {mine} runs in {wall:.1} s on {cores} cores ({:.1} flights per core-minute)",
        shard.index + 1,
        shard.count,
        mine as f64 / (wall * cores as f64 / 60.0)
    );
    let code = print_report(&r.report, &r.files)?;
    if let Some(b) = p95_max {
        let p = &r.report["p95_rms_error_m"];
        let over: Vec<String> = ["x", "y", "z"]
            .iter()
            .zip(b)
            .filter(|(k, lim)| !p[**k].as_f64().is_some_and(|v| v <= *lim))
            .map(|(k, lim)| format!("{k} {} > {lim}", p[*k]))
            .collect();
        if !over.is_empty() {
            eprintln!("p95 RMS error over its bound: {}", over.join(", "));
            return Ok(ExitCode::from(3));
        }
    }
    Ok(code)
}

fn merge(a: &MergeArgs) -> Result<ExitCode> {
    let outputs = sim_host::sweep::output_files(&a.out);
    sim_host::files::refuse_overwrites(
        &outputs.iter().map(|p| p.as_path()).collect::<Vec<_>>(),
        &a.dirs.iter().map(|p| p.as_path()).collect::<Vec<_>>(),
    )?;
    let r = sim_host::sweep::merge(&a.dirs, &a.out)?;
    print_report(&r.report, &r.files)
}

fn print_report(r: &serde_json::Value, files: &[PathBuf]) -> Result<ExitCode> {
    let f = |v: &serde_json::Value| v.as_f64().map_or("-".to_string(), |x| format!("{:.1}", 1e3 * x));
    eprintln!(
        "{} runs: {} crashed, {} landed and disarmed, {} wall contacts; p95 RMS error x {} y {} z {} mm, largest x {} y {} z {} mm",
        r["runs"],
        r["crashed"],
        r["landed"],
        r["wall_contacts"],
        f(&r["p95_rms_error_m"]["x"]),
        f(&r["p95_rms_error_m"]["y"]),
        f(&r["p95_rms_error_m"]["z"]),
        f(&r["max_rms_error_m"]["x"]),
        f(&r["max_rms_error_m"]["y"]),
        f(&r["max_rms_error_m"]["z"]),
    );
    for w in r["failed"].as_array().into_iter().flatten().take(10) {
        eprintln!(
            "  failed run {} ({}): {}",
            w["run"],
            w["why"].as_str().unwrap_or(""),
            w["command"].as_str().unwrap_or("")
        );
    }
    if let Some(n) = r["aborted"].as_u64().filter(|n| *n > 0) {
        eprintln!(
            "  {n} runs landed by a failsafe before tracking (a fault during the take-off): see aborted_runs"
        );
    }
    eprintln!("wrote:");
    for p in files {
        eprintln!("  {}", p.display());
    }
    let failed = r["failures"].as_u64().unwrap_or(0);
    Ok(if failed > 0 { ExitCode::from(3) } else { ExitCode::SUCCESS })
}
