//! The measurements and the telemetry in fewer bytes: what crosses the radio at the default rates.
//!
//! The full messages ([`VisionMeasurement`], [`FlowMeasurement`], [`Telemetry`]) carry every field as an
//! `f32` and some twice (the estimate's Euler angles beside its quaternion). At 30 line measurements, 60 flow
//! measurements and 25 telemetry messages a second they took 6.7 kB/s up, more than half of a 115200-baud
//! line, and 5.6 kB/s down, just under half (docs/ground-station.md, "Link budget"). The packed forms keep
//! at full precision what the flight code's accuracy depends on and send the rest as IEEE 754 half
//! precision ([`F16`], 11 significant bits, a relative error of at most 2^-11):
//!
//! - a line edge keeps its centroid and its normal's angle as `f32` (the pose is as sensitive to them as to
//!   the pixels) and sends its spread and RMS residual, which only weight and bound it, as `F16`;
//! - a flow keeps its interval as a `u32` beside the later capture time, sends its statistics as `F16` (the
//!   flow's relative error of at most 2^-11 is 0.5 mm/s at 1 m/s), and leaves out what the vehicle can
//!   compute (the quality, inliers over selected features, computed the same way) or never uses (the raw
//!   median in pixels, which the station keeps in its own log);
//! - telemetry keeps position, velocity, attitude quaternion, rates and the position setpoint as `f32` and
//!   sends standard deviations, biases, wind, rotor speeds and the setpoint's velocity and acceleration as
//!   `F16`; the Euler angles are computed again from the quaternion.
//!
//! Unpacking is exact where packing kept `f32` (to the last bit, except the normal, rebuilt from its angle to
//! 2.5e-7); the vehicle and the simulator unpack with the same code, so they still compute the same bits.
use control_core::estimator::StateEstimate;
use control_core::laws::Setpoint;
use control_core::{Failsafe, FlightMode};
use geometry::frames::Attitude;
use geometry::{Quat, Vec2, Vec3};
use serde::{Deserialize, Serialize};
use vision_core::flow::{FlowStats, NoFlowReason};
use vision_core::{EdgeStats, LineObservation};

use crate::{FlowMeasurement, Telemetry, VisionMeasurement};

/// An IEEE 754 binary16 number as its two bytes, little endian (postcard writes a byte array as it is:
/// always 2 bytes on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct F16(pub [u8; 2]);

impl F16 {
    /// The nearest half-precision number (ties to even; beyond 65504 infinity, NaN stays NaN).
    pub fn from_f32(x: f32) -> Self {
        Self(half::f16::from_f32(x).to_le_bytes())
    }

    /// Its exact value as an `f32`.
    pub fn to_f32(self) -> f32 {
        half::f16::from_le_bytes(self.0).to_f32()
    }
}

fn pack<const N: usize>(v: [f32; N]) -> [F16; N] {
    v.map(F16::from_f32)
}

fn unpack<const N: usize>(v: [F16; N]) -> [f32; N] {
    v.map(F16::to_f32)
}

fn v2(v: [F16; 2]) -> Vec2 {
    let [x, y] = unpack(v);
    Vec2::new(x, y)
}

fn v3(v: [F16; 3]) -> Vec3 {
    let [x, y, z] = unpack(v);
    Vec3::new(x, y, z)
}

/// One edge of the line in 17-19 bytes (25-27 unpacked; the count is a varint).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PackedEdge {
    /// Centroid of the points (normalised coordinates), exact.
    pub centroid: Vec2,
    /// The angle of the best-fit line's unit normal, `atan2(n_y, n_x)` (rad).
    pub normal_angle_rad: f32,
    /// Number of points.
    pub count: u16,
    /// RMS spread of the points along the line (normalised units).
    pub spread: F16,
    /// RMS distance of the points from the line (normalised units).
    pub rms: F16,
}

impl PackedEdge {
    /// Packs an edge.
    pub fn pack(e: &EdgeStats) -> Self {
        Self {
            centroid: e.centroid,
            normal_angle_rad: libm::atan2f(e.normal.y, e.normal.x),
            count: e.count,
            spread: F16::from_f32(e.spread),
            rms: F16::from_f32(e.rms),
        }
    }

