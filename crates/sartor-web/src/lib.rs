//! # sartor-web
//!
//! sartor's runtime in the browser: the shipped garment model on the body, driven by a web
//! page (`web/`, built by `cargo xtask web`). Built for `wasm32-unknown-unknown` with
//! wasm-bindgen; everything but the JavaScript bindings is plain Rust and tested natively.
//!
//! - **Files** ([`FileSet`], [`MODEL_FILES`], [`BODY_FILES`]): the model folder's and the
//!   body folder's files as bytes (a page has no file system), read by the same readers as on
//!   disk, with the same checks.
//! - **Try-on** ([`TryOn`]): one avatar — shape from β or from the phenotype sliders
//!   ([`PhenotypeSliders`], the command line's rule), a motion (procedural, the walk cycle, a
//!   stored CMU clip, a dropped BVH: retargeted as `sartor_motion::load_motion` does), play,
//!   seek, another garment model put on (`set_garment`: another resolution), per-frame garment
//!   and body vertices and the time of each stage ([`FrameTimes`]).
//!   Sequential: the runtime's threads are not used in the browser.
//! - **Held limbs in a worker** ([`LimbsWorker`]): what a change of shape, a scrub or a new clip
//!   waits on, computed in a Web Worker from the try-on's job (`TryOn::arms_job`) and taken up
//!   by it (`TryOn::absorb_arms`), so that the page's thread keeps drawing and playing.
//! - **JavaScript** (`js.rs`): `AssetFiles`, `TryOn`, `LimbsWorker` and `proceduralClips` for the
//!   page; every fault comes back as a JavaScript `Error` naming it.
//! - **Kernel probe** ([`kernel_probe`]): the runtime's matrix kernels on fixed inputs, for
//!   the browser test's bitwise comparison of the WebAssembly build with the native one.
//! - **Serving** (`serve_dir`, native only): the static server of `cargo xtask web --serve`
//!   and of the browser test.
//!
//! ```no_run
//! use sartor_web::{FileSet, PhenotypeSliders, TryOn, TryOnOptions};
//!
//! let mut files = FileSet::new();
//! for name in sartor_web::MODEL_FILES {
//!     let file = name.trim_start_matches("model/");
//!     files.insert(name, std::fs::read(format!("datasets/models/default/{file}"))?);
//! }
//! for name in sartor_web::BODY_FILES {
//!     let file = name.trim_start_matches("body/");
//!     files.insert(name, std::fs::read(format!("datasets/body/makehuman/{file}"))?);
//! }
//! let mut try_on = TryOn::load(files, TryOnOptions::default())?;
//! try_on.set_phenotype(&PhenotypeSliders {
//!     gender: 0.0, height_m: 1.70, weight: 0.75, muscle: 0.5, age_years: 25.0,
//! })?;
//! try_on.set_motion(TryOn::motion_procedural("dance_disco")?)?;
//! for _ in 0..30 {
//!     try_on.step()?;
//! }
//! assert!(try_on.garment_vertices().iter().all(|v| v.is_finite()));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod clock;
mod error;
mod files;
mod js;
mod limbs;
mod post;
mod probe;
#[cfg(not(target_arch = "wasm32"))]
mod serve;
mod session;

pub use clock::now_ms;
pub use error::{Error, Result};
pub use files::{BODY_FILES, FileSet, MODEL_FILES};
pub use js::{
    AssetFiles, WebLimbsWorker, WebPostWorker, WebTryOn, kernel_probe_js, procedural_clips,
};
pub use limbs::LimbsWorker;
pub use post::PostWorker;
pub use probe::kernel_probe;
#[cfg(not(target_arch = "wasm32"))]
pub use serve::{Server, serve_dir};
pub use session::{
    FrameTimes, PhenotypeSliders, TryOn, TryOnOptions, WARMUP_FRAMES, procedural_clip_names,
};
