//! sartor-import's integration tests (one binary, one module per importer).

mod common;
mod import;
mod smpl;
mod walk;
