//! The vehicle's clock, seen from the station.
//!
//! The station sends `Uplink::TimeSync { station_time_us: t1 }`; the vehicle answers with its own clock `v`
//! from the control step that read the request, and the answer arrives at the station's `t4`. Causality alone
//! says that the vehicle read `v` at some station time in `[t1, t4]`: the pair pins the offset
//! `vehicle - station` to within half the round trip, around `v - (t1 + t4) / 2` (exact when the two
//! directions take as long; NTP and MAVLink's TIMESYNC use the same midpoint).
//!
//! Each exchange bounds the offset from both sides: the vehicle read `v` no earlier than `t1`, so the offset is
//! at most `v - t1`, and no later than `t4`, so it is at least `v - t4`. [`ClockSync`] keeps the exchanges of
//! the last `window` and intersects those intervals within each `bin` (1 s: the drift moves the offset by
//! 0.1 ms in that time at 100 ppm): the tightest lower bound comes from the exchange whose answer came back
//! quickest, the tightest upper bound from the one whose request went quickest, so the intersection is set by
//! each direction's *smallest* delay, whatever the jitter (a refinement of NTP's minimum-round-trip filter,
//! which takes one exchange for both). A straight line through the bins' midpoints (least squares) gives the
//! offset and the drift (crystals differ by tens of ppm: 100 ppm is 6 ms a minute), each bin weighed by the
//! inverse square of its interval's half-width (the newest bin, still filling, is wide).
//! [`ClockSync::bound_us`] is what the mapping can be trusted to: half the shortest round trip (the
//! asymmetry of the smallest delays, which nobody can observe) plus the larger of the largest distance of
//! the bins' midpoints from the line and the largest distance by which the line leaves an exchange's causal
//! interval (a drift not found yet, a clock that jumped). The intervals are intersected after removing the
//! drift found so far, so a system clock being slewed (0.5 % seen on a VM) is followed too.
use std::collections::VecDeque;

/// One exchange: the station's midpoint, the offset it implies and the round trip (all us).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Pair {
    mid_us: u64,
    offset_us: f64,
    rtt_us: u64,
}

/// The fitted mapping: `vehicle = station + offset_us + drift * (station - t_ref_us)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClockFit {
    /// The station time the offset refers to (us).
    pub t_ref_us: u64,
    /// Vehicle less station clock at `t_ref_us` (us).
    pub offset_us: f64,
    /// How much faster the vehicle's clock runs (us per us; 1e-4 is 100 ppm).
    pub drift: f64,
    /// The error bound of the mapping (us), see [`ClockSync::bound_us`].
    pub bound_us: f64,
    /// Bins of exchanges the fit used.
    pub pairs: usize,
}

/// Why an exchange was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refused {
    /// The answer arrived before the request left (`t4 < t1`): not an answer to that request.
    Acausal,
    /// The round trip exceeds the limit (a late answer to an old request, or a link that queues).
    TooSlow,
}

/// Counters of the exchanges seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClockCounters {
    /// Exchanges kept.
    pub used: u64,
    /// Answers arriving before their request left.
    pub acausal: u64,
    /// Answers slower than the round-trip limit.
    pub too_slow: u64,
}

/// The station's estimate of the vehicle's clock.
#[derive(Clone, Debug)]
pub struct ClockSync {
    answer_latency_us: f64,
    window_us: u64,
    bin_us: u64,
    max_rtt_us: u64,
    pairs: VecDeque<Pair>,
    fit: Option<ClockFit>,
    counters: ClockCounters,
}

impl Default for ClockSync {
    /// A 20 s window of 1 s bins, round trips up to 1 s.
    fn default() -> Self {
        Self::new(20_000_000, 1_000_000, 1_000_000)
    }
}

impl ClockSync {
    /// Keeps the exchanges of the last `window_us`, intersects them per `bin_us`, refuses round trips over
    /// `max_rtt_us`.
    pub fn new(window_us: u64, bin_us: u64, max_rtt_us: u64) -> Self {
        Self {
            answer_latency_us: 0.0,
            window_us: window_us.max(1),
            bin_us: bin_us.max(1),
            max_rtt_us,
            pairs: VecDeque::new(),
            fit: None,
            counters: ClockCounters::default(),
        }
    }

    /// A vehicle that reads requests at its control steps stamps its answer with the step after the request
    /// arrived: on average half a control period late (`period_us / 2`), a delay the request's direction
    /// seems to take and the answer's does not. Without this the offset reads that much too late on average
    /// (0.4 ms at 500 Hz steps with ten exchanges a second through 5 ms of jitter). The intervals' upper
    /// ends are moved down by it; the bound reported stays the causal one.
    pub fn with_answer_period(mut self, period_us: u64) -> Self {
        self.answer_latency_us = period_us as f64 * 0.5;
        self
    }

