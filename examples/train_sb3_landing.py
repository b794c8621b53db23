"""Train a landing policy with stable-baselines3 (SAC) on the synthetic field, state observations, velocity setpoints.

    pip install 'viva-sitl[gym,rl]'
    OMP_NUM_THREADS=1 nice -n 10 python examples/train_sb3_landing.py --minutes 35 -o /work/models/sb3_landing_sac
    python bench/bench_rl.py --model /work/models/sb3_landing_sac.zip      # vs random and `descend`, same scenarios

The environment is `viva_sitl/LandingStateVelocity-v0` over configs/trials/synthetic_emergency.toml: each episode is
one trial scenario of that spec (start 15..30 m up within 45 m of the plaza, people walking around, wind, gusts),
the policy commands NED velocity + yaw rate through the autopilot (OFFBOARD) at 2 Hz, and the episode ends as
the trial would (landed, crash, left the footage, timeout) with the trials' score row in the last info["trial"].
State-only observations: nothing is rendered (the VAC is never drawn), which is what makes it fast. Training draws
trials of seed --train-seed (1000 by default); the bench evaluates on the spec's own seed (0): held-out scenarios.

--action-mode velocity_land (the run recorded in bench/results_gym.md) flies the env's landing assist: the policy's
velocity setpoints are limited near the ground as PX4's Land limits its descent (MPC_LAND_SPEED below MPC_LAND_ALT2,
blended up to MPC_Z_VEL_MAX_DN at MPC_LAND_ALT1; horizontal speed likewise down to --land-xy), so what it must learn
is WHERE to land (away from people and risky ground; the synthetic field's risk map is fixed, so position -> risk is
learnable from the state), not how to flare:

    OMP_NUM_THREADS=1 nice -n 10 python examples/train_sb3_landing.py --minutes 14 --action-mode velocity_land \
        --land-xy 0 --gamma 0.98 -o /work/models/sb3_landing_sac_assist_xy0

--ground-truth-obs (the run recorded as the third attempt in bench/results_gym.md) adds the env's PRIVILEGED
ground-truth observation (LandingEnv(ground_truth_obs=True): the world model's risk levels on a 7 x 7 grid 4 m apart
under the vehicle, people's buffers included, and the nearest person's offset and distance): what the `oracle` pilot
knows, not what a camera gives; it measures what a ground-aware landing buys, a perception model must supply it for
real. Checkpoints every --checkpoint-min; bench_rl.py on another seed picks one:

    OMP_NUM_THREADS=1 nice -n 10 python examples/train_sb3_landing.py --minutes 42 --action-mode velocity_land \
        --land-xy 0 --gamma 0.98 --ground-truth-obs --net-arch 128 128 --checkpoint-min 5 -o /work/models/rl3/sac_gt

The observation is the env's state vector scaled to O(1) (ScaledState: positions / 50 m, velocities / 5 m/s, angles /
pi, altitude / 30 m): make_env() builds the exact env the bench evaluates.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

import viva_sitl.gym  # noqa: F401  (registers the ids)

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "configs" / "trials" / "synthetic_emergency.toml"
ENV_ID = "viva_sitl/LandingStateVelocity-v0"
ENV_KWARGS: dict[str, Any] = {"control_hz": 2.0, "max_speed_m_s": 5.0, "max_vspeed_m_s": 3.0}
# north, east, down, v_north, v_east, v_down, roll, pitch, yaw, altitude above ground (viva_sitl.gym.STATE_FIELDS)
STATE_SCALE = np.array([50, 50, 30, 5, 5, 5, math.pi, math.pi, math.pi, 30], np.float32)


# --ground-truth-obs (PRIVILEGED, the env's ground_truth_obs): risk levels 1..5 / 5, the nearest person's offset and
# distance / 10 m
RISK_SCALE, PERSON_SCALE_M = 5.0, 10.0


def observation_scale(env: gym.Env[Any, Any]) -> NDArray[np.float32]:
    """The fixed scales of the env's state vector (STATE_SCALE, then the privileged ground-truth fields if on)."""
    n_extra = int(env.observation_space.shape[0]) - len(STATE_SCALE)  # type: ignore[index]
    if n_extra == 0:
        return STATE_SCALE
    extra = np.full(n_extra, RISK_SCALE, np.float32)
    extra[-3:] = PERSON_SCALE_M
    return np.concatenate([STATE_SCALE, extra])


