//! The measurements a size chart asks for, taken on the shaped body `T_b(β)` in its rest pose:
//! standing height, chest (bust), waist and hip girths, and mass.
//!
//! A girth is what a tape measure held level reads: the perimeter of the convex hull of the
//! body's horizontal cross-section at one height (a tape spans the hollow between the breasts
//! and the one between the buttocks), taken over the *trunk*, i.e. every face but those of the
//! arms (a face belongs to the joint with the largest summed skin weight over its corners; the
//! arms are the joints below each shoulder girdle's first joint, found from the skeleton: see
//! [`BodyMeasurer::new`]). Which height, after ISO 8559-1's wording, by landmarks found on the
//! mesh and the skeleton:
//!
//! - *armpit*: the lowest vertex shared by an arm face and a trunk face;
//! - *crotch*: the lowest vertex on the body's plane of symmetry (the template's vertices within
//!   a millimetre of the root joint's `x`);
//! - **waist**: the smallest girth between the root joint (the pelvis) and the armpit;
//! - **chest** (bust): the largest girth between the waist and the armpit;
//! - **hips**: the largest girth between 1 cm above the crotch and the waist.
//!
//! Each is sought on slices 1 cm apart, then by a golden-section search to 1 mm around the
//! best. The **mass** is the volume the closed mesh bounds (divergence theorem) times
//! [`BODY_DENSITY_KG_PER_M3`], that of water: a whole body's density lies within a few per cent
//! of it (lean tissue above, fat and the air in the lungs below), so the mass is an estimate to
//! that accuracy.
//!
//! [`fit_measurements`] finds the shape that has given measurements (a shopper's size-chart
//! figures); `sartor_core::PhenotypeSpace::betas_for` runs it for a phenotype request such as
//! `"female, 1.65 m, bust_cm=94, waist_cm=76, hips_cm=102"`.
//!
//! ```no_run
//! use sartor_core::{BodyMeasurer, BodyModel};
//!
//! let body = BodyModel::load(std::path::Path::new("datasets/body/makehuman"))?;
//! let betas = [0.0; 10];
//! let m = BodyMeasurer::new(&body)?.measure(&body, &body.shaped_vertices(&betas)?, &betas)?;
//! println!("chest {:.1} cm, waist {:.1} cm", 100.0 * m.chest_m, 100.0 * m.waist_m);
//! # Ok::<(), sartor_core::Error>(())
//! ```

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::{BodyModel, Error, Result, enclosed_volume};

/// Density the mass is computed with, kg/m³ (water's; see the module docs).
pub const BODY_DENSITY_KG_PER_M3: f64 = 1000.0;
/// Spacing of the slices a girth is first sought on, metres.
const COARSE_STEP_M: f64 = 0.01;
/// The search around the best of those stops when its bracket is this narrow, metres.
const SLICE_STEP_M: f64 = 0.001;
/// The hip girth is sought from this far above the crotch, metres (at the crotch itself the
/// slice runs along the inner thighs).
const ABOVE_CROTCH_M: f64 = 0.01;
/// A template vertex this close to the root joint's `x` lies on the plane of symmetry, metres.
const MIDLINE_M: f64 = 1e-3;

/// A body's measurements (metres, kilograms; heights above the soles).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BodyMeasurements {
    /// Standing height: the vertical extent of the mesh.
    pub height_m: f64,
    /// Chest (bust) girth.
    pub chest_m: f64,
    /// Waist girth.
    pub waist_m: f64,
    /// Hip girth.
    pub hips_m: f64,
    /// Volume bounded by the mesh, m³.
    pub volume_m3: f64,
    /// `volume_m3 ×` [`BODY_DENSITY_KG_PER_M3`].
    pub mass_kg: f64,
    /// Height of the chest girth's slice.
    pub chest_level_m: f64,
    /// Height of the waist girth's slice.
    pub waist_level_m: f64,
    /// Height of the hip girth's slice.
    pub hips_level_m: f64,
    /// Height of the crotch.
    pub crotch_m: f64,
    /// Height of the armpit.
    pub armpit_m: f64,
}

