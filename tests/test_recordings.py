"""Tests of sweep.data.recordings on the real FRT-DS-ESSO files and on malformed copies of them.

The recordings are read from $MMG_DATA_DIR, else ../shared/data/frt-ds-esso beside the repository.
Malformed files are written into tmp_path only.
"""

from __future__ import annotations

import csv
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sweep.data.recordings import (
    DT,
    MIN_SAMPLES,
    Recording,
    RecordingError,
    RecordingWarning,
    read_recording,
    read_recordings,
    wrap_angle,
    write_parquet,
)

RANDOM_1 = "data/random/random_06-Aug-2020_16_24_25_1.csv"
RANDOM_4 = "data/random/random_06-Aug-2020_16_24_25_4.csv"
TURN_TEST = "data/turning/turn_14-Sep-2020_14_50_41.csv"
TURN_CUT = "data/turning/turn_cut_14-Sep-2020_15_58_08.csv"
ZIGZAG_TRAILING = "data/zigzag/zigzag_31-Jul-2020_13_50_28.csv"
ZIGZAG = "data/zigzag/zigzag_31-Jul-2020_13_22_52.csv"

Rows = list[list[str]]


def _head(data_dir: Path, rel: str, n: int = 300) -> tuple[list[str], Rows]:
    """Header and first n data rows of a real file, as strings."""
    with (data_dir / rel).open(newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        rows = [row for _, row in zip(range(n), reader, strict=False)]
    return header, rows


def _write(path: Path, header: list[str], rows: Rows, tail: str = "") -> Path:
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(rows)
        fh.write(tail)
    return path


def _variant(
    data_dir: Path,
    tmp_path: Path,
    edit: Callable[[list[str], Rows], None],
    rel: str = ZIGZAG,
    n: int = 300,
    tail: str = "",
) -> Path:
    header, rows = _head(data_dir, rel, n)
    edit(header, rows)
    return _write(tmp_path / "bad.csv", header, rows, tail)


def _col(header: list[str], name: str) -> int:
    return header.index(name)


# -------------------------------------------------------------------------------------------------
# the real files


def test_real_random_file_values_and_layout(data_dir: Path) -> None:
    rec = read_recording(data_dir / RANDOM_1)
    assert rec.name == "random_06-Aug-2020_16_24_25_1"
    assert rec.path == data_dir / RANDOM_1
    assert rec.n_samples == 6717
    assert rec.t.shape == (6717,) and rec.x.shape == (6717, 6)
    assert rec.u.shape == (6717, 2) and rec.w.shape == (6717, 2)
    # first CSV row, reordered into state / control (delta, n_p) / true wind
    np.testing.assert_array_equal(
        rec.x[0],
        [
            1.94369887982279,
            0.0026239957439088,
            1.56550548447008,
            0.0071168358440694,
            0.0335089747970352,
            -0.0034096346712241,
        ],
    )
    np.testing.assert_array_equal(rec.u[0], [0.0, 9.99969482421875])
    np.testing.assert_array_equal(rec.w[0], [3.35372618593842, 5.19827538008124])
    assert rec.w_apparent is not None
    np.testing.assert_array_equal(rec.w_apparent[0], [3.34847666035523, 5.1664002397363])
    assert rec.dt == DT == 0.1
    assert rec.duration == pytest.approx(671.6, abs=1e-9)
    assert rec.duration == pytest.approx(rec.t[-1] - rec.t[0], abs=1e-9)
    assert np.abs(rec.u[:, 0]).max() < 0.62  # rudder angle in rad
    assert np.abs(rec.u[:, 1]).max() == pytest.approx(10.0)  # propeller in rps


def test_random_cut_time_does_not_start_at_zero(data_dir: Path) -> None:
    rec = read_recording(data_dir / RANDOM_4)
    assert rec.t[0] == pytest.approx(1894.0)
    assert rec.duration == pytest.approx(607.6, abs=1e-9)


def test_arrays_are_read_only(data_dir: Path) -> None:
    rec = read_recording(data_dir / ZIGZAG)
    with pytest.raises(ValueError, match="read-only"):
        rec.x[0, 0] = 1.0
    with pytest.raises(AttributeError):
        rec.name = "other"  # type: ignore[misc]


def test_real_zigzag_trailing_empty_rows_warn_327(data_dir: Path) -> None:
    with pytest.warns(RecordingWarning, match=r"dropped 327 trailing empty rows") as record:
        rec = read_recording(data_dir / ZIGZAG_TRAILING)
    assert len(record) == 1
    assert "zigzag_31-Jul-2020_13_50_28.csv" in str(record[0].message)
    assert rec.n_samples == 2028 - 327
    assert rec.duration == pytest.approx(170.0, abs=1e-9)
    assert np.all(np.isfinite(rec.x))


def test_clean_file_gives_no_warning(data_dir: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_recording(data_dir / ZIGZAG)


def test_psi_is_unwrapped_in_the_turning_file(data_dir: Path) -> None:
    raw = pd.read_csv(data_dir / TURN_TEST)["psi_hat [rad]"].to_numpy()
    assert np.abs(np.diff(raw)).max() > np.pi  # the file is wrapped: the test is meaningful
    rec = read_recording(data_dir / TURN_TEST)
    psi = rec.x[:, 4]
    assert np.abs(np.diff(psi)).max() < 0.1  # no jump > pi, in fact smooth at 10 Hz
    assert psi[-1] - psi[0] == pytest.approx(12.74, abs=0.01)  # two full turns to starboard
    np.testing.assert_allclose(rec.psi_wrapped, raw, rtol=0, atol=1e-12)
    np.testing.assert_allclose(wrap_angle(psi), raw, rtol=0, atol=1e-12)


def test_parquet_round_trip(data_dir: Path, tmp_path: Path) -> None:
    rec = read_recording(data_dir / TURN_CUT)
    out = write_parquet(rec, tmp_path / "sub" / f"{rec.name}.parquet")
    assert out.is_file() and not list(out.parent.glob(".*.tmp"))
    cols = list(pd.read_parquet(out).columns)
    with (data_dir / TURN_CUT).open() as fh:
        assert cols == fh.readline().strip().split(",")  # same names and order as the CSV
    back = read_recording(out)
    assert back.name == rec.name
    np.testing.assert_array_equal(back.t, rec.t)
    np.testing.assert_array_equal(back.u, rec.u)
    np.testing.assert_array_equal(back.w, rec.w)
    assert back.w_apparent is not None and rec.w_apparent is not None
    np.testing.assert_array_equal(back.w_apparent, rec.w_apparent)
    np.testing.assert_array_equal(back.x[:, [0, 1, 2, 3, 5]], rec.x[:, [0, 1, 2, 3, 5]])
    np.testing.assert_allclose(back.x[:, 4], rec.x[:, 4], rtol=0, atol=1e-12)
    assert rec.x[:, 4].max() > 6.0  # unwrapped across a full turn: beyond pi


def test_read_recordings_directories_recursive_sorted(data_dir: Path, tmp_path: Path) -> None:
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "deep").mkdir(parents=True)
    zig = read_recording(data_dir / ZIGZAG)
    write_parquet(zig, tmp_path / "b" / "zz.parquet")
    header, rows = _head(data_dir, RANDOM_1, 200)
    _write(tmp_path / "a" / "deep" / "r1.csv", header, rows)
    (tmp_path / "a" / "notes.txt").write_text("not a recording")
    recs = read_recordings([tmp_path, data_dir / RANDOM_4])
    assert [r.name for r in recs] == ["r1", "zz", "random_06-Aug-2020_16_24_25_4"]
    assert recs[0].n_samples == 200
    assert read_recordings(tmp_path / "b")[0].n_samples == zig.n_samples
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(RecordingError, match=r"no \*\.csv or \*\.parquet"):
        read_recordings(empty)


# -------------------------------------------------------------------------------------------------
# malformed files


def test_misspelled_column_suggests_expected_name(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        header[_col(header, "n_prop [rps]")] = "n_porp [rps]"

    path = _variant(data_dir, tmp_path, edit)
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    msg = str(exc.value)
    assert str(path) in msg
    assert "'n_porp [rps]'" in msg and "did you mean 'n_prop [rps]'" in msg


def test_wrong_unit_in_header_suggests_expected_name(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        header[_col(header, "delta_rudder [rad]")] = "delta_rudder [deg]"

    with pytest.raises(RecordingError, match=r"did you mean 'delta_rudder \[rad\]'"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_missing_column_is_named(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "wind_dir_true [rad]")
        del header[j]
        for row in rows:
            del row[j]

    with pytest.raises(RecordingError, match=r"missing required column 'wind_dir_true \[rad\]'"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_apparent_wind_columns_are_optional(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        for name in ("wind_velo_relative_mid [m/s]", "wind_dir_relative_mid [rad]"):
            j = _col(header, name)
            del header[j]
            for row in rows:
                del row[j]

    rec = read_recording(_variant(data_dir, tmp_path, edit))
    full = read_recording(data_dir / ZIGZAG)
    assert rec.w_apparent is None
    np.testing.assert_array_equal(rec.w, full.w[:300])
    np.testing.assert_array_equal(rec.x, full.x[:300])


def test_apparent_wind_must_be_numeric(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[9][_col(header, "wind_dir_relative_mid [rad]")] = "NNE"

    with pytest.raises(RecordingError, match=r"'wind_dir_relative_mid \[rad\]', row 10: non-num"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_non_numeric_value_names_file_column_row(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[56][_col(header, "u_velo [m/s]")] = "0.1O3"  # letter O, row 57

    path = _variant(data_dir, tmp_path, edit)
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    msg = str(exc.value)
    assert str(path) in msg
    assert "column 'u_velo [m/s]', row 57: non-numeric value '0.1O3'" in msg


def test_empty_row_in_the_middle(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[99] = [""] * len(header)  # row 100 blanked: ",,,,,,"

    with pytest.raises(RecordingError, match=r"row 100 \(line 101\) is empty in the middle"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_blank_line_in_the_middle(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows.insert(150, [])  # a truly blank line becomes row 151

    with pytest.raises(RecordingError, match=r"row 151 \(line 152\) is empty in the middle"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_nan_value_in_the_middle(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[119][_col(header, "r_angvelo [rad/s]")] = "NaN"

    with pytest.raises(
        RecordingError, match=r"column 'r_angvelo \[rad/s\]', row 120: missing value"
    ):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_empty_field_in_the_middle(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[4][_col(header, "n_prop [rps]")] = ""

    with pytest.raises(RecordingError, match=r"column 'n_prop \[rps\]', row 5: missing value"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_ragged_row(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[19] = rows[19][:-2]

    with pytest.raises(
        RecordingError, match=r"row 20 \(line 21\) has 11 fields, the header has 13"
    ):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_non_increasing_time(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[149][0] = rows[148][0]  # row 150 repeats the time of row 149

    with pytest.raises(RecordingError) as exc:
        read_recording(_variant(data_dir, tmp_path, edit))
    msg = str(exc.value)
    assert "column 't [s]', row 150: time does not increase" in msg
    assert "t = 14.8 s after t = 14.8 s at row 149" in msg


def test_decreasing_time(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[30], rows[31] = rows[31], rows[30]  # rows 31 and 32 swapped

    with pytest.raises(RecordingError, match=r"row 32: time does not increase"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_irregular_step_from_a_dropped_sample(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        del rows[199]  # row 200 now follows row 199 after 0.2 s

    with pytest.raises(RecordingError) as exc:
        read_recording(_variant(data_dir, tmp_path, edit))
    msg = str(exc.value)
    assert "column 't [s]', row 200: irregular time step 0.2 s" in msg
    assert "expected 0.1 s +- 0.001 s" in msg


def test_irregular_step_jitter_beyond_tolerance(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[79][0] = f"{float(rows[79][0]) + 0.002:.4f}"  # 2 ms late: beyond the 1 ms tolerance

    with pytest.raises(RecordingError, match=r"row 80: irregular time step 0.102 s"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_step_jitter_within_tolerance_is_accepted(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[79][0] = f"{float(rows[79][0]) + 0.0005:.4f}"

    rec = read_recording(_variant(data_dir, tmp_path, edit))
    assert rec.t[79] == pytest.approx(7.9005)


def test_rudder_in_degrees(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "delta_rudder [rad]")
        for row in rows:
            row[j] = repr(float(np.degrees(float(row[j]))))

    header, rows = _head(data_dir, ZIGZAG)
    delta = np.array([float(r[_col(header, "delta_rudder [rad]")]) for r in rows])
    first = int(np.flatnonzero(np.abs(np.degrees(delta)) > np.pi / 2)[0]) + 1
    with pytest.raises(RecordingError) as exc:
        read_recording(_variant(data_dir, tmp_path, edit))
    msg = str(exc.value)
    assert f"column 'delta_rudder [rad]', row {first}: implausible value" in msg
    assert "degrees where radians are expected" in msg


def test_yaw_rate_in_degrees_per_second_large(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "r_angvelo [rad/s]")
        rows[41][j] = "4.5"  # one sample in deg/s beyond |r| = 3 rad/s

    with pytest.raises(RecordingError, match=r"'r_angvelo \[rad/s\]', row 42: implausible value"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_yaw_rate_in_degrees_per_second_caught_by_heading(data_dir: Path, tmp_path: Path) -> None:
    # |r| of this model stays below 0.07 rad/s (4 deg/s): only the heading consistency check
    # can tell deg/s from rad/s
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "r_angvelo [rad/s]")
        for row in rows:
            row[j] = repr(float(np.degrees(float(row[j]))))

    path = _variant(data_dir, tmp_path, edit, rel=ZIGZAG_TRAILING)
    header, rows = _head(data_dir, ZIGZAG_TRAILING)
    r_deg = np.degrees([float(r[_col(header, "r_angvelo [rad/s]")]) for r in rows])
    assert np.abs(r_deg).max() < 3.0  # the magnitude limit alone would not see it
    with pytest.raises(RecordingError, match=r"degrees per second where rad/s is expected"):
        read_recording(path)
    read_recording(_variant(data_dir, tmp_path, lambda h, r: None, rel=ZIGZAG_TRAILING))


def test_heading_in_degrees(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "psi_hat [rad]")
        for row in rows:
            row[j] = repr(float(np.degrees(float(row[j]))))

    with pytest.raises(RecordingError, match=r"'psi_hat \[rad\]', row \d+: implausible value"):
        read_recording(_variant(data_dir, tmp_path, edit, rel=RANDOM_4))


def test_small_heading_in_degrees_caught_by_yaw_rate(data_dir: Path, tmp_path: Path) -> None:
    # this zigzag start keeps |psi| < 3 deg: only the consistency with r reveals the degrees
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "psi_hat [rad]")
        for row in rows:
            row[j] = repr(float(np.degrees(float(row[j]))))

    header, rows = _head(data_dir, ZIGZAG)
    psi_deg = np.degrees([float(r[_col(header, "psi_hat [rad]")]) for r in rows])
    assert np.abs(psi_deg).max() < np.pi
    with pytest.raises(RecordingError, match=r"heading in degrees where radians are expected"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_propeller_in_rpm(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "n_prop [rps]")
        for row in rows:
            row[j] = repr(60.0 * float(row[j]))

    with pytest.raises(RecordingError) as exc:
        read_recording(_variant(data_dir, tmp_path, edit))
    msg = str(exc.value)
    assert "column 'n_prop [rps]', row 1: implausible value 600" in msg
    assert "rpm where rev/s (rps) is expected" in msg


def test_negative_wind_speed(data_dir: Path, tmp_path: Path) -> None:
    def edit(header: list[str], rows: Rows) -> None:
        rows[2][_col(header, "wind_velo_true [m/s]")] = "-1.5"

    with pytest.raises(RecordingError, match=r"'wind_velo_true \[m/s\]', row 3: negative wind"):
        read_recording(_variant(data_dir, tmp_path, edit))


def test_too_short_run(data_dir: Path, tmp_path: Path) -> None:
    path = _variant(data_dir, tmp_path, lambda h, r: None, n=MIN_SAMPLES - 1)
    with pytest.raises(RecordingError, match=r"too short a run: 100 samples \(9.9 s\)"):
        read_recording(path)
    assert read_recording(_variant(data_dir, tmp_path, lambda h, r: None, n=MIN_SAMPLES))


def test_trailing_empty_rows_dropped_with_count(data_dir: Path, tmp_path: Path) -> None:
    header, _ = _head(data_dir, ZIGZAG, 0)
    path = _variant(data_dir, tmp_path, lambda h, r: None, tail="," * 12 + "\n" * 5 + "\n\n")
    with pytest.warns(RecordingWarning, match=r"dropped 7 trailing empty rows \(rows 301-307\)"):
        rec = read_recording(path)
    assert len(header) == 13
    assert rec.n_samples == 300
    assert rec.duration == pytest.approx(29.9)


def test_only_header(tmp_path: Path, data_dir: Path) -> None:
    header, _ = _head(data_dir, ZIGZAG, 0)
    path = _write(tmp_path / "bad.csv", header, [], tail="," * 12 + "\n")
    with pytest.raises(RecordingError, match="no data rows"):
        read_recording(path)


def test_unsupported_suffix_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"unsupported file type '\.xlsx'"):
        read_recording(tmp_path / "run.xlsx")
    with pytest.raises(FileNotFoundError, match=r"nope\.csv"):
        read_recording(tmp_path / "nope.csv")


def test_parquet_with_text_value(data_dir: Path, tmp_path: Path) -> None:
    frame = read_recording(data_dir / ZIGZAG).frame().head(300)
    text = [repr(v) for v in frame["u_velo [m/s]"]]
    text[9] = "fast"
    frame["u_velo [m/s]"] = text
    path = tmp_path / "bad.parquet"
    frame.to_parquet(path, index=False)
    with pytest.raises(RecordingError, match=r"bad.parquet: column 'u_velo \[m/s\]', row 10: non"):
        read_recording(path)


def test_constructor_checks_shapes() -> None:
    t = np.asarray(np.arange(5) * DT, dtype=np.float64)
    with pytest.raises(RecordingError, match=r"x: shape \(5, 5\)"):
        Recording("r", None, t, np.zeros((5, 5)), np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(RecordingError, match="non-finite"):
        Recording("r", None, t, np.full((5, 6), np.nan), np.zeros((5, 2)), np.zeros((5, 2)))
    rec = Recording("r", None, t, np.zeros((5, 6)), np.zeros((5, 2)), np.zeros((5, 2)))
    assert rec.duration == pytest.approx(0.4)


def _scale_columns(names: tuple[str, ...], factor: float) -> Callable[[list[str], Rows], None]:
    def edit(header: list[str], rows: Rows) -> None:
        for name in names:
            j = _col(header, name)
            for row in rows:
                row[j] = repr(factor * float(row[j]))

    return edit


def _swap_columns(a: str, b: str) -> Callable[[list[str], Rows], None]:
    def edit(header: list[str], rows: Rows) -> None:
        i, j = _col(header, a), _col(header, b)
        for row in rows:
            row[i], row[j] = row[j], row[i]

    return edit


@pytest.mark.parametrize(
    ("edit", "reading"),
    [
        (_scale_columns(("u_velo [m/s]", "vm_velo [m/s]"), 100.0), "in cm/s"),
        (_swap_columns("x_position_mid [m]", "y_position_mid [m]"), "position columns swapped"),
        (_scale_columns(("vm_velo [m/s]",), -1.0), "v_m of the opposite sign"),
    ],
    ids=["cm_per_s", "x_y_swapped", "v_sign"],
)
@pytest.mark.parametrize("rel", [ZIGZAG, TURN_TEST])
def test_velocities_that_do_not_integrate_to_the_track_are_rejected(
    data_dir: Path, tmp_path: Path, edit: Callable[[list[str], Rows], None], reading: str, rel: str
) -> None:
    """u in cm/s, swapped x and y columns, a v_m of the wrong sign: the error names the file,
    the columns, the misfit found and the reading under which the columns would agree."""
    path = _variant(data_dir, tmp_path, edit, rel=rel, n=1200)
    with pytest.raises(RecordingError) as err:
        read_recording(path)
    text = str(err.value)
    assert text.startswith(str(path))
    assert "'u_velo [m/s]'" in text and "'x_position_mid [m]'" in text
    assert "do not integrate to the track" in text and "ratio" in text
    assert reading in text, text


def test_every_real_recording_integrates_to_its_track(data_dir: Path) -> None:
    """The check's tolerance leaves a wide margin on the real data (misfit 3-5 %, ratio ~1)."""
    from sweep.data.recordings import TRACK_TOLERANCE, _track_misfit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recs = read_recordings(data_dir / "data")
    assert len(recs) == 13
    for rec in recs:
        x = np.asarray(rec.x)
        misfit, ratio, corr, rms = _track_misfit(x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4])
        assert misfit < TRACK_TOLERANCE / 2.5 and abs(ratio - 1.0) < 0.01 and corr > 0.99, rec.name
        assert rms > 0.25


def test_a_heading_offset_is_not_mistaken_for_a_wrong_reading(
    data_dir: Path, tmp_path: Path
) -> None:
    """A constant heading error of 0.3 rad makes the velocities miss the track by about 30 %,
    but no mistaken reading (units, swapped columns, a sign) explains it: it is physics or a
    measurement error for the diagnosis to name (heading_bias), so the file is read."""
    from sweep.data.recordings import TRACK_TOLERANCE, _track_misfit

    def edit(header: list[str], rows: Rows) -> None:
        j = _col(header, "psi_hat [rad]")
        for row in rows:
            row[j] = repr(float(wrap_angle(float(row[j]) + 0.3)))

    rec = read_recording(_variant(data_dir, tmp_path, edit, rel=ZIGZAG, n=1200))
    x = np.asarray(rec.x)
    assert _track_misfit(x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4])[0] > 2 * TRACK_TOLERANCE
