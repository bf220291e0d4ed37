"""The machine a benchmark ran on, for its printed and stored figures: the same code gives other
numbers on another CPU (the kernels are compiled for the machine they run on)."""

from __future__ import annotations

import contextlib
import functools
import os
import platform
from pathlib import Path

CPUINFO = Path("/proc/cpuinfo")


def cpu_name() -> str:
    """The CPU's model name (/proc/cpuinfo; else the platform's processor string)."""
    with contextlib.suppress(OSError):
        for line in CPUINFO.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown CPU"


def has_avx512() -> bool:
    """Whether the CPU has AVX-512 (its foundation instructions)."""
    with contextlib.suppress(OSError):
        return " avx512f" in CPUINFO.read_text()
    return False


@functools.cache
def machine() -> str:
    """The CPU's model, its count and whether it has AVX-512, in one line (read once per
    process: the planted benchmark names it in every case and every results file)."""
    avx = ", AVX-512" if has_avx512() else ""
    return f"{cpu_name()}, {os.cpu_count()} CPUs{avx}"
