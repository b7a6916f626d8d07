//! DShot motor output for the ESCs of off-the-shelf flight-controller boards: the frames, the timer's
//! duty-cycle buffer that a DMA burst writes to four timer channels, the rotor-speed-to-throttle mapping and
//! the arming sequence. The frame itself (11-bit value, telemetry bit, 4-bit checksum; commands below 48)
//! comes from the `dshot-frame` crate; what is here is what a flight stack adds around it.
//!
//! On the wire a frame is 16 bits, most significant first, each bit one period of the bit clock
//! (DShot600: 600 kbit/s, 1.667 us); a 1 is high for 75 % of the period, a 0 for 37.5 % (the timings of the
//! DShot description by the protocol's authors, also those of Betaflight's and PX4's outputs). A final slot
//! of duty 0 leaves the line low between frames. Bidirectional DShot (eRPM telemetry from the ESC on the
//! same wire) inverts the line and the checksum; the checksum is [`BidirectionalFrame`]'s, the inversion
//! is the timer channel's output polarity.
//!
//! Value 0 is "motor stop"; 1-47 are commands (beeps, settings, direction) that the flight code does not send
//! in flight; 48-2047 are throttle from zero to full. An ESC arms only after it has received motor-stop
//! frames for a while after power-up, so [`DshotOutput`] sends nothing else until that time has passed,
//! whatever the flight code asks.
pub use dshot_frame::{BidirectionalFrame, Command, NormalFrame};

/// Bits per frame.
pub const FRAME_BITS: usize = 16;
/// Timer slots per frame: the 16 bits and a final low slot.
pub const SLOTS: usize = FRAME_BITS + 1;
/// The largest throttle step (the frame's value less the 48 commands).
pub const MAX_THROTTLE: u16 = 1999;

/// The bit rate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Speed {
    /// 150 kbit/s.
    Dshot150,
    /// 300 kbit/s.
    Dshot300,
    /// 600 kbit/s (the usual choice on an STM32F4 at 1-8 kHz loop rates).
    Dshot600,
}

impl Speed {
    /// Bits per second.
    pub const fn bit_rate_hz(self) -> u32 {
        match self {
            Speed::Dshot150 => 150_000,
            Speed::Dshot300 => 300_000,
            Speed::Dshot600 => 600_000,
        }
    }

    /// The timer's period in ticks of `timer_clock_hz` for one bit (its auto-reload value plus one), or
    /// `None` when the clock gives fewer than 8 ticks (too few to tell 37.5 % from 75 %). Any `u32` clock
    /// fits a 16-bit timer (at most 28,633 ticks at DShot150).
    pub const fn period_ticks(self, timer_clock_hz: u32) -> Option<u16> {
        let rate = self.bit_rate_hz() as u64;
        let ticks = (timer_clock_hz as u64 + rate / 2) / rate;
        if ticks < 8 { None } else { Some(ticks as u16) }
    }
}

/// The duty (compare value) of a 1 bit: 75 % of the period.
pub const fn duty_one(period_ticks: u16) -> u16 {
    ((period_ticks as u32 * 3 + 2) / 4) as u16
}

/// The duty of a 0 bit: 37.5 % of the period.
pub const fn duty_zero(period_ticks: u16) -> u16 {
    ((period_ticks as u32 * 3 + 4) / 8) as u16
}

/// The throttle step (0 to [`MAX_THROTTLE`]) for a rotor speed, assuming the ESC's speed is proportional to
/// throttle up to `max_rad_s` at full throttle (calibrate per airframe, as for the BL-Ctrl), or `None` for
/// "stop": zero or below, NaN, or no valid `max_rad_s`.
pub fn throttle_for_speed(speed_rad_s: f32, max_rad_s: f32) -> Option<u16> {
    if !(speed_rad_s > 0.0) || !(max_rad_s > 0.0) {
        return None;
    }
    let t = speed_rad_s / max_rad_s * MAX_THROTTLE as f32 + 0.5;
    Some(if t >= MAX_THROTTLE as f32 { MAX_THROTTLE } else { t as u16 })
}

/// Four motors on one timer, M1 first.
#[derive(Clone, Debug)]
pub struct DshotOutput {
    period_ticks: u16,
    bidirectional: bool,
    max_rad_s: f32,
    stop_frames_left: u32,
}

