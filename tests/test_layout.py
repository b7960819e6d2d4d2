"""The shape of the house (README "What it does"): data flows one way, bytes -> frames ->
samples -> monitor -> verdicts -> status, and no import runs back up.

Every module of the package is parsed and its imports (function-level ones too) are
resolved to modules of the package; a test fails on an import cycle between modules, on an
arrow running up a floor, and on a module that no floor claims.
"""

from __future__ import annotations

import ast
import functools
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Installed package -> its directory in the tree (pyproject's package-dir).
PACKAGE_DIRS = {
    "imudiag": ROOT / "imudiag",
    "imudiag.drivers": ROOT / "drivers",
    "imudiag.config": ROOT / "config",
}

#: Floors, bottom up: a module imports only from its own floor or below. Each entry is a
#: module or a package prefix; the longest matching prefix decides. These are the rows of
#: the README's stage table ("What it does"), in order, entry for entry (tested below): a
#: new module gets its floor here and its place in that table.
FLOORS: list[tuple[str, ...]] = [
    # 0 ground: errors, the YAML loader, atomic files, bundled configuration, value checks,
    # the Earth model, the switch of the optional compiled kernels and the kernels
    (
        "imudiag.errors",
        "imudiag.units",
        "imudiag.yamlio",
        "imudiag.atomic",
        "imudiag.config",
        "imudiag.reports",
        "imudiag.progress",
        "imudiag.argtypes",
        "imudiag.validate",
        "imudiag.earth",
        "imudiag.kernels",
        "imudiag.numba_kernels",
    ),
    # 1 data: samples with units, the certificate model, rotations, arithmetic on rows
    ("imudiag.samples", "imudiag.certificate", "imudiag.rotations", "imudiag.rowwise"),
    # 2 wire: bytes <-> frames <-> samples
    ("imudiag.drivers.wire", "imudiag.drivers.crc"),
    # 3 transports: byte sources by URL
    ("imudiag.drivers",),
    # 4 logs
    ("imudiag.logs",),
    # 5 monitor: the per-sample checks and what they stand on
    (
        "imudiag.monitor",
        "imudiag.quasistatic",
        "imudiag.persistence",
        "imudiag.ringbuffer",
        "imudiag.trailing",
        "imudiag.noise_estimate",
        "imudiag.vibration",
        "imudiag.scalar",
        "imudiag.stats",
    ),
    # 6 verdicts: window diagnosis, aiding, model check, simulator, Allan, other tools
    (
        "imudiag.diagnosis",
        "imudiag.aiding",
        "imudiag.modelcheck",
        "imudiag.sim",
        "imudiag.noise_stats",
        "imudiag.interop",
        "imudiag.plots",
    ),
    # 7 sources above the transports: sim://, replay://
    ("imudiag.sources",),
    # 8 service: the daemon
    ("imudiag.service",),
    # 9 faces: the library API, the command line, the bench
    (
        "imudiag",
        "imudiag.api",
        "imudiag.cli",
        "imudiag.__main__",
        "imudiag.commands",
        "imudiag.bench",
        "imudiag.fleet",
    ),
]
#: The README table's stage names, one per floor.
STAGES = [
    "ground",
    "data",
    "bytes -> frames",
    "transports",
    "samples",
    "monitor",
    "verdicts",
    "sources above",
    "status",
    "faces",
]


def _modules() -> dict[str, Path]:
    mods: dict[str, Path] = {}
    for base, directory in PACKAGE_DIRS.items():
        for path in directory.rglob("*.py"):
            parts = list(path.relative_to(directory).with_suffix("").parts)
            if base == "imudiag" and parts[0] in ("drivers", "config"):
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join([base, *parts])] = path
    return mods


MODULES = _modules()


def _is_module(name: str) -> bool:
    return name in MODULES or (name.startswith("drivers.") and "imudiag." + name in MODULES)


@functools.cache
def _tree(path: Path) -> ast.Module:
    """A module's syntax tree, parsed once for the tests that read it."""
    return ast.parse(path.read_text(), str(path))


