"""Robot logs in: a WPILib ``.wpilog`` (SysId's entries) and a ROS 2 bag, written by those libraries' own
writers, read with the same unit rules and refusals as a CSV."""
from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from identify import fit
from motorid.cli import main
from motorsim import Motor
from motorsim.columns import ImportFormatError, import_recording
from motorsim.plant import simulate

A, B_VOLT, DT = 25.0, 60.0, 0.005      # the motor: a in 1/s, b in (rad/s^2)/V, a 200 Hz loop


def _sysid_voltage() -> tuple[np.ndarray, np.ndarray, list[tuple[float, str]]]:
    """A SysId routine's input: quasistatic ramps and dynamic steps both ways, 1 s each, 0.5 s apart."""
    t = np.arange(int(round(6.0 / DT))) * DT
    u = np.zeros_like(t)
    tests = [(0.0, "quasistatic-forward", lambda s: 1.5 * s), (1.5, "quasistatic-reverse", lambda s: -1.5 * s),
             (3.0, "dynamic-forward", lambda s: 4.0 + 0 * s), (4.5, "dynamic-reverse", lambda s: -4.0 + 0 * s)]
    marks = []
    for start, name, law in tests:
        on = (t >= start) & (t < start + 1.0)
        u[on] = law(t[on] - start)
        marks += [(start, name), (start + 1.0, "none")]
    return t, np.round(u, 6), marks


def _write_wpilog(path, *, units=True) -> None:
    wpiutil = pytest.importorskip("wpiutil", reason="robotpy-wpiutil (the wpilib extra) is not installed")
    from wpiutil.log import DoubleLogEntry, StringLogEntry
    t, u, marks = _sysid_voltage()
    traj = simulate(Motor(A, B_VOLT), u, t)
    log = wpiutil.DataLogWriter(str(path))
    us = lambda s: int(round(1e6 * (1.0 + s)))          # noqa: E731 -- the FPGA clock starts at 1 s here
    state = StringLogEntry(log, "sysid-test-state-drive", us(0.0))
    volts = DoubleLogEntry(log, "voltage-drive", "Volt" if units else "", us(0.0))
    position = DoubleLogEntry(log, "position-drive", "Rotation" if units else "", us(0.0))
    velocity = DoubleLogEntry(log, "velocity-drive", "Rotation per Second" if units else "", us(0.0))
    marks_left = list(marks)
    for k in range(len(t)):
        while marks_left and marks_left[0][0] <= t[k] + 1e-12:
            state.append(marks_left.pop(0)[1], us(t[k]))
        volts.append(float(u[k]), us(t[k]))
        position.append(float(traj.angle[k] / (2 * math.pi)), us(t[k]))
        velocity.append(float(traj.speed[k] / (2 * math.pi)), us(t[k]))
    log.flush()
    log.stop()


def test_a_sysid_wpilog_imports_with_the_units_its_entries_state(tmp_path):
    path = tmp_path / "sysid.wpilog"
    _write_wpilog(path)
    with pytest.warns(UserWarning, match="the unit its header states"):
        rec = import_recording(path, time="time_s", input="voltage-drive", speed="velocity-drive")
    assert rec.input_unit == "V" and rec.speed_unit == "rev/s" and rec.sample_period == DT
    # only the rows logged inside a test (the state entry not 'none'): 4 tests of 1 s at 200 Hz
    assert len(rec) == 4 * 200
    est = fit(rec, method="oe", input_delay=0)
    # noise-free data of the exact model: the fit recovers it to rounding of the logged doubles
    assert est.a == pytest.approx(A, rel=1e-6) and est.b == pytest.approx(B_VOLT, rel=1e-6)


def test_identify_reports_ks_kv_ka_in_the_logs_units_as_sysid_does(tmp_path, capsys):
    path = tmp_path / "sysid.wpilog"
    _write_wpilog(path)
    assert main(["identify", str(path), "--time", "time_s", "--input", "voltage-drive", "--speed",
                 "velocity-drive", "--method", "oe", "--input-delay", "0", "--json"]) == 0
    captured = capsys.readouterr()
    ff = json.loads(captured.out)["in_speed_unit"]["feedforward"]
    # kV = a/b V per rad/s = 2 pi a/b V per rotation/s; kA = 2 pi/b V per rotation/s^2 (SysId's units)
    assert ff["kV"] == pytest.approx(2 * math.pi * A / B_VOLT, rel=1e-6) and ff["kV_unit"] == "V/(rev/s)"
    assert ff["kA"] == pytest.approx(2 * math.pi / B_VOLT, rel=1e-6) and ff["kA_unit"] == "V/(rev/s^2)"
    lo, hi = ff["kV_ci95"]
    assert lo <= ff["kV"] <= hi
    assert "SysId      kS" in captured.err and "V/(rev/s)" in captured.err


