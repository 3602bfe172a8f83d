"""``jaxapf compare``: methods compared each at its tuned best under equal budgets, on held-out fields.

==================  ===================================================================
:mod:`.spec`        the compare spec (TOML), validated into a :class:`CompareSpec`
:mod:`.select`      each method's gains chosen on training fields under the same budget
:mod:`.protocol`    the whole command: selection, held-out test sweep, report, ``compare.md``
==================  ===================================================================
"""

from .protocol import run_compare, run_compare_spec, test_sweep_spec
from .select import Selection
from .spec import CompareSpec, load_compare_spec, parse_compare_spec

__all__ = ["run_compare", "run_compare_spec", "test_sweep_spec", "Selection", "CompareSpec",
           "load_compare_spec", "parse_compare_spec"]
