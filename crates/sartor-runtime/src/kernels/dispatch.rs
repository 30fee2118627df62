//! Run-time instruction-set dispatch for the row kernels — the crate's only `unsafe` code.
//!
//! [`super::rows::rows`] (and `int8.rs`'s integer kernels) is generic over an engine. This
//! module instantiates it with the portable engines and, on x86-64, inside
//! `#[target_feature(enable = "avx2,fma,f16c")]` and
//! `#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]` functions with engines written with
//! AVX2 / AVX-512 and F16C intrinsics (LLVM's auto-vectoriser proved unreliable for the 32-lane
//! accumulators: inside the crate it chose 2-wide vectors and ran 5–10× slower). The kernels
//! are written once (`isa_kernels!`) over each module's vector type. One instruction set is
//! picked at run time with `is_x86_feature_detected!`: the widest.
//!
//! Within the AVX-512 level the int8 quad panels (`int8.rs`) use VNNI (`vpdpbusd`) where the
//! CPU has it (`has_vnni`), and so do the integer rows (`vpdpwssd`); within the AVX2 level the
//! quad panels use AVX-VNNI, its 256-bit form (`has_avx_vnni`; `SARTOR_RUNTIME_VNNI=0` turns
//! them all off for benchmarking), with their weights on cache lines ([`LineAligned`]): exact
//! integer sums, so the same bits.
//!
//! Unsafe operations, each with its `SAFETY` comment: the unaligned loads and stores of the
//! intrinsics (from references of exactly the size they touch), the byte view of
//! [`LineAligned`]'s lines, and calls of
//! `#[target_feature]` functions, which are sound exactly when the CPU has those features. An
//! [`Isa`] other than the portable one can only be made after detection succeeded, and the
//! SIMD engines are private to this module and only instantiated inside the wrappers with
//! their features. The intrinsic engines follow the lane rule of `rows.rs` (32 lanes: 4
//! registers × 8 on AVX2, 2 × 16 on AVX-512; separate multiply and add, the same padded tail
//! and reduction tree), so every [`Isa`] gives bitwise the same results; the tests below check
//! that against the portable engines. The single-vector path reduces its lane sums in
//! registers (`reduce_acc`: one vector add per level of the tree) rather than storing them
//! and adding 31 scalars: for the rows of 64 weights of the shipped model's PCA basis the
//! stored reduction cost several times the dot product itself.
//!
//! A row whose length is not a multiple of 32 ends in a partial chunk, read with masked loads
//! that stop at the row's end (zero beyond, as the padded chunk; AVX2 has no masked load of
//! bytes or halves, so its i8 and f16 tails still go through a copy). Copying each row's tail
//! into a zero-padded array on the stack, as before, cost more than the rest of a short row:
//! the shipped model's GRU input product (768 rows of 88 columns) took 10.7 µs against 2.8
//! for 96 columns, and its GRU step 17.7–20.4 → 10.7–11.9 µs with the masked loads; the
//! paper-size GRU and dense output layer (rows of 1,500) 3.16–3.36 → 3.11–3.15 ms in f32,
//! 1.82–1.87 → 1.57–1.70 in f16, 0.72–0.76 → 0.68–0.69 in int8 (`cargo bench --bench kernels`,
//! AMD EPYC VM, alternating builds, two rounds). Every result keeps its bits.
#![allow(unsafe_code)]

use std::sync::OnceLock;

use super::int8::{self, PortableInt, rows_int};
#[cfg(target_arch = "x86_64")]
use super::interleaved::IL_AHEAD;
use super::interleaved::interleaved;
use super::panels::panels;
use super::rows::{F16Bits, F16Codec, F32Codec, I8Codec, Portable, rows};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Level {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

/// An instruction set the kernels may use; only constructible after run-time detection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Isa(Level);

#[cfg(target_arch = "x86_64")]
fn has_avx2() -> bool {
    // The bit-manipulation extensions for the lane masks of `widest_where_present!`
    // functions (every AVX2 CPU has them).
    is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("fma")
        && is_x86_feature_detected!("f16c")
        && is_x86_feature_detected!("bmi1")
        && is_x86_feature_detected!("bmi2")
        && is_x86_feature_detected!("lzcnt")
        && is_x86_feature_detected!("popcnt")
}

#[cfg(target_arch = "x86_64")]
fn has_avx512() -> bool {
    // avx512bw for the integer kernels' 16-bit lanes (every AVX-512 CPU but Xeon Phi has it).
    has_avx2()
        && is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx512bw")
        && is_x86_feature_detected!("avx512vl")
        && is_x86_feature_detected!("avx512dq")
}

/// Whether the AVX-512 quad panels and integer rows use VNNI (`vpdpbusd`, `vpdpwssd`): where
/// this CPU has it, unless `SARTOR_RUNTIME_VNNI=0` (for benchmarking; the results are the same
/// bits either way).
#[cfg(target_arch = "x86_64")]
fn has_vnni() -> bool {
    static VNNI: OnceLock<bool> = OnceLock::new();
    *VNNI.get_or_init(|| has_avx512() && is_x86_feature_detected!("avx512vnni") && vnni_allowed())
}

/// Whether `SARTOR_RUNTIME_VNNI` leaves the VNNI engines on (anything but `0`).
#[cfg(target_arch = "x86_64")]
fn vnni_allowed() -> bool {
    std::env::var("SARTOR_RUNTIME_VNNI").as_deref() != Ok("0")
}

/// Whether the AVX2 quad panels use AVX-VNNI (the 256-bit `vpdpbusd` of CPUs without AVX-512,
/// such as Intel's cores from Alder Lake on): where this CPU has it, unless
/// `SARTOR_RUNTIME_VNNI=0`, as [`has_vnni`].
#[cfg(target_arch = "x86_64")]
fn has_avx_vnni() -> bool {
    static VNNI: OnceLock<bool> = OnceLock::new();
    *VNNI.get_or_init(|| has_avx2() && is_x86_feature_detected!("avxvnni") && vnni_allowed())
}

/// One cache line of int8 weights.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct Line([i8; 64]);

/// int8 weights that start on a cache line (64 bytes): the quad panels' 64-byte quads are then
/// each one aligned load (the VNNI engine read unaligned quads 20–30 % slower from L1).
#[derive(Clone)]
pub(crate) struct LineAligned {
    lines: Vec<Line>,
    len: usize,
}

impl From<&[i8]> for LineAligned {
    fn from(v: &[i8]) -> Self {
        let mut lines = vec![Line([0; 64]); v.len().div_ceil(64)];
        for (line, chunk) in lines.iter_mut().zip(v.chunks(64)) {
            line.0[..chunk.len()].copy_from_slice(chunk);
        }
        Self {
            lines,
            len: v.len(),
        }
    }
}

impl From<Vec<i8>> for LineAligned {
    fn from(v: Vec<i8>) -> Self {
        Self::from(v.as_slice())
    }
}

impl std::ops::Deref for LineAligned {
    type Target = [i8];

    fn deref(&self) -> &[i8] {
        // SAFETY: `lines` holds at least `len` bytes (`from`), `Line` is 64 `i8` without
        // padding (`repr(C)`), and the slice borrows `self`.
        unsafe { std::slice::from_raw_parts(self.lines.as_ptr().cast::<i8>(), self.len) }
    }
}

impl PartialEq for LineAligned {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl std::fmt::Debug for LineAligned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LineAligned({} bytes)", self.len)
    }
}

impl Isa {
    /// Plain Rust for the compilation target (SSE2 on x86-64).
    pub(crate) fn portable() -> Self {
        Self(Level::Portable)
    }

    /// Every instruction set this CPU supports, portable first.
    pub(crate) fn available() -> Vec<Self> {
        #[allow(unused_mut)]
        let mut all = vec![Self::portable()];
        #[cfg(target_arch = "x86_64")]
        {
            if has_avx2() {
                all.push(Self(Level::Avx2));
            }
            if has_avx512() {
                all.push(Self(Level::Avx512));
            }
        }
        all
    }

    /// The instruction set the kernels use, detected once: the widest available. The
    /// environment variable `SARTOR_RUNTIME_ISA` (`portable`, `avx2`, `avx512`) picks another
    /// one for benchmarking; a choice this CPU does not support, or an unknown name, is
    /// ignored.
    pub(crate) fn best() -> Self {
        static BEST: OnceLock<Isa> = OnceLock::new();
        *BEST.get_or_init(|| {
            let available = Self::available();
            if let Ok(choice) = std::env::var("SARTOR_RUNTIME_ISA")
                && let Some(&isa) = available.iter().find(|i| i.name() == choice)
            {
                return isa;
            }
            available.last().copied().unwrap_or_else(Self::portable)
        })
    }

    /// A short name for reports.
    pub(crate) fn name(self) -> &'static str {
        match self.0 {
            Level::Portable => "portable",
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 => "avx2",
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => "avx512",
        }
    }
}

/// Which build [`widest_where_present!`] functions take: 2 for AVX-512, 1 for AVX2, 0 as
/// written, by [`Isa::best`] (`SARTOR_RUNTIME_ISA=portable` runs them as written).
#[cfg(target_arch = "x86_64")]
pub(crate) fn widest_level() -> u8 {
    match Isa::best().0 {
        Level::Portable => 0,
        Level::Avx2 => 1,
        Level::Avx512 => 2,
    }
}

/// Which lanes of 16 lie at most a threshold, as bits: the certified search's lane masks
/// ([`LaneMask::at_most`]). Plain Rust builds the mask by shifting each lane's sign into place,
/// which LLVM compiles to a horizontal OR of the 16 lanes even in an AVX-512 build; where AVX-512
/// runs ([`widest_level`] 2) one compare into a mask register gives it, where AVX2 runs (1) two
/// compares read out by `movemask`, on any other x86-64 CPU (0) four SSE compares, and in
/// WebAssembly with SIMD four compares read out by `bitmask`; plain Rust remains for other
/// targets. The same bits every way for lanes that are not NaN. Before the SIMD compares, one
/// lane at a time: the try-on page's post-process took 4.26–4.39 ms a frame back to back at
/// 4,210 triangles, now 3.26–3.46 (the browser test, the same garments), and the AVX2 build's
/// on the trained 8,710-triangle walk 0.74–0.75 ms, now 0.70–0.72 (Intel Xeon VM, builds in
/// turn); the build as written (`SARTOR_RUNTIME_ISA=portable`) on the shipped walk 554–567 µs,
/// now 518–522.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct LaneMask {
    /// [`widest_level`] where it was detected (0, the plain mask, by default).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    level: u8,
}

impl LaneMask {
    /// The mask for this CPU and [`Isa::best`].
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        return Self {
            level: widest_level(),
        };
        #[cfg(not(target_arch = "x86_64"))]
        Self::default()
    }

    /// Whether a test over 16 lanes that ends in one yes or no runs faster as one difference per
    /// lane read by [`LaneMask::at_most`] than as booleans (the certified sweep's cluster test):
    /// in WebAssembly and where the AVX2 build runs; not with AVX-512, SSE or plain Rust.
    #[inline(always)]
    pub(crate) fn prefers_one_mask(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        return self.level == 1;
        #[cfg(target_arch = "wasm32")]
        return true;
        #[cfg(not(any(target_arch = "x86_64", target_arch = "wasm32")))]
        false
    }

    /// Bit `l` set where `v[l] ≤ t`, for a finite `t ≥ 0` and no NaN lane (the search's reach
    /// is a positive square, the rays' box test compares with 0; bounds at infinity lie
    /// beyond).
    #[inline(always)]
    pub(crate) fn at_most(self, v: &[f32; 16], t: f32) -> u32 {
        #[cfg(target_arch = "x86_64")]
        return match self.level {
            // SAFETY: `level` is only 2 where `widest_level` found AVX-512 on this CPU.
            2 => unsafe { at_most_avx512(v, t) },
            // SAFETY: `level` is only 1 where `widest_level` found AVX2 on this CPU.
            1 => unsafe { at_most_avx2(v, t) },
            _ => at_most_sse2(v, t),
        };
        #[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
        return at_most_simd128(v, t);
        #[cfg(not(any(
            target_arch = "x86_64",
            all(target_arch = "wasm32", target_feature = "simd128")
        )))]
        at_most_plain(v, t)
    }
}

/// [`LaneMask::at_most`] in plain Rust (other targets): the sign bit of `t − b` is set exactly
/// when `b > t` (`b` at infinity included).
#[cfg(not(any(
    target_arch = "x86_64",
    all(target_arch = "wasm32", target_feature = "simd128")
)))]
#[inline(always)]
fn at_most_plain(v: &[f32; 16], t: f32) -> u32 {
    let mut beyond = 0u32;
    for (l, &b) in v.iter().enumerate() {
        beyond |= ((t - b).to_bits() >> 31) << l;
    }
    !beyond & 0xffff
}

/// [`LaneMask::at_most`] with AVX2: two compares, each read out by `movemask`.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn at_most_avx2(v: &[f32; 16], t: f32) -> u32 {
    use std::arch::x86_64::{
        _CMP_LE_OQ, _mm256_cmp_ps, _mm256_loadu_ps, _mm256_movemask_ps, _mm256_set1_ps,
    };
    let t = _mm256_set1_ps(t);
    // SAFETY: the loads read the 16 floats of `v`, eight at a time.
    let (lo, hi) = unsafe {
        (
            _mm256_loadu_ps(v.as_ptr()),
            _mm256_loadu_ps(v.as_ptr().add(8)),
        )
    };
    let lo = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(lo, t)) as u32;
    let hi = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(hi, t)) as u32;
    lo | (hi << 8)
}