impl DshotOutput {
    /// Four motors at `speed` on a timer clocked at `timer_clock_hz`, refreshed every `frame_period_us`;
    /// the ESCs get motor-stop frames for `arm_ms` first (300 ms suits BLHeli_32, Bluejay and AM32).
    /// `None` when the timer cannot produce the bit rate.
    pub fn new(
        speed: Speed,
        timer_clock_hz: u32,
        bidirectional: bool,
        max_rad_s: f32,
        frame_period_us: u32,
        arm_ms: u32,
    ) -> Option<Self> {
        let period_ticks = speed.period_ticks(timer_clock_hz)?;
        let stop_frames_left = (arm_ms * 1000).div_ceil(frame_period_us.max(1));
        Some(Self { period_ticks, bidirectional, max_rad_s, stop_frames_left })
    }

    /// The timer's auto-reload value (the period less one).
    pub fn auto_reload(&self) -> u16 {
        self.period_ticks - 1
    }

    /// The rotor speed of full throttle from now on (rad/s; a new configuration's `motor_speed_max_rad_s`).
    pub fn set_max_rad_s(&mut self, max_rad_s: f32) {
        self.max_rad_s = max_rad_s;
    }

    /// Whether the arming time has passed (the frames follow the commands).
    pub fn armed_escs(&self) -> bool {
        self.stop_frames_left == 0
    }

    /// The four frames for rotor speeds `speeds_rad_s`: motor stop while `motors_enabled` is false, during
    /// the arming time and for a speed of zero (or NaN); throttle otherwise.
    pub fn frames(&mut self, speeds_rad_s: [f32; 4], motors_enabled: bool) -> [u16; 4] {
        let arming = self.stop_frames_left > 0;
        self.stop_frames_left = self.stop_frames_left.saturating_sub(1);
        speeds_rad_s.map(|s| {
            let throttle =
                if arming || !motors_enabled { None } else { throttle_for_speed(s, self.max_rad_s) };
            self.frame(throttle)
        })
    }

    fn frame(&self, throttle: Option<u16>) -> u16 {
        match (throttle, self.bidirectional) {
            (Some(t), false) => NormalFrame::new(t, false).map_or(0, |f| f.inner()),
            (Some(t), true) => BidirectionalFrame::new(t, false)
                .map_or(BidirectionalFrame::command(Command::MotorStop, false).inner(), |f| f.inner()),
            (None, false) => NormalFrame::command(Command::MotorStop, false).inner(),
            (None, true) => BidirectionalFrame::command(Command::MotorStop, false).inner(),
        }
    }

