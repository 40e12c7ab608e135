"""The Cycles side of ``bench_render.py --only cycles``: runs inside Blender's Python (bpy).

Not part of the package and never imported by it: ``bpy`` pins numpy < 2, so it lives in
a virtual environment of its own (``python3 -m venv /work/bpy-venv &&
/work/bpy-venv/bin/pip install 'bpy>=4.2,<5'``) and this script runs in that interpreter.

    BPY_PYTHON bench/cycles_scene.py SCENE_DIR FD

``SCENE_DIR/scene.json`` (written by ``bench_render.write_cycles_scene``) describes the
scene the renderer builds: one OBJ per render part (the renderer's own parts, written by
``obj_io.write_mesh``) with an ``.npz`` beside it holding the renderer's vertex normals
(and the iris's vertex colours), the skin maps as an EXR texture set
(``appearance.texture_io``), the camera and the area lights as Blender world matrices,
the environment's constant radiance, resolution and path depth. The script builds that
scene in Cycles (CPU), renders one warm-up sample, then reads commands from stdin, one
JSON object a line: ``{"spp": N, "seed": S, "denoise": false, "out": "x.exr"}``; it
renders, writes the linear premultiplied RGBA to ``out`` (EXR, float32) and answers on
file descriptor FD (Blender's own output stays on stdout) with one JSON line:
``{"cpu_s": process time of the render call (all threads), "wall_s": ...}``.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import bpy
import numpy as np


def _node(tree, kind: str, inputs: dict | None = None):
    n = tree.nodes.new(kind)
    for key, value in (inputs or {}).items():
        n.inputs[key].default_value = value
    return n


def _principled(tree, base=None, roughness=0.5, ior=1.5):
    p = _node(tree, "ShaderNodeBsdfPrincipled")
    p.distribution = "GGX"  # single-scattering GGX, as Mitsuba's microfacet BSDFs
    if base is not None:
        p.inputs["Base Color"].default_value = (*base, 1.0)
    p.inputs["Roughness"].default_value = roughness
    p.inputs["IOR"].default_value = ior
    return p


def _image(tree, path: Path, data: bool):
    img = bpy.data.images.load(str(path))
    img.colorspace_settings.name = "Non-Color" if data else "Linear Rec.709"
    n = tree.nodes.new("ShaderNodeTexImage")
    n.image, n.interpolation, n.extension = img, "Linear", "EXTEND"  # bilinear, clamped
    return n


def skin_material(textures: dict, spec: dict):
    """Principled BSDF from the skin maps: two of them mixed for the dual GGX lobe."""
    mat = bpy.data.materials.new("skin")
    mat.use_nodes = True
    t = mat.node_tree
    t.nodes.clear()
    link = t.links.new
    out = t.nodes.new("ShaderNodeOutputMaterial")
    diffuse = _image(t, textures["diffuse"], False)
    rough = _image(t, textures["roughness"], True)
    specular = _image(t, textures["specular"], True)
    # Specular IOR Level scales F0 by 2 x level: level = s / 2 gives F0 = 0.028 s
    level = _node(t, "ShaderNodeMath", {1: 0.5})
    level.operation = "MULTIPLY"
    link(specular.outputs["Color"], level.inputs[0])
    normal = None
    if "normal" in textures:
        nimg = _image(t, textures["normal"], True)
        enc = t.nodes.new("ShaderNodeVectorMath")  # raw [-1, 1] -> the node's [0, 1] coding
        enc.operation = "MULTIPLY_ADD"
        enc.inputs[1].default_value = (0.5, 0.5, 0.5)
        enc.inputs[2].default_value = (0.5, 0.5, 0.5)
        link(nimg.outputs["Color"], enc.inputs[0])
        normal = t.nodes.new("ShaderNodeNormalMap")
        normal.space, normal.uv_map = "TANGENT", "UVMap"
        link(enc.outputs["Vector"], normal.inputs["Color"])
    lobes = []
    for k in spec["lobe_roughness"]:
        p = _principled(t, ior=spec["ior"])
        scale = _node(t, "ShaderNodeMath", {1: float(k)})
        scale.operation, scale.use_clamp = "MULTIPLY", True
        link(rough.outputs["Color"], scale.inputs[0])
        link(scale.outputs["Value"], p.inputs["Roughness"])
        link(diffuse.outputs["Color"], p.inputs["Base Color"])
        link(level.outputs["Value"], p.inputs["Specular IOR Level"])
        if normal is not None:
            link(normal.outputs["Normal"], p.inputs["Normal"])
        lobes.append(p)
    mix = _node(t, "ShaderNodeMixShader", {"Fac": 1.0 - spec["lobe_mix"]})
    link(lobes[0].outputs["BSDF"], mix.inputs[1])
    link(lobes[1].outputs["BSDF"], mix.inputs[2])
    link(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def part_material(name: str, spec: dict, root: Path):
    """The other parts: principled (roughplastic, iris), diffuse (bust cap), masked lashes
    (a constant opacity, or the strand texture ``opacity_map`` in ``root``)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    t = mat.node_tree
    t.nodes.clear()
    out = t.nodes.new("ShaderNodeOutputMaterial")
    if spec["kind"] == "diffuse":
        shader = _node(t, "ShaderNodeBsdfDiffuse", {"Color": (*spec["base"], 1.0),
                                                    "Roughness": 0.0})
    else:
        shader = _principled(t, spec.get("base"), spec["roughness"], spec["ior"])
        if spec.get("vertex_color"):
            attr = t.nodes.new("ShaderNodeVertexColor")
            attr.layer_name = spec["vertex_color"]
            t.links.new(attr.outputs["Color"], shader.inputs["Base Color"])
        if spec.get("coat"):
            shader.inputs["Coat Weight"].default_value = spec["coat"]
            shader.inputs["Coat Roughness"].default_value = spec["coat_roughness"]
            shader.inputs["Coat IOR"].default_value = 1.5
    opacity = spec.get("opacity", 1.0)
    if opacity < 1.0 or "opacity_map" in spec:
        mix = _node(t, "ShaderNodeMixShader", {"Fac": opacity})
        if "opacity_map" in spec:  # the strand texture, as Mitsuba's mask BSDF reads it
            tex = _image(t, root / spec["opacity_map"], True)
            t.links.new(tex.outputs["Color"], mix.inputs["Fac"])
        clear = t.nodes.new("ShaderNodeBsdfTransparent")
        t.links.new(clear.outputs[0], mix.inputs[1])
        t.links.new(shader.outputs[0], mix.inputs[2])
        shader = mix
    t.links.new(shader.outputs[0], out.inputs["Surface"])
    return mat


