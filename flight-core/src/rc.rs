//! The pilot's RC receiver as the flight code sees it: the CRSF driver (`drivers::crsf`: ExpressLRS, TBS
//! Crossfire) fed the UART's bytes, its channels decoded with the vehicle's channel map (`rc.channel_map`) into
//! a `control_core::pilot::PilotInput` each control step. The firmware feeds it the receiver UART's bytes; the
//! simulator the bytes of its simulated transmitter, so that both run the same decoding.
use control_core::pilot::{ModeSwitch, PilotInput, RcLink};
use drivers::crsf::{ChannelMap, CrsfCounters, CrsfReceiver, RcDecoder, RcInputs, RcState, SwitchPosition};

/// A CRSF receiver and the decoding of its channels.
#[derive(Debug)]
pub struct RcReceiver {
    crsf: CrsfReceiver,
    decoder: RcDecoder,
    map: ChannelMap,
    /// The last decoded input (kept while the link is lost: the flight code ignores it then).
    last: Option<RcInputs>,
}

/// The driver's channel map from the parameters' (`rc.channel_map`: roll, pitch, throttle, yaw, arm, mode,
/// kill).
pub fn channel_map(c: [u8; 7]) -> ChannelMap {
    ChannelMap { roll: c[0], pitch: c[1], throttle: c[2], yaw: c[3], arm: c[4], mode: c[5], kill: c[6] }
}

impl RcReceiver {
    /// A receiver that has heard nothing, decoding with `channel_map` (`rc.channel_map`).
    pub fn new(channel_map_param: [u8; 7]) -> Self {
        Self {
            crsf: CrsfReceiver::new(),
            decoder: RcDecoder::default(),
            map: channel_map(channel_map_param),
            last: None,
        }
    }

    /// Decodes with another channel map from now on (a new configuration).
    pub fn set_channel_map(&mut self, channel_map_param: [u8; 7]) {
        self.map = channel_map(channel_map_param);
    }

    /// One byte from the receiver's UART, received at `now_us`.
    pub fn push(&mut self, byte: u8, now_us: u64) {
        self.crsf.push(byte, now_us);
    }

    /// What the driver counted.
    pub fn counters(&self) -> CrsfCounters {
        self.crsf.counters()
    }

    /// The pilot's input at `now_us`: `None` until the receiver has been heard; the link lost after its
    /// timeout or its own failsafe report (`drivers::crsf::CrsfReceiver::rc`).
    pub fn pilot(&mut self, now_us: u64) -> Option<PilotInput> {
        let link = match self.crsf.rc(now_us) {
            RcState::NoReceiver => return None,
            RcState::Ok(ch) => {
                self.last = Some(self.decoder.decode(&ch, &self.map));
                RcLink::Ok
            }
            RcState::Lost => RcLink::Lost,
        };
        let i = self.last?;
        Some(PilotInput {
            link,
            roll: i.roll,
            pitch: i.pitch,
            yaw: i.yaw,
            throttle: i.throttle,
            arm: i.arm == SwitchPosition::High,
            mode: match i.mode {
                SwitchPosition::Low => ModeSwitch::Manual,
                SwitchPosition::Mid => ModeSwitch::Auto,
                SwitchPosition::High => ModeSwitch::Land,
            },
            kill: i.kill == SwitchPosition::High,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivers::crsf::{CHANNEL_MAX, CHANNEL_MID, CHANNEL_MIN};
    use uf_crsf::packets::{PacketAddress, RcChannelsPacked, write_packet_to_buffer};

    fn frame(ch: [u16; 16]) -> std::vec::Vec<u8> {
        let mut buf = [0u8; 64];
        let n =
            write_packet_to_buffer(&mut buf, PacketAddress::FlightController, &RcChannelsPacked(ch)).unwrap();
        buf[..n].to_vec()
    }

    #[test]
    fn channels_become_the_pilots_input_through_the_channel_map() {
        // A map that is not the default: throttle on channel 1, roll on 3, the kill switch on 10.
        let map = [2, 1, 0, 3, 4, 5, 9];
        let mut rx = RcReceiver::new(map);
        assert_eq!(rx.pilot(0), None, "nothing heard");
        let mut ch = [CHANNEL_MID; 16];
        ch[0] = CHANNEL_MAX; // throttle up
        ch[2] = CHANNEL_MIN; // roll full left
        ch[4] = CHANNEL_MAX; // arm high
        ch[5] = CHANNEL_MIN; // mode low: manual
        ch[9] = CHANNEL_MAX; // kill high
        for b in frame(ch) {
            rx.push(b, 1000);
        }
        let p = rx.pilot(2000).unwrap();
        assert_eq!(p.link, RcLink::Ok);
        assert_eq!((p.throttle, p.roll, p.pitch, p.yaw), (1.0, -1.0, 0.0, 0.0));
        assert_eq!((p.arm, p.mode, p.kill), (true, ModeSwitch::Manual, true));
        // Mid and high positions of the mode switch.
        ch[5] = CHANNEL_MID;
        for b in frame(ch) {
            rx.push(b, 10_000);
        }
        assert_eq!(rx.pilot(10_000).unwrap().mode, ModeSwitch::Auto);
        ch[5] = CHANNEL_MAX;
        for b in frame(ch) {
            rx.push(b, 20_000);
        }
        assert_eq!(rx.pilot(20_000).unwrap().mode, ModeSwitch::Land);
        // No frame for longer than the receiver's timeout: lost, with the last values kept.
        let p = rx.pilot(20_000 + drivers::crsf::RC_LOST_AFTER_US + 1).unwrap();
        assert_eq!((p.link, p.mode), (RcLink::Lost, ModeSwitch::Land));
        // Another map decodes the same frame differently.
        rx.set_channel_map([0, 1, 2, 3, 4, 5, 6]);
        for b in frame(ch) {
            rx.push(b, 400_000);
        }
        let p = rx.pilot(400_000).unwrap();
        assert_eq!((p.roll, p.throttle, p.kill), (1.0, 0.0, false));
        assert!(rx.counters().rc_frames == 4);
    }
}
