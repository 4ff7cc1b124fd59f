//! Sleep at rest: a device whose hands are still and whose nodes have stopped moving skips its
//! steps (its state is already its equilibrium) until a hand moves or a load, an effort or an
//! instrument changes, as rigid-body engines put resting bodies to sleep.

use nalgebra::{UnitQuaternion, Vector3};

use crate::beam::ContactStep;

/// When a device at rest sleeps: after `window_steps` steps in a row with every hand still in
/// which no node moved more than `max_step_m` in any one step, no node's mean position over
/// the window's second half lies more than `max_drift_m` from its mean over the first half,
/// and no node's frame turned more than `max_turn_rad` from the window's start to its end.
/// The drift of the means decides, not each step's motion: a device whose contacts chatter
/// (a few steps sinking micrometres into the wall, one pushing it back out) goes nowhere,
/// while one creeping along the wall at `2 max_drift_m / window_steps` a step or faster stays
/// awake. While asleep a step costs nothing and changes nothing: the contacts, their forces and
/// the hands' reactions stay those of the last step taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sleep {
    /// Steps in a row with the hands still over which the device must stay put (even).
    pub window_steps: u32,
    /// The most any node's mean position may drift from the window's first half to its
    /// second (m).
    pub max_drift_m: f64,
    /// The most any node may move in one step of the window (m).
    pub max_step_m: f64,
    /// The most any node's frame may turn over the window (rad).
    pub max_turn_rad: f64,
}

impl Default for Sleep {
    /// 100 steps (0.2 s at 500 Hz) with the means drifting under 5 µm (a creep of 0.1 µm a
    /// step, 50 µm/s at 500 Hz, or faster stays awake: at that pace a device moves one
    /// detector pixel, 0.2-0.4 mm, in 4-8 s), no node moving 25 µm in a step (two and a half
    /// contact tolerances) and no frame turning 5 mrad.
    fn default() -> Self {
        Self {
            window_steps: 100,
            max_drift_m: 5e-6,
            max_step_m: 25e-6,
            max_turn_rad: 5e-3,
        }
    }
}

/// The contacts detected and those pushing in `last`, the step a sleeping device repeats.
pub(crate) fn contact_counts(last: Option<&ContactStep>) -> (usize, usize) {
    last.map_or((0, 0), |s| {
        (
            s.contacts.len(),
            s.response.local.iter().filter(|l| l.x > 0.0).count(),
        )
    })
}

/// A device's progress towards sleep: the steps of the current window, its nodes' frames at
/// the window's start, their positions summed over each half, and where they were before the
/// step being taken.
#[derive(Debug, Clone, Default)]
pub(crate) struct Stillness {
    quiet: u32,
    asleep: bool,
    start: Vec<UnitQuaternion<f64>>,
    halves: [Vec<Vector3<f64>>; 2],
    before: Vec<Vector3<f64>>,
}

impl Stillness {
    /// Whether the device sleeps under `sleep` (never without it).
    pub(crate) fn asleep(&self, sleep: Option<&Sleep>) -> bool {
        sleep.is_some() && self.asleep
    }

    /// Something other than a hand changed (a load, the effort, an instrument): awake, and
    /// the window starts again.
    pub(crate) fn wake(&mut self) {
        self.asleep = false;
        self.quiet = 0;
    }

    /// Before a step is taken with the hands `still` (or not): where the nodes are.
    pub(crate) fn before_step(
        &mut self,
        sleep: Option<&Sleep>,
        still: bool,
        positions: &[Vector3<f64>],
        rotations: &[UnitQuaternion<f64>],
    ) {
        self.before.clear();
        if sleep.is_none() || !still {
            self.wake();
            return;
        }
        if self.quiet == 0 {
            self.start.clear();
            self.start.extend_from_slice(rotations);
            for half in &mut self.halves {
                half.clear();
                half.resize(positions.len(), Vector3::zeros());
            }
        }
        self.before.extend_from_slice(positions);
    }

