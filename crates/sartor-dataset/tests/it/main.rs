//! sartor-dataset's integration tests (one binary).

mod build;
mod common;
mod extract;
