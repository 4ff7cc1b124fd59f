//! A scripted virtual haptic device: speaks the device side of the UDP protocol at a fixed
//! rate, with one channel or two (an outer hand beside the inner one), moves by a script of
//! constant-speed segments, drops a chosen fraction of datagrams both ways (to test loss),
//! and reports the force each hand is asked to render.

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use rand::RngExt;
use serde::Serialize;

use crate::protocol::{DeviceSample, Feedback, HandPosition};

/// One piece of the script.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Segment {
    /// Push (+) or pull (−).
    Push {
        /// Speed (mm/s).
        mm_s: f64,
        /// Duration (s).
        seconds: f64,
    },
    /// Turn.
    Twist {
        /// Rate (deg/s, + clockwise).
        deg_s: f64,
        /// Duration (s).
        seconds: f64,
    },
    /// The outer hand (a two-channel device) pushes (+) or pulls (−).
    OuterPush {
        /// Speed (mm/s).
        mm_s: f64,
        /// Duration (s).
        seconds: f64,
    },
    /// The outer hand turns.
    OuterTwist {
        /// Rate (deg/s, + clockwise).
        deg_s: f64,
        /// Duration (s).
        seconds: f64,
    },
    /// Hold still.
    Hold {
        /// Duration (s).
        seconds: f64,
    },
    /// Fluoroscopy pedal down or up (instant).
    Pedal(bool),
}

impl Segment {
    fn seconds(&self) -> f64 {
        match *self {
            Segment::Push { seconds, .. }
            | Segment::Twist { seconds, .. }
            | Segment::OuterPush { seconds, .. }
            | Segment::OuterTwist { seconds, .. }
            | Segment::Hold { seconds } => seconds,
            Segment::Pedal(_) => 0.0,
        }
    }
}

/// A script that cannot be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("script segment {index} ({text:?}): {reason}")]
pub struct ScriptError {
    /// Which segment (0-based).
    pub index: usize,
    /// Its text.
    pub text: String,
    /// What is wrong.
    pub reason: String,
}

/// Parses `push:MM_S:SECONDS`, `twist:DEG_S:SECONDS`, `outer-push:MM_S:SECONDS`,
/// `outer-twist:DEG_S:SECONDS`, `hold:SECONDS`, `pedal:on|off`, separated by commas: e.g.
/// `hold:0.5,push:15:4,twist:90:1`. The outer segments move a two-channel device's outer hand.
pub fn parse_script(text: &str) -> Result<Vec<Segment>, ScriptError> {
    text.split(',')
        .map(str::trim)
        .enumerate()
        .map(|(index, part)| {
            let fail = |reason: &str| ScriptError {
                index,
                text: part.to_owned(),
                reason: reason.to_owned(),
            };
            let fields: Vec<&str> = part.split(':').collect();
            let number = |s: &str, what: &str| -> Result<f64, ScriptError> {
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| fail(&format!("{what} {s:?} is not a finite number")))
            };
            let duration = |s: &str| -> Result<f64, ScriptError> {
                let v = number(s, "duration")?;
                if (0.0..=3600.0).contains(&v) {
                    Ok(v)
                } else {
                    Err(fail("duration must be 0..3600 s"))
                }
            };
            match fields.as_slice() {
                ["push", v, t] => Ok(Segment::Push {
                    mm_s: number(v, "speed")?,
                    seconds: duration(t)?,
                }),
                ["twist", v, t] => Ok(Segment::Twist {
                    deg_s: number(v, "rate")?,
                    seconds: duration(t)?,
                }),
                ["outer-push", v, t] => Ok(Segment::OuterPush {
                    mm_s: number(v, "speed")?,
                    seconds: duration(t)?,
                }),
                ["outer-twist", v, t] => Ok(Segment::OuterTwist {
                    deg_s: number(v, "rate")?,
                    seconds: duration(t)?,
                }),
                ["hold", t] => Ok(Segment::Hold {
                    seconds: duration(t)?,
                }),
                ["pedal", "on"] => Ok(Segment::Pedal(true)),
                ["pedal", "off"] => Ok(Segment::Pedal(false)),
                _ => Err(fail(
                    "expected push:MM_S:S, twist:DEG_S:S, outer-push:MM_S:S, outer-twist:DEG_S:S, \
                     hold:S or pedal:on|off",
                )),
            }
        })
        .collect()
}

