//! soundmap simulation library.
