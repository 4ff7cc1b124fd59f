//! The physics stage of a step: each instrument's operator command held back where a limit
//! stops its push (the hand's force, the device's buckling load or length, the governor's
//! speed cap) or its twist (the hand's torque), the strand stepped, and a diverged step (an
//! error, a non-finite tip, a tip or any node of any instrument through the wall) reset to the
//! device's start, reported and counted.

use cathlab_physics::{Insertion, Twist};
use nalgebra::Point3;

use super::World;
use super::fidelity::fidelity_effort;
use super::hand::{PushLimit, start_hands};
use super::tips::{MAX_ESCAPE_M, tracked_tip};
use crate::error::Result;
use crate::metrics::EventKind;
use crate::scene::FORCE_OVERSHOOT;
use crate::strand::{HandReaction, Strand};

/// While any hand's last reaction is at least this share of its limit, a step that moves an
/// instrument is guarded ([`World::step_within_force_limits`]).
const FORCE_GUARD_FRACTION: f64 = 0.25;

/// The share of its limit from which a hand is watched while nothing moves that loads it: the
/// device settling (new contacts, friction giving, a twist's writhing) can take it past, and
/// then it gives way within the step ([`World::step_within_force_limits`]).
const SETTLING_WATCH_FRACTION: f64 = 0.9;

/// How far past its torque strength a step may leave a hand that was within it (a fraction
/// of the limit) before the force guard takes the step again: a push can load a hand's
/// torque as well as its force (a curved catheter's tip meeting a wall turns the shaft about
/// the entry axis by the contact's lever arm: 51 → 153 mN·m in one step of the stroke
/// scene's guide).
const TORQUE_OVERSHOOT: f64 = 0.1;

/// The least difference between two tries' advances of an instrument (m) from which its
/// hand's stiffness is learnt.
const MIN_LEARNING_MOVE_M: f64 = 1e-7;

/// The share of its limit below which a guarded step taken once leaves a hand's learnt
/// stiffness forgotten (`World::forget_slack_stiffness`).
const STIFFNESS_KEPT_FRACTION: f64 = 0.9;

/// How far under its limit a hand that gives way aims (a fraction of the limit): half the
/// overshoot a step may leave.
const GIVE_UNDERSHOOT: f64 = FORCE_OVERSHOOT / 2.0;

/// The most a hand held past its strength gives way in one step (m).
const MAX_GIVE_M: f64 = 0.5e-3;

/// How many times a step the force guard retakes it with the hands still past their limits
/// giving way, after holding every move did not bring them within
/// ([`World::step_within_force_limits`]).
const FINAL_GIVES: usize = 2;

/// The most a hand twisted past its strength gives its twist back in one step (rad).
const MAX_GIVE_RAD: f64 = 0.05;

/// How far `insertion` moves an instrument inserted `inserted_m` (m) in a step of `dt` (s):
/// its speed over the step, or the way to its target (m).
fn advance_m(insertion: Insertion, inserted_m: f64, dt: f64) -> f64 {
    match insertion {
        Insertion::Velocity(v) => v * dt,
        Insertion::Target(x) => x - inserted_m,
    }
}

/// Whether a hand past its strength, feeling `force` (N), gives way this step, after its
/// limit acted last step at `last` (the force then, N, and whether it gave way or held; None:
/// it did not act). A give that made the force worse (pulling a coiled wire back out of a dead
/// end can load the hand more, not less) is not repeated: the hand holds where it is. A hold
/// that does not bring the force down (the device settling, another instrument pushing) gives
/// way again: before, the hold was renewed while the force crept past the limit step after
/// step.
fn gives_way(last: Option<(f64, bool)>, force: f64) -> bool {
    last.is_none_or(|(before, gave)| {
        if gave {
            force.abs() <= before.abs()
        } else {
            force.abs() >= before.abs()
        }
    })
}

/// The give (m, from where the hand was) that brings a hand to [`GIVE_UNDERSHOOT`] under
/// its signed `limit` (N; the held force's side), by the secant through the hold (`held`:
/// its give, m, and force, N; a hand past its limit already gives in the hold) and a try
/// (`tried`: its give and force). Where the try fell short of the aim: at least the try's
/// give, at most [`MAX_GIVE_M`], and four times as far beyond the hold where the force did
/// not fall with it. Where the try overshot (the force went past the aim, even to the other
/// side: a pulled wire's give in against the default cap's strain put 16 N of push on the
/// hand), the secant between the two.
fn next_give((g0, f0): (f64, f64), (g1, f1): (f64, f64), limit: f64) -> f64 {
    let aim = (1.0 - GIVE_UNDERSHOOT) * limit;
    let step = g1 - g0;
    let secant = step * (aim - f0) / (f1 - f0);
    if (f1 - aim) * (f0 - aim) < 0.0 {
        return g0 + secant;
    }
    let beyond = if secant.is_finite() && secant * step > 0.0 {
        secant
    } else {
        4.0 * step
    };
    let next = g0 + beyond;
    next.signum() * next.abs().clamp(g1.abs().min(MAX_GIVE_M), MAX_GIVE_M)
}

