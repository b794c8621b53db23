"""Frozen benchmark suites (issue 20 §2): shipped suites hash to their frozen values, a changed suite is refused,
`trials suite run` flies the pilot and the descend baseline, and `trials suite card` writes the citable card."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from viva_sitl.evaluation.suites import (
    SPLITS,
    card,
    check_frozen,
    load_suite,
    safety_gain,
    split_hashes,
    suite_hash,
    suite_names,
)

REPO = Path(__file__).resolve().parents[1]
SDD = REPO.parent / "shared" / "footage" / "sdd"


def _cli(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "viva_sitl", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


@pytest.mark.parametrize("name", ["synthetic-emergency", "sdd-emergency"])
def test_shipped_suites_hash_to_their_frozen_values(name: str) -> None:
    assert name in suite_names()
    if name.startswith("sdd") and not SDD.is_dir():
        pytest.skip(f"{SDD} is absent")
    su = load_suite(name)
    assert su.id == f"{name}@v1" and tuple(su.splits) == SPLITS
    for split in SPLITS:
        got = split_hashes(su.splits[split])
        check_frozen(su, split, got)  # raises when the content moved
        assert got == su.frozen[split]
    dev, test = su.splits["dev"], su.splits["test"]
    # the test split is held out: other ground (synthetic) or other footage (SDD), other seeds
    assert dev.seed != test.seed and (dev.footage != test.footage or dev.east_m != test.east_m)


def test_a_changed_suite_is_refused_naming_what_changed(tmp_path: Path) -> None:
    src = (REPO / "viva_sitl" / "data" / "suites" / "synthetic-emergency.toml").read_text()
    changed = tmp_path / "mine.toml"
    changed.write_text(src.replace("seed = 202", "seed = 203"))
    r = _cli("trials", "suite", "run", str(changed), "--pilot", "descend", "-o", str(tmp_path / "out"))
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "viva-sitl trials: suite synthetic-emergency@v1, split test: content hash "
        f"{split_hashes(load_suite(str(changed)).splits['test'])['sha256'][:12]} is not the frozen "
        f"{load_suite('synthetic-emergency').frozen['test']['sha256'][:12]} (scenarios changed): not the published "
        "suite; publish a new version to change it"
    ], r.stderr
    assert not (tmp_path / "out").exists()
    crit = tmp_path / "crit.toml"
    crit.write_text(src.replace("min_dist_person_m = 5.0, max_risk_level = 2 }\n\n[test", "min_dist_person_m = 3.0, "
                                "max_risk_level = 2 }\n\n[test"))  # fmt: skip
    with pytest.raises(ValueError, match=r"split dev: .* \(scoring changed\)"):
        su = load_suite(str(crit))
        check_frozen(su, "dev", split_hashes(su.splits["dev"]))
    for args, needle in (
        (
            ["run", "no-such-suite", "--pilot", "descend", "-o", str(tmp_path / "x")],
            "no suite 'no-such-suite'",
        ),
        (["card", str(tmp_path)], f"{tmp_path}: no suite.json"),
    ):
        r = _cli("trials", "suite", *args)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and needle in r.stderr, r.stderr


def test_safety_gain_is_the_relative_reduction_of_unsafe_outcomes() -> None:
    def rows(ok: list[bool | None]) -> list[dict]:  # type: ignore[type-arg]
        return [{"trial": k, "seed": k, "success": s} for k, s in enumerate(ok)]

    base = rows([False, False, False, False, True, True, True, True])  # descend unsafe in 4 of 8
    sg = safety_gain(rows([True, True, True, False, True, True, True, True]), base)  # the pilot in 1 of 8
    assert sg["pairs"] == 8 and sg["unsafe_descend"] == 0.5 and sg["unsafe_pilot"] == 0.125
    assert sg["value"] == 0.75 and sg["ci95"][0] <= 0.75 <= sg["ci95"][1] <= 1.0
    worse = safety_gain(rows([False] * 8), base)
    assert worse["value"] == -1.0
    # unscored trials are left out of the pairs; no unsafe descend outcome: no gain to speak of (null)
    assert safety_gain(rows([None] * 4 + [True] * 4), base)["pairs"] == 4
    assert safety_gain(rows([True] * 4), rows([True] * 4))["value"] is None


@pytest.mark.slow  # real campaigns: the pilot and the baseline, 2 trials each
def test_suite_run_and_card_on_the_synthetic_field(tmp_path: Path) -> None:
    out = tmp_path / "suite"
    r = _cli("trials", "suite", "run", "synthetic-emergency", "--pilot", "oracle", "--split", "dev", "--limit", "2",
             "--jobs", "2", "--no-progress", "-o", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = _cli("trials", "suite", "card", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == f"  card: {out / 'card.md'}, {out / 'card.json'}"
    c = json.loads((out / "card.json").read_text())
    su = load_suite("synthetic-emergency")
    assert c["suite"] == "synthetic-emergency@v1" and c["pilot"] == "oracle" and c["partial"] is True
    assert c["suite_sha256"] == suite_hash({s: su.frozen[s]["sha256"] for s in SPLITS})
    assert c["split_sha256"] == {"dev": su.frozen["dev"]["sha256"]} and list(c["splits"]) == ["dev"]
    assert c["timing"] == {
        "timing": "lockstep",
        "pilot_cpu_factor": None,
        "pilot_latency_ms": None,
        "speed": 4.0,
    }
    assert c["versions"]["viva-sitl"]
    dev = c["splits"]["dev"]
    res = json.loads((out / "dev" / "results.json").read_text())
    base = json.loads((out / "baseline" / "dev" / "results.json").read_text())
    assert [x["trial"] for x in res["rows"]] == [0, 1] and base["pilot"] == "descend"
    assert dev["success"]["k"] == res["aggregate"]["success"] and dev["trials"] == 20 and not dev["complete"]
    assert dev["safety_gain_vs_descend"] == safety_gain(res["rows"], base["rows"])
    assert dev["min_dist_person_m"]["mean"] == res["aggregate"]["scores"]["min_dist_person_m"]["mean"]
    assert sum(dev["risk_level"]["counts"].values()) == dev["risk_level"]["n"] == 2
    md = (out / "card.md").read_text()
    assert md.startswith("# synthetic-emergency@v1: `oracle`") and c["suite_sha256"] in md
    assert "PARTIAL RUN" in md and "| safety gain over descend |" in md and "| time to land |" in md
    # the card is a function of what OUT holds: written again, the same
    assert card(out) == c


@pytest.mark.slow  # real campaigns over the SDD footage
@pytest.mark.skipif(not SDD.is_dir(), reason=f"{SDD} is absent")
def test_suite_over_the_sdd_footage(tmp_path: Path) -> None:
    out = tmp_path / "sdd"
    r = _cli("trials", "suite", "run", "sdd-emergency", "--pilot", "descend", "--split", "test", "--limit", "1",
             "--jobs", "1", "--no-progress", "-o", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert not (out / "baseline").exists()  # descend is its own baseline
    c = card(out)
    t = c["splits"]["test"]
    row = json.loads((out / "test" / "results.json").read_text())["rows"][0]
    assert row["footage"] == "sdd-deathcircle-4" and row["persons_present"] is True  # real people, annotated
    assert t["min_dist_person_m"]["n"] == 1 and t["min_dist_person_m"]["mean"] == row["min_dist_person_m"]
    sg = t["safety_gain_vs_descend"]
    assert sg["value"] in (None, 0.0)  # descend against itself gains nothing
