"""ROS bags read directly (``.bag`` and ``.mcap``): bags written here with rosbags itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lab_logs import LabTrial, depth_at, force_of_tip, tip_of_depth
from tympani.pipeline.cli import main

rosbags = pytest.importorskip("rosbags", reason="the optional rosbags package (pip install 'tympani[ros]')")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

EPOCH_NS = 1_700_000_000_250_000_000

FORMAT = """
[force]
topic = "/ati/wrench"
time_column = "header.stamp"
column = "wrench.force.z"
unit = "N"
sign = -1
[depth]
topic = "/stage/joint_states"
column = "position[0]"
unit = "m"
[angles]
topic = "/tracker/tip_deg"
zero = "log"
theta_tip = "data"
unit = "deg"
"""


def _messages(trial: LabTrial, rng: np.random.Generator):
    """(topic, record time ns, kind, values) of one trial, in time order."""
    span = trial.rest_before_s + trial.motion_s + trial.rest_after_s
    out = []
    for t in np.arange(0.0, span, 1 / 50):  # force, 50 Hz, stamped 3 ms before it is recorded
        f = force_of_tip(tip_of_depth(depth_at(t, trial))) + rng.normal(0, 0.02)
        out.append(("/ati/wrench", int(t * 1e9) + 3_000_000, "wrench", (int(t * 1e9), -f * 9.80665e-3)))
    for t in np.arange(-0.01, span, 1 / 250):  # stage, metres
        out.append(("/stage/joint_states", int(t * 1e9), "joint", float(depth_at(t, trial)) / 1000.0))
    for t in np.arange(trial.rest_before_s, trial.rest_before_s + trial.motion_s, 1 / 60):  # tracker, degrees
        out.append(("/tracker/tip_deg", int(t * 1e9), "float", float(np.degrees(tip_of_depth(depth_at(t, trial))))))
    out.sort(key=lambda m: m[1])
    return out


def _build(ts, kind: str, value, i: int):
    T = ts.types
    if kind == "wrench":
        stamp_ns, fz = value
        stamp = T["builtin_interfaces/msg/Time"](sec=(EPOCH_NS + stamp_ns) // 10**9, nanosec=(EPOCH_NS + stamp_ns) % 10**9)
        header_args = {"stamp": stamp, "frame_id": "nano17"}
        if "seq" in T["std_msgs/msg/Header"].__dataclass_fields__:
            header_args["seq"] = i
        vec = T["geometry_msgs/msg/Vector3"]
        return "geometry_msgs/msg/WrenchStamped", T["geometry_msgs/msg/WrenchStamped"](
            header=T["std_msgs/msg/Header"](**header_args),
            wrench=T["geometry_msgs/msg/Wrench"](force=vec(x=0.0, y=0.0, z=fz), torque=vec(x=0.0, y=0.0, z=0.0)))
    if kind == "joint":
        header_args = {"stamp": T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), "frame_id": ""}
        if "seq" in T["std_msgs/msg/Header"].__dataclass_fields__:
            header_args["seq"] = i
        return "sensor_msgs/msg/JointState", T["sensor_msgs/msg/JointState"](
            header=T["std_msgs/msg/Header"](**header_args), name=["x"], position=np.array([value]),
            velocity=np.zeros(1), effort=np.zeros(1))
    return "std_msgs/msg/Float64", T["std_msgs/msg/Float64"](data=value)


def write_bag(path: Path, trial: LabTrial, rng: np.random.Generator) -> Path:
    """A ROS 1 ``.bag`` (path ends in .bag) or a ROS 2 MCAP bag (a folder; returns its .mcap file)."""
    ros1 = path.suffix == ".bag"
    if ros1:
        from rosbags.rosbag1 import Writer

        ts = get_typestore(Stores.ROS1_NOETIC)
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        ts = get_typestore(Stores.ROS2_HUMBLE)
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    conns = {}
    with writer:
        for i, (topic, t_ns, kind, value) in enumerate(_messages(trial, rng)):
            msgtype, msg = _build(ts, kind, value, i)
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            data = ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)
            writer.write(conns[topic], EPOCH_NS + t_ns, data)
    if ros1:
        return path
    return next(path.glob("*.mcap"))


@pytest.mark.parametrize("suffix", [".bag", ""])
def test_a_bag_is_synced_like_csv_logs(tmp_path, capsys, suffix):
    """A ROS 1 bag and a ROS 2 (mcap) bag with force, depth and angle topics sync like CSV logs
    (measured against the truth: force at most 0.063 g off (the log's noise), depth 0.006 mm,
    theta_tip 0.0027 rad)."""
    trial = LabTrial(speed_mm_s=2.0, depth_mm=18.0, rest_before_s=1.2, rest_after_s=1.0)
    bag = write_bag(tmp_path / f"trial{suffix or '_ros2'}", trial, np.random.default_rng(4))
    (tmp_path / "bag.toml").write_text(FORMAT)
    name = bag.relative_to(tmp_path)
    (tmp_path / "m.csv").write_text(f"trial,speed_mm_s,force,depth,angles,format\nb,2,{name},{name},{name},bag.toml\n")
    code = main(["sync", "--manifest", str(tmp_path / "m.csv"), "--out", str(tmp_path / "s.csv"), "-q"])
    out, err = capsys.readouterr()
    assert code == 0, err
    s = pd.read_csv(tmp_path / "s.csv")
    # force: the header stamp's clock (3 ms before recording), N -> g with the sign
    assert s["time_s"].iloc[0] == 0.0 and s["time_s"].iloc[1] == pytest.approx(0.02, abs=1e-9)
    truth = force_of_tip(tip_of_depth(depth_at(s["time_s"], trial)))
    assert np.max(np.abs(s["force_g"] - truth)) < 0.13 and s["force_g"].max() == pytest.approx(truth.max(), rel=0.03)
    # depth: metres -> mm, on the bag's record time, 3 ms after the force stamps' clock
    d_truth = depth_at(s["time_s"] - 0.003, trial)
    have = s["depth_mm"].notna()
    assert have.mean() > 0.99 and np.max(np.abs(s.loc[have, "depth_mm"] - d_truth[have])) < 0.012
    # angles on the bag's clock (zero = "log")
    tip = s.dropna(subset=["theta_tip"])
    assert np.max(np.abs(tip["theta_tip"] - tip_of_depth(depth_at(tip["time_s"] - 0.003, trial)))) < 0.006
    assert tip["theta_tip"].max() > 2 * np.pi


def test_bag_errors_name_the_bag_and_the_key(tmp_path, capsys):
    trial = LabTrial(depth_mm=5.0, rest_before_s=1.0, rest_after_s=0.5)
    bag = write_bag(tmp_path / "t.bag", trial, np.random.default_rng(5))
    cases = {
        "topic": (FORMAT.replace('"/ati/wrench"', '"/ati/wrench_raw"'), "[force] topic '/ati/wrench_raw' is not in the bag"),
        "field": (FORMAT.replace('"wrench.force.z"', '"wrench.force.w"'),
                  "[force] column 'wrench.force.w': message 1 of /ati/wrench (geometry_msgs/msg/WrenchStamped) has no "
                  "field 'w' (fields: x, y, z)"),
        "index": (FORMAT.replace('"position[0]"', '"position[3]"'), "[depth] column 'position[3]'"),
        "no topic": (FORMAT.replace('topic = "/ati/wrench"\n', 'time_column = "t"\n').replace('time_column = "header.stamp"\n', ""),
                     "[force] topic: this is a ROS bag; the log format must name its topic"),
    }
    for key, (fmt, fragment) in cases.items():
        (tmp_path / "f.toml").write_text(fmt)
        (tmp_path / "m.csv").write_text("trial,speed_mm_s,force,depth,angles,format\nb,1.25,t.bag,t.bag,t.bag,f.toml\n")
        code = main(["sync", "--manifest", str(tmp_path / "m.csv"), "--out", str(tmp_path / "s.csv")])
        _, err = capsys.readouterr()
        lines = [x for x in err.splitlines() if x.strip()]
        assert code == 2 and len(lines) == 1 and str(bag) in lines[0] and fragment in lines[0], (key, lines)
