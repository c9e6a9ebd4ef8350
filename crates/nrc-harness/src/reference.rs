//! The reference store: reference images rendered with the unbiased path tracer, stored with their
//! per-pixel variance and cached, so that every comparison against the same scene, camera and
//! settings reuses one render.
//!
//! **Cache.** References live in a folder the caller names (the CLI: `--cache-dir`, else
//! `$NRC_CACHE_DIR/references`, else `out/references`). Each is a folder
//! `<scene>-<W>x<H>-<spp>spp-<key>` holding
//! - `mean.exr`: the per-pixel mean radiance (linear RGB, 32-bit float);
//! - `variance.exr`: the per-pixel, per-channel variance *of that mean* (the sample variance of
//!   one path divided by spp), which bias estimates subtract;
//! - `reference.json`: the settings and the content key, written last, so a folder without it
//!   is an interrupted render and is rendered again.
//!
//! **Content key.** SHA-256 over a format tag, the bytes of the scene file and of every external
//! file it names (buffers and images, in document order), the camera, image size, spp, seed,
//! depth limits and background. Editing the scene or any of its files changes the key. The
//! renderer's estimator is not part of the bytes hashed: [`FORMAT`] is bumped when a change of
//! the path tracer changes what references converge to.
//!
//! A reference that is unreadable (corrupt EXR, bad sidecar) or does not match its sidecar or the
//! request (size, key) is an error naming the folder, never silently replaced.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail, ensure};
use glam::Vec3;
use nrc_render::{Moments, PathTracer, render_moments};
use nrc_scene::{Camera, Image, Scene};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::progress::{Progress, Unit};

/// Format tag of reference entries and of the key; bump when the path tracer's expected
/// value changes (a fix to an estimator), so that stale references are not reused.
pub const FORMAT: &str = "nrc-reference/2";

/// The settings a reference is rendered with: everything its key covers.
#[derive(Clone, Debug)]
pub struct ReferenceRequest<'a> {
    /// The scene file (hashed with the files it names).
    pub scene_path: &'a Path,
    /// The loaded scene, with its camera and background as rendered.
    pub scene: &'a Scene,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u64,
    pub tracer: PathTracer,
}

impl ReferenceRequest<'_> {
    /// The estimator a reference is rendered with: the request's depths with the plain path
    /// tracer, whatever variance-reduction options (`glossy_samples`, `direct_samples`) the
    /// methods use, so that one key always holds the same estimator's samples.
    pub fn estimator(&self) -> PathTracer {
        PathTracer {
            glossy_samples: 0,
            direct_samples: 1,
            ..self.tracer
        }
    }
}

/// The camera as stored in the sidecar.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    pub position: [f32; 3],
    pub forward: [f32; 3],
    pub up: [f32; 3],
    pub fov_y_degrees: f32,
}

impl From<&Camera> for CameraRecord {
    fn from(c: &Camera) -> Self {
        Self {
            position: c.position.to_array(),
            forward: c.forward.to_array(),
            up: c.up.to_array(),
            fov_y_degrees: c.fov_y.to_degrees(),
        }
    }
}

/// `reference.json`: how a reference was made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceMeta {
    pub format: String,
    /// SHA-256 (hex) of everything the reference depends on.
    pub key: String,
    /// SHA-256 (hex) of the scene file and the files it names.
    pub scene_content: String,
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u64,
    pub max_depth: i32,
    pub rr_depth: u32,
    /// The environment, described (a constant or a map with its intensity and rotation).
    pub environment: String,
    pub camera: CameraRecord,
    /// Wall time of the render, seconds.
    pub render_seconds: f64,
    pub invalid_samples: u64,
    /// What `variance.exr` holds.
    pub variance: String,
    pub created_by: String,
}

impl ReferenceMeta {
    /// One-line description for reports.
    pub fn describe(&self) -> String {
        let depth = if self.max_depth <= 0 {
            "unlimited".to_string()
        } else {
            self.max_depth.to_string()
        };
        format!(
            "path tracer (NEE + BSDF, MIS), {} spp, seed {}, max depth {depth}, key {}",
            self.spp,
            self.seed,
            &self.key[..16]
        )
    }
}

/// A reference image with its per-pixel variance of the mean.
#[derive(Clone, Debug)]
pub struct Reference {
    pub mean: Image,
    /// Per-pixel variance of `mean`; `None` for a reference given as a bare EXR file.
    pub variance: Option<Image>,
    /// Settings, when the reference comes from the cache.
    pub meta: Option<ReferenceMeta>,
    /// The cache folder or file it was read from or written to.
    pub location: PathBuf,
    /// Whether it was found in the cache rather than rendered now.
    pub reused: bool,
}

const MEAN_FILE: &str = "mean.exr";
const VARIANCE_FILE: &str = "variance.exr";
const META_FILE: &str = "reference.json";

