"""Threads (issue 65): the OpenMP wait policy is set before torch loads and a user's own
value wins; ``--threads`` reaches torch, Dr.Jit and OIDN; every long command takes it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from hack_render import threads
from hack_render.errors import HackError

# records the wait policy in the environment at the moment torch's import begins
_SPY = """
import json, os, sys
seen = {}
class Spy:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" and "torch" not in seen:
            seen["torch"] = os.environ.get("OMP_WAIT_POLICY")
        return None
sys.meta_path.insert(0, Spy())
import %s
print(json.dumps({"at_torch": seen.get("torch", "not imported"),
                  "now": os.environ.get("OMP_WAIT_POLICY")}))
"""


def _python(code: str, **env) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items()
            if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS", "OIDN_NUM_THREADS")}
    return subprocess.run([sys.executable, "-c", code], env={**base, **env}, check=False,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("module", ["hack_render.geometry.model", "appearance.model"])
def test_wait_policy_is_passive_before_torch_loads(module):
    res = _python(_SPY % module)
    assert res.returncode == 0, res.stderr[-2000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got == {"at_torch": "PASSIVE", "now": "PASSIVE"}


def test_a_users_wait_policy_is_kept():
    res = _python(_SPY % "hack_render.geometry.model", OMP_WAIT_POLICY="ACTIVE")
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads(res.stdout.strip().splitlines()[-1]) == {"at_torch": "ACTIVE",
                                                               "now": "ACTIVE"}


def test_importing_the_package_loads_no_engine():
    res = _python("import sys, hack_render, hack_render.threads; "
                  "print(sorted(m for m in ('torch', 'drjit', 'mitsuba') if m in sys.modules))")
    assert res.returncode == 0 and res.stdout.strip() == "[]", res.stderr[-2000:]


def test_set_threads_reaches_torch_drjit_and_oidn():
    code = """
import os, json
import drjit as dr
import torch
from hack_render.threads import set_threads
set_threads(1)
print(json.dumps([torch.get_num_threads(), dr.thread_count(), os.environ["OIDN_NUM_THREADS"]]))
"""
    res = _python(code)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads(res.stdout.strip().splitlines()[-1]) == [1, 1, "1"]


def test_set_threads_before_the_engines_load():
    """Given before torch and Dr.Jit load: torch reads OMP_NUM_THREADS as it loads, Dr.Jit
    gets the count when the engine activates a variant."""
    code = """
import json, sys
from hack_render.threads import set_threads
set_threads(1)
assert "torch" not in sys.modules and "drjit" not in sys.modules
import torch
from hack_render.render.engine import ensure_variant
ensure_variant()
import drjit as dr
print(json.dumps([torch.get_num_threads(), dr.thread_count()]))
"""
    res = _python(code)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads(res.stdout.strip().splitlines()[-1]) == [1, 1]


def test_command_default_keeps_a_users_omp_num_threads():
    code = """
