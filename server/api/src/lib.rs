//! The wire API (`proto/cathlab/v1`, package `cathlab.v1`): generated messages and the
//! `Simulator` service, the encoded descriptor set for reflection, validation of client
//! messages into engine commands (errors name the field), conversions of engine values into
//! messages, and the one place engine errors become gRPC status codes.

use cathlab_engine::telemetry::TimingSummary;
use cathlab_engine::world::Drive;
use cathlab_engine::world::PushLimit;
use cathlab_engine::{Command, EngineError, Event, Metrics, Snapshot};
use tonic::Status;

/// Generated code of `cathlab.v1`.
#[allow(missing_docs, clippy::all)]
pub mod pb {
    tonic::include_proto!("cathlab.v1");
}

/// The encoded `FileDescriptorSet` of the API, for gRPC reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/cathlab_descriptor.bin"));

/// Largest push/pull speed a client may ask for (mm/s); the physics clamps to its own limit.
pub const MAX_PUSH_MM_S: f64 = 500.0;
/// Largest twist rate (deg/s).
pub const MAX_TWIST_DEG_S: f64 = 3600.0;

/// A request carrying `authorization: Bearer <token>`, as every call on a session needs. A
/// token that cannot be a header value is left out, and the server answers UNAUTHENTICATED.
pub fn authorized<T>(message: T, token: &str) -> tonic::Request<T> {
    let mut request = tonic::Request::new(message);
    if let Ok(value) = format!("Bearer {token}").parse() {
        request.metadata_mut().insert("authorization", value);
    }
    request
}

/// The gRPC status for an engine error.
pub fn status_of(error: &EngineError) -> Status {
    match error {
        EngineError::Scene { .. } | EngineError::InvalidArgument { .. } => {
            Status::invalid_argument(error.to_string())
        }
        EngineError::FailedPrecondition(_) => Status::failed_precondition(error.to_string()),
        EngineError::NotFound(_) => Status::not_found(error.to_string()),
        EngineError::Cancelled(_) => Status::cancelled(error.to_string()),
        EngineError::Closed(_) => Status::failed_precondition(error.to_string()),
        EngineError::QueueFull(_) | EngineError::Exhausted(_) => {
            Status::resource_exhausted(error.to_string())
        }
        EngineError::Io { .. }
        | EngineError::Anatomy(_)
        | EngineError::Imaging(_)
        | EngineError::Physics(_)
        | EngineError::Hemo(_)
        | EngineError::Xray(_)
        | EngineError::Spawn(_) => Status::internal(error.to_string()),
        // The recording cannot be written (the database is unreachable): try again later.
        EngineError::Store(_) => Status::unavailable(error.to_string()),
    }
}

/// `value` if finite and within `lo..=hi`, else INVALID_ARGUMENT naming `field`.
pub fn checked(field: &str, value: f64, lo: f64, hi: f64) -> Result<f64, Status> {
    if !value.is_finite() {
        return Err(Status::invalid_argument(format!(
            "{field}: {value} is not a finite number"
        )));
    }
    if value < lo || value > hi {
        return Err(Status::invalid_argument(format!(
            "{field}: {value} is outside {lo}..={hi}"
        )));
    }
    Ok(value)
}

/// A wire command as an engine command (SI units), every number checked.
pub fn command_from_wire(command: Option<&pb::Command>) -> Result<Command, Status> {
    let kind = command
        .and_then(|c| c.kind.as_ref())
        .ok_or_else(|| Status::invalid_argument("command: missing"))?;
    let plain = plain_command(kind)?;
    let Some(index) = command.and_then(|c| c.instrument) else {
        return Ok(plain);
    };
    let drive = match plain {
        Command::PushVelocity(v) => Drive::PushVelocity(v),
        Command::PushTarget(x) => Drive::PushTarget(x),
        Command::TwistRate(w) => Drive::TwistRate(w),
        Command::TwistTarget(a) => Drive::TwistTarget(a),
        _ => {
            return Err(Status::invalid_argument(
                "command.instrument: only an insertion or a twist names an instrument",
            ));
        }
    };
    if index as usize >= cathlab_engine::scene::MAX_STACK {
        return Err(Status::invalid_argument(format!(
            "command.instrument: {index} is not an instrument (a stack has at most {})",
            cathlab_engine::scene::MAX_STACK
        )));
    }
    Ok(Command::Instrument { index, drive })
}

