//! Firmware in the loop: the flight firmware's ELF runs in QEMU's STM32F405 model (`netduinoplus2`) and flies
//! the simulated vehicle, in lockstep (`flight_core::fil`).
//!
//! The wire is two named pipes in a directory of this run, `fil-to-fc` and `fil-from-fc`, which the firmware
//! reads and writes through QEMU's semihosting, a block per call (the firmware's `fil_io.rs`; QEMU's UART model
//! moves one byte per turn of its main loop, which held the lockstep to 0.1-0.35 of real time). Each control
//! period the simulator sends the radio messages that arrived and the period's sensors; the firmware steps and
//! answers with its radio messages and the step's report. QEMU runs with `-icount shift=0`: every guest
//! instruction takes one nanosecond of virtual time, so the firmware's SysTick (168 MHz) counts 0.168 per
//! instruction and each step's cost is reproducible (the host's work between the calls costs the guest
//! nothing). QEMU is killed, and the directory removed, when the run ends, fails or is dropped.
use anyhow::{Context, Result, bail};
use flight_core::StepReport;
use flight_core::fil::{FcToFil, FilToFc, MAX_IMU_PER_STEP, SensorStep};
use protocol::Downlink;
use protocol::frame::{Decoder, MAX_FRAME, WIRE_VERSION, encode};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The QEMU binary.
pub const QEMU: &str = "qemu-system-arm";
/// Cycles of the emulated 168 MHz clock per instruction under `-icount shift=0`.
pub const CYCLES_PER_INSTRUCTION: f64 = 0.168;
/// The budget of one control step: 20 % of the 2 ms period at 168 MHz, one instruction per cycle.
pub const STEP_BUDGET_INSTRUCTIONS: u32 = 67_200;
/// Instructions per second of the 168 MHz core at one instruction per cycle (for the CPU share of the
/// background work).
pub const CORE_INSTRUCTIONS_PER_S: f64 = 168e6;

/// How to run the firmware.
#[derive(Clone, Debug)]
pub struct QemuOptions {
    /// The firmware ELF (built with `--features fil`).
    pub elf: PathBuf,
    /// How long the firmware may take to boot and say hello (wall clock).
    pub boot_timeout: Duration,
    /// How long one step may take to answer (wall clock).
    pub step_timeout: Duration,
    /// Further QEMU arguments, e.g. `-d exec,nochain -D trace.log` for an execution trace or `-s -S` to
    /// attach a debugger (from the environment variable `SIM_HOST_QEMU_ARGS`, split at white space).
    pub extra_args: Vec<String>,
}

impl QemuOptions {
    /// Defaults for an ELF: 20 s to boot, 10 s per step, extra arguments from `SIM_HOST_QEMU_ARGS`.
    pub fn new(elf: impl Into<PathBuf>) -> Self {
        let extra_args = std::env::var("SIM_HOST_QEMU_ARGS")
            .map(|a| a.split_whitespace().map(str::to_string).collect())
            .unwrap_or_default();
        Self {
            elf: elf.into(),
            boot_timeout: Duration::from_secs(20),
            step_timeout: Duration::from_secs(10),
            extra_args,
        }
    }
}

/// One step's answer.
#[derive(Clone, Debug)]
pub struct FcStep {
    /// What the step returned.
    pub report: StepReport,
    /// Its cost in emulated clock cycles.
    pub cost_cycles: u32,
    /// The cost of the background work (pose solves) the firmware ran after the previous step (cycles).
    pub background_cycles: u32,
    /// Frames that background work solved.
    pub background_solves: u8,
    /// The radio messages the firmware sent during the step.
    pub downlink: Vec<Downlink>,
}

impl FcStep {
    /// The step's cost in instructions.
    pub fn instructions(&self) -> u32 {
        to_instructions(self.cost_cycles)
    }

    /// The cost of the background work after the previous step, in instructions.
    pub fn background_instructions(&self) -> u32 {
        to_instructions(self.background_cycles)
    }
}