    /// The edge the vehicle uses.
    pub fn unpack(&self) -> EdgeStats {
        let (s, c) = geometry::trig::sin_cos(self.normal_angle_rad);
        EdgeStats {
            centroid: self.centroid,
            normal: Vec2::new(c, s),
            count: self.count,
            spread: self.spread.to_f32(),
            rms: self.rms.to_f32(),
        }
    }
}

/// A [`LineObservation`] with packed edges.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PackedLine {
    /// The upper long edge.
    pub top: PackedEdge,
    /// The lower long edge.
    pub bottom: PackedEdge,
    /// The short edge at the line's start, when in view.
    pub start_end: Option<PackedEdge>,
    /// The short edge at the line's finish, when in view.
    pub finish_end: Option<PackedEdge>,
}

/// A [`VisionMeasurement`] in fewer bytes (see the module's documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PackedVision {
    /// Capture time of the frame (mid-exposure, us).
    pub capture_time_us: u64,
    /// Frame counter of the camera.
    pub frame_seq: u32,
    /// The line's edges, or `None` when the frame had no line.
    pub observation: Option<PackedLine>,
}

impl PackedVision {
    /// Packs a measurement.
    pub fn pack(m: &VisionMeasurement) -> Self {
        Self {
            capture_time_us: m.capture_time_us,
            frame_seq: m.frame_seq,
            observation: m.observation.map(|o| PackedLine {
                top: PackedEdge::pack(&o.top),
                bottom: PackedEdge::pack(&o.bottom),
                start_end: o.start_end.as_ref().map(PackedEdge::pack),
                finish_end: o.finish_end.as_ref().map(PackedEdge::pack),
            }),
        }
    }

    /// The measurement the vehicle uses.
    pub fn unpack(&self) -> VisionMeasurement {
        VisionMeasurement {
            capture_time_us: self.capture_time_us,
            frame_seq: self.frame_seq,
            observation: self.observation.map(|o| LineObservation {
                top: o.top.unpack(),
                bottom: o.bottom.unpack(),
                start_end: o.start_end.as_ref().map(PackedEdge::unpack),
                finish_end: o.finish_end.as_ref().map(PackedEdge::unpack),
            }),
        }
    }
}

/// A flow's statistics in 24-28 bytes (58-62 unpacked; the two counts are varints).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PackedFlowStats {
    /// The derotated median flow (normalised).
    pub flow: [F16; 2],
    /// The camera rotation whose flow was removed (camera frame, rad).
    pub predicted_rotation: [F16; 3],
    /// Mean position of the inliers.
    pub mean_pos: [F16; 2],
    /// Means of x^2, y^2 and x y over the inliers.
    pub mean_sq: [F16; 3],
    /// Inlier tracks.
    pub inliers: u16,
    /// Features selected.
    pub selected: u16,
    /// RMS residual of the inliers about the affine fit (normalised units).
    pub residual_rms: F16,
}

/// A [`FlowMeasurement`] in fewer bytes (see the module's documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PackedFlow {
    /// Capture time of the later frame (mid-exposure, us).
    pub t_next_us: u64,
    /// From the earlier frame's capture to the later's (us); an earlier frame stamped after the later one
    /// packs as 0, which the flight code refuses as it refuses the unpacked pair.
    pub interval_us: u32,
    /// Frame counter of the later frame.
    pub frame_seq: u32,
    /// The flow's statistics, or why there was none.
    pub result: Result<PackedFlowStats, NoFlowReason>,
}

impl PackedFlow {
    /// Packs a measurement. An interval longer than `u32::MAX` us (71 minutes) saturates.
    pub fn pack(m: &FlowMeasurement) -> Self {
        let interval = m.t_next_us.saturating_sub(m.t_prev_us);
        Self {
            t_next_us: m.t_next_us,
            interval_us: u32::try_from(interval).unwrap_or(u32::MAX),
            frame_seq: m.frame_seq,
            result: m.result.map(|s| PackedFlowStats {
                flow: pack([s.flow.x, s.flow.y]),
                predicted_rotation: pack([
                    s.predicted_rotation.x,
                    s.predicted_rotation.y,
                    s.predicted_rotation.z,
                ]),
                mean_pos: pack([s.mean_pos.x, s.mean_pos.y]),
                mean_sq: pack(s.mean_sq),
                inliers: s.inliers,
                selected: s.selected,
                residual_rms: F16::from_f32(s.residual_rms),
            }),
        }
    }