/// A command without its instrument.
fn plain_command(kind: &pb::command::Kind) -> Result<Command, Status> {
    use pb::command::Kind;
    Ok(match kind {
        Kind::Insertion(i) => match i.mode {
            Some(pb::insertion::Mode::VelocityMmS(v)) => Command::PushVelocity(
                checked(
                    "command.insertion.velocity_mm_s",
                    v,
                    -MAX_PUSH_MM_S,
                    MAX_PUSH_MM_S,
                )? * 1e-3,
            ),
            Some(pb::insertion::Mode::TargetMm(x)) => {
                Command::PushTarget(checked("command.insertion.target_mm", x, 0.0, 5000.0)? * 1e-3)
            }
            None => return Err(Status::invalid_argument("command.insertion.mode: missing")),
        },
        Kind::Twist(t) => match t.mode {
            Some(pb::twist::Mode::RateDegS(w)) => Command::TwistRate(
                checked(
                    "command.twist.rate_deg_s",
                    w,
                    -MAX_TWIST_DEG_S,
                    MAX_TWIST_DEG_S,
                )?
                .to_radians(),
            ),
            Some(pb::twist::Mode::TargetDeg(a)) => Command::TwistTarget(
                checked("command.twist.target_deg", a, -36000.0, 36000.0)?.to_radians(),
            ),
            None => return Err(Status::invalid_argument("command.twist.mode: missing")),
        },
        Kind::SelectDevice(i) => Command::SelectDevice(*i),
        Kind::Fluoroscopy(on) => Command::Fluoroscopy(*on),
        Kind::PulseRate(rate) => Command::PulseRate(match pb::PulseRate::try_from(*rate) {
            Ok(pb::PulseRate::PulseRate75) => cathlab_xray::PulseRate::Hz7_5,
            Ok(pb::PulseRate::PulseRate15) => cathlab_xray::PulseRate::Hz15,
            Ok(pb::PulseRate::PulseRate30) => cathlab_xray::PulseRate::Hz30,
            _ => {
                return Err(Status::invalid_argument(format!(
                    "command.pulse_rate: {rate} is not 7.5, 15 or 30 pulses per second"
                )));
            }
        }),
        Kind::Dsa(on) => Command::Dsa(*on),
        Kind::Roadmap(on) => Command::Roadmap(*on),
        Kind::Carm(pose) => Command::CArm {
            primary_deg: checked("command.carm.primary_deg", pose.primary_deg, -120.0, 120.0)?,
            secondary_deg: checked(
                "command.carm.secondary_deg",
                pose.secondary_deg,
                -60.0,
                60.0,
            )?,
        },
        Kind::Inject(inj) => {
            let volume_ml = checked("command.inject.volume_ml", inj.volume_ml, 0.0, 20.0)?;
            let rate_ml_s = checked("command.inject.rate_ml_s", inj.rate_ml_s, 0.0, 10.0)?;
            if volume_ml <= 0.0 || rate_ml_s <= 0.0 {
                return Err(Status::invalid_argument(
                    "command.inject: volume_ml and rate_ml_s must be above 0",
                ));
            }
            Command::Inject {
                volume_ml,
                rate_ml_s,
            }
        }
        Kind::Reset(_) => Command::Reset,
        Kind::Aspiration(on) => Command::Aspiration(*on),
        Kind::Demonstrate(on) => Command::Demonstrate(*on),
        Kind::Thrombectomy(action) => match pb::ThrombectomyAction::try_from(*action) {
            Ok(pb::ThrombectomyAction::DeployStent) => Command::DeployStent,
            Ok(pb::ThrombectomyAction::RetrieveStent) => Command::RetrieveStent,
            _ => {
                return Err(Status::invalid_argument(format!(
                    "command.thrombectomy: {action} is not a thrombectomy action \
                     (DEPLOY_STENT or RETRIEVE_STENT)"
                )));
            }
        },
        Kind::Load(x) => match &x.device {
            Some(pb::load::Device::CatalogueId(id)) => Command::Load {
                catalogue: catalogue_index(id, "command.load.catalogue_id")?,
            },
            Some(pb::load::Device::Spare(spare)) => Command::LoadSpare { spare: *spare },
            None => {
                return Err(Status::invalid_argument(
                    "command.load.device: missing (a catalogue_id or a spare)",
                ));
            }
        },
        Kind::Unload(_) => Command::Unload,
        Kind::Exchange(x) => {
            let index = x.instrument;
            match &x.device {
                Some(pb::exchange::Device::CatalogueId(id)) => Command::Exchange {
                    index,
                    catalogue: catalogue_index(id, "command.exchange.catalogue_id")?,
                },
                Some(pb::exchange::Device::Spare(spare)) => Command::ExchangeSpare {
                    index,
                    spare: *spare,
                },
                None => {
                    return Err(Status::invalid_argument(
                        "command.exchange.device: missing (a catalogue_id or a spare)",
                    ));
                }
            }
        }
    })
}

