//! Passes of a thrombectomy and their force balances: a stent retriever engaged in the clot
//! and pulled back into a receiving catheter, or an aspiration catheter sealed on the clot's
//! face that ingests it or, corked, drags it out. Each pass advances by the hand's pull and
//! ends retrieved or failed, with the fragments it broke off (emboli).
//!
//! **Drag.** A clot dragged proximally resists with Coulomb friction on the wall, the normal
//! force being its own wedging pressure over its wall area plus the stent's radial force
//! pressing it outward; while it still occludes its site the pressure drop across it pushes
//! it back; around bends the resistance grows by the capstan factor `exp(μΘ)` of the turning
//! `Θ` travelled (the pulling tension presses the clot on the outer wall). The friction
//! rises with speed ([`crate::ClotMechanics::wall_friction_at`]).
//!
//! **Stent grip.** Strut friction on the stent's radial force over its overlap with the
//! clot, plus interlock: the clot bulging into the open cells must shear off (at its
//! strength) to escape, over the open area, in proportion to how deep the stent opened into
//! it (soft, red clots integrate; stiff, fibrin-rich clots keep the struts at their
//! surface).
//! Where grip falls short of drag the stent slides out of the clot and the overlap, hence the
//! grip, shrinks. A clot tail beyond the stent's distal end is dragged through the clot's own
//! section and breaks off when the stress exceeds the clot's strength. At the receiving
//! catheter, the clot must be squeezed into its bore ([`crate::ClotMechanics::ingestion_pressure_pa`]),
//! helped by suction through it; short of that, the part not held between the struts is
//! stripped off at the tip.
//!
//! **Aspiration.** Suction `Δp` over the bore, times the apposition (the sealed fraction of
//! the bore): the clot is ingested when `Δp·a` reaches its ingestion pressure; otherwise it
//! corks the tip, held by `Δp·a·A`, and comes out with the catheter while that exceeds the
//! drag. Default suction 90 kPa at the tip: aspiration pumps draw about −29 inHg (−98 kPa,
//! Penumbra Pump MAX specification, not re-verified here), less losses (assumed).

use crate::clot::Clot;
use crate::error::{Result, require_non_negative, require_positive};
use crate::path::RetrievalPath;
use crate::stent::{Deployment, StentRetriever, Surroundings, cerebral_wall_stiffness};
use std::f64::consts::PI;

/// Suction at an aspiration catheter's tip with the pump on (Pa below blood pressure).
pub const DEFAULT_SUCTION_PA: f64 = 90e3;

/// Spacing of the stent's rings in the deployment solve (m).
pub const RING_SPACING_M: f64 = 0.25e-3;

/// Resistance (N) of a clot `length_m` long dragged proximally where the vessel's radius is
/// `radius_m` (m), after turning `turning_rad` (rad), pressed on the wall by `radial_n` (N)
/// besides its own wedging, at `speed_m_s`, with `pressure_drop_pa` across it while it
/// occludes.
pub fn drag_n(
    clot: &Clot,
    length_m: f64,
    radius_m: f64,
    turning_rad: f64,
    radial_n: f64,
    speed_m_s: f64,
    pressure_drop_pa: f64,
) -> f64 {
    let mu = clot.mechanics.wall_friction_at(speed_m_s);
    let wedge = clot.wall_pressure_pa(radius_m);
    let normal = wedge * 2.0 * PI * radius_m * length_m + radial_n;
    let occluding = if wedge > 0.0 {
        pressure_drop_pa * PI * radius_m * radius_m
    } else {
        0.0
    };
    (mu * normal + occluding) * (mu * turning_rad).exp()
}

/// How a pass ended.
#[derive(Debug, Clone, PartialEq)]
pub enum PassOutcome {
    /// The clot (what is left of it) is out of the patient, in the catheter.
    Retrieved {
        /// Fragments broken off on the way (lengths, m), now emboli downstream.
        emboli_m: Vec<f64>,
    },
    /// The clot slipped or was stripped and is still in the patient.
    Failed {
        /// Fragments broken off (lengths, m).
        emboli_m: Vec<f64>,
        /// What slipped: `stent` (slid out of the clot) or `cork` (lost from the tip).
        reason: &'static str,
    },
}

