//! `bench runtime --anchors`: the same weights in the tools a user would otherwise pick, in the
//! same run as sartor's own timings.
//!
//! For each model (the shipped one and a paper-size one), this module
//!
//! 1. writes the model (`model.json` + `model.safetensors`) and an inputs file to a temporary
//!    folder: `inputs` `[T, I]` (seeded random raw wrinkle inputs, `mean + std · u`,
//!    `u ∈ [−1, 1]`) and `outputs` `[T, 3V]`, sartor's f32 displacements for them from a zero
//!    state;
//! 2. starts `bench/anchors.py` (PyTorch eager and compiled, ONNX Runtime; see the script's
//!    docs), which builds every engine and checks its outputs against sartor's, then answers
//!    timing requests;
//! 3. in each of [`AnchorOptions::rounds`] rounds, per thread count (1 and 2; sartor on a rayon
//!    pool of exactly that many threads): times sartor's own wrinkle step
//!    ([`GarmentNetwork::wrinkle_step`]: normalisation, GRU, output layer, denormalisation) at
//!    batch 1, one frame per call, the state carried, in f32, f16 and int8; measures a
//!    memory-bandwidth floor, the time to stream each precision's weight bytes once (a sum over
//!    a buffer of exactly that many bytes, median of many repetitions); and asks the script
//!    to time every anchor the same way;
//! 4. records ms per frame per engine and thread count (the median over the rounds), and the
//!    ratios sartor / anchor for sartor's f32 and for its fastest precision, and sartor /
//!    floor, each the median over the rounds of the ratio within a round.
//!
//! Rounds, because the 2-core VMs this was built on drift: timings a minute apart disagreed by
//! a third (the paper-size f32 step on two threads read 1.77 ms before a minute of anchors and
//! 1.16 after them, 2026-12-01), and a comparison of engines timed minutes apart measured the
//! machine as much as the engines. Within a round, sartor and the anchors run seconds apart.
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
    /// Timed frames, every engine, per round.
    pub frames: usize,
    /// Rounds of the comparison (see the module docs).
    pub rounds: usize,
    /// Input frames whose outputs every engine checks against sartor's (from a zero state);
    /// the timed frames cycle through them.
    pub check_frames: usize,
}

/// One engine of the script's set-up line.
#[derive(Clone, Debug, Deserialize)]
struct ScriptEntry {
    engine: String,
    threads: usize,
    /// How ONNX Runtime was called (`run` or `io_binding`); absent for torch.
    #[serde(default)]
    call: Option<String>,
    #[serde(default)]
    max_abs_diff: Option<f64>,
    error: Option<String>,
}

/// One timing of one engine in the script's answer to a request.
#[derive(Clone, Debug, Deserialize)]
struct ScriptTime {
    engine: String,
    #[serde(default)]
    call: Option<String>,
    ms_per_frame: f64,
    ms_per_frame_mean: f64,
}

/// The script's answer to one timing request: every working engine at `threads`.
#[derive(Clone, Debug, Deserialize)]
struct ScriptTimes {
    threads: usize,
    times: Vec<ScriptTime>,
}

/// The ONNX export's outcome.
#[derive(Clone, Debug, Deserialize, Serialize)]
struct OnnxExport {
    exporter: Option<String>,
    error: Option<String>,
}

/// The script's set-up line (see `bench/anchors.py`).
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
    /// The median over the rounds of `ms_per_frame_rounds`.
    ms_per_frame: f64,
    /// Each round's median over the timed frames.
    ms_per_frame_rounds: Vec<f64>,
}

