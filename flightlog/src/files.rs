//! Writing files without losing data: no command writes over one of its inputs, and every output is written
//! to a temporary file in the same directory and renamed into place when complete, so that an interrupted or
//! failed write leaves the old file (if any) untouched and no half-written file under the final name.
use anyhow::{Context, Result, bail};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The path with links and `..` resolved, also for a file that does not exist yet (its directory is
/// resolved).
fn resolve(p: &Path) -> Option<PathBuf> {
    if let Ok(c) = p.canonicalize() {
        return Some(c);
    }
    let parent = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.canonicalize().ok()?,
        _ => std::env::current_dir().ok()?,
    };
    Some(parent.join(p.file_name()?))
}

/// Refuses an output that is one of the inputs (the same file after resolving links), or an existing file
/// inside an input directory (a dataset's own files).
pub fn refuse_overwrite(out: &Path, inputs: &[&Path]) -> Result<()> {
    let Some(o) = resolve(out) else { return Ok(()) };
    for input in inputs {
        let Some(i) = resolve(input) else { continue };
        if o == i {
            bail!(
                "refusing to write {}: it is an input of this command (choose another output)",
                out.display()
            );
        }
        if i.is_dir() && o.starts_with(&i) && o.exists() {
            bail!(
                "refusing to write {}: it would replace a file of the input {} (choose another output)",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// Refuses, before anything is written, every output that [`refuse_overwrite`] refuses, and two outputs that
/// are one file (the second would replace the first).
pub fn refuse_overwrites(outputs: &[&Path], inputs: &[&Path]) -> Result<()> {
    for o in outputs {
        refuse_overwrite(o, inputs)?;
    }
    for (i, a) in outputs.iter().enumerate() {
        let Some(ra) = resolve(a) else { continue };
        for b in &outputs[i + 1..] {
            if resolve(b).as_ref() == Some(&ra) {
                bail!(
                    "refusing to write {} and {}: they are one file, and the second would replace the first",
                    a.display(),
                    b.display()
                );
            }
        }
    }
    Ok(())
}

/// The last component of `path` (empty for a path without one, such as `/`, whose file then cannot be
/// created anyway).
fn file_name(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// A file written under a temporary name and renamed into place by [`AtomicFile::commit`]; dropped without
/// committing, the temporary file is removed and the destination left as it was.
pub struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    file: Option<std::io::BufWriter<std::fs::File>>,
    /// Bytes the file may still take before writes fail as on a full disk (tests of that path only).
    space: Option<u64>,
    /// Bytes accepted by `write` so far.
    written: u64,
}

impl AtomicFile {
    /// Creates the temporary file beside `path`.
    pub fn create(path: &Path) -> Result<Self> {
        let tmp = path.with_file_name(format!(".{}.partial-{}", file_name(path), std::process::id()));
        let f = std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            tmp,
            file: Some(std::io::BufWriter::with_capacity(1 << 20, f)),
            space: None,
            written: 0,
        })
    }

    /// As [`AtomicFile::create`], on a "disk" that takes `bytes` more bytes: later writes fail with
    /// `StorageFull`, as a full disk's do (for tests of what a full disk does to a command).
    pub fn create_with_space(path: &Path, bytes: u64) -> Result<Self> {
        let mut f = Self::create(path)?;
        f.space = Some(bytes);
        Ok(f)
    }

    /// The name under which [`AtomicFile::keep_partial`] keeps an unfinished file: `NAME.partial`.
    pub fn partial_path(path: &Path) -> PathBuf {
        path.with_file_name(format!("{}.partial", file_name(path)))
    }

    /// Gives up on the file and keeps what reached the disk under [`AtomicFile::partial_path`] (the
    /// destination untouched): a write that failed half way, on a full disk, loses nothing written before it.
    /// Returns that name.
    pub fn keep_partial(mut self) -> Result<PathBuf> {
        let kept = Self::partial_path(&self.path);
        if let Some(f) = self.file.take() {
            // What the buffer still holds goes to the disk if it can (a full disk may refuse it).
            if let Err(e) = f.into_inner() {
                drop(e.into_inner());
            }
            std::fs::rename(&self.tmp, &kept)
                .with_context(|| format!("cannot keep the unfinished file as {}", kept.display()))?;
        }
        Ok(kept)
    }

    /// Gives up after `error` (a failed write: a full disk, a device gone) and keeps what reached the disk,
    /// as [`AtomicFile::keep_partial`]; returns the error that says so, naming the file, the bytes written
    /// and where they are kept.
    pub fn give_up(self, error: anyhow::Error) -> anyhow::Error {
        let path = self.path.clone();
        let written = self.written;
        match self.keep_partial() {
            Ok(kept) => error.context(format!(
                "writing {} failed after {written} bytes; what reached the disk is kept in {}",
                path.display(),
                kept.display()
            )),
            Err(k) => error.context(format!(
                "writing {} failed after {written} bytes, and what was written could not be kept: {k:#}",
                path.display()
            )),
        }
    }

    /// The destination.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes, syncs and renames the file into place.
    pub fn commit(mut self) -> Result<()> {
        if let Some(mut f) = self.file.take() {
            f.flush().with_context(|| format!("writing {}", self.path.display()))?;
            let f = f
                .into_inner()
                .map_err(|e| anyhow::anyhow!("writing {}: {}", self.path.display(), e.error()))?;
            f.sync_all().with_context(|| format!("writing {}", self.path.display()))?;
            std::fs::rename(&self.tmp, &self.path).with_context(|| {
                format!("cannot move the finished file into place as {}", self.path.display())
            })?;
        }
        Ok(())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let buf = match self.space {
            Some(0) if !buf.is_empty() => {
                return Err(std::io::Error::new(std::io::ErrorKind::StorageFull, "no space left on device"));
            }
            Some(n) => &buf[..buf.len().min(n as usize)],
            None => buf,
        };
        match self.file.as_mut() {
            Some(f) => {
                let k = f.write(buf)?;
                if let Some(n) = self.space.as_mut() {
                    *n -= k as u64;
                }
                self.written += k as u64;
                Ok(k)
            }
            None => Err(std::io::Error::other("file already committed")),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self.file.as_mut() {
            Some(f) => f.flush(),
            None => Ok(()),
        }
    }
}

/// Seeking (for formats that go back to fill in a length, as MCAP's chunks do) flushes the buffer first.
impl std::io::Seek for AtomicFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        match self.file.as_mut() {
            Some(f) => f.seek(pos),
            None => Err(std::io::Error::other("file already committed")),
        }
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            // Not committed: the partial file goes, the destination stays as it was. A failure to remove it
            // leaves a hidden `.partial-` file, never a damaged destination.
            if let Err(e) = std::fs::remove_file(&self.tmp) {
                eprintln!("warning: could not remove {}: {e}", self.tmp.display());
            }
        }
    }
}

