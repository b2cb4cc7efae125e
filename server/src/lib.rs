//! soundmap coordinator library.
