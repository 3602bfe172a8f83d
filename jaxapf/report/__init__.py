"""``jaxapf report``: statistics, figures and tables from the episodes of a sweep.

=================  =====================================================================
:mod:`.build`      :func:`build_report` and its :class:`ReportOptions`
:mod:`.load`       reading a sweep for a report; which metrics a report shows (from the registry)
:mod:`.select`     settings, filters, and pairing every setting with its baseline
:mod:`.tables`     per-setting summaries and paired comparisons, and their text
:mod:`.document`   the document model and its Markdown and HTML renderers
:mod:`.latex`      the LaTeX tables
:mod:`.figures`    the figures
:mod:`.gallery`    the worst episodes, re-simulated and drawn
=================  =====================================================================
"""

from .build import ReportOptions, ReportResult, build_report
from .load import ReportError, load_sweep, report_metrics, validate_sweep
from .select import ignored_columns, parse_filters, setting_labels, setting_table, swept_columns
from .tables import ALL, compare, summarize

__all__ = ["build_report", "ReportOptions", "ReportResult", "ReportError", "load_sweep", "validate_sweep",
           "report_metrics", "setting_table", "swept_columns", "setting_labels", "parse_filters", "ignored_columns",
           "summarize", "compare", "ALL"]