    /// One exchange: the request left at the station's `t1_us`, the vehicle answered with `vehicle_us`, the
    /// answer arrived at the station's `t4_us`.
    pub fn observe(&mut self, t1_us: u64, vehicle_us: u64, t4_us: u64) -> Result<(), Refused> {
        if t4_us < t1_us {
            self.counters.acausal += 1;
            return Err(Refused::Acausal);
        }
        let rtt_us = t4_us - t1_us;
        if rtt_us > self.max_rtt_us {
            self.counters.too_slow += 1;
            return Err(Refused::TooSlow);
        }
        let mid_us = t1_us + rtt_us / 2;
        let offset_us = vehicle_us as f64 - (t1_us as f64 + t4_us as f64) * 0.5;
        self.pairs.push_back(Pair { mid_us, offset_us, rtt_us });
        while self.pairs.front().is_some_and(|p| p.mid_us + self.window_us < mid_us) {
            self.pairs.pop_front();
        }
        self.counters.used += 1;
        self.fit = self.refit();
        Ok(())
    }

    /// Each bin's intersection of the exchanges' offset intervals: (mean station time, lower, upper), in time
    /// order. An empty intersection (a clock that jumped) keeps the bin's quickest exchange's interval. The
    /// intervals are intersected after removing a `drift` (us per us) over their times, and the
    /// intersection is put back at the bin's mean time: the offset moves within a bin by the drift times
    /// the bin's length (0.1 ms at 100 ppm, but 5 ms at the 5000 ppm of a system clock being slewed).
    fn bins(&self, drift: f64) -> Vec<(f64, f64, f64)> {
        let mut out: Vec<(u64, f64, f64, f64, u64, f64, f64)> = Vec::new();
        let t0 = self.pairs.front().map_or(0.0, |p| p.mid_us as f64);
        for p in &self.pairs {
            let bin = p.mid_us / self.bin_us;
            let half = p.rtt_us as f64 * 0.5;
            let trend = drift * (p.mid_us as f64 - t0);
            let offset = p.offset_us - trend;
            let (lo, hi) = (offset - half, (offset + half - self.answer_latency_us).max(offset - half));
            match out.last_mut() {
                Some(b) if b.0 == bin => {
                    b.1 = b.1.max(lo);
                    b.2 = b.2.min(hi);
                    b.3 += p.mid_us as f64;
                    b.4 += 1;
                    if p.rtt_us < (b.6 - b.5) as u64 {
                        (b.5, b.6) = (lo, hi);
                    }
                }
                _ => out.push((bin, lo, hi, p.mid_us as f64, 1, lo, hi)),
            }
        }
        out.into_iter()
            .map(|(_, lo, hi, sum, n, qlo, qhi)| {
                let t = sum / n as f64;
                let trend = drift * (t - t0);
                let (lo, hi) = if lo <= hi { (lo, hi) } else { (qlo, qhi) };
                (t, lo + trend, hi + trend)
            })
            .collect()
    }

    /// The fit, with the bins intersected under the last fit's drift, then once more under the drift found
    /// (a drift found from scratch converges in those two passes).
    fn refit(&self) -> Option<ClockFit> {
        let mut fit = self.fit_bins(self.fit.map_or(0.0, |f| f.drift))?;
        for _ in 0..3 {
            fit = self.fit_bins(fit.drift)?;
        }
        Some(fit)
    }