/// The index of catalogue entry `id`; INVALID_ARGUMENT naming `field` when there is none.
fn catalogue_index(id: &str, field: &str) -> Result<u32, Status> {
    let entries = cathlab_engine::scene::catalogue().entries();
    entries
        .iter()
        .position(|e| e.id == id)
        .map(|k| k as u32)
        .ok_or_else(|| {
            Status::invalid_argument(format!(
                "{field}: '{}' is not in the device catalogue",
                id.chars().take(64).collect::<String>()
            ))
        })
}

/// A haptic bridge input as engine commands, for a scene of `instruments` instruments: the
/// one-channel setpoints (driving the innermost), or one `Instrument` setpoint per hand.
pub fn control_from_wire(
    input: &pb::ControlInput,
    instruments: u32,
) -> Result<Vec<Command>, Status> {
    // The field's path is written only on the error path (inputs arrive at 1 kHz).
    let speeds = |prefix: &str, push_mm_s: f64, twist_deg_s: f64| -> Result<(f64, f64), Status> {
        let named = |e: Status| Status::invalid_argument(format!("{prefix}{}", e.message()));
        Ok((
            checked("push_mm_s", push_mm_s, -MAX_PUSH_MM_S, MAX_PUSH_MM_S).map_err(named)? * 1e-3,
            checked(
                "twist_deg_s",
                twist_deg_s,
                -MAX_TWIST_DEG_S,
                MAX_TWIST_DEG_S,
            )
            .map_err(named)?
            .to_radians(),
        ))
    };
    if input.hands.is_empty() {
        let (push_m_s, twist_rad_s) = speeds("", input.push_mm_s, input.twist_deg_s)?;
        return Ok(vec![Command::Setpoints {
            push_m_s,
            twist_rad_s,
        }]);
    }
    if input.push_mm_s != 0.0 || input.twist_deg_s != 0.0 {
        return Err(Status::invalid_argument(
            "push_mm_s, twist_deg_s: must be 0 when hands are given (each hand names its instrument)",
        ));
    }
    let mut seen = 0u64;
    input
        .hands
        .iter()
        .enumerate()
        .map(|(i, hand)| {
            if hand.instrument >= instruments {
                return Err(Status::invalid_argument(format!(
                    "hands[{i}].instrument: {} is not an instrument of this scene, which has \
                     {instruments} (0 is the outermost)",
                    hand.instrument
                )));
            }
            // Fewer than 64 instruments: checked above against the scene's stack.
            let bit = 1u64 << hand.instrument.min(63);
            if seen & bit != 0 {
                return Err(Status::invalid_argument(format!(
                    "hands[{i}].instrument: {} is driven twice in one input",
                    hand.instrument
                )));
            }
            seen |= bit;
            let (push_m_s, twist_rad_s) =
                speeds(&format!("hands[{i}]."), hand.push_mm_s, hand.twist_deg_s)?;
            Ok(Command::Instrument {
                index: hand.instrument,
                drive: Drive::Setpoints {
                    push_m_s,
                    twist_rad_s,
                },
            })
        })
        .collect()
}

fn vec3_mm(v: &nalgebra::Vector3<f64>) -> pb::Vec3 {
    pb::Vec3 {
        x: v.x * 1e3,
        y: v.y * 1e3,
        z: v.z * 1e3,
    }
}

fn vec3(x: f64, y: f64, z: f64) -> pb::Vec3 {
    pb::Vec3 { x, y, z }
}

