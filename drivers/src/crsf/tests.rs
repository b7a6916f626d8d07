use super::*;

/// CRC-8/DVB-S2 (polynomial 0xD5, initial 0, no reflection), bit by bit from its definition: independent of
/// the crate's table.
fn crc8_dvb_s2(data: &[u8]) -> u8 {
    let mut crc = 0u8;
    for &b in data {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0xD5 } else { crc << 1 };
        }
    }
    crc
}

/// A frame to the flight controller (address 0xC8) of `kind` with `payload`, as the CRSF specification lays
/// it out.
fn frame(kind: u8, payload: &[u8]) -> std::vec::Vec<u8> {
    let mut f = vec![0xC8, payload.len() as u8 + 2, kind];
    f.extend_from_slice(payload);
    let crc = crc8_dvb_s2(&f[2..]);
    f.push(crc);
    f
}

/// 16 channels of 11 bits, least significant bit first (the specification's packing).
fn pack(ch: &[u16; 16]) -> [u8; 22] {
    let mut out = [0u8; 22];
    for (i, &v) in ch.iter().enumerate() {
        for b in 0..11 {
            if v >> b & 1 == 1 {
                let bit = i * 11 + b;
                out[bit / 8] |= 1 << (bit % 8);
            }
        }
    }
    out
}

fn rc_frame(ch: &[u16; 16]) -> std::vec::Vec<u8> {
    frame(0x16, &pack(ch))
}

fn link_frame(lq: u8) -> std::vec::Vec<u8> {
    // RSSI 1 and 2, link quality, SNR, antenna, RF mode, TX power, downlink RSSI, quality, SNR.
    frame(0x14, &[60, 62, lq, 8, 0, 5, 3, 55, 100, 9])
}

fn feed(rx: &mut CrsfReceiver, bytes: &[u8], t_us: u64) {
    for &b in bytes {
        rx.push(b, t_us);
    }
}

fn sample_channels() -> [u16; 16] {
    let mut ch = [CHANNEL_MID; 16];
    ch[0] = CHANNEL_MIN;
    ch[1] = CHANNEL_MAX;
    ch[2] = 300;
    ch[3] = 1500;
    ch[4] = CHANNEL_MAX;
    ch[7] = 0;
    ch[15] = 2047;
    ch
}

#[test]
fn the_crc_is_crc8_dvb_s2_with_its_published_check_value() {
    // The catalogue's check value of CRC-8/DVB-S2 over "123456789".
    assert_eq!(crc8_dvb_s2(b"123456789"), 0xBC);
    // And the crate agrees on a frame: a frame built with the reference CRC parses, one with another fails.
    let mut rx = CrsfReceiver::new();
    let mut f = rc_frame(&sample_channels());
    feed(&mut rx, &f, 0);
    assert_eq!(rx.counters().rc_frames, 1);
    let n = f.len();
    f[n - 1] ^= 1;
    feed(&mut rx, &f, 0);
    assert_eq!((rx.counters().rc_frames, rx.counters().bad_crc), (1, 1));
}

#[test]
fn channels_unpack_to_the_values_sent_and_microseconds_follow_the_receivers_scaling() {
    let ch = sample_channels();
    let mut rx = CrsfReceiver::new();
    assert_eq!(rx.rc(0), RcState::NoReceiver);
    feed(&mut rx, &rc_frame(&ch), 1000);
    assert_eq!(rx.rc(1000), RcState::Ok(ch));
    assert_eq!(
        (channel_us(CHANNEL_MIN), channel_us(CHANNEL_MID), channel_us(CHANNEL_MAX)),
        (988, 1500, 2011)
    );
    assert_eq!(rx.counters().frames, 1);
}

#[test]
fn a_stream_with_noise_and_a_damaged_frame_loses_only_that_frame() {
    let mut ch = sample_channels();
    let mut stream = vec![0x00, 0x13, 0x37];
    let mut want = std::vec::Vec::new();
    for k in 0..20u16 {
        ch[8] = 200 + k * 50;
        let mut f = rc_frame(&ch);
        if k == 7 {
            f[10] ^= 0x20; // a flipped bit in the payload: the CRC fails
        } else {
            want.push(ch[8]);
        }
        stream.extend_from_slice(&f);
        if k == 12 {
            stream.extend_from_slice(&link_frame(100));
        }
        if k == 15 {
            stream.extend_from_slice(&[0xC8, 0xFF]); // a start byte and an impossible length
        }
    }
    // Fed byte by byte without pauses (the worst case: no gap to resynchronise on). The noise's 0x00 and 0x13
    // are addresses of the protocol: false starts, whose frames fail and whose bytes are looked at again.
    let mut rx = CrsfReceiver::new();
    for &b in &stream {
        rx.push(b, 0);
    }
    let c = rx.counters();
    assert_eq!(c.rc_frames as usize, want.len(), "every intact frame: {c:?}");
    assert_eq!(rx.rc(0), RcState::Ok(ch));
    assert_eq!(c.link_statistics, 1, "{c:?}");
    assert!(c.bad_crc >= 1 && c.bad_length >= 1, "{c:?}");
    assert_eq!(c.bytes as usize, stream.len());
    assert!(c.skipped >= 2, "{c:?}");
    assert_eq!(rx.link().map(|l| l.uplink_link_quality), Some(100));
}