/// [`LaneMask::at_most`] with SSE2 (every x86-64 CPU): four compares, each read out by
/// `movemask`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn at_most_sse2(v: &[f32; 16], t: f32) -> u32 {
    use std::arch::x86_64::{_mm_cmple_ps, _mm_loadu_ps, _mm_movemask_ps, _mm_set1_ps};
    let mut mask = 0u32;
    // SAFETY: SSE is part of every x86-64 CPU; the loads read floats `4k..4k + 4` of `v`.
    unsafe {
        let t = _mm_set1_ps(t);
        for k in 0..4 {
            let lanes = _mm_loadu_ps(v.as_ptr().add(4 * k));
            mask |= (_mm_movemask_ps(_mm_cmple_ps(lanes, t)) as u32) << (4 * k);
        }
    }
    mask
}

/// [`LaneMask::at_most`] with WebAssembly SIMD: four compares, each read out by `bitmask`.
#[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
#[inline]
fn at_most_simd128(v: &[f32; 16], t: f32) -> u32 {
    use std::arch::wasm32::{f32x4, f32x4_le, f32x4_splat, i32x4_bitmask};
    let t = f32x4_splat(t);
    let mut mask = 0u32;
    for (k, c) in v.chunks_exact(4).enumerate() {
        let lanes = f32x4(c[0], c[1], c[2], c[3]);
        mask |= u32::from(i32x4_bitmask(f32x4_le(lanes, t))) << (4 * k);
    }
    mask
}

/// [`LaneMask::at_most`] with AVX-512.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
fn at_most_avx512(v: &[f32; 16], t: f32) -> u32 {
    use std::arch::x86_64::{_CMP_LE_OQ, _mm512_cmp_ps_mask, _mm512_loadu_ps, _mm512_set1_ps};
    // SAFETY: the load reads the 16 floats of `v`.
    let lanes = unsafe { _mm512_loadu_ps(v.as_ptr()) };
    u32::from(_mm512_cmp_ps_mask::<_CMP_LE_OQ>(lanes, _mm512_set1_ps(t)))
}

/// `fn name(args) -> ret { body }`, built three times: as written, with AVX2 enabled and with
/// AVX-512 enabled, the widest that [`Isa::best`] allows running. For loops of plain arithmetic
/// that the baseline x86-64 target vectorises poorly (no vector rounding, unsigned maximum or
/// float-to-integer steps) and lane tests that AVX-512's mask registers answer in one
/// instruction; IEEE arithmetic that Rust never contracts gives the same bits in every build.
/// Arguments are plain identifiers (no patterns, no `self`). The one place of the crate's
/// `unsafe` outside the kernels below.
///
/// The certified post-process's search gains from the AVX-512 build on the AMD EPYC (Zen 5) VM:
/// the shipped model's post-process 511–517 → 499–509 µs (`cargo bench --bench postprocess`,
/// alternating builds, three rounds; the extensions for bit scans added 1–2 % of that).
macro_rules! widest_where_present {
    (
        $(#[$attr:meta])*
        $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block
    ) => {
        $(#[$attr])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn written($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
                fn avx2($($arg: $ty),*) $(-> $ret)? {
                    written($($arg),*)
                }
                #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
                fn avx512($($arg: $ty),*) $(-> $ret)? {
                    written($($arg),*)
                }
                match $crate::kernels::widest_level() {
                    // SAFETY: `widest_level` found these features on this CPU (`has_avx512`).
                    #[allow(unsafe_code)]
                    2 => return unsafe { avx512($($arg),*) },
                    // SAFETY: `widest_level` found these features on this CPU (`has_avx2`).
                    #[allow(unsafe_code)]
                    1 => return unsafe { avx2($($arg),*) },
                    _ => {}
                }
            }
            written($($arg),*)
        }
    };
}
pub(crate) use widest_where_present;

/// Bytes ahead of each stream's current chunk that the eight-row kernels ask the cache for
/// where their rows come from memory: f16 rows (`dot8_block`, rows of `EIGHT_ROWS_FROM` columns
/// or more) and int8's strided rows (`dot8_far`). At 32 or 64 bytes per row and step these
/// streams advance too slowly for the hardware's prefetch: on the AMD EPYC VM the paper-size
/// GRU + dense step took 1.45–1.50 → 1.27–1.31 ms in f16 and 0.66–0.68 → 0.54–0.55 in int8
/// on one thread (`cargo bench --bench kernels -- gru1500_out13272`, alternating builds; 512,
/// 1,024, 3,072 and 4,096 bytes ahead measured slower than 2,048). Each stream runs on into the
/// next row of its own, so a prefetch past a row's end fetches what the stream reads next.
///
/// One prefetch per row and cache line: the int8 rows' steps read 16 bytes of a row (AVX2) or
/// 32 (AVX-512), and until 2026-12-07 each step asked for its line again. On the AMD EPYC Zen
/// 3 VM (AVX2) the 13,272 × 1,500 and 4,500 × 1,500 int8 products, the two rules alternated
/// in one process (three runs each), read 0.90–0.93× the time on two threads (median over the
/// rounds) and 0.99–1.02× on one in a slow hour of the VM's memory (0.93–0.96× in a faster
/// one; docs/speed-log.md); the AVX-512 build's half of the saving was not measured.
#[cfg(target_arch = "x86_64")]
const STREAM_AHEAD: usize = 2048;

/// Whether the CPU's vendor string (`cpuid` leaf 0) is `vendor`.
#[cfg(target_arch = "x86_64")]
fn vendor_is(vendor: &[u8; 12]) -> bool {
    let id = std::arch::x86_64::__cpuid(0);
    [id.ebx, id.edx, id.ecx]
        .iter()
        .flat_map(|r| r.to_le_bytes())
        .eq(*vendor)
}

/// Whether the CPU is Intel's.
#[cfg(target_arch = "x86_64")]
fn genuine_intel() -> bool {
    vendor_is(b"GenuineIntel")
}

/// The family of an AMD CPU (`cpuid` leaf 1: the base family, plus the extended family where
/// the base is 15): 0x19 for Zen 3 and Zen 4, 0x1A for Zen 5. `None` for other vendors.
#[cfg(target_arch = "x86_64")]
fn amd_family() -> Option<u32> {
    if !vendor_is(b"AuthenticAMD") {
        return None;
    }
    let eax = std::arch::x86_64::__cpuid(1).eax;
    let base = (eax >> 8) & 0xF;
    Some(if base == 0xF {
        base + ((eax >> 20) & 0xFF)
    } else {
        base
    })
}

/// `default()`, unless the environment variable `var` is `0` or `1` (for benchmarking: the
/// choices it overrides change no result).
fn overridable(var: &str, default: impl FnOnce() -> bool) -> bool {
    match std::env::var(var).as_deref() {
        Ok("0") => false,
        Ok("1") => true,
        _ => default(),
    }
}

/// Whether f32 rows that come from memory are prefetched [`STREAM_AHEAD`] bytes ahead, as f16
/// rows always are: on Intel CPUs, not on others. Measured on the paper-size GRU + dense
/// f32 step (`cargo bench -p sartor-runtime --bench kernels -- gru1500_out13272/f32/batch1`,
/// alternating builds): on the 2-core Intel Xeon VM (Sapphire Rapids family) one thread
/// 4.80–5.53 → 4.21–4.74 ms, two 2.53 → 2.13–2.22 (one core of this Xeon keeps too few lines
/// in flight on its own); on the AMD EPYC (Zen 5) VM every distance and hint tried was 3–10 %
/// slower (its own prefetch keeps up with eight f32 streams), and on the AMD EPYC Zen 3 VM
/// the row-major 13,272 × 1,500 and 4,500 × 1,500 products took 1.2–1.3× as long prefetched
/// (medians 6.60–6.91 against 5.09–5.56 ms for ten frames, three runs of each in turn).
/// `SARTOR_RUNTIME_F32_PREFETCH` (`0` or `1`) overrides the choice, for benchmarking.
/// Prefetching changes no result. Where `Matrix` stores f32 rows of that length interleaved
/// ([`interleave_long_rows`]: Zen 5 and later), they are read as one stream per panel and
/// always prefetched, and there this choice only concerns row-major blocks passed to the row
/// kernels directly (the tests).
#[cfg(target_arch = "x86_64")]
pub(crate) fn prefetch_f32_rows() -> bool {
    static CHOICE: OnceLock<bool> = OnceLock::new();
    *CHOICE.get_or_init(|| overridable("SARTOR_RUNTIME_F32_PREFETCH", genuine_intel))
}

/// Whether `Matrix` stores f32 and f16 rows of `EIGHT_ROWS_FROM` columns or more interleaved
/// (`interleaved.rs`): on AMD CPUs from Zen 5 on (family 0x1A) and on targets other than
/// x86-64; elsewhere the row-major rows, eight streams, read faster. Measured on the paper-size
/// GRU + dense step (109 MB in f32), a throwaway harness alternating the two layouts in one
/// process (ten rounds of 50 frames each, the median per round): on the 2-core AMD EPYC Zen 5
/// VM interleaved took 0.73–0.77× the row-major time in f32 on one thread and 0.87–0.97× on
/// two (`interleaved.rs`); on the 2-core Intel Xeon VM (Sapphire Rapids, 2026-12-02)
/// **0.90–1.72×** on one thread (above 1.0 in 16 of 20 rounds over two runs) and 0.88–1.11× on
/// two (above in 15 of 20), and in f16 0.90–1.03× and 0.99–1.09×. Prefetching the panels 2, 4
/// or 16 KiB ahead instead of 8, or into the L2 only, did not close the gap there. On the
/// 2-core AMD EPYC Zen 3 VM (family 0x19, AVX2 only, 32 MiB of L3; 2026-12-07), the 13,272 ×
/// 1,500 and 4,500 × 1,500 products of that step alternated in one process (38 rounds of ten
/// frames; the ratio's 10th, 50th and 90th percentiles over the rounds): interleaved
/// **1.18 / 1.46 / 1.59×** the row-major time in f32 on one thread, 1.04 / 1.20 / 1.30× on
/// two, f16 1.09 / 1.27 / 1.40× and 1.01 / 1.10 / 1.34×; without its prefetch still 1.11 /
/// 1.27 / 1.43× in f32 (one panel is one stream, and one stream per core did not fetch as fast
/// there as eight). So the AMD CPUs before Zen 5 keep the rows row-major: the paper-size f32
/// step in `cargo xtask bench runtime --anchors` on that VM took 7.08 ms on one thread with
/// the panels (2.0× the memory floor, 1.20× ONNX Runtime's time). `SARTOR_RUNTIME_INTERLEAVE`
/// (`0` or `1`) overrides the choice, for benchmarking; either layout gives the same bits.
pub(crate) fn interleave_long_rows() -> bool {
    static CHOICE: OnceLock<bool> = OnceLock::new();
    #[cfg(target_arch = "x86_64")]
    let default = || amd_family().is_some_and(|family| family >= 0x1A);
    #[cfg(not(target_arch = "x86_64"))]
    let default = || true;
    *CHOICE.get_or_init(|| overridable("SARTOR_RUNTIME_INTERLEAVE", default))
}

/// A hint to load the cache line at `p` into every level of the cache.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn prefetch(p: *const i8) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    // SAFETY: a prefetch never faults and changes nothing the program can observe, whatever
    // the address (the pointer is only formed with wrapping arithmetic and never read).
    unsafe { _mm_prefetch::<_MM_HINT_T0>(p) }
}

/// Ask the cache for chunk `i` (`LANES` values) of `ahead`, if it has one.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn ask_chunk<T>(ahead: &[T], i: usize) {
    use super::rows::LANES;
    if i < ahead.len().div_ceil(LANES) {
        let at = ahead.as_ptr().wrapping_add(i * LANES).cast::<i8>();
        for line in 0..size_of::<[T; LANES]>().div_ceil(64) {
            prefetch(at.wrapping_add(64 * line));
        }
    }
}

