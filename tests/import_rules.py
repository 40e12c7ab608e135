"""The import discipline that ``tests/test_structure.py`` asserts, as data and parsers:
the layers (:data:`LAYERS`), the engines a function body may defer (:data:`DEFERRABLE`),
what ``--help`` may load, and the parser of every import in the package's modules
(:func:`all_imports`, wherever an import stands) with the graph checks over it (layers,
circles, private names, deferred imports). A helper module of the tests, not a test file.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

import hack_render

ROOT = Path(hack_render.__file__).resolve().parents[1]
PACKAGES = ("hack_render", "appearance", "scenes")
FIT = ROOT / "hack_render" / "fit"

#: the layers, lowest first; a module belongs to the longest prefix listed. A module may
#: import its own layer's packages or lower ones, never a higher layer's. The ground floor
#: holds what every package shares (errors, file writing, the command line's checks).
LAYERS: tuple[tuple[str, ...], ...] = (
    ("hack_render", "hack_render.errors", "hack_render.interrupts", "hack_render.io",
     "hack_render.boundary", "hack_render.cli_options"),
    ("hack_render.geometry",),
    ("appearance", "scenes", "hack_render.hair"),
    ("hack_render.render",),
    ("hack_render.vision",),
    ("hack_render.fit", "hack_render.dataset", "hack_render.export", "hack_render.register"),
    ("hack_render.track", "hack_render.motion", "hack_render.learn"),
    ("hack_render.cli",),
)

#: the third-party modules a function body may import, and why (everything else, the
#: project's own modules and the standard library included, is imported at the top)
DEFERRABLE = {
    "mitsuba": "the renderer: 0.4 s to import, and a variant to choose first "
               "(hack_render.render.engine)",
    "drjit": "Mitsuba's JIT, imported with it (variant first)",
    "torch": "2.2 s to import: NumPy paths and commands that need no tensors avoid it",
    "scipy": "0.25-0.8 s a subpackage (ndimage, optimize, sparse, spatial), few functions "
             "need one",
    "skimage": "scikit-image's subpackages load lazily and cost 0.3-1 s each",
    "matplotlib": "pyplot costs 0.9 s; only figure-writing functions need it",
    "colour": "colour-science costs 1.3-1.6 s to import; only colour conversions need it",
    "trimesh": "1.2 s to import; only mesh files of other tools need it",
    "dlib": "the `fit` extra (optional)",
    "face_recognition_models": "the `fit` extra (optional)",
    "mediapipe": "the `fit` extra (optional; no wheel for Python 3.13+)",
    "ai_edge_litert": "the `fit` extra (optional)",
    "cv2": "OpenCV comes with mediapipe, the `fit` extra (optional)",
    "pyoidn": "the `denoise` extra (optional)",
    "ray": "the `ray` extra (optional)",
    "bpy": "the `blender` extra (optional, ~400 MB)",
    "smplx": "the `bench` extra (optional)",
}

#: the project's own modules that a module may still import lazily (in a function, or by a
#: package's ``_LAZY`` table of re-exported names), each for its reason: all of them keep
#: torch (2.2 s) off a path that runs without it (`hack-render mesh` poses in NumPy,
#: `render` reads its mesh cache). Counted in the issue's note; keep it short.
DEFERRED_OWN: dict[tuple[str, str], str] = {
    ("hack_render.geometry.limits", "hack_render.geometry.skeleton"):
        "torch: clamping a tensor theta; NumPy posing shares apply_limit_policy",
    ("hack_render.geometry.cli", "hack_render.geometry.loading"):
        "torch: `model info` loads the torch model; `mesh`, in the same module, poses in NumPy",
    ("hack_render.render.skin_maps", "appearance.model"):
        "torch: only --alpha needs the PCA model; renders from texture files or the mesh "
        "cache run without torch",
    ("hack_render.render.skin_maps", "appearance.generator"):
        "torch: only --appearance-seed needs the generator (as for appearance.model)",
}

#: the engines that a command's ``--help`` must not import (tests/test_cli.py checks every
#: ``--help`` in one process): a command module (``cli.py``, ``*_cli.py``) imports a
#: module whose import loads one of them inside the command's function, where the command
#: runs, and only such a module
HEAVY_AT_HELP = ("torch", "mitsuba", "drjit", "scipy", "dlib", "ray", "skimage",
                 "matplotlib", "colour", "trimesh", "cv2", "mediapipe")

#: the packages that re-export their modules' names lazily (a ``_LAZY`` name -> module
#: table and ``__getattr__``): importing any module of a package runs its ``__init__``, so
#: these stay light for the reason given
LAZY_PACKAGES = {
    "hack_render.geometry": "its NumPy modules (posing, params, limits, model_file) run "
                            "without torch: `hack-render mesh`, the render's mesh cache",
    "appearance": "its texture IO and UV layout serve renders from texture files without "
                  "torch, and `appearance --help` imports the package",
    "hack_render.dataset": "`dataset --help` imports the package; its modules load Mitsuba",
}

#: what ``hack_render.cli`` may import before a command runs (``hack-render --help``)
LIGHT_AT_HELP = ("torch", "mitsuba", "drjit", "numpy", "scipy", "colour", "trimesh",
                 "matplotlib", "dlib", "mediapipe", "cv2")


# ----------------------------------------------------------------------------- parsing


def modules() -> dict[str, Path]:
    """Every module of the three packages, by dotted name (a package by its name)."""
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


class Import:
    """One imported name: the module it resolves to (an own module, or a third-party or
    standard-library top-level name), the name taken from it (None for a module), the
    line, and whether it stands inside a function."""

    __slots__ = ("in_function", "lazy_table", "line", "module", "name", "type_only")

    def __init__(self, module, name, line, in_function, type_only=False, lazy_table=False):
        self.module, self.name, self.line, self.in_function = module, name, line, in_function
        self.type_only = type_only  # under `if TYPE_CHECKING:`: never run
        self.lazy_table = lazy_table  # a package's `_LAZY` name -> module table

    def __repr__(self):
        where = "in a function" if self.in_function else "at the top"
        return f"line {self.line}: {self.module}{'.' + self.name if self.name else ''} ({where})"


def parse_imports(source: str, modname: str, is_package: bool,
                  mods: dict[str, Path]) -> list[Import]:
    """Every import in ``source`` at any depth, resolved against ``mods``."""
    tree = ast.parse(source)
    parents = {}
    for node in ast.walk(tree):
        for child in ast.iter_child_nodes(node):
            parents[child] = node

    def type_only(node):
        while node in parents:
            node = parents[node]
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                return True
        return False

    def in_function(node):
        while node in parents:
            node = parents[node]
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                return True
        return False

    def own(target):  # the deepest own module that target names
        while target not in mods and "." in target:
            target = target.rsplit(".", 1)[0]
        return target

    out = []
    pkg_name = modname if is_package else modname.rsplit(".", 1)[0]
    for node in tree.body:  # a package's table of lazily imported names: {name: submodule}
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "_LAZY"
                                                for t in node.targets) and \
                isinstance(node.value, ast.Dict):
            for v in node.value.values:
                if isinstance(v, ast.Constant) and isinstance(v.value, str):
                    target = v.value if v.value.split(".")[0] in PACKAGES else \
                        f"{pkg_name}.{v.value}"
                    out.append(Import(own(target), None, node.lineno, True, lazy_table=True))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                top = a.name.split(".")[0]
                mod = own(a.name) if top in PACKAGES else top
                out.append(Import(mod, None, node.lineno, in_function(node), type_only(node)))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = modname.split(".") if is_package else modname.split(".")[:-1]
                pkg = pkg[:len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([base] if base else []))
            top = base.split(".")[0]
            for a in node.names:
                sub = f"{base}.{a.name}"
                where = (node.lineno, in_function(node), type_only(node))
                if top not in PACKAGES:
                    out.append(Import(top, None, *where))
                elif sub in mods:
                    out.append(Import(sub, None, *where))
                else:
                    out.append(Import(own(base), a.name, *where))
    return out


def lazy_tables(mods: dict[str, Path]) -> dict[str, dict[str, str]]:
    """Each package's ``_LAZY`` table: {package: {name: module}}."""
    out = {}
    for m, p in mods.items():
        if p.name != "__init__.py":
            continue
        for node in ast.parse(p.read_text()).body:
            if isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id == "_LAZY" for t in node.targets):
                out[m] = {k.value: (v.value if v.value.split(".")[0] in PACKAGES
                                    else f"{m}.{v.value}")
                          for k, v in zip(node.value.keys, node.value.values)}
    return out


