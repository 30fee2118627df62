//! sartor-body's integration tests (one binary, one module per area).

mod common;
mod model;
mod smpl;
