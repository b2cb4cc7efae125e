//! soundmap-agent binary.
fn main() {}
