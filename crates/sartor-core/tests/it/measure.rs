//! Body measurements on the built-in body, checked against independent computations (a grid
//! count of its volume, the hull of its vertices near a girth's slice) and human ranges, and the
//! fit that meets a shopper's measurements.

use nalgebra::Vector3;
use sartor_core::{
    BodyMeasurements, BodyMeasurer, BodyModel, FIT_BETA_LIMIT, MeasurementTargets, MeshProximity,
    PhenotypeRequest, PhenotypeSpace, fit_measurements,
};

use crate::common;

fn builtin() -> (BodyModel, PhenotypeSpace) {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman");
    (
        BodyModel::load(&dir).expect("the built-in body"),
        PhenotypeSpace::load(&dir).expect("its phenotype space"),
    )
}

fn measure(
    model: &BodyModel,
    space: &PhenotypeSpace,
    text: &str,
) -> (Vec<f64>, Vec<Vector3<f64>>, BodyMeasurements) {
    let request: PhenotypeRequest = text.parse().expect("a valid request");
    let (_, betas) = space.betas_for(model, &request).expect("reachable");
    let v = model.shaped_vertices(&betas).expect("valid");
    let m = BodyMeasurer::new(model)
        .expect("the built-in body has arms and a midline")
        .measure(model, &v, &betas)
        .expect("measurable");
    (betas, v, m)
}

#[test]
fn the_built_in_bodies_measure_like_people() {
    let (model, space) = builtin();
    let mut by_weight = Vec::new();
    for text in [
        "female, light",
        "female, heavy",
        "male, light",
        "male, heavy",
        "female, 1.45 m, heavy",
        "male, 2.10 m, light",
    ] {
        let (betas, _, m) = measure(&model, &space, text);
        assert_eq!(m.height_m, model.height_m(&betas).expect("valid"), "{text}");
        // Landmarks in order up the body, each girth in its band.
        assert!(
            m.crotch_m + 0.01 <= m.hips_level_m + 1e-9
                && m.hips_level_m <= m.waist_level_m
                && m.waist_level_m <= m.chest_level_m
                && m.chest_level_m <= m.armpit_m + 1e-9,
            "{text}: {m:?}"
        );
        assert!(m.waist_m < m.chest_m && m.waist_m < m.hips_m, "{text}: {m}");
        // Human adult ranges (ISO 8559 surveys span these many times over).
        for (what, v, lo, hi) in [
            ("chest", m.chest_m, 0.7, 1.3),
            ("waist", m.waist_m, 0.5, 1.2),
            ("hips", m.hips_m, 0.75, 1.3),
            ("mass", m.mass_kg, 30.0, 120.0),
        ] {
            assert!(
                (lo..=hi).contains(&v),
                "{text}: {what} {v} outside [{lo}, {hi}]"
            );
        }
        // Relative to height as people are: crotch near half of it, armpit near three quarters.
        for (what, v, lo, hi) in [
            ("crotch", m.crotch_m / m.height_m, 0.42, 0.52),
            ("armpit", m.armpit_m / m.height_m, 0.68, 0.78),
        ] {
            assert!(
                (lo..=hi).contains(&v),
                "{text}: {what} at {v} of the height"
            );
        }
        by_weight.push(m);
    }
    for pair in by_weight[..4].chunks(2) {
        let (light, heavy) = (pair[0], pair[1]);
        assert!(heavy.waist_m > light.waist_m + 0.01, "{light} / {heavy}");
        assert!(heavy.mass_kg > light.mass_kg + 2.0, "{light} / {heavy}");
    }
}

#[test]
fn the_volume_agrees_with_a_grid_count_of_the_inside() {
    let (model, space) = builtin();
    let (_, v, m) = measure(&model, &space, "male, heavy");
    let proximity = MeshProximity::new(&v, model.faces()).expect("valid");
    let (lo, hi) = v.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    // Cell centres 1.2 cm apart; each inside one counts its cell's volume.
    let h = 0.012;
    let n = ((hi - lo) / h).map(|x| x.ceil() as usize);
    let mut inside = 0usize;
    for i in 0..n.x {
        for j in 0..n.y {
            for k in 0..n.z {
                let p = lo + Vector3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * h;
                inside += usize::from(proximity.closest(&p).signed_distance_m < 0.0);
            }
        }
    }
    let counted = inside as f64 * h * h * h;
    let rel = (counted - m.volume_m3).abs() / m.volume_m3;
    assert!(rel < 0.02, "grid {counted} m³ against {} m³", m.volume_m3);
}

