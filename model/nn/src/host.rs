//! The trained network's inference forward on the host, in plain `f32` (`--runtime native`).
//!
//! At batch 1 a Burn backend spends most of a network call in per-operation overhead: each of
//! the ~110 tensor operations of an iteration on `[1, 128]` rows costs about a microsecond of
//! dispatch, more than its arithmetic (`docs/results/cost-model.md`). [`HostNet`] copies the
//! weights of a [`NeuralNet`] once and runs the same layers as loops over rows: Linear
//! (`y = x W + b`, `W` `[in, out]` as Burn stores it), LayerNorm, BatchNorm with its running
//! statistics (inference mode), the layer-normalized GRU of papers/002 supp. eq. (12), the
//! residual MLP core, the initializers Φ/Φh, the λ/γ network and the update rules of
//! [`NeuralNet::update`]. It is inference only (no autodiff, no dropout) and is tested against
//! the Burn modules it was read from (`tests.rs`, `host_forward_matches_burn_*`).
//!
//! It runs through [`crate::unroll::unroll_rows`], the same host loop as ONNX Runtime.

use std::ops::Range;

use burn::nn::{BatchNorm, LayerNorm, LayerNormConfig, Linear};
use burn::tensor::Tensor;
use rayon::prelude::*;
use wide::f32x4;

use crate::config::{NetConfig, UpdateRule};
use crate::features::FeatureStats;
use crate::layers::{GruStack, InitMlp, LnGruCell, ResidualMlp};
use crate::net::{Core, NeuralNet};
use crate::unroll::{RowNetwork, RowState, StepOut};
use lfit_model::error::{ModelError, Result};

/// Output columns a Linear layer accumulates at once: 32 `f32` accumulators stay in registers
/// (eight SSE registers) while the input is streamed, one weight load per four multiply-adds
/// (a `[575] × [575, 384]` product: 25 µs as one `axpy` per input, 14 µs in blocks of 32).
const LANES: usize = 32;

/// Host values of a Burn tensor, row-major.
pub fn values<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| ModelError::Config(format!("cannot read the network's weights: {e:?}")))
}

/// Epsilon of the LayerNorms lfit builds (Burn's `LayerNormConfig` default: the field is
/// private in Burn, and every LayerNorm of the network is created with the default).
pub fn layer_norm_epsilon() -> f64 {
    LayerNormConfig::new(1).epsilon
}

/// `y = x W + b` (`W` `[in, out]` as Burn stores it), the weights packed in blocks of [`LANES`]
/// output columns: block `k` holds `W[i, 32k..32k + 32]` for every input `i` in turn (the last
/// block zero-padded), so one block streams contiguously past its accumulators. The arithmetic is
/// explicit SIMD: 4-wide `wide::f32x4` (SSE2, the portable build's), or 8-wide AVX where the
/// machine has AVX2 (`pulp::x86::V3`, detected at run time; no `unsafe` in lfit). The compiler
/// does not vectorise the 32 scalar accumulators reliably (measured: it kept them scalar here).
/// Both paths compute every output as the same sequence of rounded multiplies and adds (no fused
/// multiply-add), so they agree to the bit and a fit does not depend on the machine's vector
/// width (`the_avx_path_computes_the_portable_paths_bits`).
#[derive(Debug, Clone)]
struct HostLinear {
    packed: Vec<f32>,
    /// The bias, zero-padded to whole blocks of [`LANES`] outputs.
    bias: Vec<f32>,
    d_in: usize,
    d_out: usize,
    /// AVX2's token where the machine has it (the 8-wide path), else `None` (the 4-wide one).
    #[cfg(target_arch = "x86_64")]
    avx: Option<pulp::x86::V3>,
}

impl HostLinear {
    fn new(linear: &Linear) -> Result<Self> {
        let (w, b, d_in, d_out) = Self::read(linear)?;
        Self::pack(&w, d_out, 0..d_in, b)
    }

    /// The weights `[in, out]` row-major, the bias, `in` and `out` of a Burn Linear.
    fn read(linear: &Linear) -> Result<(Vec<f32>, Vec<f32>, usize, usize)> {
        let [d_in, d_out] = linear.weight.val().dims();
        let w = values(linear.weight.val())?;
        let b = match &linear.bias {
            Some(b) => values(b.val())?,
            None => vec![0.0; d_out],
        };
        if b.len() != d_out {
            return Err(shape("Linear bias", d_out, b.len()));
        }
        Ok((w, b, d_in, d_out))
    }

    /// The layer `x W[rows] + bias` of the input rows `rows` of `w` (`[in, out]` row-major).
    fn pack(w: &[f32], d_out: usize, rows: Range<usize>, bias: Vec<f32>) -> Result<Self> {
        let d_in = rows.len();
        let blocks = d_out.div_ceil(LANES);
        let mut packed = vec![0.0f32; blocks * d_in * LANES];
        for (k, block) in packed.chunks_exact_mut(d_in * LANES).enumerate() {
            for (i, lanes) in block.chunks_exact_mut(LANES).enumerate() {
                for (l, v) in lanes.iter_mut().enumerate() {
                    let j = k * LANES + l;
                    if j < d_out {
                        *v = w[(rows.start + i) * d_out + j];
                    }
                }
            }
        }
        let mut bias = bias;
        bias.resize(blocks * LANES, 0.0);
        Ok(Self {
            packed,
            bias,
            d_in,
            d_out,
            #[cfg(target_arch = "x86_64")]
            avx: if wide_simd()? {
                pulp::x86::V3::try_new()
            } else {
                None
            },
        })
    }

    /// `linear` as two layers over its inputs `..at` and `at..`: the first without the bias,
    /// the second with it. `b + x[at..] W[at..]` computed once serves as the start of
    /// `x[..at] W[..at]` ([`HostLinear::forward_from`]) for any `x[..at]`.
    fn split(linear: &Linear, at: usize) -> Result<(Self, Self)> {
        let (w, b, d_in, d_out) = Self::read(linear)?;
        if at > d_in {
            return Err(shape("split Linear input", d_in, at));
        }
        Ok((
            Self::pack(&w, d_out, 0..at, vec![0.0; d_out])?,
            Self::pack(&w, d_out, at..d_in, b)?,
        ))
    }

    /// A one-line error unless this layer is `[d_in, d_out]`.
    fn expect(&self, what: &str, d_in: usize, d_out: usize) -> Result<()> {
        expect_layer(what, (d_in, d_out), (self.d_in, self.d_out))
    }

    /// `x` `[batch, in]` → `[batch, out]`; each output is `b_j + Σ_i x_i W_ij` summed in the
    /// order of `i`. A block of weights serves every row of the batch before the next block.
    ///
    /// Batches of at least twice [`PARALLEL_ROWS`] rows are split into blocks of that many rows
    /// over rayon's threads: every row is computed by the same loop whichever thread runs it, so the
    /// result does not depend on the number of threads.
    fn forward(&self, x: &[f32], batch: usize) -> Vec<f32> {
        self.forward_with(x, self.d_in, batch, None)
    }