class ScaledState(gym.ObservationWrapper[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]):
    """The state vector divided by fixed scales (no running statistics: the saved policy needs nothing else)."""

    def __init__(self, env: gym.Env[NDArray[np.float32], NDArray[np.float32]]) -> None:
        super().__init__(env)
        self.scale = observation_scale(env)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=self.scale.shape, dtype=np.float32)

    def observation(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        return (observation / self.scale).astype(np.float32)


def make_env(
    spec: str | Path = SPEC,
    max_episode_s: float | None = 60.0,
    physics_hz: float | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> gym.Env[Any, Any]:
    """The env the policy flies. physics_hz: None = the trials' physics (250 Hz); training uses 100 Hz (2.6x
    fewer physics steps; a 20 s test landing touched down 0.13 m apart, 0.004 m/s slower; the bench evaluates at
    250 Hz)."""
    from viva_sitl.config import SimConfig
    from viva_sitl.dynamics import EavParams

    kw = dict(ENV_KWARGS if env_kwargs is None else env_kwargs)
    if physics_hz is not None:
        kw["config"] = SimConfig(physics=EavParams().with_rate(physics_hz))
    env = gym.make(ENV_ID, spec=str(spec), max_episode_s=max_episode_s, **kw)
    return ScaledState(env.unwrapped)  # the env truncates on time itself; no TimeLimit/order checker needed


def train(
    out: Path,
    *,
    total_steps: int = 10**7,
    minutes: float = 35.0,
    spec: str | Path = SPEC,
    train_seed: int = 1000,
    learning_starts: int = 500,
    log_every_s: float = 30.0,
    seed: int = 0,
    physics_hz: float | None = 100.0,
    env_kwargs: dict[str, Any] | None = None,
    gamma: float = 0.95,
    net_arch: tuple[int, ...] = (64, 64),
    checkpoint_every_s: float | None = None,
) -> dict[str, Any]:
    """Train SAC until total_steps or `minutes` of wall time; save out.zip (the policy) and out.json (how it was
    trained: steps, wall time, env steps/s, episodes, success rate over the last 100 episodes). checkpoint_every_s:
    also save out_<steps>.zip/.json every that many wall seconds (pick one with bench_rl.py --select)."""
    import torch
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.utils import set_random_seed

    torch.set_num_threads(1)
    # not SAC(seed=...): SB3 would then reset the env with seed 0, the bench's scenarios
    set_random_seed(seed)
    env_kwargs = dict(ENV_KWARGS if env_kwargs is None else env_kwargs)
    env = make_env(spec, physics_hz=physics_hz, env_kwargs=env_kwargs)
    env.reset(seed=train_seed)  # training flies trials train_seed/0, 1, 2, ... (SB3 resets without a seed)
    model = SAC(
        "MlpPolicy", env, learning_rate=3e-4, buffer_size=200_000, learning_starts=learning_starts,
        batch_size=128, gamma=gamma, train_freq=1, gradient_steps=1, policy_kwargs={"net_arch": list(net_arch)},
        device="cpu", verbose=0,
    )  # fmt: skip
    deadline = time.perf_counter() + minutes * 60.0
    stats: dict[str, Any] = {"episodes": 0, "outcomes": [], "returns": []}

    def meta(wall: float) -> dict[str, Any]:
        last = stats["outcomes"][-100:]
        return {
            "algo": "SAC", "gamma": gamma, "net_arch": list(net_arch), "env_id": ENV_ID, "env_kwargs": env_kwargs,
            "spec": str(spec), "train_seed": train_seed, "physics_hz": physics_hz, "steps": int(model.num_timesteps),
            "wall_s": round(wall, 1), "steps_per_s": round(model.num_timesteps / max(wall, 1e-9), 1),
            "episodes": stats["episodes"],
            "landed_last100": round(sum(e == "landed" for e, _ in last) / max(1, len(last)), 3),
            "success_last100": round(sum(s for _, s in last) / max(1, len(last)), 3),
        }  # fmt: skip

    def save(path: Path, wall: float) -> dict[str, Any]:
        path.parent.mkdir(parents=True, exist_ok=True)
        model.save(str(path))
        m = meta(wall)
        Path(str(path) + ".json").write_text(json.dumps(m, indent=1))
        return m

    class Progress(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.t0 = time.perf_counter()
            self.next_log = self.t0 + log_every_s
            self.next_ckpt = self.t0 + (math.inf if checkpoint_every_s is None else checkpoint_every_s)
            self.ret = 0.0

        def _on_step(self) -> bool:
            self.ret += float(self.locals["rewards"][0])
            for info in self.locals["infos"]:
                row = info.get("trial")
                if row is not None:
                    stats["episodes"] += 1
                    stats["outcomes"].append((row["end"], bool(row["success"])))
                    stats["returns"].append(self.ret)
                    self.ret = 0.0
            now = time.perf_counter()
            if now >= self.next_log:
                self.next_log = now + log_every_s
                last = stats["outcomes"][-100:]
                print(json.dumps({
                    "steps": self.num_timesteps, "wall_s": round(now - self.t0, 1),
                    "steps_per_s": round(self.num_timesteps / (now - self.t0), 1), "episodes": stats["episodes"],
                    "landed_last100": round(sum(e == "landed" for e, _ in last) / max(1, len(last)), 3),
                    "success_last100": round(sum(s for _, s in last) / max(1, len(last)), 3),
                    "return_last100": round(float(np.mean(stats["returns"][-100:] or [0.0])), 2),
                }), flush=True)  # fmt: skip
            if now >= self.next_ckpt:
                self.next_ckpt = now + (math.inf if checkpoint_every_s is None else checkpoint_every_s)
                save(out.with_name(f"{out.name}_{self.num_timesteps}"), now - self.t0)
            return now < deadline

    t0 = time.perf_counter()
    model.learn(total_timesteps=total_steps, callback=Progress())
    final = save(out, time.perf_counter() - t0)
    env.close()
    return final


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--out", type=Path, default=Path("/work/models/sb3_landing_sac"),
                    help="model path without .zip (default %(default)s)")  # fmt: skip
    ap.add_argument("--minutes", type=float, default=35.0, help="wall-time budget (default %(default)s)")
    ap.add_argument("--steps", type=int, default=10**7, help="env step budget (default %(default)s)")
    ap.add_argument("--spec", default=str(SPEC))
    ap.add_argument("--train-seed", type=int, default=1000)
    ap.add_argument("--max-speed", type=float, default=ENV_KWARGS["max_speed_m_s"], help="m/s at action 1")
    ap.add_argument("--max-vspeed", type=float, default=ENV_KWARGS["max_vspeed_m_s"], help="m/s at action 1")
    ap.add_argument("--gamma", type=float, default=0.95)
    ap.add_argument("--action-mode", choices=["velocity", "velocity_land"], default="velocity",
                    help="velocity_land: the env's landing assist (PX4 Land's descent/horizontal limits near the "
                    "ground), the policy learns where to land (default %(default)s)")  # fmt: skip
    ap.add_argument(
        "--land-xy",
        type=float,
        default=0.0,
        help="velocity_land: m/s below MPC_LAND_ALT2 (0: hold, as PX4 Land)",
    )
    ap.add_argument("--ground-truth-obs", action="store_true",
                    help="PRIVILEGED: append the env's ground-truth risk grid + nearest-person vector to the state "
                    "(LandingEnv ground_truth_obs; what the oracle pilot knows, not a sensor)")  # fmt: skip
    ap.add_argument(
        "--net-arch", type=int, nargs="+", default=[64, 64], help="hidden layers (default %(default)s)"
    )
    ap.add_argument("--checkpoint-min", type=float, help="also save out_<steps> every that many minutes")
    args = ap.parse_args(argv)
    kw = {**ENV_KWARGS, "max_speed_m_s": args.max_speed, "max_vspeed_m_s": args.max_vspeed}
    if args.action_mode != "velocity":
        kw.update(action_mode=args.action_mode, land_xy_m_s=args.land_xy)
    if args.ground_truth_obs:
        kw["ground_truth_obs"] = True
    ckpt = None if args.checkpoint_min is None else args.checkpoint_min * 60.0
    meta = train(
        args.out, total_steps=args.steps, minutes=args.minutes, spec=args.spec, train_seed=args.train_seed,
        env_kwargs=kw, gamma=args.gamma, net_arch=tuple(args.net_arch), checkpoint_every_s=ckpt,
    )  # fmt: skip
    print(json.dumps(meta))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
