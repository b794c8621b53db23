"""Frozen benchmark suites: named, versioned sets of landing scenarios whose content is hashed, with a public
**dev** split and a held-out **test** split (other footage or other ground), a fixed metric set, and a citable
result card.

    viva-sitl trials suite list
    viva-sitl trials suite run synthetic-emergency --pilot mypkg.mod:MyPilot -o out/suite   # both splits
    viva-sitl trials suite card out/suite                  # out/suite/card.md + card.json

A suite is a TOML file under viva_sitl/data/suites/: `[suite]` (name, version, title, description), one table per
split (`[dev]`, `[test]`, each a whole trial spec: `[dev.trials]`, `[dev.scenario]`, `[dev.scoring]`), and
`[frozen.<split>]`: the content hashes the suite was published with. A split's hash covers

- the scenario list it draws (every scenario's start pose, footage time, wind, parameters, failures, seeds),
- each footage it uses: its metadata (paths left out) and the sha256 of every file it names (video or image,
  tracks, risk polygons or raster); for the built-in synthetic field, its ground truth sampled on a grid
  (risk levels and distances to its actors at fixed times), since code, not a file, draws it,
- the scoring: the criterion and what the trial ends and scores depend on (timeout, crash speed, leaving the
  footage, final descent height, log rate).

`suite run` refuses a suite whose content no longer hashes to its frozen values (one line naming the part that
changed): its results would not be results on the published suite. A run flies the pilot and, for the safety gain,
the `descend` baseline (PX4's plain Land where it is: the default mitigation) on the same scenarios.

Metrics (fixed; `card`), per split: success rate over the judged trials (Wilson 95 % CI); safety gain over
`descend`; minimum distance to people and to vehicles over the final descent (mean, bootstrap 95 % CI); risk
level at touchdown (ordinal: trials per level, median, share at or below the criterion's level); time to land
(mean, bootstrap 95 % CI); the trials the harness failed (left out of every rate). Safety gain follows the
evaluation of Guerin et al. (ICRA 2022, "Evaluation of Runtime Monitoring for UAV Emergency Landing"), which judge an
emergency-landing system by how much it reduces the unsafe outcomes of the default mitigation on the same
situations: here SG = 1 - U_pilot / U_descend, U = the share of judged trials that fail the suite's criterion, paired
on the same scenarios (bootstrap 95 % CI over the scenarios); 1 = every unsafe outcome of descend avoided, 0 = no
better, negative = worse; null when descend had no unsafe outcome.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from viva_sitl.config import ConfigError
from viva_sitl.evaluation.ends import INFRA_ENDS
from viva_sitl.evaluation.spec import TrialSpec, draw_scenarios, spec_from_dict

SUITE_DIR = Path(__file__).resolve().parents[1] / "data" / "suites"
SPLITS = ("dev", "test")
BASELINE = "descend"
RUN_SCHEMA = "vivasitl.suite-run.v1"
CARD_SCHEMA = "vivasitl.suite-card.v1"
# what the trial ends and the scores depend on, besides the criterion (TrialSpec fields)
_SCORING_FIELDS = ("timeout_s", "crash_speed_m_s", "end_outside_s", "final_descent_below_m", "log_hz")


@dataclass(frozen=True)
class Suite:
    name: str
    version: int
    title: str
    description: str
    splits: dict[str, TrialSpec]
    frozen: dict[str, dict[str, Any]]
    path: Path

    @property
    def id(self) -> str:
        return f"{self.name}@v{self.version}"


def _sha(data: Any) -> str:
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _file_sha(path: str) -> str | None:
    if not path:
        return None
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_suite(name_or_path: str) -> Suite:
    """A shipped suite by name (viva_sitl/data/suites/NAME.toml) or a suite file; ConfigError (one line) if not."""
    p = Path(name_or_path)
    if not (p.suffix == ".toml" and p.is_file()):
        p = SUITE_DIR / f"{name_or_path}.toml"
        if not p.is_file():
            raise ConfigError(f"no suite {name_or_path!r} (shipped: {', '.join(suite_names()) or 'none'})")
    try:
        data = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    where = p.name
    unknown = set(data) - {"suite", "frozen", *SPLITS}
    if unknown:
        raise ConfigError(f"{where}: unknown table {sorted(unknown)[0]!r} (suite, dev, test, frozen)")
    meta = data.get("suite", {})
    for key in ("name", "version", "title"):
        if key not in meta:
            raise ConfigError(f"{where}.suite.{key}: missing")
    if not isinstance(meta["version"], int) or isinstance(meta["version"], bool):
        raise ConfigError(f"{where}.suite.version: expected an integer")
    splits = {}
    for split in SPLITS:
        if split not in data:
            raise ConfigError(f"{where}: no [{split}] split")
        splits[split] = spec_from_dict(data[split], f"{where}.{split}")
    return Suite(name=str(meta["name"]), version=int(meta["version"]), title=str(meta["title"]),
                 description=str(meta.get("description", "")), splits=splits,
                 frozen=dict(data.get("frozen", {})), path=p)  # fmt: skip


def suite_names() -> list[str]:
    return sorted(p.stem for p in SUITE_DIR.glob("*.toml"))


# --------------------------------------------------------------------------------------------- hashing


def _synthetic_fingerprint() -> list[Any]:
    """The built-in field's ground truth on a grid: risk levels and distances to its actors at fixed times."""
    from viva_sitl.footage import open_footage
    from viva_sitl.world import ALL, world_from_source

    grid = np.arange(-100.0, 100.1, 20.0)
    out: list[Any] = []
    with open_footage("synthetic") as src:
        world = world_from_source(src)
        for t in (0.0, 7.5, 19.0, 41.0):
            out.append([int(world.risk_at(float(n), float(e), t)) for n in grid for e in grid])
            out.append(
                [
                    round(float(world.tracks.distance_m(float(n), float(e), t, ALL)), 3)
                    for n in grid
                    for e in grid
                ]
            )
    return out