#[test]
fn a_girth_agrees_with_the_hull_of_the_vertices_at_its_height() {
    let (model, space) = builtin();
    let names = model.skeleton().names();
    let arm: Vec<bool> = (0..model.n_vertices())
        .map(|i| {
            let name = &names[model.skin_weights().dominant_joint(i)];
            ["Arm", "Hand", "Finger", "Thumb"]
                .iter()
                .any(|w| name.contains(w))
        })
        .collect();
    for text in ["female, 1.65 m", "male, 1.80 m, heavy"] {
        let (_, v, m) = measure(&model, &space, text);
        let floor = v.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        for (what, level, girth) in [
            ("chest", m.chest_level_m, m.chest_m),
            ("waist", m.waist_level_m, m.waist_m),
            ("hips", m.hips_level_m, m.hips_m),
        ] {
            // The trunk's vertices within 1 cm of the slice (the mesh's rows are 1–2 cm apart):
            // those whose largest skin weight is not on a joint CMU's names call an arm, hand,
            // finger or thumb (the measurer finds the arms from the skeleton's shape instead).
            let band: Vec<[f64; 2]> = v
                .iter()
                .enumerate()
                .filter(|(i, p)| (p.y - floor - level).abs() < 0.01 && !arm[*i])
                .map(|(_, p)| p)
                .map(|p| [p.x, p.z])
                .collect();
            let hull = hull_perimeter(band);
            assert!(
                (hull - girth).abs() < 0.02 * girth,
                "{text}: {what} {girth} m, vertices' hull {hull} m"
            );
        }
    }
}

/// The convex hull's perimeter by gift wrapping (another algorithm than the library's).
fn hull_perimeter(p: Vec<[f64; 2]>) -> f64 {
    let start = (0..p.len())
        .min_by(|&a, &b| p[a][0].total_cmp(&p[b][0]))
        .expect("points");
    let (mut at, mut length) = (start, 0.0);
    loop {
        let mut next = (at + 1) % p.len();
        for c in 0..p.len() {
            let cross = (p[next][0] - p[at][0]) * (p[c][1] - p[at][1])
                - (p[next][1] - p[at][1]) * (p[c][0] - p[at][0]);
            if cross < 0.0 {
                next = c;
            }
        }
        length += ((p[next][0] - p[at][0]).powi(2) + (p[next][1] - p[at][1]).powi(2)).sqrt();
        at = next;
        if at == start {
            return length;
        }
    }
}

#[test]
fn a_shoppers_measurements_are_met() {
    let (model, space) = builtin();
    // A phenotype's own measurements, asked for from another start.
    let (_, _, own) = measure(&model, &space, "female, 1.60 m, heavy");
    let asked = format!(
        "female, 1.60 m, bust_cm={:.2}, waist_cm={:.2}, hips_cm={:.2}",
        100.0 * own.chest_m,
        100.0 * own.waist_m,
        100.0 * own.hips_m
    );
    // Size-chart bodies, slim to heavy (the last beyond MakeHuman's weight slider).
    for text in [
        asked.as_str(),
        "female, 1.68 m, bust_cm=92, waist_cm=76, hips_cm=100, 65 kg",
        "male, 1.82 m, chest_cm=104, waist_cm=92, hips_cm=104, 88 kg",
        "female, 1.62 m, bust_cm=116, waist_cm=102, hips_cm=124",
    ] {
        let request: PhenotypeRequest = text.parse().expect("valid");
        let (phenotype, betas) = space.betas_for(&model, &request).expect(text);
        phenotype.validate().expect("sliders in range");
        assert!(
            betas.iter().all(|b| b.abs() <= FIT_BETA_LIMIT),
            "{text}: {betas:?}"
        );
        let v = model.shaped_vertices(&betas).expect("valid");
        let m = BodyMeasurer::new(&model)
            .expect("measurer")
            .measure(&model, &v, &betas)
            .expect("measurable");
        let want = request.measurements;
        assert!(
            (m.height_m - request.height_m.expect("height")).abs() < 0.002,
            "{text}: {m}"
        );
        for (what, got, asked) in [
            ("chest", m.chest_m, want.chest_m),
            ("waist", m.waist_m, want.waist_m),
            ("hips", m.hips_m, want.hips_m),
        ] {
            let asked = asked.expect("given");
            assert!((got - asked).abs() < 0.01, "{text}: {what} {got} m");
        }
        if let Some(kg) = want.mass_kg {
            // The mass guides the fit but is not required (see `fit_measurements`).
            assert!((m.mass_kg - kg).abs() < 0.15 * kg, "{text}: {m}");
        }
    }
}

