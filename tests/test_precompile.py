"""Ahead-of-time compilation in worker processes (mmg.precompile).

Run in a child process with its own kernel directory: this test session has its kernels loaded
already, and a kernel loaded in a process is never looked up in the cache again.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mmg.precompile import ENTRIES, tasks

SCRIPT = textwrap.dedent(
    """
    import json, sys
    from mmg.precompile import is_compiled, precompile, tasks
    wanted = tasks([()], ("derivatives",))
    before = is_compiled((), "derivatives")
    first = precompile(wanted, processes=2, log=lambda m: print(m, file=sys.stderr))
    after = is_compiled((), "derivatives")
    second = precompile(wanted, processes=2)
    print(json.dumps([before, first, after, second]))
    """
)


def test_precompile_compiles_what_the_cache_lacks_once(tmp_path: Path) -> None:
    env = dict(os.environ, MMG_KERNEL_DIR=str(tmp_path / "kernels"))
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    before, first, after, second = json.loads(proc.stdout.splitlines()[-1])
    assert (before, first, after, second) == (False, 1, True, 0)
    assert "compiled derivatives for the base model (1/1" in proc.stderr
    # the worker wrote Numba's cache into the run's kernel directory
    assert list((tmp_path / "kernels" / "__pycache__").glob("mmg_kernel_*.rhs_share-*.nbi"))


def test_tasks_name_unknown_entry_points() -> None:
    assert tasks([(), ()], ("simulate",)) == [((), "simulate"), ((), "simulate")]
    with pytest.raises(ValueError, match="unknown kernel entry point"):
        tasks([()], ("simulate", "jacobian"))
    assert set(ENTRIES) == {"simulate", "moments", "derivatives", "accelerations"}


def test_a_long_generated_name_is_cut_in_the_log_with_its_count() -> None:
    from mmg.precompile import _short

    assert _short("propeller_walk") == "propeller_walk"
    name = "discovered:" + "+".join(f"X_t{k}" for k in range(50))
    short = _short(name)
    assert short.startswith(name[:100]) and short.endswith("... (50 terms or groups)")
