//! The Python module `nrc` (its native part, `nrc._nrc`): thin bindings of the workspace's
//! crates. Every function calls them and converts: NumPy arrays in and out (`float32`,
//! C-contiguous, shapes checked), keyword options parsed exactly as the CLI's flags (the run
//! files' conversion, [`nrc_harness::run_file::fields_to_flags`]), the GIL released during work,
//! and every error a Python exception: [`NrcError`] with the CLI's `error:` line, `ValueError`
//! or `TypeError` for a malformed array.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use clap::{CommandFactory, Parser};
use numpy::{
    PyArray1, PyArray2, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use nrc_cache::{CacheQuery, TrainingBatch};
use nrc_harness::options::{RadianceCacheArgs, SceneArgs, TracerArgs};
use nrc_render::{PassSpec, Termination, ZeroSource};
use nrc_train::QueryMaker;

create_exception!(
    _nrc,
    NrcError,
    PyException,
    "An error of nrc: the message is the command line's `error:` line."
);

/// Floats per query row: position (3, in the scene box's [0,1]³), direction (3), normal (3),
/// roughness (1), diffuse (3), specular (3).
const QUERY_DIMS: usize = 16;
const _: () = assert!(std::mem::size_of::<CacheQuery>() == QUERY_DIMS * 4);

fn nrc_err(e: anyhow::Error) -> PyErr {
    NrcError::new_err(nrc::one_line(&e))
}

fn closed(what: &str) -> PyErr {
    PyValueError::new_err(format!("this {what} is closed"))
}

/// Runs `f` on the object's state, locked (call without the GIL): an error when it was closed,
/// or when an earlier call failed inside it (a poisoned lock: its state may be half updated).
fn with_state<T, R>(
    inner: &Mutex<Option<T>>,
    what: &str,
    f: impl FnOnce(&mut T) -> PyResult<R>,
) -> PyResult<R> {
    let mut guard = inner.lock().map_err(|_| {
        NrcError::new_err(format!(
            "this {what} is unusable: an earlier call failed inside it"
        ))
    })?;
    f(guard.as_mut().ok_or_else(|| closed(what))?)
}

/// Empties the object's state (`close()`), without the GIL.
fn close_state<T: Send>(py: Python<'_>, inner: &Mutex<Option<T>>) {
    py.detach(|| {
        let mut g = inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        *g = None;
    });
}

/// The most records, pixels and samples a call may ask for: beyond them an allocation could
/// fail, which aborts the interpreter instead of raising.
const MAX_RECORDS: usize = 1 << 24;
const MAX_PIXEL_SAMPLES: u64 = 1 << 30;

fn check_image(width: u32, height: u32, spp: u32) -> PyResult<()> {
    if width == 0 || height == 0 || spp == 0 {
        return Err(NrcError::new_err(format!(
            "image size {width}x{height} at {spp} spp is empty"
        )));
    }
    let n = u64::from(width) * u64::from(height) * u64::from(spp);
    if n > MAX_PIXEL_SAMPLES {
        return Err(PyValueError::new_err(format!(
            "{width}x{height} at {spp} spp is {n} samples, above this module's limit of {MAX_PIXEL_SAMPLES} a call"
        )));
    }
    Ok(())
}

/// Keyword arguments as a JSON object (`None`: an empty one).
fn kwargs_json(py: Python<'_>, kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<serde_json::Value> {
    let Some(kwargs) = kwargs else {
        return Ok(serde_json::json!({}));
    };
    let text: String = py
        .import("json")?
        .call_method1("dumps", (kwargs,))
        .map_err(|e| PyTypeError::new_err(format!("keyword arguments must be JSON values: {e}")))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// Parses the options `value` (a JSON object of flags, as a run file holds) after `leading`
/// command-line words into `T`, as the CLI parses its flags; `what` names the call in errors.
fn parse_options<T: Parser>(
    value: &serde_json::Value,
    leading: &[String],
    what: &str,
) -> PyResult<T> {
    let command = T::command();
    let flags = nrc_harness::run_file::fields_to_flags(value, &command, what, &[])
        .map_err(|e| PyValueError::new_err(nrc::one_line(&e)))?;
    let mut argv: Vec<std::ffi::OsString> = vec!["nrc".into()];
    argv.extend(leading.iter().map(Into::into));
    argv.extend(flags);
    T::try_parse_from(argv)
        .map_err(|e| PyValueError::new_err(format!("{what}: {}", nrc::clap_message(&e))))
}

// ---------------------------------------------------------------------------------------------
// Arrays.

/// A 2-D `float32`, C-contiguous array with `cols` columns, borrowed (its shape and type
/// checked; its values are checked by the reader: [`queries_of`], [`f32_rows`]).
fn f32_matrix<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    cols: usize,
) -> PyResult<numpy::PyReadonlyArray2<'py, f32>> {
    let arr = obj.cast::<PyUntypedArray>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name} must be a NumPy array (float32, shape (N, {cols})), got {}",
            obj.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    })?;
    let dtype = arr.dtype();
    if !dtype.is_equiv_to(&numpy::dtype::<f32>(obj.py())) {
        return Err(PyTypeError::new_err(format!(
            "{name} must be float32, got {} (convert with .astype(numpy.float32))",
            dtype.str()?
        )));
    }
    if arr.ndim() != 2 || arr.shape()[1] != cols {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (N, {cols}), got {:?}",
            arr.shape()
        )));
    }
    if !arr.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "{name} must be C-contiguous (use numpy.ascontiguousarray)"
        )));
    }
    arr.cast::<PyArray2<f32>>()?
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("{name} cannot be read: {e}")))
}

/// The array's data (`f32_matrix` checked its layout).
fn data<'a>(arr: &'a numpy::PyReadonlyArray2<'_, f32>, name: &str) -> PyResult<&'a [f32]> {
    arr.as_slice()
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))
}

