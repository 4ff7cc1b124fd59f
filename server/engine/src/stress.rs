//! The random operator: a seeded hand that drives a scene's instruments as a careless trainee
//! would (any instrument, pushes and pulls up to the device limits, fast pulls, twists, long
//! pushes into a blocked tip, hands let go), with the governor's fidelity fixed or switched
//! mid-run; and what the physics did under it: divergences, errors, panics, step times, the
//! deepest penetration of any instrument's surface and the largest hand force.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::Instant;

use crate::metrics::InstrumentMetrics;
use crate::world::{Command, Drive, MAX_FIDELITY_LEVEL, World};

/// A step's time budget at 500 Hz (s).
pub const STEP_BUDGET_S: f64 = 2e-3;

/// How far past its torque strength a hand's torque may rise (a share of it): the twist is
/// held from the step after the one that reaches it, with no retake, so one step's rise.
pub const TORQUE_OVERSHOOT: f64 = 0.25;

/// How the operator's fidelity is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Levels {
    /// The scene's full fidelity throughout (no governor).
    Full,
    /// One governor level throughout.
    Fixed(u8),
    /// A random level every few simulated seconds.
    Switched,
}

/// One run of the random operator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StressSettings {
    /// Seed of the operator's choices.
    pub seed: u64,
    /// Simulated time (s).
    pub simulated_s: f64,
    /// The governor's fidelity.
    pub levels: Levels,
    /// Fastest push or pull the hand makes (m/s).
    pub max_push_m_s: f64,
    /// Fastest twist (rad/s).
    pub max_twist_rad_s: f64,
    /// Steps slower than this (s) are described in [`StressReport::slow_steps`] (at most
    /// [`SLOW_STEPS_KEPT`]); `None` keeps none.
    pub slow_step_s: Option<f64>,
    /// Every step in this window of simulated time (from, to; s) is described in
    /// [`StressReport::watched`]; `None` describes none.
    pub watch_s: Option<(f64, f64)>,
}

/// The most slow steps a report describes.
pub const SLOW_STEPS_KEPT: usize = 2000;

/// What the strand looked like after a slow step.
#[derive(Debug, Clone, PartialEq)]
pub struct SlowStep {
    /// Simulated time (s).
    pub at_s: f64,
    /// Wall time of the step (s).
    pub step_s: f64,
    /// The governor's fidelity level.
    pub level: u8,
    /// Each instrument's inserted length (m), outermost first.
    pub inserted_m: Vec<f64>,
    /// Nodes of the strand's beam model.
    pub nodes: usize,
    /// Contacts of the last solve, those pushing, its sweeps and detection rounds.
    pub contacts: (usize, usize, usize, usize),
}

/// One step of the watched window ([`StressSettings::watch_s`]): what each hand did and felt.
#[derive(Debug, Clone, PartialEq)]
pub struct WatchedStep {
    /// What [`SlowStep`] says of every slow step.
    pub step: SlowStep,
    /// Each instrument's hand (outermost first): the force it feels (N, push positive), its
    /// torque (N·m) and the operator's command.
    pub hands: Vec<(f64, f64, cathlab_physics::Command)>,
    /// The axial forces (N, tension positive) of the strand's first elements from the entry
    /// (at most [`WATCHED_ENTRY_ELEMENTS`]).
    pub entry_elements_n: Vec<f64>,
    /// A stack's instruments' tips (outermost first): where each lies (m of path from the
    /// entry; with the slide, where its material is, not its hand) and the axial forces (N,
    /// tension positive) of the elements just before and just after it. Empty for a single
    /// device.
    pub tips: Vec<(f64, f64, f64)>,
}

/// How many elements from the entry a [`WatchedStep`] reports.
pub const WATCHED_ENTRY_ELEMENTS: usize = 4;

impl StressSettings {
    /// A run of `simulated_s` seconds with seed `seed` at full fidelity, pushing up to
    /// 150 mm/s and twisting up to two turns a second.
    pub fn new(seed: u64, simulated_s: f64) -> Self {
        Self {
            seed,
            simulated_s,
            levels: Levels::Full,
            max_push_m_s: 0.15,
            max_twist_rad_s: 4.0 * std::f64::consts::PI,
            slow_step_s: None,
            watch_s: None,
        }
    }
}