    fn fit_bins(&self, drift: f64) -> Option<ClockFit> {
        let bins = self.bins(drift);
        let &(t_last, _, _) = bins.last()?;
        let t_ref_us = t_last.round() as u64;
        // (time s, midpoint us, weight): a bin of few exchanges (the newest, filling) has a wide interval and a
        // midpoint that may sit anywhere in it; each bin weighs as the inverse square of its half-width.
        let pts: Vec<(f64, f64, f64)> = bins
            .iter()
            .map(|&(t, lo, hi)| {
                let half = ((hi - lo) * 0.5).max(1.0);
                ((t - t_ref_us as f64) * 1e-6, (lo + hi) * 0.5, 1.0 / (half * half))
            })
            .collect();
        let (offset_us, slope) = if pts.len() < 2 {
            (pts[0].1, 0.0)
        } else {
            let w: f64 = pts.iter().map(|p| p.2).sum();
            let mx = pts.iter().map(|p| p.2 * p.0).sum::<f64>() / w;
            let my = pts.iter().map(|p| p.2 * p.1).sum::<f64>() / w;
            let sxx: f64 = pts.iter().map(|p| p.2 * (p.0 - mx).powi(2)).sum();
            let sxy: f64 = pts.iter().map(|p| p.2 * (p.0 - mx) * (p.1 - my)).sum();
            let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
            (my - slope * mx, slope)
        };
        // The slope is in us per second: the drift in us per us. How far the line misses the bins' midpoints,
        // over the bins about as narrow as the narrowest (a bin of slow exchanges only, a scheduler stall of
        // the station or the vehicle, has a wide interval whose midpoint says little; its exchanges still
        // count below, through causality).
        let narrowest_bin = pts.iter().map(|p| p.2).fold(0.0, f64::max);
        let worst = pts
            .iter()
            .filter(|p| p.2 * 4.0 >= narrowest_bin)
            .map(|p| (p.1 - (offset_us + slope * p.0)).abs())
            .fold(0.0, f64::max);
        // Causality, exchange by exchange: the vehicle read `v` between the request's leaving and the
        // answer's arrival, so a mapping outside `[v - t4, v - t1]` at that time is wrong by at least the
        // distance. The bound takes the largest such distance over the window (a drift not yet found, a
        // clock that jumped) and half the narrowest causal interval (what no exchange can resolve).
        let line = |t_us: f64| offset_us + slope * (t_us - t_ref_us as f64) * 1e-6;
        let mut narrowest = f64::INFINITY;
        let mut violated = 0.0f64;
        for p in &self.pairs {
            let half = p.rtt_us as f64 * 0.5;
            narrowest = narrowest.min(p.rtt_us as f64);
            let miss = (line(p.mid_us as f64) - p.offset_us).abs() - half;
            violated = violated.max(miss);
        }
        Some(ClockFit {
            t_ref_us,
            offset_us,
            drift: slope * 1e-6,
            bound_us: narrowest * 0.5 + worst.max(violated),
            pairs: bins.len(),
        })
    }

    /// The current fit, once an exchange was used.
    pub fn fit(&self) -> Option<ClockFit> {
        self.fit
    }

    /// The vehicle's clock at the station's `station_us`.
    pub fn vehicle_time_us(&self, station_us: u64) -> Option<u64> {
        let f = self.fit?;
        let dt = station_us as f64 - f.t_ref_us as f64;
        let v = station_us as f64 + f.offset_us + f.drift * dt;
        (v.is_finite() && v >= 0.0).then(|| v.round() as u64)
    }

    /// The error bound of [`ClockSync::vehicle_time_us`] (us): half the shortest round trip, plus the larger
    /// of the bins' midpoints' largest distance from the fitted line and the line's largest distance outside
    /// an exchange's causal interval.
    pub fn bound_us(&self) -> Option<f64> {
        self.fit.map(|f| f.bound_us)
    }

    /// Exchanges used and refused.
    pub fn counters(&self) -> ClockCounters {
        self.counters
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift64*): uniform in [0, 1).
    struct Rng(u64);
    impl Rng {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The vehicle's clock at a station time: an offset of seconds and a drift (us).
    fn vehicle_clock(station_us: f64, offset_us: f64, drift: f64) -> f64 {
        station_us * (1.0 + drift) + offset_us
    }

    /// Exchanges about every 100 ms over `seconds`, each direction `base` plus up to `jitter` (us, uniform),
    /// the vehicle answering at its next 2 ms control step; returns the worst error of the mapping over the
    /// last 10 s (checked every 37 ms) and the bound reported.
    fn run(seconds: f64, offset_us: f64, drift: f64, base: f64, jitter: f64, seed: u64) -> (f64, f64) {
        let mut sync = ClockSync::default().with_answer_period(2_000);
        let mut rng = Rng(seed);
        let mut worst = 0.0f64;
        // The station has been up for a minute (a negative offset keeps the vehicle's clock positive).
        let mut t = 60.0e6;
        let end = t + seconds * 1e6;
        while t < end {
            let up = base + jitter * rng.uniform();
            let down = base + jitter * rng.uniform();
            let arrive_vehicle = vehicle_clock(t + up, offset_us, drift);
            // Read by the next control step (vehicle clock, 2 ms steps).
            let v = (arrive_vehicle / 2000.0).ceil() * 2000.0;
            let v_station = (v - offset_us) / (1.0 + drift);
            let t4 = v_station + down;
            sync.observe(t as u64, v as u64, t4 as u64).unwrap();
            // Requests every 100 ms as the station's scheduler manages (+-3 ms): their phase against the
            // vehicle's 2 ms steps wanders, as two free-running clocks' do.
            t += 100_000.0 + 6_000.0 * (rng.uniform() - 0.5);
            if t > end - 10e6 {
                let mut s = t - 100_000.0;
                while s < t {
                    let truth = vehicle_clock(s, offset_us, drift);
                    let got = sync.vehicle_time_us(s as u64).unwrap() as f64;
                    worst = worst.max((got - truth).abs());
                    s += 37_000.0;
                }
            }
        }
        (worst, sync.bound_us().unwrap())
    }