    /// The measurement the vehicle uses. The quality is computed as the flow computes it; the raw median in
    /// pixels is not sent and unpacks as NaN.
    pub fn unpack(&self) -> FlowMeasurement {
        FlowMeasurement {
            t_prev_us: self.t_next_us.saturating_sub(u64::from(self.interval_us)),
            t_next_us: self.t_next_us,
            frame_seq: self.frame_seq,
            result: self.result.map(|s| FlowStats {
                flow: v2(s.flow),
                predicted_rotation: v3(s.predicted_rotation),
                mean_pos: v2(s.mean_pos),
                mean_sq: unpack(s.mean_sq),
                inliers: s.inliers,
                selected: s.selected,
                residual_rms: s.residual_rms.to_f32(),
                median_flow_px: Vec2::new(f32::NAN, f32::NAN),
                quality: f32::from(s.inliers) / f32::from(s.selected.max(1)),
            }),
        }
    }
}

/// [`Telemetry`] in fewer bytes (see the module's documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PackedTelemetry {
    /// Time of the control step (us).
    pub time_us: u64,
    /// The estimate's time less the step's (us), saturated to the `i32` range.
    pub estimate_offset_us: i32,
    /// Mode.
    pub mode: FlightMode,
    /// Active or last failsafe.
    pub failsafe: Option<Failsafe>,
    /// Position, world frame (m).
    pub position_m: Vec3,
    /// Velocity, world frame (m/s).
    pub velocity_m_s: Vec3,
    /// Attitude quaternion, world from body.
    pub q: Quat,
    /// Body angular rates, bias removed (rad/s).
    pub rates_rad_s: Vec3,
    /// Gyro bias (rad/s).
    pub gyro_bias_rad_s: [F16; 3],
    /// Accelerometer bias (m/s^2).
    pub accel_bias_m_s2: [F16; 3],
    /// The wind, world frame (m/s).
    pub wind_m_s: [F16; 3],
    /// Its standard deviation, world x and y (m/s).
    pub wind_std_m_s: [F16; 2],
    /// Position standard deviation (m).
    pub position_std_m: [F16; 3],
    /// Velocity standard deviation (m/s).
    pub velocity_std_m_s: [F16; 3],
    /// Roll and pitch standard deviation (rad).
    pub tilt_std_rad: F16,
    /// Yaw standard deviation (rad).
    pub yaw_std_rad: F16,
    /// The setpoint's position (m).
    pub setpoint_position_m: Vec3,
    /// The setpoint's velocity (m/s).
    pub setpoint_velocity_m_s: [F16; 3],
    /// The setpoint's acceleration (m/s^2).
    pub setpoint_accel_m_s2: [F16; 3],
    /// The setpoint's yaw from facing the wall (rad).
    pub setpoint_yaw_rad: f32,
    /// Rotor speed commands (rad/s).
    pub motors_rad_s: [F16; 4],
    /// Age of the last accepted vision fix (s).
    pub fix_age_s: F16,
    /// Cost of the last control step.
    pub step_cost: u32,
}

fn arr3(v: Vec3) -> [f32; 3] {
    [v.x, v.y, v.z]
}

impl PackedTelemetry {
    /// Packs telemetry.
    pub fn pack(t: &Telemetry) -> Self {
        let e = &t.estimate;
        let offset = e.time_us as i128 - t.time_us as i128;
        Self {
            time_us: t.time_us,
            estimate_offset_us: offset.clamp(i32::MIN as i128, i32::MAX as i128) as i32,
            mode: t.mode,
            failsafe: t.failsafe,
            position_m: e.position_m,
            velocity_m_s: e.velocity_m_s,
            q: e.q,
            rates_rad_s: e.rates_rad_s,
            gyro_bias_rad_s: pack(arr3(e.gyro_bias_rad_s)),
            accel_bias_m_s2: pack(arr3(e.accel_bias_m_s2)),
            wind_m_s: pack(arr3(e.wind_m_s)),
            wind_std_m_s: pack(e.wind_std_m_s),
            position_std_m: pack(arr3(e.position_std_m)),
            velocity_std_m_s: pack(arr3(e.velocity_std_m_s)),
            tilt_std_rad: F16::from_f32(e.tilt_std_rad),
            yaw_std_rad: F16::from_f32(e.yaw_std_rad),
            setpoint_position_m: t.setpoint.position_m,
            setpoint_velocity_m_s: pack(arr3(t.setpoint.velocity_m_s)),
            setpoint_accel_m_s2: pack(arr3(t.setpoint.accel_m_s2)),
            setpoint_yaw_rad: t.setpoint.yaw_rad,
            motors_rad_s: pack(t.motors_rad_s),
            fix_age_s: F16::from_f32(t.fix_age_s),
            step_cost: t.step_cost,
        }
    }

