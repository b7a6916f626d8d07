//! What the IMU alone says about the vehicle's motion: still, moved by hand, or carried by its rotors.
//!
//! The estimator needs this to choose the accelerometer's model (see `docs/architecture.md`, "State
//! estimation"):
//!
//! - **still** (on the floor, on a table): the specific force is gravity, the velocity and the angular rate
//!   are zero; the ground constraint and the gyro-bias update apply. Being disarmed is not enough: a vehicle
//!   carried by hand, or an imported log recorded before a take-off, is disarmed and moving;
//! - **gravity-dominated** (carried, handled): the specific force is gravity plus an acceleration that
//!   averages out; a weak gravity update applies;
//! - **thrust-borne** (flying): the specific force stays along the rotors' thrust axis, whatever the tilt,
//!   so gravity cannot be read from it; the rotor-drag model applies instead.
//!
//! Samples are summed into blocks (`block_s`, 50 ms by default); the last `window_blocks` block means form
//! the window. The vehicle is still when the block means of the angular rate and of the specific force stay
//! within tolerances of their window means and the specific force's magnitude is that of gravity (like the
//! at-rest checks of the PX4 and ArduPilot land detectors, which also test the rates and accelerations
//! against thresholds over a window).
//!
//! The two moving cases are told apart by where the specific force's direction stays fixed: a rigid body
//! that does not accelerate much sees gravity, fixed in the world, so the direction turns in the body as the
//! body turns; a multirotor sees its thrust, fixed in the body, so the direction turns in the world instead.
//! With `u_k` the block's mean direction in the body and `R_k` the estimated attitude, the RMS spreads of
//! `u_k` and of `R_k u_k` (exponentially weighted over `classify_window_s`) are compared once the body's
//! tilt has changed by more than `classify_min_tilt_rad` RMS; with less the previous class is kept. A body
//! spread beyond what drag and vibration give a flying vehicle (`classify_body_spread_max`) is a shaking
//! hand.
use crate::GRAVITY;
use crate::estimator::ImuSample;
use geometry::{Quat, Vec3};

/// Most blocks a window can hold.
pub const MAX_WINDOW_BLOCKS: usize = 16;

params_struct! {
    /// Thresholds of the motion detector.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct MotionParams in ["estimator.motion"] {
        /// Length of one block of samples (s).
        block_s: f32 = 0.05, { >= 0.005, <= 0.5 } "s";
        /// Blocks in the window (at most 16, `MAX_WINDOW_BLOCKS`).
        window_blocks: u8 = 8, { >= 2, <= 16 } "";
        /// Still: largest deviation of a block's mean angular rate from the window's mean (rad/s), beyond
        /// three times the noise of a block mean (measured within the blocks).
        still_gyro_rad_s: f32 = 0.02, { > 0.0, < 10.0 } "rad/s";
        /// Still: largest deviation of a block's mean specific force from the window's mean (m/s^2), beyond
        /// three times the noise of a block mean (measured within the blocks).
        still_accel_m_s2: f32 = 0.3, { > 0.0, < 10.0 } "m/s^2";
        /// Still: largest difference between the window's mean specific force magnitude and gravity
        /// (m/s^2).
        still_norm_m_s2: f32 = 0.5, { > 0.0, < 10.0 } "m/s^2";
        /// Still: largest window-mean angular rate once the estimated gyro bias is removed (rad/s); a steady
        /// rotation slower than this is indistinguishable from a bias.
        still_rate_max_rad_s: f32 = 0.2, { > 0.0, < 10.0 } "rad/s";
        /// How long the vehicle must have been found still, block after block, before it counts as resting
        /// (s), unless it may be flying (`still_confirm_flying_s`). A moving vehicle can hold its rates
        /// and specific force steady for a moment: a glide at constant velocity looks like rest to an IMU (on
        /// EuRoC MH_01 in flight such stretches last up to 0.93 s; its rests last 10 s and more). The
        /// estimator waits for it only when the flight code cannot tell whether the vehicle flies (disarmed,
        /// or a log without a land detector).
        still_confirm_s: f32 = 0.5, { >= 0.0, <= 10.0 } "s";
        /// The same when the vehicle may be flying (s): last seen flying (a landing), or moving before it was
        /// ever seen at rest or classified (a recording that starts in the air). PX4's land detector likewise
        /// waits for its conditions to hold (`LNDMC_TRIG_TIME`, 1 s, after the earlier "maybe landed" stages)
        /// before it declares a landing.
        still_confirm_flying_s: f32 = 2.0, { >= 0.0, <= 10.0 } "s";
        /// Time constant of the statistics that tell a hand-held from a flying vehicle (s).
        classify_window_s: f32 = 2.0, { > 0.0, < 10.0 } "s";
        /// Smallest RMS tilt change over that time that can tell them apart (rad).
        classify_min_tilt_rad: f32 = 0.015, { > 0.0, < 10.0 } "rad";
        /// Largest RMS spread of the specific force's direction in the body for a flying vehicle (its drag
        /// and vibration); a hand-held one that shakes more is carried, whatever the world spread.
        classify_body_spread_max: f32 = 0.05, { > 0.0, < 10.0 } "";
    }
}