def import_part(root: Path, part: dict, mat) -> None:
    """One render part from its OBJ, with the renderer's normals (and colours) set on it."""
    bpy.ops.object.select_all(action="DESELECT")
    # forward +Y, up +Z: no axis conversion, the file's coordinates are used as they are
    bpy.ops.wm.obj_import(filepath=str(root / part["obj"]), forward_axis="Y", up_axis="Z",
                          validate_meshes=False)
    obj = bpy.context.selected_objects[0]
    obj.name = part["name"]
    mesh = obj.data
    extra = np.load(root / part["extra"])
    pos = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", pos)
    want = extra["positions"].astype(np.float32)
    if pos.size != want.size or np.abs(pos.reshape(-1, 3) - want).max() > 1e-5:
        raise SystemExit(f"{part['obj']}: the imported vertices are not the file's, in order "
                         f"({pos.size // 3} against {len(want)}).")
    if part["flat"]:
        mesh.shade_flat()
    else:
        mesh.shade_smooth()
        mesh.normals_split_custom_set_from_vertices(extra["normals"].tolist())
    if "colors" in extra:
        attr = mesh.color_attributes.new("vertex_color", "FLOAT_COLOR", "POINT")
        rgba = np.concatenate([extra["colors"], np.ones((len(want), 1))], 1).astype(np.float32)
        attr.data.foreach_set("color", rgba.ravel())
    mesh.materials.clear()
    mesh.materials.append(mat)


