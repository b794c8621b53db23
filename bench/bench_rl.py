"""A trained stable-baselines3 landing policy vs a random policy vs `descend`, on the SAME trial scenarios, scored by
the landing trials' scorer (issue 11 §1).

    /work/venv/bin/python bench/bench_rl.py --model /work/models/sb3_landing_sac.zip --n 30 --markdown /tmp/rl.md
    /work/venv/bin/python bench/bench_rl.py --pilots descend random --n 30 --rows /tmp/rl_rows.json   # no model

Scenarios: trials 0..n-1 of `--seed` (default: the spec's own seed 0, which training never flies: it draws seed 1000)
of configs/trials/synthetic_emergency.toml. `descend` is flown by the trials runner (viva_sitl.evaluation.runner,
what `viva-sitl trials run SPEC --pilot descend` does); the SAC and random policies by the gym env
(examples/train_sb3_landing.make_env at the trials' 250 Hz physics and the spec's timeout), whose reset(seed)/reset()
draws the same scenarios (checked here, scenario by scenario) and whose last info["trial"] is the same score row.
Per pilot: landed %, success rate under the spec's criterion (landed, touchdown < 1 m/s, >= 5 m from people, risk
<= 2) with Wilson and bootstrap 95 % CIs, min distance to people over the final descent, risk level at touchdown,
touchdown speed; paired against the --vs baselines (default descend; McNemar exact p, success difference with
bootstrap CI). `--pilots oracle` flies the trials' ground-truth reference pilot. A --rows file of a larger --n serves a
smaller one (its first n rows, checked scenario by scenario); `--pilots` with no names only reports it.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))

import train_sb3_landing as example  # noqa: E402

from viva_sitl.evaluation.runner import run_inprocess_trial  # noqa: E402
from viva_sitl.evaluation.spec import Scenario, TrialSpec, draw_scenarios, load_spec  # noqa: E402
from viva_sitl.evaluation.stats import aggregate, mcnemar_exact, paired  # noqa: E402

Policy = Callable[[np.ndarray], np.ndarray]
Row = dict[str, Any]


def model_env_kwargs(model_path: str | Path) -> dict[str, Any] | None:
    """The env keyword arguments the policy was trained with (its .json beside the .zip), None: the example's."""
    meta = Path(str(model_path).removesuffix(".zip") + ".json")
    return json.loads(meta.read_text()).get("env_kwargs") if meta.is_file() else None


def sb3_policy(model_path: str | Path) -> Policy:
    from stable_baselines3 import SAC

    model = SAC.load(str(model_path), device="cpu")

    def act(obs: np.ndarray) -> np.ndarray:
        return np.asarray(model.predict(obs, deterministic=True)[0], np.float32)

    return act


def land_speed_cap(policy: Policy, below_m: float, max_m_s: float, max_vspeed_m_s: float) -> Policy:
    """A fixed rule on top of a policy: below `below_m` above ground the commanded descent is at most max_m_s (as PX4's
    land speed near the ground); the policy still chooses everything else. Scaled observation: altitude = obs[9] x 30 m
    (train_sb3_landing.STATE_SCALE)."""
    cap = max_m_s / max_vspeed_m_s

    def act(obs: np.ndarray) -> np.ndarray:
        a = policy(obs).copy()
        if float(obs[9]) * float(example.STATE_SCALE[9]) < below_m:
            a[2] = min(float(a[2]), cap)
        return a

    return act


def random_policy(seed: int) -> Policy:
    rng = np.random.default_rng(seed)
    return lambda obs: rng.uniform(-1.0, 1.0, 4).astype(np.float32)


