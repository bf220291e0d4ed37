"""Checkpoints are verified before use and run no code from storage.

A damaged (truncated, bit-flipped), foreign (another job's) or forged checkpoint is set aside,
never unpickled, and the run resumes from the previous checkpoint, or afresh; either way it ends
where an uninterrupted run ends. The key comes from $MMG_CHECKPOINT_KEY or the user's key file.
"""

from __future__ import annotations

import os
import pickle
import stat
from pathlib import Path

import numpy as np
import pytest

from sweep.identification import checkpoint as envelope
from sweep.identification.checkpoint import CheckpointError, checkpoint_key, seal
from sweep.identification.cmaes import Box, Settings, load_checkpoint, optimise
from sweep.identification.workers import InProcess
from sweep.service.storage import Location
from sweep.service.tracking import outcome_metrics, outcome_tags

N = 6
BOX = Box(-5.0 * np.ones(N), 5.0 * np.ones(N))
SETTINGS = Settings(seed=11, max_evaluations=2000, sigma0=0.3, tolfun=1e-4)
KEY = b"k" * 32
JOB = "job-a"


def rastrigin(X):
    X = np.asarray(X)
    return 10 * N + np.sum(X * X - 10 * np.cos(2 * np.pi * X), axis=1)


def run(ck=None, key=KEY, job=JOB, **kwargs):
    return optimise(rastrigin, BOX, np.zeros(N), SETTINGS, checkpoint=ck, checkpoint_key=key,
                    checkpoint_job=job, checkpoint_seconds=0.0, **kwargs)  # fmt: skip


@pytest.fixture(scope="module")
def full():
    """The uninterrupted run."""
    return run()


