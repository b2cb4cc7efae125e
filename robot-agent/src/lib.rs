//! soundmap robot agent library.
