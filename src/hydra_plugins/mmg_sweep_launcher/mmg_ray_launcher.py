"""The ``mmg_ray`` Hydra launcher: runs a multirun as one mmg-sweep on Ray.

Hydra composes the configuration of every job of ``python -m sweep -m ...``; this launcher turns
them into :class:`sweep.service.job.JobSpec` and hands them to
:func:`sweep.service.orchestration.run_sweep` with a Ray executor and an MLflow tracker: bounded
concurrency, skip-if-finished, resume from checkpoints, failures recorded, a live progress display,
summary tables at the end. Its job directories are ``hydra.sweep.dir/hydra.sweep.subdir`` (stable
names, so a rerun resumes).
"""

import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobReturn, JobStatus
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


@dataclass
class MmgRayLauncherConf:
    """Hydra's structured config of the launcher (``hydra/launcher=mmg_ray``); no options."""

    _target_: str = "hydra_plugins.mmg_sweep_launcher.mmg_ray_launcher.MmgRayLauncher"


ConfigStore.instance().store(group="hydra/launcher", name="mmg_ray", node=MmgRayLauncherConf)

#: the last sweep's summary, for ``python -m sweep`` to set its exit status
LAST_SUMMARY: Any = None


def job_config(cfg: DictConfig) -> dict[str, Any]:
    """The job's configuration as plain data, interpolations resolved (no Hydra node)."""
    out: dict[str, Any] = {}
    for key in cfg:
        if key == "hydra":
            continue
        value = cfg[key]
        out[str(key)] = (
            OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value
        )
    return out


class MmgRayLauncher(Launcher):
    """Hydra launcher that runs all jobs of a multirun as one sweep on Ray, tracked in MLflow."""

    def __init__(self) -> None:
        self.config: DictConfig | None = None
        self.hydra_context: HydraContext | None = None
        self.task_function: TaskFunction | None = None

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        """Keep what Hydra hands over: the primary config, its context and the task function
        (unused: jobs run :func:`sweep.service.job.run_job` on Ray, not the task function)."""
        self.config = config
        self.hydra_context = hydra_context
        self.task_function = task_function

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        """Compose and validate every job's config, run the sweep, print the J2 table.

        Returns one COMPLETED :class:`JobReturn` per job whose return value is ``"ok"`` or the
        job's error (the sweep's summary, with its failures, is :data:`LAST_SUMMARY`). A user
        mistake exits with a one-line error.
        """
        from sweep.errors import exit_on_user_error

        with exit_on_user_error():
            return self._launch(job_overrides, initial_job_idx)

    def _launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        global LAST_SUMMARY
        from sweep.service.job import JobSpec
        from sweep.service.orchestration import (
            Progress,
            check_recordings,
            efd_reference,
            run_sweep,
            spec_from_config,
        )
        from sweep.service.raycluster import RayExecutor
        from sweep.service.schema import validate
        from sweep.service.tracking import RETRY_SECONDS, MlflowTracker

        assert self.config is not None and self.hydra_context is not None
        specs: list[JobSpec] = []
        job_cfgs: list[DictConfig] = []
        for idx, overrides in enumerate(job_overrides):
            cfg = self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
            with open_dict(cfg):
                cfg.hydra.job.id = f"job_{initial_job_idx + idx}"
                cfg.hydra.job.num = initial_job_idx + idx
            HydraConfig.instance().set_config(cfg)
            job_dir = Path(cfg.hydra.sweep.dir) / str(cfg.hydra.sweep.subdir)
            plain = job_config(cfg)
            validate(plain)  # every job's configuration, before Ray or MLflow start
            specs.append(spec_from_config(plain, job_dir))
            job_cfgs.append(cfg)
        check_recordings(specs)  # bad files fail here; data warnings are said once
        first = job_cfgs[0]
        sweep_dir = Path(first.hydra.sweep.dir)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        progress = Progress(every=float(first.sweep.progress_seconds))
        tracker = MlflowTracker(
            str(first.tracking.uri),
            str(first.tracking.experiment),
            allow_config_change=bool(first.sweep.allow_config_change),
            retry_seconds=float(first.tracking.get("retry_seconds", RETRY_SECONDS)),
            notify=progress.note,
        )
        data_root = first.data.root
        efd = efd_reference(job_config(first)["test"], data_root)
        executor = RayExecutor(
            address=first.ray.address,
            num_cpus=first.ray.num_cpus,
            workers_per_job=int(first.ray.workers_per_job),
            jobs=len(specs),
            cpus_per_worker=first.ray.get("cpus_per_worker"),
        )
        try:
            summary = run_sweep(
                name=str(first.sweep.name),
                specs=specs,
                executor=executor,
                tracker=tracker,
                efd=efd,
                out_dir=sweep_dir,
                sweep_config={
                    "overrides": [" ".join(o) for o in job_overrides],
                    "jobs": len(specs),
                },
                max_concurrent=first.ray.max_concurrent_jobs,
                progress=progress,
                max_retries=int(first.sweep.get("max_retries", 3)),
            )
        finally:
            executor.shutdown()
        LAST_SUMMARY = summary
        if "J2" in summary.tables:
            from sweep.service.tables import format_table

            # the user's question, answered in the terminal: the J2 table, the others' paths
            print("\n" + format_table(summary.tables["J2"], "J2 on the test set"), file=sys.stderr)
            others = sorted(str(p) for n, p in summary.files.items() if n.endswith(".md"))
            print(f"tables: {', '.join(others)}", file=sys.stderr)
        log.info(
            "sweep %s: %d finished, %d skipped, %d failed in %.0f s; tables in %s",
            first.sweep.name,
            len(summary.finished),
            len(summary.skipped),
            len(summary.failed),
            summary.seconds,
            sweep_dir / "summary",
        )
        returns = []
        for spec, cfg, overrides in zip(specs, job_cfgs, job_overrides, strict=True):
            ret = JobReturn(
                overrides=list(overrides),
                cfg=cfg,
                hydra_cfg=cfg,
                working_dir=str(spec.job_dir),
                task_name="sweep",
                status=JobStatus.COMPLETED,
                _return_value=summary.failed.get(spec.key, "ok"),
            )
            returns.append(ret)
        return returns
