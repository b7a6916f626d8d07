//! An RC receiver speaking CRSF (ExpressLRS, TBS Crossfire) on a UART: 420 000 baud 8N1, frames of
//! `[address, length, type, payload, CRC-8/DVB-S2 over type and payload]`. The frame state machine, the CRC and
//! the payloads come from the `uf-crsf` crate; what is here is what a flight stack adds around it: counters for
//! everything refused, the sticks and switches of a channel map, and the receiver's failsafe.
//!
//! Channels are 11-bit values, 172-1811 for 988-2011 us (992 is the centre, 1500 us; Betaflight's and the
//! receivers' own scaling, `us = 1500 + (v - 992) * 5 / 8`). An ExpressLRS receiver in failsafe stops sending RC
//! frames altogether (its "no pulses" mode, the default), and a TBS one may keep sending the last or the
//! preset channels while it reports an uplink link quality of 0: both count as lost here
//! ([`CrsfReceiver::rc`]).
//!
//! Resynchronisation: the crate's state machine takes a start byte in line noise for a frame's start and then
//! swallows the real frame behind it when the false frame's CRC fails. Here, a frame that fails (its CRC or
//! its length) has its bytes after the false start fed again, so a real frame among them is found; and a gap of
//! [`FRAME_GAP_US`] on the line starts the search afresh, as receivers send their frames in bursts (Betaflight
//! resynchronises the same way, on the time since a frame began).
//!
//! Switch positions come with hysteresis, so that a channel at a threshold does not flicker between them.
pub use uf_crsf::packets::{LinkStatistics, RcChannelsPacked};
use uf_crsf::{CrsfParser, CrsfStreamError, Packet};

/// The UART's speed.
pub const BAUD: u32 = 420_000;
/// The channel value at the centre (1500 us).
pub const CHANNEL_MID: u16 = 992;
/// The channel values at the ends of the sticks' travel (988 and 2011 us).
pub const CHANNEL_MIN: u16 = 172;
/// See [`CHANNEL_MIN`].
pub const CHANNEL_MAX: u16 = 1811;
/// No RC frame for this long: the RC link is lost (us). ExpressLRS sends 50-500 frames a second, TBS 50-150;
/// PX4's and Betaflight's defaults are 0.3-0.5 s.
pub const RC_LOST_AFTER_US: u64 = 300_000;

/// A pause on the line this long ends any frame in progress (us): a 64-byte frame takes 1.5 ms at 420 000
/// baud, and receivers send a frame's bytes back to back.
pub const FRAME_GAP_US: u64 = 2_000;

/// A channel value in microseconds of pulse width.
pub fn channel_us(v: u16) -> i32 {
    1500 + (v as i32 - CHANNEL_MID as i32) * 5 / 8
}

/// What the receiver counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CrsfCounters {
    /// Bytes received.
    pub bytes: u32,
    /// Frames whose CRC held.
    pub frames: u32,
    /// RC channel frames.
    pub rc_frames: u32,
    /// Link statistics frames.
    pub link_statistics: u32,
    /// Frames of other kinds (telemetry from other devices, parameters), taken and ignored.
    pub other_frames: u32,
    /// Frames whose CRC failed.
    pub bad_crc: u32,
    /// Length bytes out of range.
    pub bad_length: u32,
    /// Bytes skipped while looking for a frame's start (line noise, a frame cut short).
    pub skipped: u32,
    /// Frames of a known type whose payload did not parse (a wrong length for its type).
    pub bad_payload: u32,
}

/// The RC link as the flight code sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RcState {
    /// Never heard from since power-up.
    NoReceiver,
    /// RC frames arrive and the receiver reports its uplink.
    Ok([u16; 16]),
    /// The last RC frame is older than [`RC_LOST_AFTER_US`], or the receiver reports no uplink.
    Lost,
}

/// A CRSF receiver: bytes in, the RC channels and the link's state out.
#[derive(Debug, Default)]
pub struct CrsfReceiver {
    parser: CrsfParser,
    counters: CrsfCounters,
    channels: Option<[u16; 16]>,
    last_rc_us: Option<u64>,
    link: Option<LinkStatistics>,
    /// The bytes of the frame in progress, from its start byte.
    attempt: heapless::Vec<u8, 64>,
    last_byte_us: Option<u64>,
}

