//! sartor-core's integration tests (one binary).

mod common;
mod model;