impl MotionParams {
    /// How long a still stretch must last to count as a rest, after moving as `before`. `in_doubt`: the
    /// vehicle has moved without ever having been seen at rest or classified (a recording that starts in the
    /// air, with a flight too gentle to classify): it waits as long as after a flight. Still from the start,
    /// or after being carried or a rest, it waits `still_confirm_s`.
    pub fn still_confirm_after(&self, before: MotionClass, in_doubt: bool) -> f32 {
        match before {
            MotionClass::ThrustBorne => self.still_confirm_flying_s,
            MotionClass::Unknown if in_doubt => self.still_confirm_flying_s,
            _ => self.still_confirm_s,
        }
    }

    pub(crate) fn validate(&self) -> Result<(), crate::params::ParamError> {
        const _: () = assert!(MAX_WINDOW_BLOCKS == 16, "the declared range of window_blocks");
        self.check_declared(0)
    }
}

/// How the vehicle moves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotionClass {
    /// Not yet known (too few samples, or moving without a tilt change that tells).
    #[default]
    Unknown,
    /// At rest.
    Still,
    /// Moving, the specific force dominated by gravity (carried by hand).
    GravityDominated,
    /// Moving, the specific force along the thrust axis (flying).
    ThrustBorne,
}

/// One finished block of samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Block {
    /// Time of its last sample (us).
    pub end_us: u64,
    /// Samples in it.
    pub samples: u32,
    /// Mean angular rate (body, rad/s, bias not removed).
    pub mean_gyro: Vec3,
    /// Mean specific force (body, m/s^2, bias not removed).
    pub mean_accel: Vec3,
}

/// What the detector says when a block ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionReport {
    /// The block that ended.
    pub block: Block,
    /// The class after it.
    pub class: MotionClass,
    /// At rest: the whole window's mean angular rate and specific force (body).
    pub still_window: Option<(Vec3, Vec3)>,
    /// Still for as long as a rest lasts (`MotionParams::still_confirm_after` the moving class before).
    pub rest_confirmed: bool,
    /// The class before the vehicle was last found still (what a still stretch too short to be a rest
    /// leaves unchanged); the class itself when moving.
    pub moving_class: MotionClass,
}

#[derive(Clone, Copy, Debug, Default)]
struct Entry {
    gyro: Vec3,
    accel: Vec3,
    /// Standard deviations of the block's means, from the samples' spread within it.
    gyro_sd: f32,
    accel_sd: f32,
}

/// The detector: blocks of samples, a window of block means, the class.
#[derive(Clone, Debug)]
pub struct MotionDetector {
    params: MotionParams,
    sum_gyro: Vec3,
    sum_accel: Vec3,
    sq_gyro: f32,
    sq_accel: f32,
    n: u32,
    start_us: u64,
    last_us: Option<u64>,
    ring: [Entry; MAX_WINDOW_BLOCKS],
    len: usize,
    head: usize,
    class: MotionClass,
    spread: Spread,
    /// End of the first block of the current still stretch.
    still_since_us: Option<u64>,
    /// The class before the current still stretch.
    moving_class: MotionClass,
    /// Whether the vehicle has moved (a full window not still) since the start or a gap.
    moved: bool,
    /// Whether it has been seen at rest, carried or flying since the start or a gap.
    known: bool,
}

