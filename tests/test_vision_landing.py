"""mission_scripts/vision_landing.py (issue 9 §5): the vision companion flown as an external pilot in landing trials.

A token risk U-Net is trained in the fixture on a small synthetic-field export (seconds: road vs lawn is a colour
question); the trials start the vehicle over the ring road (risk level 5), so landing straight down fails there and
the companion must see the road, fly off it and land on low-risk ground. Then its bad-input lines."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from sitl_process import MavlinkPeer, free_udp_ports

from viva_sitl.evaluation.report import read_results
from viva_sitl.world import load_world

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "mission_scripts" / "vision_landing.py"
pytestmark = pytest.mark.e2e


@pytest.fixture(scope="module")
def token_segmenter(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip(
        "torch",
        reason="the segmenter needs the perception extra: pip install torch==2.13.0 && pip install 'viva-sitl[perception]'",
    )
    d = tmp_path_factory.mktemp("seg")
    env_cmd = [sys.executable, "-m", "viva_sitl"]
    r = subprocess.run(
        [*env_cmd, "dataset", "export", "--footage", "synthetic", "--n", "24", "--seed", "3",
         "--poses", "alt=3:30,tilt=0:5,radius=60", "-o", str(d / "data")],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = subprocess.run(
        [*env_cmd, "perception", "train-segmenter", "--data", str(d / "data"), "--epochs", "20", "--size", "64x48",
         "--width", "8", "--batch", "4", "-o", str(d / "unet.pt")],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    return d / "unet.pt"


@pytest.fixture(scope="module")
def untrained_segmenter(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A loadable risk U-Net checkpoint with initial weights: enough for the bad-input lines, which stop before the
    first frame is segmented (the trained `token_segmenter` costs a dataset export and 20 epochs in subprocesses)."""
    pytest.importorskip(
        "torch",
        reason="the segmenter needs the perception extra: pip install torch==2.13.0 && pip install 'viva-sitl[perception]'",
    )
    from viva_sitl.perception.segment import UNet, save_segmenter

    path = tmp_path_factory.mktemp("seg0") / "unet0.pt"
    save_segmenter(UNet(width=4, depth=3), path)
    return path


def _leftovers(marker: str) -> list[str]:
    ps = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [line for line in ps.splitlines() if marker in line and "ps -eo" not in line]


SPEC = """
[trials]
name = "vision"
n = 2
seed = 4
timeout_s = 150.0
speed = 4.0          # the CLI's --speed 2 overrides it, and --frames turns the camera on (no trials.frames here)

[scenario]
footage = ["synthetic"]
start = "air"
north_m = [-3.0, 3.0]      # over the ring road (risk level 5)
east_m = [49.0, 51.0]
altitude_m = [18.0, 22.0]
land_at_s = 1.0

[scoring]
criterion = { name = "safe", landed = true, max_risk_level = 2 }
"""


@pytest.mark.slow  # a camera trial
def test_vision_pilot_flies_off_the_road_and_lands_in_trials(tmp_path: Path, token_segmenter: Path) -> None:
    spec = tmp_path / "vision.toml"
    spec.write_text(SPEC)
    world = load_world("synthetic")
    pilot = f"{{python}} {SCRIPT} {{mavsdk_url}} --frames {{frame_socket}} --segmenter {token_segmenter}"
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "trials", "run", str(spec), "--frames", "--speed", "2", "--jobs", "2",
         "--no-progress", "-o", str(out), "--pilot", pilot],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    doc = read_results(out)
    assert doc["spec"]["speed"] == 2.0 and doc["spec"]["frames"] is True, doc["spec"]
    rows = doc["rows"]
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert len(rows) == 2
    for r in rows:
        log = (tmp_path / "out" / "trials" / f"{r['trial']:04d}" / "pilot.log").read_text()
        assert world.risk_at(r["start_north_m"], r["start_east_m"], 0.0) == 5  # started over the busy road
        assert r["end"] == "landed" and r["landed"], (r, log[-3000:])
        assert "no --detector: ground risk from the segmenter only" in log
        result = re.search(r"RESULT .*spot_north_m=(\S+) spot_east_m=(\S+)", log)
        assert result is not None, log[-3000:]
        spot = float(result.group(1)), float(result.group(2))
        # it landed where it chose (AUTO.LAND from 3 m over the spot), off the road, and was scored
        assert abs(r["touchdown_north_m"] - spot[0]) < 1.5 and abs(r["touchdown_east_m"] - spot[1]) < 1.5, log
        assert r["risk_level"] is not None and r["risk_level"] <= 2, (r, log[-3000:])
        assert r["success"] is True and r["touchdown_speed_m_s"] < 1.5
        assert r["min_dist_person_m"] is not None
    assert _leftovers(str(tmp_path)) == []


