//! What the commands share: number lists, progress bars, real-time factors.
use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};

pub(crate) fn parse_floats<const N: usize>(s: &str, what: &str) -> Result<[f64; N]> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        bail!("{what}: expected {N} comma-separated numbers, got `{s}`");
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.parse::<f64>().with_context(|| format!("{what}: `{p}` is not a number"))?;
        if !o.is_finite() {
            bail!("{what}: `{p}` is not finite");
        }
    }
    Ok(out)
}
/// A progress bar of `len` steps with a template.
pub(crate) fn progress_bar(len: u64, template: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

/// Log records with a progress bar on their byte offsets.
pub(crate) struct ProgressItems<'a, R: std::io::BufRead> {
    pub(crate) inner: sim_host::flightlog::LogReader<R>,
    pub(crate) bar: &'a ProgressBar,
    pub(crate) count: &'a mut u64,
}

impl<R: std::io::BufRead> Iterator for ProgressItems<'_, R> {
    type Item = sim_host::flightlog::LogItem;
    fn next(&mut self) -> Option<Self::Item> {
        let item = self.inner.next();
        *self.count += 1;
        if self.count.is_multiple_of(4096) {
            self.bar.set_position(self.inner.offset() as u64);
        }
        item
    }
}

/// A real-time factor for people: "450x", "2.3x", "0.27x".
pub(crate) fn rtf_text(rtf: f64) -> String {
    if rtf >= 10.0 {
        format!("{rtf:.0}x")
    } else if rtf >= 1.0 {
        format!("{rtf:.1}x")
    } else {
        format!("{rtf:.2}x")
    }
}
