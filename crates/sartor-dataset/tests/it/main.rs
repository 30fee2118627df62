//! sartor-dataset's integration tests (one binary).

mod common;
mod extract;
