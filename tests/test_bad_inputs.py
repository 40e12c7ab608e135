"""Every bad input a clean answer (issue 29): exit code 2, one line naming the argument,
no traceback, and no file or folder left behind; and a fuzz of the parameter-file reader.

Each case runs `hack-render` in-process (``hack_render.cli.main``) in a fresh output
folder ``{o}`` that holds a folder ``d/``, a file ``file`` and a dataset folder with one
sample; inputs (parameter files, landmark files, training data) are in ``{i}``.

``python tests/test_bad_inputs.py`` runs the whole table and prints the issue's figures:
cases tried, clean exits, tracebacks, and exits 0 (each of which would be garbage
written, since every case is a bad input).
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from pathlib import Path

import numpy as np
import pytest

from hack_render.cli import main

# (id, arguments, text the one error line must contain: the argument's name)
CASES: list[tuple[str, str, str]] = [
    # --- mesh: output paths -------------------------------------------------------------
    ("mesh-out-is-dir", "mesh -o {o}/d", "-o/--output"),
    ("mesh-out-parent-is-file", "mesh -o {o}/file/x.obj", "-o/--output"),
    ("mesh-out-wrong-suffix", "mesh -o {o}/x.txt", "-o/--output"),
    ("mesh-out-no-suffix", "mesh -o {o}/x", "-o/--output"),
    ("mesh-both-target-is-dir", "mesh -o {o}/m.obj --both", "--both"),
    # --- mesh: numbers ----------------------------------------------------------------------
    ("mesh-beta-1e30", "mesh -o {o}/x.obj --beta 1e30", "--beta"),
    ("mesh-beta-nan", "mesh -o {o}/x.obj --beta 1,nan", "--beta"),
    ("mesh-beta-text", "mesh -o {o}/x.obj --beta abc", "--beta"),
    ("mesh-beta-empty-item", "mesh -o {o}/x.obj --beta 1,,2", "empty item"),
    ("mesh-beta-trailing-comma", "mesh -o {o}/x.obj --beta 1,2,", "empty item"),
    ("render-alpha-empty-item", "render -o {o}/x.png --alpha ,0.5", "--alpha"),
    ("mesh-tau-1e30", "mesh -o {o}/x.obj --tau 1e30", "--tau"),
    ("mesh-eta-1e30", "mesh -o {o}/x.obj --eta 1e30", "--eta"),
    ("mesh-eta-nan", "mesh -o {o}/x.obj --eta nan", "--eta"),
    ("mesh-eta-negative", "mesh -o {o}/x.obj --eta -1", "--eta"),
    ("mesh-head-rotation-1000-limits-error",
     "mesh -o {o}/x.obj --head-rotation 1000,0,0 --limits error", "--head-rotation"),
    ("mesh-head-rotation-beyond-neck-limits-error",
     "mesh -o {o}/x.obj --head-rotation 100,0,0 --limits error", "head rotation"),
    ("mesh-tau-beyond-limits-error", "mesh -o {o}/x.obj --tau 0.05 --limits error", "tau"),
    ("mesh-beta-implausible-limits-error", "mesh -o {o}/x.obj --beta 0,7 --limits error",
     "--beta"),
    ("turntable-head-rotation-limits-error",
     "turntable -o {o}/t --head-rotation 100,0,0 --limits error", "head rotation"),
    ("turntable-limits-unknown", "turntable -o {o}/t --limits maybe", "--limits"),
    ("render-tau-limits-error", "render -o {o}/x.png --tau 0.05 --limits error", "tau"),
    ("mesh-head-rotation-two-values", "mesh -o {o}/x.obj --head-rotation 1,2", "--head-rotation"),
    ("mesh-head-rotation-inf", "mesh -o {o}/x.obj --head-rotation inf,0,0", "--head-rotation"),
    ("mesh-expr-1e9", "mesh -o {o}/x.obj --expr AU12=1e9", "--expr"),
    ("mesh-expr-no-value", "mesh -o {o}/x.obj --expr AU12", "--expr"),
    ("mesh-expr-nan", "mesh -o {o}/x.obj --expr AU12=nan", "--expr"),
    ("mesh-expr-unknown-au", "mesh -o {o}/x.obj --expr AU99=0.5", "AU99"),
    ("mesh-limits-unknown", "mesh -o {o}/x.obj --limits sometimes", "--limits"),
    ("mesh-model-missing", "mesh -o {o}/x.obj --model {i}/none.npz", "--model"),
    ("mesh-unknown-option", "mesh -o {o}/x.obj --bogus", "--bogus"),
    # --- parameter files ------------------------------------------------------------------
    ("params-missing", "mesh -o {o}/x.obj --params {i}/none.json", "--params"),
    ("params-folder", "mesh -o {o}/x.obj --params {i}", "--params"),
    ("params-wrong-suffix", "mesh -o {o}/x.obj --params {i}/params.txt", "--params"),
    ("params-duplicate-key-json", "mesh -o {o}/x.obj --params {i}/dup.json", "duplicate key"),
    ("params-duplicate-key-yaml", "mesh -o {o}/x.obj --params {i}/dup.yaml", "duplicate key"),
    ("params-theta-string", "mesh -o {o}/x.obj --params {i}/theta_zero.json", "theta"),
    ("params-theta-ragged", "mesh -o {o}/x.obj --params {i}/ragged.json", "theta"),
    ("params-nan", "mesh -o {o}/x.obj --params {i}/nan.json", "beta"),
    ("params-beta-1e30", "mesh -o {o}/x.obj --params {i}/huge.json", "beta"),
    ("params-not-a-mapping", "mesh -o {o}/x.obj --params {i}/list.json", "mapping"),
    ("params-unknown-key", "mesh -o {o}/x.obj --params {i}/unknown.json", "unknown keys"),
    ("params-bad-json", "mesh -o {o}/x.obj --params {i}/broken.json", "not valid JSON"),
    ("params-bad-yaml", "mesh -o {o}/x.obj --params {i}/broken.yaml", "not valid YAML"),
    ("params-yaml-alias-bomb", "mesh -o {o}/x.obj --params {i}/bomb.yaml", "aliases"),
    ("params-huge-file", "mesh -o {o}/x.obj --params {i}/huge_file.json", "--params"),
    ("params-eta-string", "mesh -o {o}/x.obj --params {i}/eta_text.json", "eta"),
    ("params-expression-weight-text", "mesh -o {o}/x.obj --params {i}/expr_text.json",
     "expression"),
    ("params-binary", "mesh -o {o}/x.obj --params {i}/binary.json", "--params"),
    # --- render -----------------------------------------------------------------------------
    ("render-out-is-dir", "render -o {o}/d", "-o/--output"),
    ("render-out-jpg", "render -o {o}/x.jpg", "-o/--output"),
    ("render-out-parent-is-file", "render -o {o}/file/x.png", "-o/--output"),
    ("render-exr-not-exr", "render -o {o}/x.png --exr {o}/x.png", "--exr"),
    ("render-exposure-nan", "render -o {o}/x.png --exposure nan", "--exposure"),
    ("render-exposure-minus-1e6", "render -o {o}/x.png --exposure -1e6", "--exposure"),
    ("render-exposure-1e6", "render -o {o}/x.png --exposure 1e6", "--exposure"),
    ("render-env-rotation-inf", "render -o {o}/x.png --env-rotation inf", "--env-rotation"),
    ("render-iris-color-nan", "render -o {o}/x.png --iris-color nan,0,0", "--iris-color"),
    ("render-iris-color-two", "render -o {o}/x.png --iris-color 1,0", "--iris-color"),
    ("render-iris-color-above-1", "render -o {o}/x.png --iris-color 5,0,0", "--iris-color"),
    ("render-focal-1e9", "render -o {o}/x.png --focal-mm 1e9", "--focal-mm"),
    ("render-focal-0", "render -o {o}/x.png --focal-mm 0", "--focal-mm"),
    ("render-alpha-1e30", "render -o {o}/x.png --alpha 1e30", "--alpha"),
    ("render-beta-1e30", "render -o {o}/x.png --beta 1e30", "--beta"),
    ("render-resolution-0", "render -o {o}/x.png --resolution 0", "--resolution"),
    ("render-resolution-text", "render -o {o}/x.png --resolution big", "--resolution"),
    ("render-resolution-huge", "render -o {o}/x.png --resolution 100000", "--resolution"),
    ("render-spp-0", "render -o {o}/x.png --spp 0", "--spp"),
    ("render-spp-text", "render -o {o}/x.png --spp many", "--spp"),
    ("render-max-depth-0", "render -o {o}/x.png --max-depth 0", "--max-depth"),
    ("render-views-0", "render -o {o}/x.png --camera ring --views 0", "--views"),
    ("render-camera-unknown", "render -o {o}/x.png --camera fisheye", "--camera"),
    ("render-lighting-unknown", "render -o {o}/x.png --lighting disco", "--lighting"),
    ("render-lighting-env-missing", "render -o {o}/x.png --lighting env:{i}/none.exr",
     "--lighting"),
    ("render-tonemap-unknown", "render -o {o}/x.png --tonemap filmic", "--tonemap"),
    ("render-aov-unknown", "render -o {o}/x.exr --aov depth,colour", "--aov"),
    ("render-aov-without-exr", "render -o {o}/x.png --aov all", "--aov"),
    ("render-appearance-seed-negative", "render -o {o}/x.png --appearance-seed -1",
     "--appearance-seed"),
    ("render-limits-unknown", "render -o {o}/x.png --limits maybe", "--limits"),
    ("render-seed-negative", "render -o {o}/x.png --seed -4", "--seed"),
    # --- turntable --------------------------------------------------------------------------
    ("turntable-out-is-file", "turntable -o {o}/file", "-o/--output"),
    ("turntable-pitch-nan", "turntable -o {o}/t --pitch nan", "--pitch"),
    ("turntable-pitch-100", "turntable -o {o}/t --pitch 100", "--pitch"),
    ("turntable-frames-1", "turntable -o {o}/t --frames 1", "--frames"),
    ("turntable-frames-0", "turntable -o {o}/t --frames 0", "--frames"),
    ("turntable-frames-fraction", "turntable -o {o}/t --frames 1.5", "--frames"),
    ("turntable-fps-0", "turntable -o {o}/t --fps 0", "--fps"),
    ("turntable-mode-unknown", "turntable -o {o}/t --mode spin", "--mode"),
    ("turntable-formats-unknown", "turntable -o {o}/t --formats avi", "--formats"),
    ("turntable-odd-resolution-mp4", "turntable -o {o}/t --resolution 33", "--resolution"),
    ("turntable-sequence-suffix", "turntable -o {o}/t --sequence {o}/s.txt", "--sequence"),
    ("turntable-exposure-inf", "turntable -o {o}/t --exposure inf", "--exposure"),
    ("turntable-focal-nan", "turntable -o {o}/t --focal-mm nan", "--focal-mm"),
    ("turntable-beta-1e30", "turntable -o {o}/t --beta 1e30", "--beta"),
    ("turntable-spp-0", "turntable -o {o}/t --spp 0", "--spp"),
    # --- fit --------------------------------------------------------------------------------
    ("fit-photo-missing", "fit {i}/none.jpg -o {o}/f", "photo"),
    ("fit-iterations-0", "fit {i}/face.png -o {o}/f --iterations 0", "--iterations"),
    ("fit-iterations-negative", "fit {i}/face.png -o {o}/f --iterations -1", "--iterations"),
    ("fit-iterations-text", "fit {i}/face.png -o {o}/f --iterations a,b", "--iterations"),
    ("fit-iterations-count", "fit {i}/face.png -o {o}/f --levels 64 --iterations 4,4",
     "--iterations"),
    ("fit-levels-8", "fit {i}/face.png -o {o}/f --levels 8", "--levels"),
    ("fit-spp-0", "fit {i}/face.png -o {o}/f --spp 0", "--spp"),
    ("fit-detector-mesh", "fit {i}/face.png -o {o}/f --detector mesh", "--detector"),
    ("fit-focal-1", "fit {i}/face.png -o {o}/f --focal-mm 1", "--focal-mm"),
    ("fit-focal-nan", "fit {i}/face.png -o {o}/f --focal-mm nan", "--focal-mm"),
    ("fit-landmarks-3-columns", "fit {i}/face.png -o {o}/f --landmarks {i}/lm3.txt",
     "--landmarks"),
    ("fit-landmarks-empty-npy", "fit {i}/face.png -o {o}/f --landmarks {i}/empty.npy",
     "--landmarks"),
    ("fit-landmarks-3d-npy", "fit {i}/face.png -o {o}/f --landmarks {i}/lm3.npy",
     "--landmarks"),
    ("fit-landmarks-count", ("fit {i}/face.png -o {o}/f --landmarks {i}/lm3.txt "
     "--landmarks {i}/lm3.txt"), "--landmarks"),
    ("fit-landmarks-suffix", "fit {i}/face.png -o {o}/f --landmarks {i}/params.txt.bin",
     "--landmarks"),
    ("fit-out-is-file", "fit {i}/face.png -o {o}/file", "-o/--output"),
    ("fit-config-missing", "fit {i}/face.png -o {o}/f --config {i}/none.toml", "--config"),
    ("fit-mask-missing", "fit {i}/face.png -o {o}/f --mask {i}/none.png", "--mask"),
    # --- dataset ----------------------------------------------------------------------------
    ("dataset-n-0", "dataset --n 0 -o {o}/ds", "--n"),
    ("dataset-n-negative", "dataset --n -3 -o {o}/ds", "--n"),
    ("dataset-n-1e12", "dataset --n 1000000000000 -o {o}/ds", "--n"),
    ("dataset-n-1e12-sharded", "dataset --n 1000000000000 --shard 0/1000 -o {o}/ds", "--n"),
    ("dataset-n-missing", "dataset -o {o}/ds", "--n"),
    ("dataset-shard-k-ge-m", "dataset --n 3 --shard 3/2 -o {o}/ds", "--shard"),
    ("dataset-shard-empty", "dataset --n 3 --shard 5/10 -o {o}/ds", "--shard"),
    ("dataset-shard-text", "dataset --n 3 --shard a/b -o {o}/ds", "--shard"),
    ("dataset-executor-unknown", "dataset --n 3 --executor mpi -o {o}/ds", "--executor"),
    ("dataset-workers-0", "dataset --n 3 --workers 0 -o {o}/ds", "--workers"),
    ("dataset-seed-negative", "dataset --n 3 --seed -1 -o {o}/ds", "--seed"),
    ("dataset-config-missing", "dataset --n 3 --config {i}/none.yaml -o {o}/ds", "--config"),
    ("dataset-config-bad-key", "dataset --n 3 --config {i}/ds_bad.yaml -o {o}/ds",
     "config key"),
    ("dataset-config-duplicate-key", "dataset --n 3 --config {i}/dup.yaml -o {o}/ds",
     "duplicate key"),
    ("dataset-config-broken", "dataset --n 3 --config {i}/broken.yaml -o {o}/ds", "--config"),
    ("dataset-out-is-file", "dataset --n 3 -o {o}/file", "-o/--output"),
    ("dataset-rerun-without-resume", ("dataset --n 1 -o {o}/ds_existing --config "
     "{i}/ds_tiny.yaml"), "--resume"),
    ("dataset-preview-missing", "dataset preview {i}/none", "FOLDER"),
    ("dataset-preview-count-0", "dataset preview {o}/ds_existing --count 0", "--count"),
    # --- appearance -------------------------------------------------------------------------
    ("appearance-sample-components-0", "appearance sample -o {o}/s --components 0",
     "--components"),
    ("appearance-sample-detail-negative", "appearance sample -o {o}/s --detail -1",
     "--detail"),
    ("appearance-sample-alpha-nan", "appearance sample -o {o}/s --alpha nan", "--alpha"),
    ("appearance-sample-alpha-and-seed", "appearance sample -o {o}/s --alpha 1 --seed 2",
     "--alpha or --seed"),
    ("appearance-sample-format", "appearance sample -o {o}/s --format tiff", "--format"),
    ("appearance-sample-out-is-file", "appearance sample -o {o}/file", "-o/--output"),
    ("appearance-sample-no-output", "appearance sample", "-o/--output"),
    ("appearance-build-components-0", "learn appearance {i} -o {o}/a.npz --components 0",
     "--components"),
    ("appearance-build-holdout-1.5", "learn appearance {i} -o {o}/a.npz --holdout 1.5",
     "--holdout"),
    ("appearance-build-data-missing", "learn appearance {i}/none -o {o}/a.npz", "DATA"),
    ("appearance-build-out-suffix", "learn appearance {i} -o {o}/a.txt", "-o/--output"),
    ("appearance-report-missing", "appearance report {i}/none.npz", "MODEL"),
    # --- model, learn -----------------------------------------------------------------------
    ("model-info-missing", "model info {i}/none.npz", "MODEL"),
    ("model-report-out-is-file", "model report -o {o}/file", "-o/--output"),
    ("learn-joints-missing", "learn joints {i}/none.npz -o {o}/j.npy", "DATA"),
    ("learn-joints-out-suffix", "learn joints {i}/joints.npz -o {o}/j.txt", "-o/--output"),
    ("learn-joints-out-is-dir", "learn joints {i}/joints.npz -o {o}/d", "-o/--output"),
    ("learn-joints-wrong-shape", "learn joints {i}/joints_shape.npz -o {o}/j.npy", "joints"),
    ("learn-joints-nan", "learn joints {i}/joints_nan.npz -o {o}/j.npy", "NaN"),
    ("learn-joints-single-pair", "learn joints {i}/joints_one.npz -o {o}/j.npy", "P >= 2"),
    ("learn-joints-text-file", "learn joints {i}/joints_text.npz -o {o}/j.npy",
     "could not read"),
    ("learn-joints-pickled", "learn joints {i}/joints_pickle.npz -o {o}/j.npy",
     "could not read"),
    ("learn-joints-missing-key", "learn joints {i}/joints_key.npz -o {o}/j.npy",
     "expected keys"),
    ("learn-joints-slab-0", "learn joints {i}/joints.npz -o {o}/j.npy --slab 0", "--slab"),
    ("learn-pose-out-suffix", "learn pose -o {o}/m.txt", "-o/--output"),
    ("learn-pose-iterations-0", "learn pose -o {o}/m.npz --iterations 0", "--iterations"),
    ("learn-pose-loss-unknown", "learn pose -o {o}/m.npz --loss wrose=3", "--loss"),
    ("learn-pose-loss-not-a-number", "learn pose -o {o}/m.npz --loss fold_sum=x", "--loss"),
    ("learn-pose-loss-cosine-above-1", "learn pose -o {o}/m.npz --loss near_fold=2", "near_fold"),
    ("learn-pose-hard-negative", "learn pose -o {o}/m.npz --hard-examples -1", "--hard-examples"),
    ("learn-pose-corner-above-1", "learn pose -o {o}/m.npz --corner-poses 1.5", "--corner-poses"),
    ("learn-model-ict-missing", "learn model --ict {i}/none -o {o}/m.npz", "--ict"),
    ("learn-base-model-ict-missing", "learn base-model --ict {i}/none -o {o}/m.npz", "--ict"),
    ("learn-embedding-out-suffix", "learn landmark-embedding -o {o}/e.txt", "-o/--output"),
    ("learn-embedding-spp-0", "learn landmark-embedding -o {o}/e.npz --spp 0", "--spp"),
    ("learn-refiner-out-suffix", "learn landmark-refiner -o {o}/r.txt", "-o/--output"),
    ("learn-refiner-cache-is-file", "learn landmark-refiner -o {o}/r.npz --cache {o}/file",
     "--cache"),
    ("learn-template-ict-missing", "learn template --ict {i}/none -o {o}/t.npz", "--ict"),
    # --- export, view -----------------------------------------------------------------------
    ("export-out-fbx", "export -o {o}/p.fbx", "-o/--output"),
    ("export-out-is-dir", "export -o {o}/d", "-o/--output"),
    ("export-out-parent-is-file", "export -o {o}/file/p.glb", "-o/--output"),
    ("export-beta-inf", "export -o {o}/p.glb --beta inf", "--beta"),
    ("export-alpha-nan", "export -o {o}/p.glb --alpha nan", "--alpha"),
    ("export-tau-limits-error", "export -o {o}/p.glb --tau 0.05 --limits error", "tau"),
    ("export-limits-unknown", "export -o {o}/p.glb --limits maybe", "--limits"),
    ("export-influences-3", "export -o {o}/p.glb --influences 3", "--influences"),
    ("export-sequence-missing", "export -o {o}/p.glb --sequence {i}/none.npz", "--sequence"),
    ("export-sequence-with-obj", "export -o {o}/p.obj --sequence {i}/none.npz", "--sequence"),
    ("export-sequence-duplicate-key", "export -o {o}/p.glb --sequence {i}/dup.jsonl",
     "duplicate key"),
    ("export-params-duplicate-key", "export -o {o}/p.glb --params {i}/dup.json",
     "duplicate key"),
    ("view-missing", "view {i}/none.glb --no-open", "FILE"),
    ("view-wrong-suffix", "view {i}/params.txt --no-open", "FILE"),
    ("view-port-70000", "view {i}/person.glb --no-open --port 70000", "--port"),
]


# inputs that are files of the wrong kind (a model, a photo, a texture folder, a config)
CASES += [
    ("preview-folder-without-samples", "dataset preview {o}/d", "/d"),
    ("appearance-report-not-a-model", "appearance report {i}/joints.npz", "joints.npz"),
    ("model-info-not-a-model", "model info {i}/joints.npz", "joints.npz"),
    ("render-textures-missing", "render -o {o}/x.png --textures {i}/none", "--textures"),
    ("render-textures-empty", "render -o {o}/x.png --textures {o}/d", "--textures"),
    ("export-textures-missing", "export -o {o}/p.glb --textures {i}/none", "--textures"),
    ("fit-photo-is-text", "fit {i}/params.txt -o {o}/f", "params.txt"),
    ("fit-photo-is-dir", "fit {i} -o {o}/f", "photo"),
    ("fit-config-unknown-key", "fit {i}/face.png -o {o}/f --config {i}/fit_unknown.json",
     "bta"),
    ("fit-config-duplicate-key", "fit {i}/face.png -o {o}/f --config {i}/fit_dup.json",
     "duplicate key"),
    ("fit-light-model-unknown", "fit {i}/face.png -o {o}/f --light-model laser", "laser"),
    ("turntable-sequence-is-dir", "turntable -o {o}/t --sequence {o}/d", "--sequence"),
    ("learn-template-not-obj", "learn template --ict {i}/params.txt -o {o}/t.npz",
     "params.txt"),
    ("export-sequence-not-a-sequence", "export -o {o}/p.glb --sequence {i}/joints.npz",
     "joints.npz"),
    ("appearance-sample-model-missing",
     "appearance sample -o {o}/s --appearance-model {i}/none.npz", "none.npz"),
    ("appearance-sample-not-a-model",
     "appearance sample -o {o}/s --appearance-model {i}/joints.npz", "joints.npz"),
    ("render-model-not-a-model", "render -o {o}/x.png --model {i}/joints.npz", "joints.npz"),
    ("mesh-model-not-readable", "mesh -o {o}/x.obj --model {i}/joints_text.npz",
     "joints_text.npz"),
    ("learn-pose-model-not-a-model", "learn pose --model {i}/joints.npz -o {o}/m.npz",
     "joints.npz"),
    ("learn-appearance-no-subjects", "learn appearance {o}/d -o {o}/a.npz", "subject"),
    ("dataset-config-preset-null", "dataset --n 2 --config {i}/ds_null.yaml -o {o}/ds",
     "lighting.presets"),
    ("dataset-config-not-a-mapping", "dataset --n 2 --config {i}/list.json -o {o}/ds",
     "--config"),
    ("learn-refiner-holdout-0.9", "learn landmark-refiner -o {o}/r.npz --holdout 0.9",
     "--holdout"),
    ("learn-refiner-subjects-5", "learn landmark-refiner -o {o}/r.npz --subjects 5",
     "--subjects"),
    ("learn-embedding-subjects-0", "learn landmark-embedding -o {o}/e.npz --subjects 0",
     "--subjects"),
]

# commands added by the other open issues (register, transfer, drive, learn shape and the
# motion learners): their own checks, held to the same standard here
CASES += [
    ("register-scan-missing", "register {i}/none.ply -o {o}/r", "none.ply"),
    ("register-preset-unknown", "register {i}/scan.ply -o {o}/r --preset fast", "--preset"),
    ("register-shape-components-0", "register {i}/scan.ply -o {o}/r --shape-components 0",
     "--shape-components"),
    ("register-texture-size-0", "register {i}/scan.ply -o {o}/r --texture-size 0",
     "--texture-size"),
    ("register-shard-k-ge-m", "register {i}/scan.ply -o {o}/r --shard 3/2", "--shard"),
    ("register-landmarks-missing", "register {i}/scan.ply -o {o}/r --landmarks {i}/none.json",
     "--landmarks"),
    ("transfer-target-unknown", ("transfer --motion {i}/seq.npz --target procedural:giraffe "
     "-o {o}/t"), "--target"),
    ("transfer-influences-3", ("transfer --motion {i}/seq.npz --target procedural:long-neck "
     "-o {o}/t --influences 3"), "--influences"),
    ("transfer-frames-0", ("transfer --motion {i}/seq.npz --target procedural:long-neck "
     "-o {o}/t --frames 0"), "--frames"),
    ("learn-head-to-neck-one-sequence", "learn head-to-neck {i}/seq.npz -o {o}/h.npz",
     "SEQUENCES"),
    ("learn-larynx-motion-held-out", "learn larynx-motion {i}/seq.npz -o {o}/l.npz",
     "--held-out"),
    ("learn-shape-too-few", "learn shape {i}/scan.ply -o {o}/s.npz", "registrations"),
    ("learn-shape-out-suffix", ("learn shape {i}/scan.ply {i}/scan.ply {i}/scan.ply "
     "-o {o}/s.txt"), "-o"),
    ("learn-shape-components-0", "learn shape {i}/scan.ply -o {o}/s.npz --components 0",
     "--components"),
]

CASES += [    ("register-out-is-file", "register {i}/scan.ply -o {o}/file", "-o/--output"),
    ("register-units-unknown", "register {i}/scan.ply -o {o}/r --units inch", "--units"),
    ("register-not-a-scan", "register {i}/params.txt -o {o}/r", "params.txt"),
    ("transfer-motion-missing", ("transfer --motion {i}/none.npz --target "
     "procedural:long-neck -o {o}/t"), "--motion"),
    ("transfer-out-is-file", ("transfer --motion {i}/seq.npz --target procedural:long-neck "
     "-o {o}/file"), "-o/--output"),
    ("transfer-spp-0", ("transfer --motion {i}/seq.npz --target procedural:long-neck "
     "-o {o}/t --spp 0"), "--spp"),
    ("drive-capture-missing", "drive {i}/none.csv -o {o}/s.npz", "none.csv"),
    ("drive-out-suffix", "drive {i}/cap.csv -o {o}/s.txt", "-o/--output"),
    ("drive-out-is-dir", "drive {i}/cap.csv -o {o}/d", "-o/--output"),
    ("drive-fps-0", "drive {i}/cap.csv -o {o}/s.npz --fps 0", "--fps"),
    ("drive-fps-nan", "drive {i}/cap.csv -o {o}/s.npz --fps nan", "--fps"),
    ("drive-limits-unknown", "drive {i}/cap.csv -o {o}/s.npz --limits maybe", "--limits"),
    ("drive-not-a-capture", "drive {i}/params.txt -o {o}/s.npz", "params.txt"),
    ("drive-empty-csv", "drive {i}/empty.csv -o {o}/s.npz", "empty.csv"),
    ("drive-model-missing", "drive {i}/cap.csv -o {o}/s.npz --model {i}/none.npz",
     "none.npz"),
]

# issue 65: the last bad inputs
CASES += [
    ("mesh-out-trailing-slash", "mesh -o {o}/x.obj/", "-o/--output"),
    ("render-out-trailing-slash", "render -o {o}/x.png/", "-o/--output"),
    ("export-out-trailing-slash", "export -o {o}/p.glb/", "-o/--output"),
    ("render-resolution-trailing-x", "render -o {o}/x.png --resolution 64x", "--resolution"),
    ("render-resolution-leading-x", "render -o {o}/x.png --resolution x64", "--resolution"),
    ("turntable-resolution-three-sides", "turntable -o {o}/t --resolution 64x64x",
     "--resolution"),
    ("params-beta-booleans", "mesh -o {o}/x.obj --params {i}/bools.json", "beta"),
    ("params-theta-text-inside", "mesh -o {o}/x.obj --params {i}/theta_text.json", "theta"),
    ("params-null", "mesh -o {o}/x.obj --params {i}/null.json", "--params"),
    ("params-null-yaml", "mesh -o {o}/x.obj --params {i}/null.yaml", "--params"),
    ("view-empty-glb", "view {i}/empty.glb --no-open", "empty.glb"),
    ("view-cut-glb", "view {i}/cut.glb --no-open", "cut.glb"),
    ("view-text-as-glb", "view {i}/person.glb --no-open", "person.glb"),
    ("view-glb-without-asset", "view {i}/noasset.glb --no-open", "noasset.glb"),
    ("view-gltf-without-its-bin", "view {i}/lonely.gltf --no-open", "lonely.gltf"),
    ("register-obj-cut-short", "register {i}/cut.obj -o {o}/r", "cut.obj:"),
]


def _glb(doc: dict, binary: bytes = b"") -> bytes:
    """A .glb of a JSON document and a BIN chunk (each padded to 4 bytes)."""
    import struct

    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def make_inputs(folder: Path) -> Path:
    """The input files the cases name as ``{i}/...``."""
    import imageio.v3 as iio

    folder.mkdir(parents=True, exist_ok=True)
    files = {
        "params.txt": "beta: [1]\n",
        "params.txt.bin": "1 2\n",
        "dup.json": '{"beta": [1.0], "beta": [2.0]}',
        "dup.yaml": "beta: [1.0]\neta: 1.0\nbeta: [2.0]\n",
        "theta_zero.json": json.dumps({"theta": "zero"}),
        "ragged.json": json.dumps({"theta": [[0, 0, 0], [0, 0]]}),
        "nan.json": '{"beta": [NaN]}',
        "huge.json": json.dumps({"beta": [1e30]}),
        "list.json": "[1, 2]",
        "unknown.json": json.dumps({"bta": [1.0]}),
        "broken.json": "{",
        "broken.yaml": "beta: [1, 2\n",
        "eta_text.json": json.dumps({"eta": "big"}),
        "fit_unknown.json": json.dumps({"bta": 1}),
        "fit_dup.json": '{"seed": 1, "seed": 2}',
        "dup.jsonl": '{"format": "hack-sequence", "fps": 24}\n{"tau": 0.0, "tau": 0.01}\n',
        "bomb.yaml": "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\nb: &b [*a, *a, *a, *a, *a, *a, *a]\n"
                     "psi: [*b, *b, *b, *b, *b, *b, *b, *b]\n",
        "expr_text.json": json.dumps({"expression": {"AU12": "lots"}}),
        "lm3.txt": "\n".join("1 2 3" for _ in range(68)) + "\n",
        "ds_bad.yaml": "camera: {yaw: [0, 1]}\n",
        "ds_null.yaml": "lighting: {presets: [null]}\n",
        "ds_tiny.yaml": "render: {resolution: 16, spp: 1, soft_mask_samples: 0}\n"
                        "appearance: {height: 16, source: constant}\n"
                        "lighting: {presets: [studio]}\n",
        "joints_text.npz": "meshes, joints\n1, 2\n",
        "person.glb": "not really a glb",
        "bools.json": json.dumps({"beta": [True, False]}),
        "theta_text.json": json.dumps({"theta": [[0, 0, "1"]] + [[0, 0, 0]] * 7}),
        "null.json": "null\n",
        "null.yaml": "~\n",
        "lonely.gltf": json.dumps({"asset": {"version": "2.0"},
                                   "buffers": [{"byteLength": 8, "uri": "lonely.bin"}]}),
    }
    for name, text in files.items():
        (folder / name).write_text(text)
    (folder / "binary.json").write_bytes(b"\xff\xfe\x00\x81 binary")
    (folder / "empty.glb").write_bytes(b"")
    whole = _glb({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 8}]}, bytes(8))
    (folder / "cut.glb").write_bytes(whole[:len(whole) - 6])
    (folder / "noasset.glb").write_bytes(_glb({"buffers": []}))
    grid = [f"v {x} {y} 0" for y in range(11) for x in range(11)]  # a 121-vertex scan...
    grid += [f"f {k + 1} {k + 2} {k + 13}" for k in range(108) if (k + 1) % 11]
    (folder / "cut.obj").write_text("\n".join(grid)[:-4])  # ...cut inside its last face
    (folder / "empty.npy").write_bytes(b"")
    with open(folder / "huge_file.json", "wb") as f:  # sparse: no disk used
        f.truncate(20 * 1024 * 1024)
    np.save(folder / "lm3.npy", np.zeros((68, 3)))
    (folder / "scan.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    np.savez(folder / "seq.npz", fps=24.0, theta=np.zeros((3, 8, 3)))
    (folder / "cap.csv").write_text("Timecode,BlendShapeCount,EyeBlinkLeft\n"
                                    "00:00:00:00.000,52,0.1\n")
    (folder / "empty.csv").write_text("")
    iio.imwrite(folder / "face.png", np.full((48, 48, 3), 128, np.uint8))
    rng = np.random.default_rng(0)
    meshes = rng.normal(size=(3, 50, 3)) * 0.05
    joints = rng.normal(size=(3, 8, 3)) * 0.05
    np.savez(folder / "joints.npz", meshes=meshes, joints=joints)
    np.savez(folder / "joints_shape.npz", meshes=meshes, joints=joints[:, :5])
    np.savez(folder / "joints_nan.npz", meshes=meshes, joints=np.full_like(joints, np.nan))
    np.savez(folder / "joints_one.npz", meshes=meshes[:1], joints=joints[:1])
    np.savez(folder / "joints_key.npz", mesh=meshes, joints=joints)
    np.savez(folder / "joints_pickle.npz", meshes=np.array([{"a": 1}], dtype=object),
             joints=joints)
    return folder


def make_output_folder(folder: Path) -> Path:
    """The case's output folder: ``d/``, ``file``, a mesh target whose .ply twin is a
    folder, and a dataset folder holding one sample."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "d").mkdir()
    (folder / "file").write_text("x")
    (folder / "m.ply").mkdir()
    (folder / "ds_existing" / "samples" / "0000000").mkdir(parents=True)
    return folder


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every file (bytes) and folder (None) under ``folder``."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def stamps(folder: Path) -> dict[str, tuple[int, int]]:
    """Size and modification time of every file under ``folder`` (the inputs: cheap)."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*"))}


def run_case(args: str, i: Path, o: Path, capsys) -> tuple[object, str]:
    """(exit code, or the exception that escaped, and stderr) of one case."""
    argv = args.format(i=i, o=o).split()
    saved, sys.argv = sys.argv, ["hack-render", *argv]  # as the console script sees them
    try:
        main(argv)
        code: object = 0
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:  # noqa: BLE001 - a traceback is what the table counts
        code = exc
        traceback.print_exc()
    finally:
        sys.argv = saved
    return code, capsys.readouterr().err


def error_lines(err: str) -> list[str]:
    """The error lines of stderr (ours: ``error: ...``; Click's usage errors: ``Error:``)."""
    return [ln for ln in err.splitlines() if ln.lstrip(" │").startswith(("error:", "Error:"))]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    return make_inputs(tmp_path_factory.mktemp("bad_inputs"))


@pytest.mark.parametrize("case, args, names", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_a_clean_answer(case, args, names, inputs, tmp_path, capsys):
    out = make_output_folder(tmp_path / "o")
    before, before_in = snapshot(out), stamps(inputs)
    code, err = run_case(args, inputs, out, capsys)
    assert code == 2, f"{case}: exit {code!r}\n{err[-3000:]}"
    assert "Traceback" not in err, err
    lines = error_lines(err)
    assert len(lines) == 1, f"{case}: expected one error line, found {lines}\n{err}"
    assert names in lines[0], f"{case}: {names!r} not in {lines[0]!r}"
    assert snapshot(out) == before, f"{case}: files left behind"
    assert stamps(inputs) == before_in, f"{case}: an input was changed"


def test_the_table_is_large_enough():
    """Every family of the issue, and at least 60 more cases."""
    assert len(CASES) >= 60 + 30 and len({c[0] for c in CASES}) == len(CASES)


def test_missing_parents_are_created(tmp_path, capsys):
    """Not a bad input: an output whose folders do not exist yet is written there."""
    code, err = run_case("mesh -o {o}/new/sub/x.obj", tmp_path, tmp_path, capsys)
    assert code == 0 and (tmp_path / "new" / "sub" / "x.obj").stat().st_size > 1000, err


@pytest.mark.parametrize("args", ["mesh -o {o}/imm/x.obj", "turntable -o {o}/imm/t",
                                  "dataset --n 2 -o {o}/imm/ds",
                                  "learn joints {i}/joints.npz -o {o}/imm/j.npy"],
                         ids=["mesh", "turntable", "dataset", "learn-joints"])
def test_immutable_output_folder_is_refused_before_the_work(inputs, tmp_path, capsys, args):
    """chattr +i: not even root writes there (the issue's immutable folder)."""
    import shutil
    import subprocess

    imm = tmp_path / "imm"
    imm.mkdir()
    if shutil.which("chattr") is None or subprocess.run(
            ["chattr", "+i", str(imm)], check=False, capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not available here")
    try:
        code, err = run_case(args, inputs, tmp_path, capsys)
    finally:
        subprocess.run(["chattr", "-i", str(imm)], check=True)
    lines = error_lines(err)
    assert code == 2 and len(lines) == 1 and "not writable" in lines[0], err
    assert "-o/--output" in lines[0] and not list(imm.iterdir())


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder_is_refused_before_the_work(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, err = run_case("mesh -o {o}/ro/x.obj", tmp_path, tmp_path, capsys)
    finally:
        ro.chmod(0o755)
    assert code == 2 and "not writable" in err and not list(ro.iterdir())


# --- the parameter-file reader, fuzzed ------------------------------------------------------
try:
    import hypothesis
    from hypothesis import strategies as st
except ImportError:  # the test extra installs it; the table above runs without
    hypothesis = None


if hypothesis is not None:
    _scalars = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 30, 10 ** 30),
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5))
    _values = st.recursive(_scalars, lambda kids: st.one_of(
        st.lists(kids, max_size=9), st.dictionaries(st.text(max_size=6), kids, max_size=4)),
        max_leaves=30)
    _keys = st.one_of(st.sampled_from(["beta", "psi", "expression", "head_rotation_deg",
                                       "theta", "global_orient", "transl", "eta", "tau"]),
                      st.text(max_size=8))


    @hypothesis.settings(max_examples=300, deadline=None, derandomize=True)
    @hypothesis.given(data=st.dictionaries(_keys, _values, max_size=5))
    def test_fuzz_parameter_mapping_never_raises_anything_but_hack_error(data):
        from hack_render.errors import HackError
        from hack_render.geometry.params import check_params

        try:
            out = check_params(data, "fuzz")
        except HackError as err:
            assert "\n" not in str(err)
            return
        # accepted: every value is finite and inside its bound, lists have the right shapes
        json.dumps(out, allow_nan=False)
        if "theta" in out:
            assert np.asarray(out["theta"]).shape == (8, 3)


    @hypothesis.settings(max_examples=300, deadline=None, derandomize=True)
    @hypothesis.given(text=st.one_of(st.text(max_size=60), st.binary(max_size=60).map(
        lambda b: b.decode("latin-1"))), suffix=st.sampled_from([".json", ".yaml"]))
    def test_fuzz_parameter_file_text_never_raises_anything_but_hack_error(text, suffix):
        from hack_render.errors import HackError
        from hack_render.geometry.params import check_params, parse_params_text

        try:
            data = parse_params_text(text, suffix, "fuzz" + suffix)
            check_params({} if data is None else data, "fuzz" + suffix)
        except HackError:
            pass


if hypothesis is not None:
    _flag_text = st.one_of(st.none(), st.text(max_size=30), st.lists(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.sampled_from(["AU12=0.5", "jawOpen=1e9", "=", "nan", "x=nan", ""])),
        max_size=5).map(",".join))
    _flag_number = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True))

    @hypothesis.settings(max_examples=400, deadline=None, derandomize=True)
    @hypothesis.given(beta=_flag_text, expression=_flag_text, head=_flag_text,
                      eta=_flag_number, tau=_flag_number)
    def test_fuzz_pose_flags_never_raise_anything_but_hack_error(beta, expression, head, eta,
                                                                 tau):
        """The flags of mesh/render/turntable/export: a clean refusal or finite values
        inside their bounds, whatever the text."""
        from hack_render.errors import HackError
        from hack_render.geometry.params import check_flags, check_params

        try:
            flags = check_flags(beta, expression, head, eta, tau)
        except HackError as err:
            assert "\n" not in str(err)
            return
        out = check_params({k: v for k, v in flags.items() if v is not None}, "flags")
        json.dumps(out, allow_nan=False)


