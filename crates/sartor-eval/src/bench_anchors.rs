//! `bench runtime --anchors`: the same weights in the tools a user would otherwise pick, in the
//! same run as sartor's own timings.
//!
//! For each model (the shipped one and a paper-size one), this module
//!
//! 1. writes the model (`model.json` + `model.safetensors`) and an inputs file to a temporary
//!    folder: `inputs` `[T, I]` (seeded random raw wrinkle inputs, `mean + std · u`,
//!    `u ∈ [−1, 1]`) and `outputs` `[T, 3V]`, sartor's f32 displacements for them from a zero
//!    state;
//! 2. times sartor's own wrinkle step ([`GarmentNetwork::wrinkle_step`]: normalisation, GRU,
//!    output layer, denormalisation) at batch 1, one frame per call, the state carried, in f32,
//!    f16 and int8, on 1 and 2 threads (a rayon pool of exactly that many threads);
//! 3. measures a memory-bandwidth floor: the time to stream the step's weight bytes once (a
//!    sum over a buffer of exactly that many bytes, median of many repetitions), for each
//!    precision's weight size and thread count;
//! 4. runs `bench/anchors.py` (PyTorch eager and compiled, ONNX Runtime; see the script's
//!    docs), which checks its outputs against sartor's and reports median ms per frame;
//! 5. records ms per frame per engine and thread count, and the ratios sartor / anchor for
//!    sartor's f32 and for its fastest precision, and sartor / floor.
//!
//! The anchors need Python with torch, onnx, onnxruntime, numpy and safetensors
//! ([`ANCHORS_INSTALL`]); when they are missing, [`check_anchors`] fails with that hint.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use sartor_core::io::{OwnedTensor, serialize_tensors, write_atomic};
use sartor_runtime::{
    GarmentModel, GarmentNetwork, ModelSizes, OutputKind, Parallelism, Precision,
};
use serde::{Deserialize, Serialize};

use crate::error::{Context, Error, bail, ensure};
use crate::timing::median;
use crate::{Progress, Result};

/// How to install the anchors' Python packages (quoted in errors and in the README).
pub const ANCHORS_INSTALL: &str = "python3 -m venv .venv-anchors && .venv-anchors/bin/pip \
     install torch onnx onnxruntime numpy safetensors (a plain `pip install torch` pulls about \
     5 GB of CUDA packages; fine for a benchmark venv), then pass --anchors-python \
     .venv-anchors/bin/python or set SARTOR_PYTHON";

/// The `format` of the script's JSON.
const SCRIPT_FORMAT: &str = "sartor-anchors";

/// An anchor agrees with sartor when its largest output difference is at most this fraction
/// of sartor's largest |output| (f32 rounding differs by about 1e-7 of it; a wrong gate order or
/// layout by order 1).
pub const AGREEMENT_TOLERANCE: f64 = 1e-4;

/// Where the anchors come from and how long they run.
#[derive(Clone, Debug)]
pub struct AnchorOptions {
    /// The Python interpreter (`python3`, `$SARTOR_PYTHON`, or a venv's `bin/python`).
    pub python: PathBuf,
    /// The script (`bench/anchors.py`).
    pub script: PathBuf,
    /// The shipped model's folder (`datasets/models/default`), timed besides the paper-size
    /// model.
    pub shipped_model: PathBuf,
    /// Thread counts (1 and 2).
    pub threads: Vec<usize>,
    /// Untimed frames before timing, every engine.
    pub warmup: usize,
    /// Timed frames, every engine.
    pub frames: usize,
    /// Input frames whose outputs every engine checks against sartor's (from a zero state);
    /// the timed frames cycle through them.
    pub check_frames: usize,
}

/// One engine of the script's output.
#[derive(Clone, Debug, Deserialize)]
struct ScriptEntry {
    engine: String,
    threads: usize,
    /// How ONNX Runtime was called (`run` or `io_binding`); absent for torch.
    #[serde(default)]
    call: Option<String>,
    ms_per_frame: Option<f64>,
    #[serde(default)]
    ms_per_frame_mean: Option<f64>,
    #[serde(default)]
    max_abs_diff: Option<f64>,
    error: Option<String>,
}

/// The ONNX export's outcome.
#[derive(Clone, Debug, Deserialize, Serialize)]
struct OnnxExport {
    exporter: Option<String>,
    error: Option<String>,
}

/// The script's JSON (see `bench/anchors.py`).
#[derive(Clone, Debug, Deserialize)]
struct ScriptOutput {
    format: String,
    version: u32,
    #[serde(default)]
    torch_cpu_capability: Option<String>,
    frames_checked: usize,
    onnx_export: OnnxExport,
    engines: Vec<ScriptEntry>,
}

/// What `--check` prints.
#[derive(Debug, Deserialize)]
struct ScriptCheck {
    format: String,
    versions: BTreeMap<String, String>,
}

/// sartor's wrinkle step in one precision.
#[derive(Clone, Debug, Serialize)]
struct SartorTime {
    precision: &'static str,
    /// The mean of `ms_per_frame_before` and `ms_per_frame_after`: the ratios use it.
    ms_per_frame: f64,
    /// Median over the timed frames, timed just before the anchors.
    ms_per_frame_before: f64,
    /// The same, timed again just after them.
    ms_per_frame_after: f64,
}

