//! Batches for training, deterministic under a seed.
//!
//! - The wrinkle GRU learns from whole sequences, a batch of sequences at a time, cut into
//!   windows of `window_len` frames for truncated backpropagation through time
//!   ([`sequence_batches`], [`window`]): the hidden state is carried from one window of a batch
//!   to the next (the caller detaches it) and starts at zero for each batch. Shorter sequences
//!   are padded with zeros and masked out ([`Window::mask`]).
//! - The linear baseline learns from shuffled frames ([`frame_batches`], [`gather_frames`]).
//! - The fit MLP learns from shapes ([`gather_shapes`]).
//!
//! Every gather returns normalised values (see [`crate::NormStats`]).

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use crate::TrainingData;

/// A deterministic permutation of `items` for `(seed, epoch)`.
pub fn shuffled<T: Clone>(items: &[T], seed: u64, epoch: u64) -> Vec<T> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ epoch.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let mut out = items.to_vec();
    out.shuffle(&mut rng);
    out
}

/// Sequence indices shuffled for `(seed, epoch)` and cut into batches of at most `batch_size`.
pub fn sequence_batches(
    sequences: &[usize],
    batch_size: usize,
    seed: u64,
    epoch: u64,
) -> Vec<Vec<usize>> {
    shuffled(sequences, seed, epoch)
        .chunks(batch_size.max(1))
        .map(<[usize]>::to_vec)
        .collect()
}

/// One TBPTT window of a batch of sequences, normalised.
#[derive(Clone, Debug, PartialEq)]
pub struct Window {
    /// Sequences in the batch `B`.
    pub batch: usize,
    /// Frames in the window `L` (the last window may be shorter than the others).
    pub len: usize,
    /// First frame of the window.
    pub start: usize,
    /// Inputs `[B, L, n_inputs]`, zero where masked.
    pub inputs: Vec<f32>,
    /// Targets `Δ_L` `[B, L, 3V]`, zero where masked.
    pub targets: Vec<f32>,
    /// 1 for a real frame, 0 for padding, `[B, L]`.
    pub mask: Vec<f32>,
}

/// The number of windows of `window_len` frames that cover the longest sequence in `batch`.
pub fn window_count(data: &TrainingData, batch: &[usize], window_len: usize) -> usize {
    let longest = batch
        .iter()
        .map(|&s| data.sequences()[s].n_frames)
        .max()
        .unwrap_or(0);
    longest.div_ceil(window_len.max(1))
}

/// Window `index` (frames `index·window_len ..`) of `batch`.
pub fn window(data: &TrainingData, batch: &[usize], window_len: usize, index: usize) -> Window {
    let window_len = window_len.max(1);
    let longest = batch
        .iter()
        .map(|&s| data.sequences()[s].n_frames)
        .max()
        .unwrap_or(0);
    let start = index * window_len;
    let len = longest.saturating_sub(start).min(window_len);
    let (n_in, n_out) = (data.n_inputs(), data.n_outputs());
    let b = batch.len();
    let mut w = Window {
        batch: b,
        len,
        start,
        inputs: vec![0.0; b * len * n_in],
        targets: vec![0.0; b * len * n_out],
        mask: vec![0.0; b * len],
    };
    let stats = data.stats();
    for (row, &s) in batch.iter().enumerate() {
        let q = &data.sequences()[s];
        let end = q.n_frames.min(start + len);
        for (k, t) in (start..end).enumerate() {
            let slot = row * len + k;
            w.mask[slot] = 1.0;
            let x = &mut w.inputs[slot * n_in..(slot + 1) * n_in];
            x.copy_from_slice(&q.inputs[t * n_in..(t + 1) * n_in]);
            stats.wrinkle_in.normalize(x);
            let y = &mut w.targets[slot * n_out..(slot + 1) * n_out];
            y.copy_from_slice(&q.wrinkle_delta[t * n_out..(t + 1) * n_out]);
            stats.wrinkle_out.normalize(y);
        }
    }
    w
}

/// Every frame `(sequence, frame)` of `sequences`, shuffled for `(seed, epoch)`, in batches.
pub fn frame_batches(
    data: &TrainingData,
    sequences: &[usize],
    batch_size: usize,
    seed: u64,
    epoch: u64,
) -> Vec<Vec<(usize, usize)>> {
    let frames: Vec<(usize, usize)> = sequences
        .iter()
        .flat_map(|&s| (0..data.sequences()[s].n_frames).map(move |t| (s, t)))
        .collect();
    shuffled(&frames, seed, epoch)
        .chunks(batch_size.max(1))
        .map(<[(usize, usize)]>::to_vec)
        .collect()
}

/// Normalised inputs `[N, n_inputs]` and `Δ_L` targets `[N, 3V]` of the given frames.
pub fn gather_frames(data: &TrainingData, frames: &[(usize, usize)]) -> (Vec<f32>, Vec<f32>) {
    let (n_in, n_out) = (data.n_inputs(), data.n_outputs());
    let mut x = Vec::with_capacity(frames.len() * n_in);
    let mut y = Vec::with_capacity(frames.len() * n_out);
    for &(s, t) in frames {
        let q = &data.sequences()[s];
        x.extend_from_slice(&q.inputs[t * n_in..(t + 1) * n_in]);
        y.extend_from_slice(&q.wrinkle_delta[t * n_out..(t + 1) * n_out]);
    }
    data.stats().wrinkle_in.normalize(&mut x);
    data.stats().wrinkle_out.normalize(&mut y);
    (x, y)
}

