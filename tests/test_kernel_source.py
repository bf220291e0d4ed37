"""The generated kernel source keeps to the project's style: ruff checks what mmg.kernel renders.

The kernel is Python written by :func:`mmg.kernel.render` from a template, imported from the
kernel cache and never seen by the linter run over src/. These tests render it for the base
model, for every catalog effect at once (every kind of hook), for discovered terms beside
catalog effects, for the benchmarks' planted forms and for a replacement right-hand side, and
run ``ruff check`` and ``ruff format --check`` on it with the project's configuration. Nothing
is compiled.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from benchmarks.planted import UNLISTED

from mmg import catalog, get_effect
from mmg.kernel import render
from tests.rk4_linear import linear_rhs

ROOT = Path(__file__).resolve().parents[1]


def ruff(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """``ruff <args>`` with the project's configuration, run from the project's root (the
    configuration's ``src`` paths, which tell first-party imports from others, are relative)."""
    command = [sys.executable, "-m", "ruff", *map(str, args), "--config", "pyproject.toml"]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)


def check(source: str, path: Path) -> list[str]:
    """ruff's complaints about ``source`` written to ``path`` (empty: none)."""
    path.write_text(source.replace("{key}", "0" * 20))  # a key is 20 hex digits
    problems = []
    lint = ruff("check", "--no-cache", "--output-format", "concise", path)
    if lint.returncode != 0:
        problems.append(f"ruff check:\n{lint.stdout}{lint.stderr}")
    style = ruff("format", "--no-cache", "--diff", path)
    if style.returncode != 0:
        problems.append(f"ruff format --check:\n{style.stdout}{style.stderr}")
    return problems


CASES = {
    "base model": lambda: render(),
    "every catalog effect": lambda: render(tuple(catalog().values())),
    "current and discovered terms": lambda: render(
        (get_effect("current"), get_effect("discovered:N_dnn+Y_t+X_wuu"))
    ),
    "discovered term, then an effect without a force": lambda: render(
        (get_effect("discovered:Y_vav"), get_effect("rudder_offset"))
    ),
    "planted forms": lambda: render((UNLISTED["wash_yaw"], UNLISTED["earth_force"])),
    "replacement right-hand side": lambda: render(rhs_override=linear_rhs),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_rendered_kernel_passes_ruff(case: str, tmp_path: Path) -> None:
    problems = check(CASES[case](), tmp_path / "mmg_kernel_rendered.py")
    assert not problems, "\n".join(problems)


def test_the_check_sees_a_fault(tmp_path: Path) -> None:
    """The check is not vacuous: an unused import and a long line in the rendered source are
    reported."""
    source = render().replace("import math\n", "import math\nimport os\n", 1)
    source += f"\nLONG = {'1 + ' * 40}1\n"
    problems = "\n".join(check(source, tmp_path / "mmg_kernel_faulty.py"))
    assert "F401" in problems
    assert "E501" in problems
