//! The radiance cache's fused training step and inference on the GPU, as CubeCL kernels run by
//! burn's Cube backend (wgpu here; the same kernels compile for CUDA and SPIR-V).
//!
//! This crate knows nothing of caches: it takes the model as a [`Layout`] (plain numbers), the
//! packed rows and the training state as burn `CubeTensor`s, and launches [`kernels`]. One
//! training step is four dispatches ([`STEP_DISPATCHES`]; two without a hash grid): the tile
//! pass (encode → MLP forward → loss → MLP backward, per tile of rows in workgroup memory), the
//! MLP's reduction + Adam + EMA, the hash-grid gradient scatter, and the table's sparse Adam +
//! EMA gap (over a list of the referenced entries where the batch is small against the table,
//! else over every entry, skipping the untouched). Inference is one dispatch. `nrc_cache`
//! implements its fused-ops interface with it.

pub mod kernels;

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use burn::backend::wgpu::CubeTensor;
use burn::cubecl::features::AtomicUsage;
use burn::cubecl::ir::{ElemType, FloatKind};
use burn::cubecl::prelude::*;
use burn::tensor::{DType, Shape, f16};

use kernels::{LEVEL_WORDS, PART_WORDS, WIDTH};

/// Dispatches of one training step with a hash grid (tile pass, MLP update, scatter, table
/// update); without a grid the last two are skipped.
pub const STEP_DISPATCHES: u64 = 4;

/// Cubes of the tile passes at most: each keeps a weight-gradient partial, so more cubes cost
/// memory and reduction time; this many fill a large GPU.
const MAX_TILE_CUBES: usize = 1024;
/// Workgroup barriers one cube of a tile pass may execute, at most: each cube takes at least
/// enough tiles for this. On lavapipe (llvmpipe, Mesa 22.3) a cube that executed more than
/// about 700–950 barriers computed wrong results (the 4097-row gradient test with the cubes
/// capped at 3: 86 tiles of a 4-hidden-layer network, 12 barriers a tile, lost a third of its
/// loss; 64 tiles were right); whether hardware drivers share the limit is not known, and the
/// extra cubes cost only partials.
const MAX_BARRIERS_PER_CUBE: usize = 512;

/// Cubes for `tiles` tiles of `barriers` barriers each, at most `cap` unless the barrier bound
/// needs more.
fn tile_cubes(tiles: usize, barriers: usize, cap: usize) -> usize {
    let per_cube = (MAX_BARRIERS_PER_CUBE / barriers).max(1);
    tiles.min(cap).max(tiles.div_ceil(per_cube)).max(1)
}

/// Units per cube of the element-wise kernels.
const ELEMENTWISE: u32 = 256;

static DISPATCHES: AtomicU64 = AtomicU64::new(0);
/// A smaller cap on the tile passes' cubes (0: none), so that tests make every cube walk
/// several tiles on small batches.
static CUBE_CAP: AtomicU64 = AtomicU64::new(0);

/// Caps the tile passes' cubes below [`MAX_TILE_CUBES`] (`None`: no cap): for tests of the path
/// where a cube sums several tiles into its partial.
pub fn set_cube_cap(cap: Option<usize>) {
    CUBE_CAP.store(cap.map_or(0, |c| c.max(1) as u64), Ordering::Relaxed);
}

/// 0: the table update lists the referenced entries on small batches only; 1: always; 2: never.
static TABLE_LIST: AtomicU64 = AtomicU64::new(0);

/// Forces the table update's mode (`Some(true)`: visit a list of the referenced entries;
/// `Some(false)`: every entry; `None`: a list where the batch references fewer than a quarter
/// of them): for tests of both.
pub fn set_table_list(list: Option<bool>) {
    TABLE_LIST.store(
        match list {
            None => 0,
            Some(true) => 1,
            Some(false) => 2,
        },
        Ordering::Relaxed,
    );
}

fn max_cubes() -> usize {
    match CUBE_CAP.load(Ordering::Relaxed) {
        0 => MAX_TILE_CUBES,
        c => (c as usize).min(MAX_TILE_CUBES),
    }
}

/// Kernel launches by this crate since the process started (for dispatch-count guards).
pub fn dispatches() -> u64 {
    DISPATCHES.load(Ordering::Relaxed)
}

fn counted() {
    DISPATCHES.fetch_add(1, Ordering::Relaxed);
}

/// One level of the hash grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Level {
    /// `s_l`, the very f32 the CPU uses.
    pub scale: f32,
    /// Vertices per axis.
    pub resolution: u32,
    /// Table entries.
    pub entries: u32,
    /// First entry of the level in the table.
    pub offset: u32,
    /// Indexed densely (else hashed).
    pub dense: bool,
}

