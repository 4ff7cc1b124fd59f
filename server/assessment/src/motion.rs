//! Motion metrics of the leading tip and the hands.
//!
//! - **Tip path length** (m): Σ |x(tᵢ₊₁) − x(tᵢ)| over the samples. Longer paths for the same
//!   route separate novices from experts in endovascular simulators (Rolls et al., J Vasc
//!   Surg 2017; Duran et al., Eur J Vasc Endovasc Surg 2015, "tip path length").
//! - **Path ratio** (1): tip path length over the distance gained along the route
//!   (last − first `along_route_m`); 1 for a tip that only ever advanced along the route,
//!   more for every detour, retreat and wobble. Undefined (`None`) when the tip gained less
//!   than 1 mm.
//! - **Idle time** (s): time in intervals where no hand moved its instrument, neither by more
//!   than `idle_speed_m_s` in insertion nor `idle_twist_rad_s` in twist (Rolls et al. count
//!   such pauses; thresholds here: 0.5 mm/s and 0.05 rad/s, below a hand's deliberate
//!   motion).

use crate::trace::Trace;

/// Insertion speed below which a hand counts as still (m/s).
pub const IDLE_SPEED_M_S: f64 = 0.5e-3;
/// Twist rate below which a hand counts as still (rad/s).
pub const IDLE_TWIST_RAD_S: f64 = 0.05;

/// Distance the leading tip travelled (m).
pub fn tip_path_length_m(trace: &Trace) -> f64 {
    trace
        .samples()
        .windows(2)
        .map(|w| {
            let d: f64 = (0..3)
                .map(|a| (w[1].tip_m[a] - w[0].tip_m[a]).powi(2))
                .sum();
            d.sqrt()
        })
        .sum()
}

/// Tip path length over the distance gained along the route (1); `None` when less than
/// 1 mm was gained.
pub fn path_ratio(trace: &Trace) -> Option<f64> {
    let s = trace.samples();
    let gained = s[s.len() - 1].along_route_m - s[0].along_route_m;
    (gained >= 1e-3).then(|| tip_path_length_m(trace) / gained)
}

/// Time in which no hand moved (s), with the default thresholds.
pub fn idle_time_s(trace: &Trace) -> f64 {
    idle_time_with(trace, IDLE_SPEED_M_S, IDLE_TWIST_RAD_S)
}

/// Time in which no hand moved faster than `speed_m_s` in insertion or `twist_rad_s` in
/// twist (s).
pub fn idle_time_with(trace: &Trace, speed_m_s: f64, twist_rad_s: f64) -> f64 {
    let s = trace.samples();
    idle_intervals(trace, speed_m_s, twist_rad_s)
        .iter()
        .zip(s.windows(2))
        .filter(|(still, _)| **still)
        .map(|(_, w)| w[1].time_s - w[0].time_s)
        .fold(0.0, |a, b| a + b)
}

/// For each interval between consecutive samples, whether no hand moved faster than
/// `speed_m_s` in insertion or `twist_rad_s` in twist.
pub fn idle_intervals(trace: &Trace, speed_m_s: f64, twist_rad_s: f64) -> Vec<bool> {
    trace
        .samples()
        .windows(2)
        .map(|w| {
            let dt = w[1].time_s - w[0].time_s;
            // A device loaded or taken out is no idle hand.
            w[0].inserted_m.len() == w[1].inserted_m.len()
                && w[0]
                    .inserted_m
                    .iter()
                    .zip(&w[1].inserted_m)
                    .all(|(a, b)| (b - a).abs() <= speed_m_s * dt)
                && w[0]
                    .twist_rad
                    .iter()
                    .zip(&w[1].twist_rad)
                    .all(|(a, b)| (b - a).abs() <= twist_rad_s * dt)
        })
        .collect()
}

/// The leading tip's speed between samples (m/s) and the sampling interval, for
/// [`crate::smoothness`]: (speeds, mean interval in s).
pub fn tip_speeds(trace: &Trace) -> (Vec<f64>, f64) {
    let s = trace.samples();
    let speeds = s
        .windows(2)
        .map(|w| {
            let d: f64 = (0..3)
                .map(|a| (w[1].tip_m[a] - w[0].tip_m[a]).powi(2))
                .sum();
            d.sqrt() / (w[1].time_s - w[0].time_s)
        })
        .collect();
    (speeds, trace.duration_s() / (s.len() - 1) as f64)
}