/// The error for a non-finite value at flat index `i` of rows of `cols` values.
fn not_finite(name: &str, i: usize, cols: usize) -> PyErr {
    PyValueError::new_err(format!(
        "{name} holds a NaN or infinite value (row {}, column {})",
        i / cols,
        i % cols
    ))
}

/// The rows of a 2-D float32 array with `cols` columns, finite throughout, copied.
fn f32_rows(obj: &Bound<'_, PyAny>, name: &str, cols: usize) -> PyResult<(Vec<f32>, usize)> {
    let arr = f32_matrix(obj, name, cols)?;
    let slice = data(&arr, name)?;
    if let Some(i) = slice.iter().position(|v| !v.is_finite()) {
        return Err(not_finite(name, i, cols));
    }
    Ok((slice.to_vec(), slice.len() / cols))
}

/// Query rows (16 floats each) as queries, without a copy ([`CacheQuery`] is 16 `f32` in
/// the rows' order); a non-finite value is an error naming its row and column. Checked in
/// parallel (called without the GIL).
fn queries_of(rows: &[f32]) -> PyResult<&[CacheQuery]> {
    use rayon::prelude::*;
    if !rows
        .par_chunks(1 << 14)
        .all(|c| c.iter().all(|v| v.is_finite()))
    {
        let i = rows.iter().position(|v| !v.is_finite()).unwrap_or(0);
        return Err(not_finite("queries", i, QUERY_DIMS));
    }
    Ok(bytemuck::cast_slice(rows))
}

fn queries_from(obj: &Bound<'_, PyAny>) -> PyResult<Vec<CacheQuery>> {
    let arr = f32_matrix(obj, "queries", QUERY_DIMS)?;
    Ok(queries_of(data(&arr, "queries")?)?.to_vec())
}

fn query_row(q: &CacheQuery) -> [f32; QUERY_DIMS] {
    let mut r = [0f32; QUERY_DIMS];
    r[0..3].copy_from_slice(&q.position);
    r[3..6].copy_from_slice(&q.direction);
    r[6..9].copy_from_slice(&q.normal);
    r[9] = q.roughness;
    r[10..13].copy_from_slice(&q.diffuse);
    r[13..16].copy_from_slice(&q.specular);
    r
}

/// A `[rows, cols]` float32 array that takes over `data` (no copy).
fn array2<'py>(
    py: Python<'py>,
    data: Vec<f32>,
    rows: usize,
    cols: usize,
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, data)
        .reshape([rows, cols])?
        .into_any())
}

fn image_array<'py>(
    py: Python<'py>,
    image: &nrc_scene::image::Image,
) -> PyResult<Bound<'py, PyAny>> {
    let flat: Vec<f32> = image.data.iter().flat_map(|p| p.to_array()).collect();
    Ok(PyArray1::from_vec(py, flat)
        .reshape([image.height, image.width, 3])?
        .into_any())
}

fn batch_dict<'py>(py: Python<'py>, batch: TrainingBatch) -> PyResult<Bound<'py, PyDict>> {
    let n = batch.queries.len();
    let queries: Vec<f32> = batch.queries.iter().flat_map(query_row).collect();
    let targets: Vec<f32> = batch.targets.iter().flatten().copied().collect();
    let weights = batch.weights.unwrap_or_else(|| vec![1.0; n]);
    let d = PyDict::new(py);
    d.set_item("queries", array2(py, queries, n, QUERY_DIMS)?)?;
    d.set_item("targets", array2(py, targets, n, 3)?)?;
    d.set_item("weights", PyArray1::from_vec(py, weights))?;
    Ok(d)
}

fn batch_from(batch: &Bound<'_, PyAny>) -> PyResult<TrainingBatch> {
    let get = |key: &str| -> PyResult<Option<Bound<'_, PyAny>>> {
        match batch.get_item(key) {
            Ok(v) if !v.is_none() => Ok(Some(v)),
            Ok(_) => Ok(None),
            Err(_) => Ok(None),
        }
    };
    let queries = get("queries")?.ok_or_else(|| {
        PyValueError::new_err(
            "batch must be a dict with `queries` and `targets` (and optionally `weights`)",
        )
    })?;
    let targets = get("targets")?.ok_or_else(|| {
        PyValueError::new_err(
            "batch must be a dict with `queries` and `targets` (and optionally `weights`)",
        )
    })?;
    let queries = queries_from(&queries)?;
    let (t, n) = f32_rows(&targets, "targets", 3)?;
    if n != queries.len() {
        return Err(PyValueError::new_err(format!(
            "targets has {n} rows for {} queries",
            queries.len()
        )));
    }
    let weights = match get("weights")? {
        None => None,
        Some(w) => {
            let w2 = w.call_method1("reshape", ((-1i64, 1i64),))?;
            let (w, m) = f32_rows(&w2, "weights", 1)?;
            if m != queries.len() {
                return Err(PyValueError::new_err(format!(
                    "weights has {m} entries for {} queries",
                    queries.len()
                )));
            }
            Some(w)
        }
    };
    Ok(TrainingBatch {
        queries,
        targets: t.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        weights,
    })
}

// ---------------------------------------------------------------------------------------------
// Scenes.

#[derive(Parser, Debug)]
struct SceneOptions {
    #[command(flatten)]
    scene: SceneArgs,
}

/// A loaded scene: triangles, materials, lights, bounds and camera (immutable).
#[pyclass(frozen, module = "nrc")]
struct Scene {
    scene: Arc<nrc_scene::Scene>,
    /// How it was loaded (its file and the overrides).
    args: SceneArgs,
    /// The load options as given (passed on to `compare`).
    options: serde_json::Value,
    animated: Arc<nrc_scene::AnimatedScene>,
    /// Seconds into the animation it is posed at.
    time: f32,
}