impl World {
    /// Steps the strand with every hand's command within its limits (the operators' commands
    /// are put back after the step); a diverged step puts the device back at its start,
    /// reports it and counts it, and the world stays usable.
    pub(super) fn step_physics(&mut self, dt: f64) -> Result<()> {
        let operators: Vec<cathlab_physics::Command> = (0..self.strand.len())
            .map(|i| self.strand.command(i))
            .collect();
        let mut moves = Vec::with_capacity(operators.len());
        for (i, operator) in operators.iter().enumerate() {
            let command = self.limited_command(i, *operator, dt);
            if let Some(command) = command {
                self.strand.set_command(i, command)?;
            }
            moves.push(command.unwrap_or(*operator).insertion);
        }
        let outcome = self.step_within_force_limits(&moves, dt);
        // The operators' commands back (a limit or a retake changed some).
        for (i, operator) in operators.iter().enumerate() {
            self.strand.set_command(i, *operator)?;
        }
        let diverged = match outcome {
            Ok(()) => {
                let tip = self.strand.leading_tip();
                let escaped = self
                    .strand
                    .wall()
                    .0
                    .lumen
                    .query(&Point3::from(tip))
                    .signed_distance
                    > MAX_ESCAPE_M;
                if !tip.iter().all(|v| v.is_finite()) {
                    Some("non-finite tip position".to_owned())
                } else if escaped {
                    Some("the tip left the vessel".to_owned())
                } else {
                    // Every node of every instrument, with its own outer radius.
                    let depth = self.strand.max_penetration_m();
                    if depth.is_nan() || depth > MAX_ESCAPE_M {
                        Some(format!("a node passed the wall by {:.1} mm", depth * 1e3))
                    } else {
                        self.metrics.deepest_penetration_m =
                            self.metrics.deepest_penetration_m.max(depth);
                        self.metrics.peak_element_force_n = self
                            .metrics
                            .peak_element_force_n
                            .max(self.strand.model().max_axial_force_n());
                        None
                    }
                }
            }
            // The physics refused the step: a divergence. Anything else is the caller's.
            Err(crate::error::EngineError::Physics(e)) => Some(e.to_string()),
            Err(e) => return Err(e),
        };
        if let Some(reason) = diverged {
            self.metrics.divergence_resets += 1;
            self.restart_device(self.active_device)?;
            self.event(
                EventKind::Divergence,
                format!("physics diverged ({reason}); the device was put back at its start"),
            );
        }
        Ok(())
    }