/// Exponentially weighted first and second moments of the block directions: the specific force in the body
/// (`u`), in the world (`R u`), and the world's up in the body (the tilt).
#[derive(Clone, Copy, Debug, Default)]
struct Spread {
    blocks: u32,
    u: Vec3,
    uu: f32,
    w: Vec3,
    ww: f32,
    up: Vec3,
    upup: f32,
}

impl Spread {
    fn add(&mut self, a: f32, u: Vec3, w: Vec3, up: Vec3) {
        let a = if self.blocks == 0 { 1.0 } else { a.max(1.0 / (self.blocks + 1) as f32) };
        self.blocks = self.blocks.saturating_add(1);
        let mix = |m: &mut Vec3, mm: &mut f32, x: Vec3| {
            *m = *m + (x - *m) * a;
            *mm += (x.norm_sq() - *mm) * a;
        };
        mix(&mut self.u, &mut self.uu, u);
        mix(&mut self.w, &mut self.ww, w);
        mix(&mut self.up, &mut self.upup, up);
    }

    /// RMS spreads: body, world, tilt.
    fn rms(&self) -> (f32, f32, f32) {
        let r = |m: Vec3, mm: f32| libm::sqrtf((mm - m.norm_sq()).max(0.0));
        (r(self.u, self.uu), r(self.w, self.ww), r(self.up, self.upup))
    }
}

impl MotionDetector {
    /// A detector with no samples.
    pub fn new(params: MotionParams) -> Self {
        Self {
            params,
            sum_gyro: Vec3::ZERO,
            sum_accel: Vec3::ZERO,
            sq_gyro: 0.0,
            sq_accel: 0.0,
            n: 0,
            start_us: 0,
            last_us: None,
            ring: [Entry::default(); MAX_WINDOW_BLOCKS],
            len: 0,
            head: 0,
            class: MotionClass::Unknown,
            spread: Spread::default(),
            still_since_us: None,
            moving_class: MotionClass::Unknown,
            moved: false,
            known: false,
        }
    }

    /// The current class.
    pub fn class(&self) -> MotionClass {
        self.class
    }

    fn block_us(&self) -> u64 {
        (self.params.block_s * 1e6) as u64
    }

