"""The package's shape: every module imports in a fresh interpreter, the import graph has no
cycle (every import counts: module level, inside functions, and type-checking only), the
library never imports the service, and no source file grows past MAX_LINES."""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: installed name -> source folder (pyproject's package-dir)
PACKAGES = {
    "tactus_memory": ROOT / "tactus_memory",
    "tactus_memory.adapters": ROOT / "adapters",
    "tactus_memory.service": ROOT / "service",
}
#: the size a source file should stay under (issue 10: "no source file over ~500 lines")
MAX_LINES = 500


def modules() -> dict[str, Path]:
    """Every module of the package, by its installed dotted name."""
    out: dict[str, Path] = {}
    for pkg, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            rel = path.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            name = ".".join([pkg, *parts])
            out[name] = path
    return out


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The package modules ``name`` imports (absolute and relative, anywhere in the file)."""
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text(), str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".") if is_pkg else name.split(".")[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        for t in targets:
            # the longest known module the target names (``pkg.mod.Name`` -> ``pkg.mod``)
            parts = t.split(".")
            for i in range(len(parts), 0, -1):
                cand = ".".join(parts[:i])
                if cand in known:
                    if cand != name:
                        found.add(cand)
                    break
    return found


@functools.cache  # one walk per test process (the tests only read it): ~4 s each on 2 cores
def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {name: imports_of(name, path, known) for name, path in mods.items()}


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10_000)
    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_the_walker_sees_a_cycle_when_there_is_one() -> None:
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(g) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_in_the_package() -> None:
    g = graph()
    assert len(g) > 60  # the walk found the package (tactus_memory, adapters, service)
    assert "tactus_memory.temporal.operators" in g["tactus_memory.memory.main"]
    assert cycles(g) == []


def test_the_library_never_imports_the_service() -> None:
    g = graph()
    for name, deps in g.items():
        if name.startswith("tactus_memory.service") or name.startswith("tactus_memory.cli"):
            continue  # the CLI is the application layer (``tactus serve``)
        assert not [d for d in deps if d.startswith("tactus_memory.service")], name


#: the layers above the models, lowest first: each is one package, named as its layer
PACKAGE_LAYERS = (
    "adapters", "storage", "search", "temporal", "memory", "recordings", "export", "training",
    "client", "mcp", "service", "cli"
)  # fmt: skip

#: modules that live in another layer's package (a package that holds one contract whose
#: parts sit at different heights: ``senses/`` has the Sense contract and the plug-in registry
#: in the base, the store's sense registry in search)
LAYER_EXTRA: dict[str, tuple[str, ...]] = {"search": ("tactus_memory.senses.stored",)}

#: The base's inner order, bottom to top: the vocabulary (errors, limits, results, the name
#: validators...) that imports nothing of the package above it; the contracts (a space, a
#: sense, the plug-in registry); the query vocabulary (filters, scopes, batches, the match
#: bar); the configuration (policies, settings); the front (the package's ``__init__`` and the
#: Memory/Client contract). Each is a layer of LAYER_MAP, so the layer test checks the order.
BASE_LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "base: vocabulary",
        (
            "tactus_memory.errors",
            "tactus_memory.limits",
            "tactus_memory.names",
            "tactus_memory.results",
            "tactus_memory.hashing",
            "tactus_memory.signatures",
            "tactus_memory.vectors",
            "tactus_memory.times",
        ),
    ),
    ("base: contracts", ("tactus_memory.spaces.base", "tactus_memory.senses")),
    (
        "base: query",
        (
            "tactus_memory.where",
            "tactus_memory.identity",
            "tactus_memory.query",
            "tactus_memory.batches",
            "tactus_memory.matching",
        ),
    ),
    ("base: configuration", ("tactus_memory.policies", "tactus_memory.settings")),
    ("base: front", ("tactus_memory", "tactus_memory.contract")),
)

#: The layer map, bottom to top (docs/architecture.md draws it). A module belongs to the layer
#: whose entry names it most precisely (``tactus_memory.spaces.base`` is base, the rest of
#: ``tactus_memory.spaces`` is models); it may import its own layer and the layers below, never
#: one above. ``tactus_memory`` alone is the package's ``__init__``.
LAYER_MAP: tuple[tuple[str, tuple[str, ...]], ...] = (
    *BASE_LAYERS,
    ("models", ("tactus_memory.spaces", "tactus_memory.touch", "tactus_memory.datasets")),
    # every layer above the models is the one package of its name (and the modules named
    # in LAYER_EXTRA: the store's sense registry, in senses/ beside the contract, is search's)
    *((name, (f"tactus_memory.{name}", *LAYER_EXTRA.get(name, ()))) for name in PACKAGE_LAYERS),
)
#: layers that may import only some of the layers below them (the remote client needs no
#: store, search or model code: it speaks HTTP and shares the base's vocabulary)
ONLY: dict[str, tuple[str, ...]] = {"client": tuple(name for name, _ in BASE_LAYERS)}


def _under(name: str, pkg: str) -> bool:
    return name == pkg or name.startswith(pkg + ".")


def layer_of(name: str) -> int | None:
    """The index in LAYER_MAP of the layer ``name`` belongs to (its most precise entry)."""
    best: tuple[int, int] | None = None  # (entry length, layer index)
    for i, (_, entries) in enumerate(LAYER_MAP):
        for e in entries:
            found = (name == e) if e == "tactus_memory" else _under(name, e)
            if found and (best is None or len(e) > best[0]):
                best = (len(e), i)
    return None if best is None else best[1]


def layer_violations(g: dict[str, set[str]]) -> list[str]:
    """``module -> import`` edges that go up the layer map (or, for a layer in ONLY, to a
    layer it may not use)."""
    wrong = []
    for name, deps in sorted(g.items()):
        mine = layer_of(name)
        if mine is None:
            continue
        allowed = ONLY.get(LAYER_MAP[mine][0])
        for d in sorted(deps):
            theirs = layer_of(d)
            if theirs is None:
                continue
            if theirs > mine or (
                allowed is not None and theirs != mine and LAYER_MAP[theirs][0] not in allowed
            ):
                wrong.append(f"{name} -> {d}")
    return wrong


def test_the_layer_check_sees_an_upward_import() -> None:
    g = {
        "tactus_memory.storage.store": {"tactus_memory.search.ranking", "tactus_memory.errors"},
        "tactus_memory.search.ranking": {"tactus_memory.where", "tactus_memory.memory.main"},
        "tactus_memory.temporal.clocks": {"tactus_memory.search.ranking"},
        "tactus_memory.spaces.base": {"tactus_memory.spaces.minilm"},
        "tactus_memory.client.main": {"tactus_memory.search.grasps", "tactus_memory.results"},
        # inside the base: the vocabulary below the filters, the filters below the settings
        "tactus_memory.errors": {"tactus_memory.where"},
        "tactus_memory.where": {"tactus_memory.senses.base", "tactus_memory.settings"},
    }
    assert layer_violations(g) == [
        "tactus_memory.client.main -> tactus_memory.search.grasps",
        "tactus_memory.errors -> tactus_memory.where",
        "tactus_memory.search.ranking -> tactus_memory.memory.main",
        "tactus_memory.spaces.base -> tactus_memory.spaces.minilm",
        "tactus_memory.storage.store -> tactus_memory.search.ranking",
        "tactus_memory.where -> tactus_memory.settings",
    ]


def test_every_module_has_a_layer() -> None:
    assert [name for name in graph() if layer_of(name) is None] == []


def test_layers_import_only_downwards() -> None:
    g = graph()
    for _, entries in LAYER_MAP:
        for e in entries:
            assert any(_under(name, e) for name in g), e  # the walk found every entry
    assert layer_violations(g) == []


def test_recordings_cut_windows_through_the_sense() -> None:
    """Ingest asks the mapped sense to decode and to window (``Sense.from_message``,
    ``WindowedSense.window_stream``): it imports no touch module and no sense adapter (the ROS 2
    message helpers of ``adapters/decode.py`` serve every sense)."""
    g = graph()
    deps = g["tactus_memory.recordings.ingest"] | g["tactus_memory.recordings.decoding"]
    adapters = {f"tactus_memory.adapters.{s}" for s in ("text", "image", "vectors", "touch")}
    assert [d for d in deps if _under(d, "tactus_memory.touch") or d in adapters] == []


def touch_imports(g: dict[str, set[str]], under: str) -> list[str]:
    """``module -> import`` edges from the modules under ``under`` to touch's own modules
    (``tactus_memory.touch``) or the touch adapter (``tactus_memory.adapters.touch*``)."""
    return sorted(
        f"{n} -> {d}"
        for n, deps in g.items()
        if _under(n, under)
        for d in deps
        if _under(d, "tactus_memory.touch") or d.startswith("tactus_memory.adapters.touch")
    )


def test_the_touch_check_sees_a_touch_import() -> None:
    g = {
        "tactus_memory.service.routers.ui": {"tactus_memory.touch.render"},
        "tactus_memory.service.arrays": {"tactus_memory.errors"},
        "tactus_memory.service.app": {"tactus_memory.adapters.touch_drawing"},
        "tactus_memory.adapters.touch": {"tactus_memory.touch.windows"},
    }
    assert touch_imports(g, "tactus_memory.service") == [
        "tactus_memory.service.app -> tactus_memory.adapters.touch_drawing",
        "tactus_memory.service.routers.ui -> tactus_memory.touch.render",
    ]


def test_the_service_knows_senses_not_touch() -> None:
    """No service module imports ``tactus_memory.touch`` (or the touch adapter): windowed
    writes, streams, drawing and search by example go through the windowed-sense contract
    (``senses/windowed.py``) and the plug-in registry (issue 49)."""
    g = graph()
    assert any(_under(n, "tactus_memory.service") for n in g)
    assert touch_imports(g, "tactus_memory.service") == []


def test_storage_gets_its_configuration_passed_in() -> None:
    """No ``Settings`` read inside storage: the memory (or the service) reads it once."""
    g = graph()
    assert [
        n for n in g if _under(n, "tactus_memory.storage") and "tactus_memory.settings" in g[n]
    ] == []


def test_every_module_imports_in_a_fresh_interpreter() -> None:
    names = sorted(modules())
    code = (
        "import importlib, sys\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name)\n"
        "print(len(sys.modules))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT
    )
    assert r.returncode == 0, r.stderr[-3000:]


def test_no_source_file_is_over_max_lines() -> None:
    long = {
        str(path.relative_to(ROOT)): n
        for path in modules().values()
        if (n := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert long == {}


def defined_names(path: Path) -> set[str]:
    """Names a module defines itself at top level (def, class, assignment), not imports."""
    out: set[str] = set()
    for node in ast.parse(path.read_text(), str(path)).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
    return out


def test_every_name_is_imported_from_the_module_that_owns_it() -> None:
    """No re-export shims: ``from M import N`` (library, service, tests, benchmarks) names
    the module M that defines N (or N is a submodule of M)."""
    mods = modules()
    owned = {name: defined_names(path) for name, path in mods.items()}
    files = [*mods.values(), *sorted((ROOT / "tests").rglob("*.py"))]
    files += sorted((ROOT / "benchmarks").glob("*.py"))
    wrong = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.ImportFrom) or node.level or node.module not in mods:
                continue
            for alias in node.names:
                if (
                    alias.name not in owned[node.module]
                    and f"{node.module}.{alias.name}" not in mods
                ):
                    wrong.append(
                        f"{path.relative_to(ROOT)}:{node.lineno} {node.module}.{alias.name}"
                    )
    assert wrong == []


#: what serving must never load: training, evaluation, the STAG .mat reader, plotting, Ray
NOT_SERVED = (
    "h5py",
    "scipy.io",
    "matplotlib",
    "tactus_memory.cli",
    "tactus_memory.datasets.stag",
    "tactus_memory.training",
    # bulk work on Ray (tactus_memory/recordings/ray_jobs.py) loads only for --ray
    "ray",
    "lance_ray",
)


def test_serving_loads_nothing_of_training_plotting_or_mat_reading(tmp_path: Path) -> None:
    """The app, built on a real store with the shipped touch encoder, in a fresh interpreter:
    no training, evaluation, plotting or ``.mat`` reading module is in ``sys.modules``."""
    code = (
        "import sys\n"
        "from tactus_memory.service.app import create_app\n"
        "from tactus_memory.settings import Settings\n"
        f"app = create_app(Settings(data={str(tmp_path / 'm')!r}))\n"
        "assert 'touch' in app.state.tactus.memory.senses, app.state.tactus.touch_unavailable\n"
        f"bad = sorted(m for m in sys.modules if m.startswith({NOT_SERVED!r}))\n"
        "print(bad)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.strip().splitlines()[-1] == "[]"


def _imported_modules(path: Path) -> set[str]:
    """Every module ``path`` names in an import (``from a import b`` gives ``a`` and ``a.b``)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def test_no_test_module_imports_another() -> None:
    """Shared pieces live in tests/helpers/ (and fixtures in conftest.py), never in a test."""
    wrong = [
        f"{path.relative_to(ROOT)} -> {name}"
        for path in sorted((ROOT / "tests").rglob("*.py"))
        for name in sorted(_imported_modules(path))
        if name.startswith("tests.") and name.rsplit(".", 1)[-1].startswith("test_")
    ]
    assert wrong == []


def test_benchmarks_import_the_package_not_the_tests() -> None:
    wrong = [
        f"{path.relative_to(ROOT)} -> {name}"
        for path in sorted((ROOT / "benchmarks").rglob("*.py"))
        for name in sorted(_imported_modules(path))
        if name == "tests" or name.startswith("tests.")
    ]
    assert wrong == []


def test_tests_mirror_the_package() -> None:
    """A test module sits in the folder of the layer it tests (tests/storage/, ...), helpers
    in tests/helpers/: none lies loose at the top of tests/."""
    loose = [p.name for p in (ROOT / "tests").glob("test_*.py")]
    assert loose == []
    folders = {p.name for p in (ROOT / "tests").iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert {"helpers", "storage", "search", "temporal", "memory", "service"} <= folders


# ------------------------------------------------------------------ the docs' architecture page
PAGE = ROOT / "docs" / "architecture.md"
#: the package folders as the checkout has them, in the order the page lists them
TREE_ROOTS = (("tactus_memory", ROOT / "tactus_memory"), ("adapters", ROOT / "adapters"),
              ("service", ROOT / "service"))  # fmt: skip


def render_tree() -> str:
    """One line per package folder: its path and its modules (``__init__`` left out)."""
    lines = []
    for label, folder in TREE_ROOTS:
        for d in sorted([folder, *(p for p in folder.rglob("*") if p.is_dir())]):
            if not (d / "__init__.py").exists():
                continue  # data folders (configs, checkpoints, plans, static)
            mods = sorted(p.stem for p in d.glob("*.py") if p.stem != "__init__")
            rel = label + "/" + d.relative_to(folder).as_posix() + "/"
            lines.append(f"{rel.replace('/./', '/'):<28}{' '.join(mods)}".rstrip())
    return "```text\n" + "\n".join(lines) + "\n```"


def render_layers() -> str:
    rows = ["| layer | packages and modules |", "| --- | --- |"]
    for name, entries in LAYER_MAP:
        shown = [e.removeprefix("tactus_memory.") if e != "tactus_memory" else "__init__"
                 for e in entries]  # fmt: skip
        rule = " (imports only the base)" if name in ONLY else ""
        rows.append(f"| {name}{rule} | {', '.join(f'`{s}`' for s in shown)} |")
    return "\n".join(rows)


def _block(text: str, name: str) -> str:
    start, end = f"<!-- {name}:start -->\n", f"\n<!-- {name}:end -->"
    return text[text.index(start) + len(start) : text.index(end)]


def write_page() -> None:
    text = PAGE.read_text()
    for name, body in (("tree", render_tree()), ("layers", render_layers())):
        old = _block(text, name)
        text = text.replace(f"<!-- {name}:start -->\n{old}", f"<!-- {name}:start -->\n{body}")
    PAGE.write_text(text)


def test_the_docs_page_shows_the_tree_and_the_layer_map_as_they_are() -> None:
    text = PAGE.read_text()
    assert _block(text, "tree") == render_tree()
    assert _block(text, "layers") == render_layers()


def test_every_file_the_docs_page_names_exists() -> None:
    """Paths in backticks (``memory/writes.py``, ``service/routers/touch.py``) name real files:
    under the checkout, or under ``tactus_memory/``."""
    import re

    named = set(re.findall(r"`([\w/]+\.py)[`.:]", PAGE.read_text()))
    assert len(named) > 20
    missing = [
        n for n in sorted(named)
        if not (ROOT / n).exists() and not (ROOT / "tactus_memory" / n).exists()
    ]  # fmt: skip
    assert missing == []


if __name__ == "__main__":  # python -m tests.project.test_architecture: rewrite the page's blocks
    write_page()