    /// Steps the strand so that the instruments' moves do not push or pull a hand past its
    /// limit: where an instrument moves while some hand's last reaction is at
    /// [`FORCE_GUARD_FRACTION`] of its limit or more, the strand is kept, and a step that
    /// leaves a hand that was within its limit more than [`FORCE_OVERSHOOT`] past it is taken
    /// again with the moves that load the hands scaled by the share the force allows (the
    /// force taken as linear in the move, between the last reaction and this step's, for the
    /// hand that allows least), and if that is still too far, without them. A hand already
    /// past its limit gives way (`limited_command`); its move is never scaled, and the others'
    /// moves may not load it further (in a merged stack the guide's hand feels the
    /// microcatheter pushed). The first try already takes the share each hand's stiffness
    /// learnt in the last guarded step allows, so a push held at its limit is stepped once, not
    /// twice. Torques are guarded alike: a step that leaves a hand within its torque limit
    /// more than [`TORQUE_OVERSHOOT`] past it is taken again with the moves and the twists
    /// scaled by the share the torque allows (a push loads the torque too, through the lever
    /// arm of a curved device's contacts). Where the held step still leaves a hand past its
    /// limit (a settling shape loads it with nothing moving), that hand gives way within the
    /// step: by its excess over its stiffness, then along the secant through the hold and
    /// that give (at most [`FINAL_GIVES`] tries); a hand at
    /// [`SETTLING_WATCH_FRACTION`] of its limit is watched so even where nothing moves.
    /// `moves` are the insertions this step runs.
    fn step_within_force_limits(&mut self, moves: &[Insertion], dt: f64) -> Result<()> {
        // Per hand: its limits as signed forces (push, pull) and its last reaction (N).
        let hands: Vec<(f64, f64, f64)> = self
            .hands
            .iter()
            .map(|h| {
                (
                    h.limits.force_n,
                    -h.limits.pull_force_n,
                    h.reaction.axial_force_n,
                )
            })
            .collect();
        // Per hand: whether its last force was within its limits (not giving way).
        let within: Vec<bool> = hands
            .iter()
            .map(|&(push, pull, last)| last < push && last > pull)
            .collect();
        // Per hand: its torque limit and its last torque's size (N·m).
        let torques: Vec<(f64, f64)> = self
            .hands
            .iter()
            .map(|h| (h.limits.torque_nm, h.reaction.torque_nm.abs()))
            .collect();
        // Per instrument: inserted before (m), its move this step (m) and whether the move is
        // scaled in a retake (it moves, and its hand is within its limit: not giving way).
        let before_moves: Vec<(f64, f64, bool)> = moves
            .iter()
            .enumerate()
            .map(|(i, insertion)| {
                let inserted = self.strand.inserted_m(i);
                let advance = advance_m(*insertion, inserted, dt);
                // A hand past its limit moving against the force it feels (pulling while the
                // device pushes it out, as a coil pulled out of a dead end does here) is not
                // giving way: its move is scaled too, and held where it loads the hand further.
                let against = advance * hands[i].2 < 0.0;
                (inserted, advance, advance != 0.0 && (within[i] || against))
            })
            .collect();
        // Per instrument: twisted before (rad) and its twist this step (rad), scaled in a
        // retake where its hand is within its torque limit (not giving its twist back).
        let before_twists: Vec<(f64, f64)> = (0..moves.len())
            .map(|i| {
                let twisted = self.strand.twist_rad(i);
                let turn = match self.strand.command(i).twist {
                    Twist::Rate(w) => w * dt,
                    Twist::Target(angle) => angle - twisted,
                };
                let (limit, last) = torques[i];
                (twisted, if last < limit { turn } else { 0.0 })
            })
            .collect();
        let pushing = before_moves.iter().any(|&(_, _, scaled)| scaled);
        let twisting = before_twists.iter().any(|&(_, turn)| turn != 0.0);
        // Whether any hand's last force is at `fraction` of its limit or more.
        let force_at = |fraction: f64| {
            hands
                .iter()
                .any(|&(push, pull, last)| last / push >= fraction || last / pull >= fraction)
        };
        let near_force = force_at(FORCE_GUARD_FRACTION);
        let near_torque = torques
            .iter()
            .any(|&(limit, last)| last / limit >= FORCE_GUARD_FRACTION);
        let guarded = (pushing && (near_force || near_torque)) || (twisting && near_torque);
        // At its limit with nothing loading it, a hand is still watched: the device's own
        // settling can take it past (below).
        if !guarded && !force_at(SETTLING_WATCH_FRACTION) {
            return Ok(self.strand.step()?);
        }
        let before = self.strand.clone();
        // The share of the moves the hands' last stiffness allows: the first try.
        let predicted = before_moves
            .iter()
            .zip(&self.hands)
            .filter(|&(&(_, _, scaled), _)| scaled)
            .filter_map(|(&(_, advance, _), hand)| {
                let limit = if advance > 0.0 {
                    hand.limits.force_n
                } else {
                    -hand.limits.pull_force_n
                };
                let room = limit - hand.reaction.axial_force_n;
                Some((room / hand.stiffness_n_per_m? / advance).clamp(0.0, 1.0))
            })
            .fold(1.0, f64::min);
        if predicted < 1.0 {
            self.scale_moves(&before_moves, |_, advance| predicted * advance, None)?;
        }
        self.strand.step()?;
        // The shares of this step's loading moves that keep every hand that was within its
        // limits there (1: all): the pushes' by the forces and the torques, the twists' by
        // the torques alone.
        let allowed = |reactions: &[HandReaction]| -> (f64, f64) {
            let force = hands
                .iter()
                .zip(reactions)
                .map(|(&(push, pull, last), r)| {
                    let now = r.axial_force_n;
                    let limit = if now >= 0.0 { push } else { pull };
                    if now / limit <= 1.0 + FORCE_OVERSHOOT {
                        1.0
                    } else if last / limit < 1.0 {
                        // Within its limit before: the share that meets it, linearly.
                        ((limit - last) / (now - last)).clamp(0.0, 1.0)
                    } else if now / limit <= last / limit {
                        // Past it and giving way: the others' moves may not load it further.
                        1.0
                    } else {
                        0.0
                    }
                })
                .fold(1.0, f64::min);
            let torque = torques
                .iter()
                .zip(reactions)
                .map(|(&(limit, last), r)| {
                    let now = r.torque_nm.abs();
                    if now <= limit * (1.0 + TORQUE_OVERSHOOT) {
                        1.0
                    } else if last < limit {
                        ((limit - last) / (now - last)).clamp(0.0, 1.0)
                    } else if now <= last {
                        // Past it and giving its twist back (`limited_twist`): the moves may
                        // not load it further.
                        1.0
                    } else {
                        0.0
                    }
                })
                .fold(1.0, f64::min);
            (force.min(torque), torque)
        };
        // The hands' reactions after the step taken last (computed once a step).
        let mut reactions = self.strand.reactions().1;
        let (push_share, twist_share) = allowed(&reactions);
        if push_share >= 1.0 && twist_share >= 1.0 {
            self.forget_slack_stiffness(&hands, &reactions);
        } else if guarded {
            // The moves as the physics took them (clamped to the device's speed and range).
            let taken: Vec<f64> = before_moves
                .iter()
                .enumerate()
                .map(|(i, &(inserted, _, _))| self.strand.inserted_m(i) - inserted)
                .collect();
            let first = reactions.clone();
            // The tries: the share; then, if still too far, without the moves whose share was
            // short, first keeping the moves of hands past their limit that move against the
            // force they feel (a guide catheter pulled back while the microcatheter pushed
            // through it loads it: holding both held the guide past its limit for seconds,
            // every step taken three times), then without those too.
            let count = before_moves.len();
            let relieving: Vec<bool> = before_moves
                .iter()
                .zip(&within)
                .map(|(&(_, _, scaled), &within)| scaled && !within)
                .collect();
            // Each try: the share of each move kept, of the twists, and the gives (m).
            let none = vec![0.0; count];
            let mut tries: Vec<(Vec<f64>, f64, Vec<f64>)> = Vec::new();
            if push_share > 0.0 || (twist_share > 0.0 && twist_share < 1.0) {
                tries.push((vec![push_share; count], twist_share, none.clone()));
            }
            let others_move = before_moves
                .iter()
                .zip(&relieving)
                .any(|(&(_, _, scaled), &r)| scaled && !r);
            if push_share < 1.0 && others_move && relieving.contains(&true) {
                let keep = relieving
                    .iter()
                    .map(|&r| if r { 1.0 } else { 0.0 })
                    .collect();
                tries.push((keep, 0.0, none.clone()));
            }
            // Every move and twist held, and each hand past its limit that did not move
            // gives way (as `limited_command` gives): what others' moves or the device's own
            // settling put on such a hand is not held there. (A guide held at its strength
            // while a microwire was pulled back through it crept 0.01–0.02 N a step past it
            // with everything held: the stroke scene, seed 2.)
            let gives = self.gives_past_limits(&hands, &first, &before_moves, false);
            if gives.iter().any(|&g| g != 0.0) {
                tries.push((none.clone(), 0.0, gives));
            }
            // Every move held, twists too: a push's share and a twist's interact (the stroke
            // scene's guide, pushed at a wall and twisted, kept within its torque by its push
            // and past it without).
            let hold = (none.clone(), 0.0, none);
            if tries.last() != Some(&hold) {
                tries.push(hold);
            }
            for (k, (push, twist, gives)) in tries.iter().enumerate() {
                let twists = (*twist < 1.0).then_some((&before_twists[..], *twist));
                let moves = |i: usize, _| push[i] * taken[i];
                reactions = self.retake(&before, &before_moves, moves, twists, gives)?;
                let (p, t) = allowed(&reactions);
                if (p >= 1.0 && t >= 1.0) || k + 1 == tries.len() {
                    break;
                }
            }
            self.learn_hand_stiffness(&before_moves, (&taken, &first), &reactions);
        }
        // Held and still past: the device settling (new contacts found, friction giving,
        // a twist's writhing) loaded the hand with nothing moving. A hand cannot hold
        // more than its strength, so every hand still past it gives way, moving or not
        // (the aorta's wire, pushed and twisted at its limits, went 10.00 → 10.22 N in
        // one step with both held: the random operator, seed 1, with the physics
        // options on). The first give is the excess over the hand's stiffness; a looped
        // wire is far softer than that, so a second comes from the secant between the
        // hold and the first give.
        let held = reactions.clone();
        let held_gives: Vec<f64> = (0..before_moves.len())
            .map(|i| self.strand.inserted_m(i) - before_moves[i].0)
            .collect();
        let mut gives = self.gives_past_limits(&hands, &reactions, &before_moves, true);
        let held_twists = Some((&before_twists[..], 0.0));
        for _ in 0..FINAL_GIVES {
            if allowed(&reactions).0 >= 1.0 || gives.iter().all(|&g| g == 0.0) {
                break;
            }
            reactions = self.retake(&before, &before_moves, |_, _| 0.0, held_twists, &gives)?;
            let hold = (&held_gives[..], &held[..]);
            gives = self.secant_gives(&hands, hold, (&gives, &reactions), &before_moves);
        }
        Ok(())
    }

