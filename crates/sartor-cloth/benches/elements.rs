//! The assembly's element derivatives on an 8,712-triangle sheet (12,936 hinges), one element
//! at a time against four at once (`MembraneRest::derivatives_lanes`,
//! `BendingRest::gauss_newton_lanes`), with the stiffness and bending coefficient looked up at
//! the state as the step's first Newton iteration does. Both run compiled for AVX2 where the
//! CPU has it, as the assembly does; the ratio of the two, in the same run, is the measure.
//!
//! `cargo bench -p sartor-cloth --bench elements -- --warm-up-time 1 --measurement-time 3`
#![allow(unsafe_code)]

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use sartor_cloth::energy::{
    BendingRest, ElementDerivatives, F64x4, GaussNewtonHinge, MembraneRest, Projection,
    gather_lanes,
};
use sartor_cloth::{Cloth, Material, rectangle_sheet};

/// A 1 m sheet of 66 × 66 quads with its vertices moved by up to ±2 mm (a fixed sequence):
/// strained triangles and bent hinges.
fn sheet() -> (Cloth, Vec<Vector3<f64>>) {
    let mesh = rectangle_sheet(
        Vector3::new(-0.5, 1.0, 0.5),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.0, 0.0, -1.0),
        66,
        66,
    )
    .expect("valid sheet");
    let cloth = Cloth::new(mesh, Material::gray_interlock(), None).expect("valid cloth");
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut jitter = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.004
    };
    let x = cloth
        .rest_mesh()
        .positions()
        .iter()
        .map(|p| p + Vector3::new(jitter(), jitter(), jitter()))
        .collect();
    (cloth, x)
}

/// One pass over the sheet's elements, for [`widest`]: `run` and what it calls are
/// `#[inline(always)]`, so that they are compiled into `widest`'s AVX2 version (a closure's
/// body would be compiled apart, for the baseline, as `sartor_cloth`'s `isa::Kernel` notes).
trait Pass {
    fn run(&mut self) -> f64;
}

/// `pass.run()` compiled for AVX2 and FMA when the CPU has them (as the assembly's kernel).
fn widest<P: Pass>(pass: &mut P) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
        #[target_feature(enable = "avx2,fma")]
        fn enabled<P: Pass>(pass: &mut P) -> f64 {
            pass.run()
        }
        // SAFETY: the CPU has the features `enabled` is compiled with (checked just above).
        return unsafe { enabled(pass) };
    }
    pass.run()
}

/// The sheet and its positions, what every pass reads.
struct Sheet {
    cloth: Cloth,
    x: Vec<Vector3<f64>>,
}

struct MembraneOne<'a>(&'a Sheet);

impl Pass for MembraneOne<'_> {
    #[inline(always)]
    fn run(&mut self) -> f64 {
        let (cloth, x) = (&self.0.cloth, &self.0.x);
        let model = cloth.material().membrane();
        let mut sum = 0.0;
        for (f, m) in cloth.faces().iter().zip(cloth.membranes()) {
            let xt = [x[f[0] as usize], x[f[1] as usize], x[f[2] as usize]];
            let d = m.derivatives_frozen_here(&xt, model, Projection::Psd);
            sum += d.hessian[0][1][(0, 1)] + d.gradient[2].x;
        }
        sum
    }
}

struct MembraneFour<'a> {
    sheet: &'a Sheet,
    xl: [Vector3<F64x4>; 3],
    d: ElementDerivatives<3, F64x4>,
}

impl Pass for MembraneFour<'_> {
    #[inline(always)]
    fn run(&mut self) -> f64 {
        let (cloth, x) = (&self.sheet.cloth, &self.sheet.x);
        let model = cloth.material().membrane();
        let mut sum = 0.0;
        for (f, m) in cloth
            .faces()
            .chunks_exact(4)
            .zip(cloth.membranes().chunks_exact(4))
        {
            gather_lanes(x, [&f[0], &f[1], &f[2], &f[3]], &mut self.xl);
            let rests = [&m[0], &m[1], &m[2], &m[3]];
            let d = &mut self.d;
            MembraneRest::derivatives_lanes(rests, &self.xl, model, None, Projection::Psd, d);
            sum += d.hessian[0][1][(0, 1)].0[3] + d.gradient[2].x.0[3];
        }
        sum
    }
}

struct HingeOne<'a>(&'a Sheet);

impl Pass for HingeOne<'_> {
    #[inline(always)]
    fn run(&mut self) -> f64 {
        let (cloth, x) = (&self.0.cloth, &self.0.x);
        let model = cloth.material().bending();
        let mut sum = 0.0;
        for h in cloth.hinges() {
            let v = h.vertices;
            let xh = [
                x[v[0] as usize],
                x[v[1] as usize],
                x[v[2] as usize],
                x[v[3] as usize],
            ];
            if let Some(d) = h.gauss_newton_frozen_here(&xh, model) {
                sum += d.gradient[1].x + d.curvature;
            }
        }
        sum
    }
}

struct HingeFour<'a> {
    sheet: &'a Sheet,
    xl: [Vector3<F64x4>; 4],
    d: GaussNewtonHinge<F64x4>,
}

impl Pass for HingeFour<'_> {
    #[inline(always)]
    fn run(&mut self) -> f64 {
        let (cloth, x) = (&self.sheet.cloth, &self.sheet.x);
        let model = cloth.material().bending();
        let mut sum = 0.0;
        for h in cloth.hinges().chunks_exact(4) {
            let idx = [
                &h[0].vertices,
                &h[1].vertices,
                &h[2].vertices,
                &h[3].vertices,
            ];
            gather_lanes(x, idx, &mut self.xl);
            let rests = [&h[0], &h[1], &h[2], &h[3]];
            let d = &mut self.d;
            let has = BendingRest::gauss_newton_lanes(rests, &self.xl, model, None, d);
            if has[3] {
                sum += d.gradient[1].x.0[3] + d.curvature.0[3];
            }
        }
        sum
    }
}

fn bench(c: &mut Criterion) {
    let (cloth, x) = sheet();
    let sheet = Sheet { cloth, x };
    let zeros = Vector3::from_element(F64x4([0.0; 4]));
    let mut group = c.benchmark_group("element_derivatives_8712_triangles");
    let mut pass = MembraneOne(&sheet);
    group.bench_function("membrane/one_at_a_time", |b| b.iter(|| widest(&mut pass)));
    let mut pass = MembraneFour {
        sheet: &sheet,
        xl: [zeros; 3],
        d: ElementDerivatives::default(),
    };
    group.bench_function("membrane/four_at_a_time", |b| b.iter(|| widest(&mut pass)));
    let mut pass = HingeOne(&sheet);
    group.bench_function("hinge/one_at_a_time", |b| b.iter(|| widest(&mut pass)));
    let mut pass = HingeFour {
        sheet: &sheet,
        xl: [zeros; 4],
        d: GaussNewtonHinge::default(),
    };
    group.bench_function("hinge/four_at_a_time", |b| b.iter(|| widest(&mut pass)));
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