impl PassOutcome {
    /// Whether the clot came out.
    pub fn retrieved(&self) -> bool {
        matches!(self, Self::Retrieved { .. })
    }

    /// The emboli (m).
    pub fn emboli_m(&self) -> &[f64] {
        match self {
            Self::Retrieved { emboli_m } | Self::Failed { emboli_m, .. } => emboli_m,
        }
    }
}

/// A stent-retriever pass as set up: the stent deployed across the clot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StentSetup {
    /// The stent.
    pub stent: StentRetriever,
    /// The clot.
    pub clot: Clot,
    /// Where the stent's distal end lies beyond the clot's distal end (m; negative: short of
    /// it, leaving a distal tail).
    pub distal_offset_m: f64,
    /// Inner radius of the microcatheter that delivered it, the channel it left (m).
    pub channel_radius_m: f64,
    /// Bore of the catheter the stent is pulled into (m).
    pub receiving_bore_m: f64,
    /// Suction through the receiving catheter (Pa), 0 without.
    pub suction_pa: f64,
    /// Pressure drop across the clot while it occludes (Pa).
    pub pressure_drop_pa: f64,
}

impl StentSetup {
    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        self.stent.validate()?;
        self.clot.validate()?;
        if !self.distal_offset_m.is_finite() {
            return Err(crate::ThrombectomyError::InvalidParameter {
                name: "stent distal offset (m)".into(),
                value: self.distal_offset_m,
                requirement: "finite",
            });
        }
        require_positive("microcatheter inner radius (m)", self.channel_radius_m)?;
        require_positive("receiving catheter bore (m)", self.receiving_bore_m)?;
        require_non_negative("suction (Pa)", self.suction_pa)?;
        require_non_negative("pressure drop across the clot (Pa)", self.pressure_drop_pa)
    }
}

/// How the deployed stent holds the clot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Engagement {
    /// Overlap with the clot, from its proximal end (m).
    pub overlap_m: (f64, f64),
    /// The stent's radial force over the overlap (N).
    pub radial_n: f64,
    /// Mean depth to which the stent opened into the clot (0 at the channel, 1 at the wall).
    pub embedding: f64,
    /// Grip (N): strut friction × radial force + strength × open area × embedding × the
    /// stent's surface over the overlap.
    pub grip_n: f64,
}

impl Engagement {
    /// Deploys the stent across the clot (stent coordinates from its proximal end) and
    /// measures its hold.
    pub fn of(setup: &StentSetup) -> Result<Self> {
        setup.validate()?;
        let StentSetup {
            stent,
            clot,
            distal_offset_m,
            channel_radius_m,
            ..
        } = *setup;
        // Clot coordinates: 0 at its proximal end, L at its distal end. The stent covers
        // [a, b].
        let b = clot.length_m + distal_offset_m;
        let a = b - stent.length_m;
        let radius = clot.vessel_radius_m;
        let wall = cerebral_wall_stiffness(radius);
        let modulus = clot.mechanics.modulus_pa;
        let length = clot.length_m;
        // The whole stent unsheathed: the microcatheter pulled back past its proximal end
        // (ring 0, held at the microcatheter's radius).
        let deployment = Deployment::solve(
            &stent,
            stent.length_m,
            channel_radius_m,
            RING_SPACING_M,
            |s| {
                let x = a + s;
                Surroundings {
                    vessel_radius_m: radius,
                    wall_stiffness: wall,
                    clot: ((0.0..=length).contains(&x)).then_some((modulus, channel_radius_m)),
                }
            },
        )?;
        let (from, to) = (a.max(0.0), b.min(length));
        if to <= from {
            return Ok(Self {
                overlap_m: (0.0, 0.0),
                radial_n: 0.0,
                embedding: 0.0,
                grip_n: 0.0,
            });
        }
        let radial_n = deployment.radial_force_over_n(from - a, to - a);
        let (mut depth, mut surface, mut count) = (0.0, 0.0, 0usize);
        for (i, r) in deployment.radii_m.iter().enumerate() {
            let x = a + i as f64 * deployment.spacing_m;
            if (from..=to).contains(&x) {
                depth += ((r - channel_radius_m) / (radius - channel_radius_m)).clamp(0.0, 1.0);
                surface += 2.0 * PI * r;
                count += 1;
            }
        }
        let (embedding, circumference) = if count > 0 {
            (depth / count as f64, surface / count as f64)
        } else {
            (0.0, 0.0)
        };
        let interlock =
            clot.mechanics.strength_pa * stent.open_area * embedding * circumference * (to - from);
        Ok(Self {
            overlap_m: (from, to),
            radial_n,
            embedding,
            grip_n: stent.strut_friction * radial_n + interlock,
        })
    }
}