#[test]
fn the_rc_link_is_lost_when_frames_stop_or_the_receiver_reports_no_uplink() {
    let ch = sample_channels();
    let mut rx = CrsfReceiver::new();
    feed(&mut rx, &rc_frame(&ch), 1_000_000);
    assert_eq!(rx.rc(1_000_000 + RC_LOST_AFTER_US), RcState::Ok(ch));
    assert_eq!(rx.rc(1_000_000 + RC_LOST_AFTER_US + 1), RcState::Lost);
    // Frames again: back.
    feed(&mut rx, &rc_frame(&ch), 2_000_000);
    assert_eq!(rx.rc(2_000_000), RcState::Ok(ch));
    // A receiver that keeps sending channels but reports a link quality of 0 (a TBS failsafe): lost.
    feed(&mut rx, &link_frame(0), 2_001_000);
    feed(&mut rx, &rc_frame(&ch), 2_002_000);
    assert_eq!(rx.rc(2_002_000), RcState::Lost);
    feed(&mut rx, &link_frame(80), 2_003_000);
    assert_eq!(rx.rc(2_003_000), RcState::Ok(ch));
}

fn us_to_channel(us: i32) -> u16 {
    (CHANNEL_MID as i32 + (us - 1500) * 8 / 5) as u16
}

#[test]
fn switches_have_hysteresis_and_sticks_their_ranges() {
    use SwitchPosition::*;
    assert_eq!(SwitchPosition::of(us_to_channel(1000), None), Low);
    assert_eq!(SwitchPosition::of(us_to_channel(1500), None), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(2000), None), High);
    // Just past a threshold: the last position holds within the hysteresis.
    assert_eq!(SwitchPosition::of(us_to_channel(1320), Some(Low)), Low);
    assert_eq!(SwitchPosition::of(us_to_channel(1360), Some(Low)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1680), Some(High)), High);
    assert_eq!(SwitchPosition::of(us_to_channel(1640), Some(High)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1270), Some(Mid)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1230), Some(Mid)), Low);
    assert_eq!(SwitchPosition::of(us_to_channel(1730), Some(Mid)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1770), Some(Mid)), High);

    let map = ChannelMap::default();
    assert!(map.is_valid());
    assert!(!ChannelMap { kill: 4, ..map }.is_valid(), "arm and kill on one channel");
    assert!(!ChannelMap { kill: 16, ..map }.is_valid());
    let mut dec = RcDecoder::default();
    let mut ch = [CHANNEL_MID; 16];
    ch[2] = CHANNEL_MIN;
    ch[0] = CHANNEL_MAX;
    ch[6] = CHANNEL_MAX;
    let i = dec.decode(&ch, &map);
    assert_eq!((i.roll, i.pitch, i.yaw, i.throttle), (1.0, 0.0, 0.0, 0.0));
    assert_eq!((i.arm, i.mode, i.kill), (Mid, Mid, High));
    ch[2] = CHANNEL_MAX;
    ch[1] = CHANNEL_MIN;
    let i = dec.decode(&ch, &map);
    assert_eq!((i.pitch, i.throttle), (-1.0, 1.0));
}

/// A small deterministic generator for the fuzzing below.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

