//! sartor-core's integration tests (one binary).

mod body_distance;
mod common;
mod measure;
mod model;
mod proximity;
