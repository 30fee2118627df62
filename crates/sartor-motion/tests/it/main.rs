//! sartor-motion's integration tests (one binary).

mod amass_fk;
mod bvh_map;
mod clearance;
mod cmu_excerpts;
mod motion_library;
mod motion_sources;
mod numpy_archives;
