//! soundmap-coordinator binary.
fn main() {}