def import_hair(root: Path, spec: dict) -> None:
    """One hair shape of ours (``hair_shapes.HairShape``): ``spec['npz']`` holds the
    control points (S, M, 3) and radii (S, M) of Mitsuba's ``linearcurve`` strands, the
    points ``HeadScene`` renders; they become a Curves object through the same points
    (Cycles' round 3-D curves, Catmull-Rom between them: Cycles 4.5 has no linear
    curves), with the Principled Hair BSDF (Chiang) of absorption ``spec['sigma_a']``
    (Mitsuba's ``eumelanin x (0.419, 0.697, 1.37) + pheomelanin x (0.187, 0.4, 1.05)``,
    per unit of fibre radius in both), Mitsuba's ``hair`` defaults otherwise (roughness
    0.3, radial 0.3, IOR 1.55, scale tilt 2 deg)."""
    d = np.load(root / spec["npz"])
    pts, rad = d["points"].astype(np.float32), d["radius"].astype(np.float32)
    s, m, _ = pts.shape
    curves = bpy.data.hair_curves.new(spec["name"])
    curves.add_curves([m] * s)
    curves.position_data.foreach_set("vector", pts.ravel())
    radius = curves.attributes.get("radius") or curves.attributes.new("radius", "FLOAT",
                                                                       "POINT")
    radius.data.foreach_set("value", rad.ravel())
    mat = bpy.data.materials.new(spec["name"])
    mat.use_nodes = True
    t = mat.node_tree
    t.nodes.clear()
    out = t.nodes.new("ShaderNodeOutputMaterial")
    hair = t.nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.model = "CHIANG"
    if "melanin" in spec:  # Cycles' pigment parametrisation: its own pigment spectra
        hair.parametrization = "MELANIN"
        for key, value in (("Melanin", spec["melanin"]),
                           ("Melanin Redness", spec["melanin_redness"]),
                           ("Tint", (1.0, 1.0, 1.0, 1.0)), ("Random Color", 0.0)):
            hair.inputs[key].default_value = value
    else:
        hair.parametrization = "ABSORPTION"
        hair.inputs["Absorption Coefficient"].default_value = tuple(spec["sigma_a"])
    for key, value in (("Roughness", 0.3), ("Radial Roughness", 0.3), ("Coat", 0.0),
                       ("IOR", 1.55), ("Offset", math.radians(2.0)),
                       ("Random Roughness", 0.0)):
        hair.inputs[key].default_value = value
    t.links.new(hair.outputs[0], out.inputs["Surface"])
    curves.materials.append(mat)
    obj = bpy.data.objects.new(spec["name"], curves)
    bpy.context.scene.collection.objects.link(obj)