def test_trials_speed_override_is_checked(tmp_path: Path) -> None:
    spec = tmp_path / "vision.toml"
    spec.write_text(SPEC)
    r = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "trials", "run", str(spec), "--speed", "0", "--pilot", "descend"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert (
        r.returncode == 2 and r.stderr.strip() == "viva-sitl trials: --speed must be a positive number, got 0"
    )


def _run(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def test_bad_inputs_are_one_line(tmp_path: Path, untrained_segmenter: Path) -> None:
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    cases = [
        ((), 2, "no model: give --segmenter PATH"),
        (("--segmenter", str(tmp_path / "nope.pt")), 2, "segmenter weights not found: "),
        (("--segmenter", str(tmp_path / "junk.pt")), 2, "is not a torch checkpoint"),
        (("--segmenter", str(untrained_segmenter), "--scenario", str(tmp_path / "none.json")), 2,
         "cannot read the scenario"),
        (("--segmenter", str(untrained_segmenter), "--margin-m", "-1"), 2, "must be finite and > 0"),
    ]  # fmt: skip
    for args, code, needle in cases:
        r = _run(*args)
        err = [x for x in r.stderr.splitlines() if x.strip()]
        assert r.returncode == code and len(err) == 1 and needle in err[0], (args, r.stderr)
    # no vehicle: the wait for a heartbeat ends with one FAILED line
    t0 = time.monotonic()
    r = _run("udpin://127.0.0.1:9", "--now", "--segmenter", str(untrained_segmenter), "--step-timeout", "3")
    assert r.returncode == 1 and "FAILED: no autopilot heartbeat on udpin://127.0.0.1:9" in r.stderr, r.stderr
    assert time.monotonic() - t0 < 40


def test_bad_detector_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "w.txt").write_bytes(b"x")
    for args, needle in (
        (("--detector", str(tmp_path / "nope.pt")), "detector weights not found: "),
        (("--detector", str(tmp_path / "w.txt")), "must be a .pt or .onnx file"),
    ):
        r = _run(*args)
        err = [x for x in r.stderr.splitlines() if x.strip()]
        assert r.returncode == 2 and len(err) == 1 and needle in err[0], (args, r.stderr)


