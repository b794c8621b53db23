"""AUTOPILOT_VERSION's version fields, in PX4's encoding.

flight_sw_version = major << 24 | minor << 16 | patch << 8 | type, with PX4's FIRMWARE_VERSION_TYPE in the low byte
(dev 0, alpha 64, beta 128, rc 192, official 255), from the package version. flight_custom_version holds the first
8 bytes of the git commit hash as PX4 stores them (the 64-bit number of the first 16 hex digits, copied in
little-endian byte order: QGroundControl prints the bytes from the last to the first), when the package runs from a
git checkout; zeros otherwise (a wheel install has no commit).
"""

from __future__ import annotations

import re
import subprocess
from functools import lru_cache
from pathlib import Path

from viva_sitl import __version__

__all__ = [
    "FLIGHT_SW_VERSION",
    "flight_custom_version",
    "encode_sw_version",
    "git_commit_hash",
    "custom_version",
]

VERSION_TYPE_DEV = 0
VERSION_TYPE_ALPHA = 64
VERSION_TYPE_BETA = 128
VERSION_TYPE_RC = 192
VERSION_TYPE_OFFICIAL = 255

_VERSION_RE = re.compile(r"^\s*v?(\d+)(?:\.(\d+))?(?:\.(\d+))?(.*)$")


def encode_sw_version(version: str) -> int:
    """ "1.2.3" -> 0x010203FF; pre-releases ("1.2.3rc1", "1.2.3b2", "1.2.3a1", "1.2.3.dev4") get PX4's type byte."""
    m = _VERSION_RE.match(version)
    if m is None:
        return VERSION_TYPE_DEV
    major, minor, patch = (min(255, int(g)) if g else 0 for g in m.group(1, 2, 3))
    rest = m.group(4).lower()
    if "dev" in rest or "+" in rest:
        vtype = VERSION_TYPE_DEV
    elif "rc" in rest:
        vtype = VERSION_TYPE_RC
    elif "b" in rest:
        vtype = VERSION_TYPE_BETA
    elif "a" in rest:
        vtype = VERSION_TYPE_ALPHA
    else:
        vtype = VERSION_TYPE_OFFICIAL
    return (major << 24) | (minor << 16) | (patch << 8) | vtype


@lru_cache(maxsize=1)
def git_commit_hash(package_dir: Path | None = None) -> str | None:
    """The commit of the source checkout the package runs from (40 hex digits), None outside a git checkout."""
    root = (package_dir or Path(__file__).resolve().parents[1]).parent
    if not (root / ".git").exists():  # a worktree has a .git file, a clone a .git directory
        return None
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5.0,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and re.fullmatch(r"[0-9a-f]{40}", commit) else None


def custom_version(commit: str | None) -> bytes:
    """flight_custom_version (8 bytes) for a commit hash, as PX4 fills it; zeros without a commit."""
    if not commit:
        return bytes(8)
    return int(commit[:16], 16).to_bytes(8, "little")


def flight_custom_version() -> bytes:
    """This process's flight_custom_version (git is asked once, on first use)."""
    return custom_version(git_commit_hash())


FLIGHT_SW_VERSION = encode_sw_version(__version__)
