//! [`GarmentNetwork`]: a loaded model in the chosen precision, with allocation-free single and
//! batched evaluation of the fit MLP, the wrinkle GRU and the linear baseline.

use std::path::Path;

use crate::error::{Error, Result, check_finite, check_len};
use crate::format::{GarmentModel, MeanStd, ModelHeader, OutputKind};
use crate::kernels::{
    GruCell, GruScratch, Linear, Matrix, Mlp, MlpScratch, OutputLayer, OutputScratch, Parallelism,
    Precision,
};
use crate::lowrank::truncated_svd;

/// Whether a call of several products, some of which `splits` across rayon's threads, should
/// run inside [`sartor_core::awake::with_workers_awake`]: on a worker of the pool, entered
/// once, while the other workers poll for work. True for [`Parallelism::Rayon`] unless this
/// thread already runs such a call. Entered from outside once per product, the shipped
/// model's step took longer on two threads than on one (AMD EPYC VM: 46–62 µs in f32 against
/// 39–41; entered once, 31–33); inside the pool the helper still fell asleep between the
/// step's products (Intel Xeon VM, fresh two-thread pools: 27–29 µs in most frames, 68–80,
/// its one-thread time, in up to half of them; polling, 27–30 in every pool: see
/// `docs/speed-log.md`).
/// A call whose products all stay on the calling thread does not move (entering cost the int8
/// step 8.5 → 20–21 µs).
fn runs_awake(splits: bool, par: Parallelism) -> bool {
    splits && par == Parallelism::Rayon && !sartor_core::awake::is_awake()
}

/// `x ↦ (x − mean) / std` into `out`.
fn normalise(x: &[f32], stats: &MeanStd, out: &mut [f32]) {
    let n = stats.mean.len();
    for (o, xs) in out.chunks_exact_mut(n).zip(x.chunks_exact(n)) {
        for ((o, &v), (m, s)) in o.iter_mut().zip(xs).zip(stats.mean.iter().zip(&stats.std)) {
            *o = (v - m) / s;
        }
    }
}

/// `out[b·n + i] = y_t[i·B + b] · std_i + mean_i` (for `B = 1`, `y_t` may be `out` itself:
/// see [`denormalise_in_place`]).
fn denormalise_t(y_t: &[f32], batch: usize, stats: &MeanStd, out: &mut [f32]) {
    let n = stats.mean.len();
    for (b, o) in out.chunks_exact_mut(n).enumerate() {
        for (i, (o, (m, s))) in o
            .iter_mut()
            .zip(stats.mean.iter().zip(&stats.std))
            .enumerate()
        {
            *o = y_t[i * batch + b] * s + m;
        }
    }
}

crate::kernels::widest_where_present! {
    /// `y_i = y_i · std_i + mean_i`, built for the widest vectors present: the baseline
    /// x86-64 build ran it four lanes at a time, 7 % of the shipped model's int8 step (its
    /// 6,504 outputs); multiply then add in every build, so the same bits.
    fn denormalise_in_place(y: &mut [f32], stats: &MeanStd) {
        for (o, (m, s)) in y.iter_mut().zip(stats.mean.iter().zip(&stats.std)) {
            *o = *o * s + m;
        }
    }
}

/// By default a batch of avatars shares one pass over the wrinkle weights
/// ([`GarmentNetwork::wrinkle_step_batch`]) from this many bytes of them; below, each avatar is
/// stepped alone. For eight on one thread, shared against alone (`cargo bench -p
/// sartor-runtime --bench kernels -- 'shipped/.*8|shared_line'`, 2-core Intel Xeon VM, whose
/// cores have 2 MB of L2): the shipped model (GRU 256, PCA 64) 0.91–1.07 against 0.52–0.70 ms
/// in f16 (1.4 MB), 0.21–0.25 against 0.14–0.16 in int8 (0.7 MB), level in f32 (2.8 MB); a
/// GRU 256 with a dense 6,504 output 0.54–0.67 against 0.45–0.50 in int8 (2.0 MB), but
/// 1.35–1.46 against 1.68–2.00 in f16 (3.9 MB) and 1.28–1.61 against 3.25–3.49 in f32 (7.7
/// MB); a GRU 512's int8 (4.3 MB) 1.00–1.18 against 1.82–2.04; the paper's size in every
/// precision. Not measured on a CPU with less L2 (the AMD EPYC VM's 1 MB), where the line may
/// lie lower.
const SHARED_PASS_FROM_BYTES: usize = 3 << 20;