impl Scene {
    fn path(&self) -> PathBuf {
        self.args.scene.clone()
    }
}

#[pymethods]
impl Scene {
    /// Loads a glTF scene. Keyword options are `nrc info`'s flags (`camera_pos=(x, y, z)`,
    /// `camera_target`, `camera_up`, `fov_y`, `background`, `env`, `env_intensity`,
    /// `env_rotate`, `light_sampler="power"|"tree"`).
    #[staticmethod]
    #[pyo3(signature = (path, **options))]
    fn load(py: Python<'_>, path: PathBuf, options: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let mut value = kwargs_json(py, options)?;
        let parsed: SceneOptions = parse_options(
            &value,
            &["--scene".into(), path.display().to_string()],
            "nrc.Scene.load",
        )?;
        if let Some(map) = value.as_object_mut() {
            map.insert(
                "scene".into(),
                serde_json::json!(path.display().to_string()),
            );
        }
        let args = parsed.scene;
        let (scene, animated) = py
            .detach(|| -> anyhow::Result<_> {
                let scene = args.load()?;
                let animated = args.load_animated()?;
                Ok((scene, animated))
            })
            .map_err(nrc_err)?;
        Ok(Self {
            scene: Arc::new(scene),
            args,
            options: value,
            animated: Arc::new(animated),
            time: 0.0,
        })
    }

    /// The scene posed at `t` seconds of its animation (itself when nothing moves).
    fn at(&self, py: Python<'_>, t: f32) -> PyResult<Self> {
        if !t.is_finite() {
            return Err(PyValueError::new_err(format!("t must be finite, got {t}")));
        }
        let scene = py
            .detach(|| self.args.pose(&self.animated, t))
            .map_err(nrc_err)?;
        Ok(Self {
            scene: Arc::new(scene),
            args: self.args.clone(),
            options: self.options.clone(),
            animated: self.animated.clone(),
            time: t,
        })
    }

    /// The scene file.
    #[getter(path)]
    fn path_getter(&self) -> String {
        self.path().display().to_string()
    }

    #[getter]
    fn triangle_count(&self) -> usize {
        self.scene.triangle_count()
    }

    #[getter]
    fn light_count(&self) -> usize {
        self.scene.light_count()
    }

    #[getter]
    fn is_animated(&self) -> bool {
        self.animated.is_animated()
    }

    /// Length of the animation in seconds (0 for a still scene).
    #[getter]
    fn duration(&self) -> f32 {
        self.animated.animation.duration()
    }

    /// Seconds into the animation this scene is posed at.
    #[getter]
    fn time(&self) -> f32 {
        self.time
    }

    /// The bounding box: `((min x, y, z), (max x, y, z))`.
    #[getter]
    fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let b = self.scene.bounds();
        (b.min.to_array(), b.max.to_array())
    }

    /// The box the cache's query positions are normalised to: `((min), (max))`.
    #[getter]
    fn scene_box(&self) -> ([f32; 3], [f32; 3]) {
        let b = QueryMaker::new(&self.scene.bounds()).scene_box;
        (b.min, b.max)
    }

    /// The camera: a dict of `position`, `forward`, `up`, `right` and `fov_y` (degrees).
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = &self.scene.camera;
        let d = PyDict::new(py);
        d.set_item("position", c.position.to_array())?;
        d.set_item("forward", c.forward.to_array())?;
        d.set_item("up", c.up.to_array())?;
        d.set_item("right", c.right.to_array())?;
        d.set_item("fov_y", c.fov_y.to_degrees())?;
        Ok(d)
    }

    /// The lights: `emissive_triangles` (int64 indices into `triangles()`), `punctual` (a
    /// list of dicts: `kind` (`point`, `spot` with `cos_inner` and `cos_outer`,
    /// `directional`), `position`, `direction`, `intensity`, `range`) and
    /// `environment` (whether an environment lights the scene).
    fn lights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let sampler = self.scene.lights();
        let d = PyDict::new(py);
        let tris: Vec<i64> = sampler.triangles().iter().map(|&t| i64::from(t)).collect();
        d.set_item("emissive_triangles", PyArray1::from_vec(py, tris))?;
        let punctual = pyo3::types::PyList::empty(py);
        for l in self.scene.punctual_lights() {
            let e = PyDict::new(py);
            let kind = match l.kind {
                nrc_scene::light::PunctualKind::Point => "point",
                nrc_scene::light::PunctualKind::Spot {
                    cos_inner,
                    cos_outer,
                } => {
                    e.set_item("cos_inner", cos_inner)?;
                    e.set_item("cos_outer", cos_outer)?;
                    "spot"
                }
                nrc_scene::light::PunctualKind::Directional => "directional",
            };
            e.set_item("kind", kind)?;
            e.set_item("position", l.position.to_array())?;
            e.set_item("direction", l.direction.to_array())?;
            e.set_item("intensity", l.intensity.to_array())?;
            e.set_item("range", l.range)?;
            punctual.append(e)?;
        }
        d.set_item("punctual", punctual)?;
        d.set_item("environment", sampler.counts().2 > 0)?;
        Ok(d)
    }

    /// The triangles' vertices, `float32` of shape `(T, 3, 3)` (triangle, vertex, xyz).
    fn triangles<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let n = self.scene.triangle_count();
        let flat: Vec<f32> = (0..n as u32)
            .flat_map(|t| self.scene.triangle_vertices(t))
            .flat_map(|v| v.to_array())
            .collect();
        Ok(PyArray1::from_vec(py, flat).reshape([n, 3, 3])?.into_any())
    }

    /// The options it was loaded with, the file as `scene` (the flags `compare` passes on).
    fn _options<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        py.import("json")?
            .call_method1("loads", (self.options.to_string(),))
    }

    /// What `nrc info` prints.
    fn summary(&self) -> String {
        self.scene.summary().to_string()
    }

    fn __repr__(&self) -> String {
        format!(
            "nrc.Scene('{}': {} triangles, {} lights)",
            self.path().display(),
            self.scene.triangle_count(),
            self.scene.light_count()
        )
    }
}

