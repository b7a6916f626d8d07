//! The live view's rate limit for a flight faster than real time (pure: the caller gives the wall clock).
//!
//! A simulated flight runs several times faster than real time. Sending every step's records to a viewer would
//! cost the simulation its speed (the copies, the encoding, the sockets) for messages no one can watch at that
//! pace, so the step-rate records go out at most `max_speedup` times as densely as a real-time flight sends
//! them; a flight at real time or slower sends every step.
use std::time::Instant;

/// Which steps of a faster-than-real-time flight go out.
#[derive(Clone, Debug)]
pub struct StepThinning {
    max_speedup: f64,
    last_sent: Option<Instant>,
    last_step_us: Option<u64>,
}

impl StepThinning {
    /// Steps at most `max_speedup` times as dense as in real time.
    pub fn new(max_speedup: f64) -> Self {
        Self { max_speedup, last_sent: None, last_step_us: None }
    }

    /// Whether the step at flight time `t_us`, reached at wall time `now`, goes out: when the wall time since
    /// the last step sent is at least the flight time since the previous step divided by the speed-up.
    pub fn due(&mut self, t_us: u64, now: Instant) -> bool {
        let step_s = self.last_step_us.map_or(0.0, |p| t_us.saturating_sub(p) as f64 * 1e-6);
        self.last_step_us = Some(t_us);
        match self.last_sent {
            Some(w) if now.duration_since(w).as_secs_f64() * self.max_speedup < step_s => false,
            _ => {
                self.last_sent = Some(now);
                true
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// Steps of 2 ms of flight at `speed` times real time, for 2 s of flight: the share sent.
    fn share_sent(speed: f64, max_speedup: f64) -> f64 {
        let mut th = StepThinning::new(max_speedup);
        let t0 = Instant::now();
        let n = 1000u64;
        let sent = (0..n)
            .filter(|&k| {
                let t_us = 2_000 * k;
                th.due(t_us, t0 + Duration::from_secs_f64(t_us as f64 * 1e-6 / speed))
            })
            .count();
        sent as f64 / n as f64
    }

    #[test]
    fn a_flight_at_real_time_sends_every_step() {
        assert_eq!(share_sent(1.0, 2.0), 1.0);
        assert_eq!(share_sent(0.5, 2.0), 1.0);
        assert_eq!(share_sent(1.9, 2.0), 1.0);
    }

    #[test]
    fn a_faster_flight_sends_at_most_the_speedup_over_its_speed() {
        // At 8x with a limit of 2x: one step in four (the density of a flight at 2x real time).
        let s = share_sent(8.0, 2.0);
        assert!((s - 0.25).abs() < 0.01, "{s}");
        let s = share_sent(20.0, 2.0);
        assert!((s - 0.1).abs() < 0.01, "{s}");
        // The first step always goes out.
        let mut th = StepThinning::new(2.0);
        assert!(th.due(0, Instant::now()));
    }
}
