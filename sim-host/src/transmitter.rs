//! The simulated pilot: an RC transmitter that follows a timed script of stick and switch positions, and the
//! vehicle's CRSF receiver that hears it. The transmitter's RC frames go through the same driver and decoding as
//! the firmware's UART bytes (`flight_core::rc::RcReceiver`), so the flight code gets the `PilotInput` a real
//! receiver would give; an `rc_loss` fault silences the transmitter (an ExpressLRS receiver then stops sending
//! frames, and the driver calls the link lost after 300 ms).
use flight_core::rc::RcReceiver;
use serde::{Deserialize, Serialize};
use uf_crsf::packets::{PacketAddress, RcChannelsPacked, write_packet_to_buffer};

/// The mode switch's positions in a script.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum TxMode {
    /// Low: manual.
    Manual,
    /// Mid: the automatic mode.
    Auto,
    /// High: land.
    Land,
}

/// From `at_s` on, the controls it names are where it says (the others stay where they were).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TxEvent {
    /// When (s of simulated time).
    pub at_s: f64,
    /// The arm switch (true: high).
    #[serde(default)]
    pub arm: Option<bool>,
    /// The mode switch.
    #[serde(default)]
    pub mode: Option<TxMode>,
    /// The kill switch (true: high, motors off).
    #[serde(default)]
    pub kill: Option<bool>,
    /// The roll stick, -1 (left) to 1 (right).
    #[serde(default)]
    pub roll: Option<f64>,
    /// The pitch stick, -1 (back) to 1 (forward).
    #[serde(default)]
    pub pitch: Option<f64>,
    /// The yaw stick, -1 (left) to 1 (right).
    #[serde(default)]
    pub yaw: Option<f64>,
    /// The throttle stick, 0 (down) to 1 (up); 0.5, the centre, holds the height in manual.
    #[serde(default)]
    pub throttle: Option<f64>,
}

/// The scenario's `[transmitter]`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct TransmitterConfig {
    /// Whether the vehicle has an RC receiver (and the pilot a transmitter). Without, the flight code gets no
    /// pilot input, as the paper's vehicle.
    pub enabled: bool,
    /// RC frames a second (ExpressLRS 50-500, TBS Crossfire 50-150).
    pub frame_rate_hz: f64,
    /// What the pilot does when. At the start: sticks centred, throttle at the centre, every switch low (arm
    /// off, mode manual, no kill) unless the first event says otherwise at 0 s.
    pub script: Vec<TxEvent>,
}

impl Default for TransmitterConfig {
    fn default() -> Self {
        Self { enabled: false, frame_rate_hz: 150.0, script: Vec::new() }
    }
}

/// The transmitter's controls now.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Controls {
    arm: bool,
    mode: TxMode,
    kill: bool,
    roll: f64,
    pitch: f64,
    yaw: f64,
    throttle: f64,
}

/// A channel value (172-1811, 992 the centre) for a stick at `v` in -1..1.
fn channel(v: f64) -> u16 {
    let (mid, max) = (drivers::crsf::CHANNEL_MID as f64, drivers::crsf::CHANNEL_MAX as f64);
    (mid + v.clamp(-1.0, 1.0) * (max - mid)).round() as u16
}

/// A switch's channel value: low, mid or high (1000, 1500, 2000 us).
fn switch(position: u8) -> u16 {
    [drivers::crsf::CHANNEL_MIN, drivers::crsf::CHANNEL_MID, drivers::crsf::CHANNEL_MAX]
        [position.min(2) as usize]
}

/// The simulated transmitter and the vehicle's receiver.
pub struct Transmitter {
    script: Vec<TxEvent>,
    next_event: usize,
    controls: Controls,
    channel_map: [u8; 7],
    frame_period_us: u64,
    next_frame_us: u64,
    receiver: RcReceiver,
    /// RC frames sent.
    pub frames_sent: u64,
}

impl Transmitter {
    /// A transmitter following `cfg`'s script, heard by a receiver decoding with `channel_map`
    /// (`rc.channel_map`); `None` when the scenario's vehicle has no receiver.
    pub fn new(cfg: &TransmitterConfig, channel_map: [u8; 7]) -> Option<Self> {
        if !cfg.enabled {
            return None;
        }
        let mut script = cfg.script.clone();
        script.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        Some(Self {
            script,
            next_event: 0,
            controls: Controls {
                arm: false,
                mode: TxMode::Manual,
                kill: false,
                roll: 0.0,
                pitch: 0.0,
                yaw: 0.0,
                throttle: 0.5,
            },
            channel_map,
            frame_period_us: (1e6 / cfg.frame_rate_hz).round().max(1.0) as u64,
            next_frame_us: 0,
            receiver: RcReceiver::new(channel_map),
            frames_sent: 0,
        })
    }

