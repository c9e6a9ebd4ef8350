#!/usr/bin/env python3
"""Cross-check `nrc render` against Mitsuba 3's `path` integrator (variant `scalar_rgb`).

Loads a glTF scene (the Cornell boxes, the many-light hall, the Country Kitchen), rebuilds it
in Mitsuba (geometry exported to PLY with normals and texture coordinates, same camera, box
pixel filter, same max_depth and Russian-roulette start depth), renders it with both programs at equal resolution, depth and
samples per pixel, and reports:

* the render times of both (Mitsuba's `mi.render` call; nrc's closing line), and each one's
  CPU time of rendering alone (loading excluded on both sides): samples per CPU-second,
* whether the two images' mean radiance agrees within noise. Under the hypothesis that both
  renderers are unbiased for the same pixel values, the per-pixel differences d_i have mean
  0 and are independent across pixels, so mean(d) has standard error sqrt(sum d_i^2) / N;
  |z| < 4 (a 99.99% two-sided bound) counts as agreement.

Usage (from the repository root, after `cargo build --release`):

    pip install mitsuba numpy
    python3 scripts/mitsuba_compare.py --scene scenes/cornell-box.gltf \
        --width 256 --height 256 --spp 64 --max-depth 8 --threads 2

Translated: meshes under node transforms (instances included); materials as `material_of`
says (Lambertian when metallic is 0 and KHR_materials_specular's factor 0; metallic 1 as
Mitsuba's `principled` with metallic 1: Schlick Fresnel from the base colour, GGX with alpha =
roughness^2, as nrc; Mitsuba's Smith shadowing is the separable form, nrc's the
height-correlated one; glass; the default specular layer approximately; base colour textures); emissive factor times
KHR_materials_emissive_strength (area lights); KHR_lights_punctual lights (point -> `point`,
directional -> `directional`, spot -> `spot`, each with colour x intensity as RGB radiant
intensity or irradiance, no 683 factor, as nrc reads them); `--env` (Mitsuba `envmap`, with
`scale` and a rotation about +y); and the first perspective camera (or --camera-* overrides).

Known differences, kept small by the test scene rather than translated away:
* Spot falloff: glTF's (and nrc's) is saturate((cos - cos_outer)/(cos_inner - cos_outer))^2;
  Mitsuba's is linear in angle between beam_width and cutoff_angle. Mitsuba gets
  cutoff_angle = outer and beam_width = outer - (2/3)(outer - inner), which gives the band
  between the cones the same power (to first order in its width); inside the band the two
  curves still differ, so use a nearly hard cone (inner close to outer).
* Environment lookup: nrc takes the nearest texel, Mitsuba's envmap interpolates bilinearly.
  Both have the same integral to second order in the texel size; a smooth, low-frequency
  sky makes the per-pixel difference negligible.

With `--per-pixel`, nrc writes its per-pixel variance (`--variance`) and each pixel's
difference gets a z-score against twice nrc's variance of the pixel mean (Mitsuba's own
`moment` integrator reports moments in XYZ only, without the cross terms an RGB variance
needs, so the two estimators are taken to have equal variance); the fraction of pixel
channels with |z| < 4 is reported (99.994% expected under agreement, before the
heavier-than-Gaussian tails of a path tracer's estimates), over the pixels where nrc's
variance is non-zero (a pixel that sees only the environment directly has zero variance in
nrc, whose nearest-texel lookup is constant over it, and differs from Mitsuba's bilinear
value by a fixed amount), and over 8x8-pixel blocks.
"""

import argparse
import base64
import json
import math
import os
import re
import resource
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np