impl std::fmt::Display for BodyMeasurements {
    /// `height 1.733 m, chest 94.8 cm, waist 77.1 cm, hips 92.8 cm, mass 62.4 kg`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "height {:.3} m, chest {:.1} cm, waist {:.1} cm, hips {:.1} cm, mass {:.1} kg",
            self.height_m,
            100.0 * self.chest_m,
            100.0 * self.waist_m,
            100.0 * self.hips_m,
            self.mass_kg
        )
    }
}

/// Measures bodies of one model (see the module docs): the trunk's faces, the plane of
/// symmetry's vertices and the armpit seam are found once, from the model's template, skeleton
/// and skin weights.
#[derive(Clone, Debug)]
pub struct BodyMeasurer {
    n_vertices: usize,
    trunk_faces: Vec<[u32; 3]>,
    midline: Vec<u32>,
    seam: Vec<u32>,
    root: usize,
}

impl BodyMeasurer {
    /// Find the trunk, the plane of symmetry and the armpit seam of `body`.
    ///
    /// The arms: the skeleton's *spine* runs from the root through, at each joint, the child
    /// whose subtree reaches highest in the rest pose (up to the head); a child of a spine joint
    /// above the root that is not on the spine starts a shoulder girdle (a clavicle: CMU's
    /// `LeftShoulder`, SMPL's `left_collar`), and every joint below that first one is the arm's.
    /// Errors when the skeleton has no such branch, or the template no vertex on the root
    /// joint's plane of symmetry.
    pub fn new(body: &BodyModel) -> Result<Self> {
        let bad = |m: String| Error::invalid("body measurements", format!("{}: {m}", body.name()));
        let skeleton = body.skeleton();
        let parents = skeleton.parents();
        let n_joints = skeleton.n_joints();
        let rest = body.joint_template();
        let children = |j: usize| (0..n_joints).filter(move |&c| parents[c] == Some(j));
        // Highest rest joint in each subtree (children come after their parents, so one
        // backward sweep suffices, but do not rely on the order: iterate to a fixed point).
        let mut top = rest.iter().map(|p| p.y).collect::<Vec<_>>();
        for _ in 0..n_joints {
            let mut changed = false;
            for c in 0..n_joints {
                if let Some(p) = parents[c]
                    && top[c] > top[p]
                {
                    top[p] = top[c];
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let Some(root) = (0..n_joints).find(|&j| parents[j].is_none()) else {
            return Err(bad("the skeleton has no root".into()));
        };
        let mut spine = vec![root];
        while let Some(next) =
            children(*spine.last().expect("spine")).max_by(|&a, &b| top[a].total_cmp(&top[b]))
        {
            spine.push(next);
        }
        let mut arm = vec![false; n_joints];
        let mut n_girdles = 0;
        for &s in &spine[1..] {
            for girdle in children(s).filter(|c| !spine.contains(c)) {
                n_girdles += 1;
                let mut stack: Vec<usize> = children(girdle).collect();
                while let Some(j) = stack.pop() {
                    arm[j] = true;
                    stack.extend(children(j));
                }
            }
        }
        if n_girdles == 0 || !arm.iter().any(|&a| a) {
            return Err(bad(
                "the skeleton has no arms branching off its spine".into()
            ));
        }
        let faces = body.faces();
        let dominant = body.skin_weights().face_dominant_joints(faces);
        let (mut trunk_faces, mut on_arm, mut on_trunk) = (
            Vec::new(),
            vec![false; body.n_vertices()],
            vec![false; body.n_vertices()],
        );
        for (t, &j) in faces.iter().zip(&dominant) {
            let side = if arm[j] { &mut on_arm } else { &mut on_trunk };
            for &v in t {
                side[v as usize] = true;
            }
            if !arm[j] {
                trunk_faces.push(*t);
            }
        }
        let seam: Vec<u32> = (0..body.n_vertices() as u32)
            .filter(|&v| on_arm[v as usize] && on_trunk[v as usize])
            .collect();
        let root_x = rest[root].x;
        let midline: Vec<u32> = body
            .template()
            .positions()
            .iter()
            .enumerate()
            .filter(|(_, p)| (p.x - root_x).abs() < MIDLINE_M)
            .map(|(v, _)| v as u32)
            .collect();
        if midline.is_empty() {
            return Err(bad(format!(
                "no template vertex lies within {MIDLINE_M} m of the root joint's plane \
                 x = {root_x}"
            )));
        }
        if seam.is_empty() {
            return Err(bad("no vertex joins an arm face to a trunk face".into()));
        }
        Ok(Self {
            n_vertices: body.n_vertices(),
            trunk_faces,
            midline,
            seam,
            root,
        })
    }

    /// Measure the shaped rest vertices `vertices` of `body` (the model this measurer was made
    /// for) at shape `betas` (`body.shaped_vertices(betas)`; β, missing entries zero, gives the
    /// pelvis's height, which bounds the waist's search). Errors on a shape the body rejects, on
    /// vertices that are not finite or not the model's count, and on a body whose landmarks come
    /// out of order (crotch, pelvis, armpit).
    pub fn measure(
        &self,
        body: &BodyModel,
        v: &[Vector3<f64>],
        betas: &[f64],
    ) -> Result<BodyMeasurements> {
        let root_y = body.shaped_joints(betas)?[self.root].y;
        let bad = |m: String| Error::invalid("body measurements", m);
        if v.len() != self.n_vertices {
            return Err(bad(format!(
                "{} vertices for a body of {}",
                v.len(),
                self.n_vertices
            )));
        }
        if let Some(i) = v.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(bad(format!("vertex {i} is not finite")));
        }
        let (floor, top) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.y), hi.max(p.y))
            });
        let lowest = |set: &[u32]| {
            set.iter()
                .map(|&i| v[i as usize].y)
                .fold(f64::INFINITY, f64::min)
        };
        let (crotch, armpit) = (lowest(&self.midline), lowest(&self.seam));
        let hips_from = crotch + ABOVE_CROTCH_M;
        if !(hips_from < root_y && root_y < armpit) {
            return Err(bad(format!(
                "the landmarks are out of order: crotch {:.3} m, pelvis {:.3} m, armpit {:.3} m \
                 above the soles",
                crotch - floor,
                root_y - floor,
                armpit - floor
            )));
        }
        let slicer = Slicer::new(v, &self.trunk_faces, hips_from, armpit);
        let (waist_y, waist) = slicer.extreme(root_y, armpit, false);
        let (chest_y, chest) = slicer.extreme(waist_y, armpit, true);
        let (hips_y, hips) = slicer.extreme(hips_from, waist_y, true);
        let volume = enclosed_volume(v, body.faces());
        Ok(BodyMeasurements {
            height_m: top - floor,
            chest_m: chest,
            waist_m: waist,
            hips_m: hips,
            volume_m3: volume,
            mass_kg: volume * BODY_DENSITY_KG_PER_M3,
            chest_level_m: chest_y - floor,
            waist_level_m: waist_y - floor,
            hips_level_m: hips_y - floor,
            crotch_m: crotch - floor,
            armpit_m: armpit - floor,
        })
    }
}

