"""One command-line call with its output captured; imports nothing but the standard library, so the
subprocess of tests/test_cli_imports.py that checks which modules the CLI imports can use it too."""

import contextlib
import io


def capture(main, argv):
    """``(status, stdout, stderr)`` of ``main(argv)``; argparse's exits give their status."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exit:
            rc = exit.code
    return rc, out.getvalue(), err.getvalue()
