"""``python -m jaxapf``: the command line (:mod:`jaxapf.cli`), run by the program around it
(:mod:`jaxapf.cli.program`: Ctrl-C at any moment is one line)."""

import sys

from .cli.program import console

sys.exit(console())
