"""Shared fixtures: where the reference files and the real recordings are; the kernels the tests
compile, one effect kernel for the whole session, compiled side by side before the first test."""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from mmg.catalog import EFFECTS as CATALOG_EFFECTS
from mmg.effect import Effect

SHARED = Path(__file__).resolve().parents[1].parent / "shared"

#: the effects of the one effect kernel the fast tier compiles: every catalog effect and two
#: generated terms, one of them a time term. A test that needs some effect uses this combination,
#: with the effects it does not study at their neutral values (which add exactly nothing), rather
#: than a kernel of its own: each kernel entry point costs 20-60 s of compilation from a cold
#: cache, and a session used to compile some fifty
SHARED_EFFECTS = (*(e.name for e in CATALOG_EFFECTS), "discovered:N_dnn+Y_t")
#: every kernel entry point that mmg.precompile compiles
ENTRIES = ("simulate", "moments", "derivatives")


def kernels(effects: tuple[str, ...], *entries: str) -> tuple[tuple[tuple[str, ...], str], ...]:
    """The arguments of a ``kernels`` mark: (effect names, entry point) for each of ``entries``
    (:data:`ENTRIES` if none); ``effects`` () is the base model."""
    return tuple((effects, entry) for entry in entries or ENTRIES)


def probe_kernels(library: bool = True) -> tuple[tuple[tuple[str, ...], str], ...]:
    """The kernels of a diagnosis's probes on the base model: the library's columns (every
    searched term in one generated effect; not with ``library`` False) and the shapes' columns
    (one probe for every candidate group), as :func:`sweep.diagnose.run.probe_tasks` compiles
    them."""
    from mmg.shapes import Group, memory_coefficients
    from sweep.diagnose.memory import FORMS, by_form
    from sweep.diagnose.run import probes

    # the memories' closed forms of both controls, of the plain gap and of the gap signed away
    # from the control's zero (a kernel is of the groups' structure: any range names it)
    gaps = (("D", "ed"), ("P", "en"), ("D", "eda"), ("P", "ena"))
    memory = [
        Group(c, v, -4.0, 4.0, memory_coefficients(v), form=f) for c, v in gaps for f in FORMS
    ]
    return tuple(
        kernel
        for probe, entries in probes(discover=library)
        for kernel in kernels((probe.name,), *entries)
    ) + tuple(kernel for eff, _ in by_form(memory) for kernel in kernels((eff.name,), "simulate"))


def planted_case_args(case: Path, out: Path) -> list[str]:
    """The diagnosis's arguments for a small planted case (``case``/train, ``case``/test) of the
    end-to-end tests: the EFD parameters, a budget of 200, two catalog candidates."""
    return [
        "--params", "efd",
        "--train", str(case / "train"),
        "--test", str(case / "test"),
        "--out", str(out),
        "--budget", "200",
        "--candidates", "rudder_offset,current",
    ]  # fmt: skip


def shared_effects() -> tuple[Effect, ...]:
    """The effects of :data:`SHARED_EFFECTS`, in that order."""
    from mmg import get_effect

    return tuple(get_effect(name) for name in SHARED_EFFECTS)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files with ``integration`` tests first, the others after, each in its own order.

    xdist hands out whole files (``--dist loadfile``) in collection order as workers come free;
    the long files first and the short ones filling in at the end keep the two workers busy to
    the end (in alphabetical order a file of two 110-s server tests came last and ran alone for
    3-4 minutes while the other worker was idle)."""
    heavy = {item.path for item in items if item.get_closest_marker("integration")}
    items.sort(key=lambda item: item.path not in heavy)  # stable: files keep their order


def pytest_collection_finish(session: pytest.Session) -> None:
    """Compile the kernels that the selected tests name in their ``kernels`` marks ((effect
    names, entry point) pairs) and the cache lacks, two at a time (mmg.precompile), before the
    first test. Under xdist every worker collects the whole selection: the first to take the
    lock compiles, the others then find the cache warm. A failure is left to the tests."""
    wanted = {
        kernel: None
        for item in session.items
        for mark in item.iter_markers("kernels")
        for kernel in mark.args
    }
    if not wanted or os.environ.get("NUMBA_DISABLE_JIT") == "1":
        return
    from mmg import get_effect
    from mmg.kernel import kernel_dir
    from mmg.precompile import precompile

    directory = kernel_dir()
    directory.mkdir(parents=True, exist_ok=True)
    tasks = [(tuple(get_effect(n) for n in names), entry) for names, entry in wanted]
    with open(directory / ".precompile.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            precompile(tasks, processes=2)
        except Exception as exc:  # the tests that use the kernel say what failed
            warnings.warn(f"precompiling the tests' kernels failed: {exc}", stacklevel=1)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def recordings_root() -> Path:
    """The FRT-DS-ESSO recordings: $MMG_DATA_DIR, else ../shared/data/frt-ds-esso."""
    env = os.environ.get("MMG_DATA_DIR")
    return Path(env) if env else SHARED / "data" / "frt-ds-esso"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"the shared reference directory {SHARED} is missing")
    return SHARED


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The recordings' root directory (fails, never skips, when they are missing)."""
    d = recordings_root()
    if not (d / "data").is_dir():
        pytest.fail(
            f"FRT-DS-ESSO recordings not found in {d}: set MMG_DATA_DIR or run "
            "`python -m sweep.download --root <dir>`"
        )
    return d