/// Work buffers for one [`GarmentNetwork`], sized for batches of up to `capacity` avatars.
/// Make one per thread that evaluates the network; after that, no call allocates.
#[derive(Clone, Debug)]
pub struct Workspace {
    capacity: usize,
    /// `(n_betas, I, H, 3V, H_f)` of the network it was made for.
    sizes: [usize; 5],
    fit_x: Vec<f32>,
    wrinkle_x: Vec<f32>,
    mlp: MlpScratch,
    gru: GruScratch,
    output: OutputScratch,
    /// `[3V, B]` outputs before transposition (empty when `capacity == 1`).
    out_t: Vec<f32>,
}

impl Workspace {
    /// The largest batch it holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

/// How a network is loaded: the weight precision and, optionally, a reduced output rank. Part
/// of a level of detail ([`crate::LevelOfDetail`]); decided once, at load.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NetworkOptions {
    /// Storage of every weight matrix (biases and statistics stay f32).
    pub precision: Precision,
    /// Use a rank-`r` wrinkle output instead of the full one. A PCA-output model keeps its first
    /// `r ≤ k` components (the coefficient rows and basis columns); a dense model replaces its
    /// `3V × H` layer by a truncated SVD `(3V × r)(r × H)`, computed once here (see
    /// [`truncated_svd`]), which costs `r (3V + H)` instead of `3V H` multiply–adds per frame.
    /// `None` keeps the model's own output.
    pub output_rank: Option<usize>,
}

/// A garment model ready to run: `R_G(β)` (fit MLP) and `R_L(β, θ)` (wrinkle GRU + output
/// layer), optionally the linear baseline, with every weight matrix stored in one
/// [`Precision`].
///
/// Inputs are raw (un-normalised) features laid out as the model's header says; outputs are
/// garment displacements in metres, `3V` values ordered `(v·3 + c)`. The caller carries the
/// GRU state between frames (zeros at the start of a sequence, see
/// [`GarmentNetwork::initial_state`]). Results are bitwise independent of [`Parallelism`] and
/// of batching.
#[derive(Clone, Debug)]
pub struct GarmentNetwork {
    header: ModelHeader,
    precision: Precision,
    output_rank: Option<usize>,
    fit: Mlp,
    gru: GruCell,
    output: OutputLayer,
    lr: Option<Linear>,
    fit_in: MeanStd,
    fit_out: MeanStd,
    wrinkle_in: MeanStd,
    wrinkle_out: MeanStd,
    /// [`GarmentNetwork::set_shared_pass_from`].
    shared_pass_from: usize,
}

impl GarmentNetwork {
    /// Store the model's weight matrices in `precision` (biases and statistics stay f32).
    pub fn new(model: GarmentModel, precision: Precision) -> Result<Self> {
        Self::with_options(
            model,
            NetworkOptions {
                precision,
                output_rank: None,
            },
        )
    }

