"""argparse value types and the one-line-error parser shared by every `viva-sitl` command (one wording per mistake).

positive_float  a finite number > 0                        "expected a positive number, got '...'"
hfov            a positive number below 180 (degrees)      "a horizontal FoV must be below 180 degrees, ..."
port            a UDP/TCP port 0..65535                    "expected a port number" / "port out of range: N"
pose            north,east,alt,roll,pitch,yaw (6 numbers)  "--pose needs 6 (finite) numbers ..."
home            lat,lon[,alt] (PX4_HOME_* syntax)          the message of viva_sitl.geo.parse_home
nonneg_int      an integer >= 0                            "expected an integer >= 0, got '...'"
pos_int         an integer >= 1                            "expected an integer >= 1, got '...'"
positive_int    an integer >= 1 (perception's wording)     "expected a positive integer, got '...'"
OneLineErrors   an ArgumentParser whose errors are one line: "prog: error: ... (see prog --help)", exit 2
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import NoReturn

from viva_sitl.geo import GeoOrigin, parse_home


class OneLineErrors(argparse.ArgumentParser):
    """A bad flag is one line on stderr (the usage synopsis stays in --help), exit status 2 as argparse."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def hfov(text: str) -> float:
    v = positive_float(text)
    if v >= 180.0:
        raise argparse.ArgumentTypeError(f"a horizontal FoV must be below 180 degrees, got {text!r}")
    return v


def port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"port out of range: {v}")
    return v


def pose(text: str) -> tuple[float, float, float, float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--pose needs 6 numbers north,east,alt,roll,pitch,yaw; got {text!r}"
        ) from None
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"--pose needs 6 finite numbers north,east,alt,roll,pitch,yaw; got {text!r}"
        )
    return values  # type: ignore[return-value]


def home(text: str) -> GeoOrigin:
    try:
        return parse_home(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


def pos_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def nonneg_float(text: str) -> float:
    """A finite number >= 0 (e.g. --pilot-cpu-factor: 0 = lockstep)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0.0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def add_timing_flags(parser: argparse.ArgumentParser, default_from: str) -> None:
    """--timing, --pilot-cpu-factor and --pilot-latency-ms (viva_sitl.timing), for `run` and `trials run`."""
    parser.add_argument(
        "--timing", choices=("realtime", "lockstep", "charged"),
        help=f"how sim time relates to an external pilot's computing (default: {default_from}, else realtime): "
        "lockstep stops the clock while the pilot's processes compute (scores independent of the machine and "
        "its load); charged also bills their CPU time x --pilot-cpu-factor in sim time (README: Timing)",
    )  # fmt: skip
    parser.add_argument(
        "--pilot-cpu-factor", type=nonneg_float, metavar="F",
        help="charged timing: sim seconds billed per CPU second of the pilot (2 = a computer 2x slower than this "
        "one; 0 = lockstep; default 1)",
    )  # fmt: skip
    parser.add_argument(
        "--pilot-latency-ms", type=nonneg_float, metavar="MS",
        help="charged timing: a fixed latency per frame: what the pilot sends after frame k takes effect no earlier "
        "than the frame's sim time + MS (with --pilot-cpu-factor, the later of the two; default 0)",
    )  # fmt: skip


def add_cache_args(p: argparse.ArgumentParser) -> None:
    """`--no-cache` / `--cache-max-gb` / `--tile-cache-dir` / `--cache-compact`: the automatic tile cache of heavy
    (>= ~4K) footage (viva_sitl.footage.autocache)."""
    g = p.add_argument_group("automatic tile cache of >= 4K footage")
    g.add_argument(
        "--no-cache", action="store_true", help="read heavy footage from the video, build no tile cache"
    )
    g.add_argument(
        "--cache-max-gb", type=positive_float, default=32.0,
        help="size bound of all automatic tile caches together; least recently used caches are removed "
        "(default 32; ~9.5 MiB per 4K frame, ~16.7 GiB per minute of 30 fps 4K, ~32 MiB per 8K frame)",
    )  # fmt: skip
    g.add_argument(
        "--cache-compact", action="store_true",
        help="build the cache ~30 %% smaller (full-resolution tiles gradient-coded, the same pixels: ~6.5 MiB per "
        "4K frame, ~20 per 8K frame), its full-resolution reads ~1.3x slower (6-13 %% fewer steps/s at 50 m over "
        "4K); an existing cache of the other kind is not reused",
    )  # fmt: skip
    g.add_argument(
        "--tile-cache-dir", type=Path, help="where they go (default $XDG_CACHE_HOME/viva-sitl/tiles-auto)"
    )
