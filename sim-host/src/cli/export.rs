//! `sim-host export`: flight logs to MCAP and CSV.
use super::common::{ProgressItems, progress_bar};
use anyhow::{Result, bail};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub(crate) struct ExportArgs {
    /// The flight log.
    pub(crate) log: PathBuf,
    /// Write an MCAP file: one channel per topic; poses, images, body frames (/tf), the scene and the forward
    /// image's annotations in Foxglove's protobuf schemas, our records as JSON with JSON Schemas.
    #[arg(long, value_name = "FILE")]
    pub(crate) mcap: Option<PathBuf>,
    /// Write one CSV file per topic into this directory (nested fields as dotted columns).
    #[arg(long, value_name = "DIR")]
    pub(crate) csv: Option<PathBuf>,
}
pub(crate) fn run_export(a: &ExportArgs) -> Result<ExitCode> {
    if a.mcap.is_none() && a.csv.is_none() {
        bail!("nothing to export: give --mcap FILE and/or --csv DIR");
    }
    let outputs: Vec<&std::path::Path> =
        [a.mcap.as_deref(), a.csv.as_deref()].into_iter().flatten().collect();
    sim_host::files::refuse_overwrites(&outputs, &[&a.log])?;
    if let Some(dir) = &a.csv {
        // A CSV file is named after its topic (`/estimate/pose` -> `estimate_pose.csv`): a log in that
        // directory with a `.csv` name could be one of them.
        let in_dir = match (a.log.canonicalize(), dir.canonicalize()) {
            (Ok(log), Ok(d)) => log.parent() == Some(d.as_path()),
            _ => false,
        };
        if in_dir && a.log.extension().is_some_and(|e| e == "csv") {
            bail!(
                "refusing to write CSV files into {}: the input {} is there with a name an exported topic may \
                 take (choose another directory)",
                dir.display(),
                a.log.display()
            );
        }
    }
    let file_len = std::fs::metadata(&a.log).map(|m| m.len()).unwrap_or(0);
    let mut damaged = false;
    let outputs: [(Option<&PathBuf>, bool); 2] = [(a.mcap.as_ref(), true), (a.csv.as_ref(), false)];
    for (path, mcap) in outputs {
        let Some(path) = path else { continue };
        // CSV files list the frames but do not hold their pixels: skip them unread.
        let reader = sim_host::flightlog::open_log(&a.log)?;
        let header = reader.header.clone();
        let bar = progress_bar(
            file_len.max(1),
            "{spinner} exporting [{bar:40}] {bytes}/{total_bytes} ({elapsed} elapsed)",
        );
        let mut count = 0u64;
        let items = ProgressItems { inner: reader, bar: &bar, count: &mut count };
        let s = if mcap {
            sim_host::export::export_mcap(&header, items, path)?
        } else {
            sim_host::export::export_csv(&header, items, path)?
        };
        bar.finish_and_clear();
        let total: u64 = s.messages.values().sum();
        eprintln!("wrote {} ({} topics, {total} messages)", path.display(), s.messages.len());
        for (topic, n) in &s.messages {
            eprintln!("  {topic:<22} {n}");
        }
        for d in &s.damage {
            eprintln!("damaged record {d} (skipped)");
        }
        for n in &s.notes {
            eprintln!("note: {n}");
        }
        damaged |= !s.damage.is_empty();
    }
    Ok(if damaged { ExitCode::from(1) } else { ExitCode::SUCCESS })
}