impl CrsfReceiver {
    /// A receiver that has heard nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// What was counted.
    pub fn counters(&self) -> CrsfCounters {
        self.counters
    }

    /// The receiver's last link statistics, if it sent any.
    pub fn link(&self) -> Option<LinkStatistics> {
        self.link.clone()
    }

    /// One byte from the UART, received at `now_us`.
    pub fn push(&mut self, byte: u8, now_us: u64) {
        self.counters.bytes = self.counters.bytes.wrapping_add(1);
        if self.last_byte_us.is_some_and(|t| now_us.saturating_sub(t) >= FRAME_GAP_US)
            && !self.attempt.is_empty()
        {
            // The frame in progress ended without its bytes: a cut frame.
            self.counters.skipped += self.attempt.len() as u32;
            self.attempt.clear();
            self.parser.reset();
        }
        self.last_byte_us = Some(now_us);
        // The byte, and the bytes of failed frames fed again (at most a frame's worth at any time: each
        // feeding again drops the false start).
        let mut pending: heapless::Deque<u8, 128> = heapless::Deque::new();
        let _fits = pending.push_back(byte);
        while let Some(b) = pending.pop_front() {
            // A frame is at most 64 bytes, and the parser never holds more.
            let _fits = self.attempt.push(b);
            let c = &mut self.counters;
            let failed = match self.parser.push_byte(b) {
                Ok(None) => false,
                Ok(Some(p)) => {
                    c.frames += 1;
                    match p {
                        Packet::RCChannels(RcChannelsPacked(ch)) => {
                            c.rc_frames += 1;
                            self.channels = Some(ch);
                            self.last_rc_us = Some(now_us);
                        }
                        Packet::LinkStatistics(l) => {
                            c.link_statistics += 1;
                            self.link = Some(l);
                        }
                        _ => c.other_frames += 1,
                    }
                    self.attempt.clear();
                    false
                }
                Err(CrsfStreamError::InvalidSync(_)) => {
                    c.skipped += 1;
                    self.attempt.clear();
                    false
                }
                Err(CrsfStreamError::InvalidPacketLength(_)) => {
                    c.bad_length += 1;
                    true
                }
                Err(CrsfStreamError::InvalidCrc { .. }) => {
                    c.bad_crc += 1;
                    true
                }
                // The CRC held: a frame of a type the crate does not decode, or whose payload does not fit
                // its type.
                Err(CrsfStreamError::UnexpectedPacketType(_))
                | Err(CrsfStreamError::ParsingError(uf_crsf::CrsfParsingError::UnexpectedPacketType(_)))
                | Err(CrsfStreamError::ParsingError(uf_crsf::CrsfParsingError::PacketNotImlemented(_))) => {
                    c.frames += 1;
                    c.other_frames += 1;
                    self.attempt.clear();
                    false
                }
                Err(_) => {
                    c.frames += 1;
                    c.bad_payload += 1;
                    self.attempt.clear();
                    false
                }
            };
            if failed {
                // The false start is dropped; what followed it is looked at again, before what is pending.
                self.parser.reset();
                for &r in self.attempt.iter().skip(1).rev() {
                    let _fits = pending.push_front(r);
                }
                self.attempt.clear();
            }
        }
    }

    /// The RC link at `now_us`: the channels while frames arrive and the receiver does not report a lost
    /// uplink, lost otherwise.
    pub fn rc(&self, now_us: u64) -> RcState {
        let (Some(ch), Some(at)) = (self.channels, self.last_rc_us) else { return RcState::NoReceiver };
        let stale = now_us.saturating_sub(at) > RC_LOST_AFTER_US;
        let no_uplink = self.link.as_ref().is_some_and(|l| l.uplink_link_quality == 0);
        if stale || no_uplink { RcState::Lost } else { RcState::Ok(ch) }
    }
}

/// A switch's position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchPosition {
    /// Below 1300 us.
    Low,
    /// 1300-1700 us.
    Mid,
    /// Above 1700 us.
    High,
}

/// Hysteresis of the switch thresholds (us): a switch leaves its position only this far past a threshold.
pub const SWITCH_HYSTERESIS_US: i32 = 50;

