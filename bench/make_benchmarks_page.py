"""Write docs/benchmarks.md from bench/results/*.json (run by the docs build's hook too).

    python bench/make_benchmarks_page.py            # rewrite docs/benchmarks.md
    python bench/make_benchmarks_page.py --check    # exit 1 if the page is stale

Each result file carries ``commit``, ``date``, ``machine`` and ``command`` (written by
``bench/provenance.py``); the page shows them beside the figures, so every number on it
says which code, machine and command made it. Nothing here runs a benchmark.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
PAGE = ROOT / "docs" / "benchmarks.md"

# what each synthetic-fit run varies (the rest: bench_fit.py's defaults at its commit)
FIT_RUNS = {
    "fit_synthetic256": "default, `light_stage` lighting",
    "fit_synthetic256_random_lighting": "default, random presets",
    "fit_synthetic256_random_lighting_landmarks": "random presets, landmark stages only",
    "fit_synthetic256_known_focal": "true focal length given (as EXIF would)",
    "fit_synthetic256_silhouette_depth2.5":
        "`light_stage`, silhouette border depth 2.5, no chroma step",
    "fit_synthetic256_random_lighting_silhouette_depth2.5":
        "random presets, border depth 2.5, no chroma step",
    "fit_synthetic256_random_lighting_landmarks_silhouette_depth2.5":
        "random presets, landmark stages, border depth 2.5",
    "fit_synthetic256_random_lighting_landmarks_oracle_mask_depth2.5":
        "random presets, landmark stages, true mask (diagnostic)",
    "fit_synthetic256_sh": "`light_stage`, SH lighting alone",
    "fit_synthetic256_random_lighting_sh": "random presets, SH lighting alone",
    "fit_synthetic256_random_lighting_lobes2": "random presets, two lobes",
    "fit_synthetic256_random_lighting_lr_geometry": "random presets, `lr_geometry` 0.01",
    "fit_synthetic256_random_lighting_iterations60_45_first10":
        "random presets, 60 + 45 iterations, subjects 0-9",
    "fit_synthetic256_random_lighting_oracle_light": "random presets, true light (diagnostic)",
    "fit_detector_random_lighting_nochroma":
        "random presets, detector and mask only, no chroma step",
    "fit_expressions8_l1": "8 subjects with expressions, L1 psi prior, landmark stages",
    "fit_expressions8_l2": "8 subjects with expressions, Gaussian psi prior, landmark stages",
    "fit_oracle6": "6 subjects fitted to the true landmarks (diagnostic)",
}
FIT_COLUMNS = [("vertex_mm", "vertex error (mm)", 1, "{:.2f}"), ("nme", "NME (%)", 100, "{:.2f}"),
               ("psnr_db_64spp", "PSNR 64 spp (dB)", 1, "{:.1f}"),
               ("albedo_de2000", "albedo ΔE2000", 1, "{:.1f}"),
               ("joint_deg", "neck joints (deg)", 1, "{:.2f}"),
               ("mask_iou", "mask IoU", 1, "{:.3f}"),
               ("detector_nme_inner", "dlib NME 18-68 (%)", 100, "{:.2f}"),
               ("seconds", "s / subject", 1, "{:.0f}")]


def load() -> dict[str, dict]:
    """Every result file by name (without .json), checked for the provenance fields."""
    out = {}
    for path in sorted(RESULTS.glob("*.json")):
        data = json.loads(path.read_text())
        missing = [k for k in ("commit", "date", "machine", "command") if not data.get(k)]
        if missing:
            raise SystemExit(f"{path}: missing {missing}; write results with "
                             f"bench/provenance.py's write_result.")
        out[path.stem] = data
    return out


def _source(name: str, d: dict) -> str:
    commit = d["commit"][:10] if d["commit"] != "unknown" else "unknown"
    return (f"`bench/results/{name}.json`: commit `{commit}`, {d['date'][:10]}, "
            f"{d['machine']}. Command: `{d['command']}`")


def _fit_table(results: dict) -> list[str]:
    names = [n for n in FIT_RUNS if n in results]
    lines = ["| run | fitted | " + " | ".join(c[1] for c in FIT_COLUMNS) + " |",
             "|---|---|" + "---|" * len(FIT_COLUMNS)]
    for n in names:
        d = results[n]
        med = d.get("median", {})
        cells = []
        for key, _, scale, fmt in FIT_COLUMNS:
            v = med.get(key)
            cells.append(fmt.format(v * scale) if isinstance(v, (int, float)) else "-")
        total = len(d.get("subjects", []))
        lines.append(f"| {FIT_RUNS[n]} | {d.get('n_ok', '-')} of {total} | "
                     + " | ".join(cells) + " |")
    lines += ["", "Sources:", ""] + [f"- {_source(n, results[n])}" + (f" Note: {results[n]['note']}"
                                     if results[n].get("note") else "") for n in names]
    return lines


def _budget(results: dict) -> list[str]:
    names = [n for n in ("fit_budget20", "fit_budget8") if n in results]
    keys = []
    for n in names:
        keys += [k for k in results[n]["median_mm"] if k not in keys]
    lines = ["| landmark stages given | " + " | ".join(f"`{n}` (median mm)" for n in names) + " |",
             "|---|" + "---|" * len(names)]
    for k in keys:
        lines.append(f"| `{k}` | " + " | ".join(
            f"{results[n]['median_mm'][k]:.2f}" if k in results[n]["median_mm"] else "-"
            for n in names) + " |")
    if "fit_tune_jaw_20_39" in results:
        t = results["fit_tune_jaw_20_39"]["configs"]
        lines += ["", "Tuning on subjects 20-39 (landmark stages, refined points):", "",
                  "| config | median mm | mean mm | better than the first |", "|---|---|---|---|"]
        lines += [f"| `{k}` | {v['median_mm']:.2f} | {v['mean_mm']:.2f} | {v['better_than_first']} |"
                  for k, v in t.items()]
        names.append("fit_tune_jaw_20_39")
    lines += ["", "Sources:", ""] + [f"- {_source(n, results[n])}" for n in names]
    return lines


def _refiner(results: dict) -> list[str]:
    d = results.get("landmark_refiner")
    if d is None:
        return []
    lines = [f"dlib on the benchmark's subjects: median {d['dlib']['median']:.2f} %, mean "
             f"{d['dlib']['mean']:.2f} % of the inter-ocular distance (inner points and chin). "
             f"Refiners trained on {d['training_subjects']} renders:", "",
             "| variant | median (%) | mean (%) | subjects better |", "|---|---|---|---|"]
    for k, v in d["variants"].items():
        lines.append(f"| `{k}` | {v['median']:.2f} | {v['mean']:.2f} | {v.get('better', '-')} |")
    lines += ["", f"- {_source('landmark_refiner', d)}"]
    return lines


def _figures(name: str, d: dict) -> list[str]:
    lines = [f"### {d.get('title', name)}", ""]
    if "figures" in d:
        lines += ["| what | result |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in d["figures"].items()]
    else:  # a script that reports by printing (bench/provenance.py's recorded)
        lines += ["```text", *d["printed"], "```"]
    return lines + ["", f"- {_source(name, d)}", ""]


KNOWN = set(FIT_RUNS) | {"fit_budget20", "fit_budget8", "fit_tune_jaw_20_39", "landmark_refiner",
                         "register"}


def _pm(entry: dict, key: str, fmt: str = "{:.2f}") -> str:
    v = entry.get(key) or {}
    if not v:
        return "-"
    return f"{fmt.format(v['mean'])} ± {fmt.format(v['std'])}"


def _register(results: dict) -> list[str]:
    """bench_register.py's Table 1: mean +- std over held-out scans per configuration."""
    d = results.get("register")
    if d is None:
        return []
    p = d["protocol"]
    lines = [f"Leave-k-out: {p['held_out']} identities held out of {p['population']}; the "
             f"registering model's shape space ({p['registering_model_components']} components) "
             "is learned without them. Scans re-tessellated, "
             f"{p['noise_mm']} mm noise, {p['holes']} holes, a random similarity; {p['data']}. "
             "Scan-to-mesh: each scan's mean distance (mm) from its points to the registration; "
             "against the clean surface: from the noise-free surface; vertex: registered "
             "vertices to the truth over the skin.", "",
             "| model | scans | scan-to-mesh (mm) | face | neck | to the clean surface (mm) | "
             "vertex (mm) | s / scan | failed |", "|---|---|---|---|---|---|---|---|---|"]
    order = ["linear", "paper", "hack (no free-form)", "hack"]
    for kind in ("neutral", "posed"):
        for name in order:
            e = d["table"].get(f"{name}/{kind}")
            if not e:
                continue
            lines.append(f"| {name} | {kind} | {_pm(e, 's2m_mean')} | {_pm(e, 's2m_face')} | "
                         f"{_pm(e, 's2m_neck')} | {_pm(e, 'clean_s2m_mean')} | "
                         f"{_pm(e, 'vertex_mean')} | {_pm(e, 'seconds', '{:.0f}')} | "
                         f"{e.get('failed', '-')} |")
    ratios = {k: v for k, v in d["table"].items() if k.startswith("ratio")}
    lines += [""] + [f"- {k}: {v:.2f}" for k, v in ratios.items()]
    lines += [f"- part: `{q['command']}` (commit `{q['commit'][:10]}`)" for q in p.get("parts", [])]
    lines += [f"- seconds per scan: wall time with torch on {p['torch_threads']} thread(s), the "
              "runs side by side on this machine; landmarks given"]
    return lines + ["", f"- {_source('register', d)}"]