/// The characters of a glTF URI, percent-decoded, exactly as the scene loader resolves them.
use nrc_scene::gltf_load::percent_decode;

/// The JSON document of a `.gltf` file, or the JSON chunk of a `.glb` container.
fn gltf_json(path: &Path, bytes: &[u8]) -> Result<serde_json::Value> {
    let json = if bytes.starts_with(b"glTF") {
        ensure!(
            bytes.len() >= 20,
            "{}: truncated .glb header",
            path.display()
        );
        let len = u32::from_le_bytes(bytes[12..16].try_into().expect("4 bytes")) as usize;
        ensure!(
            &bytes[16..20] == b"JSON",
            "{}: the .glb's first chunk is not JSON",
            path.display()
        );
        bytes
            .get(20..20 + len)
            .with_context(|| format!("{}: truncated .glb JSON chunk", path.display()))?
    } else {
        bytes
    };
    serde_json::from_slice(json).with_context(|| format!("{}: invalid glTF JSON", path.display()))
}

/// SHA-256 (hex) of the scene file and of every external buffer and image it names.
pub fn scene_content_hash(path: &Path) -> Result<String> {
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let mut hasher = Sha256::new();
    let mut add = |name: &str, data: &[u8]| {
        hasher.update((name.len() as u64).to_le_bytes());
        hasher.update(name.as_bytes());
        hasher.update((data.len() as u64).to_le_bytes());
        hasher.update(data);
    };
    add("scene", &bytes);
    let json = gltf_json(path, &bytes)?;
    let base = path.parent().unwrap_or(Path::new("."));
    for list in ["buffers", "images"] {
        let Some(items) = json.get(list).and_then(|v| v.as_array()) else {
            continue;
        };
        for item in items {
            let Some(uri) = item.get("uri").and_then(|u| u.as_str()) else {
                continue;
            };
            if uri.starts_with("data:") {
                continue; // Embedded: already hashed with the scene file.
            }
            let file = base.join(percent_decode(uri));
            let data = std::fs::read(&file).with_context(|| {
                format!(
                    "cannot read {} (named by scene {})",
                    file.display(),
                    path.display()
                )
            })?;
            add(uri, &data);
        }
    }
    Ok(hex(&hasher.finalize()))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The key of a request, given the scene's content hash.
fn request_key(req: &ReferenceRequest<'_>, scene_content: &str) -> String {
    let c = &req.scene.camera;
    let bits = |v: Vec3| {
        format!(
            "{:08x},{:08x},{:08x}",
            v.x.to_bits(),
            v.y.to_bits(),
            v.z.to_bits()
        )
    };
    let text = format!(
        "{FORMAT}\nscene {scene_content}\ncamera {} {} {} {:08x}\nsize {}x{}\nspp {}\nseed {}\nmax_depth {}\nrr_depth {}\nenvironment {}\n",
        bits(c.position),
        bits(c.forward),
        bits(c.up),
        c.fov_y.to_bits(),
        req.width,
        req.height,
        req.spp,
        req.seed,
        req.tracer.max_depth,
        req.tracer.rr_depth,
        req.scene.environment().content_key(),
    );
    hex(&Sha256::digest(text.as_bytes()))
}

/// [`obtain`] with the progress of a new render shown ([`crate::progress`]).
pub fn obtain_showing_progress(
    req: &ReferenceRequest<'_>,
    cache_dir: &Path,
    force: bool,
) -> Result<Reference> {
    let pixels = req.width as u64 * req.height as u64;
    let progress = Progress::new(pixels, Unit::Pixels, "reference");
    let r = obtain(req, cache_dir, force, &|n| progress.inc(n));
    progress.finish();
    r
}

/// Finds the reference of `req` in `cache_dir` or renders and stores it (`force`: always render).
/// Runs on the current rayon pool; `progress(pixels)` is called as tiles of a new render finish.
pub fn obtain(
    req: &ReferenceRequest<'_>,
    cache_dir: &Path,
    force: bool,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Reference> {
    obtain_from(req, cache_dir, force, &|| {
        let start = Instant::now();
        let (moments, _) = render_moments(
            req.scene,
            &req.scene.camera,
            &req.estimator(),
            (req.width, req.height),
            req.seed,
            0..req.spp,
            progress,
        );
        Ok((moments, start.elapsed().as_secs_f64()))
    })
}

/// [`obtain`], with the samples of an entry that must be made from `samples` (the per-pixel
/// moments of samples `0..spp` and the seconds they took): a render here, or the merged
/// chunks of a study's jobs ([`crate::study`]).
pub fn obtain_from(
    req: &ReferenceRequest<'_>,
    cache_dir: &Path,
    force: bool,
    samples: &dyn Fn() -> Result<(Moments, f64)>,
) -> Result<Reference> {
    ensure!(
        req.width > 0 && req.height > 0,
        "image size {}x{} is empty",
        req.width,
        req.height
    );
    ensure!(
        req.spp >= 2,
        "a reference needs at least 2 samples per pixel (for its variance), got {}",
        req.spp
    );
    let scene_content = scene_content_hash(req.scene_path)?;
    let key = request_key(req, &scene_content);
    let stem = req
        .scene_path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let stem: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let dir = cache_dir.join(format!(
        "{stem}-{}x{}-{}spp-{}",
        req.width,
        req.height,
        req.spp,
        &key[..16]
    ));

    if !force && dir.join(META_FILE).exists() {
        let r = load_entry(&dir)?;
        let meta = r.meta.as_ref().expect("cache entries have metadata");
        ensure!(
            meta.key == key,
            "reference {} does not match this request (its key is {}, expected {}); delete the folder to render it again",
            dir.display(),
            meta.key,
            key
        );
        return Ok(Reference { reused: true, ..r });
    }

    std::fs::create_dir_all(&dir)
        .with_context(|| format!("cannot create reference folder {}", dir.display()))?;
    // An earlier entry is invalid from here on: its sidecar goes first.
    match std::fs::remove_file(dir.join(META_FILE)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("cannot replace reference {}", dir.display()));
        }
        _ => {}
    }
    let (moments, render_seconds) = samples()?;
    ensure!(
        moments.count == u64::from(req.spp)
            && (moments.width, moments.height) == (req.width, req.height),
        "the reference's samples are {} per pixel at {}x{}, expected {} at {}x{}",
        moments.count,
        moments.width,
        moments.height,
        req.spp,
        req.width,
        req.height
    );
    let mean = moments.mean_image();
    let mut variance = moments
        .variance_image()
        .context("the renderer returned no variance")?;
    let inv_spp = 1.0 / req.spp as f32;
    for v in &mut variance.data {
        *v *= inv_spp;
    }
    mean.write_exr(&dir.join(MEAN_FILE))?;
    variance.write_exr(&dir.join(VARIANCE_FILE))?;
    let meta = ReferenceMeta {
        format: FORMAT.into(),
        key,
        scene_content,
        scene: req.scene_path.display().to_string(),
        width: req.width,
        height: req.height,
        spp: req.spp,
        seed: req.seed,
        max_depth: req.tracer.max_depth,
        rr_depth: req.tracer.rr_depth,
        environment: req.scene.environment().describe(),
        camera: (&req.scene.camera).into(),
        render_seconds,
        invalid_samples: moments.invalid_samples,
        variance: "per-pixel, per-channel variance of the mean (path sample variance / spp)".into(),
        created_by: format!("nrc {}", env!("CARGO_PKG_VERSION")),
    };
    let json = serde_json::to_string_pretty(&meta).expect("metadata serialises");
    nrc_scene::image::write_atomic(&dir.join(META_FILE), json.as_bytes())?;
    Ok(Reference {
        mean,
        variance: Some(variance),
        meta: Some(meta),
        location: dir,
        reused: false,
    })
}