#[test]
fn measurements_no_body_has_are_an_error_naming_them() {
    let (model, space) = builtin();
    let request: PhenotypeRequest = "male, 1.75 m, chest_cm=80, waist_cm=130"
        .parse()
        .expect("valid");
    let err = space
        .betas_for(&model, &request)
        .expect_err("out of reach")
        .to_string();
    assert!(err.contains("waist 130.0 cm (reached"), "{err}");
    // The fit alone returns the nearest body and says what it misses.
    let targets = MeasurementTargets {
        waist_m: Some(1.3),
        chest_m: Some(0.8),
        ..Default::default()
    };
    let measurer = BodyMeasurer::new(&model).expect("measurer");
    let fit = fit_measurements(&model, &measurer, &[0.0; 10], &targets).expect("fits");
    assert_eq!(
        targets.misses(&fit.measurements).len(),
        2,
        "{}",
        fit.measurements
    );
    assert!(
        fit.betas
            .iter()
            .all(|b| b.abs() <= FIT_BETA_LIMIT && b.is_finite())
    );
}

#[test]
fn bad_bodies_and_vertices_are_errors() {
    let (model, _) = builtin();
    let measurer = BodyMeasurer::new(&model).expect("measurer");
    let mut v = model.shaped_vertices(&[]).expect("valid");
    let err = measurer
        .measure(&model, &v[1..], &[])
        .expect_err("short")
        .to_string();
    assert!(err.contains("vertices for a body of"), "{err}");
    v[7].y = f64::NAN;
    let err = measurer
        .measure(&model, &v, &[])
        .expect_err("NaN")
        .to_string();
    assert!(err.contains("vertex 7 is not finite"), "{err}");
    let err = measurer
        .measure(&model, &v, &[0.0; 11])
        .expect_err("betas")
        .to_string();
    assert!(err.contains("11 betas"), "{err}");
    // A skeleton whose branches off the spine carry no arm joints (root, spine, head, and two
    // one-joint branches).
    let body = common::model(3);
    let err = BodyMeasurer::new(&body).expect_err("no arms").to_string();
    assert!(err.contains("no arms"), "{err}");
}

#[test]
fn a_weight_alone_keeps_the_height_and_is_met() {
    let (model, space) = builtin();
    let (_, _, neutral) = measure(&model, &space, "female");
    let (_, _, m) = measure(&model, &space, "female, 75 kg");
    assert!(
        (m.height_m - neutral.height_m).abs() < 0.002,
        "{neutral} / {m}"
    );
    assert!((m.mass_kg - 75.0).abs() < 0.05 * 75.0, "{m}");
    assert!(m.waist_m > neutral.waist_m + 0.05, "{neutral} / {m}");
    // The edges of what a request may ask: errors naming the miss, never a body off the mark.
    for (text, want) in [
        ("female, mass_kg=300", "mass 300.0 kg (reached"),
        ("female, 1.45 m, waist_cm=200", "waist 200.0 cm (reached"),
        ("male, 2.10 m, chest_cm=50", "chest 50.0 cm (reached"),
        (
            "chest_cm=200, waist_cm=40, hips_cm=200",
            "waist 40.0 cm (reached",
        ),
    ] {
        let request: PhenotypeRequest = text.parse().expect("valid");
        let err = space
            .betas_for(&model, &request)
            .expect_err(text)
            .to_string();
        assert!(err.contains(want), "{text}: {err}");
    }
}
