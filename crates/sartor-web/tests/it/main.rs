//! sartor-web's integration tests: the wrapper's logic, natively, on the shipped assets; and
//! the page in headless Chromium (`browser.rs`).

mod browser;
mod common;
mod errors;
mod try_on;
