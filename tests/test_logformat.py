"""Log format files: what they say, and one-line errors naming the file and the key."""

from __future__ import annotations

import math

import pytest

from tympani.pipeline.force.logformat import AnglesFormat, ForceFormat, parse_log_format, read_log_format
from tympani.vision.errors import InputError

FULL = """
[force]                 # the force log's own columns
time_column = "%time"
time_unit = "ns"
column = "field.Fz"
unit = "N"
sign = -1
gain = 1.0679
[depth]
time_column = "%time"
time_unit = "ns"
column = "field0"
unit = "mm"
[angles]
time_column = "time"
time_unit = "s"
zero = "motion_start"
theta_tip = "angle"
unit = "deg"
"""


def _error(text: str) -> str:
    with pytest.raises(InputError) as info:
        parse_log_format(text, name="lab.toml")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("lab.toml: ")
    return msg.removeprefix("lab.toml: ")


def test_the_full_example_is_read():
    fmt = parse_log_format(FULL, name="lab.toml")
    assert fmt.force == ForceFormat(section="force", time_column="%time", time_unit="ns", column="field.Fz", unit="N",
                                    sign=-1, gain=1.0679)
    assert fmt.force.to_g == pytest.approx(-1.0679 / 9.80665e-3)
    assert fmt.force.ns_per_unit == 1
    assert fmt.depth.to_mm == 1.0 and fmt.depth.column == "field0"
    assert fmt.angles.zero == "motion_start" and fmt.angles.to_rad == pytest.approx(math.pi / 180)
    assert fmt.angles.columns == {"theta_tip": "angle"}


def test_defaults_and_optional_sections():
    fmt = parse_log_format('[force]\ntime_column = "t"\ncolumn = "f"\nunit = "mN"\n')
    assert fmt.depth is None and fmt.angles is None
    assert (fmt.force.time_unit, fmt.force.sign, fmt.force.gain) == ("s", 1, 1.0)
    assert fmt.force.to_g == pytest.approx(1e-3 / 9.80665e-3)
    angles = parse_log_format('[angles]\ntime_column = "t"\nzero = 2.5\ntheta_tip = "a"\ntheta_con = "c"\nunit = "rad"\n').angles
    assert isinstance(angles, AnglesFormat) and angles.zero == 2.5 and angles.columns == {"theta_tip": "a", "theta_con": "c"}


def test_bag_sections_take_a_topic_and_default_to_the_record_time():
    fmt = parse_log_format('[force]\ntopic = "/ati/wrench"\ncolumn = "wrench.force.z"\nunit = "N"\n')
    assert fmt.force.topic == "/ati/wrench" and fmt.force.time_column is None and fmt.force.time_unit == "ns"
    assert "time_unit 's' without time_column" in _error('[force]\ntopic = "/w"\ntime_unit = "s"\ncolumn = "x"\nunit = "N"\n')


@pytest.mark.parametrize("text, expected", [
    ('[force]\ntime_column = "t"\ncolum = "f"\nunit = "N"\n', "[force] unknown key 'colum'"),
    ('[forse]\ntime_column = "t"\n', "unknown section or key 'forse'"),
    ('title = "lab"\n', "unknown section or key 'title'"),
    ('[force]\ntime_column = "t"\nunit = "N"\n', "[force] missing key 'column'"),
    ('[force]\ncolumn = "f"\nunit = "N"\n', "[force] missing key 'time_column'"),
    ('[force]\ntime_column = "t"\ncolumn = "f"\nunit = "lbf"\n', "[force] unit 'lbf' is not one of g, mN, N"),
    ('[force]\ntime_column = "t"\ntime_unit = "min"\ncolumn = "f"\nunit = "N"\n', "[force] time_unit 'min' is not one of s, ms, us, ns"),
    ('[depth]\ntime_column = "t"\ncolumn = "d"\nunit = "cm"\n', "[depth] unit 'cm' is not one of um, mm, m"),
    ('[angles]\ntime_column = "t"\nzero = "start"\ntheta_tip = "a"\nunit = "deg"\n', "[angles] zero 'start' is not one of"),
    ('[angles]\ntime_column = "t"\nzero = 0\ntheta_tip = "a"\nunit = "grad"\n', "[angles] unit 'grad' is not one of rad, deg"),
    ('[force]\ntime_column = "t"\ncolumn = "f"\nunit = "N"\nsign = 2\n', "[force] sign must be 1 or -1, not 2"),
    ('[force]\ntime_column = "t"\ncolumn = "f"\nunit = "N"\ngain = -1.0\n', "[force] gain must be > 0"),
    ('[force]\ntime_column = "t"\ncolumn = "f"\nunit = "N"\ngain = "1.07"\n', "[force] gain must be a finite number"),
    ('[force]\ntime_column = 3\ncolumn = "f"\nunit = "N"\n', "[force] time_column must be a non-empty string"),
    ('force = 1\n', "[force] must be a table of keys"),
    ('[force\n', "not a valid TOML log format file"),
    ('', "no section"),
])
def test_bad_format_files_name_the_key(text, expected):
    assert expected in _error(text)


def test_read_log_format_names_a_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such log format file"):
        read_log_format(tmp_path / "absent.toml")
    (tmp_path / "lab.toml").write_text(FULL, encoding="utf-8")
    assert read_log_format(tmp_path / "lab.toml").path == str(tmp_path / "lab.toml")
