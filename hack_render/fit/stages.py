"""The optimisation loop shared by every stage: Adam, progress bar, loss history, NaN guard.

A stage that produces a non-finite loss or gradient stops there: the best parameters seen
so far (lowest total loss) are restored and the event is reported with the stage's name
(:class:`StageReport.failure`), so one bad step never destroys a fit.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import torch
from tqdm import tqdm


class FitWarning(UserWarning):
    """Something went wrong in a stage but the fit continued (e.g. NaN caught)."""


@dataclass
class StageReport:
    """What one stage did: its name, per-iteration losses (total and terms), seconds,
    iterations run, and a failure message (None if it ran to the end)."""

    name: str
    history: dict = field(default_factory=dict)
    seconds: float = 0.0
    iterations: int = 0
    failure: str | None = None
    best_loss: float = float("inf")
    per_iteration_s: list = field(default_factory=list)


def run_stage(name: str, groups: list[dict], loss_fn: Callable[[int], tuple[torch.Tensor, dict]],
              iterations: int, progress: bool = True, after_step: Callable[[], None] | None = None,
              keep: str = "best") -> StageReport:
    """Minimise ``loss_fn`` over the parameter groups (torch.optim.Adam param groups).

    Args:
        loss_fn: iteration -> (total loss, {term name: float}).
        after_step: called after each step (projections such as clamping psi to [0, 1]).
        keep: ``"best"`` restores the parameters of the lowest loss seen; ``"last"`` keeps
            the final iterate (for losses whose per-iteration noise exceeds the progress,
            e.g. per-texel albedo rendered with a new sample pattern each iteration, where
            the minimum over iterations selects a lucky sample pattern, usually the
            first). A non-finite loss or gradient restores the best parameters either way.
    """
    report = StageReport(name)
    params = [p for g in groups for p in g["params"]]
    if iterations <= 0 or not params:
        return report
    opt = torch.optim.Adam(groups)
    best = [p.detach().clone() for p in params]
    t0 = time.perf_counter()
    bar = tqdm(range(iterations), desc=f"fit {name}", unit="it", disable=not progress,
               leave=False)
    for it in bar:
        ti = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        loss, terms = loss_fn(it)
        ok = bool(torch.isfinite(loss))
        if ok:
            loss.backward()
            ok = all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in params)
        if not ok:
            what = "loss" if not torch.isfinite(loss) else "gradient"
            report.failure = (f"stage {name!r}: non-finite {what} at iteration {it}; kept the "
                              f"best parameters so far (loss {report.best_loss:.4g}).")
            warnings.warn(report.failure, FitWarning, stacklevel=2)
            break
        value = float(loss.detach())
        if value < report.best_loss:
            report.best_loss = value
            best = [p.detach().clone() for p in params]
        report.history.setdefault("total", []).append(value)
        for k, v in terms.items():
            report.history.setdefault(k, []).append(float(v))
        opt.step()
        if after_step is not None:
            after_step()
        report.iterations = it + 1
        report.per_iteration_s.append(time.perf_counter() - ti)
        bar.set_postfix(loss=f"{value:.4g}")
    bar.close()
    if report.failure is not None or (report.iterations and keep == "best"):
        # keep the best iterate (for noisy photometric losses this is the best estimate)
        with torch.no_grad():
            for p, b in zip(params, best):
                p.copy_(b)
    report.seconds = time.perf_counter() - t0
    return report


@dataclass
class StageLog:
    """The reports of the stages run so far and the seconds per stage name (a stage run
    twice, e.g. per-texel refinement after the photometric levels, adds up)."""

    reports: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    progress: bool = True

    def run(self, name: str, groups: list[dict], loss_fn, iterations: int,
            after_step: Callable[[], None] | None = None, keep: str = "best") -> StageReport:
        """:func:`run_stage`, its report appended and its seconds added."""
        t0 = time.perf_counter()
        rep = run_stage(name, groups, loss_fn, iterations, self.progress, after_step, keep)
        self.reports.append(rep)
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0
        return rep