/// The most axial force an element may carry in a run, as a multiple of the hands' strength.
/// Within a device the axial force changes only by friction and drag, so the hands' strength
/// bounds it; the engine relieves whatever passes twice it before each step
/// (`NavigationSettings::max_axial_force_n`; a coaxial stack's merged element twice the
/// strength of each hand whose instrument it holds), and what one step's slide leaves before
/// the next relief is up to some 17 times the strength in the smoke. The fault this catches
/// is elements crushed step after step, which reached 3,400 times it (34 kN) in a 30 s run
/// before the relief (and 3,200 times in a coaxial stack's before the stacks had it).
pub const ELEMENT_FORCE_BOUND: f64 = 100.0;

/// What a run found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StressReport {
    /// Steps taken.
    pub steps: u64,
    /// Simulated time (s).
    pub simulated_s: f64,
    /// Steps the world reported diverged (and put the device back at its start).
    pub divergences: u32,
    /// Steps that returned an error, with the first error's message.
    pub errors: u32,
    /// The first divergence or error message, if any.
    pub first_failure: Option<String>,
    /// Whether a step panicked (the run stops there).
    pub panicked: bool,
    /// Step wall times (s), sorted.
    pub step_s: Vec<f64>,
    /// The deepest penetration of any instrument's surface after any step (m).
    pub worst_penetration_m: f64,
    /// When the deepest penetration was reached: simulated time (s) and the governor's
    /// fidelity level of that step (None: nothing penetrated).
    pub deepest_at: Option<(f64, u8)>,
    /// The largest axial force any hand felt (N).
    pub worst_hand_force_n: f64,
    /// The hands' strength in the scene (N): the most any may push or pull with.
    pub hand_limit_n: f64,
    /// The largest torque any hand felt (N·m).
    pub worst_hand_torque_nm: f64,
    /// The hands' torque strength in the scene (N·m): the most any may twist with.
    pub hand_torque_limit_nm: f64,
    /// The largest axial force any element of the device carried (N): see
    /// [`Metrics::peak_element_force_n`](crate::metrics::Metrics::peak_element_force_n).
    pub worst_element_force_n: f64,
    /// The steps slower than [`StressSettings::slow_step_s`], in order.
    pub slow_steps: Vec<SlowStep>,
    /// The steps of the watched window ([`StressSettings::watch_s`]), in order.
    pub watched: Vec<WatchedStep>,
    /// When a hand first felt more than its strength: simulated time (s), the instrument
    /// (outermost first), its force (N) and torque (N·m) then; None while none did.
    pub limit_passed_at: Option<(f64, usize, f64, f64)>,
    /// Steps the hands' force guard took again ([`Metrics::force_retakes`](crate::metrics::Metrics::force_retakes)).
    pub force_retakes: u64,
}

