"""``python -m jaxapf``: the command line (:mod:`jaxapf.cli`)."""

import sys

from .cli import console

sys.exit(console())