    /// For each instrument (m; 0: none), the give of its hand where the force guard's try
    /// (`first`: the reactions after it) left it past its limit by more than
    /// [`FORCE_OVERSHOOT`] and, unless `moving_too`, its own move did not (it was held,
    /// `before_moves`' flag unset): its excess over the aim
    /// ([`GIVE_UNDERSHOOT`] under the limit) over its stiffness, at most [`MAX_GIVE_M`], back
    /// against a push and in against a pull (never past its hub). `hands`: each one's signed
    /// limits, push and pull (N).
    fn gives_past_limits(
        &self,
        hands: &[(f64, f64, f64)],
        first: &[HandReaction],
        before_moves: &[(f64, f64, bool)],
        moving_too: bool,
    ) -> Vec<f64> {
        hands
            .iter()
            .zip(first)
            .zip(before_moves)
            .enumerate()
            .map(|(i, ((&(push, pull, _), r), &(inserted, _, scaled)))| {
                let now = r.axial_force_n;
                let limit = if now >= 0.0 { push } else { pull };
                if (scaled && !moving_too) || now / limit <= 1.0 + FORCE_OVERSHOOT {
                    return 0.0;
                }
                let axial = self.proximal_stiffness(i, |p| p.axial_stiffness_n);
                let stiffness = self.hands[i]
                    .stiffness_n_per_m
                    .map_or(axial, |k| k.min(axial));
                let give =
                    ((now - (1.0 - GIVE_UNDERSHOOT) * limit).abs() / stiffness).min(MAX_GIVE_M);
                self.within_travel(i, inserted, if now > 0.0 { -give } else { give })
            })
            .collect()
    }

