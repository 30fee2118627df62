//! sartor-import's integration tests (one binary, one module per importer).

mod common;
/// The geometry core's test fixtures (random poses, a stand-in body), shared rather than copied.
#[allow(dead_code)]
#[path = "../../../sartor-core/tests/it/common.rs"]
mod core_fixtures;
mod import;
mod smpl;
mod walk;
