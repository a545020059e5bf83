//! The neural fitter network (papers/002 Alg. 1, eq. 1–2, SPEC §7):
//!
//! ```text
//! θ0 = Φ(D), h0 = Φh(D)
//! Δθn, hn = f([R(θ(n−1)), g(n−1), θ(n−1), D], h(n−1))
//! λ, γ    = fλγ(R(θ(n−1)), R(θ(n−1) + Δθn))
//! θn      = θ(n−1) + u(Δθn, g(n−1), λ, γ)
//! ```
//!
//! This file holds the modules and the update rule; [`crate::unroll`] runs the loop with the
//! energy's residuals and gradients.

use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::activation::{sigmoid, softplus};
use burn::tensor::{Device, Int, Tensor};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::config::{CoreKind, NetConfig, UpdateRule};
use crate::layers::{Dropout, GruStack, InitMlp, ResidualMlp, xavier_linear};
use lfit_model::error::Result;

/// A recurrent core (GRU stack) or a memoryless one (residual MLP); exactly one is set.
#[derive(Module, Debug)]
pub struct Core {
    pub gru: Option<GruStack>,
    pub mlp: Option<ResidualMlp>,
}

impl Core {
    fn new(config: &NetConfig, d_in: usize, rng: &mut ChaCha8Rng, device: &Device) -> Self {
        match config.core {
            CoreKind::Gru => Self {
                gru: Some(GruStack::new(
                    d_in,
                    config.hidden,
                    config.layers,
                    rng,
                    device,
                )),
                mlp: None,
            },
            CoreKind::ResidualMlp => Self {
                gru: None,
                mlp: Some(ResidualMlp::new(
                    d_in,
                    config.hidden,
                    config.layers,
                    rng,
                    device,
                )),
            },
        }
    }

    /// Output `[B, H]`; `states` (one per GRU layer) are replaced by the new ones.
    fn forward(
        &self,
        x: Tensor<2>,
        states: &mut Vec<Tensor<2>>,
        dropout: &mut Dropout<'_>,
    ) -> Tensor<2> {
        match (&self.gru, &self.mlp) {
            (Some(gru), _) => {
                let (out, next) = gru.forward(x, states, dropout);
                *states = next;
                out
            }
            (None, Some(mlp)) => mlp.forward(x, dropout),
            (None, None) => unreachable!("Core::new sets one of gru/mlp"),
        }
    }
}

/// The λ/γ network `fλγ` of eq. (2): one core with a head for both (shared), or one per output.
#[derive(Module, Debug)]
pub struct StepNet {
    pub lambda_core: Core,
    /// `[H, k]` (separate) or `[H, 2k]` (shared: λ then γ); `k` = 57 or 1.
    pub lambda_head: Linear,
    pub gamma_core: Option<Core>,
    pub gamma_head: Option<Linear>,
}

/// Recurrent state of one batch: per GRU layer of `f`, of the λ core and of the γ core.
#[derive(Debug, Clone)]
pub struct State {
    pub core: Vec<Tensor<2>>,
    pub lambda: Vec<Tensor<2>>,
    pub gamma: Vec<Tensor<2>>,
}

impl State {
    /// The state of the batch rows `rows` (in order), every layer's.
    pub fn select(&self, rows: &Tensor<1, Int>) -> Self {
        let pick = |layers: &[Tensor<2>]| -> Vec<Tensor<2>> {
            layers
                .iter()
                .map(|t| t.clone().select(0, rows.clone()))
                .collect()
        };
        Self {
            core: pick(&self.core),
            lambda: pick(&self.lambda),
            gamma: pick(&self.gamma),
        }
    }
}

/// Step sizes of one iteration, `[B, k]` each (`None` where the rule does not use one).
#[derive(Debug, Clone)]
pub struct StepSizes {
    pub lambda: Option<Tensor<2>>,
    pub gamma: Option<Tensor<2>>,
}

/// The whole learned fitter.
#[derive(Module, Debug)]
pub struct NeuralNet {
    /// Φ: D → θ0.
    pub phi: InitMlp,
    /// Φh: D → h0 of every GRU layer of `f` (absent for the residual-MLP core).
    pub phi_h: Option<InitMlp>,
    /// `f`, one per weight set (1, or N with per-step weights).
    pub cores: Vec<Core>,
    /// Δθ output layer per weight set, `[H, 57]`, initialised with `output_gain`.
    pub delta_heads: Vec<Linear>,
    /// `fλγ` per weight set (empty for the Δθ-only rule).
    pub steps: Vec<StepNet>,
    #[module(skip)]
    pub config: NetConfig,
}