/// The hash grid of the encoding.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    /// Features per entry (1, 2, 4 or 8).
    pub features: usize,
    /// The levels, coarse to fine.
    pub levels: Vec<Level>,
    /// Raw input column of the position's x.
    pub in_offset: usize,
    /// First network-input column of the grid's features.
    pub out_offset: usize,
}

impl Grid {
    /// Table entries over all levels.
    pub fn entries(&self) -> usize {
        self.levels.iter().map(|l| l.entries as usize).sum()
    }
}

/// A non-grid part of the composite encoding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PartKind {
    /// One-blob with this many bins, periodic or not.
    OneBlob {
        /// Bins per dimension.
        bins: u32,
        /// Periodic.
        wrap: bool,
    },
    /// Triangle waves of this many octaves.
    TriangleWave {
        /// Octaves per dimension.
        frequencies: u32,
    },
    /// `x·scale + offset`.
    Identity {
        /// Multiplier.
        scale: f32,
        /// Offset.
        offset: f32,
    },
}

/// A non-grid encoding part and where it reads and writes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Part {
    /// What it computes.
    pub kind: PartKind,
    /// First raw input read.
    pub in_offset: usize,
    /// Raw inputs read.
    pub in_dims: usize,
    /// First network-input column written.
    pub out_offset: usize,
}

/// The output activation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// `exp(clamp(o, ±40))`.
    Exponential,
    /// `ln(1 + e^o)`.
    Softplus,
    /// `max(o, 0)`.
    ReLU,
}

/// The model as the kernels need it.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    /// Network inputs after padding with ones.
    pub inputs: usize,
    /// Network inputs before padding.
    pub unpadded: usize,
    /// Hidden layers of [`WIDTH`] neurons (at least 1).
    pub hidden: usize,
    /// Output activation.
    pub activation: Activation,
    /// The hash grid, if any.
    pub grid: Option<Grid>,
    /// The other parts of the encoding.
    pub parts: Vec<Part>,
    /// Raw inputs per row (the reflectance factor follows them; in a training row the target
    /// and the weight follow that).
    pub raw_dims: usize,
    /// The MLP in half precision: its weights read from an f16 copy and its activations (the
    /// encoded inputs and every hidden layer's outputs) kept in f16 in workgroup memory, every
    /// product summed in f32; the loss, the backward's deltas, the gradients and Adam's master
    /// weights stay f32 (tiny-cuda-nn's mixed precision without its f16 backward, which needs
    /// loss scaling). Needs f16 arithmetic ([`supports_f16`]).
    pub half_mlp: bool,
}

impl Layout {
    /// MLP weights: `inputs × 64`, `(hidden − 1) × 64 × 64`, `64 × 3`.
    pub fn mlp_len(&self) -> usize {
        self.inputs * WIDTH + (self.hidden - 1) * WIDTH * WIDTH + WIDTH * 3
    }

    /// Floats of a training row.
    pub fn train_row(&self) -> usize {
        self.raw_dims + 7
    }

    /// Floats of a query row.
    pub fn query_row(&self) -> usize {
        self.raw_dims + 3
    }

    fn levels(&self) -> usize {
        self.grid.as_ref().map_or(0, |g| g.levels.len())
    }

    fn features(&self) -> usize {
        self.grid.as_ref().map_or(1, |g| g.features)
    }

    fn grid_dims(&self) -> usize {
        self.levels() * self.features()
    }

    /// The info words the kernels read: the levels, then the parts.
    fn info(&self) -> Vec<u32> {
        let mut info =
            Vec::with_capacity(self.levels() * LEVEL_WORDS + self.parts.len() * PART_WORDS);
        for l in self.grid.iter().flat_map(|g| &g.levels) {
            info.extend([
                l.scale.to_bits(),
                l.resolution,
                l.entries,
                l.offset,
                u32::from(l.dense),
            ]);
        }
        for p in &self.parts {
            let (kind, count, wrap, scale, offset) = match p.kind {
                PartKind::OneBlob { bins, wrap } => (1, bins, u32::from(wrap), 1.0f32, 0.0f32),
                PartKind::TriangleWave { frequencies } => (2, frequencies, 0, 1.0, 0.0),
                PartKind::Identity { scale, offset } => (3, 1, 0, scale, offset),
            };
            info.extend([
                kind,
                p.in_offset as u32,
                p.in_dims as u32,
                p.out_offset as u32,
                count,
                wrap,
                scale.to_bits(),
                offset.to_bits(),
            ]);
        }
        // A buffer is never empty (a zero-sized binding is refused).
        info.push(0);
        info
    }

    /// Checks what the kernels assume.
    pub fn check(&self) -> Result<(), String> {
        if self.hidden == 0 {
            return Err("the fused GPU path needs at least one hidden layer".into());
        }
        if let Some(g) = &self.grid
            && !matches!(g.features, 1 | 2 | 4 | 8)
        {
            return Err(format!(
                "the fused GPU path takes 1, 2, 4 or 8 features per level, not {}",
                g.features
            ));
        }
        if let Some(g) = &self.grid
            && g.entries() * g.features >= 1 << 31
        {
            return Err(format!(
                "the fused GPU path indexes the table with 32-bit integers: {} entries of {} \
                 features are too many",
                g.entries(),
                g.features
            ));
        }
        Ok(())
    }