/// Writes a whole file atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes).with_context(|| format!("writing {}", path.display()))?;
    f.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_input_is_never_an_output() {
        let dir = std::env::temp_dir().join(format!("wlq-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let input = dir.join("in.log");
        std::fs::write(&input, b"data").unwrap();
        assert!(refuse_overwrite(&input, &[&input]).is_err());
        // The same file through `..` and through a link.
        let sub = dir.join("sub");
        std::fs::create_dir_all(&sub).unwrap();
        assert!(refuse_overwrite(&sub.join("../in.log"), &[&input]).is_err());
        #[cfg(unix)]
        {
            let link = dir.join("link.log");
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink(&input, &link).unwrap();
            assert!(refuse_overwrite(&link, &[&input]).is_err());
        }
        assert!(refuse_overwrite(&dir.join("out.log"), &[&input]).is_ok());
        // A dataset directory's own files.
        assert!(refuse_overwrite(&input, &[&dir]).is_err());
        assert!(refuse_overwrite(&dir.join("new.log"), &[&dir]).is_ok());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_uncommitted_file_leaves_the_destination_untouched() {
        let dir = std::env::temp_dir().join(format!("wlq-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("out.bin");
        std::fs::write(&p, b"old").unwrap();
        {
            let mut f = AtomicFile::create(&p).unwrap();
            f.write_all(b"new but unfinished").unwrap();
        }
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "no partial file left");
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"new").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