class Planted:
    """A pickle that, if it were ever unpickled, would create ``marker``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def interrupted(tmp_path: Path, generations: int = 10, **kwargs) -> Path:
    """A checkpoint ``ck.pkl`` and its previous one ``ck.pkl.prev`` (one generation older)."""
    ck = tmp_path / "ck.pkl"
    run(ck, stop_after_generations=generations, **kwargs)
    assert ck.is_file() and (tmp_path / "ck.pkl.prev").is_file()
    return ck


def damage(kind: str, ck: Path, tmp_path: Path) -> bytes:
    """Replace the checkpoint as ``kind`` says; returns the bytes left there."""
    data = ck.read_bytes()
    marker = tmp_path / "planted"
    if kind == "truncated":
        bad = data[:100]
    elif kind == "bit-flipped":
        i = len(data) // 2
        bad = data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1 :]
    elif kind == "foreign":  # another job's valid checkpoint, signed with the same key
        other = tmp_path / "other"
        run(other / "ck.pkl", job="job-b", stop_after_generations=3)
        bad = (other / "ck.pkl").read_bytes()
    elif kind == "forged pickle":  # today's raw format: a bare pickle
        bad = pickle.dumps(Planted(marker))
    elif kind == "forged envelope":  # a correct-looking header whose HMAC is wrong
        bad = seal(pickle.dumps(Planted(marker)), b"the attacker's key", JOB)
    else:
        raise AssertionError(kind)
    ck.write_bytes(bad)
    return bad


REASONS = {
    "truncated": "truncated",
    "bit-flipped": "checksum mismatch",
    "foreign": "written for another job",
    "forged pickle": "other format",
    "forged envelope": "not authenticated",
}


@pytest.mark.parametrize("kind", list(REASONS))
def test_a_bad_checkpoint_is_set_aside_and_the_run_resumes_from_the_previous_one(
    kind, tmp_path, full, capsys
):
    ck = interrupted(tmp_path)
    previous_evaluations = load_checkpoint(tmp_path / "ck.pkl.prev", KEY, JOB).evaluations
    bad = damage(kind, ck, tmp_path)
    capsys.readouterr()
    with pytest.raises(CheckpointError, match=REASONS[kind]):
        load_checkpoint(ck, KEY, JOB)
    seen: list[int] = []
    resumed = run(ck, progress=lambda state, row: seen.append(state.evaluations))
    assert seen[0] == previous_evaluations + 20  # the first generation after the previous one
    assert resumed.recovery is not None and resumed.recovery.resumed == "previous"
    assert [r.reason for r in resumed.recovery.rejected] == [REASONS[kind]]
    assert (tmp_path / "ck.pkl.bad-1").read_bytes() == bad  # set aside, not deleted
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(ck) in err and REASONS[kind] in err
    assert "set aside as ck.pkl.bad-1" in err and "resuming from the previous checkpoint" in err
    assert not (tmp_path / "planted").exists()
    assert resumed.f == full.f and np.array_equal(resumed.theta, full.theta)
    assert resumed.evaluations == full.evaluations


def test_with_both_checkpoints_bad_the_run_starts_afresh(tmp_path, full, capsys):
    ck = interrupted(tmp_path)
    damage("truncated", ck, tmp_path)
    prev = tmp_path / "ck.pkl.prev"
    damage("forged envelope", prev, tmp_path)
    (tmp_path / "ck.pkl.bad-1").write_bytes(b"an older one set aside")
    capsys.readouterr()
    resumed = run(ck)
    assert resumed.recovery is not None and resumed.recovery.resumed == "fresh"
    assert resumed.recovery.tag() == "fresh: truncated, not authenticated"
    assert (tmp_path / "ck.pkl.bad-1").read_bytes() == b"an older one set aside"
    assert (tmp_path / "ck.pkl.bad-2").stat().st_size == 100
    assert (tmp_path / "ck.pkl.prev.bad-1").is_file()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "starting afresh" in err
    assert not (tmp_path / "planted").exists()
    assert resumed.f == full.f and np.array_equal(resumed.theta, full.theta)
    assert resumed.evaluations == full.evaluations


def test_a_checkpoint_signed_with_another_key_is_not_authenticated(tmp_path, full):
    ck = interrupted(tmp_path, key=b"another key")
    resumed = run(ck)
    assert resumed.recovery is not None
    assert resumed.recovery.tag() == "fresh: not authenticated, not authenticated"
    assert resumed.f == full.f and resumed.evaluations == full.evaluations


def test_a_crash_between_keeping_the_previous_and_writing_the_new_one_resumes(tmp_path, full):
    """The previous checkpoint alone (the current one not yet written) is resumed from, quietly."""
    ck = interrupted(tmp_path)
    ck.unlink()
    resumed = run(ck)
    assert resumed.recovery is None
    assert resumed.f == full.f and resumed.evaluations == full.evaluations


def test_a_storage_location_keeps_the_previous_checkpoint_and_sets_a_bad_one_aside(tmp_path, full):
    """The same through a storage URI's store (sweep.service.storage.Location)."""
    uri = f"file://{tmp_path}/store/ck.pkl"
    run(Location(uri), stop_after_generations=6)
    assert (tmp_path / "store" / "ck.pkl.prev").is_file()
    damage("bit-flipped", tmp_path / "store" / "ck.pkl", tmp_path)
    resumed = run(Location(uri))
    assert resumed.recovery is not None and resumed.recovery.tag() == "previous: checksum mismatch"
    assert (tmp_path / "store" / "ck.pkl.bad-1").is_file()
    assert resumed.f == full.f and resumed.evaluations == full.evaluations


def test_the_key_comes_from_the_environment_or_the_users_key_file(tmp_path, monkeypatch):
    monkeypatch.setattr(envelope.platformdirs, "user_config_dir", lambda app: str(tmp_path / app))
    monkeypatch.delenv(envelope.KEY_VARIABLE, raising=False)
    key = checkpoint_key()
    path = tmp_path / "mmg-sweep" / "checkpoint.key"
    assert len(key) == 32 and path.read_bytes() == key
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert checkpoint_key() == key  # the next process (the same user) reads the same key
    monkeypatch.setenv(envelope.KEY_VARIABLE, "00ff10")
    assert checkpoint_key() == b"\x00\xff\x10"  # hex
    monkeypatch.setenv(envelope.KEY_VARIABLE, "a passphrase")
    assert checkpoint_key() == b"a passphrase"  # any other text
    monkeypatch.setenv(envelope.KEY_VARIABLE, " ")
    with pytest.raises(envelope.CheckpointKeyError, match="empty"):
        checkpoint_key()