@pytest.mark.slow  # a viva-sitl process
def test_lost_vehicle_is_a_clean_exit(tmp_path: Path, token_segmenter: Path, sitl_factory: Any) -> None:
    """Airborne, waiting for "land now" (far away): the vehicle process dies -> one FAILED line, exit 1."""
    from viva_sitl.evaluation.monitor import Limits
    from viva_sitl.evaluation.session import write_scenario_file
    from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

    spec = spec_from_dict(
        {"trials": {"name": "lost", "n": 1, "timeout_s": 600.0},
         "scenario": {"footage": "synthetic", "start": "air", "altitude_m": 20.0, "land_at_s": 500.0}},
        "lost",
    )  # fmt: skip
    scen = tmp_path / "scenario.json"
    write_scenario_file(scen, draw_scenarios(spec)[0], Limits(timeout_s=600.0))
    sitl = sitl_factory(video_port=free_udp_ports(1)[0], extra_args=("--scenario", str(scen)))
    p = subprocess.Popen(
        [sys.executable, str(SCRIPT), sitl.ports.mavsdk_url, "--frames", f"tcp://127.0.0.1:{sitl.frame_socket_port}",
         "--scenario", str(scen), "--segmenter", str(token_segmenter), "--link-timeout", "3"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert p.stdout is not None
    for line in p.stdout:  # connected and waiting for the trigger
        if "waiting for 'land now'" in line:
            break
    sitl.stop()
    _, err = p.communicate(timeout=60)
    assert p.returncode == 1 and "FAILED: lost the vehicle: no telemetry for" in err, err


@pytest.mark.slow  # a flight
def test_stalled_pilot_takes_offboard_back_after_the_failsafe(
    tmp_path: Path, token_segmenter: Path, sitl_factory: Any
) -> None:
    """A starved companion: the pilot process is frozen (SIGSTOP, MAVSDK's own re-send thread included) for longer
    than COM_OF_LOSS_T while in OFFBOARD. The vehicle fails safe to Hold and says why; the thawed pilot reads that
    STATUSTEXT, takes OFFBOARD back and still lands (what CI's loaded machine once hit at --speed 2)."""
    from viva_sitl.evaluation.monitor import Limits
    from viva_sitl.evaluation.session import write_scenario_file
    from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

    spec = spec_from_dict(
        {"trials": {"name": "stall", "n": 1, "timeout_s": 300.0},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": 20.0, "east_m": 20.0, "altitude_m": 12.0,
                      "land_at_s": 1.0}},
        "stall",
    )  # fmt: skip
    scen = tmp_path / "scenario.json"
    write_scenario_file(scen, draw_scenarios(spec)[0], Limits(timeout_s=300.0))
    sitl = sitl_factory(video_port=free_udp_ports(1)[0], extra_args=("--scenario", str(scen)))
    gcs = MavlinkPeer(sitl.ports.gcs)  # the ground station sees the failsafe's STATUSTEXT
    p = subprocess.Popen(
        [sys.executable, str(SCRIPT), sitl.ports.mavsdk_url, "--frames", f"tcp://127.0.0.1:{sitl.frame_socket_port}",
         "--scenario", str(scen), "--segmenter", str(token_segmenter)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert p.stdout is not None
        lines: list[str] = []
        for line in p.stdout:
            lines.append(line)
            if "offboard: holding" in line:
                break
        assert lines and "offboard: holding" in lines[-1], "".join(lines)
        p.send_signal(signal.SIGSTOP)
        said = gcs.wait("STATUSTEXT", lambda m: "offboard" in m.text, 30.0, what="the offboard-loss failsafe")
        gcs.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5.0, since_s=time.monotonic() + 0.5)
        p.send_signal(signal.SIGCONT)  # frozen ~1 s in all (the vehicle's failsafe after 1 s / speed 3)
        out, err = p.communicate(timeout=240)
    finally:
        gcs.close()
        if p.poll() is None:
            p.send_signal(signal.SIGCONT)
            p.kill()
            p.wait()
    text = "".join(lines) + out
    assert "Failsafe activated (no offboard)" in said.text, said.text  # its first 50-char chunk
    # why it took OFFBOARD back: the failsafe's text, or (when the frozen socket dropped that) its own stall
    assert re.search(
        r"left OFFBOARD \((.*no offboard.*|this process stalled .*)\); re-engaging OFFBOARD \(1/2\)", text
    ), text + err
    assert p.returncode == 0 and "landed and disarmed" in text, text + err


@pytest.mark.slow  # a pilot process
def test_ctrl_c_is_a_clean_exit(token_segmenter: Path) -> None:
    p = subprocess.Popen(
        [sys.executable, str(SCRIPT), "udpin://127.0.0.1:9", "--now", "--segmenter", str(token_segmenter)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert p.stdout is not None
    for line in p.stdout:  # wait until it is waiting for the vehicle
        if "connecting to" in line:
            break
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130 and "interrupted (Ctrl-C)" in err and "Traceback" not in err, err


@pytest.mark.slow  # trains a detector
def test_detections_become_keep_out_discs_on_the_ground(tmp_path: Path) -> None:
    """Detector only (no segmenter): every detected person/vehicle is a level-5 disc of its buffer on the ground,
    where the frame's pose puts it; the spot chosen keeps out of all of them."""
    ultralytics = pytest.importorskip("ultralytics", reason="needs the perception-yolo extra")
    import numpy as np

    from viva_sitl.perception.detect import Detector
    from viva_sitl.perception.landing_spot import PERSON_NAMES, VEHICLE_NAMES, Eyes, PlanConfig, choose_spot
    from viva_sitl.sim import Simulator

    net = ultralytics.YOLO("yolov8n.yaml", task="detect")  # random weights: boxes at a tiny threshold
    net.model.names = {
        0: "person",
        1: "bicycle",
        2: "car",
        3: "bus",
        4: "truck",
        5: "other",
        6: "moving object",
    }
    net.model.names.update({k: f"class{k}" for k in range(7, 80)})
    pt = tmp_path / "tiny.pt"
    net.save(str(pt))
    det = Detector(pt, conf=1e-7, imgsz=160)
    cfg = PlanConfig(person_buffer_m=4.0, vehicle_buffer_m=3.0)
    with Simulator(footage="synthetic") as sim:
        sim.reset(pos_ned_m=(10.0, -10.0, -25.0))
        frame = sim.render()
    meta = frame.meta.to_dict()
    view = Eyes(None, det, cfg).look(frame.image_bgr, meta)
    dets = det.detect(frame.image_bgr)
    kept = [d for d in dets if d.name in PERSON_NAMES | VEHICLE_NAMES]
    assert kept and view.people + view.vehicles == len(kept)
    ground = Detector.on_ground(kept, meta=meta)
    for n, e in ground:
        r, c = view.cell_of(n, e)
        if 0 <= r < view.levels.shape[0] and 0 <= c < view.levels.shape[1]:
            assert view.levels[r, c] == 5
    seen = view.levels > 0
    assert np.all(
        np.isin(view.levels[seen], (1, 5))
    )  # open ground or keep-out: nothing else without a segmenter
    spot = choose_spot(view, (10.0, -10.0), cfg)
    if spot is not None and spot.level == 1:
        assert np.min(np.hypot(ground[:, 0] - spot.north_m, ground[:, 1] - spot.east_m)) > cfg.person_buffer_m