/// The kernels of one instruction set, written once for its vector type: each ISA module
/// defines `V` (a vector of `W` f32 lanes), `R = LANES / W` vectors per lane sum, `add`, `mul`,
/// `load_f32`, `load_i8`, `load_f16` (exact conversions) and `store`, all with the module's
/// target features; `$feat` repeats them for the functions made here.
#[cfg(target_arch = "x86_64")]
macro_rules! isa_kernels {
    ($feat:literal, $add:ident, $mul:ident, $loadu:ident, $storeu:ident) => {
        #[inline]
        #[target_feature(enable = $feat)]
        fn add(a: V, b: V) -> V {
            $add(a, b)
        }

        #[inline]
        #[target_feature(enable = $feat)]
        fn mul(a: V, b: V) -> V {
            $mul(a, b)
        }

        #[inline]
        #[target_feature(enable = $feat)]
        fn load_f32(a: &[f32; W]) -> V {
            // SAFETY: `a` is W f32, exactly the vector's width; the load needs no alignment.
            unsafe { $loadu(a.as_ptr()) }
        }

        #[inline]
        #[target_feature(enable = $feat)]
        fn store(v: V, out: &mut [f32; W]) {
            // SAFETY: `out` is W writable f32, exactly the vector's width; no alignment needed.
            unsafe { $storeu(out.as_mut_ptr(), v) }
        }

        #[inline]
        #[target_feature(enable = $feat)]
        fn load_acc(s: &[f32; LANES]) -> [V; R] {
            let (sw, _) = s.as_chunks::<W>();
            std::array::from_fn(|r| load_f32(&sw[r]))
        }

        #[inline]
        #[target_feature(enable = $feat)]
        fn store_acc(acc: [V; R], s: &mut [f32; LANES]) {
            let (sw, _) = s.as_chunks_mut::<W>();
            for r in 0..R {
                store(acc[r], &mut sw[r]);
            }
        }

        /// Vector `r` of a partial last chunk of an input, zero beyond its end.
        #[inline]
        #[target_feature(enable = $feat)]
        fn x_tail(x: &[f32]) -> [V; R] {
            std::array::from_fn(|r| load_f32_tail(x, r))
        }

        // f32 rows are prefetched where `prefetch_f32_rows` says (on the AMD EPYC VM, with
        // `STREAM_AHEAD`, 1,024 or 512 bytes ahead, or into L2 only, the paper-size f32 step
        // was 3–10 % slower; prefetching one of each chunk's two lines, 50 % slower).
        isa_kernels!(@one $feat, prefetch_f32_rows(), f32, load_f32, load_f32_tail, dot_f32, dot8_block_f32, dot4_block_f32, dot8_interleaved_f32, dotn_block_f32, madd1_f32, madd2_f32, madd2_tile_f32);
        isa_kernels!(@one $feat, false, i8, load_i8, load_i8_tail, dot_i8, dot8_block_i8, dot4_block_i8, dot8_interleaved_i8, dotn_block_i8, madd1_i8, madd2_i8, madd2_tile_i8);
        isa_kernels!(@one $feat, true, F16Bits, load_f16, load_f16_tail, dot_f16, dot8_block_f16, dot4_block_f16, dot8_interleaved_f16, dotn_block_f16, madd1_f16, madd2_f16, madd2_tile_f16);
    };
    (@one $feat:literal, $prefetch:expr, $t:ty, $load:ident, $load_tail:ident,
        $dot:ident, $dot8_block:ident, $dot4_block:ident, $dot8_il:ident, $dotn_block:ident, $madd1:ident, $madd2:ident, $madd2_tile:ident) => {
        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $dot(w: &[$t], x: &[f32]) -> f32 {
            // The same sums as `madd1` from zero, lane for lane.
            let mut s = [0.0f32; LANES];
            $madd1(w, x, &mut s);
            reduce_acc(load_acc(&s))
        }

        /// `Engine::dot8_block`: eight rows at a time, each row prefetched `STREAM_AHEAD` bytes
        /// ahead where `$prefetch` says.
        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $dot8_block(w: &[$t], cols: usize, x: &[f32], n8: usize, sums: &mut [f32]) {
            if $prefetch {
                $dotn_block::<8, STREAM_AHEAD, false>(w, cols, x, n8, 1, n8, sums)
            } else {
                $dotn_block::<8, 0, false>(w, cols, x, n8, 1, n8, sums)
            }
        }

        /// `Engine::dot8_interleaved`: each panel of eight rows read as one stream, prefetched
        /// `IL_AHEAD` bytes ahead.
        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $dot8_il(w: &[$t], cols: usize, x: &[f32], n8: usize, sums: &mut [f32]) {
            $dotn_block::<8, IL_AHEAD, true>(w, cols, x, n8, 8, 1, sums)
        }

        /// `Engine::dot4_block`: four neighbouring rows at a time.
        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $dot4_block(w: &[$t], cols: usize, x: &[f32], nq: usize, sums: &mut [f32]) {
            $dotn_block::<4, 0, false>(w, cols, x, nq, 4, 1, sums)
        }

        /// `groups` groups of `N` rows, row `q·q_stride + k·k_stride` for group `q` and `k < N`
        /// (all of them below `N·groups`): `sums[row]` is its dot product with `x`, each row
        /// prefetched `AHEAD` bytes ahead of its chunk (none if 0). Per row the same sums as
        /// `dot`, lane for lane. Rows are row-major, or with `IL` interleaved
        /// (`interleaved.rs`: group `q` is panel `q`, `q_stride = N`, `k_stride = 1`, each row
        /// zero-padded to whole chunks, so that its last chunk is read whole: the zeros meet
        /// the input's zero-padded tail and add `+0`, as the masked loads' zeros do).
        ///
        /// The loop over the groups runs here, with the rows' pointers and the input's last
        /// partial chunk worked out from `cols` once. Written as one call of a kernel of `N`
        /// rows per group (its rows passed as slices, each checked and split into chunks: the
        /// `dotn` of git history before 2026-12-01), on the AMD EPYC VM
        /// the paper-size 13,272 × 1,500 f32 product read its 80 MB at 40–41 GB/s, and at 47–48
        /// as it is here, with the same inner loop and the same bits (1.92–1.98 → 1.65–1.68 ms;
        /// eight plain u64 streams read 57–58 GB/s there); the shipped model's f32 step, whose
        /// rows of 64 to 256 columns go four at a time, took 38.8–39.0 → 34.5–35.3 µs and f16
        /// 23.5–24.0 → 21.5–21.7 (`cargo bench --bench kernels -- shipped`, alternating
        /// builds). Which part of the per-group work cost that was not isolated: the tail masks
        /// worked out once, the chunks indexed rather than iterated and the loads' order each
        /// left that kernel as slow.
        #[inline]
        #[target_feature(enable = $feat)]
        fn $dotn_block<const N: usize, const AHEAD: usize, const IL: bool>(
            w: &[$t],
            cols: usize,
            x: &[f32],
            groups: usize,
            q_stride: usize,
            k_stride: usize,
            sums: &mut [f32],
        ) {
            let rows_in = N * groups;
            // Values per row as stored.
            let stored = if IL { cols.next_multiple_of(LANES) } else { cols };
            assert!(
                x.len() == cols
                    && w.len() >= rows_in * stored
                    && sums.len() >= rows_in
                    && (groups == 0 || (groups - 1) * q_stride + (N - 1) * k_stride < rows_in)
                    && (!IL || (q_stride == N && k_stride == 1)),
                "a block shorter than its rows"
            );
            let (xc, xt) = x.as_chunks::<LANES>();
            let full = xc.len() * LANES;
            let xv_tail = x_tail(xt);
            // From one chunk of a row to its next: the row's next values, or (interleaved)
            // past the other rows' chunks of the panel.
            let step = if IL { N * LANES } else { LANES };
            for q in 0..groups {
                let index = |k: usize| q * q_stride + k * k_stride;
                // SAFETY: every row index is below `N·groups` (asserted above), and `w` holds
                // that many rows of `stored` values; interleaved, panel `q` is the
                // `N·stored` values from `q·N·stored`, row `k`'s first chunk `k·LANES` into it.
                let rows: [*const $t; N] = std::array::from_fn(|k| unsafe {
                    if IL {
                        w.as_ptr().add(q * N * stored + k * LANES)
                    } else {
                        w.as_ptr().add(index(k) * cols)
                    }
                });
                let zero = [0.0f32; LANES];
                let mut acc = [load_acc(&zero); N];
                for i in 0..xc.len() {
                    if AHEAD > 0 {
                        for row in rows {
                            let at = row.wrapping_add(i * step).cast::<i8>().wrapping_add(AHEAD);
                            for line in 0..size_of::<[$t; LANES]>().div_ceil(64) {
                                prefetch(at.wrapping_add(64 * line));
                            }
                        }
                    }
                    let (xw, _) = xc[i].as_chunks::<W>();
                    for k in 0..N {
                        // SAFETY: chunk `i` of a row of `cols ≥ (i + 1)·LANES` values (interleaved,
                        // `(i·N + k)·LANES` into a panel of `N·stored`).
                        let chunk = unsafe { &*rows[k].add(i * step).cast::<[$t; LANES]>() };
                        let (ww, _) = chunk.as_chunks::<W>();
                        for r in 0..R {
                            acc[k][r] = add(acc[k][r], mul($load(&ww[r]), load_f32(&xw[r])));
                        }
                    }
                }
                if !xt.is_empty() {
                    // The partial last chunk read with loads that stop at the rows' ends, zero
                    // beyond (the same sums as a zero-padded chunk).
                    for (a, row) in acc.iter_mut().zip(rows) {
                        if IL {
                            // SAFETY: the row's zero-padded last chunk, `(full/LANES·N + k)·LANES`
                            // into its panel of `N·stored` values.
                            let chunk = unsafe { &*row.add(xc.len() * step).cast::<[$t; LANES]>() };
                            let (ww, _) = chunk.as_chunks::<W>();
                            for r in 0..R {
                                a[r] = add(a[r], mul($load(&ww[r]), xv_tail[r]));
                            }
                        } else {
                            // SAFETY: the row's last `cols − full` values.
                            let tail = unsafe { std::slice::from_raw_parts(row.add(full), cols - full) };
                            for r in 0..R {
                                a[r] = add(a[r], mul($load_tail(tail, r), xv_tail[r]));
                            }
                        }
                    }
                }
                for (k, d) in reduce_rows(acc).into_iter().enumerate() {
                    sums[index(k)] = d;
                }
            }
        }

        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $madd1(w: &[$t], x: &[f32], s: &mut [f32; LANES]) {
            #[inline]
            #[target_feature(enable = $feat)]
            fn step(acc: &mut [V; R], w: &[$t; LANES], x: &[f32; LANES]) {
                let (ww, _) = w.as_chunks::<W>();
                let (xw, _) = x.as_chunks::<W>();
                for r in 0..R {
                    acc[r] = add(acc[r], mul($load(&ww[r]), load_f32(&xw[r])));
                }
            }
            let mut acc = load_acc(s);
            let (wc, wt) = w.as_chunks::<LANES>();
            let (xc, xt) = x.as_chunks::<LANES>();
            for (a, b) in wc.iter().zip(xc) {
                step(&mut acc, a, b);
            }
            if !wt.is_empty() {
                let xv = x_tail(xt);
                for r in 0..R {
                    acc[r] = add(acc[r], mul($load_tail(wt, r), xv[r]));
                }
            }
            store_acc(acc, s);
        }

        /// `Engine::madd2_tile`: each input vector loaded once for the tile's rows.
        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $madd2_tile(
            w: [&[$t]; ROW_BLOCK],
            ahead: [&[$t]; ROW_BLOCK],
            x0: &[f32],
            x1: &[f32],
            s: [&mut [[f32; LANES]; 2]; ROW_BLOCK],
        ) {
            assert!(
                x1.len() == x0.len() && w.iter().all(|w| w.len() == x0.len()),
                "rows and inputs of one length"
            );
            let (x0c, x0t) = x0.as_chunks::<LANES>();
            let (x1c, x1t) = x1.as_chunks::<LANES>();
            let full = x0c.len() * LANES;
            let mut acc: [[[V; R]; 2]; ROW_BLOCK] =
                std::array::from_fn(|m| [load_acc(&s[m][0]), load_acc(&s[m][1])]);
            for i in 0..x0c.len() {
                // Chunk `i` of each row's `ahead` asked for beside chunk `i` of the rows.
                for ahead in ahead {
                    ask_chunk(ahead, i);
                }
                let (x0w, _) = x0c[i].as_chunks::<W>();
                let (x1w, _) = x1c[i].as_chunks::<W>();
                for r in 0..R {
                    let (a, b) = (load_f32(&x0w[r]), load_f32(&x1w[r]));
                    for m in 0..ROW_BLOCK {
                        // SAFETY: every row is as long as the inputs (asserted above), so the W
                        // values from `i·LANES + r·W` lie within its chunk `i`.
                        let ww = unsafe { &*w[m].as_ptr().add(i * LANES + r * W).cast::<[$t; W]>() };
                        let wv = $load(ww);
                        acc[m][0][r] = add(acc[m][0][r], mul(wv, a));
                        acc[m][1][r] = add(acc[m][1][r], mul(wv, b));
                    }
                }
            }
            if !x0t.is_empty() {
                let (a, b) = (x_tail(x0t), x_tail(x1t));
                for r in 0..R {
                    for m in 0..ROW_BLOCK {
                        let wv = $load_tail(&w[m][full..], r);
                        acc[m][0][r] = add(acc[m][0][r], mul(wv, a[r]));
                        acc[m][1][r] = add(acc[m][1][r], mul(wv, b[r]));
                    }
                }
            }
            for (acc, s) in acc.into_iter().zip(s) {
                store_acc(acc[0], &mut s[0]);
                store_acc(acc[1], &mut s[1]);
            }
        }

        #[inline]
        #[target_feature(enable = $feat)]
        pub(super) fn $madd2(
            w: &[$t],
            ahead: &[$t],
            x0: &[f32],
            x1: &[f32],
            s0: &mut [f32; LANES],
            s1: &mut [f32; LANES],
        ) {
            #[inline]
            #[target_feature(enable = $feat)]
            fn step(acc: [&mut [V; R]; 2], w: &[$t; LANES], x: [&[f32; LANES]; 2]) {
                let (ww, _) = w.as_chunks::<W>();
                let (x0w, _) = x[0].as_chunks::<W>();
                let (x1w, _) = x[1].as_chunks::<W>();
                let [acc0, acc1] = acc;
                for r in 0..R {
                    let wv = $load(&ww[r]);
                    acc0[r] = add(acc0[r], mul(wv, load_f32(&x0w[r])));
                    acc1[r] = add(acc1[r], mul(wv, load_f32(&x1w[r])));
                }
            }
            let mut acc0 = load_acc(s0);
            let mut acc1 = load_acc(s1);
            let (wc, wt) = w.as_chunks::<LANES>();
            let (x0c, x0t) = x0.as_chunks::<LANES>();
            let (x1c, x1t) = x1.as_chunks::<LANES>();
            for (i, ((a, b0), b1)) in wc.iter().zip(x0c).zip(x1c).enumerate() {
                // Chunk `i` of `ahead` asked for beside chunk `i` of `w`.
                ask_chunk(ahead, i);
                step([&mut acc0, &mut acc1], a, [b0, b1]);
            }
            if !wt.is_empty() {
                let (x0v, x1v) = (x_tail(x0t), x_tail(x1t));
                for r in 0..R {
                    let wv = $load_tail(wt, r);
                    acc0[r] = add(acc0[r], mul(wv, x0v[r]));
                    acc1[r] = add(acc1[r], mul(wv, x1v[r]));
                }
            }
            store_acc(acc0, s0);
            store_acc(acc1, s1);
        }
    };
}