// ---------------------------------------------------------------------------------------------
// The cache.

#[derive(Parser, Debug)]
struct CacheOptions {
    #[command(flatten)]
    cache: RadianceCacheArgs,
    #[arg(long, default_value = "neural")]
    cache_kind: nrc_cache::CacheKind,
}

/// A radiance cache (the neural one, or the spatial-hash baseline).
#[pyclass(frozen, module = "nrc")]
struct Cache {
    inner: Mutex<Option<nrc_cache::Cache>>,
}

impl Cache {
    fn new(cache: nrc_cache::Cache) -> Self {
        Self {
            inner: Mutex::new(Some(cache)),
        }
    }

    /// Runs `f` on the cache (with the GIL released).
    fn with<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut nrc_cache::Cache) -> PyResult<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| with_state(&self.inner, "cache", f))
    }
}

fn cache_error(e: nrc_cache::CacheError) -> PyErr {
    nrc_err(e.into())
}

#[pymethods]
impl Cache {
    /// A new, untrained cache. `config`: a preset name (`"hashgrid"`, `"trianglewave"`), a
    /// configuration file, or a dict (the JSON configuration); `scene`: a `Scene` whose box the
    /// queries' positions are normalised to, or `scene_box=((min), (max))`; `kind`: `"neural"`
    /// or `"hash"`. Other keyword options are `nrc train`'s cache flags (`resolution`,
    /// `hash_cell`, ...).
    #[new]
    #[pyo3(signature = (config=None, scene=None, scene_box=None, device="cpu", kind="neural", **options))]
    fn py_new(
        py: Python<'_>,
        config: Option<&Bound<'_, PyAny>>,
        scene: Option<&Bound<'_, Scene>>,
        scene_box: Option<([f32; 3], [f32; 3])>,
        device: &str,
        kind: &str,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let mut value = kwargs_json(py, options)?;
        let map = value.as_object_mut().expect("an object");
        if let Some(c) = config {
            let c = if c.is_instance_of::<PyDict>() {
                let text: String = py.import("json")?.call_method1("dumps", (c,))?.extract()?;
                serde_json::from_str(&text).map_err(|e| PyValueError::new_err(e.to_string()))?
            } else {
                serde_json::Value::String(c.str()?.to_string())
            };
            map.insert("config".into(), c);
        }
        map.insert("device".into(), device.into());
        map.insert("cache_kind".into(), kind.into());
        let parsed: CacheOptions = parse_options(&value, &[], "nrc.Cache")?;
        let scene_box = match (scene, scene_box) {
            (Some(_), Some(_)) => {
                return Err(PyValueError::new_err("give scene or scene_box, not both"));
            }
            (Some(s), None) => QueryMaker::new(&s.get().scene.bounds()).scene_box,
            (None, Some((min, max))) => {
                if !(0..3).all(|k| min[k].is_finite() && max[k].is_finite() && max[k] > min[k]) {
                    return Err(PyValueError::new_err(format!(
                        "scene_box must be finite with max > min on every axis, got {min:?} {max:?}"
                    )));
                }
                nrc_cache::SceneBox { min, max }
            }
            (None, None) => nrc_cache::SceneBox::default(),
        };
        let cache = py
            .detach(|| -> anyhow::Result<nrc_cache::Cache> {
                let mut settings = parsed.cache.method_settings(0, 0, false)?;
                settings.kind = parsed.cache_kind;
                Ok(nrc_harness::methods::scene_cache(scene_box, &settings)?)
            })
            .map_err(nrc_err)?;
        Ok(Self::new(cache))
    }

    /// Loads a snapshot (`nrc train --snapshot`, `Cache.save`) of either kind.
    #[staticmethod]
    #[pyo3(signature = (path, device="cpu"))]
    fn load(py: Python<'_>, path: PathBuf, device: &str) -> PyResult<Self> {
        let device = device_of(device)?;
        let cache = py
            .detach(|| nrc_cache::Cache::load(&path, device))
            .map_err(|e| {
                nrc_err(
                    anyhow::Error::from(e)
                        .context(format!("cannot load the cache snapshot {}", path.display())),
                )
            })?;
        Ok(Self::new(cache))
    }

    /// Learns from `batch` (a dict of `queries` `(N, 16)`, `targets` `(N, 3)` and optionally
    /// `weights` `(N,)`, as `Producer.produce` returns): `steps` optimiser steps. Returns the
    /// loss of the last step.
    #[pyo3(signature = (batch, steps=1))]
    fn train(&self, py: Python<'_>, batch: &Bound<'_, PyAny>, steps: u32) -> PyResult<f32> {
        if steps == 0 {
            return Err(PyValueError::new_err("steps must be at least 1"));
        }
        let batch = batch_from(batch)?;
        if batch.queries.is_empty() {
            return Err(PyValueError::new_err("batch holds no records"));
        }
        self.with(py, |c| {
            c.train(&batch, steps).map(|s| s.loss).map_err(cache_error)
        })
    }