    /// `start + x[.., ..in] W`: `x` `[batch, stride]` of which each row's first `in` columns are
    /// read, `start` `[batch, out]` in place of the bias (the first sum of every output).
    fn forward_from(&self, x: &[f32], stride: usize, batch: usize, start: &[f32]) -> Vec<f32> {
        self.forward_with(x, stride, batch, Some(start))
    }

    fn forward_with(
        &self,
        x: &[f32],
        stride: usize,
        batch: usize,
        start: Option<&[f32]>,
    ) -> Vec<f32> {
        let (d_in, d_out) = (self.d_in, self.d_out);
        debug_assert!(stride >= d_in);
        debug_assert_eq!(x.len(), batch * stride);
        debug_assert!(start.is_none_or(|s| s.len() == batch * d_out));
        let mut y = vec![0.0f32; batch * d_out];
        if batch >= 2 * PARALLEL_ROWS {
            let rows = PARALLEL_ROWS;
            x.par_chunks(rows * stride)
                .zip(y.par_chunks_mut(rows * d_out))
                .enumerate()
                .for_each(|(k, (x, y))| {
                    let start = start.map(|s| &s[k * rows * d_out..][..y.len()]);
                    self.forward_rows(x, stride, start, y)
                });
        } else {
            self.forward_rows(x, stride, start, &mut y);
        }
        y
    }

    /// [`HostLinear::forward_with`] of the rows of `x` into `y` (zeroed, `[rows, out]`), on the
    /// widest path the machine has.
    fn forward_rows(&self, x: &[f32], stride: usize, start: Option<&[f32]>, y: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.avx {
            AvxRows::run(simd, self, Rows { x, stride, start }, y);
            return;
        }
        self.forward_rows_portable(Rows { x, stride, start }, y);
    }

    /// Each block of [`LANES`] outputs: its output columns, its packed weights (one row of
    /// `LANES` per input) and its bias.
    fn blocks(&self) -> impl Iterator<Item = (Range<usize>, &[[f32; LANES]], &[f32; LANES])> {
        let (d_in, d_out) = (self.d_in, self.d_out);
        self.packed
            .chunks_exact(d_in * LANES)
            .zip(self.bias.as_chunks::<LANES>().0)
            .enumerate()
            .map(move |(k, (block, bias))| {
                let cols = k * LANES..(k * LANES + LANES).min(d_out);
                (cols, block.as_chunks::<LANES>().0, bias)
            })
    }

    /// The 4-wide path: for each block, each row with its 32 accumulators in eight SSE registers.
    fn forward_rows_portable(&self, rows: Rows<'_>, y: &mut [f32]) {
        let (d_in, d_out) = (self.d_in, self.d_out);
        for (cols, weights, bias) in self.blocks() {
            for (r, (xb, yb)) in rows
                .x
                .chunks_exact(rows.stride)
                .zip(y.chunks_exact_mut(d_out))
                .enumerate()
            {
                let init = rows.first(r, d_out, &cols, bias);
                let quads = init.as_chunks::<4>().0;
                let mut acc: [f32x4; LANES / 4] = std::array::from_fn(|q| f32x4::from(quads[q]));
                for (&xi, lanes) in xb[..d_in].iter().zip(weights) {
                    let xv = f32x4::splat(xi);
                    for (a, w) in acc.iter_mut().zip(lanes.as_chunks::<4>().0) {
                        *a += xv * f32x4::from(*w);
                    }
                }
                let out: [f32; LANES] = std::array::from_fn(|l| acc[l / 4].to_array()[l % 4]);
                yb[cols.clone()].copy_from_slice(&out[..cols.len()]);
            }
        }
    }
}

/// A one-line error unless a layer of shape `got` (`[in, out]`) is `expected`.
fn expect_layer(what: &str, expected: (usize, usize), got: (usize, usize)) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(ModelError::Shape {
            what: format!("network layer {what}"),
            expected: format!("[{}, {}]", expected.0, expected.1),
            got: format!("[{}, {}]", got.0, got.1),
        })
    }
}

/// The input rows of [`HostLinear::forward_rows`]: `x` `[rows, stride]` (each row's first `in`
/// columns are the layer's input) and the first sum of every output, the bias or `start`
/// `[rows, out]`.
#[derive(Clone, Copy)]
struct Rows<'a> {
    x: &'a [f32],
    stride: usize,
    start: Option<&'a [f32]>,
}

impl Rows<'_> {
    /// The first sums of row `r`'s outputs `cols` (a block; zero past the layer's outputs).
    #[inline(always)]
    fn first(
        &self,
        r: usize,
        d_out: usize,
        cols: &Range<usize>,
        bias: &[f32; LANES],
    ) -> [f32; LANES] {
        match self.start {
            None => *bias,
            Some(s) => {
                let mut init = [0.0f32; LANES];
                init[..cols.len()]
                    .copy_from_slice(&s[r * d_out + cols.start..r * d_out + cols.end]);
                init
            }
        }
    }
}

/// The 8-wide path of [`HostLinear::forward_rows`], run inside AVX2's target features by
/// `V3::vectorize`: for each block of 32 outputs, rows two at a time (eight accumulators, each
/// weight load serving both rows; [`AvxRows`] with `pairs`), then a last odd row alone (four
/// accumulators; a second `vectorize`, so that the compiler allocates its registers apart from
/// the pairs' — in one function it kept the lone row's accumulators on the stack, slower than
/// the 4-wide path). Every output is the bias plus `x_i W_ij` added in the order of `i`, as on
/// the 4-wide path.
#[cfg(target_arch = "x86_64")]
struct AvxRows<'a> {
    simd: pulp::x86::V3,
    layer: &'a HostLinear,
    rows: Rows<'a>,
    y: &'a mut [f32],
    pairs: bool,
}

#[cfg(target_arch = "x86_64")]
type F32x8Block = [pulp::f32x8; LANES / 8];

