//! The radio link's key on the host: made by `sim-host keygen`, read by `sim-host station --key` and by the
//! virtual vehicle (`sim-host fly --serve-link ... --key`), and the two ends of a keyed link
//! (`protocol::auth`, docs/security.md).
//!
//! A key file holds the 32-byte key as 64 hexadecimal digits and a newline. It must be readable by its owner
//! only (mode 0600, as ssh asks of a private key): a key others can read is refused, naming the file and its
//! mode. The key never enters a log, a summary or an error message.
use anyhow::{Context, Result, bail};
use protocol::auth::{AuthCounters, KEY_LEN, Key, Nonce, Opened, Role, SecureLink};
use protocol::frame::{Decoder, MAX_FRAME};
use serde::{Serialize, de::DeserializeOwned};
use std::io::Write;
use std::path::Path;

/// Creates `path` for a secret, readable by its owner only (mode 0600); an existing file is refused.
fn create_secret_file(path: &Path, what: &str) -> Result<std::fs::File> {
    let mut o = std::fs::OpenOptions::new();
    o.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.mode(0o600);
    }
    o.open(path).with_context(|| {
        format!("{}: cannot create the {what} (an existing file is never overwritten)", path.display())
    })
}

/// Writes a new random key to `path` (mode 0600), refusing a file that exists.
pub fn keygen(path: &Path) -> Result<()> {
    let mut key = [0u8; KEY_LEN];
    getrandom::fill(&mut key).map_err(|e| anyhow::anyhow!("no random source for the key: {e}"))?;
    let mut f = create_secret_file(path, "key file")?;
    let hex: String = key.iter().map(|b| format!("{b:02x}")).collect();
    f.write_all(format!("{hex}\n").as_bytes())
        .with_context(|| format!("{}: writing the key", path.display()))?;
    f.sync_all().with_context(|| format!("{}: writing the key", path.display()))?;
    Ok(())
}

/// Writes the flash block that provisions a board with the key in `key_file`
/// (`protocol::auth::provision`, 48 bytes, mode 0600; refused if `out` exists), for the debug probe to
/// write at `protocol::auth::provision::KEY_BLOCK_ADDRESS`.
pub fn key_image(key_file: &Path, out: &Path) -> Result<()> {
    let key = read_key(key_file)?;
    let block = protocol::auth::provision::key_block(&key);
    let mut f = create_secret_file(out, "key image")?;
    f.write_all(&block).with_context(|| format!("{}: writing the key image", out.display()))?;
    f.sync_all().with_context(|| format!("{}: writing the key image", out.display()))?;
    Ok(())
}

/// Reads a key file, refusing one that others may read, or that is not 64 hexadecimal digits.
pub fn read_key(path: &Path) -> Result<Key> {
    let meta = std::fs::metadata(path).with_context(|| format!("the key file {}", path.display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            bail!(
                "the key file {} is readable by others (mode {mode:04o}): `chmod 600 {}`",
                path.display(),
                path.display()
            );
        }
    }
    #[cfg(not(unix))]
    let _ = meta;
    let text = std::fs::read_to_string(path).with_context(|| format!("the key file {}", path.display()))?;
    let hex = text.trim();
    if hex.len() != 2 * KEY_LEN || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        bail!(
            "the key file {}: {} hexadecimal digits expected (sim-host keygen --out FILE makes one), {} \
             characters found",
            path.display(),
            2 * KEY_LEN,
            hex.len()
        );
    }
    let mut key = [0u8; KEY_LEN];
    for (i, k) in key.iter_mut().enumerate() {
        *k = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16)?;
    }
    Ok(key)
}

/// A fresh random nonce for a handshake.
pub fn random_nonce() -> Result<Nonce> {
    let mut n = [0u8; protocol::auth::NONCE_LEN];
    getrandom::fill(&mut n).map_err(|e| anyhow::anyhow!("no random source for the link's nonce: {e}"))?;
    Ok(n)
}