def _imports(name: str, path: Path) -> set[str]:
    """The package's modules that ``name`` imports anywhere in its text."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    tree = _tree(path)
    type_only = {  # `if TYPE_CHECKING:` blocks run under a type checker only
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and ast.unparse(block.test).endswith("TYPE_CHECKING")
        for stmt in block.body
        for n in ast.walk(stmt)
    }
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package
                for _ in range(node.level - 1):
                    base = base.rpartition(".")[0]
                base = f"{base}.{node.module}" if node.module else base
            else:
                base = node.module or ""
            names = [f"{base}.{a.name}" for a in node.names]
            # `from pkg import module` imports the module; `from pkg import name`, the package
            candidates = names + ([base] if not all(_is_module(n) for n in names) else [])
        elif isinstance(node, ast.Import):
            candidates = [a.name for a in node.names]
        else:
            continue
        for c in candidates:
            if c == "drivers" or c.startswith("drivers."):
                c = "imudiag." + c  # the tree's own name for imudiag.drivers
            if c in MODULES and c != name:
                found.add(c)
    return found


@functools.cache
def graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports; parsed on first use, once a process (not
    at import: every pytest worker and the real-time tier import this file to collect it)."""
    return {name: _imports(name, path) for name, path in MODULES.items()}


def floor(name: str) -> int:
    """The floor of a module: the one whose longest entry is a prefix of its name."""
    best, best_len = -1, -1
    for level, entries in enumerate(FLOORS):
        for entry in entries:
            if (name == entry or name.startswith(entry + ".")) and len(entry) > best_len:
                best, best_len = level, len(entry)
    return best


def test_the_walk_sees_the_package():
    assert len(MODULES) > 100
    assert "imudiag.drivers.wire" in MODULES and "imudiag.sources.sim" in MODULES
    assert "imudiag.logs" in graph()["imudiag.sources.replay"]  # function-level imports count


def test_every_module_has_a_floor():
    assert [m for m in MODULES if floor(m) < 0] == []


def _readme_stages() -> list[tuple[str, tuple[str, ...]]]:
    """The README's stage table: (stage, module entries) per row, in order. ``.name`` is
    short for a sibling of the entry before it (``imudiag.errors``, ``.yamlio``); a path in
    backticks (``config/``) is the directory, not an entry."""
    text = (ROOT / "README.md").read_text()
    table = text[text.index("| stage | module | what |") :].split("\n\n")[0]
    rows = []
    for line in table.splitlines()[2:]:
        stage, modules = (cell.strip() for cell in line.strip("|").split("|")[:2])
        entries: list[str] = []
        for name in re.findall(r"`([^`]+)`", modules):
            if "/" in name:
                continue
            if name.startswith("."):
                name = entries[-1].rpartition(".")[0] + name
            entries.append(name)
        rows.append((stage, tuple(entries)))
    return rows


def test_the_readme_stage_table_is_the_floors():
    """Issue 30 item 3: the floors the README names are the floors enforced here, entry for
    entry, so "monitor -> verdicts" and "verdicts -> status" are checked, not only said."""
    readme = [(stage, sorted(entries)) for stage, entries in _readme_stages()]
    assert readme == [(stage, sorted(e)) for stage, e in zip(STAGES, FLOORS, strict=True)]


def test_every_floor_entry_names_a_module():
    """No entry of the table (and so of the floors) names a module that does not exist."""
    stale = [e for entries in FLOORS for e in entries if e not in MODULES]
    assert stale == []


def test_the_monitor_stands_below_the_verdicts():
    """The per-sample checks import nothing of the window diagnosis, aiding, model check or
    simulator; the simulator imports no analysis (the Earth model is on the ground floor)."""
    verdicts = FLOORS[STAGES.index("verdicts")]
    assert all(floor(d) <= floor("imudiag.monitor") for m, deps in graph().items()
               if floor(m) == floor("imudiag.monitor") for d in deps)  # fmt: skip
    analyses = tuple(v for v in verdicts if v != "imudiag.sim")
    from_sim = sorted(
        f"{m} imports {d}"
        for m, deps in graph().items()
        if m.startswith("imudiag.sim")
        for d in deps
        if d.startswith(analyses)
    )
    assert from_sim == []


def test_plain_mypy_finds_the_installed_layout():
    """``mypy -p imudiag`` from the root (.ci/style.py) reaches imudiag.drivers and
    imudiag.config through links to the top-level drivers/ and config/ (pyproject's
    package-dir), so an editable install type-checks without staging."""
    for name in ("drivers", "config"):
        link = ROOT / "imudiag" / name
        assert link.is_symlink() and os.readlink(link) == f"../{name}", link
        assert (ROOT / name).is_dir() and not (ROOT / name).is_symlink()


def test_ci_runs_the_readme_suite_command():
    """.ci/run runs exactly the README's second quick-start command (the whole suite)."""
    readme = (ROOT / "README.md").read_text()
    block = readme[readme.index("## Quick start") :].split("```sh\n")[1].split("```")[0]
    command = block.splitlines()[1]
    assert ".ci/suite.py" in command
    ci = (ROOT / ".ci" / "run").read_text().rstrip().splitlines()
    assert ci[-1] == command