/// Node positions as x y z per node (mm, f32); none when `tip_only`.
fn nodes_to_wire(nodes: &[nalgebra::Vector3<f64>], tip_only: bool) -> Vec<f32> {
    if tip_only {
        return Vec::new();
    }
    nodes
        .iter()
        .flat_map(|n| [n.x as f32 * 1e3, n.y as f32 * 1e3, n.z as f32 * 1e3])
        .collect()
}

/// A snapshot on the wire (mm, N, N·mm); `tip_only` leaves out the nodes.
pub fn state_to_wire(s: &Snapshot, tip_only: bool, server_unix_us: u64) -> pb::DeviceState {
    let p = &s.proximal;
    let (axial_force_n, axial_torque_nm) = s.axial_reaction();
    pb::DeviceState {
        step: s.step,
        time_s: s.time_s,
        last_seq: s.last_seq,
        nodes_mm: nodes_to_wire(&s.nodes, tip_only),
        tip_position_mm: Some(vec3_mm(&s.tip())),
        tip_direction: Some(vec3(
            s.tip_direction.x,
            s.tip_direction.y,
            s.tip_direction.z,
        )),
        inserted_mm: s.inserted_m * 1e3,
        twist_deg: s.twist_rad.to_degrees(),
        // Contacts stay with tip_only: they are few, and the HUD's wall-force warning needs them.
        contacts: s
            .contacts
            .iter()
            .map(|c| pb::WallContact {
                position: Some(vec3_mm(&c.position)),
                force: Some(vec3(c.force.x, c.force.y, c.force.z)),
            })
            .collect(),
        proximal_force_n: Some(vec3(p[0], p[1], p[2])),
        proximal_torque_nmm: Some(vec3(p[3] * 1e3, p[4] * 1e3, p[5] * 1e3)),
        active_device: s.active_device,
        server_unix_us,
        axial_force_n,
        axial_torque_nmm: axial_torque_nm * 1e3,
        push_limit: push_limit_to_wire(s.push_limit) as i32,
        push_force_limit_n: s.push_force_limit_n,
        fidelity_level: u32::from(s.fidelity_level),
        instruments: s
            .instruments
            .iter()
            .enumerate()
            .map(|(k, i)| pb::InstrumentState {
                name: i.name.clone(),
                catalogue_id: i.catalogue_id.clone(),
                nodes_mm: nodes_to_wire(&i.nodes, tip_only),
                inserted_mm: i.inserted_m * 1e3,
                twist_deg: i.twist_rad.to_degrees(),
                tip_position_mm: i.tip.as_ref().map(vec3_mm),
                beyond_outer_mm: k
                    .checked_sub(1)
                    .map_or(0.0, |o| (i.inserted_m - s.instruments[o].inserted_m) * 1e3),
                axial_force_n: i.axial_force_n,
                axial_torque_nmm: i.torque_nm * 1e3,
                push_limit: push_limit_to_wire(i.push_limit) as i32,
                push_force_limit_n: i.push_force_limit_n,
            })
            .collect(),
    }
}

fn push_limit_to_wire(limit: PushLimit) -> pb::PushLimit {
    match limit {
        PushLimit::None => pb::PushLimit::None,
        PushLimit::Force => pb::PushLimit::Force,
        PushLimit::Length => pb::PushLimit::Length,
    }
}