/// The memory-bandwidth floor of one precision's weights.
#[derive(Clone, Debug, Serialize)]
struct Floor {
    precision: &'static str,
    /// Weight bytes the step reads per frame (GRU and output layer, int8 scales included).
    bytes: usize,
    /// Median ms to stream that many bytes once: the mean of `ms_before` and `ms_after`, as
    /// sartor's `ms_per_frame` is (so that `sartor_*_over_floor` compares times taken at the
    /// same moments).
    ms: f64,
    /// The fastest of the four ways, measured just before the anchors (the four below are
    /// that measurement's).
    ms_before: f64,
    /// The same, measured again just after them.
    ms_after: f64,
    /// Implied bandwidth, GB/s (10^9 bytes).
    gb_per_s: f64,
    /// The same from a buffer in ordinary (4 KiB) pages.
    ms_small_pages: f64,
    /// The same from a buffer advised to huge pages (Linux only; `None` elsewhere).
    ms_huge_pages: Option<f64>,
    /// `ms_small_pages` with each stream prefetched [`PREFETCH_AHEAD_BYTES`] ahead (x86-64
    /// only), as sartor's f16 rows and, on Intel CPUs, its f32 rows are read.
    ms_small_pages_prefetched: Option<f64>,
    /// `ms_huge_pages`, prefetched.
    ms_huge_pages_prefetched: Option<f64>,
}

/// One anchor at one thread count.
#[derive(Clone, Debug, Serialize)]
struct AnchorTime {
    engine: String,
    call: Option<String>,
    /// Median; `None` where the engine failed (see `error`).
    ms_per_frame: Option<f64>,
    ms_per_frame_mean: Option<f64>,
    /// Against sartor's f32 displacements over the checked frames, metres.
    max_abs_diff_m: Option<f64>,
    /// `max_abs_diff_m` within [`AGREEMENT_TOLERANCE`] of the largest output; an engine that
    /// disagrees times another computation and is never the best anchor.
    agrees_with_sartor: Option<bool>,
    error: Option<String>,
    /// sartor f32 / this anchor (below 1: sartor is faster).
    ratio_f32: Option<f64>,
    /// sartor's fastest precision / this anchor.
    ratio_fastest: Option<f64>,
}

/// Everything at one thread count.
#[derive(Clone, Debug, Serialize)]
struct ThreadAnchors {
    threads: usize,
    sartor: Vec<SartorTime>,
    fastest_precision: &'static str,
    floor: Vec<Floor>,
    /// sartor f32 / the f32 floor (1: at the bandwidth).
    sartor_f32_over_floor: Option<f64>,
    /// sartor's fastest precision / the floor of that precision's weight bytes.
    sartor_fastest_over_floor: Option<f64>,
    anchors: Vec<AnchorTime>,
    /// The fastest anchor that ran and agrees with sartor.
    best_anchor: Option<String>,
    best_anchor_ms_per_frame: Option<f64>,
    ratio_f32_to_best_anchor: Option<f64>,
    ratio_fastest_to_best_anchor: Option<f64>,
}

/// sartor's f16 or int8 displacements against its f32 ones over the checked frames.
#[derive(Clone, Debug, Serialize)]
struct PrecisionError {
    precision: &'static str,
    max_abs_diff_m: f64,
    /// Root mean square difference over the root mean square f32 output.
    relative_rms: f64,
}

/// One model's anchors.
#[derive(Clone, Debug, Serialize)]
pub struct ModelAnchors {
    name: String,
    source: String,
    garment: String,
    sizes: ModelSizes,
    output: String,
    /// Wrinkle-step weight MB (10^6 bytes) per precision.
    wrinkle_mb: BTreeMap<&'static str, f64>,
    /// Largest |displacement| of sartor's f32 outputs over the checked frames, metres (the
    /// scale of `max_abs_diff_m`).
    max_abs_output_m: f64,
    precision_error: Vec<PrecisionError>,
    onnx_export: OnnxExport,
    threads: Vec<ThreadAnchors>,
}

/// The `anchors` section of `bench-runtime.json`.
#[derive(Clone, Debug, Serialize)]
pub struct AnchorsReport {
    python: String,
    script: String,
    versions: BTreeMap<String, String>,
    torch_cpu_capability: Option<String>,
    /// The transparent-huge-page mode the OS reports (`always`, `madvise`, `never`), which
    /// decides whether the floor's huge-page buffer gets huge pages.
    transparent_huge_pages: Option<String>,
    warmup_frames: usize,
    timed_frames: usize,
    check_frames: usize,
    models: Vec<ModelAnchors>,
    notes: Vec<&'static str>,
}

/// A model the anchors time: its name, where it comes from, and the weights.
pub(crate) struct AnchorModel {
    pub name: &'static str,
    pub source: String,
    pub model: GarmentModel,
}

const PRECISIONS: [Precision; 3] = [Precision::F32, Precision::F16, Precision::Int8];

fn install_hint(python: &Path) -> String {
    format!(
        "the anchors need Python 3 with torch, onnx, onnxruntime, numpy and safetensors \
         (interpreter: {}); install them with: {ANCHORS_INSTALL}",
        python.display()
    )
}

/// Run the script with `args`; its stdout, with a clear error when Python, the script or its
/// packages are missing or it fails.
fn run_script(options: &AnchorOptions, args: &[&std::ffi::OsStr]) -> Result<String> {
    ensure!(
        options.script.is_file(),
        "anchors script {} not found (run from the repository, or pass --anchors-script)",
        options.script.display()
    );
    let output = Command::new(&options.python)
        .arg(&options.script)
        .args(args)
        .output()
        .map_err(|e| {
            Error::Invalid(format!(
                "could not start {}: {e}; {}",
                options.python.display(),
                install_hint(&options.python)
            ))
        })?;
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        let tail: String = {
            let chars: Vec<char> = stderr.chars().collect();
            chars[chars.len().saturating_sub(3000)..].iter().collect()
        };
        let hint = if output.status.code() == Some(3) {
            // The script's own "missing packages" exit.
            install_hint(&options.python)
        } else {
            "see the script's output above".to_string()
        };
        bail!(
            "{} {} failed ({}): {}\n{hint}",
            options.python.display(),
            options.script.display(),
            output.status,
            tail.trim()
        );
    }
    Ok(String::from_utf8_lossy(&output.stdout).into_owned())
}

