//! Reference trajectories: the sweep of paper section 5.2 and the take-off and landing ramps.
//!
//! Each pass is the paper's `x_d(t) = b0 + b1 t + b2 t^2` per segment: accelerate (`b2 = +-a/2`), cruise
//! (`b1 = +-v`), decelerate. When a pass reaches its end, the direction flag flips and the next pass starts
//! back (the paper's boolean direction flag).

/// One piece `b0 + b1 t + b2 t^2` of a profile, valid for `t` in `[0, duration_s]`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment {
    /// Constant term (m).
    pub b0: f32,
    /// Linear term (m/s).
    pub b1: f32,
    /// Quadratic term (m/s^2).
    pub b2: f32,
    /// Duration (s).
    pub duration_s: f32,
}

impl Segment {
    /// Position, velocity, acceleration at `t` seconds into the segment.
    pub fn eval(&self, t: f32) -> (f32, f32, f32) {
        (self.b0 + self.b1 * t + self.b2 * t * t, self.b1 + 2.0 * self.b2 * t, 2.0 * self.b2)
    }
}

/// A rest-to-rest move from `from` to `to`: three segments (accelerate, cruise, decelerate; the cruise is
/// empty for short moves).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Move {
    /// The three segments.
    pub segments: [Segment; 3],
}

impl Move {
    /// A move with top speed `v` and acceleration `a` (both positive).
    pub fn new(from: f32, to: f32, v: f32, a: f32) -> Self {
        let d = to - from;
        let dir = if d >= 0.0 { 1.0 } else { -1.0 };
        let dist = d.abs();
        let (v_top, t_acc) = if dist >= v * v / a {
            (v, v / a)
        } else {
            let vp = libm::sqrtf(dist * a);
            (vp, vp / a)
        };
        let d_acc = 0.5 * a * t_acc * t_acc;
        let t_cruise = if v_top > 0.0 { (dist - 2.0 * d_acc).max(0.0) / v_top } else { 0.0 };
        let acc = Segment { b0: from, b1: 0.0, b2: 0.5 * dir * a, duration_s: t_acc };
        let cruise = Segment { b0: from + dir * d_acc, b1: dir * v_top, b2: 0.0, duration_s: t_cruise };
        let dec = Segment { b0: to - dir * d_acc, b1: dir * v_top, b2: -0.5 * dir * a, duration_s: t_acc };
        Self { segments: [acc, cruise, dec] }
    }

    /// Total duration (s).
    pub fn duration_s(&self) -> f32 {
        self.segments.iter().map(|s| s.duration_s).sum()
    }

    /// Position, velocity, acceleration `t` seconds after the start (held at the end afterwards).
    pub fn eval(&self, t: f32) -> (f32, f32, f32) {
        let mut t = t.max(0.0);
        for s in &self.segments {
            if t <= s.duration_s {
                return s.eval(t);
            }
            t -= s.duration_s;
        }
        let last = self.segments[2];
        (last.eval(last.duration_s).0, 0.0, 0.0)
    }
}

/// The way back to a reference from where a vehicle is and how fast it moves: a stop at acceleration `a`
/// (the velocity it has ramps to zero), then a rest-to-rest [`Move`] to the target. After a vision hold the
/// vehicle may be metres per second off its sweep's standoff and moving away; a reference that stepped to
/// the standoff's direction at the limiter's rate reversed the velocity demand at once (0.9 m/s), which the
/// vehicle followed with decimetres of lag.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rejoin {
    /// The stop.
    pub stop: Segment,
    /// Then the move.
    pub back: Move,
}

impl Rejoin {
    /// From position `p0` at velocity `v0` to `target`, with top speed `v` and acceleration `a` (positive).
    pub fn new(p0: f32, v0: f32, target: f32, v: f32, a: f32) -> Self {
        let t_stop = libm::fabsf(v0) / a;
        let b2 = if v0 > 0.0 { -0.5 * a } else { 0.5 * a };
        let stop = Segment { b0: p0, b1: v0, b2, duration_s: t_stop };
        let p_stop = stop.eval(t_stop).0;
        Self { stop, back: Move::new(p_stop, target, v, a) }
    }

    /// Total duration (s).
    pub fn duration_s(&self) -> f32 {
        self.stop.duration_s + self.back.duration_s()
    }

    /// Position, velocity, acceleration `t` seconds after the start (held at the target afterwards).
    pub fn eval(&self, t: f32) -> (f32, f32, f32) {
        if t <= self.stop.duration_s {
            self.stop.eval(t.max(0.0))
        } else {
            self.back.eval(t - self.stop.duration_s)
        }
    }
}

/// The back-and-forth sweep along x.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sweep {
    range: [f32; 2],
    speed: f32,
    accel: f32,
    passes_total: u16,
    /// Passes completed.
    pub passes_done: u16,
    /// Direction flag: true while moving toward `range[1]`.
    pub forward: bool,
    current: Move,
    pass_start_us: u64,
}

