//! sartor-core's integration tests (one binary).

mod body_distance;
mod common;
mod model;
mod proximity;
