"""The package's shape: no import circles, no mutable state at module level."""

from __future__ import annotations

import ast
import importlib
import threading
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CODEC = ROOT / "codec"


#: Installed package -> its folder in the repository (pyproject.toml's package-dir).
FOLDERS = {"codec": CODEC, "codec.cli": ROOT / "cli", "codec.format_spec": ROOT / "format_spec"}


def _modules() -> dict[str, Path]:
    """Every module of the installed codec package by dotted name (packages by their
    own name), the folders it maps in included."""
    out = {}
    for package, folder in FOLDERS.items():
        # the compiled kernels (.pyx) are modules too: `from . import _fields` imports one
        for path in sorted([*folder.rglob("*.py"), *folder.rglob("*.pyx")]):
            parts = tuple(package.split(".")) + path.relative_to(folder).with_suffix("").parts
            if "conformance" in parts:
                continue  # a script that writes the conformance files, not a module
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the codec modules it imports, at the top or inside functions alike
    (a circle through a deferred import is still a circle)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        if path.suffix == ".pyx":
            graph[name] = set()  # a kernel imports nothing of the codec
            continue
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")
                    anchor = anchor[: len(anchor) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                # `from package import submodule` imports the submodule
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                continue
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.add(target)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One circle through each strongly connected group of more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle_in_codec():
    graph = import_graph()
    # the graph is real: the pipeline reaches the meshers and the writer
    assert {"codec.mesher", "codec.meshcode", "codec.holes"} <= graph["codec.pipeline"]
    assert cycles(graph) == []


#: Modules outside the encoder, whose owners are changing them now: they are held to
#: the rule for real state (locks, thread-locals, compressors, buffers) only, and their
#: unfrozen constant tables are reported instead (see the report of this change).
NOT_ENCODER = ("codec.coding", "codec.container", "codec.export", "codec.image", "codec.pil",
               "codec.decoder_cpu", "codec.decoder_gl", "codec.cli", "codec.format_spec")
#: Module-level objects that hold state by design, with the reason.
ALLOWED_STATE = {
    # one GL context per process, created under this lock and used under its own
    ("codec.decoder_gl", "_create_lock"),
}


def _assigned(path: Path) -> set[str]:
    """The names a module assigns at its top level (not the ones it imports)."""
    names = set()
    for node in ast.parse(path.read_text()).body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        for t in targets:
            names |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
    return names


def _state(value, constants_too: bool) -> bool:
    """Objects that can change after import: locks, thread-locals, compressors,
    buffers; with constants_too, also containers and writable arrays."""
    kind = type(value)
    if isinstance(value, (threading.local, bytearray)) or kind.__module__.startswith("zstandard"):
        return True
    if kind.__name__ in ("lock", "RLock"):
        return True
    if not constants_too:
        return False
    if isinstance(value, np.ndarray):
        return value.flags.writeable
    return isinstance(value, (list, dict, set))


def test_the_state_finder_finds_state():
    assert _state(threading.local(), False) and _state(np.zeros(2), True) and _state({}, True)
    frozen = np.zeros(2)
    frozen.flags.writeable = False
    assert not _state(frozen, True) and not _state((1, 2), True) and not _state({}, False)


def test_no_mutable_state_at_module_level():
    """Nothing a call could leave behind for the next one, in this thread or another:
    the encoder's constant tables are frozen (tuples, read-only arrays, mapping
    proxies) and no module holds locks, thread-locals, compressors or buffers."""
    offenders = []
    for name, path in _modules().items():
        if name == "codec.__main__":
            continue  # running it is the CLI
        module = importlib.import_module(name)
        constants_too = not name.startswith(NOT_ENCODER)
        # a compiled kernel's source is not Python: ask the module what it holds
        names = _assigned(path) if path.suffix == ".py" else vars(module)
        for attr in sorted(names):
            if not attr.startswith("__") and (name, attr) not in ALLOWED_STATE and _state(getattr(module, attr, None), constants_too):
                offenders.append(f"{name}.{attr}")
    assert offenders == []