impl SwitchPosition {
    /// The position of a channel value, given the last position (hysteresis).
    pub fn of(v: u16, last: Option<SwitchPosition>) -> SwitchPosition {
        let us = channel_us(v);
        let (lo, hi) = (1300, 1700);
        let h = SWITCH_HYSTERESIS_US;
        match last {
            Some(SwitchPosition::Low) if us < lo + h => SwitchPosition::Low,
            Some(SwitchPosition::High) if us > hi - h => SwitchPosition::High,
            Some(SwitchPosition::Mid) if us >= lo - h && us <= hi + h => SwitchPosition::Mid,
            _ if us < lo => SwitchPosition::Low,
            _ if us > hi => SwitchPosition::High,
            _ => SwitchPosition::Mid,
        }
    }
}

/// Which channel is what (0-based), a parameter of the vehicle. The default is the usual AETR order of
/// ExpressLRS and Betaflight with the arm switch on the first auxiliary channel (channel 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChannelMap {
    /// Roll stick.
    pub roll: u8,
    /// Pitch stick.
    pub pitch: u8,
    /// Throttle stick.
    pub throttle: u8,
    /// Yaw stick.
    pub yaw: u8,
    /// Arm switch (high: armed).
    pub arm: u8,
    /// Mode switch (low: manual, mid: automatic line tracking, high: land).
    pub mode: u8,
    /// Kill switch (high: motors off, whatever else).
    pub kill: u8,
}

impl Default for ChannelMap {
    fn default() -> Self {
        Self { roll: 0, pitch: 1, throttle: 2, yaw: 3, arm: 4, mode: 5, kill: 6 }
    }
}

impl ChannelMap {
    /// Whether every channel index names one of the 16 channels and no two functions share one.
    pub fn is_valid(&self) -> bool {
        let c = [self.roll, self.pitch, self.throttle, self.yaw, self.arm, self.mode, self.kill];
        c.iter().all(|&i| i < 16) && c.iter().enumerate().all(|(i, a)| c[i + 1..].iter().all(|b| a != b))
    }
}

/// The pilot's inputs, decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RcInputs {
    /// Roll, pitch and yaw sticks, -1 (left, back... as the transmitter sends) to 1; throttle 0 to 1.
    pub roll: f32,
    /// See [`RcInputs::roll`].
    pub pitch: f32,
    /// See [`RcInputs::roll`].
    pub yaw: f32,
    /// See [`RcInputs::roll`].
    pub throttle: f32,
    /// The arm switch.
    pub arm: SwitchPosition,
    /// The mode switch.
    pub mode: SwitchPosition,
    /// The kill switch.
    pub kill: SwitchPosition,
}

fn stick(v: u16) -> f32 {
    ((v as f32 - CHANNEL_MID as f32) / (CHANNEL_MAX - CHANNEL_MID) as f32).clamp(-1.0, 1.0)
}

/// The switches' last positions (for their hysteresis) and the decoding of a channel frame.
#[derive(Clone, Copy, Debug, Default)]
pub struct RcDecoder {
    last: Option<[SwitchPosition; 3]>,
}

impl RcDecoder {
    /// Decodes one channel frame with `map` (a valid one, [`ChannelMap::is_valid`]; an index beyond the
    /// channels reads as the centre).
    pub fn decode(&mut self, ch: &[u16; 16], map: &ChannelMap) -> RcInputs {
        let get = |i: u8| ch.get(i as usize).copied().unwrap_or(CHANNEL_MID);
        let last = self.last;
        let sw = |k: usize, i: u8| SwitchPosition::of(get(i), last.map(|l| l[k]));
        let (arm, mode, kill) = (sw(0, map.arm), sw(1, map.mode), sw(2, map.kill));
        self.last = Some([arm, mode, kill]);
        RcInputs {
            roll: stick(get(map.roll)),
            pitch: stick(get(map.pitch)),
            yaw: stick(get(map.yaw)),
            throttle: ((get(map.throttle) as f32 - CHANNEL_MIN as f32) / (CHANNEL_MAX - CHANNEL_MIN) as f32)
                .clamp(0.0, 1.0),
            arm,
            mode,
            kill,
        }
    }
}

#[cfg(test)]
mod tests;