def evaluate_gym(
    policy: Policy,
    spec_path: str | Path,
    n: int,
    seed: int,
    scenarios: list[Scenario] | None = None,
    max_episode_s: float | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> list[Row]:
    """Fly trials 0..n-1 of `seed` with `policy` in the example's env; the trials' score rows. With `scenarios`
    (draw_scenarios(spec, n, seed)) each episode's scenario is checked to be that trial's. max_episode_s: None =
    the spec's timeout_s (as the trials)."""
    env = example.make_env(spec_path, max_episode_s=max_episode_s, env_kwargs=env_kwargs)
    rows: list[Row] = []
    try:
        for k in range(n):
            obs, _ = env.reset(seed=seed) if k == 0 else env.reset()
            flown = env.unwrapped.scenario  # type: ignore[attr-defined]
            if scenarios is not None and flown != scenarios[k]:
                raise RuntimeError(f"gym scenario {k} differs from the trials': {flown} != {scenarios[k]}")
            while True:
                obs, _, term, trunc, info = env.step(policy(obs))
                if term or trunc:
                    rows.append(info["trial"])
                    break
    finally:
        env.close()
    return rows


def evaluate_trials(pilot: str, spec: TrialSpec, scenarios: list[Scenario]) -> list[Row]:
    """The trials runner's rows for a built-in pilot (descend, oracle) on these scenarios."""
    with tempfile.TemporaryDirectory() as tmp:
        return [run_inprocess_trial(spec, sc, pilot, Path(tmp) / f"{sc.index:04d}") for sc in scenarios]


def summary(rows: list[Row], criterion: str) -> dict[str, Any]:
    agg = aggregate(rows, criterion)
    s = agg["scores"]
    return {
        "n": agg["n"], "landed_rate": agg["landed_rate"], "success_rate": agg["success_rate"],
        "success_ci95_wilson": agg["success_rate_ci95_wilson"],
        "success_ci95_bootstrap": agg["success_rate_ci95_bootstrap"], "ends": agg["ends"],
        "min_dist_person_m_median": s["min_dist_person_m"].get("median"),
        "min_dist_person_m_mean": s["min_dist_person_m"].get("mean"),
        "risk_level_mean": s["risk_level"].get("mean"), "risk_level_ci95": s["risk_level"].get("mean_ci95"),
        "touchdown_speed_m_s_median": s["touchdown_speed_m_s"].get("median"),
    }  # fmt: skip


def markdown(results: dict[str, Any]) -> str:
    out = [
        f"scenarios: trials 0..{results['n'] - 1} of seed {results['seed']} of `{results['spec']}`; "
        f"criterion {results['criterion']}",
        "",
        "| pilot | landed | success (95 % CI Wilson / bootstrap) | min dist to people, final descent (median / mean, m) "
        "| risk at touchdown (mean, 95 % CI) | touchdown speed (median, m/s) | ends | wall s |",
        "|---|---:|---|---:|---:|---:|---|---:|",
    ]
    for name, s in results["pilots"].items():
        w, b = s["success_ci95_wilson"], s["success_ci95_bootstrap"]
        out.append(
            f"| {name} | {s['landed_rate']:.0%} | **{s['success_rate']:.0%}** ({w[0]:.0%}-{w[1]:.0%} / "
            f"{b[0]:.0%}-{b[1]:.0%}) | {s['min_dist_person_m_median']} / {s['min_dist_person_m_mean']} | "
            f"{s['risk_level_mean']} ({s['risk_level_ci95']}) | {s['touchdown_speed_m_s_median']} | "
            f"{', '.join(f'{k} {v}' for k, v in s['ends'].items())} | {s['wall_s']} |"
        )
    out.append("")
    for base, pairs in results.get("paired", {}).items():
        for name, p in pairs.items():
            su, risk = p["success"], p["scores"].get("risk_level", {})
            dist = p["scores"].get("min_dist_person_m", {})
            out.append(
                f"- {name} vs {base}, paired over {su['judged_pairs']} scenarios: success {su['rate_b']:.0%} vs "
                f"{su['rate_a']:.0%}, only {name} {su['only_b']}, only {base} {su['only_a']}, difference "
                f"{su['diff_b_minus_a']:+.2f} (95 % CI {su['diff_ci95']}), McNemar exact p = "
                f"{mcnemar_exact(su['only_a'], su['only_b']):.2g}"
                + (
                    f"; risk at touchdown {risk['mean_diff_b_minus_a']:+.2f} (95 % CI {risk['diff_ci95']}, "
                    f"{risk['pairs']} pairs)"
                    if risk.get("pairs")
                    else ""
                )
                + (
                    f"; min dist to people {dist['mean_diff_b_minus_a']:+.1f} m (95 % CI {dist['diff_ci95']})"
                    if dist.get("pairs")
                    else ""
                )
            )
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spec", default=str(example.SPEC))
    ap.add_argument(
        "--model", type=Path, help="a saved SB3 SAC policy (.zip); the random pilot flies its env too"
    )
    ap.add_argument("--pilots", nargs="*", default=["sac", "random", "descend"],
                    help="pilots to fly (none: report the --rows file); descend and oracle: the trials runner")  # fmt: skip
    ap.add_argument("--name", default="sac", help="the row name of the sac pilot (default %(default)s)")
    ap.add_argument(
        "--random-name", default="random", help="the row name of the random pilot (default %(default)s)"
    )
    ap.add_argument("--cap", type=float, nargs=2, metavar=("BELOW_M", "M_S"),
                    help="sac pilot: cap the commanded descent to M_S below BELOW_M above ground (a fixed rule)")  # fmt: skip
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, help="scenario seed (default: the spec's)")
    ap.add_argument("--rows", type=Path, help="write/merge every pilot's rows here (JSON)")
    ap.add_argument("--markdown", type=Path)
    ap.add_argument("--vs", nargs="+", default=["descend"],
                    help="pair every other pilot with these baselines (default %(default)s)")  # fmt: skip
    ap.add_argument("--only", nargs="+", help="report only these pilots of the --rows file (default: all)")
    args = ap.parse_args(argv)
    spec = load_spec(args.spec)
    seed = spec.seed if args.seed is None else args.seed
    scenarios = draw_scenarios(spec, args.n, seed)
    rows: dict[str, list[Row]] = {}
    if args.rows is not None and args.rows.exists():
        rows = json.loads(args.rows.read_text())["rows"]
    walls: dict[str, float] = {}
    for pilot in args.pilots:
        t0 = time.perf_counter()
        if pilot == "sac":
            if args.model is None:
                ap.error("--model is needed for the sac pilot")
            kw = model_env_kwargs(args.model)
            policy = sb3_policy(args.model)
            if args.cap is not None:
                vmax = (kw or example.ENV_KWARGS)["max_vspeed_m_s"]
                policy = land_speed_cap(policy, args.cap[0], args.cap[1], vmax)
            rows[args.name] = evaluate_gym(policy, args.spec, args.n, seed, scenarios, env_kwargs=kw)
            walls[args.name] = round(time.perf_counter() - t0, 1)
            print(f"{args.name}: {args.n} trials in {walls[args.name]} s", flush=True)
            continue
        elif pilot == "random":
            # in the trained policy's env (its action mode and scaling) when a model is given
            kw_r = model_env_kwargs(args.model) if args.model is not None else None
            rows[args.random_name] = evaluate_gym(
                random_policy(seed), args.spec, args.n, seed, scenarios, env_kwargs=kw_r
            )
            walls[args.random_name] = round(time.perf_counter() - t0, 1)
            print(f"{args.random_name}: {args.n} trials in {walls[args.random_name]} s", flush=True)
            continue
        else:
            rows[pilot] = evaluate_trials(pilot, spec, scenarios)
        walls[pilot] = round(time.perf_counter() - t0, 1)
        print(f"{pilot}: {args.n} trials in {walls[pilot]} s", flush=True)
    if args.rows is not None:
        old = json.loads(args.rows.read_text()).get("wall_s", {}) if args.rows.exists() else {}
        walls = {**old, **walls}
        args.rows.write_text(
            json.dumps({"seed": seed, "n": args.n, "rows": rows, "wall_s": walls}, default=str)
        )
    crit = spec.criterion.describe()
    results: dict[str, Any] = {"spec": args.spec, "seed": seed, "n": args.n, "criterion": crit, "pilots": {}}
    shown = {k: v for k, v in rows.items() if args.only is None or k in args.only}
    for name, r in list(shown.items()):
        # a --rows file of a larger --n holds these n scenarios first (a scenario is a pure function of seed, index)
        r = shown[name] = r[: args.n]
        if [(row["trial"], row["seed"]) for row in r] != [(sc.index, sc.seed) for sc in scenarios]:
            raise SystemExit(f"{name}: its rows in {args.rows} are not trials 0..{args.n - 1} of seed {seed}")
        results["pilots"][name] = {**summary(r, crit), "wall_s": walls.get(name)}
    results["paired"] = {
        base: {name: paired(shown[base], r) for name, r in shown.items() if name != base}
        for base in args.vs
        if base in shown
    }
    print(json.dumps(results, indent=1))
    md = markdown(results)
    print(md)
    if args.markdown is not None:
        args.markdown.write_text(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
