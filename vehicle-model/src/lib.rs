//! The quadrotor's Newton-Euler model (paper section 3, eq. 15-22), in f64, integrated by RK4.
//!
//! State: position and velocity (world), attitude quaternion (world from body), body angular velocity, and
//! the four rotor speeds. Forces and torques:
//!
//! - thrust `f_i = k w_i^2` along body z, optionally raised near the floor by the ground effect
//!   (Cheeseman and Bennett, "The effect of the ground on a helicopter rotor in forward flight", ARC R&M
//!   3021, 1955: `T / T_inf = 1 / (1 - (R / 4z)^2)`, capped at 1.5);
//! - rotor drag: the rotors' induced drag perpendicular to their axis, proportional to the air-relative
//!   velocity in the rotor plane and to the sum of the rotor speeds, `F = -c (sum w_i) v_air,xy` in the body
//!   frame (the standard quadrotor drag model: Martin and Salaun, "The true role of accelerometer feedback in
//!   quadrotor control", ICRA 2010; Leishman et al., IEEE Control Systems Magazine 2014); with the default
//!   `c` the drag is 0.3 m/s^2 per m/s at hover; an optional linear translational drag (both off in the
//!   paper's model);
//! - wind: the air moves with a world velocity given at each step; the drag terms see the air-relative
//!   velocity;
//! - roll and pitch torques from the thrust differences: `tau_x = l k (w2^2 - w4^2)`,
//!   `tau_y = l k (w3^2 - w1^2)` (M1 front, M2 left, M3 rear, M4 right);
//! - yaw: the reaction of each motor's torque on its rotor, `-s_i (k_tau w_i^2 + I_M w_i')` about body z,
//!   with the spin signs `s_i` (M1, M3 clockwise seen from above, M2, M4 counter-clockwise);
//! - the rotors' gyroscopic torque `-Omega x h`, `h = I_M sum_i s_i w_i z_B` (the paper's sum, signed by the
//!   spin directions);
//! - first-order motors: `w_i' = (w_cmd,i - w_i) / tau_m`, commands clamped to the motor limits.
//!
//! `J Omega' = tau - Omega x J Omega` (eq. 21). A simple ground contact holds the vehicle on the floor while
//! the thrust is below its weight.
// Indexing by rotor and axis mirrors the equations.
#![allow(clippy::needless_range_loop)]
#![warn(missing_docs)]

pub mod battery;

use control_core::mixer::SPIN;
use control_core::params::VehicleParams;

/// 3-vector of f64.
pub type V3 = [f64; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Rotation matrix (rows) of a unit quaternion `[w, x, y, z]`.
pub fn quat_to_mat(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

fn mat_vec(m: &[[f64; 3]; 3], v: V3) -> V3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

fn mat_t_vec(m: &[[f64; 3]; 3], v: V3) -> V3 {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

/// Physical parameters of the model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelParams {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Arm length (m).
    pub arm_m: f64,
    /// Principal inertia (kg m^2).
    pub inertia: V3,
    /// Thrust coefficient (N s^2).
    pub k: f64,
    /// Drag-torque coefficient (N m s^2).
    pub k_tau: f64,
    /// Rotor inertia (kg m^2).
    pub rotor_inertia: f64,
    /// Motor time constant (s).
    pub motor_tau_s: f64,
    /// Rotor speed limits (rad/s).
    pub motor_limits: [f64; 2],
    /// Linear translational drag (N per m/s); 0 in the paper.
    pub linear_drag: f64,
    /// Rotor drag coefficient `c` (N per (m/s) per (rad/s) of the rotor speed sum); 0 in the paper.
    pub rotor_drag: f64,
    /// Rotor radius for the ground effect (m); `None` turns the ground effect off.
    pub ground_effect_rotor_radius_m: Option<f64>,
    /// Each rotor's thrust and drag torque relative to the nominal (a damaged or stopped rotor: below 1).
    pub rotor_scale: [f64; 4],
    /// Gravity (m/s^2).
    pub gravity: f64,
    /// Height of the centre of mass when resting on the floor (m); `None` disables the floor.
    pub ground_height_m: Option<f64>,
}

impl ModelParams {
    /// From the flight code's vehicle parameters plus the model-only ones.
    pub fn from_vehicle(
        v: &VehicleParams,
        motor_tau_s: f64,
        linear_drag: f64,
        ground_height_m: Option<f64>,
    ) -> Self {
        Self {
            mass_kg: v.mass_kg as f64,
            arm_m: v.arm_length_m as f64,
            inertia: v.inertia_kg_m2.map(|x| x as f64),
            k: v.thrust_coeff as f64,
            k_tau: v.drag_torque_coeff as f64,
            rotor_inertia: v.rotor_inertia_kg_m2 as f64,
            motor_tau_s,
            motor_limits: [0.0, v.motor_speed_max_rad_s as f64],
            linear_drag,
            rotor_drag: 0.0,
            ground_effect_rotor_radius_m: None,
            rotor_scale: [1.0; 4],
            gravity: control_core::GRAVITY as f64,
            ground_height_m,
        }
    }

    /// Rotor speed that holds the weight (rad/s).
    pub fn hover_speed(&self) -> f64 {
        (self.mass_kg * self.gravity / (4.0 * self.k)).sqrt()
    }
}

/// The model's state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct State {
    /// Position, world (m).
    pub p: V3,
    /// Velocity, world (m/s).
    pub v: V3,
    /// Attitude `[w, x, y, z]`, world from body.
    pub q: [f64; 4],
    /// Body angular velocity (rad/s).
    pub w: V3,
    /// Rotor speeds (rad/s).
    pub rotors: [f64; 4],
}

/// Time derivative of the state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deriv {
    /// Velocity.
    pub dp: V3,
    /// Acceleration (world).
    pub dv: V3,
    /// Quaternion rate.
    pub dq: [f64; 4],
    /// Angular acceleration (body).
    pub dw: V3,
    /// Rotor accelerations.
    pub drotors: [f64; 4],
}

