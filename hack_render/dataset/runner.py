"""Running a dataset job: checks, shards, resumption, executors, manifests.

Layout of an output folder ``DIR``::

    DIR/config.json                      the resolved config, seed and label table
    DIR/samples/0000012/sample.json      the sample's record (written last: complete)
    DIR/samples/0000012/params.json      geometry parameters (``hack-render render --params``)
    DIR/samples/0000012/view_00/...      per-view images and labels (the README (Datasets))
    DIR/manifest/shard-000-of-004.jsonl  one record per line, sorted by index

Shard ``K/M`` (0 <= K < M) owns the samples with ``index % M == K``. A job array (Slurm,
Kubernetes) runs one shard per task into the same ``DIR``; shards share nothing but
``config.json``, which every shard writes with the same content (a shard refuses a
``DIR`` made with another config or seed).

Executors: ``serial`` renders in this process; ``ray`` runs one
:class:`~hack_render.dataset.worker.SampleRenderer` per Ray actor and hands samples to
them with Ray's own ``ActorPool`` (a local Ray instance by default, or a cluster
address). Both write the same files.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from appearance.model import AppearanceModel
from appearance.projected import model_height, supports_height
from appearance.uv import default_template
from hack_render import boundary, interrupts
from hack_render.boundary import estimate_line
from hack_render.dataset.config import render_settings
from hack_render.dataset.labels import LABEL_DESCRIPTIONS, LABELS
from hack_render.dataset.sampling import pool_size
from hack_render.dataset.worker import SAMPLE_RECORD, SampleRenderer, sample_dir
from hack_render.errors import HackError
from hack_render.geometry import load_default_model
from hack_render.io import atomic_path, temp_glob, write_json
from hack_render.render.engine import set_thread_count

EXECUTORS = ("serial", "ray")
#: The most samples one dataset folder holds (sample folders are named by a 7-digit index
#: and one folder of 10^8 entries is already beyond what file systems list in useful time).
MAX_SAMPLES = 10 ** 8


@dataclass(frozen=True)
class Job:
    """One shard of a dataset: ``n`` samples of ``cfg`` with ``seed`` into ``out``."""

    out: Path
    n: int
    seed: int
    cfg: dict
    shard: tuple[int, int] = (0, 1)
    resume: bool = False

    def indices(self) -> range:
        """The shard's sample indices (a range: planning streams, whatever ``n``)."""
        k, m = self.shard
        return range(k, self.n, m)

    @property
    def manifest_path(self) -> Path:
        k, m = self.shard
        return self.out / "manifest" / f"shard-{k:03d}-of-{m:03d}.jsonl"

    @property
    def complete_path(self) -> Path:
        """The shard's completion marker, written last."""
        return self.manifest_path.with_name(f"{self.manifest_path.stem}.complete.json")

    @property
    def lock_name(self) -> str:
        """One writer per shard and folder (``boundary.folder_lock`` in ``manifest/``)."""
        return f".lock.{self.manifest_path.stem}"


def parse_shard(text: str | None) -> tuple[int, int]:
    """'K/M' -> (K, M) with 0 <= K < M."""
    if text is None:
        return (0, 1)
    try:
        k, m = (int(x) for x in text.split("/"))
    except ValueError as err:
        raise HackError(f"--shard: expected K/M (e.g. 3/16, K counted from 0), found "
                        f"{text!r}.") from err
    if not (m >= 1 and 0 <= k < m):
        raise HackError(f"--shard: expected 0 <= K < M in K/M, found {text!r}. With a Slurm "
                        "array use --array=0-(M-1) and --shard $SLURM_ARRAY_TASK_ID/M.")
    return (k, m)