    /// Checks that a batch of `n` rows can be indexed with 32-bit integers.
    pub fn check_rows(&self, n: usize) -> Result<(), String> {
        let widest = self.train_row().max(self.grid_dims()).max(3);
        if n.saturating_mul(widest) >= 1 << 31 {
            return Err(format!(
                "the fused GPU path indexes with 32-bit integers: {n} rows are too many"
            ));
        }
        Ok(())
    }
}

/// How the gradient scatter adds floats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Atomics {
    /// The adapter's float atomic add (`SHADER_FLOAT32_ATOMIC` on wgpu).
    Native,
    /// A compare-and-swap loop on the float's bits (any adapter).
    CompareSwap,
}

impl Atomics {
    /// What `client` offers: native float adds where it has them.
    pub fn best(client: &Client) -> Self {
        let native = client
            .properties()
            .atomic_type_usage(Type::atomic(ElemType::Float(FloatKind::F32)))
            .contains(AtomicUsage::Add);
        if native {
            Self::Native
        } else {
            Self::CompareSwap
        }
    }

    /// Its name in descriptions.
    pub fn name(self) -> &'static str {
        match self {
            Self::Native => "native f32 atomics",
            Self::CompareSwap => "compare-and-swap f32 adds",
        }
    }
}

/// Rows per tile for `layout` within the device's workgroup memory, and the values of the
/// activation buffer at that size: the largest of 32, 16, 8, 4, 2, 1 that fits.
pub fn tile_rows(client: &Client, layout: &Layout) -> Result<(usize, usize), String> {
    if layout.half_mlp && !supports_f16(client) {
        return Err(
            "the half-precision MLP needs f16 arithmetic (shader-f16), which the adapter lacks"
                .into(),
        );
    }
    let limit = client.properties().hardware.max_shared_memory_size;
    let act_bytes = if layout.half_mlp { 2 } else { 4 };
    for r in [32usize, 16, 8, 4, 2, 1] {
        let act = r * layout.inputs + layout.hidden * r * WIDTH;
        // act (f16 with a half-precision MLP) + small (7 per row) + delta (2 × 64 per row), f32.
        let bytes = act_bytes * act + 4 * (7 * r + 2 * r * WIDTH);
        if bytes <= limit {
            return Ok((r, act));
        }
    }
    Err(format!(
        "the fused GPU path needs more workgroup memory than the adapter has ({limit} bytes)"
    ))
}

fn buffer(t: &CubeTensor) -> BufferArg {
    let n = t.meta.shape().num_elements();
    // SAFETY: the length is the tensor's own element count (contiguous f32 or u32 tensors, as
    // every caller makes sure), so the kernels' bounds are the buffer's.
    unsafe { BufferArg::from_raw_parts(t.handle.clone(), n.max(1)) }
}

/// A 1-D contiguous tensor of `values` on `like`'s device.
fn upload_u32(like: &CubeTensor, values: &[u32]) -> CubeTensor {
    let handle = like.client.create_from_slice(bytemuck::cast_slice(values));
    CubeTensor::new_contiguous(
        like.client.clone(),
        like.device.clone(),
        Shape::new([values.len()]),
        handle,
        DType::U32,
    )
}

/// A zeroed f32 (or u32) tensor of `len` elements on `like`'s device.
fn zeros(like: &CubeTensor, len: usize, dtype: DType) -> CubeTensor {
    let handle = like.client.create_from_slice(&vec![0u8; 4 * len.max(1)]);
    CubeTensor::new_contiguous(
        like.client.clone(),
        like.device.clone(),
        Shape::new([len.max(1)]),
        handle,
        dtype,
    )
}

static POISON: AtomicBool = AtomicBool::new(false);

/// With `true`, every buffer a kernel is to fill starts as NaN instead of uninitialised memory
/// (pooled memory often holds zeros, which would hide a value a kernel fails to write): for
/// tests.
pub fn set_poison(on: bool) {
    POISON.store(on, Ordering::Relaxed);
}

/// An f32 tensor of `len` elements on `like`'s device, for a kernel to fill (uninitialised, or
/// NaN under [`set_poison`]).
fn empty(like: &CubeTensor, len: usize) -> CubeTensor {
    let bytes = 4 * len.max(1);
    let handle = if POISON.load(Ordering::Relaxed) {
        let nan = vec![f32::NAN; len.max(1)];
        like.client.create_from_slice(bytemuck::cast_slice(&nan))
    } else {
        like.client.empty(bytes)
    };
    CubeTensor::new_contiguous(
        like.client.clone(),
        like.device.clone(),
        Shape::new([len]),
        handle,
        DType::F32,
    )
}