def quat_to_mat(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def node_matrix(node):
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    s = np.array(node.get("scale", [1, 1, 1]), dtype=np.float64)
    m[:3, :3] = quat_to_mat(node.get("rotation", [0, 0, 0, 1])) * s[None, :]
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def load_gltf(path):
    """Returns (json document, list of buffers as bytes)."""
    data = open(path, "rb").read()
    if data[:4] == b"glTF":
        jlen = struct.unpack("<I", data[12:16])[0]
        doc = json.loads(data[20:20 + jlen])
        rest = data[20 + jlen:]
        bin_chunk = rest[8:8 + struct.unpack("<I", rest[:4])[0]] if len(rest) >= 8 else b""
    else:
        doc = json.loads(data)
        bin_chunk = None
    buffers = []
    for b in doc.get("buffers", []):
        uri = b.get("uri")
        if uri is None:
            buffers.append(bin_chunk)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            buffers.append(open(os.path.join(os.path.dirname(path), uri), "rb").read())
    return doc, buffers


COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def accessor(doc, buffers, i):
    a = doc["accessors"][i]
    v = doc["bufferViews"][a["bufferView"]]
    dt = np.dtype(COMPONENT[a["componentType"]])
    n = WIDTH[a["type"]]
    stride = v.get("byteStride", dt.itemsize * n)
    base = v.get("byteOffset", 0) + a.get("byteOffset", 0)
    out = np.ndarray((a["count"], n), dtype=dt, buffer=buffers[v["buffer"]], offset=base,
                     strides=(stride, dt.itemsize)).copy()
    if a.get("normalized", False):
        out = out.astype(np.float64) / np.iinfo(dt).max
    return out


def walk(doc, roots, parent=np.eye(4)):
    for i in roots:
        node = doc["nodes"][i]
        m = parent @ node_matrix(node)
        yield node, m
        yield from walk(doc, node.get("children", []), m)


def gather(doc, buffers):
    """World-space triangles grouped by material (corners, shading normals, texture
    coordinates), and the first camera (pos, target, up, fov_y)."""
    groups = {}
    camera = None
    scene = doc.get("scenes", [{"nodes": list(range(len(doc.get("nodes", []))))}])[doc.get("scene", 0)]
    for node, m in walk(doc, scene["nodes"]):
        if "camera" in node and camera is None:
            cam = doc["cameras"][node["camera"]]
            pos = m[:3, 3]
            fwd = -m[:3, 2] / np.linalg.norm(m[:3, 2])
            up = m[:3, 1] / np.linalg.norm(m[:3, 1])
            camera = (pos, pos + fwd, up, math.degrees(cam["perspective"]["yfov"]))
        if "mesh" not in node:
            continue
        for prim in doc["meshes"][node["mesh"]]["primitives"]:
            if prim.get("mode", 4) != 4:
                continue
            p = accessor(doc, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
            p = (np.c_[p, np.ones(len(p))] @ m.T)[:, :3]
            if "indices" in prim:
                idx = accessor(doc, buffers, prim["indices"]).reshape(-1, 3).astype(np.int64)
            else:
                idx = np.arange(len(p)).reshape(-1, 3)
            if np.linalg.det(m[:3, :3]) < 0:
                idx = idx[:, ::-1]
            t = p[idx]
            # Zero-area triangles are dropped, as nrc drops them (their normals are undefined).
            keep = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1) > 0
            idx, t = idx[keep], t[keep]
            if "NORMAL" in prim["attributes"]:
                nv = accessor(doc, buffers, prim["attributes"]["NORMAL"]).astype(np.float64)
                nv = nv @ np.linalg.inv(m[:3, :3])  # rows times the inverse transpose
                nv /= np.linalg.norm(nv, axis=1, keepdims=True)
                nt = nv[idx]
            else:
                fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
                fn /= np.linalg.norm(fn, axis=1, keepdims=True)
                nt = np.repeat(fn[:, None, :], 3, axis=1)
            if "TEXCOORD_0" in prim["attributes"]:
                uv = accessor(doc, buffers, prim["attributes"]["TEXCOORD_0"]).astype(np.float64)[idx]
            else:
                uv = np.zeros((len(idx), 3, 2))
            groups.setdefault(prim.get("material", -1), []).append((t, nt, uv))
    return {k: tuple(np.concatenate([g[j] for g in v]) for j in range(3)) for k, v in groups.items()}, camera


def write_ply(path, tris, normals, uvs):
    """Triangles (N, 3, 3) with per-corner shading normals (N, 3, 3) and texture coordinates
    (N, 3, 2): flat meshes carry their face normal at every corner, smooth ones their NORMAL
    attribute. glTF's v runs down the image from its top row, as Mitsuba's bitmap lookup."""
    v = np.concatenate([tris.reshape(-1, 3), normals.reshape(-1, 3), uvs.reshape(-1, 2)], axis=1).astype(np.float32)
    with open(path, "wb") as f:
        f.write(("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
                 "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                 "property float u\nproperty float v\n"
                 "element face %d\nproperty list uchar int vertex_indices\nend_header\n"
                 % (len(v), len(tris))).encode())
        f.write(v.tobytes())
        faces = np.empty(len(tris), dtype=[("n", "u1"), ("i", "<i4", 3)])
        faces["n"] = 3
        faces["i"] = np.arange(len(v), dtype=np.int32).reshape(-1, 3)
        f.write(faces.tobytes())


def material_of(doc, i, scene_dir):
    """(Mitsuba BSDF, emitted radiance, double-sided) of glTF material i. Translated as nrc
    reads it (`Bsdf::from_pbr`): metallic 0 with KHR_materials_specular 0 -> `diffuse`;
    metallic 1 -> `principled` metallic 1; KHR_materials_transmission 1 -> `dielectric`
    (`roughdielectric`, GGX, alpha = roughness^2, when rough) with the base colour as its
    transmittance; any other (glTF's default dielectric specular layer, F0 0.04, over the base
    colour) -> `principled` with metallic 0 and specular 0.5 (F0 0.04), an approximation: its
    diffuse lobe is Disney's (retro-reflection at grazing angles), nrc's a Lambertian weighted
    by the layer's albedo. A base colour texture becomes a `bitmap` (sRGB, bilinear), used as is
    where the base colour factor is 1 (a factor other than 1 on a texture is dropped, with a
    warning)."""
    if i < 0:
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1, 1, 1]}}, np.zeros(3), False
    m = doc["materials"][i]
    name = m.get("name", i)
    pbr = m.get("pbrMetallicRoughness", {})
    ext = m.get("extensions", {})
    base = np.array(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3], dtype=np.float64)
    le = np.array(m.get("emissiveFactor", [0, 0, 0])) * ext.get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
    spec = ext.get("KHR_materials_specular", {}).get("specularFactor", 1.0)
    metallic = pbr.get("metallicFactor", 1.0)
    rough = pbr.get("roughnessFactor", 1.0)
    transmission = ext.get("KHR_materials_transmission", {}).get("transmissionFactor", 0.0)
    ior = ext.get("KHR_materials_ior", {}).get("ior", 1.5)
    double_sided = bool(m.get("doubleSided", False))
    colour = {"type": "rgb", "value": list(base)}
    if "baseColorTexture" in pbr:
        tex = doc["textures"][pbr["baseColorTexture"]["index"]]
        uri = doc["images"][tex["source"]]["uri"]
        if pbr["baseColorTexture"].get("texCoord", 0) != 0:
            print("warning: material %r reads its texture through TEXCOORD_1; Mitsuba gets TEXCOORD_0" % name, file=sys.stderr)
        if not np.allclose(base, 1.0):
            print("warning: material %r multiplies its texture by %s; Mitsuba gets the texture alone" % (name, base), file=sys.stderr)
        colour = {"type": "bitmap", "filename": os.path.join(scene_dir, uri), "raw": False}
    if "metallicRoughnessTexture" in pbr or "normalTexture" in m:
        print("warning: material %r has a metallic-roughness or normal texture; Mitsuba gets the factors" % name, file=sys.stderr)
    if transmission == 1 and metallic == 0:
        bsdf = {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0, "specular_transmittance": colour}
        if rough > 0:
            bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": rough * rough,
                    "int_ior": ior, "ext_ior": 1.0, "specular_transmittance": colour}
        return bsdf, le, double_sided
    if transmission != 0:
        print("warning: material %r is partly transmissive; Mitsuba gets it opaque" % name, file=sys.stderr)
    if metallic == 1:
        inner = {"type": "principled", "base_color": colour, "metallic": 1.0, "roughness": rough}
    elif metallic == 0 and spec == 0:
        inner = {"type": "diffuse", "reflectance": colour}
    else:
        if metallic != 0 or spec != 1:
            print("warning: material %r (metallic %g, specular %g) is approximated by Mitsuba's principled with metallic %g, specular %g" % (name, metallic, spec, metallic, 0.5 * spec), file=sys.stderr)
        inner = {"type": "principled", "base_color": colour, "metallic": metallic, "specular": 0.5 * spec,
                 "roughness": rough}
    return {"type": "twosided", "bsdf": inner}, le, double_sided


