"""Tests of sweep.data.datasets: the split configuration, the data root, and the berthing sides.

The recordings are read from $MMG_DATA_DIR, else ../shared/data/frt-ds-esso beside the repository.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from sweep.data import datasets
from sweep.data.datasets import (
    CONF_DIR,
    DataNotFoundError,
    Split,
    SplitError,
    available_splits,
    berthing_evidence,
    berthing_side,
    data_root,
    load_split,
)
from sweep.data.recordings import DT, Recording, RecordingWarning
from sweep.download import CHECKSUMS

R = "data/random/random_06-Aug-2020_16_24_25_{}.csv"
TRAIN = {
    "R": [R.format(1), R.format(4), R.format(5), R.format(6)],
    "TR": [
        R.format(4),
        R.format(5),
        R.format(6),
        "data/turning/turn_cut_14-Sep-2020_15_58_08.csv",
        "data/turning/turn_cut_14-Sep-2020_16_09_02.csv",
    ],
    "TZR": [
        R.format(4),
        R.format(5),
        R.format(6),
        "data/turning/turn_cut_14-Sep-2020_16_09_02.csv",
        "data/zigzag/zigzag_31-Jul-2020_13_22_52.csv",
        "data/zigzag/zigzag_31-Jul-2020_13_50_28.csv",
    ],
}
B_STARBOARD = "data/berthing/berthing_12-Nov-2020_11_49_21.csv"
B_PORT = "data/berthing/berthing_12-Nov-2020_13_21_03.csv"
TEST = {
    "Test-R": R.format(3),
    "Test-T": "data/turning/turn_14-Sep-2020_14_50_41.csv",
    "Test-Z": "data/zigzag/zigzag_31-Jul-2020_14_10_05.csv",
    "Test-B-S": B_STARBOARD,
    "Test-B-P": B_PORT,
}


def _load(split: Split, root: Path) -> dict[str, Recording]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)  # the zigzag file with 327 empty rows
        return split.load(root)


# -------------------------------------------------------------------------------------------------
# split configuration


def test_conf_dir_is_the_repository_conf() -> None:
    assert Path(__file__).resolve().parents[1] / "conf" == CONF_DIR
    assert available_splits() == ["train/R", "train/TR", "train/TZR", "test/paper"]


@pytest.mark.parametrize("stem", ["R", "TR", "TZR"])
def test_train_splits_match_the_paper_table(stem: str) -> None:
    split = load_split(stem)
    assert split.name == f"Train-{stem}"
    assert split.group == "train"
    assert split.source == CONF_DIR / "train" / f"{stem}.yaml"
    assert list(split.files) == TRAIN[stem]
    assert list(split.subsets) == [Path(f).stem for f in TRAIN[stem]]


def test_test_split_matches_the_paper_table() -> None:
    split = load_split("paper")
    assert split.name == "Test"
    assert split.group == "test"
    assert split.subsets == TEST
    assert list(split.subsets) == ["Test-R", "Test-T", "Test-Z", "Test-B-S", "Test-B-P"]


def test_split_name_aliases_and_yaml_path() -> None:
    by_stem = load_split("TZR")
    for alias in ("train/TZR", "Train-TZR", "train-tzr", CONF_DIR / "train" / "TZR.yaml"):
        assert load_split(alias) == by_stem
    assert load_split("Test") == load_split("test/paper") == load_split("paper")


def test_split_files_are_the_13_downloaded_files() -> None:
    files = {f for s in ("R", "TR", "TZR", "paper") for f in load_split(s).files}
    assert files == set(CHECKSUMS)
    assert len(files) == 13


def test_unknown_split_lists_available() -> None:
    with pytest.raises(SplitError, match=r"unknown split 'Train-X'.*'train/R'.*'test/paper'"):
        load_split("Train-X")
    with pytest.raises(SplitError, match="not found"):
        load_split("/nonexistent/split.yaml")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("files: [data/a.csv]\n", "missing or invalid 'name'"),
        ("name: X\n", "exactly one of 'files'"),
        ("name: X\nfiles: [a.csv]\nsubsets: {A: b.csv}\n", "exactly one of 'files'"),
        ("name: X\nfiles: []\n", "non-empty list"),
        ("name: X\nfiles: [/abs/a.csv]\n", "relative POSIX path"),
        ("name: X\nfiles: [../a.csv]\n", "relative POSIX path"),
        ("name: X\nfiles: [data/a.txt]\n", "not a .csv or .parquet"),
        ("name: X\nfiles: [data/a.csv, data/a.csv]\n", "duplicate file"),
        ("name: X\nsubsets: {A: data/a.csv, B: data/a.csv}\n", "listed twice"),
        ("name: X\nfiles: [data/a.csv\n", "invalid YAML"),
        ("- just\n- a list\n", "expected a mapping"),
    ],
)
def test_malformed_split_yaml(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(SplitError, match=message) as exc:
        load_split(path)
    assert str(path) in str(exc.value)


def test_hydra_composes_the_same_groups() -> None:
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name="config", overrides=["train=TR", "test=paper"])
    assert list(cfg.train.files) == list(load_split("TR").files)
    assert cfg.train.name == "Train-TR"
    assert dict(cfg.test.subsets) == TEST


# -------------------------------------------------------------------------------------------------
# data root


def test_data_root_precedence(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setattr(datasets.platformdirs, "user_cache_dir", lambda app: str(cache / app))
    env_dir = tmp_path / "env"
    env_dir.mkdir()
    explicit = tmp_path / "explicit"
    explicit.mkdir()
    monkeypatch.setenv("MMG_DATA_DIR", str(env_dir))
    assert data_root(explicit) == explicit
    assert data_root(str(explicit)) == explicit
    assert data_root() == env_dir
    monkeypatch.setenv("MMG_DATA_DIR", "")
    assert data_root(must_exist=False) == cache / "mmg-sweep" / "frt-ds-esso"
    monkeypatch.delenv("MMG_DATA_DIR")
    assert data_root(must_exist=False) == cache / "mmg-sweep" / "frt-ds-esso"


def test_data_root_missing_says_how_to_download(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(datasets.platformdirs, "user_cache_dir", lambda app: str(tmp_path / app))
    monkeypatch.delenv("MMG_DATA_DIR", raising=False)
    default = tmp_path / "mmg-sweep" / "frt-ds-esso"
    with pytest.raises(DataNotFoundError) as exc:
        data_root()
    msg = str(exc.value)
    assert str(default) in msg and "python -m sweep.download" in msg and "MMG_DATA_DIR" in msg
    assert isinstance(exc.value, FileNotFoundError)
    monkeypatch.setenv("MMG_DATA_DIR", str(tmp_path / "nowhere"))
    with pytest.raises(DataNotFoundError, match=r"nowhere \(from \$MMG_DATA_DIR\) does not exist"):
        data_root()


def test_listed_file_missing_is_named(tmp_path: Path, data_dir: Path) -> None:
    root = tmp_path / "partial"
    keep = root / R.format(1)
    keep.parent.mkdir(parents=True)
    keep.write_bytes((data_dir / R.format(1)).read_bytes())
    with pytest.raises(DataNotFoundError) as exc:
        load_split("R").paths(root)
    msg = str(exc.value)
    assert "3 of 4 file(s) missing" in msg
    assert "random_06-Aug-2020_16_24_25_4.csv" in msg and "_1.csv" not in msg
    assert f"python -m sweep.download --root {root}" in msg


def test_paths_resolve_below_root(data_dir: Path) -> None:
    paths = load_split("paper").paths(data_dir)
    assert paths["Test-B-P"] == data_dir / B_PORT
    assert all(p.is_file() for p in paths.values())


# -------------------------------------------------------------------------------------------------
# durations


@pytest.mark.parametrize(
    ("split", "seconds", "n_files"),
    [("R", 2694.6, 4), ("paper", 1623.6, 5), ("TR", 2579.4, 5), ("TZR", 2635.5, 6)],
)
def test_split_durations(data_dir: Path, split: str, seconds: float, n_files: int) -> None:
    recs = _load(load_split(split), data_dir)
    assert len(recs) == n_files
    assert sum(r.duration for r in recs.values()) == pytest.approx(seconds, abs=0.05)
    assert sum(r.t[-1] - r.t[0] for r in recs.values()) == pytest.approx(seconds, abs=0.05)
    assert sum(r.n_samples for r in recs.values()) * DT != pytest.approx(seconds, abs=0.05)


def test_test_subset_durations(data_dir: Path) -> None:
    recs = _load(load_split("paper"), data_dir)
    got = {k: round(r.duration, 6) for k, r in recs.items()}
    assert got == {
        "Test-R": 717.8,
        "Test-T": 519.7,
        "Test-Z": 152.6,
        "Test-B-S": 127.7,
        "Test-B-P": 105.8,
    }


# -------------------------------------------------------------------------------------------------
# berthing side


def test_paper_yaml_berthing_sides_agree_with_the_tracks(data_dir: Path) -> None:
    recs = _load(load_split("paper"), data_dir)
    starboard = berthing_evidence(recs["Test-B-S"])
    port = berthing_evidence(recs["Test-B-P"])
    assert starboard.side == "starboard"
    assert port.side == "port"
    # the numbers quoted in the module docstring
    assert starboard.mean_v_m_end == pytest.approx(0.0152, abs=5e-4)
    assert starboard.lateral_offset == pytest.approx(5.95, abs=0.01)
    assert np.degrees(starboard.heading_change) == pytest.approx(6.6, abs=0.1)
    assert port.mean_v_m_end == pytest.approx(-0.0226, abs=5e-4)
    assert port.lateral_offset == pytest.approx(-5.49, abs=0.01)
    assert np.degrees(port.heading_change) == pytest.approx(5.5, abs=0.1)
    assert berthing_side(data_dir / B_STARBOARD) == "starboard"
    assert berthing_side(data_dir / B_PORT) == "port"


def test_berthing_evidence_is_robust_to_the_window(data_dir: Path) -> None:
    recs = _load(load_split("paper"), data_dir)
    for tail in (10.0, 20.0, 30.0):
        assert berthing_evidence(recs["Test-B-S"], tail_s=tail).side == "starboard"
        assert berthing_evidence(recs["Test-B-P"], tail_s=tail).side == "port"


def _sideways(v_m: float, psi: float) -> Recording:
    """A ship at constant heading psi drifting sideways at v_m, per the model's kinematics."""
    n = 301
    t = np.asarray(np.arange(n) * DT, dtype=np.float64)
    x = np.zeros((n, 6))
    x[:, 0] = -v_m * np.sin(psi) * t  # x0_dot = u cos psi - v_m sin psi, u = 0
    x[:, 2] = v_m * np.cos(psi) * t  # y0_dot = u sin psi + v_m cos psi
    x[:, 3] = v_m
    x[:, 4] = psi
    return Recording("synthetic", None, t, x, np.zeros((n, 2)), np.zeros((n, 2)))


@pytest.mark.parametrize("psi", [0.0, np.pi / 2, -2.5])
def test_berthing_geometry_sign_convention(psi: float) -> None:
    ev = berthing_evidence(_sideways(0.02, psi))
    assert ev.side == "starboard"
    # offset = distance travelled since the middle of the first 5 s: 0.02 m/s * (30 - 2.5) s
    assert ev.lateral_offset == pytest.approx(0.02 * 27.5, rel=1e-9)
    assert ev.mean_v_m_end == pytest.approx(0.02)
    assert berthing_evidence(_sideways(-0.02, psi)).side == "port"


def test_contradictory_evidence_is_ambiguous() -> None:
    rec = _sideways(0.02, 0.3)
    x = np.array(rec.x)
    x[-100:, 3] = -0.05  # moving to port at the end although it drifted to starboard
    odd = Recording("odd", None, rec.t, x, rec.u, rec.w)
    assert berthing_evidence(odd).side == "ambiguous"
    with pytest.raises(ValueError, match=r"odd: ambiguous berthing side"):
        berthing_side(odd)