/// Thrust (N) and body torques (N m) of the rotors alone (no gyroscopic or reaction terms).
pub fn rotor_wrench(par: &ModelParams, rotors: [f64; 4]) -> (f64, V3) {
    let mut s = rotors.map(|w| w * w);
    for i in 0..4 {
        s[i] *= par.rotor_scale[i];
    }
    let t = par.k * (s[0] + s[1] + s[2] + s[3]);
    let tau = [
        par.arm_m * par.k * (s[1] - s[3]),
        par.arm_m * par.k * (s[2] - s[0]),
        -(0..4).map(|i| SPIN[i] as f64 * par.k_tau * s[i]).sum::<f64>(),
    ];
    (t, tau)
}

/// The ground effect's thrust factor at a height of the rotors above the floor.
pub fn ground_effect_factor(par: &ModelParams, height_m: f64) -> f64 {
    match (par.ground_effect_rotor_radius_m, par.ground_height_m) {
        (Some(r), Some(_)) => {
            // The rotors sit at about the centre of mass's height.
            let x = r / (4.0 * height_m.max(0.01));
            if x >= 0.8 { 1.5 } else { (1.0 / (1.0 - x * x)).min(1.5) }
        }
        _ => 1.0,
    }
}

/// The state derivative for commanded rotor speeds `cmd` in still air.
pub fn derivative(par: &ModelParams, s: &State, cmd: [f64; 4]) -> Deriv {
    derivative_in_wind(par, s, cmd, [0.0; 3])
}

/// The state derivative for commanded rotor speeds `cmd` in air moving at `wind` (world, m/s).
pub fn derivative_in_wind(par: &ModelParams, s: &State, cmd: [f64; 4], wind: V3) -> Deriv {
    let mut drotors = [0.0; 4];
    for i in 0..4 {
        let c = cmd[i].clamp(par.motor_limits[0], par.motor_limits[1]);
        drotors[i] = (c - s.rotors[i]) / par.motor_tau_s;
    }
    let (thrust, mut tau) = rotor_wrench(par, s.rotors);
    // Reaction of the motors accelerating their rotors, and the rotors' gyroscopic torque.
    let h_sum: f64 = (0..4).map(|i| SPIN[i] as f64 * s.rotors[i]).sum();
    let dh_sum: f64 = (0..4).map(|i| SPIN[i] as f64 * drotors[i]).sum();
    tau[2] -= par.rotor_inertia * dh_sum;
    let h = [0.0, 0.0, par.rotor_inertia * h_sum];
    tau = add(tau, scale(cross(s.w, h), -1.0));
    let r = quat_to_mat(s.q);
    let thrust = thrust * ground_effect_factor(par, s.p[2]);
    let v_air = add(s.v, scale(wind, -1.0));
    let v_air_b = mat_t_vec(&r, v_air);
    let sum_w: f64 = s.rotors.iter().map(|w| w.abs()).sum();
    let drag_b = [-par.rotor_drag * sum_w * v_air_b[0], -par.rotor_drag * sum_w * v_air_b[1], 0.0];
    let f_body = add([0.0, 0.0, thrust], drag_b);
    let f_world = add(mat_vec(&r, f_body), scale(v_air, -par.linear_drag));
    let dv = add(scale(f_world, 1.0 / par.mass_kg), [0.0, 0.0, -par.gravity]);
    let j = par.inertia;
    let jw = [j[0] * s.w[0], j[1] * s.w[1], j[2] * s.w[2]];
    let rhs = add(tau, scale(cross(s.w, jw), -1.0));
    let dw = [rhs[0] / j[0], rhs[1] / j[1], rhs[2] / j[2]];
    let [qw, qx, qy, qz] = s.q;
    let [wx, wy, wz] = s.w;
    let dq = [
        0.5 * (-qx * wx - qy * wy - qz * wz),
        0.5 * (qw * wx + qy * wz - qz * wy),
        0.5 * (qw * wy - qx * wz + qz * wx),
        0.5 * (qw * wz + qx * wy - qy * wx),
    ];
    Deriv { dp: s.v, dv, dq, dw, drotors }
}