def footage_hash(name: str) -> str:
    """sha256 of a footage's content: its metadata (absolute paths left out: they differ per machine) with each
    file it names replaced by that file's sha256; the synthetic field: its ground truth on a grid."""
    from viva_sitl.footage.loader import resolve_metadata
    from viva_sitl.footage.metadata import FootageKind

    meta = resolve_metadata(name)
    d = dataclasses.asdict(meta)
    d.pop("config_file", None)
    d.pop("levels", None)  # an ingest cache's reduced copies: derived, machine-local
    for key in ("path", "srt", "annotations_path"):
        d[key] = _file_sha(str(d.get(key) or ""))
    if meta.tracks is not None:
        d["tracks"]["path"] = _file_sha(meta.tracks.path)
    if meta.risk is not None:
        d["risk"]["polygons"] = _file_sha(meta.risk.polygons)
        d["risk"]["raster"] = _file_sha(meta.risk.raster)
    if meta.kind is FootageKind.SYNTHETIC:
        d["ground_truth"] = _synthetic_fingerprint()
    return _sha(d)


def split_hashes(spec: TrialSpec) -> dict[str, Any]:
    """{sha256, scenarios, scoring, footage: {name: sha256}} of one split (see the module docstring)."""
    scen = _sha([s.to_dict() for s in draw_scenarios(spec)])
    scoring = _sha(
        {"criterion": dataclasses.asdict(spec.criterion)} | {k: getattr(spec, k) for k in _SCORING_FIELDS}
    )
    foot = {name: footage_hash(name) for name in sorted(spec.footage)}
    return {"sha256": _sha({"scenarios": scen, "scoring": scoring, "footage": foot}), "scenarios": scen,
            "scoring": scoring, "footage": foot}  # fmt: skip


def suite_hash(split_sha: dict[str, str]) -> str:
    return _sha(dict(sorted(split_sha.items())))


def check_frozen(suite: Suite, split: str, got: dict[str, Any]) -> None:
    """ValueError (one line, naming what changed) when a split no longer hashes to its frozen values."""
    want = suite.frozen.get(split)
    if not isinstance(want, dict) or "sha256" not in want:
        raise ValueError(
            f"suite {suite.id}: split {split!r} has no frozen hash ([frozen.{split}] in {suite.path})"
        )
    if got["sha256"] == want["sha256"]:
        return
    changed = [k for k in ("scenarios", "scoring") if got[k] != want.get(k)]
    wf = want.get("footage") or {}
    changed += [
        f"footage {n}" for n in sorted(set(got["footage"]) | set(wf)) if got["footage"].get(n) != wf.get(n)
    ]
    raise ValueError(
        f"suite {suite.id}, split {split}: content hash {got['sha256'][:12]} is not the frozen "
        f"{str(want['sha256'])[:12]} ({', '.join(changed) or 'hash'} changed): not the published suite; "
        "publish a new version to change it"
    )