/// AVX2 + F16C kernels with explicit intrinsics: 4 registers of 8 lanes per lane sum. Every
/// function has `#[target_feature(enable = "avx2,fma,f16c")]`; they are only reached through
/// the engines below, inside the `avx2` wrappers of `dispatched!`.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::{
        __m128i, __m256, _mm_add_ps, _mm_add_ss, _mm_cvtss_f32, _mm_loadl_epi64, _mm_loadu_si128,
        _mm_movehl_ps, _mm_shuffle_ps, _mm256_add_ps, _mm256_castps256_ps128, _mm256_cmpgt_epi32,
        _mm256_cvtepi8_epi32, _mm256_cvtepi32_ps, _mm256_cvtph_ps, _mm256_extractf128_ps,
        _mm256_loadu_ps, _mm256_maskload_ps, _mm256_mul_ps, _mm256_set1_epi32, _mm256_setr_epi32,
        _mm256_setzero_ps, _mm256_storeu_ps,
    };

    use super::super::rows::{F16Bits, LANES, ROW_BLOCK};
    use super::{IL_AHEAD, STREAM_AHEAD, ask_chunk, prefetch, prefetch_f32_rows};

    type V = __m256;
    const W: usize = 8;
    const R: usize = LANES / W;

    /// `rows::reduce` of the lane sums in registers: the same tree, each level one vector add
    /// of `s[l]` and `s[l + w]` (lanes 0–7, 8–15, 16–23, 24–31 in the four registers).
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn reduce_acc(acc: [V; R]) -> f32 {
        // + 16: lanes 0–15 in two registers.
        let (a, b) = (_mm256_add_ps(acc[0], acc[2]), _mm256_add_ps(acc[1], acc[3]));
        // + 8: lanes 0–7.
        let s8 = _mm256_add_ps(a, b);
        // + 4: lanes 0–3.
        let s4 = _mm_add_ps(_mm256_castps256_ps128(s8), _mm256_extractf128_ps::<1>(s8));
        reduce4(s4)
    }

    /// [`reduce_acc`] of each of `N` rows.
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn reduce_rows<const N: usize>(acc: [[V; R]; N]) -> [f32; N] {
        acc.map(|a| reduce_acc(a))
    }

    /// The last two levels of the tree on lanes 0–3: `+ 2`, then `+ 1`.
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn reduce4(s4: std::arch::x86_64::__m128) -> f32 {
        let s2 = _mm_add_ps(s4, _mm_movehl_ps(s4, s4));
        _mm_cvtss_f32(_mm_add_ss(s2, _mm_shuffle_ps::<0b01>(s2, s2)))
    }

    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn load_i8(a: &[i8; W]) -> V {
        // SAFETY: `a` is 8 readable bytes; `_mm_loadl_epi64` reads exactly 8 bytes, unaligned.
        let q = unsafe { _mm_loadl_epi64(a.as_ptr().cast::<__m128i>()) };
        _mm256_cvtepi32_ps(_mm256_cvtepi8_epi32(q))
    }

    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn load_f16(a: &[F16Bits; W]) -> V {
        // SAFETY: `a` is 8 `F16Bits` = 16 readable bytes (`repr(transparent)` over u16);
        // `_mm_loadu_si128` needs no alignment.
        let h = unsafe { _mm_loadu_si128(a.as_ptr().cast::<__m128i>()) };
        _mm256_cvtph_ps(h)
    }

    /// Lanes `r·W ..` of a partial chunk `t` (shorter than `LANES`), zero beyond its end.
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn load_f32_tail(t: &[f32], r: usize) -> V {
        let n = t.len().saturating_sub(r * W).min(W);
        if n == 0 {
            return _mm256_setzero_ps();
        }
        let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let mask = _mm256_cmpgt_epi32(_mm256_set1_epi32(n as i32), lanes);
        // SAFETY: `r·W < t.len()`, so the pointer is inside `t`; the masked load reads only
        // the `n` lanes left in `t` (the others are zero and never touched).
        unsafe { _mm256_maskload_ps(t.as_ptr().add(r * W), mask) }
    }

    /// [`load_f32_tail`] for i8 (through a copy: AVX2 has no byte-masked load).
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn load_i8_tail(t: &[i8], r: usize) -> V {
        load_i8(&part(t, r))
    }

    /// [`load_f32_tail`] for f16 (through a copy: AVX2 has no 16-bit masked load).
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn load_f16_tail(t: &[F16Bits], r: usize) -> V {
        load_f16(&part(t, r))
    }

    /// Lanes `r·W ..` of `t`, zero-padded to `W`.
    #[inline(always)]
    fn part<T: Copy + Default>(t: &[T], r: usize) -> [T; W] {
        let start = (r * W).min(t.len());
        let n = (t.len() - start).min(W);
        let mut a = [T::default(); W];
        a[..n].copy_from_slice(&t[start..start + n]);
        a
    }

    isa_kernels!(
        "avx2,fma,f16c",
        _mm256_add_ps,
        _mm256_mul_ps,
        _mm256_loadu_ps,
        _mm256_storeu_ps
    );
}

/// AVX-512 kernels: 2 registers of 16 lanes per lane sum, the same lane rule. Every function
/// has `#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]`; reached only through the engines
/// below, inside the `avx512` wrappers of `dispatched!`.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::{
        __m128, __m128i, __m256i, __m512, _mm_add_ps, _mm_add_ss, _mm_cvtss_f32, _mm_loadu_si128,
        _mm_maskz_loadu_epi8, _mm_movehl_ps, _mm_shuffle_ps, _mm256_add_ps, _mm256_castpd_ps,
        _mm256_castps256_ps128, _mm256_extractf128_ps, _mm256_loadu_si256,
        _mm256_maskz_loadu_epi16, _mm256_storeu_ps, _mm512_add_ps, _mm512_castpd512_pd256,
        _mm512_castps_pd, _mm512_castps512_ps256, _mm512_cvtepi8_epi32, _mm512_cvtepi32_ps,
        _mm512_cvtph_ps, _mm512_extractf64x4_pd, _mm512_loadu_ps, _mm512_maskz_loadu_ps,
        _mm512_mul_ps, _mm512_permute_ps, _mm512_permutexvar_ps, _mm512_setr_epi32,
        _mm512_setzero_ps, _mm512_shuffle_f32x4, _mm512_shuffle_ps, _mm512_storeu_ps,
    };

    use super::super::rows::{F16Bits, LANES, ROW_BLOCK};
    use super::{IL_AHEAD, STREAM_AHEAD, ask_chunk, prefetch, prefetch_f32_rows};

    type V = __m512;
    const W: usize = 16;
    const R: usize = LANES / W;

    /// `rows::reduce` of the lane sums in registers: the same tree, each level one vector add
    /// of `s[l]` and `s[l + w]` (lanes 0–15 and 16–31 in the two registers).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn reduce_acc(acc: [V; R]) -> f32 {
        // + 16: lanes 0–15.
        let s16 = _mm512_add_ps(acc[0], acc[1]);
        // + 8: lanes 0–7 (the upper half moved down as four doubles: the same bits).
        let d = _mm512_castps_pd(s16);
        let (lo, hi) = (
            _mm256_castpd_ps(_mm512_castpd512_pd256(d)),
            _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(d)),
        );
        let s8 = _mm256_add_ps(lo, hi);
        // + 4: lanes 0–3.
        let s4 = _mm_add_ps(_mm256_castps256_ps128(s8), _mm256_extractf128_ps::<1>(s8));
        reduce4(s4)
    }

    /// [`reduce_acc`] of `N` rows, four or eight of them at once: each level of the tree is
    /// one vector add over lanes of several rows, which adds the same pairs of lanes in the same
    /// order (`s[l] + s[l + w]`), so every row's sum has the same bits. One row's tree takes
    /// about nine instructions, four or eight together about five per row: the shipped f16
    /// step 25.3–26.2 → 23.7–24.7 µs; the f32 step level (its PCA decode, 6,504 rows of 64, is
    /// bound by reading 1.7 MB from L3, not by the tree).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn reduce_rows<const N: usize>(acc: [[V; R]; N]) -> [f32; N] {
        let mut out = [0.0f32; N];
        if N == 4 || N == 8 {
            // Rows past N are zero and their sums dropped.
            let e = reduce_to_quads(&acc);
            // + 2 and + 1: lane 4k holds row k's sum, lane 4k + 2 row k + 4's.
            let h = pairs_then_neighbours(e[0], e[1]);
            let at = _mm512_setr_epi32(0, 4, 8, 12, 2, 6, 10, 14, 0, 0, 0, 0, 0, 0, 0, 0);
            let mut rows = [0.0f32; 8];
            let sums = _mm512_castps512_ps256(_mm512_permutexvar_ps(at, h));
            // SAFETY: `rows` is 8 writable f32, exactly the 256 bits stored.
            unsafe { _mm256_storeu_ps(rows.as_mut_ptr(), sums) };
            out.copy_from_slice(&rows[..N]);
        } else {
            for (o, a) in out.iter_mut().zip(acc) {
                *o = reduce_acc(a);
            }
        }
        out
    }

    /// Levels `+ 16`, `+ 8` and `+ 4` of the tree for 4 or 8 rows: vector `q` holds lanes 0–3
    /// of rows `4q .. 4q + 4`, one row per 128-bit quarter.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn reduce_to_quads(acc: &[[V; R]]) -> [V; 2] {
        // + 16: row r's lanes 0–15.
        let c: [V; 8] = std::array::from_fn(|r| {
            acc.get(r)
                .map_or(_mm512_setzero_ps(), |a| _mm512_add_ps(a[0], a[1]))
        });
        // + 8, rows in pairs: [row 2p lanes 0–7 | row 2p + 1 lanes 0–7].
        let d: [V; 4] = std::array::from_fn(|p| {
            let (a, b) = (c[2 * p], c[2 * p + 1]);
            _mm512_add_ps(
                _mm512_shuffle_f32x4::<0b01_00_01_00>(a, b),
                _mm512_shuffle_f32x4::<0b11_10_11_10>(a, b),
            )
        });
        // + 4, pairs of pairs: [row 4q, 4q + 1, 4q + 2, 4q + 3: lanes 0–3 each].
        std::array::from_fn(|q| {
            let (a, b) = (d[2 * q], d[2 * q + 1]);
            _mm512_add_ps(
                _mm512_shuffle_f32x4::<0b10_00_10_00>(a, b),
                _mm512_shuffle_f32x4::<0b11_01_11_01>(a, b),
            )
        })
    }

    /// Levels `+ 2` and `+ 1` on two vectors of [`reduce_to_quads`]: in quarter `k`, lane 0
    /// gets row `k` of `e0`'s sum and lane 2 row `k` of `e1`'s.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn pairs_then_neighbours(e0: V, e1: V) -> V {
        // + 2: quarter k = [e0 s0 + s2, e0 s1 + s3, e1 s0 + s2, e1 s1 + s3].
        let g = _mm512_add_ps(
            _mm512_shuffle_ps::<0b01_00_01_00>(e0, e1),
            _mm512_shuffle_ps::<0b11_10_11_10>(e0, e1),
        );
        // + 1: lane 0 = g0 + g1, lane 2 = g2 + g3.
        _mm512_add_ps(g, _mm512_permute_ps::<0b10_11_00_01>(g))
    }

    /// The last two levels of the tree on lanes 0–3: `+ 2`, then `+ 1`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn reduce4(s4: __m128) -> f32 {
        let s2 = _mm_add_ps(s4, _mm_movehl_ps(s4, s4));
        _mm_cvtss_f32(_mm_add_ss(s2, _mm_shuffle_ps::<0b01>(s2, s2)))
    }

    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn load_i8(a: &[i8; W]) -> V {
        // SAFETY: `a` is 16 readable bytes; `_mm_loadu_si128` reads exactly 16, unaligned.
        let q = unsafe { _mm_loadu_si128(a.as_ptr().cast::<__m128i>()) };
        _mm512_cvtepi32_ps(_mm512_cvtepi8_epi32(q))
    }

    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn load_f16(a: &[F16Bits; W]) -> V {
        // SAFETY: `a` is 16 `F16Bits` = 32 readable bytes (`repr(transparent)` over u16);
        // `_mm256_loadu_si256` needs no alignment.
        let h = unsafe { _mm256_loadu_si256(a.as_ptr().cast::<__m256i>()) };
        _mm512_cvtph_ps(h)
    }

    /// Lanes `r·W ..` of a partial chunk `t` (shorter than `LANES`), zero beyond its end.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn load_f32_tail(t: &[f32], r: usize) -> V {
        let n = t.len().saturating_sub(r * W).min(W);
        if n == 0 {
            return _mm512_setzero_ps();
        }
        // SAFETY: `r·W < t.len()`, so the pointer is inside `t`; the masked load reads only
        // the `n` lanes left in `t` (the others are zero and never touched).
        unsafe { _mm512_maskz_loadu_ps(tail_mask(n), t.as_ptr().add(r * W)) }
    }

    /// [`load_f32_tail`] for i8.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn load_i8_tail(t: &[i8], r: usize) -> V {
        let n = t.len().saturating_sub(r * W).min(W);
        if n == 0 {
            return _mm512_setzero_ps();
        }
        // SAFETY: as in `load_f32_tail`.
        let q = unsafe { _mm_maskz_loadu_epi8(tail_mask(n), t.as_ptr().add(r * W)) };
        _mm512_cvtepi32_ps(_mm512_cvtepi8_epi32(q))
    }

    /// [`load_f32_tail`] for f16.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma,f16c")]
    fn load_f16_tail(t: &[F16Bits], r: usize) -> V {
        let n = t.len().saturating_sub(r * W).min(W);
        if n == 0 {
            return _mm512_setzero_ps();
        }
        // SAFETY: as in `load_f32_tail` (`F16Bits` is `repr(transparent)` over u16).
        let h = unsafe { _mm256_maskz_loadu_epi16(tail_mask(n), t.as_ptr().add(r * W).cast()) };
        _mm512_cvtph_ps(h)
    }

    /// The first `n` (1 to 16) lanes.
    #[inline(always)]
    fn tail_mask(n: usize) -> u16 {
        ((1u32 << n) - 1) as u16
    }

    isa_kernels!(
        "avx512f,avx512bw,avx512vl,avx2,fma,f16c",
        _mm512_add_ps,
        _mm512_mul_ps,
        _mm512_loadu_ps,
        _mm512_storeu_ps
    );
}