fn elementwise_count(len: usize) -> CubeCount {
    let groups = len.div_ceil(ELEMENTWISE as usize).max(1) as u32;
    let x = groups.min(65_535);
    CubeCount::Static(x, groups.div_ceil(x), 1)
}

/// The table-sized scratch of finished runs (the gradient accumulator and the touched marks),
/// all zeros again (the table update clears what the scatter wrote), kept for the next run on
/// the same device and table: a run allocating and zeroing them anew cost a 60 MiB upload
/// per `train` call with the hash-grid preset.
static SCRATCH: Mutex<Vec<(CubeTensor, CubeTensor)>> = Mutex::new(Vec::new());
/// Scratch pairs kept at most (one per cache alive, typically one).
const SCRATCH_KEPT: usize = 4;

fn take_scratch(like: &CubeTensor, entries: usize, features: usize) -> (CubeTensor, CubeTensor) {
    let mut pool = SCRATCH.lock().unwrap_or_else(|e| e.into_inner());
    let fits = |(g, t): &(CubeTensor, CubeTensor)| {
        g.device == like.device
            && g.meta.shape().num_elements() == entries * features
            && t.meta.shape().num_elements() == entries
    };
    if let Some(i) = pool.iter().position(fits) {
        return pool.swap_remove(i);
    }
    drop(pool);
    (
        zeros(like, entries * features, DType::F32),
        zeros(like, entries, DType::U32),
    )
}

impl Drop for Trainer {
    fn drop(&mut self) {
        // Only scratch known to be zero goes back: not after `gradients` (no table update
        // cleared it) or a panic (a step may have stopped between the scatter and the update).
        if self.dirty || std::thread::panicking() {
            return;
        }
        if let (Some(g), Some(t)) = (self.grad.take(), self.touched.take()) {
            let mut pool = SCRATCH.lock().unwrap_or_else(|e| e.into_inner());
            if pool.len() >= SCRATCH_KEPT {
                pool.remove(0);
            }
            pool.push((g, t));
        }
    }
}

/// What [`Trainer::gradients`] reads back.
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients {
    /// Mean loss over samples and channels.
    pub loss: f32,
    /// ∂L/∂(MLP weights).
    pub mlp: Vec<f32>,
    /// ∂L/∂table, dense (`[entries · F]`; empty without a grid).
    pub table: Vec<f32>,
}

/// Adam's constants of one step (as `nrc_cache::cpu::optim::StepConstants`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamStep {
    /// β₁.
    pub beta1: f32,
    /// β₂.
    pub beta2: f32,
    /// ε.
    pub epsilon: f32,
    /// L2 regularisation.
    pub l2: f32,
    /// `learning rate / (1 − β₁^t)`.
    pub step_size: f32,
    /// `1 / (1 − β₂^t)`.
    pub inv_bc2: f32,
    /// The EMA decay, if any.
    pub ema: Option<f32>,
    /// The factor of a table weight's change in its EMA gap.
    pub gap_growth: f32,
}

/// The loss settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Loss {
    /// ε of the relative loss.
    pub epsilon: f32,
    /// The relative residual beyond which the loss is linear.
    pub huber: f32,
}

/// The hash table's training state: weights, Adam's moments and the EMA gap (see
/// `nrc_cache::cpu::optim`), `[entries · F]` each.
#[derive(Debug)]
pub struct TableState<'a> {
    /// Weights.
    pub w: &'a CubeTensor,
    /// Adam's first moment.
    pub m: &'a CubeTensor,
    /// Adam's second moment.
    pub v: &'a CubeTensor,
    /// The EMA gap.
    pub q: &'a CubeTensor,
    /// The weights rounded to half precision (f16), which the training forward reads instead
    /// of `w` where present; every update keeps it equal to `w` rounded.
    pub half: Option<&'a CubeTensor>,
}

/// The training state, updated in place: the table (`None` without a grid) and the MLP's
/// weights, moments and raw EMA. Every tensor must be contiguous f32 and not shared
/// (`CubeTensor::can_mut`). The table's four arrays are separate (not the CPU's per-entry
/// records): one binding each, so a 2^19-entry table stays within WebGPU's 128 MiB binding.
#[derive(Debug)]
pub struct State<'a> {
    /// The hash table.
    pub table: Option<TableState<'a>>,
    /// MLP weights.
    pub mlp: &'a CubeTensor,
    /// Adam's first moment of the MLP.
    pub mlp_m: &'a CubeTensor,
    /// Adam's second moment.
    pub mlp_v: &'a CubeTensor,
    /// The raw EMA.
    pub mlp_ema: &'a CubeTensor,
    /// The MLP's weights rounded to f16, which the tile pass reads instead of `mlp` where
    /// present (a layout with [`Layout::half_mlp`]); every update keeps it equal to `mlp`
    /// rounded.
    pub mlp_half: Option<&'a CubeTensor>,
}