    /// `give` (m) for instrument `index`, inserted `inserted` m, kept within its travel:
    /// never out of the sheath, never in past its hub.
    fn within_travel(&self, index: usize, inserted: f64, give: f64) -> f64 {
        let to_hub = (self.hands[index].limits.max_inserted_m - inserted).max(0.0);
        give.clamp(-inserted, to_hub)
    }

    /// The step taken again from `before`: the scaled moves set by `move_m` and the twists
    /// by `twists` (as in [`Self::scale_moves`]), then each hand with a give (m) set to give
    /// way by it from where it was. Returns the hands' reactions.
    fn retake(
        &mut self,
        before: &Strand,
        before_moves: &[(f64, f64, bool)],
        move_m: impl Fn(usize, f64) -> f64,
        twists: Option<(&[(f64, f64)], f64)>,
        gives: &[f64],
    ) -> Result<Vec<HandReaction>> {
        self.metrics.force_retakes += 1;
        self.strand = before.clone();
        self.scale_moves(before_moves, move_m, twists)?;
        for (i, &give) in gives.iter().enumerate() {
            if give != 0.0 {
                let mut command = self.strand.command(i);
                command.insertion = Insertion::Target(before_moves[i].0 + give);
                self.strand.set_command(i, command)?;
            }
        }
        self.strand.step()?;
        Ok(self.strand.reactions().1)
    }

    /// The next gives of the hands still past their limits after a try that gave `gives`
    /// (m) and led to `reactions`, by [`next_give`] from the hold (`held`: each hand's give
    /// there, m, and its reactions with no move loading it), never past the hub or out of the
    /// sheath. 0 where a hand is within its limit or did not give. `hands` as in
    /// [`Self::gives_past_limits`] (signed limits: the pull's is negative).
    fn secant_gives(
        &self,
        hands: &[(f64, f64, f64)],
        (held_gives, held): (&[f64], &[HandReaction]),
        (gives, reactions): (&[f64], &[HandReaction]),
        before_moves: &[(f64, f64, bool)],
    ) -> Vec<f64> {
        (0..gives.len())
            .map(|i| {
                let (give, f0, f1) = (gives[i], held[i].axial_force_n, reactions[i].axial_force_n);
                let (push, pull, _) = hands[i];
                let past = f1 / push > 1.0 + FORCE_OVERSHOOT || f1 / pull > 1.0 + FORCE_OVERSHOOT;
                if give == 0.0 || !past {
                    return 0.0;
                }
                let limit = if f0 >= 0.0 { push } else { pull };
                let next = next_give((held_gives[i], f0), (give, f1), limit);
                self.within_travel(i, before_moves[i].0, next)
            })
            .collect()
    }