def check_job(job: Job) -> None:
    """Everything that can be checked before rendering: N, seed, model-dependent config
    values, the output folder, an existing folder's config. Raises HackError."""
    if isinstance(job.n, bool) or not isinstance(job.n, int) or not 1 <= job.n <= MAX_SAMPLES:
        raise HackError(f"--n: expected a number of samples in 1..{MAX_SAMPLES:,}, found "
                        f"{job.n!r}. Larger datasets: several folders with different --seed.")
    if not job.indices():
        raise HackError(f"--shard {job.shard[0]}/{job.shard[1]}: expected a shard that owns "
                        f"samples, found none of the {job.n} (K >= N). Use fewer shards.")
    if not 0 <= job.seed < 2 ** 63:
        raise HackError(f"--seed: expected 0 <= seed < 2^63, found {job.seed}.")
    model = load_default_model()
    aus = job.cfg["expression"]["aus"]
    if aus != "all":
        bad = [a for a in aus if a not in model.au_names]
        if bad:
            raise HackError(f"config key 'expression.aus': unknown action units {bad}; the "
                            f"model has {', '.join(model.au_names)}.")
    if job.cfg["identity"]["components"] > model.num_shape:
        raise HackError(f"config key 'identity.components': expected <= {model.num_shape} "
                        f"(the model's shape components), found "
                        f"{job.cfg['identity']['components']}.")
    app = job.cfg["appearance"]
    if app["source"] == "alpha":
        try:
            k = AppearanceModel.load().n_components
        except (ImportError, OSError) as err:
            raise HackError(f"config key 'appearance.source': 'alpha' needs the appearance "
                            f"PCA model, found it unavailable ({err}). Use 'seed'.") from err
        if app["components"] > k:
            raise HackError(f"config key 'appearance.components': expected <= {k} (the "
                            f"appearance model's components), found {app['components']}.")
    if app["source"] == "seed" and app["maps"] == "projected":
        top = model_height()
        if not supports_height(app["height"], top):
            raise HackError(f"config key 'appearance.height': expected the appearance model's "
                            f"{top} divided by a power of two with appearance.maps: projected, "
                            f"found {app['height']}. Use one of {top}, {top // 2}, "
                            f"{top // 4}, ..., or appearance.maps: generated.")
    if app["source"] in ("seed", "alpha"):
        default_template()  # the skin atlas needs the packaged template (raises with the fix)
    boundary.output_dir(job.out)
    for sub in ("samples", "manifest"):
        boundary.output_dir(job.out / sub)
    info = run_info(job)
    path = job.out / "config.json"
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError):
            old = None
        old_cfg = old.get("config") if isinstance(old, dict) else None
        old_app = old_cfg.get("appearance") if isinstance(old_cfg, dict) else None
        legacy = isinstance(old_app, dict) and "maps" not in old_app
        if legacy:  # made before appearance.maps: with the generator's maps
            old_app["maps"] = "generated"
        if old is not None and old != info:
            diff = [k for k in info if old.get(k) != info[k]]
            hint = (" It was made before appearance.maps existed, with the generator's maps: "
                    "add `appearance: {maps: generated}` to the config to resume it."
                    if legacy and info["config"]["appearance"]["maps"] != "generated" else "")
            if isinstance(old_cfg, dict) and "hair" not in old_cfg:
                hint = (" It was made before the hair layer (no hair section, no 'hair' "
                        "label): this version writes another label table and cannot resume "
                        "it.")
            raise HackError(f"-o/--output {job.out}: expected an empty folder or one made with "
                            f"the same config and seed, found a dataset that differs in "
                            f"{diff}.{hint} Choose another folder.")
    _refuse_rerun(job, existing_samples(job))


def run_info(job: Job) -> dict:
    """What ``config.json`` records: config, seed and the label table."""

    st = render_settings(job.cfg)
    return {"format": "hack-render-dataset", "version": 1, "seed": job.seed, "config": job.cfg,
            # what the images are rendered with (the sampler rounds render.spp up): a
            # folder made by a version that rendered otherwise is not resumed into
            "rendered": {"sampler": st.mitsuba_sampler, "spp": st.effective_spp},
            "labels": [{"id": i, "name": n, "description": LABEL_DESCRIPTIONS[n]}
                       for i, n in enumerate(LABELS)]}


def read_record(out: Path, index: int) -> dict | None:
    """A sample's record if the sample is complete (record and every listed file of the
    recorded size), else None."""
    path = sample_dir(out, index) / SAMPLE_RECORD
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    for rel, size in rec.get("files", {}).items():
        p = out / rel
        if not p.is_file() or p.stat().st_size != size:
            return None
    return rec


def _clean_temporaries(folder: Path, pattern: str = ".*") -> None:
    """Remove the temporary files a killed run left behind (``hack_render.io.atomic_path``'s
    ``.tmp-*``; ``.<stem>.*`` from older versions) that match ``pattern``."""
    for p in folder.rglob(pattern):
        if p.is_file():
            p.unlink()


def existing_samples(job: Job) -> list[int]:
    """Indices of the shard's sample folders already in ``DIR/samples`` (complete or not)."""
    folder = job.out / "samples"
    if not folder.is_dir():
        return []
    k, m = job.shard
    found = [int(p.name) for p in folder.iterdir() if p.name.isdigit()]
    return sorted(i for i in found if i < job.n and i % m == k)


