//! The operator's command at a device's proximal end: push/pull and twist, each as a rate or a
//! target.

/// Push/pull command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Insertion {
    /// Insertion speed (m/s; negative pulls).
    Velocity(f64),
    /// Inserted length to move to (m).
    Target(f64),
}

/// Twist command (about the device axis at the entry point).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Twist {
    /// Twist rate (rad/s).
    Rate(f64),
    /// Twist angle to move to (rad).
    Target(f64),
}

/// The operator's command at the device's proximal end.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Push/pull.
    pub insertion: Insertion,
    /// Twist.
    pub twist: Twist,
}

impl Default for Command {
    fn default() -> Self {
        Self {
            insertion: Insertion::Velocity(0.0),
            twist: Twist::Rate(0.0),
        }
    }
}