/// The virtual device's settings.
#[derive(Debug, Clone)]
pub struct VirtualDevice {
    /// The bridge's UDP address.
    pub bridge: SocketAddr,
    /// The motion.
    pub script: Vec<Segment>,
    /// Device rate (Hz).
    pub rate_hz: f64,
    /// Fraction of datagrams dropped, each way (0..1).
    pub loss: f64,
    /// How often to report (s).
    pub report_every_s: f64,
    /// Two channels (protocol version 2: an outer hand too); one otherwise.
    pub two_hands: bool,
}

/// Whether a script moves an outer hand (and so needs a two-channel device).
pub fn moves_outer_hand(script: &[Segment]) -> bool {
    script
        .iter()
        .any(|s| matches!(s, Segment::OuterPush { .. } | Segment::OuterTwist { .. }))
}

/// What the device saw at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DeviceReport {
    /// Time since the start (s).
    pub t_s: f64,
    /// Device position (mm) and angle (deg).
    pub position_mm: f64,
    /// Angle (deg).
    pub rotation_deg: f64,
    /// Last force received (N) and torque (N·mm).
    pub force_n: f64,
    /// Torque (N·mm).
    pub torque_nmm: f64,
    /// The bridge had a session / fresh state.
    pub connected: bool,
    /// Fresh server state behind the force.
    pub live: bool,
    /// Datagrams sent, dropped on purpose, and feedback received.
    pub sent: u64,
    /// Dropped on purpose (outgoing).
    pub dropped: u64,
    /// Feedback datagrams accepted.
    pub received: u64,
    /// Device-to-device round trip of the last feedback (ms).
    pub round_trip_ms: f64,
    /// The outer hand (a two-channel device; zeros otherwise): position (mm), angle (deg),
    /// force (N), torque (N·mm) and whether its feedback is live.
    pub outer_position_mm: f64,
    /// Angle (deg).
    pub outer_rotation_deg: f64,
    /// Force (N).
    pub outer_force_n: f64,
    /// Torque (N·mm).
    pub outer_torque_nmm: f64,
    /// Live.
    pub outer_live: bool,
}