fn advance(s: &State, d: &Deriv, h: f64) -> State {
    let mut q = s.q;
    for i in 0..4 {
        q[i] += h * d.dq[i];
    }
    let mut rotors = s.rotors;
    for i in 0..4 {
        rotors[i] += h * d.drotors[i];
    }
    State { p: add(s.p, scale(d.dp, h)), v: add(s.v, scale(d.dv, h)), q, w: add(s.w, scale(d.dw, h)), rotors }
}

/// The simulated vehicle.
#[derive(Clone, Debug)]
pub struct Quadrotor {
    /// Parameters.
    pub params: ModelParams,
    /// State.
    pub state: State,
    /// Whether the vehicle rests on the floor.
    pub on_ground: bool,
    /// Fastest descent speed at a touchdown so far (m/s).
    pub max_touchdown_speed: f64,
    last_accel: V3,
}

impl Quadrotor {
    /// A vehicle at `p` with the attitude `q`, at rest with the rotors stopped.
    pub fn new(params: ModelParams, p: V3, q: [f64; 4]) -> Self {
        let on_ground = params.ground_height_m.is_some_and(|g| p[2] <= g + 1e-9);
        Self {
            params,
            state: State { p, v: [0.0; 3], q, w: [0.0; 3], rotors: [0.0; 4] },
            on_ground,
            max_touchdown_speed: 0.0,
            last_accel: [0.0; 3],
        }
    }

    /// One RK4 step of `h` seconds with the rotor commands held, in still air.
    pub fn step(&mut self, h: f64, cmd: [f64; 4]) {
        self.step_in_wind(h, cmd, [0.0; 3]);
    }

    /// One RK4 step of `h` seconds with the rotor commands and the wind (world, m/s) held.
    pub fn step_in_wind(&mut self, h: f64, cmd: [f64; 4], wind: V3) {
        let s = self.state;
        let p = &self.params;
        let k1 = derivative_in_wind(p, &s, cmd, wind);
        let k2 = derivative_in_wind(p, &advance(&s, &k1, 0.5 * h), cmd, wind);
        let k3 = derivative_in_wind(p, &advance(&s, &k2, 0.5 * h), cmd, wind);
        let k4 = derivative_in_wind(p, &advance(&s, &k3, h), cmd, wind);
        let mut n = s;
        let comb = |a: f64, b: f64, c: f64, d: f64| (a + 2.0 * b + 2.0 * c + d) * h / 6.0;
        for i in 0..3 {
            n.p[i] += comb(k1.dp[i], k2.dp[i], k3.dp[i], k4.dp[i]);
            n.v[i] += comb(k1.dv[i], k2.dv[i], k3.dv[i], k4.dv[i]);
            n.w[i] += comb(k1.dw[i], k2.dw[i], k3.dw[i], k4.dw[i]);
        }
        for i in 0..4 {
            n.q[i] += comb(k1.dq[i], k2.dq[i], k3.dq[i], k4.dq[i]);
            n.rotors[i] += comb(k1.drotors[i], k2.drotors[i], k3.drotors[i], k4.drotors[i]);
        }
        let norm = n.q.iter().map(|x| x * x).sum::<f64>().sqrt();
        n.q = n.q.map(|x| x / norm);
        // Ground contact: the floor carries the vehicle while the thrust cannot lift it.
        if let Some(g) = p.ground_height_m {
            let (thrust, _) = rotor_wrench(p, n.rotors);
            let r = quat_to_mat(n.q);
            let lift = r[2][2] * thrust * ground_effect_factor(p, n.p[2]);
            if n.p[2] <= g {
                if !self.on_ground {
                    self.max_touchdown_speed = self.max_touchdown_speed.max(-n.v[2]);
                }
                if lift < p.mass_kg * p.gravity || n.v[2] < 0.0 {
                    // Resting: level, still, on the floor (keeps the heading).
                    n.p[2] = g;
                    n.v = [0.0; 3];
                    n.w = [0.0; 3];
                    let yaw = (2.0 * (n.q[0] * n.q[3] + n.q[1] * n.q[2]))
                        .atan2(1.0 - 2.0 * (n.q[2] * n.q[2] + n.q[3] * n.q[3]));
                    n.q = [(0.5 * yaw).cos(), 0.0, 0.0, (0.5 * yaw).sin()];
                    self.on_ground = true;
                } else {
                    self.on_ground = false;
                }
            } else {
                self.on_ground = false;
            }
        }
        // What the accelerometer integrates over the step: the mean acceleration, contact impulses included.
        self.last_accel = scale(add(n.v, scale(s.v, -1.0)), 1.0 / h);
        self.state = n;
    }

