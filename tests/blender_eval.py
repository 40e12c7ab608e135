"""Run with a Python that has `bpy` (pip install '.[blender]'): import a glTF with Blender's
own importer, evaluate a frame (armature, shape keys, animation) and save the vertices in
glTF axes (Y up) with their `_HACK_VERTEX` index.

Usage: python tests/blender_eval.py FILE.glb FPS FRAME|rest OUT.npz
"""

import sys

import bpy
import numpy as np

path, fps, frame, out = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = round(fps), round(fps) / fps  # frame k = time k / fps
bpy.ops.import_scene.gltf(filepath=path)
if frame != "rest":
    scene.frame_set(int(frame))
else:  # the file's default state: no action on the armature or the shape keys
    for ob in scene.objects:
        if ob.animation_data:
            ob.animation_data.action = None
        data = getattr(ob, "data", None)
        keys = getattr(data, "shape_keys", None)
        if keys is not None and keys.animation_data:
            keys.animation_data.action = None
    scene.frame_set(0)
depsgraph = bpy.context.evaluated_depsgraph_get()
meshes = [ob for ob in scene.objects  # (the importer adds an Icosphere to draw the bones)
          if ob.type == "MESH" and "_HACK_VERTEX" in ob.data.attributes]
assert len(meshes) == 1, [ob.name for ob in meshes]
ob = meshes[0].evaluated_get(depsgraph)
me = ob.to_mesh()
co = np.zeros(len(me.vertices) * 3)
me.vertices.foreach_get("co", co)
co = co.reshape(-1, 3)
mw = np.array(ob.matrix_world)
world = co @ mw[:3, :3].T + mw[:3, 3]
idx = np.zeros(len(me.vertices))
me.attributes["_HACK_VERTEX"].data.foreach_get("value", idx)
gltf_axes = np.stack([world[:, 0], world[:, 2], -world[:, 1]], 1)  # Blender Z up -> glTF Y up
np.savez(out, vertices=gltf_axes, index=idx.astype(np.int64),
         shape_keys=len(meshes[0].data.shape_keys.key_blocks) if meshes[0].data.shape_keys else 0)
print("blender", bpy.app.version_string, len(idx), "vertices")
