//! Procedural neurovascular phantom (placeholder until written).

/// Aortic arch type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArchType {
    /// Type I.
    I,
}
/// Parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeuroPhantomParams;
/// Builds it.
pub fn neuro_phantom() {}
