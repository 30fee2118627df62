//! The wrinkle GRU's contact term: an extension of the paper's loss, off by default
//! ([`crate::TrainingConfig::contact_weight`] 0).
//!
//! The paper trains the GRU on the squared error of `Δ_L` alone. Where the cloth lies on the
//! body (shoulders, chest, back) an error of a millimetre inwards puts a vertex inside the body,
//! and an error outwards costs the same: on the held-out motions about a tenth of the shipped
//! model's cloth vertex-frames lie inside the body before the post-process, against less than a
//! thousandth in the simulated ground truth, and the post-process pushes each of them out every
//! frame. Nearly all of them are inside in the rest pose already (the network's garment `T̄ + Δ_G +
//! Δ_L` against the body at its shape, unposed), so the term is taken there.
//!
//! Per training shape `β`, the fit's garment `x_G = T̄ + Δ_G(β)` (its ground truth) has, per
//! vertex, a closest point `c` on the body in the rest pose at `β`, the pseudo-normal `n` there
//! and a signed height `h = (x_G − c)·n`. A predicted displacement `Δ̂_L` of a frame whose ground
//! truth is `Δ_L` is penalised by
//!
//! `max(0, min(ε − h, Δ_L·n) − Δ̂_L·n)²`
//!
//! the depth by which the prediction lies below both the margin `ε` above the body and the
//! ground truth, along `n`: nothing where the prediction is as high as the ground truth or
//! clear of the body by `ε`, and nothing for a perfect prediction. The height is taken on the
//! body's tangent plane at `c` (the wrinkle displacements are centimetres, the body's curvature
//! radii decimetres), so a vertex the ground truth moves along a curved surface is compared
//! with the ground truth on the same plane, never pushed off it. In the loss it is divided by
//! the mean variance of the normalised displacements' components, so that a weight of 1 counts
//! a millimetre of depth as a millimetre of error of one component.

use nalgebra::Vector3;
use sartor_core::{BodyModel, MeshProximity};
use sartor_dataset::TrainingData;

use crate::{Error, Result};

/// Per training shape and garment vertex, the body's normal and the fit garment's height above
/// the body in the rest pose (see the module docs).
#[derive(Clone, Debug)]
pub struct RestContact {
    n_vertices: usize,
    /// Per shape, per vertex: the body's unit pseudo-normal at the closest point.
    normals: Vec<[f32; 3]>,
    /// Per shape, per vertex: the fit garment's signed height above the body, metres.
    heights: Vec<f32>,
}

impl RestContact {
    /// The contact of every shape of `data`, with its garment's `template` (`T̄`, the dataset's
    /// binding) on `body` (the body model the data was simulated on).
    pub fn new(data: &TrainingData, template: &[Vector3<f32>], body: &BodyModel) -> Result<Self> {
        let n = data.n_vertices();
        if template.len() != n {
            return Err(Error::invalid(
                "contact term",
                format!(
                    "the garment template has {} vertices, the training data {n}",
                    template.len()
                ),
            ));
        }
        let mut normals = Vec::with_capacity(data.shapes().len() * n);
        let mut heights = Vec::with_capacity(data.shapes().len() * n);
        for shape in data.shapes() {
            let betas: Vec<f64> = shape.betas.iter().map(|&b| f64::from(b)).collect();
            let rest = body.shaped_vertices(&betas)?;
            let proximity = MeshProximity::new(&rest, body.faces())?;
            for (t, d) in template.iter().zip(shape.fit_delta.chunks_exact(3)) {
                let x = Vector3::new(t.x + d[0], t.y + d[1], t.z + d[2]).cast::<f64>();
                let closest = proximity.closest(&x);
                normals.push(closest.normal.cast::<f32>().into());
                heights.push(closest.signed_distance_m as f32);
            }
        }
        Ok(Self {
            n_vertices: n,
            normals,
            heights,
        })
    }