#[cfg(target_arch = "x86_64")]
impl AvxRows<'_> {
    /// Runs the rows of `x` (pairs, then the last one alone).
    fn run(simd: pulp::x86::V3, layer: &HostLinear, rows: Rows<'_>, y: &mut [f32]) {
        let (stride, d_out) = (rows.stride, layer.d_out);
        let paired = rows.x.len() / stride / 2 * 2;
        let (x_pairs, x_last) = rows.x.split_at(paired * stride);
        let (y_pairs, y_last) = y.split_at_mut(paired * d_out);
        let (s_pairs, s_last) = match rows.start {
            Some(s) => {
                let (a, b) = s.split_at(paired * d_out);
                (Some(a), Some(b))
            }
            None => (None, None),
        };
        if paired > 0 {
            simd.vectorize(AvxRows {
                simd,
                layer,
                rows: Rows {
                    x: x_pairs,
                    stride,
                    start: s_pairs,
                },
                y: y_pairs,
                pairs: true,
            });
        }
        if !x_last.is_empty() {
            simd.vectorize(AvxRows {
                simd,
                layer,
                rows: Rows {
                    x: x_last,
                    stride,
                    start: s_last,
                },
                y: y_last,
                pairs: false,
            });
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn load8(w: &[f32]) -> F32x8Block {
    std::array::from_fn(|q| pulp::cast(*w[8 * q..].first_chunk::<8>().unwrap()))
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn store8(acc: F32x8Block, out: &mut [f32]) {
    let lanes: [[f32; 8]; LANES / 8] = acc.map(pulp::cast);
    let width = out.len();
    out.copy_from_slice(&lanes.as_flattened()[..width]);
}

#[cfg(target_arch = "x86_64")]
impl pulp::NullaryFnOnce for AvxRows<'_> {
    type Output = ();

    #[inline(always)]
    fn call(self) {
        let Self {
            simd,
            layer,
            rows,
            y,
            pairs,
        } = self;
        let (d_in, d_out, stride) = (layer.d_in, layer.d_out, rows.stride);
        for (cols, weights, bias) in layer.blocks() {
            if pairs {
                let pairs = rows
                    .x
                    .chunks_exact(2 * stride)
                    .zip(y.chunks_exact_mut(2 * d_out));
                for (p, (x, y)) in pairs.enumerate() {
                    let (x0, x1) = x.split_at(stride);
                    let mut acc0 = load8(&rows.first(2 * p, d_out, &cols, bias));
                    let mut acc1 = load8(&rows.first(2 * p + 1, d_out, &cols, bias));
                    for ((&a, &b), w) in x0[..d_in].iter().zip(&x1[..d_in]).zip(weights) {
                        let (av, bv, w) = (simd.splat_f32x8(a), simd.splat_f32x8(b), load8(w));
                        for ((s0, s1), w) in acc0.iter_mut().zip(acc1.iter_mut()).zip(w) {
                            *s0 = simd.add_f32x8(*s0, simd.mul_f32x8(av, w));
                            *s1 = simd.add_f32x8(*s1, simd.mul_f32x8(bv, w));
                        }
                    }
                    let (y0, y1) = y.split_at_mut(d_out);
                    store8(acc0, &mut y0[cols.clone()]);
                    store8(acc1, &mut y1[cols.clone()]);
                }
            } else {
                let single = rows.x.chunks_exact(stride).zip(y.chunks_exact_mut(d_out));
                for (r, (x0, y0)) in single.enumerate() {
                    let mut acc = load8(&rows.first(r, d_out, &cols, bias));
                    for (&a, w) in x0[..d_in].iter().zip(weights) {
                        let (av, w) = (simd.splat_f32x8(a), load8(w));
                        for (s, w) in acc.iter_mut().zip(w) {
                            *s = simd.add_f32x8(*s, simd.mul_f32x8(av, w));
                        }
                    }
                    store8(acc, &mut y0[cols.clone()]);
                }
            }
        }
    }
}

/// Whether the forward may take the widest vector path the machine has: `LFIT_NATIVE_SIMD`
/// unset or `auto` (the default) yes, `portable` no (the 4-wide SSE2 path everywhere, for A/B
/// timing in one binary: the two compute the same bits); anything else is a one-line error.
/// Read once per process (every layer asks; the `lfit` command asks first, so that a bad value
/// is refused before anything is loaded).
pub fn wide_simd() -> Result<bool> {
    static CHOICE: std::sync::OnceLock<std::result::Result<bool, String>> =
        std::sync::OnceLock::new();
    CHOICE
        .get_or_init(|| match std::env::var("LFIT_NATIVE_SIMD") {
            Err(std::env::VarError::NotPresent) => Ok(true),
            Ok(v) if v == "auto" => Ok(true),
            Ok(v) if v == "portable" => Ok(false),
            Ok(v) => Err(format!(
                "LFIT_NATIVE_SIMD must be auto or portable, got {v:?}"
            )),
            Err(e) => Err(format!("LFIT_NATIVE_SIMD: {e}")),
        })
        .clone()
        .map_err(ModelError::Config)
}

/// Rows per parallel block of [`HostLinear::forward`]: a batch of at least twice this many is
/// spread over rayon's threads (a 575 × 384 layer costs ~10 µs per row, so a block is ~0.15 ms of
/// work, far above rayon's dispatch cost).
const PARALLEL_ROWS: usize = 16;

/// LayerNorm over the last axis: `(x − mean) / sqrt(var + ε) · g + b` (biased variance).
#[derive(Debug, Clone)]
struct HostLayerNorm {
    gamma: Vec<f32>,
    beta: Vec<f32>,
    epsilon: f32,
}

impl HostLayerNorm {
    fn new(ln: &LayerNorm) -> Result<Self> {
        let gamma = values(ln.gamma.val())?;
        let beta = match &ln.beta {
            Some(b) => values(b.val())?,
            None => vec![0.0; gamma.len()],
        };
        Ok(Self {
            gamma,
            beta,
            epsilon: layer_norm_epsilon() as f32,
        })
    }

    /// Normalises one row into `out`.
    fn row(&self, x: &[f32], out: &mut [f32]) {
        let n = x.len() as f32;
        let mean = lane_sum(x, |v| v) / n;
        let var = lane_sum(x, |v| (v - mean) * (v - mean)) / n;
        let inv = 1.0 / (var + self.epsilon).sqrt();
        for (((o, v), g), b) in out.iter_mut().zip(x).zip(&self.gamma).zip(&self.beta) {
            *o = (v - mean) * inv * g + b;
        }
    }
}

/// `Σ f(x_k)` in eight interleaved partial sums (`f(x_k)` into sum `k mod 8`), added pairwise at
/// the end: one sum per element in order is a chain of dependent adds (a LayerNorm's mean and
/// variance over 128 entries were ~6 % of a markers frame at batch 1); eight chains vectorise.
/// The order is fixed by the code, so every machine computes the same bits.
#[inline(always)]
fn lane_sum(x: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut acc = [0.0f32; 8];
    let (chunks, rest) = x.as_chunks::<8>();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a += f(v);
        }
    }
    for (a, &v) in acc.iter_mut().zip(rest) {
        *a += f(v);
    }
    ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]))
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// `tanh x` as `1 − 2 / (e^{2x} + 1)`: one `exp` (glibc's `tanhf` took three times as long, 7 %
/// of a markers frame at batch 1), within 2.4·10⁻⁷ of `tanh` everywhere (absolute, one ulp of the
/// 2 it subtracts from; relative near 0 it is looser, where the GRU's candidate is blended by z
/// anyway); ±1 past |x| ≈ 44 (e^{2x} overflows to ∞ or underflows to 0, no NaN).
fn tanh(x: f32) -> f32 {
    1.0 - 2.0 / ((2.0 * x).exp() + 1.0)
}