    #[test]
    fn a_second_of_slow_exchanges_does_not_inflate_the_bound() {
        // Loopback: 100 us each way, exchanges every 100 ms; seconds 5 and 9 see every exchange delayed by a
        // stall of 30-70 ms (the station's or the vehicle's scheduler). The mapping stays right, and so does
        // its bound: the slow exchanges' midpoints say nothing (measured: the bound grew to 37 ms before).
        let mut sync = ClockSync::default().with_answer_period(2_000);
        let mut rng = Rng(7);
        let offset = 1.5e6;
        let mut t = 60.0e6;
        for k in 0..150 {
            let stall = if (50..60).contains(&k) || (90..100).contains(&k) {
                30_000.0 + 40_000.0 * rng.uniform()
            } else {
                0.0
            };
            let up = 100.0 + stall;
            let v = ((t + up + offset) / 2000.0).ceil() * 2000.0;
            let t4 = v - offset + 100.0;
            sync.observe(t as u64, v as u64, t4 as u64).unwrap();
            t += 100_000.0;
        }
        let truth = t + offset;
        let got = sync.vehicle_time_us(t as u64).unwrap() as f64;
        let bound = sync.bound_us().unwrap();
        assert!((got - truth).abs() <= bound, "error {} us, bound {bound} us", got - truth);
        assert!(bound < 3_000.0, "bound {bound} us");
    }

    #[test]
    fn within_a_millisecond_of_a_drifting_offset_clock_through_a_jittery_link() {
        // The case: an offset of seconds, 100 ppm of drift, 5 ms of jitter each way; several seeds
        // and both signs of drift and offset.
        for (seed, offset, drift) in
            [(1, 3.7e6, 100e-6), (2, -2.2e6, -100e-6), (3, 12.5e6, 100e-6), (4, 0.8e6, -60e-6)]
        {
            let (worst, bound) = run(60.0, offset, drift, 8_000.0, 5_000.0, seed);
            eprintln!("seed {seed}: worst {worst:.0} us, bound {bound:.0} us");
            assert!(worst <= 1_000.0, "seed {seed}: {worst:.0} us off");
            assert!(bound >= worst, "seed {seed}: bound {bound:.0} us under the error {worst:.0} us");
            assert!(bound < 12_000.0, "seed {seed}: bound {bound:.0} us");
        }
    }

    #[test]
    fn a_system_clock_slewed_half_a_percent_is_followed() {
        // A station whose system clock is being slewed (seen on a VM: 0.5 % for minutes) against the
        // vehicle's crystal: a drift of 5000 ppm from the start. Loopback timing (0.2 ms each way), ten
        // exchanges a second; the mapping checked 50 ms after each answer, from the third second on (the
        // first second has one bin: no drift can be found in it). Intersected without removing the drift,
        // the bins of a 5000 ppm clock held intervals 5 ms apart: the mapping was 4 ms off after 4 s with a
        // bound of 1 ms.
        for (seed, drift) in [(5u64, -5000e-6), (6, 5000e-6), (7, 100e-6)] {
            let mut sync = ClockSync::default().with_answer_period(2_000);
            let mut rng = Rng(seed);
            let (offset_us, mut t) = (1.5e6, 60.0e6);
            let mut worst_after_2s = 0.0f64;
            for k in 0..300 {
                let (up, down) = (200.0 + 100.0 * rng.uniform(), 200.0 + 100.0 * rng.uniform());
                let v = (vehicle_clock(t + up, offset_us, drift) / 2000.0).ceil() * 2000.0;
                let t4 = (v - offset_us) / (1.0 + drift) + down;
                sync.observe(t as u64, v as u64, t4 as u64).unwrap();
                let s = t4 + 50_000.0;
                let err = (sync.vehicle_time_us(s as u64).unwrap() as f64
                    - vehicle_clock(s, offset_us, drift))
                .abs();
                let bound = sync.bound_us().unwrap();
                if k >= 20 {
                    worst_after_2s = worst_after_2s.max(err);
                    assert!(
                        err <= bound.max(100.0),
                        "seed {seed}, exchange {k}: {err:.0} us off, bound {bound:.0} us"
                    );
                }
                t += 100_000.0;
            }
            let found = sync.fit().unwrap().drift;
            eprintln!(
                "drift {:.0} ppm: found {:.0} ppm, worst after 2 s {worst_after_2s:.0} us",
                drift * 1e6,
                found * 1e6
            );
            assert!(
                (found - drift).abs() < 200e-6,
                "drift {:.0} ppm found as {:.0}",
                drift * 1e6,
                found * 1e6
            );
            assert!(worst_after_2s <= 1_000.0, "{worst_after_2s:.0} us off");
        }
    }

