"""``python -m jaxapf``: the command line (:mod:`jaxapf.cli`)."""

import sys

try:
    from .cli import console
except KeyboardInterrupt:  # Ctrl-C while the command line is still being imported
    print("jaxapf: interrupted; nothing was written", file=sys.stderr)
    sys.exit(130)

sys.exit(console())