/// `ln(1 + eˣ)`, stable for large |x|.
fn softplus(x: f32) -> f32 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// The first layer of a core: `x W + b` over the core's whole input, or — for the core `f`,
/// whose input ends with the observation features D — split at D: `b + D W_D` is the same at
/// every iteration of a frame, so it is computed once per frame ([`HostCore::constant`], kept in
/// [`RowState::constant`]) and each iteration adds only `[R, g, θ] W_[R,g,θ]` to it. The sums
/// run in another order than the unsplit layer's (b, D, then R, g, θ): the same products, the
/// f32 rounding of a different order.
#[derive(Debug, Clone)]
struct HostInput {
    /// The layer over the inputs before D (without the bias), or over all of them (with it).
    head: HostLinear,
    /// `b + D W_D`'s layer, where the input is split.
    obs: Option<HostLinear>,
}

impl HostInput {
    fn new(linear: &Linear, split: Option<usize>) -> Result<Self> {
        Ok(match split {
            Some(at) => {
                let (head, obs) = HostLinear::split(linear, at)?;
                Self {
                    head,
                    obs: Some(obs),
                }
            }
            None => Self {
                head: HostLinear::new(linear)?,
                obs: None,
            },
        })
    }

    fn d_in(&self) -> usize {
        self.head.d_in + self.obs.as_ref().map_or(0, |o| o.d_in)
    }

    /// A one-line error unless this layer is `[d_in, d_out]` (both halves of a split one
    /// with `d_out` outputs).
    fn expect(&self, what: &str, d_in: usize, d_out: usize) -> Result<()> {
        expect_layer(what, (d_in, d_out), (self.d_in(), self.head.d_out))?;
        match &self.obs {
            Some(o) => o.expect(what, o.d_in, d_out),
            None => Ok(()),
        }
    }

    /// `b + D W_D` of the observation rows `obs` `[B, D]`; `None` where the layer is not split.
    fn constant(&self, obs: &[f32], batch: usize) -> Option<Vec<f32>> {
        self.obs.as_ref().map(|o| o.forward(obs, batch))
    }

    /// `x W + b` of `x` `[B, in]`; a split layer starts from `constant` (`b + D W_D` of these
    /// rows), or computes it from `x`'s D columns where none is given.
    fn forward(&self, x: &[f32], batch: usize, constant: Option<&[f32]>) -> Vec<f32> {
        let Some(obs) = &self.obs else {
            return self.head.forward(x, batch);
        };
        let d_in = self.d_in();
        let computed;
        let start = match constant {
            Some(c) => c,
            None => {
                let d: Vec<f32> = x
                    .chunks_exact(d_in)
                    .flat_map(|row| &row[self.head.d_in..])
                    .copied()
                    .collect();
                computed = obs.forward(&d, batch);
                &computed
            }
        };
        self.head.forward_from(x, d_in, batch, start)
    }
}

#[derive(Debug, Clone)]
struct HostGruCell {
    w: HostInput,
    u_zr: HostLinear,
    u_h: HostLinear,
    /// ln_wz, ln_wr, ln_wh, ln_uz, ln_ur, ln_uh.
    ln: [HostLayerNorm; 6],
    hidden: usize,
}

impl HostGruCell {
    fn new(cell: &LnGruCell, split: Option<usize>) -> Result<Self> {
        Ok(Self {
            w: HostInput::new(&cell.w, split)?,
            u_zr: HostLinear::new(&cell.u_zr)?,
            u_h: HostLinear::new(&cell.u_h)?,
            ln: [
                HostLayerNorm::new(&cell.ln_wz)?,
                HostLayerNorm::new(&cell.ln_wr)?,
                HostLayerNorm::new(&cell.ln_wh)?,
                HostLayerNorm::new(&cell.ln_uz)?,
                HostLayerNorm::new(&cell.ln_ur)?,
                HostLayerNorm::new(&cell.ln_uh)?,
            ],
            hidden: cell.hidden,
        })
    }

    /// papers/002 supp. eq. (12), as [`LnGruCell::forward`]: `x` `[B, in]`, `h` `[B, H]` → `h'`
    /// (`constant`: see [`HostInput::forward`]). The gates row by row ([`for_rows`]: over
    /// rayon's threads in large batches).
    fn forward(&self, x: &[f32], h: &[f32], batch: usize, constant: Option<&[f32]>) -> Vec<f32> {
        let hd = self.hidden;
        let wx = self.w.forward(x, batch, constant);
        let uh = self.u_zr.forward(h, batch);
        let [ln_wz, ln_wr, ln_wh, ln_uz, ln_ur, ln_uh] = &self.ln;
        // r ⊙ h and z, side by side in one `[B, 2H]` buffer (a row's two halves): `u_h` reads
        // r ⊙ h from it in place (stride 2H).
        let mut zrh = vec![0.0f32; batch * 2 * hd];
        for_rows(&mut zrh, 2 * hd, |i, row, (a, b)| {
            let (wx, uh, h) = (
                &wx[i * 3 * hd..(i + 1) * 3 * hd],
                &uh[i * 2 * hd..(i + 1) * 2 * hd],
                &h[i * hd..(i + 1) * hd],
            );
            let (rh, z) = row.split_at_mut(hd);
            ln_wz.row(&wx[..hd], a);
            ln_uz.row(&uh[..hd], b);
            for ((zj, aj), bj) in z.iter_mut().zip(a.iter()).zip(b.iter()) {
                *zj = sigmoid(aj + bj);
            }
            ln_wr.row(&wx[hd..2 * hd], a);
            ln_ur.row(&uh[hd..], b);
            for (((o, aj), bj), hj) in rh.iter_mut().zip(a.iter()).zip(b.iter()).zip(h) {
                *o = sigmoid(aj + bj) * hj;
            }
        });
        let uhh = self.u_h.forward_with(&zrh, 2 * hd, batch, None);
        let mut out = vec![0.0f32; batch * hd];
        for_rows(&mut out, hd, |i, out, (a, b)| {
            let r = i * hd..(i + 1) * hd;
            ln_wh.row(&wx[i * 3 * hd + 2 * hd..(i + 1) * 3 * hd], a);
            ln_uh.row(&uhh[r.clone()], b);
            let z = &zrh[i * 2 * hd + hd..(i + 1) * 2 * hd];
            for ((((o, aj), bj), zj), hj) in out
                .iter_mut()
                .zip(a.iter())
                .zip(b.iter())
                .zip(z)
                .zip(&h[r.clone()])
            {
                let cand = tanh(aj + bj);
                *o = (1.0 - zj) * hj + zj * cand;
            }
        });
        out
    }
}