# --------------------------------------------------------------------------------------------- run


def run_suite(
    suite: Suite,
    pilot: str,
    out: Path,
    *,
    splits: tuple[str, ...] = SPLITS,
    jobs: int | None = None,
    limit: int | None = None,
    resume: bool = False,
    force: bool = False,
    progress: bool = True,
    say: Any = print,
) -> dict[str, Any]:
    """Fly `pilot` and the descend baseline over the chosen splits into OUT/<split> and OUT/baseline/<split>;
    write OUT/suite.json (what ran: suite id, hashes, pilot, splits). `limit` flies only the first K scenarios
    of each split (a smoke run: its card says it is not a suite result)."""
    from viva_sitl.evaluation.campaign import run_campaign

    hashes = {s: split_hashes(suite.splits[s]) for s in SPLITS}
    for s in splits:
        check_frozen(suite, s, hashes[s])
    out.mkdir(parents=True, exist_ok=True)
    rec: dict[str, Any] = {
        "schema": RUN_SCHEMA, "suite": suite.id, "name": suite.name, "version": suite.version,
        "suite_sha256": suite_hash({s: h["sha256"] for s, h in hashes.items()}),
        "split_sha256": {s: hashes[s]["sha256"] for s in splits}, "pilot": pilot, "baseline": BASELINE,
        "limit": limit, "splits": {}, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }  # fmt: skip
    for s in splits:
        spec = suite.splits[s]
        only = list(range(min(limit, spec.n))) if limit is not None else None
        d = {"dir": s, "baseline_dir": None if pilot == BASELINE else f"baseline/{s}"}
        for who, sub in ((pilot, d["dir"]), (BASELINE, d["baseline_dir"])):
            if sub is None:
                continue
            say(f"{suite.id} {s}: {who} -> {out / sub}")
            run_campaign(spec, who, out / sub, jobs=jobs, resume=resume, force=force, only=only,
                         progress=progress)  # fmt: skip
        rec["splits"][s] = d
        tmp = out / "suite.json.tmp"
        tmp.write_text(json.dumps(rec, indent=1))
        tmp.replace(out / "suite.json")
    return rec


# --------------------------------------------------------------------------------------------- card


def _ci(lo_hi: tuple[float, float]) -> list[float | None]:
    return [None if not math.isfinite(v) else round(v, 4) for v in lo_hi]


def safety_gain(pilot_rows: list[dict[str, Any]], base_rows: list[dict[str, Any]]) -> dict[str, Any]:
    """SG = 1 - U_pilot / U_descend over the scenarios both judged (U: share failing the criterion), with a
    bootstrap 95 % CI over those scenarios (resamples where descend had no unsafe outcome are left out)."""
    from viva_sitl.evaluation.stats import BOOTSTRAP_SEED, RESAMPLES

    a = {(r["trial"], r["seed"]): r for r in base_rows}
    b = {(r["trial"], r["seed"]): r for r in pilot_rows}
    keys = sorted(
        k for k in set(a) & set(b) if a[k].get("success") is not None and b[k].get("success") is not None
    )
    out: dict[str, Any] = {"pairs": len(keys), "value": None, "ci95": None, "unsafe_pilot": None,
                           "unsafe_descend": None}  # fmt: skip
    if not keys:
        return out
    up = np.array([0.0 if b[k]["success"] else 1.0 for k in keys])
    ub = np.array([0.0 if a[k]["success"] else 1.0 for k in keys])
    out["unsafe_pilot"], out["unsafe_descend"] = round(float(up.mean()), 4), round(float(ub.mean()), 4)
    if ub.sum() == 0:
        return out
    out["value"] = round(1.0 - float(up.mean()) / float(ub.mean()), 4)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = rng.integers(0, len(keys), size=(RESAMPLES, len(keys)))
    mb = ub[idx].mean(axis=1)
    ok = mb > 0
    if ok.any():
        sg = 1.0 - up[idx].mean(axis=1)[ok] / mb[ok]
        out["ci95"] = _ci((float(np.quantile(sg, 0.025)), float(np.quantile(sg, 0.975))))
    return out


