//! `sim-host sweep`, run as a user would: a small campaign from the repository's VARY file, whole and as
//! four shards in separate processes (as a Slurm job array and a Kubernetes Indexed Job would run them),
//! merged byte for byte; one of its runs repeated alone with `fly --vary --run`.
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sim-host"))
}

fn campaign() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sweeps/campaign.toml")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sim-host-sweep-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

const RUNS: &str = "8";

fn sweep(out: &Path, extra: &[&str], env: &[(&str, &str)]) -> String {
    let mut c = bin();
    c.args(["sweep", "--vary"])
        .arg(campaign())
        .args(["--runs", RUNS, "--seed", "7", "--out"])
        .arg(out)
        .args(extra);
    for k in ["SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "SLURM_ARRAY_TASK_MIN", "JOB_COMPLETION_INDEX"]
    {
        c.env_remove(k);
    }
    for (k, v) in env {
        c.env(k, v);
    }
    let r = c.output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    // Exit 0, or 3 when a run failed the campaign's criteria: both write the outputs.
    assert!(matches!(r.status.code(), Some(0) | Some(3)), "{err}");
    err
}

#[test]
fn shards_merged_equal_the_whole_sweep_byte_for_byte() {
    let whole = tmp("whole");
    let err = sweep(&whole, &[], &[]);
    assert!(err.contains("flights per core-minute"), "{err}");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(whole.join("report.json")).unwrap()).unwrap();
    for key in ["runs", "crashed", "landed", "wall_contacts", "p95_rms_error_m", "max_rms_error_m", "worst"] {
        assert!(report.get(key).is_some(), "report.json lacks {key}");
    }
    assert_eq!(report["runs"], 8);
    for axis in ["x", "y", "z"] {
        assert!(report["p95_rms_error_m"][axis].as_f64().is_some_and(|v| v > 0.0 && v < 1.0), "{report}");
    }
    let worst = &report["worst"][0];
    assert!(
        worst["command"].as_str().unwrap().starts_with("sim-host fly --scenario paper --vary"),
        "{worst}"
    );
    for f in ["histogram_rms_x.png", "histogram_rms_y.png", "histogram_rms_z.png"] {
        assert!(std::fs::metadata(whole.join(f)).unwrap().len() > 1000, "{f}");
    }
    let csv = std::fs::read_to_string(whole.join("runs.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    for col in [
        "run",
        "seed",
        "mismatch.mass_scale",
        "wind.mean_m_s.speed",
        "fault.kind",
        "crashed",
        "landed",
        "wall_contact",
    ] {
        assert!(header.split(',').any(|c| c == col), "runs.csv lacks {col}: {header}");
    }
    for col in ["rms_error_x_m", "max_tilt_deg", "failsafes", "touchdown_speed_m_s"] {
        assert!(header.split(',').any(|c| c == col), "runs.csv lacks {col}");
    }
    assert_eq!(csv.lines().count(), 9);

    // Four shards: two with --shard, one as a Slurm array task, one as a Kubernetes Indexed Job's pod.
    let shards: Vec<PathBuf> = (1..=4).map(|i| tmp(&format!("shard{i}"))).collect();
    sweep(&shards[0], &["--shard", "1/4"], &[]);
    sweep(&shards[1], &["--shard", "2/4"], &[]);
    sweep(&shards[2], &[], &[("SLURM_ARRAY_TASK_ID", "2"), ("SLURM_ARRAY_TASK_COUNT", "4")]);
    sweep(&shards[3], &["--shards", "4"], &[("JOB_COMPLETION_INDEX", "3")]);
    for (i, d) in shards.iter().enumerate() {
        let rows = std::fs::read_to_string(d.join("runs.csv")).unwrap().lines().count() - 1;
        assert_eq!(rows, 2, "shard {} has runs {i}, {}", i + 1, i + 5);
    }
    let merged = tmp("merged");
    let mut c = bin();
    c.args(["sweep", "merge"]).args(&shards).arg("--out").arg(&merged);
    let r = c.output().unwrap();
    assert!(matches!(r.status.code(), Some(0) | Some(3)), "{}", String::from_utf8_lossy(&r.stderr));
    for f in ["runs.csv", "report.json"] {
        assert_eq!(
            std::fs::read(merged.join(f)).unwrap(),
            std::fs::read(whole.join(f)).unwrap(),
            "{f}: the merged shards differ from the whole sweep"
        );
    }
    // A missing shard is refused, naming the missing runs.
    let r =
        bin().args(["sweep", "merge"]).args(&shards[..3]).arg("--out").arg(tmp("partial")).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("missing"), "{}", String::from_utf8_lossy(&r.stderr));
    // A shard given twice: its runs would be in the merge twice; refused, naming both (it used to be dropped
    // silently).
    let twice: Vec<&std::path::PathBuf> = shards.iter().chain([&shards[0]]).collect();
    let r = bin().args(["sweep", "merge"]).args(&twice).arg("--out").arg(tmp("twice")).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("is in two shards"), "{err}");

    // A run alone: `fly --vary --run K --seed S` flies the very run the sweep flew.
    let row: Vec<&str> = csv.lines().nth(3).unwrap().split(',').collect();
    let col = |name: &str| header.split(',').position(|c| c == name).unwrap();
    let alone = tmp("alone");
    let r = bin()
        .args(["fly", "--vary"])
        .arg(campaign())
        .args(["--run", row[0], "--seed", "7", "--camera", "analytic", "--no-plots", "--no-log", "--out"])
        .arg(&alone)
        .output()
        .unwrap();
    assert!(matches!(r.status.code(), Some(0) | Some(3)), "{}", String::from_utf8_lossy(&r.stderr));
    let s: Value =
        serde_json::from_str(&std::fs::read_to_string(alone.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["seed"].to_string(), row[col("seed")]);
    let rms_x: f64 = row[col("rms_error_x_m")].parse().unwrap_or(f64::NAN);
    let alone_x = s["rms_error_m"]["x"].as_f64().unwrap_or(f64::NAN);
    assert!((rms_x - alone_x).abs() < 2e-6 || (rms_x.is_nan() && alone_x.is_nan()), "{rms_x} vs {alone_x}");
    assert!(alone.join("scenario.toml").is_file(), "the drawn scenario is written beside the outputs");
    for d in shards.iter().chain([&whole, &merged, &alone]) {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn bad_sweep_options_are_refused_by_name() {
    let out = tmp("bad");
    for (args, says) in [
        (vec!["--shard", "5/4"], "--shard"),
        (vec!["--shard", "x"], "--shard"),
        (vec!["--runs", "0"], "--runs"),
    ] {
        let mut c = bin();
        c.args(["sweep", "--vary"]).arg(campaign()).arg("--out").arg(&out);
        if !args.contains(&"--runs") {
            c.args(["--runs", "4"]);
        }
        let r = c.args(&args).output().unwrap();
        assert_ne!(r.status.code(), Some(0), "{args:?}");
        assert!(
            String::from_utf8_lossy(&r.stderr).contains(says),
            "{args:?}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
    }
    let bad = out.with_extension("toml");
    std::fs::write(&bad, "[vary]\n\"mismatch.no_such_field\" = { uniform = [0, 1] }\n").unwrap();
    let r =
        bin().args(["sweep", "--vary"]).arg(&bad).args(["--runs", "2", "--out"]).arg(&out).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&r.stderr).contains("mismatch.no_such_field"),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let _ = std::fs::remove_file(&bad);
}
