//! The bridge end to end: a real cathlab server (in this process, on loopback), the bridge
//! and a scripted virtual device as separate processes. The device pushes a straight wire
//! into the capped end of the real LCCA: the rendered force rises. With 10 % of datagrams
//! dropped each way; and the server is stopped and started again under the bridge, which
//! reconnects, makes a new session and renders again.

mod common;

use common::{Rig, Server, device, mean_force};

#[test]
fn a_virtual_device_feels_the_wall_through_loss_and_a_server_restart() {
    let dir = std::env::temp_dir().join(format!("cathlab-haptic-{}", std::process::id()));
    let database = dir.join("haptic.sqlite");
    let Rig {
        server,
        port,
        mut bridge,
        udp,
    } = Rig::start(&dir, &database);

    // Hold, then push 60 mm at 15 mm/s: free for ~40 mm, then into the cap.
    let samples = device(&udp, "hold:1,push:15:4,hold:0.5", 0.1);
    if std::env::var("HAPTIC_DEBUG").is_ok() {
        for s in &samples {
            println!("{s}");
        }
        while let Ok(v) = bridge.lines.try_recv() {
            println!("{v}");
        }
    }
    let free = mean_force(&samples, 1.3, 2.3);
    let wall = mean_force(&samples, 4.5, 5.5);
    let connected = samples.iter().filter(|s| s["live"] == true).count();
    println!(
        "force: free {free:.4} N, against the wall {wall:.4} N; {connected} of {} samples live",
        samples.len()
    );
    assert!(
        connected * 10 >= samples.len() * 8,
        "feedback live most of the time"
    );
    assert!(wall > 0.05, "the wall pushes back: {wall} N");
    assert!(
        wall > 3.0 * free.abs().max(0.005),
        "force rises at the wall: {free} → {wall} N"
    );
    let report = bridge.latest();
    println!("bridge: {report}");
    let packets = report["device_packets"].as_f64().unwrap();
    let lost = report["device_lost"].as_f64().unwrap();
    let loss = lost / (packets + lost);
    assert!(
        (0.05..0.15).contains(&loss),
        "10 % dropped, {:.1} % counted lost",
        100.0 * loss
    );
    assert!(report["round_trips"].as_u64().unwrap() > 100, "{report}");

    // The server goes away: the bridge stays, reports the loss, the device is told.
    server.stop();
    bridge.until(10.0, "a disconnected report", |v| {
        v["report"]["connected"] == false
    });
    let quiet = device(&udp, "push:10:0.5", 0.0);
    assert!(
        quiet.iter().all(|s| s["live"] == false),
        "no live feedback without a server"
    );

    // Back on the same port: the bridge reconnects and makes a new session.
    let server = Server::start(port, &database);
    let report = bridge.until(30.0, "a reconnected report", |v| {
        v["report"]["connected"] == true && v["report"]["sessions_created"] == 2
    })["report"]
        .clone();
    assert!(report["reconnects"].as_u64().unwrap() >= 1);
    let again = device(&udp, "hold:0.5,push:15:4", 0.0);
    assert!(
        mean_force(&again, 4.0, 4.5) > 0.05,
        "the wall is felt again after the restart"
    );

    drop(bridge.child.stdin.take());
    let stopped = bridge.until(10.0, "the stopped line", |v| v["event"] == "stopped");
    println!("final bridge report: {}", stopped["report"]);
    assert!(bridge.child.wait().unwrap().success());
    server.stop();
    let _ = std::fs::remove_dir_all(&dir);
}