    /// Outgoing radiance (emission excluded) at each query: `(N, 16)` float32 in, `(N, 3)` out.
    fn infer<'py>(
        &self,
        py: Python<'py>,
        queries: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let arr = f32_matrix(queries, "queries", QUERY_DIMS)?;
        let rows = data(&arr, "queries")?;
        let n = rows.len() / QUERY_DIMS;
        // The rows are read without the GIL, as NumPy's own functions read arrays.
        let out = self.with(py, |c| Ok(c.infer(queries_of(rows)?)))?;
        array2(py, out.into_flattened(), n, 3)
    }

    /// Writes a snapshot (atomically).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.with(py, |c| c.save(&path).map_err(cache_error))
    }

    /// Writes the portable export (`config.json` and `weights.safetensors`, docs/export.md)
    /// into the folder `path`; returns `{"config", "weights", "bytes"}`.
    fn export<'py>(&self, py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
        let written = self.with(py, |c| {
            let neural = c.neural().ok_or_else(|| {
                NrcError::new_err(
                    "this is a spatial-hash cache: only the neural cache exports (its cells are not a network)",
                )
            })?;
            nrc_cache::export::export(neural, &path).map_err(cache_error)
        })?;
        let d = PyDict::new(py);
        d.set_item("config", written.config.display().to_string())?;
        d.set_item("weights", written.weights.display().to_string())?;
        d.set_item("bytes", written.bytes)?;
        Ok(d)
    }

    /// The neural cache's weights by tensor (`hash_grid` `(entries, features)`, `mlp.0` … as
    /// in the export): `inference=True` (default) the values inference reads (the weights'
    /// average), else the training weights.
    #[pyo3(signature = (inference=true))]
    fn parameters<'py>(&self, py: Python<'py>, inference: bool) -> PyResult<Bound<'py, PyDict>> {
        let (layout, grid, mlp) = self.with(py, |c| {
            let n = c.neural().ok_or_else(|| {
                NrcError::new_err("this is a spatial-hash cache: it has no network parameters")
            })?;
            let (g, m) = if inference {
                n.inference_weights_host()
            } else {
                n.weights()
            };
            Ok((n.layout().clone(), g, m))
        })?;
        let d = PyDict::new(py);
        if let Some((g, _)) = layout.encoding.grid() {
            d.set_item(
                "hash_grid",
                array2(py, grid, g.total_entries, g.features())?,
            )?;
        }
        for (i, l) in layout.layers.iter().enumerate() {
            let w = mlp[l.offset..l.offset + l.len()].to_vec();
            d.set_item(format!("mlp.{i}"), array2(py, w, l.inputs, l.outputs)?)?;
        }
        Ok(d)
    }

    /// `"neural"` or `"hash"`.
    #[getter]
    fn kind(&self, py: Python<'_>) -> PyResult<String> {
        self.with(py, |c| Ok(c.kind().to_string()))
    }

    /// The box query positions are normalised to: `((min), (max))`.
    #[getter]
    fn scene_box(&self, py: Python<'_>) -> PyResult<([f32; 3], [f32; 3])> {
        self.with(py, |c| {
            let b = c.scene_box();
            Ok((b.min, b.max))
        })
    }

    #[getter]
    fn memory_bytes(&self, py: Python<'_>) -> PyResult<usize> {
        self.with(py, |c| Ok(c.memory_bytes()))
    }

    /// One line on the cache (as `nrc train` prints it).
    fn describe(&self, py: Python<'_>) -> PyResult<String> {
        self.with(py, |c| Ok(c.describe()))
    }

    /// Frees the cache; using it afterwards raises `ValueError`.
    fn close(&self, py: Python<'_>) {
        close_state(py, &self.inner);
    }

    fn __enter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        self.close(py);
        false
    }

    /// Seconds per `infer` of `queries` measured inside Rust (`reps` calls, the queries
    /// already converted): the reference the Python call's overhead is measured against.
    fn _time_infer(&self, py: Python<'_>, queries: &Bound<'_, PyAny>, reps: u32) -> PyResult<f64> {
        let queries = queries_from(queries)?;
        self.with(py, |c| {
            let t = std::time::Instant::now();
            for _ in 0..reps.max(1) {
                std::hint::black_box(c.infer(&queries));
            }
            Ok(t.elapsed().as_secs_f64() / f64::from(reps.max(1)))
        })
    }
}

fn device_of(device: &str) -> PyResult<nrc_cache::CacheDevice> {
    Ok(match device {
        "cpu" => nrc_cache::CacheDevice::Cpu,
        "wgpu" => nrc_cache::CacheDevice::Wgpu,
        "auto" => nrc_cache::CacheDevice::auto().0,
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown device `{other}` (cpu, wgpu or auto)"
            )));
        }
    })
}

// ---------------------------------------------------------------------------------------------
// Rendering.

#[derive(Parser, Debug)]
struct RenderOptions {
    #[command(flatten)]
    tracer: TracerArgs,
    #[command(flatten)]
    emitters: nrc_harness::options::EmitterArgs,
    #[command(flatten)]
    offsets: nrc_harness::options::OffsetArgs,
    #[arg(long, default_value = "spread", value_parser = nrc_harness::options::parse_termination)]
    termination: Termination,
    #[arg(long)]
    allow_other_scene: bool,
}

/// The render job of `nrc render` for these settings.
struct RenderCall {
    spec: PassSpec,
    tracer: nrc_render::PathTracer,
    width: u32,
    height: u32,
    spp: u32,
    seed: u64,
    emitter_samples: u32,
    camera_offsets: nrc_harness::budget::CameraOffsets,
}

impl RenderCall {
    fn run(
        &self,
        scene: &nrc_scene::Scene,
        cache: Option<&nrc_cache::Cache>,
    ) -> anyhow::Result<nrc_render::passes::PassOutput> {
        let cameras = [scene.camera];
        let rendered = nrc_harness::run::render(nrc_harness::run::RenderJob {
            scene,
            pass: &self.spec,
            tracer: self.tracer,
            cache,
            cameras: &cameras,
            width: self.width,
            height: self.height,
            spp: self.spp,
            seed: self.seed,
            emitter_samples: self.emitter_samples,
            camera_offsets: self.camera_offsets,
            variance: false,
            progress: None,
        })?;
        Ok(rendered.output)
    }
}