def test_a_checkpoint_under_the_environments_key_is_refused_under_the_key_file(
    tmp_path, monkeypatch
):
    """optimise without a key uses the user's: $MMG_CHECKPOINT_KEY, else the key file."""
    monkeypatch.setattr(envelope.platformdirs, "user_config_dir", lambda app: str(tmp_path / app))
    monkeypatch.setenv(envelope.KEY_VARIABLE, "a passphrase")
    ck = tmp_path / "ck.pkl"
    optimise(rastrigin, BOX, np.zeros(N), SETTINGS, checkpoint=ck, stop_after_generations=3)
    assert load_checkpoint(ck).evaluations == 60
    monkeypatch.delenv(envelope.KEY_VARIABLE)
    with pytest.raises(CheckpointError, match="not authenticated"):
        load_checkpoint(ck)


def test_a_rejected_checkpoint_reaches_the_jobs_outcome_and_its_child_run(tmp_path, data_dir):
    """Through run_job: a truncated checkpoint -> resumed from the previous one; a checkpoint
    of another configuration (another config hash) -> set aside, fresh. The tag and the counter
    reach the outcome and the child run; the results equal an uninterrupted job's."""
    from mmg import efd_parameters
    from sweep.identification.vector import joint_box
    from sweep.service.job import run_job, settings_of
    from sweep.service.orchestration import spec_from_config
    from tests.test_service import _cfg

    def spec(name: str, budget: int = 100):
        cfg = _cfg("J2", 0, budget)
        cfg["data"]["root"] = str(data_dir)
        cfg["sweep"] = {"name": "integrity", "checkpoint_seconds": 0.0}
        return spec_from_config(cfg, tmp_path / name)

    def interrupt(job, written_for):
        from sweep.data.datasets import split_from_mapping
        from sweep.data.objective import Objective

        train = split_from_mapping(dict(job.config["train"]), "train").load(str(data_dir))
        job.job_dir.mkdir(parents=True)
        optimise(
            InProcess(Objective(list(train.values()), "J2")), joint_box(()),
            efd_parameters().vector(), settings_of(written_for.config, 0),
            checkpoint=job.checkpoint_location, stop_after_generations=3, checkpoint_seconds=0.0,
            checkpoint_key=job.checkpoint_key, checkpoint_job=written_for.config_hash,
        )  # fmt: skip

    fresh, _ = run_job(spec("fresh"), InProcess, plots=False)
    assert fresh.checkpoint_recovery == "" and fresh.checkpoint_rejected == 0
    assert "checkpoint.recovery" not in outcome_tags(fresh, "parent")
    assert outcome_metrics(fresh)["checkpoint_rejected"] == 0.0

    cut = spec("cut")
    interrupt(cut, cut)
    path = cut.job_dir / "checkpoint.pkl"
    path.write_bytes(path.read_bytes()[:100])
    outcome, _ = run_job(cut, InProcess, plots=False)
    assert outcome.checkpoint_recovery == "previous: truncated"
    assert outcome_tags(outcome, "parent")["checkpoint.recovery"] == "previous: truncated"
    assert outcome_metrics(outcome)["checkpoint_rejected"] == 1.0
    assert outcome.f == fresh.f and outcome.evaluations == fresh.evaluations

    foreign = spec("foreign")
    interrupt(foreign, spec("other", budget=200))
    outcome, _ = run_job(foreign, InProcess, plots=False)
    assert outcome.checkpoint_recovery == "fresh: written for another job, written for another job"
    assert outcome_metrics(outcome)["checkpoint_rejected"] == 2.0
    assert (foreign.job_dir / "checkpoint.pkl.bad-1").is_file()
    assert outcome.f == fresh.f and outcome.evaluations == fresh.evaluations
