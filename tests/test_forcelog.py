"""Force logs: parsing, unit conversion and every validation / cleaning case."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tympani.pipeline.force.forcelog import (
    G_PER_N,
    ForceLogConfig,
    find_saturation,
    parse_force_log,
    read_force_log,
)
from tympani.vision.errors import InputError


def _log(rows, header="time_s,force_g", comments=("# sensor: test",)) -> str:
    lines = list(comments) + [header] + [",".join(str(v) for v in r) for r in rows]
    return "\n".join(lines) + "\n"


def _ramp(n=50, dt=0.01, scale=1.0):
    t = np.arange(n) * dt
    return [(f"{a:.4f}", f"{scale * (1 + 5 * a):.6f}") for a in t]


def _error(text, cfg=ForceLogConfig(), name="log.csv") -> str:
    with pytest.raises(InputError) as info:
        parse_force_log(text, name=name, cfg=cfg)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


# --------------------------------------------------------------------------- happy paths


def test_parse_grams_with_comments_and_lines():
    text = _log(_ramp(), comments=("# sensor: ATI nano17", "# rate 100 Hz"))
    data, report = parse_force_log(text, name="log.csv")
    assert list(data.columns) == ["time_s", "force_g", "depth_mm", "saturated", "line"]
    assert len(data) == 50 and report.n_samples == 50 and report.n_rows == 50
    assert data["line"].iloc[0] == 4  # two comments and the header come first
    assert report.comments == ("sensor: ATI nano17", "rate 100 Hz")
    assert report.unit == "g" and report.cleaning == () and report.warnings == ()
    assert report.sample_period_s == pytest.approx(0.01)
    assert data["depth_mm"].isna().all() and not data["saturated"].any()
    json.dumps(report.to_dict())  # JSON-compatible


def test_force_newtons_are_converted_to_grams():
    rows = [(f"{0.01 * i:.2f}", f"{0.05 + 0.001 * i:.6f}") for i in range(20)]
    data, report = parse_force_log(_log(rows, header="time_s,force_N"), name="n.csv")
    assert report.unit == "N"
    assert data["force_g"].iloc[0] == pytest.approx(0.05 / 9.80665e-3)
    assert data["force_g"].iloc[-1] == pytest.approx((0.05 + 0.019) * G_PER_N)
    assert not report.warnings


def test_depth_column_and_extra_columns():
    rows = [(f"{0.1 * i:.1f}", f"{1 + i}", "" if i == 3 else f"{0.5 * i}", "x") for i in range(10)]
    data, report = parse_force_log(_log(rows, header="time_s,force_g,depth_mm,note"), name="d.csv")
    assert np.isnan(data["depth_mm"].iloc[3]) and data["depth_mm"].iloc[4] == 2.0
    assert report.columns == ("time_s", "force_g", "depth_mm", "note")


def test_read_force_log_from_file(tmp_path):
    p = tmp_path / "f.csv"
    p.write_text(_log(_ramp()), encoding="utf-8")
    data, report = read_force_log(p)
    assert len(data) == 50 and report.path == str(p)


# --------------------------------------------------------------------------- refused logs


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such force log"):
        read_force_log(tmp_path / "absent.csv")


@pytest.mark.parametrize(
    "header, fragment",
    [
        ("time,force", "missing column(s) time_s, force_g or force_N"),
        ("time_s,force", "missing column(s) force_g or force_N"),
        ("t_ms,force_g", "missing column(s) time_s"),
        ("time_s,force_g,force_N", "both force_g and force_N"),
    ],
)
def test_wrong_columns_name_the_header_line(header, fragment):
    msg = _error(_log([("0", "1", "1")[: len(header.split(","))]], header=header))
    assert msg.startswith("log.csv:2: ") and fragment in msg


def test_non_numeric_value_names_line_and_column():
    rows = _ramp(10)
    rows[4] = ("0.0400", "abc")
    msg = _error(_log(rows))
    assert msg == "log.csv:7: force_g 'abc' is not a number"


def test_infinite_value_is_refused():
    rows = _ramp(10)
    rows[2] = ("0.0200", "inf")
    assert _error(_log(rows)) == "log.csv:5: force_g 'inf' is not finite"


def test_wrong_number_of_fields():
    text = _log(_ramp(5)) + "0.06,1.0,7\n"
    assert "log.csv:8: 3 fields, but the header (line 2) has 2" == _error(text)


def test_empty_and_header_only():
    assert "no header row" in _error("# only a comment\n\n")
    assert "no samples" in _error("time_s,force_g\n")


def test_time_going_backwards_names_both_lines():
    rows = _ramp(10)
    rows[6] = ("0.0450", rows[6][1])  # 0.045 after 0.05
    msg = _error(_log(rows))
    assert msg.startswith("log.csv:9: time_s goes backwards") and "on line 8" in msg


def test_nan_time_is_refused():
    rows = _ramp(10)
    rows[3] = ("nan", rows[3][1])
    assert _error(_log(rows)) == "log.csv:6: time_s is empty or NaN"


def test_too_few_samples():
    assert "only 2 usable sample(s)" in _error(_log(_ramp(2)))


# --------------------------------------------------------------------------- cleaning


def test_nan_force_rows_are_dropped_and_recorded():
    rows = _ramp(40)
    rows[5] = (rows[5][0], "")
    rows[9] = (rows[9][0], "NaN")
    data, report = parse_force_log(_log(rows), name="log.csv")
    assert len(data) == 38
    (step,) = report.cleaning
    assert step.action == "drop_nan" and step.count == 2 and step.lines == (8, 12)
    assert 8 not in set(data["line"]) and 12 not in set(data["line"])


def test_nan_force_policies_refuse():
    rows = _ramp(10)
    rows[5] = (rows[5][0], "")
    assert _error(_log(rows), ForceLogConfig(nan_policy="error")) == "log.csv:8: force_g is empty or NaN"
    many = [(t, "" if i % 2 else f) for i, (t, f) in enumerate(_ramp(10))]
    assert "in 5 of 10 rows" in _error(_log(many))


def test_duplicate_timestamps_are_averaged():
    rows = [("0.00", "1.0"), ("0.01", "2.0"), ("0.01", "4.0"), ("0.02", "3.0"), ("0.03", "4.0")]
    data, report = parse_force_log(_log(rows), name="log.csv")
    assert data["time_s"].tolist() == [0.0, 0.01, 0.02, 0.03]
    assert data["force_g"].tolist() == [1.0, 3.0, 3.0, 4.0]
    assert data["line"].tolist() == [3, 4, 6, 7]
    (step,) = report.cleaning
    assert step.action == "average_duplicates" and step.count == 1 and step.lines == (5,)
    msg = _error(_log(rows), ForceLogConfig(duplicate_policy="error"))
    assert msg == "log.csv:5: duplicate time_s 0.01 s (also on line 4)"


def test_gaps_are_reported():
    rows = _ramp(30)
    t = [float(r[0]) for r in rows]
    rows = [(f"{v + (1.0 if i >= 20 else 0.0):.4f}", f) for i, (v, (_, f)) in enumerate(zip(t, rows))]
    _, report = parse_force_log(_log(rows), name="log.csv")
    assert len(report.gaps) == 1 and report.gaps[0][2] == 23
    assert report.gaps[0][1] - report.gaps[0][0] == pytest.approx(1.01)
    assert any("gap" in w for w in report.warnings)


def _clipped(rng, clip=8.0, n=400):
    t = np.arange(n) * 0.01
    f = np.round(10 * np.sin(np.pi * t / t[-1]) + rng.normal(0, 0.2, n), 3)
    return t, np.minimum(f, clip)


def test_saturation_is_flagged_dropped_or_refused():
    rng = np.random.default_rng(0)
    t, f = _clipped(rng)
    rows = [(f"{a:.2f}", f"{b:.3f}") for a, b in zip(t, f)]
    data, report = parse_force_log(_log(rows), name="log.csv")
    clipped = f >= 8.0
    assert data["saturated"].to_numpy().tolist() == clipped.tolist()
    assert report.n_saturated == clipped.sum() > 50
    assert report.cleaning[-1].action == "flag_saturation" and any("clipped" in w for w in report.warnings)
    dropped, rep2 = parse_force_log(_log(rows), name="log.csv", cfg=ForceLogConfig(saturation_policy="drop"))
    assert len(dropped) == len(rows) - clipped.sum() and rep2.cleaning[-1].action == "drop_saturation"
    msg = _error(_log(rows), ForceLogConfig(saturation_policy="error"))
    assert "look clipped" in msg and msg.startswith(f"log.csv:{3 + int(np.argmax(clipped))}:")


def test_saturation_heuristic_spares_a_quiet_resting_maximum():
    # a quantised, nearly noiseless force that rests at its peak after the robot stops
    t = np.arange(300) * 0.01
    f = np.round(np.minimum(t, 2.0) * 5, 1)
    assert not find_saturation(f, min_run=5).any()
    # ... unless the sensor's range is known and reached
    assert find_saturation(f, min_run=5, sensor_range_g=10.0).sum() == np.sum(f >= 10.0)


@pytest.mark.parametrize(
    "header, scale, fragment",
    [
        ("time_s,force_g", 0.01, "if the values are newtons"),  # peak 0.025: newtons labelled force_g
        ("time_s,force_N", 5.0, "if the values are grams-force"),  # peak 12.5 "N" = 1275 g: grams labelled N
    ],
)
def test_unit_heuristics_warn(header, scale, fragment):
    _, report = parse_force_log(_log(_ramp(30, scale=scale), header=header), name="log.csv")
    assert any(fragment in w for w in report.warnings), report.warnings
    _, plausible = parse_force_log(_log(_ramp(30, scale=2.0)), name="log.csv")
    assert plausible.warnings == ()


def test_config_is_validated():
    with pytest.raises(ValueError):
        ForceLogConfig(nan_policy="ignore")
    with pytest.raises(ValueError):
        ForceLogConfig(gap_factor=1.0)


# --------------------------------------------------------------------------- chunked reading


def test_read_csv_columns_in_small_chunks_keeps_lines_and_exact_stamps(tmp_path):
    from tympani.pipeline.force.forcelog import read_csv_columns

    e = 1_566_497_791_436_127_452
    lines = ["# a ROS log", "%time,field.Fx,field.Fz"]
    for i in range(250):
        if i % 60 == 7:
            lines += ["", "# a comment between rows"]
        lines.append(f'{e + 20_000_000 * i + i % 3},"{i}",{-0.001 * i:.6f}')
    path = tmp_path / "ros.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    table = read_csv_columns(path, {"%time": "stamp", "field.Fz": "number"}, chunk_rows=16)
    t = table.values["%time"]
    assert t.dtype == np.int64 and t.size == 250 and table.n_rows == 250
    np.testing.assert_array_equal(t - e, 20_000_000 * np.arange(250) + np.arange(250) % 3)
    np.testing.assert_allclose(table.values["field.Fz"], -0.001 * np.arange(250))
    expected = [n for n, line in enumerate(lines, start=1) if line and not line.startswith(("#", "%"))]
    np.testing.assert_array_equal(table.lines, expected)
    assert table.comments == ("a ROS log",) + ("a comment between rows",) * 5
    assert table.header.columns == ("%time", "field.Fx", "field.Fz") and table.header.line == 2


def test_read_csv_columns_names_the_line_of_a_bad_cell_in_a_later_chunk(tmp_path):
    from tympani.pipeline.force.forcelog import read_csv_columns

    rows = [f"{i},{0.5 * i}" for i in range(100)]
    for i, bad, message in ((70, "70,abc", "t.csv:72: f 'abc' is not a number"), (55, "55,-inf", "t.csv:57: f '-inf' is not finite"),
                            (90, "90,1,2", "t.csv:92: 3 fields, but the header (line 1) has 2")):
        text = "\n".join(["t,f", *rows[:i], bad, *rows[i + 1:]]) + "\n"
        (tmp_path / "t.csv").write_text(text, encoding="utf-8")
        with pytest.raises(InputError) as info:
            read_csv_columns(tmp_path / "t.csv", {"t": "stamp", "f": "number"}, chunk_rows=8, name="t.csv")
        assert str(info.value) == message


def test_read_csv_columns_stamps_with_decimals_or_gaps_become_floats(tmp_path):
    from tympani.pipeline.force.forcelog import read_csv_columns

    text = "t,f\n" + "".join(f"{i},{i}\n" for i in range(20)) + "20.5,1\n21,\n,3\n"
    (tmp_path / "t.csv").write_text(text, encoding="utf-8")
    table = read_csv_columns(tmp_path / "t.csv", {"t": "stamp", "f": "number"}, chunk_rows=8)
    t = table.values["t"]
    assert t.dtype == np.float64 and t[20] == 20.5 and np.isnan(t[22]) and np.isnan(table.values["f"][21])
    text = 'a,"b,c"\n1,"2,5"\n3,"4,5"\n'  # a quoted comma is one field
    (tmp_path / "q.csv").write_text(text, encoding="utf-8")
    assert read_csv_columns(tmp_path / "q.csv", {"a": "stamp"}).values["a"].tolist() == [1, 3]
    with pytest.raises(InputError, match=r"q\.csv:1: missing column\(s\) z; found a, b,c"):
        read_csv_columns(tmp_path / "q.csv", {"z": "number"})


def test_read_csv_columns_text_columns_keep_every_cell_as_text(tmp_path):
    from tympani.pipeline.force.forcelog import read_csv_columns

    text = "name,x,note\n" + "".join(f" t{i} ,{i},NA\n" for i in range(10)) + "nan,1.5,a # b\n,2,\n"
    (tmp_path / "t.csv").write_text(text, encoding="utf-8")
    table = read_csv_columns(tmp_path / "t.csv", {"name": "text", "x": "number", "note": "text"}, chunk_rows=4)
    assert table.values["name"].tolist() == [f"t{i}" for i in range(10)] + ["nan", ""]
    assert table.values["note"].tolist() == ["NA"] * 10 + ["a # b", ""]
    assert table.values["x"].tolist() == [*range(10), 1.5, 2.0]
    empty = read_csv_columns(tmp_path / "t.csv", lambda h: {"name": "text"}, chunk_rows=4)
    assert empty.values["name"].dtype == object
    (tmp_path / "h.csv").write_text("name\n", encoding="utf-8")
    assert read_csv_columns(tmp_path / "h.csv", {"name": "text"}).values["name"].dtype == object


def test_a_big_log_is_read_in_bounded_memory(tmp_path):
    """300,000 rows (35 MB): the arrays the reader holds at its peak stay well below the file's
    size; reading the whole text and splitting it into rows held about ten times the file."""
    import tracemalloc

    from tympani.pipeline.force.labstreams import read_force_stream
    from tympani.pipeline.devtools.logbench import ROS_FORMAT, write_ros_force_csv
    from tympani.pipeline.force.logformat import parse_log_format

    path = write_ros_force_csv(tmp_path / "big.csv", 300_000, seed=1)
    size = path.stat().st_size
    fmt = parse_log_format(ROS_FORMAT).force
    tracemalloc.start()
    try:
        data, report, clock = read_force_stream(path, fmt)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(data) == report.n_rows == 300_000 and data["time_s"].iloc[0] == 0.0
    assert peak < 0.75 * size, (peak / 1e6, size / 1e6)
