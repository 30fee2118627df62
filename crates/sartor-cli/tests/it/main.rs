//! sartor-cli's integration tests (one binary).

mod bvh_motion;
mod relocated;