#: the CI smoke sweep: two jobs at budget=smoke through Hydra, Ray and MLflow
SMOKE_COMMAND = [
    sys.executable, "-m", "sweep", "-m", "objective=J1,J2", "train=R", "seed=0",
    "budget=smoke", "sweep.name=ci-smoke", "ray.num_cpus=2",
]  # fmt: skip


def run_smoke(cwd: Path, data_dir: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, MMG_DATA_DIR=str(data_dir), RAY_AUTH_MODE="disabled")
    return subprocess.run(
        SMOKE_COMMAND, cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="session")
def smoke(tmp_path_factory: pytest.TempPathFactory, data_dir: Path):
    """(directory, completed process) of one smoke sweep, shared by the CLI and UI tests.

    The sweep runs once per test run, not once per xdist worker (the CLI and UI tests are in
    different files, so under ``--dist loadfile`` usually in different workers; each run costs a
    minute or two of both cores): the first worker to take the lock runs it into a directory
    of the run's shared temporary root, and every worker gets its own copy of that directory
    (its tests rerun the command there and start servers on its store)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the root that the workers' own temporary directories share
    pristine = root / "smoke-sweep"
    with open(root / "smoke-sweep.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not (pristine / "returncode").exists():
                shutil.rmtree(pristine, ignore_errors=True)
                pristine.mkdir()
                done = run_smoke(pristine, data_dir)
                (pristine / "stdout").write_text(done.stdout)
                (pristine / "stderr").write_text(done.stderr)
                (pristine / "returncode").write_text(str(done.returncode))
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    first = subprocess.CompletedProcess(
        SMOKE_COMMAND,
        int((pristine / "returncode").read_text()),
        (pristine / "stdout").read_text(),
        (pristine / "stderr").read_text(),
    )
    assert first.returncode == 0, first.stderr[-3000:]
    cwd = tmp_path_factory.mktemp("sweep")
    own = shutil.ignore_patterns("stdout", "stderr", "returncode")
    shutil.copytree(pristine, cwd, dirs_exist_ok=True, ignore=own)
    return cwd, first


@pytest.fixture
def checkpoint_writes(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The evaluations of every checkpoint the test writes, in order (the writes still happen)."""
    from sweep.identification import cmaes

    writes: list[int] = []
    real_save = cmaes.save_checkpoint

    def counting_save(state: cmaes.State, path: str | Path) -> None:
        writes.append(state.evaluations)
        real_save(state, path)

    monkeypatch.setattr(cmaes, "save_checkpoint", counting_save)
    return writes


@pytest.fixture(scope="module")
def small_case(data_dir: Path):
    """Four 100-s windows (two random runs, a turn, a zigzag) of a perturbed ship without noise,
    and the noise of the recordings: (ship, windows, noise model)."""
    import numpy as np
    from benchmarks.planted import PlantedSpec, generate, noise_levels, perturbed_ship, pick_windows

    from sweep.data.recordings import read_recordings
    from sweep.diagnose.floor import NoiseModel
    from sweep.diagnose.windows import cut_windows

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        runs = {k: read_recordings(data_dir / "data" / k) for k in ("random", "turning", "zigzag")}
    rng = np.random.default_rng(3)
    ship = perturbed_ship(rng, 0.15)
    wins = pick_windows(runs, {"random": 2, "turning": 1, "zigzag": 1}, rng)
    levels = noise_levels([r for v in runs.values() for r in v])
    clean, _ = generate(wins, ship, PlantedSpec("none"), dict.fromkeys(levels, 0.0), rng)
    return ship, cut_windows(clean), NoiseModel(levels, dict.fromkeys(levels, 0.0))


def noisy_windows(params, windows, noise, seed: int):
    """``windows`` simulated with ``params`` (a :class:`mmg.Parameters`, effects included) from
    their own first states, controls and wind, plus noise drawn from ``noise`` (a
    :class:`sweep.diagnose.floor.NoiseModel`) with the generator of ``seed``: planted data."""
    import numpy as np

    from sweep.data.recordings import Recording
    from sweep.diagnose.floor import simulate_windows

    rng = np.random.default_rng(seed)
    return [
        Recording(w.name, None, w.t, x + noise.draw(rng, x.shape[0]), w.u, w.w)
        for w, x in zip(windows, simulate_windows(params, windows), strict=True)
    ]