/// Calls `f(i, row_i, scratch)` for each `width`-long row of `out`, with two scratch rows of
/// `width` (reused within a thread). Batches of at least twice [`PARALLEL_ROWS`] rows run over
/// rayon's threads in blocks of that many rows; each row is computed alone by the same code, so
/// the result does not depend on the number of threads.
fn for_rows<F>(out: &mut [f32], width: usize, f: F)
where
    F: Fn(usize, &mut [f32], (&mut [f32], &mut [f32])) + Sync,
{
    let scratch = || (vec![0.0f32; width], vec![0.0f32; width]);
    let batch = out.len() / width.max(1);
    if width == 0 {
        return;
    }
    if batch >= 2 * PARALLEL_ROWS {
        out.par_chunks_mut(width)
            .enumerate()
            .with_min_len(PARALLEL_ROWS)
            .for_each_init(scratch, |(a, b), (i, row)| f(i, row, (a, b)));
    } else {
        let (mut a, mut b) = scratch();
        for (i, row) in out.chunks_exact_mut(width).enumerate() {
            f(i, row, (&mut a, &mut b));
        }
    }
}

/// A recurrent (GRU stack) or memoryless (residual MLP) core.
#[derive(Debug, Clone)]
enum HostCore {
    Gru(Vec<HostGruCell>),
    Mlp {
        input: HostInput,
        blocks: Vec<HostLinear>,
    },
}

impl HostCore {
    /// `split`: where the input's observation features begin (the core `f`), see [`HostInput`].
    fn new(core: &Core, split: Option<usize>) -> Result<Self> {
        match (&core.gru, &core.mlp) {
            (Some(GruStack { cells }), _) => Ok(HostCore::Gru(
                cells
                    .iter()
                    .enumerate()
                    .map(|(l, cell)| HostGruCell::new(cell, split.filter(|_| l == 0)))
                    .collect::<Result<_>>()?,
            )),
            (None, Some(ResidualMlp { input, blocks })) => Ok(HostCore::Mlp {
                input: HostInput::new(input, split)?,
                blocks: blocks.iter().map(HostLinear::new).collect::<Result<_>>()?,
            }),
            (None, None) => Err(ModelError::Config(
                "a network core without GRU or MLP".into(),
            )),
        }
    }

    /// The layer that reads the core's input (`None` for a GRU without layers).
    fn first(&self) -> Option<&HostInput> {
        match self {
            HostCore::Gru(cells) => cells.first().map(|c| &c.w),
            HostCore::Mlp { input, .. } => Some(input),
        }
    }

    /// Outputs of the first layer (a row of its `b + D W_D`).
    fn first_width(&self) -> usize {
        self.first().map_or(0, |l| l.head.d_out)
    }

    /// The first layer's `b + D W_D` of the observation rows `obs` (`None` unless split).
    fn constant(&self, obs: &[f32], batch: usize) -> Option<Vec<f32>> {
        self.first().and_then(|l| l.constant(obs, batch))
    }

    /// Output `[B, H]`; a GRU's `states` (one per layer) are replaced by the new ones;
    /// `constant`: the first layer's, see [`HostInput::forward`].
    fn forward(
        &self,
        x: &[f32],
        states: &mut [Vec<f32>],
        batch: usize,
        constant: Option<&[f32]>,
    ) -> Result<Vec<f32>> {
        match self {
            HostCore::Gru(cells) => {
                if states.len() != cells.len() {
                    return Err(ModelError::Shape {
                        what: "GRU states".into(),
                        expected: cells.len().to_string(),
                        got: states.len().to_string(),
                    });
                }
                // Layer l reads layer l−1's new state (the first reads `x`, uncopied).
                let mut input: Vec<f32> = Vec::new();
                for (l, (cell, h)) in cells.iter().zip(states.iter_mut()).enumerate() {
                    if h.len() != batch * cell.hidden {
                        return Err(ModelError::Shape {
                            what: "GRU state".into(),
                            expected: (batch * cell.hidden).to_string(),
                            got: h.len().to_string(),
                        });
                    }
                    let next = if l == 0 {
                        cell.forward(x, h, batch, constant)
                    } else {
                        cell.forward(&input, h, batch, None)
                    };
                    input.clone_from(&next);
                    *h = next;
                }
                Ok(input)
            }
            HostCore::Mlp { input, blocks } => {
                let mut y = input.forward(x, batch, constant);
                relu(&mut y);
                for block in blocks {
                    let mut b = block.forward(&y, batch);
                    relu(&mut b);
                    for (v, d) in y.iter_mut().zip(&b) {
                        *v += d;
                    }
                }
                Ok(y)
            }
        }
    }
}

fn relu(x: &mut [f32]) {
    for v in x {
        *v = v.max(0.0);
    }
}

/// BatchNorm in inference mode, folded: `y = x · scale + shift`.
#[derive(Debug, Clone)]
struct HostBatchNorm {
    scale: Vec<f32>,
    shift: Vec<f32>,
}

impl HostBatchNorm {
    fn new(bn: &BatchNorm) -> Result<Self> {
        let gamma = values(bn.gamma.val())?;
        let beta = values(bn.beta.val())?;
        let mean = values(bn.running_mean.value())?;
        let var = values(bn.running_var.value())?;
        let eps = bn.epsilon as f32;
        let scale: Vec<f32> = gamma
            .iter()
            .zip(&var)
            .map(|(g, v)| g / (v + eps).sqrt())
            .collect();
        let shift = beta
            .iter()
            .zip(&mean)
            .zip(&scale)
            .map(|((b, m), s)| b - m * s)
            .collect();
        Ok(Self { scale, shift })
    }

    /// In place on `[B, C]` rows, then ReLU.
    fn forward_relu(&self, x: &mut [f32]) {
        for row in x.chunks_exact_mut(self.scale.len()) {
            for ((v, s), t) in row.iter_mut().zip(&self.scale).zip(&self.shift) {
                *v = (*v * s + t).max(0.0);
            }
        }
    }
}

/// Φ / Φh: Linear → BatchNorm → ReLU, twice, then Linear.
#[derive(Debug, Clone)]
struct HostInit {
    l1: HostLinear,
    bn1: HostBatchNorm,
    l2: HostLinear,
    bn2: HostBatchNorm,
    out: HostLinear,
}

impl HostInit {
    fn new(m: &InitMlp) -> Result<Self> {
        Ok(Self {
            l1: HostLinear::new(&m.l1)?,
            bn1: HostBatchNorm::new(&m.bn1)?,
            l2: HostLinear::new(&m.l2)?,
            bn2: HostBatchNorm::new(&m.bn2)?,
            out: HostLinear::new(&m.out)?,
        })
    }

