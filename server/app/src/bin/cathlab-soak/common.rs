//! What the soak's parts share: the instructor key and the scene, the connection timeouts the
//! soak gives its server and the rest of its configuration, and command builders.

use std::path::PathBuf;

use cathlab_api::pb;

pub(crate) const KEY: &str = "soak-instructor-key";

pub(crate) const SCENE: &str = "arch_to_cow_lcca";

/// How long a connection may be idle, and a request message take to arrive (the soak's
/// `connection_idle_timeout_s` and `message_read_timeout_s`: short, so that the connection
/// attacks resolve within a round).
pub(crate) const IDLE_TIMEOUT_S: u64 = 5;

pub(crate) const MESSAGE_TIMEOUT_S: u64 = 3;

/// The server's limits for the soak: tight timeouts so that stalls and silences are met often;
/// a throttle high enough that the random wrong secrets do not lock the control session out
/// (the throttle has its own attack test); per-client session limits and a per-address
/// connection limit high enough that the random clients, all on 127.0.0.1, and the soak's own
/// reads of `/metrics` are never refused for them (those limits have their own attack tests);
/// a small request buffer, so that HTTP/2 floods meet it; and `data_roots` with the directory
/// of the bomb files.
pub(crate) fn config(data_roots: &[PathBuf]) -> String {
    let roots: Vec<String> = data_roots
        .iter()
        .map(|r| format!("{:?}", r.display().to_string()))
        .collect();
    format!(
        "max_sessions = 8\nmax_replays = 1\ncontrol_timeout_ms = 250\n\
         stream_stall_timeout_ms = 2000\nstream_buffer_mib = 64\n\
         auth_failures_per_minute = 100000\ncontrol_inputs_per_second = 2000\n\
         max_sessions_per_client = 8\nsession_creations_per_minute = 100000\n\
         max_connections_per_address = 192\nconnection_idle_timeout_s = {IDLE_TIMEOUT_S}\n\
         message_read_timeout_s = {MESSAGE_TIMEOUT_S}\nrequest_buffer_mib = 16\n\
         data_roots = [{}]\n",
        roots.join(", ")
    )
}

pub(crate) fn command(kind: pb::command::Kind) -> Option<pb::Command> {
    Some(pb::Command {
        kind: Some(kind),
        instrument: None,
    })
}

pub(crate) fn speed(mm_s: f64, hold: bool) -> pb::command::Kind {
    pb::command::Kind::Insertion(pb::Insertion {
        mode: Some(pb::insertion::Mode::VelocityMmS(mm_s)),
        hold,
    })
}
