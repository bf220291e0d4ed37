"""What each fault the sweep service survives costs: jobs lost, jobs run twice, results, wall time.

Usage: ``PYTHONPATH=. python benchmarks/faults.py
[--faults damaged,forged,second-driver,before-logging,outage] [--out FILE.json]
[--clean-runs N] [--outage-seconds S] [--workdir DIR]`` (recordings from $MMG_DATA_DIR, else
../shared/data/frt-ds-esso; about 6 min on 2 cores).

Runs the CI smoke sweep, ``python -m sweep -m objective=J1,J2 train=R seed=0 budget=smoke
ray.num_cpus=2``, each time in a fresh working directory of its own (its own ``sweep.name``,
SQLite MLflow store and ``multirun/`` directory): clean, as the reference, then once per fault,
injecting the fault for real:

- ``damaged``: the driver's process group is killed (SIGKILL) once both jobs have a checkpoint
  and J1 its previous one too (``checkpoint.pkl.prev``, so that the job can resume from it),
  J1's ``checkpoint.pkl`` is truncated to 100 bytes, and the same command is run again;
- ``forged``: the same, with J1's checkpoint replaced by a pickle whose ``__reduce__`` would
  create a marker file (checked to work on a scratch file first); the marker must never appear;
- ``second-driver``: the same command started twice at once on the same directory and store;
- ``before-logging``: the driver is killed the moment a job's ``outcome.json`` appears (the job
  has ended, its MLflow logging is under way), then the same command is run again;
- ``outage``: the sweep is tracked by an ``mlflow server`` on loopback, which is killed once the
  first job is a FINISHED child run and started again on the same port and store after
  ``--outage-seconds`` (30).

For each it counts FINISHED child runs per job in MLflow (a job without one is lost), the job's
completed executions (its FINISHED runs plus the drivers' "not logged again" lines: a result
computed and thrown away), compares each job's ``best_f`` and test J2 (``test/J2/total``) with
the first clean run's bit for bit, and takes the wall time lost: the faulted run's wall time (the
sum of its commands' run times, from start to exit or to the kill; the benchmark's own steps in
between are not counted; two drivers at once: from their start to the later exit) minus the
clean one (the mean of ``--clean-runs``, 3: one before the faults, the others after), minus the
deliberate pause (the outage: from the server's kill until it answers again). It prints one
markdown table to stdout, progress on stderr, and writes the figures as JSON with ``--out``.
Every process it starts (drivers with their Ray, mlflow servers) runs in a session of its own
and is killed by process group and by pid, also on Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import pickle
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.machine import machine

#: the faults, in the order they run: (name in the table, what is injected)
FAULTS = {
    "damaged": (
        "damaged checkpoint",
        "driver killed (kill -9), J1's checkpoint.pkl cut to 100 bytes, same command again",
    ),
    "forged": (
        "forged checkpoint",
        "driver killed (kill -9), J1's checkpoint.pkl replaced by a planted pickle, same "
        "command again",
    ),
    "second-driver": ("second driver", "the same command started twice at once"),
    "before-logging": (
        "driver killed between a job's end and its logging",
        "driver killed (kill -9) when a job's outcome.json appears, same command again",
    ),
    "outage": (
        "tracking server outage",
        "mlflow server killed when the first job is logged, started again after the outage",
    ),
}
JOBS = ("objective=J1,seed=0,train=R", "objective=J2,seed=0,train=R")
#: the CI smoke sweep (tests/conftest.py), without its sweep.name
SMOKE = ["-m", "objective=J1,J2", "train=R", "seed=0", "budget=smoke", "ray.num_cpus=2"]
METRICS = ("best_f", "test/J2/total")
START = time.monotonic()


def say(text: str) -> None:
    """A progress line on stderr."""
    print(f"[faults {time.monotonic() - START:7.1f} s] {text}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------ processes


def _stat(pid: int) -> tuple[int, int, int, str] | None:
    """(parent pid, session id, start time [clock ticks], state) of a process, None if gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()  # the command name, in parentheses, may hold spaces
    return int(fields[1]), int(fields[3]), int(fields[19]), fields[0]


def _processes() -> dict[int, tuple[int, int, int, str]]:
    out = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit() and (st := _stat(int(entry.name))) is not None:
            out[int(entry.name)] = st
    return out


