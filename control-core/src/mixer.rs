//! Mixer: thrust and torques to rotor speeds ("+" configuration, paper section 3).
//!
//! `T = k sum w_i^2`, `tau_x = l k (w2^2 - w4^2)`, `tau_y = l k (w3^2 - w1^2)`,
//! `tau_z = k_tau (w1^2 + w3^2 - w2^2 - w4^2)` with M1 front, M2 left, M3 rear, M4 right; M1 and M3 spin
//! clockwise seen from above, M2 and M4 counter-clockwise. Within the motor limits roll and pitch come first,
//! then thrust, then yaw: yaw torque is reduced first, roll and pitch torques are scaled down only when they
//! alone cannot fit, and the thrust gives way to keep them.
use crate::laws::Demand;
use crate::params::VehicleParams;

/// Spin of each rotor: +1 counter-clockwise seen from above (angular momentum along +z body), -1 clockwise.
pub const SPIN: [f32; 4] = [-1.0, 1.0, -1.0, 1.0];

/// `sum_i SPIN_i w_i`: the rotors' net angular momentum divided by `I_M` (rad/s).
pub fn signed_rotor_sum(w: [f32; 4]) -> f32 {
    SPIN[0] * w[0] + SPIN[1] * w[1] + SPIN[2] * w[2] + SPIN[3] * w[3]
}

/// Rotor speed commands and what had to give.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MixerOutput {
    /// Commanded rotor speeds M1..M4 (rad/s).
    pub speeds_rad_s: [f32; 4],
    /// The yaw torque was reduced.
    pub yaw_limited: bool,
    /// Roll and pitch torques were scaled down.
    pub tilt_limited: bool,
    /// The thrust was changed to fit the limits.
    pub thrust_limited: bool,
}

/// Rotor speeds for a thrust and torque demand.
pub fn mix(d: &Demand, v: &VehicleParams) -> MixerOutput {
    let k = v.thrust_coeff;
    let kq = v.drag_torque_coeff;
    let l = v.arm_length_m;
    let s_min = v.motor_speed_min_rad_s * v.motor_speed_min_rad_s;
    let s_max = v.motor_speed_max_rad_s * v.motor_speed_max_rad_s;
    let finite = |x: f32| if x.is_finite() { x } else { 0.0 };
    let t = finite(d.thrust_n) / k;
    let mut tx = finite(d.torque_nm.x) / (l * k);
    let mut ty = finite(d.torque_nm.y) / (l * k);
    let mut tz = finite(d.torque_nm.z) / kq;
    let offsets = |tx: f32, ty: f32, tz: f32| {
        [0.25 * tz - 0.5 * ty, -0.25 * tz + 0.5 * tx, 0.25 * tz + 0.5 * ty, -0.25 * tz - 0.5 * tx]
    };
    let spread = |c: [f32; 4]| {
        let (mut lo, mut hi) = (c[0], c[0]);
        for &x in &c[1..] {
            lo = lo.min(x);
            hi = hi.max(x);
        }
        (lo, hi)
    };
    let room = s_max - s_min;
    let mut out = MixerOutput::default();
    let (lo, hi) = spread(offsets(tx, ty, tz));
    if hi - lo > room {
        // Drop yaw as far as needed (at most entirely).
        let (lo0, hi0) = spread(offsets(tx, ty, 0.0));
        out.yaw_limited = true;
        if hi0 - lo0 > room {
            tz = 0.0;
            let scale = room / (hi0 - lo0);
            tx *= scale;
            ty *= scale;
            out.tilt_limited = true;
        } else {
            // Bisection on the yaw fraction that still fits.
            let (mut a, mut b) = (0.0f32, 1.0f32);
            for _ in 0..20 {
                let m = 0.5 * (a + b);
                let (l2, h2) = spread(offsets(tx, ty, tz * m));
                if h2 - l2 <= room { a = m } else { b = m }
            }
            tz *= a;
        }
    }
    let c = offsets(tx, ty, tz);
    let (lo, hi) = spread(c);
    // Mean rotor speed^2 within what keeps every rotor inside its limits.
    let mean_lo = s_min - lo;
    let mean_hi = s_max - hi;
    let mut mean = 0.25 * t;
    if mean < mean_lo {
        mean = mean_lo;
        out.thrust_limited = true;
    }
    if mean > mean_hi {
        mean = mean_hi;
        out.thrust_limited = true;
    }
    for i in 0..4 {
        // `clamp_finite`, not `f32::clamp`: no panic path (its assert on the bounds, with the float formatting
        // it brings into the firmware), and a NaN gives the lower bound.
        let s = geometry::clamp_finite(mean + c[i], s_min, s_max);
        out.speeds_rad_s[i] = libm::sqrtf(s);
    }
    out
}