def _refuse_rerun(job: Job, existing: list[int]) -> None:
    if existing and not job.resume:
        raise HackError(f"-o/--output {job.out}: expected no samples of this shard yet, found "
                        f"{len(existing)} (e.g. {sample_dir(job.out, existing[0])}). Add "
                        "--resume to keep the complete ones and render the rest, or choose "
                        "an empty folder.")


def prepare(job: Job) -> tuple[object, int]:
    """Write ``config.json`` and the manifest of what is complete; returns (the sample
    indices to render, streamed, and their count). Run under the shard's lock, after
    :func:`check_job`.

    Without ``resume`` the shard must have no samples in the folder yet (a re-run would
    redo complete samples and could be killed half-way through one); with it, partial
    samples are cleaned and redone, complete ones kept."""
    existing = existing_samples(job)
    _refuse_rerun(job, existing)  # again, under the lock
    write_json(job.out / "config.json", run_info(job), indent=1, sort_keys=True)
    (job.out / "manifest").mkdir(parents=True, exist_ok=True)
    job.complete_path.unlink(missing_ok=True)
    for own in (job.manifest_path, job.complete_path):  # the other shards' are theirs
        _clean_temporaries(job.out / "manifest", temp_glob(own))
    _clean_temporaries(job.out / "manifest", f".{job.manifest_path.stem}.*")
    done: dict[int, dict] = {}
    for i in existing:
        _clean_temporaries(sample_dir(job.out, i))
        rec = read_record(job.out, i)
        if rec is not None:
            done[i] = rec
    # the manifest starts as the complete samples' records: no line of a sample redone
    _write_manifest_lines(job, [done[i] for i in sorted(done)])
    todo = (i for i in job.indices() if i not in done)
    return todo, len(job.indices()) - len(done)


def _write_manifest_lines(job: Job, records: list[dict]) -> Path:
    with atomic_path(job.manifest_path) as tmp:
        tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
    return job.manifest_path


def write_manifest(job: Job) -> Path:
    """Write the shard's manifest from its complete samples' records, sorted by index."""
    records = [rec for i in existing_samples(job)
               if (rec := read_record(job.out, i)) is not None]
    return _write_manifest_lines(job, records)


def _append_manifest(job: Job, rec: dict) -> None:
    """Progress log while running (rewritten, sorted, by :func:`write_manifest`); a line
    that cannot be written whole (disk full) is taken back, never left truncated."""
    line = json.dumps(rec, sort_keys=True) + "\n"
    with open(job.manifest_path, "a") as f:
        start = f.tell()
        try:
            f.write(line)
            f.flush()
        except OSError:
            try:
                f.truncate(start)
            except OSError:
                pass
            raise


def with_next(items):
    """(item, the item after it or None) for each item of an iterable, read one ahead."""
    it = iter(items)
    cur = next(it, None)
    while cur is not None:
        nxt = next(it, None)
        yield cur, nxt
        cur = nxt


def run_serial(job: Job, todo, progress: bool = True, total: int | None = None,
               tally: dict | None = None) -> int:
    """Render ``todo`` (indices, streamed; ``total`` of them) in this process; returns how
    many. ``tally["complete"]`` counts the shard's complete samples as they land."""

    if total is None:
        todo = list(todo)
        total = len(todo)
    if not total:
        return 0
    tally = {"complete": 0} if tally is None else tally

    def log(rec: dict) -> None:
        _append_manifest(job, rec)
        tally["complete"] += 1

    # files are written on a background thread while the next sample renders; records
    # are logged in order as their samples complete
    renderer = SampleRenderer(job.cfg, job.out, job.seed, background_writes=True)
    pending: deque = deque()
    count, t0 = 0, time.perf_counter()
    try:
        for i, upcoming in tqdm(with_next(todo), total=total, desc="dataset", unit="sample",
                                disable=not progress):
            if count == 0:  # the first sample's inputs are made while its scene is built
                renderer.prefetch(i)
            # the next sample's inputs are made while sample i renders (at the start: once
            # its scene is built)
            pending.append(renderer.submit(i, then=upcoming))
            count += 1
            if count == 1:
                t0 = time.perf_counter()  # the first sample compiles the kernels: not a rate
            elif count == 2 and total > 2:  # the size of the job, once its rate is known
                print(estimate_line("dataset", time.perf_counter() - t0, total - 2),
                      file=sys.stderr)
            while pending and pending[0].done():
                log(pending.popleft().result())
    except BaseException:
        # interrupted (Ctrl-C) or failed: finish the queued writes, so that every sample
        # whose files were queued is complete on disk, then stop
        renderer.close()
        for f in pending:
            if f.exception() is None:
                log(f.result())
        raise
    renderer.close()
    for f in pending:
        log(f.result())  # raises a failed write's error
    return count