    /// Build with a precision and an optional reduced output rank ([`NetworkOptions`]).
    pub fn with_options(model: GarmentModel, options: NetworkOptions) -> Result<Self> {
        let precision = options.precision;
        let (header, w) = model.into_parts();
        let s = header.sizes;
        let (b, i, hf, h, o3) = (
            s.n_betas,
            s.wrinkle_inputs(),
            s.fit_hidden,
            s.gru_hidden,
            s.n_outputs(),
        );
        let linear = |rows, cols, weight, bias| -> Result<Linear> {
            Linear::new(Matrix::from_f32(rows, cols, weight, precision)?, bias)
        };
        let fit = Mlp::new(
            linear(hf, b, w.fit_hidden.weight, w.fit_hidden.bias)?,
            linear(o3, hf, w.fit_out.weight, w.fit_out.bias)?,
        )?;
        let gru = GruCell::new(
            Matrix::from_f32(3 * h, i, w.gru.weight_ih, precision)?,
            Matrix::from_f32(3 * h, h, w.gru.weight_hh, precision)?,
            w.gru.bias_ih,
            w.gru.bias_hh,
        )?;
        let out_rows = s.wrinkle_out_rows();
        let (out_w, out_b) = (w.wrinkle_out.weight, w.wrinkle_out.bias);
        let output = match (s.output, w.pca, options.output_rank) {
            (OutputKind::Pca(k), Some(pca), rank) => {
                let r = rank.unwrap_or(k);
                if r == 0 || r > k {
                    return Err(Error::invalid(
                        "output rank",
                        format!("{r} is not in 1..={k} (the model's PCA components)"),
                    ));
                }
                let basis: Vec<f32> = pca
                    .basis
                    .chunks_exact(k)
                    .flat_map(|row| row[..r].iter().copied())
                    .collect();
                OutputLayer::pca(
                    linear(r, h, out_w[..r * h].to_vec(), out_b[..r].to_vec())?,
                    Matrix::from_f32(o3, r, basis, precision)?,
                    pca.mean,
                )?
            }
            (OutputKind::Dense, None, None) => {
                OutputLayer::Dense(linear(out_rows, h, out_w, out_b)?)
            }
            (OutputKind::Dense, None, Some(r)) => {
                let low = truncated_svd(&out_w, o3, h, r)?;
                OutputLayer::pca(
                    linear(r, h, low.right, vec![0.0; r])?,
                    Matrix::from_f32(o3, r, low.left, precision)?,
                    out_b,
                )?
            }
            _ => {
                return Err(Error::invalid(
                    "model",
                    "PCA tensors present iff sizes.output is pca",
                ));
            }
        };
        let lr = match w.lr {
            Some(l) => Some(linear(o3, i, l.weight, l.bias)?),
            None => None,
        };
        Ok(Self {
            header,
            precision,
            output_rank: options.output_rank,
            fit,
            gru,
            output,
            lr,
            fit_in: w.norm.fit_in,
            fit_out: w.norm.fit_out,
            wrinkle_in: w.norm.wrinkle_in,
            wrinkle_out: w.norm.wrinkle_out,
            shared_pass_from: SHARED_PASS_FROM_BYTES,
        })
    }

    /// From how many bytes of wrinkle weights a batch shares one pass over them
    /// ([`GarmentNetwork::wrinkle_step_batch`]; 3 MiB unless set): below, each avatar is
    /// stepped alone. The same bits either way; 0 always shares the pass.
    pub fn set_shared_pass_from(&mut self, bytes: usize) {
        self.shared_pass_from = bytes;
    }

    /// [`GarmentModel::load`] then [`GarmentNetwork::new`]; errors name the file.
    pub fn load(dir: &Path, precision: Precision) -> Result<Self> {
        Self::load_with(
            dir,
            NetworkOptions {
                precision,
                output_rank: None,
            },
        )
    }

    /// [`GarmentModel::load`] then [`GarmentNetwork::with_options`]; errors name the file.
    pub fn load_with(dir: &Path, options: NetworkOptions) -> Result<Self> {
        let model = GarmentModel::load(dir)?;
        Self::with_options(model, options).map_err(|e| e.in_file(dir.join(crate::MODEL_TENSORS)))
    }

    /// The reduced output rank it was built with (`None`: the model's own output).
    pub fn output_rank(&self) -> Option<usize> {
        self.output_rank
    }

    /// Bytes held by the fit MLP's weight matrices.
    pub fn fit_weight_bytes(&self) -> usize {
        self.fit.weight_bytes()
    }

    /// Bytes held by the wrinkle regressor's weight matrices (GRU and output layer; the paper's
    /// "GRU" memory).
    pub fn wrinkle_weight_bytes(&self) -> usize {
        self.gru.weight_bytes() + self.output.weight_bytes()
    }

    /// The model's header (sizes, input layout, garment and body ids).
    pub fn header(&self) -> &ModelHeader {
        &self.header
    }

    /// Weight storage precision.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Number of shape coefficients (fit input size).
    pub fn n_betas(&self) -> usize {
        self.header.sizes.n_betas
    }

    /// Wrinkle input size `I`.
    pub fn input_size(&self) -> usize {
        self.gru.input_size()
    }

    /// GRU state size `H`.
    pub fn state_size(&self) -> usize {
        self.gru.hidden_size()
    }

    /// Output size `3V`.
    pub fn output_size(&self) -> usize {
        self.header.sizes.n_outputs()
    }

