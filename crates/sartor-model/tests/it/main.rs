//! sartor-model's integration tests (one binary).

mod export;
mod learn;
mod synthetic;