/// Parses `render`'s arguments into the job `nrc render` would run.
#[allow(clippy::too_many_arguments)]
fn render_call(
    py: Python<'_>,
    cache: Option<&Bound<'_, Cache>>,
    pass_: Option<&str>,
    spp: u32,
    width: u32,
    height: u32,
    seed: u64,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<(RenderCall, RenderOptions)> {
    check_image(width, height, spp)?;
    let parsed: RenderOptions = parse_options(&kwargs_json(py, options)?, &[], "nrc.render")?;
    let tracer = parsed.tracer.tracer();
    let pass = match pass_ {
        Some(p) => Some(
            p.parse::<PassSpec>()
                .map_err(|e| NrcError::new_err(format!("invalid pass `{p}`: {e}")))?,
        ),
        None => None,
    };
    let spec = match (pass, cache) {
        (Some(p), _) => p,
        (None, Some(_)) => nrc_render::passes::CacheTerminatedSettings {
            termination: parsed.termination,
            nee: tracer.strategy != nrc_render::LightStrategy::BsdfOnly,
        }
        .into(),
        (None, None) => nrc_render::passes::PathTracedSettings {
            strategy: tracer.strategy,
        }
        .into(),
    };
    if spec.uses_source() && cache.is_none() {
        return Err(NrcError::new_err(format!(
            "the pass {spec} ends paths in a cache: give it one with cache="
        )));
    }
    Ok((
        RenderCall {
            spec,
            tracer,
            width,
            height,
            spp,
            seed,
            emitter_samples: parsed.emitters.emitter_samples,
            camera_offsets: parsed.offsets.camera_offsets,
        },
        parsed,
    ))
}

/// Renders `scene` from its camera as `nrc render` does (the same bits for the same settings
/// and seed): the path tracer, or with `cache` the cache-terminated pass (`termination=`), or
/// the pass `pass_` names. Returns an `(height, width, 3)` float32 array of linear radiance.
/// Other keyword options: `max_depth`, `rr_depth`, `strategy`, `termination`,
/// `emitter_samples` (extra camera rays at the outline of emitters), `glossy_samples` (more BSDF
/// samples of the direct light at glossy first vertices), `direct_samples` (light samples of NEE
/// at first vertices), `camera_offsets` (`"independent"` or `"sobol"`: a pixel's samples
/// stratified together by one Owen-scrambled Sobol sequence), `allow_other_scene`.
#[pyfunction]
#[pyo3(signature = (scene, pass_=None, spp=1, width=128, height=128, cache=None, seed=1, **options))]
#[allow(clippy::too_many_arguments)]
fn render<'py>(
    py: Python<'py>,
    scene: &Bound<'py, Scene>,
    pass_: Option<&str>,
    spp: u32,
    width: u32,
    height: u32,
    cache: Option<&Bound<'py, Cache>>,
    seed: u64,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let (call, parsed) = render_call(py, cache, pass_, spp, width, height, seed, options)?;
    let scene = scene.get();
    let source = call.spec.uses_source().then_some(cache).flatten();
    let out = match source {
        None => py
            .detach(|| call.run(&scene.scene, None))
            .map_err(nrc_err)?,
        Some(c) => {
            let path = scene.path();
            let allow = parsed.allow_other_scene;
            c.get().with(py, |c| {
                let check = nrc_harness::run::check_snapshot_scene(c, &scene.scene, &path)
                    .map_err(nrc_err)?;
                if let Err(e) = check
                    && !allow
                {
                    return Err(NrcError::new_err(format!(
                        "the cache: {}",
                        e.replace("--allow-other-scene", "allow_other_scene=True")
                    )));
                }
                call.run(&scene.scene, Some(c)).map_err(nrc_err)
            })?
        }
    };
    image_array(py, &out.image)
}

