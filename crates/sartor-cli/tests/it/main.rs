//! sartor-cli's integration tests (one binary).

mod relocated;