/// Normalised β `[N, n_betas]` and `Δ_G` targets `[N, 3V]` of the given shapes.
pub fn gather_shapes(data: &TrainingData, shapes: &[usize]) -> (Vec<f32>, Vec<f32>) {
    let mut x = Vec::with_capacity(shapes.len() * data.n_betas());
    let mut y = Vec::with_capacity(shapes.len() * data.n_outputs());
    for &s in shapes {
        x.extend_from_slice(&data.shapes()[s].betas);
        y.extend_from_slice(&data.shapes()[s].fit_delta);
    }
    data.stats().fit_in.normalize(&mut x);
    data.stats().fit_out.normalize(&mut y);
    (x, y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{InputLayout, MeanStd, NormStats, SequenceSample, ShapeSample, Split};
    use sartor_core::{PoseFeatureSpec, RotationEncoding};

    fn ones(n: usize) -> MeanStd {
        MeanStd {
            mean: vec![0.0; n],
            std: vec![1.0; n],
        }
    }

    /// One vertex, one β, no pose features; sequences of 5 and 3 frames whose values count
    /// frames.
    fn data() -> TrainingData {
        let layout = InputLayout {
            n_betas: 1,
            pose: PoseFeatureSpec {
                joints: vec![],
                encoding: RotationEncoding::Rot6d,
                root: vec![],
            },
        };
        let shape = ShapeSample {
            id: "s0".into(),
            betas: vec![0.5],
            fit_delta: vec![0.0; 3],
            split: Split::Train,
        };
        let seq = |id: &str, n: usize, base: f32| SequenceSample {
            id: id.into(),
            shape: 0,
            motion: id.into(),
            split: Split::Train,
            n_frames: n,
            inputs: (0..n).map(|t| base + t as f32).collect(),
            wrinkle_delta: (0..3 * n).map(|k| base + (k / 3) as f32).collect(),
        };
        let stats = NormStats {
            fit_in: ones(1),
            wrinkle_in: ones(1),
            fit_out: ones(3),
            wrinkle_out: ones(3),
        };
        TrainingData::new(
            crate::DataSource {
                garment: sartor_core::asset::AssetId {
                    id: "g".into(),
                    sha256: "0".repeat(64),
                },
                body: sartor_core::asset::AssetId {
                    id: "b".into(),
                    sha256: "1".repeat(64),
                },
            },
            1,
            layout,
            vec![shape],
            vec![seq("a", 5, 100.0), seq("b", 3, 200.0)],
            stats,
            None,
        )
        .expect("valid data")
    }

    #[test]
    fn windows_cover_every_frame_once_and_mask_padding() {
        let d = data();
        let batch = [0, 1];
        assert_eq!(window_count(&d, &batch, 2), 3);
        let mut seen = Vec::new();
        for i in 0..3 {
            let w = window(&d, &batch, 2, i);
            assert_eq!(w.start, 2 * i);
            for row in 0..2 {
                for k in 0..w.len {
                    if w.mask[row * w.len + k] == 1.0 {
                        seen.push(w.inputs[row * w.len + k]);
                    } else {
                        assert_eq!(w.inputs[row * w.len + k], 0.0);
                    }
                }
            }
        }
        seen.sort_by(f32::total_cmp);
        assert_eq!(
            seen,
            vec![100.0, 101.0, 102.0, 103.0, 104.0, 200.0, 201.0, 202.0]
        );
        // The last window holds one frame of the longer sequence only.
        let last = window(&d, &batch, 2, 2);
        assert_eq!((last.len, last.mask.clone()), (1, vec![1.0, 0.0]));
    }

    #[test]
    fn shuffles_are_deterministic_and_change_with_the_epoch() {
        let items: Vec<usize> = (0..50).collect();
        assert_eq!(shuffled(&items, 7, 3), shuffled(&items, 7, 3));
        assert_ne!(shuffled(&items, 7, 3), shuffled(&items, 7, 4));
        let mut sorted = shuffled(&items, 7, 3);
        sorted.sort_unstable();
        assert_eq!(sorted, items);
        let d = data();
        let batches = frame_batches(&d, &[0, 1], 3, 1, 0);
        assert_eq!(batches.iter().map(Vec::len).sum::<usize>(), 8);
        let (x, y) = gather_frames(&d, &batches[0]);
        assert_eq!((x.len(), y.len()), (3, 9));
        for (k, &(s, t)) in batches[0].iter().enumerate() {
            assert_eq!(x[k], d.sequences()[s].inputs[t]);
        }
    }

    #[test]
    fn bad_sizes_are_rejected() {
        let d = data();
        let with_sequences = |seqs| {
            TrainingData::new(
                d.source().clone(),
                1,
                d.layout().clone(),
                d.shapes().to_vec(),
                seqs,
                d.stats().clone(),
                None,
            )
        };
        let mut seqs = d.sequences().to_vec();
        seqs[0].inputs.pop();
        assert!(with_sequences(seqs).is_err());
        let mut seqs = d.sequences().to_vec();
        seqs[1].wrinkle_delta[0] = f32::NAN;
        assert!(with_sequences(seqs).is_err());
    }
}
