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
:mod:`.worker`     the second process that draws the figures from the rows and the gallery
=================  =====================================================================
"""

from importlib import import_module

#: public name -> the module it lives in, imported on first use (PEP 562), so that the command line can
#: start the report's second process (:mod:`.worker`) before the report's own imports
_LAZY = {
    "build_report": ".build", "ReportOptions": ".build", "ReportResult": ".build",
    "ReportError": ".load", "load_sweep": ".load", "validate_sweep": ".load", "report_metrics": ".load",
    "setting_table": ".select", "swept_columns": ".select", "setting_labels": ".select", "parse_filters": ".select",
    "ignored_columns": ".select", "summarize": ".tables", "compare": ".tables", "ALL": ".tables",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
