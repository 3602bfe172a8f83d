"""Every repository spec keeps its identity: the sweep spec's hash, the tune spec's digest and the compare
spec's digest that name its runs (a changed one would start them again and part them from their results).
The expected values are tests/data/spec_identities.json; a spec that really changes gets its new value there
(``python tests/test_spec_identities.py``), in the same commit."""

from __future__ import annotations

import json
import sys
import warnings

from conftest import ROOT

from jaxapf.validation import BoundWarning, ConfigError

EXPECTED = ROOT / "tests" / "data" / "spec_identities.json"


def identities() -> dict[str, dict[str, str]]:
    """Per spec file, the identity of each kind of spec it parses as."""
    from jaxapf.compare import load_compare_spec
    from jaxapf.compare.select import spec_digest
    from jaxapf.sweep import load_spec
    from jaxapf.tune import load_tune_spec

    kinds = {"sweep": lambda p: load_spec(p).hash, "tune": lambda p: load_tune_spec(p)[0].digest(),
             "compare": lambda p: spec_digest(load_compare_spec(p)[0])}
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)
        for path in sorted((ROOT / "sweeps").glob("*.toml")):
            row = {}
            for kind, identity in kinds.items():
                try:
                    row[kind] = identity(path)
                except ConfigError:  # not a spec of this kind
                    pass
            out[path.name] = row
    return out


def test_every_repository_spec_keeps_its_identity():
    assert identities() == json.loads(EXPECTED.read_text())


if __name__ == "__main__":
    EXPECTED.write_text(json.dumps(identities(), indent=1, sort_keys=True) + "\n")
    sys.exit(0)