    /// After a step taken with the hands still: one more step of the window if no node moved
    /// past the step bound (a split or merged element ends the window too); at the window's
    /// end, asleep if the means' drift and the frames' turn are within the bounds, else a new
    /// window.
    pub(crate) fn after_step(
        &mut self,
        sleep: Option<&Sleep>,
        positions: &[Vector3<f64>],
        rotations: &[UnitQuaternion<f64>],
    ) {
        let Some(sleep) = sleep else {
            return;
        };
        if self.before.is_empty() {
            return;
        }
        let same = self.before.len() == positions.len()
            && self.start.len() == rotations.len()
            && self.halves[0].len() == positions.len();
        let stepped = self
            .before
            .iter()
            .zip(positions)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        self.before.clear();
        if !same || stepped > sleep.max_step_m {
            self.quiet = 0;
            return;
        }
        let window = sleep.window_steps.max(2);
        let half = usize::from(self.quiet >= window / 2);
        for (sum, p) in self.halves[half].iter_mut().zip(positions) {
            *sum += p;
        }
        self.quiet += 1;
        if self.quiet < window {
            return;
        }
        self.quiet = 0;
        let (first, second) = (window / 2, window - window / 2);
        let drift = self.halves[0]
            .iter()
            .zip(&self.halves[1])
            .map(|(a, b)| (a / first as f64 - b / second as f64).norm())
            .fold(0.0, f64::max);
        let turn = self
            .start
            .iter()
            .zip(rotations)
            .map(|(q0, q)| q0.angle_to(q))
            .fold(0.0, f64::max);
        self.asleep = drift <= sleep.max_drift_m && turn <= sleep.max_turn_rad;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nodes(offset: f64) -> (Vec<Vector3<f64>>, Vec<UnitQuaternion<f64>>) {
        let p = (0..4)
            .map(|i| Vector3::new(i as f64 * 1e-3 + offset, 0.0, 0.0))
            .collect();
        let q = vec![UnitQuaternion::identity(); 4];
        (p, q)
    }

    /// Steps `s` `n` times with the hands still, the nodes going from `from` to `to` (offsets
    /// along x, m) each step; returns whether it sleeps after.
    fn steps(s: &mut Stillness, sleep: &Sleep, n: usize, from: f64, to: f64) -> bool {
        let (a, q) = nodes(from);
        let (b, _) = nodes(to);
        for _ in 0..n {
            s.before_step(Some(sleep), true, &a, &q);
            s.after_step(Some(sleep), &b, &q);
        }
        s.asleep(Some(sleep))
    }

    #[test]
    fn sleeps_after_a_window_without_drift_and_not_while_creeping_or_moved() {
        // Windows of 4: the means of steps 1-2 and 3-4 compared.
        let sleep = Sleep {
            window_steps: 4,
            ..Sleep::default()
        };
        let mut s = Stillness::default();
        assert!(!steps(&mut s, &sleep, 3, 0.0, 0.0));
        assert!(steps(&mut s, &sleep, 1, 0.0, 0.0));
        assert!(!s.asleep(None));
        s.wake();
        assert!(!s.asleep(Some(&sleep)));
        // A chatter (10 µm out and back) goes nowhere: asleep after the window.
        let (a, q) = nodes(0.0);
        let (b, _) = nodes(10e-6);
        for k in 0..4 {
            let (from, to) = if k % 2 == 0 { (&a, &b) } else { (&b, &a) };
            s.before_step(Some(&sleep), true, from, &q);
            s.after_step(Some(&sleep), to, &q);
        }
        assert!(s.asleep(Some(&sleep)));
        // A creep of 3 µm a step: the halves' means 6 µm apart, awake window after window.
        let mut s = Stillness::default();
        let (mut p, q) = nodes(0.0);
        for _ in 0..12 {
            let next: Vec<_> = p.iter().map(|x| x + Vector3::new(3e-6, 0.0, 0.0)).collect();
            s.before_step(Some(&sleep), true, &p, &q);
            s.after_step(Some(&sleep), &next, &q);
            p = next;
        }
        assert!(!s.asleep(Some(&sleep)));
        // A step of 30 µm, a moving hand, a changed node count, a frame turned 6 mrad: awake.
        let mut s = Stillness::default();
        assert!(!steps(&mut s, &sleep, 8, 0.0, 30e-6));
        let (a, q) = nodes(0.0);
        for _ in 0..8 {
            s.before_step(Some(&sleep), false, &a, &q);
            s.after_step(Some(&sleep), &a, &q);
        }
        assert!(!s.asleep(Some(&sleep)));
        for _ in 0..8 {
            s.before_step(Some(&sleep), true, &a, &q);
            s.after_step(Some(&sleep), &a[..3], &q[..3]);
        }
        assert!(!s.asleep(Some(&sleep)));
        let turned = vec![UnitQuaternion::from_euler_angles(6e-3, 0.0, 0.0); 4];
        for _ in 0..4 {
            s.before_step(Some(&sleep), true, &a, &q);
            s.after_step(Some(&sleep), &a, &turned);
        }
        assert!(!s.asleep(Some(&sleep)));
        // Asleep, a moving hand wakes it.
        let mut s = Stillness::default();
        assert!(steps(&mut s, &sleep, 4, 0.0, 0.0));
        s.before_step(Some(&sleep), false, &a, &q);
        assert!(!s.asleep(Some(&sleep)));
    }
}
