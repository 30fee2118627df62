//! # sartor-runtime
//!
//! Runs an exported sartor garment model without any learning framework: the garment fit MLP
//! `R_G(β)` and the wrinkle GRU `R_L(β, θ)` of Santesteban et al. 2019, on lean CPU kernels.
//! It never depends on burn, so it can ship in a game engine, a server or WebAssembly.
//!
//! - **Format** ([`GarmentModel`], [`ModelHeader`]): `model.safetensors` + `model.json`, read
//!   and validated (shapes, finiteness, content hash), and written for tests and exporters.
//!   The module docs of `format.rs` list every tensor and JSON field.
//! - **Kernels** ([`Matrix`], [`Linear`], [`GruCell`], [`Mlp`], [`OutputLayer`]): weights in
//!   f32, f16 or int8 ([`Precision`]), matrix–vector products that stream each row once with
//!   32 independent accumulators, a batched variant in which several avatars share one pass
//!   over the weights, the fused GRU step (three gates per matrix pass), optional rayon over
//!   row blocks ([`Parallelism`]). Deterministic: results are bitwise independent of threads,
//!   batch size and instruction set. On x86-64 the kernels use AVX2 + F16C intrinsics when the
//!   CPU has them ([`instruction_set`] says which; `SARTOR_RUNTIME_ISA=portable` forces the
//!   portable code, for comparisons); the only `unsafe` code of the crate is that dispatch
//!   module. On `wasm32` (the try-on page) the workspace enables `simd128`, with which LLVM
//!   vectorises the portable code: the same bits, 3.7× faster in Chromium. Error bounds of f16 and int8 storage are documented in `kernels/matrix.rs`.
//! - **Network** ([`GarmentNetwork`], [`Workspace`], [`NetworkOptions`]): normalisation, fit,
//!   one wrinkle frame, batches; a frame allocates nothing. A reduced output rank is chosen at
//!   load: the first `k'` PCA components, or a truncated SVD of a dense layer
//!   ([`truncated_svd`]).
//! - **Binding** ([`GarmentBinding`], sartor-core's one binding type, re-exported):
//!   `binding.safetensors` + `binding.json` beside the model: garment template `T̄_c`,
//!   triangles, cloth skin weights `W_c`, the body region the garment can touch, garment and
//!   body ids; validated on load, against the body, and against the model
//!   ([`ModelHeader::check_binding`]).
//! - **Animation** ([`GarmentRig`], [`GarmentAnimator`], [`GarmentCrowd`]): the rig shares the
//!   loaded assets (`Arc`) across avatars; an avatar caches `R_G(β)`, `J(β)` and the shaped body
//!   region once per shape, then turns each pose into garment vertices —
//!   `T̄_c + Δ_G + Δ_L`, skinned with `W_c` by `sartor_core::skin_points`, then optionally
//!   strain-limited ([`StrainLimit`]), then the collision post-process ([`CollisionOptions`],
//!   [`CollisionQuery`]) — carrying the GRU state and the
//!   previous pose. A crowd steps many avatars with one pass over the weights. A frame
//!   allocates nothing (tested with a counting allocator).
//! - **Levels of detail** ([`LevelOfDetail`]): precision and output rank at load, fit-only
//!   mode (static try-on), post-process on or off and its query.
//! - **Writers** ([`write_obj_sequence`], [`write_gltf`], [`render`], `render_png`): OBJ
//!   sequences, animated glTF 2.0 (morph targets, validated with the Khronos validator), and a
//!   software rasterizer for previews (PNG with the default `png` feature).
//!
//! ```
//! use sartor_runtime::{GruCell, Matrix, Parallelism, Precision};
//!
//! // A GRU with 2 inputs and 1 hidden unit: rows (r, z, n).
//! let w_ih = Matrix::from_f32(3, 2, vec![0.5, -0.5, 0.1, 0.2, 1.0, 1.0], Precision::F32)?;
//! let w_hh = Matrix::from_f32(3, 1, vec![0.3, -0.3, 0.7], Precision::F32)?;
//! let cell = GruCell::new(w_ih, w_hh, vec![0.0; 3], vec![0.0; 3])?;
//! let mut scratch = cell.scratch(1);
//! let mut h = [0.0f32];
//! for t in 0..100 {
//!     let x = [(t as f32 * 0.1).sin(), 1.0];
//!     cell.step(&x, &mut h, &mut scratch, Parallelism::Sequential)?;
//!     assert!(h[0].abs() <= 1.0);
//! }
//! # Ok::<(), sartor_runtime::Error>(())
//! ```

mod animator;
mod collision;
mod error;
mod format;
mod kernels;
mod lowrank;
mod network;
mod strain;
mod writers;

pub use animator::{
    AnimatorOptions, BetaOutOfRange, CollisionCount, FitMode, GarmentAnimator, GarmentCrowd,
    GarmentRig, LevelOfDetail, PostProcessReport, StageTimes, WrinkleMode,
};
pub use collision::{
    BodyRegion, CertifyStats, CollisionOptions, CollisionQuery, DEFAULT_MARGIN_M, Interpenetration,
};
pub use error::{Error, Result};
pub use format::{
    AssetId, DenseWeights, Feature, FeatureBlock, GarmentModel, GruWeights, MODEL_FORMAT,
    MODEL_JSON, MODEL_TENSORS, MODEL_VERSION, MeanStd, ModelHeader, ModelSizes, ModelWeights,
    NormStats, OutputKind, PcaWeights, RotationEncoding, TensorStorage, TrainingBetas,
};
pub use kernels::{
    GruCell, GruScratch, INT8_ZERO_ROW, Linear, Matrix, Mlp, MlpScratch, OutputLayer,
    OutputScratch, Parallelism, Precision, instruction_set,
};
pub use lowrank::{LowRank, truncated_svd};
pub use network::{GarmentNetwork, NetworkOptions, Workspace};
pub use sartor_core::{
    BINDING_FORMAT, BINDING_JSON, BINDING_TENSORS, BINDING_VERSION, BindingHeader, GarmentBinding,
};
pub use strain::StrainLimit;
#[cfg(feature = "png")]
pub use writers::render_png;
pub use writers::{
    BODY_COLOR, Camera, GARMENT_COLOR, Image, MeshSequence, Panel, Projection, RenderMesh, render,
    write_gltf, write_obj_sequence,
};
