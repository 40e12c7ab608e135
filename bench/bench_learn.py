"""Benchmarks for issue 6 (not tests): personalise-once vs per-frame, trainers' cost.

    python bench/bench_learn.py            # all
    python bench/bench_learn.py personalise

Each trainer runs in a fresh subprocess so its peak resident memory (ru_maxrss) is its own.
Ratios come from one run on this machine (2 shared CPU cores, torch with 1 thread).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

from provenance import recorded  # bench/ is sys.path[0] when run as a script

TRAINERS = {
    "larynx (60 identities)": "from hack_render.learn.larynx_learn import learn_larynx; learn_larynx(a, num_identities=60, progress=False)",
    "expressions (DT 30 identities, M_E 300 epochs)": "from hack_render.learn.expression_learn import learn_expressions; learn_expressions(a, a['template_vertices'], a['shape_components'], num_identities=30, epochs=300, progress=False)",
    "pose (2 identities, 20 iterations)": "from hack_render.learn.full_model import learn_pose; learn_pose(a, num_identities=2, iterations=20, progress=False)",
    "joint regressor (40 meshes)": "import numpy as np; from hack_render.learn.joint_regressor import train_joint_regressor; v=a['template_vertices']; S=a['shape_components'][:10]*a['shape_std'][:10,None,None]; rng=np.random.default_rng(0); M=v[None]+np.einsum('ps,snc->pnc', rng.standard_normal((40,10)), S); J=np.einsum('kn,pnc->pkc', a['joint_regressor'], M); train_joint_regressor(M, J, candidates=np.arange(11248))",
}


def personalise() -> None:
    import torch

    from hack_render.geometry import load_default_model

    torch.set_num_threads(1)
    m = load_default_model()
    beta = torch.randn(1, m.num_shape)
    frames = 300
    psi = torch.rand(frames, m.num_expressions) * 0.3
    theta = torch.randn(frames, 8, 3) * 0.05
    tau = torch.linspace(0, 0.01, frames)
    eta = torch.ones(frames)
    with torch.no_grad():
        t = time.perf_counter()
        for i in range(frames):
            m(beta=beta, psi=psi[i:i + 1], theta=theta[i:i + 1], eta=eta[i:i + 1], tau=tau[i:i + 1])
        per_frame = time.perf_counter() - t
        t = time.perf_counter()
        p = m.personalize(beta)
        for i in range(frames):
            p(psi=psi[i:i + 1], theta=theta[i:i + 1], eta=eta[i:i + 1], tau=tau[i:i + 1])
        once = time.perf_counter() - t
    print(f"300-frame animation, one identity: per-frame personalisation {per_frame:.2f} s, "
          f"personalise once {once:.2f} s, speed-up {per_frame / once:.2f}x")


def trainers() -> None:
    for name, code in TRAINERS.items():
        prog = ("import time, resource, json, torch; torch.set_num_threads(1)\n"
                "from hack_render.geometry.model_file import load_model_file\n"
                "from hack_render.geometry import default_model_path\n"
                "a, _ = load_model_file(default_model_path())\n"
                "r0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
                f"t = time.perf_counter()\n{code}\n"
                "print(json.dumps({'s': time.perf_counter() - t, 'peak_mb': resource.getrusage("
                "resource.RUSAGE_SELF).ru_maxrss / 1024, 'loaded_mb': r0 / 1024}))")
        out = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True)
        if out.returncode:
            print(f"{name}: failed\n{out.stderr[-2000:]}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{name}: {r['s']:.1f} s wall, peak RSS {r['peak_mb']:.0f} MB "
              f"(model loaded: {r['loaded_mb']:.0f} MB)")


if __name__ == "__main__":
    # python bench/bench_learn.py [personalise] [trainers] [--out bench/results/learn.json]
    args = sys.argv[1:]
    out = None
    if "--out" in args:
        i = args.index("--out")
        out, args = args[i + 1], args[:i] + args[i + 2:]
    with recorded(out, "Learners"):
        for w in args or ["personalise", "trainers"]:
            {"personalise": personalise, "trainers": trainers}[w]()