/// A stent-retriever pass under way.
#[derive(Debug, Clone, PartialEq)]
pub struct StentPass {
    setup: StentSetup,
    engagement: Engagement,
    /// How far the clot has moved from its site (m).
    travel_m: f64,
    /// How far the stent has slid out of the clot (m).
    slip_m: f64,
    /// What is left of the clot (m).
    length_m: f64,
    emboli_m: Vec<f64>,
    tail_checked: bool,
    peak_drag_n: f64,
}

impl StentPass {
    /// The stent deployed across the clot.
    pub fn new(setup: StentSetup) -> Result<Self> {
        let engagement = Engagement::of(&setup)?;
        Ok(Self {
            setup,
            engagement,
            travel_m: 0.0,
            slip_m: 0.0,
            length_m: setup.clot.length_m,
            emboli_m: Vec::new(),
            tail_checked: false,
            peak_drag_n: 0.0,
        })
    }

    /// How it holds.
    pub fn engagement(&self) -> &Engagement {
        &self.engagement
    }

    /// How far the clot has moved from its site (m).
    pub fn travel_m(&self) -> f64 {
        self.travel_m
    }

    /// The largest drag met so far (N): what the hand felt.
    pub fn peak_drag_n(&self) -> f64 {
        self.peak_drag_n
    }

    /// Grip now (N): the engagement's, in proportion to the overlap left.
    pub fn grip_n(&self) -> f64 {
        let (from, to) = self.engagement.overlap_m;
        let full = to - from;
        if full <= 0.0 {
            return 0.0;
        }
        let left = (to - self.slip_m).min(self.length_m) - from.max(0.0);
        self.engagement.grip_n * (left / full).clamp(0.0, 1.0)
    }

    /// The stent pulled back by `pull_m` (m) at `speed_m_s` along `path`, the receiving
    /// catheter's tip `catheter_at_m` along it (m). Returns the outcome once the pass ends.
    pub fn advance(
        &mut self,
        pull_m: f64,
        speed_m_s: f64,
        path: &RetrievalPath,
        catheter_at_m: f64,
    ) -> Option<PassOutcome> {
        if pull_m <= 0.0 {
            return None;
        }
        let clot = self.setup.clot;
        let (from, to) = self.engagement.overlap_m;
        // A distal tail beyond the stent, dragged by the clot's own section.
        if !self.tail_checked {
            self.tail_checked = true;
            let tail = (self.length_m - to).max(0.0);
            if tail > 0.0 {
                let (radius, turning) = path.at(self.travel_m);
                let load = drag_n(
                    &clot,
                    tail,
                    radius,
                    turning,
                    0.0,
                    speed_m_s,
                    self.setup.pressure_drop_pa,
                );
                if load > clot.mechanics.strength_pa * clot.area_m2() {
                    self.emboli_m.push(tail);
                    self.length_m -= tail;
                }
            }
        }
        let (radius, turning) = path.at(self.travel_m + pull_m);
        let drag = drag_n(
            &clot,
            self.length_m,
            radius,
            turning,
            self.engagement.radial_n * self.grip_n() / self.engagement.grip_n.max(1e-300),
            speed_m_s,
            self.setup.pressure_drop_pa,
        );
        self.peak_drag_n = self.peak_drag_n.max(drag.min(self.grip_n()));
        if self.grip_n() >= drag {
            self.travel_m += pull_m;
        } else {
            self.slip_m += pull_m;
            if self.grip_n() <= 0.0 || (to - self.slip_m) <= from {
                return Some(PassOutcome::Failed {
                    emboli_m: std::mem::take(&mut self.emboli_m),
                    reason: "stent",
                });
            }
        }
        if self.travel_m >= catheter_at_m {
            // Into the receiving catheter: squeezed into its bore, helped by suction.
            let m = &clot.mechanics;
            let bore = self.setup.receiving_bore_m;
            let area = PI * bore * bore / 4.0;
            let entry = m.ingestion_pressure_pa(clot.free_diameter_m(), bore) * area;
            let suction = self.setup.suction_pa * area;
            let mut emboli = std::mem::take(&mut self.emboli_m);
            if self.grip_n() + suction < entry + drag {
                // Stripped at the tip: only what the struts hold comes in.
                let kept = self.engagement.embedding;
                emboli.push(self.length_m * (1.0 - kept));
            }
            return Some(PassOutcome::Retrieved { emboli_m: emboli });
        }
        None
    }
}

