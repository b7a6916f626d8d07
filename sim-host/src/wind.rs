//! Wind: a mean, Dryden turbulence and 1-cosine gusts, world frame.
//!
//! Turbulence follows the Dryden forms of MIL-HDBK-1797 ("Flying qualities of piloted aircraft", 1997; also
//! MIL-F-8785C), with one intensity `sigma` and one scale length `L` for the three axes:
//!
//! `H_u(s) = sigma sqrt(2 L / (pi V)) / (1 + (L / V) s)`,
//! `H_v(s) = H_w(s) = sigma sqrt(L / (pi V)) (1 + sqrt(3) (L / V) s) / (1 + (L / V) s)^2`,
//!
//! driven by white noise. `V` is the speed at which the turbulence is carried past the vehicle (Taylor's
//! frozen-turbulence hypothesis): the air-relative speed, at least 1 m/s (a hovering multirotor in a
//! still room would otherwise see frozen air). Each stage is integrated exactly over the physics step (the
//! stages' time constants `L / V` are seconds, the step a millisecond), and the input's intensity is set so
//! that each axis's stationary standard deviation is `sigma` (first order: intensity `2 (L/V) sigma^2`; the
//! second-order form: `(L/V) sigma^2`). `u` is taken along the mean wind (x when there is none).
use crate::rng::SimRng;
use crate::scenario::WindConfig;

/// The slowest convection speed of the turbulence (m/s).
pub const MIN_CONVECTION_M_S: f64 = 1.0;

/// The wind of one run.
pub struct Wind {
    cfg: WindConfig,
    rng: SimRng,
    /// First-order state of u, and the two stages of v and w.
    u: f64,
    v: [f64; 2],
    w: [f64; 2],
}

impl Wind {
    /// The wind of a run, its turbulence drawn from `seed`'s "wind" stream.
    pub fn new(cfg: &WindConfig, seed: u64) -> Self {
        Self { cfg: cfg.clone(), rng: SimRng::stream(seed, "wind"), u: 0.0, v: [0.0; 2], w: [0.0; 2] }
    }

    /// Whether there is any wind at all.
    pub fn is_calm(&self) -> bool {
        self.cfg.mean_m_s == [0.0; 3] && self.cfg.turbulence_sigma_m_s == 0.0 && self.cfg.gusts.is_empty()
    }

    /// Advances the turbulence by `dt` at simulated time `t_s` for a vehicle moving at `vehicle_v` (world,
    /// m/s) and returns the wind (world, m/s).
    pub fn step(&mut self, t_s: f64, dt: f64, vehicle_v: [f64; 3]) -> [f64; 3] {
        let m = self.cfg.mean_m_s;
        let mut wind = m;
        let sigma = self.cfg.turbulence_sigma_m_s;
        if sigma > 0.0 {
            let rel = [m[0] - vehicle_v[0], m[1] - vehicle_v[1], m[2] - vehicle_v[2]];
            let speed = (rel[0] * rel[0] + rel[1] * rel[1] + rel[2] * rel[2]).sqrt().max(MIN_CONVECTION_M_S);
            let tau = self.cfg.turbulence_length_m / speed;
            let a = (-dt / tau).exp();
            let first = |x: f64, q: f64, n: f64| a * x + (q / (2.0 * tau) * (1.0 - a * a)).sqrt() * n;
            self.u = first(self.u, 2.0 * tau * sigma * sigma, self.rng.normal());
            let q2 = tau * sigma * sigma;
            for s in [&mut self.v, &mut self.w] {
                let n = self.rng.normal();
                let x1 = first(s[0], q2, n);
                s[1] = a * s[1] + (1.0 - a) * s[0];
                s[0] = x1;
            }
            let second = |s: &[f64; 2]| 3f64.sqrt() * s[0] + (1.0 - 3f64.sqrt()) * s[1];
            // Axes: u along the horizontal mean wind, v across it, w vertical.
            let h = (m[0] * m[0] + m[1] * m[1]).sqrt();
            let (cx, cy) = if h > 1e-6 { (m[0] / h, m[1] / h) } else { (1.0, 0.0) };
            let (tu, tv, tw) = (self.u, second(&self.v), second(&self.w));
            wind[0] += cx * tu - cy * tv;
            wind[1] += cy * tu + cx * tv;
            wind[2] += tw;
        }
        for g in &self.cfg.gusts {
            let x = (t_s - g.start_s) / g.duration_s;
            if (0.0..=1.0).contains(&x) {
                let f = 0.5 * (1.0 - (2.0 * std::f64::consts::PI * x).cos());
                for k in 0..3 {
                    wind[k] += f * g.velocity_m_s[k];
                }
            }
        }
        wind
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::GustConfig;

    #[test]
    fn turbulence_has_the_asked_intensity_and_a_gust_its_shape() {
        let cfg = WindConfig {
            mean_m_s: [1.0, 0.0, 0.0],
            turbulence_sigma_m_s: 0.5,
            turbulence_length_m: 2.0,
            gusts: vec![GustConfig { start_s: 500.0, duration_s: 2.0, velocity_m_s: [0.0, 3.0, 0.0] }],
        };
        let mut w = Wind::new(&cfg, 7);
        let n = 400_000;
        let mut sum = [0.0f64; 3];
        let mut sq = [0.0f64; 3];
        for k in 0..n {
            let v = w.step(k as f64 * 1e-3, 1e-3, [0.0; 3]);
            for i in 0..3 {
                sum[i] += v[i];
                sq[i] += v[i] * v[i];
            }
        }
        for i in 0..3 {
            let mean = sum[i] / n as f64;
            let sd = (sq[i] / n as f64 - mean * mean).sqrt();
            assert!((mean - cfg.mean_m_s[i]).abs() < 0.1, "axis {i} mean {mean}");
            assert!((sd - 0.5).abs() < 0.08, "axis {i} sigma {sd}");
        }
        // The gust: zero at its ends, its peak half-way.
        let calm = WindConfig { gusts: cfg.gusts.clone(), ..WindConfig::default() };
        let mut g = Wind::new(&calm, 1);
        assert_eq!(g.step(499.999, 1e-3, [0.0; 3])[1], 0.0);
        assert!((g.step(501.0, 1e-3, [0.0; 3])[1] - 3.0).abs() < 1e-9);
        assert!(g.step(502.0, 1e-3, [0.0; 3])[1].abs() < 1e-9);
        assert!(Wind::new(&WindConfig::default(), 1).is_calm());
    }
}
