//! Integration tests of sartor-runtime: the model and binding formats, the network against an
//! f64 reference, batching and threading, a long GRU rollout, the animator on the built-in body,
//! the default post-process against the exact query, and a count of allocations per frame.

mod alloc;
mod animator;
mod binding;
mod common;
mod extremes;
mod format;
mod network;
mod post_process;
#[allow(dead_code)]
mod reference;
mod rollout;
mod scene;
mod strain;
mod writers;
