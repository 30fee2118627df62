//! Integration tests of sartor-runtime: the model format, the network against an f64
//! reference, batching and threading, and a long GRU rollout.

mod common;
mod format;
mod network;
mod rollout;
