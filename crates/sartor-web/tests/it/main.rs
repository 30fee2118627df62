//! sartor-web's integration tests: the wrapper's logic, natively, on the shipped assets; and
//! the page in headless Chromium (`browser.rs`).

mod browser;
mod common;
mod errors;
/// Reference arithmetic shared with the runtime's tests.
#[allow(dead_code)]
#[path = "../../../sartor-runtime/tests/it/reference.rs"]
mod reference;
mod try_on;