def _mean_ci(agg: dict[str, Any], key: str) -> dict[str, Any]:
    s = agg["scores"].get(key, {"n": 0})
    if not s.get("n"):
        return {"n": 0, "mean": None, "ci95": None, "median": None}
    return {"n": s["n"], "mean": s["mean"], "ci95": s["mean_ci95"], "median": s["median"]}


def card(out: Path) -> dict[str, Any]:
    """The result card of a suite run in OUT (suite.json + the split results): written as OUT/card.json and
    OUT/card.md; returned."""
    from viva_sitl.evaluation.report import infra_aggregate, read_results
    from viva_sitl.evaluation.results import spec_hash
    from viva_sitl.evaluation.stats import wilson_ci

    try:
        rec = json.loads((out / "suite.json").read_text())
    except FileNotFoundError:
        raise ValueError(
            f"{out}: no suite.json (run `viva-sitl trials suite run SUITE --pilot ... -o {out}`)"
        ) from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{out / 'suite.json'}: not valid JSON: {exc}") from None
    if rec.get("schema") != RUN_SCHEMA:
        raise ValueError(f"{out / 'suite.json'}: schema {rec.get('schema')!r}, expected {RUN_SCHEMA}")
    suite = load_suite(rec["name"])
    if suite.version != rec["version"]:
        raise ValueError(f"{out}: ran {rec['suite']}, this viva-sitl ships {suite.id}")
    result: dict[str, Any] = {
        "schema": CARD_SCHEMA, "suite": rec["suite"], "suite_sha256": rec["suite_sha256"],
        "split_sha256": rec["split_sha256"], "title": suite.title, "pilot": rec["pilot"], "baseline": BASELINE,
        "partial": rec.get("limit") is not None, "splits": {},
    }  # fmt: skip
    for split, d in rec["splits"].items():
        doc = read_results(out / d["dir"])
        spec = suite.splits[split]
        run = doc.get("run") or {}
        if run.get("spec_hash") not in (None, spec_hash(dataclasses.replace(spec, pilot=doc["pilot"]))):
            raise ValueError(f"{out / d['dir']}: its spec is not split {split!r} of {suite.id}")
        rows = doc["rows"]
        agg = infra_aggregate(rows, spec.criterion.describe(), spec.criterion)
        base_rows = rows if d["baseline_dir"] is None else read_results(out / d["baseline_dir"])["rows"]
        flown = [r for r in rows if r.get("end") not in INFRA_ENDS]
        k, n = agg["success"], agg["success_judged"]
        risk = agg["scores"].get("risk_level", {"n": 0})
        max_lv = spec.criterion.max_risk_level
        at_or_below = (sum(c for lv, c in risk["counts"].items() if max_lv is None or int(lv) <= max_lv)
                       if risk.get("n") else None)  # fmt: skip
        result["splits"][split] = {
            "trials": spec.n, "trials_done": len(rows), "complete": doc.get("complete") and len(rows) == spec.n,
            "criterion": spec.criterion.describe(),
            "success": {"k": k, "judged": n, "rate": agg["success_rate"],
                        "ci95_wilson": _ci(wilson_ci(k, n)) if n else None},
            "safety_gain_vs_descend": safety_gain(flown, base_rows),
            "min_dist_person_m": _mean_ci(agg, "min_dist_person_m"),
            "min_dist_vehicle_m": _mean_ci(agg, "min_dist_vehicle_m"),
            "risk_level": {"n": risk.get("n", 0), "counts": risk.get("counts"), "median": risk.get("median"),
                           "at_or_below_max": at_or_below, "max": max_lv},
            "time_to_land_s": _mean_ci(agg, "time_to_land_s"),
            "infra_errors": agg["infra_errors"]["n"],
            "timing": run.get("timing", "realtime"), "pilot_cpu_factor": run.get("pilot_cpu_factor"),
            "pilot_latency_ms": run.get("pilot_latency_ms"), "speed": run.get("speed"),
            "pilot_kind": run.get("pilot_kind"), "versions": run.get("versions"),
        }  # fmt: skip
    first: dict[str, Any] = next(iter(result["splits"].values()), {})
    result["timing"] = {k: first.get(k) for k in ("timing", "pilot_cpu_factor", "pilot_latency_ms", "speed")}
    result["versions"] = first.get("versions")
    (out / "card.json").write_text(json.dumps(result, indent=1))
    (out / "card.md").write_text(card_markdown(result))
    return result


