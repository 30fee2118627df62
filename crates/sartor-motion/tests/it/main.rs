//! sartor-motion's integration tests (one binary).

mod motion_sources;
