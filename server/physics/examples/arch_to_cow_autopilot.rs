//! Work in progress (issue 4): an autopilot for the real arch-to-circle-of-Willis anatomy —
//! push along the route, twist the angled tip towards the route ahead, pull back when the tip
//! strays into a side branch. It does not reach its targets yet: the 5 F catheter enters the
//! left subclavian and the retry twist runs away. Run it with
//! `TARGET=LCCA cargo run --release -p cathlab-physics --example arch_to_cow_autopilot`;
//! `DEVICE=wire|micro` (default: the 5 F catheter), `LOOKAHEAD` (route samples, 1 mm each,
//! default 15), `SPEED` (m/s, default 0.02) and `LEGS=1` (route and aim diagnostics) vary it.
//! Tried so far without success: lookahead 15/30/45 mm, 10 and 20 mm/s, all three devices.

use std::path::Path;

use cathlab_anatomy::real::{ARCH_TO_COW_ACCESS_M, load_arch_to_cow};
use cathlab_physics::navigation::{Command, Insertion, Navigation, NavigationSettings, Twist};
use cathlab_physics::presets;
use nalgebra::Point3;

fn main() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let t0 = std::time::Instant::now();
    let anatomy = load_arch_to_cow(&dir).unwrap();
    println!("loaded in {:.1} s", t0.elapsed().as_secs_f64());
    let access = Point3::from(ARCH_TO_COW_ACCESS_M);
    let target = std::env::var("TARGET").unwrap_or("LCCA".into());
    let path = anatomy.graph.path_to(&access, &target).unwrap();
    let route: Vec<(Point3<f64>, f64)> = anatomy.graph.sample_path(&path, 1e-3);
    if std::env::var("LEGS").is_ok() {
        let mut at = 0.0;
        for leg in &path.legs {
            let b = &anatomy.graph.branches[leg.branch];
            println!(
                "leg {} from {:.0} mm: {:.0}..{:.0} mm of {:.0}",
                b.name,
                at * 1e3,
                leg.from_arc * 1e3,
                leg.to_arc * 1e3,
                b.length() * 1e3
            );
            at += (leg.to_arc - leg.from_arc).abs();
        }
        for b in &anatomy.graph.branches {
            println!(
                "branch {}: start {:?} end {:?} r0 {:.1} mm",
                b.name,
                (b.points[0].coords * 1e3).as_slice(),
                (b.points.last().unwrap().coords * 1e3).as_slice(),
                b.radii[0] * 1e3
            );
        }
    }
    let entry = route[0].0.coords;
    let direction = (route[10].0 - route[0].0).normalize();
    println!(
        "route {:.0} mm, entry {:?}, dir {:?}",
        path.length * 1e3,
        (entry * 1e3).as_slice(),
        direction.as_slice()
    );
    let device = match std::env::var("DEVICE").as_deref() {
        Ok("wire") => presets::guidewire_035(),
        Ok("micro") => presets::micro_guidewire_014(),
        _ => presets::diagnostic_catheter_5f(),
    };
    let mut nav = Navigation::new(
        device,
        &anatomy.lumen,
        entry,
        direction,
        0.01,
        NavigationSettings::default(),
    )
    .unwrap();
    let mut twist_target = 0.0;
    let mut worst: f64 = 0.0;
    let mut max_step = 0.0f64;
    let mut pull_until: Option<f64> = None;
    let mut step_times: Vec<f64> = Vec::new();
    let mut retries = 0usize;
    let mut aim_offset = 0.0;
    let offsets = [
        0.0,
        std::f64::consts::FRAC_PI_2,
        -std::f64::consts::FRAC_PI_2,
        std::f64::consts::PI,
    ];
    for step in 0..15000 {
        // Where is the tip along the route?
        let tip = nav.tip_position();
        let (index, distance) = route
            .iter()
            .enumerate()
            .map(|(i, (p, _))| (i, (p.coords - tip).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        let radius = route[index].1;
        let axis = nav.tip_axis();
        let lookahead: usize = std::env::var("LOOKAHEAD")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(15);
        let ahead = route[(index + lookahead).min(route.len() - 1)].0.coords;
        let d = (ahead - tip).normalize();
        let want = d - axis * d.dot(&axis);
        if let Some(bend) = nav.tip_bend_direction()
            && want.norm() > 0.05
        {
            // Aim the bend at the route ahead, turned by the retry offset.
            let angle = bend.cross(&want).dot(&axis).atan2(bend.dot(&want));
            twist_target = nav.twist_rad() + angle + aim_offset;
            if std::env::var("LEGS").is_ok() && (1800..2700).contains(&step) && step % 50 == 0 {
                println!(
                    "  step {step}: aim error {angle:+.2} rad, twist {:.2}, tip {:?}",
                    nav.twist_rad(),
                    (tip * 1e3).map(|v| v.round()).as_slice()
                );
            }
        }
        let here = anatomy.graph.nearest(&Point3::from(tip)).unwrap().branch;
        // Strayed: nearest to a branch off the route and outside the route's own lumen.
        let off_route = !path.legs.iter().any(|l| l.branch == here) && distance > radius;
        if off_route && pull_until.is_none() && std::env::var("LEGS").is_ok() {
            println!(
                "strayed at step {step}: tip {:?} mm near {}",
                (tip * 1e3).as_slice(),
                anatomy.graph.branches[here].name
            );
        }
        if off_route && pull_until.is_none() {
            // Strayed into a side branch: back off 15 mm, twisting towards the route.
            pull_until = Some(nav.inserted_m() - 0.015);
            retries += 1;
            aim_offset = offsets[retries % offsets.len()];
        }
        if pull_until.is_some_and(|x| nav.inserted_m() <= x) {
            pull_until = None;
        }
        let push_speed: f64 = std::env::var("SPEED")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.02);
        let speed = if pull_until.is_some() {
            -push_speed
        } else {
            push_speed
        };
        nav.set_command(Command {
            insertion: Insertion::Velocity(speed),
            twist: Twist::Target(twist_target),
        })
        .unwrap();
        let t = std::time::Instant::now();
        let report = nav.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        let elapsed = t.elapsed().as_secs_f64();
        step_times.push(elapsed);
        max_step = max_step.max(elapsed);
        let pen = nav.max_penetration_m();
        worst = worst.max(pen);
        if step % 500 == 0 {
            println!(
                "{step}: route {index}/{} ({:.1} mm off, r {:.1}), inserted {:.0} mm, twist {:.2}, {:?} contacts, pen {:.3} mm",
                route.len(),
                distance * 1e3,
                radius * 1e3,
                report.inserted_m * 1e3,
                nav.twist_rad(),
                report.active_contacts,
                pen * 1e3
            );
        }
        if index + 5 >= route.len() {
            println!("reached at step {step}");
            break;
        }
    }
    step_times.sort_by(f64::total_cmp);
    let percentile =
        |p: f64| step_times[((step_times.len() - 1) as f64 * p).round() as usize] * 1e3;
    println!(
        "step time over {} steps: p50 {:.3} ms, p90 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        step_times.len(),
        percentile(0.5),
        percentile(0.9),
        percentile(0.99),
        max_step * 1e3
    );
    let tip = Point3::from(nav.tip_position());
    let location = anatomy.graph.nearest(&tip).unwrap();
    println!(
        "tip in {:?}, worst penetration {:.3} mm, slowest step {:.2} ms",
        anatomy.graph.branches[location.branch].name,
        worst * 1e3,
        max_step * 1e3
    );
}