fn to_instructions(cycles: u32) -> u32 {
    (cycles as f64 / CYCLES_PER_INSTRUCTION).round() as u32
}

/// QEMU's console output (semihosting prints, errors), kept for messages.
#[derive(Clone, Default)]
struct Console(Arc<Mutex<String>>);

impl Console {
    fn text(&self) -> String {
        self.0.lock().map(|s| s.clone()).unwrap_or_default()
    }

    fn tail(&self) -> String {
        let t = self.text();
        let lines: Vec<&str> = t.lines().collect();
        let tail = lines[lines.len().saturating_sub(12)..].join("\n  ");
        if tail.is_empty() { "(nothing)".to_string() } else { format!("\n  {tail}") }
    }

    fn follow(&self, mut r: impl Read + Send + 'static) {
        let sink = self.0.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 1024];
            while let Ok(n) = r.read(&mut buf) {
                if n == 0 {
                    break;
                }
                if let Ok(mut s) = sink.lock() {
                    s.push_str(&String::from_utf8_lossy(&buf[..n]));
                }
            }
        });
    }
}

/// The pipe the firmware reads, and the one it writes, in QEMU's working directory.
pub const PIPE_TO_FC: &str = "fil-to-fc";
/// See [`PIPE_TO_FC`].
pub const PIPE_FROM_FC: &str = "fil-from-fc";

/// The firmware running in QEMU.
pub struct QemuFc {
    child: Child,
    /// This run's directory: the pipes, QEMU's working directory.
    dir: PathBuf,
    /// The pipes, opened for reading and writing so that neither end's open blocks and a firmware that has
    /// not opened its end yet loses nothing.
    to_fc: File,
    from_fc: File,
    decoder: Decoder,
    /// Bytes read from the UART and not yet decoded (`rx[rx_pos..rx_len]`).
    rx: Box<[u8; 4096]>,
    rx_pos: usize,
    rx_len: usize,
    console: Console,
    opts: QemuOptions,
    steps: u64,
    finished: bool,
}