/// A run of training steps on one batch: the rows uploaded once, the scratch allocated once,
/// the losses kept on the device until [`Trainer::losses`].
#[derive(Debug)]
pub struct Trainer {
    layout: Layout,
    rows: CubeTensor,
    n: usize,
    info: CubeTensor,
    dxg: CubeTensor,
    wpart: CubeTensor,
    lpart: CubeTensor,
    grad: Option<CubeTensor>,
    touched: Option<CubeTensor>,
    losses: CubeTensor,
    no_table: CubeTensor,
    r_tile: usize,
    act_len: usize,
    cubes: usize,
    atomics: Atomics,
    steps: usize,
    /// The scratch may hold non-zero values (after [`Trainer::gradients`]).
    dirty: bool,
    /// The referenced entries, listed by the scatter for the table update (small batches: see
    /// [`Trainer::new`]), and the two counters of their lengths (by step parity).
    list: Option<(CubeTensor, CubeTensor)>,
}

impl Trainer {
    /// Prepares `steps` steps on the packed rows `rows` (`n` rows of [`Layout::train_row`]
    /// floats, contiguous f32).
    pub fn new(
        layout: &Layout,
        rows: CubeTensor,
        n: usize,
        steps: usize,
        atomics: Atomics,
    ) -> Result<Self, String> {
        layout.check()?;
        layout.check_rows(n)?;
        let client = rows.client.clone();
        let (r_tile, act_len) = tile_rows(&client, layout)?;
        let tiles = n.div_ceil(r_tile).max(1);
        // Barriers a tile: encoding, each layer forward, the loss, the output layer and each
        // hidden layer backward, the tile's end.
        let cubes = tile_cubes(tiles, 2 * layout.hidden + 4, max_cubes());
        let info = upload_u32(&rows, &layout.info());
        let dxg = empty(&rows, n * layout.grid_dims());
        let wpart = empty(&rows, cubes * layout.mlp_len());
        let lpart = empty(&rows, cubes);
        let entries = layout.grid.as_ref().map_or(0, Grid::entries);
        let (grad, touched) = if layout.grid.is_some() {
            let (g, t) = take_scratch(&rows, entries, layout.features());
            (Some(g), Some(t))
        } else {
            (None, None)
        };
        let losses = zeros(&rows, steps, DType::F32);
        let no_table = zeros(&rows, 1, DType::F32);
        // The table update visits the listed entries instead of all of them where the batch
        // can reference fewer than a quarter of the entries (each sample 8 corners a level).
        let references = n * layout.levels() * 8;
        let small = match TABLE_LIST.load(Ordering::Relaxed) {
            1 => true,
            2 => false,
            _ => 4 * references < entries,
        };
        let list = (layout.grid.is_some() && small).then(|| {
            let list = CubeTensor::new_contiguous(
                rows.client.clone(),
                rows.device.clone(),
                Shape::new([references]),
                rows.client.empty(4 * references.max(1)),
                DType::U32,
            );
            (list, zeros(&rows, 2, DType::U32))
        });
        Ok(Self {
            no_table,
            layout: layout.clone(),
            rows,
            n,
            info,
            dxg,
            wpart,
            lpart,
            grad,
            touched,
            losses,
            r_tile,
            act_len,
            cubes,
            atomics,
            steps,
            dirty: false,
            list,
        })
    }

    /// Rows per tile chosen for this device.
    pub fn tile_rows(&self) -> usize {
        self.r_tile
    }

