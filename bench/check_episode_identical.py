"""Byte-identity check of trials and gym rollouts between two source trees (the episode refactor's safety net).

    python bench/check_episode_identical.py --base /path/to/old/tree [--new .] [--ignore reaction]

Each tree runs, in its own process (PYTHONPATH = that tree, cwd = that tree), in-process campaigns of `descend` and
`oracle` over configs/trials/synthetic_emergency.toml (8 trials) and interchange_emergency.toml (4; skipped
without ../shared footage), a spec with both failure kinds, and seeded gym rollouts (single env in attitude and
velocity_land mode, a 3-copy SharedFootageVectorEnv), then hashes every trial_trajectory.csv / events.jsonl /
end.json, every result row (wall_s dropped) and every observation / reward. The two trees must agree exactly.
`--ignore reaction`: drop the "reaction" events and end.json's reaction_t_s (added on purpose after 4b0e2a5).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

FAIL_SPEC = {
    "trials": {"name": "fail", "n": 2, "seed": 3, "timeout_s": 40.0},
    "scenario": {
        "footage": "synthetic", "start": "air", "north_m": [-40.0, 40.0], "east_m": [-40.0, 40.0],
        "altitude_m": [8.0, 12.0], "footage_time_s": [0.0, 60.0], "land_at_s": 35.0,
        "params": {"NAV_DLL_ACT": 3, "COM_DL_LOSS_T": 5},
        "failures": [{"kind": "battery_critical", "at_s": 1.0}, {"kind": "gcs_link_lost", "at_s": 2.0}],
    },
}  # fmt: skip


def _clean(path: Path, ignore: set[str]) -> bytes:
    data = path.read_bytes()
    if "reaction" in ignore and path.name == "events.jsonl":
        lines = [x for x in data.decode().splitlines() if json.loads(x)["kind"] != "reaction"]
        return ("\n".join(lines) + "\n").encode() if lines else b""
    if "reaction" in ignore and path.name == "end.json":
        d = json.loads(data)
        d.pop("reaction_t_s", None)
        return json.dumps(d, indent=1).encode()
    return data


def record(out: Path, ignore: set[str]) -> dict[str, Any]:
    import numpy as np

    from viva_sitl.evaluation.campaign import run_campaign
    from viva_sitl.evaluation.spec import load_spec, spec_from_dict

    rows: dict[str, Any] = {}
    specs = [("configs/trials/synthetic_emergency.toml", 8), ("configs/trials/interchange_emergency.toml", 4)]
    for path, n in specs:
        spec = load_spec(path)
        if "interchange" in path and not (Path("..") / "shared" / "footage" / "interchange").is_dir():
            continue
        for pilot in ("descend", "oracle"):
            camp = run_campaign(spec, pilot, out / f"{Path(path).stem}-{pilot}", jobs=1, n=n, progress=False)
            rows[f"{Path(path).stem}-{pilot}"] = [
                {k: v for k, v in r.items() if k != "wall_s"} for r in camp.ordered_rows()
            ]
    camp = run_campaign(
        spec_from_dict(FAIL_SPEC, "fail"), "descend", out / "fail-descend", jobs=1, progress=False
    )
    rows["fail-descend"] = [{k: v for k, v in r.items() if k != "wall_s"} for r in camp.ordered_rows()]
    files = {
        str(p.relative_to(out)): hashlib.sha256(_clean(p, ignore)).hexdigest()
        for p in sorted(out.rglob("*"))
        if p.is_file() and p.name in ("trial_trajectory.csv", "events.jsonl", "end.json")
    }
    import gymnasium as gym

    import viva_sitl.gym  # noqa: F401 - registers the ids
    from viva_sitl.gym.vector import SharedFootageVectorEnv

    rollouts = {}
    for mode in ("attitude", "velocity_land"):
        env = gym.make("viva_sitl/Landing-v0", footage="synthetic", image_size=(64, 48), action_mode=mode)
        obs, _ = env.reset(seed=5)
        rng, h = np.random.default_rng(1), hashlib.sha256()
        for _ in range(200):
            a = rng.uniform(-0.3, 0.3, 4).astype(np.float32)
            if mode != "attitude":
                a[2] = 0.6
            obs, r, term, trunc, info = env.step(a)
            h.update(obs["image"].tobytes() + obs["state"].tobytes() + np.float64(r).tobytes())
            if term or trunc:
                obs, _ = env.reset()
        rollouts[mode] = h.hexdigest()
        env.close()
    venv = SharedFootageVectorEnv(3, footage="synthetic", image_size=(64, 48), action_mode="velocity_land")
    obs, _ = venv.reset(seed=2)
    rng, h = np.random.default_rng(2), hashlib.sha256()
    for _ in range(150):
        a = rng.uniform(-0.3, 0.3, (3, 4))
        a[:, 2] = 0.7
        obs, r, term, trunc, info = venv.step(a)
        h.update(obs["image"].tobytes() + obs["state"].tobytes() + r.tobytes())
    rollouts["vector"] = h.hexdigest()
    return {"rows": rows, "files": files, "gym": rollouts}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", help="the other source tree")
    ap.add_argument("--new", default=".", help="this source tree (default .)")
    ap.add_argument("--ignore", action="append", default=[], choices=["reaction"])
    ap.add_argument("--record", help=argparse.SUPPRESS)  # child mode: write the summary JSON here
    args = ap.parse_args()
    if args.record:
        with tempfile.TemporaryDirectory() as d:
            Path(args.record).write_text(
                json.dumps(record(Path(d), set(args.ignore)), default=str, sort_keys=True)
            )
        return 0
    if not args.base:
        ap.error("--base TREE is required")
    out = {}
    with tempfile.TemporaryDirectory() as d:
        for name, tree in (("base", args.base), ("new", args.new)):
            tree = str(Path(tree).resolve())
            dest = Path(d) / f"{name}.json"
            cmd = [sys.executable, str(Path(__file__).resolve()), "--record", str(dest)]
            cmd += [x for i in args.ignore for x in ("--ignore", i)]
            subprocess.run(cmd, cwd=tree, env={**os.environ, "PYTHONPATH": tree}, check=True)
            out[name] = json.loads(dest.read_text())
    a, b = out["base"], out["new"]
    diff_files = sorted(
        k for k in set(a["files"]) | set(b["files"]) if a["files"].get(k) != b["files"].get(k)
    )
    diff_rows = sorted(k for k in set(a["rows"]) | set(b["rows"]) if a["rows"].get(k) != b["rows"].get(k))
    same_gym = a["gym"] == b["gym"]
    print(f"trial files: {len(a['files'])} vs {len(b['files'])}, differing: {diff_files or 'none'}")
    print(f"campaign rows differing: {diff_rows or 'none'}; gym rollouts identical: {same_gym}")
    return 0 if not diff_files and not diff_rows and same_gym else 1


if __name__ == "__main__":
    sys.exit(main())
