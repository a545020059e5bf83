//! Building blocks of the neural fitter: the layer-normalized GRU cell of papers/002 supp.
//! eq. (12) and stacks of it, the residual MLP core, the initializer MLPs Φ/Φh, and seeded
//! parameter initialisation and dropout (drawn from a ChaCha stream on the host, so the same seed
//! gives the same network and the same masks on every backend).

use burn::module::{Module, Param};
use burn::nn::{BatchNorm, BatchNormConfig, LayerNorm, LayerNormConfig, Linear};
use burn::tensor::activation::{relu, sigmoid, tanh};
use burn::tensor::{Device, Tensor, TensorData};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A linear layer `y = x W + b` with `W ~ U(−a, a)`, `a = gain · sqrt(6 / (fan_in + fan_out))`
/// (Xavier/Glorot uniform), `b = 0`.
pub fn xavier_linear(
    d_in: usize,
    d_out: usize,
    gain: f64,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Linear {
    let a = gain * (6.0 / (d_in + d_out) as f64).sqrt();
    let w: Vec<f32> = (0..d_in * d_out)
        .map(|_| rng.random_range(-a..=a) as f32)
        .collect();
    Linear {
        weight: Param::from_tensor(Tensor::from_data(TensorData::new(w, [d_in, d_out]), device)),
        bias: Some(Param::from_tensor(Tensor::zeros([d_out], device))),
    }
}

/// Dropout masks on the host: `None` at inference, or a seeded stream during training.
#[derive(Debug)]
pub struct Dropout<'a> {
    pub p: f64,
    pub rng: Option<&'a mut ChaCha8Rng>,
}

impl Dropout<'_> {
    /// No dropout (inference).
    pub fn off() -> Dropout<'static> {
        Dropout { p: 0.0, rng: None }
    }

    /// Inverted dropout: zeroes entries with probability `p` and scales the rest by `1/(1−p)`.
    pub fn apply(&mut self, x: Tensor<2>) -> Tensor<2> {
        let Some(rng) = self.rng.as_deref_mut() else {
            return x;
        };
        if self.p <= 0.0 {
            return x;
        }
        let [b, d] = x.dims();
        let keep = (1.0 / (1.0 - self.p)) as f32;
        let mask: Vec<f32> = (0..b * d)
            .map(|_| {
                if rng.random::<f64>() < self.p {
                    0.0
                } else {
                    keep
                }
            })
            .collect();
        let device = x.device();
        x * Tensor::from_data(TensorData::new(mask, [b, d]), &device)
    }
}

/// Layer-normalized GRU cell (papers/002 supp. eq. 12):
///
/// ```text
/// z = σ(LN(W_z x) + LN(U_z h))
/// r = σ(LN(W_r x) + LN(U_r h))
/// ĥ = tanh(LN(W_h x) + LN(U_h (r ⊙ h)))
/// h' = (1 − z) ⊙ h + z ⊙ ĥ
/// ```
///
/// `W_{z,r,h}` are one `[in, 3H]` matrix, `U_{z,r}` one `[H, 2H]`, `U_h` one `[H, H]`; each of
/// the six products has its own LayerNorm (with gain and bias).
#[derive(Module, Debug)]
pub struct LnGruCell {
    pub w: Linear,
    pub u_zr: Linear,
    pub u_h: Linear,
    pub ln_wz: LayerNorm,
    pub ln_wr: LayerNorm,
    pub ln_wh: LayerNorm,
    pub ln_uz: LayerNorm,
    pub ln_ur: LayerNorm,
    pub ln_uh: LayerNorm,
    #[module(skip)]
    pub hidden: usize,
}

impl LnGruCell {
    pub fn new(d_in: usize, hidden: usize, rng: &mut ChaCha8Rng, device: &Device) -> Self {
        let ln = || LayerNormConfig::new(hidden).init(device);
        Self {
            w: xavier_linear(d_in, 3 * hidden, 1.0, rng, device),
            u_zr: xavier_linear(hidden, 2 * hidden, 1.0, rng, device),
            u_h: xavier_linear(hidden, hidden, 1.0, rng, device),
            ln_wz: ln(),
            ln_wr: ln(),
            ln_wh: ln(),
            ln_uz: ln(),
            ln_ur: ln(),
            ln_uh: ln(),
            hidden,
        }
    }