def _pm(m: dict[str, Any], unit: str) -> str:
    if not m.get("n"):
        return "n/a"
    lo, hi = m["ci95"]
    return f"{m['mean']:.2f} {unit} (95 % CI {lo:.2f}–{hi:.2f}; n {m['n']})"


def card_markdown(c: dict[str, Any]) -> str:
    t = c["timing"]
    vers = ", ".join(f"{k} {v}" for k, v in (c.get("versions") or {}).items())
    lines = [
        f"# {c['suite']}: `{c['pilot']}`",
        "",
        f"Suite **{c['suite']}** ({c['title']}), sha256 `{c['suite_sha256']}`; pilot `{c['pilot']}`; timing "
        f"{t['timing']}, pilot CPU factor {'none' if t['pilot_cpu_factor'] is None else t['pilot_cpu_factor']}"
        + (f", latency per frame {t['pilot_latency_ms']} ms" if t.get("pilot_latency_ms") else "")
        + f", speed {t['speed']}; versions: {vers}.",
    ]
    if c["partial"]:
        lines += ["", "**PARTIAL RUN (--limit): not a result on the suite; do not cite.**"]
    for split, s in c["splits"].items():
        sr, sg = s["success"], s["safety_gain_vs_descend"]
        rate = ("n/a" if sr["rate"] is None else
                f"{sr['k']}/{sr['judged']} = {100 * sr['rate']:.1f} % (95 % CI {100 * sr['ci95_wilson'][0]:.1f}–"
                f"{100 * sr['ci95_wilson'][1]:.1f} %, Wilson)")  # fmt: skip
        if sg["value"] is None:
            gain = f"n/a (descend had no unsafe outcome in {sg['pairs']} pairs)" if sg["pairs"] else "n/a"
        else:
            ci = sg["ci95"] or [None, None]
            gain = (f"{sg['value']:+.2f} (95 % CI {ci[0]:+.2f}–{ci[1]:+.2f}; unsafe {100 * sg['unsafe_pilot']:.0f} % "
                    f"vs descend {100 * sg['unsafe_descend']:.0f} %, {sg['pairs']} paired scenarios)"
                    if ci[0] is not None else f"{sg['value']:+.2f}")  # fmt: skip
        rk = s["risk_level"]
        risk = ("n/a" if not rk["n"] else
                f"median {rk['median']}; per level {', '.join(f'{lv}: {n}' for lv, n in rk['counts'].items())}; "
                f"{rk['at_or_below_max']}/{rk['n']} at or below {rk['max']}")  # fmt: skip
        lines += [
            "",
            f"## {split} split (sha256 `{c['split_sha256'][split][:16]}`): {s['trials_done']} of {s['trials']} trials"
            + ("" if s["complete"] else " (incomplete)"),
            "",
            "| metric | value |",
            "|---|---|",
            f"| success ({s['criterion']}) | {rate} |",
            f"| safety gain over descend | {gain} |",
            f"| min distance to people, final descent | {_pm(s['min_dist_person_m'], 'm')} |",
            f"| min distance to vehicles, final descent | {_pm(s['min_dist_vehicle_m'], 'm')} |",
            f"| risk level at touchdown | {risk} |",
            f"| time to land | {_pm(s['time_to_land_s'], 's')} |",
            f"| harness failures (left out) | {s['infra_errors']} |",
        ]
    lines += ["", f"Cite as: {c['pilot']} on viva-sitl suite {c['suite']} (sha256 {c['suite_sha256'][:16]}), "
              f"timing {t['timing']}.", ""]  # fmt: skip
    return "\n".join(lines)


__all__ = [
    "SPLITS",
    "Suite",
    "card",
    "footage_hash",
    "load_suite",
    "run_suite",
    "safety_gain",
    "split_hashes",
]
