"""Modules written at run time: the generated effects (:mod:`mmg.discovered`, :mod:`mmg.shapes`,
:mod:`mmg.domain`) live in ``<kernel dir>/effects``, named by a hash of their text, so that every
process (a Ray worker, a later command) writes the same file and the kernel cache finds it."""

from __future__ import annotations

import importlib.util
import os
import sys
import threading
from pathlib import Path
from types import ModuleType

_lock = threading.Lock()


def generated_module(module_name: str, text: str) -> ModuleType:
    """The module ``module_name`` with source ``text``: this process's, else written to
    ``<kernel dir>/effects/<module_name>.py`` (atomically: concurrent workers write the same
    text) and imported."""
    from mmg.kernel import kernel_dir  # the generated kernels' directory, shared by workers

    with _lock:
        module = sys.modules.get(module_name)
        if module is not None:
            return module
        directory = kernel_dir() / "effects"
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / f"{module_name}.py"
        if not path.exists() or path.read_text() != text:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)  # atomic for concurrent workers
        return load_module(path, module_name)


def load_module(path: Path, name: str) -> ModuleType:
    """Import the Python file ``path`` as the module ``name`` (kept in ``sys.modules``)."""
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


__all__ = ["generated_module", "load_module"]
