"""The house has floors: no room imports one that imports it back, directly or through others — every import runs
down, and a newcomer can read the structure from the imports. Rooms are furuta_rt's folders and top-level modules,
hil_mock, firmware_protocol and benchmarks; inside diagnose, its wings (regression, stages, judgement, report) and
modules. Checked on the import statements of the source (those inside functions and under TYPE_CHECKING included)."""

from __future__ import annotations

import ast
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("furuta_rt", "hil_mock", "firmware_protocol", "benchmarks")


def _module(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, root: Path) -> set[str]:
    mod = _module(path, root)
    pkg = (mod if path.name == "__init__.py" else mod.rpartition(".")[0]).split(".")
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                out.add(".".join([*pkg[: len(pkg) - node.level + 1], *([node.module] if node.module else [])]))
            elif node.module:
                out.add(node.module)
    return out


def circles(files: list[Path], root: Path, room: Callable[[str], str | None]) -> list[set[str]]:
    """The sets of rooms (``room``: a module's room, None outside the house) that import each other in a loop."""
    graph: dict[str, set[str]] = defaultdict(set)
    for f in files:
        src = room(_module(f, root))
        for m in _imports(f, root):
            dst = room(m)
            if src and dst and dst != src:
                graph[src].add(dst)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[set[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp: set[str] = set()
            while not comp or w != v:
                w = stack.pop()
                comp.add(w)
            if len(comp) > 1:
                out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _house_room(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] == "furuta_rt":
        return ".".join(parts[:2])
    return parts[0] if parts[0] in PACKAGES else None


def _diagnose_room(module: str) -> str | None:
    parts = module.split(".")
    return ".".join(parts[:3]) if parts[:2] == ["furuta_rt", "diagnose"] and len(parts) > 2 else None


def test_no_two_rooms_of_the_house_import_each_other() -> None:
    files = [f for p in PACKAGES for f in (ROOT / p).rglob("*.py")]
    assert circles(files, ROOT, _house_room) == []


def test_diagnose_wings_import_downward_only() -> None:
    assert circles(list((ROOT / "furuta_rt" / "diagnose").rglob("*.py")), ROOT, _diagnose_room) == []


def test_a_circle_through_a_third_room_is_seen(tmp_path: Path) -> None:
    """The check itself: a → b → c → a (one of them inside a function) is one circle; d, imported only, is none."""
    for name, text in (("a", "from pkg.b import x\n"), ("b", "def f():\n    from pkg.c import y\n"),
                       ("c", "import pkg.a\nimport pkg.d\n"), ("d", "")):
        (tmp_path / "pkg" / name).mkdir(parents=True)
        (tmp_path / "pkg" / name / "__init__.py").write_text(text)
    files = list((tmp_path / "pkg").rglob("*.py"))
    assert circles(files, tmp_path, lambda m: ".".join(m.split(".")[:2]) if m.startswith("pkg.") else None) == [
        {"pkg.a", "pkg.b", "pkg.c"}]
