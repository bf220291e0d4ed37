"""``python -m sweep``: the Hydra application.

Multirun (the paper's grid, on Ray, tracked in MLflow)::

    python -m sweep -m objective=J1,J2,J3 train=R,TR,TZR seed=0,1,2 [budget=smoke|short|paper]
        [tracking.uri=...] [ray.address=auto] [data.root=DIR] [sweep.name=NAME]

A single run (``python -m sweep objective=J2 train=R seed=0``) runs one job in this process.
The exit status is non-zero if any job failed.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig

#: the repository's Hydra ``conf/`` directory (found relative to this file; editable install)
CONF = str(Path(__file__).resolve().parents[2] / "conf")


def single_job(cfg: DictConfig) -> Any:
    """One job in this process (no Ray): identification, test metrics, MLflow child run."""
    from hydra.core.hydra_config import HydraConfig

    from hydra_plugins.mmg_sweep_launcher.mmg_ray_launcher import job_config
    from sweep.service.orchestration import (
        LocalExecutor,
        Progress,
        check_recordings,
        efd_reference,
        run_sweep,
        spec_from_config,
    )
    from sweep.service.schema import validate
    from sweep.service.tracking import RETRY_SECONDS, MlflowTracker

    plain = job_config(cfg)
    validate(plain)  # before an MLflow run is created
    job_dir = Path(HydraConfig.get().runtime.output_dir)
    spec = spec_from_config(plain, job_dir)
    check_recordings([spec])
    progress = Progress()
    tracker = MlflowTracker(
        str(cfg.tracking.uri),
        str(cfg.tracking.experiment),
        bool(cfg.sweep.allow_config_change),
        retry_seconds=float(cfg.tracking.get("retry_seconds", RETRY_SECONDS)),
        notify=progress.note,
    )
    efd = efd_reference(plain["test"], cfg.data.root)
    summary = run_sweep(
        str(cfg.sweep.name), [spec], LocalExecutor(), tracker, efd, job_dir, progress=progress
    )
    return summary


@hydra.main(version_base=None, config_path=CONF, config_name="config")
def main(cfg: DictConfig) -> Any:
    """Hydra's task function: a single run, one job in this process (a multirun goes to the
    ``mmg_ray`` launcher instead, which does not call it).

    Raises SystemExit(1) when the job failed; returns the sweep summary.
    """
    from sweep.errors import exit_on_user_error

    with exit_on_user_error():
        summary = single_job(cfg)
    if not summary.ok:
        raise SystemExit(1)
    return summary


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def run() -> int:
    """``python -m sweep``: run :func:`main` with clean interruption; the exit status.

    0 when every job succeeded, 1 when any failed (listed on stderr), 130 when interrupted
    (Ctrl-C or SIGTERM: running jobs cancelled, checkpoints kept for a resume).
    """
    from hydra_plugins.mmg_sweep_launcher import mmg_ray_launcher

    # Ctrl-C and SIGTERM (docker stop, a CI timeout) stop the sweep cleanly: running jobs are
    # cancelled, Ray is shut down, checkpoints stay. (A shell without job control starts
    # background commands with SIGINT ignored; a sweep still honours it.)
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        main()
    except SystemExit as exc:
        return int(exc.code or 0)
    except KeyboardInterrupt as exc:
        print(
            f"\ninterrupted ({exc or 'SIGINT'}): running jobs cancelled, their checkpoints kept; "
            "run the same command again to resume",
            file=sys.stderr,
        )
        return 130
    summary = mmg_ray_launcher.LAST_SUMMARY
    if summary is not None and not summary.ok:
        print(f"{len(summary.failed)} job(s) failed:", file=sys.stderr)
        for key, err in summary.failed.items():
            print(f"  {key}: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(run())
