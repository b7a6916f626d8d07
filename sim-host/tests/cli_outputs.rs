//! No command writes over one of its inputs, or writes two of its outputs to one file: each is refused before
//! anything is written, naming the file, and the input is left byte for byte as it was.
use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sim-host"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sim-host-outputs-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `cmd` and asserts that it was refused with exit 1, naming `named`, and that `input` is unchanged.
fn assert_refused(cmd: &mut Command, input: &Path, named: &Path) {
    let before = std::fs::read(input).unwrap();
    let r = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{cmd:?}: {err}");
    assert!(err.contains("refusing to write") && err.contains(&*named.to_string_lossy()), "{cmd:?}: {err}");
    assert_eq!(std::fs::read(input).unwrap(), before, "{cmd:?} changed its input {}", input.display());
}

#[test]
fn no_command_writes_over_its_input() {
    let dir = tmp("in");
    let r = bin()
        .args(["fly", "--camera", "analytic", "--duration", "1", "--no-plots", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let log = dir.join("flight.log");

    // Export: the MCAP file is the log, directly, through `..` and through a link; a CSV file would be the log.
    assert_refused(bin().arg("export").arg(&log).arg("--mcap").arg(&log), &log, &log);
    let dotted = dir.join("sub").join("..").join("flight.log");
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    assert_refused(bin().arg("export").arg(&log).arg("--mcap").arg(&dotted), &log, &dotted);
    #[cfg(unix)]
    {
        let link = dir.join("link.mcap");
        std::os::unix::fs::symlink(&log, &link).unwrap();
        assert_refused(bin().arg("export").arg(&log).arg("--mcap").arg(&link), &log, &link);
    }
    let csv_dir = tmp("csv");
    let as_csv = csv_dir.join("motors.csv");
    std::fs::copy(&log, &as_csv).unwrap();
    assert_refused(bin().arg("export").arg(&as_csv).arg("--csv").arg(&csv_dir), &as_csv, &as_csv);
    assert_refused(bin().arg("export").arg(&log).arg("--csv").arg(&log), &log, &log);

    // Replay: the summary or the replayed log is the input, or both outputs are one file.
    assert_refused(bin().arg("replay").arg(&log).arg("--out").arg(&log), &log, &log);
    assert_refused(bin().arg("replay").arg(&log).arg("--summary").arg(&log), &log, &log);
    let both = dir.join("both.out");
    let r =
        bin().arg("replay").arg(&log).arg("--out").arg(&both).arg("--summary").arg(&both).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("refusing to write") && err.contains("both.out"), "{err}");
    assert!(!both.exists());

    // Fly: the drawn scenario of a sweep's run would replace the scenario it was drawn from.
    let scen_dir = tmp("scen");
    let scenario = scen_dir.join("scenario.toml");
    std::fs::copy(env!("CARGO_MANIFEST_DIR").to_string() + "/scenarios/paper.toml", &scenario).unwrap();
    let vary = env!("CARGO_MANIFEST_DIR").to_string() + "/sweeps/campaign.toml";
    assert_refused(
        bin()
            .arg("fly")
            .arg("--scenario")
            .arg(&scenario)
            .args(["--vary", &vary, "--run", "3", "--camera", "analytic", "--duration", "1", "--out"])
            .arg(&scen_dir),
        &scenario,
        &scenario,
    );
    // Fly's summary would replace its scenario.
    let as_summary = scen_dir.join("summary.json");
    std::fs::copy(&scenario, &as_summary).unwrap();
    assert_refused(
        bin()
            .arg("fly")
            .arg("--scenario")
            .arg(&as_summary)
            .args(["--camera", "analytic", "--duration", "1", "--no-plots", "--out"])
            .arg(&scen_dir),
        &as_summary,
        &as_summary,
    );

    // Render and vision pose: the frame written is the scenario read, or the overlay is the image measured.
    assert_refused(
        bin()
            .args(["render", "--camera", "forward", "--pose", "1,1.3,0.8,0,0,0", "--scenario"])
            .arg(&scenario)
            .arg("--out")
            .arg(&scenario),
        &scenario,
        &scenario,
    );
    let frame = dir.join("frame.png");
    let r = bin()
        .args(["render", "--camera", "forward", "--pose", "1,1.3,0.8,0,0,0", "--out"])
        .arg(&frame)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert_refused(
        bin().args(["vision", "pose", "--image"]).arg(&frame).arg("--overlay").arg(&frame),
        &frame,
        &frame,
    );

    // Sweep: a merge into one of its shards would replace that shard's runs.csv.
    let shard = tmp("shard");
    let r = bin()
        .args(["sweep", "--scenario", "paper", "--vary", &vary, "--runs", "2", "--shard", "1/2", "--out"])
        .arg(&shard)
        .output()
        .unwrap();
    assert!(
        r.status.code() == Some(0) || r.status.code() == Some(3),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let runs = shard.join("runs.csv");
    assert_refused(bin().args(["sweep", "merge"]).arg(&shard).arg("--out").arg(&shard), &runs, &runs);
    // A sweep whose vary file sits where its report goes.
    let vary_dir = tmp("vary");
    let vary_there = vary_dir.join("report.json");
    std::fs::copy(&vary, &vary_there).unwrap();
    assert_refused(
        bin()
            .args(["sweep", "--scenario", "paper", "--runs", "1", "--vary"])
            .arg(&vary_there)
            .arg("--out")
            .arg(&vary_dir),
        &vary_there,
        &vary_there,
    );

    for d in [dir, csv_dir, scen_dir, shard, vary_dir] {
        std::fs::remove_dir_all(d).unwrap();
    }
}