    #[test]
    fn the_drift_matters_and_is_found() {
        // Without the drift term a 100 ppm clock is 2 ms off after 20 s; the fit finds the drift to a few ppm.
        let mut sync = ClockSync::default();
        let mut rng = Rng(9);
        let mut t = 0.0;
        while t < 40e6 {
            let up = 8_000.0 + 5_000.0 * rng.uniform();
            let down = 8_000.0 + 5_000.0 * rng.uniform();
            let v = vehicle_clock(t + up, 1e6, 100e-6);
            sync.observe(t as u64, v as u64, ((v - 1e6) / (1.0 + 100e-6) + down) as u64).unwrap();
            t += 100_000.0;
        }
        let f = sync.fit().unwrap();
        assert!((f.drift - 100e-6).abs() < 10e-6, "drift {:.1} ppm", f.drift * 1e6);
        assert!((20..=21).contains(&f.pairs), "one bin per second of the 20 s window: {}", f.pairs);
    }

    #[test]
    fn a_single_exchange_bounds_the_offset_by_half_its_round_trip() {
        let mut sync = ClockSync::default();
        assert_eq!(sync.vehicle_time_us(5), None);
        assert_eq!(sync.bound_us(), None);
        // Out at 1.000 s, the vehicle read 4.004 s, back at 1.010 s: the offset is 3.004 - 0.005 s +- 5 ms.
        sync.observe(1_000_000, 4_004_000, 1_010_000).unwrap();
        assert_eq!(sync.vehicle_time_us(1_005_000), Some(4_004_000));
        assert_eq!(sync.bound_us(), Some(5_000.0));
        assert_eq!(sync.vehicle_time_us(2_005_000), Some(5_004_000));
    }

    #[test]
    fn answers_before_their_request_or_too_slow_are_refused_and_counted() {
        let mut sync = ClockSync::new(20_000_000, 1_000_000, 500_000);
        assert_eq!(sync.observe(2_000_000, 9, 1_999_999), Err(Refused::Acausal));
        assert_eq!(sync.observe(2_000_000, 9, 2_600_000), Err(Refused::TooSlow));
        assert_eq!(sync.fit(), None);
        sync.observe(2_000_000, 9_000_000, 2_500_000).unwrap();
        assert_eq!(sync.counters(), ClockCounters { used: 1, acausal: 1, too_slow: 1 });
    }

    #[test]
    fn the_quickest_exchange_of_a_bin_is_trusted_and_old_ones_leave_the_window() {
        let mut sync = ClockSync::new(3_000_000, 1_000_000, 1_000_000);
        // Same bin, offset 1 s: a request that went in 90 ms and came back in 10 ms (its midpoint is 40 ms
        // off), then one that went in 1.5 ms and came back in 1.5 ms. The intersection is [1 s - 1.5 ms,
        // 1 s + 1.5 ms]: its middle is the offset, however asymmetric the first exchange was.
        sync.observe(100_000, 1_100_000 + 90_000, 200_000).unwrap();
        sync.observe(300_000, 1_300_000 + 1_500, 303_000).unwrap();
        let f = sync.fit().unwrap();
        assert_eq!(f.pairs, 1);
        assert!((f.offset_us - 1_000_000.0).abs() < 1.0, "{}", f.offset_us);
        assert!((f.bound_us - 1_500.0).abs() < 1.0, "{}", f.bound_us);
        // Exchanges more than 3 s older than the newest are forgotten.
        for k in 1..=6u64 {
            let t = 300_000 + k * 1_000_000;
            sync.observe(t, t + 1_000_000 + 1_000, t + 2_000).unwrap();
        }
        assert_eq!(sync.fit().unwrap().pairs, 4);
    }
}