    /// The DMA burst buffer for four channels: slot `k` of motor `m` at `k * 4 + m` (the order a burst
    /// transfer to CCR1..CCR4 through the timer's DMA address register writes them), the last slot low.
    pub fn burst(&self, frames: [u16; 4], buf: &mut [u16; SLOTS * 4]) {
        let (one, zero) = (duty_one(self.period_ticks), duty_zero(self.period_ticks));
        for (m, frame) in frames.iter().enumerate() {
            for k in 0..FRAME_BITS {
                let bit = frame >> (FRAME_BITS - 1 - k) & 1;
                buf[k * 4 + m] = if bit == 1 { one } else { zero };
            }
            buf[FRAME_BITS * 4 + m] = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_match_the_published_bit_patterns() {
        // The worked example of the DShot description: value 1046 (throttle 998), no telemetry request:
        // 10000010110 0 0110 (checksum 0110 = 0x6).
        assert_eq!(NormalFrame::new(1046 - 48, false).unwrap().inner(), 0b1000_0010_1100_0110);
        // With the telemetry bit the checksum covers it: 10000010110 1 0111.
        assert_eq!(NormalFrame::new(1046 - 48, true).unwrap().inner(), 0b1000_0010_1101_0111);
        // Bidirectional DShot inverts the checksum.
        assert_eq!(BidirectionalFrame::new(1046 - 48, false).unwrap().inner(), 0b1000_0010_1100_1001);
        // Motor stop is all zeros (inverted checksum 1111 when bidirectional); full throttle 2047.
        assert_eq!(NormalFrame::command(Command::MotorStop, false).inner(), 0);
        assert_eq!(BidirectionalFrame::command(Command::MotorStop, false).inner(), 0x000F);
        let full = NormalFrame::new(MAX_THROTTLE, false).unwrap().inner();
        assert_eq!(full >> 5, 2047);
        let v = full >> 4;
        assert_eq!(full & 0xF, (v ^ (v >> 4) ^ (v >> 8)) & 0xF);
    }

    #[test]
    fn bit_timing_for_dshot600_on_a_168_mhz_timer() {
        // STM32F405: timers on APB2 run at 168 MHz: 280 ticks per bit (1.667 us).
        let p = Speed::Dshot600.period_ticks(168_000_000).unwrap();
        assert_eq!(p, 280);
        assert_eq!((duty_one(p), duty_zero(p)), (210, 105));
        // APB1 timers at 84 MHz: 140 ticks.
        assert_eq!(Speed::Dshot600.period_ticks(84_000_000), Some(140));
        assert_eq!(Speed::Dshot150.period_ticks(84_000_000), Some(560));
        // Too slow a clock to tell 37.5 % from 75 %; too fast for a 16-bit timer.
        assert_eq!(Speed::Dshot600.period_ticks(3_000_000), None);
        assert_eq!(Speed::Dshot600.period_ticks(4_499_999), None, "8 ticks is the least");
        assert_eq!(Speed::Dshot600.period_ticks(4_500_000), Some(8));
        // The fastest u32 clock still fits a 16-bit timer at the slowest rate.
        assert_eq!(Speed::Dshot150.period_ticks(u32::MAX), Some(28_633));
    }

    #[test]
    fn the_burst_interleaves_the_motors_most_significant_bit_first() {
        let out = DshotOutput::new(Speed::Dshot600, 168_000_000, false, 1000.0, 1000, 0).unwrap();
        assert_eq!(out.auto_reload(), 279);
        let frames = [0b1000_0010_1100_0110, 0xFFFF, 0x0000, 0x0001];
        let mut buf = [7u16; SLOTS * 4];
        out.burst(frames, &mut buf);
        let bits = |m: usize| (0..FRAME_BITS).fold(0u16, |acc, k| acc << 1 | (buf[k * 4 + m] == 210) as u16);
        for (m, f) in frames.iter().enumerate() {
            assert_eq!(bits(m), *f, "motor {m}");
            assert!((0..FRAME_BITS).all(|k| buf[k * 4 + m] == 210 || buf[k * 4 + m] == 105));
            assert_eq!(buf[FRAME_BITS * 4 + m], 0, "the line ends low");
        }
    }

    #[test]
    fn throttle_is_proportional_to_speed_and_stops_on_zero_or_nan() {
        assert_eq!(throttle_for_speed(500.0, 1000.0), Some(1000));
        assert_eq!(throttle_for_speed(1000.0, 1000.0), Some(MAX_THROTTLE));
        assert_eq!(throttle_for_speed(5000.0, 1000.0), Some(MAX_THROTTLE));
        assert_eq!(throttle_for_speed(0.2, 1000.0), Some(0), "the lowest spinning step, not stop");
        for stop in [0.0, -3.0, f32::NAN] {
            assert_eq!(throttle_for_speed(stop, 1000.0), None);
        }
        assert_eq!(throttle_for_speed(100.0, 0.0), None);
        assert_eq!(throttle_for_speed(100.0, f32::NAN), None);
    }

    #[test]
    fn the_escs_get_motor_stop_for_the_arming_time_whatever_is_asked() {
        // 300 ms at 1 kHz frames: 300 stop frames, then the commands.
        let mut out = DshotOutput::new(Speed::Dshot600, 168_000_000, false, 1000.0, 1000, 300).unwrap();
        let spin = [500.0; 4];
        for k in 0..300 {
            assert!(!out.armed_escs(), "{k}");
            assert_eq!(out.frames(spin, true), [0; 4], "frame {k}");
        }
        assert!(out.armed_escs());
        let f = out.frames(spin, true);
        assert_eq!(f, [NormalFrame::new(1000, false).unwrap().inner(); 4]);
        // Disabled motors, or a stop request, give motor stop.
        assert_eq!(out.frames(spin, false), [0; 4]);
        // Another top speed: the same rotor speed is half the throttle.
        out.set_max_rad_s(2000.0);
        assert_eq!(out.frames(spin, true), [NormalFrame::new(500, false).unwrap().inner(); 4]);
        out.set_max_rad_s(1000.0);
        assert_eq!(out.frames([0.0, 500.0, f32::NAN, 500.0], true)[0], 0);
        assert_eq!(out.frames([0.0, 500.0, f32::NAN, 500.0], true)[2], 0);
        // Bidirectional: the inverted checksum in every frame, stop included.
        let mut bi = DshotOutput::new(Speed::Dshot600, 168_000_000, true, 1000.0, 1000, 0).unwrap();
        assert_eq!(
            bi.frames([0.0, 500.0, 0.0, 0.0], true)[..2],
            [0x000F, BidirectionalFrame::new(1000, false).unwrap().inner()]
        );
        // No timer that can make the bit rate: no output.
        assert!(DshotOutput::new(Speed::Dshot600, 1_000_000, false, 1000.0, 1000, 300).is_none());
    }
}
