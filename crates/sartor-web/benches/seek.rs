//! The try-on page's jump, natively: `TryOn::seek` to a frame of a real clip (CMU 02_02, a
//! walk whose every frame needs the arms held out) with the shipped model as the page loads
//! it (the post-process with the triangles, the arms held as the model's experiment held
//! them), on the nominal body and on a heavy 1.90 m one beyond the training shapes (where the
//! post-process also seeks the faces buried inside another body part). The seeks alternate
//! between two frames, so each runs the GRU's warm-up frames and the frame shown anew; the
//! arms' poses are kept from the first seek to each frame (as the page keeps them while the
//! shape and the clip stay), so this is the garment's part of a jump, not the arms' (see the
//! README's "The same arms on the try-on page"). `shape/…` is a whole change of shape, arms
//! included; `shape-preview/…` the same changes as a moving slider previews them;
//! `garment/…` a change of garment model (`TryOn::set_garment`, the page's choice of garment),
//! the shipped 4,210- and 8,710-triangle models in turn, the files in f32 as shipped (the
//! page's are f16).
//!
//! `cargo bench -p sartor-web --bench seek -- --warm-up-time 1 --measurement-time 3`

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use sartor_web::{PhenotypeSliders, TryOn};

// The integration tests' loaders of the shipped files (the bench uses some of them).
#[allow(dead_code)]
#[path = "../tests/it/common.rs"]
mod common;

use common::{files_of, playing_02_02};

/// The page's session with the arms held, on the body of `phenotype` (`None`: nominal),
/// playing CMU 02_02.
fn playing(phenotype: Option<&str>) -> TryOn {
    let mut t = playing_02_02();
    if let Some(text) = phenotype {
        t.set_phenotype_text(text).expect("phenotype");
    }
    t
}

fn seek(c: &mut Criterion) {
    for (name, phenotype) in [
        ("seek/02_02-nominal", None),
        ("seek/02_02-male-1.90m-heavy", Some("male, 1.90 m, heavy")),
    ] {
        let mut t = playing(phenotype);
        let targets = [30, 50];
        for &frame in &targets {
            t.seek(frame).expect("seek");
        }
        let mut k = 0;
        c.bench_function(name, |b| {
            b.iter(|| {
                t.seek(targets[k % 2]).expect("seek");
                k += 1;
            })
        });
    }
}

/// A new shape while a clip plays, as a slider's move gives it: the body, the garment's shape
/// caches, the arms' poses anew (every frame a jump depends on) and the jump; two phenotypes
/// in turn at frame 50 of CMU 02_02.
fn new_shape(c: &mut Criterion) {
    let mut t = playing(None);
    t.seek(50).expect("seek");
    let shapes = ["male, 1.90 m, heavy", "female, 1.60 m, light"];
    let mut k = 0;
    c.bench_function("shape/02_02-two-phenotypes", |b| {
        b.iter(|| {
            t.set_phenotype_text(shapes[k % 2]).expect("phenotype");
            k += 1;
        })
    });
}

/// The same two phenotypes as a slider's move previews them ([`TryOn::preview_phenotype`]: the
/// arms as held for the shape last set), from the sliders the page gives.
fn preview_shape(c: &mut Criterion) {
    let mut t = playing(None);
    t.seek(50).expect("seek");
    let heavy = PhenotypeSliders {
        gender: 1.0,
        height_m: 1.90,
        weight: 0.75,
        muscle: 0.5,
        age_years: 25.0,
    };
    let light = PhenotypeSliders {
        gender: 0.0,
        height_m: 1.60,
        weight: 0.25,
        ..heavy
    };
    let mut k = 0;
    c.bench_function("shape-preview/02_02-two-phenotypes", |b| {
        b.iter(|| {
            t.preview_phenotype([&heavy, &light][k % 2])
                .expect("phenotype");
            k += 1;
        })
    });
}

/// A change of garment model at frame 50 of CMU 02_02 on the nominal body: the shipped models
/// in turn (their files' copies made outside the timing).
fn new_garment(c: &mut Criterion) {
    let mut t = playing(None);
    t.seek(50).expect("seek");
    let models = ["default-8710", "default"].map(|name| {
        files_of(&[(
            &sartor_web::MODEL_FILES[..],
            &format!("datasets/models/{name}"),
        )])
    });
    let mut k = 0;
    c.bench_function("garment/02_02-4210-8710", |b| {
        b.iter_batched(
            || {
                k += 1;
                models[k % 2].clone()
            },
            |files| t.set_garment(files).expect("garment"),
            BatchSize::PerIteration,
        )
    });
}

criterion_group!(benches, seek, new_shape, preview_shape, new_garment);
criterion_main!(benches);