    /// The channels of the controls now, by the channel map.
    fn channels(&self) -> [u16; 16] {
        let c = &self.controls;
        let mut ch = [drivers::crsf::CHANNEL_MID; 16];
        let m = self.channel_map;
        ch[m[0] as usize] = channel(c.roll);
        ch[m[1] as usize] = channel(c.pitch);
        ch[m[2] as usize] = channel(2.0 * c.throttle - 1.0);
        ch[m[3] as usize] = channel(c.yaw);
        ch[m[4] as usize] = switch(if c.arm { 2 } else { 0 });
        ch[m[5] as usize] = switch(match c.mode {
            TxMode::Manual => 0,
            TxMode::Auto => 1,
            TxMode::Land => 2,
        });
        ch[m[6] as usize] = switch(if c.kill { 2 } else { 0 });
        ch
    }

    /// Up to `now_us`: the script's events, and the RC frames sent since (none while `heard` is false), each
    /// frame's bytes given to the receiver at 420 000 baud from its start. Returns the pilot's input as the
    /// flight code gets it at `now_us`.
    pub fn step(&mut self, now_us: u64, heard: bool) -> Option<control_core::pilot::PilotInput> {
        while let Some(e) = self.script.get(self.next_event) {
            if (e.at_s * 1e6) as u64 > now_us {
                break;
            }
            let c = &mut self.controls;
            c.arm = e.arm.unwrap_or(c.arm);
            c.mode = e.mode.unwrap_or(c.mode);
            c.kill = e.kill.unwrap_or(c.kill);
            c.roll = e.roll.unwrap_or(c.roll);
            c.pitch = e.pitch.unwrap_or(c.pitch);
            c.yaw = e.yaw.unwrap_or(c.yaw);
            c.throttle = e.throttle.unwrap_or(c.throttle);
            self.next_event += 1;
        }
        while self.next_frame_us <= now_us {
            let t0 = self.next_frame_us;
            self.next_frame_us += self.frame_period_us;
            if !heard {
                continue;
            }
            let mut buf = [0u8; 64];
            // An RC frame always fits 64 bytes (26 on the wire).
            let n = write_packet_to_buffer(
                &mut buf,
                PacketAddress::FlightController,
                &RcChannelsPacked(self.channels()),
            )
            .unwrap_or(0);
            for (k, b) in buf[..n].iter().enumerate() {
                // 10 bits a byte at 420 000 baud: 23.8 us.
                self.receiver.push(*b, t0 + (k as u64 * 10_000_000) / drivers::crsf::BAUD as u64);
            }
            self.frames_sent += 1;
        }
        self.receiver.pilot(now_us)
    }

    /// The receiver's counters (frames, damage).
    pub fn receiver_counters(&self) -> drivers::crsf::CrsfCounters {
        self.receiver.counters()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use control_core::pilot::{ModeSwitch, RcLink};

    #[test]
    fn the_script_reaches_the_flight_code_through_the_receiver() {
        let cfg = TransmitterConfig {
            enabled: true,
            frame_rate_hz: 150.0,
            script: vec![
                TxEvent { at_s: 1.0, arm: Some(true), mode: Some(TxMode::Auto), ..Default::default() },
                TxEvent { at_s: 2.0, throttle: Some(1.0), roll: Some(-0.5), ..Default::default() },
                TxEvent { at_s: 3.0, kill: Some(true), mode: Some(TxMode::Land), ..Default::default() },
            ],
        };
        assert!(Transmitter::new(&TransmitterConfig::default(), [0, 1, 2, 3, 4, 5, 6]).is_none());
        // A channel map that is not the default.
        let mut tx = Transmitter::new(&cfg, [3, 2, 1, 0, 7, 8, 9]).unwrap();
        let p = tx.step(500_000, true).unwrap();
        assert_eq!((p.link, p.arm, p.mode, p.kill), (RcLink::Ok, false, ModeSwitch::Manual, false));
        // The centre as the 11-bit channel carries it (992 of 172-1811).
        assert!((p.throttle - 0.5).abs() < 1e-3, "{}", p.throttle);
        let p = tx.step(1_500_000, true).unwrap();
        assert_eq!((p.arm, p.mode), (true, ModeSwitch::Auto));
        let p = tx.step(2_500_000, true).unwrap();
        assert_eq!(p.throttle, 1.0);
        assert!((p.roll + 0.5).abs() < 2e-3, "{}", p.roll);
        let p = tx.step(3_100_000, true).unwrap();
        assert_eq!((p.kill, p.mode), (true, ModeSwitch::Land));
        // Silenced: lost after the receiver's 300 ms; heard again: back.
        assert_eq!(tx.step(3_300_000, false).unwrap().link, RcLink::Ok);
        assert_eq!(tx.step(3_500_000, false).unwrap().link, RcLink::Lost);
        assert_eq!(tx.step(3_520_000, true).unwrap().link, RcLink::Ok);
        // About 150 frames a second were sent and every one was taken.
        let c = tx.receiver_counters();
        assert_eq!(c.rc_frames as u64, tx.frames_sent);
        assert!((tx.frames_sent as i64 - 469).abs() <= 2, "{}", tx.frames_sent);
        assert_eq!(c.bad_crc + c.bad_length + c.skipped, 0);
    }
}