/// The memory-bandwidth floor of one precision's weights.
#[derive(Clone, Debug, Serialize)]
struct Floor {
    precision: &'static str,
    /// Weight bytes the step reads per frame (GRU and output layer, int8 scales included).
    bytes: usize,
    /// Median ms to stream that many bytes once: the median over the rounds of `ms_rounds`.
    ms: f64,
    /// Each round's floor: the fastest of the four ways below, measured in that round
    /// beside sartor's step.
    ms_rounds: Vec<f64>,
    /// Implied bandwidth, GB/s (10^9 bytes).
    gb_per_s: f64,
    /// From a buffer in ordinary (4 KiB) pages (the median over the rounds, as the three
    /// below).
    ms_small_pages: f64,
    /// From a buffer advised to huge pages (Linux only; `None` elsewhere).
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
    /// The median over the rounds of `ms_per_frame_rounds`; `None` where the engine failed
    /// (see `error`).
    ms_per_frame: Option<f64>,
    /// Each round's median over the timed frames.
    ms_per_frame_rounds: Vec<f64>,
    /// The median over the rounds of each round's mean.
    ms_per_frame_mean: Option<f64>,
    /// Against sartor's f32 displacements over the checked frames, metres.
    max_abs_diff_m: Option<f64>,
    /// `max_abs_diff_m` within [`AGREEMENT_TOLERANCE`] of the largest output; an engine that
    /// disagrees times another computation and is never the best anchor.
    agrees_with_sartor: Option<bool>,
    error: Option<String>,
    /// sartor f32 / this anchor, the median over the rounds of the ratio within a round
    /// (below 1: sartor is faster).
    ratio_f32: Option<f64>,
    /// sartor's fastest precision / this anchor, the same way.
    ratio_fastest: Option<f64>,
}