/// Measurements a body is asked to have (metres, kilograms): a shopper's size-chart figures.
/// Each is optional; [`fit_measurements`] reaches those given.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeasurementTargets {
    /// Standing height.
    pub height_m: Option<f64>,
    /// Chest (bust) girth.
    pub chest_m: Option<f64>,
    /// Waist girth.
    pub waist_m: Option<f64>,
    /// Hip girth.
    pub hips_m: Option<f64>,
    /// Mass (see [`BODY_DENSITY_KG_PER_M3`]).
    pub mass_kg: Option<f64>,
}

/// A target's name, value, the plausible range a request may ask for, the tolerance a fit must
/// meet, and how its residual is weighted (the height, when given, is met first).
struct Quantity {
    name: &'static str,
    unit: &'static str,
    scale: f64,
    range: (f64, f64),
    /// In metres; `None` for a target a fit weighs but does not have to meet (the mass).
    tolerance: Option<f64>,
    weight: f64,
    get: fn(&BodyMeasurements) -> f64,
}

/// A mass asked for without any girth must be met within this fraction of it.
const MASS_TOLERANCE: f64 = 0.05;
/// The fits weight the mass's relative error this much against a girth's, and with a girth
/// given do not require it: the mass is the volume times one density, which a real body's
/// differs from by a few per cent, and MakeHuman's bodies of given girths are lighter than people
/// (a neutral 1.73 m male body, chest 95 cm and waist 77 cm, bounds 62 litres); the girths decide
/// how a garment fits.
const MASS_WEIGHT: f64 = 0.1;

