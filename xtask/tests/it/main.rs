//! End-to-end tests of the command line (one binary): the tiny pipeline as CI runs it, the
//! shipped model's regression check, and the crate graph's promises.

mod bench;
mod deps;
mod pipeline;
mod shipped;