if hypothesis is not None:
    def _config_sections():
        from hack_render.dataset.config import DEFAULTS

        leaf = st.recursive(_scalars, lambda kids: st.one_of(
            st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=5), kids,
                                                        max_size=3)), max_leaves=10)
        return st.fixed_dictionaries({}, optional={
            name: st.dictionaries(st.sampled_from(list(keys)), leaf, max_size=3)
            for name, keys in DEFAULTS.items()})

    @hypothesis.settings(max_examples=300, deadline=None, derandomize=True)
    @hypothesis.given(overrides=_config_sections())
    def test_fuzz_dataset_config_never_raises_anything_but_hack_error(overrides):
        """Any values under the config's own keys: refused naming the key, or a config
        whose ranges are finite (found: `lighting.presets: [null]` was a traceback)."""
        from hack_render.dataset.config import load_config
        from hack_render.errors import HackError

        try:
            cfg = load_config(None, overrides)
        except HackError as err:
            assert "config key" in str(err) or "--config" in str(err), err
            return
        json.dumps(cfg, allow_nan=False)


def _figures() -> None:  # pragma: no cover - `python tests/test_bad_inputs.py`
    """Run the table outside pytest and print the issue's figures."""
    import contextlib
    import io
    import tempfile

    class Capture:
        def __init__(self):
            self.buf = io.StringIO()

        def readouterr(self):
            text, self.buf = self.buf.getvalue(), io.StringIO()
            return type("R", (), {"err": text})

    tally = {"tried": 0, "clean": 0, "traceback": 0, "exit0": 0, "other": 0}
    with tempfile.TemporaryDirectory() as tmp:
        i = make_inputs(Path(tmp) / "i")
        for n, (case, args, names) in enumerate(CASES):
            o = make_output_folder(Path(tmp) / f"o{n}")
            before, cap = snapshot(o), Capture()
            with contextlib.redirect_stderr(cap.buf), contextlib.redirect_stdout(io.StringIO()):
                code, err = run_case(args, i, o, cap)
            lines = error_lines(err)
            tally["tried"] += 1
            if isinstance(code, BaseException) or "Traceback" in err:
                kind = "traceback"
            elif code == 0:
                kind = "exit0"
            elif (code == 2 and len(lines) == 1 and names in lines[0]
                  and snapshot(o) == before):
                kind = "clean"
            else:
                kind = "other"
            tally[kind] += 1
            if kind != "clean":
                print(f"{kind}: {case}: exit {code!r}: {err.strip().splitlines()[-1:]}")
    print(json.dumps(tally))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_figures())


