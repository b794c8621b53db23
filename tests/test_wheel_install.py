"""The footage catalog works from a plain wheel install: build the wheel, install it (no source tree on the path) into
a fresh virtual environment that sees the test environment's dependencies, run `viva-sitl footage list` from
another directory. Skipped only when a wheel cannot be built here (no `wheel`/`setuptools` backend offline)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
COPY_IGNORE = (".git", "build", "dist", "*.egg-info", "runs", ".venv", "__pycache__", ".*_cache", "shared")


@pytest.mark.slow  # builds and installs a wheel
@pytest.mark.timeout(600)
def test_catalog_from_a_wheel_install(tmp_path: Path) -> None:
    # build from a copy of the source (an in-tree build would leave build/ and *.egg-info in the checkout)
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(*COPY_IGNORE))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIVA_SITL_SHARED_DIR")}
    dist = tmp_path / "dist"
    build = None
    for isolation in ([], ["--no-build-isolation"]):  # isolated (fetches the build backend), else this env's
        build = subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "--no-deps", *isolation, "-q", "-w", str(dist), str(src)],
            capture_output=True, text=True, timeout=300, env=env,
        )  # fmt: skip
        if build.returncode == 0:
            break
    assert build is not None
    wheels = sorted(dist.glob("viva_sitl-*.whl"))
    if build.returncode != 0 or not wheels:
        pytest.skip(f"cannot build a wheel here: {build.stderr.strip()[-300:]}")
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = subprocess.run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip
    # the dependencies (numpy, opencv, av, ...) come from this test environment; viva_sitl only from the wheel
    deps = sysconfig.get_paths()["purelib"]
    (Path(site) / "test-deps.pth").write_text(deps + "\n")
    subprocess.run(
        [str(py), "-m", "pip", "install", "--no-deps", "-q", str(wheels[0])],
        check=True, capture_output=True, text=True, timeout=300, env=env,
    )  # fmt: skip
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = subprocess.run(
        [str(py), "-c", "import viva_sitl; print(viva_sitl.__file__)"],
        capture_output=True, text=True, cwd=elsewhere, env=env, check=True,
    ).stdout.strip()  # fmt: skip
    assert Path(where).is_relative_to(Path(site)), f"viva_sitl imported from {where}, not the wheel"
    res = subprocess.run(
        [str(env_dir / "bin" / "viva-sitl"), "footage", "list"],
        capture_output=True, text=True, cwd=elsewhere, env=env, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    for name in ("synthetic", "interchange", "songdo-00003", "viva-safeland"):
        assert name in res.stdout, res.stdout
    info = subprocess.run(
        [str(py), "-m", "viva_sitl", "footage", "info", "synthetic"],
        capture_output=True, text=True, cwd=elsewhere, env=env, timeout=120,
    )  # fmt: skip
    assert info.returncode == 0 and "SYNTHETIC CALIBRATION FIELD" in info.stdout, info.stderr
