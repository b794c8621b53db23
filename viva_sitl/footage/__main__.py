"""`python -m viva_sitl.footage list|info|get|ingest` (the same as `viva-sitl footage ...`)."""

import logging
import sys

from viva_sitl.footage.cli import footage_main

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
raise SystemExit(footage_main(sys.argv[1:]))
