//! sartor-model's integration tests (one binary).

mod contact;
mod export;
mod learn;
/// Reference arithmetic shared with the runtime's tests.
#[allow(dead_code)]
#[path = "../../../sartor-runtime/tests/it/reference.rs"]
mod reference;
mod synthetic;
