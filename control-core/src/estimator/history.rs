//! The state history for delayed measurements: one snapshot per 2 ms (at most), each with the estimator's
//! cumulative corrections when it was stored.
use super::{Estimator, HISTORY_LEN, PastState, SNAPSHOT_EVERY_US};
use geometry::frames::Attitude;
use geometry::{Quat, Vec3};
/// A stored state, with the estimator's cumulative corrections when it was stored: corrections made later
/// are applied when the snapshot is read, so a delayed measurement's innovation is formed against the past
/// state *as corrected since*. Without that, the several measurements in flight during one latency would each
/// correct the same error again (with 60 Hz flow 40 ms late, three times: the estimate oscillates).
#[derive(Clone, Copy, Debug)]
pub(super) struct Snapshot {
    pub(super) time_us: u64,
    pub(super) p: Vec3,
    pub(super) v: Vec3,
    pub(super) q: Quat,
    pub(super) corr: Corrections,
}

/// Sums of the corrections injected into position, velocity and attitude (body frame, small angles).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Corrections {
    pub(super) p: Vec3,
    pub(super) v: Vec3,
    pub(super) th: Vec3,
}

impl Snapshot {
    /// The snapshot with the corrections made since it was stored.
    pub(super) fn corrected(&self, now: &Corrections) -> Snapshot {
        let dth = now.th - self.corr.th;
        Snapshot {
            time_us: self.time_us,
            p: self.p + (now.p - self.corr.p),
            v: self.v + (now.v - self.corr.v),
            q: self.q.mul(&Quat::from_rotvec(dth)).normalized(),
            corr: *now,
        }
    }
}

impl Estimator {
    pub(super) fn push_history(&mut self, now_us: u64) {
        if self.hist_len > 0 {
            let newest = self.history[(self.hist_head + HISTORY_LEN - 1) % HISTORY_LEN].time_us;
            // Within 1 % of the spacing counts as due (control steps are not exactly periodic).
            if now_us < newest + SNAPSHOT_EVERY_US - SNAPSHOT_EVERY_US / 100 {
                return;
            }
        }
        let snap = Snapshot { time_us: now_us, p: self.p, v: self.v, q: self.q, corr: self.corr };
        self.history[self.hist_head] = snap;
        self.hist_head = (self.hist_head + 1) % HISTORY_LEN;
        self.hist_len = (self.hist_len + 1).min(HISTORY_LEN);
    }

    /// The stored state nearest before-or-at `t_us`, linearly interpolated with the next one.
    pub(super) fn state_at(&self, t_us: u64) -> Option<Snapshot> {
        if self.hist_len == 0 {
            return None;
        }
        let newest = (self.hist_head + HISTORY_LEN - 1) % HISTORY_LEN;
        if t_us > self.history[newest].time_us {
            return None;
        }
        let mut later: Option<&Snapshot> = None;
        for k in 0..self.hist_len {
            let idx = (newest + HISTORY_LEN - k) % HISTORY_LEN;
            let s = &self.history[idx];
            if s.time_us <= t_us {
                let s = s.corrected(&self.corr);
                return Some(match later {
                    Some(l) if l.time_us > s.time_us => {
                        let l = l.corrected(&self.corr);
                        let f = (t_us - s.time_us) as f32 / (l.time_us - s.time_us) as f32;
                        // Attitude: the nearer sample (2 ms apart at most: below 0.1 deg at 1 rad/s).
                        let q = if f < 0.5 { s.q } else { l.q };
                        Snapshot {
                            time_us: t_us,
                            p: s.p + (l.p - s.p) * f,
                            v: s.v + (l.v - s.v) * f,
                            q,
                            corr: s.corr,
                        }
                    }
                    _ => s,
                });
            }
            later = Some(s);
        }
        None
    }

    /// Position, velocity and attitude at a past time (from the history, interpolated), for delayed
    /// measurements such as the optical flow of a frame pair.
    pub fn past_state(&self, t_us: u64) -> Option<PastState> {
        self.state_at(t_us).map(|s| PastState { time_us: t_us, position_m: s.p, velocity_m_s: s.v, q: s.q })
    }

    /// Attitude at a past time (from the history), for solving a delayed frame's pose.
    pub fn attitude_at(&self, t_us: u64) -> Option<Attitude> {
        self.state_at(t_us).map(|s| Attitude::from_world_from_body(&s.q.to_mat3()))
    }
}