    /// Adds one IMU sample with the estimator's attitude after it and its gyro bias; returns a report when
    /// the sample ends a block.
    pub fn push(&mut self, s: &ImuSample, q: &Quat, gyro_bias: Vec3) -> Option<MotionReport> {
        let block_us = self.block_us();
        // A gap of more than two blocks: what came before says nothing about now.
        if self.last_us.is_some_and(|l| s.time_us > l + 2 * block_us) {
            self.len = 0;
            self.n = 0;
            self.class = MotionClass::Unknown;
            self.spread = Spread::default();
            self.still_since_us = None;
            self.moving_class = MotionClass::Unknown;
            self.moved = false;
            self.known = false;
        }
        self.last_us = Some(s.time_us);
        if self.n == 0 {
            self.start_us = s.time_us;
            self.sum_gyro = Vec3::ZERO;
            self.sum_accel = Vec3::ZERO;
            self.sq_gyro = 0.0;
            self.sq_accel = 0.0;
        }
        let (g, a) = (Vec3::from_array(s.gyro_rad_s), Vec3::from_array(s.accel_m_s2));
        self.sum_gyro += g;
        self.sum_accel += a;
        self.sq_gyro += g.norm_sq();
        self.sq_accel += a.norm_sq();
        self.n += 1;
        if s.time_us < self.start_us + block_us - block_us / 100 {
            return None;
        }
        let inv = 1.0 / self.n as f32;
        let block = Block {
            end_us: s.time_us,
            samples: self.n,
            mean_gyro: self.sum_gyro * inv,
            mean_accel: self.sum_accel * inv,
        };
        // The noise of a block mean: the samples' variance within the block (all axes) over their count.
        let sd_of_mean = |sq: f32, mean: Vec3| {
            let n = self.n as f32;
            if self.n < 2 { 0.0 } else { libm::sqrtf(((sq - n * mean.norm_sq()) / (n - 1.0)).max(0.0) / n) }
        };
        let entry = Entry {
            gyro: block.mean_gyro,
            accel: block.mean_accel,
            gyro_sd: sd_of_mean(self.sq_gyro, block.mean_gyro),
            accel_sd: sd_of_mean(self.sq_accel, block.mean_accel),
        };
        self.n = 0;
        self.ring[self.head] = entry;
        let u = block.mean_accel.normalized().unwrap_or(Vec3::Z);
        let alpha = self.params.block_s / self.params.classify_window_s;
        self.spread.add(alpha, u, q.rotate(u), q.inverse_rotate(Vec3::Z));
        self.head = (self.head + 1) % MAX_WINDOW_BLOCKS;
        let window = self.params.window_blocks as usize;
        self.len = (self.len + 1).min(window);
        if self.len == window {
            self.class = self.classify(gyro_bias, block.end_us);
        }
        if self.class == MotionClass::Still {
            self.still_since_us.get_or_insert(block.end_us);
        } else {
            self.still_since_us = None;
            self.moving_class = self.class;
        }
        let rest_confirmed = self.rest_confirmed(block.end_us);
        self.moved |= self.len == window && self.class != MotionClass::Still;
        self.known |=
            rest_confirmed || matches!(self.class, MotionClass::GravityDominated | MotionClass::ThrustBorne);
        let still_window = (self.class == MotionClass::Still).then(|| {
            let inv = 1.0 / self.len as f32;
            let (mut g, mut a) = (Vec3::ZERO, Vec3::ZERO);
            for e in self.entries() {
                g += e.gyro;
                a += e.accel;
            }
            (g * inv, a * inv)
        });
        Some(MotionReport {
            block,
            class: self.class,
            still_window,
            rest_confirmed,
            moving_class: self.moving_class,
        })
    }

    /// Whether the current still stretch has lasted as long as a rest does, at `end_us`.
    fn rest_confirmed(&self, end_us: u64) -> bool {
        let need = self.params.still_confirm_after(self.moving_class, self.moved && !self.known);
        self.still_since_us.is_some_and(|t| end_us.saturating_sub(t) as f32 * 1e-6 >= need)
    }

    fn entries(&self) -> impl Iterator<Item = &Entry> {
        (0..self.len).map(move |k| &self.ring[(self.head + MAX_WINDOW_BLOCKS - 1 - k) % MAX_WINDOW_BLOCKS])
    }