def test_no_import_runs_up_a_floor():
    up = sorted(
        f"{m} (floor {floor(m)}) imports {d} (floor {floor(d)})"
        for m, deps in graph().items()
        for d in deps
        if floor(d) > floor(m)
    )
    assert up == []


def test_no_import_cycle():
    """Tarjan's strongly connected components of the module graph: none of two or more."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph()[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph()):
        if v not in index:
            visit(v)
    assert cycles == []


@pytest.mark.parametrize("bottom", ["imudiag.drivers.wire", "imudiag.drivers.crc"])
def test_the_wire_codec_is_the_bottom(bottom):
    """The codec imports nothing of the package but the ground and data floors."""
    assert {d for d in graph()[bottom] if floor(d) >= floor(bottom) and d != bottom} <= {
        "imudiag.drivers.crc"
    }


def test_sources_above_the_drivers_come_through_entry_points():
    """sim:// and replay:// are found through the installed package's entry points, so the
    driver layer names no module above it; a broken plug-in says what broke."""
    from importlib.metadata import EntryPoint

    from imudiag.drivers import base

    eps = base._entry_points()
    assert eps["sim"].value == "imudiag.sources.sim:SimSource"
    assert eps["replay"].value == "imudiag.sources.replay:ReplaySource"
    assert base.source_class("sim").__module__ == "imudiag.sources.sim"
    broken = EntryPoint("nosuch", "imudiag.sources.nosuch:NoSource", base.ENTRY_POINT_GROUP)
    with pytest.raises(base.SourceError, match="nosuch://.*cannot be loaded.*ModuleNotFound"):
        base._load_entry_point("nosuch", broken)
    not_a_source = EntryPoint("notsrc", "imudiag.samples:SampleBlock", base.ENTRY_POINT_GROUP)
    with pytest.raises(base.SourceError, match="not a Source class"):
        base._load_entry_point("notsrc", not_a_source)
    assert "notsrc" not in base._REGISTRY


def test_no_module_imports_another_modules_private_names():
    private = []
    for name, path in MODULES.items():
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ImportFrom) and (
                node.level or "imudiag" in (node.module or "")
            ):
                private += [
                    f"{name} imports {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert private == []


def test_quaternion_helpers_live_in_one_module():
    """The gyro fit and the model check's rotation channel share imudiag.rotations."""
    assert "imudiag.rotations" in graph()["imudiag.diagnosis.gyro_fit"]
    assert "imudiag.rotations" in graph()["imudiag.modelcheck.rotations"]
    assert "imudiag.diagnosis.gyro_fit" not in graph()["imudiag.modelcheck.rotations"]


def test_the_split_packages_keep_each_algorithm_apart_from_its_machinery():
    """Issue 30 item 6: ``imudiag.quasistatic`` and ``imudiag.monitor`` are packages whose
    algorithm module (``detector``, ``checks``) stands on its machinery through named
    interfaces; the machinery imports nothing of the algorithm, and nothing inside a
    package imports its own ``__init__`` (the public re-exports, kept for the old paths)."""
    inside = {
        "imudiag.quasistatic": ("detector", {"windows", "spread", "sharing"}, {"pool"}),
        "imudiag.monitor": ("checks", {"state", "noise", "stuck", "batching", "trace"}, set()),
    }
    for package, (algorithm, machinery, above) in inside.items():
        for part in machinery:
            deps = graph()[f"{package}.{part}"]
            assert f"{package}.{algorithm}" not in deps, (package, part)
            assert not any(d.startswith(f"{package}.") and d.rpartition(".")[2] in above
                           for d in deps), (package, part)  # fmt: skip
        for name in [m for m in MODULES if m.startswith(package + ".")]:
            assert package not in graph()[name], name
        own = {d.rpartition(".")[2] for d in graph()[f"{package}.{algorithm}"]
               if d.startswith(package + ".")}  # fmt: skip
        assert own <= machinery, (package, own)


def test_every_package_is_installed_by_pyproject() -> None:
    """A non-editable install (the README's first command) ships exactly the packages
    pyproject.toml lists: each package folder under imudiag/ must be among them (the
    monitor, quasistatic and fleet packages were missing, and `pip install .` then failed
    at `imudiag run` with ModuleNotFoundError)."""
    import tomllib

    root = Path(__file__).resolve().parents[1]
    listed = set(
        tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {"imudiag." + p.parent.name for p in (root / "imudiag").glob("*/__init__.py")}
    assert found - listed == set(), f"packages not in pyproject.toml: {sorted(found - listed)}"