/// Reads one EXR of a reference and checks its size and values.
fn read_checked(path: &Path, width: u32, height: u32, what: &str) -> Result<Image> {
    let image = Image::read_exr(path).map_err(|e| {
        anyhow::anyhow!(
            "reference {what} {} is unreadable or corrupt: {e}",
            path.display()
        )
    })?;
    ensure!(
        image.width == width as usize && image.height == height as usize,
        "reference {what} {} is {}x{}, but its settings say {width}x{height}",
        path.display(),
        image.width,
        image.height
    );
    if let Some((i, p)) = image
        .data
        .iter()
        .enumerate()
        .find(|(_, p)| !(p.is_finite() && p.min_element() >= 0.0))
    {
        bail!(
            "reference {what} {} has the invalid value {p} at pixel ({}, {})",
            path.display(),
            i % image.width,
            i / image.width
        );
    }
    Ok(image)
}

/// Reads a cache entry (a folder with `reference.json`, `mean.exr` and `variance.exr`) and
/// checks that its files agree with its settings.
pub fn load_entry(dir: &Path) -> Result<Reference> {
    let meta_path = dir.join(META_FILE);
    let text = std::fs::read_to_string(&meta_path)
        .with_context(|| format!("cannot read reference settings {}", meta_path.display()))?;
    let meta: ReferenceMeta = serde_json::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "reference settings {} are corrupt ({e}); delete {} to render it again",
            meta_path.display(),
            dir.display()
        )
    })?;
    ensure!(
        meta.format == FORMAT,
        "reference {} has format {}, this program reads {FORMAT}; delete it to render it again",
        dir.display(),
        meta.format
    );
    let hint = |e: anyhow::Error| e.context(format!("delete {} to render it again", dir.display()));
    let mean =
        read_checked(&dir.join(MEAN_FILE), meta.width, meta.height, "image").map_err(hint)?;
    let variance = read_checked(
        &dir.join(VARIANCE_FILE),
        meta.width,
        meta.height,
        "variance",
    )
    .map_err(hint)?;
    Ok(Reference {
        mean,
        variance: Some(variance),
        meta: Some(meta),
        location: dir.to_path_buf(),
        reused: true,
    })
}

