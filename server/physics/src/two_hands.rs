//! The two-hand autopilot: a scripted operator driving a coaxial stack the way one is driven
//! in an angio suite. The innermost instrument (the wire) is steered along the route by the
//! single-device [`Autopilot`]; the instrument around it (the catheter) follows its tip at a
//! fixed lag; any instrument around those (a guide, a distal-access catheter) holds, or, with
//! parks planned, follows at a further lag each until it reaches its park. Optional: a wire exchange
//! partway (catheter parked, wire withdrawn to the hub and replaced), tracking the catheter
//! over the wire once the wire has reached the target, and sending a microcatheter over a
//! microwire through the catheter at the end. Deterministic; it only looks at the stack and
//! returns what each hand does, so the same plan drives a bare [`Stack`] and a session's
//! world through recorded commands.

use cathlab_anatomy::graph::{VesselGraph, VesselPath};
use nalgebra::{Point3, Vector3};

use crate::autopilot::{Autopilot, AutopilotPhase, AutopilotSettings, GraphHandle};
use crate::device::Device;
use crate::error::{PhysicsError, Result};
use crate::navigation::{Command, Insertion, Twist};
use crate::stack::Stack;
use crate::wall::Wall;

/// What happens once the wire has reached the target.
#[derive(Debug, Clone, PartialEq)]
pub enum Finish {
    /// Nothing more: the plan is done when the wire is there.
    AtWire,
    /// The wire holds and the catheter tracks over it to `catheter_track_m` behind its tip.
    TrackCatheter,
    /// The catheter is tracked, the wire withdrawn and removed, and a microcatheter (first)
    /// sent through the catheter over a microwire (second) until the microcatheter is the
    /// given distance (m) beyond the catheter's tip.
    Microcatheter(Device, Device, f64),
}

/// A two-hand plan.
#[derive(Debug, Clone, PartialEq)]
pub struct TwoHandPlan {
    /// How far behind the wire's tip the catheter follows (m).
    pub catheter_lag_m: f64,
    /// When tracking, how far behind the wire's tip the catheter stops (m).
    pub catheter_track_m: f64,
    /// A wire change: once the wire tip is this far along the route from its start (m), park
    /// the catheter there, withdraw the wire and lead on with this device and settings.
    pub exchange: Option<(f64, Device, AutopilotSettings)>,
    /// Autopilot settings of the first wire.
    pub autopilot: AutopilotSettings,
    /// What happens at the target.
    pub finish: Finish,
    /// Inserted lengths (m) at which the instruments around the catheter park, outermost
    /// first: while the wire leads, each follows the one inside it `catheter_lag_m` behind
    /// until it reaches its park (a guide brought up from the access with the rest inside
    /// it). Empty: they hold where they are.
    pub outer_parks_m: Vec<f64>,
}

/// What the hands do next.
#[derive(Debug, Clone, PartialEq)]
pub enum TwoHandAction {
    /// Step with these commands (instrument index, command); instruments not named keep
    /// theirs.
    Drive(Vec<(usize, Command)>),
    /// Exchange instrument `.0` (withdrawn to its hub) for the device; no step.
    Exchange(usize, Device),
    /// Remove the innermost instrument (withdrawn) and add these, outermost first; no step.
    Replace(Vec<Device>),
    /// The plan is done.
    Done,
}

/// Where a two-hand plan is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwoHandPhase {
    /// The wire leads, the catheter follows.
    Lead,
    /// The wire holds, the catheter tracks over it.
    Track,
    /// The catheter holds, the wire is withdrawn to the hub.
    Withdraw,
    /// The microcatheter goes through the catheter over the microwire.
    Micro,
    /// Done.
    Done,
}

/// The two-hand autopilot's state.
#[derive(Debug, Clone)]
pub struct TwoHands<'g> {
    graph: GraphHandle<'g>,
    path: VesselPath,
    start_along_m: f64,
    /// Route samples every millimetre from the path's start (m).
    route: Vec<Point3<f64>>,
    plan: TwoHandPlan,
    pilot: Autopilot<'g>,
    phase: TwoHandPhase,
    exchanged: bool,
    catheter_park: Option<f64>,
    /// A new wire is being loaded up to the catheter's tip.
    loading: bool,
    retries: usize,
    wire_reached: bool,
}

/// Holds instrument `k` of `stack` where it is, at its twist.
fn hold<W: Wall>(stack: &Stack<W>, k: usize) -> (usize, Command) {
    (
        k,
        Command {
            insertion: Insertion::Velocity(0.0),
            twist: Twist::Target(stack.twist_rad(k).unwrap_or(0.0)),
        },
    )
}

/// Moves instrument `k` of `stack` to inserted length `l` (m), at its twist.
fn move_to<W: Wall>(stack: &Stack<W>, k: usize, l: f64) -> (usize, Command) {
    (
        k,
        Command {
            insertion: Insertion::Target(l),
            twist: Twist::Target(stack.twist_rad(k).unwrap_or(0.0)),
        },
    )
}