    /// Bytes held by all weight matrices (and int8 scales).
    pub fn weight_bytes(&self) -> usize {
        self.fit.weight_bytes()
            + self.gru.weight_bytes()
            + self.output.weight_bytes()
            + self.lr.as_ref().map_or(0, |l| l.weight().weight_bytes())
    }

    /// The GRU state at the start of a sequence: zeros.
    pub fn initial_state(&self) -> Vec<f32> {
        vec![0.0; self.state_size()]
    }

    /// Buffers for batches of up to `capacity` avatars (at least 1).
    pub fn workspace(&self, capacity: usize) -> Workspace {
        let capacity = capacity.max(1);
        let n_in = self.n_betas().max(self.input_size());
        Workspace {
            capacity,
            sizes: self.workspace_sizes(),
            fit_x: vec![0.0; self.n_betas() * capacity],
            wrinkle_x: vec![0.0; n_in * capacity],
            mlp: self.fit.scratch(capacity),
            gru: self.gru.scratch(capacity),
            output: self.output.scratch(capacity),
            out_t: if capacity > 1 {
                vec![0.0; self.output_size() * capacity]
            } else {
                Vec::new()
            },
        }
    }

    fn workspace_sizes(&self) -> [usize; 5] {
        [
            self.n_betas(),
            self.input_size(),
            self.state_size(),
            self.output_size(),
            self.fit.n_hidden(),
        ]
    }

    fn check_batch(&self, batch: usize, ws: &Workspace) -> Result<()> {
        if ws.sizes != self.workspace_sizes() {
            return Err(Error::invalid(
                "workspace",
                "it was made for a network of other sizes",
            ));
        }
        if batch == 0 || batch > ws.capacity {
            return Err(Error::invalid(
                "batch",
                format!("{batch} avatars, workspace holds 1 to {}", ws.capacity),
            ));
        }
        Ok(())
    }

    /// The fit displacement `R_G(β)` (`out`: `3V`, metres). Errors on non-finite β.
    pub fn fit(
        &self,
        betas: &[f32],
        out: &mut [f32],
        ws: &mut Workspace,
        par: Parallelism,
    ) -> Result<()> {
        self.fit_batch(betas, 1, out, ws, par)
    }

    /// [`GarmentNetwork::fit`] for `batch` shapes sharing one pass over the weights.
    ///
    /// # Shapes
    /// - `betas`: `[batch, n_betas]`, `out`: `[batch, 3V]`.
    pub fn fit_batch(
        &self,
        betas: &[f32],
        batch: usize,
        out: &mut [f32],
        ws: &mut Workspace,
        par: Parallelism,
    ) -> Result<()> {
        self.check_batch(batch, ws)?;
        // Before the other checks, which then run once, on the pool.
        if runs_awake(self.fit.splits(batch, par), par) {
            return sartor_core::awake::with_workers_awake(|| {
                self.fit_batch(betas, batch, out, ws, par)
            });
        }
        check_len("betas", betas.len(), batch * self.n_betas())?;
        check_len("fit output", out.len(), batch * self.output_size())?;
        check_finite("betas", betas)?;
        let x = &mut ws.fit_x[..batch * self.n_betas()];
        normalise(betas, &self.fit_in, x);
        if batch == 1 {
            self.fit.forward(x, out, &mut ws.mlp, par)?;
            denormalise_in_place(out, &self.fit_out);
        } else {
            let y_t = &mut ws.out_t[..batch * self.output_size()];
            self.fit.forward_batch_t(x, batch, y_t, &mut ws.mlp, par)?;
            denormalise_t(y_t, batch, &self.fit_out, out);
        }
        check_finite("fit output", out)
    }

    /// One frame of the wrinkle regressor `R_L`: advances `state` (`H`) with the wrinkle input
    /// `x_t` (`I`, raw features in the header's layout) and writes the wrinkle displacement
    /// (`3V`, metres) to `out`. Errors (before touching `state`) on non-finite `x_t` or
    /// `state`. Allocates nothing.
    pub fn wrinkle_step(
        &self,
        x_t: &[f32],
        state: &mut [f32],
        out: &mut [f32],
        ws: &mut Workspace,
        par: Parallelism,
    ) -> Result<()> {
        self.wrinkle_step_batch(x_t, 1, state, out, ws, par)
    }