/// The SIMD engines: private, and only instantiated inside the wrappers of `dispatched!`
/// with their module's target features.
#[cfg(target_arch = "x86_64")]
mod engines {
    use super::super::rows::{Engine, F16Bits, LANES, ROW_BLOCK, madd2_rows};
    use super::{avx2, avx512};

    macro_rules! engine {
        ($t:ty: $($name:ident $m:ident $tile:literal),+; $kernels:tt) => {
            $(engine!(@one $name, $m, $tile, $t, $kernels);)+
        };
        (@one $name:ident, $m:ident, $tile:literal, $t:ty, ($($kernel:ident),+)) => {
            engine!($name, $m, $tile, $t, $($kernel),+);
        };
        ($name:ident, $m:ident, $tile:literal, $t:ty, $dot:ident, $dot8_block:ident, $dot4_block:ident, $dot8_il:ident, $madd1:ident, $madd2:ident, $madd2_tile:ident) => {
            pub(super) struct $name;

            impl Engine for $name {
                type Stored = $t;

                #[inline(always)]
                fn dot(w: &[$t], x: &[f32]) -> f32 {
                    // SAFETY: this engine is only used inside wrappers with its module's
                    // `#[target_feature]`, which are only called for an `Isa` made after
                    // detection found those features.
                    unsafe { $m::$dot(w, x) }
                }

                #[inline(always)]
                fn dot8_block(w: &[$t], cols: usize, x: &[f32], n8: usize, sums: &mut [f32]) {
                    // SAFETY: as for `dot`.
                    unsafe { $m::$dot8_block(w, cols, x, n8, sums) }
                }

                #[inline(always)]
                fn dot4_block(w: &[$t], cols: usize, x: &[f32], nq: usize, sums: &mut [f32]) {
                    // SAFETY: as for `dot`.
                    unsafe { $m::$dot4_block(w, cols, x, nq, sums) }
                }

                #[inline(always)]
                fn dot8_interleaved(w: &[$t], cols: usize, x: &[f32], n8: usize, sums: &mut [f32]) {
                    // SAFETY: as for `dot`.
                    unsafe { $m::$dot8_il(w, cols, x, n8, sums) }
                }

                #[inline(always)]
                fn madd1(w: &[$t], x: &[f32], s: &mut [f32; LANES]) {
                    // SAFETY: as for `dot`.
                    unsafe { $m::$madd1(w, x, s) }
                }

                #[inline(always)]
                fn madd2(
                    w: &[$t],
                    ahead: &[$t],
                    x0: &[f32],
                    x1: &[f32],
                    s0: &mut [f32; LANES],
                    s1: &mut [f32; LANES],
                ) {
                    // SAFETY: as for `dot`.
                    unsafe { $m::$madd2(w, ahead, x0, x1, s0, s1) }
                }

                #[inline(always)]
                fn madd2_tile(
                    w: [&[$t]; ROW_BLOCK],
                    ahead: [&[$t]; ROW_BLOCK],
                    x0: &[f32],
                    x1: &[f32],
                    s: [&mut [[f32; LANES]; 2]; ROW_BLOCK],
                ) {
                    if $tile {
                        // SAFETY: as for `dot`.
                        unsafe { $m::$madd2_tile(w, ahead, x0, x1, s) }
                    } else {
                        madd2_rows::<Self>(w, ahead, x0, x1, s)
                    }
                }
            }
        };
    }

    // One engine per instruction set and storage type: the same kernels' names in `avx2` and
    // `avx512`.
    engine!(f32: Avx2F32 avx2 false, Avx512F32 avx512 true;
        (dot_f32, dot8_block_f32, dot4_block_f32, dot8_interleaved_f32, madd1_f32, madd2_f32, madd2_tile_f32));
    engine!(i8: Avx2I8 avx2 false, Avx512I8 avx512 true;
        (dot_i8, dot8_block_i8, dot4_block_i8, dot8_interleaved_i8, madd1_i8, madd2_i8, madd2_tile_i8));
    engine!(F16Bits: Avx2F16 avx2 false, Avx512F16 avx512 true;
        (dot_f16, dot8_block_f16, dot4_block_f16, dot8_interleaved_f16, madd1_f16, madd2_f16, madd2_tile_f16));
}

/// A kernel `$name(isa, w, cols, xs, batch, scales, bias, ys_t)` that calls `$portable` or,
/// inside wrappers with the instruction set's target features, `$avx2` / `$avx512` (each a
/// generic kernel instantiated for that instruction set).
macro_rules! dispatched {
    ($(#[$doc:meta])* $name:ident, $t:ty, $portable:path, $avx2:path, $avx512:path) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        pub(crate) fn $name(
            isa: Isa,
            w: &[$t],
            cols: usize,
            xs: &[f32],
            batch: usize,
            scales: Option<&[f32]>,
            bias: Option<&[f32]>,
            ys_t: &mut [f32],
        ) {
            #[cfg(target_arch = "x86_64")]
            {
                macro_rules! wrapper {
                    ($wrap:ident, $feat:literal, $kernel:path) => {
                        #[target_feature(enable = $feat)]
                        fn $wrap(
                            w: &[$t],
                            cols: usize,
                            xs: &[f32],
                            batch: usize,
                            scales: Option<&[f32]>,
                            bias: Option<&[f32]>,
                            ys_t: &mut [f32],
                        ) {
                            $kernel(w, cols, xs, batch, scales, bias, ys_t)
                        }
                    };
                }
                wrapper!(avx2, "avx2,fma,f16c", $avx2);
                wrapper!(avx512, "avx512f,avx512bw,avx512vl,avx2,fma,f16c", $avx512);
                match isa.0 {
                    // SAFETY: `Isa(Level::Avx2)` is only built after `has_avx2()` found avx2,
                    // fma and f16c on this CPU.
                    Level::Avx2 => return unsafe { avx2(w, cols, xs, batch, scales, bias, ys_t) },
                    // SAFETY: `Isa(Level::Avx512)` is only built after `has_avx512()` found
                    // avx512f and avx512bw as well.
                    Level::Avx512 => {
                        return unsafe { avx512(w, cols, xs, batch, scales, bias, ys_t) };
                    }
                    Level::Portable => {}
                }
            }
            let _ = isa;
            $portable(w, cols, xs, batch, scales, bias, ys_t)
        }
    };
}

dispatched!(
    /// f32 rows.
    rows_f32,
    f32,
    rows::<Portable<F32Codec>>,
    rows::<engines::Avx2F32>,
    rows::<engines::Avx512F32>
);
dispatched!(
    /// f16 rows (bits), converted exactly to f32 on the fly (F16C on x86-64 when present).
    rows_f16,
    F16Bits,
    rows::<Portable<F16Codec>>,
    rows::<engines::Avx2F16>,
    rows::<engines::Avx512F16>
);
dispatched!(
    /// f32 rows stored interleaved (`interleaved.rs`).
    interleaved_f32,
    f32,
    interleaved::<Portable<F32Codec>>,
    interleaved::<engines::Avx2F32>,
    interleaved::<engines::Avx512F32>
);
dispatched!(
    /// f16 rows (bits) stored interleaved.
    interleaved_f16,
    F16Bits,
    interleaved::<Portable<F16Codec>>,
    interleaved::<engines::Avx2F16>,
    interleaved::<engines::Avx512F16>
);
dispatched!(
    /// int8 rows with a per-row scale, by the lane rule (weights converted to f32): the rows
    /// [`rows_i8`] does not give to the integer kernels.
    rows_i8_lanes,
    i8,
    rows::<Portable<I8Codec>>,
    rows::<engines::Avx2I8>,
    rows::<engines::Avx512I8>
);
// The panel kernel (`panels.rs`) is plain Rust over arrays of PANEL f32; compiled inside the
// wrappers it uses their vector width (the same bits: no FMA).
dispatched!(
    /// f32 panels (see `panels.rs`).
    panels_f32,
    f32,
    panels::<f32>,
    panels::<f32>,
    panels::<f32>
);
/// Integer kernels of `int8.rs` with explicit intrinsics: int8 weights widened to 16 bits and
/// multiplied by the quantised input in pairs summed to 32 bits (`vpmaddwd`), 16 columns per
/// instruction on AVX2, 32 on AVX-512 (with avx512bw). Integer sums are exact, so they equal
/// the portable engine's whatever the order.
#[cfg(target_arch = "x86_64")]
mod int {
    use std::arch::x86_64::{
        __m128i, __m256i, __m512i, __mmask32, _mm_add_epi32, _mm_cvtsi128_si32, _mm_loadu_si128,
        _mm_shuffle_epi32, _mm256_add_epi32, _mm256_and_si256, _mm256_castsi256_si128,
        _mm256_cvtepi8_epi16, _mm256_dpbusd_avx_epi32, _mm256_extracti128_si256, _mm256_hadd_epi32,
        _mm256_loadu_si256, _mm256_madd_epi16, _mm256_maskz_loadu_epi8, _mm256_permute2x128_si256,
        _mm256_set1_epi32, _mm256_set1_epi64x, _mm256_setzero_si256, _mm256_slli_epi32,
        _mm256_storeu_si256, _mm256_sub_epi32, _mm512_add_epi32, _mm512_castsi512_si256,
        _mm512_cvtepi8_epi16, _mm512_dpbusd_epi32, _mm512_dpwssd_epi32, _mm512_extracti64x4_epi64,
        _mm512_loadu_si512, _mm512_madd_epi16, _mm512_maskz_loadu_epi16, _mm512_reduce_add_epi32,
        _mm512_set1_epi32, _mm512_set1_epi64, _mm512_setzero_si512, _mm512_slli_epi32,
        _mm512_storeu_si512, _mm512_sub_epi32,
    };

    use super::super::int8::{self, PortableInt};
    use super::super::int8::{FarGroups, IntEngine, QUAD, QUAD_BYTES, QUAD_PANEL, QuadEngine};
    use super::{STREAM_AHEAD, prefetch};

