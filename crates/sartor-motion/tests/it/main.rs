//! sartor-motion's integration tests (one binary).

mod amass_fk;
mod clearance;
mod cmu_excerpts;
mod motion_library;
mod motion_sources;