def build(root: Path, desc: dict) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.use_adaptive_sampling = False  # a fixed sample count, as ours
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0  # no clamping, no glossy blur:
    cy.blur_glossy = 0.0  # the same (unbiased) estimate as Mitsuba's path tracer
    # Mitsuba's max_depth counts path segments (2: direct light only); Cycles' bounces count
    # scattering events after the first hit (0: direct light only)
    bounces = max(0, desc["max_depth"] - 2)
    cy.max_bounces = bounces
    cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = bounces
    cy.pixel_filter_type, cy.filter_width = "GAUSSIAN", desc["filter_width"]
    cy.denoiser, cy.denoising_input_passes = "OPENIMAGEDENOISE", "RGB_ALBEDO_NORMAL"
    cy.denoising_prefilter, cy.denoising_quality = "ACCURATE", desc["denoise_quality"]
    r = sc.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = desc["width"], desc["height"], 100
    r.film_transparent = True  # the film holds the subject alone, as hide_emitters
    r.use_persistent_data = True  # keep the synced scene between renders (as HeadScene)
    r.use_compositing = r.use_sequencer = False
    r.threads_mode = "AUTO"
    r.image_settings.file_format, r.image_settings.color_depth = "OPEN_EXR", "32"
    r.image_settings.color_mode = "RGBA"
    sc.view_settings.view_transform, sc.view_settings.look = "Standard", "None"
    sc.view_settings.exposure, sc.view_settings.gamma = 0.0, 1.0
    world = bpy.data.worlds.new("environment")
    sc.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    env = desc["environment"]
    bg.inputs["Color"].default_value = (*(env or (0.0, 0.0, 0.0)), 1.0)
    bg.inputs["Strength"].default_value = 1.0 if env else 0.0
    world.cycles_visibility.camera = False  # hide_emitters: the camera never sees it
    for i, light in enumerate(desc["lights"]):
        data = bpy.data.lights.new(f"light_{i}", "AREA")
        data.shape, data.size, data.size_y = "RECTANGLE", *light["size"]
        # a normalised area light of power P and area A has radiance P / (pi A) (checked
        # with bpy 4.5 by rendering a light seen face on); the colour carries the ratios
        rad = np.asarray(light["radiance"], float)
        data.normalize, data.energy = True, float(math.pi * light["size"][0]
                                                  * light["size"][1] * rad.max())
        data.color = tuple(rad / rad.max())
        obj = bpy.data.objects.new(f"light_{i}", data)
        obj.matrix_world = [list(row) for row in np.asarray(light["matrix"]).T]
        obj.visible_camera = False  # camera rays look through the lights' rectangles
        sc.collection.objects.link(obj)
    cam = bpy.data.cameras.new("camera")
    cam.sensor_fit, cam.angle = "HORIZONTAL", math.radians(desc["camera"]["fov_x_deg"])
    cam.clip_start, cam.clip_end = 0.01, 100.0
    cobj = bpy.data.objects.new("camera", cam)
    cobj.matrix_world = [list(row) for row in np.asarray(desc["camera"]["matrix"]).T]
    sc.collection.objects.link(cobj)
    sc.camera = cobj
    textures = {k: root / v for k, v in desc["textures"].items()}
    skin = skin_material(textures, desc["skin"])
    for part in desc["parts"]:
        mat = skin if part["material"]["kind"] == "skin" else \
            part_material(part["name"], part["material"], root)
        import_part(root, part, mat)
    if desc.get("hair"):
        sc.cycles_curves.shape = "THICK"  # round 3-D curves, as Mitsuba's
        for spec in desc["hair"]:
            import_hair(root, spec)


def render(cmd: dict) -> dict:
    sc = bpy.context.scene
    sc.cycles.samples = int(cmd["spp"])
    sc.cycles.seed = int(cmd.get("seed", 0))
    sc.cycles.use_denoising = bool(cmd.get("denoise", False))
    w0, c0 = time.perf_counter(), time.process_time()
    bpy.ops.render.render()
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    if cmd.get("out"):
        bpy.data.images["Render Result"].save_render(str(cmd["out"]))
    return {"cpu_s": cpu, "wall_s": wall, "spp": sc.cycles.samples}


def main() -> None:
    root, fd = Path(sys.argv[-2]), int(sys.argv[-1])
    reply = os.fdopen(fd, "w", buffering=1)
    desc = json.loads((root / "scene.json").read_text())
    c0 = time.process_time()
    build(root, desc)
    warm = render({"spp": 1})
    reply.write(json.dumps({"ready": True, "version": bpy.app.version_string,
                            "build_cpu_s": time.process_time() - c0,
                            "warmup_cpu_s": warm["cpu_s"]}) + "\n")
    for line in sys.stdin:
        if line.strip():
            reply.write(json.dumps(render(json.loads(line))) + "\n")


if __name__ == "__main__":
    main()