SKIP = {"commit", "date", "machine", "command", "provenance_note", "title", "note"}


def _flatten(value, key: str = ""):
    """(dotted key, short text) for every scalar of a result; long lists are summarised."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _flatten(v, f"{key}.{k}" if key else str(k))
    elif isinstance(value, list) and len(value) > 6:
        yield key, f"({len(value)} values)"
    elif isinstance(value, list):
        yield key, ", ".join(_short(v) for v in value)
    else:
        yield key, _short(value)


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v) if not isinstance(v, (dict, list)) else json.dumps(v)[:80]


def _generic(name: str, d: dict) -> list[str]:
    """Any other result file: its values as a table (a script's own schema)."""
    rows = [(k, v) for k, v in _flatten({k: v for k, v in d.items() if k not in SKIP})]
    lines = [f"### {d.get('title', name)}", ""]
    if d.get("note"):
        lines += [d["note"], ""]
    lines += ["| value | result |", "|---|---|"] + [f"| `{k}` | {v} |" for k, v in rows[:60]]
    if len(rows) > 60:
        lines.append(f"| ... | {len(rows) - 60} more in the file |")
    return lines + ["", f"- {_source(name, d)}", ""]


def render(results: dict) -> str:
    out = ["# Benchmarks", "",
           "<!-- generated by bench/make_benchmarks_page.py from bench/results/*.json: "
           "edit those, not this page -->", "",
           "Generated from `bench/results/*.json`; each figure names the commit, date, machine "
           "and command that made it. Benchmarks live in `bench/`, are not tests, and print "
           "ratios measured in one run; rerun one with its command and it writes its result "
           "file with the same fields (`bench/provenance.py`). Older files were recovered from "
           "the git history and say so (`provenance_note`).", "",
           "## Fitting: synthetic recovery", "",
           "Subjects with known parameters rendered at 256 px, 64 spp, fitted from the image "
           "(dlib landmarks, default config unless the run says otherwise); medians over the "
           "subjects dlib detects.", ""]
    out += _fit_table(results)
    out += ["", "## Fitting: where the error lies", ""] + _budget(results)
    out += ["", "## Landmark refiner", ""] + _refiner(results)
    if "register" in results:
        out += ["", "## Registration to scans (Table 1 style)", ""] + _register(results)
    out += ["", "## Other benchmarks", ""]
    for name, d in results.items():
        if "figures" in d or "printed" in d:
            out += _figures(name, d)
        elif name not in KNOWN and "median" not in d:
            out += _generic(name, d)
    for name, d in results.items():  # every file is on the page, whatever its shape
        if f"bench/results/{name}.json" not in "\n".join(out):
            out += _generic(name, d)
    return "\n".join(out).rstrip() + "\n"


def write(check: bool = False) -> str:
    """'current' when the page matches the results; else rewrite it ('written'), or with
    ``check`` only report it ('stale')."""
    text = render(load())
    if PAGE.is_file() and PAGE.read_text() == text:
        return "current"
    if check:
        return "stale"
    PAGE.write_text(text)
    return "written"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/benchmarks.md is stale")
    args = ap.parse_args()
    state = write(args.check)
    print(f"{PAGE}: {state}")
    if state == "stale":
        print("run python bench/make_benchmarks_page.py", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