/// An aspiration pass as set up: the catheter's tip on the clot's face.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AspirationSetup {
    /// The clot.
    pub clot: Clot,
    /// The aspiration catheter's bore (m).
    pub bore_m: f64,
    /// Suction at the tip (Pa).
    pub suction_pa: f64,
    /// Sealed fraction of the bore (0–1): how squarely the tip sits on the clot's face.
    pub apposition: f64,
    /// Pressure drop across the clot while it occludes (Pa).
    pub pressure_drop_pa: f64,
}

/// An aspiration pass under way.
#[derive(Debug, Clone, PartialEq)]
pub struct AspirationPass {
    setup: AspirationSetup,
    /// Ingested at once.
    ingested: bool,
    travel_m: f64,
}

impl AspirationPass {
    /// Suction on with the tip on the clot: ingested if the sealed suction reaches the clot's
    /// ingestion pressure for the bore, else corked.
    pub fn new(setup: AspirationSetup) -> Result<Self> {
        setup.clot.validate()?;
        require_positive("aspiration catheter bore (m)", setup.bore_m)?;
        require_non_negative("suction (Pa)", setup.suction_pa)?;
        if !(0.0..=1.0).contains(&setup.apposition) {
            return Err(crate::ThrombectomyError::InvalidParameter {
                name: "apposition".into(),
                value: setup.apposition,
                requirement: "between 0 and 1",
            });
        }
        require_non_negative("pressure drop across the clot (Pa)", setup.pressure_drop_pa)?;
        let needed = setup
            .clot
            .mechanics
            .ingestion_pressure_pa(setup.clot.free_diameter_m(), setup.bore_m);
        Ok(Self {
            ingested: setup.suction_pa * setup.apposition >= needed,
            setup,
            travel_m: 0.0,
        })
    }

    /// Whether the clot went straight into the catheter.
    pub fn ingested(&self) -> bool {
        self.ingested
    }

    /// Force holding a corked clot on the tip (N).
    pub fn hold_n(&self) -> f64 {
        let bore = self.setup.bore_m;
        self.setup.suction_pa * self.setup.apposition * PI * bore * bore / 4.0
    }

    /// The catheter withdrawn by `pull_m` (m) at `speed_m_s` along `path`, the guide's tip
    /// `guide_at_m` along it (m). An ingested clot is out at once.
    pub fn advance(
        &mut self,
        pull_m: f64,
        speed_m_s: f64,
        path: &RetrievalPath,
        guide_at_m: f64,
    ) -> Option<PassOutcome> {
        if self.ingested {
            return Some(PassOutcome::Retrieved {
                emboli_m: Vec::new(),
            });
        }
        if pull_m <= 0.0 {
            return None;
        }
        let clot = self.setup.clot;
        let (radius, turning) = path.at(self.travel_m + pull_m);
        let drag = drag_n(
            &clot,
            clot.length_m,
            radius,
            turning,
            0.0,
            speed_m_s,
            self.setup.pressure_drop_pa,
        );
        if self.hold_n() < drag {
            return Some(PassOutcome::Failed {
                emboli_m: Vec::new(),
                reason: "cork",
            });
        }
        self.travel_m += pull_m;
        (self.travel_m >= guide_at_m).then(|| PassOutcome::Retrieved {
            emboli_m: Vec::new(),
        })
    }
}
