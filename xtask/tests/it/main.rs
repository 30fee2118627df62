//! End-to-end tests of the command line (one binary): the tiny pipeline as CI runs it.

mod pipeline;
mod shipped;