#[test]
fn ten_million_random_and_mutated_bytes_never_panic_and_every_byte_is_counted() {
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    let mut rx = CrsfReceiver::new();
    let valid = rc_frame(&sample_channels());
    let mut n = 0u64;
    while n < 10_000_000 {
        match rng.next() % 4 {
            // Pure noise.
            0 => {
                for _ in 0..64 {
                    rx.push(rng.next() as u8, n);
                    n += 1;
                }
            }
            // A valid frame with one to three bytes changed.
            1 => {
                let mut f = valid.clone();
                for _ in 0..1 + rng.next() % 3 {
                    let i = (rng.next() % f.len() as u64) as usize;
                    f[i] = rng.next() as u8;
                }
                for &b in &f {
                    rx.push(b, n);
                    n += 1;
                }
            }
            // A frame start, a random length and type, random payload: any type the crate knows.
            2 => {
                // The length byte counts the type, the payload and the CRC; out of range sometimes.
                let len = (rng.next() % 70) as u8;
                let mut f = vec![0xC8, len, rng.next() as u8];
                f.extend((0..len.saturating_sub(2)).map(|_| rng.next() as u8));
                let crc = crc8_dvb_s2(&f[2..]);
                f.push(crc);
                for &b in &f {
                    rx.push(b, n);
                    n += 1;
                }
            }
            // A valid frame cut short.
            _ => {
                let cut = (rng.next() % valid.len() as u64) as usize;
                for &b in &valid[..cut] {
                    rx.push(b, n);
                    n += 1;
                }
            }
        }
    }
    let c = rx.counters();
    eprintln!("{n} bytes: {c:?}");
    assert_eq!(c.bytes as u64, n);
    // The receiver still reads a clean frame after all that.
    feed(&mut rx, &[0; 70], n);
    feed(&mut rx, &valid, n);
    assert_eq!(rx.rc(n), RcState::Ok(sample_channels()));
    assert!(c.frames > 10_000 && c.bad_crc > 10_000 && c.skipped > 100_000, "{c:?}");
}

#[test]
fn a_pause_on_the_line_ends_a_cut_frame_and_frames_of_other_kinds_are_counted_apart() {
    let ch = sample_channels();
    let f = rc_frame(&ch);
    let mut rx = CrsfReceiver::new();
    // Half a frame, a pause, then a whole frame: found at once, the half counted as skipped.
    feed(&mut rx, &f[..10], 1_000);
    feed(&mut rx, &f, 1_000 + FRAME_GAP_US);
    let c = rx.counters();
    assert_eq!((c.rc_frames, c.skipped, c.bad_crc, c.bad_length), (1, 10, 0, 0), "{c:?}");
    // Without the pause the half frame takes the whole one's first bytes as its own.
    let mut rx = CrsfReceiver::new();
    feed(&mut rx, &f[..10], 1_000);
    feed(&mut rx, &f, 1_000 + FRAME_GAP_US - 1);
    assert!(rx.counters().bad_crc + rx.counters().bad_length >= 1, "{:?}", rx.counters());
    // A battery frame (a kind the crate decodes), a frame of a kind it does not know, and an RC frame with a
    // payload too short for its kind: frames with a good CRC, counted by kind.
    let mut rx = CrsfReceiver::new();
    feed(&mut rx, &frame(0x08, &[0, 120, 0, 15, 0, 0, 40, 80]), 0);
    feed(&mut rx, &frame(0x7F, &[1, 2, 3]), 0);
    feed(&mut rx, &frame(0x16, &[1, 2, 3, 4, 5]), 0);
    let c = rx.counters();
    assert_eq!((c.frames, c.other_frames, c.bad_payload, c.rc_frames), (3, 2, 1, 0), "{c:?}");
    assert_eq!(rx.rc(0), RcState::NoReceiver);
}

#[test]
fn switch_thresholds_and_stick_scaling_at_exact_values() {
    use SwitchPosition::*;
    // Exactly at a threshold: the middle position (the ends start strictly beyond).
    assert_eq!(channel_us(us_to_channel(1300)), 1300);
    assert_eq!(SwitchPosition::of(us_to_channel(1300), None), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1700), None), Mid);
    // Exactly at the hysteresis' edge: the end position is left.
    assert_eq!(SwitchPosition::of(us_to_channel(1350), Some(Low)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1650), Some(High)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1250), Some(Mid)), Mid);
    assert_eq!(SwitchPosition::of(us_to_channel(1750), Some(Mid)), Mid);
    // Sticks in between their ends.
    let map = ChannelMap::default();
    let mut ch = [CHANNEL_MID; 16];
    ch[0] = CHANNEL_MID + 273; // a third of the way to full right
    ch[3] = CHANNEL_MID - 546; // two thirds to full left
    ch[2] = 1000;
    let i = RcDecoder::default().decode(&ch, &map);
    assert!((i.roll - 1.0 / 3.0).abs() < 1e-6, "{}", i.roll);
    assert!((i.yaw + 2.0 / 3.0).abs() < 1e-6, "{}", i.yaw);
    assert!((i.throttle - 828.0 / 1639.0).abs() < 1e-6, "{}", i.throttle);
}