/// Seconds per `render` (same arguments) measured inside Rust over `reps` renders: the
/// reference the Python call's overhead is measured against.
#[pyfunction]
#[pyo3(signature = (scene, reps, pass_=None, spp=1, width=128, height=128, cache=None, seed=1, **options))]
#[allow(clippy::too_many_arguments)]
fn _time_render(
    py: Python<'_>,
    scene: &Bound<'_, Scene>,
    reps: u32,
    pass_: Option<&str>,
    spp: u32,
    width: u32,
    height: u32,
    cache: Option<&Bound<'_, Cache>>,
    seed: u64,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<f64> {
    let (call, _) = render_call(py, cache, pass_, spp, width, height, seed, options)?;
    let scene = scene.get();
    let time = |c: Option<&nrc_cache::Cache>| -> PyResult<f64> {
        let t = std::time::Instant::now();
        for _ in 0..reps.max(1) {
            std::hint::black_box(call.run(&scene.scene, c).map_err(nrc_err)?);
        }
        Ok(t.elapsed().as_secs_f64() / f64::from(reps.max(1)))
    };
    match cache.filter(|_| call.spec.uses_source()) {
        None => py.detach(|| time(None)),
        Some(c) => c.get().with(py, |c| time(Some(c))),
    }
}

// ---------------------------------------------------------------------------------------------
// Producers.

#[derive(Parser, Debug)]
struct TrainOptions {
    #[command(flatten)]
    cache: RadianceCacheArgs,
    #[command(flatten)]
    tracer: TracerArgs,
    #[arg(long, default_value_t = 0.0)]
    from_terminations: f32,
}

struct ProducerState {
    mix: nrc_train::mix::ProducerMix,
    settings: nrc_train::OnlineSettings,
    frame: u32,
}

/// A producer of training records (or a mix), producing exactly what the online loop's frames
/// produce for the same seed.
#[pyclass(frozen, module = "nrc")]
struct Producer {
    scene: Py<Scene>,
    width: u32,
    height: u32,
    inner: Mutex<Option<ProducerState>>,
}

#[pymethods]
impl Producer {
    /// `kind`: `pt`, `pt-sl`, `bt`, `lt`, `sppc` or `mix:NAME=SHARE,...`; `width`, `height`:
    /// the image whose camera tiles the training queries start from; `seed`: as `nrc train
    /// --seed`. Other keyword options are `nrc train`'s producer and depth flags
    /// (`sppc_capacity`, `lt_surface_balance`, `max_depth`, `from_terminations`, ...).
    #[new]
    #[pyo3(signature = (scene, kind="pt-sl", seed=1, width=128, height=128, **options))]
    fn py_new(
        py: Python<'_>,
        scene: Py<Scene>,
        kind: &str,
        seed: u64,
        width: u32,
        height: u32,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        check_image(width, height, 1)?;
        let spec: nrc_train::ProducerSpec = kind
            .parse()
            .map_err(|e: nrc_train::error::TrainError| NrcError::new_err(e.to_string()))?;
        let parsed: TrainOptions = parse_options(&kwargs_json(py, options)?, &[], "nrc.Producer")?;
        let cache_settings = parsed
            .cache
            .method_settings(0, seed, false)
            .map_err(nrc_err)?;
        let s = scene.get();
        let mut settings = nrc_train::OnlineSettings::new(spec, &s.scene, parsed.tracer.tracer());
        settings.producer_options = cache_settings.producer_options;
        settings.from_terminations = parsed.from_terminations;
        settings.seed = seed;
        settings
            .validate()
            .map_err(|e| NrcError::new_err(e.to_string()))?;
        let mix = nrc_train::mix::ProducerMix::new(&settings.producer, &settings.producer_options);
        mix.check(&s.scene)
            .map_err(|e| NrcError::new_err(e.to_string()))?;
        Ok(Self {
            scene,
            width,
            height,
            inner: Mutex::new(Some(ProducerState {
                mix,
                settings,
                frame: 0,
            })),
        })
    }

    /// The next frame's records: about `n` (never more) training records as a dict of
    /// `queries` `(N, 16)`, `targets` `(N, 3)` and `weights` `(N,)`. `cache`: the cache
    /// self-learning targets read (`pt-sl`; none: paths end in black).
    #[pyo3(signature = (n=4096, cache=None))]
    fn produce<'py>(
        &self,
        py: Python<'py>,
        n: usize,
        cache: Option<&Bound<'py, Cache>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        if n == 0 || n > MAX_RECORDS {
            return Err(PyValueError::new_err(format!(
                "n must be in 1..={MAX_RECORDS}, got {n}"
            )));
        }
        let scene = self.scene.get();
        let (w, h) = (self.width, self.height);
        let run = |state: &mut ProducerState, source: &dyn nrc_render::RadianceSource| {
            let seed = nrc_render::pass_seed(state.settings.seed, state.frame);
            let view = nrc_train::online::FrameView {
                scene: &scene.scene,
                camera: &scene.scene.camera,
                width: w,
                height: h,
            };
            let produced = nrc_train::online::produce_frame(
                &mut state.mix,
                &state.settings,
                source,
                &view,
                &[],
                n,
                seed,
            );
            state.frame += 1;
            produced.batch
        };
        let batch = match cache {
            None => {
                py.detach(|| with_state(&self.inner, "producer", |s| Ok(run(s, &ZeroSource))))?
            }
            Some(c) => c.get().with(py, |c| {
                with_state(&self.inner, "producer", |s| {
                    let source = nrc_train::CacheSource {
                        cache: c,
                        queries: s.settings.queries,
                    };
                    Ok(run(s, &source))
                })
            })?,
        };
        batch_dict(py, batch)
    }

    /// Frames produced so far.
    #[getter]
    fn frame(&self, py: Python<'_>) -> PyResult<u32> {
        py.detach(|| with_state(&self.inner, "producer", |s| Ok(s.frame)))
    }

    fn close(&self, py: Python<'_>) {
        close_state(py, &self.inner);
    }
}

// ---------------------------------------------------------------------------------------------
// The online loop.

/// The online loop of `nrc train`: produce → train → render, a frame per `step()`.
#[pyclass(frozen, module = "nrc")]
struct OnlineTrainer {
    scene: Py<Scene>,
    width: u32,
    height: u32,
    fps: f32,
    inner: Mutex<Option<nrc_train::OnlineTrainer>>,
}

#[pymethods]
impl OnlineTrainer {
    /// `producer`, `pass_` and every other keyword option are `nrc train`'s flags (`records`,
    /// `config`, `device`, `cache_kind`, `termination`, `spp`, `seed`, `train_budget_ms`, ...).
    #[new]
    #[pyo3(signature = (scene, producer="pt-sl", pass_=None, width=128, height=128, **options))]
    fn py_new(
        py: Python<'_>,
        scene: Py<Scene>,
        producer: &str,
        pass_: Option<&str>,
        width: u32,
        height: u32,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let mut value = kwargs_json(py, options)?;
        let s = scene.get();
        let map = value.as_object_mut().expect("an object");
        // The scene's own load options, then these.
        if let Some(scene_options) = s.options.as_object() {
            for (k, v) in scene_options {
                map.entry(k.clone()).or_insert(v.clone());
            }
        }
        map.insert("producer".into(), producer.into());
        if let Some(p) = pass_ {
            map.insert("pass".into(), p.into());
        }
        map.insert("width".into(), width.into());
        map.insert("height".into(), height.into());
        let args = parse_train_args(&value)?;
        check_image(args.width, args.height, args.spp)?;
        if args.cache.records > MAX_RECORDS {
            return Err(PyValueError::new_err(format!(
                "records must be at most {MAX_RECORDS}, got {}",
                args.cache.records
            )));
        }
        let trainer = py
            .detach(|| nrc::train::trainer(&args, &s.scene, false))
            .map_err(nrc_err)?;
        Ok(Self {
            scene,
            width: args.width,
            height: args.height,
            fps: args.fps,
            inner: Mutex::new(Some(trainer)),
        })
    }

