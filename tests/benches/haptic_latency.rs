//! Bridge timing: a real server (in this process), the bridge and a virtual device (processes)
//! pushing a 0.014" microwire into the capped end of the real LCCA with 10 % datagram loss.
//! Prints the bridge's loop period, setpoint → state round trip, server state age and loss
//! counts. `cargo bench -p cathlab-tests --bench haptic_latency` runs the full 5.5 s script;
//! under `cargo test` (no `--bench` argument) a 1.5 s smoke run.

use cathlab_tests::haptic::{Rig, device};

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let script = if full {
        "hold:1,push:15:4,hold:0.5"
    } else {
        "hold:0.5,push:15:1"
    };
    let dir = std::env::temp_dir().join(format!("cathlab-haptic-bench-{}", std::process::id()));
    let Rig {
        server,
        mut bridge,
        udp,
        ..
    } = Rig::start(&dir, &dir.join("bench.sqlite"));
    device(&udp, script, 0.1);
    drop(bridge.child.stdin.take());
    let r = bridge.until(10.0, "the stopped line", |v| v["event"] == "stopped")["report"].clone();
    let _ = bridge.child.wait();
    server.stop();
    let _ = std::fs::remove_dir_all(&dir);
    let ms = |key: &str| r[key].as_f64().unwrap_or(f64::NAN) / 1e3;
    let packets = r["device_packets"].as_f64().unwrap_or(0.0);
    let lost = r["device_lost"].as_f64().unwrap_or(0.0);
    println!(
        "haptic bridge, script {script}, 10 % loss each way ({} ticks)",
        r["ticks"]
    );
    println!(
        "loop period p50 / p99 / max: {:.3} / {:.3} / {:.3} ms; overruns {}",
        ms("period_p50_us"),
        ms("period_p99_us"),
        ms("period_max_us"),
        r["overruns"]
    );
    println!(
        "setpoint -> state round trip p50 / p99: {} / {} ms ({} measured)",
        r["round_trip_p50_ms"], r["round_trip_p99_ms"], r["round_trips"]
    );
    println!("server state age p99: {} ms", r["state_age_p99_ms"]);
    println!(
        "device datagrams lost: {:.1} %",
        100.0 * lost / (packets + lost).max(1.0)
    );
}
