//! Coaxial stacks in merged mode: composite stiffness against analytic cantilevers, the
//! stiffness-weighted blend of rest shapes, twist of one instrument without the other,
//! invariants of the instruments' positions, and bad input; nested mode against merged; the
//! device catalogue; and two-hand runs in the real arch-to-circle-of-Willis anatomy.
//!
//! Figures print with `cargo test -p cathlab-physics --test coaxial -- --nocapture`.
//!
//! One module a topic: `merged` (mechanics of the composite strand), `control` (fit, bad
//! input, exchange, ranges, effort), `catalogue` (device definitions), `nested` (nested
//! coupling), `arch_to_cow` (runs in the real anatomy), `capstan` (friction on a wire slid
//! round a bend: the capstan law, the hand's force against the wall's, and a wire pushed
//! through a still catheter), `slide` (inner instruments sliding with their own axial strain: each
//! hand its own load); shared builders and measures in `support`.

mod arch_to_cow;
mod capstan;
mod catalogue;
mod control;
mod merged;
mod nested;
mod slide;
mod support;