    /// [`GarmentNetwork::wrinkle_step`] for `batch` avatars sharing one pass over the weights
    /// (from [`GarmentNetwork::set_shared_pass_from`] bytes of them; a smaller model's avatars
    /// are stepped one at a time); each avatar's state and output are bitwise equal to stepping
    /// it alone.
    ///
    /// # Shapes
    /// - `xs`: `[batch, I]`, `states`: `[batch, H]`, `out`: `[batch, 3V]`.
    pub fn wrinkle_step_batch(
        &self,
        xs: &[f32],
        batch: usize,
        states: &mut [f32],
        out: &mut [f32],
        ws: &mut Workspace,
        par: Parallelism,
    ) -> Result<()> {
        self.check_batch(batch, ws)?;
        if batch > 1 && self.wrinkle_weight_bytes() < self.shared_pass_from {
            // Weights that stay in cache gain nothing from one pass for all: each avatar alone
            // (the same bits), after every input and state is checked, so that an error
            // changes no state.
            self.check_step(xs, batch, states, out)?;
            let (n_in, n_h, n_out) = (self.input_size(), self.state_size(), self.output_size());
            let avatars = xs
                .chunks_exact(n_in)
                .zip(states.chunks_exact_mut(n_h))
                .zip(out.chunks_exact_mut(n_out));
            for ((x, state), out) in avatars {
                self.wrinkle_step_batch(x, 1, state, out, ws, par)?;
            }
            return Ok(());
        }
        // Before the other checks, which then run once, on the pool.
        let splits = self.gru.splits(batch, par) || self.output.splits(batch, par);
        if runs_awake(splits, par) {
            return sartor_core::awake::with_workers_awake(|| {
                self.wrinkle_step_batch(xs, batch, states, out, ws, par)
            });
        }
        self.check_step(xs, batch, states, out)?;
        let n_in = self.input_size();
        let x = &mut ws.wrinkle_x[..batch * n_in];
        normalise(xs, &self.wrinkle_in, x);
        self.gru.step_batch(x, batch, states, &mut ws.gru, par)?;
        if batch == 1 {
            self.output
                .forward_batch_t(states, 1, out, &mut ws.output, par)?;
            denormalise_in_place(out, &self.wrinkle_out);
        } else {
            let y_t = &mut ws.out_t[..batch * self.output_size()];
            self.output
                .forward_batch_t(states, batch, y_t, &mut ws.output, par)?;
            denormalise_t(y_t, batch, &self.wrinkle_out, out);
        }
        check_finite("wrinkle output", out)
    }

    /// The lengths of a wrinkle step's input, state and output for `batch` avatars, and that
    /// the input and state are finite.
    fn check_step(&self, xs: &[f32], batch: usize, states: &[f32], out: &[f32]) -> Result<()> {
        check_len("wrinkle input", xs.len(), batch * self.input_size())?;
        check_len("wrinkle state", states.len(), batch * self.state_size())?;
        check_len("wrinkle output", out.len(), batch * self.output_size())?;
        check_finite("wrinkle input", xs)?;
        check_finite("wrinkle state", states)
    }

    /// Whether the model carries the linear baseline.
    pub fn has_linear_baseline(&self) -> bool {
        self.lr.is_some()
    }

    /// The linear baseline in place of `R_L`: `out = (W x̂ + b) · std + mean` with `x̂` the
    /// normalised wrinkle input and the wrinkle output statistics. Errors when the model has
    /// no baseline or `x_t` is not finite.
    pub fn linear_baseline(
        &self,
        x_t: &[f32],
        out: &mut [f32],
        ws: &mut Workspace,
        par: Parallelism,
    ) -> Result<()> {
        let lr = self
            .lr
            .as_ref()
            .ok_or_else(|| Error::invalid("model", "it has no linear baseline"))?;
        let n_in = self.input_size();
        check_len("wrinkle input", x_t.len(), n_in)?;
        check_len("baseline output", out.len(), self.output_size())?;
        check_finite("wrinkle input", x_t)?;
        let x = &mut ws.wrinkle_x[..n_in];
        normalise(x_t, &self.wrinkle_in, x);
        lr.forward(x, out, par)?;
        denormalise_in_place(out, &self.wrinkle_out);
        check_finite("baseline output", out)
    }
}