/// How a link end treats its frames: authenticated with a key, or (for development only, asked for with
/// `--no-key`) not.
pub enum LinkSecurity {
    /// `protocol::auth` frames; everything else refused.
    Keyed(Box<SecureLink>),
    /// Unauthenticated frames (wire version 1): anyone on the radio may command the vehicle.
    Open,
}

impl LinkSecurity {
    /// The link for `role` with `key`, or open without one.
    pub fn new(role: Role, key: Option<Key>) -> Self {
        match key {
            Some(k) => LinkSecurity::Keyed(Box::new(SecureLink::new(role, k))),
            None => LinkSecurity::Open,
        }
    }

    /// What the status and the log header say: `hmac-sha256-48` or `none (development)`.
    pub fn describe(&self) -> &'static str {
        match self {
            LinkSecurity::Keyed(_) => "hmac-sha256-48",
            LinkSecurity::Open => "none (development)",
        }
    }

    /// The authentication's counters (zero on an open link).
    pub fn counters(&self) -> AuthCounters {
        match self {
            LinkSecurity::Keyed(l) => l.counters(),
            LinkSecurity::Open => AuthCounters::default(),
        }
    }

    /// Whether messages may be sent: always on an open link, after the handshake on a keyed one.
    pub fn ready(&self) -> bool {
        match self {
            LinkSecurity::Keyed(l) => l.has_session(),
            LinkSecurity::Open => true,
        }
    }

    /// One message as the frame's bytes.
    pub fn frame<T: Serialize>(&mut self, msg: &T) -> Result<Vec<u8>> {
        let mut out = [0u8; MAX_FRAME];
        let bytes = match self {
            LinkSecurity::Keyed(l) => {
                l.seal(msg, &mut out).map_err(|e| anyhow::anyhow!("sealing a frame: {e:?}"))?
            }
            LinkSecurity::Open => protocol::frame::encode(msg, &mut out)
                .map_err(|e| anyhow::anyhow!("encoding a frame: {e:?}"))?,
        };
        Ok(bytes.to_vec())
    }
}

/// What one received byte completed.
pub enum Received<T> {
    /// A message (authenticated on a keyed link).
    Message(T),
    /// A handshake completed: on the vehicle, these bytes (the welcome) go back at once.
    SessionStarted(Option<Vec<u8>>),
    /// A frame refused (counted by the decoder or the authentication).
    Refused,
}

/// Decodes a link end's incoming bytes through its security.
pub struct LinkReceiver {
    decoder: Decoder,
}

impl Default for LinkReceiver {
    fn default() -> Self {
        Self { decoder: Decoder::new() }
    }
}

impl LinkReceiver {
    /// The decoder's framing counters.
    pub fn framing(&self) -> protocol::frame::DecodeCounters {
        self.decoder.counters()
    }