    /// Sets each scaled instrument's insertion this step to `move_m(instrument, planned
    /// advance)` beyond where it was (`before_moves` as in `step_within_force_limits`).
    /// With `twists` (each instrument's twist before and this step's scaled twist, rad, as
    /// in `step_within_force_limits`, and the share), the twists are scaled by the share too.
    fn scale_moves(
        &mut self,
        before_moves: &[(f64, f64, bool)],
        move_m: impl Fn(usize, f64) -> f64,
        twists: Option<(&[(f64, f64)], f64)>,
    ) -> Result<()> {
        for (i, &(inserted, advance, scaled)) in before_moves.iter().enumerate() {
            let mut command = self.strand.command(i);
            if scaled {
                command.insertion = Insertion::Target(inserted + move_m(i, advance));
            }
            if let Some((twists, share)) = twists
                && let Some(&(twisted, turn)) = twists.get(i)
                && turn != 0.0
            {
                command.twist = Twist::Target(twisted + share * turn);
            }
            self.strand.set_command(i, command)?;
        }
        Ok(())
    }

    /// After a step the force guard took again: each hand's stiffness (N/m) as the secant
    /// between the two tries from the same start, the overshooting one (`first`: its moves,
    /// m, and the reactions they led to) and the one kept (`reactions`). Learnt where the
    /// force rose with the move, forgotten where it did not, kept where the two moves hardly
    /// differ. A secant, not the force's change from the last step over one move: while a
    /// push is held against a dead end the force also drifts step to step as the device
    /// settles (about 0.08 N down a step on the aorta's looped wire), which made the
    /// one-move estimate tiny or negative, the next first try overshoot, and every held step
    /// cost two or three solves.
    fn learn_hand_stiffness(
        &mut self,
        before_moves: &[(f64, f64, bool)],
        first: (&[f64], &[HandReaction]),
        reactions: &[HandReaction],
    ) {
        let (first_moves, first_reactions) = first;
        for (i, (hand, &(inserted, _, _))) in self.hands.iter_mut().zip(before_moves).enumerate() {
            let kept_move = self.strand.inserted_m(i) - inserted;
            let apart = first_moves[i] - kept_move;
            if apart.abs() < MIN_LEARNING_MOVE_M {
                continue;
            }
            let k = (first_reactions[i].axial_force_n - reactions[i].axial_force_n) / apart;
            hand.stiffness_n_per_m = (k.is_finite() && k > 0.0).then_some(k);
        }
    }

    /// After a guarded step taken once: a hand it left below [`STIFFNESS_KEPT_FRACTION`] of
    /// its limit forgets its stiffness (`hands`: each one's signed limits, push and pull, N;
    /// `reactions`: after the step), so its next first try takes its whole move: the learnt
    /// stiffness (from a dead end, say) scaled it down more than the force needed.
    fn forget_slack_stiffness(&mut self, hands: &[(f64, f64, f64)], reactions: &[HandReaction]) {
        for ((hand, &(push, pull, _)), r) in self.hands.iter_mut().zip(hands).zip(reactions) {
            let now = r.axial_force_n;
            let limit = if now >= 0.0 { push } else { pull };
            if now / limit < STIFFNESS_KEPT_FRACTION {
                hand.stiffness_n_per_m = None;
            }
        }
    }