    /// The garment's vertices.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// The training data's shapes it was made for.
    pub fn n_shapes(&self) -> usize {
        self.heights.len() / self.n_vertices.max(1)
    }

    /// Shape `shape`'s normals, one per vertex.
    pub fn normals(&self, shape: usize) -> &[[f32; 3]] {
        &self.normals[shape * self.n_vertices..(shape + 1) * self.n_vertices]
    }

    /// Shape `shape`'s heights of the fit garment above the body, metres, one per vertex.
    pub fn heights(&self, shape: usize) -> &[f32] {
        &self.heights[shape * self.n_vertices..(shape + 1) * self.n_vertices]
    }
}

/// The term as the GRU's windows read it, in normalised units: per shape, `a = σ ∘ n` per output
/// component and the room `ε − h − μ·n` per vertex (`μ`, `σ`: the displacements' normalisation),
/// so that a normalised prediction `p` lies at `a·p − (ε − h − μ·n)` above the margin.
pub(crate) struct ContactTerm {
    n_vertices: usize,
    a: Vec<f32>,
    room: Vec<f32>,
    /// The configured weight over the mean variance of the components.
    pub weight: f64,
}

/// The room given to a padding row: far below any prediction, so never penalised.
const PADDING_ROOM: f32 = -1e3;

impl ContactTerm {
    pub fn new(contact: &RestContact, data: &TrainingData, weight: f64, margin_m: f64) -> Self {
        let stats = &data.stats().wrinkle_out;
        let n = contact.n_vertices;
        let n_shapes = data.shapes().len();
        let mut a = Vec::with_capacity(n_shapes * 3 * n);
        let mut room = Vec::with_capacity(n_shapes * n);
        for s in 0..n_shapes {
            for (v, (normal, &h)) in contact
                .normals(s)
                .iter()
                .zip(contact.heights(s))
                .enumerate()
            {
                let mut mean_along = 0.0;
                for k in 0..3 {
                    a.push(stats.std[3 * v + k] * normal[k]);
                    mean_along += stats.mean[3 * v + k] * normal[k];
                }
                room.push(margin_m as f32 - h - mean_along);
            }
        }
        let variance =
            stats.std.iter().map(|s| f64::from(s * s)).sum::<f64>() / stats.std.len() as f64;
        Self {
            n_vertices: n,
            a,
            room,
            weight: weight / variance,
        }
    }

    /// The window's `a` (`[rows, 3V]`) and floors `min(room, a·y)` (`[rows, V]`; a prediction
    /// `p` is penalised by `max(0, floor − a·p)²`) for the sequences `batch` (rows `b·len + t`,
    /// normalised targets `targets`, `mask` 0 on padding rows).
    pub fn window(
        &self,
        data: &TrainingData,
        batch: &[usize],
        len: usize,
        targets: &[f32],
        mask: &[f32],
    ) -> (Vec<f32>, Vec<f32>) {
        let n = self.n_vertices;
        let rows = batch.len() * len;
        let mut a = vec![0.0f32; rows * 3 * n];
        let mut floor = vec![PADDING_ROOM; rows * n];
        for (b, &q) in batch.iter().enumerate() {
            let s = data.sequences()[q].shape;
            let (shape_a, shape_room) = (
                &self.a[s * 3 * n..(s + 1) * 3 * n],
                &self.room[s * n..(s + 1) * n],
            );
            for t in 0..len {
                let row = b * len + t;
                if mask[row] <= 0.0 {
                    continue;
                }
                a[row * 3 * n..(row + 1) * 3 * n].copy_from_slice(shape_a);
                let y = &targets[row * 3 * n..(row + 1) * 3 * n];
                for (v, f) in floor[row * n..(row + 1) * n].iter_mut().enumerate() {
                    let along: f32 = (0..3).map(|k| shape_a[3 * v + k] * y[3 * v + k]).sum();
                    *f = shape_room[v].min(along);
                }
            }
        }
        (a, floor)
    }
}