    fn classify(&self, gyro_bias: Vec3, end_us: u64) -> MotionClass {
        let p = &self.params;
        let inv = 1.0 / self.len as f32;
        let (mut mg, mut ma) = (Vec3::ZERO, Vec3::ZERO);
        for e in self.entries() {
            mg += e.gyro;
            ma += e.accel;
        }
        mg = mg * inv;
        ma = ma * inv;
        let max_dev = |f: &dyn Fn(&Entry) -> f32| self.entries().map(f).fold(0.0f32, f32::max);
        let mean_of = |f: &dyn Fn(&Entry) -> f32| self.entries().map(f).sum::<f32>() * inv;
        let (gyro_noise, accel_noise) = (mean_of(&|e| e.gyro_sd), mean_of(&|e| e.accel_sd));
        let still = max_dev(&|e| (e.gyro - mg).norm()) <= p.still_gyro_rad_s + 3.0 * gyro_noise
            && max_dev(&|e| (e.accel - ma).norm()) <= p.still_accel_m_s2 + 3.0 * accel_noise
            && (ma.norm() - GRAVITY).abs() <= p.still_norm_m_s2
            && (mg - gyro_bias).norm() <= p.still_rate_max_rad_s;
        if still {
            return MotionClass::Still;
        }
        // Leaving a rest: what flew before may land now; a short still stretch keeps the class before it.
        let keep = match self.class {
            MotionClass::Still if self.rest_confirmed(end_us) => MotionClass::Unknown,
            MotionClass::Still => self.moving_class,
            c => c,
        };
        // Too early to tell: the spreads cover less than the classification window.
        if (self.spread.blocks as f32) * p.block_s < p.classify_window_s {
            return keep;
        }
        let (spread_body, spread_world, tilt_change) = self.spread.rms();
        if tilt_change < p.classify_min_tilt_rad {
            keep
        } else if spread_body < 0.5 * spread_world && spread_body < p.classify_body_spread_max {
            MotionClass::ThrustBorne
        } else if spread_world < 0.5 * spread_body || spread_body >= p.classify_body_spread_max {
            MotionClass::GravityDominated
        } else {
            keep
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::frames::Attitude;

    fn sample(t_us: u64, gyro: Vec3, accel: Vec3) -> ImuSample {
        ImuSample { time_us: t_us, gyro_rad_s: gyro.to_array(), accel_m_s2: accel.to_array() }
    }

    /// Runs `secs` of 1 kHz samples from `f(t) -> (attitude, gyro, accel)`; returns the last report.
    fn run(d: &mut MotionDetector, t0: u64, secs: f32, f: impl Fn(f32) -> (Quat, Vec3, Vec3)) -> MotionClass {
        let n = (secs * 1000.0) as u64;
        let mut last = d.class();
        for k in 1..=n {
            let t = t0 + k * 1000;
            let (q, g, a) = f(t as f32 * 1e-6);
            if let Some(r) = d.push(&sample(t, g, a), &q, Vec3::ZERO) {
                last = r.class;
            }
        }
        last
    }

    fn level() -> Quat {
        Quat::from_mat3(&Attitude::default().world_from_body())
    }

    #[test]
    fn still_with_noise_and_a_gyro_bias_is_still() {
        let mut d = MotionDetector::new(MotionParams::default());
        let mut x = 1u32;
        let mut noise = move || {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (x >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        let mut last = MotionClass::Unknown;
        for k in 1..=1000u64 {
            let g = Vec3::new(0.08 + 0.05 * noise(), 0.02, 0.01 * noise());
            let a = Vec3::new(0.5 * noise(), 0.5 * noise(), GRAVITY + 0.5 * noise());
            if let Some(r) = d.push(&sample(k * 1000, g, a), &level(), Vec3::ZERO) {
                last = r.class;
            }
        }
        assert_eq!(last, MotionClass::Still);
    }

    #[test]
    fn a_hand_held_tilting_motion_is_gravity_dominated_and_a_flying_one_thrust_borne() {
        // Rocking in roll at 1 Hz, 8 deg: by hand, the accelerometer reads gravity in the body.
        let amp = 8f32.to_radians();
        let w = core::f32::consts::TAU;
        let att = |t: f32| Attitude::new(amp * libm::sinf(w * t), 0.0, 0.0);
        let mut d = MotionDetector::new(MotionParams::default());
        let hand = run(&mut d, 0, 3.0, |t| {
            let r = att(t).world_from_body();
            let g = Vec3::new(amp * w * libm::cosf(w * t), 0.0, 0.0);
            (Quat::from_mat3(&r), g, r.tmul_vec(Vec3::new(0.0, 0.0, GRAVITY)))
        });
        assert_eq!(hand, MotionClass::GravityDominated);
        // The same rocking in flight: the thrust stays along body z.
        let mut d = MotionDetector::new(MotionParams::default());
        let fly = run(&mut d, 0, 3.0, |t| {
            let r = att(t).world_from_body();
            let g = Vec3::new(amp * w * libm::cosf(w * t), 0.0, 0.0);
            (Quat::from_mat3(&r), g, Vec3::new(0.0, 0.0, GRAVITY))
        });
        assert_eq!(fly, MotionClass::ThrustBorne);
        // Hovering without a tilt change cannot tell: the class is kept.
        let kept =
            run(&mut d, 3_000_000, 2.0, |_| (level(), Vec3::new(0.0, 0.0, 0.3), Vec3::new(0.0, 0.0, 9.0)));
        assert_eq!(kept, MotionClass::ThrustBorne);
    }

    /// The report of each block over `secs` of 1 kHz samples from `f(t)`.
    fn reports(
        d: &mut MotionDetector,
        t0: u64,
        secs: f32,
        f: impl Fn(f32) -> (Quat, Vec3, Vec3),
    ) -> Vec<MotionReport> {
        let n = (secs * 1000.0) as u64;
        (1..=n)
            .filter_map(|k| {
                let t = t0 + k * 1000;
                let (q, g, a) = f(t as f32 * 1e-6);
                d.push(&sample(t, g, a), &q, Vec3::ZERO)
            })
            .collect()
    }

    /// Flying, rocking 8 deg in roll at 1 Hz on the thrust (the force stays along body z).
    fn rocking_flight(t: f32) -> (Quat, Vec3, Vec3) {
        let (amp, w) = (8f32.to_radians(), core::f32::consts::TAU);
        let r = Attitude::new(amp * libm::sinf(w * t), 0.0, 0.0).world_from_body();
        let g = Vec3::new(amp * w * libm::cosf(w * t), 0.0, 0.0);
        (Quat::from_mat3(&r), g, Vec3::new(0.0, 0.0, GRAVITY))
    }

    #[test]
    fn a_still_stretch_is_a_rest_once_it_has_lasted_longer_after_flight() {
        let p = MotionParams::default();
        let calm = |_: f32| (level(), Vec3::ZERO, Vec3::new(0.0, 0.0, GRAVITY));
        // From the start: still after the window fills, a rest `still_confirm_s` later.
        let mut d = MotionDetector::new(p);
        let r = reports(&mut d, 0, 1.5, calm);
        let first_still = r.iter().find(|r| r.class == MotionClass::Still).unwrap().block.end_us;
        let first_rest = r.iter().find(|r| r.rest_confirmed).unwrap().block.end_us;
        assert!(r.iter().all(|r| r.moving_class == MotionClass::Unknown));
        let waited = (first_rest - first_still) as f32 * 1e-6;
        assert!((waited - p.still_confirm_s).abs() < 0.051, "{waited} s");
        // Flying (rocking on the thrust), then as steady as a rest: still, not yet a rest, and the class
        // before it kept until `still_confirm_flying_s` has passed.
        let mut d = MotionDetector::new(p);
        let fly = reports(&mut d, 0, 3.0, rocking_flight);
        assert_eq!(fly.last().unwrap().class, MotionClass::ThrustBorne);
        let r = reports(&mut d, 3_000_000, 3.0, calm);
        let first_still = r.iter().find(|r| r.class == MotionClass::Still).unwrap().block.end_us;
        let first_rest = r.iter().find(|r| r.rest_confirmed).unwrap().block.end_us;
        let waited = (first_rest - first_still) as f32 * 1e-6;
        assert!((waited - p.still_confirm_flying_s).abs() < 0.051, "{waited} s");
        for x in r.iter().filter(|r| r.block.end_us < first_rest) {
            assert!(!x.rest_confirmed);
            assert_eq!(x.moving_class, MotionClass::ThrustBorne);
        }
        // Moving again before the rest is confirmed: the flight's class comes back at once.
        let mut d = MotionDetector::new(p);
        reports(&mut d, 0, 3.0, rocking_flight);
        let r = reports(&mut d, 3_000_000, 1.0, calm);
        assert!(r.iter().any(|r| r.class == MotionClass::Still) && !r.iter().any(|r| r.rest_confirmed));
        let r = reports(&mut d, 4_000_000, 0.1, |_| (level(), Vec3::new(0.5, 0.0, 0.0), Vec3::Z * GRAVITY));
        assert_eq!(r.last().unwrap().class, MotionClass::ThrustBorne);
    }

    #[test]
    fn a_motion_before_anything_is_known_waits_as_after_a_flight() {
        // A recording that starts in the air with a gentle flight: moving (the rates wander), never turning
        // enough to be classified. Its first still stretch may be a glide: a rest only after
        // `still_confirm_flying_s`. Once a rest has been seen, the same unclassified motion waits
        // `still_confirm_s` (a vehicle picked up and put down, or the first seconds after a take-off).
        let p = MotionParams::default();
        let calm = |_: f32| (level(), Vec3::ZERO, Vec3::new(0.0, 0.0, GRAVITY));
        let wander = |t: f32| (level(), Vec3::new(0.0, 0.0, 0.3 * libm::sinf(6.0 * t)), Vec3::Z * GRAVITY);
        let waited = |r: &[MotionReport]| {
            let still = r.iter().find(|r| r.class == MotionClass::Still).unwrap().block.end_us;
            let rest = r.iter().find(|r| r.rest_confirmed).unwrap().block.end_us;
            (rest - still) as f32 * 1e-6
        };
        let mut d = MotionDetector::new(p);
        let r = reports(&mut d, 0, 1.0, wander);
        assert_eq!(r.last().unwrap().class, MotionClass::Unknown);
        let r = reports(&mut d, 1_000_000, 3.0, calm);
        assert!((waited(&r) - p.still_confirm_flying_s).abs() < 0.051, "{} s", waited(&r));
        reports(&mut d, 4_000_000, 1.0, wander);
        let r = reports(&mut d, 5_000_000, 3.0, calm);
        assert!((waited(&r) - p.still_confirm_s).abs() < 0.051, "{} s", waited(&r));
    }

    #[test]
    fn a_short_still_stretch_keeps_the_flight_and_a_rest_ends_it() {
        // Flying, then hovering level (no tilt change, so the spreads cannot tell and the class is kept):
        // a still moment shorter than a rest leaves the vehicle flying; after a rest, the next motion is
        // not known to be a flight (it landed).
        let calm = |_: f32| (level(), Vec3::ZERO, Vec3::new(0.0, 0.0, GRAVITY));
        let wander = |t: f32| (level(), Vec3::new(0.0, 0.0, 0.3 * libm::sinf(6.0 * t)), Vec3::Z * GRAVITY);
        let mut d = MotionDetector::new(MotionParams::default());
        let fly = reports(&mut d, 0, 3.0, rocking_flight);
        assert_eq!(fly.last().unwrap().class, MotionClass::ThrustBorne);
        // 12 s: the flight's tilt changes have left the spreads' window (2 s time constant).
        let hover = reports(&mut d, 3_000_000, 12.0, wander);
        assert_eq!(hover.last().unwrap().class, MotionClass::ThrustBorne);
        let moment = reports(&mut d, 15_000_000, 1.0, calm);
        assert!(
            moment.iter().any(|r| r.class == MotionClass::Still) && !moment.iter().any(|r| r.rest_confirmed)
        );
        let on = reports(&mut d, 16_000_000, 0.3, wander);
        assert_eq!(on.last().unwrap().class, MotionClass::ThrustBorne);
        let rest = reports(&mut d, 16_300_000, 3.0, calm);
        assert!(rest.iter().any(|r| r.rest_confirmed));
        let moved = reports(&mut d, 19_300_000, 0.3, wander);
        assert_eq!(moved.last().unwrap().class, MotionClass::Unknown);
    }

    #[test]
    fn a_gap_forgets_the_window() {
        let mut d = MotionDetector::new(MotionParams::default());
        let still = run(&mut d, 0, 1.0, |_| (level(), Vec3::ZERO, Vec3::new(0.0, 0.0, GRAVITY)));
        assert_eq!(still, MotionClass::Still);
        let r = d.push(&sample(5_000_000, Vec3::ZERO, Vec3::new(0.0, 0.0, GRAVITY)), &level(), Vec3::ZERO);
        assert!(r.is_none());
        assert_eq!(d.class(), MotionClass::Unknown);
    }
}
