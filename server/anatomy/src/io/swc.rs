//! SWC trees (`id type x y z radius parent`, one sample per line, `#` comments), converted to
//! a vessel graph: one branch between consecutive branch points, ends or roots.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;

use super::{LengthUnit, check_plausible_extent, parse_f64, read_bytes, utf8};
use crate::error::{AnatomyError, Result};
use crate::graph::{BranchSpec, Side, VesselGraph, VesselKind};

struct Sample {
    position: Point3<f64>,
    radius: f64,
    parent: Option<usize>,
}

/// Parses SWC text whose coordinates and radii are in `unit`.
pub fn parse(bytes: &[u8], unit: LengthUnit, file: &str) -> Result<VesselGraph> {
    let text = utf8(bytes, file)?;
    let mut samples: Vec<Sample> = Vec::new();
    let mut index_of: HashMap<i64, usize> = HashMap::new();
    let mut parents: Vec<(i64, usize)> = Vec::new();
    for (number, raw) in text.lines().enumerate() {
        let line = Some(number + 1);
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let fields: Vec<&str> = content.split_whitespace().collect();
        if fields.len() < 7 {
            return Err(AnatomyError::Parse {
                file: file.to_owned(),
                line,
                message: format!(
                    "{} fields (SWC needs id type x y z radius parent)",
                    fields.len()
                ),
            });
        }
        let int = |k: usize, what: &str| -> Result<i64> {
            fields[k].parse().map_err(|_| AnatomyError::Parse {
                file: file.to_owned(),
                line,
                message: format!("{what} {:?} is not an integer", fields[k]),
            })
        };
        let id = int(0, "id")?;
        let parent = int(6, "parent")?;
        let x = parse_f64(fields[2], file, line, "x")?;
        let y = parse_f64(fields[3], file, line, "y")?;
        let z = parse_f64(fields[4], file, line, "z")?;
        let radius = parse_f64(fields[5], file, line, "radius")?;
        if radius <= 0.0 {
            return Err(AnatomyError::Parse {
                file: file.to_owned(),
                line,
                message: format!("radius {radius} is not positive"),
            });
        }
        if index_of.insert(id, samples.len()).is_some() {
            return Err(AnatomyError::Parse {
                file: file.to_owned(),
                line,
                message: format!("sample id {id} appears twice"),
            });
        }
        parents.push((parent, number + 1));
        samples.push(Sample {
            position: Point3::new(x, y, z) * unit.metres(),
            radius: radius * unit.metres(),
            parent: None,
        });
    }
    if samples.len() < 2 {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: format!("{} samples (a vessel needs 2)", samples.len()),
        });
    }
    for (i, &(parent, line)) in parents.iter().enumerate() {
        if parent < 0 {
            continue;
        }
        let p = *index_of.get(&parent).ok_or_else(|| AnatomyError::Parse {
            file: file.to_owned(),
            line: Some(line),
            message: format!("parent {parent} does not exist"),
        })?;
        if p == i {
            return Err(AnatomyError::Parse {
                file: file.to_owned(),
                line: Some(line),
                message: "sample is its own parent".into(),
            });
        }
        samples[i].parent = Some(p);
    }
    // Reject cycles: walking up from any sample must reach a root within n steps.
    for (start, &(_, line)) in parents.iter().enumerate() {
        let mut at = start;
        for _ in 0..=samples.len() {
            match samples[at].parent {
                Some(p) => at = p,
                None => break,
            }
        }
        if samples[at].parent.is_some() {
            return Err(AnatomyError::Parse {
                file: file.to_owned(),
                line: Some(line),
                message: "parent links form a cycle".into(),
            });
        }
    }
    let (lo, hi) = samples
        .iter()
        .fold((samples[0].position, samples[0].position), |(lo, hi), s| {
            (lo.inf(&s.position), hi.sup(&s.position))
        });
    check_plausible_extent(file, unit, (hi - lo).amax())?;
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); samples.len()];
    for (i, s) in samples.iter().enumerate() {
        if let Some(p) = s.parent {
            children[p].push(i);
        }
    }
    // A branch starts at a root or a branch point and follows single children.
    let mut graph = VesselGraph::new();
    let mut count = 0;
    for (start, s) in samples.iter().enumerate() {
        if !(s.parent.is_none() || children[start].len() > 1) {
            continue;
        }
        for &first in &children[start] {
            let mut points = vec![samples[start].position];
            let mut radii = vec![samples[first].radius];
            let mut at = first;
            loop {
                points.push(samples[at].position);
                radii.push(samples[at].radius);
                if children[at].len() != 1 {
                    break;
                }
                at = children[at][0];
            }
            count += 1;
            graph
                .add_branch(BranchSpec {
                    name: format!("swc_{count}"),
                    kind: VesselKind::Other,
                    side: Side::Midline,
                    points,
                    radii,
                })
                .map_err(|e| AnatomyError::Parse {
                    file: file.to_owned(),
                    line: None,
                    message: e.to_string(),
                })?;
        }
    }
    if graph.branches.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: "no connected samples".into(),
        });
    }
    Ok(graph)
}

/// Loads an SWC file whose coordinates are in `unit` (SWC files are often in µm).
pub fn load(path: &Path, unit: LengthUnit) -> Result<VesselGraph> {
    parse(&read_bytes(path)?, unit, &path.display().to_string())
}