/// Metrics on the wire.
pub fn metrics_to_wire(m: &Metrics) -> pb::Metrics {
    pb::Metrics {
        procedure_time_s: m.procedure_time_s,
        fluoroscopy_time_s: m.fluoroscopy_time_s,
        dsa_runs: m.dsa_runs,
        contrast_volume_ml: m.contrast_volume_ml,
        max_wall_force_n: m.max_wall_force_n,
        mean_wall_force_n: m.mean_wall_force_n,
        tip_path_length_mm: m.tip_path_length_m * 1e3,
        target_reached: m.target_reached_at_s.is_some(),
        target_reached_at_s: m.target_reached_at_s.unwrap_or(0.0),
        steps: m.steps,
        divergence_resets: m.divergence_resets,
        operator_resets: m.operator_resets,
        attempt_started_at_s: m.attempt_started_at_s,
        target_remaining_mm: m.target_remaining_m * 1e3,
        instruments: m
            .instruments
            .iter()
            .take(m.instrument_count as usize)
            .map(|i| pb::InstrumentMetrics {
                tip_path_length_mm: i.tip_path_length_m * 1e3,
                moving_time_s: i.moving_time_s,
                peak_axial_force_n: i.peak_axial_force_n,
            })
            .collect(),
        leading_instrument: u32::from(m.leading_instrument),
        lead_changes: m.lead_changes,
        passed_inner_tip: m.passed_inner_tip,
        reperfusion: m.reperfusion.map(|r| pb::Reperfusion {
            fraction: r.fraction,
            etici: r.etici.label().into(),
        }),
        thrombectomy: m.thrombectomy.map(|t| pb::Thrombectomy {
            passes: t.passes,
            first_pass_effect: t.first_pass_effect,
            emboli: t.emboli,
            crossing_force_n: t.crossing_force_n,
            peak_crossing_force_n: t.peak_crossing_force_n,
            grip_n: t.grip_n,
            aspiration: t.aspiration,
            reperfused_at_s: t.reperfused_at_s,
        }),
    }
}

/// Thread timing on the wire (ms).
pub fn timing_to_wire(t: &TimingSummary) -> pb::Timing {
    pb::Timing {
        steps: t.steps,
        late_steps: t.late_steps,
        missed_steps: t.missed_steps,
        step_time_p50_ms: t.step_p50_s * 1e3,
        step_time_p99_ms: t.step_p99_s * 1e3,
        step_time_max_ms: t.step_max_s * 1e3,
        frames: t.frames,
        frame_time_p50_ms: t.frame_p50_s * 1e3,
        frame_time_p99_ms: t.frame_p99_s * 1e3,
        frame_time_max_ms: t.frame_max_s * 1e3,
    }
}

/// An event on the wire.
pub fn event_to_wire(e: &Event) -> pb::Event {
    pb::Event {
        step: e.step,
        time_s: e.time_s,
        kind: e.kind.as_str().into(),
        message: e.message.clone(),
    }
}