def run_ray(job: Job, todo, address: str | None = None,
            workers: int | None = None, progress: bool = True, tally: dict | None = None) -> int:
    """Render ``todo`` on Ray actors (one renderer and one CPU each) through ActorPool."""
    try:
        import ray
        from ray.util import ActorPool
    except ImportError as err:
        raise HackError("--executor ray: expected Ray, found it not installed. Install the "
                        "extra: pip install 'hack-render[ray]'.") from err

    todo = list(todo)
    if not todo:
        return 0
    tally = {"complete": 0} if tally is None else tally
    started = False
    if not ray.is_initialized():
        kw = {"address": address} if address else {"num_cpus": workers or os.cpu_count()}
        ray.init(include_dashboard=False, log_to_driver=False, **kw)
        started = True
    try:
        n = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        actors = [_RayRenderer.remote(job.cfg, str(job.out), job.seed) for _ in range(n)]
        pool = ActorPool(actors)
        results = pool.map_unordered(lambda a, i: a.render.remote(i), todo)
        for rec in tqdm(results, total=len(todo), desc=f"dataset (ray x{n})", unit="sample",
                        disable=not progress):
            _append_manifest(job, rec)
            tally["complete"] += 1
    finally:
        if started:
            ray.shutdown()
    return len(todo)


class _LazyRayActor:
    """The Ray actor class, defined on first use so that Ray stays an optional import."""

    _cls = None

    def remote(self, *args):
        if _LazyRayActor._cls is None:
            import ray

            @ray.remote(num_cpus=1)
            class RayRenderer:
                def __init__(self, cfg, out, seed):
                    set_thread_count(1)  # one core per actor: no oversubscription
                    self.renderer = SampleRenderer(cfg, out, seed)

                def render(self, index):
                    return self.renderer.render(index)

            _LazyRayActor._cls = RayRenderer
        return _LazyRayActor._cls.remote(*args)


_RayRenderer = _LazyRayActor()


def hair_summary(cfg: dict) -> str:
    """The run's hair, for its first line: the style, and how many grooms the pool holds
    (``hair.pool``) or that everyone grows their own."""
    c = cfg["hair"]
    if c["style"] == "none":
        return "; no hair"
    style = c["style"] if isinstance(c["style"], str) else "a given style"
    grooms = (f"strands from at most {pool_size(int(c['pool']))} pooled grooms (hair.pool "
              f"{c['pool']})" if c["pool"] else "everyone's own strands (hair.pool 0)")
    return f"; hair {style} at lod {c['lod']:g}, {grooms}"


def run(job: Job, executor: str = "serial", address: str | None = None,
        workers: int | None = None, progress: bool = True) -> dict:
    """Prepare, render the pending samples, write the manifest. Returns a summary."""
    if executor not in EXECUTORS:
        raise HackError(f"--executor: expected one of {', '.join(EXECUTORS)}, found "
                        f"{executor!r}.")
    if workers is not None and workers < 1:
        raise HackError(f"--workers: expected >= 1, found {workers}.")
    if executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError as err:
            raise HackError("--executor ray: expected Ray, found it not installed. Install "
                            "the extra: pip install 'hack-render[ray]'.") from err

    check_job(job)
    total = len(job.indices())
    k, m = job.shard
    with boundary.folder_lock(job.out / "manifest", job.lock_name):
        todo, n_todo = prepare(job)
        tally = {"complete": total - n_todo}
        print(f"dataset: {n_todo:,} of the {total:,} samples of shard {k}/{m} to render into "
              f"{job.out} ({job.cfg['render']['resolution']} px, "
              f"{render_settings(job.cfg).effective_spp} spp, {job.cfg['camera']['views']} "
              f"view(s) each{hair_summary(job.cfg)})", file=sys.stderr)

        def kept() -> str:
            return (f"kept {tally['complete']:,} complete samples of the {total:,} of shard "
                    f"{k}/{m} in {job.out}; run the same command with --resume to render the "
                    "rest")

        with interrupts.on_interrupt(kept):
            if executor == "ray":
                done = run_ray(job, todo, address, workers, progress, tally)
            else:
                done = run_serial(job, todo, progress, n_todo, tally)
            manifest = write_manifest(job)
            write_json(job.complete_path, {"complete": True, "n": job.n, "shard": [k, m],
                                           "samples": total}, indent=1, sort_keys=True)
    return {"rendered": done, "skipped": total - n_todo, "total": total,
            "manifest": str(manifest)}