    /// One step: `x` `[B, in]`, `h` `[B, H]` → `h'` `[B, H]`.
    pub fn forward(&self, x: Tensor<2>, h: Tensor<2>) -> Tensor<2> {
        let hd = self.hidden;
        let wx = self.w.forward(x);
        let uh = self.u_zr.forward(h.clone());
        let z = sigmoid(
            self.ln_wz.forward(wx.clone().narrow(1, 0, hd))
                + self.ln_uz.forward(uh.clone().narrow(1, 0, hd)),
        );
        let r = sigmoid(
            self.ln_wr.forward(wx.clone().narrow(1, hd, hd))
                + self.ln_ur.forward(uh.narrow(1, hd, hd)),
        );
        let cand = tanh(
            self.ln_wh.forward(wx.narrow(1, 2 * hd, hd))
                + self.ln_uh.forward(self.u_h.forward(r * h.clone())),
        );
        let one_minus_z = z.clone().neg().add_scalar(1.0);
        one_minus_z * h + z * cand
    }
}

/// A stack of [`LnGruCell`]s: layer `l` reads layer `l−1`'s new state (after dropout).
#[derive(Module, Debug)]
pub struct GruStack {
    pub cells: Vec<LnGruCell>,
}

impl GruStack {
    pub fn new(
        d_in: usize,
        hidden: usize,
        layers: usize,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        let cells = (0..layers)
            .map(|l| LnGruCell::new(if l == 0 { d_in } else { hidden }, hidden, rng, device))
            .collect();
        Self { cells }
    }

    /// `x` `[B, in]` and one state per layer → new states; the output is the last state with
    /// dropout applied (dropout acts on what a layer passes on, not on the recurrent carry).
    pub fn forward(
        &self,
        x: Tensor<2>,
        states: &[Tensor<2>],
        dropout: &mut Dropout<'_>,
    ) -> (Tensor<2>, Vec<Tensor<2>>) {
        let mut input = x;
        let mut next = Vec::with_capacity(self.cells.len());
        for (cell, h) in self.cells.iter().zip(states) {
            let h_new = cell.forward(input, h.clone());
            input = dropout.apply(h_new.clone());
            next.push(h_new);
        }
        (input, next)
    }
}

/// Residual MLP core (the "no memory" ablation): `x → ReLU(W0 x)`, then blocks
/// `y ← y + ReLU(W_l y)`; it ignores any previous state.
#[derive(Module, Debug)]
pub struct ResidualMlp {
    pub input: Linear,
    pub blocks: Vec<Linear>,
}

impl ResidualMlp {
    pub fn new(
        d_in: usize,
        hidden: usize,
        layers: usize,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        Self {
            input: xavier_linear(d_in, hidden, 1.0, rng, device),
            blocks: (1..layers)
                .map(|_| xavier_linear(hidden, hidden, 1.0, rng, device))
                .collect(),
        }
    }

    pub fn forward(&self, x: Tensor<2>, dropout: &mut Dropout<'_>) -> Tensor<2> {
        let mut y = dropout.apply(relu(self.input.forward(x)));
        for block in &self.blocks {
            y = y.clone() + dropout.apply(relu(block.forward(y)));
        }
        y
    }
}

/// The initializers Φ and Φh (papers/002 §3.5): two hidden layers of `width` units, each
/// Linear → BatchNorm → ReLU, then a linear output layer.
#[derive(Module, Debug)]
pub struct InitMlp {
    pub l1: Linear,
    pub bn1: BatchNorm,
    pub l2: Linear,
    pub bn2: BatchNorm,
    pub out: Linear,
}

impl InitMlp {
    pub fn new(
        d_in: usize,
        width: usize,
        d_out: usize,
        out_gain: f64,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        Self {
            l1: xavier_linear(d_in, width, 1.0, rng, device),
            bn1: BatchNormConfig::new(width).init(device),
            l2: xavier_linear(width, width, 1.0, rng, device),
            bn2: BatchNormConfig::new(width).init(device),
            out: xavier_linear(width, d_out, out_gain, rng, device),
        }
    }

    /// `[B, in]` → `[B, out]`; BatchNorm uses batch statistics on an autodiff device in training
    /// mode and its running statistics otherwise.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let y = relu(self.bn1.forward(self.l1.forward(x)));
        let y = relu(self.bn2.forward(self.l2.forward(y)));
        self.out.forward(y)
    }
}