/// A girth target: from `min_m` to 2 m, met within 1 cm.
const fn girth(name: &'static str, min_m: f64, get: fn(&BodyMeasurements) -> f64) -> Quantity {
    Quantity {
        name,
        unit: "cm",
        scale: 100.0,
        range: (min_m, 2.0),
        tolerance: Some(0.01),
        weight: 1.0,
        get,
    }
}

const QUANTITIES: [Quantity; 5] = [
    Quantity {
        name: "height",
        unit: "m",
        scale: 1.0,
        range: (1.0, 2.5),
        tolerance: Some(0.002),
        weight: 10.0,
        get: |m| m.height_m,
    },
    girth("chest", 0.5, |m| m.chest_m),
    girth("waist", 0.4, |m| m.waist_m),
    girth("hips", 0.5, |m| m.hips_m),
    Quantity {
        name: "mass",
        unit: "kg",
        scale: 1.0,
        range: (20.0, 300.0),
        tolerance: None,
        weight: MASS_WEIGHT,
        get: |m| m.mass_kg,
    },
];

impl MeasurementTargets {
    fn values(&self) -> [Option<f64>; 5] {
        [
            self.height_m,
            self.chest_m,
            self.waist_m,
            self.hips_m,
            self.mass_kg,
        ]
    }

    /// Per target given, in [`QUANTITIES`] order, `measured`'s error relative to it (the
    /// height's weighted ×10, so that a fit meets it first).
    pub(crate) fn relative_errors(&self, measured: &BodyMeasurements) -> Vec<f64> {
        QUANTITIES
            .iter()
            .zip(self.values())
            .filter_map(|(q, v)| {
                let want = v?;
                Some(q.weight * ((q.get)(measured) - want) / want)
            })
            .collect()
    }

    /// Whether any measurement is asked for.
    pub fn is_empty(&self) -> bool {
        self.values().iter().all(Option::is_none)
    }

    /// Whether a girth or the mass is asked for (the height alone is met without a fit).
    pub fn has_girth_or_mass(&self) -> bool {
        self.values()[1..].iter().any(Option::is_some)
    }