    /// The command this step runs instead of the operator's for instrument `index` when a
    /// limit holds its push back (None: the operator's). The force limit looks at the last
    /// step's proximal reaction: a push (or a pull) that met it, or a hold that something
    /// else loads past it, gives way by the excess over the inserted length's axial
    /// stiffness (at most [`MAX_GIVE_M`]; nothing at the limit itself: the hand pushes or
    /// pulls no harder), so the instrument moves only as fast as the force allows. Reports
    /// each new hold once.
    fn limited_command(
        &mut self,
        index: usize,
        operator: cathlab_physics::Command,
        dt: f64,
    ) -> Option<cathlab_physics::Command> {
        let inserted = self.strand.inserted_m(index);
        let advance = advance_m(operator.insertion, inserted, dt);
        let hand = &self.hands[index];
        let force = hand.reaction.axial_force_n;
        let limits = hand.limits;
        let cap = fidelity_effort(self.fidelity).1;
        // Pulling, or holding while something else pulls it (a held hand is past its
        // strength either way).
        let pulled_too_hard = advance <= 0.0 && -force >= limits.pull_force_n;
        let pushed_too_hard = advance >= 0.0 && force >= limits.force_n;
        // A hand held past its strength gives way: back (or forward, pulling) by the excess
        // over its stiffness (the one learnt in the last guarded step, where softer than the
        // inserted length's axial stiffness), aiming [`GIVE_UNDERSHOOT`] under the limit so
        // that the others' moves in the same step do not take it past.
        let axial_stiffness = self.proximal_stiffness(index, |p| p.axial_stiffness_n);
        let stiffness = hand
            .stiffness_n_per_m
            .map_or(axial_stiffness, |k| k.min(axial_stiffness));
        let relieving = gives_way(hand.limit_acted_at, force);
        let give = |excess: f64| {
            if relieving {
                (excess.max(0.0) / stiffness).min(MAX_GIVE_M)
            } else {
                0.0
            }
        };
        let aim = 1.0 - GIVE_UNDERSHOOT;
        let (limit, insertion) = if pulled_too_hard {
            // Never in past its hub: there the hub, not the hand, meets the pull.
            let to = (inserted + give(-force - aim * limits.pull_force_n))
                .min(limits.max_inserted_m.max(inserted));
            (PushLimit::Force, Some(Insertion::Target(to)))
        } else if advance == 0.0 && pushed_too_hard {
            let to = inserted - give(force - aim * limits.force_n);
            (PushLimit::Force, Some(Insertion::Target(to)))
        } else if advance <= 0.0 {
            (PushLimit::None, None)
        } else if inserted + advance > limits.max_inserted_m {
            (
                PushLimit::Length,
                Some(Insertion::Target(limits.max_inserted_m.max(inserted))),
            )
        } else if pushed_too_hard {
            let to = inserted - give(force - aim * limits.force_n);
            (PushLimit::Force, Some(Insertion::Target(to)))
        } else if let Some(cap) = cap
            && advance > cap * dt
        {
            (PushLimit::None, Some(Insertion::Velocity(cap)))
        } else {
            (PushLimit::None, None)
        };
        let now = self.metrics.procedure_time_s;
        let hand = &mut self.hands[index];
        hand.limit_acted_at = (limit == PushLimit::Force && (pulled_too_hard || pushed_too_hard))
            .then_some((force, relieving));
        let report = hand
            .push_reports
            .update(
                hand.push_limit != PushLimit::None,
                limit != PushLimit::None,
                now,
            )
            .then_some(limit);
        hand.push_limit = limit;
        if let Some(limit) = report {
            let name = self
                .strand
                .device(index)
                .map_or_else(String::new, |d| d.name.clone());
            let message = match limit {
                PushLimit::Force if pulled_too_hard => format!(
                    "pull held at {:.1} N: the hand's limit is {:.0} N",
                    -force, limits.pull_force_n
                ),
                PushLimit::Force if limits.buckling => format!(
                    "push held at {force:.1} N: the {name} buckles outside the sheath at {:.1} N",
                    limits.force_n
                ),
                PushLimit::Force => format!(
                    "push held at {force:.1} N: the hand's limit is {:.0} N",
                    limits.force_n
                ),
                _ => format!(
                    "the {name} is in to its hub: {:.0} mm inserted, {:.0} mm outside",
                    limits.max_inserted_m * 1e3,
                    self.assets.spec.limits.outside_mm
                ),
            };
            self.event(EventKind::Limit, message);
        }
        let twist = self.limited_twist(index, operator.twist, dt);
        (insertion.is_some() || twist.is_some()).then(|| cathlab_physics::Command {
            insertion: insertion.unwrap_or(operator.insertion),
            twist: twist.unwrap_or(operator.twist),
        })
    }

    /// The twist this step runs instead of the operator's for instrument `index` when the
    /// hand's torque holds it back (None: the operator's), as the force holds a push: a twist
    /// that would load a hand whose last torque is at its strength is held, and a hand past it
    /// gives the excess back over the inserted length's torsional stiffness G·J/L (at most
    /// [`MAX_GIVE_RAD`] a step), aiming [`GIVE_UNDERSHOOT`] under it, so the torque a twist
    /// stores in a device whose tip cannot turn is bounded (and with it the axial load its
    /// writhing puts on the hand). A twist the other way, unloading, runs as commanded.
    /// Reports each new hold once.
    fn limited_twist(&mut self, index: usize, operator: Twist, dt: f64) -> Option<Twist> {
        let twisted = self.strand.twist_rad(index);
        let turn = match operator {
            Twist::Rate(w) => w * dt,
            Twist::Target(angle) => angle - twisted,
        };
        let hand = &self.hands[index];
        let torque = hand.reaction.torque_nm;
        let limit = hand.limits.torque_nm;
        // The reaction's sign is the twist's that loads it (the device resists).
        let loading = turn * torque > 0.0 || turn == 0.0;
        let held = loading && torque.abs() >= limit;
        let twist = held.then(|| {
            let torsional_stiffness = self.proximal_stiffness(index, |p| p.torsional_stiffness_nm2);
            let excess = torque.abs() - (1.0 - GIVE_UNDERSHOOT) * limit;
            let give = (excess.max(0.0) / torsional_stiffness).min(MAX_GIVE_RAD);
            Twist::Target(twisted - torque.signum() * give)
        });
        let now = self.metrics.procedure_time_s;
        let hand = &mut self.hands[index];
        let report = hand.twist_reports.update(hand.twist_held, held, now);
        hand.twist_held = held;
        if report {
            self.event(
                EventKind::Limit,
                format!(
                    "twist held at {:.0} mN·m: the hand's limit is {:.0} mN·m",
                    torque.abs() * 1e3,
                    limit * 1e3
                ),
            );
        }
        twist
    }

