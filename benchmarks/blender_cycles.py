"""Render Principled-BSDF subsurface slabs in Blender Cycles and report their diffuse albedo.

Run with a Python that has Blender's ``bpy`` module (PyPI ``bpy``; it pins its own Python and NumPy,
so it usually lives in its own environment; this script imports nothing of skinfit):

    <python with bpy> benchmarks/blender_cycles.py jobs.json results.json

``jobs.json`` holds {"jobs": [{"base_colour": [r, g, b], "radius_mm": [r, g, b], "ior": 1.4,
"anisotropy": 0.0, "method": "RANDOM_WALK", "spp": 4096}, ...]}. Each job renders the
reference scene of the renderer checks: a slab 400 mm wide and 100 mm deep under a uniform white
world, seen at normal incidence by an orthographic camera (4 x 4 pixels over 2 mm), no
denoising, linear output. The specular layer is measured by the same slab with a black base
colour and subtracted, so what remains is the diffuse (subsurface) albedo, with its standard
error over the 16 pixels. ``results.json`` gets the albedos, errors, seconds and Blender's version.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np


def _scene(job: dict, base_colour) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(job.get("spp", 4096))
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.seed = int(job.get("seed", 0))
    for name in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces", "volume_bounces", "transparent_max_bounces"):
        setattr(scene.cycles, name, 64)
    scene.cycles.sample_clamp_direct = 0.0
    scene.cycles.sample_clamp_indirect = 0.0
    scene.cycles.caustics_reflective = True
    scene.cycles.caustics_refractive = True
    scene.cycles.blur_glossy = 0.0
    scene.render.resolution_x = scene.render.resolution_y = 4
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"

    world = bpy.data.worlds.new("white")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    background.inputs["Strength"].default_value = 1.0
    scene.world = world

    width, depth = (0.001 * float(v) for v in job.get("slab_mm", (400.0, 100.0)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, -depth / 2))
    slab = bpy.context.active_object
    slab.scale = (width, width, depth)  # metres (400 x 400 x 100 mm by default), top face at z = 0
    material = bpy.data.materials.new("skin")
    material.use_nodes = True
    principled = material.node_tree.nodes["Principled BSDF"]
    principled.subsurface_method = job.get("method", "RANDOM_WALK")
    inputs = {socket.name: socket for socket in principled.inputs}  # by-name lookup misses some sockets in bpy 4.2
    inputs["Base Color"].default_value = (*map(float, base_colour), 1.0)
    inputs["Metallic"].default_value = 0.0
    inputs["Roughness"].default_value = 0.0
    inputs["IOR"].default_value = float(job.get("ior", 1.4))
    inputs["Subsurface Weight"].default_value = 1.0
    inputs["Subsurface Radius"].default_value = tuple(map(float, job["radius_mm"]))
    inputs["Subsurface Scale"].default_value = 0.001  # radius in mm, scene in metres
    inputs["Subsurface IOR"].default_value = float(job.get("ior", 1.4))
    inputs["Subsurface Anisotropy"].default_value = float(job.get("anisotropy", 0.0))
    inputs["Coat Weight"].default_value = 0.0
    inputs["Sheen Weight"].default_value = 0.0
    slab.data.materials.append(material)

    camera_data = bpy.data.cameras.new("camera")
    camera_data.type = "ORTHO"
    screen = job.get("screen_radius_mm")
    camera_data.ortho_scale = 0.002 if screen is None else min(0.002, 2e-5 * float(screen))
    if screen is not None:
        _screen(0.001 * float(screen), width, 0.001 * float(screen) * 0.01)
    camera_data.clip_start, camera_data.clip_end = 0.001, 10.0
    camera = bpy.data.objects.new("camera", camera_data)
    camera.location = (0.0, 0.0, 1.0)  # looking down -z by default
    scene.collection.objects.link(camera)
    scene.camera = camera


def _screen(inner: float, outer: float, height: float, segments: int = 512) -> None:
    """A black ring over the slab with a hole of radius ``inner`` (metres; the inner polygon
    circumscribes the circle): by reciprocity the radiance seen through the hole's centre is the
    diffuse reflectance within ``inner`` of a beam there (see skinfit.export)."""
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    r_in = inner / np.cos(np.pi / segments)
    vertices = [(r_in * np.cos(a), r_in * np.sin(a), height) for a in angle] + [(outer * np.cos(a), outer * np.sin(a), height) for a in angle]
    faces = [(k, (k + 1) % segments, segments + (k + 1) % segments, segments + k) for k in range(segments)]
    mesh = bpy.data.meshes.new("screen")
    mesh.from_pydata(vertices, [], faces)
    mesh.update()
    ring = bpy.data.objects.new("screen", mesh)
    black = bpy.data.materials.new("black")
    black.use_nodes = True
    black.node_tree.nodes["Principled BSDF"].inputs[0].default_value = (0.0, 0.0, 0.0, 1.0)
    black.node_tree.nodes["Principled BSDF"].inputs[2].default_value = 1.0  # rough, and black
    for socket in black.node_tree.nodes["Principled BSDF"].inputs:
        if socket.name == "Specular IOR Level":
            socket.default_value = 0.0
    ring.data.materials.append(black)
    bpy.context.scene.collection.objects.link(ring)


def _render(job: dict, base_colour) -> np.ndarray:
    _scene(job, base_colour)
    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / "render.exr")
        bpy.context.scene.render.filepath = path
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(path)
        pixels = np.array(image.pixels[:], dtype=float).reshape(-1, 4)[:, :3]
    return pixels


def main(jobs_path: str, out_path: str) -> None:
    jobs = json.loads(Path(jobs_path).read_text())["jobs"]
    results = []
    specular_cache = {}
    for job in jobs:
        start = time.perf_counter()
        key = (job.get("ior", 1.4), job.get("method", "RANDOM_WALK"), tuple(job["radius_mm"]), job.get("spp", 4096),
               job.get("screen_radius_mm"), tuple(job.get("slab_mm", ())))
        if key not in specular_cache:
            specular_cache[key] = _render(job, (0.0, 0.0, 0.0)).mean(axis=0)
        pixels = _render(job, job["base_colour"]) - specular_cache[key]
        results.append({**job, "albedo": pixels.mean(axis=0).tolist(), "error": (pixels.std(axis=0, ddof=1) / np.sqrt(len(pixels))).tolist(),
                        "specular": specular_cache[key].tolist(), "seconds": round(time.perf_counter() - start, 2)})
        print(json.dumps(results[-1]), flush=True)
    Path(out_path).write_text(json.dumps({"blender": bpy.app.version_string, "results": results}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
