//! A frame allocates nothing: a counting global allocator for this test binary counts the
//! allocations made by the current thread while frames run.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use sartor_runtime::{
    AnimatorOptions, CollisionOptions, CollisionQuery, GarmentAnimator, GarmentCrowd,
    NetworkOptions, OutputKind, Precision, StrainLimit,
};

use crate::scene::{clip, model, rig};

thread_local! {
    /// Allocations by this thread (const-initialised, no destructor: using it never allocates).
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: a thread being torn down has no thread-locals left; do not count there.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
}

/// The system allocator, counting allocations per thread.
struct Counting;

// SAFETY: every method forwards its arguments unchanged to the system allocator, which upholds
// the `GlobalAlloc` contract; the counting touches only a thread-local `Cell`.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwarded unchanged (the caller's guarantees hold for `System` too).
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: as above; `ptr` came from this allocator, i.e. from `System`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_during(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

#[test]
fn frames_allocate_nothing() {
    let poses = clip("walk_normal", 12, 2);
    let m = model(40, OutputKind::Dense, 32);
    let pca = model(41, OutputKind::Pca(6), 32);
    let collision = |query| {
        Some(CollisionOptions {
            query,
            ..CollisionOptions::default()
        })
    };
    let cases = [
        (
            &m,
            Precision::F32,
            collision(CollisionQuery::EXACT_BVH),
            true,
        ),
        (
            &m,
            Precision::Int8,
            collision(CollisionQuery::DEFAULT_CANDIDATES),
            true,
        ),
        (&pca, Precision::F16, None, true),
        (
            &m,
            Precision::F32,
            collision(CollisionQuery::GuardedCandidates {
                radius_m: 0.02,
                max_per_vertex: 8,
            }),
            true,
        ),
        (
            &m,
            Precision::F32,
            collision(CollisionQuery::BvhBand {
                band_m: 0.005,
                refresh_every: 4,
            }),
            true,
        ),
        (
            &m,
            Precision::F32,
            collision(CollisionQuery::DEFAULT_CANDIDATES),
            false,
        ),
    ];
    for (model, precision, collision, wrinkles) in cases {
        let options = AnimatorOptions {
            wrinkles: if wrinkles {
                sartor_runtime::WrinkleMode::Gru
            } else {
                sartor_runtime::WrinkleMode::None
            },
            collision,
            // Every edge longer than its template length projected: the strain limit's work
            // lists at their fullest.
            strain_limit: Some(StrainLimit {
                max_stretch: 1.0,
                rounds: 4,
                ..StrainLimit::default()
            }),
            ..AnimatorOptions::default()
        };
        let network = NetworkOptions {
            precision,
            output_rank: None,
        };
        let rig = rig(model, network, options);
        let mut avatar = GarmentAnimator::new(rig.clone()).expect("avatar");
        avatar.set_shape(&[0.5; 10]).expect("finite");
        let mut crowd = GarmentCrowd::new(rig, 3).expect("crowd");
        let mut out = vec![nalgebra::Vector3::zeros(); avatar.vertices().len()];
        // Warm up (lazily initialised statics such as the instruction-set choice).
        avatar.frame(&poses[0]).expect("frame");
        let trios: Vec<Vec<sartor_core::Pose>> = poses.iter().map(|p| vec![p.clone(); 3]).collect();
        crowd.frame(&trios[0]).expect("frame");
        let n = allocations_during(|| {
            for (pose, trio) in poses.iter().zip(&trios).skip(1) {
                avatar.frame_into(pose, &mut out).expect("frame");
                crowd.frame(trio).expect("frame");
            }
            avatar.reset();
            avatar.frame(&poses[3]).expect("frame");
        });
        assert_eq!(
            n, 0,
            "{precision:?} wrinkles {wrinkles} collision {collision:?}: {n} allocations"
        );
        assert!(avatar.last_frame_strained() > 0, "the strain limit ran");
        // The counter counts (the test can fail).
        assert!(allocations_during(|| avatar.set_shape(&[0.1; 10]).expect("finite")) > 0);
    }
}

/// A network step whose products split across a two-thread pool (run inside
/// `sartor_core::awake::with_workers_awake`, the other worker polling) allocates nothing on
/// the thread that runs it: the pollers go out by nested joins, not heap-allocated spawns.
#[test]
fn a_split_step_on_the_pool_allocates_nothing() {
    use sartor_runtime::{GarmentNetwork, Parallelism};

    use crate::common::{random, random_model, rng, sizes};

    let mut big = sizes(OutputKind::Dense, false);
    // 3·160 × 160 and 120·3 × 160: products of more than 2¹⁶ multiply–adds, which split.
    big.gru_hidden = 160;
    big.n_vertices = 120;
    let net = GarmentNetwork::new(random_model(29, big), Precision::F32).expect("valid");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    let mut r = rng(30);
    let xs: Vec<Vec<f32>> = (0..6)
        .map(|_| random(&mut r, net.input_size(), 1.5))
        .collect();
    let (n, on_the_pool) = pool.install(|| {
        let mut ws = net.workspace(1);
        let mut state = net.initial_state();
        let mut out = vec![0.0; net.output_size()];
        net.wrinkle_step(&xs[0], &mut state, &mut out, &mut ws, Parallelism::Rayon)
            .expect("finite");
        let n = allocations_during(|| {
            for x in &xs[1..] {
                net.wrinkle_step(x, &mut state, &mut out, &mut ws, Parallelism::Rayon)
                    .expect("finite");
            }
        });
        (n, rayon::current_thread_index().is_some())
    });
    assert!(on_the_pool);
    assert_eq!(n, 0, "{n} allocations");
}

/// A frame under `Parallelism::Rayon` on a two-thread pool (the whole frame inside
/// `sartor_core::awake::with_workers_awake`, the network's call nested in it) allocates
/// nothing on the thread that runs it: the other worker's poller goes out by a `rayon::join`.
#[test]
fn a_frame_on_the_pool_allocates_nothing() {
    use sartor_runtime::Parallelism;

    let poses = clip("walk_normal", 8, 2);
    let m = model(42, OutputKind::Dense, 32);
    let options = AnimatorOptions {
        parallelism: Parallelism::Rayon,
        collision: Some(CollisionOptions {
            query: CollisionQuery::DEFAULT_CANDIDATES,
            ..CollisionOptions::default()
        }),
        ..AnimatorOptions::default()
    };
    let rig = rig(&m, NetworkOptions::default(), options);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    let (n, on_the_pool) = pool.install(|| {
        let mut avatar = GarmentAnimator::new(rig).expect("avatar");
        avatar.set_shape(&[0.5; 10]).expect("finite");
        avatar.frame(&poses[0]).expect("frame");
        let n = allocations_during(|| {
            for pose in &poses[1..] {
                avatar.frame(pose).expect("frame");
            }
        });
        (n, rayon::current_thread_index().is_some())
    });
    assert!(on_the_pool);
    assert_eq!(n, 0, "{n} allocations");
}