@pytest.mark.parametrize("over", [{"background": {"photos": [[]]}},
                                  {"background": {"source": ["studio"]}}])
def test_background_values_of_the_wrong_type_name_the_key(over):
    """Found by the fuzz test above: a list inside background.photos (or a list as the
    source) was a TypeError (unhashable) instead of an error naming the key."""
    from hack_render.dataset.config import load_config
    from hack_render.errors import HackError

    key = next(iter(over["background"]))
    with pytest.raises(HackError, match=f"background.{key}"):
        load_config(None, over)


def test_a_folders_spelling_is_refused_for_a_file_output(tmp_path, monkeypatch):
    """`-o x.obj/` wrote x.obj (issue 65): the slash names a folder. A Path has lost it by
    the time a command sees it, so the words typed are looked at; a string keeps it."""
    from hack_render import boundary
    from hack_render.errors import HackError

    target = tmp_path / "x.obj"
    with pytest.raises(HackError, match="expected a file name, found a folder's"):
        boundary.output_file(f"{target}/", "-o/--output", (".obj",))
    for typed in (["-o", f"{target}/"], [f"--output={target}/"], [f"-o{target}/"]):
        monkeypatch.setattr(sys, "argv", ["hack-render", "mesh", *typed])
        with pytest.raises(HackError, match=r"-o/--output .*x\.obj/: expected a file name"):
            boundary.output_file(target, "-o/--output", (".obj",))
    monkeypatch.setattr(sys, "argv", ["hack-render", "mesh", "-o", str(target)])
    assert boundary.output_file(target, "-o/--output", (".obj",)) == target
    assert not target.exists()
    try:  # an in-process caller of main(argv) hands its words over
        boundary.set_command_words(["mesh", "-o", f"{target}/"])
        with pytest.raises(HackError, match="x.obj/: expected a file name"):
            boundary.output_file(target, "-o/--output", (".obj",))
    finally:
        boundary.set_command_words(None)