/// The wire imaging mode.
pub fn mode_to_wire(mode: cathlab_xray::ImagingMode) -> pb::ImagingMode {
    match mode {
        cathlab_xray::ImagingMode::Fluoroscopy => pb::ImagingMode::Fluoroscopy,
        cathlab_xray::ImagingMode::Subtraction => pb::ImagingMode::Subtraction,
        cathlab_xray::ImagingMode::Roadmap => pb::ImagingMode::Roadmap,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reperfusion_goes_on_the_wire_with_its_grade_as_written() {
        let mut m = Metrics::default();
        assert!(metrics_to_wire(&m).reperfusion.is_none());
        m.reperfusion = Some(cathlab_engine::metrics::ReperfusionMetric {
            fraction: 0.7,
            etici: cathlab_engine::metrics::Etici::of_fraction(0.7),
        });
        let wire = metrics_to_wire(&m).reperfusion.unwrap();
        assert_eq!((wire.fraction, wire.etici.as_str()), (0.7, "2b67"));
    }

    fn push(v: f64) -> pb::Command {
        pb::Command {
            kind: Some(pb::command::Kind::Insertion(pb::Insertion {
                mode: Some(pb::insertion::Mode::VelocityMmS(v)),
                hold: false,
            })),
            instrument: None,
        }
    }

    #[test]
    fn control_inputs_are_checked_by_field() {
        let input = |push_mm_s, twist_deg_s| pb::ControlInput {
            session_id: String::new(),
            seq: 1,
            push_mm_s,
            twist_deg_s,
            hands: Vec::new(),
        };
        for (bad, field) in [
            (input(f64::NAN, 0.0), "push_mm_s"),
            (input(1e6, 0.0), "push_mm_s"),
            (input(0.0, f64::NEG_INFINITY), "twist_deg_s"),
        ] {
            let err = control_from_wire(&bad, 1).unwrap_err();
            assert_eq!(err.code(), tonic::Code::InvalidArgument);
            assert!(err.message().starts_with(field), "{}", err.message());
        }
        assert_eq!(
            control_from_wire(&input(10.0, 180.0), 1).unwrap(),
            vec![Command::Setpoints {
                push_m_s: 0.01,
                twist_rad_s: std::f64::consts::PI,
            }]
        );
    }

    #[test]
    fn two_hand_control_inputs_drive_their_instruments_and_bad_ones_are_named() {
        let hand = |instrument, push_mm_s, twist_deg_s| pb::HandSetpoint {
            instrument,
            push_mm_s,
            twist_deg_s,
        };
        let input = |hands: Vec<pb::HandSetpoint>| pb::ControlInput {
            session_id: String::new(),
            seq: 1,
            push_mm_s: 0.0,
            twist_deg_s: 0.0,
            hands,
        };
        assert_eq!(
            control_from_wire(&input(vec![hand(0, 5.0, 0.0), hand(2, -10.0, 90.0)]), 3).unwrap(),
            vec![
                Command::Instrument {
                    index: 0,
                    drive: Drive::Setpoints {
                        push_m_s: 0.005,
                        twist_rad_s: 0.0
                    }
                },
                Command::Instrument {
                    index: 2,
                    drive: Drive::Setpoints {
                        push_m_s: -0.01,
                        twist_rad_s: std::f64::consts::FRAC_PI_2
                    }
                },
            ]
        );
        let mut both = input(vec![hand(0, 5.0, 0.0)]);
        both.push_mm_s = 1.0;
        for (bad, instruments, expected) in [
            (
                input(vec![hand(2, 1.0, 0.0)]),
                2,
                "hands[0].instrument: 2 is not an instrument",
            ),
            (
                input(vec![hand(0, 1.0, 0.0), hand(0, 2.0, 0.0)]),
                2,
                "hands[1].instrument: 0 is driven twice",
            ),
            (
                input(vec![hand(0, 0.0, 0.0), hand(1, f64::NAN, 0.0)]),
                2,
                "hands[1].push_mm_s: NaN is not a finite number",
            ),
            (input(vec![hand(1, 0.0, 1e9)]), 2, "hands[0].twist_deg_s"),
            (both, 2, "push_mm_s, twist_deg_s: must be 0"),
        ] {
            let err = control_from_wire(&bad, instruments).unwrap_err();
            assert_eq!(err.code(), tonic::Code::InvalidArgument);
            assert!(err.message().starts_with(expected), "{}", err.message());
        }
    }

    #[test]
    fn an_instrument_and_an_exchange_are_checked_and_named() {
        let mut on_wire = push(10.0);
        on_wire.instrument = Some(1);
        assert_eq!(
            command_from_wire(Some(&on_wire)).unwrap(),
            Command::Instrument {
                index: 1,
                drive: Drive::PushVelocity(0.01)
            }
        );
        on_wire.instrument = Some(9);
        let err = command_from_wire(Some(&on_wire)).unwrap_err();
        assert_eq!(err.code(), tonic::Code::InvalidArgument);
        assert!(
            err.message().starts_with("command.instrument"),
            "{}",
            err.message()
        );
        let reset = pb::Command {
            kind: Some(pb::command::Kind::Reset(true)),
            instrument: Some(0),
        };
        let err = command_from_wire(Some(&reset)).unwrap_err();
        assert!(
            err.message().starts_with("command.instrument"),
            "{}",
            err.message()
        );
        let exchange = |device| pb::Command {
            kind: Some(pb::command::Kind::Exchange(pb::Exchange {
                instrument: 1,
                device,
            })),
            instrument: None,
        };
        let unknown = exchange(Some(pb::exchange::Device::CatalogueId("wire-099".into())));
        let err = command_from_wire(Some(&unknown)).unwrap_err();
        assert!(
            err.message()
                .starts_with("command.exchange.catalogue_id: 'wire-099'"),
            "{}",
            err.message()
        );
        let err = command_from_wire(Some(&exchange(None))).unwrap_err();
        assert!(err.message().starts_with("command.exchange.device"));
        let known = exchange(Some(pb::exchange::Device::CatalogueId(
            "microwire-014-j".into(),
        )));
        match command_from_wire(Some(&known)).unwrap() {
            Command::Exchange { index, catalogue } => {
                assert_eq!(index, 1);
                let entry = &cathlab_engine::scene::catalogue().entries()[catalogue as usize];
                assert_eq!(entry.id, "microwire-014-j");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_load_names_its_device_and_an_unload_needs_nothing() {
        let load = |device| pb::Command {
            kind: Some(pb::command::Kind::Load(pb::Load { device })),
            instrument: None,
        };
        let err = command_from_wire(Some(&load(None))).unwrap_err();
        assert!(err.message().starts_with("command.load.device"), "{err}");
        let err = command_from_wire(Some(&load(Some(pb::load::Device::CatalogueId(
            "wire-099".into(),
        )))))
        .unwrap_err();
        assert!(
            err.message()
                .starts_with("command.load.catalogue_id: 'wire-099'"),
            "{err}"
        );
        match command_from_wire(Some(&load(Some(pb::load::Device::CatalogueId(
            "microcatheter-021-160".into(),
        )))))
        .unwrap()
        {
            Command::Load { catalogue } => {
                let entry = &cathlab_engine::scene::catalogue().entries()[catalogue as usize];
                assert_eq!(entry.id, "microcatheter-021-160");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            command_from_wire(Some(&load(Some(pb::load::Device::Spare(2))))).unwrap(),
            Command::LoadSpare { spare: 2 }
        );
        let unload = pb::Command {
            kind: Some(pb::command::Kind::Unload(pb::Unload {})),
            instrument: None,
        };
        assert_eq!(command_from_wire(Some(&unload)).unwrap(), Command::Unload);
    }

    #[test]
    fn thrombectomy_commands_and_figures_cross_the_wire() {
        let command = |kind| pb::Command {
            kind: Some(kind),
            instrument: None,
        };
        let deploy = command(pb::command::Kind::Thrombectomy(
            pb::ThrombectomyAction::DeployStent as i32,
        ));
        assert_eq!(
            command_from_wire(Some(&deploy)).unwrap(),
            Command::DeployStent
        );
        let retrieve = command(pb::command::Kind::Thrombectomy(
            pb::ThrombectomyAction::RetrieveStent as i32,
        ));
        assert_eq!(
            command_from_wire(Some(&retrieve)).unwrap(),
            Command::RetrieveStent
        );
        for bad in [0, 3, -1, 99] {
            let err = command_from_wire(Some(&command(pb::command::Kind::Thrombectomy(bad))))
                .unwrap_err();
            assert_eq!(err.code(), tonic::Code::InvalidArgument);
            assert!(
                err.message().starts_with("command.thrombectomy"),
                "{}",
                err.message()
            );
        }
        let suction = command(pb::command::Kind::Aspiration(true));
        assert_eq!(
            command_from_wire(Some(&suction)).unwrap(),
            Command::Aspiration(true)
        );
        let mut m = cathlab_engine::Metrics::default();
        assert!(metrics_to_wire(&m).thrombectomy.is_none());
        m.thrombectomy = Some(cathlab_engine::metrics::ThrombectomyMetric {
            passes: 2,
            first_pass_effect: false,
            emboli: 1,
            reperfused_at_s: Some(41.5),
            ..Default::default()
        });
        let wire = metrics_to_wire(&m).thrombectomy.unwrap();
        assert_eq!((wire.passes, wire.emboli), (2, 1));
        assert_eq!(wire.reperfused_at_s, Some(41.5));
    }

    #[test]
    fn non_finite_and_out_of_range_values_name_their_field() {
        for bad in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e4] {
            let err = command_from_wire(Some(&push(bad))).unwrap_err();
            assert_eq!(err.code(), tonic::Code::InvalidArgument);
            assert!(
                err.message().contains("command.insertion.velocity_mm_s"),
                "{}",
                err.message()
            );
        }
        assert_eq!(
            command_from_wire(Some(&push(20.0))).unwrap(),
            Command::PushVelocity(0.02)
        );
        let missing = command_from_wire(None).unwrap_err();
        assert!(missing.message().starts_with("command"));
        let carm = pb::Command {
            kind: Some(pb::command::Kind::Carm(pb::CArmPose {
                primary_deg: 0.0,
                secondary_deg: f64::NAN,
            })),
            instrument: None,
        };
        assert!(
            command_from_wire(Some(&carm))
                .unwrap_err()
                .message()
                .contains("command.carm.secondary_deg")
        );
        let rate = pb::Command {
            kind: Some(pb::command::Kind::PulseRate(0)),
            instrument: None,
        };
        assert!(
            command_from_wire(Some(&rate))
                .unwrap_err()
                .message()
                .contains("command.pulse_rate")
        );
    }
}