/// Check that the script runs and its Python packages import; returns their versions. Run
/// first, so that a missing package fails before minutes of timing.
pub fn check_anchors(options: &AnchorOptions) -> Result<BTreeMap<String, String>> {
    let out = run_script(options, &["--check".as_ref()])?;
    let check: ScriptCheck = serde_json::from_str(out.trim())
        .with_context(|| format!("{}: --check output", options.script.display()))?;
    ensure!(
        check.format == SCRIPT_FORMAT,
        "{}: --check printed format {:?}, expected {SCRIPT_FORMAT:?}",
        options.script.display(),
        check.format
    );
    Ok(check.versions)
}

/// Concurrent read streams of [`stream_sum`]: a matrix–vector product reads several rows at
/// once, and on the development machine 8 streams read 109 MB about 7 % faster than one (3.7
/// against 3.9–4.2 ms), so one stream would not be a floor.
const STREAMS: usize = 8;
/// Words per stream and step: eight independent lanes, so the adds neither serialise nor stop
/// the compiler from vectorising.
const LANES: usize = 8;

/// How far ahead of each stream the prefetched floor asks for lines: sartor's row kernels'
/// `STREAM_AHEAD` (see `sartor-runtime`'s `kernels/dispatch.rs`).
const PREFETCH_AHEAD_BYTES: usize = 2048;

/// Wrapping sum of `words`, read once as [`STREAMS`] concurrent streams over as many
/// contiguous parts (the words left over after whole steps are added at the end), built for
/// AVX2 where the CPU has it; `prefetch`: each stream's line [`PREFETCH_AHEAD_BYTES`] ahead
/// asked for at every step (x86-64 only; elsewhere the plain read). The baseline x86-64 build
/// (two words per add) was the limit, not the memory: on the AMD EPYC VM it read 109.5 MB in
/// 3.6 ms, the AVX2 build in 2.4–2.5 (in the same process), and ONNX Runtime's paper-size step,
/// which reads those bytes, ran under the baseline build's figure. (LLVM's AVX-512 build of
/// this loop read 5 GB/s.) Prefetching, because a floor must not be beaten: on the 2-core
/// Intel Xeon VM sartor's prefetched f32 rows read the paper-size weights faster than the plain
/// read did.
fn stream_sum(words: &[u64], prefetch: bool) -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn avx2(words: &[u64], prefetch: bool) -> u64 {
            if prefetch {
                stream_sum_as_built::<true>(words)
            } else {
                stream_sum_as_built::<false>(words)
            }
        }
        if is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (detected just above).
            #[allow(unsafe_code)]
            return unsafe { avx2(words, prefetch) };
        }
    }
    if prefetch {
        stream_sum_as_built::<true>(words)
    } else {
        stream_sum_as_built::<false>(words)
    }
}

/// [`stream_sum`] for the target features of its caller.
#[inline(always)]
fn stream_sum_as_built<const PREFETCH: bool>(words: &[u64]) -> u64 {
    let steps = words.len() / (STREAMS * LANES);
    let part = steps * LANES;
    let parts: [&[u64]; STREAMS] = std::array::from_fn(|k| &words[k * part..(k + 1) * part]);
    let mut acc = [[0u64; LANES]; STREAMS];
    for i in (0..part).step_by(LANES) {
        if PREFETCH {
            for p in &parts {
                prefetch_line(p.as_ptr().wrapping_add(i + PREFETCH_AHEAD_BYTES / 8));
            }
        }
        for (a, p) in acc.iter_mut().zip(&parts) {
            for (a, &w) in a.iter_mut().zip(&p[i..i + LANES]) {
                *a = a.wrapping_add(w);
            }
        }
    }
    let tail = words[STREAMS * part..]
        .iter()
        .fold(0u64, |s, &w| s.wrapping_add(w));
    acc.iter().flatten().fold(tail, |s, &a| s.wrapping_add(a))
}

/// A hint to load the cache line at `p` (x86-64; nothing elsewhere).
#[inline(always)]
fn prefetch_line(p: *const u64) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: a prefetch never faults and changes nothing the program can observe, whatever
        // the address (formed with wrapping arithmetic, never read).
        #[allow(unsafe_code)]
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(p.cast())
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

fn thread_pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Invalid(format!("a rayon pool of {threads} threads: {e}")))
}

/// The memory-bandwidth floor: median ms to read `bytes` bytes once (rounded up to whole
/// 8-byte words) on `threads` threads, the faster of ordinary and huge pages.
pub fn stream_floor_ms(bytes: usize, threads: usize, reps: usize) -> Result<f64> {
    Ok(stream_floor(bytes, threads, reps)?.ms())
}

/// The floor's measurements (see [`stream_floor`]).
#[derive(Clone, Copy, Debug)]
struct StreamFloor {
    small_pages_ms: f64,
    huge_pages_ms: Option<f64>,
    small_pages_prefetched_ms: Option<f64>,
    huge_pages_prefetched_ms: Option<f64>,
}

impl StreamFloor {
    /// The floor: the fastest of them.
    fn ms(&self) -> f64 {
        [
            self.huge_pages_ms,
            self.small_pages_prefetched_ms,
            self.huge_pages_prefetched_ms,
        ]
        .into_iter()
        .flatten()
        .fold(self.small_pages_ms, f64::min)
    }
}

