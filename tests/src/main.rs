//! soundmap-sim binary.
fn main() {}