class Started:
    """A process started in a session of its own, with every process it has been seen to start
    (pid -> start time, so that a pid reused by an unrelated process is never killed)."""

    def __init__(self, args: list[str], cwd: Path, env: dict[str, str], log: Path) -> None:
        with log.open("ab") as out:  # the child keeps its own handle
            self.proc = subprocess.Popen(
                args, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
        self.log = log
        self.started = time.monotonic()
        self.ended: float | None = None
        self.killed = False
        self.family: dict[int, int] = {}
        REGISTRY.append(self)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def track(self) -> None:
        """Remember the processes now in its session or below it (while it is not reaped, so
        that its pid and session id are still its own)."""
        if self.proc.returncode is not None:
            return
        table = _processes()
        children: dict[int, list[int]] = {}
        for pid, (ppid, _, _, _) in table.items():
            children.setdefault(ppid, []).append(pid)
        stack = [self.pid] + [p for p, st in table.items() if st[1] == self.pid]
        while stack:
            pid = stack.pop()
            if pid in table and pid not in self.family:
                self.family[pid] = table[pid][2]
                stack.extend(children.get(pid, []))

    def poll(self) -> int | None:
        """Its exit status, or None while it runs (the end time is taken when it is seen)."""
        code = self.proc.poll()
        if code is not None and self.ended is None:
            self.ended = time.monotonic()
        return code

    def wait(self, timeout: float | None = None) -> int:
        """Wait for it to exit (the end time is when it did, to the poll's 0.1 s)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"{self.proc.args!r} still runs after {timeout} s")
            self.track()
            time.sleep(0.1)
        return code

    def seconds(self) -> float:
        """Its run time [s]: from its start to its exit, or to its kill."""
        return (self.ended or time.monotonic()) - self.started

    def stop(self) -> None:
        """SIGKILL its process group at once if it still runs, then every process of its
        session and every one it was seen to start; return when they are all gone."""
        if self.poll() is None:  # not reaped: its pid and process group are still its own
            self.killed = True
            self.ended = time.monotonic()
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.pid, signal.SIGKILL)
            self.track()
        deadline = time.monotonic() + 60.0
        while True:
            table = _processes()
            left = [
                pid
                for pid, ticks in self.family.items()
                if pid != self.pid and pid in table and table[pid][2] == ticks
                and table[pid][3] != "Z"
            ]  # fmt: skip
            if not left or time.monotonic() > deadline:
                break
            for pid in left:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.1)
        if left:
            say(f"warning: processes {left} of {self.pid} outlived SIGKILL")
        self.proc.wait()


REGISTRY: list[Started] = []


def stop_all() -> None:
    """Stop every process this benchmark started (a no-op for those already stopped)."""
    for started in reversed(REGISTRY):
        started.stop()


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


# ------------------------------------------------------------------ the sweep


@dataclass
class Setup:
    """Where and how the sweeps run."""

    root: Path
    env: dict[str, str]
    clean_wall: float = 0.0
    clean: dict[str, dict[str, float]] = field(default_factory=dict)  # job -> metric -> value


def command(name: str, *extra: str) -> list[str]:
    """The smoke sweep as ``sweep.name=name``."""
    return [sys.executable, "-m", "sweep", *SMOKE, f"sweep.name={name}", *extra]


def start(setup: Setup, name: str, *extra: str, log: str = "driver") -> Started:
    """Start the sweep ``name`` in ``root/name`` (its log ``<log>.log`` there)."""
    cwd = setup.root / name
    cwd.mkdir(parents=True, exist_ok=True)
    n = len(list(cwd.glob(f"{log}*.log")))
    say(f"{name}: starting {'a driver' if not n else 'the same command again'} ({log}-{n}.log)")
    return Started(command(name, *extra), cwd, setup.env, cwd / f"{log}-{n}.log")


def job_dirs(setup: Setup, name: str) -> dict[str, Path]:
    """Job key -> its directory under ``multirun/name`` (the ones that exist)."""
    out = {}
    for path in (setup.root / name / "multirun" / name).glob("*objective=*"):
        objective = re.search(r"objective=(\w+)", path.name)
        if objective and path.is_dir():
            out[f"objective={objective.group(1)},seed=0,train=R"] = path
    return out


def wait_for(
    what: str, ready: Callable[[], bool], driver: Started, step: float, timeout: float = 600.0
) -> bool:
    """Poll ``ready()`` every ``step`` s until it is true (True) or the driver exits (False)."""
    deadline = time.monotonic() + timeout
    last_track = 0.0
    while not ready():
        if driver.poll() is not None:
            say(f"the sweep exited ({driver.proc.returncode}) before {what}")
            return False
        if time.monotonic() > deadline:
            raise TimeoutError(f"no {what} in {timeout} s")
        if time.monotonic() - last_track > 1.0:
            driver.track()
            last_track = time.monotonic()
        time.sleep(step)
    return True


def child_runs(uri: str) -> list[dict[str, Any]]:
    """Every child run (job) in the store: job key, status, the compared metrics, recovery."""
    import mlflow

    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("mmg-sweep")
    if exp is None:
        return []
    out = []
    for run in client.search_runs([exp.experiment_id], max_results=1000):
        tags = run.data.tags
        if "job_key" in tags and "mlflow.parentRunId" in tags:
            out.append(
                {
                    "job": tags["job_key"],
                    "status": run.info.status,
                    "metrics": {m: run.data.metrics.get(m) for m in METRICS},
                    "recovery": tags.get("checkpoint.recovery", ""),
                }
            )
    return out


def log_lines(setup: Setup, name: str, log: str = "driver") -> str:
    """Every driver log of the sweep ``name``, joined."""
    return "".join(
        p.read_text(errors="replace") for p in sorted((setup.root / name).glob(f"{log}*.log"))
    )


def tally(uri: str, logs: str, clean: dict[str, dict[str, float]]) -> dict[str, Any]:
    """Per job: FINISHED runs, completed executions, whether best_f and test J2 equal the
    clean run's bit for bit; jobs lost, jobs run twice."""
    runs = child_runs(uri)
    jobs: dict[str, dict[str, Any]] = {}
    for job in JOBS:
        finished = [r for r in runs if r["job"] == job and r["status"] == "FINISHED"]
        thrown_away = len(re.findall(rf"{re.escape(job)}: already logged .*not logged again", logs))
        first = finished[0]["metrics"] if finished else {}
        same = bool(finished) and all(
            r["metrics"][m] == clean.get(job, {}).get(m) for r in finished for m in METRICS
        )
        jobs[job] = {
            "finished_runs": len(finished),
            "other_runs": sorted(
                r["status"] for r in runs if r["job"] == job and r not in finished
            ),
            "executions": len(finished) + thrown_away,
            "metrics": first,
            "identical": same,
            "recovery": sorted({r["recovery"] for r in finished if r["recovery"]}),
        }
    return {
        "jobs": jobs,
        "jobs_lost": sum(1 for j in jobs.values() if j["finished_runs"] == 0),
        "jobs_run_twice": sum(
            1 for j in jobs.values() if j["finished_runs"] > 1 or j["executions"] > 1
        ),
        "identical": all(j["identical"] for j in jobs.values()),
    }


def sqlite_uri(setup: Setup, name: str) -> str:
    return f"sqlite:///{setup.root / name / 'mlflow.db'}"


def run_clean(setup: Setup, index: int) -> dict[str, Any]:
    """One uninterrupted sweep: its wall time and results."""
    name = f"clean-{index}"
    driver = start(setup, name)
    code = driver.wait()
    driver.stop()
    if code != 0:
        sys.exit(f"the clean sweep failed ({code}); its log: {driver.log}")
    runs = {r["job"]: r["metrics"] for r in child_runs(sqlite_uri(setup, name))}
    say(f"{name}: {driver.seconds():.1f} s")
    return {"wall_seconds": driver.seconds(), "metrics": runs}


# ------------------------------------------------------------------ the faults


class Planted:
    """A pickle that, if it were ever unpickled, would create ``marker``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[Path]]:
        return (Path.touch, (self.marker,))


def forged_pickle(marker: Path, scratch: Path) -> bytes:
    """A planted pickle for ``marker``; one for a scratch file is unpickled first to show that
    such a file does run code when read."""
    probe = scratch / "probe-marker"
    pickle.loads(pickle.dumps(Planted(probe)))  # the point: it runs code
    if not probe.exists():
        sys.exit(
            "the planted pickle does not create its marker: the forged fault would prove nothing"
        )
    probe.unlink()
    return pickle.dumps(Planted(marker))


def kill_and_damage(setup: Setup, name: str, forged: bool) -> dict[str, Any]:
    """Kill the driver once both jobs have a checkpoint, damage or forge J1's, run again."""
    driver = start(setup, name)
    out: dict[str, Any] = {"injected": 0, "commands": [driver]}

    def ready() -> bool:
        dirs = job_dirs(setup, name)
        return (
            len(dirs) == len(JOBS)
            and all((d / "checkpoint.pkl").is_file() for d in dirs.values())
            and (dirs[JOBS[0]] / "checkpoint.pkl.prev").is_file()
        )

    if wait_for("both jobs had a checkpoint, J1 its previous one too", ready, driver, 0.05):
        driver.stop()
        target = job_dirs(setup, name)[JOBS[0]] / "checkpoint.pkl"
        say(f"{name}: killed the driver after {driver.seconds():.1f} s")
        if forged:
            marker = setup.root / name / "planted-marker"
            target.write_bytes(forged_pickle(marker, setup.root / name))
            out["marker"] = str(marker)
            say(f"{name}: replaced {target.parent.name}/checkpoint.pkl by a planted pickle")
        else:
            target.write_bytes(target.read_bytes()[:100])
            say(f"{name}: truncated {target.parent.name}/checkpoint.pkl to 100 bytes")
        out["injected"] = 2
        rerun = start(setup, name)
        out["commands"].append(rerun)
        rerun.wait()
        rerun.stop()
        out["set_aside"] = sorted(p.name for p in target.parent.glob("checkpoint.pkl*.bad-*"))
    else:
        driver.stop()
    if forged:
        out["marker_created"] = Path(out.get("marker", "/nonexistent")).exists()
    return out


def second_driver(setup: Setup, name: str) -> dict[str, Any]:
    """The same command twice at once."""
    first = start(setup, name)
    second = start(setup, name)
    for driver in (first, second):
        driver.wait()
        driver.stop()
    return {"injected": 1, "commands": [first, second], "concurrent": True}


def before_logging(setup: Setup, name: str) -> dict[str, Any]:
    """Kill the driver the moment an outcome.json appears; run again."""
    driver = start(setup, name)
    out: dict[str, Any] = {"injected": 0, "commands": [driver]}
    seen: list[str] = []

    def ended() -> bool:
        seen[:] = [k for k, d in job_dirs(setup, name).items() if (d / "outcome.json").is_file()]
        return bool(seen)

    if wait_for("a job's outcome.json appeared", ended, driver, 0.005):
        driver.stop()
        left = [k for k, d in job_dirs(setup, name).items() if (d / "outcome.json").is_file()]
        say(f"{name}: killed the driver after {driver.seconds():.1f} s, {seen[0]} ended and "
            f"not yet logged; outcome.json left by {', '.join(left) or 'no job'}")  # fmt: skip
        out["injected"] = 1
        out["outcome_left"] = left
        rerun = start(setup, name)
        out["commands"].append(rerun)
        rerun.wait()
        rerun.stop()
    else:
        driver.stop()
    return out


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def start_server(setup: Setup, name: str, port: int, timeout: float = 120.0) -> Started:
    """``mlflow server`` on 127.0.0.1:``port``, its store in ``root/name/server``; waits until
    it answers /health."""
    store = setup.root / name / "server"
    store.mkdir(parents=True, exist_ok=True)
    args = [
        sys.executable, "-m", "mlflow", "server",
        "--backend-store-uri", f"sqlite:///{store}/mlflow.db",
        "--artifacts-destination", str(store / "artifacts"),
        "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
    ]  # fmt: skip
    env = dict(setup.env, MLFLOW_SERVER_ENABLE_JOB_EXECUTION="false")
    server = Started(args, store, env, store / "server.log")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if server.poll() is not None:
            sys.exit(f"mlflow server exited ({server.proc.returncode}); its log: {server.log}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as answer:
                if answer.status == 200:
                    return server
        except OSError:
            time.sleep(0.5)
    sys.exit(f"mlflow server did not answer on port {port} in {timeout} s; its log: {server.log}")


def outage(setup: Setup, name: str, seconds: float) -> dict[str, Any]:
    """Kill the tracking server once the first job is logged; start it again after ``seconds``."""
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    server = start_server(setup, name, port)
    say(f"{name}: mlflow server on {uri}")
    driver = start(setup, name, f"tracking.uri={uri}")
    out: dict[str, Any] = {"injected": 0, "commands": [driver], "uri": uri, "pause": 0.0}

    def logged() -> bool:
        return any(r["status"] == "FINISHED" for r in child_runs(uri))

    if wait_for("the first job was logged", logged, driver, 0.5):
        down = time.monotonic()
        server.stop()
        say(f"{name}: first job logged; mlflow server killed for {seconds:g} s")
        out["injected"] = 1
        time.sleep(seconds)
        if driver.poll() is not None:
            say(f"{name}: the sweep exited ({driver.proc.returncode}) during the outage")
        server = start_server(setup, name, port)
        out["pause"] = time.monotonic() - down
        say(f"{name}: mlflow server answers again after {out['pause']:.1f} s")
    driver.wait()
    driver.stop()
    out["tally"] = tally(uri, log_lines(setup, name), setup.clean)
    server.stop()
    return out


def run_fault(setup: Setup, fault: str, outage_seconds: float) -> dict[str, Any]:
    """Inject one fault; its row."""
    name = fault
    if fault in ("damaged", "forged"):
        out = kill_and_damage(setup, name, forged=fault == "forged")
    elif fault == "second-driver":
        out = second_driver(setup, name)
    elif fault == "before-logging":
        out = before_logging(setup, name)
    else:
        out = outage(setup, name, outage_seconds)
    drivers: list[Started] = out.pop("commands")
    if out.get("concurrent"):
        wall = max(d.started + d.seconds() for d in drivers) - min(d.started for d in drivers)
    else:
        wall = sum(d.seconds() for d in drivers)
    result = out.pop("tally", None) or tally(
        sqlite_uri(setup, name), log_lines(setup, name), setup.clean
    )
    logs = log_lines(setup, name)
    pause = float(out.pop("pause", 0.0))
    row: dict[str, Any] = {
        "fault": fault,
        "name": FAULTS[fault][0],
        "what": FAULTS[fault][1],
        **result,
        "wall_seconds": wall,
        "subtracted_seconds": pause,
        "lost_seconds": wall - setup.clean_wall - pause,
        "commands": [
            {"seconds": d.seconds(), "exit": d.proc.returncode, "killed": d.killed} for d in drivers
        ],
        "driver_lines": {
            pattern: len(re.findall(pattern, logs))
            for pattern in (
                "waiting for it to end",
                ": finished by another driver",
                "logged now from",
                "not logged again",
                "does not answer",
                "answers again",
                "set aside as",
            )
        },
        **out,
    }
    row["injected"] = int(out["injected"])
    say(
        f"{fault}: {row['jobs_lost']} lost, {row['jobs_run_twice']} run twice, "
        f"{'identical' if row['identical'] else 'NOT identical'}, wall {wall:.1f} s, "
        f"lost {row['lost_seconds']:+.1f} s"
    )
    return row


# ------------------------------------------------------------------ the table


def notes_of(row: dict[str, Any]) -> str:
    """What the row's last column says: recoveries, driver lines, the pause subtracted."""
    parts = []
    if not row["injected"]:
        parts.append("the sweep ended before the fault could be injected")
    recoveries = sorted({t for j in row["jobs"].values() for t in j["recovery"]})
    if recoveries:
        parts.append("recovery " + "; ".join(recoveries))
    if "marker_created" in row:
        parts.append("marker " + ("CREATED" if row["marker_created"] else "never created"))
    lines = row["driver_lines"]
    for pattern, text in (
        ("waiting for it to end", "jobs the other driver held, waited for"),
        (": finished by another driver", "jobs skipped as finished by the other driver"),
        ("logged now from", "jobs logged from their outcome.json, not run again"),
        ("not logged again", "results computed twice, not logged again"),
    ):
        if lines[pattern]:
            parts.append(f"{text}: {lines[pattern]}")
    if row["subtracted_seconds"]:
        parts.append(f"{row['subtracted_seconds']:.1f} s outage subtracted")
    codes = [c["exit"] for c in row["commands"] if not c["killed"]]
    if any(codes):
        parts.append(f"exit status {codes}")
    return "; ".join(parts)


def table(clean: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """The markdown table of the clean run and the faults."""
    out = [
        "| fault | faults injected | jobs lost | jobs run twice | results = clean, bit for bit "
        "| wall time [s] | wall time lost [s] | notes |",
        "|---|---:|---:|---:|---|---:|---:|---|",
        f"| none (clean reference) | 0 | 0 | 0 | {clean['determinism']} | "
        f"{clean['wall_seconds']:.1f} | | {clean['note']} |",
    ]
    for row in rows:
        same = sum(1 for j in row["jobs"].values() if j["identical"])
        out.append(
            f"| {row['name']} | {row['injected']}: {row['what']} | {row['jobs_lost']} | "
            f"{row['jobs_run_twice']} | {'yes' if row['identical'] else 'no'} "
            f"({same}/{len(row['jobs'])} jobs) | {row['wall_seconds']:.1f} | "
            f"{row['lost_seconds']:+.1f} | {notes_of(row)} |"
        )
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--faults",
        default=",".join(FAULTS),
        help=f"a subset of {','.join(FAULTS)} (comma-separated)",
    )
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    ap.add_argument(
        "--clean-runs", type=int, default=3,
        help="clean reference sweeps (the first before the faults, the others after); the "
        "reference wall time is their mean",
    )  # fmt: skip
    ap.add_argument(
        "--outage-seconds", type=float, default=30.0, help="how long the server is down"
    )
    ap.add_argument(
        "--workdir", type=Path, default=None, help="kept; default: a temporary directory"
    )
    args = ap.parse_args()
    faults = [f.strip() for f in args.faults.split(",") if f.strip()]
    unknown = [f for f in faults if f not in FAULTS]
    if unknown or not faults:
        ap.error(
            f"--faults: choose from {', '.join(FAULTS)}, not {', '.join(unknown) or 'nothing'}"
        )
    if args.clean_runs < 1:
        ap.error("--clean-runs: at least 1")
    if args.outage_seconds < 0:
        ap.error("--outage-seconds: not negative")

    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    env = dict(os.environ, RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
    env.setdefault("MMG_DATA_DIR", str(default_root))
    # a key of this benchmark's own: the user's checkpoint key file is neither read nor made
    env["MMG_CHECKPOINT_KEY"] = secrets.token_hex(32)
    root = args.workdir or Path(tempfile.mkdtemp(prefix="mmg-sweep-faults-"))
    root.mkdir(parents=True, exist_ok=True)
    setup = Setup(root.resolve(), env)
    # Ctrl-C and SIGTERM stop every process started (a shell without job control starts
    # background commands with SIGINT ignored; it is honoured all the same)
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    say(f"working directory {setup.root}; {machine()}")
    rows: list[dict[str, Any]] = []
    cleans: list[dict[str, Any]] = []
    try:
        cleans.append(run_clean(setup, 0))
        setup.clean = cleans[0]["metrics"]
        setup.clean_wall = cleans[0]["wall_seconds"]
        for fault in faults:
            rows.append(run_fault(setup, fault, args.outage_seconds))
        for i in range(1, args.clean_runs):
            cleans.append(run_clean(setup, i))
    except KeyboardInterrupt:
        say("interrupted: stopping every process started")
        return 130
    finally:
        stop_all()
    walls = [c["wall_seconds"] for c in cleans]
    setup.clean_wall = sum(walls) / len(walls)
    for row in rows:  # against the mean of the clean runs
        row["lost_seconds"] = row["wall_seconds"] - setup.clean_wall - row["subtracted_seconds"]
    deterministic = all(c["metrics"] == cleans[0]["metrics"] for c in cleans)
    clean = {
        "wall_seconds": setup.clean_wall,
        "runs_seconds": walls,
        "metrics": setup.clean,
        "determinism": f"{len(cleans)} clean runs " + ("identical" if deterministic else "DIFFER"),
        "note": f"mean of {len(walls)}: " + ", ".join(f"{w:.1f}" for w in walls) + " s",
    }
    command_text = "python -m sweep " + " ".join(SMOKE) + " sweep.name=<fault>"
    print(f"Fault benchmark: `{command_text}`, one working directory per run; {machine()}.\n")
    print(table(clean, rows))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        report = {"command": command_text, "machine": machine(), "clean": clean, "faults": rows}
        args.out.write_text(json.dumps(report, indent=1, default=str) + "\n")
        say(f"figures written to {args.out}")
    if args.workdir is None:
        shutil.rmtree(setup.root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