def punctual_lights(doc):
    """World-space KHR_lights_punctual lights: (light json, position, unit beam direction)."""
    lights = doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    out = []
    scene = doc.get("scenes", [{"nodes": list(range(len(doc.get("nodes", []))))}])[doc.get("scene", 0)]
    for node, m in walk(doc, scene["nodes"]):
        ext = node.get("extensions", {}).get("KHR_lights_punctual")
        if ext is None:
            continue
        d = -m[:3, 2]
        out.append((lights[ext["light"]], m[:3, 3].copy(), d / np.linalg.norm(d)))
    return out


def light_emitter(mi, light, pos, d):
    """The Mitsuba emitter of one glTF punctual light."""
    value = list(np.array(light.get("color", [1, 1, 1]), dtype=np.float64) * light.get("intensity", 1.0))
    kind = light["type"]
    if "range" in light:
        print("warning: light %r has a range; Mitsuba ignores it" % light.get("name"), file=sys.stderr)
    if kind == "point":
        return {"type": "point", "position": list(pos), "intensity": {"type": "rgb", "value": value}}
    if kind == "directional":
        return {"type": "directional", "direction": list(d), "irradiance": {"type": "rgb", "value": value}}
    if kind == "spot":
        spot = light.get("spot", {})
        inner = math.degrees(spot.get("innerConeAngle", 0.0))
        outer = math.degrees(spot.get("outerConeAngle", math.pi / 4))
        up = [0, 1, 0] if abs(d[1]) < 0.9 else [1, 0, 0]
        return {"type": "spot", "intensity": {"type": "rgb", "value": value},
                "cutoff_angle": outer, "beam_width": outer - 2.0 / 3.0 * (outer - inner),
                "to_world": mi.ScalarTransform4f().look_at(origin=list(pos), target=list(pos + d), up=up)}
    sys.exit("error: unknown light type %r" % kind)