def all_imports(mods: dict[str, Path] | None = None) -> dict[str, list[Import]]:
    """Every module's imports; the command line's lazily imported modules
    (``hack_render.cli.COMMANDS``, ``VERSION_MODULES``: imported by name when a command
    runs) count as imports of ``hack_render.cli`` made in a function."""
    from hack_render import cli

    mods = mods or modules()
    out = {m: parse_imports(p.read_text(), m, p.name == "__init__.py", mods)
           for m, p in mods.items()}
    # `from pkg import name` of a lazily re-exported name imports the module behind it
    tables = lazy_tables(mods)
    for imps in out.values():
        for i in imps:
            if i.module in tables and i.name in tables[i.module]:
                i.module, i.name = tables[i.module][i.name], None
    lazy = {m for _, ms in cli.COMMANDS.values() for m in ms} | set(cli.VERSION_MODULES)
    out["hack_render.cli"] += [Import(m, None, 0, True) for m in sorted(lazy)]
    return out


def is_own(module: str) -> bool:
    return module.split(".")[0] in PACKAGES


def graph(imports: dict[str, list[Import]]) -> dict[str, set[str]]:
    """Module -> the own modules it imports (at any depth), itself excluded."""
    return {m: {i.module for i in imps if is_own(i.module) and i.module != m}
            for m, imps in imports.items()}