impl Sweep {
    /// A sweep of `sweeps` round trips over `range`, starting at `start_x` (first pass toward the farther
    /// end) at time `now_us`.
    pub fn new(range: [f32; 2], speed: f32, accel: f32, sweeps: u8, start_x: f32, now_us: u64) -> Self {
        let forward = (range[1] - start_x).abs() >= (start_x - range[0]).abs();
        let to = if forward { range[1] } else { range[0] };
        Self {
            range,
            speed,
            accel,
            passes_total: 2 * sweeps as u16,
            passes_done: 0,
            forward,
            current: Move::new(start_x, to, speed, accel),
            pass_start_us: now_us,
        }
    }

    /// Goes on with the current pass from `x` (where the vehicle is after a hold), toward the same end.
    pub fn resume(&mut self, x: f32, now_us: u64) {
        let to = if self.forward { self.range[1] } else { self.range[0] };
        self.current = Move::new(x, to, self.speed, self.accel);
        self.pass_start_us = now_us;
    }

    /// Whether all passes are done.
    pub fn finished(&self) -> bool {
        self.passes_done >= self.passes_total
    }

    /// Reference `(x, x', x'')` at `now_us`; flips the direction flag at each end.
    pub fn update(&mut self, now_us: u64) -> (f32, f32, f32) {
        loop {
            let t = now_us.saturating_sub(self.pass_start_us) as f32 * 1e-6;
            let dur = self.current.duration_s();
            if t <= dur || self.finished() {
                return self.current.eval(t);
            }
            // End of the pass: flip the flag and start back.
            self.passes_done += 1;
            if self.finished() {
                return self.current.eval(dur);
            }
            let here = self.current.eval(dur).0;
            self.forward = !self.forward;
            let to = if self.forward { self.range[1] } else { self.range[0] };
            self.pass_start_us += (dur * 1e6) as u64;
            self.current = Move::new(here, to, self.speed, self.accel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rejoin_stops_then_comes_back_without_a_step() {
        // Moving away at 0.26 m/s, 0.4 m beyond the target.
        let r = Rejoin::new(1.7, 0.26, 1.3, 0.25, 0.25);
        let (p, v, a) = r.eval(0.0);
        assert_eq!((p, v, a), (1.7, 0.26, -0.25));
        // Stops at 1.7 + 0.26^2 / 0.5 after 0.26 / 0.25 s.
        let (p, v, _) = r.eval(0.26 / 0.25);
        assert!((p - (1.7 + 0.26 * 0.26 / 0.5)).abs() < 1e-5 && v.abs() < 1e-6, "{p} {v}");
        assert_eq!(r.eval(r.duration_s() + 1.0), (1.3, 0.0, 0.0));
        // The velocity never changes faster than the acceleration allows (no step), sampled at 2 ms.
        let mut prev = r.eval(0.0).1;
        let mut t = 0.0;
        while t < r.duration_s() + 0.1 {
            t += 0.002;
            let v = r.eval(t).1;
            assert!((v - prev).abs() <= 0.25 * 0.002 + 1e-5, "at {t}: {prev} -> {v}");
            prev = v;
        }
        // Moving toward the target already: the stop is in the target's direction.
        let r = Rejoin::new(1.0, 0.1, 1.3, 0.25, 0.25);
        assert!(r.eval(0.4).0 > 1.0);
        assert_eq!(r.eval(r.duration_s()).0, 1.3);
    }

    #[test]
    fn move_is_continuous_and_reaches_the_end() {
        let m = Move::new(0.0, 2.3, 0.25, 0.25);
        let mut prev = m.eval(0.0);
        let mut t = 0.0;
        while t < m.duration_s() + 1.0 {
            t += 0.01;
            let s = m.eval(t);
            assert!((s.0 - prev.0).abs() < 0.25 * 0.01 + 1e-4);
            assert!((s.1 - prev.1).abs() < 0.25 * 0.01 + 1e-4);
            assert!(s.1 >= -1e-6 && s.1 <= 0.25 + 1e-6);
            prev = s;
        }
        assert!((prev.0 - 2.3).abs() < 1e-4 && prev.1 == 0.0);
        // 2.3 m at 0.25 m/s with 1 s ramps: 9.2 s + 1 s.
        assert!((m.duration_s() - 10.2).abs() < 1e-3);
        // Short move: triangular profile, no overshoot.
        let s = Move::new(1.0, 1.05, 0.25, 0.25);
        assert!(s.segments[1].duration_s == 0.0);
        assert!((s.eval(s.duration_s()).0 - 1.05).abs() < 1e-5);
    }

    #[test]
    fn sweep_flips_direction_at_each_end() {
        let mut s = Sweep::new([0.0, 2.3], 0.25, 0.25, 2, 0.0, 0);
        let mut t = 0u64;
        let mut flips = 0;
        let mut was = s.forward;
        let mut max_x = f32::MIN;
        let mut min_x = f32::MAX;
        while !s.finished() {
            t += 10_000;
            let (x, _, _) = s.update(t);
            max_x = max_x.max(x);
            min_x = min_x.min(x);
            if s.forward != was {
                flips += 1;
                was = s.forward;
            }
            assert!(t < 100_000_000);
        }
        assert_eq!(flips, 3);
        assert_eq!(s.passes_done, 4);
        assert!((max_x - 2.3).abs() < 1e-3 && min_x.abs() < 1e-3);
        let (x, v, _) = s.update(t + 1_000_000);
        assert!(x.abs() < 1e-3 && v == 0.0);
    }
}
