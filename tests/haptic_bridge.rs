//! The bridge end to end: a real cathlab server (in this process, on loopback), the bridge
//! and a scripted virtual device as separate processes. The device pushes a straight wire
//! into the capped end of the real LCCA: the rendered force rises. With 10 % of datagrams
//! dropped each way; and the server is stopped and started again under the bridge, which
//! reconnects, makes a new session and renders again.

use cathlab_tests::haptic::{Rig, Server, device, mean_force};

#[test]
fn a_virtual_device_feels_the_wall_through_loss_and_a_server_restart() {
    let _alone = cathlab_tests::haptic::one_at_a_time();
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

/// A two-channel device (protocol version 2) on a coaxial scene: the inner hand pushes the
/// microwire out of the parked catheter into the capped end of the LCCA. The wire's hand
/// feels the wall; the catheter's hand, on the other channel, far less. Then the outer hand
/// pulls the catheter back over the still wire, and a one-channel device (version 1) on the
/// same bridge and scene drives the innermost instrument, as before.
#[test]
fn a_two_hand_device_feels_the_wire_apart_from_the_catheter() {
    let _alone = cathlab_tests::haptic::one_at_a_time();
    let dir = std::env::temp_dir().join(format!("cathlab-haptic-two-{}", std::process::id()));
    let database = dir.join("haptic.sqlite");
    let Rig {
        server,
        mut bridge,
        udp,
        ..
    } = Rig::start_with(
        &dir,
        &database,
        &cathlab_tests::haptic::coaxial_wall_scene(),
    );
    let field = |v: &serde_json::Value, name: &str| v[name].as_f64().unwrap();
    // Hold (the baseline), then the wire goes 36 mm at 15 mm/s: free for ~26 mm, then 10 mm
    // into the cap, and is held there. The hands are compared by their peak force over the
    // push and the hold against their rest: a wire pressed on the cap may buckle and relax, so
    // a mean over a late window depends on how it folded.
    let samples = cathlab_tests::haptic::two_hand_device(&udp, "hold:1,push:15:2.4,hold:1.2");
    let report = bridge.latest();
    let rest = |f: &str| cathlab_tests::haptic::mean_of(&samples, f, 0.5, 1.0);
    let peak = |f: &str| {
        samples
            .iter()
            .filter(|s| s["t_s"].as_f64().unwrap() >= 1.0)
            .map(|s| s[f].as_f64().unwrap())
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let wall = peak;
    let wire = wall("force_n") - rest("force_n");
    let catheter = wall("outer_force_n") - rest("outer_force_n");
    let live = samples.iter().filter(|s| s["outer_live"] == true).count();
    println!(
        "wire into the cap: the wire's hand {:.3} → peak {:.3} N, the catheter's hand {:.3} → \
         peak {:.3} N; {live} of {} samples with live outer feedback",
        rest("force_n"),
        wall("force_n"),
        rest("outer_force_n"),
        wall("outer_force_n"),
        samples.len()
    );
    println!("bridge: {report}");
    assert_eq!(
        report["outer_instrument"], 0,
        "the outer hand holds the catheter"
    );
    assert!(live * 10 >= samples.len() * 8, "outer feedback live");
    assert!(wire > 0.05, "the wire's hand feels the wall: {wire} N more");
    // The catheter's hand feels some of it (the wire, compressed against the cap, rubs on
    // the catheter's lumen and drags it on: about a third in this run), far less than the
    // wire's.
    assert!(
        wire > 2.0 * catheter.abs().max(0.005),
        "the catheter's hand feels much less of the wire's wall: {catheter} vs {wire} N"
    );

    // The outer hand pulls the catheter back 10 mm; the wire stays.
    let before = bridge.latest();
    cathlab_tests::haptic::two_hand_device(&udp, "hold:0.5,outer-push:-10:1,hold:0.3");
    let after = bridge.latest();
    let catheter = field(&after, "outer_inserted_mm") - field(&before, "outer_inserted_mm");
    let wire = field(&after, "inserted_mm") - field(&before, "inserted_mm");
    println!("outer hand pulls: catheter {catheter:+.1} mm, wire {wire:+.1} mm");
    assert!(
        catheter < -5.0,
        "the outer hand withdrew the catheter: {catheter} mm"
    );
    assert!(wire.abs() < 2.0, "the wire held still: {wire} mm");

    // A one-channel device: its pull drives the wire (the innermost).
    let before = bridge.latest();
    let one = device(&udp, "hold:0.5,push:-15:1,hold:0.3", 0.0);
    let after = bridge.latest();
    assert!(
        one.iter().all(|s| s["outer_force_n"] == 0.0),
        "no outer channel in version 1"
    );
    let wire = field(&after, "inserted_mm") - field(&before, "inserted_mm");
    let catheter = field(&after, "outer_inserted_mm") - field(&before, "outer_inserted_mm");
    println!("one-channel device pulls: wire {wire:+.1} mm, catheter {catheter:+.1} mm");
    assert!(
        wire < -8.0,
        "a one-channel device drives the wire: {wire} mm"
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