impl Drop for QemuFc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A fresh directory with the two pipes, and both opened.
fn make_pipes() -> Result<(PathBuf, File, File)> {
    use std::sync::atomic::{AtomicU32, Ordering};
    static RUNS: AtomicU32 = AtomicU32::new(0);
    let dir = std::env::temp_dir().join(format!(
        "wlq-fil-{}-{}",
        std::process::id(),
        RUNS.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let open = |name: &str| -> Result<File> {
        let path = dir.join(name);
        rustix::fs::mkfifoat(rustix::fs::CWD, &path, rustix::fs::Mode::from_raw_mode(0o600))
            .with_context(|| format!("making the pipe {}", path.display()))?;
        std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .with_context(|| format!("opening the pipe {}", path.display()))
    };
    let to_fc = open(PIPE_TO_FC);
    let from_fc = open(PIPE_FROM_FC);
    match (to_fc, from_fc) {
        (Ok(a), Ok(b)) => Ok((dir, a, b)),
        (Err(e), _) | (_, Err(e)) => {
            let _ = std::fs::remove_dir_all(&dir);
            Err(e)
        }
    }
}

fn check_elf(path: &Path) -> Result<()> {
    let mut f = std::fs::File::open(path).with_context(|| format!("firmware ELF {}", path.display()))?;
    let mut magic = [0u8; 20];
    let n = f.read(&mut magic).with_context(|| format!("reading {}", path.display()))?;
    if n < 20 || &magic[..4] != b"\x7fELF" {
        bail!("{} is not an ELF file", path.display());
    }
    // e_machine 40 = ARM, little endian.
    if u16::from_le_bytes([magic[18], magic[19]]) != 40 {
        bail!("{} is not an ARM ELF (build the firmware for thumbv7em-none-eabihf)", path.display());
    }
    Ok(())
}

impl QemuFc {
    /// Starts QEMU with the ELF and waits for the firmware's hello.
    pub fn start(opts: &QemuOptions) -> Result<Self> {
        check_elf(&opts.elf)?;
        // QEMU runs in the pipes' directory, so the ELF's path must not be relative to ours.
        let elf = std::fs::canonicalize(&opts.elf)
            .with_context(|| format!("firmware ELF {}", opts.elf.display()))?;
        let (dir, to_fc, from_fc) = make_pipes()?;
        let mut cmd = Command::new(QEMU);
        cmd.current_dir(&dir)
            .args(["-machine", "netduinoplus2", "-nographic", "-monitor", "none", "-serial", "null"])
            .args(["-semihosting-config", "enable=on,target=native", "-icount", "shift=0", "-kernel"])
            .arg(&elf)
            .args(opts.extra_args.iter())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = match cmd.spawn() {
            Ok(c) => c,
            Err(e) => {
                let _ = std::fs::remove_dir_all(&dir);
                if e.kind() == std::io::ErrorKind::NotFound {
                    bail!(
                        "{QEMU} not found: install QEMU's ARM system emulator (Debian and Ubuntu: \
                         `apt-get install qemu-system-arm`)"
                    );
                }
                return Err(e).context(format!("cannot start {QEMU}"));
            }
        };
        let console = Console::default();
        if let Some(o) = child.stdout.take() {
            console.follow(o);
        }
        if let Some(e) = child.stderr.take() {
            console.follow(e);
        }
        // From here on, `fc` owns the child and the directory: any error kills QEMU and removes them on drop.
        let mut fc = Self {
            child,
            dir,
            to_fc,
            from_fc,
            decoder: Decoder::new(),
            rx: Box::new([0; 4096]),
            rx_pos: 0,
            rx_len: 0,
            console,
            opts: opts.clone(),
            steps: 0,
            finished: false,
        };
        match fc.receive(opts.boot_timeout, "boot")? {
            FcToFil::Hello { wire_version } if wire_version == WIRE_VERSION => Ok(fc),
            FcToFil::Hello { wire_version } => {
                bail!(
                    "the firmware speaks wire version {wire_version}, this simulator {WIRE_VERSION}: rebuild it"
                )
            }
            other => bail!("the firmware's first message was not hello: {other:?}"),
        }
    }

    fn send(&mut self, msg: &FilToFc) -> Result<()> {
        let mut buf = [0u8; MAX_FRAME];
        let frame = encode(msg, &mut buf).map_err(|e| anyhow::anyhow!("cannot frame {msg:?}: {e:?}"))?;
        self.to_fc.write_all(frame).with_context(|| self.lost("writing to the firmware's pipe"))
    }

    fn lost(&mut self, what: &str) -> String {
        let exited = match self.child.try_wait() {
            Ok(Some(s)) => format!("QEMU exited ({s})"),
            _ => "QEMU is still running".to_string(),
        };
        format!("{what} at step {}: {exited}; it printed: {}", self.steps, self.console.tail())
    }

    /// Reads until one whole message arrives, or `timeout` passes.
    fn receive(&mut self, timeout: Duration, what: &str) -> Result<FcToFil> {
        let deadline = Instant::now() + timeout;
        loop {
            // What is buffered first: a read may have brought the start of the next message.
            while self.rx_pos < self.rx_len {
                let byte = self.rx[self.rx_pos];
                self.rx_pos += 1;
                if let Some(r) = self.decoder.push::<FcToFil>(byte) {
                    match r {
                        Ok(m) => return Ok(m),
                        Err(e) => {
                            let msg = self.lost(&format!("a garbled frame from the firmware ({e:?})"));
                            bail!(msg);
                        }
                    }
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                let msg = self.lost(&format!("the firmware did not answer ({what}) within {timeout:?}"));
                bail!(msg);
            }
            // Wait for bytes at most 0.1 s at a time, so that a QEMU that exited is noticed (this process holds
            // both ends of the pipe, so its read would never see an end of file).
            let slice = left.min(Duration::from_millis(100));
            let ts = rustix::event::Timespec {
                tv_sec: slice.as_secs() as i64,
                tv_nsec: slice.subsec_nanos() as i64,
            };
            let mut fds = [rustix::event::PollFd::new(&self.from_fc, rustix::event::PollFlags::IN)];
            match rustix::event::poll(&mut fds, Some(&ts)) {
                Ok(0) => {
                    if let Ok(Some(_)) = self.child.try_wait() {
                        let msg = self.lost("the firmware stopped answering");
                        bail!(msg);
                    }
                    continue;
                }
                Ok(_) => {}
                Err(rustix::io::Errno::INTR) => continue,
                Err(e) => {
                    let msg = self.lost(&format!("waiting for the firmware's pipe failed ({e})"));
                    bail!(msg);
                }
            }
            match self.from_fc.read(&mut self.rx[..]) {
                Ok(n) => (self.rx_pos, self.rx_len) = (0, n),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    let msg = self.lost(&format!("reading the firmware's pipe failed ({e})"));
                    bail!(msg);
                }
            }
        }
    }

    /// One control period: the radio messages, then the sensors; the firmware's step and messages back.
    pub fn step(&mut self, input: &flight_core::StepInput<'_>) -> Result<FcStep> {
        if input.imu.len() > MAX_IMU_PER_STEP {
            bail!("{} IMU samples in one step: the link carries {MAX_IMU_PER_STEP} at most", input.imu.len());
        }
        let imu =
            heapless::Vec::from_slice(input.imu).map_err(|_| anyhow::anyhow!("too many IMU samples"))?;
        // One write for the whole period: the radio messages, then the sensors.
        let mut out = Vec::with_capacity(MAX_FRAME * (input.uplink.len() + 1));
        let mut buf = [0u8; MAX_FRAME];
        // The radio messages, the pilot's transmitter when there is one, then the sensors.
        let msgs = input
            .uplink
            .iter()
            .map(|m| FilToFc::Link(*m))
            .chain(input.pilot.map(FilToFc::Pilot))
            .chain(input.battery.map(FilToFc::Battery));
        for msg in msgs.chain([FilToFc::Step(SensorStep {
            time_us: input.time_us,
            imu,
            mag: input.mag,
            baro_m: input.baro_m,
            landed: input.landed,
        })]) {
            let frame = encode(&msg, &mut buf).map_err(|e| anyhow::anyhow!("cannot frame {msg:?}: {e:?}"))?;
            out.extend_from_slice(frame);
        }
        self.to_fc.write_all(&out).with_context(|| self.lost("writing to the firmware's pipe"))?;
        let mut downlink = Vec::new();
        let timeout = self.opts.step_timeout;
        loop {
            match self.receive(timeout, "step")? {
                FcToFil::Link(d) => downlink.push(d),
                FcToFil::Step { report, cost_cycles, background_cycles, background_solves } => {
                    self.steps += 1;
                    return Ok(FcStep {
                        report,
                        cost_cycles,
                        background_cycles,
                        background_solves,
                        downlink,
                    });
                }
                FcToFil::Hello { .. } => {
                    let msg = self.lost("the firmware restarted (hello again)");
                    bail!(msg);
                }
                FcToFil::AuthCost(_) => {
                    let msg = self.lost("an answer to no question (AuthCost during a step)");
                    bail!(msg);
                }
            }
        }
    }

    /// Uploads a whole flight configuration as a station does on the ground (the pieces of
    /// `flight_core::config_upload` over the radio's path) and waits for the firmware's answer: an error unless
    /// it rebuilt its flight stack from it. Sent before the first step, it makes the firmware fly exactly what
    /// a flight stack built from `cfg` in this process flies.
    pub fn configure(&mut self, cfg: &flight_core::FlightConfig) -> Result<protocol::ConfigAck> {
        let (crc32, pieces) = flight_core::config_upload::chunks(cfg)
            .map_err(|r| anyhow::anyhow!("the configuration cannot be uploaded: {r:?}"))?;
        let mut out = Vec::new();
        let mut buf = [0u8; MAX_FRAME];
        for p in &pieces {
            let msg = FilToFc::Link(protocol::Uplink::Config(*p));
            out.extend_from_slice(
                encode(&msg, &mut buf).map_err(|e| anyhow::anyhow!("cannot frame {msg:?}: {e:?}"))?,
            );
        }
        self.to_fc.write_all(&out).with_context(|| self.lost("writing to the firmware's pipe"))?;
        match self.receive(self.opts.step_timeout, "configuration upload")? {
            FcToFil::Link(Downlink::ConfigAck(a)) if a.crc32 == crc32 => match a.outcome {
                protocol::ConfigOutcome::Applied { .. } => Ok(a),
                protocol::ConfigOutcome::Refused(r) => bail!("the firmware refused the configuration: {r:?}"),
            },
            other => bail!("the firmware answered the configuration upload with {other:?}"),
        }
    }

    /// The keyed link's cost per frame on the firmware (`flight_core::fil::measure_auth_cost`), in
    /// instructions.
    pub fn auth_cost(&mut self) -> Result<flight_core::fil::AuthCost> {
        self.send(&FilToFc::AuthCost)?;
        match self.receive(self.opts.step_timeout, "auth cost")? {
            FcToFil::AuthCost(c) => Ok(flight_core::fil::AuthCost {
                handshake: to_instructions(c.handshake),
                open: c.open.map(to_instructions),
                seal: c.seal.map(to_instructions),
                failures: c.failures,
            }),
            other => bail!("the firmware answered the auth-cost request with {other:?}"),
        }
    }

    /// Ends the run: the firmware reports (stack high-water mark, counts) and exits. Returns QEMU's output.
    pub fn finish(mut self) -> Result<String> {
        self.finished = true;
        self.send(&FilToFc::Stop)?;
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                // Give the console threads a moment to drain.
                std::thread::sleep(Duration::from_millis(50));
                return Ok(self.console.text());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(self.console.text())
    }

    /// Steps answered so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }
}

/// Parses `--fc`: `sil` (the flight code in this process) or `qemu:PATH` (the firmware ELF in QEMU).
pub fn parse_fc(s: &str) -> Result<Option<PathBuf>> {
    if s == "sil" {
        return Ok(None);
    }
    match s.strip_prefix("qemu:") {
        Some(p) if !p.is_empty() => Ok(Some(PathBuf::from(p))),
        _ => bail!("--fc: expected `sil` or `qemu:PATH/TO/ELF`, got `{s}`"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flight_computer_option_is_checked() {
        assert_eq!(parse_fc("sil").unwrap(), None);
        assert_eq!(parse_fc("qemu:fw.elf").unwrap(), Some(PathBuf::from("fw.elf")));
        for bad in ["qemu:", "hitl", "QEMU:x"] {
            assert!(format!("{:#}", parse_fc(bad).unwrap_err()).contains("expected `sil` or `qemu:"));
        }
    }

    #[test]
    fn a_missing_or_foreign_elf_is_refused_before_qemu_starts() {
        let dir = std::env::temp_dir().join(format!("fil-elf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = format!("{:#}", QemuFc::start(&QemuOptions::new(dir.join("none"))).err().unwrap());
        assert!(e.contains("firmware ELF"), "{e}");
        let text = dir.join("text");
        std::fs::write(&text, b"#!/bin/sh\necho not firmware\n").unwrap();
        let e = format!("{:#}", QemuFc::start(&QemuOptions::new(&text)).err().unwrap());
        assert!(e.contains("is not an ELF file"), "{e}");
        // This test binary: an ELF, but not for the MCU.
        let me = std::env::current_exe().unwrap();
        let e = format!("{:#}", QemuFc::start(&QemuOptions::new(me)).err().unwrap());
        assert!(e.contains("is not an ARM ELF"), "{e}");
    }
}
