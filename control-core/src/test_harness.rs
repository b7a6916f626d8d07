//! The test harness of the mode and failsafe tests (`failsafe_tests.rs`, `pilot_tests.rs`).
//!
//! The harness moves a kinematic vehicle toward the flight code's setpoint (second order, 0.3 s; the
//! setpoint's velocity fed forward when asked), synthesises a
//! consistent IMU (level, specific force `a + g` behind a first-order 98 Hz anti-alias filter, as a real MEMS
//! part has: the touchdown's stop is spread over a few samples, not one), and delivers vision fixes, link
//! messages and the pilot's transmitter as scripted, so that the mode logic is exercised without the full
//! simulator.
use super::*;
use crate::estimator::{BodyVelocity, ImuSample, PositionFix};

pub(crate) struct Harness {
    pub(crate) core: ControlCore,
    pub(crate) t_us: u64,
    pub(crate) p: Vec3,
    pub(crate) v: Vec3,
    pub(crate) tilt_accel: Vec3,
    pub(crate) imu_on: bool,
    pub(crate) imu_nan: bool,
    pub(crate) vision_on: bool,
    /// A flow velocity (the vehicle's, body frame) every 17 ms.
    pub(crate) flow_on: bool,
    pub(crate) link_on: bool,
    /// The vehicle brings its estimate, not its true position, to the setpoint (as the closed loop does: an
    /// estimate's error becomes the vehicle's).
    pub(crate) tracks_estimate: bool,
    /// The vehicle follows the setpoint's velocity as well as its position (as the laws do); without it, the
    /// position alone.
    pub(crate) follows_velocity: bool,
    /// An acceleration the vehicle undergoes (a gust) for the next `push_samples` IMU samples.
    pub(crate) push: Vec3,
    pub(crate) push_samples: u32,
    /// A gyro x reading held at this value (a saturated gyro) for the next `clip_samples` IMU samples.
    pub(crate) clip_value: f32,
    pub(crate) clip_samples: u32,
    pub(crate) out: Option<ControlOutputs>,
    /// The accelerometer's filter state.
    pub(crate) accel_lp: Vec3,
    /// Recent positions (one per step), for the fixes' capture times.
    pub(crate) trail: [Vec3; 32],
    /// The pilot's transmitter, delivered every step.
    pub(crate) pilot: Option<pilot::PilotInput>,
    /// The battery's reading, delivered every step.
    pub(crate) battery: Option<battery::BatteryReading>,
}

impl Harness {
    pub(crate) fn new() -> Self {
        Self::with(|_| {})
    }

    /// A harness whose paper parameters `edit` changes.
    pub(crate) fn with(edit: impl FnOnce(&mut FlightParams)) -> Self {
        let mut params = FlightParams::paper();
        // The kinematic vehicle accelerates level, which no quadrotor can: the estimator's rotor-drag model
        // (the specific force across the thrust axis is drag alone) does not hold for it.
        params.estimator.drag_coeff_per_s = 0.0;
        edit(&mut params);
        let home = Vec3::from_array(params.home_m);
        Self {
            core: ControlCore::new(params).unwrap(),
            t_us: 0,
            p: home,
            v: Vec3::ZERO,
            tilt_accel: Vec3::ZERO,
            imu_on: true,
            imu_nan: false,
            vision_on: true,
            flow_on: false,
            link_on: true,
            tracks_estimate: false,
            follows_velocity: false,
            push: Vec3::ZERO,
            push_samples: 0,
            clip_value: 0.0,
            clip_samples: 0,
            out: None,
            accel_lp: Vec3::new(0.0, 0.0, GRAVITY),
            trail: [home; 32],
            pilot: None,
            battery: None,
        }
    }

    /// The idle rotor speed.
    pub(crate) fn params_idle(&self) -> f32 {
        self.core.params().vehicle.motor_speed_min_rad_s
    }

    pub(crate) fn mode(&self) -> FlightMode {
        self.out.map_or(FlightMode::Disarmed, |o| o.status.mode)
    }