    /// Step `index` (0-based within this run) on `state`.
    pub fn step(&self, index: usize, state: &State<'_>, adam: &AdamStep, loss: Loss) {
        assert!(
            index < self.steps,
            "step {index} of a run of {}",
            self.steps
        );
        let l = &self.layout;
        let client = &self.rows.client;
        let (levels, features) = (l.levels(), l.features());
        let grid = l.grid.as_ref();
        // The list counter this step's scatter counts in (the table update zeroes the other).
        let parity = (index % 2) as u32;
        let (grid_in, grid_out) = grid.map_or((0, 0), |g| (g.in_offset, g.out_offset));
        let table = state
            .table
            .as_ref()
            .map_or(&self.no_table, |t| t.half.unwrap_or(t.w));
        let n = self.n;
        assert_eq!(
            state.mlp_half.map(|h| h.dtype == DType::F16),
            l.half_mlp.then_some(true),
            "the MLP's f16 copy (an f16 tensor) is given exactly when the layout has a \
             half-precision MLP"
        );
        let mlp = state.mlp_half.unwrap_or(state.mlp);
        if n > 0 {
            self.launch_tiles(table, mlp, loss, levels, features, grid_in, grid_out);
        }
        let w_total = l.mlp_len();
        macro_rules! mlp_adam {
            ($h:ty, $half:expr, $with_half:expr) => {
                kernels::mlp_adam::launch::<$h>(
                    client,
                    elementwise_count(w_total),
                    CubeDim::new_1d(ELEMENTWISE),
                    buffer(&self.wpart),
                    buffer(&self.lpart),
                    buffer(state.mlp),
                    buffer(state.mlp_m),
                    buffer(state.mlp_v),
                    buffer(state.mlp_ema),
                    buffer($half),
                    buffer(&self.losses),
                    if n > 0 { self.cubes as u32 } else { 0 },
                    w_total as u32,
                    index as u32,
                    1.0 / (3.0 * n.max(1) as f32),
                    adam.beta1,
                    adam.beta2,
                    adam.epsilon,
                    adam.l2,
                    adam.step_size,
                    adam.inv_bc2,
                    adam.ema.unwrap_or(0.0),
                    adam.ema.is_some(),
                    $with_half,
                )
            };
        }
        match state.mlp_half {
            Some(h) => mlp_adam!(f16, h, true),
            None => mlp_adam!(f32, &self.no_table, false),
        }
        counted();
        let (Some(g), Some(table), Some(grad), Some(touched)) =
            (grid, &state.table, &self.grad, &self.touched)
        else {
            return;
        };
        if n > 0 {
            self.launch_scatter(g, grad, touched, parity);
        }
        let entries = g.entries();
        let (list, counter, with_list) = self.list_args();
        let units = if with_list { n * levels * 8 } else { entries };
        macro_rules! table_adam {
            ($h:ty, $half:expr, $with_half:expr) => {
                kernels::table_adam::launch::<$h>(
                    client,
                    elementwise_count(units),
                    CubeDim::new_1d(ELEMENTWISE),
                    buffer(table.w),
                    buffer(table.m),
                    buffer(table.v),
                    buffer(table.q),
                    buffer(grad),
                    buffer(touched),
                    buffer($half),
                    buffer(list),
                    buffer(counter),
                    parity,
                    entries as u32,
                    adam.beta1,
                    adam.beta2,
                    adam.epsilon,
                    adam.l2,
                    adam.step_size,
                    adam.inv_bc2,
                    adam.gap_growth,
                    features,
                    adam.ema.is_some(),
                    $with_half,
                    with_list,
                )
            };
        }
        match table.half {
            Some(h) => table_adam!(f16, h, true),
            None => table_adam!(f32, &self.no_table, false),
        }
        counted();
    }

    fn launch_tiles(
        &self,
        table: &CubeTensor,
        mlp: &CubeTensor,
        loss: Loss,
        levels: usize,
        features: usize,
        grid_in: usize,
        grid_out: usize,
    ) {
        let l = &self.layout;
        let n = self.n;
        // SAFETY: every index the kernel forms is in bounds: rows and outputs below `n`, table
        // indices below the level's offset + entries (modulo or mask), partials below `cubes`,
        // workgroup memory within the sizes `tile_rows` chose (checked by the gradient tests
        // with poisoned buffers); its loops are bounded by `n`, the tile count and the layout.
        macro_rules! tiles {
            ($t:ty, $m:ty) => {
                unsafe {
                    kernels::train_tiles::launch_unchecked::<$t, $m>(
                        &self.rows.client,
                        CubeCount::Static(self.cubes as u32, 1, 1),
                        CubeDim::new_1d(WIDTH as u32),
                        buffer(&self.rows),
                        buffer(table),
                        buffer(&self.info),
                        buffer(mlp),
                        buffer(&self.dxg),
                        buffer(&self.wpart),
                        buffer(&self.lpart),
                        n as u32,
                        l.parts.len() as u32,
                        loss.epsilon,
                        loss.huber,
                        1.0 / (3.0 * n as f32),
                        self.r_tile,
                        l.inputs,
                        l.hidden,
                        levels,
                        features,
                        features,
                        l.train_row(),
                        grid_in,
                        grid_out,
                        l.unpadded,
                        l.raw_dims,
                        activation_code(l.activation),
                        l.mlp_len(),
                        self.act_len,
                    )
                }
            };
        }
        match (table.dtype == DType::F16, mlp.dtype == DType::F16) {
            (true, true) => tiles!(f16, f16),
            (true, false) => tiles!(f16, f32),
            (false, true) => tiles!(f32, f16),
            (false, false) => tiles!(f32, f32),
        }
        counted();
    }