    /// Specific force in the body frame over the last step (what an ideal accelerometer reads).
    pub fn specific_force_body(&self) -> V3 {
        let r = quat_to_mat(self.state.q);
        mat_t_vec(&r, add(self.last_accel, [0.0, 0.0, self.params.gravity]))
    }

    /// World-from-body rotation.
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        quat_to_mat(self.state.q)
    }

    /// Mechanical energy of the rigid body: translational and rotational kinetic, potential (J); the rotors'
    /// own spin is not included.
    pub fn energy(&self) -> f64 {
        let s = &self.state;
        let p = &self.params;
        let j = p.inertia;
        0.5 * p.mass_kg * dot(s.v, s.v)
            + 0.5 * (j[0] * s.w[0] * s.w[0] + j[1] * s.w[1] * s.w[1] + j[2] * s.w[2] * s.w[2])
            + p.mass_kg * p.gravity * s.p[2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> ModelParams {
        ModelParams::from_vehicle(&VehicleParams::default(), 0.02, 0.0, None)
    }

    fn level() -> [f64; 4] {
        [1.0, 0.0, 0.0, 0.0]
    }

    #[test]
    fn hover_equilibrium() {
        let p = params();
        let wh = p.hover_speed();
        assert!((wh - 559.0).abs() < 1.0, "{wh}");
        let mut q = Quadrotor::new(p, [0.0, 0.0, 1.0], level());
        q.state.rotors = [wh; 4];
        let d = derivative(&p, &q.state, [wh; 4]);
        assert!(d.dv.iter().all(|a| a.abs() < 1e-12), "{:?}", d.dv);
        assert!(d.dw.iter().all(|a| a.abs() < 1e-12), "{:?}", d.dw);
        for _ in 0..5000 {
            q.step(0.001, [wh; 4]);
        }
        assert!((q.state.p[2] - 1.0).abs() < 1e-9 && q.state.v.iter().all(|v| v.abs() < 1e-9));
    }

    #[test]
    fn free_fall() {
        let p = params();
        let mut q = Quadrotor::new(p, [0.0, 0.0, 10.0], level());
        for _ in 0..1000 {
            q.step(0.001, [0.0; 4]);
        }
        assert!((q.state.p[2] - (10.0 - 0.5 * p.gravity)).abs() < 1e-9);
        assert!((q.state.v[2] + p.gravity).abs() < 1e-9);
        let f = q.specific_force_body();
        assert!(f.iter().all(|v| v.abs() < 1e-9), "an accelerometer in free fall reads 0: {f:?}");
    }

    #[test]
    fn torque_directions_of_each_rotor_pair() {
        let p = params();
        let wh = p.hover_speed();
        // Left rotor (M2) faster than right (M4): positive roll torque (right side goes down).
        let (_, t) = rotor_wrench(&p, [wh, wh + 50.0, wh, wh - 50.0]);
        assert!(t[0] > 0.0 && t[1].abs() < 1e-12);
        // Rear (M3) faster than front (M1): positive pitch torque (nose goes down).
        let (_, t) = rotor_wrench(&p, [wh - 50.0, wh, wh + 50.0, wh]);
        assert!(t[1] > 0.0 && t[0].abs() < 1e-12);
        // Front and rear (clockwise) faster: their drag reaction turns the body counter-clockwise, +yaw.
        let (_, t) = rotor_wrench(&p, [wh + 50.0, wh - 50.0, wh + 50.0, wh - 50.0]);
        assert!(t[2] > 0.0);
        // And the positive torques do what the frames say: positive roll rotates body y toward +z.
        let mut q = Quadrotor::new(p, [0.0, 0.0, 1.0], level());
        q.state.rotors = [wh, wh + 50.0, wh, wh - 50.0];
        for _ in 0..100 {
            q.step(0.001, q.state.rotors);
        }
        assert!(q.state.w[0] > 0.0);
        let r = q.rotation();
        assert!(r[2][1] > 0.0, "body y tilts up: {:?}", r[2]);
    }

    #[test]
    fn gyroscopic_torque_sign() {
        // Only the counter-clockwise rotors spin: rotor momentum along +z body. Rolling at +1 rad/s then
        // gives tau = -w x h = -(x) x (z) h = +y h: a positive pitch acceleration.
        let mut p = params();
        p.k = 0.0;
        p.k_tau = 0.0;
        let s = State {
            p: [0.0; 3],
            v: [0.0; 3],
            q: level(),
            w: [1.0, 0.0, 0.0],
            rotors: [0.0, 500.0, 0.0, 500.0],
        };
        let d = derivative(&p, &s, s.rotors);
        let expected = p.rotor_inertia * 1000.0 / p.inertia[1];
        assert!((d.dw[1] - expected).abs() < 1e-9, "{} vs {expected}", d.dw[1]);
        // Equal and opposite spins cancel (the paper's unsigned sum would not).
        let s2 = State { rotors: [500.0; 4], ..s };
        assert!(derivative(&p, &s2, s2.rotors).dw[1].abs() < 1e-12);
    }

    #[test]
    fn rk4_error_shrinks_with_the_fourth_power_of_the_step() {
        // A tumbling, precessing body with the rotors held: compare with a very fine reference.
        let mut p = params();
        p.k = 0.0;
        p.k_tau = 0.0;
        let start = State {
            p: [0.0; 3],
            v: [0.1, 0.0, 0.0],
            q: level(),
            w: [3.0, -2.0, 1.0],
            rotors: [400.0, 700.0, 400.0, 700.0],
        };
        let run = |h: f64| {
            let mut q = Quadrotor::new(p, [0.0; 3], level());
            q.state = start;
            let n = (1.0 / h).round() as usize;
            for _ in 0..n {
                q.step(h, start.rotors);
            }
            q.state
        };
        let reference = run(1e-5);
        let err = |s: State| {
            let dq: f64 = (0..4).map(|i| (s.q[i] - reference.q[i]).powi(2)).sum::<f64>().sqrt();
            let dw: f64 = (0..3).map(|i| (s.w[i] - reference.w[i]).powi(2)).sum::<f64>().sqrt();
            dq + dw
        };
        let e1 = err(run(0.02));
        let e2 = err(run(0.01));
        let ratio = e1 / e2;
        assert!(ratio > 12.0 && ratio < 20.0, "halving the step divided the error by {ratio} (expected ~16)");
    }

    #[test]
    fn energy_is_conserved_with_drag_off() {
        // No aerodynamic forces: kinetic + potential constant. (The gyroscopic and Euler torques, of the form
        // omega x a, do no work: this test cannot see them; `angular_momentum_is_conserved_without_external_torque`
        // does.)
        let mut p = params();
        p.k = 0.0;
        p.k_tau = 0.0;
        p.linear_drag = 0.0;
        let mut q = Quadrotor::new(p, [0.0, 0.0, 5.0], level());
        q.state.v = [0.5, -0.3, 2.0];
        q.state.w = [2.0, 1.0, -3.0];
        q.state.rotors = [600.0, 300.0, 600.0, 300.0];
        let e0 = q.energy();
        for _ in 0..2000 {
            q.step(0.001, q.state.rotors);
        }
        assert!(((q.energy() - e0) / e0).abs() < 1e-8, "{} vs {e0}", q.energy());
        // With drag on, energy decreases.
        p.linear_drag = 0.1;
        let mut q = Quadrotor::new(p, [0.0, 0.0, 5.0], level());
        q.state.v = [0.5, -0.3, 2.0];
        let e0 = q.energy();
        for _ in 0..2000 {
            q.step(0.001, [0.0; 4]);
        }
        assert!(q.energy() < e0 - 1e-3);
    }

    // Independent checks of the equations of motion, each able to catch a single planted error: a flipped or
    // missing reaction or gyroscopic term, body rates integrated as world rates, thrust along world z, a wrong
    // arm, motors of another speed, ignored limits, an accelerometer read in the world frame, no floor.

    /// World-frame angular momentum of the body and its rotors (kg m^2/s).
    fn angular_momentum_world(q: &Quadrotor) -> V3 {
        let p = &q.params;
        let s = &q.state;
        let h: f64 = (0..4).map(|i| SPIN[i] as f64 * s.rotors[i]).sum::<f64>() * p.rotor_inertia;
        let l_body = [p.inertia[0] * s.w[0], p.inertia[1] * s.w[1], p.inertia[2] * s.w[2] + h];
        mat_vec(&q.rotation(), l_body)
    }

    #[test]
    fn angular_momentum_is_conserved_without_external_torque() {
        // No thrust or drag torque, an asymmetric body tumbling with its rotors spinning and spinning up: no
        // external torque, so the world-frame angular momentum of body and rotors is constant. Catches the
        // Euler term (omega x J omega) flipped or missing, the rotors' gyroscopic term flipped or missing, the
        // motors' reaction flipped or missing, and body rates integrated as world rates.
        let mut p = params();
        p.k = 0.0;
        p.k_tau = 0.0;
        p.inertia = [3.0e-3, 4.5e-3, 7.1e-3];
        let mut q = Quadrotor::new(p, [0.0, 0.0, 5.0], level());
        q.state.w = [2.0, -1.0, 1.5];
        q.state.rotors = [300.0, 600.0, 300.0, 600.0];
        let l0 = angular_momentum_world(&q);
        let norm = dot(l0, l0).sqrt();
        // The clockwise rotors spin up to 800 rad/s over the run (a reaction torque on the body).
        for _ in 0..1000 {
            q.step(0.001, [800.0, 600.0, 800.0, 600.0]);
        }
        let l1 = angular_momentum_world(&q);
        let d = add(l1, scale(l0, -1.0));
        assert!(dot(d, d).sqrt() < 1e-7 * norm.max(1e-3), "{l0:?} -> {l1:?}");
        assert!((q.state.rotors[0] - 800.0).abs() < 1.0, "the rotors did spin up: {:?}", q.state.rotors);
    }

    #[test]
    fn thrust_acts_along_the_body_axis_and_torques_have_their_size() {
        let p = params();
        let wh = p.hover_speed();
        // Rolled by 0.3 rad at hover thrust: the thrust tilts with the body.
        let a: f64 = 0.3;
        let s = State {
            p: [0.0, 0.0, 1.0],
            v: [0.0; 3],
            q: [(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0],
            w: [0.0; 3],
            rotors: [wh; 4],
        };
        let d = derivative(&p, &s, s.rotors);
        let t_over_m = 4.0 * p.k * wh * wh / p.mass_kg;
        assert!((d.dv[1] + t_over_m * a.sin()).abs() < 1e-9, "{:?}", d.dv);
        assert!((d.dv[2] - (t_over_m * a.cos() - p.gravity)).abs() < 1e-9, "{:?}", d.dv);
        // Roll and pitch torques: arm times the thrust difference of the opposite pair ("+" frame), exactly.
        let (w2, w4) = (wh + 40.0, wh - 40.0);
        let s = State { q: level(), rotors: [wh, w2, wh, w4], ..s };
        let d = derivative(&p, &s, s.rotors);
        let expected = p.arm_m * p.k * (w2 * w2 - w4 * w4) / p.inertia[0];
        assert!((d.dw[0] - expected).abs() < 1e-9 * expected, "{} vs {expected}", d.dw[0]);
    }

    #[test]
    fn motors_follow_their_time_constant_and_limits() {
        let p = params();
        let mut q = Quadrotor::new(p, [0.0, 0.0, 50.0], level());
        // A step from 0 to 500 rad/s: 63.2 % after one time constant.
        let n = (p.motor_tau_s / 1e-4).round() as usize;
        for _ in 0..n {
            q.step(1e-4, [500.0; 4]);
        }
        let frac = q.state.rotors[0] / 500.0;
        assert!((frac - (1.0 - (-1.0f64).exp())).abs() < 1e-3, "{frac}");
        // A command beyond the limit settles at the limit.
        for _ in 0..2000 {
            q.step(1e-3, [5000.0; 4]);
        }
        assert!((q.state.rotors[0] - p.motor_limits[1]).abs() < 1e-6, "{:?}", q.state.rotors);
    }

    #[test]
    fn the_accelerometer_reads_in_the_body_frame_and_the_floor_carries_the_vehicle() {
        let p = params();
        let wh = p.hover_speed();
        // Rolled by 0.3 rad with hover thrust: the specific force is the thrust over the mass along body z.
        let a: f64 = 0.3;
        let mut q = Quadrotor::new(p, [0.0, 0.0, 10.0], [(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0]);
        q.state.rotors = [wh; 4];
        q.step(1e-4, [wh; 4]);
        let f = q.specific_force_body();
        let t_over_m = 4.0 * p.k * wh * wh / p.mass_kg;
        assert!(f[0].abs() < 1e-6 && f[1].abs() < 1e-6, "{f:?}");
        assert!((f[2] - t_over_m).abs() < 1e-6, "{f:?}");
        // On a floor with the rotors stopped: it stays there, and the accelerometer reads +g up.
        let mut p = params();
        p.ground_height_m = Some(0.06);
        let mut q = Quadrotor::new(p, [0.0, 0.0, 0.06], level());
        for _ in 0..1000 {
            q.step(0.001, [0.0; 4]);
        }
        assert!((q.state.p[2] - 0.06).abs() < 1e-12 && q.on_ground, "{:?}", q.state.p);
        let f = q.specific_force_body();
        assert!((f[2] - p.gravity).abs() < 1e-9, "{f:?}");
    }

    /// `[w, x, y, z]` of yaw `psi`, then pitch `theta`, then roll `phi` (Z-Y-X), composed by hand.
    fn zyx(psi: f64, theta: f64, phi: f64) -> [f64; 4] {
        let (cz, sz) = ((psi / 2.0).cos(), (psi / 2.0).sin());
        let (cy, sy) = ((theta / 2.0).cos(), (theta / 2.0).sin());
        let (cx, sx) = ((phi / 2.0).cos(), (phi / 2.0).sin());
        [
            cz * cy * cx + sz * sy * sx,
            cz * cy * sx - sz * sy * cx,
            cz * sy * cx + sz * cy * sx,
            sz * cy * cx - cz * sy * sx,
        ]
    }

    #[test]
    fn the_body_frame_is_reached_through_the_transpose_of_a_general_rotation() {
        let r = quat_to_mat(zyx(0.7, -0.4, 0.25));
        let v = [0.3, -1.2, 2.5];
        // R^T v, written out element by element.
        let expected: V3 = core::array::from_fn(|c| (0..3).map(|k| r[k][c] * v[k]).sum());
        let got = mat_t_vec(&r, v);
        for i in 0..3 {
            assert!((got[i] - expected[i]).abs() < 1e-12, "{got:?} vs {expected:?}");
        }
        // And it undoes R.
        let back = mat_t_vec(&r, mat_vec(&r, v));
        assert!((0..3).all(|i| (back[i] - v[i]).abs() < 1e-12), "{back:?}");
    }

    #[test]
    fn a_weakened_rotor_loses_thrust_and_torque_in_proportion() {
        let mut p = params();
        p.rotor_scale = [0.5, 1.0, 1.0, 1.0];
        let w = 500.0;
        let (t, tau) = rotor_wrench(&p, [w; 4]);
        assert!((t - 3.5 * p.k * w * w).abs() < 1e-9 * t, "{t}");
        // M1 (front) at half thrust: the rear pushes the nose down, +pitch; half of M1's (clockwise) drag
        // reaction is missing, so the counter-clockwise rotors' reaction turns the body clockwise, -yaw.
        assert!((tau[1] - 0.5 * p.arm_m * p.k * w * w).abs() < 1e-12, "{tau:?}");
        assert!((tau[2] + 0.5 * p.k_tau * w * w).abs() < 1e-12, "{tau:?}");
    }

    #[test]
    fn the_ground_effect_follows_cheeseman_and_bennett_and_is_capped() {
        let mut p = params();
        assert_eq!(ground_effect_factor(&p, 0.1), 1.0, "off without a rotor radius");
        p.ground_effect_rotor_radius_m = Some(0.1);
        assert_eq!(ground_effect_factor(&p, 0.1), 1.0, "off without a floor");
        p.ground_height_m = Some(0.05);
        for (h, expected) in
            [(0.1, 1.0 / (1.0 - 0.0625)), (0.5, 1.0 / (1.0 - 0.0025)), (0.2, 1.0 / (1.0 - 0.015625))]
        {
            let f = ground_effect_factor(&p, h);
            assert!((f - expected).abs() < 1e-12, "at {h} m: {f} vs {expected}");
        }
        // R/4z = 0.75 would give 2.29: capped at 1.5; at 0.8 and below the floor too.
        assert_eq!(ground_effect_factor(&p, 0.1 / 3.0), 1.5);
        assert_eq!(ground_effect_factor(&p, 0.03), 1.5);
        assert_eq!(ground_effect_factor(&p, -1.0), 1.5);
        // The derivative lifts by the factor: at 0.1 m with hover speed the excess is g (f - 1).
        let wh = p.hover_speed();
        let s = State { p: [0.0, 0.0, 0.1], v: [0.0; 3], q: level(), w: [0.0; 3], rotors: [wh; 4] };
        let d = derivative(&p, &s, s.rotors);
        let expected = p.gravity * (1.0 / (1.0 - 0.0625) - 1.0);
        assert!((d.dv[2] - expected).abs() < 1e-9, "{} vs {expected}", d.dv[2]);
    }

    #[test]
    fn rotor_drag_opposes_the_air_relative_velocity_in_the_rotor_plane() {
        let mut p = params();
        p.rotor_drag = 1e-3;
        p.linear_drag = 0.0;
        let q = zyx(0.6, 0.2, -0.3);
        let r = quat_to_mat(q);
        let rotors = [400.0, 450.0, 500.0, 550.0];
        let v = [0.8, -0.5, 0.3];
        let wind = [0.2, 0.4, -0.1];
        let s = State { p: [0.0, 0.0, 2.0], v, q, w: [0.0; 3], rotors };
        let d = derivative_in_wind(&p, &s, rotors, wind);
        // Air-relative velocity in the body frame, by hand; the drag acts in body x and y only.
        let v_air = [v[0] - wind[0], v[1] - wind[1], v[2] - wind[2]];
        let vb: V3 = core::array::from_fn(|c| (0..3).map(|k| r[k][c] * v_air[k]).sum());
        let sum_w: f64 = rotors.iter().sum();
        let (thrust, _) = rotor_wrench(&p, rotors);
        let f_b = [-p.rotor_drag * sum_w * vb[0], -p.rotor_drag * sum_w * vb[1], thrust];
        for i in 0..3 {
            let f_w: f64 = (0..3).map(|k| r[i][k] * f_b[k]).sum();
            let expected = f_w / p.mass_kg - if i == 2 { p.gravity } else { 0.0 };
            assert!((d.dv[i] - expected).abs() < 1e-12, "axis {i}: {} vs {expected}", d.dv[i]);
        }
        // Still air and a still vehicle: no drag at all; air moving past a hovering vehicle pushes it downwind.
        p.linear_drag = 0.1;
        let level_still = State { v: [0.0; 3], q: level(), ..s };
        let d = derivative_in_wind(&p, &level_still, rotors, [1.0, 0.0, 0.0]);
        let expected = (p.rotor_drag * sum_w + p.linear_drag) / p.mass_kg;
        assert!((d.dv[0] - expected).abs() < 1e-12, "{} vs {expected}", d.dv[0]);
    }

    #[test]
    fn the_energy_is_the_rigid_body_s_kinetic_and_potential_energy() {
        let mut p = params();
        p.inertia = [3.0e-3, 4.5e-3, 7.1e-3];
        let mut q = Quadrotor::new(p, [1.0, 2.0, 3.5], zyx(0.3, 0.1, 0.2));
        q.state.v = [0.5, -0.7, 1.1];
        q.state.w = [2.0, -3.0, 5.0];
        q.state.rotors = [500.0; 4];
        let expected = 0.5 * p.mass_kg * (0.25 + 0.49 + 1.21)
            + 0.5 * (3.0e-3 * 4.0 + 4.5e-3 * 9.0 + 7.1e-3 * 25.0)
            + p.mass_kg * p.gravity * 3.5;
        assert!((q.energy() - expected).abs() < 1e-12, "{} vs {expected}", q.energy());
    }

    #[test]
    fn touchdown_records_the_impact_speed_and_rests_level_keeping_the_heading() {
        let mut p = params();
        p.ground_height_m = Some(0.05);
        let mut q = Quadrotor::new(p, [0.0, 0.0, 1.05], zyx(0.7, 0.15, -0.2));
        let mut steps = 0;
        while !q.on_ground {
            q.step(1e-4, [0.0; 4]);
            steps += 1;
            assert!(steps < 100_000);
        }
        let expected = (2.0 * p.gravity * 1.0).sqrt();
        assert!((q.max_touchdown_speed - expected).abs() < 2e-3, "{} vs {expected}", q.max_touchdown_speed);
        let rest = [(0.35f64).cos(), 0.0, 0.0, (0.35f64).sin()];
        assert!((0..4).all(|i| (q.state.q[i] - rest[i]).abs() < 1e-9), "{:?}", q.state.q);
        assert_eq!(q.state.p[2], 0.05);
        assert_eq!((q.state.v, q.state.w), ([0.0; 3], [0.0; 3]));
        // Resting does not count as another touchdown.
        let first = q.max_touchdown_speed;
        q.state.v = [0.0, 0.0, -5.0];
        q.step(1e-4, [0.0; 4]);
        assert_eq!(q.max_touchdown_speed, first);
    }

    #[test]
    fn the_floor_stops_a_descent_under_any_thrust_and_releases_a_vehicle_that_can_climb() {
        let mut p = params();
        p.ground_height_m = Some(0.05);
        let wh = p.hover_speed();
        // Coming down at 1 m/s with 1.2 times the weight: the floor stops it, it never sinks in.
        let fast = wh * 1.2f64.sqrt();
        let mut q = Quadrotor::new(p, [0.0, 0.0, 0.0505], level());
        q.state.v = [0.0, 0.0, -1.0];
        q.state.rotors = [fast; 4];
        for _ in 0..200 {
            q.step(1e-4, [fast; 4]);
            assert!(q.state.p[2] >= 0.05, "sank into the floor: {}", q.state.p[2]);
        }
        assert!(q.state.v[2] > 0.0, "and then climbs: {:?}", q.state.v);
        // Pushed below the floor level while rising with 0.9 of the weight: put back on the floor.
        let weak = wh * 0.9f64.sqrt();
        let mut q = Quadrotor::new(p, [0.0, 0.0, 0.04], level());
        q.state.v = [0.0, 0.0, 0.5];
        q.state.rotors = [weak; 4];
        q.step(1e-4, [weak; 4]);
        assert!(q.on_ground && q.state.p[2] == 0.05 && q.state.v == [0.0; 3], "{:?}", q.state);
        // Below the floor, rising with 1.5 of the weight: free to climb out.
        let strong = wh * 1.5f64.sqrt();
        let mut q = Quadrotor::new(p, [0.0, 0.0, 0.04], level());
        q.state.v = [0.0, 0.0, 0.5];
        q.state.rotors = [strong; 4];
        q.step(1e-4, [strong; 4]);
        assert!(!q.on_ground && q.state.v[2] > 0.5 && q.state.p[2] < 0.05, "{:?}", q.state);
        // The ground effect counts: 0.9 of the weight out of ground effect climbs out at 0.05 m (factor 4/3).
        p.ground_effect_rotor_radius_m = Some(0.1);
        let mut q = Quadrotor::new(p, [0.0, 0.0, 0.0499], level());
        q.state.v = [0.0, 0.0, 0.5];
        q.state.rotors = [weak; 4];
        q.step(1e-4, [weak; 4]);
        assert!(!q.on_ground, "{:?}", q.state);
    }
}