    /// Instrument `index`'s stiffness at its hand over the length inserted: `modulus` of its
    /// proximal section (E·A in N, or G·J in N·m²) over that length (at least 1 mm), so N/m
    /// or N·m/rad; infinite for an instrument with no section.
    fn proximal_stiffness(
        &self,
        index: usize,
        modulus: impl Fn(&cathlab_physics::BeamProperties) -> f64,
    ) -> f64 {
        self.strand
            .device(index)
            .and_then(|d| d.sections.first())
            .map_or(f64::INFINITY, |s| modulus(&s.beam_properties()))
            / self.strand.inserted_m(index).max(1e-3)
    }

    /// Back to the scene's start with device `index` of a one-device scene (a stack scene: its
    /// stack), the hands afresh; an injection under way stops.
    pub(super) fn restart_device(&mut self, index: usize) -> Result<()> {
        self.strand = Strand::start(&self.assets, index)?;
        self.exchanging = None;
        self.active_device = index;
        self.hands = start_hands(&self.assets, index);
        self.previous_instruments.clear();
        self.strand.set_effort(fidelity_effort(self.fidelity).0)?;
        self.previous_tip = tracked_tip(&self.assets, &self.strand);
        if let Some(hemo) = &mut self.hemo
            && hemo.injection.is_some()
        {
            hemo.injection = None;
            self.update_injection()?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{GIVE_UNDERSHOOT, MAX_GIVE_M, gives_way, next_give};

    #[test]
    fn a_second_give_follows_the_secant_to_the_aim() {
        let aim = (1.0 - GIVE_UNDERSHOOT) * 10.0;
        // A hand held at 10.3 N gave 5 µm and felt 10.2 N: 20 kN/m, so the aim is that much
        // further back (a linear response meets it exactly).
        let f0 = 10.3;
        let next = next_give((0.0, f0), (-5e-6, 10.2), 10.0);
        assert!((f0 + 20e3 * next - aim).abs() < 1e-9, "{next} m");
        // Pulls alike (the pull's limit is negative).
        let next = next_give((0.0, -10.3), (5e-6, -10.2), -10.0);
        assert!((-10.3 + 20e3 * next + aim).abs() < 1e-9, "{next} m");
        // A hand already giving 2 µm in the hold: the secant runs from there.
        let next = next_give((-2e-6, f0), (-7e-6, 10.2), 10.0);
        assert!((f0 + 20e3 * (next + 2e-6) - aim).abs() < 1e-9, "{next} m");
        // A force that did not fall with the give: four times as far beyond the hold; never
        // past the most a hand gives in a step, never less than the give tried.
        assert_eq!(next_give((0.0, 10.3), (-5e-6, 10.35), 10.0), -20e-6);
        assert_eq!(next_give((0.0, 10.3), (-0.2e-3, 10.3), 10.0), -MAX_GIVE_M);
        assert_eq!(
            next_give((0.0, 10.3), (-5e-6, 10.2999999), 10.0),
            -MAX_GIVE_M
        );
        // A try that overshot, here through zero to the push side (a pull held at 10.3 N
        // gave 0.3 mm in and the hand then pushed with 16 N): back along the secant.
        let next = next_give((0.0, -10.3), (0.3e-3, 16.0), -10.0);
        assert!(
            (-10.3 + 26.3 / 0.3e-3 * next + aim).abs() < 1e-9,
            "{next} m"
        );
        assert!(next > 0.0 && next < 0.3e-3, "{next} m");
    }

    #[test]
    fn a_hold_that_does_not_lower_the_force_gives_way_and_a_give_that_raised_it_holds() {
        // The limit did not act last step: give way.
        assert!(gives_way(None, 10.5));
        // A give that lowered the force (or left it) is repeated; one that raised it is not.
        assert!(gives_way(Some((10.5, true)), 10.3));
        assert!(!gives_way(Some((10.17, true)), 10.40));
        // Regression: a hold the force crept past (10.40 → 10.48 N, the stroke scene's guide
        // pushed at its limit) was renewed every step; it now gives way. A hold that lowers
        // the force holds on.
        assert!(gives_way(Some((10.40, false)), 10.48));
        assert!(!gives_way(Some((10.48, false)), 10.41));
        // Pulls alike (negative forces, by magnitude).
        assert!(!gives_way(Some((-10.1, true)), -10.3));
        assert!(gives_way(Some((-10.3, false)), -10.3));
    }
}