def vec3(s):
    return np.array([float(x) for x in s.split(",")])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", required=True)
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--rr-depth", type=int, default=5)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--camera-pos", type=vec3)
    ap.add_argument("--camera-target", type=vec3)
    ap.add_argument("--camera-up", type=vec3)
    ap.add_argument("--fov-y", type=float)
    ap.add_argument("--nrc", default="target/release/nrc", help="path of the nrc binary")
    ap.add_argument("--light-sampler", choices=["power", "tree"], default="power",
                    help="nrc's light sampler (`nrc render --light-sampler`)")
    ap.add_argument("--keep", help="folder to keep both EXRs in")
    ap.add_argument("--env", help="environment map (.exr/.hdr), as `nrc render --env`")
    ap.add_argument("--env-intensity", type=float, default=1.0)
    ap.add_argument("--env-rotate", type=float, default=0.0, help="degrees about +y")
    ap.add_argument("--env-upsample", type=int, default=1,
                    help="give both renderers a copy of --env upsampled N times by repeating texels: nrc's "
                         "nearest lookup sees the same map, and Mitsuba's bilinear one differs only in bands "
                         "1/N of a texel wide")
    ap.add_argument("--per-pixel", action="store_true",
                    help="per-pixel z-scores from both renderers' variance estimates (Mitsuba's `moment` integrator)")
    ap.add_argument("--repeats", type=int, default=1,
                    help="render with each program this many times, alternating; report the best times")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    dr.set_thread_count(args.threads)

    doc, buffers = load_gltf(args.scene)
    groups, camera = gather(doc, buffers)
    if args.camera_pos is not None:
        camera = (args.camera_pos, args.camera_target, args.camera_up, args.fov_y)
    if camera is None:
        sys.exit("error: %s has no camera; pass --camera-pos/--camera-target/--camera-up/--fov-y" % args.scene)
    pos, target, up, fov = camera

    work = args.keep or tempfile.mkdtemp(prefix="nrc-mitsuba-")
    os.makedirs(work, exist_ok=True)
    env_file = args.env and os.path.abspath(args.env)
    if args.env and args.env_upsample > 1:
        k = args.env_upsample
        dr.set_thread_count(max(2, os.cpu_count() or 2))
        env = np.array(mi.Bitmap(args.env))[:, :, :3]
        env_file = os.path.join(work, "env-x%d.exr" % k)
        mi.Bitmap(np.ascontiguousarray(np.repeat(np.repeat(env, k, axis=0), k, axis=1))).write(env_file)
        dr.set_thread_count(args.threads)
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": args.max_depth, "rr_depth": args.rr_depth},
        # (wrapped in `moment` below with --per-pixel)
        "sensor": {
            "type": "perspective", "fov": fov, "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(origin=list(pos), target=list(target), up=list(up)),
            "sampler": {"type": "independent", "sample_count": args.spp},
            "film": {"type": "hdrfilm", "width": args.width, "height": args.height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        },
    }
    for k, (tris, normals, uvs) in groups.items():
        bsdf, le, double_sided = material_of(doc, k, os.path.dirname(os.path.abspath(args.scene)))
        sides = [(tris, normals, uvs)]
        if double_sided and le.max() > 0:
            # nrc's double-sided materials emit from both faces; Mitsuba's area lights emit
            # from the front face only. Add a flipped copy, moved a hair along its own normal
            # so that each side's ray meets the copy facing it first.
            e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
            n = np.cross(e1, e2)
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            scale = np.abs(tris).max() + 1.0
            sides.append((tris[:, ::-1] - 1e-5 * scale * n[:, None, :], -normals[:, ::-1], uvs[:, ::-1]))
        for s, (t, tn, tuv) in enumerate(sides):
            ply = os.path.join(work, "mesh%d_%d.ply" % (k + 1, s))
            write_ply(ply, t, tn, tuv)
            shape = {"type": "ply", "filename": ply, "face_normals": False, "bsdf": bsdf}
            if le.max() > 0:
                shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": list(le)}}
            scene["shape%d_%d" % (k + 1, s)] = shape
    for j, (light, lpos, ldir) in enumerate(punctual_lights(doc)):
        scene["light%d" % j] = light_emitter(mi, light, lpos, ldir)
    if args.env:
        scene["environment"] = {"type": "envmap", "filename": os.path.abspath(args.env), "scale": args.env_intensity,
                                "to_world": mi.ScalarTransform4f().rotate(axis=[0, 1, 0], angle=args.env_rotate)}
    if args.env and args.env_upsample > 1:
        scene["environment"]["filename"] = env_file
    ms = mi.load_dict(scene)
    ours = os.path.join(work, "nrc.exr")
    cmd = [args.nrc, "render", "--scene", args.scene, "--width", str(args.width), "--height", str(args.height),
           "--spp", str(args.spp), "--max-depth", str(args.max_depth), "--rr-depth", str(args.rr_depth),
           "--threads", str(args.threads), "--seed", str(args.seed), "--out", ours,
           "--camera-pos", ",".join(map(str, pos)), "--camera-target", ",".join(map(str, target)),
           "--camera-up", ",".join(map(str, up)), "--fov-y", str(fov),
           "--light-sampler", args.light_sampler]
    if args.env:
        cmd += ["--env", env_file, "--env-intensity", str(args.env_intensity), "--env-rotate", str(args.env_rotate)]
    ours_var = os.path.join(work, "nrc-variance.exr")
    if args.per_pixel:
        cmd += ["--variance", ours_var]
    # Wall-clock time (best of the repeats) and CPU time of all threads (mean over the
    # repeats): on a machine shared with other work, wall time depends on the load and CPU
    # time much less. nrc's CPU time is its whole process (scene loading included).
    t_mitsuba, t_nrc, cpu_mitsuba, cpu_nrc, cpu_nrc_all = [], [], [], [], []
    for _ in range(max(1, args.repeats)):
        t0, c0 = time.perf_counter(), time.process_time()
        img = np.array(mi.render(ms, spp=args.spp, seed=args.seed))
        t_mitsuba.append(time.perf_counter() - t0)
        cpu_mitsuba.append(time.process_time() - c0)
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        run = subprocess.run(cmd, capture_output=True, text=True)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_nrc_all.append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
        if run.returncode != 0:
            sys.exit("error: nrc render failed: " + run.stderr.strip())
        m = re.search(r"in ([0-9.]+) s", run.stdout)
        t_nrc.append(float(m.group(1)) if m else float("nan"))
        # The rendering's own CPU time, as Mitsuba's is its `mi.render` call's (loading the
        # scene excluded on both sides).
        m = re.search(r"([0-9.]+) CPU-s rendering", run.stdout)
        cpu_nrc.append(float(m.group(1)) if m else float("nan"))
    t_mitsuba, t_nrc = min(t_mitsuba), min(t_nrc)
    cpu_mitsuba, cpu_nrc, cpu_nrc_all = np.mean(cpu_mitsuba), np.mean(cpu_nrc), np.mean(cpu_nrc_all)
    # Mitsuba's EXR input/output waits on its thread pool and hangs with a pool of one.
    dr.set_thread_count(max(2, os.cpu_count() or 2))
    mi.Bitmap(img).write(os.path.join(work, "mitsuba.exr"))
    a = np.array(mi.Bitmap(ours))[:, :, :3].astype(np.float64)
    b = img[:, :, :3].astype(np.float64)
    if args.per_pixel:
        var_a = np.array(mi.Bitmap(ours_var))[:, :, :3].astype(np.float64) / args.spp
        var_b = var_a

    d = a - b
    n = d.shape[0] * d.shape[1]
    mean_d = d.reshape(-1, 3).mean(0)
    se = np.sqrt((d.reshape(-1, 3) ** 2).sum(0)) / n
    z = mean_d / se
    print("scene %s, %dx%d, %d spp, max_depth %d, rr_depth %d, %d threads" % (
        args.scene, args.width, args.height, args.spp, args.max_depth, args.rr_depth, args.threads))
    print("time (best of %d): nrc %.3f s, mitsuba scalar_rgb %.3f s (nrc %.2fx faster)" % (
        max(1, args.repeats), t_nrc, t_mitsuba, t_mitsuba / t_nrc))
    print("samples/s: nrc %.3f M, mitsuba %.3f M" % (
        args.width * args.height * args.spp / t_nrc * 1e-6, args.width * args.height * args.spp / t_mitsuba * 1e-6))
    print("CPU time of the render (mean of %d): nrc %.3f s, mitsuba %.3f s (nrc %.2fx less); nrc's whole process %.3f s" % (
        max(1, args.repeats), cpu_nrc, cpu_mitsuba, cpu_mitsuba / cpu_nrc, cpu_nrc_all))
    print("samples per CPU-second: nrc %.3f M, mitsuba %.3f M (nrc %.2fx)" % (
        args.width * args.height * args.spp / cpu_nrc * 1e-6, args.width * args.height * args.spp / cpu_mitsuba * 1e-6,
        cpu_mitsuba / cpu_nrc))
    print("mean radiance (r,g,b): nrc %s, mitsuba %s" % (np.round(a.reshape(-1, 3).mean(0), 5), np.round(b.reshape(-1, 3).mean(0), 5)))
    print("difference z-scores (r,g,b): %s -> %s" % (np.round(z, 2), "agree" if np.all(np.abs(z) < 4) else "DISAGREE"))
    ma, mb = a.reshape(-1, 3).mean(0), b.reshape(-1, 3).mean(0)
    print("mean ratio nrc/mitsuba (r,g,b): %s; of the channel means %.5f" % (np.round(ma / mb, 5), ma.mean() / mb.mean()))
    if args.per_pixel:
        live = (var_a > 0).all(axis=2)
        print("pixels with zero nrc variance (environment seen directly, one texel): %d of %d; their mean |diff| %.4g, mean value %.4g" % (
            (~live).sum(), live.size, np.abs(d[~live]).mean() if (~live).any() else 0.0, a[~live].mean() if (~live).any() else 0.0))
        zp = d[live] / np.sqrt(var_a[live] + var_b[live])
        for lim in (2, 3, 4):
            print("per-pixel |z| < %d: %.4f of pixel channels (Gaussian: %.4f)" % (lim, (np.abs(zp) < lim).mean(), math.erf(lim / math.sqrt(2))))
        print("per-pixel mean z^2 (chi-square per degree of freedom): %.3f; median |z| %.3f (0.674 if Gaussian)" % (
            (zp ** 2).mean(), np.median(np.abs(zp))))
        # 8x8-pixel blocks: sum of differences over the block against the summed variances.
        bs = 8
        H, W = (d.shape[0] // bs) * bs, (d.shape[1] // bs) * bs
        db = d[:H, :W].reshape(H // bs, bs, W // bs, bs, 3).sum((1, 3))
        vb = np.where(live[:, :, None], var_a + var_b, 0)[:H, :W].reshape(H // bs, bs, W // bs, bs, 3).sum((1, 3))
        ok = (vb > 0).all(axis=2)
        zb = (db / np.sqrt(np.maximum(vb, 1e-30)))[ok]
        zfull = np.where(ok[:, :, None], db / np.sqrt(np.maximum(vb, 1e-30)), 0)
        worst = np.dstack(np.unravel_index(np.argsort(-np.abs(zfull).max(axis=2), axis=None)[:6], ok.shape))[0]
        for (by, bx) in worst:
            sl = (slice(by * bs, (by + 1) * bs), slice(bx * bs, (bx + 1) * bs))
            print("  block at pixels x %d..%d, y %d..%d: z %s, nrc mean %s, mitsuba mean %s" % (
                bx * bs, (bx + 1) * bs - 1, by * bs, (by + 1) * bs - 1, np.round(zfull[by, bx], 1),
                np.round(a[sl].reshape(-1, 3).mean(0), 4), np.round(b[sl].reshape(-1, 3).mean(0), 4)))
        print("%dx%d blocks (zero-variance pixels left out): %d block channels, |z| < 4: %.4f, mean z^2 %.3f, worst |z| %.2f" % (
            bs, bs, zb.size, (np.abs(zb) < 4).mean(), (zb ** 2).mean(), np.abs(zb).max()))
    print("images in %s" % work)
    return 0 if np.all(np.abs(z) < 4) else 1


if __name__ == "__main__":
    sys.exit(main())
