//! sartor-body's integration tests (one binary, one module per area).

mod common;
mod import;
mod model;
mod motion_sources;
mod smpl;