    /// The sum of the eight 32-bit lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn sum8(v: __m256i) -> i32 {
        let s = _mm_add_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
        let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
        let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
        _mm_cvtsi128_si32(s)
    }

    /// The sums of the eight 32-bit lanes of each of eight vectors, by a tree of pairwise
    /// horizontal adds (nine instructions for the eight sums, where eight [`sum8`] take 56).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn sums8(v: [__m256i; 8]) -> [i32; 8] {
        let h01 = _mm256_hadd_epi32(v[0], v[1]);
        let h23 = _mm256_hadd_epi32(v[2], v[3]);
        let h45 = _mm256_hadd_epi32(v[4], v[5]);
        let h67 = _mm256_hadd_epi32(v[6], v[7]);
        // Per 128-bit half: the partial sums of rows 0..4 (4..8).
        let h0123 = _mm256_hadd_epi32(h01, h23);
        let h4567 = _mm256_hadd_epi32(h45, h67);
        let s = _mm256_add_epi32(
            _mm256_permute2x128_si256::<0x20>(h0123, h4567),
            _mm256_permute2x128_si256::<0x31>(h0123, h4567),
        );
        let mut out = [0i32; 8];
        // SAFETY: `out` is eight i32, the 32 bytes stored.
        unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast::<__m256i>(), s) };
        out
    }

    /// [`sums8`] of eight 512-bit vectors, each first folded to 256 bits.
    #[inline]
    #[target_feature(enable = "avx512f,avx2")]
    fn sums8_512(v: [__m512i; 8]) -> [i32; 8] {
        sums8(v.map(|x| {
            _mm256_add_epi32(_mm512_castsi512_si256(x), _mm512_extracti64x4_epi64::<1>(x))
        }))
    }

    /// `acc + madd(q, x)`: pairs of 16-bit products summed into 32-bit lanes (AVX2).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn madd_add_avx2(acc: __m256i, q: __m256i, x: __m256i) -> __m256i {
        _mm256_add_epi32(acc, _mm256_madd_epi16(q, x))
    }

    /// [`madd_add_avx2`] on AVX-512.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw")]
    fn madd_add_avx512(acc: __m512i, q: __m512i, x: __m512i) -> __m512i {
        _mm512_add_epi32(acc, _mm512_madd_epi16(q, x))
    }

    /// [`madd_add_avx512`] in one instruction, VNNI's `vpdpwssd` (the same wrapping sums:
    /// the integer contract keeps every partial sum within `i32`, so the same bits).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
    fn madd_add_vnni(acc: __m512i, q: __m512i, x: __m512i) -> __m512i {
        _mm512_dpwssd_epi32(acc, q, x)
    }

    /// Lane `j` of a load at `OVERLAP_MASKS[rest..]` is all ones for `j ≥ 16 − rest`.
    static OVERLAP_MASKS: [i16; 32] = {
        let mut m = [0i16; 32];
        let mut j = 16;
        while j < 32 {
            m[j] = -1;
            j += 1;
        }
        m
    };

    /// The columns past the last whole chunk of 16 (`x[n..]`, fewer than 16) on AVX2, which has
    /// no masked load of bytes or halves: the last 16 columns of the rows and the input loaded
    /// again, the input's lanes of the columns already summed set to zero (exact sums, so the
    /// same bits). Every row must hold `x.len()` columns; rows shorter than 16 columns leave
    /// their columns to the portable engine. Returns the columns summed.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn overlap_tail_avx2<const N: usize>(
        acc: &mut [__m256i; N],
        rows: [*const i8; N],
        x: &[i16],
        n: usize,
        step: impl Fn(__m256i, __m256i, __m256i) -> __m256i,
    ) -> usize {
        let (len, rest) = (x.len(), x.len() - n);
        if rest == 0 || len < 16 {
            return n;
        }
        let start = len - 16;
        // SAFETY: `rest < 16`, so the 16 masks from `rest` lie within the 32; `x[start..]` is
        // 16 values.
        let xv = unsafe {
            let mask = _mm256_loadu_si256(OVERLAP_MASKS.as_ptr().add(rest).cast::<__m256i>());
            _mm256_and_si256(
                _mm256_loadu_si256(x.as_ptr().add(start).cast::<__m256i>()),
                mask,
            )
        };
        for (a, row) in acc.iter_mut().zip(rows) {
            // SAFETY: the caller checked every row holds `len` columns: 16 bytes from `start`.
            let q = unsafe { _mm_loadu_si128(row.add(start).cast::<__m128i>()) };
            *a = step(*a, _mm256_cvtepi8_epi16(q), xv);
        }
        len
    }

    /// The columns past the last whole chunk of 32 (`x[n..]`, fewer than 32) in one more step,
    /// read with masked loads that stop at the row's end (zeros beyond: the same exact sums).
    /// Every row must hold `x.len()` columns. Returns `x.len()`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl")]
    fn masked_tail<const N: usize>(
        acc: &mut [__m512i; N],
        rows: [*const i8; N],
        x: &[i16],
        n: usize,
        step: impl Fn(__m512i, __m512i, __m512i) -> __m512i,
    ) -> usize {
        let rest = x.len() - n;
        if rest > 0 {
            debug_assert!(rest < 32);
            let mask: __mmask32 = (1u32 << rest) - 1;
            // SAFETY: the mask covers `x[n..]` only; masked-off elements are not read.
            let xv = unsafe { _mm512_maskz_loadu_epi16(mask, x.as_ptr().add(n)) };
            for (a, row) in acc.iter_mut().zip(rows) {
                // SAFETY: the caller checked every row holds `x.len()` columns; the mask
                // covers the `rest` bytes from `n` only.
                let q = unsafe { _mm256_maskz_loadu_epi8(mask, row.add(n)) };
                *a = step(*a, _mm512_cvtepi8_epi16(q), xv);
            }
        }
        x.len()
    }

    /// `$dotn`: `N` rows with one input, `$w` columns per step (`$x`: a vector of `$w` i16,
    /// `$q`: a load of `$w` i8, `$acc`: the accumulate of [`madd_add_avx2`]), then `$tail`
    /// ([`masked_tail`] or [`overlap_tail_avx2`]), any rest by the portable engine; `$engine` is its
    /// [`IntEngine`], usable only inside wrappers with `$feat`.
    macro_rules! int_kernels {
        ($feat:literal, $engine:ident, $dotn:ident, $w:literal, $x:ty, $q:ty, $load_x:ident,
            $load_q:ident, $zero:ident, $widen:ident, $acc:ident, $tail:ident, $sum:path,
            $sums8:path) => {
            /// The vector partial sums of `N` rows over the input, and the columns they cover
            /// (the whole chunks, or every column with a masked tail).
            #[inline]
            #[target_feature(enable = $feat)]
            fn $dotn<const N: usize, const AHEAD: usize>(
                w: [&[i8]; N],
                x: &[i16],
            ) -> ([$x; N], usize) {
                let (xc, _) = x.as_chunks::<$w>();
                let mut acc = [$zero(); N];
                // The rows' lengths checked once, not per row and step (see `dotn_block` of
                // `isa_kernels!`).
                let n = xc.len() * $w;
                let rows: [*const i8; N] = std::array::from_fn(|k| {
                    assert!(w[k].len() >= x.len(), "a row shorter than the input");
                    w[k].as_ptr()
                });
                for (c, xv) in xc.iter().enumerate() {
                    // One prefetch per row and cache line (`STREAM_AHEAD`).
                    if AHEAD > 0 && ($w * c) % 64 == 0 {
                        for row in rows {
                            prefetch(row.wrapping_add($w * c + AHEAD));
                        }
                    }
                    // SAFETY: `xv` is `$w` i16, exactly the vector's width; no alignment needed.
                    let xv = unsafe { $load_x(xv.as_ptr().cast::<$x>()) };
                    for (a, row) in acc.iter_mut().zip(&rows) {
                        // SAFETY: `$w·c + $w ≤ n`, within the row (checked above): `$w`
                        // readable bytes, exactly what the load reads.
                        let q = unsafe { $load_q(row.add($w * c).cast::<$q>()) };
                        *a = $acc(*a, $widen(q), xv);
                    }
                }
                // Every row holds `x.len()` columns (checked above), as `$tail` needs.
                let done = $tail(&mut acc, rows, x, n, |a, q, x| $acc(a, q, x));
                (acc, done)
            }

            pub(super) struct $engine;

            impl IntEngine for $engine {
                #[inline(always)]
                fn dot(w: &[i8], x: &[i16]) -> i32 {
                    // SAFETY: this engine is only used inside the wrapper of `rows_i8` with
                    // `$feat`, called only for an `Isa` made after detection found them.
                    let ([acc], done) = unsafe { $dotn::<1, 0>([w], x) };
                    // SAFETY: as above.
                    let sum = unsafe { $sum(acc) };
                    sum + PortableInt::dot(&w[done..], &x[done..])
                }

                #[inline(always)]
                fn dot8(w: [&[i8]; 8], x: &[i16]) -> [i32; 8] {
                    // SAFETY: as for `dot`.
                    let (acc, done) = unsafe { $dotn::<8, 0>(w, x) };
                    // SAFETY: as for `dot`.
                    let sums = unsafe { $sums8(acc) };
                    std::array::from_fn(|r| sums[r] + PortableInt::dot(&w[r][done..], &x[done..]))
                }

                #[inline(always)]
                fn dot8_far(w: [&[i8]; 8], x: &[i16]) -> [i32; 8] {
                    // SAFETY: as for `dot`.
                    let (acc, done) = unsafe { $dotn::<8, STREAM_AHEAD>(w, x) };
                    // SAFETY: as for `dot`.
                    let sums = unsafe { $sums8(acc) };
                    std::array::from_fn(|r| sums[r] + PortableInt::dot(&w[r][done..], &x[done..]))
                }

                #[inline(always)]
                fn dot8_far_block(w: &[i8], x: &[i16], g: FarGroups, sums: &mut [i32]) {
                    /// The loop over the groups inside the target features.
                    #[inline]
                    #[target_feature(enable = $feat)]
                    fn block(w: &[i8], x: &[i16], g: FarGroups, sums: &mut [i32]) {
                        for (o, rows) in g.rows(w, x.len()) {
                            let (acc, done) = $dotn::<8, STREAM_AHEAD>(rows, x);
                            let acc = $sums8(acc);
                            for (r, (row, acc)) in rows.iter().zip(acc).enumerate() {
                                sums[g.at(o, r)] = acc + PortableInt::dot(&row[done..], &x[done..]);
                            }
                        }
                    }
                    // SAFETY: as for `dot`.
                    unsafe { block(w, x, g, sums) }
                }
            }
        };
    }

    /// The sums `S_r` of a panel from 32 lanes holding each row's two half sums side by side
    /// (row `r` in lanes `2r` and `2r + 1`).
    #[inline(always)]
    fn halves(lanes: [i32; 2 * QUAD_PANEL]) -> [i32; QUAD_PANEL] {
        // Two halves of an exact sum within `i32`: each is a partial sum of it, so neither
        // leaves `i32` and neither does their sum.
        std::array::from_fn(|r| lanes[2 * r] + lanes[2 * r + 1])
    }

    /// The quad-panel engine on AVX2: a quad of four rows widened to 16 bits in one vector,
    /// `vpmaddwd` against the quad's four inputs (each row's two half sums in two lanes).
    pub(super) struct Avx2Quads;

    impl QuadEngine for Avx2Quads {
        #[inline(always)]
        fn panel(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
            // SAFETY: only used inside the wrapper of `quads_i8` with avx2, called only for an
            // `Isa` made after detection found it.
            unsafe { panel_avx2(q, words) }
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    fn panel_avx2(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
        let mut acc = [_mm256_setzero_si256(); 4];
        for (quad, &w) in q.as_chunks::<QUAD_BYTES>().0.iter().zip(words) {
            let x = _mm256_set1_epi64x(w as i64);
            for (k, a) in acc.iter_mut().enumerate() {
                // SAFETY: bytes `16k … 16k + 15` of the 64-byte quad, read unaligned.
                let v = unsafe { _mm_loadu_si128(quad.as_ptr().add(16 * k).cast::<__m128i>()) };
                *a = _mm256_add_epi32(*a, _mm256_madd_epi16(_mm256_cvtepi8_epi16(v), x));
            }
        }
        let mut lanes = [0i32; 2 * QUAD_PANEL];
        for (k, a) in acc.iter().enumerate() {
            // SAFETY: lanes `8k … 8k + 7` of `lanes`, written unaligned.
            unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().add(8 * k).cast::<__m256i>(), *a) };
        }
        halves(lanes)
    }

    /// The quad-panel engine on AVX-512 (avx512bw): a quad of eight rows widened to 16 bits in
    /// one vector, as on AVX2.
    pub(super) struct Avx512Quads;

    impl QuadEngine for Avx512Quads {
        #[inline(always)]
        fn panel(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
            // SAFETY: only used inside the wrapper of `quads_i8` with avx512f and avx512bw,
            // called only for an `Isa` made after detection found them.
            unsafe { panel_avx512(q, words) }
        }
    }

    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2")]
    fn panel_avx512(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
        let mut acc = [_mm512_setzero_si512(); 2];
        for (quad, &w) in q.as_chunks::<QUAD_BYTES>().0.iter().zip(words) {
            let x = _mm512_set1_epi64(w as i64);
            for (k, a) in acc.iter_mut().enumerate() {
                // SAFETY: bytes `32k … 32k + 31` of the 64-byte quad, read unaligned.
                let v = unsafe { _mm256_loadu_si256(quad.as_ptr().add(32 * k).cast::<__m256i>()) };
                *a = _mm512_add_epi32(*a, _mm512_madd_epi16(_mm512_cvtepi8_epi16(v), x));
            }
        }
        let mut lanes = [0i32; 2 * QUAD_PANEL];
        for (k, a) in acc.iter().enumerate() {
            // SAFETY: lanes `16k … 16k + 15` of `lanes`, written unaligned.
            unsafe { _mm512_storeu_si512(lanes.as_mut_ptr().add(16 * k).cast(), *a) };
        }
        halves(lanes)
    }

    /// The quad-panel engine with AVX-512 VNNI: `vpdpbusd` sums four products of unsigned by
    /// signed bytes into each 32-bit lane, and a quad's 64 bytes are its 16 rows' four weights,
    /// so one instruction sums a quad for all 16 rows without widening them. The 16-bit inputs
    /// go in as bytes: `x + 2¹⁵ = 256 h + l` with `h` and `l` in 0…255 ([`QuadEngine::word`]:
    /// the four `l` in the low half, the four `h` in the high half), so that
    /// `S = 256 · (Σ q h − 2⁷ · Σ q) + Σ q l` with the row sums `Σ q` that follow the panel's
    /// quads. `vpdpbusd` does not saturate and vector adds and shifts wrap, so every step is
    /// exact modulo 2³², and `S` lies within `i32` (the module contract of `int8.rs`): the same
    /// sums as every engine.
    pub(super) struct Avx512VnniQuads;

    impl QuadEngine for Avx512VnniQuads {
        #[inline(always)]
        fn word(x: &[i16; QUAD]) -> u64 {
            let (mut lo, mut hi) = (0u64, 0u64);
            for (c, &v) in x.iter().enumerate() {
                let u = u64::from((v as u16) ^ 0x8000);
                lo |= (u & 0xff) << (8 * c);
                hi |= (u >> 8) << (8 * c);
            }
            lo | hi << 32
        }

        #[inline(always)]
        fn panel(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
            // SAFETY: only used inside `quads_vnni`, called only where `has_vnni` found
            // avx512vnni besides the AVX-512 features of `has_avx512`.
            unsafe { panel_vnni(q, words) }
        }
    }

    /// `quad(k, quad, word)` for each quad and its input word, `k` counting `0 … N − 1` over
    /// each whole group of `N` quads and from 0 again over the rest: the VNNI engines keep `N`
    /// independent sums.
    #[inline(always)]
    fn each_quad<const N: usize>(
        quads: &[[i8; QUAD_BYTES]],
        words: &[u64],
        mut quad: impl FnMut(usize, &[i8; QUAD_BYTES], &u64),
    ) {
        let (whole, rest) = quads.as_chunks::<N>();
        for (qs, ws) in whole.iter().zip(words.as_chunks::<N>().0) {
            for k in 0..N {
                quad(k, &qs[k], &ws[k]);
            }
        }
        for (k, (q, w)) in rest.iter().zip(&words[whole.len() * N..]).enumerate() {
            quad(k, q, w);
        }
    }

    /// Quads summed at once: independent sums for `vpdpbusd`'s latency (5 cycles at one per
    /// cycle on Sapphire Rapids).
    const VNNI_QUADS: usize = 4;

    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vnni,avx2")]
    fn panel_vnni(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
        let (quads, sums) = q.as_chunks::<QUAD_BYTES>().0.split_at(words.len());
        let mut hi = [_mm512_setzero_si512(); VNNI_QUADS];
        let mut lo = [_mm512_setzero_si512(); VNNI_QUADS];
        let quad = |k: usize, quad: &[i8; QUAD_BYTES], w: &u64| {
            // SAFETY: the 64 bytes of the quad, read unaligned.
            let v = unsafe { _mm512_loadu_si512(quad.as_ptr().cast()) };
            // The word's halves read from memory (a broadcast from a general register costs
            // a transfer to the vector unit each): `lo` at its first four bytes, `hi` at the next.
            let halves = std::ptr::from_ref(w).cast::<[u8; 4]>();
            // SAFETY: the word's two halves, each read as 4 bytes.
            let (l, h) = unsafe { (halves.read(), halves.add(1).read()) };
            let (l, h) = (i32::from_le_bytes(l), i32::from_le_bytes(h));
            hi[k] = _mm512_dpbusd_epi32(hi[k], _mm512_set1_epi32(h), v);
            lo[k] = _mm512_dpbusd_epi32(lo[k], _mm512_set1_epi32(l), v);
        };
        each_quad::<VNNI_QUADS>(quads, words, quad);
        let hi = _mm512_add_epi32(
            _mm512_add_epi32(hi[0], hi[1]),
            _mm512_add_epi32(hi[2], hi[3]),
        );
        let lo = _mm512_add_epi32(
            _mm512_add_epi32(lo[0], lo[1]),
            _mm512_add_epi32(lo[2], lo[3]),
        );
        // SAFETY: the row sums' 64 bytes after the quads (`to_quad_panels`), read unaligned.
        let s = unsafe { _mm512_loadu_si512(sums[0].as_ptr().cast()) };
        let h = _mm512_sub_epi32(hi, _mm512_slli_epi32::<7>(s));
        let total = _mm512_add_epi32(_mm512_slli_epi32::<8>(h), lo);
        let mut out = [0i32; QUAD_PANEL];
        // SAFETY: the 16 lanes of `out`, written unaligned.
        unsafe { _mm512_storeu_si512(out.as_mut_ptr().cast(), total) };
        out
    }

    /// The quad-panel engine with AVX-VNNI: [`Avx512VnniQuads`]'s sums (the same input bytes
    /// and row sums) with 256-bit `vpdpbusd`, each quad in two halves of eight rows.
    pub(super) struct AvxVnniQuads;

    impl QuadEngine for AvxVnniQuads {
        #[inline(always)]
        fn word(x: &[i16; QUAD]) -> u64 {
            Avx512VnniQuads::word(x)
        }

        #[inline(always)]
        fn panel(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
            // SAFETY: only used inside `quads_avx_vnni`, called only where `has_avx_vnni`
            // found avxvnni besides the AVX2 features of `has_avx2`.
            unsafe { panel_avx_vnni(q, words) }
        }
    }

    /// Quads summed at once by the AVX-VNNI engine: with each quad's two halves and two input
    /// bytes, eight independent sums.
    const AVX_VNNI_QUADS: usize = 2;

    #[inline]
    #[target_feature(enable = "avx2,avxvnni")]
    fn panel_avx_vnni(q: &[i8], words: &[u64]) -> [i32; QUAD_PANEL] {
        let (quads, sums) = q.as_chunks::<QUAD_BYTES>().0.split_at(words.len());
        // `[k][half]`: quad `k` of a step, rows 0–7 or 8–15.
        let mut hi = [[_mm256_setzero_si256(); 2]; AVX_VNNI_QUADS];
        let mut lo = [[_mm256_setzero_si256(); 2]; AVX_VNNI_QUADS];
        let quad = |k: usize, quad: &[i8; QUAD_BYTES], w: &u64| {
            let halves = std::ptr::from_ref(w).cast::<[u8; 4]>();
            // SAFETY: the word's two halves, each read as 4 bytes.
            let (l, h) = unsafe { (halves.read(), halves.add(1).read()) };
            let (l, h) = (
                _mm256_set1_epi32(i32::from_le_bytes(l)),
                _mm256_set1_epi32(i32::from_le_bytes(h)),
            );
            for half in 0..2 {
                // SAFETY: bytes `32·half … 32·half + 31` of the 64-byte quad, read unaligned.
                let v =
                    unsafe { _mm256_loadu_si256(quad.as_ptr().add(32 * half).cast::<__m256i>()) };
                hi[k][half] = _mm256_dpbusd_avx_epi32(hi[k][half], h, v);
                lo[k][half] = _mm256_dpbusd_avx_epi32(lo[k][half], l, v);
            }
        };
        each_quad::<AVX_VNNI_QUADS>(quads, words, quad);
        let mut out = [0i32; QUAD_PANEL];
        for half in 0..2 {
            let hi = _mm256_add_epi32(hi[0][half], hi[1][half]);
            let lo = _mm256_add_epi32(lo[0][half], lo[1][half]);
            // SAFETY: rows `8·half … 8·half + 7` of the row sums' 64 bytes after the quads
            // (`to_quad_panels`), read unaligned.
            let s = unsafe { _mm256_loadu_si256(sums[0].as_ptr().add(32 * half).cast()) };
            let h = _mm256_sub_epi32(hi, _mm256_slli_epi32::<7>(s));
            let total = _mm256_add_epi32(_mm256_slli_epi32::<8>(h), lo);
            // SAFETY: lanes `8·half … 8·half + 7` of `out`, written unaligned.
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().add(8 * half).cast(), total) };
        }
        out
    }

    /// A build's two quad-panel functions: `$vnni_fn` runs [`int8::quads_int`] with the VNNI
    /// engine `$vnni` inside the features `$feat`, and `$name` calls it where `$has` allows,
    /// else runs the widened engine `$widened`.
    macro_rules! quads_with_vnni {
        ($(#[$doc:meta])* $name:ident, $vnni_fn:ident, $feat:literal, $vnni:ty, $widened:ty, $has:path) => {
            /// [`int8::quads_int`] with this build's VNNI engine.
            #[target_feature(enable = $feat)]
            pub(super) fn $vnni_fn(
                w: &[i8],
                cols: usize,
                xs: &[f32],
                batch: usize,
                scales: Option<&[f32]>,
                bias: Option<&[f32]>,
                ys_t: &mut [f32],
            ) {
                int8::quads_int::<$vnni>(w, cols, xs, batch, scales, bias, ys_t);
            }

            $(#[$doc])*
            #[inline(always)]
            pub(super) fn $name(
                w: &[i8],
                cols: usize,
                xs: &[f32],
                batch: usize,
                scales: Option<&[f32]>,
                bias: Option<&[f32]>,
                ys_t: &mut [f32],
            ) {
                if $has() {
                    // SAFETY: `$has` found `$vnni_fn`'s features on this CPU.
                    unsafe { $vnni_fn(w, cols, xs, batch, scales, bias, ys_t) }
                } else {
                    int8::quads_int::<$widened>(w, cols, xs, batch, scales, bias, ys_t);
                }
            }
        };
    }

    quads_with_vnni!(
        /// The AVX2 build of [`int8::quads_int`]: with AVX-VNNI where [`super::has_avx_vnni`]
        /// allows, else with the weights widened to 16 bits ([`Avx2Quads`]).
        quads_avx2,
        quads_avx_vnni,
        "avx2,avxvnni,fma,f16c",
        AvxVnniQuads,
        Avx2Quads,
        super::has_avx_vnni
    );

    quads_with_vnni!(
        /// The AVX-512 build of [`int8::quads_int`]: with VNNI where [`super::has_vnni`]
        /// allows, else with the weights widened to 16 bits ([`Avx512Quads`]).
        quads_avx512,
        quads_vnni,
        "avx512f,avx512bw,avx512vl,avx512vnni,avx2,fma,f16c",
        Avx512VnniQuads,
        Avx512Quads,
        super::has_vnni
    );

    int_kernels!(
        "avx2",
        Avx2Int,
        dotn_avx2,
        16,
        __m256i,
        __m128i,
        _mm256_loadu_si256,
        _mm_loadu_si128,
        _mm256_setzero_si256,
        _mm256_cvtepi8_epi16,
        madd_add_avx2,
        overlap_tail_avx2,
        sum8,
        sums8
    );
    int_kernels!(
        "avx512f,avx512bw,avx512vl,avx2",
        Avx512Int,
        dotn_avx512,
        32,
        __m512i,
        __m256i,
        _mm512_loadu_si512,
        _mm256_loadu_si256,
        _mm512_setzero_si512,
        _mm512_cvtepi8_epi16,
        madd_add_avx512,
        masked_tail,
        _mm512_reduce_add_epi32,
        sums8_512
    );
    int_kernels!(
        "avx512f,avx512bw,avx512vl,avx512vnni,avx2",
        Avx512VnniInt,
        dotn_vnni,
        32,
        __m512i,
        __m256i,
        _mm512_loadu_si512,
        _mm256_loadu_si256,
        _mm512_setzero_si512,
        _mm512_cvtepi8_epi16,
        madd_add_vnni,
        masked_tail,
        _mm512_reduce_add_epi32,
        sums8_512
    );

    /// [`int8::rows_int`] with the VNNI engine.
    #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512vnni,avx2,fma,f16c")]
    fn rows_vnni(
        w: &[i8],
        cols: usize,
        xs: &[f32],
        batch: usize,
        scales: Option<&[f32]>,
        bias: Option<&[f32]>,
        ys_t: &mut [f32],
    ) {
        int8::rows_int::<Avx512VnniInt>(w, cols, xs, batch, scales, bias, ys_t);
    }

    /// The AVX-512 build of [`int8::rows_int`]: each 16-bit product pair summed by VNNI's
    /// `vpdpwssd` where [`super::has_vnni`] allows, else by `vpmaddwd` and an add
    /// ([`Avx512Int`]).
    #[inline(always)]
    pub(super) fn rows_avx512(
        w: &[i8],
        cols: usize,
        xs: &[f32],
        batch: usize,
        scales: Option<&[f32]>,
        bias: Option<&[f32]>,
        ys_t: &mut [f32],
    ) {
        if super::has_vnni() {
            // SAFETY: `has_vnni` found `rows_vnni`'s features on this CPU.
            unsafe { rows_vnni(w, cols, xs, batch, scales, bias, ys_t) }
        } else {
            int8::rows_int::<Avx512Int>(w, cols, xs, batch, scales, bias, ys_t);
        }
    }
}

// The integer kernels (`int8.rs`); reached through `rows_i8` only. Their 512-bit engine needs
// avx512bw, which `has_avx512` requires and the AVX-512 wrappers enable.
dispatched!(
    /// int8 rows with a per-row scale by integer products (`int8.rs`).
    rows_i8_int,
    i8,
    rows_int::<PortableInt>,
    rows_int::<int::Avx2Int>,
    int::rows_avx512
);

dispatched!(
    /// int8 rows in quad panels with a per-row scale (`int8.rs`, [`int8::quads_int`]).
    quads_i8,
    i8,
    int8::quads_int::<int8::PortableQuads>,
    int::quads_avx2,
    int::quads_avx512
);

/// int8 rows with a per-row scale: the integer kernels of `int8.rs` for rows of more than 16
/// and at most 2,048 columns, the lane kernels ([`rows_i8_lanes`]) otherwise.
#[allow(clippy::too_many_arguments)]
pub(crate) fn rows_i8(
    isa: Isa,
    w: &[i8],
    cols: usize,
    xs: &[f32],
    batch: usize,
    scales: Option<&[f32]>,
    bias: Option<&[f32]>,
    ys_t: &mut [f32],
) {
    let kernel = if int8::applies(cols) {
        rows_i8_int
    } else {
        rows_i8_lanes
    };
    kernel(isa, w, cols, xs, batch, scales, bias, ys_t);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::rows::SPREAD_ROWS;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// An integer kernel: `(w, cols, xs, batch, scales, bias, ys_t)`.
    type IntKernel = fn(&[i8], usize, &[f32], usize, Option<&[f32]>, Option<&[f32]>, &mut [f32]);

    /// A wrapper `$name` that runs `int8::$kernel::<$engine>` inside the features `$feat`.
    #[cfg(target_arch = "x86_64")]
    macro_rules! engine_wrapper {
        ($name:ident, $feat:literal, $kernel:ident, $engine:ty) => {
            #[target_feature(enable = $feat)]
            fn $name(
                w: &[i8],
                cols: usize,
                xs: &[f32],
                batch: usize,
                scales: Option<&[f32]>,
                bias: Option<&[f32]>,
                ys_t: &mut [f32],
            ) {
                int8::$kernel::<$engine>(w, cols, xs, batch, scales, bias, ys_t);
            }
        };
    }

    /// Push kernel `$name`, calling the `#[target_feature]` function `$f`, where `$has` found
    /// its features on this CPU.
    #[cfg(target_arch = "x86_64")]
    macro_rules! push_where {
        ($kernels:ident, $has:expr, $name:literal, $f:path) => {
            if $has {
                // SAFETY: `$has` found `$f`'s features on this CPU.
                $kernels.push(($name, |w, c, x, b, s, bi, y| unsafe {
                    $f(w, c, x, b, s, bi, y)
                }));
            }
        };
    }

    /// Random `rows × cols` int8 weights with row 0 all +127 and row 1 of alternating sign,
    /// and a scale and a bias per row: with [`extreme_inputs`], the integer contract's
    /// extremes.
    fn extreme_rows(
        rng: &mut ChaCha8Rng,
        rows: usize,
        cols: usize,
    ) -> (Vec<i8>, Vec<f32>, Vec<f32>) {
        let mut q: Vec<i8> = (0..rows * cols)
            .map(|_| rng.random_range(-127..=127))
            .collect();
        for (c, v) in q[..2 * cols].iter_mut().enumerate() {
            *v = if c < cols || c % 2 == 0 { 127 } else { -127 };
        }
        let scales = (0..rows).map(|_| rng.random_range(0.001..0.01)).collect();
        let bias = (0..rows).map(|_| rng.random_range(-1.0..1.0)).collect();
        (q, scales, bias)
    }

    /// `batch` random inputs of `cols`, the first alternating ±2 (quantised to ±L).
    fn extreme_inputs(rng: &mut ChaCha8Rng, batch: usize, cols: usize) -> Vec<f32> {
        let mut xs: Vec<f32> = (0..batch * cols)
            .map(|_| rng.random_range(-2.0..2.0))
            .collect();
        for (c, x) in xs[..cols].iter_mut().enumerate() {
            *x = if c % 2 == 0 { 2.0 } else { -2.0 };
        }
        xs
    }

    /// Each kernel's outputs as bits, asserted equal to the first's (`what` names the case).
    fn same_bits(
        kernels: &[(&str, IntKernel)],
        weights: &[(&[i8], &str)],
        (cols, xs, batch): (usize, &[f32], usize),
        (scales, bias): (&[f32], &[f32]),
        what: &str,
    ) {
        let mut want = None;
        for (name, kernel) in kernels {
            for (w, at) in weights {
                let mut ys = vec![f32::NAN; scales.len() * batch];
                kernel(w, cols, xs, batch, Some(scales), Some(bias), &mut ys);
                let bits: Vec<u32> = ys.iter().map(|v| v.to_bits()).collect();
                let want = want.get_or_insert(bits.clone());
                assert_eq!(&bits, want, "{what} batch {batch} {name} {at}");
            }
        }
    }

    #[test]
    fn every_quad_engine_gives_the_same_bits() {
        // The AVX2 and AVX-512 builds each pick one quad engine per CPU (VNNI where present),
        // so the matrix tests, which go through `Isa`, meet only those: here the portable,
        // widened AVX2, AVX-VNNI, widened AVX-512 and VNNI engines (those this CPU has) each
        // run the same products, from aligned and unaligned panels, with rows of ±127 against
        // inputs at ±L (the contract's extremes: VNNI's wrapping steps leave `i32` there and
        // must come back), batch 1 and 3.
        #[allow(unused_mut)]
        let mut kernels: Vec<(&str, IntKernel)> = vec![(
            "portable",
            int8::quads_int::<int8::PortableQuads> as IntKernel,
        )];
        #[cfg(target_arch = "x86_64")]
        {
            engine_wrapper!(
                widened,
                "avx512f,avx512bw,avx512vl,avx2,fma,f16c",
                quads_int,
                int::Avx512Quads
            );
            engine_wrapper!(widened2, "avx2,fma,f16c", quads_int, int::Avx2Quads);
            push_where!(kernels, has_avx512(), "avx512", widened);
            push_where!(kernels, has_avx2(), "avx2", widened2);
            push_where!(
                kernels,
                has_avx2() && is_x86_feature_detected!("avxvnni"),
                "avx-vnni",
                int::quads_avx_vnni
            );
            push_where!(
                kernels,
                has_avx512() && is_x86_feature_detected!("avx512vnni"),
                "vnni",
                int::quads_vnni
            );
        }
        let mut rng = ChaCha8Rng::seed_from_u64(41);
        for (rows, cols) in [(16, 17), (33, 88), (48, 64), (20, 256), (17, 511)] {
            let (q, scales, bias) = extreme_rows(&mut rng, rows, cols);
            let panels = int8::to_quad_panels(&q, rows, cols);
            let aligned = LineAligned::from(panels.as_slice());
            let mut shifted = vec![0i8; panels.len() + 16];
            shifted[16..].copy_from_slice(&panels);
            let weights = [(&aligned[..], "aligned"), (&shifted[16..], "shifted")];
            for batch in [1, 3] {
                let xs = extreme_inputs(&mut rng, batch, cols);
                let what = format!("{rows} × {cols}");
                same_bits(
                    &kernels,
                    &weights,
                    (cols, &xs, batch),
                    (&scales, &bias),
                    &what,
                );
            }
        }
    }

    #[test]
    fn every_integer_row_engine_gives_the_same_bits() {
        // As for the quad engines: `Isa` meets one row engine per build and CPU (VNNI's
        // `vpdpwssd` where present), so here the portable, AVX2, widened AVX-512 and VNNI
        // engines (those this CPU has) run the same products: short rows (eight neighbours)
        // and long ones (eight streams an eighth of the rows apart), rows shorter than a
        // vector, batch 1 and 3 (inputs that share a pass over the weights), with rows of
        // ±127 against inputs at ±L.
        #[allow(unused_mut)]
        let mut kernels: Vec<(&str, IntKernel)> =
            vec![("portable", int8::rows_int::<int8::PortableInt> as IntKernel)];
        #[cfg(target_arch = "x86_64")]
        {
            engine_wrapper!(
                widened,
                "avx512f,avx512bw,avx512vl,avx2,fma,f16c",
                rows_int,
                int::Avx512Int
            );
            engine_wrapper!(avx2, "avx2,fma,f16c", rows_int, int::Avx2Int);
            engine_wrapper!(
                vnni,
                "avx512f,avx512bw,avx512vl,avx512vnni,avx2,fma,f16c",
                rows_int,
                int::Avx512VnniInt
            );
            push_where!(kernels, has_avx512(), "avx512", widened);
            push_where!(kernels, has_avx2(), "avx2", avx2);
            push_where!(
                kernels,
                has_avx512() && is_x86_feature_detected!("avx512vnni"),
                "vnni",
                vnni
            );
        }
        let mut rng = ChaCha8Rng::seed_from_u64(43);
        for (rows, cols) in [
            (8 * 5 + 3, 70),
            (8 * 3 + 5, 600),
            (19, 1500),
            (11, 13),
            (9, 16),
        ] {
            let (q, scales, bias) = extreme_rows(&mut rng, rows, cols);
            for batch in [1, 3] {
                let xs = extreme_inputs(&mut rng, batch, cols);
                let what = format!("{rows} × {cols}");
                same_bits(
                    &kernels,
                    &[(&q, "rows")],
                    (cols, &xs, batch),
                    (&scales, &bias),
                    &what,
                );
            }
        }
    }

    #[test]
    fn the_lane_masks_agree_with_a_plain_comparison() {
        // Random lanes with ties, zeros of both signs and infinities, against positive finite
        // thresholds among them: the mask of every level this CPU runs (on x86-64 SSE's and
        // AVX2's `movemask`, AVX-512's mask register; elsewhere the plain mask).
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let special = [0.0, -0.0, f32::INFINITY, f32::MAX, 1e-30, 0.25];
        // Every level this CPU runs (SSE's, level 0, first).
        #[cfg(target_arch = "x86_64")]
        let masks: Vec<LaneMask> = Isa::available()
            .into_iter()
            .map(|isa| LaneMask {
                level: match isa.0 {
                    Level::Portable => 0,
                    Level::Avx2 => 1,
                    Level::Avx512 => 2,
                },
            })
            .collect();
        #[cfg(not(target_arch = "x86_64"))]
        let masks = [LaneMask::default(), LaneMask::detect()];
        for _ in 0..2_000 {
            let v: [f32; 16] = std::array::from_fn(|_| match rng.random_range(0..4) {
                0 => special[rng.random_range(0..special.len())],
                _ => rng.random_range(-1.0..1.0f32).powi(2),
            });
            // A positive finite threshold (the plain mask reads `∞ − ∞` as beyond, and
            // `−0 − 0` too).
            let t = Some(v[rng.random_range(0..16)])
                .filter(|&t| t > 0.0 && rng.random_bool(0.5))
                .unwrap_or(special[rng.random_range(3..special.len())])
                .min(f32::MAX);
            let want = (0..16).fold(0u32, |m, l| m | (u32::from(v[l] <= t) << l));
            for &mask in &masks {
                assert_eq!(mask.at_most(&v, t), want, "{mask:?} {v:?} {t}");
            }
        }
    }

    #[test]
    fn every_isa_matches_the_portable_kernels_bitwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let isas = Isa::available();
        eprintln!(
            "instruction sets: {:?} (best: {})",
            isas.iter().map(|i| i.name()).collect::<Vec<_>>(),
            Isa::best().name()
        );
        for &(n_rows, cols, batch) in &[
            (5, 1, 1),
            (9, 31, 1),
            (11, 64, 1),
            (13, 1037, 1),
            (17, 100, 3),
            (33, 1037, 9),
            (6, 600, 2),
            // The shipped model's GRU input (88) and the paper's hidden size (1,500).
            (7, 88, 1),
            (9, 1500, 1),
            // Two whole eight-row blocks (`spread_block` rows each) and a shorter one, a
            // partial last chunk, and rows left over for the four-row groups and `dot`.
            (2 * SPREAD_ROWS + 27, 520, 1),
        ] {
            let w: Vec<f32> = (0..n_rows * cols)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let wh: Vec<F16Bits> = w
                .iter()
                .map(|&v| F16Bits(half::f16::from_f32(v).to_bits()))
                .collect();
            let wq: Vec<i8> = (0..n_rows * cols)
                .map(|_| rng.random_range(-127..=127))
                .collect();
            let scales: Vec<f32> = (0..n_rows).map(|_| rng.random_range(0.001..0.1)).collect();
            let bias: Vec<f32> = (0..n_rows).map(|_| rng.random_range(-1.0..1.0)).collect();
            let xs: Vec<f32> = (0..batch * cols)
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            let run = |isa: Isa| {
                let mut a = vec![0.0; n_rows * batch];
                let mut b = vec![0.0; n_rows * batch];
                let mut c = vec![0.0; n_rows * batch];
                rows_f32(isa, &w, cols, &xs, batch, None, Some(&bias), &mut a);
                rows_f16(isa, &wh, cols, &xs, batch, None, None, &mut b);
                rows_i8(
                    isa,
                    &wq,
                    cols,
                    &xs,
                    batch,
                    Some(&scales),
                    Some(&bias),
                    &mut c,
                );
                [a, b, c]
            };
            let reference = run(Isa::portable());
            for &isa in &isas {
                let got = run(isa);
                for (r, g) in reference.iter().zip(&got) {
                    let r: Vec<u32> = r.iter().map(|v| v.to_bits()).collect();
                    let g: Vec<u32> = g.iter().map(|v| v.to_bits()).collect();
                    assert_eq!(r, g, "{} differs from portable", isa.name());
                }
            }
        }
    }
}