    fn forward(&self, x: &[f32], batch: usize) -> Vec<f32> {
        let mut y = self.l1.forward(x, batch);
        self.bn1.forward_relu(&mut y);
        let mut y = self.l2.forward(&y, batch);
        self.bn2.forward_relu(&mut y);
        self.out.forward(&y, batch)
    }
}

#[derive(Debug, Clone)]
struct HostStep {
    lambda_core: HostCore,
    lambda_head: HostLinear,
    gamma: Option<(HostCore, HostLinear)>,
}

/// The whole network on the host, read once from a [`NeuralNet`], with the feature statistics
/// of its checkpoint.
#[derive(Debug, Clone)]
pub struct HostNet {
    pub config: NetConfig,
    pub stats: FeatureStats,
    phi: HostInit,
    phi_h: Option<HostInit>,
    cores: Vec<HostCore>,
    delta_heads: Vec<HostLinear>,
    steps: Vec<HostStep>,
}

fn shape(what: &str, expected: usize, got: usize) -> ModelError {
    ModelError::Shape {
        what: what.into(),
        expected: expected.to_string(),
        got: got.to_string(),
    }
}

impl HostNet {
    /// Copies the weights of `net` (on any Burn device) to the host.
    pub fn new(net: &NeuralNet, stats: FeatureStats) -> Result<Self> {
        let c = &net.config;
        c.validate()?;
        stats.validate(c)?;
        let steps = net
            .steps
            .iter()
            .map(|s| {
                Ok(HostStep {
                    lambda_core: HostCore::new(&s.lambda_core, None)?,
                    lambda_head: HostLinear::new(&s.lambda_head)?,
                    gamma: match (&s.gamma_core, &s.gamma_head) {
                        (Some(core), Some(head)) => {
                            Some((HostCore::new(core, None)?, HostLinear::new(head)?))
                        }
                        _ => None,
                    },
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let host = Self {
            config: c.clone(),
            stats,
            phi: HostInit::new(&net.phi)?,
            phi_h: net.phi_h.as_ref().map(HostInit::new).transpose()?,
            cores: net
                .cores
                .iter()
                .map(|f| HostCore::new(f, Some(c.core_inputs() - c.obs_features())))
                .collect::<Result<_>>()?,
            delta_heads: net
                .delta_heads
                .iter()
                .map(HostLinear::new)
                .collect::<Result<_>>()?,
            steps,
        };
        let sets = c.weight_sets();
        if host.cores.len() != sets
            || host.delta_heads.len() != sets
            || (c.has_step_network() && host.steps.len() != sets)
        {
            return Err(ModelError::Config(format!(
                "the network has {} core(s) and {} step network(s), its configuration {sets} weight set(s)",
                host.cores.len(),
                host.steps.len()
            )));
        }
        host.check_shapes()?;
        Ok(host)
    }

    /// Every layer's shape against the configuration, so that a checkpoint whose weights do not
    /// match its `config.json` is a one-line error here and never a slice out of range later.
    fn check_shapes(&self) -> Result<()> {
        let c = &self.config;
        let h = c.hidden;
        let init = |m: &HostInit, what: &str, d_out: usize| -> Result<()> {
            let w = c.init_width;
            m.l1.expect(&format!("{what}.l1"), c.obs_features(), w)?;
            m.l2.expect(&format!("{what}.l2"), w, w)?;
            m.out.expect(&format!("{what}.out"), w, d_out)?;
            for (bn, name) in [(&m.bn1, "bn1"), (&m.bn2, "bn2")] {
                if bn.scale.len() != w {
                    return Err(shape(&format!("{what}.{name} width"), w, bn.scale.len()));
                }
            }
            Ok(())
        };
        init(&self.phi, "Φ", c.param_dim)?;
        if let Some(phi_h) = &self.phi_h {
            init(phi_h, "Φh", c.layers * h)?;
        } else if c.recurrent_layers() > 0 {
            return Err(ModelError::Config(
                "the network has a GRU core but no Φh".into(),
            ));
        }
        let core = |core: &HostCore, what: &str, d_in: usize| -> Result<()> {
            match core {
                HostCore::Gru(cells) => {
                    if cells.len() != c.layers {
                        return Err(shape(&format!("{what} GRU layers"), c.layers, cells.len()));
                    }
                    for (l, cell) in cells.iter().enumerate() {
                        let input = if l == 0 { d_in } else { h };
                        cell.w.expect(&format!("{what}.gru{l}.w"), input, 3 * h)?;
                        cell.u_zr.expect(&format!("{what}.gru{l}.u_zr"), h, 2 * h)?;
                        cell.u_h.expect(&format!("{what}.gru{l}.u_h"), h, h)?;
                        if cell.hidden != h || cell.ln.iter().any(|ln| ln.gamma.len() != h) {
                            return Err(shape(&format!("{what}.gru{l} LayerNorm"), h, cell.hidden));
                        }
                    }
                }
                HostCore::Mlp { input, blocks } => {
                    input.expect(&format!("{what}.mlp_in"), d_in, h)?;
                    for (l, b) in blocks.iter().enumerate() {
                        b.expect(&format!("{what}.mlp{l}"), h, h)?;
                    }
                }
            }
            Ok(())
        };
        for (s, (f, head)) in self.cores.iter().zip(&self.delta_heads).enumerate() {
            core(f, &format!("f[{s}]"), c.core_inputs())?;
            head.expect(&format!("Δθ head[{s}]"), h, c.param_dim)?;
        }
        let (k, kg) = (c.step_outputs(), c.gamma_outputs());
        for (s, step) in self.steps.iter().enumerate() {
            core(&step.lambda_core, &format!("fλ[{s}]"), c.step_inputs())?;
            let width = if step.gamma.is_none() && c.learns_gamma() {
                k + kg
            } else {
                k
            };
            step.lambda_head.expect(&format!("λ head[{s}]"), h, width)?;
            if let Some((g, head)) = &step.gamma {
                core(g, &format!("fγ[{s}]"), c.step_inputs())?;
                head.expect(&format!("γ head[{s}]"), h, kg)?;
            }
        }
        Ok(())
    }
}

impl RowNetwork for &HostNet {
    type Error = ModelError;

    fn config(&self) -> &NetConfig {
        &self.config
    }

    fn stats(&self) -> &FeatureStats {
        &self.stats
    }

    fn initial(&mut self, obs: &[f32], batch: usize) -> Result<(Vec<f32>, RowState)> {
        let c = &self.config;
        if obs.len() != batch * c.obs_features() {
            return Err(shape(
                "observation features",
                batch * c.obs_features(),
                obs.len(),
            ));
        }
        let theta0 = self.phi.forward(obs, batch);
        let core = match &self.phi_h {
            Some(phi_h) => {
                let h = phi_h.forward(obs, batch);
                let width = c.layers * c.hidden;
                (0..c.layers)
                    .map(|l| {
                        (0..batch)
                            .flat_map(|b| {
                                h[b * width + l * c.hidden..b * width + (l + 1) * c.hidden]
                                    .iter()
                                    .copied()
                            })
                            .collect()
                    })
                    .collect()
            }
            None => Vec::new(),
        };
        let mut state = RowState::zeros(c, batch, core);
        // `b + D W_D` of each weight set's core, once per frame (see `HostInput`).
        state.constant = self
            .cores
            .iter()
            .map(|f| f.constant(obs, batch).unwrap_or_default())
            .collect();
        Ok((theta0, state))
    }

    fn propose(
        &mut self,
        n: usize,
        core_in: &[f32],
        batch: usize,
        state: &mut RowState,
    ) -> Result<Vec<f32>> {
        let c = &self.config;
        if core_in.len() != batch * c.core_inputs() {
            return Err(shape("core inputs", batch * c.core_inputs(), core_in.len()));
        }
        let s = c.weight_set(n);
        let constant = state.constant.get(s).filter(|k| !k.is_empty());
        if let Some(k) = constant {
            let width = batch * self.cores[s].first_width();
            if k.len() != width {
                return Err(shape(
                    "the core's per-frame observation term",
                    width,
                    k.len(),
                ));
            }
        }
        let h =
            self.cores[s].forward(core_in, &mut state.core, batch, constant.map(Vec::as_slice))?;
        Ok(self.delta_heads[s].forward(&h, batch))
    }

    fn step(
        &mut self,
        n: usize,
        step_in: &[f32],
        delta: &[f32],
        grad: &[f32],
        batch: usize,
        state: &mut RowState,
    ) -> Result<StepOut> {
        let c = &self.config;
        if !c.has_step_network() {
            return Err(ModelError::Config(
                "the Δθ-only rule has no step network".into(),
            ));
        }
        if step_in.len() != batch * c.step_inputs() {
            return Err(shape("step inputs", batch * c.step_inputs(), step_in.len()));
        }
        let dim = c.param_dim;
        if delta.len() != batch * dim || grad.len() != batch * dim {
            return Err(shape(
                "Δθ and gradient",
                batch * dim,
                delta.len().min(grad.len()),
            ));
        }
        let net = &self.steps[c.weight_set(n)];
        let (k, kg) = (c.step_outputs(), c.gamma_outputs());
        let out = net.lambda_head.forward(
            &net.lambda_core
                .forward(step_in, &mut state.lambda, batch, None)?,
            batch,
        );
        // Raw λ and γ head outputs, `[B, k]` and `[B, kg]`.
        let (a, b): (Vec<f32>, Option<Vec<f32>>) = match &net.gamma {
            Some((core, head)) => (
                out,
                Some(head.forward(
                    &core.forward(step_in, &mut state.gamma, batch, None)?,
                    batch,
                )),
            ),
            None if c.learns_gamma() => {
                let w = k + kg;
                let a = (0..batch)
                    .flat_map(|i| out[i * w..i * w + k].iter().copied())
                    .collect();
                let b = (0..batch)
                    .flat_map(|i| out[i * w + k..(i + 1) * w].iter().copied())
                    .collect();
                (a, Some(b))
            }
            None => (out, None),
        };
        // Elementwise over `[B, k]`: over rayon's threads in large batches (the same value per
        // element whichever thread computes it).
        let map = |v: &[f32], f: &(dyn Fn(f32) -> f32 + Sync)| -> Vec<f32> {
            if batch >= 2 * PARALLEL_ROWS {
                v.par_iter().with_min_len(4096).map(|&x| f(x)).collect()
            } else {
                v.iter().map(|&x| f(x)).collect()
            }
        };
        let lambda: Vec<f32> = match c.update {
            UpdateRule::Eq1 => map(&a, &|v| v + 1.0),
            _ => map(&a, &sigmoid),
        };
        let gamma: Vec<f32> = match b {
            Some(b) => {
                let scale = (c.gamma_init / std::f64::consts::LN_2) as f32;
                map(&b, &|v| softplus(v) * scale)
            }
            None => vec![c.gamma_constant as f32; batch * kg],
        };
        let mut update = vec![0.0f32; batch * dim];
        for i in 0..batch {
            let (d, g) = (
                &delta[i * dim..(i + 1) * dim],
                &grad[i * dim..(i + 1) * dim],
            );
            let l = |j: usize| lambda[i * k + if k == 1 { 0 } else { j }];
            let gm = |j: usize| gamma[i * kg + if kg == 1 { 0 } else { j }];
            let u = &mut update[i * dim..(i + 1) * dim];
            match c.update {
                UpdateRule::DeltaOnly => u.copy_from_slice(d),
                UpdateRule::Eq1 => {
                    for j in 0..dim {
                        u[j] = l(j) * d[j] - gm(j) * g[j];
                    }
                }
                UpdateRule::Convex => {
                    for j in 0..dim {
                        u[j] = l(j) * d[j] - (1.0 - l(j)) * gm(j) * g[j];
                    }
                }
                UpdateRule::ConvexNormalized => {
                    let norm = |x: &[f32]| (x.iter().map(|v| v * v).sum::<f32>() + 1e-12).sqrt();
                    let (nd, ng) = (norm(d), norm(g));
                    for j in 0..dim {
                        u[j] = gm(j) * (l(j) * (d[j] / nd) - (1.0 - l(j)) * (g[j] / ng));
                    }
                }
            }
        }
        Ok(StepOut {
            update,
            lambda,
            gamma,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;

    /// The 8-wide AVX path gives every output of the 4-wide portable path to the bit: odd and
    /// even batches (the pairs and the last row alone), a last block of 6 of 32 outputs, one
    /// output, inputs of opposite signs and magnitudes (so the order of the adds matters).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx_path_computes_the_portable_paths_bits() {
        let device = crate::tensor::ndarray_device();
        let mut layer = None;
        for (d_in, d_out) in [(45, 70), (3, 1), (128, 64), (575, 384)] {
            let linear = LinearConfig::new(d_in, d_out).init(&device);
            let l = HostLinear::new(&linear).expect("layer");
            if l.avx.is_none() {
                let why = "this machine has no AVX2: the 8-wide path cannot run here";
                assert!(std::env::var("CI").as_deref() != Ok("true"), "{why}");
                eprintln!("skipped: {why}");
                return;
            }
            for batch in [1usize, 2, 3, 8, 13] {
                let x: Vec<f32> = (0..batch * d_in)
                    .map(|i| {
                        let v = ((i * 7919 % 1009) as f32 / 504.5 - 1.0) * 3.0;
                        if i % 5 == 0 { v * 1e3 } else { v }
                    })
                    .collect();
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                // From the bias over rows of `in`; from a start over rows of `in + 3`.
                let start: Vec<f32> = (0..batch * d_out).map(|i| (i % 13) as f32 - 6.5).collect();
                let strided: Vec<f32> = x
                    .chunks_exact(d_in)
                    .flat_map(|r| r.iter().copied().chain([9e9, -9e9, 1.0]))
                    .collect();
                for (x, stride, start) in [(&x, d_in, None), (&strided, d_in + 3, Some(&start[..]))]
                {
                    let mut wide = vec![0.0f32; batch * d_out];
                    l.forward_rows(x, stride, start, &mut wide);
                    let mut portable = vec![0.0f32; batch * d_out];
                    l.forward_rows_portable(Rows { x, stride, start }, &mut portable);
                    assert_eq!(
                        bits(&wide),
                        bits(&portable),
                        "[{d_in}, {d_out}], batch {batch}, stride {stride}"
                    );
                }
            }
            layer = Some(l);
        }
        // A path with a fused multiply-add would round once per term and differ here.
        let l = layer.expect("layer");
        let x = vec![1.0 + f32::EPSILON; l.d_in];
        let mut y = vec![0.0f32; l.d_out];
        l.forward_rows(&x, l.d_in, None, &mut y);
        let want: Vec<f32> = (0..l.d_out)
            .map(|j| {
                let mut acc = l.bias[j];
                for i in 0..l.d_in {
                    acc += x[i] * l.packed[(j / LANES) * l.d_in * LANES + i * LANES + j % LANES];
                }
                acc
            })
            .collect();
        assert_eq!(y, want);
    }

    /// A layer split at the observation features: `b + D W_D` first, then the rest from it
    /// (given, or computed from the rows' own D columns) — the same outputs as the whole layer
    /// to f32 rounding, and both ways of getting the start agree to the bit.
    #[test]
    fn a_split_layer_gives_the_whole_layers_outputs() {
        let device = crate::tensor::ndarray_device();
        let (d_in, at, d_out, batch) = (75, 40, 70, 5);
        let linear = LinearConfig::new(d_in, d_out).init(&device);
        let whole = HostInput::new(&linear, None).expect("whole");
        let split = HostInput::new(&linear, Some(at)).expect("split");
        split.expect("split", d_in, d_out).expect("shape");
        assert!(split.expect("split", d_in + 1, d_out).is_err());
        assert!(HostInput::new(&linear, Some(d_in + 1)).is_err());
        let x: Vec<f32> = (0..batch * d_in)
            .map(|i| ((i * 7919 % 1009) as f32 / 504.5 - 1.0) * 2.0)
            .collect();
        let d: Vec<f32> = x
            .chunks_exact(d_in)
            .flat_map(|r| &r[at..])
            .copied()
            .collect();
        let constant = split.constant(&d, batch).expect("a split layer's constant");
        assert!(whole.constant(&d, batch).is_none());
        let given = split.forward(&x, batch, Some(&constant));
        assert_eq!(given, split.forward(&x, batch, None));
        let want = whole.forward(&x, batch, None);
        for (g, w) in given.iter().zip(&want) {
            assert!((g - w).abs() <= 1e-5 * (1.0 + w.abs()), "{g} against {w}");
        }
        // The start is used: another constant moves every output by its difference.
        let shifted: Vec<f32> = constant.iter().map(|c| c + 1.0).collect();
        for (s, g) in split.forward(&x, batch, Some(&shifted)).iter().zip(&given) {
            assert!((s - g - 1.0).abs() < 1e-5);
        }
    }

    /// The eight-chain sum: every element once (lengths around multiples of 8), `f` applied to
    /// each, and within f32 rounding of the f64 sum on values of mixed signs and magnitudes.
    #[test]
    fn lane_sum_adds_every_element_once() {
        for n in [0usize, 1, 7, 8, 9, 16, 127, 128, 130] {
            let x: Vec<f32> = (1..=n).map(|k| k as f32).collect();
            assert_eq!(lane_sum(&x, |v| v), (n * (n + 1) / 2) as f32, "n = {n}");
            assert_eq!(lane_sum(&x, |_| 1.0), n as f32, "n = {n}");
        }
        let x: Vec<f32> = (0..128)
            .map(|i| ((i * 7919 % 1009) as f32 / 504.5 - 1.0) * if i % 3 == 0 { 1e3 } else { 1.0 })
            .collect();
        let want: f64 = x.iter().map(|&v| f64::from(v)).sum();
        assert!(
            (f64::from(lane_sum(&x, |v| v)) - want).abs() < 1e-3,
            "{want}"
        );
    }

    /// The one-`exp` tanh against the standard library's over the range a GRU sees and past
    /// where `e^{2x}` overflows: within 2.4·10⁻⁷, odd to within that, exactly ±1 far out.
    #[test]
    fn tanh_from_one_exp_matches_the_standard_tanh() {
        let mut worst = 0.0f32;
        for i in -200_000..=200_000 {
            let x = i as f32 * 1e-4;
            let (got, want) = (tanh(x), x.tanh());
            worst = worst.max((got - want).abs());
            assert!((tanh(-x) + got).abs() <= 2.4e-7, "odd at {x}");
        }
        assert!(worst <= 2.4e-7, "worst {worst}");
        for x in [50.0f32, 1e4, f32::MAX, f32::INFINITY] {
            assert_eq!(tanh(x), 1.0, "{x}");
            assert_eq!(tanh(-x), -1.0, "{x}");
        }
        assert_eq!(tanh(0.0), 0.0);
    }

    /// A batch large enough to be split over threads gives every row exactly what that row gives
    /// alone, and both match `b + x W` summed in f64 (to f32 rounding).
    #[test]
    fn a_split_batch_gives_each_row_what_it_gives_alone() {
        let device = crate::tensor::ndarray_device();
        let (d_in, d_out) = (45, 70);
        let linear = LinearConfig::new(d_in, d_out).init(&device);
        let layer = HostLinear::new(&linear).expect("layer");
        let w = values(linear.weight.val()).expect("w");
        let b = values(linear.bias.as_ref().expect("bias").val()).expect("b");
        let batch = 2 * PARALLEL_ROWS + 7;
        let x: Vec<f32> = (0..batch * d_in)
            .map(|i| ((i * 37 % 101) as f32 / 50.0 - 1.0) * 0.7)
            .collect();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("pool");
        let y = pool.install(|| layer.forward(&x, batch));
        assert_eq!(y.len(), batch * d_out);
        for (r, (xr, yr)) in x.chunks_exact(d_in).zip(y.chunks_exact(d_out)).enumerate() {
            assert_eq!(layer.forward(xr, 1), yr, "row {r}");
            for (j, &got) in yr.iter().enumerate() {
                let want = f64::from(b[j])
                    + (0..d_in)
                        .map(|i| f64::from(xr[i]) * f64::from(w[i * d_out + j]))
                        .sum::<f64>();
                assert!((f64::from(got) - want).abs() < 1e-5, "row {r}, output {j}");
            }
        }
    }
}