    /// One frame: produce and train, then (with `render`) the inference pass from the scene's
    /// camera (an animated scene posed at frame / fps). Returns `(image or None, stats)`, the
    /// stats as `nrc train --stats` writes them.
    #[pyo3(signature = (render=true))]
    fn step<'py>(
        &self,
        py: Python<'py>,
        render: bool,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let s = self.scene.get();
        let (w, h, fps) = (self.width, self.height, self.fps);
        let (stats, out) = py.detach(|| {
            with_state(&self.inner, "trainer", |t| {
                let posed;
                let scene = if s.animated.is_animated() {
                    posed = s
                        .args
                        .pose(&s.animated, s.time + t.frames() as f32 / fps)
                        .map_err(nrc_err)?;
                    &posed
                } else {
                    &*s.scene
                };
                let (stats, out) = t
                    .frame(scene, &scene.camera, w, h, render)
                    .map_err(cache_error)?;
                let json = serde_json::to_string(&stats).expect("stats serialise");
                Ok((json, out))
            })
        })?;
        let stats = py.import("json")?.call_method1("loads", (stats,))?;
        let image = match out {
            Some(o) => image_array(py, &o.image)?,
            None => py.None().into_bound(py),
        };
        Ok((image, stats))
    }

    /// Frames run so far.
    #[getter]
    fn frames(&self, py: Python<'_>) -> PyResult<u64> {
        py.detach(|| with_state(&self.inner, "trainer", |t| Ok(t.frames())))
    }

    /// Writes the cache's snapshot, naming its scene (as `nrc train --snapshot`).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let scene_path = self.scene.get().path();
        py.detach(|| -> PyResult<()> {
            let content =
                nrc_harness::reference::scene_content_hash(&scene_path).map_err(nrc_err)?;
            with_state(&self.inner, "trainer", |t| {
                t.cache.set_scene_content(Some(content));
                t.cache.save(&path).map_err(cache_error)
            })
        })
    }

    /// A copy of the cache as it is (through a snapshot: it infers the same bits).
    fn cache(&self, py: Python<'_>) -> PyResult<Cache> {
        let dir = tempfile::tempdir().map_err(|e| NrcError::new_err(e.to_string()))?;
        let path = dir.path().join("cache.nrc");
        self.save(py, path.clone())?;
        Cache::load(py, path, "cpu")
    }

    fn close(&self, py: Python<'_>) {
        close_state(py, &self.inner);
    }
}

fn parse_train_args(value: &serde_json::Value) -> PyResult<nrc::train::TrainArgs> {
    #[derive(Parser, Debug)]
    struct Train {
        #[command(flatten)]
        args: nrc::train::TrainArgs,
    }
    Ok(parse_options::<Train>(value, &[], "nrc.OnlineTrainer")?.args)
}

// ---------------------------------------------------------------------------------------------
// Commands.

/// Runs a command of the `nrc` program: `args` are its words after `nrc` (`["compare",
/// "--scene", ...]`). Raises `NrcError` with the program's `error:` line.
#[pyfunction]
fn cli(py: Python<'_>, args: Vec<String>) -> PyResult<()> {
    let mut argv: Vec<std::ffi::OsString> = vec!["nrc".into()];
    argv.extend(args.into_iter().map(Into::into));
    py.detach(|| nrc::run_args(argv)).map_err(nrc_err)
}

/// Runs the command `sub` of the `nrc` program with the keyword options `options` as its
/// flags (as a run file gives them).
#[pyfunction]
#[pyo3(signature = (sub, **options))]
fn run_command(py: Python<'_>, sub: &str, options: Option<&Bound<'_, PyDict>>) -> PyResult<()> {
    let value = kwargs_json(py, options)?;
    let command = nrc::Cli::command();
    let Some(sub_cmd) = command.find_subcommand(sub) else {
        return Err(PyValueError::new_err(format!("unknown command `{sub}`")));
    };
    let flags = nrc_harness::run_file::fields_to_flags(&value, sub_cmd, &format!("nrc.{sub}"), &[])
        .map_err(|e| PyValueError::new_err(nrc::one_line(&e)))?;
    let mut argv: Vec<std::ffi::OsString> = vec!["nrc".into(), sub.into()];
    argv.extend(flags);
    py.detach(|| nrc::run_args(argv)).map_err(nrc_err)
}

/// Reads an OpenEXR image (RGB) as an `(height, width, 3)` float32 array.
#[pyfunction]
fn read_exr(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyAny>> {
    let image = py
        .detach(|| nrc_scene::image::Image::read_exr(&path))
        .map_err(|e| nrc_err(e.into()))?;
    image_array(py, &image)
}

#[pymodule]
fn _nrc(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // A CPU without the build's SIMD level gets an ImportError naming it, not SIGILL.
    nrc_scene::cpu::check().map_err(pyo3::exceptions::PyImportError::new_err)?;
    m.add("NrcError", m.py().get_type::<NrcError>())?;
    m.add("QUERY_DIMS", QUERY_DIMS)?;
    m.add_class::<Scene>()?;
    m.add_class::<Cache>()?;
    m.add_class::<Producer>()?;
    m.add_class::<OnlineTrainer>()?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(_time_render, m)?)?;
    m.add_function(wrap_pyfunction!(cli, m)?)?;
    m.add_function(wrap_pyfunction!(run_command, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    Ok(())
}