    /// Feeds one byte received at `now_us`; on the vehicle `armed` and `nonce` as [`SecureLink::open`] takes
    /// them.
    pub fn push<T: DeserializeOwned>(
        &mut self,
        sec: &mut LinkSecurity,
        byte: u8,
        now_us: u64,
        armed: bool,
        nonce: impl FnOnce() -> Nonce,
    ) -> Option<Received<T>> {
        match sec {
            LinkSecurity::Open => match self.decoder.push::<T>(byte)? {
                Ok(m) => Some(Received::Message(m)),
                Err(_) => Some(Received::Refused),
            },
            LinkSecurity::Keyed(link) => {
                let body = match self.decoder.push_body(byte)? {
                    Ok(b) => b,
                    Err(_) => return Some(Received::Refused),
                };
                match link.open::<T>(body, now_us, armed, nonce) {
                    Ok(Opened::Message(m)) => Some(Received::Message(m)),
                    Ok(Opened::SessionStarted) => {
                        let mut out = [0u8; MAX_FRAME];
                        Some(Received::SessionStarted(link.welcome(&mut out).ok().map(|b| b.to_vec())))
                    }
                    Err(_) => Some(Received::Refused),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_file_is_made_private_read_back_and_never_overwritten() {
        let dir = std::env::temp_dir().join(format!("link-key-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("radio.key");
        std::fs::remove_file(&p).ok();
        keygen(&p).unwrap();
        let k = read_key(&p).unwrap();
        assert_ne!(k, [0; KEY_LEN]);
        let e = keygen(&p).unwrap_err().to_string();
        assert!(e.contains("never overwritten"), "{e}");
        assert_eq!(read_key(&p).unwrap(), k, "the key is unchanged");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(std::fs::metadata(&p).unwrap().permissions().mode() & 0o777, 0o600);
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o644)).unwrap();
            let e = read_key(&p).unwrap_err().to_string();
            assert!(e.contains("readable by others") && e.contains("0644") && e.contains("radio.key"), "{e}");
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
        }
        // Not a key: named, with what was expected; the content never echoed.
        std::fs::remove_file(&p).unwrap();
        let mut o = std::fs::OpenOptions::new();
        o.write(true).create_new(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            o.mode(0o600);
        }
        o.open(&p).unwrap().write_all(b"secretsecret\n").unwrap();
        let e = read_key(&p).unwrap_err().to_string();
        assert!(e.contains("64 hexadecimal digits") && !e.contains("secret"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_key_image_holds_the_key_file_s_key_for_the_probe() {
        let dir = std::env::temp_dir().join(format!("key-image-{}", std::process::id()));
        std::fs::remove_dir_all(&dir).ok();
        std::fs::create_dir_all(&dir).unwrap();
        let (key_file, image) = (dir.join("radio.key"), dir.join("key.bin"));
        keygen(&key_file).unwrap();
        key_image(&key_file, &image).unwrap();
        let bytes = std::fs::read(&image).unwrap();
        assert_eq!(bytes.len(), protocol::auth::provision::KEY_BLOCK_LEN);
        assert_eq!(protocol::auth::provision::read_key_block(&bytes), Ok(read_key(&key_file).unwrap()));
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(std::fs::metadata(&image).unwrap().permissions().mode() & 0o777, 0o600);
        }
        // Never overwritten (the image is a copy of the secret; another key's image is not silently lost).
        let e = key_image(&key_file, &image).unwrap_err().to_string();
        assert!(e.contains("key.bin") && e.contains("never overwritten"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn two_link_ends_handshake_and_carry_messages() {
        use protocol::{Downlink, Uplink};
        let key = [3u8; KEY_LEN];
        let (mut st, mut v) =
            (LinkSecurity::new(Role::Station, Some(key)), LinkSecurity::new(Role::Vehicle, Some(key)));
        let (mut st_rx, mut v_rx) = (LinkReceiver::default(), LinkReceiver::default());
        assert!(!st.ready());
        let LinkSecurity::Keyed(l) = &mut st else { unreachable!() };
        let mut out = [0u8; MAX_FRAME];
        let hello = l.hello([1; 16], &mut out).unwrap().to_vec();
        let mut welcome = None;
        for b in hello {
            if let Some(Received::SessionStarted(w)) = v_rx.push::<Uplink>(&mut v, b, 0, false, || [2; 16]) {
                welcome = w;
            }
        }
        for b in welcome.unwrap() {
            st_rx.push::<Downlink>(&mut st, b, 0, false, || [0; 16]);
        }
        assert!(st.ready() && v.ready());
        let mut got = Vec::new();
        for b in st.frame(&Uplink::Heartbeat).unwrap() {
            if let Some(Received::Message(m)) = v_rx.push::<Uplink>(&mut v, b, 1, false, || [2; 16]) {
                got.push(m);
            }
        }
        assert_eq!(got, [Uplink::Heartbeat]);
        // An open link's frame is refused by a keyed end: a downgrade, counted.
        let mut open = LinkSecurity::new(Role::Station, None);
        for b in open.frame(&Uplink::Heartbeat).unwrap() {
            assert!(!matches!(
                v_rx.push::<Uplink>(&mut v, b, 2, false, || [2; 16]),
                Some(Received::Message(_))
            ));
        }
        assert_eq!(v.counters().downgrade, 1);
        assert_eq!((open.describe(), v.describe()), ("none (development)", "hmac-sha256-48"));
    }
}