    /// One 2 ms control period; `cmd` is delivered with it.
    pub(crate) fn step(&mut self, cmd: Option<Command>) -> ControlOutputs {
        let mut imu = [ImuSample::default(); 2];
        let offset = |o: &ControlOutputs| {
            if self.tracks_estimate { self.p - o.estimate.position_m } else { Vec3::ZERO }
        };
        let sp = self.out.map(|o| (o.setpoint.position_m + offset(&o), o.setpoint.velocity_m_s));
        let airborne =
            self.out.is_some_and(|o| o.status.mode.airborne() && o.motors_rad_s.iter().any(|w| *w > 0.0));
        let mut acc;
        for s in imu.iter_mut() {
            self.t_us += 1000;
            // Kinematic follower of the setpoint while flying; resting otherwise.
            let v_before = self.v;
            if let (true, Some((target, v_ref))) = (airborne, sp) {
                let v_ff = if self.follows_velocity { v_ref } else { Vec3::ZERO };
                let a = (target - self.p) * (1.0 / 0.09) + (v_ff - self.v) * (2.0 / 0.3);
                self.v += a * 0.001;
                self.p += self.v * 0.001;
                if self.p.z < 0.06 {
                    self.p.z = 0.06;
                    self.v = Vec3::ZERO;
                }
            } else {
                self.v = Vec3::ZERO;
            }
            if self.push_samples > 0 {
                self.push_samples -= 1;
                self.v += self.push * 0.001;
            }
            // The accelerometer feels the actual change of velocity (the floor's reaction included).
            acc = (self.v - v_before) * 1000.0;
            // Level and facing the wall (yaw 0): body axes are the navigation frame's, x toward the wall.
            let world = acc + Vec3::new(0.0, 0.0, GRAVITY);
            let raw = geometry::frames::WORLD_FROM_NAV.tmul_vec(world) + self.tilt_accel;
            // 1 - exp(-2 pi 98 Hz 1 ms)
            self.accel_lp += (raw - self.accel_lp) * 0.46;
            let f = self.accel_lp;
            let mut bad = if self.imu_nan { f32::NAN } else { 0.0 };
            if self.clip_samples > 0 {
                self.clip_samples -= 1;
                bad += self.clip_value;
            }
            *s = ImuSample { time_us: self.t_us, gyro_rad_s: [bad, 0.0, 0.0], accel_m_s2: f.to_array() };
        }
        let fix =
            (self.vision_on && self.t_us > 50_000 && (self.t_us / 2000).is_multiple_of(17)).then(|| {
                PositionFix {
                    // Captured 40 ms (20 steps) ago: where the vehicle was then.
                    capture_time_us: self.t_us - 40_000,
                    position_m: self.trail[20],
                    position_std_m: Vec3::new(0.005, 0.005, 0.005),
                    x_observed: true,
                    yaw_rad: 0.0,
                    yaw_std_rad: 0.002,
                }
            });
        // The flow's velocity in the body frame (level, facing the wall: the navigation frame's axes).
        let v_body = geometry::frames::WORLD_FROM_NAV.tmul_vec(self.v);
        let flow = (self.flow_on && (self.t_us / 2000).is_multiple_of(17)).then(|| BodyVelocity {
            time_us: self.t_us - 10_000,
            velocity_m_s: [v_body.x, v_body.y],
            std_m_s: 0.02,
        });
        self.trail.rotate_right(1);
        self.trail[0] = self.p;
        let imu_slice: &[ImuSample] = if self.imu_on { &imu } else { &[] };
        let out = self.core.step(&ControlInputs {
            time_us: self.t_us,
            imu: imu_slice,
            mag: None,
            baro_m: None,
            fix,
            flow,
            command: cmd,
            link_message: self.link_on,
            landed: None,
            pilot: self.pilot,
            battery: self.battery,
        });
        self.out = Some(out);
        out
    }

    pub(crate) fn run(&mut self, seconds: f32) {
        for _ in 0..(seconds * 500.0) as usize {
            self.step(None);
        }
    }

    pub(crate) fn run_until(&mut self, mode: FlightMode, max_s: f32) {
        for _ in 0..(max_s * 500.0) as usize {
            if self.step(None).status.mode == mode {
                return;
            }
        }
        panic!("did not reach {mode:?} within {max_s} s (mode {:?})", self.mode());
    }

    pub(crate) fn command(&mut self, c: Command) -> Option<CommandResult> {
        self.step(Some(c)).status.last_command
    }

    /// Armed, airborne and hovering.
    pub(crate) fn hovering() -> Self {
        Self::hovering_with(|_| {})
    }

    /// As [`Harness::hovering`], with parameters changed by `edit`.
    pub(crate) fn hovering_with(edit: impl FnOnce(&mut FlightParams)) -> Self {
        let mut h = Harness::with(edit);
        h.run(1.0);
        assert_eq!(h.command(Command::Arm), Some(CommandResult::Accepted(Command::Arm)));
        assert_eq!(h.command(Command::TakeOff), Some(CommandResult::Accepted(Command::TakeOff)));
        h.run_until(FlightMode::Hover, 20.0);
        h
    }
}