impl StressReport {
    /// Step time at quantile `q` ∈ [0, 1] (s).
    pub fn quantile_s(&self, q: f64) -> f64 {
        if self.step_s.is_empty() {
            return 0.0;
        }
        self.step_s[((self.step_s.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize]
    }

    /// Steps over [`STEP_BUDGET_S`].
    pub fn over_budget(&self) -> usize {
        self.step_s.iter().filter(|&&t| t > STEP_BUDGET_S).count()
    }

    /// Whether nothing diverged, failed or panicked.
    pub fn sound(&self) -> bool {
        self.divergences == 0 && self.errors == 0 && !self.panicked
    }

    /// While the run goes on ([`run_while`]): whether it has failed yet, by a divergence, an
    /// error, a panic, or a hand past its strength.
    pub fn failed_so_far(&self) -> bool {
        self.first_failure.is_some()
            || self.errors > 0
            || self.panicked
            || self.limit_passed_at.is_some()
    }

    /// Whether no element carried more than [`ELEMENT_FORCE_BOUND`] times the hands'
    /// strength.
    pub fn elements_within_bound(&self) -> bool {
        self.worst_element_force_n <= ELEMENT_FORCE_BOUND * self.hand_limit_n
    }

    /// Whether no hand felt more than its strength (within the step's
    /// [`crate::scene::FORCE_OVERSHOOT`]) and no hand twisted past its torque strength by
    /// more than [`TORQUE_OVERSHOOT`].
    pub fn hands_within_limits(&self) -> bool {
        within_strength(
            (self.worst_hand_force_n, self.worst_hand_torque_nm),
            (self.hand_limit_n, self.hand_torque_limit_nm),
        )
    }
}

/// Whether a hand's force and torque (N, N·m; either sign) are within its strength (N, N·m),
/// the force within the step's [`crate::scene::FORCE_OVERSHOOT`] and the torque within
/// [`TORQUE_OVERSHOOT`].
fn within_strength(
    (force_n, torque_nm): (f64, f64),
    (limit_n, torque_limit_nm): (f64, f64),
) -> bool {
    force_n.abs() <= limit_n * (1.0 + crate::scene::FORCE_OVERSHOOT) + 1e-9
        && torque_nm.abs() <= torque_limit_nm * (1.0 + TORQUE_OVERSHOOT)
}

/// SplitMix64: a small deterministic generator for the operator's choices (and the fuzz
/// replay test's mutations).
#[derive(Debug, Clone)]
pub struct Dice(pub u64);

impl Dice {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (0 when n is 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
}

/// One of the operator's moves: which hand, what it does, for how long (s).
fn choose(dice: &mut Dice, settings: &StressSettings, hands: usize) -> (u32, Drive, f64) {
    let hand = dice.below(hands) as u32;
    let v = settings.max_push_m_s;
    let w = settings.max_twist_rad_s;
    let roll = dice.unit();
    let (push, twist, duration) = if roll < 0.3 {
        // A push at any speed.
        (dice.range(0.0, v), 0.0, dice.range(0.1, 1.5))
    } else if roll < 0.45 {
        // A pull at any speed.
        (-dice.range(0.0, v), 0.0, dice.range(0.1, 1.0))
    } else if roll < 0.55 {
        // A fast pull.
        (-v, 0.0, dice.range(0.1, 0.4))
    } else if roll < 0.75 {
        // A twist, with a slow push or pull.
        (
            dice.range(-0.2, 0.2) * v,
            dice.range(-w, w),
            dice.range(0.2, 1.5),
        )
    } else if roll < 0.9 {
        // A long push, into whatever blocks the tip.
        (dice.range(0.2, 0.5) * v, 0.0, dice.range(2.0, 4.0))
    } else {
        // Hands off.
        (0.0, 0.0, dice.range(0.1, 1.0))
    };
    (
        hand,
        Drive::Setpoints {
            push_m_s: push,
            twist_rad_s: twist,
        },
        duration,
    )
}

/// What the strand looked like after a step of `took` seconds at `now`.
fn slow_step(world: &World, now: f64, took: f64) -> SlowStep {
    let strand = world.strand();
    let contacts = strand.last_contacts().map_or((0, 0, 0, 0), |c| {
        (
            c.contacts.len(),
            c.response.local.iter().filter(|l| l.x > 0.0).count(),
            c.response.iterations,
            c.report.iterations,
        )
    });
    SlowStep {
        at_s: now,
        step_s: took,
        level: world.fidelity_level(),
        inserted_m: (0..strand.len()).map(|i| strand.inserted_m(i)).collect(),
        nodes: strand.model().positions().len(),
        contacts,
    }
}

/// A step of the watched window at `now`, of `took` seconds.
fn watched_step(world: &World, now: f64, took: f64) -> WatchedStep {
    let strand = world.strand();
    let snapshot = world.snapshot();
    let model = strand.model();
    WatchedStep {
        step: slow_step(world, now, took),
        hands: snapshot
            .instruments
            .iter()
            .enumerate()
            .map(|(i, h)| (h.axial_force_n, h.torque_nm, strand.command(i)))
            .collect(),
        entry_elements_n: (0..model.element_count().min(WATCHED_ENTRY_ELEMENTS))
            .map(|e| model.element_axial_force_n(e))
            .collect(),
        tips: strand.stack().map_or_else(Vec::new, |stack| {
            let sigma = stack.node_sigma_m();
            let last = model.element_count() - 1;
            // The element that holds path coordinate `s` (m): the one from the last node at
            // or before it. A micrometre's thousandth either side of a tip on a node picks
            // the elements that meet there.
            let force_at = |s: f64| {
                let e = sigma.partition_point(|&x| x <= s).clamp(1, last + 1) - 1;
                model.element_axial_force_n(e)
            };
            (0..stack.len())
                .filter_map(|i| stack.tip_inserted_m(i))
                .map(|tip| (tip, force_at(tip - 1e-9), force_at(tip + 1e-9)))
                .collect()
        }),
    }
}

/// The largest of a figure any of `world`'s instruments' hands felt so far, either way
/// (`figure`: one of [`InstrumentMetrics`]' peaks, N or N·m).
pub fn worst_hand(world: &World, figure: fn(&InstrumentMetrics) -> f64) -> f64 {
    let metrics = world.metrics();
    metrics.instruments[..metrics.instrument_count as usize]
        .iter()
        .map(|m| figure(m).abs())
        .fold(0.0, f64::max)
}

/// Drives `world` with the random operator of `settings` and reports what happened.
pub fn run(world: &mut World, settings: &StressSettings) -> StressReport {
    run_while(world, settings, |_, _| true)
}

/// [`run`], asking `go_on` after every step (the world and the report so far: its step times
/// unsorted, its divergences and hands' peaks not yet gathered) whether to go on: a long run
/// can report its progress, or stop at its first failure ([`StressReport::failed_so_far`])
/// instead of running its hour out. Stopped, the report covers the steps taken.
pub fn run_while(
    world: &mut World,
    settings: &StressSettings,
    mut go_on: impl FnMut(&World, &StressReport) -> bool,
) -> StressReport {
    let mut dice = Dice(settings.seed);
    let mut report = StressReport::default();
    let dt = world.assets().spec.time_step_s();
    let steps = (settings.simulated_s / dt).ceil() as u64;
    let mut seq = world.last_seq();
    let mut apply = |world: &mut World, command: Command, report: &mut StressReport| {
        seq += 1;
        if let Err(e) = world.apply(seq, &command) {
            report.errors += 1;
            report
                .first_failure
                .get_or_insert(format!("{command:?}: {e}"));
        }
    };
    match settings.levels {
        Levels::Full => {}
        Levels::Fixed(level) => apply(world, Command::Fidelity(level), &mut report),
        Levels::Switched => {}
    }
    let divergences_before = world.metrics().divergence_resets;
    let mut move_until = 0.0;
    let mut level_until = 0.0;
    report.step_s.reserve(steps as usize);
    for step in 0..steps {
        let now = step as f64 * dt;
        if settings.levels == Levels::Switched && now >= level_until {
            let level = dice.below(usize::from(MAX_FIDELITY_LEVEL) + 1) as u8;
            apply(world, Command::Fidelity(level), &mut report);
            level_until = now + dice.range(1.0, 4.0);
        }
        if now >= move_until {
            let hands = world.strand().len();
            let (index, drive, duration) = choose(&mut dice, settings, hands);
            apply(world, Command::Instrument { index, drive }, &mut report);
            move_until = now + duration;
        }
        let start = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| world.step()));
        let took = start.elapsed().as_secs_f64();
        report.step_s.push(took);
        if settings.slow_step_s.is_some_and(|s| took > s)
            && report.slow_steps.len() < SLOW_STEPS_KEPT
            && outcome.is_ok()
        {
            report.slow_steps.push(slow_step(world, now, took));
        }
        if settings
            .watch_s
            .is_some_and(|(from, to)| now >= from && now <= to)
            && outcome.is_ok()
        {
            report.watched.push(watched_step(world, now, took));
        }
        report.steps += 1;
        match outcome {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                report.errors += 1;
                report.first_failure.get_or_insert(e.to_string());
            }
            Err(_) => {
                report.panicked = true;
                break;
            }
        }
        if report.limit_passed_at.is_none() {
            let limits = &world.assets().spec.limits;
            let strength = (limits.push_force_n, limits.twist_torque_nm);
            let metrics = world.metrics();
            report.limit_passed_at = metrics.instruments[..metrics.instrument_count as usize]
                .iter()
                .position(|m| !within_strength((m.peak_axial_force_n, m.peak_torque_nm), strength))
                .map(|i| {
                    let m = &metrics.instruments[i];
                    (now, i, m.peak_axial_force_n, m.peak_torque_nm)
                });
        }
        let deepest = world.metrics().deepest_penetration_m;
        if deepest > report.worst_penetration_m {
            report.worst_penetration_m = deepest;
            report.deepest_at = Some((now, world.fidelity_level()));
        }
        for event in world.take_events() {
            if event.kind == crate::metrics::EventKind::Divergence {
                report
                    .first_failure
                    .get_or_insert(format!("{:.3} s: {}", now, event.message));
            }
        }
        if !go_on(world, &report) {
            break;
        }
    }
    report.divergences = world.metrics().divergence_resets - divergences_before;
    report.simulated_s = report.steps as f64 * dt;
    let metrics = world.metrics();
    // The world measures every node of every instrument after each step it keeps (and
    // `report.worst_penetration_m` followed it step by step).
    report.worst_element_force_n = metrics.peak_element_force_n;
    report.force_retakes = metrics.force_retakes;
    report.worst_hand_force_n = worst_hand(world, |m| m.peak_axial_force_n);
    report.worst_hand_torque_nm = worst_hand(world, |m| m.peak_torque_nm);
    let limits = &world.assets().spec.limits;
    report.hand_limit_n = limits.push_force_n;
    report.hand_torque_limit_nm = limits.twist_torque_nm;
    report.step_s.sort_by(f64::total_cmp);
    report
}
