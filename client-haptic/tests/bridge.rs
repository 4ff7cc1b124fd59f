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

/// A two-channel device (protocol version 2) on a coaxial scene: the outer hand pushes the
/// catheter into the capped LCCA while the inner hand holds the wire inside it. The outer
/// hand feels the wall; the wire's hand does not. Then a one-channel device (version 1) on
/// the same bridge and scene drives the innermost instrument, as before.
#[test]
fn a_two_hand_device_feels_the_catheter_apart_from_the_wire() {
    let dir = std::env::temp_dir().join(format!("cathlab-haptic-two-{}", std::process::id()));
    let database = dir.join("haptic.sqlite");
    let Rig {
        server,
        mut bridge,
        udp,
        ..
    } = Rig::start_with(&dir, &database, &common::coaxial_wall_scene());
    let start = bridge.latest();
    // Hold, then the outer hand pushes 75 mm at 15 mm/s: free for ~56 mm, then the cap.
    let samples = device(&udp, "hold:1,outer-push:15:5,hold:0.8", 0.0);
    let end = bridge.latest();
    let outer_free = common::mean_of(&samples, "outer_force_n", 1.5, 3.0);
    let outer_wall = common::mean_of(&samples, "outer_force_n", 6.0, 6.8);
    let inner_wall = common::mean_of(&samples, "force_n", 6.0, 6.8);
    let live = samples.iter().filter(|s| s["outer_live"] == true).count();
    println!(
        "outer hand: free {outer_free:.4} N, at the wall {outer_wall:.4} N; the wire's hand \
         then {inner_wall:.4} N; {live} of {} samples with live outer feedback",
        samples.len()
    );
    println!("bridge before: {start}\nbridge after: {end}");
    assert_eq!(
        end["outer_instrument"], 0,
        "the outer hand holds the catheter"
    );
    assert!(live * 10 >= samples.len() * 8, "outer feedback live");
    assert!(
        outer_wall > 0.05,
        "the catheter's hand feels the wall: {outer_wall} N"
    );
    assert!(
        outer_wall > 3.0 * outer_free.abs().max(0.005),
        "the catheter's force rises at the wall: {outer_free} → {outer_wall} N"
    );
    assert!(
        outer_wall > 3.0 * inner_wall.abs().max(0.005),
        "the wire's hand does not feel the catheter's wall: {inner_wall} vs {outer_wall} N"
    );
    let advanced =
        end["outer_inserted_mm"].as_f64().unwrap() - start["outer_inserted_mm"].as_f64().unwrap();
    let wire = end["inserted_mm"].as_f64().unwrap() - start["inserted_mm"].as_f64().unwrap();
    assert!(advanced > 40.0, "the catheter advanced {advanced} mm");
    assert!(wire.abs() < 2.0, "the wire held still: {wire} mm");

    // A one-channel device: its push drives the wire (the innermost).
    let before = bridge.latest();
    let one = device(&udp, "hold:0.5,push:15:1.5,hold:0.3", 0.0);
    let after = bridge.latest();
    assert!(
        one.iter().all(|s| s["outer_force_n"] == 0.0),
        "no outer channel for version 1"
    );
    let wire = after["inserted_mm"].as_f64().unwrap() - before["inserted_mm"].as_f64().unwrap();
    let catheter = after["outer_inserted_mm"].as_f64().unwrap()
        - before["outer_inserted_mm"].as_f64().unwrap();
    println!("one-channel device: wire {wire:+.1} mm, catheter {catheter:+.1} mm");
    assert!(
        wire > 10.0,
        "a one-channel device pushes the wire: {wire} mm"
    );
    assert!(
        catheter.abs() < 2.0,
        "and leaves the catheter: {catheter} mm"
    );

    drop(bridge.child.stdin.take());
    assert!(bridge.child.wait().unwrap().success());
    server.stop();
    let _ = std::fs::remove_dir_all(&dir);
}