def package_of(module: str) -> str:
    parts = module.split(".")
    return parts[0] if parts[0] != "hack_render" or len(parts) == 1 else ".".join(parts[:2])


def layer(module: str) -> int:
    best, rank = "", None
    for r, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > len(best):
                best, rank = name, r
    assert rank is not None, f"{module} is in no layer: add its package to LAYERS"
    return rank


def upward(g: dict[str, set[str]]) -> list[str]:
    return sorted(f"{a} (layer {layer(a)}) -> {b} (layer {layer(b)})"
                  for a, deps in g.items() for b in deps if layer(b) > layer(a))


def cycle(g: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``g`` (a list closing on its first element), or None."""
    state, stack = {}, []
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(g.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state:
                found = visit(d)
                if found:
                    return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(g):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def package_graph(g: dict[str, set[str]]) -> dict[str, set[str]]:
    out = defaultdict(set)
    for a, deps in g.items():
        for b in deps:
            if package_of(a) != package_of(b):
                out[package_of(a)].add(package_of(b))
    return dict(out)


def private_imports(imports: dict[str, list[Import]]) -> list[str]:
    return sorted(f"{m} {i!r}" for m, imps in imports.items() for i in imps
                  if is_own(i.module) and i.module != m and i.name
                  and i.name.startswith("_") and not i.name.startswith("__"))


def is_command_module(module: str) -> bool:
    last = module.rsplit(".", 1)[-1]
    return last == "cli" or last.endswith("_cli")


def heavy_at_import(imports: dict[str, list[Import]]) -> set[str]:
    """The own modules whose import (their top-level imports, their packages' too, and so
    on) loads one of :data:`HEAVY_AT_HELP`."""
    deps = {}
    for m, imps in imports.items():
        d = {i.module for i in imps if not i.in_function and not i.type_only}
        parts = m.split(".")
        d |= {".".join(parts[:k]) for k in range(1, len(parts))}  # the packages run first
        deps[m] = d - {m}
    heavy, changed = set(), True
    while changed:
        changed = False
        for m, d in deps.items():
            if m not in heavy and any(x.split(".")[0] in HEAVY_AT_HELP or x in heavy for x in d):
                heavy.add(m)
                changed = True
    return heavy


def deferred(imports: dict[str, list[Import]]) -> tuple[list[str], dict[str, int]]:
    """(function-level imports that are not allowed, count of the allowed ones by module)."""
    bad, ok = [], defaultdict(int)
    heavy = heavy_at_import(imports)
    for m, imps in imports.items():
        for i in imps:
            if not i.in_function or (m == "hack_render.cli" and i.line == 0):
                continue  # the command line's lazy modules (all_imports)
            top = i.module.split(".")[0]
            if top in DEFERRABLE:
                ok[top] += 1
            elif (m, i.module) in DEFERRED_OWN:
                ok[i.module] += 1
            elif i.lazy_table and m in LAZY_PACKAGES:
                ok[f"{m} (lazy names)"] += 1
            elif is_command_module(m) and is_own(i.module) and i.module in heavy:
                ok["a command's implementation"] += 1
            else:
                bad.append(f"{m} {i!r}")
    return sorted(bad), dict(ok)