def test_a_wpilog_entry_without_a_unit_is_refused_like_a_csv_column(tmp_path):
    path = tmp_path / "bare.wpilog"
    _write_wpilog(path, units=False)
    with pytest.raises(ImportFormatError, match=r"2 problems with the columns: \(1\) the input column "
                                                r"'voltage-drive' has no unit .*\(2\) the speed column"):
        import_recording(path, time="time_s", input="voltage-drive", speed="velocity-drive")
    with pytest.raises(ImportFormatError,
                       match=r"no column named 'velocity-left' for the speed \(columns: .*velocity-drive"):
        import_recording(path, time="time_s", input="voltage-drive:V", speed="velocity-left:rev/s")


def test_without_the_reader_the_error_says_what_to_install(tmp_path, monkeypatch):
    path = tmp_path / "sysid.wpilog"
    path.write_bytes(b"WPILOG\x00\x01")
    monkeypatch.setitem(sys.modules, "wpiutil.log", None)
    monkeypatch.setitem(sys.modules, "wpiutil", None)
    with pytest.raises(ImportFormatError, match=r"reading a WPILib data log needs robotpy-wpiutil \(pip install "
                                                r"'robotpy-wpiutil>="):
        import_recording(path, time="time_s", input="voltage-drive:V", speed="velocity-drive:rev/s")
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    bag = tmp_path / "run"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    with pytest.raises(ImportFormatError, match=r"reading a ROS 2 bag needs rosbags \(pip install 'rosbags>="):
        import_recording(bag, time="time_s", input="/cmd:V", speed="/joint_states/wheel/velocity")


def _write_bag(path) -> None:
    pytest.importorskip("rosbags", reason="rosbags (the ros extra) is not installed")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header = store.types["sensor_msgs/msg/JointState"], store.types["std_msgs/msg/Header"]
    Time, Float64 = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Float64"]
    t = np.arange(800) * DT
    u = np.where((t // 0.5) % 2 == 0, 6.0, -3.0)                 # a square wave in V
    traj = simulate(Motor(A, B_VOLT), u, t)
    ns = lambda s: int(round(1e9 * (100.0 + s)))                 # noqa: E731 -- ROS time starts at 100 s here
    with Writer(path, version=9) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        command = writer.add_connection("/motor_cmd", Float64.__msgtype__, typestore=store)
        for k in range(len(t)):
            # the command is published just before the joint state that sees it
            writer.write(command, ns(t[k]) - 1000, store.serialize_cdr(Float64(data=float(u[k])), Float64.__msgtype__))
            stamp = Time(sec=int(ns(t[k]) // 10**9), nanosec=int(ns(t[k]) % 10**9))
            msg = JointState(header=Header(stamp=stamp, frame_id=""), name=["wheel"],
                             position=np.array([traj.angle[k]]), velocity=np.array([traj.speed[k]]),
                             effort=np.array([0.0]))
            writer.write(joints, ns(t[k]), store.serialize_cdr(msg, JointState.__msgtype__))


def test_a_ros2_bag_imports_a_joint_state_and_a_command_topic_by_name(tmp_path):
    bag = tmp_path / "run"
    _write_bag(bag)
    speed = "/joint_states/wheel/velocity"
    with pytest.raises(ImportFormatError, match="the input column '/motor_cmd' has no unit"):
        import_recording(bag, time="time_s", input="/motor_cmd", speed=speed)
    with pytest.warns(UserWarning, match="the unit its header states"):          # REP 103: rad/s
        rec = import_recording(bag, time="time_s", input="/motor_cmd:V", speed=speed)
    assert rec.input_unit == "V" and rec.speed_unit == "rad/s" and len(rec) == 800 and rec.sample_period == DT
    est = fit(rec, method="oe", input_delay=0)
    assert est.a == pytest.approx(A, rel=1e-6) and est.b == pytest.approx(B_VOLT, rel=1e-6)