const LN2: f64 = std::f64::consts::LN_2;

impl NeuralNet {
    /// A freshly initialised network; the same `seed` gives the same weights on every backend.
    pub fn new(config: &NetConfig, seed: u64, device: &Device) -> Result<Self> {
        config.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c = config;
        let phi = InitMlp::new(
            c.obs_features(),
            c.init_width,
            c.param_dim,
            c.output_gain,
            &mut rng,
            device,
        );
        let phi_h = (c.core == CoreKind::Gru).then(|| {
            InitMlp::new(
                c.obs_features(),
                c.init_width,
                c.layers * c.hidden,
                1.0,
                &mut rng,
                device,
            )
        });
        let mut cores = Vec::new();
        let mut delta_heads = Vec::new();
        let mut steps = Vec::new();
        let (k, kg) = (c.step_outputs(), c.gamma_outputs());
        for _ in 0..c.weight_sets() {
            cores.push(Core::new(c, c.core_inputs(), &mut rng, device));
            delta_heads.push(xavier_linear(
                c.hidden,
                c.param_dim,
                c.output_gain,
                &mut rng,
                device,
            ));
            if c.has_step_network() {
                let shared = !c.separate_gamma_network();
                let lambda_out = if shared && c.learns_gamma() {
                    k + kg
                } else {
                    k
                };
                let lambda_core = Core::new(c, c.step_inputs(), &mut rng, device);
                let lambda_head =
                    xavier_linear(c.hidden, lambda_out, c.output_gain, &mut rng, device);
                let (gamma_core, gamma_head) = if shared {
                    (None, None)
                } else {
                    (
                        Some(Core::new(c, c.step_inputs(), &mut rng, device)),
                        Some(xavier_linear(c.hidden, kg, c.output_gain, &mut rng, device)),
                    )
                };
                steps.push(StepNet {
                    lambda_core,
                    lambda_head,
                    gamma_core,
                    gamma_head,
                });
            }
        }
        Ok(Self {
            phi,
            phi_h,
            cores,
            delta_heads,
            steps,
            config: config.clone(),
        })
    }

    /// Number of scalar parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }

    /// The BatchNorm layers (Φ's, then Φh's), in a fixed order.
    fn batch_norms(&self) -> Vec<&burn::nn::BatchNorm> {
        std::iter::once(&self.phi)
            .chain(self.phi_h.as_ref())
            .flat_map(|m| [&m.bn1, &m.bn2])
            .collect()
    }

    /// Data-parallel training: sets every BatchNorm running mean and variance of this network
    /// to the mean of its own and the `copies`' (copies of this network that each trained on a
    /// shard of the batch), summed in the order given. With equal shards and BatchNorm's linear
    /// update this is the update one whole-batch pass gives the mean. Each state's pending
    /// per-thread updates are flushed first (Burn keeps them per thread until read).
    pub fn average_running_stats(&self, copies: &[&NeuralNet]) {
        let own = self.batch_norms();
        let others: Vec<Vec<&burn::nn::BatchNorm>> =
            copies.iter().map(|c| c.batch_norms()).collect();
        let count = (1 + copies.len()) as f64;
        for (i, bn) in own.iter().enumerate() {
            for pick in [
                |b: &burn::nn::BatchNorm| b.running_mean.clone(),
                |b: &burn::nn::BatchNorm| b.running_var.clone(),
            ] {
                let state = pick(bn);
                // `valid` flushes the per-thread updates into the value (and returns a copy).
                let _ = state.valid();
                let mut sum = state.value();
                for other in &others {
                    let s = pick(other[i]);
                    let _ = s.valid();
                    sum = sum + s.value();
                }
                state.update(sum.div_scalar(count).detach());
                let _ = state.valid();
            }
        }
    }