import json, os
from hack_render.threads import command_threads
command_threads(None)
print(json.dumps(os.environ.get("OMP_NUM_THREADS")))
"""
    res = _python(code, OMP_NUM_THREADS="1")
    assert res.returncode == 0 and json.loads(res.stdout.strip()) == "1", res.stderr[-2000:]
    res = _python(code)
    want = str(min(threads.DEFAULT_TORCH_THREADS, threads.available_cores()))
    assert res.returncode == 0 and json.loads(res.stdout.strip()) == want, res.stderr[-2000:]


@pytest.mark.parametrize("bad", [0, -1, 1025, 2.5, True, "2"])
def test_bad_thread_counts_are_refused(bad):
    with pytest.raises(HackError, match="--threads"):
        threads.check_threads(bad)


def test_every_long_command_takes_threads():
    from hack_render.cli import load_commands

    cmds = load_commands()
    for name in ("render", "turntable", "dataset", "fit", "track", "register"):
        cmd = cmds[name]
        opts = [o for p in cmd.params for o in getattr(p, "opts", [])]
        assert "--threads" in opts, name


def test_threads_zero_is_refused_before_anything_heavy(tmp_path):
    res = subprocess.run([sys.executable, "-m", "hack_render.cli", "render", "--threads", "0",
                          "-o", str(tmp_path / "x.png")], check=False, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode != 0 and "--threads" in res.stderr, res.stderr[-2000:]
    assert not (tmp_path / "x.png").exists()


def test_small_work_runs_on_one_thread_and_restores():
    """``small_work``: one torch thread inside, the caller's count back for ``bulk_work``
    and on exit, also after an exception and when nested; inactive: nothing changes. A
    B = 1 forward (which runs in it) leaves the count as it found it and gives the same
    vertices as a batch of two whose rows are that one (which does not)."""
    import torch

    from hack_render.geometry import load_default_model

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with threads.small_work():
            assert torch.get_num_threads() == 1
            with threads.bulk_work():
                assert torch.get_num_threads() == 2
            assert torch.get_num_threads() == 1
            with threads.small_work():
                assert torch.get_num_threads() == 1
                with threads.bulk_work():
                    assert torch.get_num_threads() == 2
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with pytest.raises(ValueError), threads.small_work():
            raise ValueError("inside")
        assert torch.get_num_threads() == 2
        with threads.small_work(active=False):
            assert torch.get_num_threads() == 2
            with threads.bulk_work():
                assert torch.get_num_threads() == 2
        model = load_default_model()
        g = torch.Generator().manual_seed(3)
        kw = {"beta": torch.randn(1, 20, generator=g),
              "psi": torch.rand(1, model.num_expressions, generator=g),
              "theta": 0.1 * torch.randn(1, 8, 3, generator=g)}
        with torch.no_grad():
            one = model(**kw).vertices
            assert torch.get_num_threads() == 2
            two = model(**{k: v.expand(2, *v.shape[1:]) for k, v in kw.items()}).vertices
        assert torch.allclose(one[0], two[1], atol=1e-6)
    finally:
        torch.set_num_threads(before)


def _helper_running() -> bool:
    import threading

    return any(t.name.startswith("hack-render-beside") for t in threading.enumerate())


def test_forward_overlap_is_the_serial_forward(monkeypatch):
    """A one-row forward on two torch threads makes M_E's components product on the
    helper thread (``threads.beside``) while it runs the rest: the same vertices bit for
    bit as all on one thread (``overlap_products`` off), for dense and FACS (sparse)
    expressions, 20 and 100 shape weights and no expression; gradients to beta go
    through it; it is not used on one torch thread, for two rows or for psi with a
    gradient. (A core is taken to be idle here: the suite's other workers may keep them
    busy, where the forward rightly runs all on one thread.)"""
    import torch

    from hack_render.geometry import load_default_model
    from hack_render.geometry import model as model_module

    monkeypatch.setattr(model_module, "spare_core", lambda: True)
    before = torch.get_num_threads()
    model = load_default_model()
    g = torch.Generator().manual_seed(5)
    facs = model.expression_vector("mouthSmile_L=0.7, jawOpen=0.3, browDown_R=0.5")[None]
    try:
        torch.set_num_threads(2)
        for s, psi in ((20, torch.rand(1, model.num_expressions, generator=g)), (20, facs),
                       (model.num_shape, torch.rand(1, model.num_expressions, generator=g)),
                       (20, torch.zeros(1, model.num_expressions))):
            kw = {"beta": torch.randn(1, s, generator=g), "psi": psi,
                  "theta": 0.2 * torch.randn(1, 8, 3, generator=g),
                  "eta": torch.tensor([1.3]), "tau": torch.tensor([0.004])}
            assert model._components_beside(psi, kw["beta"]) is not None
            with torch.no_grad():
                model.overlap_products = False
                serial = model(**kw).vertices
                model.overlap_products = True
                beside = model(**kw).vertices
            assert torch.equal(serial, beside)
        assert _helper_running()
        beta = kw["beta"].clone().requires_grad_(True)
        dense = torch.rand(1, model.num_expressions, generator=g)
        grads = []
        for on in (False, True):
            model.overlap_products = on
            out = model(**{**kw, "beta": beta, "psi": dense}).vertices
            grads.append(torch.autograd.grad(out.square().sum(), beta)[0])
        assert torch.equal(grads[0], grads[1]) and grads[0].abs().sum() > 0
        # the shaped template beside too, unless beta needs its gradient
        assert model._components_beside(dense, beta)[1].result()[2] is None
        assert model._components_beside(dense, beta.detach())[1].result()[2] is not None
        assert model._components_beside(dense.expand(2, -1), beta) is None
        assert model._components_beside(dense.clone().requires_grad_(True), beta) is None
        torch.set_num_threads(1)
        assert model._components_beside(dense, beta) is None
    finally:
        model.overlap_products = True
        torch.set_num_threads(before)


_FORKED = """
import multiprocessing as mp, torch
from hack_render import threads
from hack_render.geometry import load_default_model
torch.set_num_threads(2)
model = load_default_model()
g = torch.Generator().manual_seed(1)
kw = {"beta": torch.randn(1, 20, generator=g), "psi": torch.rand(1, model.num_expressions,
      generator=g)}

def child(q):
    torch.set_num_threads(1)  # as torch's DataLoader workers: OpenMP does not survive fork
    q.put(threads.beside(sum, [40, 2]).result(timeout=60))
    with torch.no_grad():
        q.put(model(**kw).vertices.double().sum().item())

with torch.no_grad():
    parent = model(**kw).vertices.double().sum().item()
ctx = mp.get_context("fork")
q = ctx.Queue()
p = ctx.Process(target=child, args=(q,))
p.start()
got = [q.get(timeout=120), q.get(timeout=120)]
p.join(60)
print(got[0], parent == got[1], p.exitcode)
"""


def test_helper_thread_in_a_forked_child():
    """A process forked after its forwards used the helper thread starts a helper of its
    own (the parent's thread does not exist in the child: without that, a task given to
    it would wait forever), and its forward (on one torch thread, as torch's DataLoader
    workers run) gives the parent's vertices."""
    res = _python(_FORKED)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["42", "True", "0"], res.stdout + res.stderr[-2000:]


def test_spare_core_sees_busy_cores():
    """``spare_core``: False while CPU-bound processes keep every core of this process's
    busy (the forward's helper then stays idle), in at least 8 of 10 looks."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
            for _ in range(threads.available_cores())]
    try:
        time.sleep(0.5)
        busy = 0
        for _ in range(10):
            busy += not threads.spare_core()
            time.sleep(0.02)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    assert busy >= 8