    /// The telemetry as the station uses it: the Euler angles computed from the quaternion.
    pub fn unpack(&self) -> Telemetry {
        let [ws, wy] = unpack(self.wind_std_m_s);
        Telemetry {
            time_us: self.time_us,
            mode: self.mode,
            failsafe: self.failsafe,
            estimate: StateEstimate {
                time_us: self.time_us.saturating_add_signed(i64::from(self.estimate_offset_us)),
                position_m: self.position_m,
                velocity_m_s: self.velocity_m_s,
                attitude: Attitude::from_world_from_body(&self.q.to_mat3()),
                q: self.q,
                rates_rad_s: self.rates_rad_s,
                gyro_bias_rad_s: v3(self.gyro_bias_rad_s),
                accel_bias_m_s2: v3(self.accel_bias_m_s2),
                wind_m_s: v3(self.wind_m_s),
                wind_std_m_s: [ws, wy],
                position_std_m: v3(self.position_std_m),
                velocity_std_m_s: v3(self.velocity_std_m_s),
                tilt_std_rad: self.tilt_std_rad.to_f32(),
                yaw_std_rad: self.yaw_std_rad.to_f32(),
            },
            setpoint: Setpoint {
                position_m: self.setpoint_position_m,
                velocity_m_s: v3(self.setpoint_velocity_m_s),
                accel_m_s2: v3(self.setpoint_accel_m_s2),
                yaw_rad: self.setpoint_yaw_rad,
            },
            motors_rad_s: unpack(self.motors_rad_s),
            fix_age_s: self.fix_age_s.to_f32(),
            step_cost: self.step_cost,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{MAX_FRAME, encode};
    use crate::{Downlink, Uplink};

    const HALF_REL: f32 = 1.0 / 2048.0; // 2^-11: half precision's relative rounding error

    fn frame_len<T: Serialize>(m: &T) -> usize {
        let mut out = [0u8; MAX_FRAME];
        encode(m, &mut out).unwrap().len()
    }

    fn close(a: f32, b: f32, rel: f32) -> bool {
        (a - b).abs() <= rel * b.abs() + 6.0e-8 // the smallest half subnormal
    }

    fn edge(cx: f32, cy: f32, angle: f32, count: u16) -> EdgeStats {
        EdgeStats {
            centroid: Vec2::new(cx, cy),
            normal: Vec2::new(libm::cosf(angle), libm::sinf(angle)),
            count,
            spread: 0.3456,
            rms: 0.001_23,
        }
    }

    fn vision() -> VisionMeasurement {
        VisionMeasurement {
            capture_time_us: 31_234_567,
            frame_seq: 937,
            observation: Some(LineObservation {
                top: edge(0.1234, -0.2345, 1.5587, 612),
                bottom: edge(0.1301, -0.1702, -1.5832, 598),
                start_end: Some(edge(-0.4123, -0.2031, 0.0123, 41)),
                finish_end: Some(edge(0.6123, -0.2011, 3.1301, 39)),
            }),
        }
    }

    fn flow() -> FlowMeasurement {
        let stats = FlowStats {
            flow: Vec2::new(-0.0123, 0.000_41),
            predicted_rotation: Vec3::new(0.001, -0.002, 0.0005),
            mean_pos: Vec2::new(0.01, -0.02),
            mean_sq: [0.09, 0.05, -0.001],
            inliers: 44,
            selected: 48,
            residual_rms: 0.0004,
            median_flow_px: Vec2::new(-1.7, 0.57),
            quality: 44.0 / 48.0,
        };
        FlowMeasurement { t_prev_us: 10_000_000, t_next_us: 10_016_667, frame_seq: 600, result: Ok(stats) }
    }

    #[test]
    fn half_precision_bytes_are_ieee_binary16() {
        // Pinned: 1.0 is 0x3C00, -2.0 is 0xC000, 65504 the largest finite, little endian.
        assert_eq!(F16::from_f32(1.0).0, [0x00, 0x3C]);
        assert_eq!(F16::from_f32(-2.0).0, [0x00, 0xC0]);
        assert_eq!(F16::from_f32(65504.0).0, [0xFF, 0x7B]);
        assert_eq!(F16::from_f32(1.0e6).to_f32(), f32::INFINITY);
        assert!(F16::from_f32(f32::NAN).to_f32().is_nan());
        // Ties to even: 1 + 2^-11 lies halfway between 1 and 1 + 2^-10.
        assert_eq!(F16::from_f32(1.0 + 1.0 / 2048.0).to_f32(), 1.0);
        // On the wire, always two bytes (no varint).
        let mut b = [0u8; 8];
        assert_eq!(postcard::to_slice(&F16::from_f32(-2.0), &mut b).unwrap(), [0x00, 0xC0]);
    }

    #[test]
    fn a_line_measurement_keeps_its_geometry_exactly_and_takes_fewer_bytes() {
        let m = vision();
        let u = PackedVision::pack(&m).unpack();
        assert_eq!(u.capture_time_us, m.capture_time_us);
        assert_eq!(u.frame_seq, m.frame_seq);
        let (a, b) = (m.observation.unwrap(), u.observation.unwrap());
        let pairs = [
            (a.top, b.top),
            (a.bottom, b.bottom),
            (a.start_end.unwrap(), b.start_end.unwrap()),
            (a.finish_end.unwrap(), b.finish_end.unwrap()),
        ];
        for (x, y) in pairs {
            assert_eq!(x.centroid, y.centroid);
            assert_eq!(x.count, y.count);
            // The normal rebuilt from its angle: 2.5e-7 (the sine's error) plus the angle's rounding.
            assert!((x.normal - y.normal).norm() < 4.0e-7, "{:?} {:?}", x.normal, y.normal);
            assert!(close(y.spread, x.spread, HALF_REL) && close(y.rms, x.rms, HALF_REL), "{x:?} {y:?}");
            assert!(y.spread != x.spread, "the spread goes as half precision");
        }
        let (full, packed) =
            (frame_len(&Uplink::Vision(m)), frame_len(&Uplink::PackedVision(PackedVision::pack(&m))));
        // Four edges: 26 bytes each unpacked, 18 packed.
        assert_eq!(full - packed, 4 * 8, "{full} -> {packed} bytes");
        let none = VisionMeasurement { observation: None, ..m };
        assert_eq!(PackedVision::pack(&none).unpack(), none);
    }

    #[test]
    fn a_flow_keeps_its_times_and_quality_exactly_and_its_statistics_to_half_precision() {
        let m = flow();
        let u = PackedFlow::pack(&m).unpack();
        assert_eq!((u.t_prev_us, u.t_next_us, u.frame_seq), (m.t_prev_us, m.t_next_us, m.frame_seq));
        let (a, b) = (m.result.unwrap(), u.result.unwrap());
        assert_eq!((b.inliers, b.selected), (a.inliers, a.selected));
        // The quality as the flow computes it (inliers over selected), to the bit.
        assert_eq!(b.quality.to_bits(), a.quality.to_bits());
        let fields = [
            (a.flow.x, b.flow.x),
            (a.flow.y, b.flow.y),
            (a.predicted_rotation.x, b.predicted_rotation.x),
            (a.predicted_rotation.y, b.predicted_rotation.y),
            (a.predicted_rotation.z, b.predicted_rotation.z),
            (a.mean_pos.x, b.mean_pos.x),
            (a.mean_pos.y, b.mean_pos.y),
            (a.mean_sq[0], b.mean_sq[0]),
            (a.mean_sq[1], b.mean_sq[1]),
            (a.mean_sq[2], b.mean_sq[2]),
            (a.residual_rms, b.residual_rms),
        ];
        for (i, (x, y)) in fields.into_iter().enumerate() {
            assert!(close(y, x, HALF_REL), "field {i}: {x} -> {y}");
        }
        assert!(b.median_flow_px.x.is_nan() && b.median_flow_px.y.is_nan());
        let (full, packed) =
            (frame_len(&Uplink::Flow(m)), frame_len(&Uplink::PackedFlow(PackedFlow::pack(&m))));
        assert!(packed <= 48 && packed * 3 <= full * 2, "{full} -> {packed} bytes");
        // No flow: the reason goes through.
        let none = FlowMeasurement { result: Err(NoFlowReason::NoTexture), ..m };
        assert_eq!(PackedFlow::pack(&none).unpack(), none);
        // A pair stamped backwards packs as an empty interval; a 2-hour one saturates.
        let back = FlowMeasurement { t_prev_us: m.t_next_us + 5, ..none };
        assert_eq!(PackedFlow::pack(&back).interval_us, 0);
        let long = FlowMeasurement { t_prev_us: 0, t_next_us: 7_200_000_000, ..none };
        assert_eq!(PackedFlow::pack(&long).interval_us, u32::MAX);
    }

    #[test]
    fn telemetry_keeps_the_state_exactly_and_the_uncertainties_to_half_precision() {
        let q = Quat::from_rotvec(Vec3::new(0.05, -0.03, 0.2));
        let e = StateEstimate {
            time_us: 12_345_000,
            position_m: Vec3::new(0.2, -1.5, 0.81),
            velocity_m_s: Vec3::new(0.01, 0.3, -0.02),
            attitude: Attitude::from_world_from_body(&q.to_mat3()),
            q,
            rates_rad_s: Vec3::new(0.01, -0.02, 0.003),
            gyro_bias_rad_s: Vec3::new(0.001, -0.002, 0.0004),
            accel_bias_m_s2: Vec3::new(0.05, -0.02, 0.1),
            wind_m_s: Vec3::new(0.5, -0.2, 0.0),
            wind_std_m_s: [0.3, 0.31],
            position_std_m: Vec3::new(0.01, 0.02, 0.005),
            velocity_std_m_s: Vec3::new(0.03, 0.03, 0.01),
            tilt_std_rad: 0.004,
            yaw_std_rad: 0.02,
        };
        let t = Telemetry {
            time_us: 12_345_000,
            mode: FlightMode::Tracking,
            failsafe: None,
            estimate: e,
            setpoint: Setpoint {
                position_m: Vec3::new(0.2, -1.4, 0.8),
                velocity_m_s: Vec3::new(0.0, 0.25, 0.0),
                accel_m_s2: Vec3::new(0.0, 0.1, 0.0),
                yaw_rad: 0.0,
            },
            motors_rad_s: [812.5, 799.1, 805.0, 820.3],
            fix_age_s: 0.021,
            step_cost: 41_234,
        };
        let u = PackedTelemetry::pack(&t).unpack();
        let (a, b) = (&t.estimate, &u.estimate);
        assert_eq!(
            (u.time_us, u.mode, u.failsafe, u.step_cost),
            (t.time_us, t.mode, t.failsafe, t.step_cost)
        );
        assert_eq!(
            (b.time_us, b.position_m, b.velocity_m_s, b.q, b.rates_rad_s),
            (a.time_us, a.position_m, a.velocity_m_s, a.q, a.rates_rad_s)
        );
        assert_eq!((u.setpoint.position_m, u.setpoint.yaw_rad), (t.setpoint.position_m, t.setpoint.yaw_rad));
        assert_eq!(b.attitude, a.attitude, "the Euler angles from the same quaternion");
        let halves = [
            (a.gyro_bias_rad_s, b.gyro_bias_rad_s),
            (a.accel_bias_m_s2, b.accel_bias_m_s2),
            (a.wind_m_s, b.wind_m_s),
            (a.position_std_m, b.position_std_m),
            (a.velocity_std_m_s, b.velocity_std_m_s),
            (t.setpoint.velocity_m_s, u.setpoint.velocity_m_s),
            (t.setpoint.accel_m_s2, u.setpoint.accel_m_s2),
        ];
        for (x, y) in halves {
            for (p, q) in arr3(x).into_iter().zip(arr3(y)) {
                assert!(close(q, p, HALF_REL), "{x:?} -> {y:?}");
            }
        }
        for (p, q) in t.motors_rad_s.into_iter().zip(u.motors_rad_s) {
            assert!(close(q, p, HALF_REL), "{p} -> {q}");
        }
        assert!(close(u.fix_age_s, t.fix_age_s, HALF_REL) && close(b.tilt_std_rad, a.tilt_std_rad, HALF_REL));
        // An estimate older than its step keeps its time.
        let old = Telemetry { estimate: StateEstimate { time_us: 12_340_000, ..e }, ..t };
        assert_eq!(PackedTelemetry::pack(&old).unpack().estimate.time_us, 12_340_000);
        let (full, packed) = (
            frame_len(&Downlink::Telemetry(t)),
            frame_len(&Downlink::PackedTelemetry(PackedTelemetry::pack(&t))),
        );
        assert!(packed * 10 <= full * 7, "{full} -> {packed} bytes");
        assert_eq!(Downlink::PackedTelemetry(PackedTelemetry::pack(&t)).telemetry(), Some(u));
    }

    #[test]
    fn the_messages_unpack_through_one_accessor() {
        let (v, f) = (vision(), flow());
        assert_eq!(Uplink::Vision(v).vision(), Some(v));
        assert_eq!(
            Uplink::PackedVision(PackedVision::pack(&v)).vision(),
            Some(PackedVision::pack(&v).unpack())
        );
        assert_eq!(Uplink::Flow(f).flow(), Some(f));
        assert_eq!(Uplink::PackedFlow(PackedFlow::pack(&f)).flow().map(|m| m.t_prev_us), Some(f.t_prev_us));
        assert_eq!(Uplink::Heartbeat.vision(), None);
        assert_eq!(Uplink::Vision(v).flow(), None);
    }
}

#[cfg(test)]
mod golden {
    use super::*;
    use crate::Uplink;
    use crate::frame::{MAX_FRAME, WIRE_VERSION, crc16, encode};

    fn frame_of(m: &Uplink) -> std::vec::Vec<u8> {
        let mut out = [0u8; MAX_FRAME];
        encode(m, &mut out).unwrap().to_vec()
    }

    #[test]
    fn golden_bytes_of_the_packed_messages() {
        // Pinned: changing these bytes is a wire-format change (docs/log-format.md, "Packed messages").
        // A flow without a result: Uplink variant 8, t_next 1000 (E8 07), interval 16667 (9B 82 01), frame 3,
        // Err (1), NoTexture (1).
        let none = PackedFlow {
            t_next_us: 1000,
            interval_us: 16_667,
            frame_seq: 3,
            result: Err(NoFlowReason::NoTexture),
        };
        let body = [WIRE_VERSION, 8, 0xE8, 0x07, 0x9B, 0x82, 0x01, 0x03, 0x01, 0x01];
        assert_eq!(crc16(&body), 0xB785);
        assert_eq!(
            frame_of(&Uplink::PackedFlow(none)),
            [0x0D, 0x01, 0x08, 0xE8, 0x07, 0x9B, 0x82, 0x01, 0x03, 0x01, 0x01, 0x85, 0xB7, 0x00]
        );
        // The appended reason (log format 9): a repeating floor, RepeatingTexture (4).
        let repeating = PackedFlow { result: Err(NoFlowReason::RepeatingTexture), ..none };
        let body = [WIRE_VERSION, 8, 0xE8, 0x07, 0x9B, 0x82, 0x01, 0x03, 0x01, 0x04];
        assert_eq!(crc16(&body), 0xE720);
        assert_eq!(
            frame_of(&Uplink::PackedFlow(repeating)),
            [0x0D, 0x01, 0x08, 0xE8, 0x07, 0x9B, 0x82, 0x01, 0x03, 0x01, 0x04, 0x20, 0xE7, 0x00]
        );
        // An edge: centroid (0.5, -0.25) as two f32, normal angle 0 (f32), 100 points, spread 1.0 and RMS 0.5
        // as half precision (00 3C, 00 38).
        let e = PackedEdge::pack(&EdgeStats {
            centroid: Vec2::new(0.5, -0.25),
            normal: Vec2::new(1.0, 0.0),
            count: 100,
            spread: 1.0,
            rms: 0.5,
        });
        let mut b = [0u8; 32];
        let got = postcard::to_slice(&e, &mut b).unwrap();
        assert_eq!(
            got,
            [
                0x00, 0x00, 0x00, 0x3F, 0x00, 0x00, 0x80, 0xBE, 0x00, 0x00, 0x00, 0x00, 0x64, 0x00, 0x3C,
                0x00, 0x38
            ]
        );
    }
}