/// Runs the script, calling `report` every `report_every_s`; returns the last report.
pub fn run(
    device: &VirtualDevice,
    mut report: impl FnMut(&DeviceReport),
) -> std::io::Result<DeviceReport> {
    let socket = UdpSocket::bind("127.0.0.1:0")?;
    socket.connect(device.bridge)?;
    socket.set_nonblocking(true)?;
    let period = Duration::from_secs_f64(1.0 / device.rate_hz);
    let total: f64 = device.script.iter().map(Segment::seconds).sum();
    let start = Instant::now();
    let mut rng = rand::rng();
    let (mut position, mut angle, mut pedal) = (0.0f64, 0.0f64, false);
    let mut outer = HandPosition::default();
    let mut state = DeviceReport {
        t_s: 0.0,
        position_mm: 0.0,
        rotation_deg: 0.0,
        force_n: 0.0,
        torque_nmm: 0.0,
        connected: false,
        live: false,
        sent: 0,
        dropped: 0,
        received: 0,
        round_trip_ms: 0.0,
        outer_position_mm: 0.0,
        outer_rotation_deg: 0.0,
        outer_force_n: 0.0,
        outer_torque_nmm: 0.0,
        outer_live: false,
    };
    let (mut seq, mut next_tick, mut next_report) = (0u32, start, 0.0);
    let mut previous_t = 0.0;
    let mut buffer = [0u8; 64];
    loop {
        let t = start.elapsed().as_secs_f64();
        let dt = t - previous_t;
        previous_t = t;
        // Where the script is.
        let mut left = t;
        let mut running = None;
        for segment in &device.script {
            if let Segment::Pedal(on) = *segment
                && left >= 0.0
            {
                pedal = on;
            }
            if left < segment.seconds() {
                running = Some(*segment);
                break;
            }
            left -= segment.seconds();
        }
        match running {
            Some(Segment::Push { mm_s, .. }) => position += mm_s * dt,
            Some(Segment::Twist { deg_s, .. }) => angle += deg_s * dt,
            Some(Segment::OuterPush { mm_s, .. }) => outer.insertion_mm += mm_s * dt,
            Some(Segment::OuterTwist { deg_s, .. }) => outer.rotation_deg += deg_s * dt,
            _ => {}
        }
        seq = seq.wrapping_add(1);
        let sample = DeviceSample {
            seq,
            device_time_us: start.elapsed().as_micros() as u64,
            insertion_mm: position,
            rotation_deg: angle,
            pedal,
            reset: false,
            outer: device.two_hands.then_some(outer),
        };
        if rng.random::<f64>() < device.loss {
            state.dropped += 1;
        } else {
            // A full socket buffer is loss too.
            let _ = socket.send(&sample.encode());
            state.sent += 1;
        }
        while let Ok(n) = socket.recv(&mut buffer) {
            if rng.random::<f64>() < device.loss {
                continue;
            }
            if let Ok(feedback) = Feedback::decode(&buffer[..n]) {
                if let Some(o) = feedback.outer {
                    state.outer_force_n = o.force_n;
                    state.outer_torque_nmm = o.torque_nmm;
                    state.outer_live = o.live;
                }
                state.received += 1;
                state.force_n = feedback.force_n;
                state.torque_nmm = feedback.torque_nmm;
                state.connected = feedback.connected;
                state.live = feedback.live;
                state.round_trip_ms =
                    (start.elapsed().as_micros() as f64 - feedback.device_time_us as f64) / 1e3;
            }
        }
        state.t_s = t;
        state.position_mm = position;
        state.rotation_deg = angle;
        state.outer_position_mm = outer.insertion_mm;
        state.outer_rotation_deg = outer.rotation_deg;
        if t >= next_report {
            report(&state);
            next_report += device.report_every_s;
        }
        if t >= total {
            return Ok(state);
        }
        next_tick += period;
        let now = Instant::now();
        if next_tick > now {
            std::thread::sleep(next_tick - now);
        } else {
            next_tick = now;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scripts_parse_and_bad_ones_say_which_segment() {
        assert_eq!(
            parse_script("hold:0.5, push:15:4,twist:-90:1,pedal:on").unwrap(),
            vec![
                Segment::Hold { seconds: 0.5 },
                Segment::Push {
                    mm_s: 15.0,
                    seconds: 4.0
                },
                Segment::Twist {
                    deg_s: -90.0,
                    seconds: 1.0
                },
                Segment::Pedal(true),
            ]
        );
        let err = parse_script("hold:1,push:fast:2").unwrap_err();
        assert_eq!(err.index, 1);
        assert!(err.to_string().contains("speed \"fast\""), "{err}");
        assert!(
            parse_script("hold:-1")
                .unwrap_err()
                .to_string()
                .contains("duration")
        );
        assert!(
            parse_script("jump:1")
                .unwrap_err()
                .to_string()
                .contains("expected")
        );
        assert!(parse_script("push:NaN:1").is_err());
        let two = parse_script("outer-push:10:1,outer-twist:-45:0.5,push:5:1").unwrap();
        assert_eq!(
            two[0],
            Segment::OuterPush {
                mm_s: 10.0,
                seconds: 1.0
            }
        );
        assert!(moves_outer_hand(&two));
        assert!(!moves_outer_hand(&parse_script("push:5:1,hold:1").unwrap()));
        assert!(
            parse_script("outer-push:x:1")
                .unwrap_err()
                .to_string()
                .contains("speed")
        );
    }
}