    fn launch_scatter(&self, g: &Grid, grad: &CubeTensor, touched: &CubeTensor, parity: u32) {
        let (list, counter, with_list) = self.list_args();
        let l = &self.layout;
        let n = self.n;
        let (levels, features) = (l.levels(), l.features());
        let count = elementwise_count(n * levels);
        let dim = CubeDim::new_1d(ELEMENTWISE);
        let client = &self.rows.client;
        macro_rules! scatter {
            ($kernel:ident) => {
                kernels::$kernel::launch(
                    client,
                    count,
                    dim,
                    buffer(&self.rows),
                    buffer(&self.info),
                    buffer(&self.dxg),
                    buffer(grad),
                    buffer(touched),
                    buffer(list),
                    buffer(counter),
                    n as u32,
                    parity,
                    levels,
                    features,
                    l.train_row(),
                    g.in_offset,
                    with_list,
                )
            };
        }
        match self.atomics {
            Atomics::Native => scatter!(scatter_native),
            Atomics::CompareSwap => scatter!(scatter_cas),
        }
        counted();
    }

    /// The list buffers the scatter and the table update take (dummies without a list).
    fn list_args(&self) -> (&CubeTensor, &CubeTensor, bool) {
        match &self.list {
            Some((list, counter)) => (list, counter, true),
            None => (&self.no_table, &self.no_table, false),
        }
    }

    /// The loss and the gradients of one step on `state`, without an update (the tile pass and
    /// the scatter only, read back): how the kernels are checked against the CPU's.
    pub fn gradients(&mut self, state: &State<'_>, loss: Loss) -> Result<Gradients, String> {
        self.dirty = true;
        let l = &self.layout;
        let client = &self.rows.client;
        let n = self.n;
        let (levels, features) = (l.levels(), l.features());
        let (grid_in, grid_out) = l
            .grid
            .as_ref()
            .map_or((0, 0), |g| (g.in_offset, g.out_offset));
        let table = state.table.as_ref().map_or(&self.no_table, |t| t.w);
        if state.mlp_half.map(|h| h.dtype == DType::F16) != l.half_mlp.then_some(true) {
            return Err(
                "the MLP's f16 copy must be given exactly when the layout has a \
                        half-precision MLP"
                    .into(),
            );
        }
        let mlp = state.mlp_half.unwrap_or(state.mlp);
        let w_total = l.mlp_len();
        if n == 0 {
            return Ok(Gradients {
                loss: 0.0,
                mlp: vec![0.0; w_total],
                table: vec![0.0; l.grid.as_ref().map_or(0, |g| g.entries() * g.features)],
            });
        }
        self.launch_tiles(table, mlp, loss, levels, features, grid_in, grid_out);
        if let (Some(g), Some(grad), Some(touched)) = (&l.grid, &self.grad, &self.touched) {
            self.launch_scatter(g, grad, touched, 0);
        }
        let read = |t: &CubeTensor| -> Result<Vec<f32>, String> {
            let bytes = client
                .read_one(t.handle.clone())
                .map_err(|e| format!("reading back from the GPU: {e:?}"))?;
            let len = t.meta.shape().num_elements();
            Ok(bytemuck::cast_slice::<u8, f32>(&bytes[..4 * len]).to_vec())
        };
        let parts = read(&self.wpart)?;
        let mut mlp = vec![0f32; w_total];
        for part in parts.chunks_exact(w_total).take(self.cubes) {
            for (g, p) in mlp.iter_mut().zip(part) {
                *g += p;
            }
        }
        let loss_sum: f32 = read(&self.lpart)?[..self.cubes].iter().sum();
        let table = match &self.grad {
            Some(g) => read(g)?,
            None => Vec::new(),
        };
        Ok(Gradients {
            loss: loss_sum / (3.0 * n as f32),
            mlp,
            table,
        })
    }

    /// The mean loss of every step of the run, on the device (`[steps]`; reading it waits for
    /// the steps).
    pub fn loss_tensor(&self) -> CubeTensor {
        CubeTensor::new_contiguous(
            self.losses.client.clone(),
            self.losses.device.clone(),
            Shape::new([self.steps]),
            self.losses.handle.clone(),
            DType::F32,
        )
    }

    /// The mean loss of every step of the run (one read of the device).
    pub fn losses(&self) -> Result<Vec<f32>, String> {
        let bytes = self
            .rows
            .client
            .read_one(self.losses.handle.clone())
            .map_err(|e| format!("reading the losses back from the GPU: {e:?}"))?;
        let values: &[f32] = bytemuck::cast_slice(&bytes[..4 * self.steps]);
        Ok(values.to_vec())
    }
}

fn activation_code(a: Activation) -> u32 {
    match a {
        Activation::Exponential => 0,
        Activation::Softplus => 1,
        Activation::ReLU => 2,
    }
}