/// Everything at one thread count.
#[derive(Clone, Debug, Serialize)]
struct ThreadAnchors {
    threads: usize,
    sartor: Vec<SartorTime>,
    fastest_precision: &'static str,
    floor: Vec<Floor>,
    /// sartor f32 / the f32 floor (1: at the bandwidth), the median over the rounds of the
    /// ratio within a round.
    sartor_f32_over_floor: Option<f64>,
    /// sartor's fastest precision / the floor of that precision's weight bytes, the same way.
    sartor_fastest_over_floor: Option<f64>,
    anchors: Vec<AnchorTime>,
    /// The fastest anchor that ran and agrees with sartor.
    best_anchor: Option<String>,
    best_anchor_ms_per_frame: Option<f64>,
    /// sartor f32 / the best anchor: the median of `ratio_f32_to_best_anchor_rounds`.
    ratio_f32_to_best_anchor: Option<f64>,
    /// sartor's fastest precision / the best anchor, the same way.
    ratio_fastest_to_best_anchor: Option<f64>,
    /// sartor f32 / the best anchor within each round.
    ratio_f32_to_best_anchor_rounds: Vec<f64>,
    /// sartor's fastest precision / the best anchor within each round.
    ratio_fastest_to_best_anchor_rounds: Vec<f64>,
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
    rounds: usize,
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

/// `python script args`, once the script is found to be there.
fn script_command(options: &AnchorOptions, args: &[&std::ffi::OsStr]) -> Result<Command> {
    ensure!(
        options.script.is_file(),
        "anchors script {} not found (run from the repository, or pass --anchors-script)",
        options.script.display()
    );
    let mut command = Command::new(&options.python);
    command.arg(&options.script).args(args);
    Ok(command)
}

/// The error of an interpreter that would not start, with the install hint.
fn start_failed(options: &AnchorOptions, e: &std::io::Error) -> Error {
    Error::Invalid(format!(
        "could not start {}: {e}; {}",
        options.python.display(),
        install_hint(&options.python)
    ))
}

/// Run the script with `args`; its stdout, with a clear error when Python, the script or its
/// packages are missing or it fails.
fn run_script(options: &AnchorOptions, args: &[&std::ffi::OsStr]) -> Result<String> {
    let output = script_command(options, args)?
        .output()
        .map_err(|e| start_failed(options, &e))?;
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

/// The anchors script running as a server (see `bench/anchors.py`): its set-up line read, it
/// answers timing requests until its stdin closes. Its stderr (progress and errors) goes to
/// ours. Killed when dropped before [`Server::finish`].
struct Server {
    child: std::process::Child,
    stdin: Option<std::process::ChildStdin>,
    stdout: std::io::BufReader<std::process::ChildStdout>,
    what: String,
}

impl Server {
    /// Start the script with `args`; returns it and its set-up line.
    fn start(options: &AnchorOptions, args: &[&std::ffi::OsStr]) -> Result<(Self, String)> {
        let mut child = script_command(options, args)?
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .map_err(|e| start_failed(options, &e))?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            bail!(
                "{}: no pipes to the anchors script",
                options.python.display()
            );
        };
        let mut server = Self {
            child,
            stdin: Some(stdin),
            stdout: std::io::BufReader::new(stdout),
            what: format!("{} {}", options.python.display(), options.script.display()),
        };
        let setup = server.line()?;
        Ok((server, setup))
    }

    /// The script's next line; a clear error when it has ended instead.
    fn line(&mut self) -> Result<String> {
        use std::io::BufRead;
        let mut line = String::new();
        let n = self
            .stdout
            .read_line(&mut line)
            .with_context(|| format!("{}: reading its answer", self.what))?;
        if n == 0 {
            let status = self
                .child
                .wait()
                .map_or_else(|e| e.to_string(), |s| s.to_string());
            bail!(
                "{} ended without answering ({status}); see its output above",
                self.what
            );
        }
        Ok(line)
    }

    /// Time every working engine at `threads` threads over `frames` frames.
    fn time(&mut self, threads: usize, frames: usize) -> Result<ScriptTimes> {
        use std::io::Write;
        let stdin = self
            .stdin
            .as_mut()
            .context("the anchors script has finished")?;
        writeln!(stdin, "{{\"threads\": {threads}, \"frames\": {frames}}}")
            .and_then(|()| stdin.flush())
            .with_context(|| format!("{}: sending a timing request", self.what))?;
        let line = self.line()?;
        let answer: ScriptTimes = serde_json::from_str(&line)
            .with_context(|| format!("{}: its answer {:?}", self.what, line.trim()))?;
        ensure!(
            answer.threads == threads,
            "{} answered for {} thread(s), {threads} were asked for",
            self.what,
            answer.threads
        );
        Ok(answer)
    }

    /// Close its stdin and wait for it to end; an error unless it ends well.
    fn finish(mut self) -> Result<()> {
        drop(self.stdin.take());
        let status = self
            .child
            .wait()
            .with_context(|| format!("{}: waiting for it to end", self.what))?;
        ensure!(
            status.success(),
            "{} failed at the end ({status})",
            self.what
        );
        Ok(())
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if self.stdin.is_some() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
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

/// The ratios `a[r] / b[r]` of the rounds (none where `b` is not positive).
fn round_ratios(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter()
        .zip(b)
        .filter_map(|(&a, &b)| ratio(a, Some(b)))
        .collect()
}

/// The median of the rounds' ratios `a[r] / b[r]`; `None` without a round.
fn paired(a: &[f64], b: &[f64]) -> Option<f64> {
    let r = round_ratios(a, b);
    (!r.is_empty()).then(|| median(&r))
}

/// Combine sartor's timings, the floors, the script's engines and its answers at one thread
/// count (`answers`: one per round, in the order of sartor's rounds): the fastest precision,
/// the ratios to every anchor and to the fastest one, and to the floor, each the median over
/// the rounds of the ratio within a round. `max_abs_output_m` is the scale of the agreement
/// check.
fn thread_anchors(
    threads: usize,
    sartor: Vec<SartorTime>,
    floor: Vec<Floor>,
    entries: &[ScriptEntry],
    answers: &[ScriptTimes],
    max_abs_output_m: f64,
) -> Result<ThreadAnchors> {
    let rounds = answers.len();
    ensure!(
        sartor.iter().all(|s| s.ms_per_frame_rounds.len() == rounds)
            && floor.iter().all(|f| f.ms_rounds.len() == rounds)
            && answers.iter().all(|a| a.threads == threads),
        "the rounds of sartor, the floor and the anchors at {threads} thread(s) differ"
    );
    let f32_rounds = &sartor
        .iter()
        .find(|s| s.precision == Precision::F32.name())
        .context("no f32 timing of sartor")?
        .ms_per_frame_rounds;
    let fastest = sartor
        .iter()
        .min_by(|a, b| a.ms_per_frame.total_cmp(&b.ms_per_frame))
        .context("no timing of sartor")?
        .clone();
    let floor_of = |p: &str| {
        floor
            .iter()
            .find(|f| f.precision == p)
            .map(|f| f.ms_rounds.as_slice())
    };
    let anchors: Vec<AnchorTime> = entries
        .iter()
        .filter(|e| e.threads == threads)
        .map(|e| {
            let timed: Vec<&ScriptTime> = if e.error.is_some() {
                Vec::new()
            } else {
                answers
                    .iter()
                    .filter_map(|a| {
                        a.times
                            .iter()
                            .find(|t| t.engine == e.engine && t.call == e.call)
                    })
                    .collect()
            };
            let ms: Vec<f64> = timed.iter().map(|t| t.ms_per_frame).collect();
            let means: Vec<f64> = timed.iter().map(|t| t.ms_per_frame_mean).collect();
            let complete = rounds > 0 && ms.len() == rounds;
            AnchorTime {
                engine: e.engine.clone(),
                call: e.call.clone(),
                ms_per_frame: complete.then(|| median(&ms)),
                ms_per_frame_mean: complete.then(|| median(&means)),
                max_abs_diff_m: e.max_abs_diff,
                agrees_with_sartor: e
                    .max_abs_diff
                    .map(|d| d <= AGREEMENT_TOLERANCE * max_abs_output_m),
                error: match (&e.error, complete) {
                    (Some(err), _) => Some(err.clone()),
                    (None, false) => Some(format!("timed in {} of {rounds} rounds", ms.len())),
                    (None, true) => None,
                },
                ratio_f32: paired(f32_rounds, &ms).filter(|_| complete),
                ratio_fastest: paired(&fastest.ms_per_frame_rounds, &ms).filter(|_| complete),
                ms_per_frame_rounds: ms,
            }
        })
        .collect();
    let best = anchors
        .iter()
        .filter(|a| a.agrees_with_sartor == Some(true))
        .filter_map(|a| a.ms_per_frame.map(|ms| (a, ms)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|b| b.0);
    let best_rounds = best.map_or(&[][..], |b| b.ms_per_frame_rounds.as_slice());
    Ok(ThreadAnchors {
        threads,
        fastest_precision: fastest.precision,
        sartor_f32_over_floor: floor_of(Precision::F32.name()).and_then(|f| paired(f32_rounds, f)),
        sartor_fastest_over_floor: floor_of(fastest.precision)
            .and_then(|f| paired(&fastest.ms_per_frame_rounds, f)),
        best_anchor: best.map(|a| match &a.call {
            Some(c) => format!("{} ({c})", a.engine),
            None => a.engine.clone(),
        }),
        best_anchor_ms_per_frame: best.and_then(|b| b.ms_per_frame),
        ratio_f32_to_best_anchor: paired(f32_rounds, best_rounds),
        ratio_fastest_to_best_anchor: paired(&fastest.ms_per_frame_rounds, best_rounds),
        ratio_f32_to_best_anchor_rounds: round_ratios(f32_rounds, best_rounds),
        ratio_fastest_to_best_anchor_rounds: round_ratios(
            &fastest.ms_per_frame_rounds,
            best_rounds,
        ),
        sartor,
        floor,
        anchors,
    })
}

/// The version of the script's protocol (a set-up line, then answers to timing requests).
const SCRIPT_VERSION: u32 = 2;

/// Parse and check the script's set-up line for a model over `check_frames` frames.
fn parse_script_output(text: &str, check_frames: usize) -> Result<ScriptOutput> {
    let out: ScriptOutput = serde_json::from_str(text).context("the anchors script's JSON")?;
    ensure!(
        out.format == SCRIPT_FORMAT && out.version == SCRIPT_VERSION,
        "the anchors script wrote format {:?} version {}, expected {SCRIPT_FORMAT:?} \
         {SCRIPT_VERSION}",
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

    let threads_arg = options
        .threads
        .iter()
        .map(usize::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let warmup = options.warmup.to_string();
    progress.println(&format!(
        "  anchors {}: starting {} (PyTorch eager and compiled, ONNX Runtime: export, compile \
         and agreement first, a minute or two)",
        m.name,
        options.script.display()
    ));
    let (mut server, setup) = Server::start(
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
        ],
    )?;
    let script = parse_script_output(&setup, options.check_frames)?;

    // Per thread count: sartor's step per precision, the floor per precision and the
    // anchors' answer, round by round.
    let n_threads = options.threads.len();
    let mut sartor_ms = vec![vec![Vec::new(); networks.len()]; n_threads];
    let mut floors: Vec<Vec<Vec<StreamFloor>>> = vec![vec![Vec::new(); networks.len()]; n_threads];
    let mut answers = vec![Vec::new(); n_threads];
    for round in 0..options.rounds {
        for (i, &threads) in options.threads.iter().enumerate() {
            for (k, n) in networks.iter().enumerate() {
                let ms = time_step(n, &x, threads, options.warmup, options.frames)?;
                let bytes = n.wrinkle_weight_bytes();
                let streams = stream_floor(bytes, threads, floor_reps(bytes))?;
                progress.println(&format!(
                    "  anchors {} round {}: sartor {:>4} {threads} thread(s) {ms:.4} ms/frame; \
                     floor {:.4} ms for {:.1} MB",
                    m.name,
                    round + 1,
                    n.precision().name(),
                    streams.ms(),
                    bytes as f64 / 1e6
                ));
                sartor_ms[i][k].push(ms);
                floors[i][k].push(streams);
            }
            let answer = server.time(threads, options.frames)?;
            for t in &answer.times {
                progress.println(&format!(
                    "  anchors {} round {}: {}{} {threads} thread(s) {:.4} ms/frame",
                    m.name,
                    round + 1,
                    t.engine,
                    t.call
                        .as_ref()
                        .map_or_else(String::new, |c| format!(" ({c})")),
                    t.ms_per_frame
                ));
            }
            answers[i].push(answer);
        }
    }
    server.finish()?;

    let max_abs_output_m = want.iter().fold(0.0f64, |a, &v| a.max(f64::from(v).abs()));
    let mut threads = Vec::new();
    for (i, &t) in options.threads.iter().enumerate() {
        let mut sartor = Vec::new();
        let mut floor = Vec::new();
        for (k, n) in networks.iter().enumerate() {
            let ms = &sartor_ms[i][k];
            sartor.push(SartorTime {
                precision: n.precision().name(),
                ms_per_frame: median(ms),
                ms_per_frame_rounds: ms.clone(),
            });
            let rounds = &floors[i][k];
            let of = |way: fn(&StreamFloor) -> Option<f64>| -> Option<f64> {
                let v: Vec<f64> = rounds.iter().filter_map(way).collect();
                (v.len() == rounds.len() && !v.is_empty()).then(|| median(&v))
            };
            let ms_rounds: Vec<f64> = rounds.iter().map(StreamFloor::ms).collect();
            let floor_ms = median(&ms_rounds);
            let bytes = n.wrinkle_weight_bytes();
            floor.push(Floor {
                precision: n.precision().name(),
                bytes,
                ms: floor_ms,
                ms_rounds,
                gb_per_s: bytes as f64 / (floor_ms * 1e6),
                ms_small_pages: of(|f| Some(f.small_pages_ms)).unwrap_or(f64::NAN),
                ms_huge_pages: of(|f| f.huge_pages_ms),
                ms_small_pages_prefetched: of(|f| f.small_pages_prefetched_ms),
                ms_huge_pages_prefetched: of(|f| f.huge_pages_prefetched_ms),
            });
        }
        let ta = thread_anchors(
            t,
            sartor,
            floor,
            &script.engines,
            &answers[i],
            max_abs_output_m,
        )?;
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
    ensure!(options.rounds > 0, "the anchors need at least one round");
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
        rounds: options.rounds,
        models: reports,
        notes: vec![
            "Every engine runs the same per-frame wrinkle step on the same weights: \
             normalisation, GRU cell, output layer (dense, or PCA coefficients then basis), \
             denormalisation; batch 1, one frame per call, the GRU state carried from frame to \
             frame. The comparison runs in rounds: in each, per thread count, sartor's step in \
             every precision, the floors, then every anchor, seconds apart. A round's time is \
             the median over its timed frames (ms_per_frame_rounds); ms_per_frame is the median \
             over the rounds. The fit MLP (once per shape), skinning and the post-process are \
             not included on either side.",
            "Ratios are sartor / anchor: below 1, sartor is faster. Each is the median over the \
             rounds of the ratio within a round (the rounds' ratios to the best anchor are kept \
             in ratio_*_to_best_anchor_rounds), so that a machine whose speed drifts between \
             rounds tilts them less. 'fastest' is sartor's fastest precision at that thread \
             count (by its median).",
            "floor: the median time to stream the step's weight bytes once (sum of a buffer of \
             that many bytes, warm, back to back as the frames are), per precision's weight \
             size, the faster of a buffer in 4 KiB pages (ms_small_pages) and one advised to \
             2 MiB pages (ms_huge_pages, Linux), each read plainly and prefetched, measured in \
             every round beside sartor's step (ms_rounds; ms is their median); \
             sartor_*_over_floor = the median over the rounds of sartor's ms / that round's \
             floor (1: at the memory bandwidth).",
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

    /// A set-up line as `bench/anchors.py` writes it (trimmed), one failed compile.
    const CANNED: &str = r#"{
      "format": "sartor-anchors", "version": 2, "model": "/tmp/x/paper",
      "sizes": {}, "versions": {"torch": "2.9.0", "onnxruntime": "1.23.0"},
      "torch_cpu_capability": "AVX2", "frames_checked": 4, "max_abs_output": 0.01,
      "onnx_export": {"exporter": "torchscript", "error": null, "seconds": 1.0},
      "engines": [
        {"engine": "pytorch_eager", "threads": 1, "max_abs_diff": 2e-7, "error": null,
         "setup_s": 0.1},
        {"engine": "pytorch_compiled", "threads": 1,
         "error": "InductorError: no compiler", "traceback_tail": "..."},
        {"engine": "onnxruntime", "threads": 1, "call": "io_binding", "max_abs_diff": 1e-7,
         "error": null},
        {"engine": "onnxruntime", "threads": 2, "call": "run", "max_abs_diff": 1e-7,
         "error": null}
      ]
    }"#;

    /// The script's answers at `threads`, one per round: (engine, call, ms) each.
    fn answers(threads: usize, rounds: &[&[(&str, Option<&str>, f64)]]) -> Vec<ScriptTimes> {
        rounds
            .iter()
            .map(|times| {
                let times = times
                    .iter()
                    .map(|&(engine, call, ms)| {
                        let call = call.map_or_else(|| "null".to_string(), |c| format!("\"{c}\""));
                        let mean = ms + 0.1;
                        format!(
                            r#"{{"engine": "{engine}", "call": {call}, "ms_per_frame": {ms},
                                "ms_per_frame_mean": {mean}}}"#
                        )
                    })
                    .collect::<Vec<_>>()
                    .join(", ");
                let line = format!(r#"{{"threads": {threads}, "times": [{times}]}}"#);
                serde_json::from_str(&line).expect("a canned answer")
            })
            .collect()
    }

    fn sartor(f32_ms: &[f64], f16_ms: &[f64], int8_ms: &[f64]) -> Vec<SartorTime> {
        [("f32", f32_ms), ("f16", f16_ms), ("int8", int8_ms)]
            .into_iter()
            .map(|(precision, ms)| SartorTime {
                precision,
                ms_per_frame: median(ms),
                ms_per_frame_rounds: ms.to_vec(),
            })
            .collect()
    }

    fn floors(rounds: usize) -> Vec<Floor> {
        [("f32", 100, 2.0), ("f16", 50, 1.0), ("int8", 25, 0.5)]
            .into_iter()
            .map(|(precision, bytes, ms)| Floor {
                precision,
                bytes,
                ms,
                ms_rounds: vec![ms; rounds],
                gb_per_s: bytes as f64 / (ms * 1e6),
                ms_small_pages: ms,
                ms_huge_pages: None,
                ms_small_pages_prefetched: None,
                ms_huge_pages_prefetched: None,
            })
            .collect()
    }

    fn close(a: Option<f64>, b: f64) -> bool {
        a.is_some_and(|a| (a - b).abs() < 1e-12)
    }

    #[test]
    fn ratios_are_medians_of_the_rounds_ratios() -> Result<()> {
        let script = parse_script_output(CANNED, 4)?;
        assert_eq!(script.onnx_export.exporter.as_deref(), Some("torchscript"));
        let io = Some("io_binding");
        let one = answers(
            1,
            &[
                &[("pytorch_eager", None, 5.0), ("onnxruntime", io, 4.0)],
                &[("pytorch_eager", None, 4.0), ("onnxruntime", io, 5.0)],
                &[("pytorch_eager", None, 6.0), ("onnxruntime", io, 4.5)],
            ],
        );
        let s1 = || sartor(&[4.0, 6.0, 5.0], &[2.0, 2.0, 2.0], &[1.1, 1.0, 1.2]);
        let t1 = thread_anchors(1, s1(), floors(3), &script.engines, &one, 0.01)?;
        assert_eq!(t1.anchors.len(), 3, "only the one-thread entries");
        assert_eq!(t1.fastest_precision, "int8");
        let eager = &t1.anchors[0];
        assert_eq!(eager.ms_per_frame, Some(5.0));
        assert_eq!(eager.ms_per_frame_rounds, [5.0, 4.0, 6.0]);
        assert!(close(eager.ms_per_frame_mean, 5.1));
        // The median of 4/5, 6/4 and 5/6, not the ratio of the medians (5/5).
        assert!(close(eager.ratio_f32, 5.0 / 6.0));
        assert!(close(eager.ratio_fastest, 1.1 / 5.0));
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
        assert_eq!(t1.best_anchor_ms_per_frame, Some(4.5));
        // f32 / ONNX Runtime per round: 1.0, 1.2, 1.111…
        assert_eq!(t1.ratio_f32_to_best_anchor_rounds.len(), 3);
        assert!(close(t1.ratio_f32_to_best_anchor, 5.0 / 4.5));
        // int8 / ONNX Runtime: 0.275, 0.2, 0.266…
        assert!(close(t1.ratio_fastest_to_best_anchor, 1.2 / 4.5));
        // f32 against a floor of 2 ms: 2, 3, 2.5; int8 against 0.5 ms: 2.2, 2, 2.4.
        assert!(close(t1.sartor_f32_over_floor, 2.5));
        assert!(close(t1.sartor_fastest_over_floor, 2.2));

        let two = answers(2, &[&[("onnxruntime", Some("run"), 2.5)]]);
        let t2 = thread_anchors(
            2,
            sartor(&[2.0], &[3.0], &[4.0]),
            floors(1),
            &script.engines,
            &two,
            0.01,
        )?;
        assert_eq!(t2.fastest_precision, "f32");
        assert_eq!(t2.anchors.len(), 1);
        assert!(close(t2.ratio_f32_to_best_anchor, 0.8));

        // An engine missing from a round's answer is not timed (and not the best anchor).
        let gap = answers(
            1,
            &[
                &[("pytorch_eager", None, 5.0), ("onnxruntime", io, 4.0)],
                &[("pytorch_eager", None, 4.0)],
                &[("pytorch_eager", None, 6.0), ("onnxruntime", io, 4.5)],
            ],
        );
        let t = thread_anchors(1, s1(), floors(3), &script.engines, &gap, 0.01)?;
        assert_eq!(t.anchors[2].ms_per_frame, None);
        assert!(
            t.anchors[2]
                .error
                .as_deref()
                .is_some_and(|e| e.contains("2 of 3"))
        );
        assert_eq!(t.best_anchor.as_deref(), Some("pytorch_eager"));
        // Rounds that do not match are refused.
        assert!(thread_anchors(1, s1(), floors(2), &script.engines, &one, 0.01).is_err());
        assert!(thread_anchors(2, s1(), floors(3), &script.engines, &one, 0.01).is_err());

        // At a scale of 1.5e-3 m, ONNX Runtime's 1e-7 agrees, eager's 2e-7 does not: eager is
        // no longer a candidate, and the fastest that agrees is still ONNX Runtime.
        let t1 = thread_anchors(1, s1(), floors(3), &script.engines, &one, 1.5e-3)?;
        assert_eq!(t1.anchors[0].agrees_with_sartor, Some(false));
        assert_eq!(t1.anchors[2].agrees_with_sartor, Some(true));
        assert_eq!(t1.best_anchor_ms_per_frame, Some(4.5));
        // Nothing agrees: no best anchor, no ratio to it.
        let t1 = thread_anchors(1, s1(), floors(3), &script.engines, &one, 1e-4)?;
        assert_eq!(t1.best_anchor, None);
        assert_eq!(t1.ratio_f32_to_best_anchor, None);
        assert!(t1.ratio_f32_to_best_anchor_rounds.is_empty());
        Ok(())
    }

    #[test]
    fn the_server_answers_requests_and_its_end_is_an_error() -> Result<()> {
        // A stand-in for `bench/anchors.py --serve` in sh: the set-up line, then one answer
        // per request for one thread, and for two threads an answer for the wrong count; it
        // exits with status 7 on any other request.
        let dir = tempfile::tempdir().context("a temporary folder for the test")?;
        let script = dir.path().join("fake-anchors.sh");
        let setup = CANNED
            .replace('\n', " ")
            .replace("\"frames_checked\": 4", "\"frames_checked\": 1");
        let one = r#"{"threads": 1, "times": [{"engine": "onnxruntime", "call": "run",
            "ms_per_frame": 1.5, "ms_per_frame_mean": 1.6}]}"#
            .replace('\n', " ");
        let text = format!(
            "echo '{setup}'\n\
             while read line; do\n\
               case \"$line\" in\n\
                 *'\"threads\": 1,'*) echo '{one}' ;;\n\
                 *'\"threads\": 2,'*) echo '{{\"threads\": 3, \"times\": []}}' ;;\n\
                 *) exit 7 ;;\n\
               esac\n\
             done\n"
        );
        std::fs::write(&script, text).context("the fake script")?;
        let options = AnchorOptions {
            python: "sh".into(),
            script,
            shipped_model: dir.path().into(),
            threads: vec![1, 2],
            warmup: 1,
            frames: 1,
            rounds: 1,
            check_frames: 1,
        };
        let (mut server, line) = Server::start(&options, &[])?;
        assert_eq!(parse_script_output(&line, 1)?.engines.len(), 4);
        for _ in 0..2 {
            let answer = server.time(1, 10)?;
            assert_eq!((answer.threads, answer.times.len()), (1, 1));
            assert_eq!(answer.times[0].ms_per_frame, 1.5);
        }
        let err = server
            .time(2, 10)
            .expect_err("the wrong thread count")
            .to_string();
        assert!(err.contains("3 thread(s), 2 were asked for"), "{err}");
        server.finish()?;

        let (mut server, _) = Server::start(&options, &[])?;
        let err = server
            .time(5, 10)
            .expect_err("the script exits")
            .to_string();
        assert!(
            err.contains("ended without answering") && err.contains('7'),
            "{err}"
        );
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
            rounds: 1,
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