/// Thrust and torques produced by rotor speeds (the inverse of [`mix`] within the limits).
pub fn forces(w: [f32; 4], v: &VehicleParams) -> Demand {
    let s = w.map(|x| x * x);
    let (k, kq, l) = (v.thrust_coeff, v.drag_torque_coeff, v.arm_length_m);
    Demand {
        thrust_n: k * (s[0] + s[1] + s[2] + s[3]),
        torque_nm: geometry::Vec3::new(
            l * k * (s[1] - s[3]),
            l * k * (s[2] - s[0]),
            kq * (s[0] + s[2] - s[1] - s[3]),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::GRAVITY;
    use geometry::Vec3;

    #[test]
    fn mix_then_forces_round_trip() {
        let v = VehicleParams::default();
        let d = Demand { thrust_n: 0.38 * GRAVITY * 1.1, torque_nm: Vec3::new(0.02, -0.03, 0.004) };
        let m = mix(&d, &v);
        assert!(!m.yaw_limited && !m.tilt_limited && !m.thrust_limited);
        let f = forces(m.speeds_rad_s, &v);
        assert!((f.thrust_n - d.thrust_n).abs() < 1e-3);
        assert!((f.torque_nm - d.torque_nm).norm() < 1e-5, "{:?}", f.torque_nm);
    }

    #[test]
    fn hover_is_equal_speeds() {
        let v = VehicleParams::default();
        let m = mix(&Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: Vec3::ZERO }, &v);
        for w in m.speeds_rad_s {
            assert!((w - v.hover_speed_rad_s()).abs() < 0.05);
        }
    }

    #[test]
    fn limits_keep_roll_and_pitch_first() {
        let v = VehicleParams::default();
        // Huge yaw demand with a moderate pitch demand: yaw gives way, pitch is kept.
        let d = Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: Vec3::new(0.0, 0.1, 1.0) };
        let m = mix(&d, &v);
        assert!(m.yaw_limited && !m.tilt_limited);
        let f = forces(m.speeds_rad_s, &v);
        assert!((f.torque_nm.y - 0.1).abs() < 1e-4);
        for w in m.speeds_rad_s {
            assert!(w >= v.motor_speed_min_rad_s - 1e-3 && w <= v.motor_speed_max_rad_s + 1e-3);
        }
        // Impossible roll demand: scaled, direction kept, rotors within limits.
        let d = Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: Vec3::new(5.0, 0.0, 0.0) };
        let m = mix(&d, &v);
        assert!(m.tilt_limited);
        let f = forces(m.speeds_rad_s, &v);
        assert!(f.torque_nm.x > 0.3);
        // Non-finite demand: idle-safe output.
        let m = mix(&Demand { thrust_n: f32::NAN, torque_nm: Vec3::ZERO }, &v);
        assert!(m.speeds_rad_s.iter().all(|w| w.is_finite()));
    }

    #[test]
    fn yaw_sign_matches_the_paper() {
        // tau_psi = k_tau (w1^2 + w3^2 - w2^2 - w4^2): front/rear faster gives positive yaw torque.
        let v = VehicleParams::default();
        let f = forces([600.0, 500.0, 600.0, 500.0], &v);
        assert!(f.torque_nm.z > 0.0);
        assert!(signed_rotor_sum([600.0, 500.0, 600.0, 500.0]) < 0.0);
    }

    #[test]
    fn the_signed_rotor_sum_weighs_each_rotor_by_its_spin() {
        // M1 and M3 clockwise (-1), M2 and M4 counter-clockwise (+1).
        assert_eq!(signed_rotor_sum([1.0, 2.0, 3.0, 5.0]), -1.0 + 2.0 - 3.0 + 5.0);
        assert_eq!(signed_rotor_sum([7.0, 0.0, 0.0, 0.0]), -7.0);
        assert_eq!(signed_rotor_sum([0.0, 0.0, 0.0, 11.0]), 11.0);
    }

    /// The rotor speeds squared, their spread, and the room the limits leave.
    fn spread_and_room(m: &MixerOutput, v: &VehicleParams) -> (f32, f32, f32) {
        let s = m.speeds_rad_s.map(|w| w * w);
        let lo = s.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = s.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let room = v.motor_speed_max_rad_s.powi(2) - v.motor_speed_min_rad_s.powi(2);
        (lo, hi, room)
    }

    #[test]
    fn yaw_gives_way_exactly_as_far_as_needed() {
        // Pitch that fits with room to spare, and a yaw that does not: the yaw kept is the largest that fits
        // (the rotors then span exactly the limits' room, which leaves the thrust one value), the pitch is
        // kept whole.
        let v = VehicleParams::default();
        let d = Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: Vec3::new(0.0, 0.05, 0.5) };
        let m = mix(&d, &v);
        assert!(m.yaw_limited && !m.tilt_limited && m.thrust_limited, "{m:?}");
        let f = forces(m.speeds_rad_s, &v);
        assert!((f.torque_nm.y - 0.05).abs() < 1e-4, "{:?}", f.torque_nm);
        assert!(f.torque_nm.x.abs() < 1e-4);
        assert!(f.torque_nm.z > 0.0 && f.torque_nm.z < 0.5, "{:?}", f.torque_nm);
        let (lo, hi, room) = spread_and_room(&m, &v);
        assert!((hi - lo - room).abs() < 1e-3 * room, "spread {} of room {room}", hi - lo);
        // With pitch alone beside it the rotors span (|tau_z| / k_tau + |tau_y| / (l k)) / 2: the largest yaw
        // is k_tau (2 room - |tau_y| / (l k)).
        let yaw_max = v.drag_torque_coeff * (2.0 * room - 0.05 / (v.arm_length_m * v.thrust_coeff));
        assert!((f.torque_nm.z - yaw_max).abs() < 1e-3 * yaw_max, "yaw {} of {yaw_max}", f.torque_nm.z);
        // Roll and pitch together with too much yaw: both kept whole (a yaw left too large would be cut by the
        // rotors' limits, and roll with it).
        let d = Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: Vec3::new(0.03, 0.05, 0.5) };
        let m = mix(&d, &v);
        assert!(m.yaw_limited && !m.tilt_limited, "{m:?}");
        let f = forces(m.speeds_rad_s, &v);
        assert!(
            (f.torque_nm.x - 0.03).abs() < 1e-4 && (f.torque_nm.y - 0.05).abs() < 1e-4,
            "{:?}",
            f.torque_nm
        );
        assert!(f.torque_nm.z > 0.0 && f.torque_nm.z < 0.5, "{:?}", f.torque_nm);
        // The same yaw alone fits: nothing gives way.
        let m = mix(&Demand { thrust_n: d.thrust_n, torque_nm: Vec3::new(0.0, 0.0, 0.01) }, &v);
        assert!(!m.yaw_limited);
        assert!((forces(m.speeds_rad_s, &v).torque_nm.z - 0.01).abs() < 1e-5);
    }

    #[test]
    fn roll_and_pitch_too_large_are_scaled_together_to_the_limits() {
        let v = VehicleParams::default();
        let d = Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: Vec3::new(4.0, -2.0, 0.3) };
        let m = mix(&d, &v);
        assert!(m.yaw_limited && m.tilt_limited, "{m:?}");
        let f = forces(m.speeds_rad_s, &v);
        // Direction kept (x = -2 y), yaw dropped, the rotors spanning the whole room.
        assert!(
            (f.torque_nm.x + 2.0 * f.torque_nm.y).abs() < 1e-3 * f.torque_nm.x.abs(),
            "{:?}",
            f.torque_nm
        );
        assert!(f.torque_nm.x > 0.1 && f.torque_nm.x < 4.0);
        assert!(f.torque_nm.z.abs() < 1e-4, "{:?}", f.torque_nm);
        let (lo, hi, room) = spread_and_room(&m, &v);
        assert!((hi - lo - room).abs() < 1e-3 * room, "spread {} of room {room}", hi - lo);
    }

    #[test]
    fn the_thrust_gives_way_to_keep_the_torques_at_both_limits() {
        let v = VehicleParams::default();
        let tau = Vec3::new(0.02, -0.01, 0.002);
        let (lo_lim, hi_lim) = (v.motor_speed_min_rad_s.powi(2), v.motor_speed_max_rad_s.powi(2));
        // Far more thrust than the rotors give: the fastest rotor at its limit, torques whole.
        let m = mix(&Demand { thrust_n: 100.0, torque_nm: tau }, &v);
        assert!(m.thrust_limited && !m.yaw_limited && !m.tilt_limited, "{m:?}");
        let (_, hi, _) = spread_and_room(&m, &v);
        assert!((hi - hi_lim).abs() < 1e-3 * hi_lim, "fastest {hi} of {hi_lim}");
        assert!((forces(m.speeds_rad_s, &v).torque_nm - tau).norm() < 1e-4);
        // No thrust asked: the slowest rotor at idle, torques whole.
        let m = mix(&Demand { thrust_n: 0.0, torque_nm: tau }, &v);
        assert!(m.thrust_limited, "{m:?}");
        let (lo, _, _) = spread_and_room(&m, &v);
        assert!((lo - lo_lim).abs() < 1e-3 * hi_lim, "slowest {lo} of {lo_lim}");
        assert!((forces(m.speeds_rad_s, &v).torque_nm - tau).norm() < 1e-4);
        // A thrust within the limits is not touched.
        let m = mix(&Demand { thrust_n: v.mass_kg * GRAVITY, torque_nm: tau }, &v);
        assert!(!m.thrust_limited);
    }
}