impl<'g> TwoHands<'g> {
    /// A plan along `path` of `graph`, the stack entering `start_along_m` metres along it.
    pub fn new(
        graph: &'g VesselGraph,
        path: VesselPath,
        start_along_m: f64,
        plan: TwoHandPlan,
    ) -> Result<Self> {
        Self::with_graph(GraphHandle::Borrowed(graph), path, start_along_m, plan)
    }

    /// As [`TwoHands::new`] on a shared graph: an operator that can live in a session.
    pub fn shared(
        graph: std::sync::Arc<VesselGraph>,
        path: VesselPath,
        start_along_m: f64,
        plan: TwoHandPlan,
    ) -> Result<TwoHands<'static>> {
        TwoHands::with_graph(GraphHandle::Shared(graph), path, start_along_m, plan)
    }

    fn with_graph(
        graph: GraphHandle<'g>,
        path: VesselPath,
        start_along_m: f64,
        plan: TwoHandPlan,
    ) -> Result<Self> {
        let pilot =
            Autopilot::with_graph(graph.clone(), path.clone(), start_along_m, plan.autopilot)?;
        let route = graph
            .sample_path(&path, 1e-3)
            .into_iter()
            .map(|(p, _)| p)
            .collect();
        Ok(Self {
            graph,
            path,
            start_along_m,
            route,
            exchanged: plan.exchange.is_none(),
            plan,
            pilot,
            phase: TwoHandPhase::Lead,
            catheter_park: None,
            loading: false,
            retries: 0,
            wire_reached: false,
        })
    }

    /// The phase.
    pub fn phase(&self) -> TwoHandPhase {
        self.phase
    }

    /// Whether the wire has reached the target.
    pub fn wire_reached(&self) -> bool {
        self.wire_reached
    }

    /// Whether the planned wire exchange has been made (true when none is planned).
    pub fn exchanged(&self) -> bool {
        self.exchanged
    }

    /// Pull-backs of the wire's autopilot so far.
    pub fn retries(&self) -> usize {
        self.retries + self.pilot.retries()
    }

    /// Whether the wire's pilot gave up after stalling (the plan is done short of the
    /// target).
    pub fn stalled(&self) -> bool {
        self.pilot.phase() == AutopilotPhase::Stalled
    }

    /// Distance along the route from its start of the route sample nearest to `p` (m).
    fn along_route(&self, p: &Vector3<f64>) -> f64 {
        self.route
            .iter()
            .enumerate()
            .min_by(|a, b| (a.1.coords - p).norm().total_cmp(&(b.1.coords - p).norm()))
            .map_or(0.0, |(i, _)| i as f64 * 1e-3)
    }

    /// The instruments around the catheter follow its goal `goal` (inserted length, m) at a
    /// further `catheter_lag_m` each, up to their parks; none goes back (a wire's retry does
    /// not pull the guide). Without parks they hold (`drive` already says so).
    fn follow_outer<W: Wall>(
        &self,
        stack: &Stack<W>,
        drive: &mut [(usize, Command)],
        catheter: usize,
        goal: f64,
    ) {
        for (k, park) in self.plan.outer_parks_m.iter().enumerate().take(catheter) {
            let now = stack.inserted_m(k).unwrap_or(0.0);
            let lag = (catheter - k) as f64 * self.plan.catheter_lag_m;
            let follow = (goal - lag).min(*park);
            if follow > now {
                drive[k] = move_to(stack, k, follow);
            }
        }
    }

    /// Looks at `stack` (its two innermost instruments are the catheter and the wire) and says
    /// what the hands do next.
    pub fn next<W: Wall>(&mut self, stack: &Stack<W>) -> Result<TwoHandAction> {
        if stack.len() < 2 {
            return Err(PhysicsError::Stack(
                "the two-hand autopilot needs a catheter and a wire".into(),
            ));
        }
        // A phase change decides again at once (at most a few times).
        for _ in 0..8 {
            if let Some(action) = self.decide(stack)? {
                return Ok(action);
            }
        }
        Err(PhysicsError::Stack(
            "the two-hand autopilot could not decide".into(),
        ))
    }

    /// One decision: `None` when the phase changed and the next phase decides.
    fn decide<W: Wall>(&mut self, stack: &Stack<W>) -> Result<Option<TwoHandAction>> {
        let wire = stack.len() - 1;
        let catheter = wire - 1;
        let wire_l = stack.inserted_m(wire).unwrap_or(0.0);
        let catheter_l = stack.inserted_m(catheter).unwrap_or(0.0);
        // Instruments around the catheter hold.
        let mut drive: Vec<(usize, Command)> = (0..catheter).map(|k| hold(stack, k)).collect();
        match self.phase {
            TwoHandPhase::Lead => {
                // A new wire runs inside the catheter up to its tip at the hand's full speed.
                if wire_l >= catheter_l {
                    self.loading = false;
                }
                let command = if self.loading {
                    move_to(stack, wire, catheter_l).1
                } else {
                    self.pilot
                        .command(&stack.instrument(wire).expect("the wire is there"))
                };
                if !self.exchanged
                    && let Some((at, _, _)) = &self.plan.exchange
                {
                    let tip = stack.tip_position(wire).unwrap_or_else(Vector3::zeros);
                    if self.along_route(&tip) >= *at {
                        self.phase = TwoHandPhase::Track;
                        return Ok(None);
                    }
                }
                if self.pilot.phase() == AutopilotPhase::Stalled {
                    // Given up: every hand holds.
                    self.phase = TwoHandPhase::Done;
                    return Ok(None);
                }
                if self.pilot.phase() == AutopilotPhase::Reached {
                    self.wire_reached = true;
                    self.phase = match self.plan.finish {
                        Finish::AtWire => TwoHandPhase::Done,
                        _ => TwoHandPhase::Track,
                    };
                    return Ok(None);
                }
                // The catheter follows the wire's tip; after an exchange it holds where it was
                // parked while the new wire travels up to its tip and leads on.
                let floor = self.catheter_park.unwrap_or(0.01);
                let goal = (wire_l - self.plan.catheter_lag_m).max(floor);
                self.follow_outer(stack, &mut drive, catheter, goal);
                drive.push((wire, command));
                drive.push(move_to(stack, catheter, goal));
            }
            TwoHandPhase::Track => {
                let goal = wire_l - self.plan.catheter_track_m;
                if catheter_l >= goal - 1e-9 {
                    self.catheter_park = Some(catheter_l);
                    self.phase = if self.exchanged && self.plan.finish == Finish::TrackCatheter {
                        TwoHandPhase::Done
                    } else {
                        TwoHandPhase::Withdraw
                    };
                    return Ok(None);
                }
                self.follow_outer(stack, &mut drive, catheter, goal);
                drive.push(hold(stack, wire));
                drive.push(move_to(stack, catheter, goal));
            }
            TwoHandPhase::Withdraw => {
                let (hub, _) = stack.inserted_range_m(wire).expect("a wire");
                if wire_l <= hub {
                    if !self.exchanged {
                        let (_, device, settings) =
                            self.plan.exchange.clone().expect("an exchange is planned");
                        let next = Autopilot::with_graph(
                            self.graph.clone(),
                            self.path.clone(),
                            self.start_along_m,
                            settings,
                        )?;
                        self.retries += std::mem::replace(&mut self.pilot, next).retries();
                        self.exchanged = true;
                        self.loading = true;
                        self.phase = TwoHandPhase::Lead;
                        return Ok(Some(TwoHandAction::Exchange(wire, device)));
                    }
                    if let Finish::Microcatheter(micro, microwire, _) = &self.plan.finish {
                        self.phase = TwoHandPhase::Micro;
                        return Ok(Some(TwoHandAction::Replace(vec![
                            micro.clone(),
                            microwire.clone(),
                        ])));
                    }
                    self.phase = TwoHandPhase::Done;
                    return Ok(None);
                }
                match self.catheter_park {
                    Some(park) => drive.push(move_to(stack, catheter, park)),
                    None => drive.push(hold(stack, catheter)),
                }
                drive.push(move_to(stack, wire, hub));
            }
            TwoHandPhase::Micro => {
                // Here the microcatheter is `catheter` and the microwire `wire`; the catheter
                // the microcatheter goes through is the one around it.
                let Finish::Microcatheter(_, _, beyond) = self.plan.finish else {
                    self.phase = TwoHandPhase::Done;
                    return Ok(None);
                };
                let parked = catheter.checked_sub(1).ok_or_else(|| {
                    PhysicsError::Stack("a microcatheter needs a catheter around it".into())
                })?;
                let parked_l = stack.inserted_m(parked).unwrap_or(0.0);
                let micro_l = catheter_l;
                let goal = parked_l + beyond;
                if micro_l >= goal {
                    self.phase = TwoHandPhase::Done;
                    return Ok(None);
                }
                // The microwire leads the microcatheter by 10 mm outside the catheter.
                let wire_goal = (micro_l + 0.01).min(goal + 0.01);
                drive.push(move_to(stack, wire, wire_goal.max(micro_l)));
                let micro_goal = if wire_l >= micro_l + 0.005 || micro_l < parked_l - 0.01 {
                    goal
                } else {
                    micro_l
                };
                drive.push(move_to(stack, catheter, micro_goal));
            }
            TwoHandPhase::Done => return Ok(Some(TwoHandAction::Done)),
        }
        Ok(Some(TwoHandAction::Drive(drive)))
    }
}