    /// θ0 = Φ(D) `[B, 57]` and the initial state (h0 = Φh(D) for `f`, zeros for `fλγ`).
    pub fn initial(&self, obs: Tensor<2>) -> (Tensor<2>, State) {
        let [batch, _] = obs.dims();
        let device = obs.device();
        let c = &self.config;
        let theta0 = self.phi.forward(obs.clone());
        let core = match &self.phi_h {
            Some(phi_h) => {
                let h = phi_h.forward(obs);
                (0..c.layers)
                    .map(|l| h.clone().narrow(1, l * c.hidden, c.hidden))
                    .collect()
            }
            None => Vec::new(),
        };
        let zeros = || {
            (0..c.recurrent_layers())
                .map(|_| Tensor::zeros([batch, c.hidden], &device))
                .collect()
        };
        (
            theta0,
            State {
                core,
                lambda: zeros(),
                gamma: zeros(),
            },
        )
    }

    /// Δθn `[B, 57]` from the core inputs `[R, g, θ, D]` (normalised) of iteration `n` (0-based).
    pub fn propose(
        &self,
        n: usize,
        inputs: Tensor<2>,
        state: &mut State,
        dropout: &mut Dropout<'_>,
    ) -> Tensor<2> {
        let s = self.config.weight_set(n);
        let h = self.cores[s].forward(inputs, &mut state.core, dropout);
        self.delta_heads[s].forward(h)
    }

    /// λ and γ of iteration `n` from `[R(θ), R(θ + Δθ)]` (normalised), already passed through
    /// the rule's activation: eq. (1) `λ = 1 + a`, convex rules `λ = σ(a)`; learned
    /// `γ = γ_init · softplus(b)/ln 2` (so γ = γ_init where the head outputs 0).
    pub fn step_sizes(
        &self,
        n: usize,
        inputs: Tensor<2>,
        state: &mut State,
        dropout: &mut Dropout<'_>,
    ) -> StepSizes {
        let c = &self.config;
        if !c.has_step_network() {
            return StepSizes {
                lambda: None,
                gamma: None,
            };
        }
        let s = self.config.weight_set(n);
        let net = &self.steps[s];
        let (k, kg) = (c.step_outputs(), c.gamma_outputs());
        let out = net.lambda_head.forward(net.lambda_core.forward(
            inputs.clone(),
            &mut state.lambda,
            dropout,
        ));
        let (a, b) = match (&net.gamma_core, &net.gamma_head) {
            (Some(core), Some(head)) => (
                out,
                Some(head.forward(core.forward(inputs, &mut state.gamma, dropout))),
            ),
            _ if c.learns_gamma() => (out.clone().narrow(1, 0, k), Some(out.narrow(1, k, kg))),
            _ => (out, None),
        };
        let lambda = match c.update {
            UpdateRule::Eq1 => a.add_scalar(1.0),
            _ => sigmoid(a),
        };
        let gamma = match b {
            Some(b) => softplus(b, 1.0).mul_scalar(c.gamma_init / LN2),
            None => {
                let [batch, _] = lambda.dims();
                Tensor::full([batch, kg], c.gamma_constant, &lambda.device())
            }
        };
        StepSizes {
            lambda: Some(lambda),
            gamma: Some(gamma),
        }
    }

    /// The update `u(Δθ, g, λ, γ)` of the configured rule, `[B, 57]` (`g` is the raw energy
    /// gradient, `[B, 57]`).
    pub fn update(&self, delta: Tensor<2>, grad: Tensor<2>, sizes: &StepSizes) -> Tensor<2> {
        let (lambda, gamma) = match (&sizes.lambda, &sizes.gamma) {
            (Some(l), Some(g)) => (l.clone(), g.clone()),
            _ => return delta,
        };
        match self.config.update {
            UpdateRule::DeltaOnly => delta,
            UpdateRule::Eq1 => lambda * delta - gamma * grad,
            UpdateRule::Convex => {
                let one_minus = lambda.clone().neg().add_scalar(1.0);
                lambda * delta - one_minus * gamma * grad
            }
            UpdateRule::ConvexNormalized => {
                let unit = |x: Tensor<2>| {
                    let norm = x.clone().powi_scalar(2).sum_dim(1).add_scalar(1e-12).sqrt();
                    x / norm
                };
                let one_minus = lambda.clone().neg().add_scalar(1.0);
                gamma * (lambda * unit(delta) - one_minus * unit(grad))
            }
        }
    }
}
