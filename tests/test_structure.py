"""The shape of the house: layers that point one way, no import circle, short functions, and
product documentation without a work diary's session or issue numbers."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

#: the layers from the ground up; a module may import its own layer and those below it.
#: ``sweep.errors`` imports nothing of ``sweep`` (every layer derives its users' mistakes from it);
#: the modules of ``sweep`` not listed (``evaluate``, ``identify``, ``__main__``, ...) and the
#: Hydra plugin are the commands, the top layer
LAYERS = {
    "mmg": 0,
    "sweep.errors": 0,
    "sweep.data": 1,
    "sweep.identification": 2,
    "sweep.service": 3,
    "sweep.diagnose": 4,
    "sweep.diagnose.__main__": 5,
}
COMMANDS = 5
#: the longest function the house allows [lines]
MAX_FUNCTION_LINES = 120


def _modules() -> dict[str, Path]:
    out = {}
    for path in SRC.rglob("*.py"):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _layer(module: str) -> int:
    best = max(
        (k for k in LAYERS if module == k or module.startswith(k + ".")), key=len, default=None
    )
    return LAYERS[best] if best is not None else COMMANDS


def _imports(module: str, path: Path) -> Iterator[str]:
    """The project's modules that ``module`` imports (at any depth of its code)."""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package[: len(package) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            # ``from package import submodule`` imports the submodule, ``from module import
            # name`` the module
            names = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        for name in names:
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            if name and name != module:
                yield name


def _graph() -> dict[str, set[str]]:
    return {m: set(_imports(m, p)) for m, p in MODULES.items()}


def test_layers_point_one_way() -> None:
    upward = [f"{a} -> {b}" for a, bs in _graph().items() for b in bs if _layer(b) > _layer(a)]
    assert upward == []


def test_no_import_circle() -> None:
    graph = _graph()
    circles: list[list[str]] = []
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                circles.append([*path[path.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert circles == []


def test_the_checks_see_an_upward_arrow_and_a_circle(monkeypatch: pytest.MonkeyPatch) -> None:
    """The two checks above can fail: an edge from the model to the diagnosis is both."""
    graph = _graph()
    graph["mmg.params"].add("sweep.diagnose.run")
    graph["sweep.diagnose.run"].add("mmg.params")
    monkeypatch.setattr(f"{__name__}._graph", lambda: graph)
    with pytest.raises(AssertionError):
        test_layers_point_one_way()
    with pytest.raises(AssertionError):
        test_no_import_circle()


def test_no_function_is_longer_than_the_house_allows() -> None:
    long = []
    for path in MODULES.values():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert long == []


#: a work diary's references: "session 20", "issue 15", "(issue #3)", "procedure 9"
DIARY = re.compile(r"\b(?:sessions?|issues?|procedure)\s+#?\d+", re.IGNORECASE)


def _product_texts() -> Iterator[Path]:
    yield ROOT / "README.md"
    yield ROOT / "CHANGELOG.md"
    yield from SRC.rglob("*.py")
    yield from (ROOT / "docs").rglob("*.md")


def test_no_session_or_issue_numbers_in_the_product() -> None:
    found = [
        f"{path.relative_to(ROOT)}:{i}: {line.strip()}"
        for path in _product_texts()
        for i, line in enumerate(path.read_text().splitlines(), 1)
        if DIARY.search(line)
    ]
    assert found == []


@pytest.mark.parametrize(
    "line", ["as measured in session 20", "(issue 15)", "see issue #3", "procedure 9's stages"]
)
def test_the_diary_pattern_catches_what_it_should(line: str) -> None:
    assert DIARY.search(line)
