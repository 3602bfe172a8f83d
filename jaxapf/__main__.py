"""``python -m jaxapf``: the command line (:mod:`jaxapf.cli`)."""

import sys

from .cli import main

sys.exit(main())