/// Fused inference: radiance (an `[n, 3]` tensor) of the packed query rows `rows` (`n` rows of
/// [`Layout::query_row`] floats) with the table `table` (`[entries · F]`, plain weights) and the
/// MLP weights `mlp` (f16 exactly when the layout has [`Layout::half_mlp`]).
pub fn infer(
    layout: &Layout,
    table: &CubeTensor,
    mlp: &CubeTensor,
    rows: &CubeTensor,
    n: usize,
) -> Result<CubeTensor, String> {
    layout.check()?;
    layout.check_rows(n)?;
    if (mlp.dtype == DType::F16) != layout.half_mlp {
        return Err(format!(
            "MLP weights in {:?} for a layout whose MLP is {}",
            mlp.dtype,
            if layout.half_mlp { "f16" } else { "f32" }
        ));
    }
    let client = rows.client.clone();
    let (r_tile, act_len) = tile_rows(&client, layout)?;
    let out = empty(rows, 3 * n);
    let out = CubeTensor::new_contiguous(
        client.clone(),
        rows.device.clone(),
        Shape::new([n, 3]),
        out.handle,
        DType::F32,
    );
    if n == 0 {
        return Ok(out);
    }
    let info = upload_u32(rows, &layout.info());
    let (levels, features) = (layout.levels(), layout.features());
    let (grid_in, grid_out) = layout
        .grid
        .as_ref()
        .map_or((0, 0), |g| (g.in_offset, g.out_offset));
    let cubes = tile_cubes(n.div_ceil(r_tile), layout.hidden + 3, 4 * max_cubes());
    // SAFETY: as for `train_tiles` (rows and outputs below `n`, table indices within the
    // levels, workgroup memory within `tile_rows`'s sizes).
    macro_rules! infer {
        ($t:ty, $m:ty) => {
            unsafe {
                kernels::infer_tiles::launch_unchecked::<$t, $m>(
                    &client,
                    CubeCount::Static(cubes as u32, 1, 1),
                    CubeDim::new_1d(WIDTH as u32),
                    buffer(rows),
                    buffer(table),
                    buffer(&info),
                    buffer(mlp),
                    buffer(&out),
                    n as u32,
                    layout.parts.len() as u32,
                    r_tile,
                    layout.inputs,
                    layout.hidden,
                    levels,
                    features,
                    features,
                    layout.query_row(),
                    grid_in,
                    grid_out,
                    layout.unpadded,
                    layout.raw_dims,
                    activation_code(layout.activation),
                    act_len,
                )
            }
        };
    }
    match (table.dtype == DType::F16, mlp.dtype == DType::F16) {
        (true, true) => infer!(f16, f16),
        (true, false) => infer!(f16, f32),
        (false, true) => infer!(f32, f16),
        (false, false) => infer!(f32, f32),
    }
    counted();
    Ok(out)
}

/// `y ← (cx·x + cy·y)·cs` in place (the table's EMA gap `y` against its weights `x`).
pub fn combine_into(x: &CubeTensor, y: &CubeTensor, cx: f32, cy: f32, cs: f32) {
    let len = y.meta.shape().num_elements();
    assert_eq!(
        len,
        x.meta.shape().num_elements(),
        "combine_into: lengths differ"
    );
    if len == 0 {
        return;
    }
    kernels::combine_into::launch(
        &y.client,
        elementwise_count(len),
        CubeDim::new_1d(ELEMENTWISE),
        buffer(x),
        buffer(y),
        len as u32,
        cx,
        cy,
        cs,
    );
    counted();
}

/// `(cx·x + cy·y)·cs` as a new f32 tensor (`x` and `y` of one length).
pub fn combine(x: &CubeTensor, y: &CubeTensor, cx: f32, cy: f32, cs: f32) -> CubeTensor {
    combine_as(x, y, cx, cy, cs, false)
}

/// [`combine`] stored as f16 with `half` (clamped to ±65504 and rounded, as the CPU's
/// half-precision tables), as f32 otherwise.
pub fn combine_as(
    x: &CubeTensor,
    y: &CubeTensor,
    cx: f32,
    cy: f32,
    cs: f32,
    half: bool,
) -> CubeTensor {
    let len = x.meta.shape().num_elements();
    assert_eq!(
        len,
        y.meta.shape().num_elements(),
        "combine: lengths differ"
    );
    let out = if half {
        let handle = x.client.empty(2 * len.max(2));
        CubeTensor::new_contiguous(
            x.client.clone(),
            x.device.clone(),
            Shape::new([len]),
            handle,
            DType::F16,
        )
    } else {
        empty(x, len)
    };
    if len > 0 {
        macro_rules! combine {
            ($o:ty) => {
                kernels::combine::launch::<$o>(
                    &x.client,
                    elementwise_count(len),
                    CubeDim::new_1d(ELEMENTWISE),
                    buffer(x),
                    buffer(y),
                    buffer(&out),
                    len as u32,
                    cx,
                    cy,
                    cs,
                    half,
                )
            };
        }
        if half {
            combine!(f16)
        } else {
            combine!(f32)
        }
        counted();
    }
    out
}

/// Whether `client`'s device computes with half-precision floats (wgpu's `shader-f16`).
pub fn supports_f16(client: &Client) -> bool {
    client
        .properties()
        .supports_type(ElemType::Float(FloatKind::F16))
}
