//! Binding other surfaces to the body: skin-weight transfer (the cloth skin weights `W_c` of
//! Santesteban et al.) and the selection of the body region a garment can touch. One
//! implementation each, on [`MeshProximity`], used by the simulator, the dataset and the
//! runtime alike.

use std::collections::BTreeMap;

use nalgebra::Vector3;

use crate::{Error, MeshProximity, Result, SkinWeights};

/// Skin weights for arbitrary `points` from a skinned surface: each point takes the closest
/// point on the surface (`positions`, `faces`, one weight row per surface vertex) and blends the
/// weights of that triangle's three vertices with the barycentric coordinates. Weights below
/// `min_weight` are dropped and the rest renormalised (use 0 to keep every influence).
///
/// This is how `W_c` is defined in the paper: "each template cloth vertex is projected on the
/// closest triangle of the template body; its weights are the barycentric blend of that
/// triangle's body weights".
pub fn transfer_skin_weights(
    positions: &[Vector3<f64>],
    faces: &[[u32; 3]],
    weights: &SkinWeights,
    points: &[Vector3<f64>],
    min_weight: f32,
) -> Result<SkinWeights> {
    if weights.n_points() != positions.len() {
        return Err(Error::invalid(
            "skin-weight transfer",
            format!(
                "{} weight rows for a surface of {} vertices",
                weights.n_points(),
                positions.len()
            ),
        ));
    }
    if !(min_weight.is_finite() && (0.0..0.5).contains(&min_weight)) {
        return Err(Error::invalid(
            "skin-weight transfer",
            format!("min_weight must be in [0, 0.5), got {min_weight}"),
        ));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(Error::invalid(
            "skin-weight transfer",
            format!("point {i} is not finite"),
        ));
    }
    let proximity = MeshProximity::new(positions, faces)?;
    let mut offsets = Vec::with_capacity(points.len() + 1);
    offsets.push(0u32);
    let (mut joints, mut values) = (Vec::new(), Vec::new());
    let mut row: BTreeMap<usize, f64> = BTreeMap::new();
    for p in points {
        let c = proximity.closest(p);
        row.clear();
        let face = faces[c.face as usize];
        for (k, &v) in face.iter().enumerate() {
            for (j, w) in weights.point(v as usize) {
                *row.entry(j).or_default() += c.barycentric[k] * w as f64;
            }
        }
        let kept: f64 = row.values().filter(|&&w| w >= min_weight as f64).sum();
        // The largest weight is at least 1/n_joints ≥ min_weight's bound, so `kept` > 0 unless
        // every weight is tiny; then keep them all.
        let threshold = if kept > 0.0 { min_weight as f64 } else { 0.0 };
        let total: f64 = row.values().filter(|&&w| w >= threshold).sum();
        for (&j, &w) in &row {
            if w >= threshold && w > 0.0 {
                joints.push(j as u32);
                values.push((w / total) as f32);
            }
        }
        offsets.push(joints.len() as u32);
    }
    SkinWeights::new(offsets, joints, values, weights.n_joints())
}

/// The faces of a surface (`positions`, `faces`) with at least one vertex within `margin_m` of
/// another surface (`other_positions`, `other_faces`), ascending. Used to restrict body contact
/// to the region a garment can reach.
pub fn faces_near(
    positions: &[Vector3<f64>],
    faces: &[[u32; 3]],
    other_positions: &[Vector3<f64>],
    other_faces: &[[u32; 3]],
    margin_m: f64,
) -> Result<Vec<u32>> {
    if !(margin_m.is_finite() && margin_m >= 0.0) {
        return Err(Error::invalid(
            "region selection",
            format!("margin must be finite and ≥ 0, got {margin_m}"),
        ));
    }
    let other = MeshProximity::new(other_positions, other_faces)?;
    let near: Vec<bool> = positions
        .iter()
        .map(|p| other.closest_within(p, margin_m).is_some())
        .collect();
    Ok(faces
        .iter()
        .enumerate()
        .filter(|(_, t)| t.iter().any(|&v| near[v as usize]))
        .map(|(f, _)| f as u32)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles in the z = 0 plane: a unit square split on its diagonal.
    fn square() -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        (
            vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(1.0, 0.0, 0.0),
                Vector3::new(1.0, 1.0, 0.0),
                Vector3::new(0.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn transferred_weights_are_the_barycentric_blend() {
        let (positions, faces) = square();
        // Vertex 0, 1 on joint 0; 2 on joint 1; 3 half-half.
        let weights = SkinWeights::new(
            vec![0, 1, 2, 3, 5],
            vec![0, 0, 1, 0, 1],
            vec![1.0, 1.0, 1.0, 0.5, 0.5],
            2,
        )
        .expect("valid");
        // Above the first triangle at barycentric (0.2, 0.5, 0.3): x = 0.8, y = 0.3.
        let points = [Vector3::new(0.8, 0.3, 0.05)];
        let w = transfer_skin_weights(&positions, &faces, &weights, &points, 0.0).expect("ok");
        let dense = w.to_dense();
        assert!((dense[0] - 0.7).abs() < 1e-6, "{dense:?}");
        assert!((dense[1] - 0.3).abs() < 1e-6, "{dense:?}");
        // Dropping influences below 0.4 keeps joint 0 alone.
        let w = transfer_skin_weights(&positions, &faces, &weights, &points, 0.4).expect("ok");
        assert_eq!(w.point(0).collect::<Vec<_>>(), vec![(0, 1.0)]);
    }

    #[test]
    fn transfer_rejects_bad_input() {
        let (positions, faces) = square();
        let weights = SkinWeights::from_dense_top_k(&[1.0; 3], 1, 1).expect("valid");
        let p = [Vector3::zeros()];
        assert!(transfer_skin_weights(&positions, &faces, &weights, &p, 0.0).is_err());
        let weights = SkinWeights::from_dense_top_k(&[1.0; 4], 1, 1).expect("valid");
        let nan = [Vector3::new(f64::NAN, 0.0, 0.0)];
        assert!(transfer_skin_weights(&positions, &faces, &weights, &nan, 0.0).is_err());
        assert!(transfer_skin_weights(&positions, &faces, &weights, &p, 0.7).is_err());
    }

    #[test]
    fn faces_near_selects_by_vertex_distance() {
        let (positions, faces) = square();
        // A small triangle 0.1 above vertex 3 (0, 1, 0).
        let other = vec![
            Vector3::new(-0.05, 1.0, 0.1),
            Vector3::new(0.0, 1.05, 0.1),
            Vector3::new(-0.05, 1.05, 0.1),
        ];
        let near = faces_near(&positions, &faces, &other, &[[0, 1, 2]], 0.15).expect("ok");
        assert_eq!(near, vec![1]);
        let none = faces_near(&positions, &faces, &other, &[[0, 1, 2]], 0.05).expect("ok");
        assert!(none.is_empty());
        assert!(faces_near(&positions, &faces, &other, &[[0, 1, 2]], -1.0).is_err());
    }
}