/// Median ms to read `bytes` bytes once (rounded up to whole 8-byte words) on `threads`
/// threads (each a contiguous share; more than one thread runs in a rayon pool of exactly that
/// many), over `reps` repetitions after three untimed ones: from a buffer in ordinary pages and,
/// on Linux, from one advised to huge pages ([`paged_words`]), each plainly and (on x86-64)
/// prefetched. Buffers are filled with non-zero values so that every page is really backed.
///
/// Both, because a floor must not be beaten: on the 2-core Intel Xeon VM (transparent huge
/// pages `madvise`) eight streams read 108 MB in 7.2–7.5 ms from 4 KiB pages and 5.3–5.5 ms
/// from 2 MiB pages, and ONNX Runtime's paper-size step, which reads those bytes, took 5.2 ms
/// there — under a 4 KiB-page floor. (sartor's own weights advised to huge pages were no
/// faster: `gru1500_out13272` f32 6.2 ms either way, so its kernels keep ordinary pages.)
fn stream_floor(bytes: usize, threads: usize, reps: usize) -> Result<StreamFloor> {
    ensure!(bytes > 0, "no bytes to stream");
    ensure!(threads > 0, "no threads to stream with");
    ensure!(reps > 0, "no repetitions");
    let n = bytes.div_ceil(8);
    let word = |i: usize| (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let pool = thread_pool(threads)?;
    let time = |words: &[u64], prefetch: bool| -> f64 {
        let chunk = words.len().div_ceil(threads).max(1);
        let once = || -> u64 {
            if threads == 1 {
                stream_sum(std::hint::black_box(words), prefetch)
            } else {
                pool.install(|| {
                    std::hint::black_box(words)
                        .par_chunks(chunk)
                        .map(|part| stream_sum(part, prefetch))
                        .reduce(|| 0, u64::wrapping_add)
                })
            }
        };
        let mut ms = Vec::with_capacity(reps);
        for rep in 0..reps + 3 {
            let start = Instant::now();
            std::hint::black_box(once());
            if rep >= 3 {
                ms.push(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        median(&ms)
    };
    // Both ways of reading a buffer, the plain one first; the prefetched one only where a
    // prefetch is issued.
    let both = |words: &[u64]| {
        (
            time(words, false),
            cfg!(target_arch = "x86_64").then(|| time(words, true)),
        )
    };
    let small = paged_words(n, word, false).unwrap_or_else(|| (0..n).map(word).collect());
    let (small_pages_ms, small_pages_prefetched_ms) = both(&small);
    drop(small);
    let huge = paged_words(n, word, true).map(|words| both(&words));
    Ok(StreamFloor {
        small_pages_ms,
        huge_pages_ms: huge.map(|h| h.0),
        small_pages_prefetched_ms,
        huge_pages_prefetched_ms: huge.and_then(|h| h.1),
    })
}

/// `n` words `word(i)` in a fresh buffer whose whole 2 MiB pages Linux is asked to back with
/// huge pages (`huge`: `madvise(MADV_HUGEPAGE)` before the pages are first written, which it
/// follows when its transparent huge pages are `always` or `madvise`, and `MADV_COLLAPSE`
/// after, for memory the allocator had touched before) or never to (`MADV_NOHUGEPAGE`, so that
/// the ordinary-page figure is one also where huge pages are `always`). `None` off Linux or
/// when the kernel refuses the first advice.
#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
fn paged_words(n: usize, word: impl Fn(usize) -> u64, huge: bool) -> Option<Vec<u64>> {
    const HUGE_PAGE: usize = 2 << 20;
    /// `MADV_COLLAPSE` (Linux 6.1; the UAPI value, which the `libc` crate defines for glibc
    /// only). An older kernel answers `EINVAL` and the pages stay as they are.
    const MADV_COLLAPSE: libc::c_int = 25;
    let mut words: Vec<u64> = Vec::with_capacity(n);
    let start = words.as_ptr() as usize;
    let first = start.next_multiple_of(HUGE_PAGE);
    let end = (start + 8 * n) / HUGE_PAGE * HUGE_PAGE;
    // SAFETY: `[first, end)` lies within `words`' allocation of `8 n` bytes; these advices
    // change how those pages are backed, never their contents or whether they may be accessed.
    let advise =
        |flag| unsafe { libc::madvise(first as *mut libc::c_void, end - first, flag) == 0 };
    // A buffer without a whole huge page inside is in ordinary pages whatever the advice.
    let whole = end > first;
    let flag = if huge {
        libc::MADV_HUGEPAGE
    } else {
        libc::MADV_NOHUGEPAGE
    };
    if whole && !advise(flag) {
        return None;
    }
    words.extend((0..n).map(word));
    if whole && huge {
        advise(MADV_COLLAPSE);
    }
    Some(words)
}

/// Page sizes are advised on Linux only.
#[cfg(not(target_os = "linux"))]
fn paged_words(_: usize, _: impl Fn(usize) -> u64, _: bool) -> Option<Vec<u64>> {
    None
}

/// The transparent-huge-page mode Linux reports (the bracketed word of
/// `/sys/kernel/mm/transparent_hugepage/enabled`, e.g. `madvise`); `None` elsewhere.
fn transparent_huge_pages() -> Option<String> {
    let text = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").ok()?;
    let start = text.find('[')? + 1;
    let end = start + text[start..].find(']')?;
    Some(text[start..end].to_string())
}

/// Repetitions of the floor: about half a second of streaming at 10 GB/s, 20 to 2,000.
fn floor_reps(bytes: usize) -> usize {
    (5e9 / bytes.max(1) as f64).clamp(20.0, 2000.0) as usize
}

/// `frames` seeded raw wrinkle inputs `[frames, I]`: `mean + std · u`, `u ∈ [−1, 1]`.
fn inputs(model: &GarmentModel, frames: usize, seed: u64) -> Vec<f32> {
    let stats = &model.weights().norm.wrinkle_in;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut x = Vec::with_capacity(frames * stats.mean.len());
    for _ in 0..frames {
        for (m, s) in stats.mean.iter().zip(&stats.std) {
            x.push(m + s * rng.random_range(-1.0f32..1.0));
        }
    }
    x
}

/// The network's displacements `[T, 3V]` for `inputs` from a zero state.
fn outputs(network: &GarmentNetwork, inputs: &[f32]) -> Result<Vec<f32>> {
    let (n_in, n_out) = (network.input_size(), network.output_size());
    let mut ws = network.workspace(1);
    let mut state = network.initial_state();
    let mut out = vec![0.0f32; inputs.len() / n_in * n_out];
    for (x, o) in inputs.chunks_exact(n_in).zip(out.chunks_exact_mut(n_out)) {
        network.wrinkle_step(x, &mut state, o, &mut ws, Parallelism::Sequential)?;
    }
    Ok(out)
}

/// Median ms of sartor's wrinkle step over `frames` frames after `warmup`, cycling through
/// `inputs`, the state carried; on `threads` threads (more than one: a rayon pool of exactly
/// that many).
fn time_step(
    network: &GarmentNetwork,
    inputs: &[f32],
    threads: usize,
    warmup: usize,
    frames: usize,
) -> Result<f64> {
    let n_in = network.input_size();
    let xs: Vec<&[f32]> = inputs.chunks_exact(n_in).collect();
    ensure!(!xs.is_empty(), "no input frames to time");
    let run = |par: Parallelism| -> Result<f64> {
        let mut ws = network.workspace(1);
        let mut state = network.initial_state();
        let mut out = vec![0.0f32; network.output_size()];
        let mut ms = Vec::with_capacity(frames);
        for t in 0..warmup + frames {
            let x = xs[t % xs.len()];
            let start = Instant::now();
            network.wrinkle_step(x, &mut state, &mut out, &mut ws, par)?;
            std::hint::black_box(&out);
            if t >= warmup {
                ms.push(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        Ok(median(&ms))
    };
    if threads == 1 {
        run(Parallelism::Sequential)
    } else {
        thread_pool(threads)?.install(|| run(Parallelism::Rayon))
    }
}

fn precision_error(precision: Precision, got: &[f32], want: &[f32]) -> PrecisionError {
    let (mut max, mut diff2, mut want2) = (0.0f64, 0.0f64, 0.0f64);
    for (&g, &w) in got.iter().zip(want) {
        let d = f64::from(g) - f64::from(w);
        max = max.max(d.abs());
        diff2 += d * d;
        want2 += f64::from(w) * f64::from(w);
    }
    PrecisionError {
        precision: precision.name(),
        max_abs_diff_m: max,
        relative_rms: if want2 > 0.0 {
            (diff2 / want2).sqrt()
        } else {
            0.0
        },
    }
}

fn ratio(a: f64, b: Option<f64>) -> Option<f64> {
    b.filter(|b| *b > 0.0 && b.is_finite()).map(|b| a / b)
}

/// Combine sartor's timings, the floors and the script's entries at one thread count: the
/// fastest precision, the ratios to every anchor and to the fastest one, and to the floor.
/// `max_abs_output_m` is the scale of the agreement check.
fn thread_anchors(
    threads: usize,
    sartor: Vec<SartorTime>,
    floor: Vec<Floor>,
    entries: &[ScriptEntry],
    max_abs_output_m: f64,
) -> Result<ThreadAnchors> {
    let f32_ms = sartor
        .iter()
        .find(|s| s.precision == Precision::F32.name())
        .map(|s| s.ms_per_frame)
        .context("no f32 timing of sartor")?;
    let fastest = sartor
        .iter()
        .min_by(|a, b| a.ms_per_frame.total_cmp(&b.ms_per_frame))
        .context("no timing of sartor")?
        .clone();
    let floor_of = |p: &str| floor.iter().find(|f| f.precision == p).map(|f| f.ms);
    let anchors: Vec<AnchorTime> = entries
        .iter()
        .filter(|e| e.threads == threads)
        .map(|e| AnchorTime {
            engine: e.engine.clone(),
            call: e.call.clone(),
            ms_per_frame: e.ms_per_frame,
            ms_per_frame_mean: e.ms_per_frame_mean,
            max_abs_diff_m: e.max_abs_diff,
            agrees_with_sartor: e
                .max_abs_diff
                .map(|d| d <= AGREEMENT_TOLERANCE * max_abs_output_m),
            error: e.error.clone(),
            ratio_f32: ratio(f32_ms, e.ms_per_frame),
            ratio_fastest: ratio(fastest.ms_per_frame, e.ms_per_frame),
        })
        .collect();
    let best = anchors
        .iter()
        .filter(|a| a.agrees_with_sartor == Some(true))
        .filter_map(|a| a.ms_per_frame.map(|ms| (a, ms)))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    Ok(ThreadAnchors {
        threads,
        fastest_precision: fastest.precision,
        sartor_f32_over_floor: ratio(f32_ms, floor_of(Precision::F32.name())),
        sartor_fastest_over_floor: ratio(fastest.ms_per_frame, floor_of(fastest.precision)),
        best_anchor: best.map(|(a, _)| match &a.call {
            Some(c) => format!("{} ({c})", a.engine),
            None => a.engine.clone(),
        }),
        best_anchor_ms_per_frame: best.map(|b| b.1),
        ratio_f32_to_best_anchor: ratio(f32_ms, best.map(|b| b.1)),
        ratio_fastest_to_best_anchor: ratio(fastest.ms_per_frame, best.map(|b| b.1)),
        sartor,
        floor,
        anchors,
    })
}

/// Parse and check the script's JSON for a model of `sizes` over `check_frames` frames.
fn parse_script_output(text: &str, check_frames: usize) -> Result<ScriptOutput> {
    let out: ScriptOutput = serde_json::from_str(text).context("the anchors script's JSON")?;
    ensure!(
        out.format == SCRIPT_FORMAT && out.version == 1,
        "the anchors script wrote format {:?} version {}, expected {SCRIPT_FORMAT:?} 1",
        out.format,
        out.version
    );
    ensure!(
        out.frames_checked == check_frames,
        "the anchors script checked {} frames, {check_frames} were given",
        out.frames_checked
    );
    Ok(out)
}

/// Time one model in sartor, against the floor and in the anchors (see the module docs).
fn model_anchors(
    m: AnchorModel,
    options: &AnchorOptions,
    tmp: &Path,
    progress: &dyn Progress,
) -> Result<(ModelAnchors, ScriptOutput)> {
    let dir = tmp.join(m.name);
    let header = m.model.save(&dir)?;
    let sizes = header.sizes;
    let x = inputs(&m.model, options.check_frames, 17);
    let mut networks = Vec::new();
    for precision in PRECISIONS {
        networks.push(GarmentNetwork::new(m.model.clone(), precision)?);
    }
    let want = outputs(&networks[0], &x)?;
    let io_path = tmp.join(format!("{}-io.safetensors", m.name));
    let (n_in, n_out) = (networks[0].input_size(), networks[0].output_size());
    let tensors = BTreeMap::from([
        (
            "inputs".to_string(),
            OwnedTensor::f32(&[options.check_frames, n_in], x.iter().copied()),
        ),
        (
            "outputs".to_string(),
            OwnedTensor::f32(&[options.check_frames, n_out], want.iter().copied()),
        ),
    ]);
    write_atomic(&io_path, &serialize_tensors(&tensors, None)?)?;
    let mut precision_errors = Vec::new();
    for n in &networks[1..] {
        precision_errors.push(precision_error(n.precision(), &outputs(n, &x)?, &want));
    }

    // sartor's step and the floor at every thread count and precision: (ms, floor) per
    // precision, per thread count.
    let time_all = |when: &str| -> Result<Vec<Vec<(f64, StreamFloor)>>> {
        let mut all = Vec::new();
        for &threads in &options.threads {
            let mut row = Vec::new();
            for n in &networks {
                let ms = time_step(n, &x, threads, options.warmup, options.frames)?;
                let bytes = n.wrinkle_weight_bytes();
                let streams = stream_floor(bytes, threads, floor_reps(bytes))?;
                progress.println(&format!(
                    "  anchors {} sartor {:>4} {threads} thread(s), {when}: {ms:.4} ms/frame; \
                     floor {:.4} ms for {:.1} MB",
                    m.name,
                    n.precision().name(),
                    streams.ms(),
                    bytes as f64 / 1e6
                ));
                row.push((ms, streams));
            }
            all.push(row);
        }
        Ok(all)
    };
    // Timed on both sides of the anchors, which run a minute or more: a machine whose memory
    // or two-thread speed drifts over minutes (the 2-core AMD EPYC VM's two-thread step moved
    // by half between runs minutes apart) then tilts the ratios less.
    let before = time_all("before the anchors")?;

    progress.println(&format!(
        "  anchors {}: running {} (PyTorch eager and compiled, ONNX Runtime; a few minutes)",
        m.name,
        options.script.display()
    ));
    let out_path = tmp.join(format!("{}-anchors.json", m.name));
    let threads_arg = options
        .threads
        .iter()
        .map(usize::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let (warmup, frames) = (options.warmup.to_string(), options.frames.to_string());
    run_script(
        options,
        &[
            "--model".as_ref(),
            dir.as_os_str(),
            "--io".as_ref(),
            io_path.as_os_str(),
            "--threads".as_ref(),
            threads_arg.as_ref(),
            "--warmup".as_ref(),
            warmup.as_ref(),
            "--frames".as_ref(),
            frames.as_ref(),
            "--out".as_ref(),
            out_path.as_os_str(),
        ],
    )?;
    let after = time_all("after the anchors")?;
    let mut per_thread = Vec::new();
    for ((&threads, before), after) in options.threads.iter().zip(before).zip(after) {
        let mut sartor = Vec::new();
        let mut floor = Vec::new();
        for ((n, (ms_before, streams)), (ms_after, streams_after)) in
            networks.iter().zip(before).zip(after)
        {
            let bytes = n.wrinkle_weight_bytes();
            sartor.push(SartorTime {
                precision: n.precision().name(),
                ms_per_frame: 0.5 * (ms_before + ms_after),
                ms_per_frame_before: ms_before,
                ms_per_frame_after: ms_after,
            });
            let floor_ms = 0.5 * (streams.ms() + streams_after.ms());
            floor.push(Floor {
                precision: n.precision().name(),
                bytes,
                ms: floor_ms,
                ms_before: streams.ms(),
                ms_after: streams_after.ms(),
                gb_per_s: bytes as f64 / (floor_ms * 1e6),
                ms_small_pages: streams.small_pages_ms,
                ms_huge_pages: streams.huge_pages_ms,
                ms_small_pages_prefetched: streams.small_pages_prefetched_ms,
                ms_huge_pages_prefetched: streams.huge_pages_prefetched_ms,
            });
        }
        per_thread.push((threads, sartor, floor));
    }
    let text = std::fs::read_to_string(&out_path).map_err(|e| Error::io(&out_path, e))?;
    let script = parse_script_output(&text, options.check_frames)?;
    let max_abs_output_m = want.iter().fold(0.0f64, |a, &v| a.max(f64::from(v).abs()));
    let mut threads = Vec::new();
    for (t, sartor, floor) in per_thread {
        let ta = thread_anchors(t, sartor, floor, &script.engines, max_abs_output_m)?;
        for a in &ta.anchors {
            progress.println(&format!(
                "  anchors {} {} {t} thread(s): {} (sartor f32 / it {}; max abs diff {}{})",
                m.name,
                a.engine,
                a.ms_per_frame
                    .map_or_else(|| "failed".to_string(), |ms| format!("{ms:.4} ms/frame")),
                a.ratio_f32
                    .map_or_else(|| "-".into(), |r| format!("{r:.2}")),
                a.max_abs_diff_m
                    .map_or_else(|| "-".into(), |d| format!("{d:.1e} m")),
                if a.agrees_with_sartor == Some(false) {
                    ", DISAGREES with sartor"
                } else {
                    ""
                }
            ));
        }
        threads.push(ta);
    }
    let report = ModelAnchors {
        name: m.name.to_string(),
        source: m.source,
        garment: header.garment.id.clone(),
        sizes,
        output: match sizes.output {
            OutputKind::Dense => "dense".into(),
            OutputKind::Pca(k) => format!("pca {k}"),
        },
        wrinkle_mb: networks
            .iter()
            .map(|n| (n.precision().name(), n.wrinkle_weight_bytes() as f64 / 1e6))
            .collect(),
        max_abs_output_m,
        precision_error: precision_errors,
        onnx_export: script.onnx_export.clone(),
        threads,
    };
    Ok((report, script))
}

/// Time `models` in sartor, against the floor and in the anchors; `versions` from
/// [`check_anchors`].
pub(crate) fn anchors(
    models: Vec<AnchorModel>,
    options: &AnchorOptions,
    versions: BTreeMap<String, String>,
    progress: &dyn Progress,
) -> Result<AnchorsReport> {
    let tmp = tempfile::Builder::new()
        .prefix("sartor-anchors-")
        .tempdir()
        .context("a temporary folder for the anchors")?;
    let mut reports = Vec::new();
    let mut capability = None;
    for m in models {
        let (report, script) = model_anchors(m, options, tmp.path(), progress)?;
        capability = capability.or(script.torch_cpu_capability);
        reports.push(report);
    }
    Ok(AnchorsReport {
        python: options.python.display().to_string(),
        script: options.script.display().to_string(),
        versions,
        torch_cpu_capability: capability,
        transparent_huge_pages: transparent_huge_pages(),
        warmup_frames: options.warmup,
        timed_frames: options.frames,
        check_frames: options.check_frames,
        models: reports,
        notes: vec![
            "Every engine runs the same per-frame wrinkle step on the same weights: \
             normalisation, GRU cell, output layer (dense, or PCA coefficients then basis), \
             denormalisation; batch 1, one frame per call, the GRU state carried from frame to \
             frame. ms_per_frame is the median over the timed frames; sartor's step is timed \
             just before and again just after the anchors (ms_per_frame_before, \
             ms_per_frame_after) and its ms_per_frame, which the ratios use, is their mean, so \
             that a machine drifting over the minute of the anchors tilts the ratios less. The \
             fit MLP (once per shape), skinning and the post-process are not included on either \
             side.",
            "Ratios are sartor / anchor: below 1, sartor is faster. 'fastest' is sartor's \
             fastest precision at that thread count.",
            "floor: the median time to stream the step's weight bytes once (sum of a buffer of \
             that many bytes, warm, back to back as the frames are), per precision's weight \
             size, the faster of a buffer in 4 KiB pages (ms_small_pages) and one advised to \
             2 MiB pages (ms_huge_pages, Linux), each read plainly and prefetched, measured \
             before and after the anchors with sartor's step (ms_before, ms_after; ms is their \
             mean, as sartor's ms_per_frame is); sartor_*_over_floor = sartor's ms / that floor \
             (1: at the memory bandwidth).",
            "max_abs_diff_m: the engine's displacements against sartor's f32 ones for the same \
             inputs from a zero state, metres; max_abs_output_m is their scale; \
             agrees_with_sartor: within 1e-4 of that scale (an engine that disagrees is never \
             the best anchor).",
            "Inputs are seeded random raw features (mean + std · u, u in [-1, 1]): the time of \
             a dense step does not depend on them.",
        ],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A script output as `bench/anchors.py` writes it (trimmed), one failed compile.
    const CANNED: &str = r#"{
      "format": "sartor-anchors", "version": 1, "model": "/tmp/x/paper",
      "sizes": {}, "versions": {"torch": "2.9.0", "onnxruntime": "1.23.0"},
      "torch_cpu_capability": "AVX2", "frames_checked": 4, "max_abs_output": 0.01,
      "onnx_export": {"exporter": "torchscript", "error": null, "seconds": 1.0},
      "engines": [
        {"engine": "pytorch_eager", "threads": 1, "ms_per_frame": 5.0,
         "ms_per_frame_mean": 5.1, "max_abs_diff": 2e-7, "error": null},
        {"engine": "pytorch_compiled", "threads": 1, "ms_per_frame": null,
         "error": "InductorError: no compiler", "traceback_tail": "..."},
        {"engine": "onnxruntime", "threads": 1, "call": "io_binding", "ms_per_frame": 4.0,
         "max_abs_diff": 1e-7, "error": null, "other_calls": []},
        {"engine": "onnxruntime", "threads": 2, "call": "run", "ms_per_frame": 2.5,
         "max_abs_diff": 1e-7, "error": null}
      ]
    }"#;

    fn sartor(f32_ms: f64, f16_ms: f64, int8_ms: f64) -> Vec<SartorTime> {
        vec![
            SartorTime {
                precision: "f32",
                ms_per_frame: f32_ms,
                ms_per_frame_before: f32_ms,
                ms_per_frame_after: f32_ms,
            },
            SartorTime {
                precision: "f16",
                ms_per_frame: f16_ms,
                ms_per_frame_before: f16_ms,
                ms_per_frame_after: f16_ms,
            },
            SartorTime {
                precision: "int8",
                ms_per_frame: int8_ms,
                ms_per_frame_before: int8_ms,
                ms_per_frame_after: int8_ms,
            },
        ]
    }

    fn floors() -> Vec<Floor> {
        [("f32", 100, 2.0), ("f16", 50, 1.0), ("int8", 25, 0.5)]
            .into_iter()
            .map(|(precision, bytes, ms)| Floor {
                precision,
                bytes,
                ms,
                ms_before: ms,
                ms_after: ms,
                gb_per_s: bytes as f64 / (ms * 1e6),
                ms_small_pages: ms,
                ms_huge_pages: None,
                ms_small_pages_prefetched: None,
                ms_huge_pages_prefetched: None,
            })
            .collect()
    }

    #[test]
    fn ratios_from_a_canned_script_output() -> Result<()> {
        let script = parse_script_output(CANNED, 4)?;
        assert_eq!(script.onnx_export.exporter.as_deref(), Some("torchscript"));
        let t1 = thread_anchors(1, sartor(4.4, 2.0, 1.1), floors(), &script.engines, 0.01)?;
        assert_eq!(t1.anchors.len(), 3, "only the one-thread entries");
        assert_eq!(t1.fastest_precision, "int8");
        let eager = &t1.anchors[0];
        assert!((eager.ratio_f32.unwrap_or(f64::NAN) - 4.4 / 5.0).abs() < 1e-12);
        assert!((eager.ratio_fastest.unwrap_or(f64::NAN) - 1.1 / 5.0).abs() < 1e-12);
        assert_eq!(eager.max_abs_diff_m, Some(2e-7));
        assert_eq!(eager.agrees_with_sartor, Some(true));
        let compiled = &t1.anchors[1];
        assert_eq!(compiled.ms_per_frame, None);
        assert_eq!(compiled.ratio_f32, None, "no ratio to a failed engine");
        assert!(
            compiled
                .error
                .as_deref()
                .is_some_and(|e| e.contains("no compiler"))
        );
        assert_eq!(t1.best_anchor.as_deref(), Some("onnxruntime (io_binding)"));
        assert_eq!(t1.best_anchor_ms_per_frame, Some(4.0));
        assert!((t1.ratio_f32_to_best_anchor.unwrap_or(f64::NAN) - 1.1).abs() < 1e-12);
        assert!((t1.ratio_fastest_to_best_anchor.unwrap_or(f64::NAN) - 0.275).abs() < 1e-12);
        assert!((t1.sartor_f32_over_floor.unwrap_or(f64::NAN) - 2.2).abs() < 1e-12);
        // The fastest precision (int8) against the floor of int8's bytes.
        assert!((t1.sartor_fastest_over_floor.unwrap_or(f64::NAN) - 2.2).abs() < 1e-12);

        let t2 = thread_anchors(2, sartor(2.0, 3.0, 4.0), floors(), &script.engines, 0.01)?;
        assert_eq!(t2.fastest_precision, "f32");
        assert_eq!(t2.anchors.len(), 1);
        assert!((t2.ratio_f32_to_best_anchor.unwrap_or(f64::NAN) - 0.8).abs() < 1e-12);

        // At a scale of 1e-3 m, ONNX Runtime's 1e-7 agrees, eager's 2e-7 does not: eager is
        // no longer a candidate, and the fastest that agrees is still ONNX Runtime.
        let t1 = thread_anchors(1, sartor(4.4, 2.0, 1.1), floors(), &script.engines, 1.5e-3)?;
        assert_eq!(t1.anchors[0].agrees_with_sartor, Some(false));
        assert_eq!(t1.anchors[2].agrees_with_sartor, Some(true));
        assert_eq!(t1.best_anchor_ms_per_frame, Some(4.0));
        // Nothing agrees: no best anchor, no ratio to it.
        let t1 = thread_anchors(1, sartor(4.4, 2.0, 1.1), floors(), &script.engines, 1e-4)?;
        assert_eq!(t1.best_anchor, None);
        assert_eq!(t1.ratio_f32_to_best_anchor, None);
        Ok(())
    }

    #[test]
    fn script_output_of_another_run_is_refused() {
        assert!(
            parse_script_output(CANNED, 5).is_err(),
            "frame count differs"
        );
        let other = CANNED.replace("\"sartor-anchors\"", "\"other\"");
        assert!(parse_script_output(&other, 4).is_err(), "format differs");
        assert!(parse_script_output("not json", 4).is_err());
    }

    #[test]
    fn stream_floor_is_positive_and_finite() -> Result<()> {
        for prefetch in [false, true] {
            assert_eq!(
                stream_sum(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, u64::MAX], prefetch),
                54,
                "every word once, wrapping"
            );
            // Every word exactly once at every length around whole steps of the streams.
            let words: Vec<u64> = (0..300u64).map(|i| i * i + 1).collect();
            for n in 0..words.len() {
                let want = words[..n].iter().fold(0u64, |s, &w| s.wrapping_add(w));
                assert_eq!(stream_sum(&words[..n], prefetch), want, "{n} words");
            }
        }
        for threads in [1, 2] {
            let ms = stream_floor_ms(1 << 20, threads, 5)?;
            assert!(ms.is_finite() && ms > 0.0, "{threads} threads: {ms} ms");
        }
        assert!(stream_floor_ms(0, 1, 5).is_err());
        Ok(())
    }

    #[test]
    fn the_paged_buffers_hold_every_word_and_the_mode_is_one_word() {
        // 5 MiB: at least one whole 2 MiB page inside, whatever the allocation's start.
        let n = 5 << 17;
        for huge in [false, true] {
            if let Some(words) = paged_words(n, |i| i as u64 * 3 + 1, huge) {
                assert_eq!(words.len(), n);
                assert!(
                    words
                        .iter()
                        .enumerate()
                        .all(|(i, &w)| w == i as u64 * 3 + 1)
                );
            }
        }
        if let Some(mode) = transparent_huge_pages() {
            assert!(
                ["always", "madvise", "never"].contains(&mode.as_str()),
                "{mode:?}"
            );
        }
    }

    #[test]
    fn missing_python_fails_with_the_install_hint() {
        let dir = tempfile::tempdir().expect("a temporary folder for the test");
        let script = dir.path().join("anchors.py");
        std::fs::write(&script, "").expect("an empty script for the test");
        let options = AnchorOptions {
            python: dir.path().join("no-such-python"),
            script,
            shipped_model: dir.path().into(),
            threads: vec![1],
            warmup: 1,
            frames: 1,
            check_frames: 1,
        };
        let err = check_anchors(&options)
            .expect_err("no such interpreter")
            .to_string();
        assert!(err.contains("pip install torch onnx onnxruntime"), "{err}");
        let options = AnchorOptions {
            script: dir.path().join("missing.py"),
            ..options
        };
        let err = check_anchors(&options)
            .expect_err("no such script")
            .to_string();
        assert!(
            err.contains("missing.py") && err.contains("not found"),
            "{err}"
        );
    }
}