/// Refuses a stored entry (`r` from [`load_given`]) that was not rendered for `req`: another
/// scene's content, camera, size, environment or depth limits (its spp and seed may differ).
/// A bare EXR carries no key, so only its size was checked.
pub fn check_given(r: &Reference, req: &ReferenceRequest<'_>) -> Result<()> {
    let Some(meta) = &r.meta else {
        return Ok(());
    };
    let scene_content = scene_content_hash(req.scene_path)?;
    ensure!(
        meta.scene_content == scene_content,
        "reference {} was rendered from another scene ({}, content {}), not {} (content {}); \
         give this scene's reference or leave out --reference to render one",
        r.location.display(),
        meta.scene,
        &meta.scene_content[..16.min(meta.scene_content.len())],
        req.scene_path.display(),
        &scene_content[..16]
    );
    let same = ReferenceRequest {
        spp: meta.spp,
        seed: meta.seed,
        ..req.clone()
    };
    let camera = CameraRecord::from(&req.scene.camera);
    ensure!(
        meta.key == request_key(&same, &scene_content),
        "reference {} was rendered with other settings than this comparison's (camera {:?} \
         against {:?}; environment `{}` against `{}`; max depth {} against {}; Russian roulette \
         from depth {} against {}); leave out --reference to render one",
        r.location.display(),
        meta.camera,
        camera,
        meta.environment,
        req.scene.environment().describe(),
        meta.max_depth,
        req.tracer.max_depth,
        meta.rr_depth,
        req.tracer.rr_depth
    );
    Ok(())
}

/// The stored reference in `cache_dir` (as `nrc reference` and `nrc compare` store them) that
/// was made for `req`'s scene content, camera, size, environment and depth limits, whatever its
/// samples and seed: the one with the most samples; `None` where there is none (or no folder).
/// Entries that cannot be read are passed over.
pub fn find_stored(req: &ReferenceRequest<'_>, cache_dir: &Path) -> Result<Option<Reference>> {
    let Ok(entries) = std::fs::read_dir(cache_dir) else {
        return Ok(None);
    };
    let scene_content = scene_content_hash(req.scene_path)?;
    let mut best: Option<(u32, PathBuf)> = None;
    for dir in entries.flatten().map(|e| e.path()) {
        let Ok(text) = std::fs::read_to_string(dir.join(META_FILE)) else {
            continue;
        };
        let Ok(meta) = serde_json::from_str::<ReferenceMeta>(&text) else {
            continue;
        };
        let made_for = |meta: &ReferenceMeta| {
            let same = ReferenceRequest {
                spp: meta.spp,
                seed: meta.seed,
                ..req.clone()
            };
            meta.format == FORMAT
                && (meta.width, meta.height) == (req.width, req.height)
                && meta.scene_content == scene_content
                && meta.key == request_key(&same, &scene_content)
        };
        if made_for(&meta) && best.as_ref().is_none_or(|(spp, _)| meta.spp > *spp) {
            best = Some((meta.spp, dir));
        }
    }
    best.map(|(_, dir)| load_entry(&dir)).transpose()
}

/// A reference given by the user: a cache entry folder, or a bare EXR file (no variance).
/// Its size must be `width × height`.
pub fn load_given(path: &Path, width: u32, height: u32) -> Result<Reference> {
    let r = if path.is_dir() {
        load_entry(path)?
    } else {
        let mean = Image::read_exr(path).map_err(|e| {
            anyhow::anyhow!("reference {} is unreadable or corrupt: {e}", path.display())
        })?;
        Reference {
            mean,
            variance: None,
            meta: None,
            location: path.to_path_buf(),
            reused: true,
        }
    };
    ensure!(
        r.mean.width == width as usize && r.mean.height == height as usize,
        "reference {} is {}x{} pixels but the comparison renders {width}x{height}; use a reference of that size \
         (or leave out --reference to render one)",
        path.display(),
        r.mean.width,
        r.mean.height
    );
    if let Some((i, p)) = r
        .mean
        .data
        .iter()
        .enumerate()
        .find(|(_, p)| !(p.is_finite() && p.min_element() >= 0.0))
    {
        bail!(
            "reference {} has the invalid value {p} at pixel ({}, {})",
            path.display(),
            i % r.mean.width,
            i / r.mean.width
        );
    }
    Ok(r)
}
