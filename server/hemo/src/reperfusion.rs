//! The reperfusion grade after an occlusion, from the flow solution: the occluded territory
//! is the outlets whose flow the clots took (below [`TERRITORY_THRESHOLD`] of their open
//! flow); its reperfused fraction is the open-flow-weighted share of that flow that is back
//! now, each outlet counted up to its open flow; the expanded TICI grade follows from the
//! fraction (eTICI, Liebeskind et al., Stroke 2019).

use serde::{Deserialize, Serialize};

use crate::error::{HemoError, Result};
use crate::flow::FlowSolution;

/// An outlet belongs to the occluded territory when the clots leave it less than this
/// fraction of its open flow.
pub const TERRITORY_THRESHOLD: f64 = 0.9;

/// The expanded Thrombolysis in Cerebral Infarction grade.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Etici {
    /// No reperfusion.
    Grade0,
    /// Flow past the occlusion without distal branch filling (below 1 % here).
    Grade1,
    /// Reperfusion of less than half the territory.
    Grade2a,
    /// 50–66 %.
    Grade2b50,
    /// 67–89 %.
    Grade2b67,
    /// 90–99 %.
    Grade2c,
    /// Complete.
    Grade3,
}

impl Etici {
    /// The grade of a reperfused fraction (0–1) of the occluded territory.
    pub fn of_fraction(fraction: f64) -> Self {
        match fraction {
            f if f >= 0.995 => Etici::Grade3,
            f if f >= 0.90 => Etici::Grade2c,
            f if f >= 0.67 => Etici::Grade2b67,
            f if f >= 0.50 => Etici::Grade2b50,
            f if f >= 0.01 => Etici::Grade2a,
            f if f > 1e-4 => Etici::Grade1,
            _ => Etici::Grade0,
        }
    }

    /// The grade as clinicians write it ("2b67").
    pub fn label(&self) -> &'static str {
        match self {
            Etici::Grade0 => "0",
            Etici::Grade1 => "1",
            Etici::Grade2a => "2a",
            Etici::Grade2b50 => "2b50",
            Etici::Grade2b67 => "2b67",
            Etici::Grade2c => "2c",
            Etici::Grade3 => "3",
        }
    }

    /// Whether the grade counts as successful reperfusion (eTICI ≥ 2b50).
    pub fn successful(&self) -> bool {
        *self >= Etici::Grade2b50
    }
}

/// The occluded territory and how much of it is reperfused.
#[derive(Debug, Clone, PartialEq)]
pub struct Reperfusion {
    /// Outlets of the occluded territory (indices into the network's outlets).
    pub territory: Vec<usize>,
    /// Reperfused fraction of the territory (0–1).
    pub fraction: f64,
    /// Its grade.
    pub grade: Etici,
}

/// The occluded territory: outlets whose flow in `occluded` is below
/// [`TERRITORY_THRESHOLD`] of their flow in `open` (both solutions of one network).
pub fn occluded_territory(open: &FlowSolution, occluded: &FlowSolution) -> Result<Vec<usize>> {
    if open.outlet_flows.len() != occluded.outlet_flows.len() {
        return Err(HemoError::Solver(
            "the open and occluded solutions are of different networks".into(),
        ));
    }
    Ok(open
        .outlet_flows
        .iter()
        .zip(&occluded.outlet_flows)
        .enumerate()
        .filter(|(_, (o, c))| **o > 0.0 && **c < TERRITORY_THRESHOLD * **o)
        .map(|(i, _)| i)
        .collect())
}

/// How much of `territory` the flow `now` reperfuses, against `open`.
pub fn reperfusion(
    open: &FlowSolution,
    now: &FlowSolution,
    territory: &[usize],
) -> Result<Reperfusion> {
    let mut open_total = 0.0;
    let mut back = 0.0;
    for &i in territory {
        let (o, n) = match (open.outlet_flows.get(i), now.outlet_flows.get(i)) {
            (Some(o), Some(n)) => (*o, *n),
            _ => {
                return Err(HemoError::Solver(format!(
                    "outlet {i} is not in both solutions"
                )));
            }
        };
        open_total += o;
        back += n.clamp(0.0, o);
    }
    let fraction = if open_total > 0.0 {
        back / open_total
    } else {
        1.0
    };
    Ok(Reperfusion {
        territory: territory.to_vec(),
        fraction,
        grade: Etici::of_fraction(fraction),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grades_follow_the_etici_bands() {
        let cases = [
            (0.0, "0"),
            (0.005, "1"),
            (0.3, "2a"),
            (0.5, "2b50"),
            (0.66, "2b50"),
            (0.67, "2b67"),
            (0.89, "2b67"),
            (0.9, "2c"),
            (0.99, "2c"),
            (1.0, "3"),
        ];
        for (f, label) in cases {
            assert_eq!(Etici::of_fraction(f).label(), label, "{f}");
        }
        assert!(Etici::Grade2b50.successful() && !Etici::Grade2a.successful());
    }
}