    /// Check that every value given is finite and within a human range (height 1–2.5 m, chest
    /// and hips 50–200 cm, waist 40–200 cm, mass 20–300 kg).
    pub fn validate(&self) -> Result<()> {
        for (q, v) in QUANTITIES.iter().zip(self.values()) {
            let Some(v) = v else { continue };
            let (lo, hi) = q.range;
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(Error::invalid(
                    "body measurements",
                    format!(
                        "{} {} {} is outside [{}, {}] {}",
                        q.name,
                        v * q.scale,
                        q.unit,
                        lo * q.scale,
                        hi * q.scale,
                        q.unit
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The targets `measured` misses by more than their tolerance (2 mm of height, 1 cm of
    /// girth; a mass beside girths only guides a fit, see [`fit_measurements`], and alone is met
    /// within 5 %), as text such as
    /// `"waist 120.0 cm (reached 98.3 cm)"`.
    pub fn misses(&self, measured: &BodyMeasurements) -> Vec<String> {
        let girths = self.chest_m.is_some() || self.waist_m.is_some() || self.hips_m.is_some();
        QUANTITIES
            .iter()
            .zip(self.values())
            .filter_map(|(q, v)| {
                let (want, got) = (v?, (q.get)(measured));
                // The mass alone is required (see [`MASS_TOLERANCE`]).
                let tolerance = q.tolerance.or((!girths).then_some(MASS_TOLERANCE * want))?;
                ((got - want).abs() > tolerance).then(|| {
                    let decimals = if q.unit == "m" { 3 } else { 1 };
                    format!(
                        "{} {:.*} {} (reached {:.*} {})",
                        q.name,
                        decimals,
                        want * q.scale,
                        q.unit,
                        decimals,
                        got * q.scale,
                        q.unit
                    )
                })
            })
            .collect()
    }
}

/// What [`fit_measurements`] reached.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasurementFit {
    /// The shape vector.
    pub betas: Vec<f64>,
    /// Its measurements.
    pub measurements: BodyMeasurements,
    /// Levenberg–Marquardt iterations taken.
    pub iterations: usize,
}

/// How far each shape component may move from where the fit starts (and at least to ±this):
/// the range the runtime's extreme-shape tests bound the garment over.
pub const FIT_BETA_LIMIT: f64 = 5.0;
/// Weight of the pull back towards the start shape, per unit of β, against relative
/// measurement errors: a step of one unit costs as much as missing a target by 0.3 %, so
/// the fit leaves the start (a phenotype of the sliders given, on MakeHuman's body space) no
/// further than the targets need.
const FIT_PRIOR: f64 = 3e-3;
/// Finite-difference step of the fit's Jacobian, in β.
const FIT_STEP: f64 = 0.02;

/// The shape nearest `start` (a phenotype's β, say; missing entries zero) whose measurements
/// meet `targets`: a Levenberg–Marquardt least-squares fit of the relative measurement errors
/// over every shape component (the mass's weighted 0.1 of a girth's and, beside a girth, not
/// required: a body's density is known to a few per cent, and MakeHuman's bodies of given girths
/// are lighter than people), with a pull towards `start` ([`FIT_PRIOR`]), each component kept
/// within [`FIT_BETA_LIMIT`] of zero (or of `start`, where that lies beyond). Check the result
/// against the targets with [`MeasurementTargets::misses`]: a combination the model's shape space
/// cannot reach (a waist far wider than the chest) comes back as the nearest body.
pub fn fit_measurements(
    body: &BodyModel,
    measurer: &BodyMeasurer,
    start: &[f64],
    targets: &MeasurementTargets,
) -> Result<MeasurementFit> {
    targets.validate()?;
    body.check_betas(start)?;
    let mut start = start.to_vec();
    start.resize(body.n_betas(), 0.0);
    let bounds: Vec<(f64, f64)> = start
        .iter()
        .map(|&b| (b.min(-FIT_BETA_LIMIT), b.max(FIT_BETA_LIMIT)))
        .collect();
    let mut vertices = vec![Vector3::zeros(); body.n_vertices()];
    let mut measure = |betas: &[f64]| -> Result<BodyMeasurements> {
        body.shaped_vertices_into(betas, &mut vertices)?;
        measurer.measure(body, &vertices, betas)
    };
    let (betas, iterations) = least_squares(start.clone(), &bounds, FIT_STEP, |betas| {
        let mut r = targets.relative_errors(&measure(betas)?);
        r.extend(betas.iter().zip(&start).map(|(b, s)| FIT_PRIOR * (b - s)));
        Ok(r)
    })?;
    let measurements = measure(&betas)?;
    Ok(MeasurementFit {
        betas,
        measurements,
        iterations,
    })
}

/// Levenberg–Marquardt on the residuals `residuals(x)` from `x`, each coordinate kept within
/// `bounds` (a step leaving them is clamped): the minimiser found and the iterations taken (at
/// most 60). The Jacobian is taken by forward differences of `step` (backward at an upper
/// bound) at the start and every [`JACOBIAN_REFRESH`] accepted steps, and updated by
/// Broyden's rank-one rule in between (each difference costs a residual evaluation, a
/// measurement of the whole body); when no damped step lowers the cost with an updated
/// Jacobian it is taken afresh, and when none does with a fresh one, or the best step moves no
/// coordinate 1e-5, the fit stops.
pub(crate) fn least_squares(
    mut x: Vec<f64>,
    bounds: &[(f64, f64)],
    step: f64,
    mut residuals: impl FnMut(&[f64]) -> Result<Vec<f64>>,
) -> Result<(Vec<f64>, usize)> {
    use nalgebra::{DMatrix, DVector};
    let n = x.len();
    let cost = |r: &DVector<f64>| r.norm_squared();
    // Forward differences, backward at an upper bound.
    let differences = |x: &[f64],
                       r: &DVector<f64>,
                       residuals: &mut dyn FnMut(&[f64]) -> Result<Vec<f64>>|
     -> Result<DMatrix<f64>> {
        let mut jac = DMatrix::<f64>::zeros(r.len(), n);
        for k in 0..n {
            let mut xk = x.to_vec();
            let h = if xk[k] + step <= bounds[k].1 {
                step
            } else {
                -step
            };
            xk[k] += h;
            let rk = DVector::from_vec(residuals(&xk)?);
            jac.set_column(k, &((rk - r) / h));
        }
        Ok(jac)
    };
    let mut r = DVector::from_vec(residuals(&x)?);
    let mut jac = differences(&x, &r, &mut residuals)?;
    let (mut fresh, mut since_fresh) = (true, 0);
    let mut mu = 1e-3;
    let mut iterations = 0;
    while iterations < 60 {
        iterations += 1;
        let jt = jac.transpose();
        let a = &jt * &jac;
        let g = &jt * &r;
        let mut accepted = None;
        // A stale Jacobian gets a few tries before it is taken afresh.
        let mut tries = if fresh { 40 } else { 6 };
        while tries > 0 && mu < 1e10 {
            tries -= 1;
            let mut lhs = a.clone();
            for k in 0..n {
                lhs[(k, k)] += mu * (a[(k, k)] + 1e-9);
            }
            let Some(delta) = lhs.cholesky().map(|c| c.solve(&(-&g))) else {
                mu *= 4.0;
                continue;
            };
            let trial: Vec<f64> = x
                .iter()
                .zip(delta.iter())
                .zip(bounds)
                .map(|((v, d), (lo, hi))| (v + d).clamp(*lo, *hi))
                .collect();
            let rt = DVector::from_vec(residuals(&trial)?);
            if cost(&rt) < cost(&r) {
                accepted = Some((trial, rt));
                break;
            }
            mu *= 4.0;
        }
        let Some((trial, rt)) = accepted else {
            if fresh {
                break;
            }
            jac = differences(&x, &r, &mut residuals)?;
            (fresh, since_fresh, mu) = (true, 0, 1e-3);
            continue;
        };
        let d = DVector::from_iterator(n, trial.iter().zip(&x).map(|(a, b)| a - b));
        let moved = d.amax();
        // Broyden: the Jacobian that maps this step onto the change it made.
        let dd = d.norm_squared();
        if dd > 0.0 {
            let miss = &rt - &r - &jac * &d;
            jac += miss * d.transpose() / dd;
        }
        (x, r) = (trial, rt);
        mu = (mu / 3.0).max(1e-9);
        if moved <= 1e-5 {
            break;
        }
        since_fresh += 1;
        fresh = false;
        if since_fresh == JACOBIAN_REFRESH {
            jac = differences(&x, &r, &mut residuals)?;
            (fresh, since_fresh) = (true, 0);
        }
    }
    Ok((x, iterations))
}

/// Accepted steps between two Jacobians by differences in [`least_squares`].
const JACOBIAN_REFRESH: usize = 6;

/// Horizontal cross-sections of a set of faces between two heights.
struct Slicer<'a> {
    v: &'a [Vector3<f64>],
    /// The faces that reach into `[lo, hi]`.
    faces: Vec<[u32; 3]>,
    /// Per band of [`BIN_M`] from `lo`, the faces (indices into `faces`) that reach into it.
    bins: Vec<Vec<u32>>,
    lo: f64,
}

/// Height of the bands a [`Slicer`] sorts its faces into, metres.
const BIN_M: f64 = 0.01;

impl<'a> Slicer<'a> {
    fn new(v: &'a [Vector3<f64>], all: &[[u32; 3]], lo: f64, hi: f64) -> Self {
        let n_bins = (((hi - lo) / BIN_M).floor() as usize) + 1;
        let mut bins = vec![Vec::new(); n_bins];
        let mut faces = Vec::new();
        let bin = |y: f64| (((y - lo) / BIN_M).floor().max(0.0) as usize).min(n_bins - 1);
        for &t in all {
            let ys = t.map(|i| v[i as usize].y);
            let (a, b) = (ys[0].min(ys[1]).min(ys[2]), ys[0].max(ys[1]).max(ys[2]));
            if b < lo || a > hi {
                continue;
            }
            for slot in &mut bins[bin(a)..=bin(b)] {
                slot.push(faces.len() as u32);
            }
            faces.push(t);
        }
        Self { v, faces, bins, lo }
    }

    /// The girth at height `y` (see the module docs), within the slicer's heights.
    fn girth(&self, y: f64) -> f64 {
        let b = (((y - self.lo) / BIN_M).floor().max(0.0) as usize).min(self.bins.len() - 1);
        let mut points = Vec::new();
        for &f in &self.bins[b] {
            let p = self.faces[f as usize].map(|i| self.v[i as usize]);
            for k in 0..3 {
                let (s, e) = (p[k], p[(k + 1) % 3]);
                if (s.y < y) != (e.y < y) {
                    let u = (y - s.y) / (e.y - s.y);
                    points.push([s.x + u * (e.x - s.x), s.z + u * (e.z - s.z)]);
                }
            }
        }
        hull_perimeter(points)
    }

    /// The largest (`max`) or smallest girth between heights `lo` and `hi` and its height:
    /// slices [`COARSE_STEP_M`] apart, then a golden-section search within a coarse step of the
    /// best down to [`SLICE_STEP_M`]; the best slice met.
    fn extreme(&self, lo: f64, hi: f64, max: bool) -> (f64, f64) {
        // Minimise `sign · girth`.
        let sign = if max { -1.0 } else { 1.0 };
        let f = |y: f64| sign * self.girth(y);
        let n = (((hi - lo) / COARSE_STEP_M).ceil() as usize).max(2);
        let h = (hi - lo) / n as f64;
        let mut best = (lo, f(lo));
        for i in 1..=n {
            let y = lo + i as f64 * h;
            let v = f(y);
            if v < best.1 {
                best = (y, v);
            }
        }
        let (mut a, mut b) = ((best.0 - h).max(lo), (best.0 + h).min(hi));
        let ratio = 0.5 * (5f64.sqrt() - 1.0);
        let (mut c, mut d) = (b - ratio * (b - a), a + ratio * (b - a));
        let (mut fc, mut fd) = (f(c), f(d));
        while b - a > SLICE_STEP_M {
            if fc < fd {
                (b, d, fd) = (d, c, fc);
                c = b - ratio * (b - a);
                fc = f(c);
            } else {
                (a, c, fc) = (c, d, fd);
                d = a + ratio * (b - a);
                fd = f(d);
            }
        }
        for (y, v) in [(c, fc), (d, fd)] {
            if v < best.1 {
                best = (y, v);
            }
        }
        (best.0, sign * best.1)
    }
}

/// Perimeter of the convex hull of `points` (Andrew's monotone chain); 0 for fewer than three
/// distinct points.
fn hull_perimeter(mut p: Vec<[f64; 2]>) -> f64 {
    p.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup();
    if p.len() < 3 {
        return 0.0;
    }
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(p.len() + 1);
    for &q in &p {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
            hull.pop();
        }
        hull.push(q);
    }
    // The upper chain's pops stop at the lower chain's last point.
    let lower = hull.len() + 1;
    for &q in p.iter().rev().skip(1) {
        while hull.len() >= lower && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
            hull.pop();
        }
        hull.push(q);
    }
    hull.windows(2)
        .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hull_of_a_circle_and_of_two_circles() {
        let circle = |cx: f64, r: f64, n: usize| {
            (0..n).map(move |i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                [cx + r * a.cos(), r * a.sin()]
            })
        };
        let n = 720;
        let polygon = 2.0 * n as f64 * 0.3 * (std::f64::consts::PI / n as f64).sin();
        // Points inside the circle do not count.
        let mut p: Vec<_> = circle(0.0, 0.3, n).collect();
        p.extend(circle(0.05, 0.1, 50));
        assert!((hull_perimeter(p) - polygon).abs() < 1e-12);
        // Two circles 0.5 apart: a tape around both reads both half circles and two spans.
        let mut two: Vec<_> = circle(-0.25, 0.1, n).collect();
        two.extend(circle(0.25, 0.1, n));
        let want = 2.0 * n as f64 * 0.1 * (std::f64::consts::PI / n as f64).sin() + 2.0 * 0.5;
        assert!((hull_perimeter(two) - want).abs() < 1e-4, "{}", want);
        assert_eq!(
            hull_perimeter(vec![[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]]),
            0.0
        );
        // Collinear points: the hull is the segment there and back.
        let line = vec![[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [0.0, 1.0]];
        assert!((hull_perimeter(line) - (2.0 + 2f64.sqrt())).abs() < 1e-12);
    }
}
