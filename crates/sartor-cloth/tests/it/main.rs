//! sartor-cloth's integration tests (one binary, one module per area).

mod common;
mod contact;
mod drive;
mod dynamics;
mod failure;
mod finite_difference;
mod garment;
mod material;
mod regression;
mod stress_strain;
